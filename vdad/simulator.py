"""Time stepping of a model: :class:`Simulator`.

The simulator owns the state ``(t, q, qd)`` and the DCA work arrays; the model
and the assembly tree stay immutable. Forces that depend on time or state come
from two callables: ``controller(t, q, qd) -> tau`` (nv,) and
``external(t, q, qd) -> f_ext`` (nb, 6), as in :func:`vdad.forward_dynamics`.
A step that produces a non-finite state, or turns a rotational degree of
freedom by more than half a turn (|qd| dt > pi, which no integrator resolves: the
run is diverging), stops with a :class:`SimulationError` naming the step and the
first joint at fault.
"""

from __future__ import annotations

import numpy as np

from . import dca
from .adaptive import rotational_dofs
from .baselines import DistanceLOD, Sleeping, root_last_tree
from .dynamics import check_vector, default_tree, forward_dynamics
from .errors import InputError, SimulationError
from .integrators import get_integrator, normalize_configuration
from .kinematics import world_poses

METHODS = ("dca", "adaptive", "view-bvh", "view-oq", "lod-distance", "sleeping")
METHOD_OPTIONS = {"view-bvh": ("volume", "estimate", "resolution"),
                  "view-oq": ("counting", "resolution"),
                  "lod-distance": ("distance",),
                  "sleeping": ("sleep_speed", "sleep_time")}
BASELINES = ("lod-distance", "sleeping")


