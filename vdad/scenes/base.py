"""A scene: a model, its initial state, time step and the forces that drive it;
and :func:`rod`, the capsule link the scenes are built from."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..errors import InputError
from ..model import Body, Geom, Pose
from ..simulator import Simulator


def rod(name, mass, a, b, radius, rgba=(0.7, 0.7, 0.7, 1.0)) -> Body:
    """A body ``name`` that is a solid rod of ``mass`` from point ``a`` to ``b``
    (body frame) with ``radius``, drawn as a capsule: centre of mass at the
    middle, inertia of a cylinder of that length, ``m (3 r^2 + L^2) / 12`` across
    and ``m r^2 / 2`` along the axis."""
    a, b = np.asarray(a, float), np.asarray(b, float)
    L = float(np.linalg.norm(b - a))
    if not (mass > 0 and radius > 0 and L > 0):
        raise InputError(f"rod {name!r}: mass, radius and length must be positive, got "
                         f"{mass}, {radius}, {L}")
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

    def simulator(self, **options) -> Simulator:
        """A :class:`~vdad.Simulator` started at this scene's initial state."""
        options.setdefault("dt", self.dt)
        options.setdefault("camera", self.camera)
        options.setdefault("environment", self.environment)
        return Simulator(self.model, self.q0, self.qd0, controller=self.controller,
                         external=self.external, **options)
