"""Force elements (vdad.forces): body states, springs and strings, random torques,
drag, floor contact with friction, joint limits, and their sum.

Each check goes through an independent path: the full kinematics, finite
differences of poses and energies, closed-form equilibria and decay laws.
"""

import dataclasses

import numpy as np
import pytest
from strategies import random_configuration, random_inertia

import vdad
from vdad import Body, Geom, InputError, Joint, Model, ModelError, Pose
from vdad.forces import (
    BodyStates,
    Drag,
    FloorContact,
    Forces,
    JointLimits,
    RandomTorques,
    Springs,
    contact_points,
    joint_inertia,
)
from vdad.integrators import integrate_configuration
from vdad.kinematics import kinematics
from vdad.quantities import kinetic_energy, potential_energy
from vdad.reference import crba
from vdad.scenes import hanging_dogs, humanoid, pendulum
from vdad.spatial import quat_exp, quat_to_rot, skew

EPS = np.finfo(float).eps


def rotate(R, x):
    return np.einsum("kij,kj->ki", R, x)


def free_body(geoms=(), mass=1.0, com=(0.0, 0.0, 0.0), inertia=(0.1, 0.1, 0.1),
              gravity=(0.0, 0.0, -9.81), name="free"):
    """One body on a free joint."""
    return Model([Body("body", mass, com, inertia, tuple(geoms))],
                 [Joint("root", None, "body", "free")], gravity=gravity, name=name)


def free_state(position, rotvec=(0.0, 0.0, 0.0), v=(0.0, 0.0, 0.0), w=(0.0, 0.0, 0.0)):
    """``(q, qd)`` of a free joint: origin velocity ``v`` (world), body-frame ``w``."""
    q = np.concatenate([position, quat_exp(np.asarray(rotvec, float))])
    return q, np.concatenate([v, w]).astype(float)


# --- BodyStates ---------------------------------------------------------------------

def body_state_cases():
    model, _ = humanoid()
    dogs = hanging_dogs(n_dogs=3, columns=3).model
    return [(model, ["lhand", "head", "rtoes", "pelvis", "lhand", "rthumb"]),
            (dogs, ["dog002/head", "dog000/torso", "dog001/back_left_paw", "dog000/tail"])]


@pytest.mark.parametrize("case", [0, 1])
def test_body_states_equal_the_full_kinematics(case):
    """A subset of bodies (repeated, out of order, across trees) placed through
    their ancestors only: poses and velocities equal the whole model's."""
    model, names = body_state_cases()[case]
    rng = np.random.default_rng(10 + case)
    q, qd = random_configuration(model, rng), rng.normal(size=model.nv)
    idx = [model.body_index(n) for n in names]
    R, p, w, v = BodyStates(model, idx)(q, qd)
    kin = kinematics(model, q, qd)
    scale = max(1.0, np.abs(kin.p).max())
    np.testing.assert_allclose(R, kin.R[idx], rtol=0, atol=10 * EPS)
    np.testing.assert_allclose(p, kin.p[idx], rtol=0, atol=10 * EPS * scale)
    vel = np.abs(qd).max() * scale
    np.testing.assert_allclose(w, rotate(kin.R[idx], kin.v[idx, :3]), rtol=0,
                               atol=100 * EPS * vel)
    np.testing.assert_allclose(v, rotate(kin.R[idx], kin.v[idx, 3:]), rtol=0,
                               atol=100 * EPS * vel)


def test_body_velocities_are_derivatives_of_the_poses():
    """Central differences of the poses along ``q ⊕ h qd`` (the integrators'
    position update; ball and free joints turn by exp(w h) in the body frame)
    converge to ``w`` and ``v`` at second order."""
    model, _ = humanoid()
    rng = np.random.default_rng(3)
    q, qd = random_configuration(model, rng), rng.normal(size=model.nv)
    idx = [model.body_index(n) for n in ("lfingers", "head", "rtoes", "pelvis", "lthumb")]
    states = BodyStates(model, idx)
    R, p, w, v = states(q, qd)

    def errors(h):
        Rp, pp = states(integrate_configuration(model, q, qd, h), qd)[:2]
        Rm, pm = states(integrate_configuration(model, q, qd, -h), qd)[:2]
        Wfd = (Rp - Rm) / (2 * h) @ np.swapaxes(R, 1, 2)        # skew(w), world axes
        return (np.abs(Wfd - skew(w)).max() / np.abs(w).max(),
                np.abs((pp - pm) / (2 * h) - v).max() / np.abs(v).max())

    h = 1e-4
    coarse, fine = np.array(errors(2 * h)), np.array(errors(h))
    assert np.all(fine < 1e-6)
    assert np.all((coarse / fine > 3.5) & (coarse / fine < 4.5))   # O(h^2): truncation only


# --- springs and strings -------------------------------------------------------------

def tip_spring(model, **options):
    return Springs(model, ["link3"], [[0.01, 0.02, -0.08]], [[0.2, -0.1, -0.15]], 40.0,
                   **options)


def generalised_force_check(model, element, q, qd, h=1e-5):
    """``qdd`` with the element's wrench vs with ``tau = -dE/dq`` by central
    differences (revolute q); returns the relative difference and its bound."""
    forces = Forces(model, [element])
    states = BodyStates(model, element.bodies)
    zero = np.zeros(model.nv)

    def energy(x):
        return element.energy(0.0, states(x, zero))

    grad = np.array([(energy(q + h * e) - energy(q - h * e)) / (2 * h) for e in np.eye(model.nv)])
    base = vdad.forward_dynamics(model, q, qd)
    a_wrench = vdad.forward_dynamics(model, q, qd, f_ext=forces.external(0.0, q, qd)) - base
    a_grad = vdad.forward_dynamics(model, q, qd, tau=-grad) - base
    bound = 10 * np.linalg.cond(crba(model, q)) * (h**2 + EPS / h)
    return np.abs(a_wrench - a_grad).max() / np.abs(a_grad).max(), bound


@pytest.mark.parametrize("rest_length", [0.0, 0.1])
def test_springs_are_conservative(rest_length):
    scene = pendulum(n_bodies=4, axes="alternate")
    rng = np.random.default_rng(4)
    q, qd = rng.uniform(-1, 1, scene.model.nv), rng.normal(size=scene.model.nv)
    spring = tip_spring(scene.model, rest_length=rest_length)
    error, bound = generalised_force_check(scene.model, spring, q, qd)
    assert error < bound


