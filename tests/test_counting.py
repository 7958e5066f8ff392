"""Rendered per-body visible pixel counts (vdad.render.counting, Kim 2008 §5.4).

Everything here renders on EGL (Mesa llvmpipe in CI); nothing is skipped.
"""

import os
import subprocess
import sys
import threading

import numpy as np
import pytest
import trimesh

from vdad import Body, Geom, InputError, Joint, Model, Pose, RenderError
from vdad.camera import Camera
from vdad.environment import wall
from vdad.render import context
from vdad.render.counting import PixelCounter

CAMERA = Camera(position=(4.0, 0.0, 1.0), target=(0.0, 0.0, 1.0))   # 320 x 240, yfov 60 deg


def free_bodies(geoms_per_body):
    """A model of free bodies, body ``i`` carrying the geoms ``geoms_per_body[i]``."""
    bodies = [Body(f"b{i}", 1.0, geoms=tuple(g)) for i, g in enumerate(geoms_per_body)]
    return Model(bodies, [Joint(f"j{i}", None, f"b{i}", "free") for i in range(len(bodies))])


def rot_x(a):
    c, s = np.cos(a), np.sin(a)
    return np.array([[1.0, 0, 0], [0, c, -s], [0, s, c]])


def rot_z(a):
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1.0]])


# Bodies that occlude each other, cut by the viewport edges and the near plane, hidden
# in part by a wall, behind the camera, off screen and without geometry. No two
# surfaces are coplanar and no bodies interpenetrate.
SCENE_GEOMS = [
    [Geom("box", (0.3, 0.3, 0.3))],                         # 0: in the middle
    [Geom("sphere", (0.4,))],                               # 1: partly behind 0
    [Geom("capsule", (0.1, 0.3))],                          # 2: in front of 0
    [Geom("sphere", (0.5,))],                               # 3: cut by the left edge
    [Geom("box", (0.3, 0.05, 0.05))],                       # 4: crosses the near plane
    [Geom("sphere", (0.3,))],                               # 5: peeks over the wall
    [Geom("sphere", (0.3,))],                               # 6: behind the camera
    [Geom("box", (0.2, 0.2, 0.2))],                         # 7: off screen
    [],                                                     # 8: no geometry
    [Geom("capsule", (0.15, 0.4), Pose((0, 0, 0.2))),       # 9: two geoms, cut by the top
     Geom("box", (0.1, 0.1, 0.1), Pose((0, 0.3, 0)))],
]
SCENE_P = np.array([[0, 0, 1.0], [-1.0, 0.35, 1.2], [1.0, -0.15, 0.9], [0.0, -3.2, 1.0],
                    [3.85, -0.12, 0.92], [-1.5, 1.8, 1.25], [6.0, 0.0, 1.0], [0.0, 8.0, 1.0],
                    [0.0, 0.0, 0.0], [-0.5, -1.2, 3.4]])
SCENE_R = np.stack([np.eye(3)] * 2 + [rot_x(0.7)] + [np.eye(3)] * 6 + [rot_z(0.7)])
SCENE_WALL = wall((-0.9, 1.0), (-0.9, 3.0), height=1.2)


@pytest.fixture(scope="module")
def scene():
    model = free_bodies(SCENE_GEOMS)
    return model, {m: PixelCounter(model, SCENE_WALL, method=m) for m in ("merged", "queries")}


def world_vertices(i):
    vertices = np.concatenate([g.to_trimesh().vertices for g in SCENE_GEOMS[i]])
    return vertices @ SCENE_R[i].T + SCENE_P[i]


def test_scene_is_what_it_claims():
    """The scene exercises viewport clipping, the near plane and both sides of the camera."""
    size = [CAMERA.width, CAMERA.height]
    left, _ = CAMERA.project(world_vertices(3))
    top, _ = CAMERA.project(world_vertices(9))
    for xy in (left, top):
        assert ((xy >= 0) & (xy <= size)).all(axis=1).any()       # partly in view
    assert (left[:, 0] < 0).any() and (top[:, 1] > CAMERA.height).any()
    _, d = CAMERA.project(world_vertices(4))
    assert d.min() < 0 < CAMERA.znear < d.max()
    assert (CAMERA.project(world_vertices(6))[1] < 0).all()
    xy, d = CAMERA.project(world_vertices(7))
    assert (d > 0).all() and (xy[:, 0] > CAMERA.width).all()