class Simulator:
    """Step ``model`` from ``(q0, qd0)`` with time step ``dt``.

    method: ``"dca"`` (exact forward dynamics by the DCA), ``"adaptive"``
    (:class:`~vdad.adaptive.AdaptiveDynamics`, with ``threshold=`` or
    ``budget=`` and its other options as keyword arguments), or the
    view-dependent methods of Kim 2008 §5, adaptive dynamics whose metrics are
    weighted by each node's screen coverage ``N_M`` under ``camera`` (a
    :class:`~vdad.camera.Camera` or a path ``t -> Camera``): ``"view-bvh"``
    from bounding volumes (options ``volume`` = ``"sphere"``, ``"obb"`` or
    ``"aabb"``, ``estimate`` = ``"min"``, ``"node"`` or ``"bodies"``;
    :class:`~vdad.visibility.BoundingVolumes`) and ``"view-oq"`` from rendered
    pixel counts with the ``environment`` as occluder (option ``counting`` =
    ``"queries"`` or ``"merged"``; :class:`~vdad.visibility.RenderedCounts`,
    needs EGL). Both take ``resolution`` = (width, height) of the counting
    (default: the camera's) and ``coverage_every`` (steps between evaluations).
    Two game-engine baselines (:mod:`vdad.baselines`, on adaptive dynamics with
    ``threshold = 0`` and the :func:`~vdad.baselines.root_last_tree`):
    ``"lod-distance"`` makes whole articulated bodies rigid beyond ``distance``
    (m) from the camera, ``"sleeping"`` locks those that have moved slower
    than ``sleep_speed`` for ``sleep_time`` seconds.
    integrator: ``"semi-implicit"`` (symplectic Euler) or ``"rk4"``.
    tree: assembly tree (default: balanced).

    With ``"adaptive"``, ``history`` holds the :class:`~vdad.adaptive.StepStats`
    of every step and ``adaptive`` the adaptive work state.
    """

    def __init__(self, model, q0=None, qd0=None, dt=1e-3, method="dca",
                 integrator="semi-implicit", tree=None, controller=None, external=None,
                 camera=None, environment=None, **adaptive_options):
        if method not in METHODS:
            raise InputError(f"unknown method {method!r}; choose one of {METHODS}")
        if adaptive_options and method == "dca":
            raise InputError(f"options {sorted(adaptive_options)} need method='adaptive'")
        view = {k: adaptive_options.pop(k) for k in set().union(*METHOD_OPTIONS.values())
                if k in adaptive_options}
        wrong = sorted(set(view) - set(METHOD_OPTIONS.get(method, ())))
        if wrong:
            raise InputError(f"options {wrong} do not apply to method {method!r}")
        if method in BASELINES:
            given = sorted({"threshold", "budget"} & set(adaptive_options))
            if given:
                raise InputError(f"method {method!r} runs with threshold 0; {given} do not "
                                 f"apply")
            if method == "lod-distance" and view.get("distance") is None:
                raise InputError("method 'lod-distance' needs distance= (m)")
            adaptive_options["threshold"] = 0.0
        if (method.startswith("view") or method == "lod-distance") and camera is None:
            raise InputError(f"method {method!r} needs a camera (vdad.camera.Camera or a "
                             f"callable t -> Camera)")
        if not np.isfinite(dt) or dt <= 0:
            raise InputError(f"dt must be a positive finite number, got {dt}")
        self.model = model
        self.method = method
        self.dt = float(dt)
        self.integrator_name = integrator
        self._integrate = get_integrator(integrator)
        if tree is None:
            tree = root_last_tree(model) if method in BASELINES else default_tree(model)
        self.tree = tree
        self.data = dca.make_data(self.tree)
        self.controller = controller
        self.external = external
        q0 = model.q_neutral if q0 is None else q0
        self.q = normalize_configuration(model, check_vector("q0", q0, model.nq))
        self.qd = np.zeros(model.nv) if qd0 is None else check_vector("qd0", qd0, model.nv).copy()
        self.t = 0.0
        self.step_count = 0
        self._rotational = rotational_dofs(model)
        self.history = []
        self.adaptive = None
        self.camera, self.environment = camera, environment
        if method != "dca":
            from .adaptive import AdaptiveDynamics

            if method == "view-bvh":
                from .visibility import BoundingVolumes

                adaptive_options["coverage"] = BoundingVolumes(self.tree, camera, **view)
            elif method == "view-oq":
                from .visibility import RenderedCounts

                adaptive_options["coverage"] = RenderedCounts(
                    self.tree, camera, environment, method=view.get("counting", "queries"),
                    resolution=view.get("resolution"))
            elif method == "lod-distance":
                adaptive_options["coverage"] = DistanceLOD(self.tree, camera, **view)
            elif method == "sleeping":
                adaptive_options["coverage"] = Sleeping(self.tree, **view)
            self.adaptive = AdaptiveDynamics(model, self.dt, self.tree, **adaptive_options)

    def body_poses(self, bodies=None):
        """World poses ``R`` (k, 3, 3), ``p`` (k, 3) of ``bodies`` (indices; default
        all) in the current state. With ``"adaptive"`` only the active joints and
        the requested bodies' rigid groups are evaluated."""
        if self.adaptive is not None:
            return self.adaptive.body_poses(self.q, bodies)
        R, p = world_poses(self.model, self.q)
        return (R, p) if bodies is None else (R[bodies], p[bodies])

    def accelerations(self, t, q, qd):
        """``qdd`` at ``(t, q, qd)`` with the simulator's forces."""
        if not (np.all(np.isfinite(q)) and np.all(np.isfinite(qd))):
            self._blow_up(q, qd)
        tau = None if self.controller is None else self.controller(t, q, qd)
        f_ext = None if self.external is None else self.external(t, q, qd)
        return forward_dynamics(self.model, q, qd, tau, f_ext, tree=self.tree, data=self.data)

    def step(self, n=1):
        """Advance ``n`` steps; returns ``self``."""
        for _ in range(int(n)):
            try:
                if self.adaptive is None:
                    q, qd = self._integrate(self.model, self.accelerations, self.t, self.q,
                                            self.qd, self.dt)
                else:
                    q, qd = self.q.copy(), self.qd.copy()
                    self.history.append(self.adaptive.step(self.t, q, qd, self._integrate,
                                                           self.controller, self.external))
            except InputError as exc:
                raise SimulationError(f"step {self.step_count + 1} (t = {self.t:.6g} s): a "
                                      f"callable (forces, camera or coverage) returned bad "
                                      f"values: {exc}") from exc
            if not (np.all(np.isfinite(q)) and np.all(np.isfinite(qd))):
                self._blow_up(q, qd)
            fast = np.flatnonzero(self._rotational & (np.abs(qd) * self.dt > np.pi))
            if len(fast):
                joint = self.model.joint_names[self.model.dof_joint[fast[0]]]
                raise SimulationError(
                    f"step {self.step_count + 1} (t = {self.t + self.dt:.6g} s): joint "
                    f"{joint!r} turns {abs(qd[fast[0]]) * self.dt:.3g} rad in one step (more "
                    f"than half a turn): the simulation is diverging; reduce the time step"
                    + (" or the adaptive threshold (dropped accelerations feed energy in)"
                       if self.adaptive is not None else ""))
            self.q, self.qd = q, qd
            self.step_count += 1
            self.t = self.step_count * self.dt
        return self

    def _blow_up(self, q, qd):
        bad = np.flatnonzero(~np.isfinite(qd))
        if len(bad):
            joint = self.model.joint_names[self.model.dof_joint[bad[0]]]
        else:
            bad_q = np.flatnonzero(~np.isfinite(q))[0]
            joint = self.model.joint_names[np.searchsorted(self.model.q_start, bad_q, "right") - 1]
        raise SimulationError(
            f"step {self.step_count + 1} (t = {self.t + self.dt:.6g} s): the state became "
            f"non-finite at joint {joint!r}; the time step {self.dt} may be too large for the "
            f"model's stiffness, or a force returned NaN")
