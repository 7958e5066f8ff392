"""Rigid groups of adaptive dynamics: the cached data of hybrid bodies (theory §6).

A node of the assembly tree whose joints are all rigid moves as one rigid body
(T19)-(T20). :class:`RigidGroups` keeps, for every such node, data that stay
constant while it stays rigid, in the frame of its *top* body (the body whose
parent is outside it; the world frame when the node holds a ground leaf, which
makes it immobile):

* composite ``mass``, centre of mass ``com`` and rotational inertia ``inertia``
  about it;
* the same of its bodies' leaves (:func:`vdad.dca.leaf_inertias`: thin and
  light bodies raised, (R2)-(R5) of ``docs/accuracy.md``), ``leaf_mass``,
  ``leaf_com``, ``leaf_inertia``, and the inverse ``Iinv`` of ``leaf_inertia``,
  which the group's leaf (T2) uses; the model's own for bodies that are not
  raised;
* the pose of each port's body (``port_R``, ``port_p``, one per port slot of the
  tree) and the pose of the top body of its ``B`` child (``rel_R``, ``rel_p``);
* the sums of the external wrenches on its bodies, ``N = sum n_i``,
  ``F = sum f_i`` (world axes) and ``K = sum c_i f_i^T`` (``c_i`` the centres of
  mass in the node frame), from which the wrench in the node frame follows for
  any orientation ``R`` (``vdad.region.group_leaf``), so the sums stay valid while
  the node moves.

Bodies hold their own data (a body is a rigid group of one). A node is frozen
from its two children in O(its ports) (:func:`freeze_node`), so rigidifying a
sub-assembly costs O(its internal nodes) and never touches the rest; a force
change on a body is carried up through its rigid ancestors only (the
force-update region, :func:`carry_forces`); the pose of any body follows from
its group (:func:`pose_in_group`). All of it is compiled per node.
"""

from __future__ import annotations

import numpy as np

from ._linalg import (
    compose_pose,
    copy_pose,
    identity_pose,
    inlined,
    inverse3,
    kernel,
    mm3,
    mv3,
    pass_kernel,
)
from .dca import leaf_inertias
from .heaps import sort_marked
from .kinematics import joint_placement, plan


