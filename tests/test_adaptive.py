"""Adaptive dynamics against the full DCA and the locked-joint solution (theory §6).

Oracles: ``method="dca"`` (threshold 0 must reproduce it), the locked-joint
solution ``qdd_A = M_AA^-1 (tau - bias)_A`` (``bias`` from RNEA with the full
velocity, zero on the locked joints; anchors §1), the direct sum (T14) of the
acceleration metric, and the spatial momentum / kinetic energy of
:mod:`vdad.quantities`. Tolerances are ``c · cond · eps`` where a matrix is solved.
"""

import copy

import numpy as np
import pytest
from strategies import (
    random_chain,
    random_configuration,
    random_state,
    random_tree,
    with_armature,
)

import vdad
from vdad.adaptive import AdaptiveDynamics, StepStats, default_weights
from vdad.errors import InputError
from vdad.integrators import semi_implicit_euler
from vdad.quantities import kinetic_energy, spatial_momentum
from vdad.reference import bias_forces, crba
from vdad.scenes import pendulum

EPS = np.finfo(float).eps


# --- helpers -------------------------------------------------------------------------


def internal_subtree(tree, node):
    """Internal nodes of the subtree of ``node`` (itself included)."""
    nb = tree.model.nb
    out, stack = [], [node]
    while stack:
        x = stack.pop()
        if x >= nb:
            out.append(x)
            stack += [tree.left[x - nb], tree.right[x - nb]]
    return out


def joint_dofs(model, joints):
    joints = list(joints)
    if not joints:
        return np.zeros(0, int)
    return np.concatenate([np.arange(model.v_start[j], model.v_start[j] + model.nv_joint[j])
                           for j in joints])


def rigidify(ad, q, qd, nodes):
    """Lock the internal ``nodes`` (a union of subtrees) at ``q``: zero their
    velocities in ``qd`` (in place), freeze their groups, rebuild the plans."""
    model, tree = ad.model, ad.tree
    nodes = np.asarray(sorted(nodes), int)
    qd[joint_dofs(model, tree.joint[nodes - model.nb])] = 0.0
    ad.groups.freeze(nodes, q)
    ad.active[nodes] = False
    ad._build(q)


def evaluate(ad, q, qd, tau=None, f_ext=None):
    """One evaluation of ``qdd`` of the active joints (local layout), the way the
    first evaluation of :meth:`AdaptiveDynamics.step` does it."""
    if ad.js is None:
        ad._build(q)
    ad._q, ad._qd = q, qd
    ad._eval, ad._eval_time = 0, 0.0
    ad._controller = None if tau is None else (lambda t, q_, qd_: tau)
    ad._external = None if f_ext is None else (lambda t, q_, qd_: f_ext)
    ad.stats = StepStats()
    js = ad.js
    return ad._accelerations(0.0, q[js.q_index], qd[js.v_index])


def locked_solution(model, q, qd, tau, f_ext, dofs):
    """``qdd_A = M_AA^-1 (tau - bias)_A`` and ``cond(M_AA)``: M qdd + C = tau +
    passive + J^T f_ext, and ``bias_forces`` is ``C - passive - J^T f_ext``."""
    M = crba(model, q)
    rhs = (np.zeros(model.nv) if tau is None else tau) - bias_forces(model, q, qd, f_ext)
    M_AA = M[np.ix_(dofs, dofs)]
    return np.linalg.solve(M_AA, rhs[dofs]), np.linalg.cond(M_AA)


def random_rigid_set(tree, rng, fraction):
    """A union of whole subtrees of random internal nodes; the first root of the
    assembly forest stays active (other roots may be picked)."""
    nb = tree.model.nb
    internal = np.arange(nb, tree.n_nodes)
    keep = int(np.flatnonzero(tree.up == -1)[0])
    candidates = [x for x in internal if x != keep]
    picks = rng.choice(candidates, size=max(1, int(fraction * len(candidates))), replace=False)
    return sorted({x for p in picks for x in internal_subtree(tree, p)})


