"""Integrators and the Simulator (theory §8, checks 5 and 6)."""

import copy
import subprocess
import sys

import numpy as np
import pytest
from numba.core.registry import CPUDispatcher
from strategies import random_chain, random_configuration, random_state, random_tree, with_armature

import vdad
import vdad.dca
import vdad.integrators
import vdad.kinematics
import vdad.region
import vdad.visibility
from vdad.integrators import integrate_configuration
from vdad.quantities import spatial_momentum, total_energy
from vdad.scenes import pendulum


@pytest.mark.parametrize("armature", [False, True])
def test_rk4_energy_of_20_link_pendulum(armature):
    """20 links of 1 kg and 1 m from 1 rad, RK4, h = 1e-3, 2 s: |dE|/(m g L) < 1e-6
    (with rotor inertia on every joint too: its energy is part of the kinetic)."""
    scene = pendulum(20, link_length=1.0, link_mass=1.0, angle=1.0)
    model = with_armature(scene.model, 0) if armature else scene.model
    sim = vdad.Simulator(model, scene.q0, dt=1e-3, integrator="rk4")
    E0 = total_energy(model, sim.q, sim.qd)
    sim.step(2000)
    assert sim.t == pytest.approx(2.0)
    drift = abs(total_energy(model, sim.q, sim.qd) - E0) / (1.0 * 9.81 * 1.0)
    assert drift < 1e-6
    assert np.abs(sim.qd).max() > 0.5                      # it really swung


def test_semi_implicit_euler_energy_stays_bounded():
    scene = pendulum(5, link_length=0.5, link_mass=1.0, angle=0.5)
    sim = scene.simulator(integrator="semi-implicit", dt=1e-3)
    E0 = total_energy(scene.model, sim.q, sim.qd)
    errors = []
    for _ in range(20):
        sim.step(200)
        errors.append(total_energy(scene.model, sim.q, sim.qd) - E0)
    errors = np.abs(errors) / (5 * 9.81 * 2.5)
    assert errors.max() < 5e-3                              # oscillates, O(h)
    assert errors[-5:].mean() < 3 * errors[:5].mean() + 1e-4  # no secular drift


def test_the_symplectic_integrator_keeps_the_energy_of_a_long_run_bounded():
    """docs/accuracy.md, (S1)-(S3): the scene's 20-link pendulum (0.1 kg, 0.1 m
    links, from 1 rad) at dt = 0.25 ms over 40000 steps, where the fixed point of
    every step contracts. Semi-implicit Euler's energy error grows (3.6e-2 of
    n m g L in the first half, 9.7e-2 in the second); symplectic Euler in momentum
    form keeps it bounded (1.5e-3, 1.6e-3). At dt = 1 ms, see the next test."""
    scene = pendulum()
    scale = scene.model.nb * 0.1 * 9.81 * 0.1
    errors = {}
    for integrator in ("semi-implicit", "symplectic"):
        sim = scene.simulator(integrator=integrator, dt=2.5e-4)
        E0 = total_energy(scene.model, sim.q, sim.qd)
        worst = []
        for _ in range(20):
            sim.step(2000)
            worst.append(abs(total_energy(scene.model, sim.q, sim.qd) - E0) / scale)
        errors[integrator] = np.array(worst)
    symplectic, euler = errors["symplectic"], errors["semi-implicit"]
    assert symplectic[10:].max() < 1.5 * symplectic[:10].max()
    assert euler[10:].max() > 2 * euler[:10].max()
    assert symplectic.max() * 10 < euler.max()


def test_a_symplectic_step_that_needs_substeps_keeps_them():
    """(S4) of docs/accuracy.md: at dt = 1 ms the pendulum's whip at t = 4.533 s
    leaves the step's velocity equation without a fixed point near the start; that
    step is taken in two substeps, and so is every later one (a step that changed
    back would lose the bounded energy error), across calls of step(). The energy
    error stays at the size of the oscillation before it."""
    scene = pendulum()
    scale = scene.model.nb * 0.1 * 9.81 * 0.1
    sim = scene.simulator(integrator="symplectic")
    E0 = total_energy(scene.model, sim.q, sim.qd)
    errors = []
    for _ in range(9):
        sim.step(500)
        errors.append(abs(total_energy(scene.model, sim.q, sim.qd) - E0) / scale)
    assert sim.halvings[0] == 0 and max(errors) < 1e-2
    sim.step(100)
    assert sim.halvings[0] == 1
    before = total_energy(scene.model, sim.q, sim.qd)
    sim.step(400)
    assert sim.halvings[0] == 1
    assert abs(total_energy(scene.model, sim.q, sim.qd) - before) / scale < 1e-2


