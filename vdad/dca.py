"""Featherstone's divide-and-conquer algorithm, one node at a time (theory §2-6).

:func:`leaf` fills the blocks of one body (T2)-(T3), :func:`assemble_node` joins
two sub-assemblies across a joint (T6)-(T12), with the joint's armature (A1)-(A2)
of ``docs/joints.md``, and :func:`solve_node` finds the joint's wrench and
accelerations (T10), (T13). :func:`dca_pass` is the whole evaluation: the
kinematics (:func:`vdad.kinematics.kinematics_pass`), the joint springs and
dampers, then per root's subtree (:func:`subtree_passes`; on numba's threads for
large forests) every leaf and internal node in depth-first post-order, and the
top-down pass in the reverse order. All of it is compiled (numba,
``cache=True``); the passes are plain loops over nodes, so a node costs the same
wherever it sits in the tree.

Port quantities are expressed in *port frames*: both ports of joint ``J`` use the
frame of ``J``'s child body (at the joint, body axes), so a joint needs no
transform between its two sides and every quantity is translation-invariant
(theory §1).

Storage (:class:`~vdad.assembly.AssemblyTree`): node ``n`` with ``P`` ports owns
the blocks ``Phi_ac``, ``a <= c``, at ``Phi[pair_base[n] + pair_offset(P, a, c)]``
(6, 6; ``Phi_ca = Phi_ac^T`` is not stored) and the vectors ``b[pair_base[n] +
a]`` (6,; a node has at least as many blocks as ports); a ground leaf has none
(``Phi = 0``, ``b = 0``). ``pair_base`` is the data's layout (:func:`make_data`):
every node's blocks kept (:func:`node_blocks` gives a node's whole ``Phi``), or
only those live in the bottom-up pass, in stacks (``docs/design.md``, "Block
storage"). Per port slot (``slot_base[n] + a``) the tree keeps its joint, side
and origin.
Signed column blocks: for a port ``a`` of ``C`` taken from child ``X`` (``A`` or
``B``), ``G_a = s_a Phi^X_{a j_X}`` with ``s_a = -1`` on ``alpha`` and ``+1`` on
``beta``. Then (T11)-(T12) read ``Phi^C_{ac} = Phi^X_{ac} [same child] - G_a Y
G_c^T`` and ``b^C_a = b^X_a + G_a beta_C``, and (T10), (T13) read ``f_J = beta_C
- Y u``, ``r = u + gamma`` with ``u = sum_a G_a^T f_a``: the top-down pass reads
``G_a`` (kept unsigned in the slots of ``C``, ``G[slot_base[C] + a]``: the
internal nodes' slots come first) and no block of ``Phi``.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from functools import lru_cache
from typing import NamedTuple

import numpy as np
from numba import prange

from . import joints as J
from ._linalg import (
    EPS,
    cholesky,
    finite,
    identity_pose,
    inlined,
    inverse_inertia_transpose,
    is_zero6,
    kernel,
    mm6,
    mmt6_add,
    mmt6_add_symmetric,
    mtv6_add,
    mv6,
    mv6_add,
    parallel_kernel,
    pass_kernel,
    port_product,
    port_transform,
    quaternion_log,
    solve_general,
    symmetric_part,
    zero6,
)
from ._pack import pack
from .assembly import AssemblyTree
from .checks import check_count, check_flag
from .errors import InputError
from .kinematics import Kinematics, joint_kinematics, kinematics_pass, plan, world_poses
from .model import Model, Pose
from .newton_euler import FULL, MASS, body_wrench, inverse_dynamics_pass


@dataclass
class DCAData:
    """Work arrays of one DCA evaluation on a tree (Pinocchio's Data; shapes in
    brackets), allocated once by :func:`make_data` and reused.

    kin: the :class:`~vdad.kinematics.Kinematics` of the state.
    Phi [n_pairs or fewer, 6, 6], b [as many, 6]: block stores of the tree (blocks
    ``a <= c``, and ``b`` of the ports) in the layout ``layout`` (the tree's arrays
    with the ``pair_base`` of this store); G [n_inner_slots, 6, 6]: ``G_a`` of every
    internal node's ports.
    Y [nb, 6, 6], beta, gamma [nb, 6]: per internal node, the intermediates kept
    for the top-down pass, with WtWm [nv, 6]: ``W^T W_m`` of each joint, a row per
    dof (what (T13) needs of ``W_m``), and PF [nv, 6]: ``(P F)^T`` of (A2) for the
    joints with armature. f_J [nb, 6]: joint wrenches; qdd [nv]: joint
    accelerations; tau [nv]: the joint forces of the last evaluation (springs,
    dampers and actuation). X, GY [max ports, 6, 6], tmp [8, 6, 6]: scratch;
    a, f [nb, 6], cg [5, nv]: scratch of :func:`refine_pass`. ``kept``: whether
    ``Phi`` keeps every node's blocks. ``packed``: the arguments of
    :func:`dca_call` into these arrays (:func:`packed`; None until a call).
    """

    kin: Kinematics
    Phi: np.ndarray
    b: np.ndarray
    Y: np.ndarray
    WtWm: np.ndarray
    beta: np.ndarray
    gamma: np.ndarray
    f_J: np.ndarray
    qdd: np.ndarray
    tau: np.ndarray
    X: np.ndarray
    GY: np.ndarray
    tmp: np.ndarray
    PF: np.ndarray
    a: np.ndarray
    f: np.ndarray
    cg: np.ndarray
    G: np.ndarray
    layout: tuple
    kept: bool
    packed: object = None

    def __getstate__(self):
        """A copy (``copy.deepcopy``, pickle) leaves the pack out: it holds these
        arrays, and numba cannot copy it; :func:`packed` builds the copy's own."""
        return {**self.__dict__, "packed": None}

    @property
    def arrays(self) -> tuple:
        return (self.Phi, self.b, self.Y, self.WtWm, self.beta, self.gamma, self.f_J, self.qdd,
                self.tau, self.X, self.GY, self.tmp, self.PF, self.a, self.f, self.cg, self.G)


def make_data(tree, keep_blocks=False) -> DCAData:
    """Allocate the work arrays for ``tree``. ``keep_blocks``: keep every node's
    blocks ``Phi`` after an evaluation (for :func:`node_blocks`, and for adaptive
    dynamics, which reads its front nodes' blocks across steps); else only those
    live in the bottom-up pass are stored, in stacks of a few dozen blocks per
    root (:attr:`~vdad.assembly.AssemblyTree.stack_arrays`): the top-down pass needs
    none of them, and a 10000-body chain's step writes 1.55 kB per body instead of
    2.7 (``docs/design.md``, "Block storage")."""
    if not isinstance(tree, AssemblyTree):
        raise InputError(f"tree must be a vdad.AssemblyTree, got {type(tree).__name__}")
    keep_blocks = check_flag("keep_blocks", keep_blocks)
    model = tree.model
    nb, nv, P = model.nb, model.nv, tree.max_ports
    layout, n_blocks = (tree.arrays, tree.n_pairs) if keep_blocks else tree.stack_arrays
    z = np.zeros
    return DCAData(Kinematics.empty(plan(model)), z((n_blocks, 6, 6)), z((n_blocks, 6)),
                   z((nb, 6, 6)), z((nv, 6)), z((nb, 6)), z((nb, 6)), z((nb, 6)), z(nv), z(nv),
                   z((P, 6, 6)), z((P, 6, 6)), z((8, 6, 6)), z((nv, 6)), z((nb, 6)), z((nb, 6)),
                   z((5, nv)), z((tree.n_inner_slots, 6, 6)), layout, keep_blocks)


