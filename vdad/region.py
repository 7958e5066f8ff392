"""The DCA on the active region of adaptive dynamics, node by node (Kim 2008 §4.2;
theory §6; ``docs/adaptive.md``).

The active region is per-node state: flags ``active`` (internal nodes whose
joints are articulated), ``pinned`` (never rigidified) and ``desc`` (descended
into this step). :func:`rebuild` turns the flags into what the passes visit, in
O(active nodes): the active nodes and their *front* (their children outside the
region, and roots outside it, each a rigid group of :mod:`vdad.hybrid`) in
depth-first post-order with each entry's subtree size, the active joints in
ascending order (parents first), and each active joint's kinematic parent (the
top body of the group that holds its parent body) with its constant
pre-placement. Then one evaluation (:func:`evaluate`) is

1. the kinematics of the active joints (:func:`vdad.kinematics.kinematics_pass`
   on that table: rigid joints cost nothing);
2. the joint forces of the active joints, the front groups' leaves (T19)-(T20)
   (:func:`group_leaf`), the bottom-up pass (T6)-(T12) over the active nodes
   with, on a step's first evaluation, the metric coefficients (T16)-(T18)
   (:func:`metric_node`);
3. the top-down pass (T10), (T13), which stops at nodes whose predicted
   acceleration score is below ``threshold / kappa`` (threshold mode) and skips
   their subtrees: their joints coast (``qdd = 0``); in budget mode it solves
   every active node and a max-heap then keeps the ``budget`` of highest score;
   on models with thin or light bodies, whose groups' leaves are raised, the
   accelerations are refined on the hybrid (:func:`refine_region`, (R6) of
   ``docs/accuracy.md``);
4. on the first evaluation, the one-level look-ahead at the front
   (:func:`lookahead`).

:func:`update_region` rigidifies and releases nodes after a step, freezing
group data per node (:func:`vdad.hybrid.freeze_node`) and applying the
momentum-conserving locking impulse with the same passes. :func:`cap_energy`
keeps the energy of the hybrid (:func:`hybrid_energy`, O(active + front)) at or
below a cap. :func:`region_steps` runs whole steps (forces, evaluations,
integration, region changes, the cap, checks) in compiled code.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numba import prange

from ._linalg import (
    EPS,
    cholesky,
    cholesky_solve,
    copy_pose,
    copy_state,
    identity_pose,
    inlined,
    kernel,
    mm3,
    mm6,
    mmt6_add,
    motion_to_child,
    mv6,
    parallel_kernel,
    pass_kernel,
    port_transform,
    relative_pose,
    same,
    symmetric_part,
)
from .dca import (
    ONE_STEP,
    assemble_node,
    copy_block,
    in_parallel,
    leaf_blocks,
    node_vectors,
    pair_offset,
    rhs_passes,
    solve_node,
    spring_force,
)
from .forces import body_forces
from .heaps import heap_pop, heap_push, sort_ascending
from .hybrid import carry_forces, freeze_node
from .integrators import normalize_stage, stage_nq, stage_rate, stage_step
from .kinematics import joint_motion, kinematics_pass
from .newton_euler import (
    body_motion,
    force_to_parent_add,
    joint_force,
    known_wrench,
    spatial_momentum,
    subtract_at_origin,
)
from .visibility import region_bvh_pass, region_raster_pass

#: indices of :attr:`RegionData.counts`
N_VISIT, N_JOINTS, ASSEMBLED, FRONT, SOLVED, ACCELERATED, LOOKAHEAD, RIGIDIFIED, RELEASED = \
    range(9)


@dataclass
class RegionData:
    """Work state of adaptive dynamics on a tree (shapes in brackets; ``N =
    n_nodes + 1``, the last entry the sentinel above the roots).

    active, pinned, desc [N] (bool), since [N]: step of each node's last change.
    visit [n_nodes], size [n_nodes]: active nodes and front in depth-first
    post-order, and the entries of each one's subtree; joints [nb]: the active
    joints, ascending; par [nb], R0 [nb, 3, 3], p0 [nb, 3]: each active joint's
    kinematic parent (-1: the world) and joint frame in that parent's frame.
    counts [9]: :data:`N_VISIT` ... :data:`RELEASED`.
    Psi [n_pairs, 6, 6], p [n_slots, 6], eta [N]: metric coefficients
    (T16)-(T18); A [N]: the metric of the nodes reached; V [N]: the velocity
    metric (T15); la [N]: the look-ahead metric of front nodes; N_M [N]: coverage;
    wA, wV [nv]: the diagonal weights of (T14)-(T15); h [N, 6]: momenta of the
    front groups (the locking impulse); heap [2, N], popped [N]: budget mode.
    H, M [max ports, 6, 6], mtmp [10, 6, 6]: scratch. front [nb]: the front group
    whose top is each body (set for the child bodies of active joints); dofs [nv]:
    scratch (:func:`refine_region`).
    """

    active: np.ndarray
    pinned: np.ndarray
    desc: np.ndarray
    since: np.ndarray
    visit: np.ndarray
    size: np.ndarray
    joints: np.ndarray
    par: np.ndarray
    R0: np.ndarray
    p0: np.ndarray
    counts: np.ndarray
    Psi: np.ndarray
    p: np.ndarray
    eta: np.ndarray
    A: np.ndarray
    V: np.ndarray
    la: np.ndarray
    N_M: np.ndarray
    wA: np.ndarray
    wV: np.ndarray
    h: np.ndarray
    heap: np.ndarray
    popped: np.ndarray
    H: np.ndarray
    M: np.ndarray
    mtmp: np.ndarray
    front: np.ndarray
    dofs: np.ndarray

    @classmethod
    def empty(cls, tree, wA, wV):
        model = tree.model
        nb, n = model.nb, tree.n_nodes
        N, P = n + 1, tree.max_ports
        z = np.zeros
        return cls(z(N, bool), z(N, bool), z(N, bool), np.full(N, -(10**9), np.int64),
                   z(n, np.int64), z(n, np.int64), z(nb, np.int64), np.full(nb, -1, np.int64),
                   model.placement_R.copy(), model.placement_p.copy(), z(9, np.int64),
                   z((tree.n_pairs, 6, 6)), z((tree.n_slots, 6)), z(N), np.full(N, np.nan),
                   z(N), np.full(N, np.nan), np.ones(N), np.array(wA, float),
                   np.array(wV, float), z((N, 6)), z((2, N)), z(N, bool), z((P, 6, 6)),
                   z((P, 6, 6)), z((10, 6, 6)), np.full(nb, -1, np.int64), z(model.nv, np.int64))

    @property
    def arrays(self) -> tuple:
        return (self.active, self.pinned, self.desc, self.since, self.visit, self.size,
                self.joints, self.par, self.R0, self.p0, self.counts, self.Psi, self.p,
                self.eta, self.A, self.V, self.la, self.N_M, self.wA, self.wV, self.h,
                self.heap, self.popped, self.H, self.M, self.mtmp, self.front, self.dofs)


# --- the region's lists ------------------------------------------------------------------

@pass_kernel
def rebuild(nb, tree, model_js, groups, top, roots, region, stack):
    """From the flags: the visit list (active nodes and front, depth-first
    post-order) with subtree sizes, the active joints ascending, and the kinematic
    table of every active joint, set from the front group that holds its parent
    body: parent the group's ``top`` body (-1: a grounded group, the world) and
    ``R0, p0`` the port's pose in the group followed by the joint's placement
    (joints to the world keep their placement). ``stack`` [3, n_nodes + 2]:
    scratch."""
    (left, right, joint, port_A, port_B, n_ports, pair_base, slot_base, slot_joint,
     slot_side, slot_child, slot_index, slot_sign, post, segments) = tree
    placement_R, placement_p = model_js[2], model_js[3]
    grounded, port_R, port_p = groups[4], groups[7], groups[8]
    active, visit, size, joints, par, R0, p0, counts = (region[0], region[4], region[5],
                                                        region[6], region[7], region[8],
                                                        region[9], region[10])
    node_of, start_of, state = stack[0], stack[1], stack[2]
    n_out, n_joints, n_front = 0, 0, 0
    for k in range(roots.shape[0]):
        t = 0
        node_of[0], state[0] = roots[k], 0
        while t >= 0:
            n = node_of[t]
            if state[t] == 0:
                start_of[t] = n_out
                if n >= nb and active[n]:             # expand: left, then right, then n
                    state[t] = 1
                    i = n - nb
                    joints[n_joints] = joint[i]
                    n_joints += 1
                    t += 1
                    node_of[t], state[t] = right[i], 0
                    if left[i] >= 0:
                        t += 1
                        node_of[t], state[t] = left[i], 0
                    continue
            visit[n_out] = n
            size[n_out] = n_out - start_of[t] + 1
            n_out += 1
            t -= 1
            if n >= nb and active[n]:
                continue
            n_front += 1
            if not grounded[n]:
                region[26][top[n]] = n
            s0 = slot_base[n]
            for a in range(n_ports[n]):                 # the group's outbound ports
                if slot_side[s0 + a] < 0:
                    jk, s = slot_joint[s0 + a], s0 + a
                    par[jk] = -1 if grounded[n] else top[n]
                    for r in range(3):
                        acc = port_p[s, r]
                        for c in range(3):
                            acc += port_R[s, r, c] * placement_p[jk, c]
                            R0[jk, r, c] = (port_R[s, r, 0] * placement_R[jk, 0, c]
                                            + port_R[s, r, 1] * placement_R[jk, 1, c]
                                            + port_R[s, r, 2] * placement_R[jk, 2, c])
                        p0[jk, r] = acc
    sort_ascending(joints, n_joints)
    if n_joints < joints.shape[0]:
        joints[n_joints] = -1                 # the end of the list for kinematics_pass
    counts[N_VISIT], counts[N_JOINTS], counts[FRONT] = n_out, n_joints, n_front
    counts[ASSEMBLED] = n_out - n_front


# --- kernels: one node each --------------------------------------------------------------

@inlined
def group_leaf(F, tree, groups, gravity, kin, RF, pF, Rw, vF, impulse, hF, Phi, b, X, Q, tmp):
    """Blocks of rigid group ``F`` (a body or a frozen node), theory (T19)-(T20):
    (T2)-(T3) with the composite mass, centre of mass and inverse inertia of its
    bodies' leaves (:mod:`vdad.hybrid`; its own but for thin and light bodies), its
    inbound port at its frame and the port of each outbound joint ``k`` at ``k``'s
    child frame, whose pose ``(R_rel[k], p_rel[k])`` the kinematics give in a
    frame at ``(RF, pF)`` in ``F``'s (the identity but for the look-ahead); the
    known wrench :func:`group_wrench`, moved to the leaves' centre of mass. ``X``,
    ``Q`` (>= ports, 6, 6), ``tmp`` (>= 5, 6, 6): scratch."""
    (left, right, joint, port_A, port_B, n_ports, pair_base, slot_base, slot_joint,
     slot_side, slot_child, slot_index, slot_sign, post, segments) = tree
    com, Iinv, leaf_mass, leaf_com = groups[1], groups[3], groups[12], groups[13]
    R_rel, p_rel = kin[0], kin[1]
    P, s0 = n_ports[F], slot_base[F]
    c = leaf_com[F]
    eye, zero, Rh, ph = tmp[2, :3, :3], tmp[2, 3, :3], tmp[3, :3, :3], tmp[3, 3, :3]
    identity_pose(eye, zero)
    for a in range(P):
        k = slot_joint[s0 + a]
        if slot_side[s0 + a] > 0:
            port_transform(eye, zero, c, X[a])
            continue
        relative_pose(RF, pF, R_rel[k], p_rel[k], Rh, ph)
        port_transform(Rh, ph, c, X[a])
    f = tmp[1, 0]
    group_wrench(F, groups, gravity, Rw, vF, impulse, hF, f, tmp[4])
    d = tmp[4, 5, :3]                             # about the leaves' centre of mass
    for r in range(3):
        d[r] = com[F, r] - c[r]
    f[0] += d[1] * f[5] - d[2] * f[4]
    f[1] += d[2] * f[3] - d[0] * f[5]
    f[2] += d[0] * f[4] - d[1] * f[3]
    leaf_blocks(P, pair_base[F], X, Q, leaf_mass[F], Iinv[F], f, Phi, b, tmp[1, 1])


@inlined
def group_wrench(F, groups, gravity, Rw, vF, impulse, hF, f, t):
    """The known wrench ``f`` (6,) on rigid group ``F`` at its centre of mass, its
    frame's axes: gravity and bias for orientation ``Rw`` and velocity ``vF``
    (:func:`~vdad.newton_euler.known_wrench`), plus the external sums (moment ``R^T
    N + vee(K R)`` about the origin, force ``R^T F``); with ``impulse``, the
    momentum ``hF`` (6,) instead (the locking impulse). ``t`` (>= 5, 6): scratch."""
    mass, com, inertia, fN, fF, fK = groups[0], groups[1], groups[2], groups[9], groups[10], \
        groups[11]
    if impulse:
        for r in range(6):
            f[r] = hF[r]
        return
    c = com[F]
    known_wrench(mass[F], c, inertia[F], vF, Rw, gravity, f)
    KR, Fl = t[:3, :3], t[3, :3]
    for r in range(3):
        Fl[r] = Rw[0, r] * fF[F, 0] + Rw[1, r] * fF[F, 1] + Rw[2, r] * fF[F, 2]
        for s in range(3):
            KR[r, s] = fK[F, r, 0] * Rw[0, s] + fK[F, r, 1] * Rw[1, s] + fK[F, r, 2] * Rw[2, s]
    for r in range(3):
        f[r] += Rw[0, r] * fN[F, 0] + Rw[1, r] * fN[F, 1] + Rw[2, r] * fN[F, 2]
        f[3 + r] += Fl[r]
    f[0] += KR[1, 2] - KR[2, 1] - (c[1] * Fl[2] - c[2] * Fl[1])
    f[1] += KR[2, 0] - KR[0, 2] - (c[2] * Fl[0] - c[0] * Fl[2])
    f[2] += KR[0, 1] - KR[1, 0] - (c[0] * Fl[1] - c[1] * Fl[0])


@inlined
def zero_blocks(F, tree, Phi, b):
    """``Phi = 0``, ``b = 0`` on the ports of ``F``: a grounded group is immobile."""
    n_ports, pair_base = tree[5], tree[6]
    P = n_ports[F]
    for k in range(pair_base[F], pair_base[F] + P * (P + 1) // 2):
        for r in range(6):
            for s in range(6):
                Phi[k, r, s] = 0.0
    for k in range(pair_base[F], pair_base[F] + P):
        for r in range(6):
            b[k, r] = 0.0


@inlined
def metric_node(i, nb, tree, js, kin, active, wA, Psi, p, eta, Y, beta, gamma, Wm, G, GY, H, M,
                mt):
    """The metric coefficients (T16)-(T18) of internal node ``C = nb + i``, after
    :func:`~vdad.dca.assemble_node` (which leaves ``W_m``, ``G_a`` in ``G``'s slots
    of ``C``, ``GY[a]``), in
    the block form of ``docs/adaptive.md``: ``Psi^C_ac = Psi^X_ac [same child] +
    s_a s_c ((G_a Z - H_a Y) G_c^T - G_a Y H_c^T)``, ``p^C_a = p^X_a + s_a (2 H_a
    beta - G_a r)``, ``eta^C = g^T D g + beta^T Psi_m beta + p_m·beta + eta^A +
    eta^B``, with ``H_a = Psi^X_{a j_X}``, ``Z = Y Psi_m Y + N^T D N``, ``r = Y
    (2 Psi_m beta + p_m) - 2 N^T D g``, ``N = 1 - W_m Y``, ``g = W_m beta + gamma``,
    ``D = W A_J W^T``. Children outside the region (the front) have ``Psi = 0``,
    ``p = 0``, ``eta = 0``. ``H``, ``M`` (max ports, 6, 6), ``mt`` (>= 7, 6, 6):
    scratch."""
    (left, right, joint, port_A, port_B, n_ports, pair_base, slot_base, slot_joint,
     slot_side, slot_child, slot_index, slot_sign, post, segments) = tree
    v_start, nv_joint = js[6], js[7]
    C, A, B, j, jA, jB = nb + i, left[i], right[i], joint[i], port_A[i], port_B[i]
    W, d, v0 = kin[4][js[15][j]], nv_joint[j], v_start[j]
    Yj, bj, gj = Y[i], beta[i], gamma[i]
    Pm, D, Nm, Z, T1 = mt[0], mt[1], mt[2], mt[3], mt[4]
    pm, g, rv, tv, t2 = mt[6, 0], mt[6, 1], mt[6, 2], mt[6, 3], mt[6, 4]
    A_in, B_in = A >= nb and active[A], B >= nb and active[B]
    e0 = 0.0
    for r in range(6):
        pm[r] = 0.0
        for s in range(6):
            Pm[r, s] = 0.0
    if A_in:
        kA, sA = pair_base[A] + pair_offset(n_ports[A], jA, jA), slot_base[A] + jA
        e0 += eta[A]
        for r in range(6):
            pm[r] -= p[sA, r]
            for s in range(6):
                Pm[r, s] += Psi[kA, r, s]
    if B_in:
        kB, sB = pair_base[B] + pair_offset(n_ports[B], jB, jB), slot_base[B] + jB
        e0 += eta[B]
        for r in range(6):
            pm[r] += p[sB, r]
            for s in range(6):
                Pm[r, s] += Psi[kB, r, s]
    for r in range(6):                                   # D = W A_J W^T
        for s in range(6):
            acc = 0.0
            for k in range(d):
                acc += W[r, k] * wA[v0 + k] * W[s, k]
            D[r, s] = acc
    mm6(Wm, Yj, T1)                                      # N = 1 - W_m Y
    for r in range(6):
        for s in range(6):
            Nm[r, s] = (1.0 if r == s else 0.0) - T1[r, s]
    mv6(Wm, bj, g)                                       # g = W_m beta + gamma
    for r in range(6):
        g[r] += gj[r]
    mm6(Yj, Pm, T1)                                      # Z = Y Psi_m Y + N^T D N
    mm6(T1, Yj, Z)
    mm6(D, Nm, T1)
    for r in range(6):
        for s in range(6):
            acc = 0.0
            for k in range(6):
                acc += Nm[k, r] * T1[k, s]
            Z[r, s] += acc
    symmetric_part(Z, Z)
    mv6(Pm, bj, tv)                                      # r
    e = e0
    for r in range(6):
        e += bj[r] * tv[r] + pm[r] * bj[r]
        tv[r] = 2.0 * tv[r] + pm[r]
    mv6(Yj, tv, rv)
    mv6(D, g, tv)
    for r in range(6):
        e += g[r] * tv[r]
        acc = 0.0
        for k in range(6):
            acc += Nm[k, r] * tv[k]
        rv[r] -= 2.0 * acc
    eta[C] = e
    P, s0 = n_ports[C], slot_base[C]
    for a in range(P):
        X, ia, sa = slot_child[s0 + a], slot_index[s0 + a], slot_sign[s0 + a]
        X_in = X >= nb and active[X]
        if X_in:
            copy_block(Psi, pair_base[X], n_ports[X], ia, jA if X == A else jB, H[a])
        else:
            for r in range(6):
                for s in range(6):
                    H[a, r, s] = 0.0
        mv6(H[a], bj, tv)
        mv6(G[s0 + a], rv, t2)
        pa = p[s0 + a]
        for r in range(6):
            pa[r] = (p[slot_base[X] + ia, r] if X_in else 0.0) + sa * (2.0 * tv[r] - t2[r])
        mm6(G[s0 + a], Z, M[a])                          # M_a = G_a Z - H_a Y
        mm6(H[a], Yj, T1)
        for r in range(6):
            for s in range(6):
                M[a, r, s] -= T1[r, s]
    for a in range(P):
        X, ia, sa = slot_child[s0 + a], slot_index[s0 + a], slot_sign[s0 + a]
        for cc in range(a, P):
            out = Psi[pair_base[C] + pair_offset(P, a, cc)]
            if slot_child[s0 + cc] == X and X >= nb and active[X]:
                copy_block(Psi, pair_base[X], n_ports[X], ia, slot_index[s0 + cc], out)
            else:
                for r in range(6):
                    for s in range(6):
                        out[r, s] = 0.0
            sign = sa * slot_sign[s0 + cc]
            mmt6_add(M[a], G[s0 + cc], sign, out)
            mmt6_add(GY[a], H[cc], -sign, out)
            if cc == a:
                symmetric_part(out, out)


@inlined
def metric_value(n, tree, f_J, Psi, p, eta):
    """``A(C) = x^T Psi x + p·x + eta`` (T16) of node ``n`` for the wrenches ``x_a =
    side_a f_J[joint_a]`` on its ports."""
    n_ports, pair_base, slot_base, slot_joint, slot_side = tree[5], tree[6], tree[7], tree[8], \
        tree[9]
    P, s0 = n_ports[n], slot_base[n]
    val = eta[n]
    for a in range(P):
        xa, sa = f_J[slot_joint[s0 + a]], slot_side[s0 + a]
        for r in range(6):
            val += sa * p[s0 + a, r] * xa[r]
        for cc in range(a, P):
            xc, sc = f_J[slot_joint[s0 + cc]], slot_side[s0 + cc]
            B = Psi[pair_base[n] + pair_offset(P, a, cc)]
            acc = 0.0
            for r in range(6):
                for s in range(6):
                    acc += xa[r] * B[r, s] * xc[s]
            val += (1.0 if cc == a else 2.0) * sa * sc * acc
    return val


@inlined
def score(dt2, N, x):
    """``dt^k N_M sqrt(x)``: a metric as a displacement per step times the coverage."""
    return dt2 * N * np.sqrt(max(x, 0.0))


@inlined
def front_leaf(F, tree, groups, gravity, kin, top, impulse, h, Phi, b, X, Q, tmp):
    """The leaf of front group ``F`` in the main passes: zero if grounded, else
    :func:`group_leaf` at its top body's pose and velocity."""
    if groups[4][F]:
        zero_blocks(F, tree, Phi, b)
        return
    eye, zero = tmp[5, :3, :3], tmp[5, 3, :3]
    identity_pose(eye, zero)
    t = top[F]
    group_leaf(F, tree, groups, gravity, kin, eye, zero, kin[5][t], kin[7][t], impulse, h[F],
               Phi, b, X, Q, tmp)


