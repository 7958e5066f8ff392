"""Time integration of ``(q, qd)`` on the joint manifolds.

``integrate_configuration`` maps a velocity over ``dt`` onto ``q``: hinges,
slides and translations add ``qd dt``; ball stages (body-frame angular
velocity) right-multiply their quaternion by ``exp(w dt)`` and renormalise, as
MuJoCo's ``mj_integratePos``. The integrators take ``accel(t, q, qd) -> qdd``;
:func:`rk4` integrates quaternions in their embedding (see there).
"""

from __future__ import annotations

import numpy as np

from .errors import InputError
from .kinematics import as_joint_set
from .spatial import quat_exp, quat_mul


def integrate_configuration(space, q, v, dt):
    """``q ⊕ v dt`` (nq,): the configuration reached by velocity ``v`` in ``dt``.

    ``space``: a model, or a :class:`~vdad.kinematics.JointSet` whose local state
    ``(q, v)`` is given (the integrators below take the same first argument).
    """
    js = as_joint_set(space)
    lin_q, lin_v, ball_q, ball_v = js.lin_q, js.lin_v, js.ball_q, js.ball_v
    out = q.copy()
    out[lin_q] += v[lin_v] * dt
    if len(ball_q):
        quat = quat_mul(q[ball_q], quat_exp(v[ball_v] * dt))
        out[ball_q] = quat / np.linalg.norm(quat, axis=1, keepdims=True)
    return out


def normalize_configuration(space, q):
    """``q`` with every quaternion renormalised."""
    ball_q = as_joint_set(space).ball_q
    out = np.array(q, dtype=float)
    if len(ball_q):
        out[ball_q] /= np.linalg.norm(out[ball_q], axis=1, keepdims=True)
    return out


def semi_implicit_euler(space, accel, t, q, qd, dt):
    """Symplectic Euler: ``qd += dt qdd(q, qd)``, then ``q ⊕= dt qd``."""
    qd_next = qd + dt * accel(t, q, qd)
    return integrate_configuration(space, q, qd_next, dt), qd_next


def configuration_rate(space, q, v):
    """``dq/dt`` (nq,) for velocity ``v``: ``v`` on linear stages and
    ``1/2 quat ⊗ (0, w)`` on ball stages (body-frame ``w``)."""
    js = as_joint_set(space)
    lin_q, lin_v, ball_q, ball_v = js.lin_q, js.lin_v, js.ball_q, js.ball_v
    rate = np.zeros(js.nq)
    rate[lin_q] = v[lin_v]
    if len(ball_q):
        pure = np.concatenate([np.zeros((len(ball_q), 1)), v[ball_v]], axis=1)
        rate[ball_q] = 0.5 * quat_mul(q[ball_q], pure)
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


INTEGRATORS = {"semi-implicit": semi_implicit_euler, "rk4": rk4}


def get_integrator(name):
    """The integrator called ``name`` (``"semi-implicit"`` or ``"rk4"``)."""
    if not isinstance(name, str) or name not in INTEGRATORS:
        raise InputError(f"unknown integrator {name!r}; choose one of {sorted(INTEGRATORS)}")
    return INTEGRATORS[name]