def test_methods_agree_with_occlusion_clipping_and_environment(scene):
    model, counters = scene
    merged = counters["merged"].counts(CAMERA, SCENE_R, SCENE_P)
    queries = counters["queries"].counts(CAMERA, SCENE_R, SCENE_P)
    assert merged.dtype == queries.dtype == np.int64 and merged.shape == (model.nb,)
    assert (merged[[0, 1, 2, 3, 4, 5, 9]] > 100).all()
    assert (merged[[6, 7, 8]] == 0).all() and (queries[[6, 7, 8]] == 0).all()
    # The queries count every fragment that ties the nearest depth: a body's own front
    # and back faces where they meet (silhouettes, the near-plane cut). Nothing else.
    assert (queries >= merged).all()
    assert (queries - merged <= 2 + 0.002 * merged).all()
    assert np.array_equal(queries[[0, 1, 2, 3, 5, 9]], merged[[0, 1, 2, 3, 5, 9]])
    # The camera's own resolution is irrelevant: the counter draws at its own.
    assert np.array_equal(counters["merged"].counts(CAMERA.with_resolution(64, 64), SCENE_R,
                                                    SCENE_P), merged)


def test_occluders_hide_pixels(scene):
    """Body 1 loses pixels to bodies 0 and 2, body 5 to the wall."""
    model, counters = scene
    full = counters["merged"].counts(CAMERA, SCENE_R, SCENE_P)
    far = SCENE_P.copy()
    far[[0, 2]] += [0.0, 20.0, 0.0]
    alone = counters["merged"].counts(CAMERA, SCENE_R, far)
    assert alone[1] > 1.2 * full[1]
    without_wall = PixelCounter(model).counts(CAMERA, SCENE_R, SCENE_P)
    assert without_wall[5] > 1.5 * full[5]
    keep = [i for i in range(model.nb) if i != 5]
    assert np.array_equal(without_wall[keep], full[keep])


@pytest.mark.parametrize("method", ["merged", "queries"])
def test_body_behind_wall_behind_camera_or_off_screen_counts_zero(method):
    model = free_bodies([[Geom("sphere", (0.3,))]] * 3)
    R = np.stack([np.eye(3)] * 3)
    behind_wall = np.array([[-1.5, 1.8, 0.6]])
    counts = PixelCounter(model, SCENE_WALL, method=method).counts
    p = np.concatenate([behind_wall, [[6.0, 0.0, 1.0]], [[0.0, 8.0, 1.0]]])
    assert np.array_equal(counts(CAMERA, R, p), [0, 0, 0])
    # Without the wall the first one shows; seen from the other side, the second does.
    assert PixelCounter(model, method=method).counts(CAMERA, R, p)[0] > 100
    behind = Camera(position=(4.0, 0.0, 1.0), target=(8.0, 0.0, 1.0))
    assert counts(behind, R, p)[1] > 100


@pytest.mark.parametrize("method", ["merged", "queries"])
def test_camera_inside_a_body_sees_its_back_faces(method):
    model = free_bodies([[Geom("sphere", (1.0,))], [Geom("sphere", (0.3,))]])
    R, p = np.stack([np.eye(3)] * 2), np.array([[4.0, 0.0, 1.0], [0.0, 0.0, 1.0]])
    counts = PixelCounter(model, SCENE_WALL, method=method).counts(CAMERA, R, p)
    assert np.array_equal(counts, [CAMERA.width * CAMERA.height, 0])


def test_id_image_totals_equal_counts_and_rows_run_from_the_bottom(scene):
    model, counters = scene
    image = counters["merged"].id_image(CAMERA, SCENE_R, SCENE_P)
    assert image.shape == (CAMERA.height, CAMERA.width) and image.dtype == np.uint32
    totals = np.bincount(image.ravel(), minlength=model.nb + 1)
    assert np.array_equal(totals[1:], counters["merged"].counts(CAMERA, SCENE_R, SCENE_P))
    # Body 5 shows in the upper right, above the wall: image rows count from the bottom.
    (x, y), _ = CAMERA.project(SCENE_P[5] + [0.0, 0.0, 0.2])
    assert y > CAMERA.height / 2 and image[int(y), int(x)] == 6
    assert image[int(y) - 40, int(x)] == 0                    # the wall, not counted


@pytest.mark.parametrize("method", ["merged", "queries"])
def test_sphere_count_is_its_projected_ellipse_area(method):
    r = 0.5
    model = free_bodies([[Geom("mesh", mesh=trimesh.creation.icosphere(subdivisions=5,
                                                                        radius=r))]])
    centre = np.array([2.0, 0.7, 1.4])
    count = PixelCounter(model, method=method).counts(CAMERA, np.eye(3)[None], centre[None])[0]
    c = CAMERA.to_camera(centre)
    l, d = np.linalg.norm(c), -c[2]
    assert l > 1.05 * d                                        # off axis: an ellipse
    area = np.pi * CAMERA.focal**2 * r**2 * np.sqrt(l**2 - r**2) / (d**2 - r**2) ** 1.5
    assert abs(count - area) < 0.01 * area