@inlined
def lookahead_due(lookahead, step):
    """Whether step number ``step`` takes the look-ahead (:func:`lookahead_pass`),
    taken every ``lookahead`` steps (0: never)."""
    return lookahead > 0 and step % lookahead == 0


@inlined
def active_kinematics(js, region, q, qd, velocities, kin):
    """:func:`~vdad.kinematics.kinematics_pass` over the active joints only, each
    on its kinematic parent with its pre-placed joint frame (:func:`rebuild`)."""
    ajs = (region[6], region[7], region[8], region[9], js[4], js[5], js[6], js[7], js[8], js[9],
           js[10], js[11], js[12], js[13], js[14], js[15])
    kinematics_pass(ajs, q, qd, velocities, *kin)


@pass_kernel
def take_kinematics(js, region, fresh, fkin, kin):
    """:func:`active_kinematics` with velocities, taken from ``fkin``, the kinematics
    of the forces at the same ``(q, qd)`` (:func:`~vdad.forces.body_forces`), if
    those placed every active joint (``fresh``, :func:`forces_now`): the world
    poses, body velocities, ``c_J`` and subspaces copied, and each placement in its
    kinematic parent's frame from the two world poses, without the joints'
    trigonometry (``docs/adaptive.md``, "Whole steps in compiled code"). Returns
    whether it did (else ``kin`` is untouched)."""
    joints, par, counts = region[6], region[7], region[10]
    n_stages, subspace = js[5], js[15]
    for x in range(counts[N_JOINTS]):
        if not fresh[joints[x]]:
            return False
    R_rel, p_rel, S, T, W, R, p, v, c = kin[:9]
    fS, fT, fW, fR, fp, fv, fc = fkin[2:9]
    for x in range(counts[N_JOINTS]):
        j = joints[x]
        if n_stages[j] > 1:                      # the subspaces of a multi-stage joint
            u = subspace[j]
            for r in range(6):
                for m in range(6):
                    S[u, r, m], T[u, r, m], W[u, r, m] = fS[u, r, m], fT[u, r, m], fW[u, r, m]
        copy_pose(fR[j], fp[j], R[j], p[j])
        for r in range(6):
            v[j, r], c[j, r] = fv[j, r], fc[j, r]
        if par[j] < 0:
            copy_pose(fR[j], fp[j], R_rel[j], p_rel[j])
        else:
            relative_pose(fR[par[j]], fp[par[j]], fR[j], fp[j], R_rel[j], p_rel[j])
    return True