def test_strings_pull_only_while_taut():
    model = pendulum(n_bodies=4, axes="alternate").model
    rng = np.random.default_rng(5)
    q, qd = rng.uniform(-1, 1, model.nv), rng.normal(size=model.nv)
    states = BodyStates(model, [model.body_index("link3")])(q, qd)
    L = tip_spring(model).lengths(0.0, states)[0]
    slack = tip_spring(model, rest_length=1.5 * L, string=True)
    assert np.all(slack.wrenches(0.0, states) == 0.0)
    assert slack.energy(0.0, states) == 0.0
    taut = tip_spring(model, rest_length=0.5 * L, string=True)
    spring = tip_spring(model, rest_length=0.5 * L)
    np.testing.assert_array_equal(taut.wrenches(0.0, states), spring.wrenches(0.0, states))
    assert taut.energy(0.0, states) == spring.energy(0.0, states) > 0
    error, bound = generalised_force_check(model, taut, q, qd)
    assert error < bound
    # a damped string closing faster than its stretch pulls would push: clamped to zero
    R, p, w, v = states
    x = p + rotate(R, taut.points)
    u = (x - taut.anchors) / L
    rushing = (R, p, np.zeros_like(w), -u * 100.0)              # origin moving to the anchor
    damped = tip_spring(model, rest_length=0.5 * L, string=True, damping=10.0)
    assert np.all(damped.wrenches(0.0, rushing) == 0.0)
    pulling = (R, p, np.zeros_like(w), u * 0.1)                  # moving away: k e + c Ldot
    F = damped.wrenches(0.0, pulling)[0, 3:]
    np.testing.assert_allclose(F, -(40.0 * 0.5 * L + 10.0 * 0.1) * u[0], rtol=1e-12)


def test_spring_force_and_torque_about_the_centre_of_mass():
    """The wrench is the force at the attachment point moved to the centre of mass."""
    model = free_body(com=(0.1, -0.2, 0.05))
    q, qd = free_state((0.3, 0.1, 1.0), rotvec=(0.4, -0.3, 0.8))
    spring = Springs(model, "body", (0.2, 0.1, -0.1), (0.0, 0.0, 2.0), 25.0, rest_length=0.4)
    kin = kinematics(model, q, qd)
    x = kin.p[0] + kin.R[0] @ spring.points[0]
    c = kin.p[0] + kin.R[0] @ model.com[0]
    d = x - spring.anchors[0]
    F = -25.0 * (np.linalg.norm(d) - 0.4) * d / np.linalg.norm(d)
    W = Forces(model, [spring]).external(0.0, q, qd)
    np.testing.assert_allclose(W[0], np.concatenate([np.cross(x - c, F), F]), rtol=1e-13,
                               atol=1e-13 * np.abs(F).max())


def energy_drift(dt, t_end=0.4):
    """Maximal |E(t) - E(0)| of one undamped toy dog on two undamped springs (rk4),
    and the largest kinetic energy seen (the scale of the motion)."""
    scene = hanging_dogs(n_dogs=1, spring_damping=0.0, torque=0.0)
    model = Model(scene.model.bodies,
                  [dataclasses.replace(jt, damping=0.0) for jt in scene.model.joints],
                  gravity=scene.model.gravity, name="undamped_dog")
    s = scene.forces.elements[0]
    springs = Springs(model, s.bodies, s.points, s.anchors, s.stiffness, 0.0, s.rest_length)
    forces = Forces(model, [springs])

    def energy(t, q, qd):
        return (kinetic_energy(model, q, qd) + potential_energy(model, q)
                + forces.potential_energy(t, q))

    sim = vdad.Simulator(model, scene.q0, scene.qd0, dt=dt, integrator="rk4",
                         external=forces.external)
    E0, drift, motion = energy(0.0, sim.q, sim.qd), 0.0, 0.0
    for _ in range(8):
        sim.step(int(round(t_end / dt / 8)))
        drift = max(drift, abs(energy(sim.t, sim.q, sim.qd) - E0))
        motion = max(motion, kinetic_energy(model, sim.q, sim.qd))
    return drift, motion


def test_energy_is_conserved_with_undamped_springs():
    """Total energy (kinetic, gravity, joint springs, the springs of vdad.forces)
    of a twisted dog spinning on its springs drifts at RK4's order."""
    coarse, motion = energy_drift(1e-2)
    fine, _ = energy_drift(5e-3)
    assert motion > 0.1                                      # it really spins (J)
    assert fine < 1e-5 * motion
    assert coarse / fine > 8                                 # fourth order: 16


def test_moving_anchor_damping_uses_the_anchor_velocity():
    """A point moving with its anchor at rest length feels nothing, however damped;
    a point at rest while the anchor moves feels the damper."""
    model = free_body(name="carried")
    V, t0, L0 = np.array([0.3, -0.2, 0.5]), 0.7, 0.25
    point, u = np.array([0.05, 0.1, -0.02]), np.array([2.0, -1.0, 2.0]) / 3.0
    q, qd = free_state((0.2, 0.4, 1.0), rotvec=(0.3, 0.2, -0.5), v=V)
    R = quat_to_rot(q[3:])
    x0 = q[:3] + R @ point

    def anchors(t):
        return (x0 - L0 * u + V * (t - t0))[None]

    spring = Springs(model, ["body"], [point], anchors, stiffness=500.0, damping=30.0,
                     rest_length=L0)
    forces = Forces(model, [spring])
    a, va = spring.anchor_state(t0)
    np.testing.assert_allclose(va[0], V, rtol=1e-9)          # central difference of a line
    W = forces.external(t0, q, qd)
    bound = 100 * EPS * (500.0 * np.abs(x0).max() + 30.0 * np.abs(x0).max() / 1e-4)
    assert np.abs(W).max() < bound
    at_rest = forces.external(t0, q, np.zeros(6))
    np.testing.assert_allclose(at_rest[0, 3:], -30.0 * (u @ -V) * u, rtol=1e-8)
    assert spring.energy(t0, forces.states_of(spring, q, qd)) < 1e-20