def test_conventions_match_pyrender_segmentation():
    """Our id image equals pyrender's own SEG render of the same bodies, flipped."""
    import pyrender

    model = free_bodies([[Geom("capsule", (0.25, 0.6))], [Geom("box", (0.5, 0.4, 0.6))]])
    R = np.stack([rot_x(0.9) @ rot_z(0.3), rot_z(0.5)])
    p = np.array([[1.0, 0.5, 1.3], [-0.3, -0.6, 0.9]])
    camera = Camera(position=(3.0, 0.8, 1.8), target=(0.0, 0.0, 1.0), width=200, height=150)
    queries = PixelCounter(model, width=200, height=150, method="queries").counts(camera, R, p)

    renderer = context.gl_context(camera.width, camera.height)
    scene = pyrender.Scene()
    colours = [(255, 0, 0), (0, 255, 0)]
    seg = {}
    for i, body in enumerate(model.bodies):
        pose = np.eye(4)
        pose[:3, :3], pose[:3, 3] = R[i], p[i]
        # the counter's default tessellation
        mesh = pyrender.Mesh.from_trimesh(body.geoms[0].to_trimesh(sections=8))
        seg[scene.add(mesh, pose=pose)] = colours[i]
    scene.add(pyrender.PerspectiveCamera(yfov=camera.yfov, aspectRatio=200 / 150,
                                         znear=camera.znear, zfar=camera.zfar), pose=camera.pose)
    colour, _ = renderer.render(scene, flags=pyrender.RenderFlags.SEG, seg_node_map=seg)
    theirs = np.zeros(colour.shape[:2], np.uint32)            # rows from the top
    for i, c in enumerate(colours):
        theirs[(colour == c).all(axis=2)] = i + 1

    counter = PixelCounter(model, width=200, height=150)
    ours = counter.id_image(camera, R, p)[::-1]
    counts = counter.counts(camera, R, p)
    alone = counter.counts(camera, R, p + [[0.0, 30.0, 0.0], [0.0, 0.0, 0.0]])
    assert counts[0] > 1000 and 500 < counts[1] < alone[1] - 300     # the capsule occludes
    assert np.array_equal(queries, counts)
    assert np.abs(np.bincount(theirs.ravel(), minlength=3)[1:] - counts).max() <= 3
    assert (ours != theirs).sum() <= 6


def test_bodies_without_triangles_and_shared_geoms():
    """Bodies without geoms count 0; bodies sharing one Geom get one mesh each."""
    capsule = Geom("capsule", (0.1, 0.3))
    model = free_bodies([[capsule], [], [capsule]])
    R = np.stack([np.eye(3)] * 3)
    p = np.array([[0.0, -0.5, 1.0], [0.0, 0.0, 1.0], [0.0, 0.5, 1.0]])
    for method in ("merged", "queries"):
        counts = PixelCounter(model, method=method).counts(CAMERA, R, p)
        assert counts[1] == 0 and counts[0] == counts[2] > 100


@pytest.mark.parametrize("kwargs, match", [
    (dict(method="atomic"), r"counting method \(counting= of view-oq\) must be one of"),
    (dict(width=0), "width must be a positive whole number"),
    (dict(height=-240), "height must be a positive whole number"),
    (dict(width=320.5), "width must be a positive whole number"),
    (dict(environment="wall"), "environment must be"),
])
def test_bad_construction_raises_input_error(kwargs, match):
    with pytest.raises(InputError, match=match):
        PixelCounter(free_bodies([[Geom("sphere", (0.3,))]]), **kwargs)


def test_model_must_be_a_model():
    with pytest.raises(InputError, match="model must be a vdad.Model"):
        PixelCounter([Body("b", 1.0)])


@pytest.mark.parametrize("method", ["merged", "queries"])
def test_bad_poses_raise_input_error(method):
    counter = PixelCounter(free_bodies([[Geom("sphere", (0.3,))]] * 2), method=method)
    R, p = np.stack([np.eye(3)] * 2), np.zeros((2, 3))
    with pytest.raises(InputError, match=r"R must have shape \(2, 3, 3\)"):
        counter.counts(CAMERA, R[:1], p)
    with pytest.raises(InputError, match=r"p must have shape \(2, 3\)"):
        counter.counts(CAMERA, R, p.T)
    with pytest.raises(InputError, match="R and p must be finite"):
        counter.counts(CAMERA, R, np.where(np.eye(2, 3) > 0, np.nan, p))
    with pytest.raises(InputError, match="R and p must be finite"):
        counter.id_image(CAMERA, R + np.inf, p)
    with pytest.raises(InputError, match="camera must be a vdad.camera.Camera"):
        counter.counts(CAMERA.pose, R, p)