@pass_kernel
def evaluate(first, predictive, budget, impulse, placed, reuse, lookahead_on, locking, step, dwell,
             dt, keep, kappa, nb, js, tree, bodies, groups, top, up, roots, q, qd, tau_in, kin,
             work, region):
    """One evaluation of adaptive dynamics at ``(q, qd)`` (the module's steps 1-4):
    ``qdd`` of the active joints in ``work`` (zero where they coast). ``first``: the
    step's first evaluation takes the decisions (metric coefficients, pruning,
    look-ahead, budget heap); later ones (RK4) reuse them. With ``locking``
    (``drop="lock"``) a node is also descended into while its velocity score
    exceeds ``keep`` or it changed state less than ``dwell`` steps before ``step``:
    the nodes left out are those to be locked at once. ``impulse``: the
    locking impulse instead (leaves from the front's momenta ``h``, ``c_J = 0``,
    ``tau = 0``, every active node solved), whose result are the new ``qd`` of the
    active joints. ``placed``: ``kin`` holds the active joints' kinematics at ``(q,
    qd)`` already (:func:`cap_energy` of the step before computed them).
    ``reuse``: the last evaluation was at the same ``q``, and the region has
    changed since only by nodes whose state changed at ``step``
    (:func:`region_passes` keeps the blocks of the others: the locking impulse of
    ``drop="lock"`` and the evaluation after it). ``lookahead_on``: the step's
    first evaluation takes the look-ahead (:func:`lookahead_pass`); without it the
    front's scores ``la`` are NaN. On a model with raised leaves (``bodies[12]``,
    :func:`~vdad.dca.body_arrays`) the groups' leaves are raised and the
    accelerations refined on the hybrid
    (:func:`refine_region`, (R6) of ``docs/accuracy.md``) before the metric is
    summed from them (the caller takes ``predictive`` off there). Returns whether
    ``qdd`` is finite."""
    qdd, tau, X, GY, tmp = work[7], work[8], work[9], work[10], work[11]
    active, desc, visit, joints, counts, la, popped, H, M, mt = (
        region[0], region[2], region[4], region[6], region[10], region[16], region[22],
        region[23], region[24], region[25])
    stage0, n_stages, v_start, nv_joint = js[4], js[5], js[6], js[7]
    stage_kind, stage_q, stage_v = bodies[5], bodies[6], bodies[7]
    stage_stiffness, q_spring, damping = bodies[8], bodies[9], bodies[10]
    joint = tree[2]
    if not placed:
        active_kinematics(js, region, q, qd, not impulse, kin)
    c_J = kin[8]
    for x in range(counts[N_JOINTS]):                   # joint forces of the active joints
        j = joints[x]
        for k in range(v_start[j], v_start[j] + nv_joint[j]):
            qdd[k] = 0.0
            tau[k] = 0.0 if impulse else tau_in[k] - damping[k] * qd[k]
        if impulse:
            for r in range(6):
                c_J[j, r] = 0.0
        else:
            for s in range(stage0[j], stage0[j] + n_stages[j]):
                spring_force(s, stage_kind, stage_q, stage_v, stage_stiffness, q_spring, q, tau)
    if first and locking and not impulse:              # (T15) of the state, for descend
        velocity_metric(nb, js, tree, qd, region)
    n_visit = counts[N_VISIT]
    if in_parallel(nb, tree[14]):
        solved = region_forest(first, predictive, budget, impulse, reuse, locking, step, dwell,
                               dt, keep, nb, js, tree, bodies, groups, top, kin, tau, work,
                               region)
    else:
        solved = region_passes(0, n_visit, first, predictive, budget, impulse, reuse, locking,
                               step, dwell, dt, keep, nb, js, tree, bodies, groups, top, kin, tau,
                               work, region, X, GY, tmp, H, M, mt)
    if bodies[12] != 0:                                 # (R6): leaves raised
        refine_region(nb, js, tree, bodies, groups, kin, work, region, impulse)
        for e in range(n_visit):                        # the pruned joints coast again
            n = visit[e]
            if n >= nb and active[n] and not (impulse or desc[n]):
                j = joint[n - nb]
                for k in range(v_start[j], v_start[j] + nv_joint[j]):
                    qdd[k] = 0.0
    if first and not impulse:
        dt2 = dt * dt
        counts[SOLVED] = solved
        counts[LOOKAHEAD] = 0
        if not predictive:
            direct_metric(budget, locking, step, dwell, dt, keep, nb, js, tree, up, qdd,
                          region)
        if lookahead_on:
            lookahead_pass(budget, step, dwell, nb, js, tree, bodies, groups, top, up, q, tau_in,
                           kin, work, region)
        else:                                           # no front node competes (budget)
            for e in range(n_visit):
                n = visit[e]
                if n >= nb and not active[n]:
                    la[n] = np.nan
        if budget > 0:
            run_heap(budget, kappa, dt2, nb, tree, roots, region)
            for e in range(n_visit):
                n = visit[e]
                if n >= nb and active[n]:
                    desc[n] = popped[n]
                    if not popped[n]:
                        j = joint[n - nb]
                        for k in range(v_start[j], v_start[j] + nv_joint[j]):
                            qdd[k] = 0.0
        accelerated = 0
        for e in range(n_visit):
            n = visit[e]
            if n >= nb and active[n] and desc[n]:
                accelerated += 1
        counts[ACCELERATED] = accelerated
    ok = True
    for x in range(counts[N_JOINTS]):
        j = joints[x]
        for k in range(v_start[j], v_start[j] + nv_joint[j]):
            ok = ok and np.isfinite(qdd[k])
            if impulse:
                qd[k] = qdd[k]
    return ok


