"""Pictures of a simulation (vdad.render.pictures): these tests really render on EGL."""

import subprocess
import sys

import numpy as np
import pytest

from vdad.errors import InputError, RenderError
from vdad.render.pictures import (
    MARKER_RGB,
    Frame,
    SceneRenderer,
    active_joints,
    motion_strip,
    palette,
    record,
    rigid_groups,
    write,
)
from vdad.scenes import pendulum

WHITE = (255, 255, 255)


@pytest.fixture(scope="module")
def scene():
    return pendulum(n_bodies=20)


@pytest.fixture(scope="module")
def small(scene):
    with SceneRenderer(scene.model, scene.environment, 160, 120) as renderer:
        yield renderer


@pytest.fixture(scope="module")
def medium(scene):
    """320 x 240: every link of the 20-link chain covers some whole pixels."""
    with SceneRenderer(scene.model, scene.environment, 320, 240) as renderer:
        yield renderer


def _colours(image):
    """Distinct colours of ``image`` and their pixel counts: {(r, g, b): count}."""
    rows, counts = np.unique(image.reshape(-1, 3), axis=0, return_counts=True)
    return {tuple(int(c) for c in row): int(k) for row, k in zip(rows, counts, strict=True)}


def _check_group_colours(frame, nb):
    """A flat group image shows exactly the colours of its rigid groups, each of
    them, and nothing else besides white (no antialiasing blends)."""
    seen = set(_colours(frame.image)) - {WHITE}
    groups = {tuple(int(c) for c in row) for row in palette(frame.n_groups)}
    assert seen == groups
    assert len(seen) == frame.n_groups
    assert not seen & {tuple(int(c) for c in row) for row in palette(nb)[frame.n_groups:]}


def test_pendulum_pixels_where_the_camera_projects_the_links(scene, small):
    sim = scene.simulator()
    R, p = sim.body_poses()
    camera = scene.camera.with_resolution(160, 120)
    image = small.render(camera, R, p)
    assert image.shape == (120, 160, 3) and image.dtype == np.uint8
    background = np.all(image == 255, axis=2)
    assert 0 < np.count_nonzero(~background) < 0.2 * background.size
    L = scene.params["link_length"]
    centres = p + R @ np.array([0.0, 0.0, -L / 2])           # the middle of every link
    xy, depth = camera.project(centres)
    assert np.all(depth > 0)
    col = np.floor(xy[:, 0]).astype(int)
    row = 120 - 1 - np.floor(xy[:, 1]).astype(int)            # image rows from the top
    assert np.all((0 <= col) & (col < 160) & (0 <= row) & (row < 120))
    assert not background[row[10], col[10]]                    # the middle link's centre
    near = [background[r - 1:r + 2, c - 1:c + 2].all() for r, c in zip(row, col, strict=True)]
    assert not any(near)                                       # every link, within a pixel
    # the chain's mirror image across the vertical through the pivot is empty
    pivot = camera.project(p[0])[0]
    mirror = np.floor(2 * pivot[0] - xy[:, 0]).astype(int)
    assert background[row, np.clip(mirror, 0, 159)].all()


def test_flat_group_colours_count_the_rigid_groups(scene, medium):
    sim = scene.simulator(method="adaptive", threshold=1e-4)
    frames = record(sim, 200, every=50, renderer=medium, color="group", flat=True)
    assert [f.step for f in frames] == [0, 50, 100, 150, 200]
    assert frames[0].n_groups == 20                      # before the first step: all free
    assert all(1 < f.n_groups < 20 for f in frames[1:])
    assert frames[-1].n_groups == len(np.unique(rigid_groups(sim)))
    for frame in frames:
        assert frame.image.shape == (240, 320, 3)
        _check_group_colours(frame, 20)


def test_rigid_group_labels(scene):
    sim = scene.simulator(method="adaptive", threshold=1e-4)
    np.testing.assert_array_equal(rigid_groups(sim), np.arange(20))
    np.testing.assert_array_equal(active_joints(sim), np.arange(20))
    sim.step(200)
    labels = rigid_groups(sim)
    n = labels.max() + 1
    assert 1 < n < 20 and set(labels) == set(range(n))
    first = [np.flatnonzero(labels == k)[0] for k in range(n)]
    assert first == sorted(first) and first[0] == 0          # numbered by first body
    # bodies of one group are contiguous links of the chain; each moving joint
    # starts a new group (the pendulum's joints are its bodies' inbound joints)
    assert np.all(np.diff(labels) >= 0)
    starts = np.flatnonzero(np.diff(np.r_[-1, labels]))
    np.testing.assert_array_equal(starts, active_joints(sim))
    frozen = scene.simulator(method="adaptive", threshold=1e2).step(30)
    np.testing.assert_array_equal(rigid_groups(frozen), np.zeros(20))   # welded to the world
    assert len(active_joints(frozen)) == 0