def test_the_symplectic_integrator_converges_to_the_trajectory():
    """First order: halving dt halves the distance to the RK4 trajectory (a
    seeded chain of hinges and slides with armature and springs, 0.2 s)."""
    model = with_armature(random_chain(3, n=5, kinds=("revolute", "prismatic"),
                                       root="revolute"), 3)
    q0 = random_configuration(model, np.random.default_rng(3))
    exact = vdad.Simulator(model, q0, dt=1e-4, integrator="rk4").step(2000).q
    errors = []
    for dt in (2e-3, 1e-3, 5e-4):
        sim = vdad.Simulator(model, q0, dt=dt, integrator="symplectic").step(round(0.2 / dt))
        errors.append(np.abs(sim.q - exact).max())
    assert 1.6 < errors[0] / errors[1] < 2.5 and 1.6 < errors[1] / errors[2] < 2.5


def test_the_symplectic_integrator_says_what_it_needs():
    scene = pendulum(4)
    with pytest.raises(vdad.InputError, match="integrator 'symplectic' .* runs the DCA only"):
        scene.simulator(method="adaptive", integrator="symplectic")
    with pytest.raises(vdad.InputError, match="joint 'joint0' has a ball or a translation"):
        pendulum(4, joint="spherical").simulator(integrator="symplectic")
    with pytest.raises(vdad.InputError, match="Python callables need integrator"):
        scene.simulator(integrator="symplectic", controller=lambda t, q, qd: 0 * qd)
    with pytest.raises(vdad.InputError, match="unknown integrator 'leapfrog'"):
        scene.simulator(integrator="leapfrog")


@pytest.mark.parametrize("seed", [4, 5, 6])
def test_momentum_balance_of_a_free_system(seed):
    """d/dt h = sum of external wrenches, without gravity, to 1e-10 relative.

    d/dt h along the exact dynamics is a Richardson-extrapolated central
    difference (measured error of that estimate: 1e-11 to 3e-11)."""
    model = random_chain(seed, n=8, root="free", gravity=(0.0, 0.0, 0.0))
    rng = np.random.default_rng(seed)
    q, qd = random_configuration(model, rng), rng.normal(size=model.nv)
    f_ext = rng.normal(size=(model.nb, 6))
    qdd = vdad.forward_dynamics(model, q, qd, f_ext=f_ext)

    def h_along(eps):
        return spatial_momentum(model, integrate_configuration(model, q, qd, eps),
                                qd + eps * qdd)

    def derivative(eps):
        return (h_along(eps) - h_along(-eps)) / (2 * eps)

    eps = 1e-3
    rate = (4 * derivative(eps / 2) - derivative(eps)) / 3    # Richardson, O(eps^4)
    kin = vdad.kinematics.kinematics(model, q, qd)
    c = kin.p + np.einsum("kij,kj->ki", kin.R, model.com)
    expected = np.concatenate([np.sum(f_ext[:, :3] + np.cross(c, f_ext[:, 3:]), axis=0),
                               np.sum(f_ext[:, 3:], axis=0)])
    assert np.abs(rate - expected).max() < 1e-10 * np.abs(expected).max()


def test_momentum_is_conserved_without_forces():
    model = random_chain(5, n=6, root="free", gravity=(0.0, 0.0, 0.0))
    rng = np.random.default_rng(5)
    sim = vdad.Simulator(model, random_configuration(model, rng),
                                   rng.normal(size=model.nv), dt=1e-3, integrator="rk4")
    h0 = spatial_momentum(model, sim.q, sim.qd)
    sim.step(200)
    assert np.abs(spatial_momentum(model, sim.q, sim.qd) - h0).max() < 1e-8 * np.abs(h0).max()


def test_quaternions_stay_normalised():
    model = random_chain(6, n=5, root="free", kinds=("spherical",))
    rng = np.random.default_rng(6)
    sim = vdad.Simulator(model, random_configuration(model, rng),
                                   rng.normal(size=model.nv), dt=1e-3)
    sim.step(300)
    for s in np.flatnonzero(model.stage_kind == vdad.joints.BALL):
        i = model.stage_q[s]
        assert np.linalg.norm(sim.q[i:i + 4]) == pytest.approx(1.0, abs=1e-14)


def test_bad_force_stops_with_the_step():
    scene = pendulum(3)

    def broken(t, q, qd):
        return np.array([0.0, np.nan if t > 0.0045 else 0.0, 0.0])

    sim = scene.simulator(dt=1e-3)
    sim.controller = broken
    with pytest.raises(vdad.SimulationError,
                       match=r"step 6 .*controller\(t, q, qd\) has non-finite entries at "
                       r"indices \[1\]"):
        sim.step(10)
    assert sim.step_count == 5