@inlined
def region_passes(lo, hi, first, predictive, budget, impulse, reuse, locking, step, dwell, dt,
                  keep, nb, js, tree, bodies, groups, top, kin, tau, work, region, X, GY, tmp, H,
                  M, mt):
    """:func:`evaluate`'s steps 2-3 over the entries ``visit[lo:hi]``, whole
    subtrees of the active region: the front leaves and the bottom-up pass (T6)-(T12)
    with, on a step's first evaluation, the metric coefficients (T16)-(T18); then
    the top-down pass (T10), (T13), pruned. With ``reuse`` (not on a first
    evaluation), an active node none of whose subtree's nodes changed state at
    ``step`` keeps the blocks of its last assembly, at the same configuration, and
    takes the vector parts alone (:func:`~vdad.dca.node_vectors`). ``X``, ``GY``,
    ``tmp``, ``H``, ``M``, ``mt``: scratch. Returns the nodes solved."""
    Phi, b, Y, WtWm, beta, gamma, f_J, qdd, _, _, _, _, PF = work[:13]
    G = work[16]
    (active, pinned, desc, since, visit, size, joints, par, R0, p0, counts, Psi, p, eta, A, V,
     la, N_M, wA, wV, h) = region[:21]
    armature, gravity = bodies[11], bodies[4]
    reuse = reuse and not first
    changed = lo - 1                                    # the last entry that changed at step
    for e in range(lo, hi):                             # bottom-up: front leaves, (T6)-(T12)
        n = visit[e]
        if since[n] == step:
            changed = e
        if n >= nb and active[n]:
            if reuse and changed < e - size[e] + 1:     # its subtree unchanged at this q
                node_vectors(n - nb, nb, tree, js, kin, armature, tau, b, Y, WtWm, PF, beta,
                             gamma, G, True, tmp[7, 2])
                continue
            assemble_node(n - nb, nb, tree, js, kin, tau, armature, Phi, b, Y, WtWm, PF, beta,
                          gamma, G, GY, tmp)
            if first and predictive and not impulse:
                metric_node(n - nb, nb, tree, js, kin, active, wA, Psi, p, eta, Y, beta,
                            gamma, tmp[5], G, GY, H, M, mt)
        else:
            front_leaf(n, tree, groups, gravity, kin, top, impulse, h, Phi, b, X, GY, tmp)
    solved = 0
    e = hi - 1
    while e >= lo:                                      # top-down (T10), (T13), pruned
        n = visit[e]
        if not (n >= nb and active[n]):
            e -= 1
            continue
        go = impulse or desc[n]
        if first and not impulse:
            go = True
            if predictive:
                A[n] = metric_value(n, tree, f_J, Psi, p, eta)
                go = budget > 0 or descend(n, locking, step, dwell, dt, keep, region)
            desc[n] = go
        if go:
            solve_node(n - nb, nb, tree, js, kin, armature, tau, G, Y, WtWm, PF, beta, gamma,
                       f_J, qdd, tmp)
            solved += 1
            e -= 1
            continue
        lo_sub = e - size[e] + 1                        # the subtree coasts: qdd = 0
        for x in range(lo_sub, e):
            m = visit[x]
            if m >= nb and active[m] and first:
                desc[m] = False
                A[m] = np.nan
        e = lo_sub - 1
    return solved


#: :func:`region_forest` splits a forest's subtrees into this many chunks, each with
#: its scratch, that numba's threads share (a fixed number: a kernel that asks
#: numba for its thread count cannot be cached)
FOREST_CHUNKS = 16


@parallel_kernel
def region_forest(first, predictive, budget, impulse, reuse, locking, step, dwell, dt, keep, nb,
                  js, tree, bodies, groups, top, kin, tau, work, region):
    """:func:`region_passes` of a forest's root subtrees in parallel (numba threads,
    as :func:`vdad.dca.forest_passes`): the visit list holds each root's subtree in
    turn, and each of :data:`FOREST_CHUNKS` chunks takes every ``T``-th of them with
    its own scratch. Returns the nodes solved."""
    visit_size, n_visit = region[5], region[10][N_VISIT]
    n_roots, e = 0, n_visit - 1
    while e >= 0:
        n_roots += 1
        e -= visit_size[e]
    hi = np.empty(n_roots + 1, np.int64)                # subtree k: visit[hi[k+1]:hi[k]]
    hi[0], e = n_visit, n_visit - 1
    for k in range(n_roots):
        e -= visit_size[e]
        hi[k + 1] = e + 1
    T = min(FOREST_CHUNKS, n_roots)
    solved = np.zeros(T, np.int64)                      # per chunk: no reduction variable
    for t in prange(T):
        X, GY, tmp = np.empty_like(work[9]), np.empty_like(work[10]), np.empty_like(work[11])
        H, M, mt = np.empty_like(region[23]), np.empty_like(region[24]), np.empty_like(region[25])
        for k in range(t, n_roots, T):
            solved[t] += subtree_passes(hi[k + 1], hi[k], first, predictive, budget, impulse,
                                        reuse, locking, step, dwell, dt, keep, nb, js, tree,
                                        bodies, groups, top, kin, tau, work, region, X, GY, tmp,
                                        H, M, mt)
    return solved.sum()


@pass_kernel
def subtree_passes(lo, hi, first, predictive, budget, impulse, reuse, locking, step, dwell, dt,
                   keep, nb, js, tree, bodies, groups, top, kin, tau, work, region, X, GY, tmp, H,
                   M, mt):
    """:func:`region_passes` compiled on its own, as a call from the threads of
    :func:`region_forest` (as :func:`vdad.dca.subtree_passes` is): inlined into the
    parallel loop, numba's parallel passes took 15 minutes more to compile it."""
    return region_passes(lo, hi, first, predictive, budget, impulse, reuse, locking, step, dwell,
                         dt, keep, nb, js, tree, bodies, groups, top, kin, tau, work, region, X,
                         GY, tmp, H, M, mt)


@inlined
def descend(n, locking, step, dwell, dt, keep, region):
    """Threshold mode: whether the top-down pass descends into active node ``n``
    (its parent reached): pinned, or its acceleration score above ``keep``; with
    ``locking``, also while its velocity score is above ``keep`` or it changed
    state less than ``dwell`` steps before ``step`` (it would not be rigidified)."""
    pinned, since, A, V, N_M = region[1], region[3], region[14], region[15], region[17]
    if pinned[n] or score(dt * dt, N_M[n], A[n]) > keep:
        return True
    return locking and (score(dt, N_M[n], V[n]) > keep or step - since[n] < dwell)


@inlined
def direct_metric(budget, locking, step, dwell, dt, keep, nb, js, tree, up, qdd, region):
    """``metric="direct"``: (T14) summed bottom-up from the ``qdd`` of the whole
    active region, then (threshold mode) the descent from the roots: a node is
    descended into when its parent was and :func:`descend` says so; the joints of
    the others get ``qdd = 0``. The same values and decisions as the predicted
    metric (T16)-(T18)."""
    joint, v_start, nv_joint = tree[2], js[6], js[7]
    active, desc, visit, counts, A, wA = (region[0], region[2], region[4], region[10],
                                          region[14], region[18])
    n_visit = counts[N_VISIT]
    sum_up(nb, js, tree, qdd, wA, A, region)
    if budget > 0:
        return
    for e in range(n_visit - 1, -1, -1):
        n = visit[e]
        if not (n >= nb and active[n]):
            continue
        go = desc[up[n]] and descend(n, locking, step, dwell, dt, keep, region)
        desc[n] = go
        if not go:
            j = joint[n - nb]
            for k in range(v_start[j], v_start[j] + nv_joint[j]):
                qdd[k] = 0.0


@pass_kernel
def lookahead_pass(budget, step, dwell, nb, js, tree, bodies, groups, top, up, q, tau_in, kin,
                   work, region):
    """The one-level look-ahead (``docs/adaptive.md``) of every internal front node
    ``F`` whose parent was descended into: ``la[F]``, the metric of its joint ``j``
    released at rest, its children ``A`` and ``B`` held rigid, for the wrenches on
    ``F``'s ports known from the top-down pass (:func:`release_acceleration`).
    In threshold mode (``budget`` 0) a front node that changed state less than
    ``dwell`` steps before ``step`` is not looked ahead: :func:`update_region`
    would not release it. Writes only rows that rigid joints own (and restores
    ``qdd = 0`` on ``j``); ``la`` is NaN on the other front nodes."""
    f_J, qdd, tau, tmp = work[6], work[7], work[8], work[11]
    joint, v_start, nv_joint = tree[2], js[6], js[7]
    R_rel, p_rel, S, T, W, R, pw, v, c_J, R3, v6, kwork = kin
    active, desc, since, visit, counts, la, wA = (region[0], region[2], region[3], region[4],
                                                  region[10], region[16], region[18])
    grounded = groups[4]
    stage0, n_stages = js[4], js[5]
    Rw, vw = tmp[6, :3, :3], tmp[6, 3]
    counts[LOOKAHEAD] = 0
    for e in range(counts[N_VISIT]):
        F = visit[e]
        if F < nb or active[F]:
            continue
        if not desc[up[F]] or (budget == 0 and step - since[F] < dwell):
            la[F] = np.nan
            continue
        counts[LOOKAHEAD] += 1
        j = joint[F - nb]
        joint_motion(j, js, q, R_rel, p_rel, S, T, W, R3, v6, kwork)
        for k in range(v_start[j], v_start[j] + nv_joint[j]):
            tau[k] = tau_in[k]
        for s in range(stage0[j], stage0[j] + n_stages[j]):
            spring_force(s, bodies[5], bodies[6], bodies[7], bodies[8], bodies[9], q, tau)
        for r in range(3):                           # F's frame (the world if grounded)
            for c in range(3):
                Rw[r, c] = (1.0 if r == c else 0.0) if grounded[F] else R[top[F], r, c]
        for r in range(6):
            vw[r] = 0.0 if grounded[F] else v[top[F], r]
        release_acceleration(F, nb, tree, js, groups, bodies[4], kin, f_J, tau, bodies[11], Rw,
                             vw, tmp, qdd)
        val = 0.0
        for k in range(v_start[j], v_start[j] + nv_joint[j]):
            val += wA[k] * qdd[k] * qdd[k]
            qdd[k] = 0.0
        la[F] = val


