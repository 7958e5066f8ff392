"""Rendered coverage on EGL (vdad.visibility.RenderedCounts, view-oq) against the exact
projected areas, the bounding volumes and the tree sums; these tests really render."""

import numpy as np
import pytest
import trimesh
from strategies import moved_pixels, node_bodies
from test_projection import BOXES, SPHERES

import vdad
from vdad import Geom
from vdad.bounding import areas, body_volumes, place
from vdad.camera import Camera
from vdad.environment import wall
from vdad.errors import RenderError
from vdad.projection import box_areas, sphere_areas
from vdad.render import context
from vdad.render.counting import PixelCounter
from vdad.scenes import pendulum
from vdad.spatial import quat_to_rot
from vdad.visibility import RenderedCounts

# camera frame = world frame: the cases of test_projection are world positions
EYE = Camera(position=(0.0, 0.0, 0.0), target=(0.0, 0.0, -1.0), up=(0.0, 1.0, 0.0))
FAR_BEHIND = np.array([0.0, 0.0, 1e3])


def _free_bodies(geoms):
    bodies = [vdad.Body(f"b{i}", 1.0, geoms=(g,)) for i, g in enumerate(geoms)]
    joints = [vdad.Joint(f"j{i}", None, f"b{i}", "free") for i in range(len(geoms))]
    return vdad.Model(bodies, joints)


def _one_at_a_time(counter, n, R, p):
    """Counts of each body alone in view (the others far behind the camera)."""
    out = []
    for i in range(n):
        q = np.broadcast_to(FAR_BEHIND, (n, 3)).copy()
        q[i] = p[i]
        out.append(counter.counts(EYE, R, q)[i])
    return np.array(out)


@pytest.mark.parametrize("method", ["merged", "queries"])
def test_sphere_and_box_areas_equal_rendered_counts(method):
    """Fine meshes rendered on EGL cover the exact projected areas to 1 % (the
    cases of theory §7: centred, off-axis, one and two viewport edges, the near
    plane, camera inside; behind the camera 0)."""
    sphere = trimesh.creation.icosphere(subdivisions=6)
    geoms = [Geom("mesh", mesh=sphere.copy().apply_scale(r)) for _, _, r in SPHERES]
    geoms += [Geom("box", tuple(h)) for _, _, h in BOXES]
    model = _free_bodies(geoms)
    R = np.stack([np.eye(3)] * len(SPHERES)
                 + [quat_to_rot(np.array([0.9, 0.2, -0.3, 0.1]) / np.linalg.norm(
                     [0.9, 0.2, -0.3, 0.1])) if name != "camera inside" else np.eye(3)
                    for name, _, _ in BOXES])
    p = np.array([c for _, c, _ in SPHERES] + [c for _, c, _ in BOXES])
    counts = _one_at_a_time(PixelCounter(model, method=method), model.nb, R, p)
    k = len(SPHERES)
    exact = np.concatenate([
        sphere_areas(EYE, p[:k], np.array([r for _, _, r in SPHERES])),
        box_areas(EYE, p[k:], R[k:], np.array([h for _, _, h in BOXES]))])
    assert np.all(counts > 1000)
    np.testing.assert_allclose(counts, exact, rtol=0.01)
    behind = PixelCounter(model, method=method).counts(EYE, R, p * [1, 1, -1])
    np.testing.assert_array_equal(behind[:3], 0)           # centred cases, mirrored behind


