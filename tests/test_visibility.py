"""Coverage N_M (vdad.visibility) and the view-dependent methods: cached group-frame
volumes equal a full evaluation, node values are sums over bodies, and the methods
rigidify what the viewer cannot see and approach the full DCA in full view."""

from dataclasses import replace

import numpy as np
import pytest
from strategies import moved_pixels, node_bodies, random_configuration, random_tree

from vdad import Body, Geom, Model, Simulator, dca
from vdad.adaptive import AdaptiveDynamics
from vdad.assembly import AssemblyTree
from vdad.bounding import VOLUMES, areas, body_volumes, place
from vdad.camera import Camera
from vdad.errors import InputError, SimulationError
from vdad.scenes import pendulum
from vdad.visibility import (
    ESTIMATES,
    PIXELS,
    BoundingVolumes,
    camera_arrays,
    coverage_pass,
    id_counts_pass,
)


@pytest.mark.parametrize("volume", ["sphere", "obb"])
def test_cached_node_volumes_equal_full_evaluation(volume):
    """With adaptive dynamics, rigid front nodes keep their volume in the group frame;
    their N1 equals the one merged from all bodies' placed volumes at the same q."""
    scene = pendulum(n_bodies=48, axes="alternate", angle=1.2)
    sim = scene.simulator(method="view-bvh", volume=volume, estimate="node",
                          threshold=2e-3, dwell=3, coverage_every=1)   # N_M of every step
    full = BoundingVolumes(sim.tree, scene.camera, volume, estimate="node")
    internal_fronts = 0
    sim.step()                                       # builds the active region
    for step in range(120):
        ad = sim.adaptive
        q, nodes = sim.q.copy(), np.concatenate([ad.front, ad.act])
        internal_fronts += np.sum(ad.front >= scene.model.nb)
        sim.step()
        if step % 10 == 9:
            np.testing.assert_allclose(ad.N_M[nodes], full(sim.t - sim.dt, q)[nodes],
                                       rtol=1e-9, atol=1e-9)
    assert internal_fronts > 0                       # rigid groups were really placed


@pytest.mark.parametrize("volume", ["sphere", "obb", "aabb"])
def test_node_coverage_sums_bodies(volume):
    scene = pendulum(n_bodies=30, axes="alternate")
    sim = scene.simulator()
    sim.step(200)
    cov = BoundingVolumes(sim.tree, scene.camera, volume, estimate="bodies")
    N = cov(0.0, sim.q)
    per_body = areas(place(body_volumes(scene.model, volume), *sim.body_poses()), scene.camera)
    assert np.all(per_body > 0)
    sums = [per_body[node_bodies(sim.tree, n)].sum() for n in range(sim.tree.n_nodes)]
    np.testing.assert_allclose(N, sums + [0.0])
    # every node holds a contiguous set of bodies: the root holds them all
    assert N[sim.tree.n_nodes - 1] == pytest.approx(per_body.sum())
    N_min = BoundingVolumes(sim.tree, scene.camera, volume, estimate="min")(0.0, sim.q)
    N_node = BoundingVolumes(sim.tree, scene.camera, volume, estimate="node")(0.0, sim.q)
    np.testing.assert_array_equal(N_min, np.fmin(N_node, N))
    np.testing.assert_allclose(N_node[:scene.model.nb], per_body)      # leaves: the bodies


@pytest.mark.parametrize("seed", [3, 6])          # each has a joint whose rest is smaller
def test_moved_pixels_weight_a_node_by_the_bodies_its_joints_displace(seed):
    """pixels="moved" equals the brute-force rule from body sets: a joint moves its
    successor's subtree, or the smaller side inside a floating tree."""
    model = random_tree(seed, n=14, roots=2, springs=False)     # a floating and a fixed tree
    model = _with_spheres(model)
    tree = AssemblyTree.balanced(model)
    q = random_configuration(model, np.random.default_rng(seed))
    camera = Camera(position=(0.0, -12.0, 2.0), target=(0.0, 0.0, 0.0), yfov=1.2)
    per_body = BoundingVolumes(tree, camera, estimate="bodies")(0.0, q)[:model.nb]
    assert np.all(per_body > 0)
    N = BoundingVolumes(tree, camera, pixels="moved")(0.0, q)
    np.testing.assert_allclose(N, moved_pixels(tree, per_body), rtol=1e-12)
    # the floating tree's smaller sides matter: successor subtrees alone differ
    assert not np.allclose(N, moved_pixels(tree, per_body, floating=False))


