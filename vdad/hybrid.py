"""Rigid groups of adaptive dynamics: the cached data of hybrid bodies (theory §6).

A node of the assembly tree whose joints are all rigid moves as one rigid body
(T19)-(T20). :class:`RigidGroups` keeps, for every such node, data that stay
constant while it stays rigid, in the frame of its *top* body (the body whose
parent is outside the node; the world frame when the node holds a ground leaf,
which makes it immobile):

* composite ``mass``, centre of mass ``com`` and rotational inertia ``inertia``
  about it, and ``Iinv = diag(I^-1, 1/m)`` (T2);
* the pose of each port's body (``port_R``, ``port_p``, one per port slot of the
  tree) and the pose of the top body of its ``B`` child (``rel_R``, ``rel_p``);
* the sums of the external wrenches on its bodies, ``N = sum n_i``,
  ``F = sum f_i`` (world axes) and ``K = sum c_i f_i^T`` (``c_i`` the centres of
  mass in the node frame), from which the wrench in the node frame follows for
  any orientation ``R`` (:func:`group_wrench`), so the sums stay valid while the
  node moves.

Nodes are frozen bottom-up from their children (:meth:`RigidGroups.freeze`), a
force change on a body is carried up through its rigid ancestors only (the
force-update region, :meth:`RigidGroups.update_forces`), and the pose of any
body follows from its group (:meth:`RigidGroups.pose_in_group`).
"""

from __future__ import annotations

import numpy as np

from .kinematics import joint_kinematics, joint_set
from .levels import inverse_inertia
from .spatial import cross3, mv


class RigidGroups:
    """Per-node rigid-group data of ``tree`` (node stores have one extra entry,
    index ``n_nodes``, for the ground: grounded, massless, no forces)."""

    def __init__(self, tree):
        model = tree.model
        self.tree = tree
        N = tree.n_nodes + 1
        nb = model.nb
        self.mass = np.zeros(N)
        self.com = np.zeros((N, 3))
        self.inertia = np.zeros((N, 3, 3))
        self.Iinv = np.zeros((N, 6, 6))
        self.grounded = np.zeros(N, bool)
        self.grounded[-1] = True
        self.mass[:nb], self.com[:nb], self.inertia[:nb] = model.mass, model.com, model.inertia
        self.Iinv[:nb] = inverse_inertia(model.mass, model.inertia)
        self.port_R = np.broadcast_to(np.eye(3), (tree.n_slots, 3, 3)).copy()
        self.port_p = np.zeros((tree.n_slots, 3))
        self.rel_R = np.broadcast_to(np.eye(3), (N, 3, 3)).copy()
        self.rel_p = np.zeros((N, 3))
        self.fN = np.zeros((N, 3))
        self.fF = np.zeros((N, 3))
        self.fK = np.zeros((N, 3, 3))
        self.f_ext = np.zeros((nb, 6))            # wrenches the sums hold
        self.any_force = False
        right = np.zeros(N, bool)
        right[tree.right] = True
        self.is_B = right                         # node is the B child of its parent
        self.up = np.append(np.where(tree.up < 0, tree.n_nodes, tree.up), tree.n_nodes)

    def freeze(self, nodes, q):
        """Make internal ``nodes`` (a union of subtrees) rigid at configuration ``q``
        (nq,): their group data from their children's, bottom-up (vectorised per
        level). Returns the number of nodes frozen."""
        tree = self.tree
        model = tree.model
        mark = np.zeros(tree.n_nodes + 1, bool)
        mark[nodes] = True
        todo = [(lv, np.flatnonzero(mark[lv.node])) for lv in tree.levels]
        todo = [(lv, rows) for lv, rows in todo if len(rows)]
        if not todo:
            return 0
        joints = np.concatenate([lv.joint[rows] for lv, rows in todo])
        js = joint_set(model, joints, np.full(len(joints), -1))
        R_all, p_all, *_ = joint_kinematics(js, q[js.q_index])
        start = 0
        for lv, rows in todo:
            k = len(rows)
            Rj, pj = R_all[start:start + k], p_all[start:start + k]
            start += k
            A, B, C = lv.node_A[rows], lv.node_B[rows], lv.node[rows]
            Ra, pa = self.port_R[lv.bA[rows]], self.port_p[lv.bA[rows]]
            TR, Tp = Ra @ Rj, pa + mv(Ra, pj)               # top(B) in top(C)
            mA, mB = self.mass[A], self.mass[B]
            cA, cB = self.com[A], Tp + mv(TR, self.com[B])
            m = mA + mB
            c = (mA[:, None] * cA + mB[:, None] * cB) / m[:, None]
            IB = TR @ self.inertia[B] @ np.swapaxes(TR, 1, 2)
            self.inertia[C] = (self.inertia[A] + _parallel_axis(mA, cA - c)
                               + IB + _parallel_axis(mB, cB - c))
            self.mass[C], self.com[C] = m, c
            self.Iinv[C] = inverse_inertia(m, self.inertia[C])
            self.grounded[C] = self.grounded[A]
            self.rel_R[C], self.rel_p[C] = TR, Tp
            sign, b0, out = lv.sign[rows], lv.b0[rows], lv.out_b[rows]
            beta = (sign > 0)[:, :, None]
            PR, Pp = self.port_R[b0], self.port_p[b0]
            self.port_R[out] = np.where(beta[..., None], TR[:, None] @ PR, PR)
            self.port_p[out] = np.where(beta, Tp[:, None] + mv(TR[:, None], Pp), Pp)
            self.fN[C] = self.fN[A] + self.fN[B]
            self.fF[C] = self.fF[A] + self.fF[B]
            self.fK[C] = (self.fK[A] + TR @ self.fK[B]
                          + Tp[:, :, None] * self.fF[B][:, None, :])
        return int(mark.sum())

    def _climb(self, nodes, active):
        """Walk from ``nodes`` up through their rigid ancestors, stopping below
        active nodes (``active``: node mask). Yields, per step, the indices of the
        walks still climbing, the ancestor reached and whether they came from its
        ``B`` child (whose top frame is then composed with ``rel_R``, ``rel_p``)."""
        node = np.array(nodes, int)
        idx = np.arange(len(node))
        while len(idx):
            up = self.up[node]
            go = ~active[up]
            idx, node, up = idx[go], node[go], up[go]
            yield idx, up, self.is_B[node]
            node = up

    def update_forces(self, f_ext, active):
        """Carry changes of the external wrenches ``f_ext`` (nb, 6; None: zero) up
        through the rigid ancestors of each changed body, stopping below active
        nodes (``active``: node mask). Returns the number of node visits."""
        nb = self.tree.model.nb
        if f_ext is None:
            if not self.any_force:
                return 0
            f_ext = np.zeros((nb, 6))
        self.any_force = bool(np.any(f_ext))
        changed = np.flatnonzero(np.any(f_ext != self.f_ext, axis=1))
        if not len(changed):
            return 0
        d = f_ext[changed] - self.f_ext[changed]
        self.f_ext[changed] = f_ext[changed]
        dN, dF = d[:, :3], d[:, 3:]
        dK = self.com[changed][:, :, None] * dF[:, None, :]
        np.add.at(self.fN, changed, dN)
        np.add.at(self.fF, changed, dF)
        np.add.at(self.fK, changed, dK)
        visits = len(changed)
        for idx, up, B in self._climb(changed, active):
            dK[idx] = np.where(B[:, None, None], self.rel_R[up] @ dK[idx]
                               + self.rel_p[up][:, :, None] * dF[idx][:, None, :], dK[idx])
            np.add.at(self.fN, up, dN[idx])
            np.add.at(self.fF, up, dF[idx])
            np.add.at(self.fK, up, dK[idx])
            visits += len(idx)
        return visits

    def pose_in_group(self, bodies, active):
        """For ``bodies``: the rigid group (front node) holding each, and the body's
        pose ``(R, p)`` in the group frame (world frame for grounded groups)."""
        group = np.array(bodies, int)
        R = np.broadcast_to(np.eye(3), (len(group), 3, 3)).copy()
        p = np.zeros((len(group), 3))
        for idx, up, B in self._climb(group, active):
            p[idx] = np.where(B[:, None], self.rel_p[up] + mv(self.rel_R[up], p[idx]), p[idx])
            R[idx] = np.where(B[:, None, None], self.rel_R[up] @ R[idx], R[idx])
            group[idx] = up
        return group, R, p