@pytest.mark.parametrize("volume", ["sphere", "obb", "aabb"])
def test_bounding_volume_area_bounds_rendered_count(volume):
    """Unoccluded, unclipped bodies: the volume's area >= the rendered pixels."""
    scene = pendulum(n_bodies=12, axes="alternate", link_length=0.3, radius=0.06)
    sim = scene.simulator()
    sim.step(400)
    R, p = sim.body_poses()
    camera = Camera(position=(0.2, -3.5, -1.8), target=(0.0, 0.0, -1.8))
    counter = PixelCounter(scene.model, width=640, height=480)
    alone = []
    for i in range(scene.model.nb):                     # each body alone: no occlusion
        q = np.broadcast_to(camera.pose[:3, 3] + 10 * camera.pose[:3, 2], p.shape).copy()
        q[i] = p[i]
        alone.append(counter.counts(camera, R, q)[i])
    alone = np.array(alone)
    cam = camera.with_resolution(640, 480)
    bv = areas(place(body_volumes(scene.model, volume), R, p), cam)
    xy, _ = cam.project(p)
    inside = np.all((xy > 20) & (xy < [620, 460]), axis=1)
    assert inside.sum() >= 8 and np.all(alone[inside] > 150)
    assert np.all(bv[inside] >= alone[inside]), (bv[inside], alone[inside])
    ratio = np.median(bv[inside] / alone[inside])
    assert 1.0 < ratio < {"sphere": 6.0, "obb": 2.0, "aabb": 6.0}[volume]


def test_node_count_is_sum_of_its_bodies_and_wall_hides():
    scene = pendulum(n_bodies=16, axes="alternate")
    sim = scene.simulator()
    sim.step(300)
    R, p = sim.body_poses()
    camera = scene.camera
    counts = PixelCounter(scene.model).counts(camera, R, p)
    N = RenderedCounts(sim.tree, camera, method="merged")(0.0, sim.q)
    for node in range(sim.tree.n_nodes):
        assert N[node] == counts[node_bodies(sim.tree, node)].sum()
    moved = RenderedCounts(sim.tree, camera, method="merged", pixels="moved")(0.0, sim.q)
    np.testing.assert_array_equal(moved, moved_pixels(sim.tree, counts.astype(float)))
    assert moved[sim.tree.n_nodes - 1] == counts.sum()       # the pivot moves every body
    # a wall between the camera and the chain's lower half hides those bodies
    z_mid = -0.6
    screen = wall((-3.0, -0.5), (3.0, -0.5), height=3.0, base=z_mid - 3.0)
    hidden = RenderedCounts(sim.tree, camera, screen, method="queries")(0.0, sim.q)
    below = p[:, 2] < z_mid - 0.15
    assert below.sum() >= 4
    np.testing.assert_array_equal(hidden[:16][below], 0)
    above = p[:, 2] > z_mid + 0.3
    assert above.sum() >= 4
    np.testing.assert_array_equal(hidden[:16][above], N[:16][above])


def test_view_oq_rigidifies_what_a_wall_hides():
    """view-oq: behind a wall nothing stays active; in full view the joints are."""
    scene = pendulum(n_bodies=20, axes="alternate")
    z_mid = -0.75
    screen = wall((-3.0, -0.5), (3.0, -0.5), height=3.0, base=z_mid - 3.0)
    sim = scene.simulator(method="view-oq", environment=screen, threshold=1e-3,
                          counting="merged")
    sim.step(300)
    R, p = sim.body_poses()
    hidden = np.flatnonzero(p[:, 2] < z_mid - 0.2)
    assert len(hidden) >= 3
    ad = sim.adaptive
    active_joints = set(ad.joints.tolist())
    assert not active_joints & set(hidden[1:].tolist()) # joints between hidden bodies
    open_view = scene.simulator(method="view-oq", threshold=1e-3)
    open_view.step(300)
    assert (np.mean([s.active_joints for s in open_view.history[-50:]])
            > np.mean([s.active_joints for s in sim.history[-50:]]) + 2)


def test_view_oq_fails_at_once_without_egl(monkeypatch):
    import pyrender

    scene = pendulum(n_bodies=5)
    with monkeypatch.context() as patch:
        def fail(*args, **kwargs):
            raise RuntimeError("eglInitialize failed")
        patch.setattr(context, "_renderer", None)
        patch.setattr(pyrender, "OffscreenRenderer", fail)
        with pytest.raises(RenderError, match="libegl1 libegl-mesa0"):
            scene.simulator(method="view-oq", threshold=1e-3)
        scene.simulator(method="view-bvh", threshold=1e-3).step(5)   # no GL needed
