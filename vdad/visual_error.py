"""Measured visual error of a simplified simulation (Kim 2008 §3.1).

The paper defines the visual error of a simplified simulation as the pixels that
differ from the frame of the fully simulated one (§3.1.1), and the error of an
animation segment as the sum of successive static errors (§3.1.2); it then only
estimates it a priori (§5). Here it is measured a posteriori, frame by frame,
against a full-DCA reference run from the same initial state, in two ways:

* (a) screen-space displacement: points on the bodies' surfaces, placed by both
  configurations and projected by the camera; the mean and max displacement in
  pixels (pure numpy, occlusion ignored);
* (b) the paper's measure: the number of pixels whose rendered body differs
  between the two frames, from the id images of
  :class:`~vdad.render.counting.PixelCounter` (EGL, occlusion by the other
  bodies and the environment included).

:func:`measure` runs a simulator and its reference (stepped in lockstep, or a
:class:`Trajectory` recorded earlier by :func:`record`), then measures the
frames it kept, and returns an :class:`ErrorTrace`.
"""

from __future__ import annotations

import contextlib
import os
import time
import zipfile
from dataclasses import dataclass

import numpy as np

from .camera import Camera, camera_at, check_path, check_resolution
from .checks import (
    check_callable,
    check_count,
    check_finite,
    check_flag,
    check_real,
    real_array,
    show,
)
from .environment import check_environment
from .errors import InputError, SimulationError
from .kinematics import world_poses
from .model import check_configuration, check_model
from .simulator import Simulator
from .spatial import mv

MEASURES = ("mean_px", "max_px", "differing_pixels")


def _check_simulator(sim, name="sim"):
    if not isinstance(sim, Simulator):
        raise InputError(f"{name} must be a vdad.Simulator, got {type(sim).__name__}")


def _check_file(name, path):
    """``path`` as a string if it is a file system path (str or os.PathLike)."""
    if not isinstance(path, (str, os.PathLike)):
        raise InputError(f"{name} must be a file path (str or os.PathLike), got "
                         f"{type(path).__name__}: {show(path)}")
    return os.fspath(path)


def _cause(exc):
    """What an OSError says went wrong, without the path it repeats."""
    return exc.strerror or str(exc)


def reference_simulator(sim) -> Simulator:
    """Kim 2008 §3.1: the fully simulated run that a simplified one is judged
    against: a ``method="dca"`` :class:`~vdad.Simulator` with ``sim``'s model,
    initial state (copies), time step, integrator and damping scheme, assembly
    tree, forces, camera and environment. ``sim`` must not have stepped yet."""
    _check_simulator(sim)
    if sim.step_count != 0:
        raise InputError(f"sim has already taken {sim.step_count} steps; the reference must "
                         f"start from the same initial state: build it before stepping")
    ref = Simulator(sim.model, sim.q, sim.qd, dt=sim.dt, method="dca",
                    integrator=sim.integrator_name, tree=sim.tree, controller=sim.controller,
                    external=sim.external, camera=sim.camera, environment=sim.environment,
                    implicit_damping=sim.implicit_damping)
    # bit for bit: normalising the configuration again may move a quaternion by an ulp
    ref.q, ref.qd = sim.q.copy(), sim.qd.copy()
    return ref


