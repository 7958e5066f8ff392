"""The paper's scenes (Kim 2008 §6.1). Each function returns a :class:`Scene`."""

from .base import Scene, rod
from .character import falling_character, humanoid
from .dogs import dog_puppet, hanging_dogs, toy_dog
from .mjcf import mjcf_scene
from .pendulum import pendulum

SCENES = {"pendulum": pendulum, "dog_puppet": dog_puppet, "hanging_dogs": hanging_dogs,
          "falling_character": falling_character}

__all__ = ["SCENES", "Scene", "dog_puppet", "falling_character", "hanging_dogs", "humanoid",
           "mjcf_scene", "pendulum", "rod", "toy_dog"]
