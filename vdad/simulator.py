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

import inspect

import numpy as np

from . import dca
from ._linalg import compiling
from ._pack import pack, pack_once
from .adaptive import AdaptiveDynamics, History, rotational_dofs
from .assembly import check_tree
from .baselines import DistanceLOD, Sleeping, articulated_bodies, root_last_tree
from .camera import camera_at, check_path
from .checks import (
    check_callable,
    check_count,
    check_flag,
    check_real,
    check_vector,
    check_wrenches,
)
from .dynamics import default_tree, forward_dynamics_unchecked
from .environment import check_environment
from .errors import InputError, SimulationError
from .forces import Forces, ForceTables
from .integrators import (
    RK4,
    SEMI_IMPLICIT,
    SYMPLECTIC,
    SYMPLECTIC_HALVINGS,
    dca_steps,
    get_integrator,
    normalize_configuration,
    step_scratch,
)
from .kinematics import gimbal_lock, plan, world_poses
from .model import body_indices, check_configuration, check_model, with_implicit_damping

METHODS = ("dca", "adaptive", "view-bvh", "view-oq", "lod-distance", "sleeping")
#: the compiled step loop's scheme of each integrator (:func:`~vdad.integrators.dca_steps`)
SCHEMES = {"semi-implicit": SEMI_IMPLICIT, "rk4": RK4, "symplectic": SYMPLECTIC}
METHOD_OPTIONS = {"view-bvh": ("volume", "estimate", "pixels", "resolution"),
                  "view-oq": ("counting", "pixels", "resolution"),
                  "lod-distance": ("distance",),
                  "sleeping": ("sleep_speed", "sleep_time")}
BASELINES = ("lod-distance", "sleeping")
_ADAPTIVE = inspect.signature(AdaptiveDynamics).parameters
# AdaptiveDynamics' own options (its keyword arguments), given to Simulator as keywords
ADAPTIVE_OPTIONS = tuple(k for k in _ADAPTIVE if k not in ("model", "dt", "tree"))
ADAPTIVE_DEFAULTS = {k: _ADAPTIVE[k].default for k in ADAPTIVE_OPTIONS}    # None: not set
EXCLUSIVE = ("threshold", "budget")                 # give one; a default only if neither
# the options each method takes: none for the DCA; a coverage estimator of one's own
# only with "adaptive" (the others bring theirs); baselines run at threshold 0
OPTIONS = {m: () if m == "dca" else tuple(
    k for k in ADAPTIVE_OPTIONS if (m == "adaptive" or k != "coverage")
    and (m not in BASELINES or k not in EXCLUSIVE)) + METHOD_OPTIONS.get(m, ()) for m in METHODS}
LOD_PIXELS = 4.0                 # generic lod-distance: rigid once a body spans 4 pixels
FRAME_RATE = 60.0                # displayed frames per second: coverage once per frame


def frame_steps(dt):
    """``docs/visibility.md``, coverage per frame: the steps of ``dt`` in one
    displayed frame at :data:`FRAME_RATE` (at least 1), the default
    ``coverage_every`` of the view-dependent methods and of the baselines' switches
    (:mod:`vdad.baselines`): coverage is a property of
    what the viewer sees, and evaluating it every step changed the measured
    error by under 0.03 px on every scene at 1.2-6.7x the time per step."""
    return max(1, round(1.0 / (FRAME_RATE * dt)))


def lod_distance(model, q, camera, pixels=LOD_PIXELS):
    """``docs/scenes.md``, method defaults: the generic ``distance`` of
    ``"lod-distance"``, the distance (m) at which the largest articulated body of
    ``model`` (in configuration ``q``) spans ``pixels`` pixels on ``camera`` (its
    position at t = 0): the diameter of the sphere around its bodies' bounding
    spheres times the camera's focal length in pixels, over ``pixels``. Nearer,
    every articulated body covers more than ``pixels`` pixels and stays articulated."""
    from .bounding import body_volumes, place

    focal = camera_at(check_path(camera), 0.0).focal
    R, p = world_poses(model, q)
    v = place(body_volumes(model, "sphere"), R, p)
    r = np.maximum(v.r, 0.0)                            # bodies without geometry: points
    roots = articulated_bodies(model)
    size = 0.0
    for root in np.unique(roots):
        mine = roots == root
        centre = v.c[mine].mean(axis=0)
        size = max(size, 2 * float(np.max(np.linalg.norm(v.c[mine] - centre, axis=1)
                                          + r[mine])))
    return float(max(size, 1e-9) * focal / pixels)


