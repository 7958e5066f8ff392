"""The viewer: a perspective pinhole camera and camera paths (Kim 2008 §5.2, the view ``M``).

Conventions are pyrender's (and OpenGL's): the camera frame has ``x`` to the
right, ``y`` up and looks down ``-z``; :attr:`Camera.pose` is the camera-to-world
transform that a pyrender camera node takes; the vertical field of view is
``yfov`` and pixels are square, so ``fx = fy = (height / 2) / tan(yfov / 2)``.
Image coordinates in vdad are continuous pixels with the origin at the bottom-left
corner of the viewport, ``x`` right and ``y`` up, so the viewport is
``[0, width] x [0, height]`` and pixel ``(i, j)`` (column, row from the bottom)
covers ``[i, i + 1] x [j, j + 1]``. The depth of a point is its distance in front
of the camera plane, ``d = -z``.

A camera path is any callable ``t -> Camera``; a :class:`Camera` is itself a
(constant) path, and :class:`Dolly`, :class:`Orbit` and :class:`Keyframes` move
it in time.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from functools import cached_property

import numpy as np

from .checks import check_count, check_real, check_vector, real_array, show
from .errors import InputError


def _pixels(name, value):
    """``value`` as an int number of pixels (a whole number >= 1), or an error."""
    try:
        return check_count(name, value)
    except InputError:
        raise InputError(f"{name} must be a positive whole number of pixels, got "
                         f"{show(value)}") from None


def _direction(v):
    """``v`` (3,) scaled so that its largest entry is 1 in magnitude (no under- or
    overflow, unlike dividing by its norm)."""
    return v / np.abs(v).max()


def _time(t):
    """The time ``t`` of a camera path as a float, or an error naming it."""
    if isinstance(t, float) and math.isfinite(t):     # the common case, in a path's call
        return float(t)
    return float(check_real("camera path time t", t))


@dataclass(frozen=True)
class Camera:
    """A perspective camera at ``position`` looking at ``target`` with ``up`` the
    world direction shown upwards; ``yfov`` (rad), ``width`` x ``height`` pixels,
    near and far clipping planes ``znear`` < ``zfar`` (m). Checked on construction
    and stored as tuples, floats and ints."""

    position: tuple = (3.0, 0.0, 0.0)
    target: tuple = (0.0, 0.0, 0.0)
    up: tuple = (0.0, 0.0, 1.0)
    yfov: float = np.pi / 3
    width: int = 320
    height: int = 240
    znear: float = 0.05
    zfar: float = 100.0

    def __post_init__(self):
        pos, tgt, up = (check_vector(f"camera {n}", getattr(self, n), 3)
                        for n in ("position", "target", "up"))
        with np.errstate(over="ignore", invalid="ignore"):
            forward = tgt - pos
        if not np.all(np.isfinite(forward)):
            raise InputError(f"camera target {show(self.target)} is too far from its position "
                             f"{show(self.position)} (the difference overflows)")
        if not np.any(forward):
            raise InputError(f"camera target must differ from its position, both are "
                             f"{show(self.position)}")
        if not np.any(up):
            raise InputError("camera up must be a nonzero vector, got (0, 0, 0)")
        f, u = _direction(forward), _direction(up)
        with np.errstate(under="ignore"):
            sine = np.linalg.norm(np.cross(f, u)) / (np.linalg.norm(f) * np.linalg.norm(u))
        if sine <= 1e-12:
            raise InputError(f"camera up {tuple(up.tolist())} is parallel to the viewing "
                             f"direction {tuple(forward.tolist())}")
        yfov = float(check_real("camera yfov", self.yfov))
        if not 0 < yfov < np.pi:
            raise InputError(f"camera yfov must be in (0, pi) rad, got {show(self.yfov)}")
        width, height = (_pixels(f"camera {n}", getattr(self, n)) for n in ("width", "height"))
        znear, zfar = (float(check_real(f"camera {n}", getattr(self, n)))
                       for n in ("znear", "zfar"))
        if not 0 < znear < zfar:
            raise InputError(f"camera planes need 0 < znear < zfar, got znear={show(self.znear)}, "
                             f"zfar={show(self.zfar)}")
        for name, value in (("position", tuple(pos.tolist())), ("target", tuple(tgt.tolist())),
                            ("up", tuple(up.tolist())), ("yfov", yfov), ("width", width),
                            ("height", height), ("znear", znear), ("zfar", zfar)):
            object.__setattr__(self, name, value)

    def __call__(self, t):
        """A camera is the constant path: the same camera at every time ``t``."""
        return self

    def _moved(self, position, rotation):
        """This camera at ``position`` (3,) with axes ``rotation`` (3, 3), both made by
        a path from this valid camera (the target, the up vector and the angle
        between them and the viewing direction kept), so unchecked but for a
        finite position: a path's camera in microseconds instead of a checked one's
        third of a millisecond."""
        position = tuple(map(float, position))
        if not all(map(math.isfinite, position)):
            raise InputError(f"camera path left the finite numbers: position {position}")
        out = object.__new__(Camera)
        out.__dict__.update(self.__dict__)
        if not (isinstance(rotation, np.ndarray) and rotation.dtype == float
                and not rotation.flags.writeable):      # a read-only array is kept as is
            rotation = np.array(rotation, float)
            rotation.setflags(write=False)
        out.__dict__.update(position=position, rotation=rotation)
        return out

    def with_resolution(self, width, height):
        """The same view (position, direction, ``yfov``) at another resolution."""
        return replace(self, width=width, height=height)

    @cached_property
    def rotation(self) -> np.ndarray:
        """Camera axes in world coordinates (3, 3), read-only: columns ``x``
        (right), ``y`` (up), ``z`` (backwards)."""
        pos, tgt, up = (np.asarray(v, float) for v in (self.position, self.target, self.up))
        z = _direction(pos - tgt)
        z /= np.linalg.norm(z)
        x = _direction(np.cross(_direction(up), z))
        x /= np.linalg.norm(x)
        R = np.stack([x, np.cross(z, x), z], axis=1)
        R.setflags(write=False)
        return R

    @property
    def pose(self) -> np.ndarray:
        """Camera-to-world transform (4, 4): a pyrender camera node's pose."""
        T = np.eye(4)
        T[:3, :3], T[:3, 3] = self.rotation, self.position
        return T

    @property
    def view(self) -> np.ndarray:
        """World-to-camera transform (4, 4), the view matrix ``M``."""
        R = self.rotation
        T = np.eye(4)
        T[:3, :3], T[:3, 3] = R.T, -R.T @ np.asarray(self.position, float)
        return T

    @property
    def focal(self) -> float:
        """Focal length in pixels, ``fx = fy``."""
        return 0.5 * self.height / np.tan(0.5 * self.yfov)

    @property
    def projection(self) -> np.ndarray:
        """OpenGL projection matrix (4, 4), as pyrender's ``PerspectiveCamera``
        with ``aspectRatio = width / height``."""
        n, f = self.znear, self.zfar
        t = np.tan(0.5 * self.yfov)
        P = np.zeros((4, 4))
        P[0, 0] = self.height / (self.width * t)
        P[1, 1] = 1.0 / t
        P[2, 2] = (f + n) / (n - f)
        P[2, 3] = 2 * f * n / (n - f)
        P[3, 2] = -1.0
        return P

    def to_camera(self, points):
        """Camera coordinates (..., 3) of world ``points`` (..., 3)."""
        p = real_array("points", points)
        if p.shape[-1:] != (3,):
            raise InputError(f"points must have shape (..., 3) (world x, y, z), got {p.shape}")
        return (p - np.asarray(self.position)) @ self.rotation

    def project(self, points):
        """Image coordinates (..., 2) in pixels and depth (...,) of world ``points``
        (..., 3) (points behind the camera give meaningless image coordinates)."""
        c = self.to_camera(points)
        d = -c[..., 2]
        with np.errstate(divide="ignore", invalid="ignore"):
            xy = self.focal * c[..., :2] / d[..., None]
        return xy + 0.5 * np.array([self.width, self.height]), d