@inlined
def release_acceleration(F, nb, tree, js, groups, gravity, kin, f_J, tau, armature, Rw, vw,
                         tmp, qdd):
    """``qdd`` of the joint ``j`` of rigid node ``F`` released at rest, its children
    ``A`` and ``B`` rigid groups with their own inertias, under gravity and bias
    for ``F``'s orientation ``Rw`` and velocity ``vw``, the joint forces ``tau``,
    and the wrenches ``f_J`` on ``F``'s ports that the top-down pass found: the
    articulated-body solution of the two bodies (Featherstone's ABA; ``A`` at rest
    where it holds the ground), in ``A``'s frame (``F``'s) and ``B``'s, at
    ``(rel_R, rel_p)`` in it: ``U = I_B S``, ``D = S^T U + I_a``, ``u = tau - S^T
    p_B``, ``I_B^a = I_B - U D^-1 U^T``, ``p_B^a = p_B + U D^-1 u``, ``(I_A + X^T
    I_B^a X) a_A = -(p_A + X^T p_B^a)``, ``qdd = D^-1 (u - U^T X a_A)`` (``p``: the
    bias forces, minus the known wrenches). It inverts no inertia but ``D`` and
    ``I_A + X^T I_B^a X``, so thin and light bodies cost it no accuracy ((R6) of
    ``docs/accuracy.md``). ``tmp`` (8, 6, 6): scratch but ``tmp[6, :4]``."""
    (left, right, joint, port_A, port_B, n_ports, pair_base, slot_base, slot_joint,
     slot_side, slot_child, slot_index, slot_sign, post, segments) = tree
    v_start, nv_joint, subspace = js[6], js[7], js[15]
    mass, com, inertia, grounded, rel_R, rel_p = (groups[0], groups[1], groups[2], groups[4],
                                                  groups[5], groups[6])
    R_rel, p_rel = kin[0], kin[1]
    i = F - nb
    A, B, j = left[i], right[i], joint[i]
    v0, d, S = v_start[j], nv_joint[j], kin[2][subspace[j]]
    RF, pF = rel_R[F], rel_p[F]                      # B's frame in F's
    IB, U, Z, D, Ia, t = tmp[0], tmp[1], tmp[2], tmp[3], tmp[4], tmp[5]
    pA, pB, aA = tmp[6, 4], tmp[6, 5], tmp[7, 0]
    u, m, col, fp = tmp[7, 1], tmp[7, 2], tmp[7, 3], tmp[7, 4]
    RB, Rh, ph = t[:3, 3:], Ia[:3, :3], Ia[3, :3]
    fixed = A < 0 or grounded[A]
    motion_to_child(RF, pF, vw, col)                 # B's velocity and orientation
    mm3(Rw, RF, RB)
    for r in range(6):
        pA[r] = 0.0
        pB[r] = 0.0
    group_wrench(B, groups, gravity, RB, col, False, col, fp, t)
    subtract_at_origin(com[B], fp, pB)
    if not fixed:
        group_wrench(A, groups, gravity, Rw, vw, False, vw, fp, t)
        subtract_at_origin(com[A], fp, pA)
    s0 = slot_base[F]
    for a in range(n_ports[F]):                      # minus the ports' wrenches
        s, k = s0 + a, slot_joint[s0 + a]
        for r in range(6):
            fp[r] = -slot_side[s] * f_J[k, r]
        if slot_side[s] > 0:                         # the inbound port: F's frame, on A
            for r in range(6):
                pA[r] += fp[r]
        elif slot_child[s] == A:
            force_to_parent_add(R_rel[k], p_rel[k], fp, pA)
        else:                                        # the port's pose in B's frame
            relative_pose(RF, pF, R_rel[k], p_rel[k], Rh, ph)
            force_to_parent_add(Rh, ph, fp, pB)
    spatial_inertia(mass[B], com[B], inertia[B], col, IB)
    for r in range(6):                               # U = I_B S
        for c in range(d):
            acc = 0.0
            for k in range(6):
                acc += IB[r, k] * S[k, c]
            U[r, c] = acc
    for a in range(d):                               # D = S^T U + I_a, u = tau - S^T p_B
        for c in range(d):
            acc = 0.0
            for r in range(6):
                acc += S[r, a] * U[r, c]
            D[a, c] = acc
        D[a, a] += armature[v0 + a]
        acc = tau[v0 + a]
        for r in range(6):
            acc -= S[r, a] * pB[r]
        u[a] = acc
    if not cholesky(D, d):
        for a in range(d):
            qdd[v0 + a] = np.nan
        return
    for r in range(6):                               # Z = U D^-1 (rows), u := D^-1 u
        for c in range(d):
            Z[r, c] = U[r, c]
        cholesky_solve(D, Z[r], d)
    cholesky_solve(D, u, d)
    for r in range(6):                               # p_B^a = p_B + U D^-1 u
        for c in range(d):
            pB[r] += U[r, c] * u[c]
    for r in range(6):
        aA[r] = 0.0
    if not fixed:
        for r in range(6):                           # I_B^a = I_B - U D^-1 U^T
            for c in range(6):
                acc = IB[r, c]
                for k in range(d):
                    acc -= U[r, k] * Z[c, k]
                Ia[r, c] = acc
        K = IB
        spatial_inertia(mass[A], com[A], inertia[A], col, K)
        for c in range(6):                           # K = I_A + X^T I_B^a X
            for r in range(6):
                fp[r] = 1.0 if r == c else 0.0
            motion_to_child(RF, pF, fp, m)
            for r in range(6):
                acc = 0.0
                for k in range(6):
                    acc += Ia[r, k] * m[k]
                col[r] = acc
            for r in range(6):
                fp[r] = 0.0
            force_to_parent_add(RF, pF, col, fp)
            for r in range(6):
                K[r, c] += fp[r]
        for r in range(6):
            fp[r] = 0.0
        force_to_parent_add(RF, pF, pB, fp)
        for r in range(6):
            aA[r] = -(pA[r] + fp[r])
        if not cholesky(K, 6):
            for a in range(d):
                qdd[v0 + a] = np.nan
            return
        cholesky_solve(K, aA, 6)
    motion_to_child(RF, pF, aA, m)                   # qdd = D^-1 (u - U^T X a_A)
    for a in range(d):
        acc = u[a]
        for r in range(6):
            acc -= Z[r, a] * m[r]
        qdd[v0 + a] = acc


@inlined
def spatial_inertia(m, c, I, e, out):
    """The spatial inertia (6, 6) at a body's origin of mass ``m``, centre of mass
    ``c`` and inertia ``I`` about it, column by column from
    :func:`~vdad.newton_euler.spatial_momentum`. ``e`` (6,): scratch."""
    for col in range(6):
        for r in range(6):
            e[r] = 1.0 if r == col else 0.0
        spatial_momentum(m, c, I, e, out[:, col])


# --- refinement on the hybrid ((R6) of docs/accuracy.md) ----------------------------------

@inlined
def hybrid_inverse_dynamics(js, groups, region, kin, gravity, armature, x, full, impulse, a,
                            f, w, out):
    """(R1) of ``docs/accuracy.md`` on the hybrid: Newton-Euler over the active
    joints, parents first, each moving the rigid group whose top is its child body
    (``front``) with the group's own mass, centre of mass and inertia; ``out`` on
    the active joints' dofs: ``M_AA x`` for their accelerations ``x`` (the rigid
    joints' held at zero), plus with ``full`` the velocity products ``c_J`` and
    minus the groups' known wrenches (:func:`group_wrench`; with ``impulse``, their
    momenta ``h``). ``a``, ``f`` (nb, 6): the rows of the groups' top bodies;
    ``w`` (>= 6, 6): scratch."""
    joints, par, counts, h, front = region[6], region[7], region[10], region[20], region[26]
    mass, com, inertia = groups[0], groups[1], groups[2]
    R, v = kin[5], kin[7]
    n = counts[N_JOINTS]
    for e in range(n):
        j = joints[e]
        F = front[j]
        body_motion(j, par[j], js, kin, x, full, a)
        spatial_momentum(mass[F], com[F], inertia[F], a[j], f[j])
        if full:
            group_wrench(F, groups, gravity, R[j], v[j], impulse, h[F], w[0], w[1:])
            subtract_at_origin(com[F], w[0], f[j])
    for e in range(n - 1, -1, -1):
        j = joints[e]
        joint_force(j, par[j], js, kin, armature, x, f, out)


@pass_kernel
def refine_region(nb, js, tree, bodies, groups, kin, work, region, impulse):
    """(R6) of ``docs/accuracy.md``: the accelerations ``qdd`` (in ``work``) of the
    active joints, from an evaluation of the hybrid on its bodies' leaves
    (:mod:`vdad.hybrid`), refined as (R3) does the DCA's: preconditioned conjugate
    gradients on ``ID_A(qdd) = tau`` (:func:`hybrid_inverse_dynamics`, the groups'
    own inertias), the region's DCA on the leaves (:func:`~vdad.dca.rhs_passes`
    over its visit list) as preconditioner; at most ``bodies[12]`` steps, the
    first correction alone with :data:`~vdad.dca.ONE_STEP`."""
    Phi, b, Y, WtWm, beta, gamma, f_J, qdd, tau, X, GY, tmp, PF, a, f, cg, G = work
    armature, gravity, steps = bodies[11], bodies[4], bodies[12]
    active, visit, joints, counts, dofs = region[0], region[4], region[6], region[10], \
        region[27]
    v_start, nv_joint = js[6], js[7]
    x, r, z, p, Ap = cg[0], cg[1], cg[2], cg[3], cg[4]
    m = 0
    for e in range(counts[N_JOINTS]):
        j = joints[e]
        for k in range(v_start[j], v_start[j] + nv_joint[j]):
            dofs[m] = k
            m += 1
    n_visit = counts[N_VISIT]
    for e in range(m):
        x[dofs[e]] = qdd[dofs[e]]
    hybrid_inverse_dynamics(js, groups, region, kin, gravity, armature, x, True, impulse, a, f,
                            tmp[7], r)
    for e in range(m):                                        # r = tau - ID(x)
        r[dofs[e]] = tau[dofs[e]] - r[dofs[e]]
    rhs_passes(nb, js, tree, kin, armature, r, G, b, Y, WtWm, PF, beta, gamma, f, z, tmp, visit,
               n_visit, active)
    if steps == ONE_STEP:
        for e in range(m):
            qdd[dofs[e]] = x[dofs[e]] + z[dofs[e]]
        return
    rz = 0.0
    for e in range(m):
        k = dofs[e]
        p[k] = z[k]
        rz += r[k] * z[k]
    for _ in range(steps):
        change, size = 0.0, 0.0
        for e in range(m):
            change = max(change, abs(z[dofs[e]]))
            size = max(size, abs(x[dofs[e]]))
        if not change > 4.0 * EPS * size:
            break
        hybrid_inverse_dynamics(js, groups, region, kin, gravity, armature, p, False, impulse,
                                a, f, tmp[7], Ap)
        pAp = 0.0
        for e in range(m):
            pAp += p[dofs[e]] * Ap[dofs[e]]
        if not pAp > 0.0:
            break
        alpha = rz / pAp
        for e in range(m):
            k = dofs[e]
            x[k] += alpha * p[k]
            r[k] -= alpha * Ap[k]
        rhs_passes(nb, js, tree, kin, armature, r, G, b, Y, WtWm, PF, beta, gamma, f, z, tmp,
                   visit, n_visit, active)
        rz_next = 0.0
        for e in range(m):
            rz_next += r[dofs[e]] * z[dofs[e]]
        for e in range(m):
            k = dofs[e]
            p[k] = z[k] + (rz_next / rz) * p[k]
        rz = rz_next
    for e in range(m):
        qdd[dofs[e]] = x[dofs[e]]


# --- budget mode ------------------------------------------------------------------------

