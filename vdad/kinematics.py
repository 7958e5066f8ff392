"""Joint and body kinematics, one joint at a time in topological order (theory §3).

* Joint level ((T4)-(T5), (J1) of :mod:`vdad.joints`): each joint's child pose in
  its parent's frame, its motion subspace ``S`` in the child frame, the
  complements ``T`` and ``W``, and the velocity-product term ``c_J``.
* Body level: world poses and body velocities, parent before child.

Everything runs on a :class:`JointSet`: a set of joints with its own state layout
(``q``, ``qd`` of its joints only) and its own forest. :func:`plan` is the set of
all joints of a model; adaptive dynamics (:mod:`vdad.adaptive`) builds the set of
active joints, whose "bodies" are the rigid groups hanging from them (theory §6),
by :func:`joint_set` with a constant pre-placement per joint.

The sets are built in numpy once; :func:`kinematics_pass` is a compiled loop
over the joints calling one kernel per step of theory §3. Joint arrays are padded
to 6 columns: ``S``/``W`` (k, 6, 6) hold their ``d`` real columns first, ``T``
its ``6 - d`` real columns first; padding is zero.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property, lru_cache

import numpy as np

from . import joints as J
from ._linalg import (
    as_input,
    axis_angle_rotation,
    compiling,
    complement,
    cross_motion_add,
    inlined,
    kernel,
    mm3,
    motion_to_child,
    mv3,
    pass_kernel,
    quaternion_rotation,
)


def ranges(starts, lengths):
    """Concatenated ``arange(s, s + l)`` for every pair (vectorised)."""
    starts, lengths = np.asarray(starts, int), np.asarray(lengths, int)
    offsets = np.cumsum(lengths) - lengths
    return np.repeat(starts - offsets, lengths) + np.arange(int(lengths.sum()))


@dataclass(frozen=True)
class JointSet:
    """A set of ``k`` joints with a local state layout and forest (shapes in brackets).

    joints [k]: model joint ids; parent [k]: local parent (-1: world); order [k]:
    the joints parents first; root_of [k]: root of each joint's tree.
    R0 [k,3,3], p0 [k,3]: the joint frame in the local parent's frame (the
    placement). q_index [nq], v_index [nv]: model indices of the local ``q``
    and ``qd``; q_start, v_start, nv_joint [k]: the local layout per joint.
    Stage arrays ``stage_*`` [ns] as in :class:`~vdad.model.Model`, with local
    joint, ``q`` and ``qd`` indices; stage0, n_stages [k]: each joint's stages;
    s_pad [ns,6,3]: stage subspaces in post-stage frames. ``q_spring`` [nq],
    ``damping``, ``armature`` [nv] local.
    S, T, W [u,6,6]: the table of joint subspaces, ``subspace`` [k]: each joint's
    row in it. One-stage joints with the same subspaces share a constant row (every
    hinge of a chain about the same axis: one row), so the passes read a few
    kilobytes instead of 0.86 kB per joint (``docs/design.md``, "Order");
    multi-stage joints own a row, which the kinematics computes from ``q``.
    """

    model: object
    joints: np.ndarray
    parent: np.ndarray
    order: np.ndarray
    root_of: np.ndarray
    R0: np.ndarray
    p0: np.ndarray
    nq: int
    nv: int
    q_index: np.ndarray
    v_index: np.ndarray
    q_start: np.ndarray
    v_start: np.ndarray
    nv_joint: np.ndarray
    stage0: np.ndarray
    n_stages: np.ndarray
    stage_joint: np.ndarray
    stage_kind: np.ndarray
    stage_axis: np.ndarray
    stage_anchor: np.ndarray
    stage_ref: np.ndarray
    stage_stiffness: np.ndarray
    stage_q: np.ndarray
    stage_v: np.ndarray
    s_pad: np.ndarray
    q_spring: np.ndarray
    damping: np.ndarray
    armature: np.ndarray
    S: np.ndarray
    T: np.ndarray
    W: np.ndarray
    subspace: np.ndarray

    @property
    def k(self) -> int:
        return len(self.joints)

    @cached_property
    def arrays(self) -> tuple:
        """The arrays :func:`kinematics_pass` reads, as one tuple (a plain tuple
        costs numba ~0.1 µs per array to type, a namedtuple 3x that)."""
        return (self.order, self.parent, self.R0, self.p0, self.stage0, self.n_stages,
                self.v_start, self.nv_joint, self.stage_kind, self.stage_axis,
                self.stage_anchor, self.stage_ref, self.stage_q, self.stage_v, self.s_pad,
                self.subspace)


@lru_cache(maxsize=64)
def _model_tables(model):
    """Per-model constants: first stage of each joint, stage subspaces (ns, 6, 3)
    and the constant ``S, T, W`` (nj, 6, 6) of one-stage joints."""
    nb, ns = model.nb, model.ns
    first_stage = np.cumsum(model.n_stages_joint) - model.n_stages_joint
    s_pad = np.zeros((ns, 6, 3))
    for s in range(ns):
        sub = J.stage_subspace(model.stage_kind[s], model.stage_axis[s], model.stage_anchor[s])
        s_pad[s, :, :sub.shape[1]] = sub
    S, T, W = (np.zeros((nb, 6, 6)) for _ in range(3))
    d = model.nv_joint
    one = np.flatnonzero(model.n_stages_joint == 1)
    S[one, :, :3] = s_pad[first_stage[one]]
    js = np.flatnonzero(model.n_stages_joint <= 1)      # fixed joints: T = 1
    for dj in np.unique(d[js]):
        sel = js[d[js] == dj]
        Tj, Wj = J.complement(S[sel, :, :dj])
        T[sel, :, :6 - dj] = Tj
        W[sel, :, :dj] = Wj
    for a in (first_stage, s_pad, S, T, W):
        a.setflags(write=False)
    return first_stage, s_pad, S, T, W


def subspace_table(S, T, W, multi):
    """The rows ``S, T, W`` (u, 6, 6) of a joint set's subspace table from each
    joint's (k, 6, 6), and each joint's row (k,): joints not in ``multi`` (k,)
    with equal subspaces share one row, each joint in ``multi`` owns one."""
    k = len(S)
    STW = np.concatenate([S, T, W], axis=1).reshape(k, 108)
    one = np.flatnonzero(~multi)
    rows, inverse = np.unique(STW[one], axis=0, return_inverse=True)
    subspace = np.empty(k, np.int64)
    subspace[one] = inverse.ravel()
    subspace[multi] = len(rows) + np.arange(int(multi.sum()))
    table = np.concatenate([rows, STW[multi]]).reshape(-1, 18, 6)
    return table[:, :6].copy(), table[:, 6:12].copy(), table[:, 12:].copy(), subspace


@kernel
def forest_order(parent, order, root_of):
    """Fill ``order`` (k,) with the joints of the forest ``parent`` (k,), parents
    before children (by depth, stable), and ``root_of`` (k,) with each one's root."""
    k = parent.shape[0]
    depth = np.full(k, -1, np.int64)
    stack = np.empty(k, np.int64)
    for i in range(k):
        n = 0
        j = i
        while j >= 0 and depth[j] < 0:
            stack[n] = j
            n += 1
            j = parent[j]
        d = -1 if j < 0 else depth[j]
        r = -1 if j < 0 else root_of[j]
        for s in range(n - 1, -1, -1):
            d += 1
            node = stack[s]
            depth[node] = d
            if r < 0:
                r = node
            root_of[node] = r
    count = np.zeros(k + 1, np.int64)
    for i in range(k):
        count[depth[i] + 1] += 1
    for d in range(k):
        count[d + 1] += count[d]
    for i in range(k):
        order[count[depth[i]]] = i
        count[depth[i]] += 1