def check_data(tree, data):
    """``data`` checked to be :class:`DCAData` allocated for ``tree`` (by
    :func:`make_data`), or an InputError."""
    if not isinstance(data, DCAData):
        raise InputError(f"data must be vdad.dca.DCAData from make_data(tree), got "
                         f"{type(data).__name__}")
    model = tree.model
    if (data.layout[13] is not tree.arrays[13] or len(data.b) != len(data.Phi)
            or len(data.f_J) != model.nb or len(data.qdd) != model.nv
            or len(data.X) < tree.max_ports):
        raise InputError(f"data was allocated for another assembly tree than this one (of "
                         f"model {model.name!r}); allocate it with make_data(tree)")
    return data


def node_blocks(tree, data, node):
    """``Phi`` (6 P, 6 P) of ``node`` (a body or ``nb +`` an internal index) with
    its ``P`` ports in the order of ``tree.ports[node]``, from the last evaluation
    into ``data``: the inverse articulated inertia of the sub-assembly seen at its
    ports (theory (T1)). ``data`` may also be any store of that layout (n_pairs,
    6, 6), such as the metric coefficients ``Psi`` of adaptive dynamics."""
    if isinstance(data, np.ndarray):
        if data.shape != (tree.n_pairs, 6, 6):
            raise InputError(f"a block store of this tree has shape ({tree.n_pairs}, 6, 6), "
                             f"got {data.shape}")
        store = data
    else:
        store = check_data(tree, data).Phi
        if not data.kept:
            raise InputError("this data keeps only the blocks live in the bottom-up pass; "
                             "allocate it with make_data(tree, keep_blocks=True) to read "
                             "every node's blocks")
    node = check_count("node", node, minimum=0)
    if node >= tree.n_nodes:
        raise InputError(f"node must be below the tree's {tree.n_nodes} nodes (bodies "
                         f"0..{tree.model.nb - 1}, then the internal nodes), got {node}")
    P, base = int(tree.n_ports[node]), int(tree.pair_base[node])
    out = np.zeros((6 * P, 6 * P))
    for a in range(P):
        for c in range(a, P):
            block = store[base + pair_offset(P, a, c)]
            out[6 * a:6 * a + 6, 6 * c:6 * c + 6] = block
            out[6 * c:6 * c + 6, 6 * a:6 * a + 6] = block.T
    return out


#: a leaf whose smallest principal moment is below ``LEAF_FLOOR`` of its body's
#: scale has its moments raised to ``LEAF_RAISE`` of it, and the DCA's
#: accelerations are refined ((R2) of ``docs/accuracy.md``); so has a body lighter
#: than ``LIGHT_RAISE`` of its heaviest neighbour its whole inertia raised to
#: ``LEAF_RAISE`` of that neighbour's mass, and one lighter than ``LEAF_FLOOR`` of it
#: (but not that light) its accelerations refined by one step ((R5))
LEAF_FLOOR, LEAF_RAISE, LIGHT_RAISE = 1e-2, 1e-1, 1e-3


class Leaves(NamedTuple):
    """What the DCA's leaves use in place of the bodies' own inertias
    (:func:`leaf_inertias`; (R2), (R4), (R5) of ``docs/accuracy.md``)."""

    Iinv: np.ndarray       # (nb, 3, 3) inverse rotational inertias, body axes
    raised: np.ndarray     # (nb,) bodies whose leaf inertia was raised (thin or light)
    paid: np.ndarray       # (nb,) raised bodies whose raise their parent pays back
    mass: np.ndarray       # (nb,) the leaves' masses
    light: np.ndarray      # (nb,) bodies light enough to refine, not to raise


def body_scales(model):
    """(R2) of ``docs/accuracy.md``: each body's principal moments (nb, 3),
    ascending, their axes (nb, 3, 3) and its scale ``max(I_max, m l^2)`` (nb,),
    ``l`` the distance from its centre of mass to its farthest joint (its own
    joint's frame, its children's placements). A body is thin where its smallest
    moment is a small share of its scale."""
    lever = np.linalg.norm(model.com, axis=1)
    for j in np.flatnonzero(model.parent >= 0):
        b = model.parent[j]
        lever[b] = max(lever[b], np.linalg.norm(model.com[b] - model.placement_p[j]))
    moments, axes = np.linalg.eigh(model.inertia)
    return moments, axes, np.maximum(moments[:, -1], model.mass * lever ** 2)


@lru_cache(maxsize=64)
def leaf_inertias(model) -> Leaves:
    """(R2), (R4) and (R5) of ``docs/accuracy.md``: the inertias that the DCA's
    leaves use (:class:`Leaves`). Where a body's smallest principal moment is
    below :data:`LEAF_FLOOR` times its scale ``max(I_max, m l^2)`` (``l`` the
    distance from its centre of mass to its farthest joint: its own joint's frame,
    its children's placements), its moments are raised to :data:`LEAF_RAISE` times
    the scale: a thin rod or a point mass would put ``1 / I_min`` beside ``1 / (m
    l^2)`` in the leaf's blocks (T2), and the assembly (T11) would cancel them. A
    raised body on a fixed joint hands its raise ``dI`` to its parent, whose leaf
    takes ``I - R dI R^T`` where that stays above the floor (:func:`pay_back`).
    A body lighter than :data:`LIGHT_RAISE` of its heaviest neighbour (a body it
    shares a joint with) puts ``1 / m`` beside the neighbour's ``1 / M`` in the
    same way: its leaf's mass and inertia are scaled up to :data:`LEAF_RAISE` of
    that neighbour's mass; one lighter than :data:`LEAF_FLOOR` of it, but not that
    light, keeps its inertia and is marked ``light``."""
    neighbour = np.zeros(model.nb)
    for j in np.flatnonzero(model.parent >= 0):
        b = model.parent[j]
        neighbour[j] = max(neighbour[j], model.mass[b])
        neighbour[b] = max(neighbour[b], model.mass[j])
    moments, axes, scale = body_scales(model)
    thin = moments[:, 0] < LEAF_FLOOR * scale
    heavy = model.mass < LIGHT_RAISE * neighbour
    k = np.where(heavy, LEAF_RAISE * neighbour / model.mass, 1.0)     # the light raise
    leaf = np.maximum(moments, LEAF_RAISE * scale[:, None])
    Iinv = np.einsum("bij,bj,bkj->bik", axes, 1.0 / leaf, axes)
    Iinv[~thin] = np.linalg.inv(model.inertia[~thin])
    Iinv /= k[:, None, None]
    dI = np.einsum("bij,bj,bkj->bik", axes, leaf - moments, axes)
    light = (model.mass < LEAF_FLOOR * neighbour) & ~heavy
    raised = thin | heavy
    return Leaves(Iinv, raised, pay_back(model, raised, thin & ~heavy, dI, scale, Iinv),
                  model.mass * k, light)


def pay_back(model, raised, movable, dI, scale, Iinv):
    """(R4) of ``docs/accuracy.md``: the mask (nb,) of the ``movable`` (nb,) bodies
    on fixed joints whose raise ``dI`` (nb, 3, 3; body axes) their parent's leaf
    takes off its own inertia, written into ``Iinv`` (the parent's inverse leaf
    inertia). The two bodies turn as one, so the rotational inertia ``dI`` moved
    from child to parent (rotated by the weld ``R``) changes no entry of ``M``. A
    parent pays when it is not ``raised`` (nb,) itself and its inertia less what
    its welded children hand it stays above :data:`LEAF_FLOOR` of its ``scale``
    (nb,)."""
    paid = np.zeros(model.nb, bool)
    welded = np.flatnonzero(movable & (model.nv_joint == 0) & (model.parent >= 0))
    for p in set(model.parent[welded].tolist()) - set(np.flatnonzero(raised).tolist()):
        children = welded[model.parent[welded] == p]
        R = model.placement_R[children]
        leaf = model.inertia[p] - np.einsum("cij,cjk,clk->il", R, dI[children], R)
        if np.linalg.eigvalsh(leaf)[0] >= LEAF_FLOOR * scale[p]:
            Iinv[p] = np.linalg.inv(leaf)
            paid[children] = True
    return paid


