"""The ``vdad`` command line: ``vdad run SCENE ...``, ``vdad render SCENE ...`` and
``vdad reproduce``.

Every command has ``--help``; results go to plain files (JSON, PNG, GIF, MP4).
"""

from __future__ import annotations

import argparse
import functools
import json
import os
import sys

import numpy as np

from .errors import InputError, VdadError


def _number(cast, low, strict, what):
    """An argparse type: ``cast(text)``, finite and ``> low`` (``strict``) or ``>= low``."""
    def parse(text):
        value = cast(text)
        if not np.isfinite(value) or value < low or (strict and value == low):
            raise argparse.ArgumentTypeError(f"must be {what}, got {text}")
        return value

    parse.__name__ = "integer" if cast is int else "number"     # argparse's "invalid ..."
    return parse


_positive_int = _number(int, 1, False, "a positive integer")
_positive_float = _number(float, 0.0, True, "a positive number")
_nonnegative_float = _number(float, 0.0, False, "a number >= 0")
_nonnegative_int = _number(int, 0, False, "an integer >= 0")


def _resolution(text):
    try:
        w, h = (int(x) for x in text.lower().split("x"))
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"must be WIDTHxHEIGHT, e.g. 320x240, got {text}") from None
    if w < 1 or h < 1:
        raise argparse.ArgumentTypeError(f"must be positive pixel counts, got {text}")
    return w, h


def _scene_name(text):
    """A scene's name, or the path of an existing MuJoCo model file (.xml)."""
    from .scenes import SCENES

    if text in SCENES:
        return text
    if text.lower().endswith(".xml"):
        if not os.path.isfile(text):
            raise argparse.ArgumentTypeError(f"MuJoCo model file not found: {text}")
        return text
    raise argparse.ArgumentTypeError(f"invalid choice: {text!r} (choose from "
                                     f"{', '.join(sorted(SCENES))}, or give a MuJoCo .xml file)")


def _scene_options(parser):
    """Options that pick and size a scene (shared by ``run`` and ``render``)."""
    from .scenes import SCENES

    parser.add_argument("scene", type=_scene_name, metavar="SCENE",
                        help=f"scene to simulate: one of {', '.join(sorted(SCENES))}, or a "
                        f"MuJoCo model file (.xml; docs/mujoco.md)")
    scene = parser.add_argument_group("scene", "options a scene does not take are an error; "
                                      "the defaults are the scene's own")
    scene.add_argument("--bodies", type=_positive_int,
                       help="pendulum: number of links (default 20)")
    scene.add_argument("--dogs", type=_positive_int,
                       help="hanging_dogs: number of dogs (default 100)")
    scene.add_argument("--seed", type=_nonnegative_int,
                       help="random seed (hanging_dogs: twists and torques; falling_character: "
                       "initial joint angles)")
    scene.add_argument("--dt", type=_positive_float, help="time step in s (default: the scene's)")
    scene.add_argument("--camera-distance", type=_positive_float,
                       help="viewer's distance in m (default: the scene's)")
    scene.add_argument("--resolution", type=_resolution,
                       help="camera and counting resolution WIDTHxHEIGHT (default 320x240)")


# the method options that make_simulator gives Scene.simulator when set: each is the
# keyword of the CLI option of the same name (--coverage-every: coverage_every)
SIMULATOR_OPTIONS = ("threshold", "budget", "weights", "velocity_weights", "policy", "metric",
                     "drop", "energy", "dwell", "kappa", "lookahead_every", "volume", "estimate",
                     "pixels", "counting", "coverage_every", "distance", "sleep_speed",
                     "sleep_time")


def _flag(name):
    """The CLI option of a Python keyword: ``coverage_every`` -> ``--coverage-every``."""
    return "--" + name.replace("_", "-")


def in_cli_terms(message):
    """An error message of :class:`~vdad.Simulator` (or of the adaptive dynamics
    it builds) in the words of the command line: ``name=`` and a leading ``name``
    become ``--name`` for the options of :data:`SIMULATOR_OPTIONS`, and
    ``method='m'`` becomes ``--method m``."""
    import re

    names = "|".join(SIMULATOR_OPTIONS)
    message = re.sub(r"\bmethod='([\w-]+)'", r"--method \1", message)
    message = re.sub(rf"(?<![\w-])({names})=", lambda m: _flag(m[1]), message)
    return re.sub(rf"^({names})\b(?![=-])", lambda m: _flag(m[1]), message)


