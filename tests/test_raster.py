"""Visible pixels rasterised on the CPU (vdad.raster, Kim 2008 §5.4), against
OpenGL's merged id buffer (vdad.render.counting on EGL) and exact areas."""

import numpy as np
import pytest
import trimesh
from test_counting import CAMERA, SCENE_P, SCENE_R, SCENE_WALL, free_bodies

from vdad import Geom, InputError
from vdad.camera import Camera
from vdad.kinematics import world_poses
from vdad.raster import RasterCounter, merged_geometry
from vdad.render.counting import PixelCounter
from vdad.scenes import hanging_dogs, pendulum
from vdad.visibility import RenderedCounts


@pytest.fixture(scope="module")
def counters():
    from test_counting import SCENE_GEOMS

    model = free_bodies(SCENE_GEOMS)
    return model, RasterCounter(model, SCENE_WALL), PixelCounter(model, SCENE_WALL,
                                                                 method="merged")


def test_counts_equal_opengl_with_occlusion_clipping_and_the_near_plane(counters):
    """The scene of test_counting: bodies that occlude each other, cut by the
    viewport and the near plane, behind a wall, behind the camera, off screen,
    without geometry. The id images agree but for the pixels where the 24-bit
    depth buffer and double precision order two fragments differently."""
    model, raster, gl = counters
    ours, theirs = raster.counts(CAMERA, SCENE_R, SCENE_P), gl.counts(CAMERA, SCENE_R, SCENE_P)
    assert ours.dtype == np.int64 and ours.shape == (model.nb,)
    assert (ours[[0, 1, 2, 3, 4, 5, 9]] > 100).all() and (ours[[6, 7, 8]] == 0).all()
    assert (np.abs(ours - theirs) <= 2 + 0.002 * theirs).all()
    image = raster.id_image(CAMERA, SCENE_R, SCENE_P)
    assert image.shape == (CAMERA.height, CAMERA.width) and image.dtype == np.uint32
    assert (image != gl.id_image(CAMERA, SCENE_R, SCENE_P)).sum() <= 10
    assert np.array_equal(np.bincount(image.ravel(), minlength=model.nb + 1)[1:], ours)


def test_pendulum_and_dogs_id_images_equal_opengl():
    """Random poses of the Table 1 pendulum (2 px wide links: every pixel is an
    edge case of the fill rule) and of four hanging dogs."""
    rng = np.random.default_rng(1)
    for scene in (pendulum(), hanging_dogs(n_dogs=4, columns=2)):
        model = scene.model
        raster = RasterCounter(model, scene.environment)
        gl = PixelCounter(model, scene.environment, method="merged")
        for _ in range(4):
            q = np.array(scene.q0, float)
            q[:model.nq] += 0.3 * rng.standard_normal(model.nq)
            R, p = world_poses(model, q)
            ours = raster.id_image(scene.camera, R, p)
            assert (ours > 0).sum() > 100
            assert (ours != gl.id_image(scene.camera, R, p)).sum() <= 2


def test_a_frame_forgets_the_last():
    """Pixels are not cleared between frames, yet each frame counts only its own:
    a moved body leaves nothing behind."""
    model = free_bodies([[Geom("sphere", (0.3,))]] * 2)
    R = np.stack([np.eye(3)] * 2)
    p = np.array([[0.0, -0.5, 1.0], [0.0, 0.5, 1.0]])
    moved = p + [0.0, 0.0, 0.4]
    counter = RasterCounter(model)
    counter.counts(CAMERA, R, p)
    again = counter.counts(CAMERA, R, moved)
    assert np.array_equal(again, RasterCounter(model).counts(CAMERA, R, moved))
    assert np.array_equal(counter.id_image(CAMERA, R, moved),
                          RasterCounter(model).id_image(CAMERA, R, moved))