@inlined
def run_heap(budget, kappa, dt2, nb, tree, roots, region):
    """Budget mode: pop the ``budget`` highest scores from a max-heap, from the
    roots down (active nodes count ``kappa`` times their score, front nodes their
    look-ahead score; pinned nodes first), marking ``popped``."""
    left, right = tree[0], tree[1]
    active, pinned, visit, counts, A, la, N_M, heap, popped = (
        region[0], region[1], region[4], region[10], region[14], region[16], region[17],
        region[21], region[22])
    keys, nodes = heap[0], heap[1]
    for e in range(counts[N_VISIT]):
        popped[visit[e]] = False
    n = 0
    for k in range(roots.shape[0]):
        r = roots[k]
        if r >= nb and (active[r] or not np.isnan(la[r])):
            n = heap_push(keys, nodes, n, heap_key(r, kappa, dt2, active, pinned, A, la, N_M), r)
    count = 0
    while n > 0 and (count < budget or keys[0] == np.inf):
        node = int(nodes[0])
        n = heap_pop(keys, nodes, n)
        popped[node] = True
        count += 1
        if active[node]:
            for c in (left[node - nb], right[node - nb]):
                if c >= nb and (active[c] or not np.isnan(la[c])):
                    n = heap_push(keys, nodes, n,
                                  heap_key(c, kappa, dt2, active, pinned, A, la, N_M), c)


@inlined
def heap_key(n, kappa, dt2, active, pinned, A, la, N_M):
    """A node's key in the budget heap."""
    if active[n] and pinned[n]:
        return np.inf
    if active[n]:
        return kappa * score(dt2, N_M[n], A[n])
    return score(dt2, N_M[n], la[n])


# --- the region update --------------------------------------------------------------------

@pass_kernel
def update_region(step, budget, lookahead_on, dt, threshold, keep, dwell, nb, js, tree, up, qd,
                  region, stack):
    """The region update after a step (``docs/adaptive.md``): the velocity metric
    (T15) bottom-up; rigidify the highest active nodes not descended into whose
    velocity score is at most ``keep`` (any, in budget mode) and that kept their
    state ``dwell`` steps, and release the front nodes whose parent was descended
    into and whose look-ahead score exceeds ``threshold`` (popped, in budget
    mode), by :func:`change_region`. Returns the number of changed nodes."""
    (active, pinned, desc, since, visit, size, joints, par, R0, p0, counts, Psi, p, eta, A, V,
     la, N_M, wA, wV, h, heap, popped, H, M, mt, front, dofs) = region
    n_visit = counts[N_VISIT]
    velocity_metric(nb, js, tree, qd, region)
    cand, rel = stack[0], stack[1]
    nc, nr = 0, 0
    dt2 = dt * dt
    for e in range(n_visit):
        n = visit[e]
        if n < nb:
            continue
        u, old = up[n], step - since[n] >= dwell
        if active[n]:
            if ((desc[u] or pinned[u]) and not desc[n] and old and not pinned[n]
                    and (budget > 0 or score(dt, N_M[n], V[n]) <= keep)):
                cand[nc] = e
                nc += 1
        elif lookahead_on and desc[u] and old:
            if budget > 0:
                hit = popped[n]
            else:
                hit = not np.isnan(la[n]) and score(dt2, N_M[n], la[n]) > threshold
            if hit:
                rel[nr] = n
                nr += 1
    return nc, nr


@inlined
def velocity_metric(nb, js, tree, qd, region):
    """(T15) bottom-up over the active region (:func:`sum_up` of ``qd``)."""
    sum_up(nb, js, tree, qd, region[19], region[15], region)


@inlined
def sum_up(nb, js, tree, x, w, out, region):
    """``out(C) = out(A) + out(B) + x_j^T diag(w_j) x_j`` over the active nodes in
    visit order (front nodes 0): (T14) with ``x = qdd``, (T15) with ``x = qd``."""
    left, right, joint = tree[0], tree[1], tree[2]
    v_start, nv_joint = js[6], js[7]
    active, visit, counts = region[0], region[4], region[10]
    for e in range(counts[N_VISIT]):
        n = visit[e]
        if n >= nb and active[n]:
            i = n - nb
            j = joint[i]
            val = out[right[i]] + (out[left[i]] if left[i] >= 0 else 0.0)
            for k in range(v_start[j], v_start[j] + nv_joint[j]):
                val += w[k] * x[k] * x[k]
            out[n] = val
        else:
            out[n] = 0.0


@pass_kernel
def lock_pruned(nb, up, region, stack):
    """The consistent scheme (``drop="lock"``, ``docs/adaptive.md``): the highest
    active nodes that the step's first evaluation did not descend into, to be
    rigidified at once by :func:`change_region` (so no joint coasts): their visit
    positions in ``stack[0]``. Returns how many."""
    active, pinned, desc, visit, counts = region[0], region[1], region[2], region[4], region[10]
    cand = stack[0]
    nc = 0
    for e in range(counts[N_VISIT]):
        n = visit[e]
        if n >= nb and active[n] and not desc[n] and (desc[up[n]] or pinned[up[n]]):
            cand[nc] = e
            nc += 1
    return nc


@pass_kernel
def change_region(nc, nr, step, momentum, nb, js, tree, groups, top, roots, q, qd, kin, region,
                  stack):
    """Rigidify the active nodes at visit positions ``stack[0][:nc]`` with their
    subtrees (group data frozen node by node, their joints' velocities zeroed) and
    release the front nodes ``stack[1][:nr]``, then rebuild the region; with
    ``momentum``, the new front's momenta ``h`` before the change, in each group's
    axes about its centre of mass, for the locking impulse (a new group's summed
    from the old groups it absorbs, a released node's split over its children),
    which the caller then applies by the impulse passes of :func:`evaluate`."""
    (active, pinned, desc, since, visit, size, joints, par, R0, p0, counts, Psi, p, eta, A, V,
     la, N_M, wA, wV, h, heap, popped, H, M, mt, front, dofs) = region
    mass, com, inertia, grounded = groups[0], groups[1], groups[2], groups[4]
    joint = tree[2]
    v_start, nv_joint = js[6], js[7]
    R, pw, v = kin[5], kin[6], kin[7]
    cand, rel = stack[0], stack[1]
    rel_R, rel_p = groups[5], groups[6]
    left, right = tree[0], tree[1]
    if nc > 0 and momentum:           # momenta before the change: world axes, about the origin
        active_kinematics(js, region, q, qd, True, kin)
        for e in range(counts[N_VISIT]):                # every front group's own
            G = visit[e]
            if (G >= nb and active[G]) or grounded[G]:
                continue
            for r in range(6):
                h[G, r] = 0.0
            group_momentum(G, R[top[G]], pw[top[G]], v[top[G]], mass, com, inertia, mt[7, 0],
                           h[G])
        for x in range(nc):                             # summed into each new group
            e = cand[x]
            hC = mt[7, 1]
            for r in range(6):
                hC[r] = 0.0
            for y in range(e - size[e] + 1, e + 1):
                G = visit[y]
                if not ((G >= nb and active[G]) or grounded[G]):
                    for r in range(6):
                        hC[r] += h[G, r]
            for r in range(6):
                h[visit[e], r] = hC[r]
        for x in range(nr):                             # split over a released node's children
            F = rel[x]
            if grounded[F]:
                continue
            i, t = F - nb, top[F]
            Rx, px, vx = mt[8, :3, :3], mt[8, 3, :3], mt[8, 4]
            for side in range(2):
                X_ = left[i] if side == 0 else right[i]
                if X_ < 0 or grounded[X_]:
                    continue
                for r in range(3):
                    if side == 0:
                        px[r] = pw[t, r]
                    else:
                        px[r] = pw[t, r] + R[t, r, 0] * rel_p[F, 0] + R[t, r, 1] * rel_p[F, 1] \
                            + R[t, r, 2] * rel_p[F, 2]
                    for c in range(3):
                        Rx[r, c] = R[t, r, c] if side == 0 else (
                            R[t, r, 0] * rel_R[F, 0, c] + R[t, r, 1] * rel_R[F, 1, c]
                            + R[t, r, 2] * rel_R[F, 2, c])
                if side == 0:
                    for r in range(6):
                        vx[r] = v[t, r]
                else:
                    motion_to_child(rel_R[F], rel_p[F], v[t], vx)
                for r in range(6):
                    h[X_, r] = 0.0
                group_momentum(X_, Rx, px, vx, mass, com, inertia, mt[7, 0], h[X_])
    rigidified = 0
    for x in range(nc):
        e = cand[x]
        for y in range(e - size[e] + 1, e + 1):
            n = visit[y]
            if n >= nb and active[n]:
                freeze_node(n, nb, tree, js, q, kin[0], kin[1], kin[9], groups)
                j = joint[n - nb]
                for k in range(v_start[j], v_start[j] + nv_joint[j]):
                    qd[k] = 0.0
                active[n], desc[n], since[n] = False, False, step
                rigidified += 1
    for x in range(nr):
        active[rel[x]], since[rel[x]] = True, step
    counts[RIGIDIFIED], counts[RELEASED] = rigidified, nr
    if nc + nr == 0:
        return
    rebuild(nb, tree, js, groups, top, roots, region, stack)
    if nc > 0 and momentum:          # the momenta in each front's axes, about its centre
        active_kinematics(js, region, q, qd, False, kin)
        L = mt[7, 3]
        for e in range(counts[N_VISIT]):
            F = visit[e]
            if (F >= nb and active[F]) or grounded[F]:
                continue
            t, hF, c = top[F], h[F], mt[7, 4]
            for r in range(3):
                c[r] = pw[t, r] + R[t, r, 0] * com[F, 0] + R[t, r, 1] * com[F, 1] \
                    + R[t, r, 2] * com[F, 2]
            L[0] = hF[0] - (c[1] * hF[5] - c[2] * hF[4])
            L[1] = hF[1] - (c[2] * hF[3] - c[0] * hF[5])
            L[2] = hF[2] - (c[0] * hF[4] - c[1] * hF[3])
            for r in range(3):
                L[3 + r] = hF[3 + r]
            for r in range(3):
                hF[r] = R[t, 0, r] * L[0] + R[t, 1, r] * L[1] + R[t, 2, r] * L[2]
                hF[3 + r] = R[t, 0, r] * L[3] + R[t, 1, r] * L[4] + R[t, 2, r] * L[5]


