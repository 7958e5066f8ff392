"""Time integration of ``(q, qd)`` on the joint manifolds.

``integrate_configuration`` maps a velocity over ``dt`` onto ``q``: hinges,
slides and translations add ``qd dt``; ball stages (body-frame angular
velocity) right-multiply their quaternion by ``exp(w dt)`` and renormalise, as
MuJoCo's ``mj_integratePos``. The integrators take ``accel(t, q, qd) -> qdd``;
:func:`rk4` integrates quaternions in their embedding (see there). The stage
kernels are compiled; :func:`dca_steps` runs whole steps of the DCA in compiled
code (what :meth:`vdad.Simulator.step` uses when no Python callable is involved).
"""

from __future__ import annotations

import numpy as np

from ._linalg import as_input, finite, inlined, kernel, pass_kernel, quaternion_step
from .dca import ALL, dynamics_pass, passive_forces_pass, refine_pass, rhs_passes
from .errors import InputError
from .forces import body_forces
from .kinematics import as_joint_set, kinematics_pass
from .newton_euler import APPLIED, MASS, inverse_dynamics_pass, kinetic_gradient_pass


@inlined
def configuration_step(stage_kind, stage_q, stage_v, q, v, dt, out):
    """``out = q ⊕ v dt`` (nq,) stage by stage (:func:`stage_step`)."""
    for s in range(stage_kind.shape[0]):
        stage_step(s, stage_kind, stage_q, stage_v, q, v, dt, out)


@inlined
def stage_step(s, stage_kind, stage_q, stage_v, q, v, dt, out):
    """Stage ``s`` of ``out = q ⊕ v dt``: ``q + v dt`` on linear stages, ``q ⊗
    exp(w dt)`` on balls; ``out`` may be ``q``."""
    kind, iq, iv = stage_kind[s], stage_q[s], stage_v[s]
    if kind == 2:
        quaternion_step(q[iq:iq + 4], v[iv:iv + 3], dt, out[iq:iq + 4])
    else:
        for c in range(3 if kind == 3 else 1):
            out[iq + c] = q[iq + c] + v[iv + c] * dt


@inlined
def configuration_rate_of(stage_kind, stage_q, stage_v, q, v, out):
    """``out = dq/dt`` (nq,) stage by stage (:func:`stage_rate`)."""
    for s in range(stage_kind.shape[0]):
        stage_rate(s, stage_kind, stage_q, stage_v, q, v, out)


@inlined
def stage_rate(s, stage_kind, stage_q, stage_v, q, v, out):
    """Stage ``s`` of ``dq/dt``: ``v`` on linear stages, ``1/2 q ⊗ (0, w)`` on balls."""
    kind, iq, iv = stage_kind[s], stage_q[s], stage_v[s]
    if kind == 2:
        w, x, y, z = q[iq], q[iq + 1], q[iq + 2], q[iq + 3]
        a, b, c = v[iv], v[iv + 1], v[iv + 2]
        out[iq] = 0.5 * (-x * a - y * b - z * c)
        out[iq + 1] = 0.5 * (w * a + y * c - z * b)
        out[iq + 2] = 0.5 * (w * b - x * c + z * a)
        out[iq + 3] = 0.5 * (w * c + x * b - y * a)
    else:
        for c in range(3 if kind == 3 else 1):
            out[iq + c] = v[iv + c]


@inlined
def normalize_quaternions(stage_kind, stage_q, q):
    """Every ball stage's quaternion of ``q`` divided by its norm, in place."""
    for s in range(stage_kind.shape[0]):
        normalize_stage(s, stage_kind, stage_q, q)


@inlined
def stage_nq(kind):
    """Configuration coordinates of a stage of ``kind`` (:data:`vdad.joints.STAGE_NQ`)."""
    return 4 if kind == 2 else (3 if kind == 3 else 1)