@dataclass(frozen=True, eq=False)
class Trajectory:
    """Kim 2008 §3.1.2: a recorded animation segment: times ``t`` (F,) of its frames,
    configurations ``q`` (F, nq) at those times, and ``ms_per_step``, the wall time
    per step of the run that produced it (NaN if unknown). The frames are at
    increasing times."""

    t: np.ndarray
    q: np.ndarray
    ms_per_step: float = float("nan")

    def __post_init__(self):
        t = check_finite("t", self.t)
        q = check_finite("q", self.q)
        if t.ndim != 1 or q.ndim != 2 or len(q) != len(t):
            raise InputError(f"a trajectory needs t (F,) and q (F, nq), got t {t.shape} and "
                             f"q {q.shape}")
        back = np.flatnonzero(np.diff(t) <= 0)
        if len(back):
            k = back[0] + 1
            raise InputError(f"t must increase from frame to frame, got t[{k}] = {float(t[k])} "
                             f"after t[{k - 1}] = {float(t[k - 1])}")
        ms = real_array("ms_per_step", self.ms_per_step)
        if ms.ndim or not np.isnan(ms):
            ms = check_real("ms_per_step (NaN if unknown)", self.ms_per_step, nonnegative=True)
        object.__setattr__(self, "t", t)
        object.__setattr__(self, "q", q)
        object.__setattr__(self, "ms_per_step", float(ms))

    def save(self, path):
        """Write the trajectory to ``path`` as an ``.npz`` archive (at that exact path)."""
        path = _check_file("path", path)
        try:
            with open(path, "wb") as fh:
                np.savez(fh, t=self.t, q=self.q, ms_per_step=self.ms_per_step)
        except OSError as exc:
            raise InputError(f"cannot write the Trajectory to {path!r}: {_cause(exc)}") from None

    @classmethod
    def load(cls, path) -> Trajectory:
        """The trajectory that :meth:`save` wrote to ``path`` (read without pickles)."""
        path = _check_file("path", path)
        not_saved = f"{path!r} is not a Trajectory written by Trajectory.save"
        try:
            data = np.load(path, allow_pickle=False)
        except OSError as exc:
            raise InputError(f"cannot read a Trajectory from {path!r}: {_cause(exc)}") from None
        except (ValueError, EOFError, zipfile.BadZipFile):
            raise InputError(f"{not_saved}: it is not an .npz archive") from None
        if not isinstance(data, np.lib.npyio.NpzFile):
            raise InputError(f"{not_saved}: it holds one array (.npy), not an .npz archive")
        with data:
            missing = sorted({"t", "q", "ms_per_step"} - set(data.files))
            if missing:
                raise InputError(f"{not_saved}: it lacks {missing}")
            try:
                t, q, ms = data["t"], data["q"], data["ms_per_step"]
            except (OSError, ValueError, EOFError, zipfile.BadZipFile) as exc:
                raise InputError(f"{not_saved}: its arrays cannot be read ({exc})") from None
        try:
            return cls(t, q, ms)
        except InputError as exc:
            raise InputError(f"{not_saved}: {exc}") from None


def _frames(steps, every):
    """``(steps, every, frames)`` checked: ``steps`` a multiple of ``every``."""
    steps, every = check_count("steps", steps), check_count("every", every)
    if steps % every:
        raise InputError(f"steps ({steps}) must be a multiple of every ({every})")
    return steps, every, steps // every


def record(sim, steps, every=1, progress=False) -> Trajectory:
    """Kim 2008 §3.1.2: step ``sim`` ``steps`` times and keep the state after every
    ``every``-th step (frames at steps ``every``, ``2 every``, ...). Only the
    ``sim.step`` calls are timed, after the first frame, for ``ms_per_step``
    (:class:`StepTimer`); ``progress`` (bool) shows a
    progress bar."""
    from tqdm import tqdm

    _check_simulator(sim)
    steps, every, frames = _frames(steps, every)
    progress = check_flag("progress", progress)
    with tqdm(total=steps, unit="step", disable=not progress) as bar:
        t, q, _, timer, _, failure = _step_frames(sim, frames, every, bar)
    if failure is not None:
        raise failure
    return Trajectory(np.array(t), np.array(q).reshape(-1, sim.model.nq), timer.ms_per_step)


def _step_frames(sim, frames, every, bar, reference=None):
    """Step ``sim`` ``frames`` times ``every`` steps, and after each the
    ``reference`` Simulator (lockstep; None: none), each timed apart
    (:class:`StepTimer`). Returns the frames' times and configurations (lists of
    float, (nq,)), the reference's configurations, both timers, and the
    SimulationError that stopped ``sim`` (None: it took every frame)."""
    t, q, q_ref, timer, reference_timer = [], [], [], StepTimer(), StepTimer()
    for _ in range(frames):
        try:
            with timer.frame(sim):
                sim.step(every)
        except SimulationError as exc:
            return t, q, q_ref, timer, reference_timer, exc
        if reference is not None:
            with reference_timer.frame(reference):
                reference.step(every)
            q_ref.append(reference.q.copy())
        t.append(sim.t)
        q.append(sim.q.copy())
        bar.update(every)
    return t, q, q_ref, timer, reference_timer, None