def _method_options(parser):
    """Dynamics method options (shared by ``run`` and ``render``). Those left out
    take the scene's calibrated defaults (``docs/scenes.md``), then the generic
    ones of :data:`vdad.simulator.DEFAULTS` and of AdaptiveDynamics."""
    from .adaptive import DROPS, ENERGIES, METRICS, POLICIES
    from .bounding import VOLUMES
    from .integrators import INTEGRATORS
    from .simulator import ADAPTIVE_DEFAULTS, DEFAULTS, FRAME_RATE, METHODS
    from .visibility import COUNTING, ESTIMATES, PIXELS

    def default(name, method=None):
        value = DEFAULTS[method][name] if method else ADAPTIVE_DEFAULTS[name]
        return f"{value:g}" if isinstance(value, float) else value

    parser.add_argument("--method", choices=METHODS, default="dca",
                        help="dynamics method: exact DCA, adaptive dynamics, or view-dependent "
                        "adaptive dynamics with coverage from bounding volumes (view-bvh) or "
                        "rendered occlusion counts (view-oq, needs EGL), or a game-engine "
                        "baseline: whole bodies rigid beyond --distance (lod-distance) or "
                        "asleep when slow (sleeping) (default dca); every method runs with "
                        "the scene's defaults (docs/scenes.md), shown in the summary")
    parser.add_argument("--integrator", choices=sorted(INTEGRATORS), default="semi-implicit",
                        help="time integrator (default semi-implicit Euler; symplectic: "
                        "symplectic Euler in momentum form, bounded energy, for --method dca "
                        "on hinges and slides, docs/accuracy.md)")
    parser.add_argument("--implicit-damping", action="store_true",
                        help="integrate the joint dampers implicitly (semi-implicit Euler "
                        "only): (M + dt D) qdd = tau - D qd - ..., stable for any damping "
                        "(MuJoCo's implicit damping; docs/joints.md)")
    adaptive = parser.add_argument_group(
        "adaptive dynamics", "with --method adaptive, view-bvh or view-oq: --threshold or "
        "--budget (view methods: in pixels times displacement per step; default: the "
        "scene's threshold, docs/scenes.md); the other options also apply to the baselines")
    adaptive.add_argument("--threshold", type=_nonnegative_float,
                          help="drop accelerations whose score (weighted displacement per "
                          "step) is below this; 0 reproduces the DCA (default: the scene's; "
                          f"else {default('threshold', 'adaptive')} for adaptive, "
                          f"{default('threshold', 'view-bvh')} for view-bvh and "
                          f"{default('threshold', 'view-oq')} for view-oq)")
    adaptive.add_argument("--budget", type=_positive_int,
                          help="accelerate only this many joints (max-heap on the metric), "
                          "instead of a threshold")
    adaptive.add_argument("--weights", type=_positive_float,
                          help="weight of every dof in the acceleration metric (default: 1 on "
                          "rotational dofs, 1/l^2 on translational ones, l the mean link "
                          "length; docs/adaptive.md)")
    adaptive.add_argument("--velocity-weights", type=_positive_float,
                          help="the same for the velocity metric (default: --weights); "
                          "smaller lets joints that move at a steady rate, such as a body "
                          "rolling on the floor, be rigidified (docs/reproduction.md)")
    adaptive.add_argument("--policy", choices=POLICIES,
                          help="velocities of newly rigid joints: momentum-conserving "
                          "locking impulse, or zeroed as in the paper (default "
                          f"{default('policy')})")
    adaptive.add_argument("--metric", choices=METRICS,
                          help="sum the metric from computed accelerations, or predict it from "
                          f"(T16)-(T18) (same values; default {default('metric')})")
    adaptive.add_argument("--drop", choices=DROPS,
                          help="joints not accelerated: coast with their velocity (the paper), "
                          f"or lock at once (consistent; default {default('drop')})")
    adaptive.add_argument("--energy", choices=ENERGIES,
                          help="cap: without forces that do work, the total energy never "
                          "rises above the start's (velocities scaled down where a step ends "
                          "above it, docs/adaptive.md); free: no cap (default "
                          f"{default('energy')})")
    adaptive.add_argument("--dwell", type=_nonnegative_int,
                          help=f"steps a joint keeps a new state (default {default('dwell')})")
    adaptive.add_argument("--kappa", type=float,
                          help="hysteresis: rigidify below threshold/kappa (default "
                          f"{default('kappa')})")
    adaptive.add_argument("--lookahead-every", type=_positive_int,
                          help="steps between look-aheads, which release rigid joints "
                          f"(default {default('lookahead_every')})")
    view = parser.add_argument_group("view-dependent methods",
                                     "with --method view-bvh or view-oq")
    view.add_argument("--volume", choices=VOLUMES,
                      help="bounding volume of view-bvh (default "
                      f"{default('volume', 'view-bvh')})")
    view.add_argument("--estimate", choices=ESTIMATES,
                      help="view-bvh coverage: min of the node's and its bodies' areas "
                      "(eq. 7), the node's (eq. 5) or the bodies' (eq. 6) (default "
                      f"{default('estimate', 'view-bvh')})")
    view.add_argument("--pixels", choices=PIXELS,
                      help="whose pixels weight a node's joints: its own bodies' (the "
                      "paper's) or those of the bodies its joints move (docs/visibility.md) "
                      f"(default {default('pixels', 'view-bvh')})")
    view.add_argument("--counting", choices=COUNTING,
                      help="view-oq counts: OpenGL occlusion queries (the paper's), one "
                      "merged id buffer (same counts, faster), or the same id buffer "
                      "rasterised in compiled code on the CPU, no OpenGL (default "
                      f"{default('counting', 'view-oq')})")
    view.add_argument("--coverage-every", type=_positive_int,
                      help="steps between coverage evaluations (default: the steps of "
                      f"one displayed frame at {FRAME_RATE:g} Hz, e.g. 17 at dt 1 ms)")
    base = parser.add_argument_group("game-engine baselines",
                                     "with --method lod-distance or sleeping (threshold 0)")
    base.add_argument("--distance", type=_positive_float,
                      help="lod-distance: articulated bodies farther than this (m) from the "
                      "camera are rigid (default: the scene's; else the distance at which "
                      "the largest articulated body spans a few pixels, docs/scenes.md)")
    base.add_argument("--sleep-speed", type=_positive_float,
                      help="sleeping: speed below which a body may sleep (rad/s; default "
                      f"{default('sleep_speed', 'sleeping')})")
    base.add_argument("--sleep-time", type=_positive_float,
                      help="sleeping: seconds slow before it sleeps (default "
                      f"{default('sleep_time', 'sleeping')})")