def _interpolate(t, times, values):
    """Piecewise-linear interpolation of rows ``values`` (k, m) at ``t`` (clamped)."""
    return np.array([np.interp(t, times, values[:, i]) for i in range(values.shape[1])])


@dataclass(frozen=True)
class Dolly:
    """The camera moves along its viewing axis at ``speed`` (m/s; positive: away
    from the target), starting at ``camera`` at time ``start``."""

    camera: Camera
    speed: float
    start: float = 0.0

    def __post_init__(self):
        _check_camera("dolly camera", self.camera)
        object.__setattr__(self, "speed", float(check_real("dolly speed", self.speed)))
        object.__setattr__(self, "start", float(check_real("dolly start", self.start)))

    def __call__(self, t):
        pos, back, reach = self._axis
        s = max(_time(t) - self.start, 0.0) * self.speed
        s = max(s, -reach)                                     # never pass the target
        return self.camera._moved(pos + s * back, self.camera.rotation)

    @cached_property
    def _axis(self):
        """The start position (3,), the unit vector from the target to it (3,) and
        the distance the camera may move towards the target."""
        c = self.camera
        pos, tgt = np.asarray(c.position, float), np.asarray(c.target, float)
        d = np.linalg.norm(pos - tgt)
        return pos, (pos - tgt) / d, d * (1 - 1e-6)