def test_sphere_count_is_its_projected_ellipse_area():
    r = 0.5
    model = free_bodies([[Geom("mesh", mesh=trimesh.creation.icosphere(subdivisions=5,
                                                                        radius=r))]])
    centre = np.array([2.0, 0.7, 1.4])
    count = RasterCounter(model).counts(CAMERA, np.eye(3)[None], centre[None])[0]
    c = CAMERA.to_camera(centre)
    l, d = np.linalg.norm(c), -c[2]
    area = np.pi * CAMERA.focal**2 * r**2 * np.sqrt(l**2 - r**2) / (d**2 - r**2) ** 1.5
    assert abs(count - area) < 0.01 * area


def test_back_faces_count_where_they_can_show():
    """Back faces are culled only for closed meshes seen from outside: a camera
    inside a sphere sees all of it, an open sheet counts from both sides, and a
    mesh wound inwards is drawn whole."""
    model = free_bodies([[Geom("sphere", (1.0,))], [Geom("sphere", (0.3,))]])
    R, p = np.stack([np.eye(3)] * 2), np.array([[4.0, 0.0, 1.0], [0.0, 0.0, 1.0]])
    assert np.array_equal(RasterCounter(model, SCENE_WALL).counts(CAMERA, R, p),
                          [CAMERA.width * CAMERA.height, 0])
    sheet = trimesh.Trimesh([[0, -0.5, -0.5], [0, 0.5, -0.5], [0, 0, 0.5]], [[0, 1, 2]])
    inward = trimesh.creation.box(extents=(0.4, 0.4, 0.4))
    inward.invert()
    model = free_bodies([[Geom("mesh", mesh=sheet)], [Geom("mesh", mesh=inward)]])
    positions, labels, _, _, _, closed = merged_geometry(model, SCENE_WALL, 8)
    assert closed.tolist() == [True, False, False]
    R, p = np.stack([np.eye(3)] * 2), np.array([[0.0, -0.6, 1.0], [0.0, 0.6, 1.0]])
    flipped = np.stack([np.diag([-1.0, -1.0, 1.0])] * 2)     # the sheet seen from its back
    for rotation in (R, flipped):
        ours = RasterCounter(model).counts(CAMERA, rotation, p)
        assert (ours > 100).all()
        assert np.array_equal(ours, PixelCounter(model, method="merged").counts(
            CAMERA, rotation, p))


def test_rendered_counts_take_the_rasteriser():
    scene = pendulum()
    tree = scene.simulator(method="view-oq").tree
    q = np.array(scene.q0, float)
    ours = RenderedCounts(tree, scene.camera, method="raster")
    assert np.array_equal(ours(0.0, q), RenderedCounts(tree, scene.camera, method="merged")(0.0, q))
    assert ours(0.0, q)[tree.n_nodes - 1] > 100
    with pytest.raises(InputError, match=r"counting= of view-oq\) must be one of \('queries', "
                                         r"'merged', 'raster'\), got 'atomic'"):
        RenderedCounts(tree, scene.camera, method="atomic")


@pytest.mark.parametrize("kwargs, match", [
    (dict(width=0), "width must be a positive whole number"),
    (dict(height=2.5), "height must be a positive whole number"),
    (dict(sections=2), "sections must be a whole number >= 3"),
    (dict(environment="wall"), "environment must be"),
])
def test_bad_construction_raises_input_error(kwargs, match):
    with pytest.raises(InputError, match=match):
        RasterCounter(free_bodies([[Geom("sphere", (0.3,))]]), **kwargs)


def test_bad_poses_raise_input_error():
    counter = RasterCounter(free_bodies([[Geom("sphere", (0.3,))]] * 2))
    R, p = np.stack([np.eye(3)] * 2), np.zeros((2, 3))
    with pytest.raises(InputError, match=r"R must have shape \(2, 3, 3\)"):
        counter.counts(CAMERA, R[:1], p)
    with pytest.raises(InputError, match="R and p must be finite"):
        counter.id_image(CAMERA, R, p + np.nan)
    with pytest.raises(InputError, match="camera must be a vdad.camera.Camera"):
        counter.counts(Camera.pose, R, p)