@pytest.mark.parametrize("volume", ["sphere", "obb", "aabb"])
def test_a_large_forest_is_covered_on_threads_as_serially(volume):
    """A forest of at least dca.PARALLEL_BODIES bodies is covered in runs of its
    roots' subtrees on numba's threads (``forest_coverage``): under eq. 6 the
    sums of the bodies' areas, and under every estimate, to the last bit, what
    the serial pass of all subtrees gives."""
    model = _with_spheres(random_tree(11, n=dca.PARALLEL_BODIES + 40, roots=24, springs=False))
    tree = AssemblyTree.balanced(model)
    assert len(tree.segments) - 1 == 24 and model.nb >= dca.PARALLEL_BODIES
    q = random_configuration(model, np.random.default_rng(11))
    camera = Camera(position=(0.0, -30.0, 5.0), target=(0.0, 0.0, 0.0), yfov=1.2)
    R, p = Simulator(model, q).body_poses()
    per_body = areas(place(body_volumes(model, volume), R, p), camera)
    assert np.all(per_body > 0)
    for estimate in ESTIMATES:
        cov = BoundingVolumes(tree, camera, volume, estimate)
        N = cov(0.0, q)
        if estimate == "bodies":
            np.testing.assert_allclose(
                N, [per_body[node_bodies(tree, n)].sum() for n in range(tree.n_nodes)] + [0.0],
                rtol=1e-12)
        serial = np.full(tree.n_nodes + 1, np.nan)
        serial[-1] = 0.0
        world = tuple(np.zeros_like(a) for a in cov.world)
        world[2][-1, 0] = -1.0
        N1 = np.zeros(tree.n_nodes + 1)
        view, Rc, pc = camera_arrays(camera)
        coverage_pass(0, len(tree.segments) - 1, cov._kind, ESTIMATES.index(estimate), view,
                       Rc, pc, model.nb, tree.arrays[0], tree.arrays[1],
                       (tree.arrays[13], tree.arrays[14]), cov.body, cov._kin.R, cov._kin.p,
                       world, N1, serial, cov._ungrouped, cov._scratch)
        np.testing.assert_array_equal(N, serial)


def _with_spheres(model):
    bodies = [replace(b, geoms=(Geom("sphere", (0.05 + 0.02 * i,)),))
              for i, b in enumerate(model.bodies)]
    return Model(bodies, model.joints, name=model.name)


@pytest.mark.parametrize("seed, n", [(0, 16), (1, 16), (2, 16), (4, 16), (5, 16),
                                     (0, dca.PARALLEL_BODIES + 40)])    # the last on threads
def test_a_hybrid_places_its_bodies_from_their_groups(seed, n):
    """With an adaptive region, the coverage that places every body takes the
    active joints' poses and the rigid groups' frames (``region_bvh_pass``, as the
    compiled steps evaluate it once per frame): the same ``N_M`` as the evaluation
    at ``q``, for every volume and every rule that covers every node, with rigid
    groups in a floating tree and a grounded one (a fixed tree rigid to the root)."""
    model = _with_spheres(random_tree(seed, n=n, roots=2, composite=True, springs=False))
    tree = AssemblyTree.balanced(model)
    q = random_configuration(model, np.random.default_rng(seed))
    ad = AdaptiveDynamics(model, 1e-3, tree, threshold=0.0)
    nb = model.nb
    for node in [n for n in range(nb, tree.n_nodes) if tree.up[n] < 0] + [None]:
        if node is None:                # then the largest subtree left in the floating tree
            node = max((n for n in range(nb, tree.n_nodes) if ad.active[n] and not ad.pinned[n]),
                       key=lambda n: n - tree.first[n - nb])
        if not ad.pinned[node]:
            ad.rigidify(range(tree.first[node - nb] + nb, node + 1), q, np.zeros(model.nv))
    groups = ad.front[ad.front >= nb]
    assert np.any(ad.groups.grounded[groups]) and not np.all(ad.groups.grounded[groups])
    camera = Camera(position=(0.0, -12.0, 2.0), target=(0.0, 0.0, 0.0), yfov=1.2)
    for volume, estimate, pixels in [("sphere", "min", "own"), ("obb", "bodies", "own"),
                                     ("obb", "min", "own"), ("aabb", "node", "own"),
                                     ("sphere", "min", "moved")]:
        cov = BoundingVolumes(tree, camera, volume, estimate, pixels=pixels)
        assert cov.covers_every_node
        N = cov(0.0, q)
        assert np.all(N[:-1] > 0)
        np.testing.assert_allclose(cov(0.0, q, ad), N, rtol=1e-12)