def joint_set(model, joints, parent) -> JointSet:
    """The :class:`JointSet` of ``joints`` (k,) with local ``parent`` (k,) (vectorised)."""
    first_stage, s_pad_all, S_all, T_all, W_all = _model_tables(model)
    js = np.asarray(joints, int)
    parent = np.asarray(parent, int)
    k = len(js)
    nq_j, nv_j, ns_j = model.nq_joint[js], model.nv_joint[js], model.n_stages_joint[js]
    q_start, v_start = np.cumsum(nq_j) - nq_j, np.cumsum(nv_j) - nv_j
    q_index = ranges(model.q_start[js], nq_j)
    v_index = ranges(model.v_start[js], nv_j)
    nq, nv = len(q_index), len(v_index)
    stages = ranges(first_stage[js], ns_j)
    sj = np.repeat(np.arange(k), ns_j)
    stage_kind = model.stage_kind[stages]
    stage_q = model.stage_q[stages] - model.q_start[js][sj] + q_start[sj]
    stage_v = model.stage_v[stages] - model.v_start[js][sj] + v_start[sj]
    stage_nv = np.asarray(J.STAGE_NV)[stage_kind]
    damping = np.repeat(model.stage_damping[stages], stage_nv)
    S, T, W, subspace = subspace_table(S_all[js], T_all[js], W_all[js], ns_j > 1)
    order, root_of = np.empty(k, np.int64), np.empty(k, np.int64)
    forest_order(parent, order, root_of)
    R0, p0 = model.placement_R[js], model.placement_p[js]
    i64 = np.int64
    return JointSet(
        model, js, parent, order, root_of, np.ascontiguousarray(R0),
        np.ascontiguousarray(p0), nq, nv, q_index, v_index, q_start.astype(i64),
        v_start.astype(i64), nv_j.astype(i64), (np.cumsum(ns_j) - ns_j).astype(i64),
        ns_j.astype(i64), sj, stage_kind.astype(i64), model.stage_axis[stages],
        model.stage_anchor[stages], model.stage_ref[stages], model.stage_stiffness[stages],
        stage_q.astype(i64), stage_v.astype(i64), s_pad_all[stages], model.q_spring[q_index],
        damping, model.armature[v_index], S, T, W, subspace)