def test_damping_acts_on_the_rate_of_change_of_length():
    """The damper's part of the force is ``-c dL/dt u``, with dL/dt by central
    differences of the length along ``q ⊕ h qd`` and the anchors' path
    (turning bodies, ball and free joints, a moving anchor)."""
    model, _ = humanoid()
    rng = np.random.default_rng(8)
    q, qd = random_configuration(model, rng), rng.normal(size=model.nv)
    names, points = ["lhand", "head"], [[0.02, -0.01, -0.06], [0.05, 0.03, 0.1]]

    def anchors(t):
        return np.array([[0.3 * np.sin(2 * t), 0.2, 1.5], [0.1, -0.4 + t**2, 2.0]])

    t0, c = 0.3, np.array([4.0, 7.0])
    damped = Springs(model, names, points, anchors, 50.0, damping=c, rest_length=0.1)
    elastic = Springs(model, names, points, anchors, 50.0, rest_length=0.1)
    states = BodyStates(model, damped.bodies)

    def length(h):
        return damped.lengths(t0 + h, states(integrate_configuration(model, q, qd, h), qd))

    h = 1e-5
    Ldot = (length(h) - length(-h)) / (2 * h)
    s = states(q, qd)
    R, p = s[:2]
    d = p + rotate(R, damped.points) - damped.anchor_state(t0)[0]
    u = d / np.linalg.norm(d, axis=1)[:, None]
    F = damped.wrenches(t0, s)[:, 3:] - elastic.wrenches(t0, s)[:, 3:]
    np.testing.assert_allclose(F, -(c * Ldot)[:, None] * u, rtol=0,
                               atol=1e-6 * np.abs(c * Ldot).max())
    assert np.all(np.abs(Ldot) > 0.1)


# --- random torques ------------------------------------------------------------------

def test_random_torques_repeat_whatever_the_call_order():
    model = pendulum(5).model
    times = np.linspace(-0.5, 30.0, 3001)
    a = RandomTorques(model, np.arange(5), 0.3, rate=2.0, duration=0.1, seed=7)
    reference = np.array([a.torques(t) for t in times])
    b = RandomTorques(model, np.arange(5), 0.3, rate=2.0, duration=0.1, seed=7)
    order = np.random.default_rng(0).permutation(len(times))
    shuffled = np.empty_like(reference)
    for i in order:
        shuffled[i] = b.torques(times[i])
    np.testing.assert_array_equal(shuffled, reference)
    np.testing.assert_array_equal([a.torques(t) for t in times[::-1]], reference[::-1])
    other = RandomTorques(model, np.arange(5), 0.3, rate=2.0, duration=0.1, seed=8)
    assert not np.array_equal([other.torques(t) for t in times], reference)
    assert np.count_nonzero(np.abs(reference).sum(axis=2)) > 100   # pulses happen
    assert np.all(reference[times < 0] == 0.0)


@pytest.mark.parametrize("duration", [0.1, 1.7])
def test_random_torques_are_the_sum_of_the_active_pulses(duration):
    """Brute force over every window: a pulse acts during [start, start + duration),
    with norm ``magnitude``, on one body; the force part is zero."""
    model = pendulum(3).model
    pulses = RandomTorques(model, [2, 0], 0.4, rate=1.5, duration=duration, seed=3)
    T = 12
    rows, starts, taus = (np.concatenate(a) for a in zip(*[pulses.pulses(w) for w in range(T)],
                                                         strict=True))
    np.testing.assert_allclose(np.linalg.norm(taus, axis=1), 0.4, rtol=1e-14)
    assert np.all((starts >= 0) & (starts < T))
    times = np.random.default_rng(1).uniform(0.0, T, 400)
    times = np.concatenate([times, starts, starts + duration, starts + duration / 2])
    times = times[times < T]
    for t in times:
        on = (starts <= t) & (t < starts + duration)
        expected = np.zeros((2, 3))
        np.add.at(expected, rows[on], taus[on])
        W = pulses.wrenches(t)
        np.testing.assert_allclose(W[:, :3], expected, rtol=0, atol=1e-15)
        assert np.all(W[:, 3:] == 0.0)
        if np.count_nonzero(on) == 1:                            # one pulse: |tau| = magnitude
            assert np.linalg.norm(W[rows[on][0], :3]) == pytest.approx(0.4, rel=1e-14)


def test_random_torque_pulses_are_poisson():
    """Over T s the pulse count on k bodies has mean and variance rate T k."""
    model = pendulum(4).model
    pulses = RandomTorques(model, np.arange(4), 1.0, rate=2.5, duration=0.1, seed=11)
    T = 1000
    counts = np.array([len(pulses.pulses(w)[0]) for w in range(T)])
    mean = 2.5 * 4
    assert abs(counts.sum() - mean * T) < 5 * np.sqrt(mean * T)
    assert abs(counts.var() / mean - 1) < 0.25
    rows = np.concatenate([pulses.pulses(w)[0] for w in range(T)])
    assert np.all(np.abs(np.bincount(rows, minlength=4) - mean * T / 4)
                  < 5 * np.sqrt(mean * T / 4))                  # bodies hit evenly


# --- drag ----------------------------------------------------------------------------

def drag_body():
    return free_body(mass=1.7, com=(0.1, -0.05, 0.2),
                     inertia=random_inertia(np.random.default_rng(2), 0.2),
                     gravity=(0.0, 0.0, 0.0), name="dragged")


def test_drag_wrench():
    model = drag_body()
    q, qd = free_state((0.3, -0.2, 1.1), rotvec=(0.5, -1.0, 0.3), v=(0.4, -0.7, 1.2),
                       w=(2.0, -1.0, 3.0))
    kin = kinematics(model, q, qd)
    R = kin.R[0]
    w = R @ kin.v[0, :3]
    v_com = R @ (kin.v[0, 3:] + np.cross(kin.v[0, :3], model.com[0]))
    expected = -2.5 * np.concatenate([R @ model.inertia[0] @ R.T @ w, model.mass[0] * v_com])
    W = Forces(model, [Drag(model, 2.5)]).external(0.0, q, qd)
    np.testing.assert_allclose(W[0], expected, rtol=1e-13, atol=1e-13 * np.abs(expected).max())


