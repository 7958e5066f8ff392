"""Adaptive articulated-body dynamics: the DCA with pruning (Kim 2008 §4.2; theory §6).

The *active region* ``R`` is a set of internal assembly-tree nodes closed upward;
the joints of its nodes are articulated, every other joint is rigid (``qd = 0``,
``q`` frozen). Each front node (a child of ``R`` outside it) is one rigid body,
a hybrid body's leaf (T19)-(T20), with data cached in :mod:`vdad.hybrid`. A step:

1. kinematics of the active joints only: a :class:`~vdad.kinematics.JointSet`
   whose bodies are the front groups, each hanging from its top body's joint;
2. leaves of the front groups, the bottom-up pass over ``R`` with the metric
   coefficients (T16)-(T18), and the top-down pass restricted by the
   acceleration metric: threshold mode descends into a node while its score
   exceeds ``threshold``, budget mode pops the ``budget`` highest-scoring
   nodes from a max-heap; joints left out get ``qdd = 0``;
3. one-level look-ahead at the front: the acceleration each front node's joint
   would have if released (its two children held rigid);
4. integration of the active joints only, then the region update: nodes whose
   acceleration and velocity scores are both low are rigidified (velocities
   zeroed, or the momentum-conserving locking impulse), front nodes whose
   look-ahead score is high are released; hysteresis ``kappa`` and a minimum
   dwell time keep the set from flickering.

Scores put both metrics in the units of a displacement per step: ``dt^2 sqrt(A(C))``
and ``dt sqrt(V(C))`` (theory §7 with ``N_M = 1``). With a ``coverage`` estimator
(:mod:`vdad.visibility`) they become the paper's view-dependent metrics
``A_M(C) = dt^2 N_M(C) sqrt(A(C))`` and ``V_M(C) = dt N_M(C) sqrt(V(C))``
(Kim 2008 §5.2), in pixels times displacement, with ``N_M`` evaluated at the
start of each step from the configuration the viewer sees then (the last frame).
``docs/adaptive.md`` and ``docs/visibility.md`` state the design choices,
derivations and measurements.
"""

from __future__ import annotations

import heapq
import time
from dataclasses import dataclass, field, replace
from types import SimpleNamespace

import numpy as np

from . import joints as J
from .assembly import GROUND, TRASH, LeafPlan, Level
from .checks import (
    check_callable,
    check_count,
    check_flag,
    check_real,
    check_vector,
    check_wrenches,
    real_array,
)
from .dynamics import default_tree, passive_forces
from .errors import InputError
from .hybrid import RigidGroups, group_wrench, momentum_at_com
from .kinematics import body_poses, joint_kinematics, joint_set, kinematics, ranges
from .levels import (
    LevelData,
    MetricData,
    assemble,
    back_substitute,
    inverse_inertia,
    joint_solution,
    metric_value,
    rigid_leaves,
)
from .spatial import cross3, mv

POLICIES = ("momentum", "zero")
METRICS = ("coefficients", "direct")
PHASES = ("visibility", "forces", "kinematics", "leaves", "assemble", "back_substitute", "select",
          "integrate", "region")


@dataclass
class StepStats:
    """Counters of one adaptive step.

    active_joints: joints in the active region (articulated); accelerated: joints
    whose ``qdd`` was computed; front: rigid groups at the front; assembled /
    back_substituted: nodes evaluated by the two passes; force_update: node
    visits carrying force changes up rigid regions; lookahead: front joints
    evaluated; rigidified / released: nodes that changed state; times: seconds
    per phase (:data:`PHASES`; ``visibility``: the coverage ``N_M``; ``select``:
    look-ahead and budget heap).
    """

    active_joints: int = 0
    accelerated: int = 0
    front: int = 0
    assembled: int = 0
    back_substituted: int = 0
    force_update: int = 0
    lookahead: int = 0
    rigidified: int = 0
    released: int = 0
    times: dict = field(default_factory=lambda: dict.fromkeys(PHASES, 0.0))

    @property
    def node_visits(self) -> int:
        """Nodes touched by the passes: active nodes, their front, the force-update region."""
        return self.assembled + self.front + self.force_update


def default_weights(model):
    """The paper's diagonal ``D_i`` (nv,): 1 on rotational dofs, ``1/l^2`` on
    translational ones, ``l`` the mean distance between a joint and its parent's
    (the typical link length; 1 m if there is none), so both measure a
    displacement in link lengths."""
    inner = model.parent >= 0
    length = float(np.mean(np.linalg.norm(model.placement_p[inner], axis=1))) if inner.any() else 0
    length = length if length > 0 else 1.0
    return np.where(rotational_dofs(model), 1.0, 1.0 / length**2)