@inlined
def normalize_stage(s, stage_kind, stage_q, q):
    """The quaternion of stage ``s`` divided by its norm, in place, if it is a ball."""
    if stage_kind[s] == 2:
        iq = stage_q[s]
        n = np.sqrt(q[iq] ** 2 + q[iq + 1] ** 2 + q[iq + 2] ** 2 + q[iq + 3] ** 2)
        for c in range(4):
            q[iq + c] /= n


def integrate_configuration(space, q, v, dt):
    """``q ⊕ v dt`` (nq,): the configuration reached by velocity ``v`` in ``dt``.

    ``space``: a model, or a :class:`~vdad.kinematics.JointSet` whose local state
    ``(q, v)`` is given (the integrators below take the same first argument).
    """
    js = as_joint_set(space)
    out = np.empty(js.nq)
    configuration_step(js.stage_kind, js.stage_q, js.stage_v, as_input(q),
                       as_input(v), float(dt), out)
    return out


def normalize_configuration(space, q):
    """``q`` with every quaternion renormalised."""
    js = as_joint_set(space)
    out = np.array(q, dtype=float)
    normalize_quaternions(js.stage_kind, js.stage_q, out)
    return out


def semi_implicit_euler(space, accel, t, q, qd, dt):
    """Symplectic Euler: ``qd += dt qdd(q, qd)``, then ``q ⊕= dt qd``."""
    qd_next = qd + dt * accel(t, q, qd)
    return integrate_configuration(space, q, qd_next, dt), qd_next


def configuration_rate(space, q, v):
    """``dq/dt`` (nq,) for velocity ``v``: ``v`` on linear stages and
    ``1/2 quat ⊗ (0, w)`` on ball stages (body-frame ``w``)."""
    js = as_joint_set(space)
    rate = np.empty(js.nq)
    configuration_rate_of(js.stage_kind, js.stage_q, js.stage_v, as_input(q),
                          as_input(v), rate)
    return rate


def rk4(space, accel, t, q, qd, dt):
    """Classical Runge-Kutta 4 on ``(q, qd)``, quaternions in their embedding.

    Averaging body-frame angular velocities taken at different configurations
    would cost two orders on ball joints; the quaternion ODE
    ``dq/dt = 1/2 q ⊗ (0, w)`` keeps fourth order. Quaternions are normalised
    when used and at the end of the step.
    """
    k1q, k1v = configuration_rate(space, q, qd), accel(t, q, qd)
    q2, v2 = q + dt / 2 * k1q, qd + dt / 2 * k1v
    k2q, k2v = configuration_rate(space, q2, v2), accel(t + dt / 2, q2, v2)
    q3, v3 = q + dt / 2 * k2q, qd + dt / 2 * k2v
    k3q, k3v = configuration_rate(space, q3, v3), accel(t + dt / 2, q3, v3)
    q4, v4 = q + dt * k3q, qd + dt * k3v
    k4q, k4v = configuration_rate(space, q4, v4), accel(t + dt, q4, v4)
    q_next = q + dt / 6 * (k1q + 2 * k2q + 2 * k3q + k4q)
    return (normalize_configuration(space, q_next),
            qd + dt / 6 * (k1v + 2 * k2v + 2 * k3v + k4v))


#: the integrators by name; ``"symplectic"`` (symplectic Euler in momentum form,
#: (S1)-(S3) of ``docs/accuracy.md``) exists only in the compiled step loop
#: (:func:`symplectic_step`)
INTEGRATORS = {"semi-implicit": semi_implicit_euler, "rk4": rk4, "symplectic": None}


def get_integrator(name):
    """The integrator called ``name`` (``"semi-implicit"``, ``"rk4"`` or
    ``"symplectic"``, which has no Python function: None)."""
    if not isinstance(name, str) or name not in INTEGRATORS:
        raise InputError(f"unknown integrator {name!r}; choose one of {sorted(INTEGRATORS)}")
    return INTEGRATORS[name]


# --- whole steps in compiled code ------------------------------------------------------