def build_parser():
    from .render.pictures import COLORS, SUFFIXES

    parser = argparse.ArgumentParser(
        prog="vdad", description="View-dependent dynamics of articulated bodies "
        "(Kim, Redon and Kim 2008).")
    sub = parser.add_subparsers(dest="command", required=True)
    run = sub.add_parser("run", help="simulate a scene and report timing",
                         description="Simulate one of the paper's scenes (or a MuJoCo model "
                         "file) and write a JSON summary (timing, active joints, final state).")
    _scene_options(run)
    run.add_argument("--steps", type=_positive_int, default=500,
                     help="number of time steps (default 500)")
    _method_options(run)
    run.add_argument("--json", metavar="PATH", help="write the summary as JSON to PATH")
    run.add_argument("--no-progress", action="store_true", help="hide the progress bar")

    render = sub.add_parser(
        "render", help="simulate a scene and write pictures or a video",
        description="Simulate one of the paper's scenes (or a MuJoCo model file) and render "
        "it with pyrender over EGL (Kim 2008 Figures 1, 2 and 7): PNG frames, a GIF, an MP4, "
        "or a motion strip; bodies coloured by rigid group and active joints marked if asked.")
    _scene_options(render)
    render.add_argument("--out", required=True, metavar="FILE",
                        help=f"output file, by suffix ({', '.join(SUFFIXES)}); several PNG "
                        f"frames are numbered FILE_0000.png, ...")
    render.add_argument("--steps", type=_positive_int, default=1000,
                        help="number of time steps (default 1000)")
    render.add_argument("--every", type=_positive_int,
                        help="steps between frames (default: about 30 frames per simulated s)")
    render.add_argument("--size", type=_resolution, default=(640, 480),
                        help="picture size WIDTHxHEIGHT (default 640x480)")
    render.add_argument("--color", choices=COLORS, default="group",
                        help="one colour per rigid group (as the paper's figures), per body, "
                        "or the geometry's own (default group)")
    render.add_argument("--show-active", action="store_true",
                        help="mark the active joints with red spheres")
    render.add_argument("--strip", type=_positive_int, metavar="N",
                        help="write one PNG motion strip of N frames spread over the run "
                        "(Figure 7) instead of every frame")
    render.add_argument("--distances", type=_distances, metavar="D1,D2,...",
                        help="simulate once per viewer distance and show the runs one above "
                        "the other, all seen from the first distance (a strip, or a video "
                        "of the rows)")
    render.add_argument("--fps", type=_positive_float, default=30.0,
                        help="frames per second of a GIF or MP4 (default 30)")
    _method_options(render)
    render.add_argument("--no-progress", action="store_true", help="hide the progress bar")

    comp = sub.add_parser(
        "compile", help="compile the numba kernels now, on several cores",
        description="Compile vdad's numba kernels into numba's on-disk cache ahead of a "
        "first run, in several processes at once (on two cores about fifteen minutes in one "
        "process, nine and a half with --jobs 2); later runs load them in under a second.")
    comp.add_argument("--jobs", type=_positive_int, default=2,
                      help="processes compiling at once (default 2)")
    comp.add_argument("--no-progress", action="store_true",
                      help="do not say when each share of the kernels is done")

    from .reproduce import EXPERIMENTS

    rep = sub.add_parser(
        "reproduce", help="reproduce the paper's tables and figures and measure visual error",
        description="Run Table 1, Figures 6, 8 and 9 of Kim 2008 and the speed-against-"
        "measured-error study, each run beside a full-DCA reference, and write Markdown/CSV "
        "tables, PNG figures and report.md into one folder. Finished runs are stored in "
        "OUT/runs at once: a killed run resumes where it stopped. Needs the render and plots "
        "extras.")
    rep.add_argument("--out", default="results", metavar="DIR",
                     help="results folder (default results)")
    rep.add_argument("--quick", action="store_true",
                     help="short runs and thin sweeps (a few minutes on two cores)")
    rep.add_argument("--only", type=_names(EXPERIMENTS), metavar="E1,E2",
                     help=f"experiments to run, of {', '.join(EXPERIMENTS)} (default all)")
    rep.add_argument("--jobs", type=int, default=1,
                     help="parallel processes on this machine (joblib; -1: all cores; "
                     "default 1, the steadiest timings)")
    rep.add_argument("--scheduler", metavar="ADDRESS",
                     help="run on the Dask cluster at this scheduler address (e.g. "
                     "tcp://host:8786; needs the cluster extra and the same vdad on the "
                     "workers)")
    rep.add_argument("--no-progress", action="store_true", help="hide the progress bar")
    return parser