def rotational_dofs(model):
    """Mask (nv,) of the rotational degrees of freedom (hinges and balls)."""
    mask = np.ones(model.nv, bool)
    for s in range(model.ns):
        kind = model.stage_kind[s]
        if kind in (J.SLIDE, J.TRANSLATION):
            mask[model.stage_v[s]:model.stage_v[s] + J.STAGE_NV[kind]] = False
    return mask


def resolve_weights(model, weights, name="weights"):
    """Diagonal metric weights (nv,) from ``None`` (:func:`default_weights`), a
    positive scalar, an (nv,) array, or a dict {joint name: scalar or (d,)}."""
    if weights is None:
        return default_weights(model)
    if isinstance(weights, dict):
        w = default_weights(model)
        for joint, value in weights.items():
            j = model.joint_index(joint)
            d = model.nv_joint[j]
            v = real_array(f"{name}[{joint!r}]", value)
            v = np.full(d, float(v)) if v.ndim == 0 else v
            if v.shape != (d,) or not np.all(np.isfinite(v)) or np.any(v <= 0):
                raise InputError(f"{name}[{joint!r}] must be a positive scalar or {d} positive "
                                 f"numbers, got {value!r}")
            w[model.v_start[j]:model.v_start[j] + d] = v
        return w
    w = real_array(name, weights)
    if w.ndim == 0:
        w = np.full(model.nv, float(w))
    if w.shape != (model.nv,):
        raise InputError(f"{name} must be a scalar, ({model.nv},) or a dict by joint name; "
                         f"got shape {w.shape}")
    bad = np.flatnonzero(~np.isfinite(w) | (w <= 0))
    if len(bad):
        joint = model.joint_names[model.dof_joint[bad[0]]]
        raise InputError(f"{name} must be positive and finite; dof {bad[0]} of joint "
                         f"{joint!r} is {w[bad[0]]}")
    return w


def _padded(js, w):
    """Diagonal weights ``w`` (nv,) of the joints of ``js``, (k, 6) zero-padded."""
    return np.append(w[js.v_index], 0.0)[js.dof_index]


