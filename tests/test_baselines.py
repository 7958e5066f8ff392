"""The game-engine baselines (vdad.baselines): distance level of detail and sleeping."""

import numpy as np
import pytest

from vdad import InputError, Simulator, forward_dynamics
from vdad.assembly import AssemblyTree
from vdad.baselines import articulated_bodies, root_last_tree
from vdad.camera import Camera
from vdad.scenes import hanging_dogs, pendulum

EPS = np.finfo(float).eps


def test_articulated_bodies_are_the_dogs():
    scene = hanging_dogs(n_dogs=3, columns=3)
    roots = articulated_bodies(scene.model)
    assert len(np.unique(roots)) == 3
    for r in np.unique(roots):
        assert scene.model.parent[r] < 0
        assert np.sum(roots == r) == 16


def test_root_last_tree_puts_the_world_joints_on_top_and_is_exact():
    scene = hanging_dogs(n_dogs=2, columns=2)
    model = scene.model
    tree = root_last_tree(model)
    tops = tree.joint[tree.up[model.nb:] < 0]
    assert sorted(tops) == sorted(np.flatnonzero(model.parent < 0))
    assert tree.depth <= AssemblyTree.balanced(model).depth + 1
    rng = np.random.default_rng(0)
    qd = rng.normal(size=model.nv)
    a = forward_dynamics(model, scene.q0, qd, tree=tree)
    b = forward_dynamics(model, scene.q0, qd)
    assert np.allclose(a, b, rtol=0, atol=1e6 * EPS * np.abs(b).max())


def test_lod_distance_near_is_the_full_dynamics():
    scene = pendulum(n_bodies=8)
    full = scene.simulator().step(300)
    near = scene.simulator(method="lod-distance", distance=100.0).step(300)
    assert np.allclose(near.q, full.q, atol=1e-9)


def test_lod_distance_far_swings_one_rigid_rod():
    scene = pendulum(n_bodies=8)
    sim = scene.simulator(method="lod-distance", distance=0.01, dwell=0).step(300)
    assert sim.history[-1].active_joints == 1                   # the joint to the world
    assert np.allclose(sim.q[1:], scene.q0[1:])                 # the rod keeps its shape
    assert abs(sim.q[0] - scene.q0[0]) > 0.1                    # and swings


def test_lod_distance_rigidifies_only_far_dogs():
    scene = hanging_dogs(n_dogs=2, columns=2, spacing=(4.0, 1.0))
    roots = np.flatnonzero(scene.model.parent < 0)
    near_dog = scene.q0[scene.model.q_start[roots[0]]:][:3]
    camera = Camera(position=tuple(near_dog + (0.0, -1.0, 0.0)), target=tuple(near_dog))
    sim = Simulator(scene.model, scene.q0, scene.qd0, dt=scene.dt, method="lod-distance",
                    distance=2.0, camera=camera, controller=scene.controller,
                    external=scene.external, dwell=0)
    sim.step(50)
    assert sim.history[-1].active_joints == 16 + 1              # near dog + far root


def test_sleeping_locks_a_still_body_and_a_push_wakes_it():
    scene = pendulum(n_bodies=5, angle=0.0)

    def push(t, q, qd):
        return np.r_[0.02 if 1.0 < t < 1.05 else 0.0, np.zeros(4)]

    sim = Simulator(scene.model, scene.q0, np.r_[0.01, np.zeros(4)], dt=scene.dt,
                    method="sleeping", sleep_speed=0.05, sleep_time=0.5, controller=push)
    sim.step(900)
    assert sim.adaptive.coverage.asleep.all()
    assert sim.history[-1].active_joints == 0 and not sim.qd.any()
    sim.step(300)
    assert not sim.adaptive.coverage.asleep.any()
    assert sim.history[-1].active_joints == 5 and np.abs(sim.qd).max() > 0.5


def test_a_fast_body_stays_awake():
    scene = pendulum(n_bodies=5)
    sim = scene.simulator(method="sleeping").step(500)
    assert not sim.adaptive.coverage.asleep.any()
    assert np.allclose(sim.q, scene.simulator().step(500).q, atol=1e-9)


@pytest.mark.parametrize("options, message", [
    (dict(method="lod-distance", distance=-1.0), "distance"),
    (dict(method="lod-distance", distance=1.0, threshold=0.1), "threshold 0"),
    (dict(method="sleeping", sleep_speed=0.0), "sleep_speed"),
    (dict(method="sleeping", sleep_time=np.nan), "sleep_time"),
    (dict(method="sleeping", distance=1.0),
     "distance= applies to method='lod-distance', not to method='sleeping'"),
])
def test_bad_baseline_options(options, message):
    with pytest.raises(InputError, match=message):
        pendulum(n_bodies=3).simulator(**options)


@pytest.mark.parametrize("method", ["lod-distance", "sleeping"])
def test_a_switch_is_evaluated_once_per_frame(method, monkeypatch):
    """Like the coverage, a switch is evaluated once per displayed frame, and a
    region change does not call it again (it gives every node's value)."""
    from vdad.simulator import frame_steps

    scene = pendulum(n_bodies=5, angle=0.0)             # far, or still: it switches off
    options = {"distance": 0.01} if method == "lod-distance" else {"sleep_time": 0.05}
    sim = Simulator(scene.model, scene.q0, np.r_[0.01, np.zeros(4)], dt=scene.dt,
                    camera=scene.camera, method=method, dwell=0, **options)
    every = frame_steps(scene.dt)
    assert every > 1 and sim.adaptive.coverage_every == every
    switch, calls = type(sim.adaptive.coverage), []
    monkeypatch.setattr(switch, "__call__", lambda self, t, q, adaptive, call=switch.__call__:
                        calls.append(t) or call(self, t, q, adaptive))
    sim.step(10 * every)
    assert np.allclose(calls, np.arange(10) * every * scene.dt)
    assert sum(h.rigidified + h.released for h in sim.history) > 0
