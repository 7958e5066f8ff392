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
    params: dict = field(default_factory=dict)

    def simulator(self, **options) -> Simulator:
        """A :class:`~vdad.Simulator` started at this scene's initial state."""
        options.setdefault("dt", self.dt)
        return Simulator(self.model, self.q0, self.qd0, controller=self.controller,
                         external=self.external, **options)