class RigidGroups:
    """Per-node rigid-group data of ``tree`` (shapes in brackets; node stores have
    one extra entry, index ``n_nodes``, for the ground: grounded, massless, no
    forces, and above the roots). ``arrays``: the tuple the kernels take."""

    def __init__(self, tree):
        model = tree.model
        self.tree = tree
        N = tree.n_nodes + 1
        nb = model.nb
        self.mass = np.zeros(N)                                  # [N]
        self.com = np.zeros((N, 3))                              # [N, 3]
        self.inertia = np.zeros((N, 3, 3))                       # [N, 3, 3]
        self.Iinv = np.zeros((N, 3, 3))                          # [N, 3, 3] leaf's
        self.leaf_mass = np.zeros(N)                             # [N]
        self.leaf_com = np.zeros((N, 3))                         # [N, 3]
        self.leaf_inertia = np.zeros((N, 3, 3))                  # [N, 3, 3]
        self.grounded = np.zeros(N, bool)
        self.grounded[-1] = True
        self.mass[:nb], self.com[:nb], self.inertia[:nb] = model.mass, model.com, model.inertia
        leaves = leaf_inertias(model)
        own = np.linalg.inv(model.inertia)
        changed = np.any(leaves.Iinv != own, axis=(1, 2))
        self.Iinv[:nb] = leaves.Iinv
        self.leaf_mass[:nb], self.leaf_com[:nb] = leaves.mass, model.com
        self.leaf_inertia[:nb] = model.inertia
        self.leaf_inertia[:nb][changed] = np.linalg.inv(leaves.Iinv[changed])
        self.port_R = np.broadcast_to(np.eye(3), (tree.n_slots, 3, 3)).copy()
        self.port_p = np.zeros((tree.n_slots, 3))
        self.rel_R = np.broadcast_to(np.eye(3), (N, 3, 3)).copy()
        self.rel_p = np.zeros((N, 3))
        self.fN = np.zeros((N, 3))
        self.fF = np.zeros((N, 3))
        self.fK = np.zeros((N, 3, 3))
        self.f_ext = np.zeros((nb, 6))            # wrenches the sums hold
        self.any_force = False
        self.pending = np.zeros((3, N, 3, 3))      # carry_forces' scratch
        self.mark = np.zeros(N, bool)
        self.order = np.zeros(N, np.int64)
        self.is_B = np.zeros(N, bool)             # node is the B child of its parent
        self.is_B[tree.right] = True
        self.up = np.append(np.where(tree.up < 0, tree.n_nodes, tree.up), tree.n_nodes)

    @property
    def arrays(self) -> tuple:
        return (self.mass, self.com, self.inertia, self.Iinv, self.grounded, self.rel_R,
                self.rel_p, self.port_R, self.port_p, self.fN, self.fF, self.fK,
                self.leaf_mass, self.leaf_com, self.leaf_inertia)

    def freeze(self, nodes, q, kin):
        """Make internal ``nodes`` (a union of subtrees) rigid at configuration ``q``
        (nq,): their group data from their children's, bottom-up
        (:func:`freeze_node`); ``kin`` (a :class:`~vdad.kinematics.Kinematics` of
        the whole model) lends the rows of the frozen joints as scratch."""
        nodes = np.sort(np.asarray(nodes, np.int64))
        freeze_nodes(nodes, self.tree.model.nb, self.tree.arrays, plan(self.tree.model).arrays,
                     q, kin.R_rel, kin.p_rel, kin.R3, self.arrays)
        return len(nodes)

    def update_forces(self, f_ext, active):
        """Carry changes of the external wrenches ``f_ext`` (nb, 6; None: zero) up
        through the rigid ancestors of each changed body, stopping below active
        nodes (``active``: node mask). Returns the number of node visits."""
        if f_ext is None:
            if not self.any_force:
                return 0
            f_ext = np.zeros_like(self.f_ext)
        self.any_force = bool(np.any(f_ext))
        return carry_forces(np.ascontiguousarray(f_ext, dtype=float), self.f_ext, active,
                            self.up, self.is_B, self.arrays, self.pending, self.mark,
                            self.order)

    def pose_in_group(self, bodies, active, frames=()):
        """For ``bodies``: the rigid group (front node) holding each, and the body's
        pose ``(R, p)`` in the group frame (world frame for grounded groups); in
        the world with ``frames`` = (top (N,), R, p of the active joints' child
        bodies) (:func:`poses_in_groups`)."""
        bodies = np.ascontiguousarray(bodies, np.int64)
        group = np.empty(len(bodies), np.int64)
        R, p = np.empty((len(bodies), 3, 3)), np.empty((len(bodies), 3))
        top, R_top, p_top = frames or (np.zeros(0, np.int64), np.zeros((0, 3, 3)),
                                       np.zeros((0, 3)))
        poses_in_groups(bodies, active, self.up, self.is_B, self.rel_R, self.rel_p, bool(frames),
                        self.grounded, top, R_top, p_top, group, R, p)
        return group, R, p


# --- kernels: one node each --------------------------------------------------------------

@inlined
def child_slot(child, n_nodes):
    """The slot of an assembly-tree child id in the node stores (the ground, -1, is
    slot ``n_nodes``)."""
    return n_nodes if child < 0 else child


