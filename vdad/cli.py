"""The ``vdad`` command line: ``vdad run SCENE ...``.

Every command has ``--help``; results go to plain JSON files.
"""

from __future__ import annotations

import argparse
import json
import sys
import time

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


def build_parser():
    from .adaptive import METRICS, POLICIES
    from .bounding import VOLUMES
    from .integrators import INTEGRATORS
    from .scenes import SCENES
    from .simulator import METHODS
    from .visibility import ESTIMATES

    parser = argparse.ArgumentParser(
        prog="vdad", description="View-dependent dynamics of articulated bodies "
        "(Kim, Redon and Kim 2008).")
    sub = parser.add_subparsers(dest="command", required=True)
    run = sub.add_parser("run", help="simulate a scene and report timing",
                         description="Simulate one of the paper's scenes and write a JSON "
                         "summary (timing, final state).")
    run.add_argument("scene", choices=sorted(SCENES), help="scene to simulate")
    run.add_argument("--bodies", type=_positive_int, default=20,
                     help="number of bodies (pendulum links; default 20)")
    run.add_argument("--steps", type=_positive_int, default=500,
                     help="number of time steps (default 500)")
    run.add_argument("--dt", type=_positive_float, default=1e-3, help="time step in s (1e-3)")
    run.add_argument("--method", choices=METHODS, default="dca",
                     help="dynamics method: exact DCA, adaptive dynamics, or view-dependent "
                     "adaptive dynamics with coverage from bounding volumes (view-bvh) or "
                     "rendered occlusion counts (view-oq, needs EGL) (default dca)")
    adaptive = run.add_argument_group(
        "adaptive dynamics", "with --method adaptive, view-bvh or view-oq: give --threshold "
        "or --budget (view methods: in pixels times displacement per step)")
    adaptive.add_argument("--threshold", type=_nonnegative_float,
                          help="drop accelerations whose score (weighted displacement per "
                          "step) is below this; 0 reproduces the DCA")
    adaptive.add_argument("--budget", type=_nonnegative_int,
                          help="accelerate only this many joints (max-heap on the metric)")
    adaptive.add_argument("--policy", choices=POLICIES, default="momentum",
                          help="velocities of newly rigid joints: momentum-conserving "
                          "locking impulse, or zeroed as in the paper (default momentum)")
    adaptive.add_argument("--metric", choices=METRICS, default="coefficients",
                          help="predict the metric from (T16)-(T18), or sum it from computed "
                          "accelerations (same values; default coefficients)")
    adaptive.add_argument("--dwell", type=_nonnegative_int, default=10,
                          help="steps a joint keeps a new state (default 10)")
    adaptive.add_argument("--kappa", type=float, default=4.0,
                          help="hysteresis: rigidify below threshold/kappa (default 4)")
    view = run.add_argument_group("view-dependent methods", "with --method view-bvh or view-oq")
    view.add_argument("--volume", choices=VOLUMES, default="sphere",
                      help="bounding volume of view-bvh (default sphere)")
    view.add_argument("--estimate", choices=ESTIMATES, default="min",
                      help="view-bvh coverage: min of the node's and its bodies' areas "
                      "(eq. 7), the node's (eq. 5) or the bodies' (eq. 6) (default min)")
    view.add_argument("--counting", choices=("queries", "merged"), default="queries",
                      help="view-oq counts: occlusion queries (the paper's) or one merged "
                      "id buffer (same counts, faster) (default queries)")
    view.add_argument("--resolution", type=_resolution, default=(320, 240),
                      help="counting resolution WIDTHxHEIGHT (default 320x240)")
    view.add_argument("--camera-distance", type=_positive_float,
                      help="viewer's distance in m (default: the whole scene in view)")
    view.add_argument("--coverage-every", type=_positive_int, default=1,
                      help="steps between coverage evaluations (default 1: every step)")
    run.add_argument("--integrator", choices=sorted(INTEGRATORS), default="semi-implicit",
                     help="time integrator (default semi-implicit Euler)")
    run.add_argument("--json", metavar="PATH", help="write the summary as JSON to PATH")
    run.add_argument("--no-progress", action="store_true", help="hide the progress bar")
    return parser


def run_scene(args):
    from tqdm import tqdm

    from .scenes import SCENES

    scene = SCENES[args.scene](n_bodies=args.bodies, dt=args.dt,
                               camera_distance=args.camera_distance,
                               resolution=args.resolution)
    options = {}
    if args.method != "dca":
        options = dict(threshold=args.threshold, budget=args.budget, policy=args.policy,
                       metric=args.metric, dwell=args.dwell, kappa=args.kappa)
    elif args.threshold is not None or args.budget is not None:
        raise InputError("--threshold and --budget need --method adaptive, view-bvh or view-oq")
    if args.method == "view-bvh":
        options.update(volume=args.volume, estimate=args.estimate,
                       coverage_every=args.coverage_every)
    elif args.method == "view-oq":
        options.update(counting=args.counting, coverage_every=args.coverage_every)
    sim = scene.simulator(method=args.method, integrator=args.integrator, **options)
    chunk = max(1, args.steps // 100)
    start = time.perf_counter()
    with tqdm(total=args.steps, desc=f"{args.scene} ({scene.model.nb} bodies)", unit="step",
              disable=args.no_progress, file=sys.stderr) as bar:
        done = 0
        while done < args.steps:
            n = min(chunk, args.steps - done)
            sim.step(n)
            done += n
            bar.update(n)
    elapsed = time.perf_counter() - start
    summary = {
        "scene": scene.name, "method": args.method, "integrator": args.integrator,
        "bodies": scene.model.nb, "joints": scene.model.nb, "dofs": scene.model.nv,
        "steps": args.steps, "dt": args.dt, "simulated_time": sim.t,
        "ms_per_step": 1e3 * elapsed / args.steps, "final_q": sim.q.tolist(),
        "final_qd": sim.qd.tolist(), "params": scene.params,
    }
    if sim.history:
        summary.update(adaptive_summary(sim.history))
        summary["adaptive"] = {k: v for k, v in options.items() if v is not None}
    if args.json:
        with open(args.json, "w") as fh:
            json.dump(summary, fh, indent=1)
    active = (f", {summary['active_joints_mean']:.1f} of {scene.model.nb} joints active on "
              f"average" if sim.history else "")
    print(f"{scene.description}: {args.steps} steps of {args.dt} s with {args.method} "
          f"({args.integrator}), {summary['ms_per_step']:.3f} ms per step{active}"
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


def main(argv=None):
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        if args.command == "run":
            return run_scene(args)
    except VdadError as exc:
        print(f"vdad: error: {exc}", file=sys.stderr)
        return 2
    except OSError as exc:
        print(f"vdad: error: {exc}", file=sys.stderr)
        return 2
    return 1


if __name__ == "__main__":
    sys.exit(main())
