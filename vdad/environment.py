"""Environment geometry: floors, walls and boxes that belong to a scene, occlude
bodies and are never simulated (Kim 2008 §5.4: "other objects in the environment").

An :class:`Environment` is a tuple of :class:`~vdad.model.Geom` placed in world
coordinates (each geom's ``pose`` is its world pose). The rendered visibility
draws it into the depth buffer so that it hides the bodies behind it; the
bounding-volume estimates ignore it (they model no occlusion).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .errors import InputError
from .model import Geom, Pose


@dataclass(frozen=True)
class Environment:
    """Static world geometry: ``geoms`` (tuple of :class:`~vdad.model.Geom`,
    poses in world coordinates)."""

    geoms: tuple = ()

    def __post_init__(self):
        geoms = tuple(self.geoms)
        for i, g in enumerate(geoms):
            if not isinstance(g, Geom):
                raise InputError(f"environment geom {i} must be a vdad.Geom, got "
                                 f"{type(g).__name__}")
        object.__setattr__(self, "geoms", geoms)

    def __add__(self, other):
        return Environment(self.geoms + Environment(other.geoms).geoms)

    def to_trimesh(self):
        """All geoms as one trimesh.Trimesh in world coordinates (None if empty)."""
        import trimesh

        if not self.geoms:
            return None
        return trimesh.util.concatenate([g.to_trimesh() for g in self.geoms])


def check_environment(environment) -> Environment:
    """``environment`` checked: an :class:`Environment`, or None for an empty one."""
    environment = Environment() if environment is None else environment
    if not isinstance(environment, Environment):
        raise InputError(f"environment must be a vdad.environment.Environment or None, got "
                         f"{type(environment).__name__}")
    return environment


def box(center, half_extents, rotation=None, rgba=(0.6, 0.6, 0.65, 1.0)) -> Environment:
    """A box with ``half_extents`` (3,) centred at ``center`` (3,), rotated by
    ``rotation`` (3x3 matrix or quaternion w, x, y, z)."""
    h = np.asarray(half_extents, float)
    if h.shape != (3,) or not np.all(np.isfinite(h)) or np.any(h <= 0):
        raise InputError(f"box half_extents must be 3 positive numbers, got {half_extents!r}")
    c = np.asarray(center, float)
    if c.shape != (3,) or not np.all(np.isfinite(c)):
        raise InputError(f"box center must be 3 finite numbers, got {center!r}")
    return Environment((Geom("box", tuple(h), Pose(tuple(c), rotation), rgba=rgba),))


def floor(height=0.0, size=20.0, thickness=0.05, rgba=(0.5, 0.5, 0.5, 1.0)) -> Environment:
    """A square floor slab of side ``size`` whose top face is at ``z = height``."""
    return box((0.0, 0.0, height - thickness), (size / 2, size / 2, thickness), rgba=rgba)


def wall(start, end, height=2.0, thickness=0.05, base=0.0,
         rgba=(0.65, 0.6, 0.55, 1.0)) -> Environment:
    """A vertical wall from ``start`` to ``end`` ((x, y) points on the floor),
    ``height`` m tall from ``z = base``."""
    a, b = np.asarray(start, float), np.asarray(end, float)
    if a.shape != (2,) or b.shape != (2,) or np.allclose(a, b):
        raise InputError(f"a wall needs two distinct (x, y) points, got {start!r}, {end!r}")
    d = b - a
    angle = np.arctan2(d[1], d[0])
    quat = (np.cos(angle / 2), 0.0, 0.0, np.sin(angle / 2))
    mid = (a + b) / 2
    return box((mid[0], mid[1], base + height / 2),
               (np.linalg.norm(d) / 2, thickness / 2, height / 2), quat, rgba)