def spin_axes(model):
    """The axis about which every body of ``model`` turns, in each body's frame
    (nb, 3), where all do about one direction: every rotational stage a hinge, all
    hinge axes parallel (then at every configuration, since turning about a
    direction keeps it); zero vectors where nothing turns (slides only); None
    otherwise. On such (planar) models a leaf raised square to that axis changes
    no entry of ``M``, and needs no refinement (``docs/accuracy.md``)."""
    if np.any(model.stage_kind == J.BALL):
        return None
    hinges = np.flatnonzero(model.stage_kind == J.HINGE)
    if not len(hinges):
        return np.zeros((model.nb, 3))
    q = np.asarray(model.q_neutral, float)
    S = joint_kinematics(plan(model), q)[2]
    R = world_poses(model, q)[0].copy()
    joint = model.stage_joint[hinges]
    column = model.stage_v[hinges] - model.v_start[joint]
    w = np.einsum("kab,kb->ka", R[joint], S[joint, :3, column])
    a = w[0] / np.linalg.norm(w[0])
    if np.abs(np.cross(w, a)).max() > 1e-12 * np.abs(w).max():
        return None
    return np.einsum("bji,j->bi", R, a)


@lru_cache(maxsize=64)
def body_arrays(model) -> tuple:
    """The model constants the passes read, as one tuple: ``mass`` (nb,), ``com``
    (nb, 3), ``inertia`` (nb, 3, 3), the leaves' inverse inertias ``Iinv`` (nb, 3, 3;
    :func:`leaf_inertias`), ``gravity`` (3,); the springs and dampers:
    ``stage_kind, stage_q, stage_v, stage_stiffness`` (ns,), ``q_spring`` (nq,),
    ``damping``, ``armature`` (nv,); ``refine``, the most steps of
    :func:`refine_pass` (0 where no leaf was raised, or where every raise is square
    to the spin axis of a planar model, :func:`spin_axes`; :data:`ONE_STEP` where
    every other raise is paid back by a parent's leaf, :func:`pay_back`, or some
    body is light); and the leaves' masses (nb,)."""
    js = plan(model)
    leaves = leaf_inertias(model)
    heavy = leaves.mass != model.mass              # light bodies raised: M' - M spreads wider
    refined = leaves.raised & ~leaves.paid & ~heavy
    axes = spin_axes(model) if refined.any() else None
    if axes is not None:               # planar: refine where a raise meets the spin axis
        dI = np.linalg.inv(leaves.Iinv[refined]) - model.inertia[refined]
        turned = np.abs(np.einsum("bij,bj->bi", dI, axes[refined])).max(axis=1)
        refined[refined] = turned > 1e-9 * np.abs(dI).max(axis=(1, 2))
    if heavy.any():                                         # the raises that change M
        refine = MAX_REFINE
    elif refined.any():
        refine = min(2 * int(refined.sum()) + 4, MAX_REFINE)
    else:
        refine = ONE_STEP if (leaves.paid | leaves.light).any() else 0
    return (model.mass, model.com, model.inertia, leaves.Iinv, model.gravity, js.stage_kind,
            js.stage_q, js.stage_v, js.stage_stiffness, js.q_spring, js.damping, js.armature,
            refine, leaves.mass)


@lru_cache(maxsize=64)
def plain_arrays(model) -> tuple:
    """:func:`body_arrays` with the bodies' own inverse inertias and no refinement:
    the DCA of (T2)-(T13) without (R1)-(R5) of ``docs/accuracy.md``, which
    ``scripts/bench_accuracy.py`` measures beside the refined one."""
    b = body_arrays(model)
    return (*b[:3], np.linalg.inv(model.inertia), *b[4:12], 0, model.mass)


@lru_cache(maxsize=64)
def inert_arrays(model) -> tuple:
    """:func:`body_arrays` without gravity, springs and dampers: the DCA on these at
    zero velocity solves ``M qdd = tau`` (``M^-1 p`` of the symplectic integrator,
    (S3) of ``docs/accuracy.md``)."""
    b = body_arrays(model)
    return (*b[:4], _zeros_like(b[4]), *b[5:8], _zeros_like(b[8]), b[9], _zeros_like(b[10]),
            b[11], b[12], b[13])


def _zeros_like(a):
    """Zeros of ``a``'s shape, dtype and writability: the kernels' argument types
    (hence their compiled versions) stay those of :func:`body_arrays`."""
    z = np.zeros_like(a)
    z.setflags(write=a.flags.writeable)
    return z


#: the most conjugate-gradient steps of :func:`refine_pass`
MAX_REFINE = 40

#: ``refine`` of :func:`body_arrays` where every raise is paid back or a body is
#: light ((R4), (R5) of ``docs/accuracy.md``: ``M' = M``): one step of iterative
#: refinement
ONE_STEP = -1

#: ``assembled`` of :func:`rhs_passes`: every internal node
ALL = np.zeros(0, np.bool_)


# --- joint forces ---------------------------------------------------------------------

@pass_kernel
def passive_forces_pass(stage_kind, stage_q, stage_v, stage_stiffness, q_spring, damping,
                        q, qd, tau):
    """``tau = -D qd - K d`` (nv,): the joint dampers, and the springs of every
    stage towards ``q_spring`` (:func:`spring_force`)."""
    for i in range(qd.shape[0]):
        tau[i] = -damping[i] * qd[i]
    for s in range(stage_kind.shape[0]):
        spring_force(s, stage_kind, stage_q, stage_v, stage_stiffness, q_spring, q, tau)


@inlined
def spring_force(s, stage_kind, stage_q, stage_v, stage_stiffness, q_spring, q, tau):
    """``tau -= K d`` on the dofs of stage ``s``: its spring towards ``q_spring`` (a
    ball's ``d``: the rotation vector of ``q_spring^-1 q``, as MuJoCo;
    ``docs/forces.md``)."""
    k = stage_stiffness[s]
    if k == 0.0:
        return
    kind, iq, iv = stage_kind[s], stage_q[s], stage_v[s]
    if kind == 2:                                      # ball: log(conj(q_spring) q)
        a0, a1, a2, a3 = q_spring[iq], -q_spring[iq + 1], -q_spring[iq + 2], -q_spring[iq + 3]
        b0, b1, b2, b3 = q[iq], q[iq + 1], q[iq + 2], q[iq + 3]
        d = quaternion_log(a0 * b0 - a1 * b1 - a2 * b2 - a3 * b3,
                           a0 * b1 + a1 * b0 + a2 * b3 - a3 * b2,
                           a0 * b2 - a1 * b3 + a2 * b0 + a3 * b1,
                           a0 * b3 + a1 * b2 - a2 * b1 + a3 * b0)
        for c in range(3):
            tau[iv + c] -= k * d[c]
    else:
        for c in range(3 if kind == 3 else 1):
            tau[iv + c] -= k * (q[iq + c] - q_spring[iq + c])


# --- node kernels -----------------------------------------------------------------------