def test_closed_counter_refuses_and_others_keep_working():
    model = free_bodies([[Geom("sphere", (0.3,))]])
    with PixelCounter(model) as counter:
        before = counter.counts(CAMERA, np.eye(3)[None], np.zeros((1, 3)))
    with pytest.raises(RenderError, match="closed"):
        counter.counts(CAMERA, np.eye(3)[None], np.zeros((1, 3)))
    counter.close()
    assert np.array_equal(PixelCounter(model).counts(CAMERA, np.eye(3)[None], np.zeros((1, 3))),
                          before)


def test_a_counter_collected_on_another_thread_is_released_quietly(monkeypatch):
    """The last reference to a counter dropped on another thread runs its finalizer
    there, where the context (current on this thread) cannot be made current: no
    exception escapes the finalizer, and counting goes on here."""
    model = free_bodies([[Geom("sphere", (0.3,))]])
    R, p = np.eye(3)[None], np.zeros((1, 3))
    expected = PixelCounter(model).counts(CAMERA, R, p)
    unraisable = []
    monkeypatch.setattr(sys, "unraisablehook", unraisable.append)
    holder = [PixelCounter(model)]
    holder[0].counts(CAMERA, R, p)
    worker = threading.Thread(target=holder.clear)        # the last reference goes there
    worker.start()
    worker.join()
    assert not holder and unraisable == []
    assert np.array_equal(PixelCounter(model).counts(CAMERA, R, p), expected)


def test_egl_failure_raises_render_error_with_the_install_hint(monkeypatch):
    import pyrender

    model = free_bodies([[Geom("sphere", (0.3,))]])
    with monkeypatch.context() as patch:
        def fail(*args, **kwargs):
            raise RuntimeError("eglInitialize failed: EGL_NOT_INITIALIZED")
        patch.setattr(context, "_renderer", None)
        patch.setattr(pyrender, "OffscreenRenderer", fail)
        with pytest.raises(RenderError) as error:
            PixelCounter(model)
    message = str(error.value)
    for hint in ("eglInitialize failed", "libegl1 libegl-mesa0 libgl1-mesa-dri libopengl0",
                 "pip install 'vdad[render]'", "PyOpenGL>=3.1.9", "PYOPENGL_PLATFORM=egl"):
        assert hint in message
    # The process-wide context survived the simulated failure.
    assert PixelCounter(model).counts(CAMERA, np.eye(3)[None], np.zeros((1, 3)))[0] > 100


def run_python(code, **env):
    return subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          env={**os.environ, **env}, timeout=60)


def test_wrong_platform_raises_render_error_and_import_loads_no_gl():
    code = ("import sys\n"
            "import vdad.render.counting as c\n"
            "print([m for m in ('OpenGL', 'pyrender') if m in sys.modules])\n"
            "from vdad.scenes.pendulum import pendulum\n"
            "try:\n"
            "    c.PixelCounter(pendulum(2).model)\n"
            "except c.RenderError as e:\n"
            "    print('RenderError:', e)\n")
    out = run_python(code, PYOPENGL_PLATFORM="osmesa")
    assert out.returncode == 0, out.stderr
    lines = out.stdout.splitlines()
    assert lines[0] == "[]"
    assert lines[1].startswith("RenderError: vdad renders on EGL but PYOPENGL_PLATFORM='osmesa'")
    assert "libegl1" in lines[1]


def test_context_logs_its_renderer_once():
    code = ("import logging\n"
            "logging.basicConfig(level=logging.INFO, format='%(name)s %(message)s')\n"
            "from vdad.render import context\n"
            "assert context.gl_context() is context.gl_context(64, 48)\n"
            "print('name', context.renderer_name())\n")
    out = run_python(code)
    assert out.returncode == 0, out.stderr
    logged = [line for line in out.stderr.splitlines() if line.startswith("vdad.render")]
    assert len(logged) == 1 and "GL_RENDERER" in logged[0]
    name = out.stdout.split("name ", 1)[1].strip()
    assert name and name in logged[0]
    assert context.renderer_name() == context.renderer_name() != ""
