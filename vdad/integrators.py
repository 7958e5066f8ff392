"""Time integration of ``(q, qd)`` on the joint manifolds.

``integrate_configuration`` maps a velocity over ``dt`` onto ``q``: hinges,
slides and translations add ``qd dt``; ball stages (body-frame angular
velocity) right-multiply their quaternion by ``exp(w dt)`` and renormalise, as
MuJoCo's ``mj_integratePos``. The integrators take ``accel(t, q, qd) -> qdd``.
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np

from . import joints as J
from .errors import InputError
from .spatial import quat_exp, quat_mul


@lru_cache(maxsize=64)
def _layout(model):
    """Index arrays: linear (q, v) pairs and ball (q: 4, v: 3) blocks."""
    lin_q, lin_v, ball_q, ball_v = [], [], [], []
    for s in range(model.ns):
        kind, iq, iv = model.stage_kind[s], model.stage_q[s], model.stage_v[s]
        if kind == J.BALL:
            ball_q.append(iq + np.arange(4))
            ball_v.append(iv + np.arange(3))
        else:
            n = J.STAGE_NV[kind]
            lin_q.extend(range(iq, iq + n))
            lin_v.extend(range(iv, iv + n))
    return (np.array(lin_q, int), np.array(lin_v, int),
            np.array(ball_q, int).reshape(-1, 4), np.array(ball_v, int).reshape(-1, 3))


def integrate_configuration(model, q, v, dt):
    """``q ⊕ v dt`` (nq,): the configuration reached by velocity ``v`` in ``dt``."""
    lin_q, lin_v, ball_q, ball_v = _layout(model)
    out = q.copy()
    out[lin_q] += v[lin_v] * dt
    if len(ball_q):
        quat = quat_mul(q[ball_q], quat_exp(v[ball_v] * dt))
        out[ball_q] = quat / np.linalg.norm(quat, axis=1, keepdims=True)
    return out


def normalize_configuration(model, q):
    """``q`` with every quaternion renormalised."""
    ball_q = _layout(model)[2]
    out = np.array(q, dtype=float)
    if len(ball_q):
        out[ball_q] /= np.linalg.norm(out[ball_q], axis=1, keepdims=True)
    return out


def semi_implicit_euler(model, accel, t, q, qd, dt):
    """Symplectic Euler: ``qd += dt qdd(q, qd)``, then ``q ⊕= dt qd``."""
    qd_next = qd + dt * accel(t, q, qd)
    return integrate_configuration(model, q, qd_next, dt), qd_next


def rk4(model, accel, t, q, qd, dt):
    """Classical Runge-Kutta 4 with configuration updates through ``⊕``."""
    k1v, k1a = qd, accel(t, q, qd)
    q2 = integrate_configuration(model, q, k1v, dt / 2)
    k2v = qd + dt / 2 * k1a
    k2a = accel(t + dt / 2, q2, k2v)
    q3 = integrate_configuration(model, q, k2v, dt / 2)
    k3v = qd + dt / 2 * k2a
    k3a = accel(t + dt / 2, q3, k3v)
    q4 = integrate_configuration(model, q, k3v, dt)
    k4v = qd + dt * k3a
    k4a = accel(t + dt, q4, k4v)
    v_mean = (k1v + 2 * k2v + 2 * k3v + k4v) / 6
    return (integrate_configuration(model, q, v_mean, dt),
            qd + dt * (k1a + 2 * k2a + 2 * k3a + k4a) / 6)


INTEGRATORS = {"semi-implicit": semi_implicit_euler, "rk4": rk4}


def get_integrator(name):
    """The integrator called ``name`` (``"semi-implicit"`` or ``"rk4"``)."""
    try:
        return INTEGRATORS[name]
    except KeyError:
        raise InputError(f"unknown integrator {name!r}; choose one of {sorted(INTEGRATORS)}") \
            from None