class Pokes:
    """External wrenches that change on ``k`` random bodies at every step (seeded);
    ``changed[s]``: bodies whose wrench differs between steps ``s - 1`` and ``s``."""

    def __init__(self, nb, dt, k, seed, scale=1e-3):
        self.nb, self.dt, self.k, self.scale = nb, dt, k, scale
        self.rng = np.random.default_rng(seed)
        self.f = [np.zeros((nb, 6))]
        self.changed = [0]

    def at(self, step):
        while len(self.f) <= step:
            f = self.f[-1].copy()
            idx = self.rng.choice(self.nb, size=self.k, replace=False)
            f[idx] = self.rng.normal(size=(self.k, 6)) * self.scale
            self.changed.append(int(np.sum(np.any(f != self.f[-1], axis=1))))
            self.f.append(f)
        return self.f[step]

    def __call__(self, t, q, qd):
        return self.at(int(round(t / self.dt)))


# --- 1. threshold 0 is the full DCA -----------------------------------------------


def _case(name):
    if name.startswith("pendulum"):
        scene = pendulum(int(name[len("pendulum"):]))
        return scene.model, scene.q0, scene.qd0, scene.dt
    model = random_tree(3, n=12, roots=2, springs=True, composite=True)
    if name == "tree with armature":
        model = with_armature(model, 3)
    q, qd, _, _ = random_state(model, 3)
    return model, q, qd, 1e-3


@pytest.mark.parametrize("integrator", ["semi-implicit", "rk4"])
@pytest.mark.parametrize("case", ["pendulum20", "pendulum60", "tree", "tree with armature"])
def test_threshold_zero_is_full_dca(case, integrator):
    """Threshold 0 (and a budget of every joint) reproduce ``method="dca"`` over
    300 steps, to the rounding of a few eps per step compounding: the adaptive
    passes (``vdad/levels.py``, numpy) order their products differently from the
    compiled DCA. Measured: bitwise on 20 bodies and the tree; 1.3e-12 in qd
    (about 20 eps per step) on 60 bodies, where nodes whose metric is exactly 0
    (the tail, qdd == 0.0 in the DCA too) are rigidified and released again by the
    look-ahead."""
    model, q0, qd0, dt = _case(case)
    steps = 300
    ref = vdad.Simulator(model, q0, qd0, dt=dt, integrator=integrator).step(steps)
    tol = 100 * steps * np.finfo(float).eps * max(1.0, np.abs(ref.qd).max())
    for option in (dict(threshold=0.0), dict(budget=model.nb)):
        sim = vdad.Simulator(model, q0, qd0, dt=dt, method="adaptive", integrator=integrator,
                             **option).step(steps)
        assert np.abs(sim.q - ref.q).max() <= tol, option
        assert np.abs(sim.qd - ref.qd).max() <= tol, option
        assert sim.history[0].active_joints == model.nb
        assert np.abs(ref.qd).max() > 0.1                      # it moved


# --- 2. hybrid bodies ---------------------------------------------------------------


@pytest.mark.parametrize("seed", range(6))
def test_hybrid_body_is_locked_joint_solution(seed):
    """Front nodes as rigid composite bodies (T19)-(T20) give the locked-joint
    solution, with springs, tau, f_ext, every joint kind and composite joints.
    Measured: error / (cond(M_AA) eps) <= 1.6."""
    model = random_tree(seed, n=10 + 3 * seed, roots=1 + seed % 3, composite=seed % 2 == 1)
    q, qd0, tau, f_ext = random_state(model, seed)
    tree = vdad.dynamics.default_tree(model)
    rng = np.random.default_rng(100 + seed)
    multi_body_front = 0
    for fraction in (0.1, 0.3, 0.6):
        ad = AdaptiveDynamics(model, 1e-3, threshold=0.0)
        qd = qd0.copy()
        rigidify(ad, q, qd, random_rigid_set(tree, rng, fraction))
        js = ad.js
        assert js.k > 0
        qdd = evaluate(ad, q, qd, tau, f_ext)
        expected, cond = locked_solution(model, q, qd, tau, f_ext, js.v_index)
        err = np.abs(qdd - expected).max() / np.abs(expected).max()
        assert err <= 100 * cond * EPS, (fraction, err, cond)
        multi_body_front += int(np.sum(ad.front >= model.nb))
    assert multi_body_front > 0                               # some front was a composite


