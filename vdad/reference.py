"""Reference algorithms, written to be read beside Featherstone's book (RBDA).

RNEA (RBDA Table 5.1), CRBA (RBDA Table 6.2) and ABA (RBDA Table 7.1), one
Python loop over bodies each, in body coordinates at the body origins. They are
the teaching versions and the oracles of the DCA: they share only the joint
model (:func:`vdad.kinematics.joint_kinematics`) with it. Gravity enters by the
base-acceleration trick (``a_0 = -g``), an independent path from the DCA's body
forces. ``f_ext`` follows :func:`vdad.forward_dynamics`.
"""

from __future__ import annotations

import numpy as np

from . import joints as J
from .checks import check_vector, check_wrenches
from .dynamics import check_overflow, passive_forces
from .kinematics import joint_kinematics, plan
from .model import check_configuration, check_model
from .spatial import crf, crm, inertia_at_origin, pose_to_motion_transform


def _setup(model, q, qd, f_ext):
    check_model(model)
    q = check_configuration(model, "q", q)
    qd = check_vector("qd", qd, model.nv)
    f_ext = check_wrenches(model, f_ext)
    R_rel, p_rel, S, _, _ = joint_kinematics(plan(model), q)
    Xup = pose_to_motion_transform(R_rel, p_rel)                    # X_{i<-lambda(i)}
    I = inertia_at_origin(model.mass, model.com, model.inertia)
    d = model.nv_joint
    Sj = [S[i, :, :d[i]] for i in range(model.nb)]
    dofs = [slice(model.v_start[i], model.v_start[i] + d[i]) for i in range(model.nb)]
    # body-frame external wrenches at the origins, from world axes at the com
    fx = np.zeros((model.nb, 6))
    R = np.zeros((model.nb, 3, 3))
    for i in range(model.nb):
        p = model.parent[i]
        R[i] = R_rel[i] if p < 0 else R[p] @ R_rel[i]
        if f_ext is not None:
            n, f = R[i].T @ f_ext[i, :3], R[i].T @ f_ext[i, 3:]
            fx[i] = np.concatenate([n + np.cross(model.com[i], f), f])
    # velocities and the stage term of c_J (J1)
    v = np.zeros((model.nb, 6))
    u = np.zeros((model.nb, 6))
    for i in range(model.nb):
        p = model.parent[i]
        u[i] = Sj[i] @ qd[dofs[i]]
        v[i] = (0 if p < 0 else Xup[i] @ v[p]) + u[i]
    c = np.einsum("kij,kj->ki", crm(v), u)
    for i in range(model.nb):                      # (J1): sum_{r<j} crm(S_r qd_r) S_j qd_j
        prefix = np.zeros(6)
        for s in np.flatnonzero(model.stage_joint == i):
            cols = slice(model.stage_v[s], model.stage_v[s] + J.STAGE_NV[model.stage_kind[s]])
            u_s = S[i, :, cols.start - model.v_start[i]:cols.stop - model.v_start[i]] @ qd[cols]
            c[i] += crm(prefix) @ u_s
            prefix += u_s
    return q, qd, Xup, I, Sj, dofs, fx, v, c


def _a0(model):
    return np.concatenate([np.zeros(3), -model.gravity])


def rnea(model, q, qd, qdd, f_ext=None):
    """Inverse dynamics: generalised forces (nv,) for ``qdd`` (RBDA Table 5.1).

    The result excludes the joint springs and dampers; it is the ``tau`` that,
    added to them, produces ``qdd``.
    """
    q, qd, Xup, I, Sj, dofs, fx, v, c = _setup(model, q, qd, f_ext)
    qdd = check_vector("qdd", qdd, model.nv)
    a = np.zeros((model.nb, 6))
    f = np.zeros((model.nb, 6))
    for i in range(model.nb):
        p = model.parent[i]
        a_p = Xup[i] @ (_a0(model) if p < 0 else a[p])
        a[i] = a_p + Sj[i] @ qdd[dofs[i]] + c[i]
        f[i] = I[i] @ a[i] + crf(v[i]) @ I[i] @ v[i] - fx[i]
    tau = model.armature * qdd                                 # rotor inertia
    for i in range(model.nb - 1, -1, -1):
        tau[dofs[i]] += Sj[i].T @ f[i]
        p = model.parent[i]
        if p >= 0:
            f[p] += Xup[i].T @ f[i]
    return tau - passive_forces(model, q, qd)