def test_dca_shows_every_body_in_its_own_colour(scene, medium):
    frames = record(scene.simulator(), 10, every=10, renderer=medium, flat=True)
    assert len(frames) == 2 and frames[1].t == pytest.approx(10 * scene.dt)
    for frame in frames:
        assert frame.n_groups == 20
        np.testing.assert_array_equal(frame.groups, np.arange(20))
        np.testing.assert_array_equal(frame.active, np.arange(20))
        _check_group_colours(frame, 20)


def test_markers_show_the_active_joints(scene, medium):
    def red(frame):
        return _colours(frame.image).get(MARKER_RGB, 0)

    dca = record(scene.simulator(), 0, renderer=medium, show_active=True, flat=True)[0]
    plain = record(scene.simulator(), 0, renderer=medium, flat=True)[0]
    assert red(dca) > 20 and red(plain) == 0
    sim = scene.simulator(method="adaptive", threshold=1e-4)
    some = record(sim, 200, every=200, renderer=medium, show_active=True, flat=True)[-1]
    assert 0 < len(some.active) < 20
    assert 0 < red(some) < red(dca)
    frozen = scene.simulator(method="adaptive", threshold=1e2)
    none = record(frozen, 30, every=30, renderer=medium, show_active=True, flat=True)[-1]
    assert len(none.active) == 0 and red(none) == 0
    # lit: red-ish marker pixels, none without markers
    lit = medium.render(scene.camera, *scene.simulator().body_poses(), markers=np.zeros((1, 3)))
    redish = (lit[..., 0] > 180) & (lit[..., 1] < 80) & (lit[..., 2] < 80)
    assert redish.sum() > 5


def test_record_colour_modes_and_default_renderer(scene):
    sim = scene.simulator(method="adaptive", threshold=1e-4)
    frames = record(sim, 4, every=2, color="body")        # a renderer of its own, 320 x 240
    assert len(frames) == 3 and all(isinstance(f, Frame) for f in frames)
    assert frames[0].image.shape == (scene.camera.height, scene.camera.width, 3)
    geom = record(scene.simulator(), 0, color="geom", flat=True)[0]
    grey = tuple(int(round(255 * c)) for c in scene.model.bodies[0].geoms[0].rgba[:3])
    assert set(_colours(geom.image)) == {WHITE, grey}
    with pytest.raises(InputError, match="color"):
        record(sim, 1, color="rainbow")
    with pytest.raises(InputError, match="every"):
        record(sim, 1, every=0)


def test_render_checks_its_arguments(scene, small):
    R, p = scene.simulator().body_poses()
    with pytest.raises(InputError, match="R must have shape"):
        small.render(scene.camera, R[:3], p)
    with pytest.raises(InputError, match="colors"):
        small.render(scene.camera, R, p, colors=np.zeros((3, 3), np.uint8))
    with pytest.raises(InputError, match="markers"):
        small.render(scene.camera, R, p, markers=np.zeros(3))
    with pytest.raises(InputError, match="camera"):
        small.render("camera", R, p)
    renderer = SceneRenderer(scene.model, width=16, height=12)
    renderer.close()
    with pytest.raises(RenderError, match="closed"):
        renderer.render(scene.camera, R, p)


def test_palette_distinct():
    colours = palette(2000)
    assert colours.shape == (2000, 3) and colours.dtype == np.uint8
    assert len(np.unique(colours, axis=0)) == 2000
    rows = {tuple(int(c) for c in row) for row in colours}
    assert WHITE not in rows and MARKER_RGB not in rows
    assert not np.any((colours.max(axis=1) - colours.min(axis=1)) < 20)   # no greys
    np.testing.assert_array_equal(palette(7), colours[:7])
    assert palette(0).shape == (0, 3)
    with pytest.raises(InputError):
        palette(-1)


def _stripes(h, w, k):
    image = np.full((h, w, 3), 255, np.uint8)
    image[:, k::7] = (10 * k, 100, 200 - 10 * k)
    return image