def _parallel_axis(m, d):
    """``m (|d|^2 1 - d d^T)`` (k, 3, 3): inertia of a point mass about the origin."""
    return m[:, None, None] * (np.einsum("ki,ki->k", d, d)[:, None, None] * np.eye(3)
                               - d[:, :, None] * d[:, None, :])


def group_wrench(groups, nodes, R, gravity):
    """Known wrench (k, 6) on rigid groups ``nodes`` at their centres of mass, in
    group axes, for group orientations ``R`` (k, 3, 3): gravity plus the cached
    external sums (moment ``R^T N + vee(K R)`` about the group origin)."""
    RT = np.swapaxes(R, 1, 2)
    KR = groups.fK[nodes] @ R
    m_origin = mv(RT, groups.fN[nodes]) + np.stack(
        [KR[:, 1, 2] - KR[:, 2, 1], KR[:, 2, 0] - KR[:, 0, 2], KR[:, 0, 1] - KR[:, 1, 0]], axis=1)
    F = mv(RT, groups.fF[nodes])
    f = np.concatenate([m_origin - cross3(groups.com[nodes], F), F], axis=1)
    f[:, 3:] += groups.mass[nodes][:, None] * (RT @ gravity)
    return f


def momentum_at_com(groups, nodes, v):
    """Spatial momentum (k, 6) of rigid groups ``nodes`` moving with velocity ``v``
    (k, 6, at the group origin, group axes), about the centre of mass."""
    w = v[:, :3]
    vc = v[:, 3:] + cross3(w, groups.com[nodes])
    return np.concatenate([mv(groups.inertia[nodes], w), groups.mass[nodes][:, None] * vc], axis=1)