@lru_cache(maxsize=64)
def plan(model) -> JointSet:
    """The :class:`JointSet` of all joints of ``model`` (cached; models are immutable)."""
    return joint_set(model, np.arange(model.nb), model.parent)


def as_joint_set(space) -> JointSet:
    """``space`` itself if it is a :class:`JointSet`, else the set of all joints
    of the model ``space``."""
    return space if isinstance(space, JointSet) else plan(space)


@dataclass
class Kinematics:
    """Kinematic quantities of one state of a :class:`JointSet` (shapes in brackets).

    R_rel [k,3,3], p_rel [k,3]: child frame in its local parent's body frame.
    S, T, W [u,6,6]: joint subspaces in the child frame (padded), the joint set's
    table (:class:`JointSet`, a row per ``subspace[j]``).
    R [k,3,3], p [k,3]: child body frames in world coordinates.
    v [k,6]: child body velocities in body coordinates at the body origin.
    c [k,6]: velocity-product term c_J of (T4), child frame.
    R3 [3,3,3], v6 [5,6], work [3,6,6]: scratch of the pass.
    """

    R_rel: np.ndarray
    p_rel: np.ndarray
    S: np.ndarray
    T: np.ndarray
    W: np.ndarray
    R: np.ndarray
    p: np.ndarray
    v: np.ndarray
    c: np.ndarray
    R3: np.ndarray
    v6: np.ndarray
    work: np.ndarray

    @classmethod
    def empty(cls, js):
        """Work arrays for ``js``, with its subspace table."""
        k = js.k
        return cls(np.zeros((k, 3, 3)), np.zeros((k, 3)), js.S.copy(), js.T.copy(), js.W.copy(),
                   np.zeros((k, 3, 3)), np.zeros((k, 3)), np.zeros((k, 6)), np.zeros((k, 6)),
                   np.zeros((3, 3, 3)), np.zeros((5, 6)), np.zeros((3, 6, 6)))

    @property
    def arrays(self) -> tuple:
        return (self.R_rel, self.p_rel, self.S, self.T, self.W, self.R, self.p, self.v, self.c,
                self.R3, self.v6, self.work)


# --- kernels: one joint each -------------------------------------------------------------

