"""Joint and body kinematics, vectorised over joints and over tree depth.

* Joint level (theory §3, (T4)-(T5), (J1) of :mod:`vdad.joints`): each joint's
  child pose in its parent's frame, its motion subspace ``S`` in the child
  frame, the complements ``T`` and ``W``, and the velocity-product term ``c_J``.
* Body level: world poses and body velocities by pointer jumping over the
  kinematic forest, ``ceil(log2(depth))`` stacked steps instead of a loop over
  bodies (theory §5, level-synchronous evaluation).

Joint arrays are padded to 6 columns: ``S``/``W`` (nj, 6, 6) hold their ``d``
real columns first, ``T`` its ``6 - d`` real columns first; padding is zero.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

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


@dataclass(frozen=True)
class KinematicPlan:
    """Constant index arrays and joint data derived once from a model."""

    stage_groups: tuple        # ((kind, stage indices), ...)
    rank_stages: tuple         # stages of rank r, for r = 0, 1, ...
    multi_ranks: tuple         # per rank: stages of multi-stage joints
    multi_cols: tuple          # per rank: (stages, S columns (k, 3), qd indices (k, 3))
    multi_joints: np.ndarray   # joints with more than one stage
    multi_by_dof: tuple        # ((d, joints), ...) among multi_joints
    s_pad: np.ndarray          # (ns, 6, 3) stage subspaces in post-stage frames
    col_stage: np.ndarray      # flat (stage, column-in-joint, column-in-stage) of
    col_joint_col: np.ndarray  # multi-stage joints, to scatter S columns
    col_stage_col: np.ndarray
    S: np.ndarray              # (nj, 6, 6) constant S (multi-stage rows refreshed)
    T: np.ndarray              # (nj, 6, 6)
    W: np.ndarray              # (nj, 6, 6)
    T_pad_eye: np.ndarray      # (nj, 6, 6) identity on T's padding columns
    dof_index: np.ndarray      # (nj, 6) index into qd of each S column (nv: padding)
    ancestors: tuple           # pointer-jumping tables: 2^k-th ancestor (nb: none)
    root_of: np.ndarray        # (nb,) root body of each body's tree


@lru_cache(maxsize=64)
def plan(model) -> KinematicPlan:
    """The :class:`KinematicPlan` of ``model`` (cached; models are immutable)."""
    nb, ns = model.nb, model.ns
    kinds = model.stage_kind
    stage_groups = tuple((k, np.flatnonzero(kinds == k)) for k in range(4) if np.any(kinds == k))
    max_rank = int(model.stage_rank.max()) + 1 if ns else 0
    rank_stages = tuple(np.flatnonzero(model.stage_rank == r) for r in range(max_rank))
    multi = model.n_stages_joint > 1
    multi_joints = np.flatnonzero(multi)
    multi_stage = multi[model.stage_joint] if ns else np.zeros(0, bool)
    multi_ranks = tuple(np.flatnonzero((model.stage_rank == r) & multi_stage)
                        for r in range(max_rank))
    multi_cols = []
    for sel in multi_ranks:
        nv = np.array([J.STAGE_NV[k] for k in kinds[sel]], int)
        valid = np.arange(3) < nv[:, None]
        jj = model.stage_joint[sel]
        cols = model.stage_v[sel][:, None] - model.v_start[jj][:, None] + np.arange(3)
        dofs = model.stage_v[sel][:, None] + np.arange(3)
        multi_cols.append((sel, np.where(valid, cols, 0), np.where(valid, dofs, model.nv)))
    s_pad = np.zeros((ns, 6, 3))
    for s in range(ns):
        sub = J.stage_subspace(kinds[s], model.stage_axis[s], model.stage_anchor[s])
        s_pad[s, :, :sub.shape[1]] = sub
    cs, cj, cc = [], [], []
    for s in np.flatnonzero(multi_stage):
        j = model.stage_joint[s]
        for c in range(J.STAGE_NV[kinds[s]]):
            cs.append(s)
            cj.append(model.stage_v[s] - model.v_start[j] + c)
            cc.append(c)
    S = np.zeros((nb, 6, 6))
    T = np.zeros((nb, 6, 6))
    W = np.zeros((nb, 6, 6))
    T_pad_eye = np.zeros((nb, 6, 6))
    dof_index = np.full((nb, 6), model.nv)
    first_stage = np.concatenate([[0], np.cumsum(model.n_stages_joint)[:-1]])
    for j in range(nb):
        d = model.nv_joint[j]
        dof_index[j, :d] = model.v_start[j] + np.arange(d)
        T_pad_eye[j, range(6 - d, 6), range(6 - d, 6)] = 1.0
        if model.n_stages_joint[j] == 1:
            S[j, :, :d] = s_pad[first_stage[j], :, :d]
    for d in np.unique(model.nv_joint):
        js = np.flatnonzero((model.nv_joint == d) & ~multi)
        if len(js):
            Tj, Wj = J.complement(S[js, :, :d])
            T[js, :, :6 - d] = Tj
            W[js, :, :d] = Wj
    multi_by_dof = tuple((int(d), multi_joints[model.nv_joint[multi_joints] == d])
                         for d in np.unique(model.nv_joint[multi_joints]))
    ancestors = []
    anc = np.where(model.parent < 0, nb, model.parent)
    ext = np.append(anc, nb)
    while np.any(anc < nb):
        ancestors.append(anc)
        anc = ext[anc]
        ext = np.append(anc, nb)
    root_of = np.arange(nb)
    for i in range(nb):
        if model.parent[i] >= 0:
            root_of[i] = root_of[model.parent[i]]
    return KinematicPlan(stage_groups, rank_stages, multi_ranks, tuple(multi_cols),
                          multi_joints, multi_by_dof,
                         s_pad, np.array(cs, int), np.array(cj, int), np.array(cc, int),
                         S, T, W, T_pad_eye, dof_index, tuple(ancestors), root_of)


@dataclass
class Kinematics:
    """Kinematic quantities of one state (work arrays; shapes in brackets).

    R_rel [nj,3,3], p_rel [nj,3]: child frame in parent frame.
    S, T, W [nj,6,6]: joint subspaces in the child frame (padded).
    R [nb,3,3], p [nb,3]: body frames in world coordinates.
    v [nb,6]: body velocities in body coordinates at the body origin.
    c [nj,6]: velocity-product term c_J of (T4), child frame.
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