@inlined
def composite(mass, com, inertia, A, B, C, TR, Tp, R3):
    """Mass, centre of mass and inertia of node ``C`` (rows of ``mass``, ``com``,
    ``inertia``) from those of ``A`` (in ``C``'s frame) and ``B`` (in its top's
    frame, at pose ``(TR, Tp)`` in ``C``'s): parallel axes. ``R3`` (>= 3, 3, 3):
    scratch."""
    mA, mB = mass[A], mass[B]
    m = mA + mB
    cB = R3[2, 0]
    mv3(TR, com[B], cB)
    for r in range(3):
        cB[r] += Tp[r]
    c = com[C]
    for r in range(3):
        c[r] = (mA * com[A, r] + mB * cB[r]) / m
    I, IB, dA, dB = inertia[C], R3[1], R3[2, 1], R3[2, 2]
    for r in range(3):                                   # TR I_B TR^T
        for s in range(3):
            acc = 0.0
            for k in range(3):
                acc += TR[r, k] * (inertia[B, k, 0] * TR[s, 0] + inertia[B, k, 1] * TR[s, 1]
                                   + inertia[B, k, 2] * TR[s, 2])
            IB[r, s] = acc
    for r in range(3):
        dA[r] = com[A, r] - c[r]
        dB[r] = cB[r] - c[r]
    nA = dA[0] ** 2 + dA[1] ** 2 + dA[2] ** 2
    nB = dB[0] ** 2 + dB[1] ** 2 + dB[2] ** 2
    for r in range(3):                                   # parallel axes
        for s in range(3):
            e = 1.0 if r == s else 0.0
            I[r, s] = (inertia[A, r, s] + IB[r, s] + mA * (nA * e - dA[r] * dA[s])
                       + mB * (nB * e - dB[r] * dB[s]))
    mass[C] = m


@inlined
def freeze_node(C, nb, tree, js, q, R_rel, p_rel, R3, groups):
    """Group data of internal node ``C`` from its children ``A`` (the ground: the
    world frame, massless) and ``B`` across its joint ``j`` at ``q`` (theory §6):
    ``B``'s top in ``C``'s frame ``(TR, Tp)`` (``A``'s port pose of ``j``, then
    ``j``'s placement), composite mass, centre of mass and inertia (parallel axes,
    :func:`composite`) of its bodies and of their leaves, port poses, force sums
    (``K_C = K_A + TR K_B + Tp F_B^T``). ``R_rel``, ``p_rel`` (nb, ...): row ``j``
    is scratch; ``R3`` (>= 3, 3, 3): scratch."""
    (left, right, joint, port_A, port_B, n_ports, pair_base, slot_base, slot_joint,
     slot_side, slot_child, slot_index, slot_sign, post, segments) = tree
    (order, parent, R0, p0, stage0, n_stages, v_start, nv_joint, stage_kind, stage_axis,
     stage_anchor, stage_ref, stage_q, stage_v, s_pad, subspace) = js
    (mass, com, inertia, Iinv, grounded, rel_R, rel_p, port_R, port_p, fN, fF, fK, leaf_mass,
     leaf_com, leaf_inertia) = groups
    ground = mass.shape[0] - 1
    i = C - nb
    A, B, j = left[i], right[i], joint[i]
    Ag = child_slot(A, ground)
    joint_placement(j, R0, p0, stage0, n_stages, stage_kind, stage_axis, stage_anchor,
                    stage_ref, stage_q, q, R_rel, p_rel, R3[0], R3[1], rel_p[C])
    TR, Tp = rel_R[C], rel_p[C]
    if A < 0:                                   # C's frame is the world
        for r in range(3):
            Tp[r] = p_rel[j, r]
            for s in range(3):
                TR[r, s] = R_rel[j, r, s]
    else:
        sA = slot_base[A] + port_A[i]
        mm3(port_R[sA], R_rel[j], TR)
        mv3(port_R[sA], p_rel[j], Tp)
        for r in range(3):
            Tp[r] += port_p[sA, r]
    composite(mass, com, inertia, Ag, B, C, TR, Tp, R3)
    composite(leaf_mass, leaf_com, leaf_inertia, Ag, B, C, TR, Tp, R3)
    inverse3(leaf_inertia[C], Iinv[C])
    grounded[C] = grounded[Ag]
    s0 = slot_base[C]
    for a in range(n_ports[C]):                          # port poses in C's frame
        X, src = slot_child[s0 + a], slot_base[slot_child[s0 + a]] + slot_index[s0 + a]
        if X == A:
            for r in range(3):
                port_p[s0 + a, r] = port_p[src, r]
                for s in range(3):
                    port_R[s0 + a, r, s] = port_R[src, r, s]
        else:
            mm3(TR, port_R[src], port_R[s0 + a])
            mv3(TR, port_p[src], port_p[s0 + a])
            for r in range(3):
                port_p[s0 + a, r] += Tp[r]
    for r in range(3):                                   # force sums
        fN[C, r] = fN[Ag, r] + fN[B, r]
        fF[C, r] = fF[Ag, r] + fF[B, r]
        for s in range(3):
            fK[C, r, s] = (fK[Ag, r, s] + TR[r, 0] * fK[B, 0, s] + TR[r, 1] * fK[B, 1, s]
                           + TR[r, 2] * fK[B, 2, s] + Tp[r] * fF[B, s])