@dataclass(frozen=True)
class Orbit:
    """The camera circles ``camera.target`` about the world axis ``camera.up``
    once every ``period`` seconds (negative: clockwise), keeping its distance and
    height."""

    camera: Camera
    period: float

    def __post_init__(self):
        _check_camera("orbit camera", self.camera)
        period = float(check_real("orbit period", self.period))
        if period == 0:
            raise InputError(f"orbit period must be a non-zero number of seconds, "
                             f"got {show(self.period)}")
        object.__setattr__(self, "period", period)

    def __call__(self, t):
        c = self.camera
        axis = np.asarray(c.up, float) / np.linalg.norm(c.up)
        tgt = np.asarray(c.target, float)
        r = np.asarray(c.position, float) - tgt
        a = 2 * np.pi * _time(t) / self.period
        K = np.array([[0.0, -axis[2], axis[1]], [axis[2], 0.0, -axis[0]],
                      [-axis[1], axis[0], 0.0]])
        turn = np.eye(3) + np.sin(a) * K + (1 - np.cos(a)) * (K @ K)   # Rodrigues, about up
        return c._moved(tgt + turn @ r, turn @ c.rotation)


@dataclass(frozen=True)
class Keyframes:
    """Cameras at increasing ``times``, interpolated linearly in between
    (position, target, up and ``yfov``) and held before the first and after the
    last; resolution and planes are the first camera's."""

    times: tuple
    cameras: tuple

    def __post_init__(self):
        cameras = self.cameras
        if isinstance(cameras, Camera) or not isinstance(cameras, (tuple, list)):
            raise InputError(f"keyframe cameras must be a tuple of vdad.camera.Camera, got "
                             f"{type(cameras).__name__}: {show(cameras)}")
        for i, c in enumerate(cameras):
            _check_camera(f"keyframe camera {i}", c)
        times = real_array("keyframe times", self.times)
        if times.ndim != 1:
            raise InputError(f"keyframe times must be a sequence of numbers, got "
                             f"{show(self.times)}")
        if len(times) != len(cameras) or len(times) == 0:
            raise InputError(f"keyframes need as many times as cameras (at least one), got "
                             f"{len(times)} times and {len(cameras)} cameras")
        if not np.all(np.isfinite(times)) or np.any(np.diff(times) <= 0):
            raise InputError(f"keyframe times must be finite and increasing, got "
                             f"{show(self.times)}")
        object.__setattr__(self, "times", tuple(times.tolist()))
        object.__setattr__(self, "cameras", tuple(cameras))

    def __call__(self, t):
        times = np.asarray(self.times)
        rows = np.array([[*c.position, *c.target, *c.up, c.yfov] for c in self.cameras])
        v = _interpolate(_time(t), times, rows)
        return replace(self.cameras[0], position=tuple(v[:3]), target=tuple(v[3:6]),
                       up=tuple(v[6:9]), yfov=float(v[9]))


def _check_camera(name, camera):
    """An error naming ``name`` unless ``camera`` is a :class:`Camera`."""
    if not isinstance(camera, Camera):
        raise InputError(f"{name} must be a vdad.camera.Camera, got "
                         f"{type(camera).__name__}: {show(camera)}")


def check_path(camera):
    """``camera`` checked to be a :class:`Camera` or a callable ``t -> Camera``."""
    if not callable(camera):
        raise InputError(f"camera must be a vdad.camera.Camera or a callable t -> Camera, "
                         f"got {type(camera).__name__}")
    return camera


def check_resolution(resolution, allow_none=True):
    """``resolution`` (width, height) in pixels as two ints, or None (the camera's)
    if ``allow_none``; else an InputError naming ``resolution``."""
    if resolution is None and allow_none:
        return None
    pair = (resolution.shape == (2,) if isinstance(resolution, np.ndarray)
            else isinstance(resolution, (tuple, list)) and len(resolution) == 2)
    if not pair:
        raise InputError(f"resolution must be (width, height) in pixels, two positive whole "
                         f"numbers, got {show(resolution)}")
    return (_pixels("resolution width", resolution[0]),
            _pixels("resolution height", resolution[1]))


def camera_at(path, t) -> Camera:
    """The camera of ``path`` (a :class:`Camera` or a callable ``t -> Camera``) at
    time ``t``, checked."""
    camera = path(t)
    if not isinstance(camera, Camera):
        raise InputError(f"a camera path must return a vdad.camera.Camera at time {t}, got "
                         f"{type(camera).__name__}")
    return camera
