"""A scene: a model, its initial state, time step and the forces that drive it;
and :func:`rod`, the capsule link the scenes are built from."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..checks import check_real, check_vector, show
from ..errors import InputError
from ..model import Body, Geom, Pose
from ..simulator import METHODS, Simulator, with_defaults


def rod(name, mass, a, b, radius, rgba=(0.7, 0.7, 0.7, 1.0)) -> Body:
    """A body ``name`` that is a solid rod of ``mass`` from point ``a`` to ``b``
    (body frame) with ``radius``, drawn as a capsule: centre of mass at the
    middle, inertia of a cylinder of that length, ``m (3 r^2 + L^2) / 12`` across
    and ``m r^2 / 2`` along the axis."""
    what = f"rod {name!r}:"
    mass = float(check_real(f"{what} mass", mass, positive=True))
    radius = float(check_real(f"{what} radius", radius, positive=True))
    a, b = check_vector(f"{what} a", a, 3), check_vector(f"{what} b", b, 3)
    L = float(np.linalg.norm(b - a))
    if not L > 0:
        raise InputError(f"{what} its ends a and b must differ (length 0), got a = b = "
                         f"{show(a.tolist())}")
    u = (b - a) / L
    across, along = mass * (3 * radius**2 + L**2) / 12, mass * radius**2 / 2
    inertia = across * (np.eye(3) - np.outer(u, u)) + along * np.outer(u, u)
    # the capsule's axis is its z: rotate z onto u (Rodrigues, half-way vector)
    h = u + (0.0, 0.0, 1.0)
    R = (2 * np.outer(h, h) / (h @ h) - np.eye(3) if h @ h > 1e-12
         else np.diag([1.0, -1.0, -1.0]))
    half = max(L / 2 - radius, 1e-3 * L)
    geom = Geom("capsule", (radius, half), Pose(tuple((a + b) / 2), R), rgba=tuple(rgba))
    return Body(name, mass, tuple((a + b) / 2), inertia, (geom,))


@dataclass(frozen=True)
class Scene:
    """What :func:`vdad.scenes` functions return.

    name, description: what the scene models (shown by ``vdad run``).
    model, q0, qd0, dt: the model and its initial state and time step.
    controller, external: force callables passed to :class:`~vdad.Simulator`;
    forces: the :class:`~vdad.forces.Forces` they come from, if any (to inspect
    springs and contacts, or their energy).
    camera: the viewer (:class:`~vdad.camera.Camera` or a path ``t -> Camera``)
    and environment: static occluders (:class:`~vdad.environment.Environment`),
    both for the view-dependent methods and for pictures.
    params: the parameters the scene was built with.
    defaults: the scene's own method options, {method: {option: value}},
    calibrated on the scene at its default parameters (``docs/scenes.md``: a
    threshold whose measured error is small, a distance from its camera);
    :meth:`simulator` uses them for what the caller does not give.
    """

    name: str
    description: str
    model: object
    q0: np.ndarray
    qd0: np.ndarray
    dt: float
    controller: object = None
    external: object = None
    camera: object = None
    environment: object = None
    forces: object = None
    params: dict = field(default_factory=dict)
    defaults: dict = field(default_factory=dict)

    def __post_init__(self):
        if not isinstance(self.defaults, dict):
            raise InputError(f"scene {self.name!r}: defaults must be a dict {{method: {{option: "
                             f"value}}}}, got {type(self.defaults).__name__}: "
                             f"{show(self.defaults)}")
        wrong = sorted(set(self.defaults) - set(METHODS), key=str)
        if wrong:
            raise InputError(f"scene {self.name!r}: defaults for unknown methods {wrong}; "
                             f"methods are {METHODS}")
        for method, options in self.defaults.items():
            if not (isinstance(options, dict) and all(isinstance(k, str) for k in options)):
                raise InputError(f"scene {self.name!r}: defaults[{method!r}] must be a dict "
                                 f"{{option: value}}, got {show(options)}")

    def simulator(self, **options) -> Simulator:
        """``docs/scenes.md``, method defaults: a :class:`~vdad.Simulator` started at
        this scene's initial state, with its forces, time step, camera and
        environment unless ``options`` say otherwise (``q0=``, ``controller=``,
        ...). The method's options that the caller does not give (neither
        ``threshold`` nor ``budget``, no ``distance``, ...) come from
        :attr:`defaults` (by :func:`~vdad.simulator.with_defaults`), then from the
        Simulator's generic :data:`~vdad.simulator.DEFAULTS`; ``sim.options`` shows
        those used."""
        options = {**options, **with_defaults(
            options, self.defaults.get(options.get("method", "dca"), {}))}
        for name in ("q0", "qd0", "dt", "controller", "external", "camera", "environment"):
            options.setdefault(name, getattr(self, name))
        return Simulator(self.model, **options)