def _restarted(restart, start):
    """``restart()``, checked to be a simulator in the state ``start`` = (step count,
    q, qd) that the measured one started from."""
    again = restart()
    _check_simulator(again, "restart()")
    step_count, q, qd = start
    if not (again.step_count == step_count and np.array_equal(again.q, q)
            and np.array_equal(again.qd, qd)):
        raise InputError("restart() must return a simulator in the measured one's initial "
                         f"state (step {step_count}, the same q and qd); it returned one at "
                         f"step {again.step_count} with another state")
    return again


class StepTimer:
    """Wall time of a simulator's frames (``with timer.frame(sim): sim.step(n)``);
    :attr:`ms_per_step` leaves out the first frame once there are others, since a
    process's first step loads the kernels from numba's cache (about 0.6 s) or
    compiles them, a thousand times a step of a small model."""

    def __init__(self):
        self.frames = []                       # (seconds, steps) per frame

    @contextlib.contextmanager
    def frame(self, sim):
        start, count = time.perf_counter(), sim.step_count
        try:
            yield
        finally:
            self.frames.append((time.perf_counter() - start, sim.step_count - count))

    @classmethod
    def fastest(cls, timers):
        """The frames of the first of ``timers`` (repeated runs of the same frames),
        each at its fastest time over the timers that reached it."""
        out = cls()
        for i, (_, steps) in enumerate(timers[0].frames):
            out.frames.append((min(t.frames[i][0] for t in timers if i < len(t.frames)),
                               steps))
        return out

    @property
    def ms_per_step(self) -> float:
        frames = self.frames[1:] if len(self.frames) > 1 else self.frames
        steps = sum(n for _, n in frames)
        return 1e3 * sum(s for s, _ in frames) / steps if steps else np.nan


def poses(model, q):
    """Kim 2008 §3.1: where the bodies are drawn in configuration ``q`` (nq,):
    world rotations ``R`` (nb, 3, 3) and positions ``p`` (nb, 3) of every body."""
    check_model(model)
    return world_poses(model, check_configuration(model, "q", q))


