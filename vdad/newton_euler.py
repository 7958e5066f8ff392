"""Inverse dynamics and momenta, one joint at a time (``docs/accuracy.md``).

The recursive Newton-Euler algorithm in compiled form: body accelerations
parents first, then the wrenches each joint transmits children first. It works
with inertias, never their inverses, so its error follows the mechanics; the DCA
uses it to refine its accelerations on models with thin bodies or point masses
((R1)-(R3) of ``docs/accuracy.md``, :func:`vdad.dca.refine_pass`), and the
symplectic integrator for momenta and ``dT/dq`` ((S1)-(S3)).

Frames as in :mod:`vdad.kinematics`: body ``j`` is the child frame of joint
``j``; accelerations and velocities in body axes at the body origin; the known
wrench of a body at its centre of mass, body axes (:func:`known_wrench`).
"""

from __future__ import annotations

from ._linalg import inlined, motion_to_child, pass_kernel


@inlined
def known_wrench(m, c, I, v, R, gravity, f):
    """The known wrench (6,) on a rigid body of mass ``m``, centre of mass ``c``
    and inertia ``I`` about it, moving with ``v`` (its frame's velocity, at its
    origin, body axes) at orientation ``R``: gravity minus the bias of (T3), at the
    centre of mass, body axes: ``(-w × I w; m R^T g - m w × v_c)``."""
    w = v[:3]
    vc0 = v[3] + w[1] * c[2] - w[2] * c[1]
    vc1 = v[4] + w[2] * c[0] - w[0] * c[2]
    vc2 = v[5] + w[0] * c[1] - w[1] * c[0]
    Iw0 = I[0, 0] * w[0] + I[0, 1] * w[1] + I[0, 2] * w[2]
    Iw1 = I[1, 0] * w[0] + I[1, 1] * w[1] + I[1, 2] * w[2]
    Iw2 = I[2, 0] * w[0] + I[2, 1] * w[1] + I[2, 2] * w[2]
    f[0] = -(w[1] * Iw2 - w[2] * Iw1)
    f[1] = -(w[2] * Iw0 - w[0] * Iw2)
    f[2] = -(w[0] * Iw1 - w[1] * Iw0)
    f[3] = -m * (w[1] * vc2 - w[2] * vc1)
    f[4] = -m * (w[2] * vc0 - w[0] * vc2)
    f[5] = -m * (w[0] * vc1 - w[1] * vc0)
    for r in range(3):
        f[3 + r] += m * (R[0, r] * gravity[0] + R[1, r] * gravity[1] + R[2, r] * gravity[2])


@inlined
def body_wrench(i, bodies, f_ext, v, R, f):
    """The known wrench (6,) on body ``i`` at its centre of mass, body axes:
    :func:`known_wrench` at velocity ``v`` (6,) plus ``f_ext[i]`` (world axes, at
    the centre of mass; none if ``f_ext`` is empty). ``R`` (3, 3): its orientation."""
    known_wrench(bodies[0][i], bodies[1][i], bodies[2][i], v, R, bodies[4], f)
    if f_ext.shape[0] > 0:                                       # world axes -> body axes
        for r in range(3):
            f[r] += R[0, r] * f_ext[i, 0] + R[1, r] * f_ext[i, 1] + R[2, r] * f_ext[i, 2]
            f[3 + r] += R[0, r] * f_ext[i, 3] + R[1, r] * f_ext[i, 4] + R[2, r] * f_ext[i, 5]


@inlined
def spatial_momentum(m, c, I, a, h):
    """``h = I_o a`` (6,): the rigid body's inertia about its origin (mass ``m``,
    centre of mass ``c``, inertia ``I`` about it, body axes) times the motion
    ``a`` (6,) at the origin: ``(I a_w + m c × a_c; m a_c)``, ``a_c = a_v + a_w × c``."""
    w0, w1, w2 = a[0], a[1], a[2]
    l0 = m * (a[3] + w1 * c[2] - w2 * c[1])
    l1 = m * (a[4] + w2 * c[0] - w0 * c[2])
    l2 = m * (a[5] + w0 * c[1] - w1 * c[0])
    for r in range(3):
        h[r] = I[r, 0] * w0 + I[r, 1] * w1 + I[r, 2] * w2
    h[0] += c[1] * l2 - c[2] * l1
    h[1] += c[2] * l0 - c[0] * l2
    h[2] += c[0] * l1 - c[1] * l0
    h[3], h[4], h[5] = l0, l1, l2