@inlined
def stage_motion(s, stage_kind, stage_axis, stage_anchor, stage_ref, stage_q, q, Rs, ps):
    """Post-stage frame of stage ``s`` in its pre-stage frame, ``(Rs, ps)``
    (:mod:`vdad.joints`): a hinge turns about its axis through its anchor, a slide
    moves along its axis, a ball turns by its quaternion about its anchor, a
    translation moves by ``q``."""
    kind, iq, a = stage_kind[s], stage_q[s], stage_anchor[s]
    if kind == 0 or kind == 2:                   # hinge, ball: p_s = a - R_s a
        if kind == 0:
            axis_angle_rotation(stage_axis[s], q[iq] - stage_ref[s], Rs)
        else:
            quaternion_rotation(q, iq, Rs)
        for i in range(3):
            ps[i] = a[i] - (Rs[i, 0] * a[0] + Rs[i, 1] * a[1] + Rs[i, 2] * a[2])
        return
    for i in range(3):                           # slide, translation: R_s = 1
        for m in range(3):
            Rs[i, m] = 1.0 if i == m else 0.0
        ps[i] = stage_axis[s, i] * (q[iq] - stage_ref[s]) if kind == 1 else q[iq + i]


@inlined
def joint_placement(j, R0, p0, stage0, n_stages, stage_kind, stage_axis, stage_anchor,
                    stage_ref, stage_q, q, R_rel, p_rel, Rs, Rn, ps):
    """Child frame of joint ``j`` in its parent's frame (theory §3): the joint frame
    ``(R0, p0)`` followed by each stage's motion. ``Rs``, ``Rn`` (3, 3), ``ps``
    (3,): scratch."""
    R, p = R_rel[j], p_rel[j]
    for r in range(3):
        p[r] = p0[j, r]
        for c in range(3):
            R[r, c] = R0[j, r, c]
    for s in range(stage0[j], stage0[j] + n_stages[j]):
        stage_motion(s, stage_kind, stage_axis, stage_anchor, stage_ref, stage_q, q, Rs, ps)
        for r in range(3):                       # (R, p) <- (R, p) (R_s, p_s)
            p[r] += R[r, 0] * ps[0] + R[r, 1] * ps[1] + R[r, 2] * ps[2]
        mm3(R, Rs, Rn)
        for r in range(3):
            for c in range(3):
                R[r, c] = Rn[r, c]


@inlined
def joint_subspace(j, u, stage0, n_stages, stage_kind, stage_axis, stage_anchor, stage_ref,
                   stage_q, stage_v, s_pad, v_start, nv_joint, q, S, T, W, R3, v6, work):
    """``S = [X_{child<-r} s_r]`` of a multi-stage joint ``j`` ((J1),
    ``docs/joints.md``) and its complements ``T``, ``W`` (T5), into row ``u`` of
    the subspace table. The transform from
    each post-stage frame to the child frame is the product of the later stages,
    accumulated from the last stage back. ``R3`` (>= 3, 3, 3), ``v6`` (>= 5, 6),
    ``work`` (>= 3, 6, 6): scratch."""
    sufR, Rs, Rn = R3[0], R3[1], R3[2]   # child frame in post-stage-r frame
    sufp, ps, t, col, s_r = v6[0], v6[1], v6[2], v6[3], v6[4]
    for r in range(3):
        sufp[r] = 0.0
        for m in range(3):
            sufR[r, m] = 1.0 if r == m else 0.0
    Sj = S[u]
    for s in range(stage0[j] + n_stages[j] - 1, stage0[j] - 1, -1):
        for c in range(3 if stage_kind[s] >= 2 else 1):   # X_{child<-r} s_r by columns
            for i in range(6):
                s_r[i] = s_pad[s, i, c]
            motion_to_child(sufR, sufp, s_r, col)
            for i in range(6):
                Sj[i, stage_v[s] - v_start[j] + c] = col[i]
        stage_motion(s, stage_kind, stage_axis, stage_anchor, stage_ref, stage_q, q, Rs, ps)
        mv3(Rs, sufp, t)                          # suffix <- (R_s, p_s) suffix
        for i in range(3):
            sufp[i] = ps[i] + t[i]
        mm3(Rs, sufR, Rn)
        for r in range(3):
            for m in range(3):
                sufR[r, m] = Rn[r, m]
    complement(Sj, nv_joint[j], T[u], W[u], work)