@inlined
def group_momentum(G, R, pw, v, mass, com, inertia, tmp, out):
    """Add the momentum of rigid group ``G`` (frame at ``(R, pw)``, velocity ``v``
    at its origin, its axes) to ``out`` (6,): angular about the world origin, then
    linear, world axes. ``tmp`` (6,): scratch."""
    w = v[:3]
    vc0 = v[3] + w[1] * com[G, 2] - w[2] * com[G, 1]
    vc1 = v[4] + w[2] * com[G, 0] - w[0] * com[G, 2]
    vc2 = v[5] + w[0] * com[G, 1] - w[1] * com[G, 0]
    I = inertia[G]
    h0 = I[0, 0] * w[0] + I[0, 1] * w[1] + I[0, 2] * w[2]
    h1 = I[1, 0] * w[0] + I[1, 1] * w[1] + I[1, 2] * w[2]
    h2 = I[2, 0] * w[0] + I[2, 1] * w[1] + I[2, 2] * w[2]
    m = mass[G]
    for r in range(3):
        tmp[r] = R[r, 0] * h0 + R[r, 1] * h1 + R[r, 2] * h2                 # L
        tmp[3 + r] = m * (R[r, 0] * vc0 + R[r, 1] * vc1 + R[r, 2] * vc2)    # P
    c0 = pw[0] + R[0, 0] * com[G, 0] + R[0, 1] * com[G, 1] + R[0, 2] * com[G, 2]
    c1 = pw[1] + R[1, 0] * com[G, 0] + R[1, 1] * com[G, 1] + R[1, 2] * com[G, 2]
    c2 = pw[2] + R[2, 0] * com[G, 0] + R[2, 1] * com[G, 1] + R[2, 2] * com[G, 2]
    out[0] += tmp[0] + c1 * tmp[5] - c2 * tmp[4]
    out[1] += tmp[1] + c2 * tmp[3] - c0 * tmp[5]
    out[2] += tmp[2] + c0 * tmp[4] - c1 * tmp[3]
    for r in range(3):
        out[3 + r] += tmp[3 + r]


@inlined
def hybrid_energy(nb, js, bodies, groups, top, region, q, qd, kin, out):
    """Kinetic and gravitational energy of the hybrid at ``(q, qd)`` into ``out``
    (2,), O(active joints + front) (``docs/adaptive.md``, "The energy cap"): each
    front group's ``1/2 m |v_c|^2 + 1/2 w^T I_c w`` and ``-m g · c`` from its
    top body's pose and velocity (:func:`active_kinematics`; a grounded group's
    centre of mass is in world axes and it does not move), plus the active
    joints' rotors ``1/2 armature qd^2`` (a rigid joint has ``qd = 0``)."""
    (active, pinned, desc, since, visit, size, joints, par, R0, p0, counts, Psi, p, eta, A, V,
     la, N_M, wA, wV, h, heap, popped, H, M, mt, front, dofs) = region
    mass, com, inertia, grounded = groups[0], groups[1], groups[2], groups[4]
    gravity, armature = bodies[4], bodies[11]
    v_start, nv_joint = js[6], js[7]
    R, pw, v = kin[5], kin[6], kin[7]
    active_kinematics(js, region, q, qd, True, kin)
    T, U = 0.0, 0.0
    for e in range(counts[N_VISIT]):
        G = visit[e]
        if G >= nb and active[G]:
            continue
        m, c = mass[G], com[G]
        if grounded[G]:
            U -= m * (gravity[0] * c[0] + gravity[1] * c[1] + gravity[2] * c[2])
            continue
        t = top[G]
        w0, w1, w2 = v[t, 0], v[t, 1], v[t, 2]
        vc0 = v[t, 3] + w1 * c[2] - w2 * c[1]
        vc1 = v[t, 4] + w2 * c[0] - w0 * c[2]
        vc2 = v[t, 5] + w0 * c[1] - w1 * c[0]
        I = inertia[G]
        T += 0.5 * (m * (vc0 * vc0 + vc1 * vc1 + vc2 * vc2)
                    + w0 * (I[0, 0] * w0 + I[0, 1] * w1 + I[0, 2] * w2)
                    + w1 * (I[1, 0] * w0 + I[1, 1] * w1 + I[1, 2] * w2)
                    + w2 * (I[2, 0] * w0 + I[2, 1] * w1 + I[2, 2] * w2))
        for r in range(3):
            cw = pw[t, r] + R[t, r, 0] * c[0] + R[t, r, 1] * c[1] + R[t, r, 2] * c[2]
            U -= m * gravity[r] * cw
    for x in range(counts[N_JOINTS]):
        j = joints[x]
        for k in range(v_start[j], v_start[j] + nv_joint[j]):
            T += 0.5 * armature[k] * qd[k] * qd[k]
    out[0], out[1] = T, U


@pass_kernel
def cap_energy(energy, nb, js, bodies, groups, top, region, q, qd, kin):
    """The energy cap (``docs/adaptive.md``): with ``energy`` = (cap, removed, T,
    U), the hybrid's energy (:func:`hybrid_energy`) into ``T``, ``U``; a cap of
    NaN becomes ``T + U`` (the reference state), and where ``T + U`` exceeds the
    cap, the active joints' velocities are scaled by ``sqrt((cap - U) / T)``
    (zero if ``U`` alone exceeds it), which brings the kinetic energy to
    ``cap - U``, and ``removed`` grows by the excess. An infinite cap: nothing.
    Returns whether ``kin`` then holds the active joints' kinematics at ``(q, qd)``
    (computed for the energy, and ``qd`` not scaled): the next step's."""
    if energy[0] == np.inf:
        return False
    hybrid_energy(nb, js, bodies, groups, top, region, q, qd, kin, energy[2:])
    T, U = energy[2], energy[3]
    if np.isnan(energy[0]):
        energy[0] = T + U
        return True
    if not T + U > energy[0]:
        return True
    s = np.sqrt(max(energy[0] - U, 0.0) / T) if T > 0.0 else 0.0
    energy[1] += (1.0 - s * s) * T
    v_start, nv_joint, joints, counts = js[6], js[7], region[6], region[10]
    for x in range(counts[N_JOINTS]):
        j = joints[x]
        for k in range(v_start[j], v_start[j] + nv_joint[j]):
            qd[k] *= s
    return False


@pass_kernel
def resume_cap(off, energy, left, nb, js, bodies, groups, top, region, q, qd, kin):
    """The energy cap (``docs/adaptive.md``) for steps from ``(q, qd)``: none
    if ``off`` (forces that do work, or ``energy="free"``); the same cap while
    ``(q, qd)`` is the state ``left`` = (q, qd) that the last capped steps left
    (:func:`hold_cap`); else the energy of ``(q, qd)`` (:func:`cap_energy`).
    Returns whether ``kin`` then holds the active joints' kinematics at
    ``(q, qd)``."""
    left_q, left_qd = left
    if off:
        energy[0] = np.inf
        left_q[:] = np.nan
        return False
    if np.isfinite(energy[0]) and same(q, left_q) and same(qd, left_qd):
        return False
    energy[0] = np.nan
    placed = cap_energy(energy, nb, js, bodies, groups, top, region, q, qd, kin)
    hold_cap(energy, left, q, qd)
    return placed


@inlined
def hold_cap(energy, left, q, qd):
    """Under a finite energy cap, ``left`` = (q, qd), the state whose cap
    :func:`resume_cap` keeps."""
    if np.isfinite(energy[0]):
        copy_state(q, qd, left)


# --- integration of the active joints ---------------------------------------------------------

@pass_kernel
def euler_active(dt, js, bodies, region, q, qd, qdd):
    """Semi-implicit Euler on the active joints: ``qd += dt qdd``, then ``q ⊕= dt qd``."""
    stage0, n_stages, v_start, nv_joint = js[4], js[5], js[6], js[7]
    stage_kind, stage_q, stage_v = bodies[5], bodies[6], bodies[7]
    joints, counts = region[6], region[10]
    for x in range(counts[N_JOINTS]):
        j = joints[x]
        for k in range(v_start[j], v_start[j] + nv_joint[j]):
            qd[k] += dt * qdd[k]
        for s in range(stage0[j], stage0[j] + n_stages[j]):
            stage_step(s, stage_kind, stage_q, stage_v, q, qd, dt, q)


@pass_kernel
def rk4_active(k, dt, js, bodies, region, q, qd, qdd, kq, kv, qs, vs):
    """RK4 on the active joints, as :func:`vdad.integrators.rk4`: ``k`` = 0..3
    stores ``qdd`` of evaluation ``k - 1`` and sets the state ``(qs, vs)`` of
    evaluation ``k`` and its rates ``kq[k]``; ``k = 4`` stores the last and ends
    the step in ``(q, qd)``, quaternions normalised."""
    stage0, n_stages, v_start, nv_joint = js[4], js[5], js[6], js[7]
    stage_kind, stage_q, stage_v = bodies[5], bodies[6], bodies[7]
    joints, counts = region[6], region[10]
    h = 0.0 if k == 0 else (dt if k == 3 else dt / 2)
    for x in range(counts[N_JOINTS]):
        j = joints[x]
        for i in range(v_start[j], v_start[j] + nv_joint[j]):
            if k > 0:
                kv[k - 1, i] = qdd[i]
            if k < 4:
                vs[i] = qd[i] + h * kv[k - 1, i] if k > 0 else qd[i]
            else:
                qd[i] += dt / 6 * (kv[0, i] + 2 * kv[1, i] + 2 * kv[2, i] + kv[3, i])
        for s in range(stage0[j], stage0[j] + n_stages[j]):
            kind, iq = stage_kind[s], stage_q[s]
            for i in range(iq, iq + stage_nq(kind)):
                if k < 4:
                    qs[i] = q[i] + h * kq[k - 1, i] if k > 0 else q[i]
                else:
                    q[i] += dt / 6 * (kq[0, i] + 2 * kq[1, i] + 2 * kq[2, i] + kq[3, i])
            if k < 4:
                stage_rate(s, stage_kind, stage_q, stage_v, qs, vs, kq[k])
            else:
                normalize_stage(s, stage_kind, stage_q, q)


@pass_kernel
def active_state_ok(dt, js, bodies, region, rotational, q, qd):
    """The simulator's step checks on the active joints (the only ones a step
    changes: a rigid joint keeps its ``q`` and ``qd = 0``): whether their ``q`` and
    ``qd`` are finite and no rotational dof (``rotational`` (nv,)) turns by more
    than half a turn in ``dt``. O(active joints) instead of O(n)."""
    stage0, n_stages, v_start, nv_joint = js[4], js[5], js[6], js[7]
    stage_kind, stage_q = bodies[5], bodies[6]
    joints, counts = region[6], region[10]
    for x in range(counts[N_JOINTS]):
        j = joints[x]
        for k in range(v_start[j], v_start[j] + nv_joint[j]):
            if not np.isfinite(qd[k]) or (rotational[k] and abs(qd[k]) * dt > np.pi):
                return False
        for s in range(stage0[j], stage0[j] + n_stages[j]):
            kind, iq = stage_kind[s], stage_q[s]
            for i in range(iq, iq + stage_nq(kind)):
                if not np.isfinite(q[i]):
                    return False
    return True


@pass_kernel
def region_poses(js, region, q, kin):
    """World poses of the active joints' child bodies at ``q`` (placements and
    poses only): the frames of the front groups."""
    active_kinematics(js, region, q, q, False, kin)