def test_moved_pixels_in_an_adaptive_region_equal_a_full_evaluation():
    """view-bvh with pixels="moved": the N_M the adaptive region uses is the full
    evaluation's at the same configuration, and the top node takes every body."""
    scene = pendulum(n_bodies=24, axes="alternate", angle=1.0)
    sim = scene.simulator(method="view-bvh", pixels="moved", threshold=1e-3, coverage_every=1)
    assert sim.options["pixels"] == "moved" and sim.adaptive.coverage.pixels == "moved"
    full = BoundingVolumes(sim.tree, scene.camera, pixels="moved")
    rigid = 0
    for step in range(100):
        t, q = sim.t, sim.q.copy()
        sim.step()
        rigid += len(sim.adaptive.front) > 2
        if step % 10 == 9:
            N = full(t, q)
            np.testing.assert_allclose(sim.adaptive.N_M, N, rtol=1e-9)
            assert N[sim.tree.n_nodes - 1] == pytest.approx(N[:scene.model.nb].sum())
    assert rigid > 0                                 # the region was really pruned


def test_oriented_boxes_of_rigid_groups_follow_the_region():
    """view-bvh with oriented boxes places the rigid groups' internal volumes from
    their frames, kept in the estimator between frames (``region_bvh_pass``): as
    groups form, grow and are released in the compiled steps, and when the
    estimator moves to another simulator, ``N_M`` stays the full evaluation's at
    the same configuration."""
    scene = pendulum(n_bodies=24, axes="alternate", angle=1.0)
    full = BoundingVolumes(scene.simulator().tree, scene.camera, "obb")
    shared = None
    for run in range(2):
        sim = scene.simulator(method="view-bvh", volume="obb", threshold=2e-4 * (run + 1),
                              coverage_every=1)
        if shared is None:
            shared = sim.adaptive.coverage
        sim.adaptive.coverage = shared                   # the same estimator's cache
        compared = 0
        for step in range(160):
            t, q = sim.t, sim.q.copy()
            sim.step()
            if step % 8 == 7 and len(sim.adaptive.front) > 2:
                np.testing.assert_allclose(sim.adaptive.N_M, full(t, q), rtol=1e-9)
                compared += 1
        assert compared > 5
        assert sum(s.rigidified for s in sim.history) > 0
        assert sum(s.released for s in sim.history) > 0


def _run(scene, camera, threshold, steps=300, **options):
    sim = scene.simulator(method="view-bvh", camera=camera, threshold=threshold, **options)
    sim.step(steps)
    return sim, np.array([s.active_joints for s in sim.history])


def test_far_or_looking_away_rigidifies_everything():
    scene = pendulum(n_bodies=20)
    cam = scene.camera
    target = np.array(cam.target)
    away = Camera(position=cam.position, target=tuple(2 * np.array(cam.position) - target),
                  up=cam.up)
    far = Camera(position=tuple(target + 2000 * (np.array(cam.position) - target)),
                 target=cam.target, up=cam.up)
    for camera in (away, far):
        sim, active = _run(scene, camera, threshold=1e-3)
        assert active[-100:].max() <= 1, active[-100:]
    sim, near = _run(scene, cam, threshold=1e-3)
    assert near[-100:].mean() >= 5


