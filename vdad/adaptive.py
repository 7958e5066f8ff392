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

import time
from collections.abc import Sequence
from dataclasses import dataclass, field, fields

import numpy as np

from . import joints as J
from ._linalg import as_input, compiling
from ._pack import pack, pack_once
from .checks import (
    check_callable,
    check_count,
    check_flag,
    check_real,
    check_vector,
    check_wrenches,
    real_array,
)
from .dca import body_arrays, make_data
from .dynamics import default_tree
from .errors import InputError
from .forces import Forces, ForceTables, body_forces, state_bodies
from .hybrid import RigidGroups, group_poses
from .integrators import rk4
from .kinematics import Kinematics, plan
from .region import (
    ACCELERATED,
    ASSEMBLED,
    FRONT,
    LOOKAHEAD,
    N_JOINTS,
    N_VISIT,
    RELEASED,
    RIGIDIFIED,
    SOLVED,
    STEP_COUNTERS,
    RegionData,
    active_state_ok,
    cap_energy,
    change_region,
    euler_active,
    evaluate,
    lock_pruned,
    lookahead_due,
    rebuild,
    region_call,
    region_poses,
    resume_cap,
    rk4_active,
    take_kinematics,
    update_region,
)
from .visibility import idle_loop_coverage

POLICIES = ("momentum", "zero")
DROPS = ("coast", "lock")
METRICS = ("direct", "coefficients")
ENERGIES = ("cap", "free")
PHASES = ("visibility", "forces", "dynamics", "integrate", "region", "steps")


@dataclass
class StepStats:
    """Counters of one adaptive step.

    active_joints: joints in the active region (articulated); accelerated: joints
    whose ``qdd`` was computed; front: rigid groups at the front; assembled /
    back_substituted: nodes evaluated by the two passes; force_update: node
    visits carrying force changes up rigid regions; lookahead: front joints
    evaluated; rigidified / released: nodes that changed state; times: seconds
    per phase (:data:`PHASES`; ``visibility``: the coverage ``N_M`` evaluated from
    Python; ``steps``: the rest of a step run in compiled code,
    :meth:`AdaptiveDynamics.run`, whose phases are not timed apart, bounding-volume
    coverage evaluated there included).
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


#: the columns of ``region_steps``' counters in the order of StepStats' fields
_COUNTER_COLUMNS = np.array([STEP_COUNTERS.index(f.name) for f in fields(StepStats)
                             if f.name != "times"])
#: ... and of the nodes a step rigidified and released
_CHANGES = (STEP_COUNTERS.index("rigidified"), STEP_COUNTERS.index("released"))


class History(Sequence):
    """The :class:`StepStats` of every adaptive step, in order (a read-only
    sequence; slices are lists). The compiled steps hand in their counters as
    blocks (:meth:`add_block`), turned into StepStats only when read: building
    them cost 0.8 µs a step, 5 % of a 20-body step. A step's StepStats equals
    the adaptive dynamics' ``stats`` after it."""

    def __init__(self):
        self._stats = []               # StepStats of the steps read so far
        self._pending = []             # blocks and StepStats not yet read

    def append(self, stats):
        """One step's :class:`StepStats`."""
        self._pending.append(stats)

    def add_block(self, rows, seconds, visibility):
        """Steps of :meth:`AdaptiveDynamics.run`: their counters ``rows`` (k, 9) in
        the order of ``vdad.region.STEP_COUNTERS``, ``seconds`` per step and the
        coverage ``visibility`` (s) timed before the first (:func:`block_stats`)."""
        self._pending.append((rows, seconds, visibility))

    def _read(self):
        for item in self._pending:
            if isinstance(item, StepStats):
                self._stats.append(item)
                continue
            self._stats.extend(block_stats(*item))
        self._pending.clear()
        return self._stats

    def __len__(self):
        return len(self._stats) + sum(1 if isinstance(item, StepStats) else len(item[0])
                                      for item in self._pending)

    def __getitem__(self, k):
        return self._read()[k]

    def __iter__(self):
        return iter(self._read())

    def __repr__(self):
        return f"History({len(self)} steps)"


def block_stats(rows, seconds, visibility):
    """The :class:`StepStats` of steps run in compiled code (:meth:`History.add_block`)."""
    return [StepStats(*row, times=step_times(seconds, visibility if k == 0 else 0.0))
            for k, row in enumerate(rows[:, _COUNTER_COLUMNS].tolist())]


def step_times(seconds, visibility):
    """The :attr:`StepStats.times` of a step run in compiled code."""
    times = dict.fromkeys(PHASES, 0.0)
    times["steps"], times["visibility"] = seconds, visibility
    return times


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