@pass_kernel
def accelerations(js, tree, bodies, F, e, t, q, qd, kin, work, states, f_ext, tau, out):
    """``qdd`` (into ``out``) at ``(t, q, qd)`` with the forces of the tables ``F``
    (:class:`~vdad.forces.ForceTables`) at evaluation ``e``: kinematics, forces
    from every body's state (world axes, as :class:`~vdad.forces.BodyStates`), the
    DCA."""
    body_forces(js, F, e, t, q, qd, kin, states, f_ext, tau)
    dynamics_pass(js, tree, bodies, q, qd, tau, f_ext, kin, work)
    qdd = work[7]
    for i in range(out.shape[0]):
        out[i] = qdd[i]


#: integration schemes of :func:`dca_steps`
SEMI_IMPLICIT, RK4, SYMPLECTIC = 0, 1, 2
#: the most iterations of a symplectic step's velocity solve, and their tolerance
#: (relative to the largest velocity; they also stop where a change below
#: SYMPLECTIC_ACCEPT is no smaller than the one before: the rounding of the DCA's
#: solve, about cond(M) eps); a step whose solve ends above SYMPLECTIC_ACCEPT is
#: taken again in 2, 4, ... 2^SYMPLECTIC_HALVINGS substeps
SYMPLECTIC_ITERATIONS, SYMPLECTIC_TOLERANCE, SYMPLECTIC_ACCEPT = 50, 1e-14, 1e-8
SYMPLECTIC_HALVINGS = 6
#: a solve whose change grows to this many times its first one has left the
#: step's fixed point (it diverges): the step is taken again in substeps
SYMPLECTIC_GROWTH = 10.0
#: the differences of iterates that the Anderson-accelerated solve remembers
ANDERSON_MEMORY = 6


def anderson_scratch(nv):
    """Scratch of :func:`anderson_update` for ``nv`` dofs: ``(rows (3 m + 2, nv),
    R (m, m + 1))``, ``m`` = :data:`ANDERSON_MEMORY`."""
    m = ANDERSON_MEMORY
    return np.zeros((3 * m + 2, nv)), np.zeros((m, m + 1))


@inlined
def anderson_update(k, x, gx, rows, R):
    """Iteration ``k`` (from 0) of Anderson acceleration (type II; Walker and Ni
    2011, ``docs/accuracy.md`` (S4)) of the fixed point ``x = G(x)``, given ``gx =
    G(x)``: ``x <- gx - sum_c gamma_c dg_c``, ``gamma`` the least-squares fit of the
    residual ``f = gx - x`` by the last ``m`` residual differences ``df_c`` (``dg_c``
    those of ``G``), by modified Gram-Schmidt (a difference dependent on the others
    to ``1e-10`` of its length is left out). ``rows`` (3 m + 2, nv): ``df`` (m
    rows), ``dg`` (m), their orthonormalised ``df`` (m), the last ``f`` and ``G``;
    ``R`` (m, m + 1): the triangular factor and ``Q^T f``."""
    m, nv = R.shape[0], x.shape[0]
    f_last, g_last = rows[3 * m], rows[3 * m + 1]
    if k > 0:                                           # the newest differences
        c = (k - 1) % m
        for i in range(nv):
            rows[c, i] = gx[i] - x[i] - f_last[i]
            rows[m + c, i] = gx[i] - g_last[i]
    for i in range(nv):
        f_last[i] = gx[i] - x[i]
        g_last[i] = gx[i]
    n = min(k, m)
    for c in range(n):                                  # Q R = df, Q^T f
        Q = rows[2 * m + c]
        length = 0.0
        for i in range(nv):
            Q[i] = rows[c, i]
            length += Q[i] * Q[i]
        for r in range(c):
            acc = 0.0
            if R[r, r] > 0.0:
                for i in range(nv):
                    acc += rows[2 * m + r, i] * Q[i]
                for i in range(nv):
                    Q[i] -= acc * rows[2 * m + r, i]
            R[r, c] = acc
        norm = 0.0
        for i in range(nv):
            norm += Q[i] * Q[i]
        R[c, c] = np.sqrt(norm) if norm > 1e-20 * length and norm > 0.0 else 0.0
        acc = 0.0
        if R[c, c] > 0.0:
            for i in range(nv):
                Q[i] /= R[c, c]
                acc += Q[i] * f_last[i]
        R[c, m] = acc
    for c in range(n - 1, -1, -1):                      # R gamma = Q^T f, into R[:, m]
        if R[c, c] > 0.0:
            acc = R[c, m]
            for r in range(c + 1, n):
                acc -= R[c, r] * R[r, m]
            R[c, m] = acc / R[c, c]
        else:
            R[c, m] = 0.0
    for i in range(nv):
        acc = gx[i]
        for c in range(n):
            acc -= R[c, m] * rows[m + c, i]
        x[i] = acc