@inlined
def leaf(i, tree, bodies, f_ext, kin, Phi, b, X, Q, tmp):
    """Blocks of body ``i``, theory (T2)-(T3) (:func:`leaf_blocks`) with the leaf's
    mass and inverse inertia (``bodies[13]``, ``bodies[3]``: :func:`leaf_inertias`),
    ``X_h = X_{h<-c}`` from its centre of mass to port ``h`` and the known wrench
    at the centre of mass (:func:`~vdad.newton_euler.body_wrench`). The inbound
    port is the body frame; the port of a child joint is that joint's child frame.
    ``X``, ``Q`` (>= ports, 6, 6): ``X_h`` and ``Ibar^-1 X_h^T``; ``tmp`` (>= 3, 6,
    6): scratch."""
    (left, right, joint, port_A, port_B, n_ports, pair_base, slot_base, slot_joint,
     slot_side, slot_child, slot_index, slot_sign, post, segments) = tree
    mass, com, Iinv = bodies[13], bodies[1], bodies[3]
    R_rel, p_rel, R, v = kin[0], kin[1], kin[5], kin[7]
    P, s0 = n_ports[i], slot_base[i]
    m, c = mass[i], com[i]
    eye, zero = tmp[2, :3, :3], tmp[2, 3, :3]
    identity_pose(eye, zero)
    for h in range(P):
        j = slot_joint[s0 + h]
        if slot_side[s0 + h] > 0:
            port_transform(eye, zero, c, X[h])
        else:
            port_transform(R_rel[j], p_rel[j], c, X[h])
    f = tmp[1, 0]
    body_wrench(i, bodies, f_ext, v[i], R[i], f)
    leaf_blocks(P, pair_base[i], X, Q, m, Iinv[i], f, Phi, b, tmp[1, 1])


@inlined
def leaf_blocks(P, base, X, Q, m, Ii, f, Phi, b, a_c):
    """(T2)-(T3) of a rigid leaf of ``P`` ports from its port transforms ``X_h``
    (``X``): ``Phi_hk = X_h Ibar^-1 X_k^T`` (``h <= k``) and ``b_h = X_h Ibar^-1
    f``, from ``base``, ``Ibar^-1 = diag(Ii, 1/m)``, ``f`` (6,) at
    the centre of mass. ``Q`` (>= P, 6, 6), ``a_c`` (6,): scratch."""
    for h in range(P):
        inverse_inertia_transpose(X[h], Ii, m, Q[h])
    for h in range(P):
        for k in range(h, P):
            port_product(X[h], Q[k], Phi[base + pair_offset(P, h, k)])
    for r in range(3):
        a_c[r] = Ii[r, 0] * f[0] + Ii[r, 1] * f[1] + Ii[r, 2] * f[2]
        a_c[3 + r] = f[3 + r] / m
    for h in range(P):
        mv6(X[h], a_c, b[base + h])


@inlined
def articulated_inverse(Wm, T, nT, Y, WT, K, Z):
    """(T7): ``Y = T (T^T W_m T)^-1 T^T`` (6, 6) for the first ``nT`` columns of
    ``T``, by Cholesky ``K = L L^T`` of ``K = T^T W_m T`` (nT, nT), ``Z = L^-1 T^T``
    (nT, 6) and ``Y = Z^T Z``. Where rounding leaves ``K`` not quite positive
    definite (ill-conditioned trees of thousands of bodies), ``Y = T K^-1 T^T`` by
    Gaussian elimination with pivoting instead; a singular ``K`` gives NaN (the
    caller reports the overflow). ``WT``, ``K``, ``Z`` (6, 6): scratch."""
    for r in range(6):
        for c in range(nT):
            acc = 0.0
            for k in range(6):
                acc += Wm[r, k] * T[k, c]
            WT[r, c] = acc
    reduced_inertia(T, WT, nT, K)
    if cholesky(K, nT):
        for col in range(6):                                    # forward substitution
            for r in range(nT):
                acc = T[col, r]
                for k in range(r):
                    acc -= K[r, k] * Z[k, col]
                Z[r, col] = acc / K[r, r]
        for r in range(6):
            for s in range(r, 6):
                acc = 0.0
                for k in range(nT):
                    acc += Z[k, r] * Z[k, s]
                Y[r, s] = acc
                Y[s, r] = acc
        return
    reduced_inertia(T, WT, nT, K)                              # the factor overwrote it
    for r in range(nT):
        for c in range(6):
            Z[r, c] = T[c, r]
    if not solve_general(K, Z, nT):
        Y[:, :] = np.nan
        return
    for r in range(6):
        for s in range(6):
            acc = 0.0
            for k in range(nT):
                acc += T[r, k] * Z[k, s]
            WT[r, s] = acc
    symmetric_part(WT, Y)


@inlined
def reduced_inertia(T, WT, nT, K):
    """``K = T^T W_m T`` (nT, nT) of (T7) from ``WT = W_m T``: the upper triangle
    computed, the lower one copied from it."""
    for r in range(nT):
        for c in range(r, nT):
            acc = 0.0
            for k in range(6):
                acc += T[k, r] * WT[k, c]
            K[r, c] = acc
            K[c, r] = acc


@inlined
def has_armature(armature, v0, d):
    """Whether a joint's dofs ``v0 .. v0 + d`` carry rotor inertia (A1)-(A2)."""
    for k in range(d):
        if armature[v0 + k] != 0.0:
            return True
    return False


@inlined
def armature_inputs(Wm, Y, W, d, v0, armature, PF_rows, tmp):
    """(A1)-(A2) of ``docs/joints.md`` for a joint with rotor inertia ``Ia =
    armature[v0:v0 + d]`` on its dofs: ``P = W - Y W_m W``, ``F = (1 + Ia P^T W_m
    W)^-1``, ``Y += P F Ia P^T``, with ``(P F)^T`` left in ``PF_rows[v0:v0 + d]``
    (for :func:`joint_beta`). ``tmp`` (>= 5, 6, 6): scratch."""
    WmW, P, M = tmp[1], tmp[2], tmp[3]
    for r in range(6):
        for k in range(6):
            P[r, k] = 0.0
            M[r, k] = 0.0
    mm6(Wm, W, WmW)
    for r in range(6):
        for k in range(d):
            acc = W[r, k]
            for s in range(6):
                acc -= Y[r, s] * WmW[s, k]
            P[r, k] = acc
    F = tmp[4]                                                  # F = M^-1 (d, d)
    for k in range(6):
        for m in range(6):
            F[k, m] = 1.0 if k == m else 0.0
    for k in range(d):
        for m in range(d):
            acc = 0.0
            for s in range(6):
                acc += P[s, k] * WmW[s, m]
            M[k, m] = (1.0 if k == m else 0.0) + armature[v0 + k] * acc
    if not solve_general(M, F, d):
        F[:, :] = np.nan
    PF = WmW                                                    # P F (6, d)
    for r in range(6):
        for m in range(d):
            acc = 0.0
            for k in range(d):
                acc += P[r, k] * F[k, m]
            PF[r, m] = acc
            PF_rows[v0 + m, r] = acc
    for r in range(6):
        for s in range(6):
            acc = 0.0
            for m in range(d):
                acc += PF[r, m] * armature[v0 + m] * P[s, m]
            Y[r, s] += acc
    symmetric_part(Y, Y)