# Generic defaults of each method's options, used when the caller gives neither
# threshold= nor budget= (or no distance=, ...); a callable is evaluated with those
# of model, q (q0), camera and dt that it names. A Scene's own, calibrated ones
# (Scene.defaults) come first.
DEFAULTS = {"adaptive": {"threshold": 1e-6},
            "view-bvh": {"threshold": 1e-6, "volume": "sphere", "estimate": "min",
                         "pixels": "own", "coverage_every": frame_steps},
            "view-oq": {"threshold": 1e-6, "counting": "queries", "pixels": "own",
                        "coverage_every": frame_steps},
            # the baselines are what game engines do: no energy cap
            "lod-distance": {"distance": lod_distance, "energy": "free",
                             "coverage_every": frame_steps},
            "sleeping": {"sleep_speed": 0.05, "sleep_time": 0.5, "energy": "free",
                         "coverage_every": frame_steps}}


def with_defaults(options, defaults):
    """``docs/scenes.md``, method defaults: ``options`` (a dict; None values count
    as not given) completed by ``defaults``: each default the caller did not give,
    but neither threshold nor budget when the caller gave either of them."""
    given = {k: v for k, v in options.items() if v is not None}
    skip = set(given) | (set(EXCLUSIVE) if set(EXCLUSIVE) & set(given) else set())
    return {**{k: v for k, v in defaults.items() if k not in skip}, **given}


def _alternatives(items, word="or"):
    """``"a, b or c"`` (``word`` "or" or "and")."""
    items = list(items)
    return ", ".join(items[:-1]) + f" {word} " + items[-1] if len(items) > 1 else "".join(items)


def _keywords(names, word="or"):
    """``"a=, b= or c="``: option names as the keyword arguments they are."""
    return _alternatives([f"{k}=" for k in names], word)


def method_options(model, method, q0, camera, options, dt=1e-3):
    """``docs/scenes.md``, method defaults: the options ``method`` runs with, as
    :attr:`Simulator.options` shows them: ``options`` (None values count as not
    given) completed by :data:`DEFAULTS` (a callable default evaluated with those
    of ``model``, ``q`` (``q0``), ``camera`` and the time step ``dt`` that it
    names) and AdaptiveDynamics' own defaults; a baseline's
    threshold is 0. An unknown option, or one that ``method`` does not take, is an
    :class:`InputError` naming the methods that take it."""
    unknown = sorted(set(options) - set().union(*OPTIONS.values()))
    if unknown:
        raise InputError(f"unknown option {_keywords(unknown)}; method={method!r} takes "
                         + (_keywords(OPTIONS[method], "and") or "no options"))
    given = {k: v for k, v in options.items() if v is not None}
    wrong = sorted(set(given) - set(OPTIONS[method]))
    if wrong:
        raise InputError("; ".join(
            f"{k}= applies to " + _alternatives([f"method={m!r}" for m in METHODS
                                                 if k in OPTIONS[m]])
            + f", not to method={method!r}"
            + (" (a baseline runs at threshold 0)"
               if k in EXCLUSIVE and method in BASELINES else "")
            for k in wrong))
    if (method.startswith("view") or method == "lod-distance") and camera is None:
        raise InputError(f"method={method!r} needs a camera (vdad.camera.Camera or a "
                         f"callable t -> Camera)")
    used = with_defaults(given, DEFAULTS.get(method, {}))
    for k, v in used.items():
        if callable(v) and k not in given:        # derived from the model, camera, dt
            context = {"model": model, "camera": camera, "dt": dt,
                       "q": model.q_neutral if q0 is None else
                       check_configuration(model, "q0", q0)}
            used[k] = v(**{name: context[name] for name in inspect.signature(v).parameters
                           if name in context})
    if method != "dca":                           # AdaptiveDynamics' own defaults
        used = {**{k: ADAPTIVE_DEFAULTS[k] for k in OPTIONS[method]
                   if ADAPTIVE_DEFAULTS.get(k) is not None
                   and (method != "adaptive" or k != "coverage_every")}, **used}
    if method in BASELINES:
        used["threshold"] = 0.0
    return {k: used[k] for k in (*EXCLUSIVE, *METHOD_OPTIONS.get(method, ()),
                                 *ADAPTIVE_OPTIONS) if k in used}