@pytest.mark.parametrize("options", [{}, {"method": "adaptive", "threshold": 0.0}])
def test_blow_up_names_the_step_and_joint(options):
    """An unstable explicit step on a stiff spring diverges; the error says where."""
    model = vdad.Model([vdad.Body("mass", 1.0)],
                       [vdad.Joint("spring", None, "mass", "prismatic", axis=(1, 0, 0),
                                   stiffness=1e12)], gravity=(0, 0, 0))
    sim = vdad.Simulator(model, [1.0], dt=1e-2, integrator="rk4", **options)
    with np.errstate(over="ignore", invalid="ignore"):
        with pytest.raises(vdad.SimulationError, match=r"step \d+ .*joint 'spring'"):
            sim.step(1000)


def test_simulator_rejects_bad_options():
    scene = pendulum(3)
    with pytest.raises(vdad.InputError, match="unknown method 'fast'"):
        scene.simulator(method="fast")
    with pytest.raises(vdad.InputError, match="unknown integrator 'euler'"):
        scene.simulator(integrator="euler")
    with pytest.raises(vdad.InputError, match="dt must be positive"):
        scene.simulator(dt=0.0)
    with pytest.raises(vdad.InputError, match="n_bodies must be a positive integer"):
        pendulum(0)


@pytest.mark.parametrize("kwargs, match", [
    (dict(dt="0.01"), "dt must be a real number.*string"),
    (dict(dt=None), "dt must be a real number.*got None"),
    (dict(dt=[0.1, 0.2]), "dt must be a single number"),
    (dict(dt=np.nan), "dt must be finite"),
    (dict(controller=3), r"controller must be a callable \(t, q, qd\) -> tau"),
    (dict(external="f"), r"external must be a callable \(t, q, qd\) -> f_ext"),
    (dict(q0=np.full(3, np.nan)), "q0 has non-finite entries"),
    (dict(integrator={}), "unknown integrator {}"),
    (dict(camera="cam"), "camera must be a vdad.camera.Camera or a callable"),
    (dict(environment="floor"), "environment must be a vdad.environment.Environment"),
    (dict(qd0="abc"), "qd0 must be a real number"),
])
def test_simulator_rejects_bad_input(kwargs, match):
    with pytest.raises(vdad.InputError, match=match):
        vdad.Simulator(pendulum(3).model, **kwargs)
    with pytest.raises(vdad.InputError, match=match):
        pendulum(3).simulator(**kwargs)                  # a scene's own values give way


def test_scene_simulators_take_other_states_and_forces():
    scene = pendulum(3)
    sim = scene.simulator(q0=[0.1, 0.2, 0.3], controller=lambda t, q, qd: -qd)
    np.testing.assert_array_equal(sim.q, [0.1, 0.2, 0.3])
    assert sim.controller is not scene.controller and sim.step(3).step_count == 3


@pytest.mark.parametrize("model", [None, "pendulum", pendulum(3)])
def test_models_must_be_models(model):
    with pytest.raises(vdad.InputError, match="model must be a vdad.Model, got"):
        vdad.Simulator(model)
    with pytest.raises(vdad.InputError, match="model must be a vdad.Model, got"):
        vdad.forward_dynamics(model, [0.0], [0.0])


@pytest.mark.parametrize("n, match", [
    ("abc", "n must be an integer >= 0, got 'abc'"), (np.nan, "n must be an integer >= 0"),
    (-5, "n must be an integer >= 0, got -5"), (2.7, "n must be an integer >= 0, got 2.7"),
    (True, "n must be an integer >= 0, got True"),
])
def test_step_counts_are_whole_numbers(n, match):
    sim = pendulum(3).simulator()
    with pytest.raises(vdad.InputError, match=match):
        sim.step(n)
    assert sim.step_count == 0
    assert sim.step(np.int64(2)).step(0).step(3.0).step_count == 5