@inlined
def joint_beta(Y, W, WtWm, PF, v0, d, loaded, tau, gamma, beta, t):
    """``beta_C`` (6,) of (T9), ``W tau - Y (W_m W tau + gamma)`` with the joint's
    forces ``tau[v0:v0 + d]`` and ``W_m W = (W^T W_m)^T`` from the rows ``WtWm[v0:v0
    + d]``; for a joint with rotor inertia (``loaded``), (A2): ``P F tau - Y
    gamma`` with ``(P F)^T`` from the rows ``PF[v0:v0 + d]`` and ``Y`` of
    :func:`armature_inputs`. ``t`` (6,): scratch."""
    for r in range(6):                                  # t = W_m W tau + gamma
        acc = gamma[r]
        if not loaded:
            for k in range(d):
                acc += WtWm[v0 + k, r] * tau[v0 + k]
        t[r] = acc
    for r in range(6):
        acc = 0.0
        for s in range(6):
            acc -= Y[r, s] * t[s]
        for k in range(d):
            acc += (PF[v0 + k, r] if loaded else W[r, k]) * tau[v0 + k]
        beta[r] = acc


@inlined
def assemble_node(i, nb, tree, js, kin, tau, armature, Phi, b, Y, WtWm, PF, beta, gamma, G,
                  GY, tmp):
    """Internal node ``C = nb + i``: sub-assemblies ``A`` (``-1``: the ground) and
    ``B`` joined by joint ``j``, theory (T6)-(T12): :func:`joint_node`, then
    :func:`merge_ports`, which keeps ``G_a`` in ``G`` (n_inner_slots, 6, 6). ``GY`` (max
    ports, 6, 6), ``tmp`` (>= 6, 6, 6): scratch; ``GY[a]`` and ``W_m`` (``tmp[5]``)
    are left for callers that need them (the metric coefficients of
    :mod:`vdad.region`)."""
    joint_node(i, nb, tree, js, kin, tau, armature, Phi, b, Y, WtWm, PF, beta, gamma, tmp)
    merge_ports(i, nb, tree, Phi, b, Y, beta, G, GY)


@inlined
def joint_node(i, nb, tree, js, kin, tau, armature, Phi, b, Y, WtWm, PF, beta, gamma, tmp):
    """The joint ``j`` of internal node ``C = nb + i`` across its children's
    blocks, theory (T6)-(T9) with the armature (A1)-(A2): keeps ``Y``, ``beta``,
    ``gamma`` of the node (row ``i``) and ``W^T W_m`` of its joint (rows of its
    dofs) for :func:`solve_node`, ``(P F)^T`` of a joint with armature (rows of its
    dofs) for :func:`joint_rhs`; ``W_m`` is left in ``tmp[5]``. ``tmp`` (>= 6, 6,
    6): scratch."""
    (left, right, joint, port_A, port_B, n_ports, pair_base, slot_base, slot_joint,
     slot_side, slot_child, slot_index, slot_sign, post, segments) = tree
    v_start, nv_joint, subspace = js[6], js[7], js[15]
    T, W, c_J = kin[3], kin[4], kin[8]
    A, B, j = left[i], right[i], joint[i]
    jA, jB = port_A[i], port_B[i]
    d, u = nv_joint[j], subspace[j]
    Wj, Yj, Wmj, bj, gj = W[u], Y[i], tmp[5], beta[i], gamma[i]
    kB, sB = pair_base[B] + pair_offset(n_ports[B], jB, jB), pair_base[B] + jB
    for r in range(6):                                          # (T6), (T8)
        gj[r] = b[sB, r] - c_J[j, r]
        for s in range(6):
            Wmj[r, s] = Phi[kB, r, s]
    if A >= 0:
        kA, sA = pair_base[A] + pair_offset(n_ports[A], jA, jA), pair_base[A] + jA
        for r in range(6):
            gj[r] -= b[sA, r]
            for s in range(6):
                Wmj[r, s] += Phi[kA, r, s]
    Tj, WT, K, Z = T[u], tmp[0], tmp[1], tmp[2]
    if d == 1:                                  # (T7); hinges and slides: sizes known
        articulated_inverse(Wmj, Tj, 5, Yj, WT, K, Z)           # to the compiler, unrolled
    else:
        articulated_inverse(Wmj, Tj, 6 - d, Yj, WT, K, Z)
    v0 = v_start[j]
    for k in range(d):                                  # for (T9), (T13): W^T W_m
        for s in range(6):
            acc = 0.0
            for r in range(6):
                acc += Wj[r, k] * Wmj[r, s]
            WtWm[v0 + k, s] = acc
    loaded = has_armature(armature, v0, d)
    if loaded:
        armature_inputs(Wmj, Yj, Wj, d, v0, armature, PF, tmp)   # (A1)-(A2)
    joint_beta(Yj, Wj, WtWm, PF, v0, d, loaded, tau, gj, bj, tmp[0, 0])   # (T9)


@inlined
def port_blocks(i, nb, tree, Phi, G):
    """``G_a = s_a Phi^X_{a j_X}`` of (T11) for every port ``a`` of internal node
    ``C = nb + i``, kept unsigned in ``G[slot_base[C] + a]`` (6, 6): what the
    top-down pass (T10), (T13) reads of the children's blocks."""
    (left, right, joint, port_A, port_B, n_ports, pair_base, slot_base, slot_joint,
     slot_side, slot_child, slot_index, slot_sign, post, segments) = tree
    A, jA, jB, s0 = left[i], port_A[i], port_B[i], slot_base[nb + i]
    for a in range(n_ports[nb + i]):
        X, ia = slot_child[s0 + a], slot_index[s0 + a]
        copy_block(Phi, pair_base[X], n_ports[X], ia, jA if X == A else jB, G[s0 + a])


@inlined
def merge_ports(i, nb, tree, Phi, b, Y, beta, G, GY):
    """(T11)-(T12) of internal node ``C = nb + i`` over its ports ``a, c`` with
    ``G_a`` of :func:`port_blocks` and ``GY[a] = G_a Y`` (max ports, 6, 6), after
    :func:`joint_node`. A joint of six dofs without
    armature has ``Y = 0`` ((T7) with an empty ``T``), so (T11) gathers the
    children's blocks and skips the products (the free root joint of a floating
    tree, merged with the torso's seven ports: 27 of a dog's 95 merge products)."""
    (left, right, joint, port_A, port_B, n_ports, pair_base, slot_base, slot_joint,
     slot_side, slot_child, slot_index, slot_sign, post, segments) = tree
    C, Yj = nb + i, Y[i]
    P, s0 = n_ports[C], slot_base[C]
    free = is_zero6(Yj)             # a joint of six dofs: (T11) only gathers blocks
    port_blocks(i, nb, tree, Phi, G)
    for a in range(P):
        if free:
            zero6(GY[a])
        else:
            mm6(G[s0 + a], Yj, GY[a])
    port_vectors(i, nb, tree, b, beta[i], G)                     # (T12)
    for a in range(P):                                           # (T11), a <= c
        X, ia = slot_child[s0 + a], slot_index[s0 + a]
        for cc in range(a, P):
            Cac = Phi[pair_base[C] + pair_offset(P, a, cc)]
            if slot_child[s0 + cc] != X:
                zero6(Cac)
            elif cc == a:
                symmetric_part(Phi[pair_base[X] + pair_offset(n_ports[X], ia, ia)], Cac)
            else:
                copy_block(Phi, pair_base[X], n_ports[X], ia, slot_index[s0 + cc], Cac)
            if free:
                continue
            sign = -slot_sign[s0 + a] * slot_sign[s0 + cc]       # - G_a Y G_c^T
            if cc == a:
                mmt6_add_symmetric(GY[a], G[s0 + cc], sign, Cac)
            else:
                mmt6_add(GY[a], G[s0 + cc], sign, Cac)