def test_drag_decays_free_motion_exponentially():
    """Without gravity, momentum and angular momentum about the centre of mass
    decay as exp(-rate t) exactly (as vectors, whatever the tumbling): RK4 error only."""
    model, rate = drag_body(), 2.0
    q, qd = free_state((0.0, 0.0, 0.0), rotvec=(0.5, -1.0, 0.3), v=(0.4, -0.7, 1.2),
                       w=(2.0, -4.0, 3.0))

    def momenta(q, qd):
        kin = kinematics(model, q, qd)
        R, w = kin.R[0], kin.v[0, :3]
        return (model.mass[0] * R @ (kin.v[0, 3:] + np.cross(w, model.com[0])),
                R @ model.inertia[0] @ w)

    sim = vdad.Simulator(model, q, qd, dt=5e-3, integrator="rk4",
                         external=Forces(model, [Drag(model, rate)]).external)
    p0, L0 = momenta(q, qd)
    sim.step(100)
    p1, L1 = momenta(sim.q, sim.qd)
    decay = np.exp(-rate * sim.t)
    assert decay < 0.4                                       # (measured: 5e-10 relative)
    np.testing.assert_allclose(p1, decay * p0, rtol=0, atol=1e-8 * np.abs(p0).max())
    np.testing.assert_allclose(L1, decay * L0, rtol=0, atol=1e-8 * np.abs(L0).max())


# --- contact points ------------------------------------------------------------------

def test_contact_points_of_each_geometry():
    import trimesh

    Rb = quat_to_rot(quat_exp(np.array([0.3, -0.5, 0.9])))
    Rc = quat_to_rot(quat_exp(np.array([1.0, 0.2, 0.0])))
    tetra = trimesh.Trimesh([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1], [0.2, 0.2, 0.2]],
                            [[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]], process=False)
    geoms = {"ball": [Geom("sphere", (0.1,), Pose((0.1, 0.0, -0.2)))],
             "stick": [Geom("capsule", (0.05, 0.2), Pose((0.0, 0.3, 0.0), Rc)),
                       Geom("cylinder", (0.04, 0.1))],
             "brick": [Geom("box", (0.1, 0.2, 0.3), Pose((0.5, 0.0, 0.0), Rb))],
             "rock": [Geom("mesh", mesh=tetra, pose=Pose((0.0, 0.0, 1.0)))],
             "ghost": []}
    bodies = [Body(n, 1.0, geoms=tuple(g)) for n, g in geoms.items()]
    joints = [Joint(n, None, n, "free") for n in geoms]
    model = Model(bodies, joints, name="shapes")
    body, centre, radius = contact_points(model)
    counts = np.bincount(body, minlength=model.nb)
    assert counts.tolist() == [1, 6, 8, 4, 0]
    np.testing.assert_array_equal(centre[body == 0], [[0.1, 0.0, -0.2]])
    assert radius[body == 0].tolist() == [0.1]
    ends = np.array([0.0, 0.3, 0.0]) + np.outer([-1.0, 0.0, 1.0], 0.2 * Rc[:, 2])
    np.testing.assert_allclose(centre[body == 1][:3], ends, atol=1e-15)
    np.testing.assert_allclose(centre[body == 1][3:], [[0, 0, -0.1], [0, 0, 0], [0, 0, 0.1]])
    assert radius[body == 1].tolist() == [0.05] * 3 + [0.04] * 3
    corners = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)])
    expected = np.array([0.5, 0.0, 0.0]) + (corners * (0.1, 0.2, 0.3)) @ Rb.T
    distance = np.abs(centre[body == 2][:, None] - expected[None]).max(axis=2)
    assert distance.min(axis=0).max() < 1e-15 and distance.min(axis=1).max() < 1e-15
    hull = centre[body == 3] - (0.0, 0.0, 1.0)
    assert sorted(map(tuple, np.round(hull, 12))) == [(0, 0, 0), (0, 0, 1), (0, 1, 0),
                                                      (1, 0, 0)]   # interior point dropped
    assert np.all(radius[body >= 2] == 0.0)
    sub = contact_points(model, [2, 0])[0]
    assert sorted(sub.tolist()) == [0] + [2] * 8


def test_contact_points_need_geometry():
    with pytest.raises(ModelError, match="model 'bare' has no geometry"):
        contact_points(free_body(name="bare"))
    with pytest.raises(ModelError, match="model 'bare' has no geometry"):
        FloorContact(free_body(name="bare"))


# --- floor contact -------------------------------------------------------------------

def sphere_on_floor(mass=2.0, radius=0.1):
    return free_body([Geom("sphere", (radius,))], mass=mass,
                     inertia=(0.4 * mass * radius**2,) * 3, name="ball")


def test_sphere_settles_at_the_static_penetration():
    """Dropped 5 cm, a sphere (one contact point, k = m w^2) comes to rest at
    depth m g / k = g / w^2, never pulled down, and stays there."""
    model = sphere_on_floor()
    contact = FloorContact(model, height=0.0, frequency=150.0)
    forces = Forces(model, [contact])
    assert contact.k[0] == pytest.approx(2.0 * 150.0**2)
    lift = []

    def external(t, q, qd):
        f = forces.external(t, q, qd)
        lift.append(f[0, 5])
        return f

    q0, _ = free_state((0.3, -0.2, 0.15))
    sim = vdad.Simulator(model, q0, dt=1e-3, external=external)
    g, m = 9.81, 2.0

    def energy():
        return (kinetic_energy(model, sim.q, sim.qd) + potential_energy(model, sim.q)
                + forces.potential_energy(sim.t, sim.q))

    E0 = energy()
    sim.step(500)
    depth = 0.1 - sim.q[2]
    static = m * g / contact.k[0]
    assert depth == pytest.approx(static, rel=1e-6)
    assert kinetic_energy(model, sim.q, sim.qd) < 1e-12 * m * g * 0.05
    assert E0 - energy() == pytest.approx(m * g * 0.05, rel=0.02)   # the drop was dissipated
    sim.step(300)                                                       # no sinking
    assert 0.1 - sim.q[2] == pytest.approx(static, rel=1e-6)
    np.testing.assert_allclose(sim.q[:2], (0.3, -0.2), atol=1e-12)    # nor sliding
    lift = np.array(lift)
    assert lift.min() >= 0.0 and lift.max() > 2 * m * g               # impact, no suction


def test_floor_force_only_in_contact_and_never_pulls():
    model = sphere_on_floor()
    forces = Forces(model, [FloorContact(model, height=0.5)])
    above = forces.external(0.0, *free_state((0.0, 0.0, 0.601), v=(1.0, 0.0, -5.0)))
    assert np.all(above == 0.0)                                    # 1 mm above, falling
    leaving = forces.external(0.0, *free_state((0.0, 0.0, 0.599), v=(1.0, 0.0, 5.0)))
    assert np.all(leaving == 0.0)                                  # in, but leaving fast
    resting = forces.external(0.0, *free_state((0.0, 0.0, 0.599)))
    k = 2.0 * 150.0**2
    np.testing.assert_allclose(resting[0], [0, 0, 0, 0, 0, k * 1e-3], atol=1e-9 * k * 1e-3)