def test_trees_and_data_of_another_model_are_refused():
    from vdad.dca import make_data

    small, big = pendulum(3).model, pendulum(5).model
    q, qd = small.q_neutral, np.zeros(small.nv)
    with pytest.raises(vdad.InputError, match="tree was built for model 'pendulum5' .*differs "
                                              "from model 'pendulum3'"):
        vdad.Simulator(small, tree=vdad.AssemblyTree.balanced(big))
    with pytest.raises(vdad.InputError, match="tree was built for model 'pendulum5'"):
        vdad.forward_dynamics(small, q, qd, tree=vdad.AssemblyTree.balanced(big))
    with pytest.raises(vdad.InputError, match="tree must be a vdad.AssemblyTree, got str"):
        vdad.forward_dynamics(small, q, qd, tree="balanced")
    with pytest.raises(vdad.InputError, match="data was allocated for another assembly tree"):
        vdad.forward_dynamics(small, q, qd, data=make_data(vdad.AssemblyTree.balanced(big)))
    with pytest.raises(vdad.InputError, match="data must be vdad.dca.DCAData"):
        vdad.forward_dynamics(small, q, qd, data={})
    # a tree of an equal model built again (same topology) is fine, and gives the same result
    again = pendulum(3).model
    tree = vdad.AssemblyTree.sequential(again)
    np.testing.assert_allclose(vdad.forward_dynamics(small, pendulum(3).q0, qd, tree=tree),
                               vdad.forward_dynamics(small, pendulum(3).q0, qd), atol=1e-12)


@pytest.mark.parametrize("inputs, match", [
    (dict(qd=np.full(5, 1e200)), r"overflowed .*joint 'joint\d'.*\|qd\| up to 1e\+200"),
    (dict(tau=np.full(5, 1e308)), r"overflowed .*\|tau\| up to 1e\+308"),
])
def test_finite_inputs_that_overflow_are_an_error(inputs, match):
    model = pendulum(5, axes="alternate").model
    args = dict(q=np.full(5, 0.3), qd=np.zeros(5), tau=None)
    args.update(inputs)
    with np.errstate(all="ignore"), pytest.raises(vdad.InputError, match=match):
        vdad.forward_dynamics(model, **args)


def test_seeded_runs_repeat_exactly():
    a = pendulum(10, axes="alternate").simulator().step(100)
    b = pendulum(10, axes="alternate").simulator().step(100)
    np.testing.assert_array_equal(a.q, b.q)
    assert not np.allclose(a.q[1::2], 0.0)                  # the alternate chain swings in 3D


@pytest.mark.parametrize("options", [{}, {"method": "adaptive", "threshold": 0.0}])
def test_diverging_run_stops_with_the_joint(options):
    """More than half a turn per step on a rotational dof: a SimulationError (with
    adaptive dynamics, from the compiled check of the active joints first)."""
    from vdad.errors import SimulationError

    scene = pendulum(n_bodies=3)
    qd0 = np.array([0.0, 4000.0, 0.0])
    sim = vdad.Simulator(scene.model, scene.q0, qd0, dt=1e-3, **options)
    with pytest.raises(SimulationError, match="step 1 .*joint 'joint1' turns 4 rad in one "
                                              "step .*diverging; reduce the time step"):
        sim.step()


@pytest.mark.parametrize("seed", [0, 1])
@pytest.mark.parametrize("options", [{}, {"method": "adaptive", "threshold": 0.0},
                                     {"controller": lambda t, q, qd: np.zeros(len(qd))}])
def test_implicit_damping_is_backward_euler_in_the_dampers(seed, options):
    """``implicit_damping=True``: a semi-implicit Euler step solves ``(M + dt D)
    qdd = -bias`` (the CRBA and RNEA of vdad.reference, the bias with the
    dampers' ``-D qd``), ``D`` the dampers per dof, on a random tree of every
    joint kind with springs and dampers (composite stages too): in compiled
    steps, adaptive ones and the Python step."""
    from vdad.reference import bias_forces, crba

    model = random_tree(seed, composite=True)
    q, qd, _, _ = random_state(model, seed)
    dt = 0.05
    sim = vdad.Simulator(model, q, qd, dt=dt, implicit_damping=True, **options)
    nv = np.array(vdad.joints.STAGE_NV)[model.stage_kind]
    D = np.repeat(model.stage_damping, nv)
    A = crba(model, sim.q) + dt * np.diag(D)
    assert dt * D.max() > 0.01 * np.diag(A).min()            # the dampers matter
    expected = qd + dt * np.linalg.solve(A, -bias_forces(model, sim.q, qd))
    sim.step()
    tol = 100 * np.linalg.cond(A) * np.finfo(float).eps * max(1.0, np.abs(expected).max())
    np.testing.assert_allclose(sim.qd, expected, rtol=0, atol=tol)
    explicit = vdad.Simulator(model, q, qd, dt=dt, **options).step()
    assert np.abs(explicit.qd - sim.qd).max() > 1e3 * tol   # not the explicit step