@inlined
def velocities_of(js, tree, inert, q, p, zero, no_wrench, kin, work):
    """``qd = M(q)^-1 p`` (nv) into ``work``'s ``qdd``: the DCA on the model's
    ``inert`` arrays (:func:`~vdad.dca.inert_arrays`) at zero velocity with joint
    forces ``p`` ((S3) of ``docs/accuracy.md``), refined where leaves are raised."""
    kinematics_pass(js, q, zero, True, *kin)
    dynamics_pass(js, tree, inert, q, zero, p, no_wrench, kin, work)


@inlined
def symplectic_step(e, t, dt, js, tree, bodies, inert, F, q, qd, p, previous, kin, work,
                    states, f_ext, no_wrench, tau, scratch, rows, R, q_new, qd_new):
    """One step of symplectic Euler in momentum form ((S1)-(S3) of
    ``docs/accuracy.md``), for joints of hinge and slide stages: with ``qd = M(q)^-1
    p`` (:func:`velocities_of`, into ``qd``) and the forces at ``(q, qd)`` (the
    tables ``F`` at evaluation ``e``, gravity, springs, dampers: ``g``),
    ``p' = p + dt (dT/dq(q, qd') + g)`` with ``qd' = M(q)^-1 p'``, solved by
    Anderson-accelerated fixed-point iteration (:func:`anderson_update`, (S4)) from
    ``2 qd - previous``, until a change is below :data:`SYMPLECTIC_TOLERANCE` of
    the largest velocity (or, below :data:`SYMPLECTIC_ACCEPT`, no smaller than the
    one before), then ``q' = q ⊕ dt qd'``. Returns whether the solve converged (its
    last change below :data:`SYMPLECTIC_ACCEPT` of the largest velocity). Leaves
    ``p'`` in ``p``, ``qd`` in ``previous``, ``q'``, ``qd'`` in ``q_new``, ``qd_new``.
    ``no_wrench`` (0, 6): no external wrench; ``scratch`` (4, nv): ``0`` (zero),
    ``g``, ``dT/dq``, ``p'``; ``rows``, ``R``: :func:`anderson_scratch`."""
    Phi, b, Y, WtWm, beta, gamma, f_J, qdd, tau_w, X, GY, tmp, PF, a, f, cg, G = work
    zero, g, dT, p_next = scratch[0], scratch[1], scratch[2], scratch[3]
    nv, nb = qd.shape[0], f.shape[0]
    velocities_of(js, tree, inert, q, p, zero, no_wrench, kin, work)
    for i in range(nv):
        qd[i] = qdd[i]
    body_forces(js, F, e, t, q, qd, kin, states, f_ext, tau)          # kinematics at (q, qd)
    passive_forces_pass(bodies[5], bodies[6], bodies[7], bodies[8], bodies[9], bodies[10], q,
                        qd, g)
    inverse_dynamics_pass(js, bodies, kin, f_ext, zero, APPLIED, a, f, tmp[7], dT)
    for i in range(nv):                                 # g = tau + passive + J^T applied
        g[i] += tau[i] - dT[i]
        qd_new[i] = 2.0 * qd[i] - previous[i]
        previous[i] = qd[i]
    last, first, change, size = np.inf, np.inf, np.inf, 1e-300
    for k in range(SYMPLECTIC_ITERATIONS):
        inverse_dynamics_pass(js, bodies, kin, no_wrench, qd_new, MASS, a, f, tmp[7], dT)
        kinetic_gradient_pass(js, kin[2], a, f, qd_new, dT)
        for i in range(nv):
            p_next[i] = p[i] + dt * (dT[i] + g[i])
        rhs_passes(nb, js, tree, kin, inert[11], p_next, G, b, Y, WtWm, PF, beta, gamma, f_J,
                   qdd, tmp, tree[13], tree[13].shape[0], ALL)
        if inert[12] != 0:
            refine_pass(js, tree, inert, no_wrench, kin, work, MASS, p_next)
        change, size = 0.0, 1e-300
        for i in range(nv):
            change = max(change, abs(qdd[i] - qd_new[i]))
            size = max(size, abs(qdd[i]))
        if not (finite(qdd) and change < SYMPLECTIC_GROWTH * first):
            return False
        if change <= SYMPLECTIC_TOLERANCE * size or (change <= SYMPLECTIC_ACCEPT * size
                                                     and change >= last):
            break
        last = change
        if k == 0:
            first = change
        anderson_update(k, qd_new, qdd, rows, R)
    for i in range(nv):
        qd_new[i] = qdd[i]
        p[i] = p_next[i]
    configuration_step(bodies[5], bodies[6], bodies[7], q, qd_new, dt, q_new)
    return change <= SYMPLECTIC_ACCEPT * size