def test_motion_strip_layout_and_labels():
    images = [_stripes(30, w, k) for k, w in enumerate((40, 50, 60))]
    strip = motion_strip(images, gap=5)
    assert strip.shape == (30, 40 + 50 + 60 + 2 * 5, 3)
    np.testing.assert_array_equal(strip[:, 45:95], images[1])
    assert np.all(strip[:, 40:45] == 255)                     # the gap is white
    labelled = motion_strip(images, gap=5, labels=["t = 0.00 s", "t = 0.50 s", "t = 1.00 s"])
    assert labelled.shape[1] == strip.shape[1] and labelled.shape[0] > 30
    np.testing.assert_array_equal(labelled[:30], strip)
    for left, width in ((0, 40), (45, 50), (100, 60)):
        assert np.any(labelled[30:, left:left + width] < 128)   # dark text under each
    grid = motion_strip(images, columns=2, gap=3)
    assert grid.shape == (30 + 3 + 30, 60 + 3 + 50, 3)          # columns as wide as widest
    np.testing.assert_array_equal(grid[33:, :60], images[2])
    with pytest.raises(InputError, match="labels"):
        motion_strip(images, labels=["a"])


def test_write_png_gif_mp4(tmp_path):
    from PIL import Image

    images = [_stripes(24, 32, k) for k in range(5)]
    one = write(images[0], tmp_path / "one.png")
    assert one == [tmp_path / "one.png"]
    np.testing.assert_array_equal(np.asarray(Image.open(one[0]).convert("RGB")), images[0])
    several = write(images[:3], tmp_path / "seq.png")
    assert [p.name for p in several] == ["seq_0000.png", "seq_0001.png", "seq_0002.png"]
    np.testing.assert_array_equal(np.asarray(Image.open(several[2]).convert("RGB")), images[2])
    gif = write(images, tmp_path / "anim.gif", fps=10)[0]
    with Image.open(gif) as animation:
        assert animation.n_frames == 5
        assert animation.info["loop"] == 0 and animation.info["duration"] == 100
    odd = [np.full((25, 33, 3), 40 * k, np.uint8) for k in range(4)]
    mp4 = write(odd, tmp_path / "video.mp4", fps=12)[0]
    assert mp4.stat().st_size > 0
    import imageio.v2 as imageio

    frames = imageio.mimread(mp4)
    assert len(frames) == 4 and frames[0].shape == (26, 34, 3)   # padded to even sizes
    with pytest.raises(InputError, match=r"\.png, \.gif, \.mp4"):
        write(images, tmp_path / "anim.avi")
    with pytest.raises(InputError, match="same size"):
        write([images[0], odd[0]], tmp_path / "mixed.gif")
    with pytest.raises(InputError, match="does not exist"):
        write(images[0], tmp_path / "missing" / "one.png")
    with pytest.raises(InputError, match="uint8"):
        write(np.zeros((4, 4, 3)), tmp_path / "float.png")


def test_write_frames_of_a_recording(scene, small, tmp_path):
    frames = record(scene.simulator(), 6, every=3, renderer=small)
    gif = write(frames, tmp_path / "swing.gif")[0]
    from PIL import Image

    with Image.open(gif) as animation:
        assert animation.n_frames == 3 and animation.size == (160, 120)


def test_importing_pictures_loads_no_opengl():
    code = ("import sys, vdad, vdad.render.pictures; "
            "assert not {'pyrender', 'OpenGL'} & set(sys.modules), sorted(sys.modules)")
    subprocess.run([sys.executable, "-c", code], check=True)


def test_pictures_between_rendered_visibility_steps(scene, small):
    """view-oq counts pixels on the same GL context between frames: neither disturbs
    the other."""
    sim = scene.simulator(method="view-oq", threshold=1e-4, counting="merged",
                          resolution=(80, 60))
    frames = record(sim, 20, every=10, renderer=small, flat=True)
    assert len(frames) == 3
    for frame in frames:
        _check_group_colours(frame, 20)
    reference = record(scene.simulator(), 0, renderer=small, flat=True)[0]
    np.testing.assert_array_equal(frames[0].image, reference.image)


@pytest.mark.parametrize("build", ["pictures", "counting"])
def test_missing_render_extra_is_a_render_error_before_any_mesh(build, scene, monkeypatch):
    """Without the render extra (no pyrender, hence no trimesh) the renderer and the
    pixel counter stop with the install hint, not with an ImportError from meshing."""
    from vdad.model import Geom
    from vdad.render import context
    from vdad.render.counting import PixelCounter

    def no_trimesh(*args, **kwargs):
        raise ModuleNotFoundError("No module named 'trimesh'")

    monkeypatch.setattr(context, "_renderer", None)
    monkeypatch.setitem(sys.modules, "pyrender", None)          # import pyrender fails
    monkeypatch.setattr(Geom, "to_trimesh", no_trimesh)
    make = SceneRenderer if build == "pictures" else PixelCounter
    with pytest.raises(RenderError, match=r"pip install 'vdad\[render\]'"):
        make(scene.model)