@inlined
def joint_motion(j, js, q, R_rel, p_rel, S, T, W, R3, v6, work):
    """Joint ``j`` of the set ``js`` at ``q``: its placement
    (:func:`joint_placement`) and, for a multi-stage joint, its subspaces
    (:func:`joint_subspace`)."""
    (order, parent, R0, p0, stage0, n_stages, v_start, nv_joint, stage_kind, stage_axis,
     stage_anchor, stage_ref, stage_q, stage_v, s_pad, subspace) = js
    joint_placement(j, R0, p0, stage0, n_stages, stage_kind, stage_axis, stage_anchor,
                    stage_ref, stage_q, q, R_rel, p_rel, R3[1], R3[2], v6[1])
    if n_stages[j] > 1:
        joint_subspace(j, subspace[j], stage0, n_stages, stage_kind, stage_axis, stage_anchor,
                       stage_ref, stage_q, stage_v, s_pad, v_start, nv_joint, q, S, T, W, R3,
                       v6, work)


@inlined
def body_pose(j, parent, R_rel, p_rel, R, p):
    """World pose of joint ``j``'s child body from its parent's: ``R = R_par R_rel``,
    ``p = p_par + R_par p_rel``."""
    pj = parent[j]
    if pj < 0:
        for r in range(3):
            p[j, r] = p_rel[j, r]
            for m in range(3):
                R[j, r, m] = R_rel[j, r, m]
        return
    mm3(R[pj], R_rel[j], R[j])
    mv3(R[pj], p_rel[j], p[j])
    for i in range(3):
        p[j, i] += p[pj, i]


@inlined
def body_velocity(j, parent, stage0, n_stages, stage_kind, stage_v, v_start, nv_joint,
                  R_rel, p_rel, Sj, qd, v, c, tmp):
    """Velocity of joint ``j``'s child body, ``v = X v_parent + S qd`` (body axes, at
    its origin), and ``c_J = crm(v) S qd + sum_{r<j} crm(S_r qd_r) S_j qd_j``
    (T4), (J1), with ``Sj`` (6, 6) its subspace. ``tmp`` (>= 1, 6, 6): scratch."""
    pj = parent[j]
    vj, cj = v[j], c[j]
    if pj >= 0:
        motion_to_child(R_rel[j], p_rel[j], v[pj], vj)
    u, prefix, us = tmp[0, 0], tmp[0, 1], tmp[0, 2]
    for i in range(6):
        if pj < 0:
            vj[i] = 0.0
        u[i] = 0.0
        prefix[i] = 0.0
        cj[i] = 0.0
    for s in range(stage0[j], stage0[j] + n_stages[j]):
        for i in range(6):                        # S_r qd_r of stage s
            us[i] = 0.0
        first = stage_v[s] - v_start[j]
        for col in range(first, first + (3 if stage_kind[s] >= 2 else 1)):
            x = qd[v_start[j] + col]
            for i in range(6):
                us[i] += Sj[i, col] * x
        cross_motion_add(prefix, us, cj)
        for i in range(6):
            prefix[i] += us[i]
            u[i] += us[i]
    for i in range(6):
        vj[i] += u[i]
    cross_motion_add(vj, u, cj)


@pass_kernel
def kinematics_pass(js, q, qd, velocities, R_rel, p_rel, S, T, W, R, p, v, c, R3, v6, work,
                    fresh=None):
    """Theory §3 for every joint of the set ``js`` (:attr:`JointSet.arrays`), parents
    first: placement, subspaces of multi-stage joints, world pose and, if
    ``velocities``, the body velocity and ``c_J``. ``order`` may end early at a
    -1 (the active joints of adaptive dynamics, :mod:`vdad.region`). ``fresh``
    (model joints,) bool, or None: a joint whose entry is true keeps the placement
    and subspaces that ``R_rel``, ``p_rel``, ``S``, ``T``, ``W`` hold (its ``q`` has
    not changed since: a rigid joint of adaptive dynamics); the others are placed
    and marked fresh."""
    (order, parent, R0, p0, stage0, n_stages, v_start, nv_joint, stage_kind, stage_axis,
     stage_anchor, stage_ref, stage_q, stage_v, s_pad, subspace) = js
    for idx in range(order.shape[0]):
        j = order[idx]
        if j < 0:
            break
        if fresh is None or not fresh[j]:
            joint_motion(j, js, q, R_rel, p_rel, S, T, W, R3, v6, work)
            if fresh is not None:
                fresh[j] = True
        body_pose(j, parent, R_rel, p_rel, R, p)
        if velocities:
            body_velocity(j, parent, stage0, n_stages, stage_kind, stage_v, v_start, nv_joint,
                          R_rel, p_rel, S[subspace[j]], qd, v, c, work)