def _names(choices):
    """An argparse type: a comma-separated list of names from ``choices``."""
    def parse(text):
        names = [n.strip() for n in text.split(",") if n.strip()]
        wrong = [n for n in names if n not in choices]
        if wrong or not names:
            raise argparse.ArgumentTypeError(f"choose from {', '.join(choices)}, got {text}")
        return names

    parse.__name__ = "list"
    return parse


def _distances(text):
    try:
        values = [float(x) for x in text.split(",")]
    except ValueError:
        raise argparse.ArgumentTypeError(f"must be distances in m separated by commas, e.g. "
                                         f"3,12, got {text}") from None
    if not values or not all(np.isfinite(v) and v > 0 for v in values):
        raise argparse.ArgumentTypeError(f"distances must be positive, got {text}")
    return values


def make_scene(args, **override):
    """The scene ``args.scene`` built from the scene options that were given
    (``override`` wins); an option the scene does not take is an InputError."""
    import inspect

    from .scenes import SCENES
    from .scenes.mjcf import mjcf_scene

    build = SCENES.get(args.scene) or functools.partial(mjcf_scene, args.scene)
    given = {"n_bodies": args.bodies, "n_dogs": args.dogs, "seed": args.seed, "dt": args.dt,
             "camera_distance": args.camera_distance, "resolution": args.resolution}
    given = {k: v for k, v in given.items() if v is not None}
    given.update(override)
    accepted = inspect.signature(build).parameters
    wrong = [k for k in given if k not in accepted]
    if wrong:
        flags = {"n_bodies": "--bodies", "n_dogs": "--dogs"}
        names = ", ".join(flags.get(k, "--" + k.replace("_", "-")) for k in wrong)
        raise InputError(f"scene {args.scene!r} does not take {names}")
    return build(**given)