class AdaptiveDynamics:
    """Adaptive forward dynamics of ``model`` on an assembly ``tree`` (work state).

    threshold: score below which accelerations are dropped (threshold mode), in
    weighted displacement per step; budget: number of joints to accelerate
    (budget mode); exactly one of them. weights / velocity_weights: ``A_i`` and
    ``V_i`` of (T14)-(T15) (:func:`resolve_weights`; ``V_i = A_i`` by default).
    kappa: hysteresis factor: front nodes are released above ``threshold``,
    active nodes keep their accelerations down to ``threshold / kappa`` and are
    rigidified below it (in budget mode active nodes compete with ``kappa``
    times their score). A free joint to the world is never rigidified, and its
    accelerations (with those of the nodes above it) are always computed: a
    floating body whose weight were dropped would fly in a straight line.
    dwell: steps a node keeps a new state. policy: ``"momentum"`` (locking impulse) or
    ``"zero"`` (zero the velocities of newly rigid joints, as the paper).
    lookahead: release front joints whose look-ahead score is high.
    metric: ``"coefficients"`` predicts ``A(C)`` from (T16)-(T18) before any
    ``qdd`` is computed and back-substitutes only the nodes it descends into (the
    paper's algorithm); ``"direct"`` back-substitutes the whole active region and
    sums (T14) bottom-up: the same values and decisions, cheaper in numpy, whose
    cost is per level rather than per node (``docs/adaptive.md``).
    coverage: None (``N_M = 1``: view-independent) or an estimator
    ``(t, q, adaptive) -> N_M`` per node (:mod:`vdad.visibility`), evaluated
    every ``coverage_every`` steps and whenever the active region changes.
    """

    def __init__(self, model, dt, tree=None, threshold=None, budget=None, weights=None,
                 velocity_weights=None, kappa=4.0, dwell=10, policy="momentum", lookahead=True,
                 metric="coefficients", coverage=None, coverage_every=1):
        if (threshold is None) == (budget is None):
            raise InputError("adaptive dynamics needs exactly one of threshold= or budget=")
        if threshold is not None:
            threshold = float(check_real("threshold", threshold, nonnegative=True))
        if budget is not None:
            budget = check_count("budget", budget)
        kappa = float(check_real("kappa", kappa))
        if kappa < 1:
            raise InputError(f"kappa must be >= 1, got {kappa!r}")
        dwell = check_count("dwell", dwell, minimum=0)
        if policy not in POLICIES:
            raise InputError(f"unknown rigidification policy {policy!r}; choose one of {POLICIES}")
        if metric not in METRICS:
            raise InputError(f"unknown metric evaluation {metric!r}; choose one of {METRICS}")
        check_callable("coverage", coverage, "(t, q, adaptive) -> N_M")
        coverage_every = check_count("coverage_every", coverage_every)
        self.coverage, self.coverage_every = coverage, int(coverage_every)
        self.predictive = metric == "coefficients"
        self.model = model
        self.tree = default_tree(model) if tree is None else tree
        self.dt = float(dt)
        self.threshold = None if threshold is None else float(threshold)
        self.budget = None if budget is None else int(budget)
        self.kappa, self.dwell, self.policy = float(kappa), int(dwell), policy
        if coverage is None and coverage_every != 1:
            raise InputError("coverage_every applies to a coverage estimate (the view-dependent "
                             "methods); plain adaptive dynamics has none")
        self.lookahead = check_flag("lookahead", lookahead)
        self.wA = resolve_weights(model, weights, "weights")
        self.wV = self.wA if velocity_weights is None else resolve_weights(
            model, velocity_weights, "velocity_weights")
        tree = self.tree
        n = tree.n_nodes
        self.groups = RigidGroups(tree)
        self.active = np.zeros(n + 1, bool)              # sentinel n: above the roots
        self.active[model.nb:n] = True
        self.active[n] = True
        self.since = np.full(n + 1, -(10**9))           # step of each node's last change
        self.Phi = np.zeros((tree.n_blocks, 6, 6))
        self.b = np.zeros((tree.n_slots, 6))
        self.metric = MetricData(np.zeros((tree.n_blocks, 6, 6)), np.zeros((tree.n_slots, 6)),
                                 np.zeros(n + 1), None, np.full(n + 1, np.nan))
        self.V = np.zeros(n + 1)
        self.N_M = np.ones(n + 1)                        # coverage per node (pixels)
        self._stale_coverage = True
        # a free joint to the world is never rigidified: welding a floating base to
        # the world would stop it (and take its momentum); so are its ancestors
        self.pinned = np.zeros(n + 1, bool)
        floating = np.flatnonzero((model.parent < 0) & (model.nv_joint == 6))
        node = model.nb + np.flatnonzero(np.isin(self.tree.joint, floating))
        while len(node):
            self.pinned[node] = True
            node = self.tree.up[node]
            node = node[node >= 0]
        self.desc = np.zeros(n + 1, bool)              # descended into this step
        self.desc[n] = True
        self.step_count = 0
        self.stats = StepStats()
        self.js = None                                   # built at the first step

    # --- the active region as arrays (rebuilt when it changes) ---------------------

    def _build(self, q):
        """Plans of the current active region at configuration ``q`` (frozen
        joints): joint set, front leaves, restricted levels, look-ahead."""
        tree, model, g = self.tree, self.model, self.groups
        nb, n = model.nb, tree.n_nodes
        act = nb + np.flatnonzero(self.active[nb:n])
        joints = tree.joint[act - nb]
        k = len(joints)
        jmap = np.full(nb + 1, k)
        jmap[joints] = np.arange(k)
        kids = np.concatenate([tree.left[act - nb], tree.right[act - nb]])
        roots = np.flatnonzero(tree.up == -1)
        front = np.union1d(kids[(kids != GROUND)], roots)
        front = front[~self.active[front]]
        grounded = g.grounded[front]
        mobile = front[~grounded]
        # every front group hangs from its top body's joint; its outbound ports
        # give the local parent and the constant pre-placement of active joints
        slots = ranges(tree.slot_base[front], tree.n_ports[front])
        owner = np.repeat(np.arange(len(front)), tree.n_ports[front])
        out = tree.slot_side[slots] < 0
        oj = jmap[tree.slot_joint[slots[out]]]
        top_local = np.where(grounded, -1, jmap[np.maximum(tree.top[front], 0)])
        parent = np.full(k, -1)
        pre_R = np.broadcast_to(np.eye(3), (k, 3, 3)).copy()
        pre_p = np.zeros((k, 3))
        parent[oj] = top_local[owner[out]]
        pre_R[oj], pre_p[oj] = g.port_R[slots[out]], g.port_p[slots[out]]
        js = joint_set(model, joints, parent, pre_R, pre_p)
        self.js, self.jmap, self.act, self.front = js, jmap, act, front
        self.front_top = top_local[~grounded]
        self.front_mobile = mobile
        self.front_lp = _leaf_plan(tree, mobile, jmap)
        self.levels = _active_levels(tree, self.active, jmap, k)
        self.data = LevelData(self.Phi, self.b, np.zeros((k + 1, 6)), np.zeros(js.nv + 1),
                            [None] * len(self.levels))
        self.metric.D = _padded(js, self.wA)
        self.wV_local = self.wV[js.v_index]
        self.dof_joint = np.repeat(np.arange(k), model.nv_joint[joints])
        # fronts are leaves: zero metric stores; grounded fronts are immobile
        for F, P in zip(front, tree.n_ports[front], strict=True):
            blocks = slice(tree.block_base[F], tree.block_base[F] + P * P)
            sl = slice(tree.slot_base[F], tree.slot_base[F] + P)
            self.metric.Psi[blocks], self.metric.p[sl] = 0.0, 0.0
            if g.grounded[F]:
                self.Phi[blocks], self.b[sl] = 0.0, 0.0
        self.metric.eta[front], self.V[front] = 0.0, 0.0
        self.la = self._lookahead_plan(q) if self.lookahead else None
        self._rows = [None] * len(self.levels)
        self._stale_coverage = True

    def _lookahead_plan(self, q):
        """Internal front nodes, each evaluated as one node over its two rigid
        children expressed in its own frame, with its joint frozen at ``q``."""
        tree, model, g, jmap = self.tree, self.model, self.groups, self.jmap
        nb = model.nb
        F = self.front[self.front >= nb]
        if not len(F):
            return None
        i = F - nb
        A, B, j = tree.left[i], tree.right[i], tree.joint[i]
        mobile_F = ~g.grounded[F]
        leaf_node = np.concatenate([A[mobile_F], B])
        leaf_F = np.concatenate([np.flatnonzero(mobile_F), np.arange(len(F))])
        is_B = np.arange(len(leaf_node)) >= mobile_F.sum()
        TR = np.where(is_B[:, None, None], g.rel_R[F][leaf_F], np.eye(3))
        Tp = np.where(is_B[:, None], g.rel_p[F][leaf_F], 0.0)
        m = g.mass[leaf_node]
        com = Tp + mv(TR, g.com[leaf_node])
        inertia = TR @ g.inertia[leaf_node] @ np.swapaxes(TR, 1, 2)
        lp = _leaf_plan(tree, leaf_node, jmap)
        # fixed ports: each child's side of the frozen joint (body j's frame) and
        # A's inbound port (the group frame); others move with active joints
        port_joint = tree.slot_joint[lp.slot]
        frozen = port_joint == j[leaf_F][lp.body]
        fixed = frozen | (tree.slot_side[lp.slot] > 0)
        rel_R, rel_p = g.rel_R[F][leaf_F][lp.body], g.rel_p[F][leaf_F][lp.body]
        fixed_R = np.where(frozen[:, None, None], rel_R, np.eye(3))
        fixed_p = np.where(frozen[:, None], rel_p, 0.0)
        lp = replace(lp, joint=np.where(fixed, 0, lp.joint), inbound=fixed)
        for X in A[~mobile_F]:                      # grounded children are immobile
            if X != GROUND:
                P = tree.n_ports[X]
                self.Phi[tree.block_base[X]:tree.block_base[X] + P * P] = 0.0
                self.b[tree.slot_base[X]:tree.slot_base[X] + P] = 0.0
        js = joint_set(model, j, np.full(len(j), -1))
        q_la = q[js.q_index]
        *_, T, W = joint_kinematics(js, q_la)
        la_map = np.full(nb + 1, len(j))
        la_map[j] = np.arange(len(j))
        isF = np.zeros(tree.n_nodes + 1, bool)
        isF[F] = True
        pieces = []
        for lv in tree.levels:
            rows = np.flatnonzero(isF[lv.node])
            if len(rows):
                L = lv.restrict(rows, self.jmap)
                # only the intermediates are needed: Phi^C, b^C go to the trash slot,
                # so the front's own blocks (leaves of the main passes) stay intact
                pieces.append(replace(L, joint=la_map[lv.joint[rows]],
                                      out_Phi=np.full_like(L.out_Phi, TRASH),
                                      out_b=np.full_like(L.out_b, TRASH)))
        levels = Level.merge(pieces, len(self.js.joints))        # independent nodes
        pos = np.full(tree.n_nodes + 1, -1)
        pos[F] = np.arange(len(F))
        return SimpleNamespace(
            F=F, leaf_node=leaf_node, leaf_F=leaf_F, TR=TR, mass=m, com=com, inertia=inertia,
            Iinv=inverse_inertia(m, inertia), lp=lp, rows=[pos[lv.node] for lv in levels],
            fixed_R=fixed_R, fixed_p=fixed_p, js=js,
            kin=SimpleNamespace(T=T, W=W, c=np.zeros((len(j), 6))),
            tau_springs=passive_forces(js, q_la, np.zeros(js.nv)), levels=levels,
            data=LevelData(self.Phi, self.b, None, None, [None] * len(levels)),
            D=_padded(js, self.wA), top=np.where(g.grounded[F], -1,
                                                 jmap[np.maximum(tree.top[F], 0)]),
            A=np.zeros(len(F)))

    def body_poses(self, q, bodies=None):
        """World poses ``R`` (k, 3, 3), ``p`` (k, 3) of ``bodies`` (default: all) at
        ``q``: each body's pose in its rigid group (:meth:`RigidGroups.pose_in_group`)
        composed with the group's pose from the active joints only."""
        if self.js is None:
            self._build(q)
        bodies = np.arange(self.model.nb) if bodies is None else np.asarray(bodies, int)
        group, R_in, p_in = self.groups.pose_in_group(bodies, self.active)
        R_top, p_top = self.group_poses(q, group)
        return R_top @ R_in, p_top + mv(R_top, p_in)

    def group_poses(self, q, nodes):
        """World poses ``R`` (k, 3, 3), ``p`` (k, 3) of the frames of rigid ``nodes``
        (front nodes or bodies: their top body's frame; the world for grounded
        groups) at ``q``, from the active joints only."""
        js = self.js
        R_top, p_top = body_poses(js, *joint_kinematics(js, q[js.q_index])[:2])
        R_top = np.concatenate([R_top, np.eye(3)[None]])          # index k: the world
        p_top = np.concatenate([p_top, np.zeros((1, 3))])
        top = np.where(self.groups.grounded[nodes], js.k,
                       self.jmap[np.maximum(self.tree.top[nodes], 0)])
        return R_top[top], p_top[top]

    # --- one step -------------------------------------------------------------------

    def step(self, t, q, qd, integrate, controller=None, external=None):
        """Advance ``(q, qd)`` (full vectors, updated in place) by one step of
        ``integrate`` (an integrator of :mod:`vdad.integrators`). Returns the
        step's :class:`StepStats`."""
        if self.js is None:
            self._build(q)
        js = self.js
        self.stats = st = StepStats(active_joints=js.k, front=len(self.front))
        self._q, self._qd = q, qd
        self._eval, self._eval_time = 0, 0.0
        self._controller, self._external = controller, external
        if self.coverage is not None and (self._stale_coverage
                                          or self.step_count % self.coverage_every == 0):
            t0 = time.perf_counter()
            self.N_M = self._checked_coverage(t, q)
            self._stale_coverage = False
            st.times["visibility"] = time.perf_counter() - t0
        t0 = time.perf_counter()
        q_a, qd_a = integrate(js, self._accelerations, t, q[js.q_index], qd[js.v_index],
                              self.dt)
        q[js.q_index], qd[js.v_index] = q_a, qd_a
        st.times["integrate"] = time.perf_counter() - t0 - self._eval_time
        t0 = time.perf_counter()
        self.step_count += 1
        self._update_region(q, qd)
        st.times["region"] = time.perf_counter() - t0
        return st

    def _checked_coverage(self, t, q):
        N = real_array("coverage(t, q, adaptive)", self.coverage(t, q, self))
        if N.shape != (self.tree.n_nodes + 1,):
            raise InputError(f"coverage must return ({self.tree.n_nodes + 1},) values per "
                             f"node, got shape {N.shape}")
        if np.any(N < 0):                        # NaN: a node inside a rigid group, unused
            raise InputError(f"coverage returned negative pixel counts (node "
                             f"{np.flatnonzero(N < 0)[0]})")
        return N

    def _accelerations(self, t, q_a, qd_a):
        """``qdd`` of the active joints (local layout) at a local state; the first
        call of a step also takes the step's decisions (rows, look-ahead)."""
        st, js, model = self.stats, self.js, self.model
        first = self._eval == 0
        self._eval += 1
        t_start = time.perf_counter()
        t0 = t_start
        tau = passive_forces(js, q_a, qd_a)
        f_ext = None
        if self._controller is not None or self._external is not None:
            q_full, qd_full = self._q.copy(), self._qd.copy()
            q_full[js.q_index], qd_full[js.v_index] = q_a, qd_a
            if self._controller is not None:
                tau_full = np.array(check_vector("controller(t, q, qd)",
                                                 self._controller(t, q_full, qd_full), model.nv))
                tau = tau + tau_full[js.v_index]
                self._tau_full = tau_full
            if self._external is not None:
                f_ext = check_wrenches(model, self._external(t, q_full, qd_full),
                                       "external(t, q, qd)")
        st.force_update += self.groups.update_forces(f_ext, self.active)
        t1 = time.perf_counter()
        st.times["forces"] += t1 - t0
        kin = kinematics(model, q_a, qd_a, js)
        t2 = time.perf_counter()
        st.times["kinematics"] += t2 - t1
        mob = self.front_mobile
        f_leaf = group_wrench(self.groups, mob, kin.R[self.front_top], model.gravity)
        g = self.groups
        rigid_leaves(self.front_lp, kin.R_rel, kin.p_rel, kin.v[self.front_top], g.mass[mob],
                     g.com[mob], g.inertia[mob], g.Iinv[mob], f_leaf, self.data)
        t3 = time.perf_counter()
        st.times["leaves"] += t3 - t2
        assemble(self.levels, js, kin, np.append(tau, 0.0), self.data,
                 self.metric if first and self.predictive else None)
        t4 = time.perf_counter()
        st.times["assemble"] += t4 - t3
        self.data.qdd[:] = 0.0
        if first:
            st.assembled = len(self.act)
            self.desc[self.act] = False
            self.metric.A[self.act] = np.nan
            if self.predictive:
                back_substitute(self.levels, js, self.data, self._select)
            else:
                back_substitute(self.levels, js, self.data)
                self._direct_metric()
            t5 = time.perf_counter()
            st.times["back_substitute"] += t5 - t4
            if self.la is not None:
                self._lookahead(kin)
            if self.budget is not None:
                self._run_heap()
            self._drop_unselected()
            st.times["select"] += time.perf_counter() - t5
        else:
            back_substitute(self.levels, js, self.data, lambda n, lv, f: self._rows[n])
            st.times["back_substitute"] += time.perf_counter() - t4
        self._eval_time += time.perf_counter() - t_start
        return self.data.qdd[:-1].copy()

    @property
    def _keep(self):
        """Score an active node needs to keep its accelerations: ``threshold / kappa``."""
        return self.threshold / self.kappa

    def score_A(self, A, nodes):
        """``dt^2 N_M sqrt(A)`` of ``nodes``: the displacement per step their
        accelerations cause, times their coverage (Kim 2008 §5.2, ``A_M``)."""
        return self.dt**2 * self.N_M[nodes] * np.sqrt(np.maximum(A, 0.0))

    def score_V(self, V, nodes):
        """``dt N_M sqrt(V)`` of ``nodes``: the displacement per step their
        velocities cause, times their coverage (Kim 2008 §5.2, ``V_M``)."""
        return self.dt * self.N_M[nodes] * np.sqrt(np.maximum(V, 0.0))

    def _direct_metric(self):
        """(T14) summed bottom-up over the active region from the computed ``qdd``,
        then the threshold's descent (``metric="direct"``)."""
        qdd = self.data.qdd[:-1]
        own = np.bincount(self.dof_joint, self.wA[self.js.v_index] * qdd**2,
                          minlength=self.js.k)
        A = self.metric.A
        A[self.front] = 0.0
        A[-1] = 0.0
        for lv in self.levels:
            A[lv.node] = A[lv.node_A] + A[lv.node_B] + own[lv.joint]
        A[-1] = np.nan
        self.stats.back_substituted = sum(len(lv.node) for lv in self.levels)
        for n in range(len(self.levels) - 1, -1, -1):
            self._descend(n, self.levels[n], A[self.levels[n].node])

    def _select(self, n, lv, f):
        """Top-down restriction (``metric="coefficients"``): the metric of each
        node reached, predicted from its port forces ``f``, decides the rows."""
        reached = self.desc[lv.node_up]
        A = metric_value(self.metric, lv, f)
        self.metric.A[lv.node] = np.where(reached, A, np.nan)
        rows = self._descend(n, lv, A)
        self.stats.back_substituted += len(lv.node) if rows is None else len(rows)
        return rows

    def _descend(self, n, lv, A):
        """Descend into the nodes of level ``n`` whose parent was descended into and
        whose score exceeds ``threshold / kappa`` (threshold mode; in budget mode
        into all, :meth:`_run_heap` chooses). Returns the rows (``None``: all)."""
        if self.budget is not None:
            self.desc[lv.node] = True
            return None
        go = self.desc[lv.node_up] & ((self.score_A(A, lv.node) > self._keep)
                                      | self.pinned[lv.node])
        self.desc[lv.node] = go
        rows = np.flatnonzero(go)
        self._rows[n] = rows if len(rows) < len(go) else None
        return self._rows[n]

    def _drop_unselected(self):
        """``qdd = 0`` on the active joints not descended into; counts the rest."""
        keep = self.desc[self.act]
        self.stats.accelerated = int(keep.sum())
        self.data.qdd[:-1][~keep[self.dof_joint]] = 0.0

    def _run_heap(self):
        """Budget mode: pop the ``budget`` highest scores from a max-heap, from the
        roots down (active nodes count ``kappa`` times their score, front nodes
        their look-ahead score); active nodes not popped get ``qdd = 0``, front
        nodes popped are released after the step."""
        tree, nb = self.tree, self.model.nb
        self._popped = np.zeros(tree.n_nodes + 1, bool)
        la_score = {}
        if self.la is not None:
            la_score = dict(zip(self.la.F.tolist(), self.score_A(self.la.A, self.la.F).tolist(),
                                strict=True))

        def key(node):
            if self.active[node] and self.pinned[node]:
                return np.inf
            if self.active[node]:
                return self.kappa * float(self.score_A(self.metric.A[node], node))
            return la_score.get(node, -1.0)

        heap = [(-key(r), int(r)) for r in np.flatnonzero(tree.up == -1)
                if self.active[r] or r in la_score]
        heapq.heapify(heap)
        popped = self._popped
        count = 0
        while heap and (count < self.budget or heap[0][0] == -np.inf):
            _, node = heapq.heappop(heap)
            popped[node] = True
            count += 1
            if self.active[node]:
                for c in (tree.left[node - nb], tree.right[node - nb]):
                    if c >= nb and (self.active[c] or c in la_score):
                        heapq.heappush(heap, (-key(c), int(c)))
        self.desc[self.act] = popped[self.act]
        self._rows = [np.flatnonzero(popped[lv.node]) for lv in self.levels]

    def _lookahead(self, kin):
        """Score of releasing each internal front node's joint, its children rigid."""
        la, g, model = self.la, self.groups, self.model
        mobile = la.top >= 0
        R_F = np.broadcast_to(np.eye(3), (len(la.F), 3, 3)).copy()
        v_F = np.zeros((len(la.F), 6))
        R_F[mobile], v_F[mobile] = kin.R[la.top[mobile]], kin.v[la.top[mobile]]
        R_leaf = R_F[la.leaf_F]
        f = group_wrench(g, la.leaf_node, R_leaf @ la.TR, model.gravity)
        f = np.concatenate([mv(la.TR, f[:, :3]), mv(la.TR, f[:, 3:])], axis=1)
        rigid_leaves(la.lp, kin.R_rel, kin.p_rel, v_F[la.leaf_F], la.mass, la.com, la.inertia,
                     la.Iinv, f, la.data, la.fixed_R, la.fixed_p)
        tau = la.tau_springs
        if self._controller is not None:
            tau = tau + self._tau_full[la.js.v_index]
        assemble(la.levels, la.js, la.kin, np.append(tau, 0.0), la.data)
        for n, lv in enumerate(la.levels):
            f_ports = self.data.f_J[lv.port_joint] * lv.port_side[:, :, None]
            _, qdd = joint_solution(*la.data.levels[n], f_ports)
            la.A[la.rows[n]] = (la.D[lv.joint] * qdd**2).sum(axis=1)
        self.stats.lookahead = len(la.F)

    # --- region update ----------------------------------------------------------------

    def _update_region(self, q, qd):
        """Rigidify and release nodes after the step (threshold or budget rules)."""
        tree, js = self.tree, self.js
        qd_a = qd[js.v_index]
        v_own = np.bincount(self.dof_joint, self.wV_local * qd_a**2, minlength=js.k)
        for lv in self.levels:
            self.V[lv.node] = self.V[lv.node_A] + self.V[lv.node_B] + v_own[lv.joint]
        old = self.step_count - self.since >= self.dwell
        act = self.act
        up = np.where(tree.up[act] < 0, tree.n_nodes, tree.up[act])
        # candidates: the highest nodes not descended into that may be rigidified
        # (below a pinned node that was not descended into, its children are)
        cand = ((self.desc[up] | self.pinned[up]) & ~self.desc[act] & old[act]
                & ~self.pinned[act])
        if self.budget is None:                   # score_A is low: not descended into
            cand &= self.score_V(self.V[act], act) <= self._keep
        release = np.zeros(0, int)
        if self.la is not None:
            F = self.la.F
            parent_desc = self.desc[np.where(tree.up[F] < 0, tree.n_nodes, tree.up[F])]
            if self.budget is None:
                hit = self.score_A(self.la.A, F) > self.threshold
            else:
                hit = self._popped[F]
            release = F[parent_desc & hit & old[F]]
        rigid = np.zeros(tree.n_nodes + 1, bool)
        rigid[act[cand]] = True
        for lv in reversed(self.levels):                 # whole subtrees of candidates
            rigid[lv.node] |= rigid[lv.node_up]
        rigid[-1] = False
        newly = np.flatnonzero(rigid)
        built = self._rigidify(newly, q, qd) if len(newly) else False
        if len(release):
            self.active[release] = True
            self.since[release] = self.step_count
        if len(release) or (len(newly) and not built):
            self._build(q)
        self.stats.rigidified, self.stats.released = len(newly), len(release)

    def _rigidify(self, nodes, q, qd):
        """Lock the joints of ``nodes`` and freeze their groups at ``q``. Returns
        whether the region was rebuilt (the locking impulse needs it)."""
        tree, model = self.tree, self.model
        joints = tree.joint[nodes - model.nb]
        old = SimpleNamespace(js=self.js, front=self.front_mobile, top=self.front_top)
        self.groups.freeze(nodes, q)
        self.active[nodes] = False
        self.since[nodes] = self.step_count
        dofs = ranges(model.v_start[joints], model.nv_joint[joints])
        if self.policy == "momentum":
            kin_old = kinematics(model, q[old.js.q_index], qd[old.js.v_index], old.js)
            self._build(q)
            qd[dofs] = 0.0
            qd[self.js.v_index] = self._locking_impulse(q, old, kin_old)
            return True
        qd[dofs] = 0.0
        return False

    def _locking_impulse(self, q, old, kin_old):
        """Velocities of the active joints after the inelastic locking impulse
        (theory §6): the DCA with leaf ``b`` the groups' velocities from their
        momenta, ``c_J = 0`` and ``tau = 0``."""
        g, model = self.groups, self.model
        # momentum of every old group, moved to the new group that holds it
        G = old.front
        R_G, p_G = kin_old.R[old.top], kin_old.p[old.top]
        h = momentum_at_com(g, G, kin_old.v[old.top])
        L = mv(R_G, h[:, :3])
        P = mv(R_G, h[:, 3:])
        c_G = p_G + mv(R_G, g.com[G])
        new_of, _, _ = g.pose_in_group(self.tree.top[G], self.active)
        mob = self.front_mobile
        idx = np.full(self.tree.n_nodes + 1, -1)
        idx[mob] = np.arange(len(mob))
        k_new = idx[new_of]
        keep = k_new >= 0
        js = self.js
        kin = kinematics(model, q[js.q_index], np.zeros(js.nv), js)
        R_new = kin.R[self.front_top]
        c_new = kin.p[self.front_top] + mv(R_new, g.com[mob])
        Lsum = np.zeros((len(mob), 3))
        Psum = np.zeros((len(mob), 3))
        np.add.at(Psum, k_new[keep], P[keep])
        np.add.at(Lsum, k_new[keep], L[keep] + cross3(c_G[keep] - c_new[k_new[keep]],
                                                         P[keep]))
        RT = np.swapaxes(R_new, 1, 2)
        h_new = np.concatenate([mv(RT, Lsum), mv(RT, Psum)], axis=1)
        rigid_leaves(self.front_lp, kin.R_rel, kin.p_rel, np.zeros((len(mob), 6)), g.mass[mob],
                     g.com[mob], g.inertia[mob], g.Iinv[mob], h_new, self.data)
        still = SimpleNamespace(T=kin.T, W=kin.W, c=np.zeros_like(kin.c))
        assemble(self.levels, js, still, np.zeros(js.nv + 1), self.data)
        self.data.qdd[:] = 0.0
        back_substitute(self.levels, js, self.data)
        return self.data.qdd[:-1].copy()


