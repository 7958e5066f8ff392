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

from .checks import check_real, check_vector, show
from .errors import InputError
from .model import Geom, Pose


@dataclass(frozen=True)
class Environment:
    """Static world geometry: ``geoms`` (tuple of :class:`~vdad.model.Geom`,
    poses in world coordinates)."""

    geoms: tuple = ()

    def __post_init__(self):
        geoms = self.geoms
        if isinstance(geoms, Geom) or not isinstance(geoms, (tuple, list)):
            raise InputError(f"environment geoms must be a tuple of vdad.Geom, got "
                             f"{type(geoms).__name__}: {show(geoms)}")
        for i, g in enumerate(geoms):
            if not isinstance(g, Geom):
                raise InputError(f"environment geom {i} must be a vdad.Geom, got "
                                 f"{type(g).__name__}: {show(g)}")
        object.__setattr__(self, "geoms", tuple(geoms))

    def __add__(self, other):
        """The geoms of both environments (``other`` must be an Environment)."""
        if not isinstance(other, Environment):
            raise InputError(f"only a vdad.environment.Environment can be added to an "
                             f"Environment, got {type(other).__name__}: {show(other)}")
        return Environment(self.geoms + other.geoms)

    def __radd__(self, other):
        raise InputError(f"only a vdad.environment.Environment can be added to an "
                         f"Environment, got {type(other).__name__}: {show(other)}")

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
    c = check_vector("box center", center, 3)
    h = check_vector("box half_extents", half_extents, 3)
    if np.any(h <= 0):
        raise InputError(f"box half_extents must be 3 positive numbers, got {show(half_extents)}")
    return Environment((Geom("box", tuple(h), Pose(tuple(c), rotation), rgba=rgba),))


def floor(height=0.0, size=20.0, thickness=0.05, rgba=(0.5, 0.5, 0.5, 1.0)) -> Environment:
    """A square floor slab of side ``size`` whose top face is at ``z = height``
    (``thickness`` is its half-thickness, the box's half-extent along z)."""
    height = float(check_real("floor height", height))
    size = float(check_real("floor size", size, positive=True))
    thickness = float(check_real("floor thickness", thickness, positive=True))
    return box((0.0, 0.0, height - thickness), (size / 2, size / 2, thickness), rgba=rgba)


def wall(start, end, height=2.0, thickness=0.05, base=0.0,
         rgba=(0.65, 0.6, 0.55, 1.0)) -> Environment:
    """A vertical wall from ``start`` to ``end`` ((x, y) points on the floor),
    ``height`` m tall from ``z = base``."""
    a, b = check_vector("wall start", start, 2), check_vector("wall end", end, 2)
    height = float(check_real("wall height", height, positive=True))
    thickness = float(check_real("wall thickness", thickness, positive=True))
    base = float(check_real("wall base", base))
    with np.errstate(over="ignore", under="ignore", invalid="ignore"):
        d = b - a
        length = float(np.linalg.norm(d))
    if length == 0:
        raise InputError(f"a wall needs two distinct (x, y) points (a wall of zero length), "
                         f"got start={show(start)}, end={show(end)}")
    if not np.isfinite(length):
        raise InputError(f"wall start {show(start)} and end {show(end)} are too far apart "
                         f"(the length overflows)")
    angle = np.arctan2(d[1], d[0])
    quat = (np.cos(angle / 2), 0.0, 0.0, np.sin(angle / 2))
    mid = (a + b) / 2
    return box((mid[0], mid[1], base + height / 2), (length / 2, thickness / 2, height / 2),
               quat, rgba)
