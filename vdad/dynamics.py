"""Forward dynamics and the generalised forces that act in joints.

``forward_dynamics`` runs the DCA (:mod:`vdad.dca`) on a balanced assembly tree
unless another tree is given; :func:`passive_forces` gives the joint springs and
dampers of (T5)'s ``tau``.
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np

from . import dca
from . import joints as J
from .assembly import AssemblyTree
from .errors import InputError
from .kinematics import as_joint_set, kinematics
from .spatial import quat_log, quat_mul


def check_vector(name, x, n, allow_none=False):
    """``x`` as a finite float vector of length ``n``, or a clear InputError."""
    if x is None and allow_none:
        return None
    try:
        a = np.asarray(x, dtype=float)
    except (TypeError, ValueError):
        raise InputError(f"{name} must be numeric, got {type(x).__name__}") from None
    if a.shape != (n,):
        raise InputError(f"{name} must have shape ({n},), got {a.shape}")
    bad = np.flatnonzero(~np.isfinite(a))
    if len(bad):
        raise InputError(f"{name} has non-finite entries at indices {bad[:5].tolist()}")
    return a


def check_real(name, value, shape=None, positive=False, nonnegative=False):
    """``value`` as a finite float array (broadcast to ``shape`` if given; a
    scalar stays 0-d), optionally ``> 0`` or ``>= 0``, or an InputError naming
    ``name``."""
    try:
        a = np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        raise InputError(f"{name} must be numeric, got {value!r}") from None
    if shape is not None:
        try:
            a = np.broadcast_to(a, shape).copy()
        except ValueError:
            raise InputError(f"{name} must have shape {shape} (or broadcast to it), got "
                             f"{a.shape}") from None
    if not np.all(np.isfinite(a)):
        raise InputError(f"{name} must be finite, got {value}")
    if positive and np.any(a <= 0):
        raise InputError(f"{name} must be positive, got {value}")
    if nonnegative and np.any(a < 0):
        raise InputError(f"{name} must be >= 0, got {value}")
    return a


def check_count(name, value, minimum=1):
    """``value`` as an int if it is a whole number ``>= minimum``, or an
    InputError naming ``name``."""
    a = check_real(name, value)
    if a.ndim or a != int(a) or a < minimum:
        what = "a positive integer" if minimum == 1 else f"an integer >= {minimum}"
        raise InputError(f"{name} must be {what}, got {value!r}")
    return int(a)


def check_wrenches(model, f_ext):
    """``f_ext`` as a finite (nb, 6) array, or None."""
    if f_ext is None:
        return None
    a = np.asarray(f_ext, dtype=float)
    if a.shape != (model.nb, 6):
        raise InputError(f"f_ext must have shape ({model.nb}, 6) (torque about the centre of "
                         f"mass; force, world axes), got {a.shape}")
    bad = np.flatnonzero(~np.all(np.isfinite(a), axis=1))
    if len(bad):
        raise InputError(f"f_ext is not finite on body {model.body_names[bad[0]]!r}")
    return a


def spring_displacements(space, q):
    """``(k, dofs, d)`` for every stage with a spring: stiffness, its velocity
    indices and its displacement from ``q_spring`` (ball: the rotation vector of
    ``q_spring^-1 q``, as MuJoCo). The spring force is ``-k d``, its energy
    ``k |d|^2 / 2``. ``space``: a model or a :class:`~vdad.kinematics.JointSet`
    (``q`` in its local layout)."""
    js = as_joint_set(space)
    out = []
    for s in np.flatnonzero(js.stage_stiffness > 0):
        kind, iq, iv = js.stage_kind[s], js.stage_q[s], js.stage_v[s]
        n = J.STAGE_NV[kind]
        if kind == J.BALL:
            conj = js.q_spring[iq:iq + 4] * np.array([1, -1, -1, -1])
            d = quat_log(quat_mul(conj, q[iq:iq + 4] / np.linalg.norm(q[iq:iq + 4])))
        else:
            d = q[iq:iq + n] - js.q_spring[iq:iq + n]
        out.append((js.stage_stiffness[s], slice(iv, iv + n), d))
    return out


def passive_forces(space, q, qd):
    """Joint spring and damper forces (nv,): ``-K d - D qd`` per stage, with the
    displacements ``d`` of :func:`spring_displacements` (``space`` as there)."""
    js = as_joint_set(space)
    tau = -js.damping * qd
    for k, dofs, d in spring_displacements(js, q):
        tau[dofs] -= k * d
    return tau


@lru_cache(maxsize=64)
def default_tree(model) -> AssemblyTree:
    """The balanced assembly tree of ``model`` (cached)."""
    return AssemblyTree.balanced(model)


def forward_dynamics(model, q, qd, tau=None, f_ext=None, tree=None, data=None):
    """Joint accelerations ``qdd`` (nv,) by the DCA (theory §4-5).

    q (nq,), qd (nv,): state (MuJoCo layout); tau (nv,): actuation, added to
    the joint springs and dampers; f_ext (nb, 6): external wrench per body,
    (torque about its centre of mass; force) in world axes; tree: an
    :class:`~vdad.assembly.AssemblyTree` (default: balanced); data: reusable
    :class:`~vdad.dca.DCAData` work arrays of that tree.
    """
    q = check_vector("q", q, model.nq)
    qd = check_vector("qd", qd, model.nv)
    tau = check_vector("tau", tau, model.nv, allow_none=True)
    f_ext = check_wrenches(model, f_ext)
    tree = default_tree(model) if tree is None else tree
    data = dca.make_data(tree) if data is None else data
    kin = kinematics(model, q, qd)
    tau_total = passive_forces(model, q, qd)
    if tau is not None:
        tau_total += tau
    dca.dca_pass(model, tree, kin, dca.body_wrenches(model, kin, f_ext),
                 np.append(tau_total, 0.0), data)
    return data.qdd[:-1].copy()