class AdaptiveDynamics:
    """Adaptive forward dynamics of ``model`` on an assembly ``tree`` (work state;
    the compiled passes are :mod:`vdad.region`).

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
    lookahead: release front joints whose look-ahead score is high;
    lookahead_every: take the look-ahead (and its releases) only at the steps
    whose number is a multiple of it (a front joint waits up to that many steps
    more for its release; ``docs/adaptive.md``).
    drop: what becomes of the active joints a step does not accelerate:
    ``"lock"`` (default: they are rigidified at once, by ``policy``, and the step's
    dynamics re-evaluated on the smaller region: always an exact constrained
    system, whose locking can only remove energy) or ``"coast"`` (the paper: they
    keep their velocity with ``qdd = 0`` while the rest follows the full
    dynamics, which can feed energy in; ``docs/adaptive.md``).
    metric: ``"coefficients"`` predicts ``A(C)`` from (T16)-(T18) before any
    ``qdd`` is computed and back-substitutes only the nodes it descends into (the
    paper's algorithm); ``"direct"`` back-substitutes the whole active region and
    sums (T14) bottom-up: the same values and decisions, and cheaper on the
    compiled core, where the coefficients cost more in the bottom-up pass than
    the back-substitution they save (``docs/adaptive.md``). On models with thin or
    light bodies, whose accelerations are refined on the hybrid ((R6) of
    ``docs/accuracy.md``), always ``"direct"``: the coefficients would predict
    the accelerations of the raised leaves, and the refinement solves every
    active node anyway.
    energy: ``"cap"`` (default) or ``"free"``. With ``"cap"``, where the step's
    forces are gravity and joint damping only (no joint springs, force elements,
    ``controller`` or ``external``), the total energy never rises above that of
    the state the steps started from (or were last handed in changed): a step
    that ends above it scales the active joints' velocities down to it (the
    semi-implicit integrator's drift on the hybrid, ``docs/adaptive.md``, "The
    energy cap"); elsewhere, and with ``"free"``, nothing is changed.
    coverage: None (``N_M = 1``: view-independent) or an estimator
    ``(t, q, adaptive) -> N_M`` per node (:mod:`vdad.visibility`), evaluated
    every ``coverage_every`` steps and, unless its ``covers_every_node`` is
    true, whenever the active region changes.
    """

    def __init__(self, model, dt, tree=None, threshold=None, budget=None, weights=None,
                 velocity_weights=None, kappa=4.0, dwell=10, policy="momentum", lookahead=True,
                 lookahead_every=1, drop="lock", metric="direct", energy="cap", coverage=None,
                 coverage_every=1):
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
        if drop not in DROPS:
            raise InputError(f"unknown drop scheme {drop!r}; choose one of {DROPS}")
        self.drop = drop
        if metric not in METRICS:
            raise InputError(f"unknown metric evaluation {metric!r}; choose one of {METRICS}")
        self.predictive = metric == "coefficients" and body_arrays(model)[12] == 0
        if energy not in ENERGIES:
            raise InputError(f"unknown energy option {energy!r}; choose one of {ENERGIES}")
        self.energy = energy
        check_callable("coverage", coverage, "(t, q, adaptive) -> N_M")
        coverage_every = check_count("coverage_every", coverage_every)
        if coverage is None and coverage_every != 1:
            raise InputError("coverage_every applies to a coverage estimate (the view-dependent "
                             "methods); plain adaptive dynamics has none")
        self.coverage, self.coverage_every = coverage, int(coverage_every)
        self.model = model
        self.tree = tree = default_tree(model) if tree is None else tree
        self.dt = float(dt)
        self.threshold = None if threshold is None else float(threshold)
        self.budget = None if budget is None else int(budget)
        self.kappa, self.dwell, self.policy = float(kappa), int(dwell), policy
        self.lookahead = check_flag("lookahead", lookahead)
        self.lookahead_every = check_count("lookahead_every", lookahead_every)
        self.wA = resolve_weights(model, weights, "weights")
        self.wV = self.wA if velocity_weights is None else resolve_weights(
            model, velocity_weights, "velocity_weights")
        nb, n = model.nb, tree.n_nodes
        self.groups = RigidGroups(tree)
        self.region = r = RegionData.empty(tree, self.wA, self.wV)
        r.active[nb:] = True                            # sentinel n: above the roots
        r.desc[n] = True
        # a free joint to the world is never rigidified: welding a floating base to
        # the world would stop it (and take its momentum); so are its ancestors
        floating = np.flatnonzero((model.parent < 0) & (model.nv_joint == 6))
        node = nb + np.flatnonzero(np.isin(tree.joint, floating))
        while len(node):
            r.pinned[node] = True
            node = tree.up[node]
            node = node[node >= 0]
        self.data = make_data(tree, keep_blocks=True)
        self.kin = self.data.kin
        self._pose_kin = Kinematics.empty(plan(model))
        # the step's force sources (controller, external, compiled tables) and the
        # work arrays of the compiled ones (every body's kinematics and states; the
        # joints whose placement the kinematics hold, vdad.region.region_steps)
        self._sources = (None, None, None)
        self._force_work = (Kinematics.empty(plan(model)), np.empty((2, nb, 3)),
                            np.empty((nb, 6)), np.empty(model.nv), np.zeros(nb, np.bool_))
        self._force_key, self._force_order = None, None
        self._force_F = None                            # the tables of _force_order
        self._roots = np.flatnonzero(tree.up == -1).astype(np.int64)
        self._top = np.asarray(tree.top, np.int64)
        self._stack = np.zeros((3, n + 2), np.int64)
        self._zero_tau = np.zeros(model.nv)
        self._kq, self._kv = np.zeros((4, model.nq)), np.zeros((4, model.nv))
        self._stale_coverage = True
        self._idle_coverage = idle_loop_coverage(tree)
        # the energy cap: (cap, removed, T, U), whether it can apply, the state left
        self._energy = np.array([np.inf, 0.0, 0.0, 0.0])
        self._cappable = energy == "cap" and not np.any(plan(model).stage_stiffness)
        self._left = (np.full(model.nq, np.nan), np.full(model.nv, np.nan))
        # run(): the arguments of region_steps that are this object's same arrays at
        # every call, packed at the first (region_call): the groups' arrays and force
        # sums; the force work; the state before a step and the counters; no forces
        g = self.groups
        self._loop_args = (
            (g.arrays, self._top, g.up, self._roots, (g.f_ext, g.pending, g.mark, g.order, g.is_B)),
            (self._force_work[0].arrays, *self._force_work[1:]),
            (self.kin.arrays, self.data.arrays, r.arrays, self._stack,
             (np.empty(model.nq), np.empty(model.nv)),
             np.zeros((512, len(STEP_COUNTERS)), np.int64)),
            ForceTables(Forces(model, [])).arrays(0, 1, 1.0, False))
        # run()'s packs: its constants; (key, pack) pairs of the forces and volumes
        self._packs = (None, None, None)
        self.step_count = 0
        self.stats = StepStats()
        self._rebuild()

    def __getstate__(self):
        """A copy (``copy.deepcopy``, pickle) leaves the packs of :meth:`run` out:
        numba cannot copy them, and they hold this object's arrays."""
        return {**self.__dict__, "_packs": (None, None, None)}

    @property
    def stats(self):
        """The :class:`StepStats` of the last step (built when read after compiled
        steps, :meth:`run`)."""
        if self._stats is None:
            rows, seconds, visibility = self._last_block
            self._stats = block_stats(rows[-1:], seconds,
                                      visibility if len(rows) == 1 else 0.0)[0]
        return self._stats

    @stats.setter
    def stats(self, value):
        self._stats = value

    # --- state --------------------------------------------------------------------------

    @property
    def active(self):
        """Node mask (n_nodes + 1,): internal nodes whose joints are articulated."""
        return self.region.active

    @property
    def since(self):
        """Step of each node's last change of state (n_nodes + 1,)."""
        return self.region.since

    @property
    def V(self):
        """Velocity metric (T15) of the active nodes after the last step."""
        return self.region.V

    @property
    def A(self):
        """Acceleration metric (T16) of the nodes reached by the last step's
        top-down pass (NaN elsewhere among the active nodes)."""
        return self.region.A

    @property
    def la(self):
        """Look-ahead metric of each front node whose parent was descended into
        and, in threshold mode, that kept its state ``dwell`` steps (NaN for the
        others)."""
        return self.region.la

    @property
    def N_M(self):
        """Coverage per node (pixels; 1 without an estimator)."""
        return self.region.N_M

    @property
    def pinned(self):
        return self.region.pinned

    @property
    def visit(self):
        """The active nodes and their front in depth-first post-order (children first)."""
        return self.region.visit[:self.region.counts[N_VISIT]]

    @property
    def group_frames(self):
        """``(visit, n_visit, active, grounded, top, rel_R, rel_p)``: the region's
        front and its rigid groups' frames, as :func:`vdad.hybrid.group_poses`
        takes them."""
        r, g = self.region, self.groups
        return (r.visit, int(r.counts[N_VISIT]), r.active, g.grounded, self._top, g.rel_R,
                g.rel_p)

    @property
    def front(self):
        """The rigid groups at the front of the active region (node ids, ascending)."""
        v = self.visit
        return np.sort(v[~self.active[v] | (v < self.model.nb)])

    @property
    def act(self):
        """The active nodes (ascending)."""
        v = self.visit
        return np.sort(v[self.active[v] & (v >= self.model.nb)])

    @property
    def joints(self):
        """The active joints, ascending."""
        return self.region.joints[:self.region.counts[N_JOINTS]].copy()

    def active_dofs(self):
        """Velocity indices (ascending) of the active joints' dofs."""
        m, j = self.model, self.joints
        if not len(j):
            return np.zeros(0, int)
        return np.concatenate([np.arange(m.v_start[k], m.v_start[k] + m.nv_joint[k]) for k in j])

    def state_ok(self, q, qd, rotational):
        """Whether a step left the active joints' ``q``, ``qd`` finite and turned no
        ``rotational`` (nv,) dof by more than half a turn (``region.active_state_ok``:
        the simulator's checks, on the joints a step changes)."""
        with compiling(active_state_ok):
            return active_state_ok(self.dt, plan(self.model).arrays, body_arrays(self.model),
                                   self.region.arrays, rotational, q, qd)

    def _args(self):
        return (plan(self.model).arrays, self.tree.arrays, body_arrays(self.model),
                self.groups.arrays, self._top, self.groups.up, self._roots)

    def _rebuild(self):
        with compiling(rebuild):
            rebuild(self.model.nb, self.tree.arrays, plan(self.model).arrays, self.groups.arrays,
                    self._top, self._roots, self.region.arrays, self._stack)
        self._stale_coverage = True

    def rigidify(self, nodes, q, qd):
        """Lock the internal ``nodes`` (a union of whole subtrees of active nodes) at
        ``q``: freeze their groups, zero their joints' velocities in ``qd`` (in
        place; the paper's policy) and rebuild the region."""
        nodes = np.asarray(sorted(nodes), np.int64)
        self.groups.freeze(nodes, np.asarray(q, float), self.kin)
        m = self.model
        for j in self.tree.joint[nodes - m.nb]:
            qd[m.v_start[j]:m.v_start[j] + m.nv_joint[j]] = 0.0
        self.region.active[nodes] = False
        self.region.since[nodes] = self.step_count
        self._rebuild()

    # --- poses --------------------------------------------------------------------------

    def body_poses(self, q, bodies=None):
        """World poses ``R`` (k, 3, 3), ``p`` (k, 3) of ``bodies`` (default: all) at
        ``q``: each body's pose in its rigid group composed with the group's pose
        from the active joints only (all: :func:`~vdad.hybrid.group_poses`; some:
        :meth:`RigidGroups.pose_in_group`; compiled)."""
        kin = self.front_kinematics(q)
        if bodies is None:                      # top-down from the front: O(bodies)
            tree, nb = self.tree, self.model.nb
            R, p = np.empty((tree.n_nodes + 1, 3, 3)), np.empty((tree.n_nodes + 1, 3))
            with compiling(group_poses):
                group_poses(nb, tree.arrays[0], tree.arrays[1],
                            (tree.arrays[13], tree.arrays[14]), *self.group_frames, kin.R, kin.p,
                            R, p, np.empty((3, 3)))
            return R[:nb], p[:nb]
        bodies = np.asarray(bodies, int)
        _, R, p = self.groups.pose_in_group(bodies, self.active, (self._top, kin.R, kin.p))
        return R, p

    def front_kinematics(self, q):
        """The :class:`Kinematics` of the active joints at ``q`` (placements and
        poses only, ``region.region_poses``): ``R``, ``p`` of each active joint's
        child body, the frames of the front groups (through :attr:`top`)."""
        kin = self._pose_kin
        with compiling(region_poses):
            region_poses(plan(self.model).arrays, self.region.arrays, as_input(q), kin.arrays)
        return kin

    @property
    def top(self):
        """The top body of every node (the body whose parent is outside it; -1 for
        a node holding the ground), int64."""
        return self._top

    # --- one step -------------------------------------------------------------------------

    def score_A(self, A, nodes):
        """``dt^2 N_M sqrt(A)`` of ``nodes``: the displacement per step their
        accelerations cause, times their coverage (Kim 2008 §5.2, ``A_M``)."""
        return self.dt**2 * self.N_M[nodes] * np.sqrt(np.maximum(A, 0.0))

    def score_V(self, V, nodes):
        """``dt N_M sqrt(V)`` of ``nodes``: the displacement per step their
        velocities cause, times their coverage (Kim 2008 §5.2, ``V_M``)."""
        return self.dt * self.N_M[nodes] * np.sqrt(np.maximum(V, 0.0))

    @property
    def _keep(self):
        """Score an active node needs to keep its accelerations: ``threshold / kappa``."""
        return 0.0 if self.threshold is None else self.threshold / self.kappa

    def accelerations(self, t, q, qd, tau=None, f_ext=None, first=True):
        """``qdd`` (nv,) of the current region at ``(q, qd)`` (full vectors, rigid
        joints frozen), zero on rigid and coasting joints, for joint forces ``tau``
        (nv,) and external wrenches ``f_ext`` (nb, 6) (None: none). ``first``: take
        the step's decisions (pruning, look-ahead, budget), as a step's first
        evaluation does; else reuse them."""
        self.stats.force_update += self.groups.update_forces(f_ext, self.active)
        self._evaluate(first, as_input(q), as_input(qd),
                       self._zero_tau if tau is None else as_input(tau))
        return self.data.qdd.copy()

    def _evaluate(self, first, q, qd, tau, placed=False, reuse=False):
        """The compiled evaluation (``vdad.region.evaluate``; ``placed``: ``kin``
        holds the active joints' kinematics at ``(q, qd)``; ``reuse``: the blocks of
        the last evaluation, at the same ``q``, hold where the region did not change
        this step); an InputError naming the joint if ``qdd`` is not finite."""
        budget = 0 if self.budget is None else self.budget
        with compiling(evaluate):
            ok = evaluate(first, self.predictive, budget, False, placed, reuse,
                          self._lookahead_at(self.step_count + 1),
                          self.drop == "lock", self.step_count + 1, self.dwell, self.dt,
                          self._keep, self.kappa, self.model.nb, *self._args()[:4], self._top,
                          self.groups.up, self._roots, q, qd, tau, self.kin.arrays,
                          self.data.arrays,
                          self.region.arrays)
        if not ok:
            raise self.not_finite()

    def not_finite(self):
        """The InputError of an evaluation whose ``qdd`` is not finite, naming the
        first joint where it is not."""
        bad = np.flatnonzero(~np.isfinite(self.data.qdd))
        joint = self.model.joint_names[self.model.dof_joint[bad[0]]] if len(bad) else "?"
        return InputError(f"the accelerations became non-finite at joint {joint!r}")

    def force_joints(self, F):
        """The joint set (:attr:`~vdad.kinematics.JointSet.arrays`) whose kinematics
        the built-in forces of the tables ``F`` read: the bodies that springs, drag
        and contact act on, and their ancestors, parents first (pulses and joint
        limits read no body state). The DCA's step places every body anyway; an
        adaptive step places only the active joints' bodies, so its forces place
        only these (on the 100 dogs, 100 torsos instead of 1600 bodies)."""
        if F is not self._force_F:                      # new tables (the same: no forces)
            self._force_order = self._force_bodies(state_bodies(F))
            self._force_F = F
        # the model's own arrays beside it (a deep copy's would be writable, and
        # numba would compile the kernels again for them)
        return (self._force_order, *plan(self.model).arrays[1:])

    def _force_bodies(self, rows):
        """The joints placed for forces on the bodies ``rows``, parents first."""
        key = rows.tobytes()
        if key != self._force_key:
            js, need = plan(self.model), np.zeros(self.model.nb, bool)
            need[rows] = True
            for j in js.order[::-1]:                    # children before their parents
                if need[j] and self.model.parent[j] >= 0:
                    need[self.model.parent[j]] = True
            self._force_key = key
            self._force_order = np.ascontiguousarray(js.order[need[js.order]], np.int64)
        return self._force_order

    def _forces(self, t, q, qd, k):
        """``tau``, ``f_ext`` (None: zero) of the step's sources at evaluation ``k``
        of the step (RK4: 0-3): the compiled tables (:func:`vdad.forces.body_forces`)
        if given, else the Python callables."""
        controller, external, tables = self._sources
        if tables is not None:
            F, e = tables
            kin, states, f_ext, tau, fresh = self._force_work
            js = self.force_joints(F)
            with compiling(body_forces):
                body_forces(js, F, e + k, t, q, qd, kin.arrays, states, f_ext, tau)
            fresh[:] = False                            # the joints kin holds (_stage)
            fresh[js[0]] = True
            return tau, f_ext
        tau = f_ext = None
        if controller is not None:
            tau = np.array(check_vector("controller(t, q, qd)", controller(t, q, qd),
                                        self.model.nv))
        if external is not None:
            f_ext = check_wrenches(self.model, external(t, q, qd), "external(t, q, qd)")
        return tau, f_ext

    def step(self, t, q, qd, integrate, controller=None, external=None, tables=None):
        """Advance ``(q, qd)`` (full vectors, updated in place) by one step of
        ``integrate`` (:func:`vdad.integrators.semi_implicit_euler` or
        :func:`vdad.integrators.rk4`, on the active joints): :meth:`advance`, then
        :meth:`update`, then the energy cap (``energy="cap"``). Returns the step's
        :class:`StepStats`."""
        forced = controller is not None or external is not None or tables is not None
        self._cap_from(q, qd, forced)
        self.advance(t, q, qd, integrate, controller, external, tables)
        st = self.update(q, qd)
        self._cap(q, qd)
        return st

    @property
    def energy_cap(self):
        """The energy (J) that steps may not exceed (``energy="cap"``), or None
        where the cap does not apply (the last steps had forces that do work)."""
        cap = self._energy[0]
        return float(cap) if np.isfinite(cap) else None

    @property
    def energy_removed(self):
        """Energy (J) the cap has taken out over all steps so far."""
        return float(self._energy[1])

    def energy_of(self, q, qd):
        """Kinetic plus gravitational energy of the hybrid at ``(q, qd)``, with the
        rotors', in O(active joints + front) (``vdad.region.hybrid_energy``): the
        total energy of a state whose rigid joints have ``qd = 0``, less the joint
        springs' potential. The energy cap's measure."""
        out = np.array([np.nan, 0.0, 0.0, 0.0])
        with compiling(cap_energy):
            cap_energy(out, self.model.nb, plan(self.model).arrays, body_arrays(self.model),
                       self.groups.arrays, self._top, self.region.arrays, q, qd,
                       self.kin.arrays)
        return float(out[0])

    def _cap_from(self, q, qd, forced):
        """The cap for steps from ``(q, qd)`` (:func:`vdad.region.resume_cap`):
        none under forces that do work or with ``energy="free"``; the energy of
        ``(q, qd)`` unless it is the state the last capped steps left."""
        with compiling(resume_cap):
            resume_cap(forced or not self._cappable, self._energy, self._left, self.model.nb,
                       plan(self.model).arrays, body_arrays(self.model), self.groups.arrays,
                       self._top, self.region.arrays, q, qd, self.kin.arrays)

    def _cap(self, q, qd):
        """:func:`vdad.region.cap_energy` on ``(q, qd)`` (in place); keeps the state."""
        if self._energy[0] == np.inf:
            return
        with compiling(cap_energy):
            cap_energy(self._energy, self.model.nb, plan(self.model).arrays,
                       body_arrays(self.model), self.groups.arrays, self._top,
                       self.region.arrays, q, qd, self.kin.arrays)
        self._left[0][:], self._left[1][:] = q, qd

    def advance(self, t, q, qd, integrate, controller=None, external=None, tables=None):
        """The dynamics and integration of a step, in place, on the current region
        (the coverage first, if due); the region update is :meth:`update`. Forces
        from the Python callables ``controller`` and ``external``, or, in their
        place, from ``tables`` = ``(F, e)``: the arrays of
        :meth:`vdad.forces.ForceTables.arrays` and the index of the step's first
        evaluation in them (RK4 evaluates ``e`` to ``e + 3``)."""
        self._sources = (controller, external, tables)
        r = self.region
        self.stats = st = StepStats(active_joints=int(r.counts[N_JOINTS]),
                                    front=int(r.counts[FRONT]))
        if self.coverage is not None and (self._stale_coverage
                                          or self.step_count % self.coverage_every == 0):
            t0 = time.perf_counter()
            r.N_M[:] = self._checked_coverage(t, q)
            self._stale_coverage = False
            st.times["visibility"] = time.perf_counter() - t0
        js, bodies = plan(self.model).arrays, body_arrays(self.model)
        qdd = self.data.qdd
        self._stage(st, True, t, q, qd)                              # the step's decisions
        if self.drop == "lock" and r.counts[ACCELERATED] < r.counts[ASSEMBLED]:
            t0 = time.perf_counter()
            with compiling(lock_pruned):
                nc = lock_pruned(self.model.nb, self.groups.up, r.arrays, self._stack)
            st.rigidified += self._change(nc, 0, self.step_count + 1, q, qd, reuse=True)[0]
            st.times["region"] += time.perf_counter() - t0
            st.active_joints, st.front = int(r.counts[N_JOINTS]), int(r.counts[FRONT])
            self._stage(st, False, t, q, qd, reuse=True)
        t0, inner = time.perf_counter(), st.times["forces"] + st.times["dynamics"]
        if integrate is rk4:
            qs, vs = q.copy(), qd.copy()
            for k in range(4):
                rk4_active(k, self.dt, js, bodies, r.arrays, q, qd, qdd, self._kq, self._kv,
                           qs, vs)
                if k > 0:
                    h = self.dt if k == 3 else self.dt / 2
                    self._stage(st, False, t + h, qs, vs, k)
            rk4_active(4, self.dt, js, bodies, r.arrays, q, qd, qdd, self._kq, self._kv, qs, vs)
        else:
            euler_active(self.dt, js, bodies, r.arrays, q, qd, qdd)
        st.times["integrate"] += (time.perf_counter() - t0
                                  - (st.times["forces"] + st.times["dynamics"] - inner))
        c = r.counts
        st.assembled, st.back_substituted = int(c[ASSEMBLED]), int(c[SOLVED])
        st.accelerated, st.lookahead = int(c[ACCELERATED]), int(c[LOOKAHEAD])

    def update(self, q, qd):
        """The region update after :meth:`advance` (``vdad.region.update_region``):
        rigidify and release nodes, with the locking impulse on ``qd`` (in place)
        under the momentum policy. Returns the step's :class:`StepStats`."""
        r, st = self.region, self.stats
        t0 = time.perf_counter()
        self.step_count += 1
        with compiling(update_region):
            nc, nr = update_region(
                self.step_count, 0 if self.budget is None else self.budget,
                self._lookahead_at(self.step_count),
                self.dt, np.inf if self.threshold is None else self.threshold, self._keep,
                self.dwell, self.model.nb, plan(self.model).arrays, self.tree.arrays,
                self.groups.up, qd, r.arrays, self._stack)
        rigidified, released = self._change(nc, nr, self.step_count, q, qd)
        st.rigidified += rigidified
        st.released += released
        st.times["region"] += time.perf_counter() - t0
        return st

    def run(self, n, time0, q, qd, rotational, tables=None, history=None):
        """Up to ``n`` steps of semi-implicit Euler in compiled code
        (``vdad.region.region_steps``), ``q``, ``qd`` (full vectors) in place, the
        first at simulator step ``time0`` (``t = time0 dt``): as many calls of
        :meth:`step` and of the simulator's checks, with no Python between them.
        The coverage, when it is due, is evaluated first; the call then stops
        before the next evaluation is due (every ``coverage_every`` steps, and
        after a step that changed the region). Forces: the built-in elements of
        ``tables`` = ``(F, e0)`` (as :meth:`advance`; None: none). Adds each
        step's :class:`StepStats` to ``history`` (a :class:`History`). Returns ``(steps done,
        status, q_last, qd_last)``: status 0, or 1 if the next step's
        accelerations were not finite, 2 if its state failed the checks (``q``,
        ``qd`` hold that state, ``q_last``, ``qd_last`` the one before; the step
        counts as done for adaptive dynamics, as :meth:`step` would)."""
        head, force_work, tail, no_forces = self._loop_args
        last, counters = tail[-2:]
        F, e0 = (no_forces, 0) if tables is None else tables
        options = (self.predictive, 0 if self.budget is None else self.budget,
                   self._lookahead_steps,
                   self.drop == "lock", self.policy == "momentum", self.dwell, self.dt,
                   self._keep, self.kappa, np.inf if self.threshold is None else self.threshold)
        r, vis, m = self.region, 0.0, min(n, len(counters))
        coverage, estimator = self._idle_coverage, None
        if self.coverage is not None:
            first = -self.step_count % self.coverage_every        # the next frame's step
            due = list(range(first, m, self.coverage_every))
            if self._stale_coverage and first > 0:             # stale: evaluated at once
                due.insert(0, 0)
            loop = getattr(self.coverage, "loop_coverage", None)
            times = [(time0 + s) * self.dt for s in due]
            in_loop = None if loop is None else loop(due, times, self)
            if in_loop is not None:             # bounding volumes, in the compiled steps
                coverage, estimator, self._stale_coverage = in_loop, self.coverage, False
            else:
                if due and due[0] == 0:
                    t0 = time.perf_counter()
                    r.N_M[:] = self._checked_coverage(time0 * self.dt, q)
                    self._stale_coverage = False
                    vis = time.perf_counter() - t0
                m = min(m, self.coverage_every - self.step_count % self.coverage_every)
        constants, forces, volumes = self._packs
        if constants is None:       # with the model's (a deep copy's would be writable)
            constants = pack((self.model.nb, plan(self.model).arrays, self.tree.arrays,
                              body_arrays(self.model), *head, force_work, self._energy,
                              self._left, *tail))
        forces = pack_once(forces, F, lambda: (F, self.force_joints(F)))
        volumes = pack_once(volumes, estimator, lambda: coverage[0])
        self._packs = (constants, forces, volumes)
        cap_off = tables is not None or self.groups.any_force or not self._cappable
        t0 = time.perf_counter()
        with compiling(region_call):
            done, status = region_call(
                constants, forces[1], volumes[1], coverage[1], m, self.step_count, time0, e0,
                self._refresh_on_change, options, tables is not None, cap_off, rotational, q,
                qd)
        rows = done + (status == 2)
        each = (time.perf_counter() - t0) / max(rows, 1)
        if rows:
            block = counters[:rows].copy()
            self._stats, self._last_block = None, (block, each, vis)
            if history is not None:
                history.add_block(block, each, vis)
            row = block[-1]
            if row[_CHANGES[0]] or row[_CHANGES[1]]:
                self._stale_coverage = self._refresh_on_change
        self.step_count += rows
        if tables is not None:
            self.groups.any_force = bool(self.groups.f_ext.any())
        return done, status, last[0], last[1]

    def _change(self, nc, nr, step, q, qd, reuse=False):
        """Rigidify the ``nc`` candidates and release the ``nr`` front nodes that
        ``update_region`` or ``lock_pruned`` left in the stack, with the locking
        impulse on ``qd`` under the momentum policy (``vdad.region.change_region``,
        then ``evaluate`` with ``impulse``; ``reuse``: the step's evaluation before
        the change was at this ``q``). Returns (nodes rigidified, nodes released)."""
        if nc + nr == 0:
            return 0, 0
        r, momentum = self.region, self.policy == "momentum"
        with compiling(change_region):
            change_region(nc, nr, step, momentum, self.model.nb, plan(self.model).arrays,
                          self.tree.arrays, self.groups.arrays, self._top, self._roots, q, qd,
                          self.kin.arrays, r.arrays, self._stack)
        if nc and momentum:                     # the locking impulse on qd
            with compiling(evaluate):
                evaluate(False, self.predictive, 0, True, False, reuse, False, False, step, 0,
                         self.dt, 0.0, 1.0, self.model.nb, *self._args()[:4], self._top,
                         self.groups.up, self._roots, q, qd, qd, self.kin.arrays,
                         self.data.arrays, r.arrays)
        self._stale_coverage = self._stale_coverage or self._refresh_on_change
        return int(r.counts[RIGIDIFIED]), int(r.counts[RELEASED])

    @property
    def _lookahead_steps(self):
        """The steps between look-aheads (0: none)."""
        return self.lookahead_every if self.lookahead else 0

    def _lookahead_at(self, step):
        """Whether step number ``step`` takes the look-ahead
        (``vdad.region.lookahead_due``, the compiled steps' rule)."""
        return bool(lookahead_due(self._lookahead_steps, step))

    @property
    def _refresh_on_change(self):
        """Whether a region change needs the coverage anew: an estimator that gives
        only the region's nodes (``covers_every_node`` False or absent) leaves the
        new front without values; one that gives every node keeps its frame's."""
        return self.coverage is not None and not getattr(self.coverage, "covers_every_node",
                                                         False)

    def _stage(self, st, first, t, q, qd, k=0, reuse=False):
        """Evaluation ``k`` of a step: forces (:meth:`_forces`), then the passes
        (``reuse``: :meth:`_evaluate`'s)."""
        t0 = time.perf_counter()
        tau, f_ext = self._forces(t, q, qd, k)
        st.force_update += self.groups.update_forces(f_ext, self.active)
        t1 = time.perf_counter()
        st.times["forces"] += t1 - t0
        placed = False
        if self._sources[2] is not None:    # the active joints' kinematics from the forces'
            fkin, fresh = self._force_work[0], self._force_work[4]
            with compiling(take_kinematics):
                placed = take_kinematics(plan(self.model).arrays, self.region.arrays, fresh,
                                         fkin.arrays, self.kin.arrays)
        self._evaluate(first, q, qd, self._zero_tau if tau is None else tau, placed, reuse)
        st.times["dynamics"] += time.perf_counter() - t1

    def _checked_coverage(self, t, q):
        N = real_array("coverage(t, q, adaptive)", self.coverage(t, q, self))
        if N.shape != (self.tree.n_nodes + 1,):
            raise InputError(f"coverage must return ({self.tree.n_nodes + 1},) values per "
                             f"node, got shape {N.shape}")
        if np.any(N < 0):                        # NaN: a node inside a rigid group, unused
            raise InputError(f"coverage returned negative pixel counts (node "
                             f"{np.flatnonzero(N < 0)[0]})")
        return np.nan_to_num(N, nan=0.0)