def test_implicit_damping_holds_a_damper_that_explicit_euler_cannot():
    """A body spinning about its axis under a damper ``d`` with ``dt d / I = 10``:
    explicit Euler multiplies its rate by ``1 - 10`` a step and diverges; with
    ``implicit_damping`` each step divides it by ``1 + 10``, backward Euler's
    exact decay; the falling character with ``joint_damping`` 60 (its clavicle
    diverges at step 130 explicitly, docs/adaptive.md) completes 1000 steps."""
    from vdad.errors import SimulationError
    from vdad.scenes import falling_character

    model = vdad.Model([vdad.Body("wheel", 1.0, inertia=(1.0, 1.0, 2.0))],
                       [vdad.Joint("axle", None, "wheel", "revolute", damping=2e4)],
                       gravity=(0.0, 0.0, 0.0))
    sim = vdad.Simulator(model, qd0=[1.0], dt=1e-3, implicit_damping=True).step(10)
    np.testing.assert_allclose(sim.qd, [11.0 ** -10], rtol=1e-12)
    with pytest.raises(SimulationError, match="joint 'axle'"):
        vdad.Simulator(model, qd0=[1.0], dt=1e-3).step(10)
    scene = falling_character(joint_damping=60.0)
    with pytest.raises(SimulationError, match="lclavicle"):
        scene.simulator().step(1000)
    for method in ("dca", "view-bvh"):
        sim = scene.simulator(method=method, implicit_damping=True).step(1000)
        assert np.all(np.isfinite(sim.qd))


def test_implicit_damping_takes_a_flag_and_euler():
    scene = pendulum(n_bodies=3)
    with pytest.raises(vdad.InputError, match="implicit_damping must be True or False"):
        scene.simulator(implicit_damping="yes")
    for integrator in ("rk4", "symplectic"):
        with pytest.raises(vdad.InputError, match=f"implicit_damping=True .* applies to "
                                                   f"integrator 'semi-implicit' .*not to "
                                                   f"'{integrator}'"):
            scene.simulator(integrator=integrator, implicit_damping=True)
    sim = scene.simulator()
    assert sim.dynamics is sim.model and not sim.implicit_damping


@pytest.mark.parametrize("method", ["dca", "adaptive"])
def test_body_poses_take_names_or_indices_in_range(method):
    sim = pendulum(3).simulator(method=method)
    R, p = sim.body_poses(["link0", 2])
    R_all, p_all = sim.body_poses()
    np.testing.assert_allclose(p, p_all[[0, 2]], atol=1e-12)
    for bad in ([5], [-1], [0.5], [True], "link9"):
        with pytest.raises(vdad.VdadError, match="link9|neither a body name nor a body index"):
            sim.body_poses(bad)


SCENES = {"pendulum": lambda: pendulum(20, axes="alternate"),
          "dog puppet": lambda: vdad.scenes.dog_puppet(),
          "hanging dogs": lambda: vdad.scenes.hanging_dogs(n_dogs=4, columns=2),
          "falling character": lambda: vdad.scenes.falling_character()}


@pytest.mark.parametrize("name", sorted(SCENES))
def test_compiled_steps_equal_the_python_steps_on_every_scene(name):
    """Simulator.step(n) of a scene (forces of vdad's own elements) runs whole steps
    in compiled code (vdad.integrators.dca_steps, forces by vdad.forces.apply_forces);
    the same forces as Python callables take the Python-level step: 1000 steps
    agree to 1e-12 (they share every kernel, so they agree to the last bit)."""
    scene = SCENES[name]()
    fast = scene.simulator()
    assert fast.force_tables() is not None
    ext, ctl = scene.external, scene.controller
    slow = scene.simulator(
        external=None if ext is None else (lambda t, q, qd: ext(t, q, qd)),
        controller=(lambda t, q, qd: np.zeros(scene.model.nv)) if ctl is None
        else (lambda t, q, qd: ctl(t, q, qd)))
    assert slow.force_tables() is None
    fast.step(1000)
    slow.step(1000)
    assert fast.step_count == slow.step_count == 1000 and fast.t == slow.t
    for a, b in ((fast.q, slow.q), (fast.qd, slow.qd)):
        np.testing.assert_allclose(a, b, rtol=0, atol=1e-12 * max(1.0, np.abs(b).max()))
    assert np.abs(fast.qd).max() > 0.1                        # it moved