@inlined
def force_to_parent_add(R, p, f, out):
    """``out += X^* f`` (6,): the force ``f`` in a child frame at pose ``(R, p)``
    in its parent's, seen in the parent frame: ``(R n + p × R F; R F)``."""
    F0 = R[0, 0] * f[3] + R[0, 1] * f[4] + R[0, 2] * f[5]
    F1 = R[1, 0] * f[3] + R[1, 1] * f[4] + R[1, 2] * f[5]
    F2 = R[2, 0] * f[3] + R[2, 1] * f[4] + R[2, 2] * f[5]
    for r in range(3):
        out[r] += R[r, 0] * f[0] + R[r, 1] * f[1] + R[r, 2] * f[2]
    out[0] += p[1] * F2 - p[2] * F1
    out[1] += p[2] * F0 - p[0] * F2
    out[2] += p[0] * F1 - p[1] * F0
    out[3] += F0
    out[4] += F1
    out[5] += F2


#: modes of :func:`inverse_dynamics_pass`: ``M x`` alone; with the velocity products
#: and the applied wrenches (gravity, ``f_ext``); with the applied wrenches only
MASS, FULL, APPLIED = 0, 1, 2


@pass_kernel
def inverse_dynamics_pass(js, bodies, kin, f_ext, x, mode, a, f, w, out):
    """Joint forces (nv,) by Newton-Euler ((R1) of ``docs/accuracy.md``) for joint
    accelerations ``x`` at the state of ``kin``: with ``mode`` :data:`FULL`, those
    that give the accelerations ``x`` under gravity and ``f_ext`` (``M x + C qd -
    Q``: the velocity products ``c_J``, the known wrenches of :func:`body_wrench`);
    :data:`MASS`: ``M x`` alone (armature included); :data:`APPLIED`: ``M x - Q``,
    the applied wrenches without the velocity products. Body accelerations ``a``
    and the wrenches that joints transmit to their children ``f`` (nb, 6), body
    axes at body origins, are left in the arrays given: with :data:`MASS` and ``x =
    qd``, ``a`` holds the body velocities and ``f`` the momenta of the subtrees
    (S1). ``w`` (2, 6): scratch."""
    order, parent = js[0], js[1]
    mass, com, inertia = bodies[0], bodies[1], bodies[2]
    R, v = kin[5], kin[7]
    wrench, rest = w[0], w[1]
    for r in range(6):
        rest[r] = 0.0
    k = order.shape[0]
    for idx in range(k):                                         # parents first
        j = order[idx]
        body_motion(j, parent[j], js, kin, x, mode == FULL, a)
        spatial_momentum(mass[j], com[j], inertia[j], a[j], f[j])    # I_o a
        if mode != MASS:                          # minus the known wrench, at the origin
            body_wrench(j, bodies, f_ext, v[j] if mode == FULL else rest, R[j], wrench)
            subtract_at_origin(com[j], wrench, f[j])
    for idx in range(k - 1, -1, -1):                             # children first
        j = order[idx]
        joint_force(j, parent[j], js, kin, bodies[11], x, f, out)


@inlined
def body_motion(j, pj, js, kin, x, bias, a):
    """``a_j = X a_p + S x_j`` (+ ``c_J`` with ``bias``): the acceleration (6,) of
    joint ``j``'s child body, body axes at its origin, from that of its parent
    body ``pj`` (-1: the world, at rest) across ``j`` (``kin``'s pose of ``j`` in
    ``pj``'s frame)."""
    v_start, nv_joint, subspace = js[6], js[7], js[15]
    R_rel, p_rel, c_J = kin[0], kin[1], kin[8]
    Sj, v0, aj = kin[2][subspace[j]], v_start[j], a[j]
    if pj >= 0:
        motion_to_child(R_rel[j], p_rel[j], a[pj], aj)
    for r in range(6):
        acc = aj[r] if pj >= 0 else 0.0
        if bias:
            acc += c_J[j, r]
        for col in range(nv_joint[j]):
            acc += Sj[r, col] * x[v0 + col]
        aj[r] = acc