def test_close_up_approaches_full_dca():
    """In full view, as the threshold falls, the active set grows to all joints and
    the trajectory to the DCA's."""
    scene = pendulum(n_bodies=20, axes="alternate")
    dca = scene.simulator()
    dca.step(300)
    tip_dca = dca.body_poses([19])[1][0]
    errors, actives = [], []
    for threshold in (1e-2, 1e-4, 1e-7, 0.0):
        sim, active = _run(scene, scene.camera, threshold)
        actives.append(active.mean())
        errors.append(np.linalg.norm(sim.body_poses([19])[1][0] - tip_dca))
    assert actives == sorted(actives) and actives[-1] == 20
    assert errors[-1] < 1e-12 and errors[-2] < 1e-6 and errors[0] > 1e-3
    assert errors == sorted(errors, reverse=True)


def test_distance_orders_active_joints():
    """The same threshold: the farther the viewer, the fewer active joints."""
    scene = pendulum(n_bodies=20, axes="alternate")
    cam, target = scene.camera, np.array(scene.camera.target)
    means = []
    for scale in (1.0, 4.0, 16.0):
        pos = target + scale * (np.array(cam.position) - target)
        means.append(_run(scene, Camera(position=tuple(pos), target=cam.target),
                          threshold=1e-4)[1].mean())
    assert means[0] > means[1] > means[2], means


def test_view_method_errors():
    scene = pendulum(n_bodies=5)
    with pytest.raises(InputError, match="needs a camera"):
        Simulator(scene.model, method="view-bvh", threshold=1e-3)
    with pytest.raises(InputError, match=r"volume= applies to method='view-bvh', not to "
                                         r"method='adaptive'"):
        scene.simulator(method="adaptive", threshold=1e-3, volume="obb")
    with pytest.raises(InputError, match="unknown bounding volume"):
        scene.simulator(method="view-bvh", threshold=1e-3, volume="cone")
    with pytest.raises(InputError, match="unknown coverage estimate"):
        scene.simulator(method="view-bvh", threshold=1e-3, estimate="max")
    with pytest.raises(InputError, match="unknown pixels rule 'mine'; choose one of"):
        scene.simulator(method="view-bvh", threshold=1e-3, pixels="mine")
    with pytest.raises(InputError, match="estimate='node' .* does not apply to pixels='moved'"):
        scene.simulator(method="view-bvh", threshold=1e-3, pixels="moved", estimate="node")
    with pytest.raises(InputError, match=r"pixels= applies to method='view-bvh' or "
                                         r"method='view-oq', not to method='adaptive'"):
        scene.simulator(method="adaptive", threshold=1e-3, pixels="moved")
    with pytest.raises(InputError, match="resolution"):
        scene.simulator(method="view-bvh", threshold=1e-3, resolution=(320, 0))
    with pytest.raises(InputError, match="coverage_every"):
        scene.simulator(method="view-bvh", threshold=1e-3, coverage_every=0)
    with pytest.raises(SimulationError, match="must return a vdad.camera.Camera"):
        scene.simulator(method="view-bvh", threshold=1e-3, camera=lambda t: None).step()
    sim = Simulator(scene.model, method="adaptive", threshold=1e-3,
                    coverage=lambda t, q, ad: np.ones(3))
    with pytest.raises(SimulationError, match="coverage must return"):
        sim.step()


@pytest.mark.parametrize("method", ["view-bvh", "view-oq"])
def test_view_methods_need_geometry(method):
    """A model without geometry covers no pixels: every joint would freeze."""
    bodies = [Body(b.name, b.mass, b.com, b.inertia) for b in pendulum(3).model.bodies]
    bare = Model(bodies, pendulum(3).model.joints, name="bare")
    with pytest.raises(InputError, match="view-dependent coverage needs geometry, but no body "
                                         "of model 'bare' has any"):
        Simulator(bare, method=method, threshold=1e-3, camera=pendulum(3).camera)