def make_simulator(scene, args):
    """The simulator of ``scene`` with the method options of ``args`` that were
    given (the others: the scene's and the generic defaults; ``sim.options`` holds
    those used). An error in them is an InputError in the CLI's words
    (:func:`in_cli_terms`)."""
    options = {k: getattr(args, k) for k in SIMULATOR_OPTIONS if getattr(args, k) is not None}
    try:
        return scene.simulator(method=args.method, integrator=args.integrator,
                               implicit_damping=args.implicit_damping, **options)
    except InputError as exc:
        raise type(exc)(in_cli_terms(str(exc))) from exc


def describe_options(method, options):
    """The method's options of ``sim.options`` that the summary line shows: the
    threshold or budget (not of a baseline), the metric weights if given and the
    method's own, e.g.
    ``"threshold 0.01, volume sphere, estimate min"``."""
    from .simulator import BASELINES, EXCLUSIVE, METHOD_OPTIONS

    keys = ((() if method in BASELINES else EXCLUSIVE) + ("weights", "velocity_weights")
            + METHOD_OPTIONS.get(method, ()))
    shown = [(k, options[k]) for k in keys if k in options]
    return ", ".join(f"{k.replace('_', ' ')} " + (f"{v:g}" if isinstance(v, float) else
                                                  str(v)) + (" m" if k == "distance" else "")
                     for k, v in shown)


def _check_json(path):
    """An InputError, before a run, if the ``--json`` file cannot be written."""
    from pathlib import Path

    if path is None:
        return
    target = Path(path)
    if not path or target.is_dir() or not target.parent.is_dir():
        raise InputError(f"--json {path!r}: give a file name in an existing folder")