@inlined
def port_vectors(i, nb, tree, b, beta_C, G):
    """(T12) of internal node ``C = nb + i``: ``b^C_a = b^X_a + G_a beta_C`` for
    every port ``a`` (``G_a`` of :func:`port_blocks`)."""
    (left, right, joint, port_A, port_B, n_ports, pair_base, slot_base, slot_joint,
     slot_side, slot_child, slot_index, slot_sign, post, segments) = tree
    C = nb + i
    s0, k0 = slot_base[C], pair_base[C]
    for a in range(n_ports[C]):
        ba = b[k0 + a]
        for r in range(6):
            ba[r] = b[pair_base[slot_child[s0 + a]] + slot_index[s0 + a], r]
        mv6_add(G[s0 + a], beta_C, slot_sign[s0 + a], ba)


@inlined
def pair_offset(P, a, c):
    """Where a node of ``P`` ports stores its block ``Phi_ac``, ``a <= c``, after
    its first (``pair_base``): row by row of the upper triangle."""
    return a * P - a * (a - 1) // 2 + c - a


@inlined
def copy_block(Phi, base, P, a, c, out):
    """``out = Phi_ac`` (6, 6) of the node whose blocks start at ``base``, from
    ``Phi_ca^T`` where ``a > c``."""
    if a <= c:
        B = Phi[base + pair_offset(P, a, c)]
        for r in range(6):
            for s in range(6):
                out[r, s] = B[r, s]
    else:
        B = Phi[base + pair_offset(P, c, a)]
        for r in range(6):
            for s in range(6):
                out[r, s] = B[s, r]


@inlined
def solve_node(i, nb, tree, js, kin, armature, tau, G, Y, WtWm, PF, beta, gamma, f_J, qdd,
               tmp):
    """Joint ``j`` of internal node ``C = nb + i`` given the wrenches ``f_a`` on
    ``C``'s ports (from joints solved before it) and ``G_a`` of its ports
    (:func:`port_blocks`): ``u = sum_a G_a^T f_a``,
    ``f_J = beta_C - Y u`` (T10), ``qdd = W^T (W_m f_J + u + gamma)`` (T13); for a
    joint with rotor inertia, ``qdd = (E F) tau + (P F)^T (u + gamma)`` (A3) of
    ``docs/joints.md``, with ``E F = W^T W_m (P F)`` from the rows ``WtWm`` and
    ``PF`` that :func:`joint_node` kept and the joint forces ``tau`` it took.
    ``tmp`` (>= 2, 6, 6): scratch."""
    (left, right, joint, port_A, port_B, n_ports, pair_base, slot_base, slot_joint,
     slot_side, slot_child, slot_index, slot_sign, post, segments) = tree
    v_start, nv_joint, subspace = js[6], js[7], js[15]
    W = kin[4]
    C, j = nb + i, joint[i]
    u, t = tmp[0, 0], tmp[0, 1]
    for r in range(6):
        u[r] = 0.0
    s0 = slot_base[C]
    for a in range(n_ports[C]):                        # u += s_a Phi^X_{a j_X}^T f_a
        f_a, s = f_J[slot_joint[s0 + a]], slot_sign[s0 + a] * slot_side[s0 + a]
        mtv6_add(G[s0 + a], f_a, s, u)                 # f_a = side f_J
    fJ = f_J[j]
    mv6(Y[i], u, t)                                              # (T10)
    for r in range(6):
        fJ[r] = beta[i, r] - t[r]
    v0, d = v_start[j], nv_joint[j]
    if has_armature(armature, v0, d):                            # (A3)
        for k in range(d):
            acc = 0.0
            for r in range(6):
                acc += PF[v0 + k, r] * (u[r] + gamma[i, r])
            for m in range(d):
                EF = 0.0
                for r in range(6):
                    EF += WtWm[v0 + k, r] * PF[v0 + m, r]
                acc += EF * tau[v0 + m]
            qdd[v0 + k] = acc
        return
    Wj = W[subspace[j]]                                          # (T13)
    for k in range(d):
        acc = 0.0
        for r in range(6):
            acc += WtWm[v0 + k, r] * fJ[r] + Wj[r, k] * (u[r] + gamma[i, r])
        qdd[v0 + k] = acc


# --- refinement (docs/accuracy.md) ------------------------------------------------------

@inlined
def joint_rhs(i, nb, tree, js, kin, armature, tau, b, Y, WtWm, PF, beta, gamma, velocity, t):
    """(T8)-(T9) of internal node ``C = nb + i`` from what :func:`joint_node` kept at
    this configuration (``W^T W_m``, ``(P F)^T``, ``Y``): ``gamma = b^B_jB - c_J -
    b^A_jA`` and ``beta_C`` by :func:`joint_beta`; without ``velocity``, for joint
    forces ``tau`` alone (no ``c_J``; the leaves' ``b`` without known wrenches).
    ``t`` (6,): scratch."""
    (left, right, joint, port_A, port_B, n_ports, pair_base, slot_base, slot_joint,
     slot_side, slot_child, slot_index, slot_sign, post, segments) = tree
    v_start, nv_joint, subspace, c_J = js[6], js[7], js[15], kin[8]
    A, B, j = left[i], right[i], joint[i]
    v0, d, Wj, gj = v_start[j], nv_joint[j], kin[4][subspace[j]], gamma[i]
    for r in range(6):                                  # (T8)
        gj[r] = b[pair_base[B] + port_B[i], r] - (c_J[j, r] if velocity else 0.0)
        if A >= 0:
            gj[r] -= b[pair_base[A] + port_A[i], r]
    joint_beta(Y[i], Wj, WtWm, PF, v0, d, has_armature(armature, v0, d), tau, gj, beta[i], t)


@inlined
def node_vectors(i, nb, tree, js, kin, armature, tau, b, Y, WtWm, PF, beta, gamma, G, velocity,
                 t):
    """The vector parts of :func:`assemble_node` for internal node ``C = nb + i`` at
    the configuration of its last assembly, whose ``Y``, ``W^T W_m``, ``(P F)^T``
    and ``G_a`` they reuse ((T7), (T10)-(T11) depend on the configuration alone):
    (T8)-(T9) by :func:`joint_rhs`, (T12) by :func:`port_vectors`. ``t`` (6,):
    scratch."""
    joint_rhs(i, nb, tree, js, kin, armature, tau, b, Y, WtWm, PF, beta, gamma, velocity, t)
    port_vectors(i, nb, tree, b, beta[i], G)                     # (T12)


@pass_kernel
def rhs_passes(nb, js, tree, kin, armature, tau, G, b, Y, WtWm, PF, beta, gamma, f_J, qdd,
               tmp, order, n, assembled):
    """``qdd = M^-1 tau`` by the DCA at the configuration of its last evaluation,
    whose ``G_a``, ``Y``, ``W^T W_m``, ``(P F)^T`` it reuses: the vector parts
    alone ((R3) of ``docs/accuracy.md``), leaves without known wrenches, by
    :func:`node_vectors` without velocity, then :func:`solve_node`;
    over the nodes ``order[:n]`` in depth-first post-order, of which the internal
    nodes marked in ``assembled`` (every internal node where it is empty) were
    assembled and the others are leaves (on adaptive dynamics' region: its hybrid,
    ``M_AA`` of the active joints' dofs)."""
    n_ports, pair_base = tree[5], tree[6]
    for k in range(n):
        node = order[k]
        if not (node >= nb and (assembled.shape[0] == 0 or assembled[node])):
            for a in range(n_ports[node]):
                for r in range(6):
                    b[pair_base[node] + a, r] = 0.0
            continue
        node_vectors(node - nb, nb, tree, js, kin, armature, tau, b, Y, WtWm, PF, beta, gamma,
                     G, False, tmp[7, 2])
    for k in range(n - 1, -1, -1):
        node = order[k]
        if node >= nb and (assembled.shape[0] == 0 or assembled[node]):
            solve_node(node - nb, nb, tree, js, kin, armature, tau, G, Y, WtWm, PF, beta,
                       gamma, f_J, qdd, tmp)