def _active_levels(tree, active, jmap, k):
    """The tree's levels restricted to ``active`` nodes and re-batched by height
    within the active region (fronts at 0), so that a small region costs as many
    levels as it is deep, not as the tree; joints renumbered by ``jmap``."""
    height = np.zeros(tree.n_nodes + 1, int)
    pieces = []
    for lv in tree.levels:
        rows = np.flatnonzero(active[lv.node])
        if len(rows):
            L = lv.restrict(rows, jmap)
            height[L.node] = 1 + np.maximum(height[L.node_A], height[L.node_B])
            pieces.append(L)
    levels = []
    for h in range(1, int(height.max()) + 1 if pieces else 1):
        parts = []
        for L in pieces:
            rows = np.flatnonzero(height[L.node] == h)
            if len(rows):
                parts.append(L if len(rows) == len(L.node) else L.restrict(rows))
        if parts:
            levels += Level.merge(parts, k)
    return levels


def _leaf_plan(tree, nodes, jmap):
    """Leaf ports and port pairs of rigid ``nodes`` (a LeafPlan; ``body`` indexes
    ``nodes``, ``joint`` the local joint of each port)."""
    P = tree.n_ports[nodes]
    slots = ranges(tree.slot_base[nodes], P)
    leaf = np.repeat(np.arange(len(nodes)), P)
    first = np.cumsum(P) - P
    n_pairs = P * P
    pair_leaf = np.repeat(np.arange(len(nodes)), n_pairs)
    within = np.arange(int(n_pairs.sum())) - np.repeat(np.cumsum(n_pairs) - n_pairs, n_pairs)
    a, b = within // P[pair_leaf], within % P[pair_leaf]
    return LeafPlan(leaf, jmap[tree.slot_joint[slots]], tree.slot_side[slots] > 0, slots,
                    first[pair_leaf] + a, first[pair_leaf] + b,
                    tree.block_base[nodes][pair_leaf] + within)
