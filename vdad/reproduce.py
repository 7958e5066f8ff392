"""Reproduction of Kim 2008 (Table 1, Figures 6, 8 and 9) and speed against
measured visual error (``docs/reproduction.md``).

:func:`plan` lists the runs of every experiment as configurations (plain dicts:
scene, scene arguments, method, method options, steps, frames); :func:`run_config`
runs one of them beside its full-DCA reference (:func:`vdad.visual_error.measure`)
and returns its timing, active joints and visual error; :func:`reproduce` runs
them all as a resumable sweep (:func:`vdad.sweep.run_sweep`) and writes the
tables, figures and the report into one folder. A stored run that lacks what the
report reads (:data:`RESULT_FIELDS`, checked by :func:`check_result`) is
recomputed, with one line saying so.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from .errors import InputError
from .simulator import frame_steps

# The paper's numbers (Kim 2008 Table 1, Figure 6; 2.26 GHz Pentium M, C++)
PAPER = {
    "table1": {"dca": (0.218, 19), "view-bvh": (0.136, 10), "view-oq": (0.108, 8)},
    "dogs": {"active_joints": 493, "joints": 1500, "ms_per_frame": 14.0},
}
EXPERIMENTS = ("table1", "figure8", "figure9", "dogs", "speed_vs_error")
# the 300-body pendulum of Figures 8-9 and the speed study: beads (radius half a link)
# seen at 640 x 480, so that links cover pixels when all 300 are in view
PENDULUM300 = {"n_bodies": 300, "radius": 0.05, "resolution": [640, 480]}
# the speed study's "slow" family (the falling character's): the velocity weight
# relative to the acceleration weight (AdaptiveDynamics' velocity_weights; the character
# rolls on the floor with joint rates that keep its velocity metric above any sub-pixel
# threshold), and the dwell and look-ahead period that keep its fall from rigidifying and
# releasing joints every few steps (docs/reproduction.md, "Speed against measured
# visual error"; the look-ahead every 2 steps rather than 5 releases the joints an
# impact reaches sooner: less error at the same threshold, 0.62 against 0.80 px at 7e-3),
# and the coverage every two displayed frames (30 Hz; the character's dt is 1 ms): its
# cost per frame is a tenth of a frozen character's step (scripts/bench_character.py,
# 1.96x at every frame against 2.06x at every second, 0.82 and 0.79 px at 1.2e-2)
SLOW = 1e-4
SLOW_OPTIONS = {"velocity_weights": SLOW, "dwell": 100, "lookahead_every": 2,
                "coverage_every": 2 * frame_steps(1e-3)}
SLOW_FAMILY = (f"view-bvh sphere moved (velocity weights {SLOW:g}, dwell "
               f"{SLOW_OPTIONS['dwell']}, look-ahead every {SLOW_OPTIONS['lookahead_every']}, "
               f"coverage every {SLOW_OPTIONS['coverage_every']} steps)")
FAMILIES = ("adaptive", "view-bvh sphere", "view-bvh obb", "view-bvh aabb", "view-oq",
            "view-bvh sphere moved", SLOW_FAMILY, "view-oq moved", "lod-distance", "sleeping")
CURVES = ("view-bvh", "view-oq", "view-bvh moved", "view-oq moved")   # of Figures 8 and 9
TRACE = ("t", "mean_px", "max_px", "differing_pixels")      # per-frame columns of a run
# every run and its reference are timed this many times, each frame at its fastest
# (vdad.visual_error.measure): one pass of Table 1's 20 ms runs spread by 20 %
REPEATS = 5


def _is_number(value):
    return value is None or (isinstance(value, (int, float)) and not isinstance(value, bool))


def _is_count(value):
    return isinstance(value, int) and not isinstance(value, bool)


def _is_text(value):
    return value is None or isinstance(value, str)


def _is_series(value):
    return isinstance(value, list) and all(_is_number(x) for x in value)


_NUMBER = ("a number or null", _is_number)
# What the report (vdad.report) reads of a run's result, {key: (kind, test)}, nested
# for the error summary and the trace: a stored run must hold all of it to be reused.
RESULT_FIELDS = {
    "ms_per_step": _NUMBER, "reference_ms_per_step": _NUMBER, "speedup": _NUMBER,
    "active_joints": _NUMBER, "node_visits": _NUMBER, "joints": ("an int", _is_count),
    "steps": ("an int", _is_count),
    "failure": ("a str or null", _is_text),
    "error": {m: {stat: _NUMBER for stat in ("mean", "max", "sum")} for m in TRACE[1:]},
    "trace": {k: ("a list of numbers or nulls", _is_series) for k in TRACE},
}


def _config(scene, args, method, options, steps, every):
    return {"scene": scene, "scene_args": args, "method": method, "options": options,
            "steps": steps, "every": every}


def _view(method, threshold, **extra):
    """Options of a view-dependent run (view-oq: the merged id buffer's counts
    rasterised on the CPU, inside the compiled steps; ``docs/visibility.md``)."""
    options = {"threshold": threshold, **extra}
    if method == "view-oq":
        options["counting"] = "raster"
    return options


def _family_configs(scene, args, steps, every, values):
    """One run per value of every method family of the speed study, and the DCA
    (the moved-pixels rule at thresholds of its own: its weights are larger; with
    :data:`SLOW_OPTIONS` at those of ``values["slow"]``, where given)."""
    out = [_config(scene, args, "dca", {}, steps, every)]
    for t in values["adaptive"]:
        out.append(_config(scene, args, "adaptive", {"threshold": t}, steps, every))
    for volume in ("sphere", "obb", "aabb"):
        for t in values["view"]:
            out.append(_config(scene, args, "view-bvh", _view("view-bvh", t, volume=volume),
                               steps, every))
    for t in values["view"]:
        out.append(_config(scene, args, "view-oq", _view("view-oq", t), steps, every))
    for m in ("view-bvh", "view-oq"):
        for t in values["moved"]:
            out.append(_config(scene, args, m, _view(m, t, pixels="moved"), steps, every))
    for t in values.get("slow", ()):
        out.append(_config(scene, args, "view-bvh",
                           _view("view-bvh", t, pixels="moved", **SLOW_OPTIONS), steps,
                           every))
    for d in values["distance"]:
        out.append(_config(scene, args, "lod-distance", {"distance": d}, steps, every))
    for s in values["sleep"]:
        out.append(_config(scene, args, "sleeping", {"sleep_speed": s}, steps, every))
    return out


def plan(quick=False) -> dict:
    """Kim 2008 Table 1, Figures 6, 8, 9 and the speed study of
    ``docs/reproduction.md``: the configurations of every experiment,
    {experiment: [config, ...]}.
    ``quick`` shortens the runs and thins the sweeps (minutes on two cores)."""
    q = bool(quick)
    p_steps, p_every = (200, 20) if q else (600, 20)
    table1 = [_config("pendulum", {"n_bodies": 20}, "dca", {}, 200 if q else 1000, 10)]
    for t in (0.01, 0.03) if q else (0.01, 0.03, 0.1, 0.12):
        for m, extra in (("adaptive", {}), ("view-bvh", {}), ("view-bvh", {"pixels": "moved"}),
                         ("view-oq", {})):
            options = {"threshold": t * 1e-3} if m == "adaptive" else _view(m, t, **extra)
            table1.append(_config("pendulum", {"n_bodies": 20}, m, options,
                                  200 if q else 1000, 10))
    thresholds = [1e-5, 1e-3, 1e-1] if q else [1e-6, 1e-5, 1e-4, 1e-3, 1e-2, 1e-1, 1.0]
    figure8 = [_config("pendulum", PENDULUM300, "dca", {}, p_steps, p_every)] + [
        _config("pendulum", PENDULUM300, m, _view(m, t), p_steps, p_every)
        for m in ("view-bvh", "view-oq") for t in thresholds]
    distances = [33.0, 120.0, 480.0] if q else [15.0, 33.0, 60.0, 120.0, 240.0, 480.0]
    figure9 = [_config("pendulum", {**PENDULUM300, "camera_distance": d}, m,
                       _view(m, 1e-5, pixels=pixels), p_steps, p_every)
               for pixels in ("own", "moved") for m in ("view-bvh", "view-oq") for d in distances]
    d_steps = 30 if q else 300
    dogs = [_config("hanging_dogs", {}, "dca", {}, d_steps, 10)] + [
        _config("hanging_dogs", {}, m, _view(m, 0.01), d_steps, 10)
        for m in ("view-bvh", "view-oq")]
    if q:
        sve = (_family_configs("pendulum", PENDULUM300, p_steps, p_every, {
                   "adaptive": [1e-5, 1e-2], "view": [1e-3], "moved": [1e-1],
                   "distance": [30.0], "sleep": [0.5]})
               + _family_configs("hanging_dogs", {"n_dogs": 16, "columns": 4}, 40, 10, {
                   "adaptive": [1e-5, 1e-2], "view": [1e-2], "moved": [1e-2],
                   "distance": [3.5], "sleep": [0.5]})
               + _family_configs("falling_character", {}, 300, 25, {
                   "adaptive": [1e-6, 1e-3], "view": [3e-3], "moved": [3e-3],
                   "slow": [5e-3], "distance": [4.0], "sleep": [0.2]}))
    else:
        sve = (_family_configs("pendulum", PENDULUM300, p_steps, p_every, {
                   "adaptive": [1e-6, 1e-4, 1e-2], "view": [1e-5, 1e-3, 1e-1],
                   "moved": [1e-3, 1e-1, 1.0], "distance": [30.0, 50.0], "sleep": [0.05, 0.5, 2.0]})
               + _family_configs("hanging_dogs", {}, 200, 10, {
                   "adaptive": [1e-6, 1e-4, 1e-2], "view": [1e-3, 1e-2, 1e-1],
                   "moved": [1e-3, 1e-2, 1e-1], "distance": [3.5, 4.5, 6.0],
                   "sleep": [0.05, 0.5, 2.0]})
               + _family_configs("falling_character", {}, 2500, 25, {
                   "adaptive": [1e-6, 1e-4, 1e-2], "view": [1e-3, 3e-3, 1e-2],
                   "moved": [1e-3, 3e-3, 1e-2, 3e-2, 1e-1],
                   "slow": [5e-3, 7e-3, 1e-2, 1.2e-2, 1.5e-2],
                   "distance": [4.0, 5.0, 6.0, 8.0],
                   "sleep": [0.05, 0.2, 1.0]}))
    return {"table1": table1, "figure8": figure8, "figure9": figure9, "dogs": dogs,
            "speed_vs_error": sve}


def curve(config) -> str:
    """The method of a configuration, with " moved" under the moved-pixels rule."""
    moved = config["options"].get("pixels") == "moved"
    return config["method"] + (" moved" if moved else "")


def family(config) -> str:
    """The method family of a configuration in the speed study's legend."""
    method = config["method"]
    if method == "view-bvh":
        method += " " + config["options"].get("volume", "sphere")
    name = curve({**config, "method": method})
    o = config["options"]
    if "velocity_weights" in o:
        extra = [f"velocity weights {o['velocity_weights']:g}"]
        extra += [label.format(o[key]) for key, label in (
            ("dwell", "dwell {}"), ("lookahead_every", "look-ahead every {}"),
            ("coverage_every", "coverage every {} steps")) if key in o]
        name += f" ({', '.join(extra)})"
    return name


