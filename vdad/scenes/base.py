"""A scene: a model, its initial state, time step and the forces that drive it."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..simulator import Simulator


@dataclass(frozen=True)
class Scene:
    """What :func:`vdad.scenes` functions return.

    name, description: what the scene models (shown by ``vdad run``).
    model, q0, qd0, dt: the model and its initial state and time step.
    controller, external: force callables passed to :class:`~vdad.Simulator`.
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
    params: dict = field(default_factory=dict)

    def simulator(self, **options) -> Simulator:
        """A :class:`~vdad.Simulator` started at this scene's initial state."""
        options.setdefault("dt", self.dt)
        options.setdefault("camera", self.camera)
        options.setdefault("environment", self.environment)
        return Simulator(self.model, self.q0, self.qd0, controller=self.controller,
                         external=self.external, **options)