@pytest.mark.parametrize("method", ["dca", "adaptive"])
def test_forces_set_between_calls_are_the_ones_the_compiled_steps_apply(method):
    """The compiled steps take the force tables in a pack that a simulator keeps
    while its tables are the same object (``vdad._pack.pack_once``): forces set
    between two calls are the ones the next call applies, as the same forces as
    Python callables (the Python-level step) give, to 1e-12."""
    from vdad.forces import Drag, Forces

    scene = pendulum(6)
    model = scene.model
    weak, strong = (Forces(model, [Drag(model, c)]) for c in (0.05, 3.0))
    options = {} if method == "dca" else {"method": "adaptive", "threshold": 1e-6}
    runs = []
    for wrap in (False, True):
        sim = vdad.Simulator(model, scene.q0, **options)
        for forces in (weak, strong, weak):
            sim.external = (lambda t, q, qd, f=forces: f.external(t, q, qd)) if wrap \
                else forces.external
            assert (sim.force_tables() is None) == wrap
            sim.step(40)
        runs.append(sim)
    fast, slow = runs
    for a, b in ((fast.q, slow.q), (fast.qd, slow.qd)):
        np.testing.assert_allclose(a, b, rtol=0, atol=1e-12 * max(1.0, np.abs(b).max()))
    weak_only = vdad.Simulator(model, scene.q0, external=weak.external, **options).step(120)
    assert np.abs(weak_only.qd - fast.qd).max() > 1e-3            # the strong drag acted


@pytest.mark.parametrize("name, integrator", [(n, "semi-implicit") for n in sorted(SCENES)]
                         + [("falling character", "rk4")])
def test_adaptive_steps_evaluate_the_built_in_forces_in_compiled_code(name, integrator):
    """Adaptive dynamics takes a scene's own force elements from the compiled tables
    (vdad.forces.body_forces, one chunk of steps at a time) instead of the Python
    callables: 600 steps (past a chunk of 512) agree with the callables' to 1e-12,
    with the same active joints at every step."""
    scene = SCENES[name]()
    ext, ctl = scene.external, scene.controller
    runs = []
    for wrap in (False, True):
        options = {} if not wrap else {
            "external": None if ext is None else (lambda t, q, qd: ext(t, q, qd)),
            "controller": None if ctl is None else (lambda t, q, qd: ctl(t, q, qd))}
        sim = scene.simulator(method="adaptive", threshold=1e-4, integrator=integrator,
                              **options)
        own = not wrap and (ext is not None or ctl is not None)
        assert (sim._tables_for(1) is not None) == own          # tables: forces to compute
        runs.append(sim.step(600))
    fast, slow = runs
    for a, b in ((fast.q, slow.q), (fast.qd, slow.qd)):
        np.testing.assert_allclose(a, b, rtol=0, atol=1e-12 * max(1.0, np.abs(b).max()))
    active = [[s.active_joints for s in sim.history] for sim in runs]
    assert active[0] == active[1] and min(active[0]) < scene.model.nb     # it pruned
    assert np.abs(fast.qd).max() > 0.1


@pytest.mark.parametrize("name, method, options", [
    ("pendulum", "adaptive", {"threshold": 1e-4}),
    ("pendulum", "adaptive", {"budget": 6, "drop": "coast", "policy": "zero"}),
    ("pendulum", "view-bvh", {"pixels": "moved", "threshold": 1e-3}),
    ("pendulum", "view-bvh", {"threshold": 0.1, "lookahead_every": 4}),
    ("pendulum", "adaptive", {"budget": 6, "lookahead_every": 3}),
    ("dog puppet", "view-bvh", {}),
    ("hanging dogs", "adaptive", {"threshold": 1e-5, "metric": "coefficients"}),
    ("falling character", "view-bvh", {"coverage_every": 5}),
    ("pendulum", "view-oq", {"counting": "raster", "threshold": 0.03}),
    ("dog puppet", "view-oq", {"counting": "raster", "pixels": "moved"}),
])
def test_compiled_adaptive_steps_equal_the_python_steps(name, method, options):
    """Adaptive steps by semi-implicit Euler run in compiled code
    (AdaptiveDynamics.run, vdad.region.region_steps) where the forces allow: the
    same states, to the last bit, and the same counters at every step as one
    Python-level step at a time, with coverage evaluated as often (bounding
    volumes and rasterised counts: in the compiled loop, ``loop_coverage``,
    against the estimator's call from Python)."""
    import dataclasses

    runs = []
    for loop in (True, False):
        sim = SCENES[name]().simulator(method=method, **options)
        sim.adaptive_loop = loop
        calls = []
        coverage = sim.adaptive.coverage
        if coverage is not None and loop:
            in_loop = coverage.loop_coverage
            coverage.loop_coverage = (lambda steps, times, ad, calls=calls, in_loop=in_loop:
                                      calls.extend(times) or in_loop(steps, times, ad))
        elif coverage is not None:
            def counted(t, q, ad, calls=calls, coverage=coverage):
                return calls.append(t) or coverage(t, q, ad)
            counted.covers_every_node = coverage.covers_every_node
            sim.adaptive.coverage = counted
        sim.step(300)
        sim.step(400)
        runs.append((sim, calls))
    (fast, fast_calls), (slow, slow_calls) = runs
    np.testing.assert_array_equal(fast.q, slow.q)
    np.testing.assert_array_equal(fast.qd, slow.qd)
    assert fast.t == slow.t and fast_calls == slow_calls
    counters = [[{k: v for k, v in dataclasses.asdict(st).items() if k != "times"}
                 for st in sim.history] for sim in (fast, slow)]
    assert counters[0] == counters[1]
    assert all(st.times["steps"] > 0 and st.times["dynamics"] == 0 for st in fast.history)
    assert min(st.active_joints for st in fast.history) < fast.model.nb     # it pruned