def test_grounded_front_after_lookahead():
    """A second evaluation at the same state (the next step) gives the same
    locked-joint solution as the first: the look-ahead, which assembles each
    internal front node ``F`` across its released joint, must not overwrite the
    blocks of ``F`` (for a group welded to the ground they are written only when
    the region is built). Regression: once gave an absolute error of 235 in qdd
    on the second evaluation (8-link pendulum, ground + link0 rigid)."""
    scene = pendulum(8)
    model, q, qd = scene.model, scene.q0.copy(), np.zeros(8)
    ad = AdaptiveDynamics(model, 1e-3, threshold=0.0)
    tree = ad.tree
    F = model.nb + int(np.flatnonzero(tree.joint == 0)[0])     # holds the ground leaf
    rigidify(ad, q, qd, internal_subtree(tree, F))
    assert ad.groups.grounded[F] and F in ad.front and ad.la is not None
    expected, cond = locked_solution(model, q, qd, None, None, ad.js.v_index)
    tol = 100 * cond * EPS * np.abs(expected).max()
    first = evaluate(ad, q, qd)
    assert np.abs(first - expected).max() <= tol
    second = evaluate(ad, q, qd)
    assert np.abs(second - expected).max() <= tol, np.abs(second - expected).max()


@pytest.mark.parametrize("lookahead", [False, True])
def test_hybrid_bodies_stay_exact_during_a_run(lookahead):
    """After steps with rigidification, release and changing external forces
    (budget mode, short dwell), the hybrid evaluation at the current state still
    equals the locked-joint solution: the cached group data and force sums are
    right. Checked on copies of the simulator every 10 steps.

    With ``lookahead=True`` this fails (relative error 0.1 from step 3 on) because
    of the grounded-front bug described in :func:`test_grounded_front_after_lookahead`;
    with ``lookahead=False`` the error is 1e-14."""
    seed = 3
    model = random_tree(seed, n=30, roots=2, composite=True, springs=False)
    q, qd, tau, _ = random_state(model, seed)
    pokes = Pokes(model.nb, 1e-3, 3, seed)
    sim = vdad.Simulator(model, q, 0.1 * qd, method="adaptive", budget=10, dwell=3,
                         external=pokes, lookahead=lookahead)
    worst = 0.0
    for block in range(8):
        sim.step(10)
        check = copy.deepcopy(sim)
        ad = check.adaptive
        ad.threshold, ad.budget = 0.0, None                   # accelerate every active joint
        nb = model.nb
        rigid = nb + np.flatnonzero(~ad.active[nb:ad.tree.n_nodes])
        assert np.all(check.qd[joint_dofs(model, ad.tree.joint[rigid - nb])] == 0.0)
        f_next = pokes.at(check.step_count + 1)
        qdd = evaluate(ad, check.q, check.qd, tau, f_next)
        expected, cond = locked_solution(model, check.q, check.qd, tau, f_next, ad.js.v_index)
        err = np.abs(qdd - expected).max() / np.abs(expected).max()
        worst = max(worst, err / (cond * EPS))
        assert err <= 100 * cond * EPS, (block, err)
    history = sim.history
    assert sum(h.rigidified for h in history) > 0 and sum(h.force_update for h in history) > 0


# --- 3. metric coefficients -------------------------------------------------------------


def _check_metric(ad, model, qdd_full, active_nodes):
    """metric.A at every reached node of ``active_nodes`` against (T14) with
    ``qdd_full`` (zeros on locked joints); Psi symmetric PSD at every such node."""
    tree, w, nb = ad.tree, default_weights(model), model.nb
    active_joint = np.zeros(nb, bool)
    active_joint[ad.js.joints] = True
    direct = {}
    for node in active_nodes:
        joints = [tree.joint[x - nb] for x in internal_subtree(tree, node)
                  if active_joint[tree.joint[x - nb]]]
        dofs = joint_dofs(model, joints)
        direct[node] = float(np.sum(w[dofs] * qdd_full[dofs] ** 2))
    total = max(direct.values())
    assert total > 0
    reached = 0
    for node, value in direct.items():
        A = ad.metric.A[node]
        if np.isnan(A):                # not reached: an ancestor's metric was 0
            assert value <= 1e-12 * total, (node, value)
            continue
        reached += 1
        assert abs(A - value) <= 1e-9 * max(value, 1e-6 * total), (node, A, value)
        P = tree.n_ports[node]
        if P:
            base = tree.block_base[node]
            Psi = ad.metric.Psi[base:base + P * P].reshape(P, P, 6, 6)
            Psi = Psi.transpose(0, 2, 1, 3).reshape(6 * P, 6 * P)
            scale = max(np.abs(Psi).max(), 1e-300)
            assert np.abs(Psi - Psi.T).max() <= 1e-12 * scale
            eig = np.linalg.eigvalsh(0.5 * (Psi + Psi.T))
            assert eig[0] >= -1e-9 * np.abs(eig).max()
    return reached