def parameter(config):
    """The swept value of a configuration: threshold, distance or sleep speed."""
    o = config["options"]
    return o.get("threshold", o.get("distance", o.get("sleep_speed")))


def run_config(config) -> dict:
    """Kim 2008 §3.1, measured: one run of the plan beside its full-DCA reference,
    from the scene's initial state with the same forces, time step and integrator
    (a sweep's function).

    Returns ``ms_per_step`` and ``reference_ms_per_step`` (timed in the same
    process, :data:`REPEATS` times, each frame at its fastest), ``speedup``, mean
    ``active_joints`` of ``joints`` and ``node_visits`` per step, ``steps``,
    ``failure`` (the message if the run diverged; its numbers then cover the
    steps before), ``error`` (:meth:`~vdad.visual_error.ErrorTrace.summary`) and
    the per-frame ``trace``."""
    from .scenes import SCENES
    from .visual_error import measure

    if config["scene"] not in SCENES:
        raise InputError(f"unknown scene {config['scene']!r}; choose one of {sorted(SCENES)}")
    args = dict(config["scene_args"])
    if "resolution" in args:
        args["resolution"] = tuple(args["resolution"])
    scene = SCENES[config["scene"]](**args)

    def restart():
        return scene.simulator(method=config["method"], **config["options"])

    trace, info = measure(restart(), config["steps"], config["every"], repeats=REPEATS,
                          restart=restart)
    finite = {k: (None if isinstance(v, float) and not np.isfinite(v) else v)
              for k, v in info.items()}
    speedup = info["reference_ms_per_step"] / info["ms_per_step"] if info["steps"] else None
    return {**finite, "joints": scene.model.nb, "speedup": speedup, "error": trace.summary(),
            "trace": {k: [None if not np.isfinite(x) else float(x) for x in getattr(trace, k)]
                      for k in TRACE}}