def test_sliding_box_decelerates_at_mu_g_and_stops():
    """Coulomb friction while fast: dv/dt = -mu g, stopping distance v^2 / (2 mu g);
    then the regularised friction holds it."""
    half, mu, g, v0, w = np.array([0.15, 0.1, 0.05]), 0.8, 9.81, 2.0, 150.0
    m = 1.0
    inertia = m / 3 * np.array([half[1]**2 + half[2]**2, half[0]**2 + half[2]**2,
                                half[0]**2 + half[1]**2])
    model = free_body([Geom("box", tuple(half))], mass=m, inertia=tuple(inertia), name="box")
    forces = Forces(model, [FloorContact(model, frequency=w, friction=mu)])
    depth = m * g / (4 * m * w**2 / 8)                   # 4 of 8 corners carry the box
    q0, qd0 = free_state((0.0, 0.0, half[2] - depth), v=(v0, 0.0, 0.0))
    sim = vdad.Simulator(model, q0, qd0, dt=1e-3, external=forces.external)
    t, x, vx = [], [], []
    for _ in range(500):
        sim.step()
        t.append(sim.t)
        x.append(sim.q[0])
        vx.append(sim.qd[0])
    t, x, vx = map(np.array, (t, x, vx))
    fast = (t > 0.02) & (vx > 0.3)
    slope = np.polyfit(t[fast], vx[fast], 1)[0]
    assert slope == pytest.approx(-mu * g, rel=0.01)
    assert x[-1] == pytest.approx(v0**2 / (2 * mu * g), rel=0.01)
    assert abs(vx[-1]) < 1e-3
    sim.step(200)
    assert abs(sim.q[0] - x[-1]) < 1e-4 and abs(sim.qd[0]) < 1e-4
    assert abs(sim.q[2] - q0[2]) < 0.1 * depth                       # still on its face


# --- joint limits --------------------------------------------------------------------

def limited_model():
    stages = (vdad.joints.Stage("hinge", (1, 0, 0)), vdad.joints.Stage("hinge", (0, 1, 0)))
    bodies = [Body("base", 2.0, (0, 0, -0.2), (0.05, 0.05, 0.02)),
              Body("arm", 0.5, (0, 0, -0.15), (0.004, 0.004, 0.001)),
              Body("slider", 0.3, (0, 0, 0), (0.001, 0.001, 0.001)),
              Body("gimbal", 0.2, (0, 0, -0.05), (0.001, 0.001, 0.001)),
              Body("flyer", 1.0)]
    joints = [Joint("hinge", None, "base", "revolute", axis=(0, 1, 0)),
              Joint("ball", "base", "arm", "spherical", placement=Pose((0, 0, -0.4))),
              Joint("slide", "base", "slider", "prismatic", axis=(1, 0, 0)),
              Joint("composite", "base", "gimbal", "composite", stages=stages),
              Joint("free", None, "flyer", "free")]
    return Model(bodies, joints, name="limited")


def test_hinge_limits():
    model = limited_model()
    limits = JointLimits(model, {"hinge": (-0.5, 1.0), "slide": (0.0, 0.2)}, frequency=30.0,
                         damping_ratio=0.8)
    I_h, m_s = joint_inertia(model, 0), joint_inertia(model, 2, "mass")
    k, c = I_h * 30.0**2, 2 * 0.8 * I_h * 30.0
    assert m_s == 0.3
    ih, isl = model.v_start[0], model.v_start[2]
    q = np.array(model.q_neutral)

    def tau(angle, rate, slide=0.1, slide_rate=0.0):
        q[model.q_start[0]], q[model.q_start[2]] = angle, slide
        qd = np.zeros(model.nv)
        qd[ih], qd[isl] = rate, slide_rate
        out = np.zeros(model.nv)
        limits.tau(0.0, q, qd, out)
        return out

    assert np.all(tau(0.3, 5.0) == 0.0) and np.all(tau(-0.5, -5.0) == 0.0)   # inside
    out = tau(1.2, -3.0)                                         # above, moving back in
    assert out[ih] == pytest.approx(-k * 0.2, rel=1e-12)
    assert np.count_nonzero(out) == 1
    assert tau(1.2, 3.0)[ih] == pytest.approx(-k * 0.2 - c * 3.0, rel=1e-12)  # going out
    assert tau(-0.8, 2.0)[ih] == pytest.approx(k * 0.3, rel=1e-12)
    assert tau(-0.8, -2.0)[ih] == pytest.approx(k * 0.3 + c * 2.0, rel=1e-12)
    out = tau(0.0, 0.0, slide=0.25, slide_rate=-1.0)
    assert out[isl] == pytest.approx(-0.3 * 30.0**2 * 0.05, rel=1e-12)
    q[model.q_start[0]], q[model.q_start[2]] = 1.2, -0.1
    assert limits.energy(q) == pytest.approx(k * 0.2**2 / 2 + 0.3 * 900 * 0.1**2 / 2, rel=1e-12)


def test_composite_joint_limits_act_per_stage():
    """A composite joint's stages (MuJoCo's multi-joint bodies) are limited one by
    one, each at its own q and dof, as a one-dof joint would be; None: no limit."""
    model = limited_model()
    limits = JointLimits(model, {"composite": ((-0.2, 0.2), None)}, frequency=30.0)
    k = joint_inertia(model, 3) * 30.0**2
    j = 3
    iq, iv = model.q_start[j], model.v_start[j]
    q, qd = np.array(model.q_neutral), np.zeros(model.nv)
    q[iq], q[iq + 1] = 0.5, 7.0                          # stage 0 past 0.2; stage 1 free
    out = np.zeros(model.nv)
    limits.tau(0.0, q, qd, out)
    assert out[iv] == pytest.approx(-k * 0.3, rel=1e-12) and np.count_nonzero(out) == 1
    assert limits.energy(q) == pytest.approx(k * 0.3**2 / 2, rel=1e-12)