def stage_transforms(model, q):
    """Post-stage frames in pre-stage frames: R (ns, 3, 3), p (ns, 3)."""
    pl = plan(model)
    ns = model.ns
    R = np.broadcast_to(_EYE3, (ns, 3, 3)).copy()
    p = np.zeros((ns, 3))
    for kind, sel in pl.stage_groups:
        qi = model.stage_q[sel]
        if kind == J.HINGE:
            R[sel] = axis_angle_to_rot(model.stage_axis[sel], q[qi] - model.stage_ref[sel])
        elif kind == J.SLIDE:
            p[sel] = model.stage_axis[sel] * (q[qi] - model.stage_ref[sel])[:, None]
        elif kind == J.BALL:
            quat = q[qi[:, None] + np.arange(4)]
            R[sel] = quat_to_rot(quat / np.linalg.norm(quat, axis=1, keepdims=True))
        else:
            p[sel] = q[qi[:, None] + np.arange(3)]
        if kind in (J.HINGE, J.BALL):
            a = model.stage_anchor[sel]
            p[sel] = a - mv(R[sel], a)
    return R, p


def joint_kinematics(model, q):
    """Child poses in parent frames and the padded ``S, T, W`` of every joint."""
    pl = plan(model)
    Rs, ps = stage_transforms(model, q)
    R_rel = np.array(model.placement_R)
    p_rel = np.array(model.placement_p)
    for sel in pl.rank_stages:
        jj = model.stage_joint[sel]
        p_rel[jj] += mv(R_rel[jj], ps[sel])
        R_rel[jj] = R_rel[jj] @ Rs[sel]
    S, T, W = pl.S, pl.T, pl.W
    Xs = None
    if len(pl.multi_joints):
        S, T, W = S.copy(), T.copy(), W.copy()
        Xs = np.zeros((model.ns, 6, 3))
        sufR = np.broadcast_to(_EYE3, (model.nb, 3, 3)).copy()
        sufp = np.zeros((model.nb, 3))
        for sel in reversed(pl.multi_ranks):
            jj = model.stage_joint[sel]
            Xs[sel] = pose_to_motion_transform(sufR[jj], sufp[jj]) @ pl.s_pad[sel]
            sufp[jj] = ps[sel] + mv(Rs[sel], sufp[jj])
            sufR[jj] = Rs[sel] @ sufR[jj]
        cs = pl.col_stage
        S[model.stage_joint[cs], :, pl.col_joint_col] = Xs[cs, :, pl.col_stage_col]
        for d, js in pl.multi_by_dof:
            Tj, Wj = J.complement(S[js, :, :d])
            T[js, :, :6 - d] = Tj
            W[js, :, :d] = Wj
    return R_rel, p_rel, S, T, W