def crba(model, q):
    """Joint-space mass matrix ``M`` (nv, nv) (RBDA Table 6.2)."""
    check_model(model)
    _, _, Xup, I, Sj, dofs, _, _, _ = _setup(model, q, np.zeros(model.nv), None)
    Ic = I.copy()
    for i in range(model.nb - 1, -1, -1):
        p = model.parent[i]
        if p >= 0:
            Ic[p] += Xup[i].T @ Ic[i] @ Xup[i]
    M = np.zeros((model.nv, model.nv))
    for i in range(model.nb):
        F = Ic[i] @ Sj[i]
        M[dofs[i], dofs[i]] = Sj[i].T @ F
        j = i
        while model.parent[j] >= 0:
            F = Xup[j].T @ F
            j = model.parent[j]
            M[dofs[i], dofs[j]] = F.T @ Sj[j]
            M[dofs[j], dofs[i]] = M[dofs[i], dofs[j]].T
    M[np.diag_indices(model.nv)] += model.armature
    return M


def bias_forces(model, q, qd, f_ext=None):
    """``C(q, qd) + g(q) - J^T f_ext - passive``: RNEA with ``qdd = 0``."""
    return rnea(model, q, qd, np.zeros(model.nv), f_ext)


def crba_forward_dynamics(model, q, qd, tau=None, f_ext=None):
    """``qdd = M^-1 (tau - bias)`` by a Cholesky solve of the CRBA mass matrix."""
    tau = np.zeros(model.nv) if tau is None else check_vector("tau", tau, model.nv)
    M = crba(model, q)
    L = np.linalg.cholesky(M)
    rhs = tau - bias_forces(model, q, qd, f_ext)
    return np.linalg.solve(L.T, np.linalg.solve(L, rhs))


def aba(model, q, qd, tau=None, f_ext=None):
    """Articulated-body algorithm (RBDA Table 7.1): ``qdd`` (nv,)."""
    q, qd, Xup, I, Sj, dofs, fx, v, c = _setup(model, q, qd, f_ext)
    tau = passive_forces(model, q, qd) + (0 if tau is None else check_vector("tau", tau, model.nv))
    IA = I.copy()
    pA = np.array([crf(v[i]) @ I[i] @ v[i] - fx[i] for i in range(model.nb)])
    U, Dinv, u = [None] * model.nb, [None] * model.nb, [None] * model.nb
    for i in range(model.nb - 1, -1, -1):
        U[i] = IA[i] @ Sj[i]
        Dinv[i] = np.linalg.inv(Sj[i].T @ U[i] + np.diag(model.armature[dofs[i]]))
        u[i] = tau[dofs[i]] - Sj[i].T @ pA[i]
        p = model.parent[i]
        if p >= 0:
            Ia = IA[i] - U[i] @ Dinv[i] @ U[i].T
            pa = pA[i] + Ia @ c[i] + U[i] @ Dinv[i] @ u[i]
            IA[p] += Xup[i].T @ Ia @ Xup[i]
            pA[p] += Xup[i].T @ pa
    a = np.zeros((model.nb, 6))
    qdd = np.zeros(model.nv)
    for i in range(model.nb):
        p = model.parent[i]
        a_p = Xup[i] @ (_a0(model) if p < 0 else a[p]) + c[i]
        qdd[dofs[i]] = Dinv[i] @ (u[i] - U[i].T @ a_p)
        a[i] = a_p + Sj[i] @ qdd[dofs[i]]
    return check_overflow(model, qdd, q, qd=qd, tau=tau)