@pytest.mark.parametrize("seed", range(6))
def test_metric_coefficients_match_direct_sum(seed):
    """A(C) = x^T Psi x + p·x + eta from (T16)-(T18) equals the direct sum (T14)
    at every reached node, with all joints active and in a hybrid state.
    Measured: relative 3e-12 at worst."""
    model = random_tree(seed, n=10 + 3 * seed, roots=1 + seed % 3, composite=seed % 2 == 1)
    q, qd, tau, f_ext = random_state(model, seed)
    nb = model.nb
    ad = AdaptiveDynamics(model, 1e-3, threshold=0.0)
    evaluate(ad, q, qd, tau, f_ext)
    qdd = vdad.forward_dynamics(model, q, qd, tau, f_ext)
    reached = _check_metric(ad, model, qdd, range(nb, ad.tree.n_nodes))
    assert reached >= 0.8 * (ad.tree.n_nodes - nb)

    ad = AdaptiveDynamics(model, 1e-3, threshold=0.0)
    qd = qd.copy()
    rigidify(ad, q, qd, random_rigid_set(ad.tree, np.random.default_rng(seed), 0.3))
    evaluate(ad, q, qd, tau, f_ext)
    qdd_full = np.zeros(model.nv)
    qdd_full[ad.js.v_index], _ = locked_solution(model, q, qd, tau, f_ext, ad.js.v_index)
    assert _check_metric(ad, model, qdd_full, ad.act) >= 1


# --- 4. rigidification policies ----------------------------------------------------------


def _free_chain(seed):
    model = random_chain(seed, n=12, root="free", gravity=(0.0, 0.0, 0.0))
    rng = np.random.default_rng(seed)
    return model, random_configuration(model, rng), rng.normal(size=model.nv)


def _region_updates(model, q, qd, steps=200, **options):
    """Run AdaptiveDynamics; for every step that rigidified nodes, the momentum
    and kinetic energy right before and right after the region update."""
    ad = AdaptiveDynamics(model, 1e-3, **options)
    before = {}

    def integrate(js, accel, t, q_a, qd_a, dt):
        q_a, qd_a = semi_implicit_euler(js, accel, t, q_a, qd_a, dt)
        q_full, qd_full = ad._q.copy(), ad._qd.copy()
        q_full[js.q_index], qd_full[js.v_index] = q_a, qd_a
        before["h"] = spatial_momentum(model, q_full, qd_full)
        before["T"] = kinetic_energy(model, q_full, qd_full)
        return q_a, qd_a

    events = []
    for k in range(steps):
        stats = ad.step(k * 1e-3, q, qd, integrate)
        if stats.rigidified:
            events.append((before["h"], spatial_momentum(model, q, qd),
                           before["T"], kinetic_energy(model, q, qd)))
    return events