def test_ball_joint_cone():
    """Beyond the cone the torque is -(k e + c outward rate) along the rotation
    axis, and -grad of the energy k e^2 / 2 (body-frame finite differences)."""
    model = limited_model()
    limits = JointLimits(model, {"ball": 0.6}, frequency=40.0, damping_ratio=0.5)
    I_b = joint_inertia(model, 1)
    k, c = I_b * 40.0**2, 2 * 0.5 * I_b * 40.0
    iq, iv = model.q_start[1], model.v_start[1]
    axis = np.array([0.48, -0.6, 0.64])
    q = np.array(model.q_neutral)
    qd = np.zeros(model.nv)

    def tau(angle, w):
        q[iq:iq + 4] = quat_exp(angle * axis)
        qd[iv:iv + 3] = w
        out = np.zeros(model.nv)
        limits.tau(0.0, q, qd, out)
        return out

    assert np.all(tau(0.55, 3 * axis) == 0.0)                           # inside the cone
    out = tau(0.9, np.zeros(3))
    np.testing.assert_allclose(out[iv:iv + 3], -k * 0.3 * axis, rtol=1e-12)
    assert np.all(np.delete(out, np.arange(iv, iv + 3)) == 0.0)
    across = np.cross(axis, [1.0, 0.0, 0.0])
    np.testing.assert_allclose(tau(0.9, across - 2 * axis)[iv:iv + 3], -k * 0.3 * axis,
                               rtol=1e-12)                                # moving back in
    np.testing.assert_allclose(tau(0.9, across + 2 * axis)[iv:iv + 3],
                               -(k * 0.3 + c * 2.0) * axis, rtol=1e-12)  # moving out
    q[iq:iq + 4] = quat_exp(0.9 * axis)
    h = 1e-6
    for i in range(3):
        e = np.zeros(model.nv)
        e[iv + i] = 1.0
        dE = (limits.energy(integrate_configuration(model, q, e, h))
              - limits.energy(integrate_configuration(model, q, e, -h))) / (2 * h)
        assert dE == pytest.approx(k * 0.3 * axis[i], abs=1e-7 * k)


def test_joint_limit_errors():
    model = limited_model()
    with pytest.raises(ModelError, match="no joint called 'elbow'"):
        JointLimits(model, {"elbow": (0.0, 1.0)})
    with pytest.raises(InputError, match="joint 'hinge': limit low 1.0 > high -1.0"):
        JointLimits(model, {"hinge": (1.0, -1.0)})
    with pytest.raises(ModelError, match="joint 'free': limits need a one-dof, ball or "
                                         "composite hinge and slide joint"):
        JointLimits(model, {"free": 0.5})
    with pytest.raises(InputError, match="limits\\['composite'\\]: a composite joint of 2 "
                                         "stages takes one \\(low, high\\) or None per stage"):
        JointLimits(model, {"composite": 0.5})
    with pytest.raises(InputError, match="limits\\['ball'\\]: a ball joint takes one cone"):
        JointLimits(model, {"ball": (0.1, 0.5)})
    with pytest.raises(InputError, match="limits\\['hinge'\\]: a one-dof joint takes \\(low"):
        JointLimits(model, {"hinge": 0.5})                     # not a hinge locked at 0.5
    with pytest.raises(InputError, match="limits\\['ball'\\] must be positive"):
        JointLimits(model, {"ball": -0.5})
    with pytest.raises(InputError, match="limits\\['hinge'\\] must be finite"):
        JointLimits(model, {"hinge": (0.0, np.nan)})
    with pytest.raises(InputError, match="frequency must be positive"):
        JointLimits(model, {"hinge": (0.0, 1.0)}, frequency=0.0)


def test_joint_inertia_is_the_lighter_side():
    """A rod about its end, m (3 r^2 + L^2)/12 + m (L/2)^2; a heavy body on a light
    one: the parent's largest moment about the joint (parallel axes)."""
    model = pendulum(3, link_length=0.5, link_mass=2.0).model
    r, L, m = 0.05, 0.5, 2.0
    expected = m * (3 * r**2 + L**2) / 12 + m * (L / 2) ** 2
    for j in range(3):
        assert joint_inertia(model, j) == pytest.approx(expected, rel=1e-12)
        assert joint_inertia(model, j, "mass") == m
    model = Model([Body("light", 0.2, (0, 0, -0.1), (0.003, 0.002, 0.001)),
                   Body("heavy", 5.0, (0, 0, -0.2), (0.05, 0.04, 0.03))],
                  [Joint("top", None, "light", axis=(1, 0, 0)),
                   Joint("knee", "light", "heavy", axis=(1, 0, 0), placement=Pose((0, 0, -0.3)))])
    assert joint_inertia(model, 1) == pytest.approx(0.003 + 0.2 * 0.2**2, rel=1e-12)
    assert joint_inertia(model, 1, "mass") == 0.2
    assert joint_inertia(model, 0) == pytest.approx(0.003 + 0.2 * 0.1**2, rel=1e-12)


# --- the sum of forces ---------------------------------------------------------------

def test_forces_sum_their_elements():
    model = pendulum(n_bodies=4, axes="alternate").model
    rng = np.random.default_rng(6)
    q, qd = rng.uniform(-1, 1, model.nv), rng.normal(size=model.nv)
    s1 = Springs(model, ["link3", "link1"], [[0, 0, -0.1], [0.01, 0, -0.05]],
                 lambda t: np.array([[0.1 * t, 0.2, -0.3], [0.0, -0.1, 0.05]]), [30.0, 10.0],
                 damping=0.5, rest_length=0.05)
    s2 = Springs(model, [3, 2, 3], [[0.01, 0.02, -0.08]] * 3, [[0.2, -0.1, -0.15]] * 3,
                 20.0, damping=[0.1, 0.2, 0.3])
    both = Forces(model, [s1, s2]).external(0.4, q, qd)
    one, two = (Forces(model, [s]).external(0.4, q, qd) for s in (s1, s2))
    np.testing.assert_allclose(both, one + two, rtol=0, atol=10 * EPS * np.abs(both).max())
    kin = kinematics(model, q, qd)
    idx = s1.bodies
    states = (kin.R[idx], kin.p[idx], rotate(kin.R[idx], kin.v[idx, :3]),
              rotate(kin.R[idx], kin.v[idx, 3:]))
    np.testing.assert_allclose(one[idx], s1.wrenches(0.4, states), rtol=1e-13)
    assert np.all(one[[0, 2]] == 0.0)
    assert np.all(two[[0, 1]] == 0.0)
    np.testing.assert_allclose(two[3], s2.wrenches(0.4, Forces(model, [s2]).states_of(
        s2, q, qd))[[0, 2]].sum(axis=0), rtol=1e-13)


