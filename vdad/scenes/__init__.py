"""The paper's scenes (Kim 2008 §6.1). Each function returns a :class:`Scene`."""

from .base import Scene
from .pendulum import pendulum

SCENES = {"pendulum": pendulum}

__all__ = ["SCENES", "Scene", "pendulum"]