@pytest.mark.parametrize("seed, threshold", [(1, 5e-3), (3, 1e-2)])
def test_momentum_policy_conserves_momentum(seed, threshold):
    """The locking impulse conserves the spatial momentum of a free system and
    does not add kinetic energy; zeroing the velocities changes the momentum.

    The floating base (free joint j0) gets a large weight so that it stays
    articulated: locking it welds the system to the world, see
    :func:`test_momentum_policy_keeps_a_floating_base_floating`. Momentum is
    compared across the region update only: semi-implicit Euler alone drifts
    (5e-3 relative over 200 steps with the full DCA on these chains), and
    threshold mode drops the accelerations of active joints below the threshold.
    Measured: |dh|/|h| <= 2.3e-15 (momentum), 4e-2 to 0.56 (zero)."""
    model, q, qd = _free_chain(seed)
    heavy = dict(weights={"j0": 1e8}, velocity_weights={"j0": 1e8}, threshold=threshold)
    events = _region_updates(model, q.copy(), qd.copy(), policy="momentum", **heavy)
    assert events
    for h0, h1, T0, T1 in events:
        assert np.abs(h1 - h0).max() <= 1e-10 * np.abs(h0).max()
        assert T1 <= T0 * (1 + 1e-12)
    events = _region_updates(model, q.copy(), qd.copy(), policy="zero", **heavy)
    assert events
    change = max(np.abs(h1 - h0).max() / np.abs(h0).max() for h0, h1, _, _ in events)
    assert change > 1e-6


def test_momentum_policy_keeps_a_floating_base_floating():
    """With the default weights a slow free chain is rigidified at the first
    step; its root free joint is never rigidified (a floating base welded to
    the world would stop), so the momentum policy conserves its momentum.
    Regression: the whole chain was once welded, qd = 0 and |dh|/|h| = 1."""
    model, q, qd = _free_chain(1)
    events = _region_updates(model, q, qd, steps=20, threshold=5e-2, policy="momentum")
    assert events
    for h0, h1, _, _ in events:
        assert np.abs(h1 - h0).max() <= 1e-10 * np.abs(h0).max(), (h0, h1)


# --- 5. cost ----------------------------------------------------------------------------


@pytest.mark.parametrize("n", [255, 1023])
def test_node_visits_bound(n):
    """node_visits <= 2 n_a + 1 + n_f (log2(n / n_f) + 2) at every step after the
    first, ``n_f`` the bodies whose external force changed (theory §6,
    complexity). Measured: the bound is met with equality (front = n_a + 1) at
    some steps, never exceeded."""
    scene = pendulum(n)
    for option in (dict(budget=20), dict(budget=50), dict(threshold=1e-6),
                   dict(threshold=1e-4)):
        for k in (0, 3):
            pokes = Pokes(n, scene.dt, k, n) if k else None
            sim = vdad.Simulator(scene.model, scene.q0, scene.qd0, dt=scene.dt,
                                 method="adaptive", external=pokes, **option).step(60)
            for s, st in enumerate(sim.history[1:], start=1):
                n_f = pokes.changed[s] if pokes else 0
                bound = 2 * st.active_joints + 1 + (n_f * (np.log2(n / n_f) + 2) if n_f else 0)
                assert st.node_visits <= bound, (option, k, s, st)
                assert st.active_joints < n / 2
            if k:
                assert sum(st.force_update for st in sim.history) > 0


# --- 6. threshold sweep -----------------------------------------------------------------


def test_threshold_monotone_on_300_pendulum():
    """300-link pendulum, 150 steps: fewer active joints and less work per step as
    the threshold grows over eight decades (Figure 8's trend). Work is counted,
    not timed (timings belong to benchmarks): nodes visited by the passes per
    step. Measured: mean active 39.6, 28.7, 16.7; node visits 75.6, 53.8, 29.6."""
    scene = pendulum(300)
    active, visits = [], []
    for threshold in (1e-12, 1e-8, 1e-4):
        sim = scene.simulator(method="adaptive", threshold=threshold).step(150)
        active.append(np.mean([h.active_joints for h in sim.history]))
        visits.append(np.mean([h.node_visits for h in sim.history[1:]]))
        assert np.abs(sim.q - scene.q0).max() > 0.01           # it swings
    assert active[0] > active[1] + 3 > active[2] + 6, active
    assert visits[0] > visits[1] > visits[2] and visits[2] < 0.5 * visits[0], visits


# --- 7. input errors --------------------------------------------------------------------