def compiled_forces(model, controller, external):
    """The :class:`~vdad.forces.ForceTables` that stand for ``controller`` and
    ``external`` in compiled steps: none of either, or those of one
    :class:`~vdad.forces.Forces` of vdad's own elements; else None (Python
    callables run every step)."""
    owner = getattr(external, "__self__", None) or getattr(controller, "__self__", None)
    if controller is None and external is None:
        owner = Forces(model, [])
    if not isinstance(owner, Forces) or owner.model is not model:
        return None
    if external != owner.external or controller != owner.controller:
        return None                     # not exactly that Forces' two callables
    return ForceTables.of(owner)


class Simulator:
    """Step ``model`` from ``(q0, qd0)`` with time step ``dt``.

    method: ``"dca"`` (exact forward dynamics by the DCA), ``"adaptive"``
    (:class:`~vdad.adaptive.AdaptiveDynamics`, with ``threshold=`` or
    ``budget=`` and its other options, :data:`ADAPTIVE_OPTIONS`, as keyword
    arguments), or the view-dependent methods of Kim 2008 §5, adaptive dynamics
    whose metrics are weighted by each node's screen coverage ``N_M`` under ``camera`` (a
    :class:`~vdad.camera.Camera` or a path ``t -> Camera``): ``"view-bvh"``
    from bounding volumes (options ``volume`` = ``"sphere"``, ``"obb"`` or
    ``"aabb"``, ``estimate`` = ``"min"``, ``"node"`` or ``"bodies"``;
    :class:`~vdad.visibility.BoundingVolumes`) and ``"view-oq"`` from rendered
    pixel counts with the ``environment`` as occluder (option ``counting`` =
    ``"queries"`` or ``"merged"`` on OpenGL, which needs EGL, or ``"raster"``
    on the CPU; :class:`~vdad.visibility.RenderedCounts`). Both take ``pixels``
    = ``"own"`` (the paper's: a node weighted by its own bodies' pixels) or
    ``"moved"`` (by the pixels its joints displace, ``docs/visibility.md``),
    ``resolution`` = (width, height) of the counting (default: the camera's)
    and ``coverage_every`` (steps between evaluations; default
    :func:`frame_steps`, once per displayed frame).
    Two game-engine baselines (:mod:`vdad.baselines`, on adaptive dynamics with
    ``threshold = 0`` and the :func:`~vdad.baselines.root_last_tree`):
    ``"lod-distance"`` makes whole articulated bodies rigid beyond ``distance``
    (m) from the camera, ``"sleeping"`` locks those that have moved slower
    than ``sleep_speed`` for ``sleep_time`` seconds.
    Every method runs without options (``docs/scenes.md``, method defaults):
    what is not given (None counts as not given) comes from :data:`DEFAULTS`
    (``threshold`` 1e-6 for ``"adaptive"``, ``"view-bvh"`` and ``"view-oq"``
    unless ``budget`` is given; for ``"lod-distance"`` the :func:`lod_distance`
    at which the model's largest articulated body spans :data:`LOD_PIXELS`
    pixels) and from AdaptiveDynamics' own defaults; a :class:`~vdad.scenes.Scene`
    gives its calibrated ones first. ``options`` holds the values used (empty
    for ``"dca"``). An option that no method takes, or one that this method does
    not take, is an :class:`InputError` that lists what it takes.
    integrator: ``"semi-implicit"`` (Euler: velocities first), ``"rk4"``, or
    ``"symplectic"``: symplectic Euler in momentum form, whose energy error stays
    bounded (``docs/accuracy.md``; the DCA method on hinges and slides, with vdad's
    own force elements).
    implicit_damping: integrate the joint dampers implicitly (semi-implicit Euler
    only): the step solves ``(M + dt D) qdd = tau - D qd - ...``, MuJoCo's
    implicit damping, stable for any damping and time step where explicit
    dampers diverge past ``dt d / I ~ 2`` (``docs/joints.md``, "Implicit
    damping"); the step's model is :attr:`dynamics` (:func:`~vdad.model.
    with_implicit_damping`), and :meth:`accelerations` are the step's.
    tree: assembly tree (default: balanced; for the adaptive methods on a model
    with a floating base, and for the baselines, the balanced tree with every
    joint to the world assembled last, :func:`~vdad.baselines.root_last_tree`:
    a floating base is never rigidified, nor are the nodes above its joint, so
    at the top it keeps one joint articulated per floating body instead of a
    path of them, ``docs/adaptive.md``).

    With ``"adaptive"``, ``history`` (a :class:`~vdad.adaptive.History`) holds
    the :class:`~vdad.adaptive.StepStats` of every step and ``adaptive`` the
    adaptive work state. With ``"symplectic"``, each step is taken in ``2 **
    halvings[0]`` substeps: 1 until a step's velocity solve fails to converge,
    then as many as that step needed, for the rest of the run ((S4) of
    ``docs/accuracy.md``).
    """

    def __init__(self, model, q0=None, qd0=None, dt=1e-3, method="dca",
                 integrator="semi-implicit", tree=None, controller=None, external=None,
                 camera=None, environment=None, implicit_damping=False, **adaptive_options):
        if method not in METHODS:
            raise InputError(f"unknown method {method!r}; choose one of {METHODS}")
        self.model = check_model(model)
        self.dt = float(check_real("dt", dt, positive=True))
        self.options = method_options(model, method, q0, camera, adaptive_options, self.dt)
        adaptive_options = dict(self.options)
        view = {k: adaptive_options.pop(k) for k in METHOD_OPTIONS.get(method, ())
                if k in adaptive_options}
        self.method = method
        self.integrator_name = integrator
        self._integrate = get_integrator(integrator)
        self.implicit_damping = check_flag("implicit_damping", implicit_damping)
        if self.implicit_damping and integrator != "semi-implicit":
            raise InputError(f"implicit_damping=True (--implicit-damping) applies to integrator "
                             f"'semi-implicit' (Euler), not to {integrator!r}")
        # the model the steps solve: the model itself, or with dt D in its armature
        self.dynamics = with_implicit_damping(model, self.dt) if self.implicit_damping else model
        if tree is None:
            floating = bool(np.any((model.parent < 0) & (model.nv_joint == 6)))
            tree = (root_last_tree(model) if method in BASELINES
                    or (method != "dca" and floating) else default_tree(model))
        self.tree = check_tree(model, tree)
        self.data = dca.make_data(self.tree)
        self.controller = check_callable("controller", controller, "(t, q, qd) -> tau (nv,)")
        self.external = check_callable("external", external, "(t, q, qd) -> f_ext (nb, 6)")
        self._tables = (self, self, None)       # (controller, external, their ForceTables)
        q0 = model.q_neutral if q0 is None else q0
        self.q = normalize_configuration(model, check_configuration(model, "q0", q0))
        self.qd = np.zeros(model.nv) if qd0 is None else check_vector("qd0", qd0, model.nv).copy()
        self.t = 0.0
        self.step_count = 0
        self._rotational = rotational_dofs(model)
        self.halvings = np.zeros(1, np.int64)
        # dca_steps' packs: its constants; the (force tables, pack) pair
        self._packs = (None, None)
        self.history = History()
        self.adaptive = None
        self.camera = None if camera is None else check_path(camera)
        self.environment = None if environment is None else check_environment(environment)
        if method != "dca":
            if method == "view-bvh":
                from .visibility import BoundingVolumes

                adaptive_options["coverage"] = BoundingVolumes(self.tree, camera, **view)
            elif method == "view-oq":
                from .visibility import RenderedCounts

                adaptive_options["coverage"] = RenderedCounts(
                    self.tree, camera, environment, method=view.get("counting", "queries"),
                    resolution=view.get("resolution"), pixels=view.get("pixels", "own"))
            elif method == "lod-distance":
                adaptive_options["coverage"] = DistanceLOD(self.tree, camera, **view)
            elif method == "sleeping":
                adaptive_options["coverage"] = Sleeping(self.tree, **view)
            self.adaptive = AdaptiveDynamics(self.dynamics, self.dt, self.tree,
                                             **adaptive_options)
        if integrator == "symplectic":
            self._check_symplectic()

    def __getstate__(self):
        """A copy (``copy.deepcopy``, pickle) leaves the packs of :meth:`_compiled_steps`
        out: numba cannot copy them, and they hold this simulator's arrays."""
        return {**self.__dict__, "_packs": (None, None)}

    def _check_symplectic(self):
        """The symplectic integrator's conditions (:func:`~vdad.integrators.
        symplectic_step`), or an InputError naming what is not met."""
        what = "integrator 'symplectic' (symplectic Euler in momentum form)"
        if self.method != "dca":
            raise InputError(f"{what} runs the DCA only; use method='dca', or integrator "
                             f"'semi-implicit' or 'rk4' with method {self.method!r}")
        model = self.model
        bad = np.flatnonzero(model.stage_kind > 1)
        if len(bad):
            joint = model.joint_names[model.stage_joint[bad[0]]]
            raise InputError(f"{what} needs joints of hinges and slides (coordinates whose "
                             f"rates are the velocities); joint {joint!r} has a ball or a "
                             f"translation stage: use integrator 'semi-implicit' or 'rk4'")
        if self.force_tables() is None:
            raise InputError(f"{what} runs in compiled code with vdad's own force elements "
                             f"(vdad.forces.Forces) as controller and external; Python "
                             f"callables need integrator 'semi-implicit' or 'rk4'")

    def body_poses(self, bodies=None):
        """World poses ``R`` (k, 3, 3), ``p`` (k, 3) of ``bodies`` (names or indices;
        default all) in the current state. With ``"adaptive"`` only the active joints and
        the requested bodies' rigid groups are evaluated."""
        bodies = None if bodies is None else body_indices(self.model, bodies)
        if self.adaptive is not None:
            return self.adaptive.body_poses(self.q, bodies)
        R, p = world_poses(self.model, self.q)
        return (R, p) if bodies is None else (R[bodies], p[bodies])

    def accelerations(self, t, q, qd):
        """``qdd`` at ``(t, q, qd)`` with the simulator's forces."""
        if not (np.all(np.isfinite(q)) and np.all(np.isfinite(qd))):
            self._blow_up(q, qd)
        tau = None if self.controller is None else check_vector(
            "controller(t, q, qd)", self.controller(t, q, qd), self.model.nv)
        f_ext = None if self.external is None else check_wrenches(
            self.model, self.external(t, q, qd), "external(t, q, qd)")
        return forward_dynamics_unchecked(self.dynamics, q, qd, tau, f_ext, self.data)

    def step(self, n=1):
        """Advance ``n`` steps (a whole number >= 0); returns ``self``. With
        ``"dca"`` and no Python forces (no ``controller`` or ``external``, or those
        of a :class:`~vdad.forces.Forces` of vdad's own elements), the steps run in
        compiled code (:func:`vdad.integrators.dca_steps`), with the same checks."""
        n = check_count("n", n, minimum=0)
        if self.adaptive is None and self.force_tables() is not None:
            return self._compiled_steps(n)
        return self._python_steps(n)

    def _python_steps(self, n):
        """``n`` steps from Python: the DCA with Python forces, or adaptive dynamics,
        whose built-in force elements are evaluated in compiled code from the
        tables of each chunk of steps (:meth:`_tables_for`)."""
        while n > 0:
            m = min(n, self.CHUNK)
            F = self._tables_for(m)
            if self._adaptive_loop(F):
                self._run_adaptive(m, F)
                n -= m
                continue
            for k in range(m):
                try:
                    if self.adaptive is None:
                        q, qd = self._integrate(self.model, self.accelerations, self.t, self.q,
                                                self.qd, self.dt)
                    else:
                        q, qd = self.q.copy(), self.qd.copy()
                        tables = None if F is None else (F, k * (4 if self._rk4 else 1))
                        self.history.append(self.adaptive.step(
                            self.t, q, qd, self._integrate, self.controller, self.external,
                            tables))
                except InputError as exc:
                    raise SimulationError(f"step {self.step_count + 1} (t = {self.t:.6g} s): "
                                          f"{exc}") from exc
                self._check_step(q, qd)
                self.q, self.qd = q, qd
                self._advance(1)
            n -= m
        return self

    def _adaptive_loop(self, F):
        """Whether adaptive steps can run in compiled code (:meth:`_run_adaptive`):
        :attr:`adaptive_loop`, semi-implicit Euler, and forces that are vdad's own
        elements (tables ``F``) or none at all."""
        if self.adaptive is None or not self.adaptive_loop or self._rk4:
            return False
        if F is not None:
            return True
        return (self.controller is None and self.external is None
                and not self.adaptive.groups.any_force)

    def _run_adaptive(self, m, F):
        """``m`` adaptive steps in compiled code (:meth:`AdaptiveDynamics.run`, one
        call per stretch between coverage evaluations), with the same history,
        checks and errors as one step at a time."""
        done = 0
        while done < m:
            q, qd = self.q.copy(), self.qd.copy()
            try:
                k, status, q_last, qd_last = self.adaptive.run(
                    m - done, self.step_count, q, qd, self._rotational,
                    None if F is None else (F, done), self.history)
            except InputError as exc:              # from the coverage estimator
                raise SimulationError(f"step {self.step_count + 1} (t = {self.t:.6g} s): "
                                      f"{exc}") from exc
            self._advance(k)
            done += k
            if status == 0:
                self.q, self.qd = q, qd
                continue
            self.q, self.qd = q_last.copy(), qd_last.copy()
            if status == 1:
                raise SimulationError(f"step {self.step_count + 1} (t = {self.t:.6g} s): "
                                      f"{self.adaptive.not_finite()}")
            self._check_step(q, qd)

    def _tables_for(self, m):
        """With adaptive dynamics and forces of vdad's own elements only, their
        :meth:`~vdad.forces.ForceTables.arrays` for the next ``m`` steps; else (or
        where a moving anchor fails: its Python callable names the step) None."""
        if self.adaptive is None or (self.controller is None and self.external is None):
            return None
        tables = self.force_tables()
        if tables is None:
            return None
        try:
            return tables.arrays(self.step_count, m, self.dt, self._rk4)
        except InputError:
            return None

    CHUNK = 512          # compiled steps per call: bounds the time-dependent force tables
    #: adaptive steps by semi-implicit Euler run in compiled code where the forces
    #: allow (AdaptiveDynamics.run); False: one Python-level step at a time, each
    #: phase timed apart (StepStats.times)
    adaptive_loop = True

    def force_tables(self):
        """The :class:`~vdad.forces.ForceTables` of the current ``controller`` and
        ``external`` (:func:`compiled_forces`; None: they run in Python)."""
        controller, external, tables = self._tables
        if controller != self.controller or external != self.external:
            tables = compiled_forces(self.model, self.controller, self.external)
            self._tables = (self.controller, self.external, tables)
        return tables

    @property
    def _rk4(self):
        return self.integrator_name == "rk4"

    def _compiled_steps(self, n):
        scheme = SCHEMES[self.integrator_name]
        q_new, qd_new = np.empty_like(self.q), np.empty_like(self.qd)
        q, qd = self.q.copy(), self.qd.copy()
        constants, tables = self._packs
        if constants is None:
            constants = pack((plan(self.dynamics).arrays, self.data.layout,
                              dca.body_arrays(self.dynamics), dca.inert_arrays(self.dynamics),
                              self._rotational, self.data.kin.arrays, self.data.arrays,
                              self.halvings,
                              step_scratch(self.model.nq, self.model.nv, self.model.nb)))
        while n > 0:
            m = min(n, self.CHUNK)
            try:
                F = self.force_tables().arrays(self.step_count, m, self.dt, self._rk4)
            except InputError:              # a moving anchor failed: find its step in Python
                self.q, self.qd = q, qd
                return self._python_steps(n)
            tables = pack_once(tables, F)
            self._packs = (constants, tables)
            with compiling(dca_steps):
                done, status = dca_steps(m, self.dt, self.step_count, scheme, constants,
                                         tables[1], q, qd, q_new, qd_new)
            self.q, self.qd = q.copy(), qd.copy()
            self._advance(done)
            if status == 3:
                raise SimulationError(
                    f"step {self.step_count + 1} (t = {self.t:.6g} s): the symplectic step's "
                    f"fixed-point iteration does not converge, even in "
                    f"{2 ** SYMPLECTIC_HALVINGS} substeps: reduce the time step")
            if status:
                self._check_step(q_new, qd_new)
            n -= m
        return self

    def _advance(self, steps):
        self.step_count += steps
        self.t = self.step_count * self.dt

    def _check_step(self, q, qd):
        """The checks of a step's new state ``(q, qd)``: a SimulationError if it is
        not finite or turns a rotational dof by more than half a turn. With adaptive
        dynamics only the active joints change, and a compiled check of those
        comes first (the full one runs to name the joint when it fails)."""
        if self.adaptive is not None and self.adaptive.state_ok(q, qd, self._rotational):
            return
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
                   if self.adaptive is not None else "")
                + ("; or the forces of controller / external are too large"
                   if self.controller is not None or self.external is not None else ""))

    def _blow_up(self, q, qd):
        lock = gimbal_lock(self.model, self.q)
        if lock is not None:
            raise SimulationError(f"step {self.step_count + 1} (t = {self.t:.6g} s): {lock}")
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