@pass_kernel
def freeze_nodes(nodes, nb, tree, js, q, R_rel, p_rel, R3, groups):
    """:func:`freeze_node` of internal ``nodes`` in ascending order (children
    first: nodes are numbered in depth-first post-order)."""
    for k in range(nodes.shape[0]):
        freeze_node(nodes[k], nb, tree, js, q, R_rel, p_rel, R3, groups)


@pass_kernel
def carry_forces(f_ext, held, active, up, is_B, groups, pending, mark, order):
    """Carry each body's change of external wrench (``f_ext`` against the ``held``
    one, both (nb, 6), world axes, at the centre of mass) into its own sums and up
    through its rigid ancestors, stopping below the first active one: ``dN``,
    ``dF``, and ``dK = c dF^T`` composed with ``(rel_R, rel_p)`` on the way up from
    a ``B`` child. The changed bodies and their rigid ancestors (the force-update
    region) are marked first, each once (a climb stops at a marked node), then
    visited once each in ascending order (children first), each handing its
    accumulated change to its parent (``pending`` [3, N, 3, 3]: ``dN``, ``dF`` in
    row 0, ``dK``; ``mark`` [N], ``order`` [N]: scratch), so that ``n_f`` changed
    bodies cost O(n_f log(n / n_f)) visits (theory §6). Returns the visits."""
    (mass, com, inertia, Iinv, grounded, rel_R, rel_p, port_R, port_p, fN, fF, fK, leaf_mass,
     leaf_com, leaf_inertia) = groups
    n = 0
    for i in range(f_ext.shape[0]):
        same = True
        for r in range(6):
            same = same and f_ext[i, r] == held[i, r]
        if same:
            continue
        dN, dF, dK = pending[0, i, 0], pending[0, i, 1], pending[1, i]
        for r in range(3):
            dN[r] = f_ext[i, r] - held[i, r]
            dF[r] = f_ext[i, 3 + r] - held[i, 3 + r]
        for r in range(3):
            for s in range(3):
                dK[r, s] = com[i, r] * dF[s]
        for r in range(6):
            held[i, r] = f_ext[i, r]
        node = i
        mark[node] = True
        order[n] = node
        n += 1
        while not active[up[node]] and not mark[up[node]]:
            node = up[node]
            mark[node] = True
            order[n] = node
            n += 1
    sort_marked(order, n, mark)
    K2 = pending[2, 0]
    for k in range(n):
        node = order[k]
        dN, dF, dK = pending[0, node, 0], pending[0, node, 1], pending[1, node]
        for r in range(3):
            fN[node, r] += dN[r]
            fF[node, r] += dF[r]
            for s in range(3):
                fK[node, r, s] += dK[r, s]
        u = up[node]
        if not active[u]:                      # hand the change to the parent
            uN, uF, uK = pending[0, u, 0], pending[0, u, 1], pending[1, u]
            if is_B[node]:
                mm3(rel_R[u], dK, K2)
                for r in range(3):
                    for s in range(3):
                        K2[r, s] += rel_p[u, r] * dF[s]
            else:
                for r in range(3):
                    for s in range(3):
                        K2[r, s] = dK[r, s]
            for r in range(3):
                uN[r] += dN[r]
                uF[r] += dF[r]
                for s in range(3):
                    uK[r, s] += K2[r, s]
        for r in range(3):
            dN[r] = 0.0
            dF[r] = 0.0
            for s in range(3):
                dK[r, s] = 0.0
        mark[node] = False
    return n