# --- the public functions ------------------------------------------------------------------

def kinematics(model, q, qd, js=None, out=None) -> Kinematics:
    """All kinematic quantities of state ``(q, qd)`` (theory §3) of the joint set
    ``js`` (default: the whole model; ``q``, ``qd`` in ``js``'s local layout), into
    ``out`` (a :class:`Kinematics` of ``js``) if given."""
    js = plan(model) if js is None else js
    return _evaluate(js, q, qd, Kinematics.empty(js) if out is None else out)


def _evaluate(js, q, qd=None, kin=None):
    """:func:`kinematics_pass` of ``js`` into ``kin`` (new work arrays if None);
    without ``qd``, placements and poses only."""
    kin = Kinematics.empty(js) if kin is None else kin
    with compiling(kinematics_pass):
        kinematics_pass(js.arrays, as_input(q), _NO_VELOCITY if qd is None else as_input(qd),
                        qd is not None, *kin.arrays)
    return kin


_NO_VELOCITY = np.zeros(0)


def joint_kinematics(js, q):
    """Child poses in local parent frames and the padded ``S, T, W`` (k, 6, 6) of
    every joint of ``js`` at its local configuration ``q``."""
    kin = _evaluate(js, q)
    u = js.subspace
    return kin.R_rel, kin.p_rel, kin.S[u], kin.T[u], kin.W[u]


@pass_kernel
def _poses(order, parent, R_rel, p_rel, R, p):
    for idx in range(order.shape[0]):
        body_pose(order[idx], parent, R_rel, p_rel, R, p)


def body_poses(js, R_rel, p_rel):
    """World poses of the child bodies of ``js``: R (k, 3, 3), p (k, 3)."""
    R, p = np.empty((js.k, 3, 3)), np.empty((js.k, 3))
    _poses(js.order, js.parent, as_input(R_rel), as_input(p_rel), R, p)
    return R, p


def world_poses(model, q, out=None):
    """World poses ``R`` (nb, 3, 3), ``p`` (nb, 3) of every body of ``model`` at
    configuration ``q`` (nq,), in the work arrays of the :class:`Kinematics`
    ``out`` if given (then views of it, overwritten by the next call)."""
    kin = _evaluate(plan(model), q, kin=out)
    return kin.R, kin.p


def gimbal_lock(model, q):
    """Where a joint of ``model`` loses a dof at configuration ``q`` (nq,): a
    message naming the first composite joint whose motion subspace ``S`` has lost
    rank (a diagonal entry of its QR factor below ``64 eps`` of the largest, the
    test of :func:`~vdad._linalg.complement`), its coordinates and what to do; None
    if there is none. The joint-space inertia is singular there, so no
    accelerations exist."""
    multi = np.flatnonzero(model.n_stages_joint > 1)
    if not len(multi) or not np.all(np.isfinite(q)):
        return None
    S = joint_kinematics(plan(model), np.asarray(q, float))[2]
    for j in multi:
        d = int(model.nv_joint[j])
        R = np.abs(np.diag(np.linalg.qr(S[j, :, :d])[1]))
        if R.min() <= 64 * np.finfo(float).eps * R.max():
            i0 = model.q_start[j]
            coordinates = np.array2string(np.asarray(q[i0:i0 + model.nq_joint[j]]),
                                          precision=6)
            rank = int(np.sum(R > 64 * np.finfo(float).eps * R.max()))
            return (f"joint {model.joint_names[j]!r} is in gimbal lock at q = {coordinates}: "
                    f"its {d} axes span only {rank} directions, so the joint-space inertia is "
                    f"singular and the accelerations are undefined; model the joint as a "
                    f"ball joint (quaternion), or keep it away from this configuration")
    return None