def check_result(result):
    """Validation of a stored run before the report reads it (the ``validate`` of
    :func:`reproduce`'s sweep): None when ``result`` holds every field of
    :data:`RESULT_FIELDS` with its type and trace columns of one length, otherwise
    what is wrong, e.g. ``"incomplete (no 'ms_per_step', 'error.mean_px')"`` or
    ``"invalid ('steps' is not an int: a str)"``."""
    if not isinstance(result, dict):
        return f"invalid (its result is {_a(result)}, not a dict)"
    missing, wrong = [], []
    _check_fields(result, RESULT_FIELDS, "", missing, wrong)
    if missing:
        return f"incomplete (no {', '.join(map(repr, missing))})"
    if wrong:
        return f"invalid ({'; '.join(wrong)})"
    lengths = {k: len(result["trace"][k]) for k in TRACE}
    if len(set(lengths.values())) > 1:
        return f"invalid (trace columns of different lengths: {lengths})"
    return None


def _a(value):
    """The JSON type of ``value`` with its article: "null", "a str", "an int"..."""
    if value is None:
        return "null"
    name = type(value).__name__
    return f"{'an' if name[0] in 'aeiou' else 'a'} {name}"


def _check_fields(value, fields, prefix, missing, wrong):
    """Append to ``missing`` the dotted names of the ``fields`` absent from ``value``
    and to ``wrong`` a phrase for each present one of the wrong kind."""
    for key, kind in fields.items():
        name = prefix + key
        if key not in value:
            missing.append(name)
        elif isinstance(kind, dict):
            if isinstance(value[key], dict):
                _check_fields(value[key], kind, name + ".", missing, wrong)
            else:
                wrong.append(f"{name!r} is not a dict: {_a(value[key])}")
        elif not kind[1](value[key]):
            wrong.append(f"{name!r} is not {kind[0]}: {_a(value[key])}")