def surface_points(model, per_body=64, sections=8):
    """Kim 2008 §3.1: sample points of what the viewer sees of each body: the
    distinct vertices of its geoms tessellated with ``sections`` segments around
    (:meth:`~vdad.model.Geom.to_trimesh`, body frame), at most ``per_body`` per body
    taken evenly along the vertex order. Bodies without geoms get none.

    Returns ``body`` (P,) int64, the body of each point, and ``local`` (P, 3), its
    position in that body's frame."""
    check_model(model)
    per_body = check_count("per_body", per_body)
    sections = check_count("sections", sections, minimum=3)
    meshes = {}                     # id(geom) -> vertices, for geoms shared by bodies
    body, local = [], []
    for i, b in enumerate(model.bodies):
        if not b.geoms:
            continue
        for geom in b.geoms:
            if id(geom) not in meshes:
                meshes[id(geom)] = np.asarray(geom.to_trimesh(sections).vertices, dtype=float)
        v = np.concatenate([meshes[id(geom)] for geom in b.geoms])              # (n, 3)
        _, first = np.unique(np.round(v, 12), axis=0, return_index=True)
        v = v[np.sort(first)]
        if len(v) > per_body:
            v = v[np.arange(per_body) * len(v) // per_body]
        body.append(np.full(len(v), i, dtype=np.int64))
        local.append(v)
    if not body:
        return np.zeros(0, dtype=np.int64), np.zeros((0, 3))
    return np.concatenate(body), np.concatenate(local)


def _world_points(name, X):
    X = check_finite(name, X)
    if X.ndim != 2 or X.shape[1] != 3:
        raise InputError(f"{name} must have shape (P, 3), got {X.shape}")
    return X


def screen_displacement(camera, X_ref, X):
    """Kim 2008 §3.1.1, measured on points: how far, in pixels, ``camera`` sees
    each world point move from ``X_ref`` (P, 3) in the reference frame to ``X``
    (P, 3) in the simplified one. Counted are the points in front of the near plane
    in both frames and inside the viewport in at least one. Occlusion is ignored: a
    hidden point counts as if seen (the rendered measure of :class:`VisualError`
    accounts for it).

    Returns the mean and the max displacement over the counted points (0 when none)."""
    if not isinstance(camera, Camera):
        raise InputError(f"camera must be a vdad.camera.Camera, got {type(camera).__name__}")
    X_ref, X = _world_points("X_ref", X_ref), _world_points("X", X)
    if X.shape != X_ref.shape:
        raise InputError(f"X_ref and X must have the same shape, got {X_ref.shape} and "
                         f"{X.shape}")
    (xy_ref, d_ref), (xy, d) = camera.project(X_ref), camera.project(X)    # (P, 2), (P,)
    size = np.array([camera.width, camera.height])

    def inside(a):                                                          # (P,) bool
        return np.all((a >= 0) & (a < size), axis=1)

    counted = (d_ref > camera.znear) & (d > camera.znear) & (inside(xy_ref) | inside(xy))
    if not counted.any():
        return 0.0, 0.0
    moved = np.linalg.norm(xy[counted] - xy_ref[counted], axis=1)          # (counted,)
    return float(moved.mean()), float(moved.max())


class VisualError:
    """Kim 2008 §3.1.1: the static visual error of a simplified frame of ``model``
    against the fully simulated one, seen by ``camera`` (a
    :class:`~vdad.camera.Camera` or a path ``t -> Camera``) among the static
    occluders of ``environment``, at ``resolution`` (width, height; default: the
    camera's, for a path the camera at the first call's time).

    Calling it with the time ``t`` and both configurations gives (a) the mean and
    max screen displacement ``mean_px``, ``max_px`` of up to ``per_body`` surface
    points per body (:func:`surface_points`, :func:`screen_displacement`;
    occlusion ignored) and (b) ``differing_pixels``, the paper's count of pixels
    whose rendered body differs (id images of one
    :class:`~vdad.render.counting.PixelCounter`, ``"merged"``; needs EGL). With
    ``pixels=False``, (b) is skipped (None) and nothing renders (``pixels`` is a bool).
    """

    def __init__(self, model, camera, environment=None, resolution=None, per_body=64,
                 pixels=True):
        self.model, self.camera = check_model(model), check_path(camera)
        self.environment = check_environment(environment)
        self.resolution = check_resolution(resolution)
        self.pixels = check_flag("pixels", pixels)
        self.body, self.local = surface_points(model, per_body)    # (P,), (P, 3)
        self._counter = None

    def _camera(self, t):
        """The camera at time ``t`` at the measuring resolution."""
        camera = camera_at(self.camera, t)
        if self.resolution is None:
            self.resolution = (camera.width, camera.height)
        return camera.with_resolution(*self.resolution)

    def _id_image(self, camera, R, p):
        """Id image (height, width) of the bodies posed at ``R``, ``p``."""
        if self._counter is None:
            from .render.counting import PixelCounter

            self._counter = PixelCounter(self.model, self.environment, *self.resolution,
                                         method="merged")
        return self._counter.id_image(camera, R, p)

    def __call__(self, t, q_ref, q) -> dict:
        """The errors at time ``t`` of configuration ``q`` (nq,) against ``q_ref``
        (nq,): ``mean_px``, ``max_px`` (floats) and ``differing_pixels`` (int, None
        without pixels)."""
        t = float(check_real("t", t))
        q_ref = check_configuration(self.model, "q_ref", q_ref)
        q = check_configuration(self.model, "q", q)
        camera = self._camera(t)
        (R_ref, p_ref), (R, p) = world_poses(self.model, q_ref), world_poses(self.model, q)
        b, x = self.body, self.local
        X_ref = p_ref[b] + mv(R_ref[b], x)                                  # (P, 3)
        X = p[b] + mv(R[b], x)                                              # (P, 3)
        mean_px, max_px = screen_displacement(camera, X_ref, X)
        differing = None
        if self.pixels:
            image_ref = self._id_image(camera, R_ref, p_ref)                # (height, width)
            differing = int(np.count_nonzero(image_ref != self._id_image(camera, R, p)))
        return dict(mean_px=mean_px, max_px=max_px, differing_pixels=differing)

    def close(self):
        """Release the pixel counter's GL objects (if one was made); it renders no more."""
        if self._counter is not None:
            self._counter.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()


@dataclass(frozen=True, eq=False)
class ErrorTrace:
    """Kim 2008 §3.1.2: the static errors of every compared frame: times ``t``,
    ``mean_px``, ``max_px`` and ``differing_pixels`` (F,) (NaN where not measured;
    the times are finite)."""

    t: np.ndarray
    mean_px: np.ndarray
    max_px: np.ndarray
    differing_pixels: np.ndarray

    def __post_init__(self):
        columns = {"t": check_finite("t", self.t)}
        columns.update((name, real_array(name, getattr(self, name))) for name in MEASURES)
        shapes = {name: a.shape for name, a in columns.items()}
        if any(len(shape) != 1 or shape != shapes["t"] for shape in shapes.values()):
            raise InputError(f"an error trace needs arrays of one shape (F,), got {shapes}")
        for name, a in columns.items():
            object.__setattr__(self, name, a)

    def summary(self) -> dict:
        """``frames`` and, for each measure, its ``mean`` and ``max`` over the frames
        and its ``sum`` over them (the paper's sum of successive static errors);
        None for a measure with no measured frame."""
        out = {"frames": len(self.t)}
        for name in MEASURES:
            a = getattr(self, name)
            if len(a) == 0 or np.all(np.isnan(a)):
                out[name] = dict(mean=None, max=None, sum=None)
            else:
                out[name] = dict(mean=float(np.mean(a)), max=float(np.max(a)),
                                 sum=float(np.sum(a)))
        return out

    def to_csv(self, path):
        """Write the columns ``t,mean_px,max_px,differing_pixels`` to ``path``."""
        path = _check_file("path", path)
        table = np.column_stack([self.t, *(getattr(self, name) for name in MEASURES)])
        try:
            np.savetxt(path, table.reshape(-1, 4), fmt="%.17g", delimiter=",", comments="",
                       header=",".join(("t", *MEASURES)))
        except OSError as exc:
            raise InputError(f"cannot write the error trace to {path!r}: {_cause(exc)}") from None


def measure(sim, steps, every=1, reference=None, camera=None, environment=None,
            resolution=None, pixels=True, per_body=64, progress=False, repeats=1,
            restart=None):
    """Kim 2008 §3.1: step ``sim`` ``steps`` times and measure the visual error of
    every ``every``-th frame against the fully simulated one: ``reference`` is a
    :class:`Trajectory` recorded with the same time step and ``every`` (its frame
    times must match), or None for a :func:`reference_simulator` of ``sim``
    stepped in lockstep; the frames are measured once both runs have stepped, so
    that the measure's rendering between two steps does not slow the next one (it
    evicted the caches of whichever run stepped after it: 60-70 µs per frame on a
    20-body pendulum). ``camera`` (Camera or path) and ``environment`` default to
    ``sim``'s; ``resolution``, ``pixels`` (bool) and ``per_body`` go to
    :class:`VisualError`; ``progress`` (bool) shows a progress bar. A
    :class:`~vdad.errors.SimulationError` of ``sim`` (a diverging simplified run)
    stops the run there, with the frames so far. ``repeats`` > 1 times the runs
    again, ``repeats - 1`` more times, each from a new simulator that ``restart()``
    returns in ``sim``'s initial state (with a new lockstep reference), and keeps
    each frame's fastest time (:meth:`StepTimer.fastest`): a run of a few
    milliseconds is otherwise timed with whatever else the machine did then
    (``docs/reproduction.md``).

    Returns the :class:`ErrorTrace` and a dict ``info``: ``ms_per_step`` (of the
    ``sim.step`` calls only, after the first frame: :class:`StepTimer`),
    ``reference_ms_per_step`` (of the lockstep reference or the Trajectory's),
    ``steps`` taken, ``failure`` (None or the SimulationError's message),
    ``active_joints``, the mean number of active joints per step (``model.nb``
    without adaptive dynamics), and ``node_visits``,
    the mean number of assembly-tree nodes the dynamics touched per step
    (:attr:`~vdad.adaptive.StepStats.node_visits`; every node without adaptive
    dynamics): the work that the time per step follows once coverage is paid."""
    from tqdm import tqdm

    _check_simulator(sim)
    steps, every, frames = _frames(steps, every)
    pixels, progress = check_flag("pixels", pixels), check_flag("progress", progress)
    repeats = check_count("repeats", repeats)
    check_callable("restart", restart, "() -> Simulator in sim's initial state")
    if repeats > 1 and restart is None:
        raise InputError(f"repeats={repeats} needs restart, a callable () -> Simulator in "
                         f"sim's initial state")
    start = (sim.step_count, sim.q.copy(), sim.qd.copy())
    times = (sim.step_count + every * np.arange(1, frames + 1)) * sim.dt   # (F,)
    if reference is None:
        reference = reference_simulator(sim)
    elif isinstance(reference, Trajectory):
        if reference.q.shape[1] != sim.model.nq:
            raise InputError(f"reference configurations have {reference.q.shape[1]} "
                             f"coordinates, the model {sim.model.nq}")
        if len(reference.t) < frames or not np.allclose(reference.t[:frames], times, rtol=0,
                                                        atol=1e-6 * sim.dt):
            raise InputError(f"reference frame times {reference.t[:3]}... ({len(reference.t)} "
                             f"frames) do not match this run's {times[:3]}... ({frames} frames): "
                             f"record it from the same initial time with dt={sim.dt} and "
                             f"every={every}")
    else:
        raise InputError(f"reference must be a Trajectory or None, got "
                         f"{type(reference).__name__}")
    camera = sim.camera if camera is None else camera
    if camera is None:
        raise InputError("camera: measure needs a camera; pass camera= or give the simulator one")
    environment = sim.environment if environment is None else environment

    lockstep = isinstance(reference, Simulator)
    start_step, start_history = sim.step_count, len(sim.history)
    with tqdm(total=steps, unit="step", desc="simulate", disable=not progress) as bar:
        t, q, q_ref, timer, reference_timer, failure = _step_frames(
            sim, frames, every, bar, reference if lockstep else None)
    if not lockstep:
        q_ref = reference.q[:len(t)]
    timers, reference_timers = [timer], [reference_timer]
    for _ in range(repeats - 1):                # timing only: the same frames again
        again = _restarted(restart, start)
        with tqdm(disable=True) as quiet:
            *_, t_again, ref_again, _ = _step_frames(
                again, len(t), every, quiet, reference_simulator(again) if lockstep else None)
        timers.append(t_again)
        reference_timers.append(ref_again)
    timer, reference_timer = StepTimer.fastest(timers), StepTimer.fastest(reference_timers)
    failure = None if failure is None else str(failure)
    # the errors after the runs: the measuring renderer, between two steps, would
    # evict the caches of whichever run stepped next and bias its time (docs/reproduction.md)
    rows = []
    with VisualError(sim.model, camera, environment, resolution, per_body, pixels) as error, \
            tqdm(total=len(t), unit="frame", desc="measure", disable=not progress) as bar:
        for k in range(len(t)):
            e = error(t[k], q_ref[k], q[k])
            rows.append((t[k], e["mean_px"], e["max_px"],
                         np.nan if e["differing_pixels"] is None else e["differing_pixels"]))
            bar.update()
    done = sim.step_count - start_step
    history = sim.history[start_history:]
    if sim.adaptive is None:
        active, visits = float(sim.model.nb), float(sim.tree.n_nodes)
    elif history:
        active = float(np.mean([s.active_joints for s in history]))
        visits = float(np.mean([s.node_visits for s in history]))
    else:
        active = visits = np.nan
    reference_ms = reference_timer.ms_per_step if lockstep else reference.ms_per_step
    info = dict(ms_per_step=timer.ms_per_step,
                reference_ms_per_step=reference_ms, steps=done, failure=failure,
                active_joints=active, node_visits=visits)
    table = np.array(rows, dtype=float).reshape(-1, 4)                     # (F, 4)
    return ErrorTrace(*table.T), info