def run_scene(args):
    from tqdm import tqdm

    from .visual_error import StepTimer

    _check_json(args.json)
    scene = make_scene(args)
    sim = make_simulator(scene, args)
    chunk = max(1, args.steps // 100)
    timer = StepTimer()             # the first step loads (or compiles) the kernels
    with tqdm(total=args.steps, desc=f"{args.scene} ({scene.model.nb} bodies)", unit="step",
              disable=args.no_progress, file=sys.stderr) as bar:
        done = 0
        while done < args.steps:
            n = 1 if done == 0 else min(chunk, args.steps - done)
            with timer.frame(sim):
                sim.step(n)
            done += n
            bar.update(n)
    first = timer.frames[0][0]
    summary = {
        "scene": scene.name, "method": args.method, "integrator": args.integrator,
        "implicit_damping": args.implicit_damping,
        "bodies": scene.model.nb, "joints": scene.model.nb, "dofs": scene.model.nv,
        "steps": args.steps, "dt": sim.dt, "simulated_time": sim.t,
        "ms_per_step": timer.ms_per_step, "first_step_s": first, "final_q": sim.q.tolist(),
        "final_qd": sim.qd.tolist(), "params": scene.params, "options": sim.options,
    }
    if sim.history:
        summary.update(adaptive_summary(sim.history))
    if args.json:
        with open(args.json, "w") as fh:
            json.dump(summary, fh, indent=1)
    active = (f", {summary['active_joints_mean']:.1f} of {scene.model.nb} joints active on "
              f"average" if sim.history else "")
    shown = describe_options(args.method, sim.options)
    slow = (f" after a first step of {first:.2f} s (loading or compiling the kernels)"
            if args.steps > 1 and first > 0.1 else "")
    print(f"{scene.description}: {args.steps} steps of {sim.dt} s with {args.method} "
          f"({shown + '; ' if shown else ''}{args.integrator}"
          f"{', implicit damping' if args.implicit_damping else ''}), "
          f"{summary['ms_per_step']:.3f} "
          f"ms per step{slow}{active}"
          + (f"; summary in {args.json}" if args.json else ""))
    return 0


def adaptive_summary(history):
    """Means of the adaptive counters over ``history`` (a list of StepStats): the
    JSON's ``active_joints_mean``, ``counters_mean`` and ``ms_per_phase_mean``."""
    from dataclasses import fields

    names = [f.name for f in fields(history[0]) if f.name != "times"]
    counters = {name: float(np.mean([getattr(s, name) for s in history])) for name in names}
    counters["node_visits"] = float(np.mean([s.node_visits for s in history]))
    phases = {k: 1e3 * float(np.mean([s.times[k] for s in history])) for k in history[0].times}
    return {"active_joints_mean": counters["active_joints"], "counters_mean": counters,
            "ms_per_phase_mean": phases}


def render_scene(args):
    from .render.pictures import SceneRenderer, check_output, motion_strip, record, write

    check_output(args.out)
    distances = args.distances or [None]
    runs = []
    for d in distances:
        scene = make_scene(args, **({} if d is None else {"camera_distance": d}))
        sim = make_simulator(scene, args)
        runs.append((d, scene, sim))
    first = runs[0][1]
    every = args.every or max(1, round(1 / (30 * runs[0][2].dt)))
    if args.strip:
        every = max(1, args.steps // max(args.strip - 1, 1))
    w, h = args.size
    rows = []
    for d, scene, sim in runs:
        label = f"{first.name} ({args.method}" + (f", viewer at {d:g} m)" if d else ")")
        print(f"rendering {label}", file=sys.stderr)
        with SceneRenderer(scene.model, scene.environment, w, h) as renderer:
            frames = record(sim, args.steps, every, renderer=renderer, camera=first.camera,
                            color=args.color, show_active=args.show_active,
                            progress=not args.no_progress)
        rows.append(frames[:args.strip] if args.strip else frames)
    if args.strip:
        images = [f for row in rows for f in row]
        labels = [f"t = {f.t:.2f} s, {f.n_groups} groups" + (f", {d:g} m" if d else "")
                  for (d, _, _), row in zip(runs, rows, strict=True) for f in row]
        out = write(motion_strip(images, columns=len(rows[0]), labels=labels), args.out)
    elif len(rows) > 1:
        n = min(len(r) for r in rows)
        out = write([np.concatenate([r[i].image for r in rows], axis=0) for i in range(n)],
                    args.out, fps=args.fps)
    else:
        out = write(rows[0], args.out, fps=args.fps)
    print(f"wrote {len(out)} file(s): {out[0]}" + (f" ... {out[-1]}" if len(out) > 1 else ""))
    return 0


def reproduce_paper(args):
    from .reproduce import reproduce

    if args.jobs == 0:
        raise InputError("--jobs must be a nonzero number of processes (-1: all cores)")
    files = reproduce(args.out, quick=args.quick, jobs=args.jobs, scheduler=args.scheduler,
                      progress=not args.no_progress, only=args.only)
    print(f"wrote {len(files)} files into {args.out}; see {args.out}/report.md")
    return 0


def main(argv=None):
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        if args.command == "run":
            return run_scene(args)
        if args.command == "render":
            return render_scene(args)
        if args.command == "reproduce":
            return reproduce_paper(args)
        if args.command == "compile":
            from .warmup import compile_kernels

            seconds = compile_kernels(args.jobs, out=None if args.no_progress else sys.stderr)
            print(f"compiled the kernels in {seconds:.0f} s")
            return 0
    except VdadError as exc:
        print(f"vdad: error: {exc}", file=sys.stderr)
        return 2
    except OSError as exc:
        print(f"vdad: error: {exc}", file=sys.stderr)
        return 2
    return 1


if __name__ == "__main__":
    sys.exit(main())