def test_adaptive_options_are_checked():
    scene = pendulum(4)
    assert scene.simulator(method="adaptive").options["threshold"] == 1e-5   # the scene's
    with pytest.raises(InputError, match="threshold=.*budget="):
        scene.simulator(method="adaptive", threshold=1e-3, budget=2)
    with pytest.raises(InputError, match="threshold must be .* got -0.001"):
        scene.simulator(method="adaptive", threshold=-1e-3)
    with pytest.raises(InputError, match="threshold must be"):
        scene.simulator(method="adaptive", threshold=float("nan"))
    with pytest.raises(InputError, match="budget must be"):
        scene.simulator(method="adaptive", budget=-1)
    with pytest.raises(InputError, match="budget must be"):
        scene.simulator(method="adaptive", budget=2.5)
    with pytest.raises(InputError, match="policy 'bogus'"):
        scene.simulator(method="adaptive", threshold=1e-3, policy="bogus")
    with pytest.raises(InputError, match="kappa must be >= 1, got 0.5"):
        scene.simulator(method="adaptive", threshold=1e-3, kappa=0.5)
    with pytest.raises(InputError,
                       match=r"threshold= applies to method='adaptive'.*not to method='dca'"):
        scene.simulator(method="dca", threshold=1e-3)
    with pytest.raises(InputError, match="threshold must be a real number.*string: 'small'"):
        scene.simulator(method="adaptive", threshold="small")
    with pytest.raises(InputError, match="budget must be a positive integer, got 0"):
        scene.simulator(method="adaptive", budget=0)
    with pytest.raises(InputError, match="coverage_every must be a positive integer, got 0"):
        scene.simulator(method="adaptive", threshold=1e-3, coverage_every=0)
    with pytest.raises(InputError, match="coverage must be a callable"):
        scene.simulator(method="adaptive", threshold=1e-3, coverage=np.ones(9))
    with pytest.raises(InputError, match="coverage_every applies to a coverage estimate"):
        scene.simulator(method="adaptive", coverage_every=2)
    for bad in ("no", np.array([True, False]), 1):
        with pytest.raises(InputError, match="lookahead must be True or False"):
            scene.simulator(method="adaptive", lookahead=bad)
    for weights, match in (("abc", "weights must be a real number"),
                           ({"joint0": "x"}, r"weights\['joint0'\] must be a real number"),
                           (True, "weights must be a real number.*boolean")):
        with pytest.raises(InputError, match=match):
            scene.simulator(method="adaptive", weights=weights)
    with pytest.raises(InputError, match="velocity_weights must be a real number"):
        scene.simulator(method="adaptive", velocity_weights="x")
    for counts, match in ((np.full(9, -1.0), "negative pixel counts"),
                          ("x", r"coverage\(t, q, adaptive\) must be a real number")):
        sim = scene.simulator(method="adaptive", threshold=1e-3,
                              coverage=lambda t, q, ad, counts=counts: counts)
        with pytest.raises(vdad.SimulationError, match=match):
            sim.step()
    with pytest.raises(InputError, match="dwell must be"):
        scene.simulator(method="adaptive", threshold=1e-3, dwell=True)
    with pytest.raises(InputError, match=r"weights\['joint1'\] must be a positive scalar or 1"):
        scene.simulator(method="adaptive", threshold=1e-3, weights={"joint1": [1.0, 2.0]})
    with pytest.raises(InputError, match=r"velocity_weights must be positive .* 'joint0'"):
        scene.simulator(method="adaptive", threshold=1e-3, velocity_weights=[0.0, 1, 1, 1])


@pytest.mark.parametrize("seed", [0, 3])
def test_body_poses_follow_their_rigid_groups(seed):
    """Poses asked for during an adaptive run (rigid groups composed with the
    active joints only) equal the full kinematics of the frozen configuration."""
    model = random_tree(seed, n=16, roots=2, composite=True)
    q, qd, _, _ = random_state(model, seed)
    sim = vdad.Simulator(model, q, 0.2 * qd, method="adaptive", budget=5, dwell=2)
    full = vdad.Simulator(model, q, qd)
    for _ in range(4):
        sim.step(5)
        assert sim.history[-1].active_joints < model.nb
        full.q = sim.q
        R_ref, p_ref = full.body_poses()
        R, p = sim.body_poses()
        scale = 1 + np.abs(p_ref).max()
        assert np.abs(R - R_ref).max() < 1e-12 and np.abs(p - p_ref).max() < 1e-12 * scale
        some = [model.nb - 1, 0, 5]
        R_s, p_s = sim.body_poses(some)
        assert np.abs(p_s - p_ref[some]).max() < 1e-12 * scale