@pytest.mark.parametrize("loop", [True, False])
def test_a_diverging_compiled_adaptive_run_stops_as_a_python_one(loop):
    """The compiled loop stops at the step whose state fails the checks, with the
    simulator at the state before it, as a Python-level step does."""
    from vdad.errors import SimulationError

    scene = pendulum(n_bodies=3)
    sim = vdad.Simulator(scene.model, scene.q0, dt=1e-2, method="adaptive", threshold=0.0)
    sim.adaptive_loop = loop
    sim.step(3)
    q, qd = sim.q.copy(), sim.qd.copy()
    sim.qd = qd + np.array([0.0, 400.0, 0.0])
    kept = sim.qd.copy()
    with pytest.raises(SimulationError, match=r"step 4 \(t = 0.04 s\): joint 'joint0' turns"):
        sim.step(10)
    assert sim.step_count == 3
    np.testing.assert_array_equal(sim.q, q)
    np.testing.assert_array_equal(sim.qd, kept)


@pytest.mark.parametrize("integrator", ["semi-implicit", "rk4"])
def test_compiled_rk4_and_euler_steps_equal_the_python_steps(integrator):
    """The same on a random tree of every joint kind with springs, dampers and
    armature, by both integrators."""
    from strategies import random_tree

    model = with_armature(random_tree(4, n=10, roots=2, composite=True), 4)
    rng = np.random.default_rng(4)
    q0, qd0 = random_configuration(model, rng), 0.3 * rng.normal(size=model.nv)
    fast = vdad.Simulator(model, q0, qd0, dt=1e-3, integrator=integrator)
    slow = vdad.Simulator(model, q0, qd0, dt=1e-3, integrator=integrator,
                          controller=lambda t, q, qd: np.zeros(model.nv))
    fast.step(1000)
    slow.step(1000)
    for a, b in ((fast.q, slow.q), (fast.qd, slow.qd)):
        np.testing.assert_allclose(a, b, rtol=0, atol=1e-12 * max(1.0, np.abs(b).max()))
    assert np.abs(fast.qd).max() > 0.1


def test_only_vdads_own_forces_run_compiled():
    """A Forces of vdad's elements runs compiled; a user element, a callable of
    one's own, or half of a Forces (its external without its controller) runs in
    Python."""
    from vdad.forces import Drag, Forces, JointLimits

    scene = pendulum(3)
    model = scene.model
    forces = Forces(model, [Drag(model, 0.5), JointLimits(model, {"joint1": (-1, 1)})])
    assert vdad.Simulator(model, external=forces.external,
                          controller=forces.controller).force_tables() is not None
    assert vdad.Simulator(model, external=forces.external).force_tables() is None

    class Mine(Drag):
        pass

    assert vdad.Simulator(model, external=Forces(model, [Mine(model, 0.5)]).external
                          ).force_tables() is None
    assert vdad.Simulator(model, external=lambda t, q, qd: np.zeros((3, 6))
                          ).force_tables() is None


def test_compiled_steps_stop_at_the_diverging_step():
    """The compiled loop stops at the first bad step with the Python step's error,
    keeping the last good state: a hinge on a spring too stiff for the time step
    (w dt = 3) grows every step until it turns more than half a turn."""
    model = vdad.Model([vdad.Body("wheel", 1.0, inertia=(1.0, 1.0, 1.0))],
                       [vdad.Joint("hinge", None, "wheel", stiffness=9e6)], gravity=(0, 0, 0))
    sim = vdad.Simulator(model, [0.01], dt=1e-3)
    with pytest.raises(vdad.SimulationError, match=r"step (\d+) .*joint 'hinge' turns"):
        sim.step(100)
    assert 1 < sim.step_count < 10 and abs(sim.qd[0]) * 1e-3 <= np.pi


