"""The DCA level by level in stacked numpy arrays: the passes adaptive dynamics runs on.

Adaptive dynamics (:mod:`vdad.adaptive`) still runs the DCA in batches of nodes of
equal height, restricted to its active region, with the metric coefficients
(T16)-(T18) and a pruned top-down pass; the full DCA runs on the compiled per-node
kernels of :mod:`vdad.dca`. Issue 15 moves adaptive dynamics onto those kernels and
removes this module.

:func:`rigid_leaves` fills the blocks of rigid leaves, single bodies (T2)-(T3)
or the rigid groups of adaptive dynamics (T19)-(T20); :func:`assemble` runs the
bottom-up pass (T6)-(T12), with the metric coefficients (T16)-(T18) when asked,
and :func:`back_substitute` the top-down pass (T10), (T13), restricted to the
rows a caller selects. Each loop runs over a list of levels in Python, every node
of a level evaluated in stacked numpy arrays.

Signed column blocks: for a port ``a`` of ``C`` taken from child ``X`` (``A`` or
``B``), ``G_a = s_a Phi^X_{a j_X}`` with ``s_a = -1`` on ``alpha`` and ``+1`` on
``beta``. Then (T11)-(T12) read ``Phi^C = blockdiag(Phi^A, Phi^B) - G Y G^T`` and
``b^C = b^X + G beta_C``, and (T10), (T13) read ``f_J = beta_C - Y u``,
``r = u + gamma`` with ``u = sum_a G_a^T f_a``. The metric coefficients in the
same notation are derived in ``docs/adaptive.md``.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .spatial import cross3, motion_transform, mv


@dataclass
class LevelData:
    """Work arrays of the level passes (Pinocchio's Data; shapes in brackets).

    Phi [n_blocks, 6, 6], b [n_slots, 6]: block stores of the tree.
    f_J [k + 1, 6]: joint wrenches (last row: zero, read by padding).
    qdd [nv + 1]: joint accelerations (last entry: scratch for padding).
    levels: per level, the intermediates kept for the top-down pass
    (``Y``, ``W_m``, ``G``, ``beta``, ``gamma``, ``W``).
    """

    Phi: np.ndarray
    b: np.ndarray
    f_J: np.ndarray
    qdd: np.ndarray
    levels: list = field(default_factory=list)


@dataclass
class MetricData:
    """Acceleration-metric coefficients (T16)-(T18) in stores shaped like Phi and b.

    Psi [n_blocks, 6, 6], p [n_slots, 6], eta [n_nodes + 1] (last: ground, 0);
    D [k, 6]: per joint the diagonal of ``A_J`` (weights of (T14)), zero-padded;
    A [n_nodes + 1]: the metric of every node reached by the top-down pass.
    """

    Psi: np.ndarray
    p: np.ndarray
    eta: np.ndarray
    D: np.ndarray
    A: np.ndarray


def rigid_leaves(lp, R_rel, p_rel, v, mass, com, inertia, Iinv, f, data, fixed_R=None,
                 fixed_p=None):
    """Blocks of rigid leaves: (T2)-(T3) for bodies, (T19)-(T20) for rigid groups.

    Per leaf (index ``lp.body``): ``mass``, ``com`` (3,) and ``inertia`` (3, 3)
    about it in the leaf frame, ``Iinv = diag(I^-1, 1/m)`` (6, 6), velocity ``v``
    (6,) at the frame origin and known wrench ``f`` (6,) at the centre of mass,
    leaf axes. Ports flagged ``lp.inbound`` have a fixed frame in the leaf frame,
    ``fixed_R``, ``fixed_p`` per port (``None``: the leaf frame itself); any other
    port is the child frame ``(R_rel, p_rel)`` of its joint ``lp.joint``, seen from
    the leaf frame (for rigid groups the active joints' kinematics carry their
    pre-placement in the group, :mod:`vdad.adaptive`).
    """
    j = lp.joint
    inb = lp.inbound
    if fixed_R is None:
        E = np.where(inb[:, None, None], np.eye(3), np.swapaxes(R_rel[j], 1, 2))
        r = np.where(inb[:, None], 0.0, p_rel[j])
    else:
        moving = np.flatnonzero(~inb)
        E = np.swapaxes(fixed_R, 1, 2).copy()
        r = fixed_p.copy()
        E[moving] = np.swapaxes(R_rel[j[moving]], 1, 2)
        r[moving] = p_rel[j[moving]]
    X = motion_transform(E, r - com[lp.body])                       # X_{h<-c} (np_, 6, 6)
    Z = X @ Iinv[lp.body]
    XT = np.ascontiguousarray(np.swapaxes(X, 1, 2))
    data.Phi[lp.pair_block] = Z[lp.pair_h] @ XT[lp.pair_k]
    w, vc = v[:, :3], v[:, 3:] + cross3(v[:, :3], com)               # at the com
    Iw = mv(inertia, w)
    bias = np.concatenate([cross3(w, Iw), mass[:, None] * cross3(w, vc)], axis=1)
    a_c = mv(Iinv, f - bias)                   # (leaves, 6)
    data.b[lp.slot] = mv(X, a_c[lp.body])


def inverse_inertia(mass, inertia):
    """``Ibar_c^-1 = diag(I_c^-1, 1/m)`` (k, 6, 6), as in (T2)."""
    Iinv = np.zeros((len(mass), 6, 6))
    Iinv[:, :3, :3] = np.linalg.inv(inertia)
    Iinv[:, 3:, 3:] = (1.0 / mass)[:, None, None] * np.eye(3)
    return Iinv


def assemble(levels, js, kin, tau_ext, data, metric=None):
    """Bottom-up pass (T6)-(T12) over ``levels``.

    ``js``: the :class:`~vdad.kinematics.JointSet` whose local joint indices the
    levels use, ``kin`` its kinematics, ``tau_ext`` (nv + 1,) its joint forces
    ending in 0. With ``metric`` (:class:`MetricData`), also the coefficients
    (T16)-(T18). Gathers use ``take``, three times cheaper than fancy indexing
    on the small batches of adaptive dynamics.
    """
    Phi, b = data.Phi, data.b
    for n, lv in enumerate(levels):
        jid = lv.joint
        Wm = Phi.take(lv.WA, 0) + Phi.take(lv.WB, 0)                    # (T6)
        T = kin.T.take(jid, 0)
        Tt = np.ascontiguousarray(np.swapaxes(T, 1, 2))
        Y = T @ np.linalg.inv(Tt @ Wm @ T + js.T_pad_eye.take(jid, 0)) @ Tt   # (T7)
        W = kin.W.take(jid, 0)
        dofs = js.dof_index.take(jid, 0)
        tau = tau_ext.take(dofs)                                            # (k, 6)
        gamma = b.take(lv.bB, 0) - b.take(lv.bA, 0) - kin.c.take(jid, 0)      # (T8)
        Ia = js.armature_ext.take(dofs)                                     # (k, 6)
        if Ia.any():                                  # (A1)-(A2), docs/joints.md
            P = W - Y @ Wm @ W
            F = np.linalg.inv(np.eye(6) + Ia[:, :, None] * (np.swapaxes(P, 1, 2) @ Wm @ W))
            Y = Y + P @ (F * Ia[:, None, :]) @ np.swapaxes(P, 1, 2)
            beta = mv(P, mv(F, tau)) - mv(Y, gamma)
        else:
            Wtau = mv(W, tau)
            beta = Wtau - mv(Y, mv(Wm, Wtau) + gamma)                         # (T9)
        k, P = lv.sign.shape
        G = Phi.take(lv.G, 0) * lv.sign[:, :, None, None]               # (k, P, 6, 6)
        Gt = None
        if P:
            Gt = np.ascontiguousarray(np.swapaxes(G.reshape(k, 6 * P, 6), 1, 2))
            M = ((G @ Y[:, None]).reshape(k, 6 * P, 6) @ Gt).reshape(k, P, 6, P, 6)
            PhiC = Phi.take(lv.Phi0, 0) - M.transpose(0, 1, 3, 2, 4)   # (T11)
            Phi[lv.out_Phi] = 0.5 * (PhiC + PhiC.transpose(0, 2, 1, 4, 3))
            b[lv.out_b] = b.take(lv.b0, 0) + mv(G, beta[:, None])      # (T12)
        data.levels[n] = (Y, Wm, G, beta, gamma, W)
        if metric is not None:
            _metric_coefficients(lv, metric, Y, Wm, G, Gt, beta, gamma, W)


def _metric_coefficients(lv, metric, Y, Wm, G, Gt, beta, gamma, W):
    """(T16)-(T18) of one level (``docs/adaptive.md`` derives this block form).

    With ``H_a = s_a Psi^X_{a j_X}``, ``Psi_m = Psi^A_{jA jA} + Psi^B_{jB jB}``,
    ``N = 1 - W_m Y``, ``D = W A_J W^T`` and ``Z = Y Psi_m Y + N^T D N``:
    ``Psi^C = Psi_0 + G Z G^T - H Y G^T - G Y H^T``,
    ``p^C = p_0 + 2 H beta - G (Y (2 Psi_m beta + p_m) - 2 N^T D g)``,
    ``eta^C = g^T D g + beta^T Psi_m beta + p_m·beta + eta^A + eta^B``,
    with ``g = W_m beta + gamma`` and ``p_m = p^B_{jB} - p^A_{jA}``.
    """
    Psi, p, eta = metric.Psi, metric.p, metric.eta
    Pm = Psi.take(lv.WA, 0) + Psi.take(lv.WB, 0)
    pm = p.take(lv.bB, 0) - p.take(lv.bA, 0)
    N = np.eye(6) - Wm @ Y
    D = (W * metric.D.take(lv.joint, 0)[:, None, :]) @ np.swapaxes(W, 1, 2)
    g = mv(Wm, beta) + gamma
    Dg = mv(D, g)
    Pb = mv(Pm, beta)
    eta[lv.node] = ((g * Dg + beta * (Pb + pm)).sum(axis=1)
                    + eta.take(lv.node_A) + eta.take(lv.node_B))
    k, P = lv.sign.shape
    if not P:
        return
    Nt = np.swapaxes(N, 1, 2)
    Z = Y @ Pm @ Y + Nt @ D @ N
    H = Psi.take(lv.G, 0) * lv.sign[:, :, None, None]                  # (k, P, 6, 6)
    Q = (0.5 * G.reshape(k, 6 * P, 6) @ Z - (H @ Y[:, None]).reshape(k, 6 * P, 6)) @ Gt
    Q = Q.reshape(k, P, 6, P, 6).transpose(0, 1, 3, 2, 4)    # G Z G^T / 2 - H Y G^T
    Psi[lv.out_Phi] = Psi.take(lv.Phi0, 0) + Q + Q.transpose(0, 2, 1, 4, 3)
    u = mv(Y, 2 * Pb + pm) - 2 * mv(Nt, Dg)
    p[lv.out_b] = p.take(lv.b0, 0) + mv(H, 2 * beta[:, None]) - mv(G, u[:, None])


def back_substitute(levels, js, data, select=None):
    """Top-down pass (T10), (T13): joint wrenches and accelerations into ``data``.

    ``select(n, lv, f)``, given the forces ``f`` (k, P, 6) on the ports of the
    level's nodes, returns the rows to evaluate (``None``: all); joints of rows
    left out keep ``qdd = 0`` and their subtrees must be left out too.
    """
    dof_index = js.dof_index
    f_J, qdd = data.f_J, data.qdd
    for n in range(len(levels) - 1, -1, -1):
        lv = levels[n]
        Y, Wm, G, beta, gamma, W = data.levels[n]
        f = f_J.take(lv.port_joint, 0) * lv.port_side[:, :, None]     # forces on C
        rows = None if select is None else select(n, lv, f)
        joint = lv.joint
        if rows is not None:
            if not len(rows):
                continue
            Y, Wm, G, beta, gamma, W, f = (x[rows] for x in (Y, Wm, G, beta, gamma, W, f))
            joint = joint[rows]
        f_J[joint], qdd[dof_index[joint]] = joint_solution(Y, Wm, G, beta, gamma, W, f)


def joint_solution(Y, Wm, G, beta, gamma, W, f):
    """``f_J`` (T10) and ``qdd`` (T13) (k, 6) of nodes whose port forces are ``f``."""
    u = mv(np.swapaxes(G, -1, -2), f).sum(axis=1)
    fJ = beta - mv(Y, u)                       # (T10)
    r = u + gamma
    return fJ, mv(np.swapaxes(W, 1, 2), mv(Wm, fJ) + r)


def metric_value(metric, lv, f):
    """``A(C) = x^T Psi x + p·x + eta`` (k,) of the level's nodes, ``x = f`` (k, P, 6)."""
    k, P = lv.sign.shape
    Psi = metric.Psi.take(lv.out_Phi, 0).transpose(0, 1, 3, 2, 4).reshape(k, 6 * P, 6 * P)
    x = f.reshape(k, 6 * P)
    return ((x * (mv(Psi, x) + metric.p.take(lv.out_b, 0).reshape(k, 6 * P))).sum(axis=1)
            + metric.eta.take(lv.node))