@inlined
def subtract_at_origin(c, wrench, fj):
    """``fj -= wrench`` (6,), the wrench given at the centre of mass ``c`` moved to
    the body origin."""
    fj[0] -= wrench[0] + c[1] * wrench[5] - c[2] * wrench[4]
    fj[1] -= wrench[1] + c[2] * wrench[3] - c[0] * wrench[5]
    fj[2] -= wrench[2] + c[0] * wrench[4] - c[1] * wrench[3]
    for r in range(3, 6):
        fj[r] -= wrench[r]


@inlined
def joint_force(j, pj, js, kin, armature, x, f, out):
    """Joint ``j``'s forces ``out`` (its dofs) ``S^T f_j + I_a x`` from the wrench
    ``f_j`` its child body's subtree needs (body axes at its origin), which is
    then added to its parent body ``pj``'s (none for the world)."""
    v_start, nv_joint, subspace = js[6], js[7], js[15]
    Sj, v0 = kin[2][subspace[j]], v_start[j]
    for col in range(nv_joint[j]):
        acc = armature[v0 + col] * x[v0 + col]
        for r in range(6):
            acc += Sj[r, col] * f[j, r]
        out[v0 + col] = acc
    if pj >= 0:
        force_to_parent_add(kin[0][j], kin[1][j], f[j], f[pj])


@pass_kernel
def kinetic_gradient_pass(js, S, v, H, x, out):
    """``dT/dq`` (nv,) at joint velocities ``x`` ((S2) of ``docs/accuracy.md``), for
    joints of hinge and slide stages: ``-s^T crf(w) H_j`` for the stage of each
    column ``s`` of ``S_j``, with ``H_j`` the momentum of joint ``j``'s subtree and
    ``w = v_j - sum of S_k x_k`` over that stage and the later ones, the motion of
    the frame before the stage; ``v``, ``H`` (nb, 6) as :func:`inverse_dynamics_pass`
    leaves them (mode :data:`MASS`, ``x``), in child frames."""
    order, v_start, nv_joint, subspace = js[0], js[6], js[7], js[15]
    for idx in range(order.shape[0]):
        j = order[idx]
        Sj, v0, Hj = S[subspace[j]], v_start[j], H[j]
        w0, w1, w2, u0, u1, u2 = v[j, 0], v[j, 1], v[j, 2], v[j, 3], v[j, 4], v[j, 5]
        n0, n1, n2, F0, F1, F2 = Hj[0], Hj[1], Hj[2], Hj[3], Hj[4], Hj[5]
        for col in range(nv_joint[j] - 1, -1, -1):
            xc = x[v0 + col]
            w0 -= Sj[0, col] * xc
            w1 -= Sj[1, col] * xc
            w2 -= Sj[2, col] * xc
            u0 -= Sj[3, col] * xc
            u1 -= Sj[4, col] * xc
            u2 -= Sj[5, col] * xc
            c0 = w1 * n2 - w2 * n1 + u1 * F2 - u2 * F1        # crf(w) H = (w × n + u × F;
            c1 = w2 * n0 - w0 * n2 + u2 * F0 - u0 * F2        #             w × F)
            c2 = w0 * n1 - w1 * n0 + u0 * F1 - u1 * F0
            c3 = w1 * F2 - w2 * F1
            c4 = w2 * F0 - w0 * F2
            c5 = w0 * F1 - w1 * F0
            out[v0 + col] = -(Sj[0, col] * c0 + Sj[1, col] * c1 + Sj[2, col] * c2
                              + Sj[3, col] * c3 + Sj[4, col] * c4 + Sj[5, col] * c5)