def test_forces_callables_and_potential_energy():
    model, limit_table = humanoid()
    limits = JointLimits(model, limit_table)
    contact = FloorContact(model, height=0.3)
    springs = Springs(model, ["head", "lhand"], [[0, 0, 0.1], [0, 0, -0.05]],
                      [[0, 0, 2.5], [0.5, 0.5, 1.0]], 80.0, rest_length=0.2)
    pulses = RandomTorques(model, ["thorax"], 2.0, rate=5.0, seed=1)
    assert Forces(model, [limits]).external is None
    assert Forces(model, [springs, contact]).controller is None
    rng = np.random.default_rng(7)
    q, qd = random_configuration(model, rng), rng.normal(size=model.nv)
    q[:3] = (0.0, 0.0, 0.5)                                 # pelvis low: bodies in the floor
    forces = Forces(model, [springs, contact, limits, pulses])
    zero = np.zeros(model.nv)
    parts = [springs.energy(0.0, BodyStates(model, springs.bodies)(q, zero)),
             contact.energy(0.0, BodyStates(model, contact.bodies)(q, zero)), limits.energy(q)]
    assert all(e > 0 for e in parts)
    assert forces.potential_energy(0.0, q) == pytest.approx(sum(parts), rel=1e-13)
    tau = np.zeros(model.nv)
    limits.tau(0.0, q, qd, tau)
    np.testing.assert_array_equal(forces.controller(0.0, q, qd), tau)
    t = 0.37
    total = forces.external(t, q, qd)
    without = Forces(model, [springs, contact]).external(t, q, qd)
    thorax = model.body_index("thorax")
    np.testing.assert_allclose(total[thorax, :3] - without[thorax, :3], pulses.torques(t)[0],
                               atol=1e-12)
    only_pulses = Forces(model, [pulses]).external(t, q, qd)
    assert np.all(np.delete(only_pulses, thorax, axis=0) == 0.0)


def test_forces_reject_elements_of_another_model():
    a, b = pendulum(3).model, pendulum(3).model
    with pytest.raises(InputError, match="Springs was built for another model than 'pendulum3'"):
        Forces(b, [Springs(a, [2], [[0, 0, 0]], [[0, 0, 1]], 1.0)])


# --- bad inputs ----------------------------------------------------------------------

def test_bad_inputs_name_the_argument():
    model = pendulum(3).model
    ok = dict(bodies=["link2"], points=[[0, 0, -0.1]], anchors=[[0, 0, 0.5]], stiffness=10.0)

    def springs(**changes):
        return Springs(model, **{**ok, **changes})

    with pytest.raises(ModelError, match="no body called 'nose' in model 'pendulum3'"):
        springs(bodies=["nose"])
    with pytest.raises(InputError, match="bodies: 7 is neither a body name nor a body index"):
        springs(bodies=[7])
    with pytest.raises(InputError, match=r"points must have shape \(1, 3\).*got \(2, 2\)"):
        springs(points=[[0, 0], [1, 1]])
    with pytest.raises(InputError, match=r"anchors must have shape \(1, 3\)"):
        springs(anchors=[[0, 0, 0, 1]])
    with pytest.raises(InputError, match="anchors must be finite"):
        springs(anchors=[[0, np.nan, 0]])
    with pytest.raises(InputError, match="stiffness must be >= 0"):
        springs(stiffness=-1.0)
    with pytest.raises(InputError, match="damping must be >= 0"):
        springs(damping=-0.1)
    with pytest.raises(InputError, match="rest_length must be >= 0"):
        springs(rest_length=[-0.1])
    broken = springs(anchors=lambda t: np.array([[0.0, 0.0, np.nan if t > 0.55 else 0.5]]))
    forces = Forces(model, [broken])
    forces.external(0.2, model.q_neutral, np.zeros(model.nv))
    with pytest.raises(InputError, match=r"anchors\(t\) must be finite"):
        forces.external(0.6, model.q_neutral, np.zeros(model.nv))
    sim = vdad.Simulator(model, dt=0.1, external=forces.external)
    with pytest.raises(vdad.SimulationError, match=r"step 7 .*anchors\(t\) must be finite"):
        sim.step(10)
    with pytest.raises(InputError, match=r"anchors\(t\) must have shape \(1, 3\)"):
        springs(anchors=lambda t: np.zeros((2, 3))).anchor_state(0.0)
    with pytest.raises(InputError, match="magnitude must be >= 0"):
        RandomTorques(model, [0], -1.0)
    with pytest.raises(InputError, match="duration must be positive"):
        RandomTorques(model, [0], 1.0, duration=0.0)
    with pytest.raises(InputError, match="seed must be an integer >= 0"):
        RandomTorques(model, [0], 1.0, seed=1.5)
    with pytest.raises(InputError, match="rate must be >= 0"):
        Drag(model, -1.0)
    with pytest.raises(InputError, match="friction must be >= 0"):
        FloorContact(model, friction=-0.1)
    with pytest.raises(InputError, match="frequency must be positive"):
        FloorContact(model, frequency=0.0)
    with pytest.raises(InputError, match="height must be finite"):
        FloorContact(model, height=np.inf)


# --- the campaign's bad inputs: vdad errors naming the culprit ------------------------

SPRING = dict(points=[[0, 0, -0.1]], anchors=[[0, 0, 0.5]], stiffness=10.0)


@pytest.mark.parametrize("bodies, message", [
    ([True], "bodies: True is neither a body name nor a body index"),
    ([np.bool_(False)], "bodies: (np.)?False_? is neither a body name nor a body index"),
    ([1.5], "bodies: 1.5 is neither a body name nor a body index"),
    ([-1], "bodies: -1 is neither a body name nor a body index of 'pendulum3' \\(0..2\\)"),
    ([None], "bodies: None is neither"),
    (None, "bodies must be a body name or index or a list of them, got NoneType"),
    ({0}, "bodies must be a body name or index or a list of them, got set"),
    ([], "bodies is empty: give at least one body of 'pendulum3'"),
])
def test_bodies_must_be_names_or_whole_indices_in_range(bodies, message):
    model = pendulum(3).model
    with pytest.raises(InputError, match=message):
        Springs(model, bodies, **SPRING)