def body_poses(model, R_rel, p_rel):
    """World poses of all bodies by pointer jumping: R (nb, 3, 3), p (nb, 3)."""
    R = np.concatenate([R_rel, _EYE3[None]])
    p = np.concatenate([p_rel, np.zeros((1, 3))])
    for anc in plan(model).ancestors:
        Ra = R[anc]
        p[:-1] = p[anc] + mv(Ra, p[:-1])
        R[:-1] = Ra @ R[:-1]
    return R[:-1], p[:-1]


def subtree_sum(model, x):
    """``y_i = sum of x_j over j = i and its ancestors`` by pointer jumping; x (nb, ...)."""
    y = np.concatenate([x, np.zeros((1,) + x.shape[1:])])
    for anc in plan(model).ancestors:
        y[:-1] = y[:-1] + y[anc]
    return y[:-1]


def body_velocities(model, S, R, p, qd):
    """Body velocities (nb, 6) in body coordinates at the body origins.

    Each joint's contribution ``S qd`` is moved to world axes at its tree's root
    origin, summed down the tree (:func:`subtree_sum`) and moved back to the
    body; using the root origin as reference keeps the sum translation-invariant.
    """
    pl = plan(model)
    qd_pad = np.append(qd, 0.0)[pl.dof_index]                      # (nj, 6)
    u = mv(S, qd_pad)                          # child frame
    w = mv(R, u[:, :3])
    vp = mv(R, u[:, 3:])
    r = p[pl.root_of]
    V = subtree_sum(model, np.concatenate([w, vp + cross3(w, r - p)], axis=1))
    w = V[:, :3]
    v_origin = V[:, 3:] + cross3(w, p - r)
    RT = np.swapaxes(R, 1, 2)
    return np.concatenate([mv(RT, w),
                           mv(RT, v_origin)], axis=1), u


def velocity_product(model, S, v, u, qd):
    """``c_J`` of (T4)/(J1) for every joint (nj, 6), child frame.

    ``u`` (nj, 6) is ``S qd`` per joint; multi-stage joints add the stage sum of (J1).
    """
    pl = plan(model)
    c = cross_motion(v, u)
    if len(pl.multi_joints):
        qd_ext = np.append(qd, 0.0)
        prefix = np.zeros((model.nb, 6))
        for sel, cols, dofs in pl.multi_cols:
            jj = model.stage_joint[sel]
            u_s = np.einsum("kcj,kc->kj", S[jj[:, None], :, cols], qd_ext[dofs])
            c[jj] += cross_motion(prefix[jj], u_s)
            prefix[jj] += u_s
    return c


def kinematics(model, q, qd) -> Kinematics:
    """All kinematic quantities of state ``(q, qd)`` (theory §3)."""
    R_rel, p_rel, S, T, W = joint_kinematics(model, q)
    R, p = body_poses(model, R_rel, p_rel)
    v, u = body_velocities(model, S, R, p, qd)
    c = velocity_product(model, S, v, u, qd)
    return Kinematics(R_rel, p_rel, S, T, W, R, p, v, c)
