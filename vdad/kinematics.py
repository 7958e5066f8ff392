"""Joint and body kinematics, vectorised over joints and over tree depth.

* Joint level (theory §3, (T4)-(T5), (J1) of :mod:`vdad.joints`): each joint's
  child pose in its parent's frame, its motion subspace ``S`` in the child
  frame, the complements ``T`` and ``W``, and the velocity-product term ``c_J``.
* Body level: world poses and body velocities by pointer jumping over the
  kinematic forest, ``ceil(log2(depth))`` stacked steps instead of a loop over
  bodies (theory §5, level-synchronous evaluation).

Everything runs on a :class:`JointSet`: a set of joints with its own state
layout (``q``, ``qd`` of its joints only) and its own forest. :func:`plan` is the
set of all joints of a model; adaptive dynamics (:mod:`vdad.adaptive`) builds the
set of active joints, whose "bodies" are the rigid groups hanging from them
(theory §6), by :func:`joint_set` with a constant pre-placement per joint.

Joint arrays are padded to 6 columns: ``S``/``W`` (k, 6, 6) hold their ``d``
real columns first, ``T`` its ``6 - d`` real columns first; padding is zero.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property, lru_cache

import numpy as np

from . import joints as J
from .spatial import (
    axis_angle_to_rot,
    cross3,
    cross_motion,
    mv,
    pose_to_motion_transform,
    quat_to_rot,
)

_EYE3 = np.eye(3)


def ranges(starts, lengths):
    """Concatenated ``arange(s, s + l)`` for every pair (vectorised)."""
    starts, lengths = np.asarray(starts, int), np.asarray(lengths, int)
    offsets = np.cumsum(lengths) - lengths
    return np.repeat(starts - offsets, lengths) + np.arange(int(lengths.sum()))


@dataclass(frozen=True)
class JointSet:
    """A set of ``k`` joints with a local state layout and forest (shapes in brackets).

    joints [k]: model joint ids; parent [k]: local parent (-1: world).
    pre_R [k,3,3], pre_p [k,3]: constant pose of each joint's parent frame in its
    local parent's body frame (``None``: identity, the model's own tree).
    q_index [nq], v_index [nv]: model indices of the local ``q`` and ``qd``.
    Stage arrays ``stage_*`` [ns] as in :class:`~vdad.model.Model`, with local
    joint, ``q`` and ``qd`` indices; ``q_spring`` [nq], ``damping``, ``armature``
    [nv] local.
    S, T, W, T_pad_eye [k,6,6]: constant joint subspaces (multi-stage joints are
    refreshed from ``q``); dof_index [k,6]: local ``qd`` index of each column
    (``nv``: padding). ancestors: pointer-jumping tables (``k``: none);
    root_of [k]: root of each joint's tree. lin_q, lin_v, ball_q [., 4],
    ball_v [., 3]: the integration layout of :mod:`vdad.integrators`.
    """

    model: object
    joints: np.ndarray
    parent: np.ndarray
    pre_R: np.ndarray | None
    pre_p: np.ndarray | None
    nq: int
    nv: int
    q_index: np.ndarray
    v_index: np.ndarray
    placement_R: np.ndarray
    placement_p: np.ndarray
    stage_joint: np.ndarray
    stage_rank: np.ndarray
    stage_kind: np.ndarray
    stage_axis: np.ndarray
    stage_anchor: np.ndarray
    stage_ref: np.ndarray
    stage_stiffness: np.ndarray
    stage_q: np.ndarray
    stage_v: np.ndarray
    q_spring: np.ndarray
    damping: np.ndarray
    armature: np.ndarray
    stage_groups: tuple        # ((kind, stage indices), ...)
    rank_stages: tuple         # stages of rank r, for r = 0, 1, ...
    multi_ranks: tuple         # per rank: stages of multi-stage joints
    multi_cols: tuple          # per rank: (stages, S columns (., 3), qd indices (., 3))
    multi_joints: np.ndarray   # joints with more than one stage
    multi_by_dof: tuple        # ((d, joints), ...) among multi_joints
    s_pad: np.ndarray          # (ns, 6, 3) stage subspaces in post-stage frames
    col_stage: np.ndarray      # flat (stage, column-in-joint, column-in-stage) of
    col_joint_col: np.ndarray  # multi-stage joints, to scatter S columns
    col_stage_col: np.ndarray
    S: np.ndarray
    T: np.ndarray
    W: np.ndarray
    T_pad_eye: np.ndarray
    dof_index: np.ndarray
    ancestors: tuple
    root_of: np.ndarray
    lin_q: np.ndarray
    lin_v: np.ndarray
    ball_q: np.ndarray
    ball_v: np.ndarray

    @property
    def k(self) -> int:
        return len(self.joints)

    @cached_property
    def armature_ext(self) -> np.ndarray:
        """``armature`` (nv + 1,) ending in 0, read through ``dof_index`` padding."""
        return np.append(self.armature, 0.0)


@lru_cache(maxsize=64)
def _model_tables(model):
    """Per-model constants: first stage of each joint, stage subspaces (ns, 6, 3)
    and the constant ``S, T, W, T_pad_eye`` (nj, 6, 6) of one-stage joints."""
    nb, ns = model.nb, model.ns
    first_stage = np.cumsum(model.n_stages_joint) - model.n_stages_joint
    s_pad = np.zeros((ns, 6, 3))
    for s in range(ns):
        sub = J.stage_subspace(model.stage_kind[s], model.stage_axis[s], model.stage_anchor[s])
        s_pad[s, :, :sub.shape[1]] = sub
    S, T, W = (np.zeros((nb, 6, 6)) for _ in range(3))
    d = model.nv_joint
    T_pad_eye = (np.arange(6) >= 6 - d[:, None])[:, :, None] * np.eye(6)
    one = np.flatnonzero(model.n_stages_joint == 1)
    S[one, :, :3] = s_pad[first_stage[one]]
    js = np.flatnonzero(model.n_stages_joint <= 1)      # fixed joints: T = 1
    for dj in np.unique(d[js]):
        sel = js[d[js] == dj]
        Tj, Wj = J.complement(S[sel, :, :dj])
        T[sel, :, :6 - dj] = Tj
        W[sel, :, :dj] = Wj
    for a in (first_stage, s_pad, S, T, W, T_pad_eye):
        a.setflags(write=False)
    return first_stage, s_pad, S, T, W, T_pad_eye


def _ancestor_tables(parent):
    """Pointer-jumping tables of a forest: ``2^t``-th ancestors (``k``: none)."""
    k = len(parent)
    anc = np.where(parent < 0, k, parent)
    tables = []
    while np.any(anc < k):
        tables.append(anc)
        ext = np.append(anc, k)
        anc = ext[anc]
    root = np.arange(k)
    for anc in reversed(tables):
        up = np.append(anc, k)[root]
        root = np.where(up < k, up, root)
    return tuple(tables), root


def joint_set(model, joints, parent, pre_R=None, pre_p=None) -> JointSet:
    """The :class:`JointSet` of ``joints`` (k,) with local ``parent`` (k,) and
    constant pre-placements ``pre_R`` (k, 3, 3), ``pre_p`` (k, 3) (vectorised)."""
    first_stage, s_pad_all, S_all, T_all, W_all, T_pad_all = _model_tables(model)
    js = np.asarray(joints, int)
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
    stage_rank = model.stage_rank[stages]
    stage_nv = np.asarray(J.STAGE_NV)[stage_kind]
    damping = np.repeat(model.stage_damping[stages], stage_nv)
    stage_groups = tuple((kind, np.flatnonzero(stage_kind == kind)) for kind in range(4)
                         if np.any(stage_kind == kind))
    max_rank = int(stage_rank.max()) + 1 if len(stages) else 0
    rank_stages = tuple(np.flatnonzero(stage_rank == r) for r in range(max_rank))
    multi = ns_j > 1
    multi_joints = np.flatnonzero(multi)
    multi_stage = multi[sj]
    multi_ranks = tuple(np.flatnonzero((stage_rank == r) & multi_stage) for r in range(max_rank))
    multi_cols = []
    for sel in multi_ranks:
        valid = np.arange(3) < stage_nv[sel][:, None]
        cols = stage_v[sel][:, None] - v_start[sj[sel]][:, None] + np.arange(3)
        dofs = stage_v[sel][:, None] + np.arange(3)
        multi_cols.append((sel, np.where(valid, cols, 0), np.where(valid, dofs, nv)))
    ms = np.flatnonzero(multi_stage)
    col_stage = np.repeat(ms, stage_nv[ms])
    col_stage_col = np.arange(len(col_stage)) - np.repeat(np.cumsum(stage_nv[ms]) - stage_nv[ms],
                                                          stage_nv[ms])
    col_joint_col = stage_v[col_stage] - v_start[sj[col_stage]] + col_stage_col
    dof_index = np.where(np.arange(6) < nv_j[:, None], v_start[:, None] + np.arange(6), nv)
    multi_by_dof = tuple((int(d), multi_joints[nv_j[multi_joints] == d])
                         for d in np.unique(nv_j[multi_joints]))
    ancestors, root_of = _ancestor_tables(np.asarray(parent, int))
    ball = stage_kind == J.BALL
    lin = np.flatnonzero(~ball)
    lin_q = ranges(stage_q[lin], stage_nv[lin])
    lin_v = ranges(stage_v[lin], stage_nv[lin])
    ball_q = (stage_q[ball][:, None] + np.arange(4)).reshape(-1, 4)
    ball_v = (stage_v[ball][:, None] + np.arange(3)).reshape(-1, 3)
    return JointSet(
        model, js, np.asarray(parent, int), pre_R, pre_p, nq, nv, q_index, v_index,
        model.placement_R[js], model.placement_p[js], sj, stage_rank, stage_kind,
        model.stage_axis[stages], model.stage_anchor[stages], model.stage_ref[stages],
        model.stage_stiffness[stages], stage_q, stage_v, model.q_spring[q_index], damping,
        model.armature[v_index], stage_groups, rank_stages, multi_ranks, tuple(multi_cols),
        multi_joints, multi_by_dof,
        s_pad_all[stages], col_stage, col_joint_col, col_stage_col,
        S_all[js], T_all[js], W_all[js], T_pad_all[js], dof_index, ancestors, root_of,
        lin_q, lin_v, ball_q, ball_v)


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
    S, T, W [k,6,6]: joint subspaces in the child frame (padded).
    R [k,3,3], p [k,3]: child body frames in world coordinates.
    v [k,6]: child body velocities in body coordinates at the body origin.
    c [k,6]: velocity-product term c_J of (T4), child frame.
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


def stage_transforms(js, q):
    """Post-stage frames in pre-stage frames: R (ns, 3, 3), p (ns, 3)."""
    ns = len(js.stage_kind)
    R = np.broadcast_to(_EYE3, (ns, 3, 3)).copy()
    p = np.zeros((ns, 3))
    for kind, sel in js.stage_groups:
        qi = js.stage_q[sel]
        if kind == J.HINGE:
            R[sel] = axis_angle_to_rot(js.stage_axis[sel], q[qi] - js.stage_ref[sel])
        elif kind == J.SLIDE:
            p[sel] = js.stage_axis[sel] * (q[qi] - js.stage_ref[sel])[:, None]
        elif kind == J.BALL:
            quat = q[qi[:, None] + np.arange(4)]
            R[sel] = quat_to_rot(quat / np.linalg.norm(quat, axis=1, keepdims=True))
        else:
            p[sel] = q[qi[:, None] + np.arange(3)]
        if kind in (J.HINGE, J.BALL):
            a = js.stage_anchor[sel]
            p[sel] = a - mv(R[sel], a)
    return R, p


def joint_kinematics(js, q):
    """Child poses in local parent frames and the padded ``S, T, W`` of every joint."""
    Rs, ps = stage_transforms(js, q)
    R_rel = np.array(js.placement_R)
    p_rel = np.array(js.placement_p)
    if js.pre_R is not None:
        p_rel = js.pre_p + mv(js.pre_R, p_rel)
        R_rel = js.pre_R @ R_rel
    for sel in js.rank_stages:
        jj = js.stage_joint[sel]
        p_rel[jj] += mv(R_rel[jj], ps[sel])
        R_rel[jj] = R_rel[jj] @ Rs[sel]
    S, T, W = js.S, js.T, js.W
    if len(js.multi_joints):
        S, T, W = S.copy(), T.copy(), W.copy()
        Xs = np.zeros((len(js.stage_kind), 6, 3))
        sufR = np.broadcast_to(_EYE3, (js.k, 3, 3)).copy()
        sufp = np.zeros((js.k, 3))
        for sel in reversed(js.multi_ranks):
            jj = js.stage_joint[sel]
            Xs[sel] = pose_to_motion_transform(sufR[jj], sufp[jj]) @ js.s_pad[sel]
            sufp[jj] = ps[sel] + mv(Rs[sel], sufp[jj])
            sufR[jj] = Rs[sel] @ sufR[jj]
        cs = js.col_stage
        S[js.stage_joint[cs], :, js.col_joint_col] = Xs[cs, :, js.col_stage_col]
        for d, jm in js.multi_by_dof:
            Tj, Wj = J.complement(S[jm, :, :d])
            T[jm, :, :6 - d] = Tj
            W[jm, :, :d] = Wj
    return R_rel, p_rel, S, T, W


def body_poses(js, R_rel, p_rel):
    """World poses of the child bodies by pointer jumping: R (k, 3, 3), p (k, 3)."""
    R = np.concatenate([R_rel, _EYE3[None]])
    p = np.concatenate([p_rel, np.zeros((1, 3))])
    for anc in js.ancestors:
        Ra = R[anc]
        p[:-1] = p[anc] + mv(Ra, p[:-1])
        R[:-1] = Ra @ R[:-1]
    return R[:-1], p[:-1]


def world_poses(model, q):
    """World poses ``R`` (nb, 3, 3), ``p`` (nb, 3) of every body of ``model`` at
    configuration ``q`` (nq,)."""
    js = plan(model)
    return body_poses(js, *joint_kinematics(js, q)[:2])


def subtree_sum(js, x):
    """``y_i = sum of x_j over j = i and its ancestors`` by pointer jumping; x (k, ...)."""
    y = np.concatenate([x, np.zeros((1,) + x.shape[1:])])
    for anc in js.ancestors:
        y[:-1] = y[:-1] + y[anc]
    return y[:-1]


def body_velocities(js, S, R, p, qd):
    """Child body velocities (k, 6) in body coordinates at the body origins.

    Each joint's contribution ``S qd`` is moved to world axes at its tree's root
    origin, summed down the tree (:func:`subtree_sum`) and moved back to the
    body; using the root origin as reference keeps the sum translation-invariant.
    """
    qd_pad = np.append(qd, 0.0)[js.dof_index]                      # (k, 6)
    u = mv(S, qd_pad)                          # child frame
    w = mv(R, u[:, :3])
    vp = mv(R, u[:, 3:])
    r = p[js.root_of]
    V = subtree_sum(js, np.concatenate([w, vp + cross3(w, r - p)], axis=1))
    w = V[:, :3]
    v_origin = V[:, 3:] + cross3(w, p - r)
    RT = np.swapaxes(R, 1, 2)
    return np.concatenate([mv(RT, w), mv(RT, v_origin)], axis=1), u


def velocity_product(js, S, v, u, qd):
    """``c_J`` of (T4)/(J1) for every joint (k, 6), child frame.

    ``u`` (k, 6) is ``S qd`` per joint; multi-stage joints add the stage sum of (J1).
    """
    c = cross_motion(v, u)
    if len(js.multi_joints):
        qd_ext = np.append(qd, 0.0)
        prefix = np.zeros((js.k, 6))
        for sel, cols, dofs in js.multi_cols:
            jj = js.stage_joint[sel]
            u_s = np.einsum("kcj,kc->kj", S[jj[:, None], :, cols], qd_ext[dofs])
            c[jj] += cross_motion(prefix[jj], u_s)
            prefix[jj] += u_s
    return c


def kinematics(model, q, qd, js=None) -> Kinematics:
    """All kinematic quantities of state ``(q, qd)`` (theory §3) of the joint set
    ``js`` (default: the whole model; ``q``, ``qd`` in ``js``'s local layout)."""
    js = plan(model) if js is None else js
    R_rel, p_rel, S, T, W = joint_kinematics(js, q)
    R, p = body_poses(js, R_rel, p_rel)
    v, u = body_velocities(js, S, R, p, qd)
    c = velocity_product(js, S, v, u, qd)
    return Kinematics(R_rel, p_rel, S, T, W, R, p, v, c)