def test_step_loop_loaded_from_the_cache_in_a_fresh_process():
    """A process whose first compiled call is the step loop, loaded from numba's
    cache (compiled by this session's earlier steps), runs it: the loop links the
    parallel forest pass, whose threading layer numba would not start on that load
    (numba #8578; it crashed before vdad started it in ``_linalg.compiling``)."""
    scene = pendulum(3)
    expected = scene.simulator().step(5).q
    code = ("import vdad.scenes as s; import numpy as np; "
            "print(np.array2string(s.pendulum(3).simulator().step(5).q, precision=17))")
    for _ in range(2):                 # the first may compile; the second loads
        done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                              timeout=600)
        assert done.returncode == 0, done.stderr
    q = np.array(done.stdout.strip().strip("[]").split(), float)
    np.testing.assert_array_equal(q, expected)



@pytest.mark.parametrize("options", [{}, {"method": "adaptive", "budget": 3},
                                     {"method": "view-bvh", "threshold": 1e-3,
                                      "pixels": "moved"}])
def test_a_copied_simulator_runs_the_same_compiled_kernels(options):
    """copy.deepcopy of a simulator shares its immutable model and tree (the same
    objects, read-only arrays and all), so the copy steps with the kernels already
    compiled for the original instead of compiling a second version of each (two
    minutes for the adaptive passes) and gives the same state; so does a
    view-dependent one, whose bounding volumes run inside the compiled steps."""
    scene = pendulum(8)
    sim = scene.simulator(**options) if options.get("pixels") else vdad.Simulator(
        scene.model, scene.q0, **options)
    sim.step(2)
    kernels = [k for m in (vdad.dca, vdad.integrators, vdad.kinematics, vdad.region,
                           vdad.visibility)
               for k in vars(m).values() if isinstance(k, CPUDispatcher)]
    compiled = {k: len(k.signatures) for k in kernels}
    twin = copy.deepcopy(sim)
    assert twin.model is sim.model and copy.copy(sim.model) is sim.model
    assert not twin.model.mass.flags.writeable
    packs = (twin.adaptive or twin)._packs                  # numba cannot copy a pack
    assert packs == (None,) * len(packs) != (sim.adaptive or sim)._packs
    twin.step(3)
    sim.step(3)
    np.testing.assert_array_equal(twin.q, sim.q)
    assert {k: len(k.signatures) for k in kernels} == compiled
    assert (twin.adaptive or twin)._packs[0] is not (sim.adaptive or sim)._packs[0]


def test_a_simulator_with_python_forces_is_copied_after_stepping():
    """With a Python controller the DCA runs from Python (``dca.dca_call``), and
    its work arrays hold the packed arguments (``vdad._pack``), which numba cannot
    copy: copy.deepcopy leaves them out, the copy builds its own and steps as the
    original does."""
    scene = pendulum(5)
    sim = scene.simulator(controller=lambda t, q, qd: -0.1 * qd)
    sim.step(3)
    assert sim.data.packed is not None
    twin = copy.deepcopy(sim)
    assert twin.data.packed is None
    twin.step(4)
    sim.step(4)
    np.testing.assert_array_equal(twin.q, sim.q)
    assert twin.data.packed is not sim.data.packed


def test_view_methods_evaluate_coverage_once_per_displayed_frame_by_default():
    """docs/visibility.md, coverage once per frame: view-bvh and view-oq default to
    the steps of one 60 Hz frame (17 at 1 ms, 8 at 2 ms, never below 1); a given
    coverage_every is kept; the coverage runs on those steps (and on region
    changes) only."""
    from vdad.simulator import FRAME_RATE, frame_steps

    assert FRAME_RATE == 60.0
    assert (frame_steps(1e-3), frame_steps(2e-3), frame_steps(0.5)) == (17, 8, 1)
    scene = pendulum(6)
    assert scene.simulator(method="view-bvh").options["coverage_every"] == 17
    assert scene.simulator(method="view-bvh", dt=2e-3).options["coverage_every"] == 8
    assert scene.simulator(method="view-bvh", coverage_every=1).options["coverage_every"] == 1
    assert "coverage_every" not in scene.simulator(method="dca").options
    sim = scene.simulator(method="view-bvh", threshold=1e-4)
    calls = []
    coverage = sim.adaptive.coverage

    def counted(t, q, adaptive):
        calls.append(round(t / sim.dt))
        return coverage(t, q, adaptive)

    sim.adaptive.coverage = counted
    sim.step(68)
    frames = {k for k in range(68) if k % 17 == 0}
    assert frames <= set(calls)
    assert len(calls) < 68 / 2                          # not every step
