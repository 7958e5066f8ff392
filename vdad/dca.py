"""Featherstone's divide-and-conquer algorithm, level by level (theory §2-5).

:func:`leaves` fills the leaf blocks (T2)-(T3), :func:`assemble` runs the
bottom-up pass (T6)-(T12) over the levels of an :class:`~vdad.assembly.AssemblyTree`
and :func:`back_substitute` the top-down pass (T10), (T13). Each loop runs over
levels in Python, with every node of a level evaluated in stacked numpy arrays.

Port quantities are expressed in *port frames*: both ports of joint ``J`` use the
frame of ``J``'s child body (at the joint, body axes), so a joint needs no
transform between its two sides and every quantity is translation-invariant
(theory §1).

Signed column blocks: for a port ``a`` of ``C`` taken from child ``X`` (``A`` or
``B``), ``G_a = s_a Phi^X_{a j_X}`` with ``s_a = -1`` on ``alpha`` and ``+1`` on
``beta``. Then (T11)-(T12) read ``Phi^C = blockdiag(Phi^A, Phi^B) - G Y G^T`` and
``b^C = b^X + G beta_C``, and (T10), (T13) read ``f_J = beta_C - Y u``,
``r = u + gamma`` with ``u = sum_a G_a^T f_a``.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import lru_cache

import numpy as np

from .kinematics import plan
from .spatial import cross3, motion_transform, mv


@dataclass
class DCAData:
    """Work arrays of one DCA evaluation (Pinocchio's Data; shapes in brackets).

    Phi [n_blocks, 6, 6], b [n_slots, 6]: block stores of the tree.
    f_J [nj + 1, 6]: joint wrenches (last row: zero, read by padding).
    qdd [nv + 1]: joint accelerations (last entry: scratch for padding).
    levels: per level, the intermediates kept for the top-down pass
    (``Y``, ``W_m``, ``G``, ``beta``, ``gamma``, ``W``) and for the adaptive
    metrics of later passes.
    """

    Phi: np.ndarray
    b: np.ndarray
    f_J: np.ndarray
    qdd: np.ndarray
    levels: list = field(default_factory=list)


def make_data(tree) -> DCAData:
    """Allocate the work arrays for ``tree``."""
    model = tree.model
    return DCAData(np.zeros((tree.n_blocks, 6, 6)), np.zeros((tree.n_slots, 6)),
                   np.zeros((model.nb + 1, 6)), np.zeros(model.nv + 1),
                   [None] * len(tree.levels))


def body_wrenches(model, kin, f_ext):
    """Net known wrench on each body at its centre of mass, body axes (nb, 6).

    Gravity ``m g`` plus the external wrench ``f_ext`` (nb, 6), given as
    (torque about the centre of mass; force) in world axes (theory §1).
    """
    RT = np.swapaxes(kin.R, 1, 2)
    f = np.zeros((model.nb, 6))
    f[:, 3:] = model.mass[:, None] * (RT @ model.gravity)
    if f_ext is not None:
        f[:, :3] += mv(RT, f_ext[:, :3])
        f[:, 3:] += mv(RT, f_ext[:, 3:])
    return f


def leaves(model, tree, kin, f_body, data):
    """Leaf blocks (T2) and biases (T3) of every body into ``data``.

    ``f_body`` (nb, 6) is the known wrench at each centre of mass in body axes.
    """
    lp = tree.leaves
    com = model.com[lp.body]                                        # (np_, 3)
    j = lp.joint
    E = np.where(lp.inbound[:, None, None], np.eye(3), np.swapaxes(kin.R_rel[j], 1, 2))
    r = np.where(lp.inbound[:, None], 0.0, kin.p_rel[j]) - com
    X = motion_transform(E, r)                                      # X_{h<-c} (np_, 6, 6)
    Iinv = _inverse_inertia(model)                                  # (nb, 6, 6)
    Z = X @ Iinv[lp.body]
    XT = np.ascontiguousarray(np.swapaxes(X, 1, 2))
    data.Phi[lp.pair_block] = Z[lp.pair_h] @ XT[lp.pair_k]
    w, v = kin.v[:, :3], kin.v[:, 3:] + cross3(kin.v[:, :3], model.com)   # at the com
    Iw = mv(model.inertia, w)
    bias = np.concatenate([cross3(w, Iw), model.mass[:, None] * cross3(w, v)], axis=1)
    a_c = mv(Iinv, f_body - bias)              # (nb, 6)
    data.b[lp.slot] = mv(X, a_c[lp.body])


@lru_cache(maxsize=64)
def _inverse_inertia(model):
    """``Ibar_c^-1 = diag(I_c^-1, 1/m)`` per body (nb, 6, 6), as in (T2)."""
    Iinv = np.zeros((model.nb, 6, 6))
    Iinv[:, :3, :3] = np.linalg.inv(model.inertia)
    Iinv[:, 3:, 3:] = (1.0 / model.mass)[:, None, None] * np.eye(3)
    Iinv.setflags(write=False)
    return Iinv


def assemble(model, tree, kin, tau_ext, data):
    """Bottom-up pass (T6)-(T12) over all levels; ``tau_ext`` (nv + 1,) ends in 0."""
    pl = plan(model)
    Phi, b = data.Phi, data.b
    for n, lv in enumerate(tree.levels):
        jid = lv.joint
        Wm = Phi[lv.WA] + Phi[lv.WB]                                    # (T6)
        T = kin.T[jid]
        Tt = np.ascontiguousarray(np.swapaxes(T, 1, 2))
        Y = T @ np.linalg.inv(Tt @ Wm @ T + pl.T_pad_eye[jid]) @ Tt    # (T7)
        W = kin.W[jid]
        Wtau = mv(W, tau_ext[pl.dof_index[jid]])
        gamma = b[lv.bB] - b[lv.bA] - kin.c[jid]                        # (T8)
        beta = Wtau - mv(Y, mv(Wm, Wtau) + gamma)  # (T9)
        k, P = lv.sign.shape
        G = Phi[lv.G] * lv.sign[:, :, None, None]                       # (k, P, 6, 6)
        if P:
            GY = (G @ Y[:, None]).reshape(k, 6 * P, 6)
            Gt = np.ascontiguousarray(np.swapaxes(G.reshape(k, 6 * P, 6), 1, 2))
            M = (GY @ Gt).reshape(k, P, 6, P, 6)
            PhiC = Phi[lv.Phi0] - M.transpose(0, 1, 3, 2, 4)             # (T11)
            Phi[lv.out_Phi] = 0.5 * (PhiC + PhiC.transpose(0, 2, 1, 4, 3))
            b[lv.out_b] = b[lv.b0] + mv(G, beta[:, None])                # (T12)
        data.levels[n] = (Y, Wm, G, beta, gamma, W)


def back_substitute(model, tree, data):
    """Top-down pass (T10), (T13): joint wrenches and accelerations into ``data``."""
    dof_index = plan(model).dof_index
    f_J, qdd = data.f_J, data.qdd
    for n in range(len(tree.levels) - 1, -1, -1):
        lv = tree.levels[n]
        Y, Wm, G, beta, gamma, W = data.levels[n]
        f = f_J[lv.port_joint] * lv.port_side[:, :, None]              # forces on C
        u = mv(np.swapaxes(G, -1, -2), f).sum(axis=1)
        fJ = beta - mv(Y, u)                       # (T10)
        r = u + gamma
        f_J[lv.joint] = fJ
        qdd[dof_index[lv.joint]] = mv(np.swapaxes(W, 1, 2), mv(Wm, fJ) + r)  # (T13)