def test_camera_checks_and_paths():
    with pytest.raises(InputError, match="target must differ"):
        Camera(position=(1, 0, 0), target=(1, 0, 0))
    with pytest.raises(InputError, match="parallel"):
        Camera(position=(0, 0, 3), target=(0, 0, 0), up=(0, 0, 1))
    with pytest.raises(InputError, match="znear"):
        Camera(znear=0.0)
    cam = Camera(position=(3.0, 0.0, 1.0), target=(0.0, 0.0, 1.0))
    # view and pose are inverse; the target projects to the viewport centre
    np.testing.assert_allclose(cam.view @ cam.pose, np.eye(4), atol=1e-15)
    xy, d = cam.project(np.array([[0.0, 0.0, 1.0]]))
    np.testing.assert_allclose(xy[0], [160, 120])
    assert d[0] == pytest.approx(3.0)
    # a point at the top edge of the field of view lands on the top row
    top = np.array([[0.0, 0.0, 1.0 + 3.0 * np.tan(cam.yfov / 2)]])
    np.testing.assert_allclose(cam.project(top)[0][0], [160, 240])
    from vdad.camera import Dolly, Keyframes, Orbit

    far = Dolly(cam, speed=2.0)(1.5)
    assert np.linalg.norm(np.array(far.position) - far.target) == pytest.approx(6.0)
    half = Orbit(cam, period=4.0)(2.0)
    np.testing.assert_allclose(half.position, (-3.0, 0.0, 1.0), atol=1e-12)
    k = Keyframes((0.0, 1.0), (cam, far))
    np.testing.assert_allclose(k(0.5).position, (4.5, 0.0, 1.0))
    np.testing.assert_allclose(k(9.0).position, far.position)
    with pytest.raises(InputError, match="increasing"):
        Keyframes((1.0, 0.0), (cam, far))


@pytest.mark.parametrize("pixels", PIXELS)
@pytest.mark.parametrize("volume", VOLUMES)
def test_in_loop_coverage_has_the_types_of_the_idle_coverage(volume, pixels):
    """`vdad compile` compiles the compiled adaptive steps (region.region_steps)
    with the idle coverage of a view-independent run; the bounding volumes'
    coverage of a view-bvh run must have the same numba types (read-only flags
    included), or its first run after `vdad compile` compiles the loop again.
    The rasteriser's coverage (view-oq) has its own, which `vdad compile`
    compiles from another model's."""
    import numba

    sim = pendulum(4).simulator(method="view-bvh", threshold=1e-3, volume=volume,
                                pixels=pixels)
    ad = sim.adaptive
    raster = [pendulum(n).simulator(method="view-oq", counting="raster", threshold=1e-3,
                                    pixels=pixels).adaptive for n in (4, 8)]
    for steps, times in (([], []), ([0, 5], [0.0, 0.005])):
        live = ad.coverage.loop_coverage(steps, times, ad)
        assert numba.typeof(live) == numba.typeof(ad._idle_coverage)
        # the rasteriser's loop has a type of its own, the same for every model
        first, second = (r.coverage.loop_coverage(steps, times, r) for r in raster)
        assert numba.typeof(first) == numba.typeof(second) != numba.typeof(live)


@pytest.mark.parametrize("nb", [1, 20, 300])
def test_id_counts_equal_a_count_of_every_id(nb):
    """Kim 2008 §5.4: the pixels of each body in a merged id image equal
    ``np.bincount`` of the image's ids (the background and ids above ``nb``,
    which no body draws, not counted), in images of blocks of one id, as bodies
    draw them, and of single pixels."""
    rng = np.random.default_rng(nb)
    image = np.zeros((240, 320), np.uint32)
    for _ in range(3 * nb):
        r, c = rng.integers(0, 240), rng.integers(0, 320)
        image[r:r + rng.integers(1, 30), c:c + rng.integers(1, 30)] = rng.integers(0, nb + 3)
    image.ravel()[rng.integers(0, image.size, 500)] = rng.integers(0, nb + 3, 500)
    counts = np.full(nb, -1, np.int64)
    id_counts_pass(image, counts)
    expected = np.bincount(image.ravel(), minlength=nb + 3)[1:nb + 1]
    assert expected.sum() > 0
    np.testing.assert_array_equal(counts, expected)