@inlined
def group_poses(nb, left, right, forest, visit, n_visit, active, grounded, top, rel_R, rel_p,
                R_top, p_top, R, p, t):
    """World poses ``R`` (n_nodes + 1, 3, 3), ``p`` (n_nodes + 1, 3) of every body
    of the hybrid, top-down from the front: each front node at its group's frame
    (:func:`front_frames`), then down every rigid group (:func:`down_groups`
    of every root's subtree; ``forest`` = (post, segments) of the tree). Rows
    ``nb`` on hold the internal nodes' frames; ``t`` (3, 3) scratch. One pose
    copy per body and one composition per internal node of a group: O(bodies),
    against :func:`poses_in_groups`' O(depth) per body."""
    front_frames(nb, visit, n_visit, active, grounded, top, R_top, p_top, R, p)
    down_groups(0, forest[1].shape[0] - 1, nb, left, right, forest, active, rel_R, rel_p, R, p,
                t)


@inlined
def front_frames(nb, visit, n_visit, active, grounded, top, R_top, p_top, R, p):
    """The world pose ``R[F]``, ``p[F]`` of each front node ``F`` (the entries of
    ``visit[:n_visit]`` that are not active): its group's frame, the world if
    ``grounded``, else the pose ``R_top``, ``p_top`` of its ``top`` body."""
    for e in range(n_visit):
        F = visit[e]
        if F >= nb and active[F]:
            continue
        if grounded[F]:
            identity_pose(R[F], p[F])
        else:
            copy_pose(R_top[top[F]], p_top[top[F]], R[F], p[F])


@inlined
def down_groups(r0, r1, nb, left, right, forest, active, rel_R, rel_p, R, p, t):
    """Down the rigid groups of the subtrees of roots ``r0`` to ``r1 - 1``
    (``forest`` = (post, segments): their nodes in reverse post-order, parents
    first), from their front nodes' poses (:func:`front_frames`): each internal
    node that is not active places its children, an ``A`` child in its own
    frame, the top body of a ``B`` child at ``rel_R``, ``rel_p`` in it (the
    ground, a child -1, has no pose); ``t`` (3, 3) scratch."""
    post, segments = forest
    for k in range(segments[r1] - 1, segments[r0] - 1, -1):
        C = post[k]
        if C < nb or active[C]:
            continue
        A, B = left[C - nb], right[C - nb]
        if A >= 0:
            copy_pose(R[C], p[C], R[A], p[A])
        if B >= 0:
            copy_pose(rel_R[C], rel_p[C], R[B], p[B])
            compose_pose(R[C], p[C], R[B], p[B], t)


@kernel
def poses_in_groups(bodies, active, up, is_B, rel_R, rel_p, world, grounded, top, R_top, p_top,
                    group, R, p):
    """For each of ``bodies``: the front node holding it (``group``) and its pose
    ``(R, p)`` in that node's frame, composed up its rigid ancestors; with
    ``world``, then composed with the group's world frame: the world for a
    ``grounded`` group, else the pose ``R_top``, ``p_top`` (per body) of its
    ``top`` body."""
    t = np.empty((3, 3))
    for k in range(bodies.shape[0]):
        node = bodies[k]
        Rk, pk = R[k], p[k]
        identity_pose(Rk, pk)
        while not active[up[node]]:
            u = up[node]
            if is_B[node]:
                compose_pose(rel_R[u], rel_p[u], Rk, pk, t)
            node = u
        group[k] = node
        if world and not grounded[node]:
            compose_pose(R_top[top[node]], p_top[top[node]], Rk, pk, t)