def _check_extras():
    """The render and plots extras, before any run: an :class:`InputError` naming
    the missing modules, or a RenderError with the hint when EGL is unavailable."""
    from importlib.util import find_spec

    missing = [m for m in ("trimesh", "pyrender", "matplotlib") if find_spec(m) is None]
    if missing:
        raise InputError(f"vdad reproduce needs {', '.join(missing)}: pip install "
                         f"\"vdad[render,plots]\"")
    from .render.context import make_current

    make_current()


def reproduce(out, quick=False, jobs=1, scheduler=None, progress=True, only=None) -> list:
    """Run the experiments ``only`` (default: all of :data:`EXPERIMENTS`) as one
    resumable sweep stored in ``out/runs`` (a killed run resumes; a stored run
    that is unreadable or fails :func:`check_result` is recomputed, with one line
    on stderr), then write the tables, figures and ``report.md`` into ``out``.
    Returns the files written."""
    from .sweep import ResultStore, check_scheduler, run_sweep

    only = list(EXPERIMENTS) if only is None else list(only)
    unknown = sorted(set(only) - set(EXPERIMENTS))
    if unknown:
        raise InputError(f"unknown experiments {unknown}; choose from {EXPERIMENTS}")
    _check_extras()
    if scheduler is not None:
        check_scheduler(scheduler)
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    experiments = {k: v for k, v in plan(quick).items() if k in only}
    configs = [c for cs in experiments.values() for c in cs]
    report = run_sweep(run_config, configs, ResultStore(out / "runs"), jobs=jobs,
                       scheduler=scheduler, progress=progress, desc="vdad reproduce",
                       validate=check_result)
    results = iter(report.results)                    # in the order of configs
    rows = {name: [{**next(results), "config": c} for c in cs]
            for name, cs in experiments.items()}
    from . import report as writers

    files = []
    for name in experiments:
        files += getattr(writers, f"write_{name}")(rows[name], out)
    files += writers.write_report(rows, out, quick)
    return files