#: columns of :func:`region_steps`' per-step counters (the StepStats fields)
STEP_COUNTERS = ("active_joints", "front", "accelerated", "assembled", "back_substituted",
                 "force_update", "lookahead", "rigidified", "released")


@pass_kernel
def forces_now(use, F, e, t, js, q, qd, fkin, fresh, states, f_ext, tau, held, active, up,
               is_B, groups, pending, mark, order):
    """The built-in forces of the tables ``F`` at evaluation ``e`` (with ``use``;
    else ``tau`` is zero and no wrench acts) and their changes carried up the
    rigid groups (:func:`vdad.hybrid.carry_forces`); the forces' kinematics
    ``fkin`` place only the joints not ``fresh`` (:func:`vdad.forces.body_forces`).
    Returns its node visits."""
    if not use:
        for i in range(tau.shape[0]):
            tau[i] = 0.0
        return 0
    body_forces(js, F, e, t, q, qd, fkin, states, f_ext, tau, fresh)
    return carry_forces(f_ext, held, active, up, is_B, groups, pending, mark, order)


@pass_kernel
def region_steps(n, step0, time0, e0, stop_on_change, options, nb, js, tree, bodies, groups,
                 top, up, roots, sums, use_forces, F, force_work, coverage, raster, energy, cap_off,
                 left, rotational, q, qd, kin, work, region, stack, last, counters):
    """Up to ``n`` adaptive steps by semi-implicit Euler, the first numbered
    ``step0 + 1`` by adaptive dynamics and at ``t = time0 dt`` (the simulator's
    step count), each as ``AdaptiveDynamics.step`` takes it from Python:
    forces (the built-in elements of ``F`` at evaluation ``e0 + s`` for the step
    ``s`` of the call, if ``use_forces``), the first evaluation, under
    ``drop="lock"`` the immediate locking of what it pruned and a second
    evaluation, the integration of the active joints, the region update, the
    energy cap; then the simulator's checks on the active joints. ``options`` =
    (predictive, budget, lookahead, locking, momentum, dwell, dt, keep, kappa,
    threshold), ``lookahead`` 0 (none) or the steps between look-aheads;
    ``sums`` = the force sums held by the groups and ``carry_forces``' scratch;
    ``force_work`` = (the joints whose kinematics the forces read,
    ``AdaptiveDynamics.force_joints``; kinematics, states, f_ext, tau of every
    body; ``fresh``, the joints whose placement those kinematics hold: none at
    the start, the rigid ones once placed, :func:`forces_now`); ``energy``,
    ``cap_off``, ``left``: the energy cap's (:func:`resume_cap` before the steps,
    :func:`cap_energy` after each); ``coverage`` = (constants, frames) of
    ``vdad.visibility.BoundingVolumes.loop_coverage`` (with ``raster`` None) or
    of ``vdad.visibility.RenderedCounts.loop_coverage`` (the rasteriser's arrays
    in ``raster``): ``N_M`` of every node by :func:`vdad.visibility.region_bvh_pass`
    or :func:`vdad.visibility.region_raster_pass` (a branch numba prunes by the
    type of ``raster``, so that each compiled loop holds one) before the steps
    ``frames[0]`` (ascending) of the call, each under its camera (none if empty), from the
    active joints' poses at the step's ``q`` (as ``AdaptiveDynamics.front_kinematics``
    places them for the Python steps; without forces, with the velocities that the
    step's first evaluation then takes). Writes
    each step's :data:`STEP_COUNTERS` into ``counters`` (n, 9) and keeps the state
    before the last step in ``last`` (q, qd). Stops after a step that changed the
    region if ``stop_on_change`` (the coverage is stale then). Returns ``(steps done,
    status)``: 0, or 1 if a step's ``qdd`` was not finite (its state not
    advanced), 2 if its new state failed the checks (``last`` holds the one before)."""
    predictive, budget, lookahead, locking, momentum, dwell, dt, keep, kappa, threshold = \
        options
    held, pending, mark, order, is_B = sums
    fjs, fkin, states, f_ext, tau, fresh = force_work
    active, counts, qdd = region[0], region[10], work[7]
    (codes, first, poses, volumes, cache, world, N1, moved, scratch), (due, views, Rcs, pcs) = \
        coverage
    # placed: kin holds the active joints' kinematics at (q, qd); fresh: the joints
    # whose placement the forces' kinematics hold at q (none: q comes from Python)
    fresh[:] = False
    placed = resume_cap(cap_off, energy, left, nb, js, bodies, groups, top, region, q, qd, kin)
    f, done, status = 0, n, 0
    # the constant arguments below as plain types: numba types a constant as a
    # literal and would compile the callee once per call site (docs/design.md)
    yes, no, zero = bool(True), bool(False), np.int64(0)   # noqa: UP018
    for s in range(n):
        step = step0 + s
        t = (time0 + s) * dt
        if f < due.shape[0] and due[f] == s:    # N_M of the frame (Kim 2008 §5.3)
            if not placed:                      # the step's own poses; with forces,
                # take_kinematics below replaces them, velocities and all
                active_kinematics(js, region, q, qd, not use_forces, kin)
                placed = not use_forces
            v = views[f]
            if raster is None:                  # numba compiles one branch: the type decides
                region_bvh_pass(codes, (v[0], v[1], v[2], v[3]), Rcs[f], pcs[f], nb, tree[0],
                                tree[1], (tree[13], tree[14]), first,
                                (region[4], counts[N_VISIT], active, groups[4], top, groups[5],
                                 groups[6]), region[3], kin[5], kin[6], poses, volumes, cache,
                                world, N1, region[17], moved, scratch)
            else:
                region_raster_pass(codes, (v[0], v[1], v[2], v[3]), Rcs[f], pcs[f], nb,
                                   tree[0], tree[1], (tree[13], tree[14]),
                                   (region[4], counts[N_VISIT], active, groups[4], top,
                                    groups[5], groups[6]), kin[5], kin[6], poses, raster,
                                   region[17], moved, scratch[0])
            f += 1
        copy_state(q, qd, last)
        row = counters[s]
        for c in range(row.shape[0]):
            row[c] = 0
        row[0], row[1] = counts[N_JOINTS], counts[FRONT]
        row[5] += forces_now(use_forces, F, e0 + s, t, fjs, q, qd, fkin, fresh, states, f_ext,
                             tau, held, active, up, is_B, groups, pending, mark, order)
        if use_forces and take_kinematics(js, region, fresh, fkin, kin):
            placed = True
        lookahead_on = lookahead_due(lookahead, step + 1)
        if not evaluate(yes, predictive, budget, no, placed, no, lookahead_on, locking, step + 1,
                        dwell, dt, keep, kappa, nb, js, tree, bodies, groups, top, up, roots, q,
                        qd, tau, kin, work, region):
            done, status = s, 1
            break
        if locking and counts[ACCELERATED] < counts[ASSEMBLED]:
            nc = lock_pruned(nb, up, region, stack)
            if nc:
                change_region(nc, zero, step + 1, momentum, nb, js, tree, groups, top, roots, q,
                              qd, kin, region, stack)
                if momentum:                    # the locking impulse (evaluate's impulse)
                    evaluate(no, predictive, zero, yes, no, yes, no, no, step + 1, zero, dt,
                             0.0, 1.0, nb, js, tree, bodies, groups, top, up, roots, q, qd, qd,
                             kin, work, region)
                row[7] += counts[RIGIDIFIED]
            row[0], row[1] = counts[N_JOINTS], counts[FRONT]
            row[5] += forces_now(use_forces, F, e0 + s, t, fjs, q, qd, fkin, fresh, states,
                                 f_ext, tau, held, active, up, is_B, groups, pending, mark,
                                 order)
            again = use_forces and take_kinematics(js, region, fresh, fkin, kin)
            if not evaluate(no, predictive, budget, no, again, yes, lookahead_on, locking,
                            step + 1, dwell, dt, keep, kappa, nb, js, tree, bodies, groups, top,
                            up, roots, q, qd, tau, kin, work, region):
                done, status = s, 1
                break
        euler_active(dt, js, bodies, region, q, qd, qdd)
        for x in range(counts[N_JOINTS]):               # their q moved
            fresh[region[6][x]] = False
        row[2], row[3], row[4], row[6] = (counts[ACCELERATED], counts[ASSEMBLED], counts[SOLVED],
                                          counts[LOOKAHEAD])
        nc, nr = update_region(step + 1, budget, lookahead_on, dt, threshold, keep, dwell, nb, js,
                               tree, up, qd, region, stack)
        if nc + nr:
            change_region(nc, nr, step + 1, momentum, nb, js, tree, groups, top, roots, q, qd,
                          kin, region, stack)
            if nc and momentum:
                evaluate(no, predictive, zero, yes, no, no, no, no, step + 1, zero, dt, 0.0,
                         1.0, nb, js, tree, bodies, groups, top, up, roots, q, qd, qd, kin, work,
                         region)
            row[7] += counts[RIGIDIFIED]
            row[8] += counts[RELEASED]
        placed = cap_energy(energy, nb, js, bodies, groups, top, region, q, qd, kin)
        if not active_state_ok(dt, js, bodies, region, rotational, q, qd):
            done, status = s, 2
            break
        if stop_on_change and row[7] + row[8]:
            done = s + 1
            break
    hold_cap(energy, left, q, qd)
    return done, status


@kernel
def region_call(constants, tables, volumes, frames, n, step0, time0, e0, stop_on_change,
                options, use_forces, cap_off, rotational, q, qd):
    """:func:`region_steps` with the arguments that stay the same from call to call
    in three packs (:class:`~vdad._pack.Pack`), so that a call from Python converts
    a dozen arrays instead of some 270 (``vdad._pack``): ``constants`` = (nb, js,
    tree, bodies, groups, top, up, roots, sums, force work, energy, left, kin,
    work, region, stack, last, counters), ``force work`` without its joint set;
    ``tables`` = (F, the joint set of the forces' kinematics); ``volumes`` = the
    constants of ``coverage`` and ``raster``, whose ``frames`` come apart."""
    (nb, js, tree, bodies, groups, top, up, roots, sums, force_work, energy, left, kin, work,
     region, stack, last, counters) = constants.data
    F, fjs = tables.data
    coverage, raster = volumes.data
    return region_steps(n, step0, time0, e0, stop_on_change, options, nb, js, tree, bodies,
                        groups, top, up, roots, sums, use_forces, F, (fjs,) + force_work,
                        (coverage, frames), raster, energy, cap_off, left, rotational, q, qd,
                        kin, work, region, stack, last, counters)