@pass_kernel
def refine_pass(js, tree, bodies, f_ext, kin, work, mode, rhs):
    """(R1)-(R3) of ``docs/accuracy.md``: the accelerations ``qdd`` (in ``work``) of
    a DCA evaluation whose leaves were raised (:func:`leaf_inertias`), refined by
    preconditioned conjugate gradients on ``ID(qdd) = rhs``, ``ID`` Newton-Euler
    with the model's own inertias in ``mode``
    (:func:`~vdad.newton_euler.inverse_dynamics_pass`;
    :data:`~vdad.newton_euler.FULL` with the joint forces for ``rhs``: the dynamics;
    :data:`~vdad.newton_euler.MASS`: ``M qdd = rhs``), with the DCA's solve
    on the raised leaves (:func:`rhs_passes`) as preconditioner; at most
    ``bodies[12]`` steps, until the preconditioned residual is below ``4 eps`` of
    the largest acceleration. The joint wrenches ``f_J`` are those of the
    result (Newton-Euler's, linear in ``qdd``). With ``bodies[12]`` =
    :data:`ONE_STEP` (``M' = M``, (R4)): the first correction alone, ``f_J``
    Newton-Euler's before it (the correction is of the DCA's rounding)."""
    Phi, b, Y, WtWm, beta, gamma, f_J, qdd, tau, X, GY, tmp, PF, a, f, cg, G = work
    nb, armature, steps = bodies[0].shape[0], bodies[11], bodies[12]
    x, r, z, p, Ap = cg[0], cg[1], cg[2], cg[3], cg[4]
    w, nv = tmp[7], qdd.shape[0]
    for i in range(nv):
        x[i] = qdd[i]
    inverse_dynamics_pass(js, bodies, kin, f_ext, x, mode, a, f, w, r)
    for i in range(nv):                                       # r = rhs - ID(x)
        r[i] = rhs[i] - r[i]
    for j in range(nb):                                       # f_J: Newton-Euler's of x
        for s in range(6):
            f_J[j, s] = f[j, s]
    post = tree[13]
    rhs_passes(nb, js, tree, kin, armature, r, G, b, Y, WtWm, PF, beta, gamma, f, z, tmp, post,
               post.shape[0], ALL)
    if steps == ONE_STEP:
        for i in range(nv):
            qdd[i] = x[i] + z[i]
        return
    rz = 0.0
    for i in range(nv):
        p[i] = z[i]
        rz += r[i] * z[i]
    for _ in range(steps):
        change, size = 0.0, 0.0
        for i in range(nv):
            change = max(change, abs(z[i]))
            size = max(size, abs(x[i]))
        if not change > 4.0 * EPS * size:
            break
        inverse_dynamics_pass(js, bodies, kin, f_ext, p, MASS, a, f, w, Ap)
        pAp = 0.0
        for i in range(nv):
            pAp += p[i] * Ap[i]
        if not pAp > 0.0:
            break
        alpha = rz / pAp
        for i in range(nv):
            x[i] += alpha * p[i]
            r[i] -= alpha * Ap[i]
        for j in range(nb):
            for s in range(6):
                f_J[j, s] += alpha * f[j, s]
        rhs_passes(nb, js, tree, kin, armature, r, G, b, Y, WtWm, PF, beta, gamma, f, z,
                   tmp, post, post.shape[0], ALL)
        rz_next = 0.0
        for i in range(nv):
            rz_next += r[i] * z[i]
        for i in range(nv):
            p[i] = z[i] + (rz_next / rz) * p[i]
        rz = rz_next
    for i in range(nv):
        qdd[i] = x[i]


@pass_kernel
def subtree_passes(lo, hi, nb, js, tree, bodies, f_ext, kin, tau, Phi, b, Y, WtWm, PF, beta,
                   gamma, f_J, qdd, G, X, GY, tmp):
    """The DCA of one root's subtree, ``post[lo:hi]``: the leaves and the
    bottom-up pass node by node in depth-first post-order, then the top-down pass
    in the reverse order (its root has no ports: subtrees are independent)."""
    post = tree[13]
    for k in range(lo, hi):                     # depth first: a subtree stays in cache
        n = post[k]
        if n < nb:
            leaf(n, tree, bodies, f_ext, kin, Phi, b, X, GY, tmp)
        else:
            assemble_node(n - nb, nb, tree, js, kin, tau, bodies[11], Phi, b, Y, WtWm, PF, beta,
                          gamma, G, GY, tmp)
    for k in range(hi - 1, lo - 1, -1):
        n = post[k]
        if n >= nb:
            solve_node(n - nb, nb, tree, js, kin, bodies[11], tau, G, Y, WtWm, PF, beta, gamma,
                       f_J, qdd, tmp)


#: forests of at least this many bodies run their trees' subtrees in parallel
PARALLEL_BODIES = 256


@inlined
def in_parallel(nb, segments):
    """Whether a forest of ``nb`` bodies whose root subtrees start at
    ``segments`` (roots + 1,) runs them on numba's threads: two roots or more and
    :data:`PARALLEL_BODIES` bodies."""
    return segments.shape[0] > 2 and nb >= PARALLEL_BODIES


@parallel_kernel
def forest_passes(js, tree, bodies, f_ext, kin, tau, Phi, b, Y, WtWm, PF, beta, gamma, f_J, qdd,
                  G, P):
    """:func:`subtree_passes` of every root's subtree of a forest, in parallel
    (numba threads): each writes only its own nodes' blocks, joints and dofs, and
    takes its own scratch (``P``: the most ports of a node)."""
    nb, segments = bodies[0].shape[0], tree[14]
    for r in prange(segments.shape[0] - 1):
        X, GY, tmp = np.empty((P, 6, 6)), np.empty((P, 6, 6)), np.empty((8, 6, 6))
        subtree_passes(segments[r], segments[r + 1], nb, js, tree, bodies, f_ext, kin, tau,
                       Phi, b, Y, WtWm, PF, beta, gamma, f_J, qdd, G, X, GY, tmp)


@kernel
def dynamics_pass(js, tree, bodies, q, qd, tau_in, f_ext, kin, work):
    """The DCA on kinematics ``kin`` already computed for ``(q, qd)``: joint forces
    ``tau = tau_in - D qd - K d``, then :func:`subtree_passes` of each root's
    subtree (in parallel for forests of :data:`PARALLEL_BODIES` bodies or more),
    and :func:`refine_pass` where the model has raised leaves; ``qdd`` ends in
    ``work``."""
    Phi, b, Y, WtWm, beta, gamma, f_J, qdd, tau, X, GY, tmp, PF, a, f, cg, G = work
    passive_forces_pass(bodies[5], bodies[6], bodies[7], bodies[8], bodies[9], bodies[10],
                        q, qd, tau)
    for r in range(tau_in.shape[0]):
        tau[r] += tau_in[r]
    nb, segments = bodies[0].shape[0], tree[14]
    if in_parallel(nb, segments):
        forest_passes(js, tree, bodies, f_ext, kin, tau, Phi, b, Y, WtWm, PF, beta, gamma, f_J,
                      qdd, G, X.shape[0])
    else:
        for r in range(segments.shape[0] - 1):
            subtree_passes(segments[r], segments[r + 1], nb, js, tree, bodies, f_ext, kin, tau,
                           Phi, b, Y, WtWm, PF, beta, gamma, f_J, qdd, G, X, GY, tmp)
    if bodies[12] != 0 and finite(qdd):
        refine_pass(js, tree, bodies, f_ext, kin, work, FULL, tau)


