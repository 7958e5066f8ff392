"""Forward dynamics and the generalised forces that act in joints.

``forward_dynamics`` runs the DCA (:mod:`vdad.dca`) on a balanced assembly tree
unless another tree is given; :func:`inverse_dynamics` runs Newton-Euler
(:mod:`vdad.newton_euler`); :func:`passive_forces` gives the joint springs and
dampers of (T5)'s ``tau``.
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np

from . import dca
from . import joints as J
from ._linalg import as_input, compiling
from .assembly import AssemblyTree, check_tree
from .checks import all_finite, check_vector, check_wrenches
from .errors import InputError, SimulationError
from .kinematics import JointSet, as_joint_set, gimbal_lock, kinematics, plan
from .model import check_configuration, check_model
from .newton_euler import FULL, inverse_dynamics_pass
from .spatial import quat_log, quat_mul


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
    if not isinstance(space, JointSet):
        check_model(space)
        q = check_configuration(space, "q", q)
        qd = check_vector("qd", qd, space.nv)
    js = as_joint_set(space)
    tau = np.empty(js.nv)
    dca.passive_forces_pass(js.stage_kind, js.stage_q, js.stage_v, js.stage_stiffness,
                            js.q_spring, js.damping, as_input(q), as_input(qd),
                            tau)
    return tau


@lru_cache(maxsize=64)
def default_tree(model) -> AssemblyTree:
    """The balanced assembly tree of ``model`` (cached)."""
    return AssemblyTree.balanced(model)


@lru_cache(maxsize=64)
def _work(tree) -> dca.DCAData:
    """Work arrays of ``tree`` for calls that give none (cached: :func:`forward_dynamics`
    returns a copy of its ``qdd``, so no caller holds them)."""
    return dca.make_data(tree)


@lru_cache(maxsize=64)
def _default_call(model) -> tuple:
    """The packed DCA (:func:`~vdad.dca.packed`) and work arrays that
    :func:`forward_dynamics` uses without a tree: of the welded model
    (:func:`~vdad.dca.welded`) where ``model`` has fixed joints below a body,
    else of ``model``, on the balanced tree."""
    welds = dca.welded(model)
    dca_model = model if welds is None else welds.model
    data = _work(default_tree(dca_model))
    return dca.packed(dca_model, data, welds), data


def forward_dynamics(model, q, qd, tau=None, f_ext=None, tree=None, data=None):
    """Joint accelerations ``qdd`` (nv,) by the DCA (theory §4-5).

    q (nq,), qd (nv,): state (MuJoCo layout); tau (nv,): actuation, added to
    the joint springs and dampers; f_ext (nb, 6): external wrench per body,
    (torque about its centre of mass; force) in world axes; tree: an
    :class:`~vdad.assembly.AssemblyTree` (default: balanced); data: reusable
    :class:`~vdad.dca.DCAData` work arrays of that tree. Without either, a model
    with fixed joints below a body runs on its welded model
    (:func:`~vdad.dca.welded`).
    """
    check_model(model)
    if tree is None and data is None:
        constants, data = _default_call(model)
    else:
        tree = default_tree(model) if tree is None else check_tree(model, tree)
        data = _work(tree) if data is None else dca.check_data(tree, data)
        constants = dca.packed(model, data)
    if (_as_given(q, (model.nq,)) and _as_given(qd, (model.nv,))
            and (tau is None or _as_given(tau, (model.nv,)))
            and (f_ext is None or _as_given(f_ext, (model.nb, 6)))
            and _call(constants, q, qd, tau, f_ext)):
        return data.qdd.copy()          # float arrays as the kernels take them, all finite
    q = check_configuration(model, "q", q)
    qd = check_vector("qd", qd, model.nv)
    tau = check_vector("tau", tau, model.nv, allow_none=True)
    f_ext = check_wrenches(model, f_ext)
    _evaluate(constants, q, qd, tau, f_ext)
    return check_overflow(model, data.qdd.copy(), q, qd=qd, tau=tau, f_ext=f_ext)


def inverse_dynamics(model, q, qd, qdd, f_ext=None):
    """The actuation ``tau`` (nv,) under which ``model`` at ``(q, qd)`` accelerates
    by ``qdd`` (nv,), with gravity, ``f_ext`` (nb, 6; as :func:`forward_dynamics`)
    and the joint springs and dampers: ``forward_dynamics(model, q, qd, tau, f_ext)``
    is ``qdd``. Newton-Euler with the bodies' inertias (RBDA §5.3; (R1) of
    ``docs/accuracy.md``), compiled."""
    check_model(model)
    q = check_configuration(model, "q", q)
    qd = check_vector("qd", qd, model.nv)
    qdd = check_vector("qdd", qdd, model.nv)
    f_ext = check_wrenches(model, f_ext)
    js, kin = plan(model), kinematics(model, q, qd)
    a, f, out = np.empty((model.nb, 6)), np.empty((model.nb, 6)), np.empty(model.nv)
    with compiling(inverse_dynamics_pass):
        inverse_dynamics_pass(js.arrays, dca.body_arrays(model), kin.arrays,
                              _NO_WRENCH if f_ext is None else as_input(f_ext), as_input(qdd),
                              FULL, a, f, np.empty((2, 6)), out)
    return out - passive_forces(js, q, qd)


def _as_given(x, shape):
    """Whether ``x`` is an array the kernels take as it is: float64 of ``shape``,
    C-contiguous, writable (:func:`~vdad._linalg.as_input`); its values are
    checked by the pass itself, and the full checks run only if that finds a
    non-finite number."""
    if type(x) is not np.ndarray or x.dtype != np.float64 or x.shape != shape:
        return False
    flags = x.flags
    return flags.c_contiguous and flags.writeable


def check_overflow(model, qdd, q, **inputs):
    """``qdd`` if it is finite; else a SimulationError if a joint is in gimbal lock
    at ``q`` (:func:`~vdad.kinematics.gimbal_lock`), or the InputError of
    accelerations that came out non-finite from finite ``inputs`` (name: array or
    None): they overflowed double precision. Names the first joint at fault and the
    size of the inputs."""
    if all_finite(qdd):
        return qdd
    lock = gimbal_lock(model, q)
    if lock is not None:
        raise SimulationError(lock)
    bad = model.dof_joint[np.flatnonzero(~np.isfinite(qdd))[0]]
    sizes = ", ".join(f"|{k}| up to {np.abs(v).max():.3g}" for k, v in inputs.items()
                      if v is not None)
    raise InputError(f"forward dynamics overflowed double precision (non-finite acceleration "
                     f"at joint {model.joint_names[bad]!r}); the inputs are too large: {sizes}")


def forward_dynamics_unchecked(model, q, qd, tau, f_ext, data):
    """:func:`forward_dynamics` of inputs already checked (q (nq,) and qd (nv,)
    finite floats, tau (nv,) or None, f_ext (nb, 6) or None, ``data`` of a tree
    of ``model``): what a simulator calls every step."""
    _evaluate(dca.packed(model, data), q, qd, tau, f_ext)
    return data.qdd.copy()


def _evaluate(constants, q, qd, tau, f_ext):
    """:func:`_call` of any float arrays (made the kernels' type,
    :func:`~vdad._linalg.as_input`)."""
    return _call(constants, as_input(q), as_input(qd), None if tau is None else as_input(tau),
                 None if f_ext is None else as_input(f_ext))


def _call(constants, q, qd, tau, f_ext):
    """:func:`~vdad.dca.dca_call` of the packed DCA ``constants``
    (:func:`~vdad.dca.packed`), into its work arrays, on arrays of the kernels'
    type; whether the inputs and ``qdd`` are all finite."""
    with compiling(dca.dca_call):
        return dca.dca_call(constants, q, qd, _NO_TAU if tau is None else tau,
                            _NO_WRENCH if f_ext is None else f_ext)


_NO_TAU, _NO_WRENCH = np.zeros(0), np.zeros((0, 6))