@kernel
def dca_steps(n, dt, step0, scheme, constants, tables, q, qd, q_new, qd_new):
    """Up to ``n`` steps of the DCA from step number ``step0`` (``t = step dt``),
    with the model's own forces (gravity, joint springs and dampers) and the
    built-in force elements of the tables ``F`` (:meth:`~vdad.forces.ForceTables.
    arrays`, evaluation ``e = step * evaluations + k`` of the chunk), by ``scheme``:
    semi-implicit Euler or RK4, as :func:`semi_implicit_euler` and :func:`rk4`, or
    symplectic Euler in momentum form (:func:`symplectic_step`; ``inert``:
    :func:`~vdad.dca.inert_arrays`) in ``2^halvings[0]`` substeps a step, updating
    ``q``, ``qd`` in place. A symplectic step whose solve does not converge is taken
    again in twice as many substeps, and ``halvings[0]`` keeps the new number for
    every later step ((S4) of ``docs/accuracy.md``: a step that changes back and
    forth loses the bounded energy error). Stops at a step whose state is not
    finite (status 1) or that turns a rotational dof by more than half a turn
    (status 2), or whose symplectic step does not converge even in
    ``2^SYMPLECTIC_HALVINGS`` substeps (status 3, ``q``, ``qd`` left at that step's
    start), leaving that step's state in ``q_new``, ``qd_new``. The arguments that
    stay the same from call to call come in two packs (:class:`~vdad._pack.Pack`), so
    that a call from Python converts ten arguments instead of some 140 (``vdad._pack``):
    ``constants`` = (js, tree, bodies, inert, rotational, kin, work, halvings,
    :func:`step_scratch`) and ``tables`` = ``F``. Returns ``(steps done, status)``."""
    js, tree, bodies, inert, rotational, kin, work, halvings, held = constants.data
    F = tables.data
    stage_kind, stage_q, stage_v = bodies[5], bodies[6], bodies[7]
    nq, nv = q.shape[0], qd.shape[0]
    kq, kv, qs, vs, states, f_ext, tau, p, previous, scratch, rows, R, no_wrench, start = held
    if scheme == SYMPLECTIC:                                       # p = M(q) qd
        previous[:] = qd                   # the solve's memory starts from this call's qd
        scratch[:] = 0.0
        rows[:] = 0.0
        R[:] = 0.0
        kinematics_pass(js, q, qd, True, *kin)
        inverse_dynamics_pass(js, bodies, kin, no_wrench, qd, MASS, work[13], work[14],
                              work[11][7], p)
    for step in range(n):
        t = (step0 + step) * dt
        if scheme == SEMI_IMPLICIT:
            accelerations(js, tree, bodies, F, step, t, q, qd, kin, work, states, f_ext, tau,
                          kv[0])
            for i in range(nv):
                qd_new[i] = qd[i] + dt * kv[0, i]
            configuration_step(stage_kind, stage_q, stage_v, q, qd_new, dt, q_new)
        elif scheme == SYMPLECTIC:                 # in 2^level substeps where it must
            for i in range(nq):
                start[0, i] = q[i]
            for i in range(nv):
                start[1, i] = p[i]
                start[2, i] = previous[i]
            converged = True
            for level in range(halvings[0], SYMPLECTIC_HALVINGS + 1):
                k = 1 << level
                for i in range(nq):
                    qs[i] = start[0, i]
                for i in range(nv):
                    p[i] = start[1, i]
                    previous[i] = start[2, i]
                converged = True
                for sub in range(k):
                    converged = symplectic_step(step, t + sub * dt / k, dt / k, js, tree,
                                                bodies, inert, F, qs, qd, p, previous, kin,
                                                work, states, f_ext, no_wrench, tau, scratch,
                                                rows, R, q_new, qd_new)
                    for i in range(nq):
                        qs[i] = q_new[i]
                    if not converged:
                        break
                if converged:
                    halvings[0] = level
                    break
            if not converged:                      # the step's start, qd = M(q)^-1 p
                for i in range(nv):
                    p[i] = start[1, i]
                velocities_of(js, tree, inert, q, p, scratch[0], no_wrench, kin, work)
                for i in range(nv):
                    qd[i] = work[7][i]
                return step, 3
        else:
            for k in range(4):
                h = 0.0 if k == 0 else (dt if k == 3 else dt / 2)
                for i in range(nq):
                    qs[i] = q[i] + h * kq[k - 1, i] if k > 0 else q[i]
                for i in range(nv):
                    vs[i] = qd[i] + h * kv[k - 1, i] if k > 0 else qd[i]
                configuration_rate_of(stage_kind, stage_q, stage_v, qs, vs, kq[k])
                accelerations(js, tree, bodies, F, 4 * step + k, t + h, qs, vs, kin, work,
                              states, f_ext, tau, kv[k])
            for i in range(nq):
                q_new[i] = q[i] + dt / 6 * (kq[0, i] + 2 * kq[1, i] + 2 * kq[2, i] + kq[3, i])
            for i in range(nv):
                qd_new[i] = qd[i] + dt / 6 * (kv[0, i] + 2 * kv[1, i] + 2 * kv[2, i] + kv[3, i])
            normalize_quaternions(stage_kind, stage_q, q_new)
        for i in range(nq):
            if not np.isfinite(q_new[i]):
                return step, 1
        for i in range(nv):
            if not np.isfinite(qd_new[i]):
                return step, 1
            if rotational[i] and abs(qd_new[i]) * dt > np.pi:
                return step, 2
        for i in range(nq):
            q[i] = q_new[i]
        for i in range(nv):
            qd[i] = qd_new[i]
    if scheme == SYMPLECTIC:                                       # qd = M(q)^-1 p
        velocities_of(js, tree, inert, q, p, scratch[0], no_wrench, kin, work)
        for i in range(nv):
            qd[i] = work[7][i]
    return n, 0


def step_scratch(nq, nv, nb):
    """The scratch arrays of :func:`dca_steps`, kept in its constants pack so that a
    call allocates none: RK4's stages ``kq`` (4, nq), ``kv`` (4, nv), ``qs``, ``vs``;
    the forces' ``states`` (2, nb, 3), ``f_ext`` (nb, 6), ``tau``; the symplectic
    step's momentum ``p``, previous velocities, scratch (4, nv), Anderson memory
    (:func:`anderson_scratch`), an empty wrench array and the step's start (3,
    max(nq, nv))."""
    return (np.empty((4, nq)), np.empty((4, nv)), np.empty(nq), np.empty(nv),
            np.empty((2, nb, 3)), np.empty((nb, 6)), np.empty(nv), np.empty(nv),
            np.empty(nv), np.zeros((4, nv)), *anderson_scratch(nv), np.empty((0, 6)),
            np.empty((3, max(nq, nv))))