@pass_kernel
def dca_pass(js, tree, bodies, q, qd, tau_in, f_ext, kin, work):
    """One DCA evaluation: the kinematics of ``(q, qd)`` (theory §3), then
    :func:`dynamics_pass`. Returns whether the inputs and ``qdd`` are all finite
    (the callers' checks, at no cost)."""
    kinematics_pass(js, q, qd, True, *kin)
    return dynamics_checked(js, tree, bodies, q, qd, tau_in, f_ext, kin, work, f_ext)


@inlined
def dynamics_checked(js, tree, bodies, q, qd, tau_in, f_ext, kin, work, given):
    """:func:`dynamics_pass`; whether ``q``, ``qd``, ``tau_in``, the wrenches
    ``given`` by the caller and ``qdd`` are all finite."""
    dynamics_pass(js, tree, bodies, q, qd, tau_in, f_ext, kin, work)
    return finite(q) and finite(qd) and finite(tau_in) and finite(given) and finite(work[7])


@kernel
def dca_call(constants, q, qd, tau_in, f_ext):
    """:func:`dca_pass` with its constant arguments ``(js, tree, bodies, kin,
    work)`` from the :class:`~vdad._pack.Pack` ``constants`` (:func:`packed`): a
    call from Python then converts five arguments instead of 81 (``vdad._pack``).
    Of a welded model (:func:`welded`; the pack's ``host``, ``lever`` and scratch
    ``f_welded`` not empty), the external wrenches ``f_ext`` of the model's
    bodies are gathered onto the welded bodies once their poses are known
    (:func:`gather_wrenches`)."""
    js, tree, bodies, kin, work, host, lever, f_welded = constants.data
    if host.shape[0] == 0 or f_ext.shape[0] == 0:
        return dca_pass(js, tree, bodies, q, qd, tau_in, f_ext, kin, work)
    kinematics_pass(js, q, qd, True, *kin)
    gather_wrenches(host, lever, kin[5], f_ext, f_welded)
    return dynamics_checked(js, tree, bodies, q, qd, tau_in, f_welded, kin, work, f_ext)


@inlined
def gather_wrenches(host, lever, R, f_ext, out):
    """The external wrenches ``f_ext`` (nb, 6; torque about each body's centre of
    mass, force; world axes) of a model's bodies as wrenches ``out`` (nh, 6) on
    the bodies of its welded model (:func:`welded`): body ``b``'s on ``host[b]``,
    its torque moved to the host's centre of mass, ``tau + d x f`` with ``d``
    the lever ``lever[b]`` (3,; host axes) turned by the host's orientation ``R``
    (nh, 3, 3)."""
    for h in range(out.shape[0]):
        for r in range(6):
            out[h, r] = 0.0
    for b in range(f_ext.shape[0]):
        h, Rh, c = host[b], R[host[b]], lever[b]
        d0 = Rh[0, 0] * c[0] + Rh[0, 1] * c[1] + Rh[0, 2] * c[2]
        d1 = Rh[1, 0] * c[0] + Rh[1, 1] * c[1] + Rh[1, 2] * c[2]
        d2 = Rh[2, 0] * c[0] + Rh[2, 1] * c[1] + Rh[2, 2] * c[2]
        f0, f1, f2 = f_ext[b, 3], f_ext[b, 4], f_ext[b, 5]
        out[h, 0] += f_ext[b, 0] + d1 * f2 - d2 * f1
        out[h, 1] += f_ext[b, 1] + d2 * f0 - d0 * f2
        out[h, 2] += f_ext[b, 2] + d0 * f1 - d1 * f0
        out[h, 3] += f0
        out[h, 4] += f1
        out[h, 5] += f2


class Welds(NamedTuple):
    """A model whose bodies on fixed joints are welded into their parents
    (:func:`welded`), and where each of the model's bodies went."""

    model: object          # the welded Model: no fixed joint below a body
    host: np.ndarray       # (nb,) the welded body that holds each body
    lever: np.ndarray      # (nb, 3) each body's centre of mass from its host's, host axes


@lru_cache(maxsize=64)
def welded(model):
    """``model`` with every body on a fixed joint below another body welded into
    that body, as :class:`Welds` (None if it has no such joint): the host takes
    the bodies' composite mass, centre of mass and inertia, and the joints below
    a welded body hang from its host, placed through the weld. The dofs, their
    order, the joints' springs and dampers are those of ``model``, so the DCA of
    the welded model is ``model``'s forward dynamics, with fewer leaves and
    no six-constraint merges (``docs/design.md``, "Welds"); the external wrenches
    move by :func:`gather_wrenches`."""
    fixed = [j for j in range(model.nb)
             if model.joints[j].kind == "fixed" and model.parent[j] >= 0]
    if not fixed:
        return None
    host, R, p = np.arange(model.nb), np.tile(np.eye(3), (model.nb, 1, 1)), np.zeros((model.nb, 3))
    for j in fixed:                     # parents first: a chain of welds ends at its host
        b = model.parent[j]
        host[j] = host[b]
        R[j] = R[b] @ model.placement_R[j]
        p[j] = R[b] @ model.placement_p[j] + p[b]
    com = np.einsum("bij,bj->bi", R, model.com) + p                   # host axes
    hosts = np.unique(host)
    mass = np.zeros(model.nb)
    np.add.at(mass, host, model.mass)
    centre = np.zeros((model.nb, 3))
    np.add.at(centre, host, model.mass[:, None] * com)
    centre[hosts] /= mass[hosts, None]
    lever = com - centre[host]
    inertia = np.zeros((model.nb, 3, 3))
    turned = np.einsum("bij,bjk,blk->bil", R, model.inertia, R)
    np.add.at(inertia, host, turned + model.mass[:, None, None] * (
        np.einsum("bi,bi->b", lever, lever)[:, None, None] * np.eye(3)
        - np.einsum("bi,bj->bij", lever, lever)))
    bodies = [replace(model.bodies[h], mass=float(mass[h]), com=tuple(centre[h].tolist()),
                      inertia=0.5 * (inertia[h] + inertia[h].T)) for h in hosts]
    joints = []
    for j in hosts:
        jt, b = model.joints[j], model.parent[j]
        if b >= 0 and host[b] != b:                     # hangs from a welded body
            jt = replace(jt, parent=model.body_names[host[b]], placement=Pose(
                tuple((R[b] @ model.placement_p[j] + p[b]).tolist()),
                R[b] @ model.placement_R[j]))
        joints.append(jt)
    welds = Model(bodies, joints, gravity=model.gravity, q_spring=model.q_spring,
                  name=model.name)
    index = np.zeros(model.nb, int)
    index[hosts] = np.arange(len(hosts))
    return Welds(welds, index[host], lever)


def packed(model, data, welds=None):
    """The constant arguments of :func:`dca_pass` on ``model`` into ``data`` (a
    :class:`DCAData` of a tree of ``model``), packed once for :func:`dca_call`;
    with ``welds`` (:func:`welded`, whose ``model`` is then ``model``), what
    :func:`gather_wrenches` needs."""
    if data.packed is None:
        weld = ((np.zeros(0, np.int64), np.zeros((0, 3)), np.zeros((0, 6))) if welds is None
                else (welds.host, welds.lever, np.zeros((model.nb, 6))))
        data.packed = pack((plan(model).arrays, data.layout, body_arrays(model),
                            data.kin.arrays, data.arrays, *weld))
    return data.packed