def test_bodies_accept_names_whole_numbers_and_arrays():
    model = pendulum(3).model
    for bodies in ("link2", 2, np.int64(2), 2.0, [2], np.array([2]), ["link2"]):
        assert Springs(model, bodies, **SPRING).bodies.tolist() == [2]
    assert Drag(model, 1.0, bodies=range(3)).bodies.tolist() == [0, 1, 2]
    assert BodyStates(model, ["link1", 0]).rows.tolist() == [1, 0]


@pytest.mark.parametrize("build", [
    lambda m: BodyStates(m, [0]),
    lambda m: Springs(m, [0], **SPRING),
    lambda m: RandomTorques(m, [0], 1.0),
    lambda m: Drag(m, 1.0),
    lambda m: FloorContact(m),
    lambda m: JointLimits(m, {"joint0": (0, 1)}),
    lambda m: Forces(m, []),
    lambda m: contact_points(m),
    lambda m: joint_inertia(m, 0),
])
@pytest.mark.parametrize("model", ["m", None, 3])
def test_constructors_check_the_model(build, model):
    with pytest.raises(InputError, match="model must be a vdad.Model, got "
                       + type(model).__name__):
        build(model)


def test_random_torque_rate_is_bounded():
    from vdad.forces import MAX_PULSE_RATE

    model = pendulum(3).model
    with pytest.raises(InputError, match=r"rate = 1e\+30 pulses per second on each of 1 body "
                       r"is too high: rate \* len\(bodies\) must be at most 1e\+06"):
        RandomTorques(model, [0], 1.0, rate=1e30)
    with pytest.raises(InputError, match="on each of 3 bodies is too high"):
        RandomTorques(model, [0, 1, 2], 1.0, rate=MAX_PULSE_RATE / 2)
    pulses = RandomTorques(model, [0], 1.0, rate=MAX_PULSE_RATE, duration=1e-7)
    assert np.all(np.isfinite(pulses.torques(0.5)))
    long = RandomTorques(model, [0], 1.0, rate=2.0, duration=1e30)   # windows from 0 only
    assert np.all(np.isfinite(long.torques(2.5)))
    with pytest.raises(InputError, match="rate must be finite"):
        RandomTorques(model, [0], 1.0, rate=np.inf)


@pytest.mark.parametrize("limits, message", [
    ([("joint0", (0, 1))], "limits must be a dict {joint name: .*got list"),
    (None, "limits must be a dict {joint name: .*got NoneType"),
    ("joint0", "limits must be a dict {joint name: .*got str"),
    ({0: (0, 1)}, "limits: keys must be joint names, got 0"),
    ({"joint0": [[0], [1, 2]]}, "limits\\['joint0'\\] must be a real number .*ragged"),
    ({"joint0": "ab"}, "limits\\['joint0'\\] must be a real number .*a string"),
    ({"joint0": (True, 1)}, "limits\\['joint0'\\] must be a real number"),
])
def test_joint_limits_need_a_dict_of_joint_names(limits, message):
    with pytest.raises(InputError, match=message):
        JointLimits(pendulum(3).model, limits)


class Pusher:
    """A force element from outside the module: a constant push on one body."""

    def __init__(self, bodies):
        self.bodies = bodies

    def wrenches(self, t, states):
        return np.tile([0.0, 0.0, 0.0, 1.0, 0.0, 0.0], (len(self.bodies), 1))


def test_forces_need_a_list_of_force_elements():
    model = pendulum(3).model
    drag = Drag(model, 1.0)
    for elements, what in ((drag, "Drag"), (None, "NoneType"), ("drag", "str"),
                           (iter([drag]), "list_iterator")):
        with pytest.raises(InputError, match="elements must be a list or tuple of force "
                           f"elements, got {what}"):
            Forces(model, elements)
    for bad, what in ((5, "int: 5"), (None, "NoneType"), ("drag", "str"), (Drag, "type"),
                      (np.zeros(3), "ndarray")):
        with pytest.raises(InputError, match=r"elements\[1\] is not a force element \(an object "
                           f"with wrenches.*got {what}"):
            Forces(model, [drag, bad])
    with pytest.raises(InputError, match=r"elements\[0\].bodies: 7 is neither a body name"):
        Forces(model, [Pusher([7])])
    forces = Forces(model, (drag, Pusher(np.array([2]))))         # a tuple, a foreign element
    f = forces.external(0.0, model.q_neutral, np.zeros(model.nv))
    assert f[2, 3] == 1.0 and np.all(f[:2] == 0.0)
    assert Forces(model, []).external is None


def test_contact_points_and_joint_inertia_check_their_arguments():
    model = pendulum(3).model
    with pytest.raises(InputError, match="bodies: 9 is neither a body name nor a body index"):
        contact_points(model, bodies=[9])
    with pytest.raises(InputError, match="bodies is empty"):
        contact_points(model, bodies=[])
    assert contact_points(model, bodies=["link1"])[0].tolist() == [1, 1, 1]
    for j in (9, -1, True, 0.5, None, (0,)):
        with pytest.raises(InputError, match="j: .* is neither a joint name nor a joint index "
                           "of 'pendulum3' \\(0..2\\)"):
            joint_inertia(model, j)
    with pytest.raises(ModelError, match="no joint called 'knee'"):
        joint_inertia(model, "knee")
    assert joint_inertia(model, "joint1") == joint_inertia(model, 1) == joint_inertia(model, 1.0)
    for kind in ("volume", None, "Mass"):
        with pytest.raises(InputError, match="kind must be 'inertia' or 'mass', got"):
            joint_inertia(model, 0, kind=kind)


def test_floor_contact_with_no_bodies_says_so():
    model = pendulum(3).model                                      # it has geometry
    with pytest.raises(InputError, match="bodies is empty: give at least one body of "
                       "'pendulum3'"):
        FloorContact(model, bodies=[])
    two = Model([Body("ball", 1.0, geoms=(Geom("sphere", (0.1,)),)), Body("ghost", 1.0)],
                [Joint("a", None, "ball", "free"), Joint("b", None, "ghost", "free")],
                name="half")
    with pytest.raises(ModelError, match="model 'half' has no geometry on bodies \\['ghost'\\]"):
        FloorContact(two, bodies=["ghost"])
    assert FloorContact(two).bodies.tolist() == [0]
