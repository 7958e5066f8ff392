"""Time what a call of ``Simulator.step`` costs beside its steps (issue 16, Table 1).

A program that draws every frame steps the simulator once per frame, and
``vdad reproduce`` once per measured frame (every 10 steps in Table 1), so each
call's fixed cost (the Python around the compiled step loop and numba's
dispatch of its arrays) is paid once per frame. On the 20-body pendulum of
Table 1 (the full DCA, adaptive dynamics at threshold 1e-4 and view-bvh with
the moved-pixels rule at 0.1, both at 7.7 active joints on average) the script
times Table 1's 1000 steps from the scene's initial state in calls of k = 1, 10
and 100 steps, each run a deep copy of a simulator that has not stepped, the
runs in turns, a round of each per repeat (this shared VM's speed drifts), and
fits ``fixed + k per_step`` to the medians. Writes ``docs/bench_calls.json``
and the section between the markers of ``docs/benchmarks.md``. Usage:
``python scripts/bench_calls.py [--quick]``.
"""

from __future__ import annotations

import argparse
import copy
import json
import os
import platform
import statistics
import time
from pathlib import Path

import numpy as np
from bench_dynamics import DOCS, write_section

import vdad
from vdad.scenes import pendulum

MARK = ("<!-- bench_calls:start -->", "<!-- bench_calls:end -->")
STEPS = (1, 10, 100)
RUNS = {"full DCA": {},
        "adaptive, threshold 1e-4": {"method": "adaptive", "threshold": 1e-4},
        "view-bvh, moved pixels, 0.1": {"method": "view-bvh", "threshold": 0.1,
                                        "pixels": "moved"}}
#: Table 1's steps (dt = 1 ms)
TABLE1_STEPS = 1000


def fixed_and_per_step(us):
    """Least-squares ``(fixed, per_step)`` µs of ``us`` = {k: µs per call of k steps}."""
    k = np.array(sorted(us), float)
    per_step, fixed = np.polyfit(k, [us[int(x)] for x in k], 1)
    return float(fixed), float(per_step)


def replay(sim0, k):
    """Seconds that Table 1's steps take from a deep copy of ``sim0`` in calls of
    ``k`` steps, and the copy."""
    sim = copy.deepcopy(sim0)
    t0 = time.perf_counter()
    for _ in range(TABLE1_STEPS // k):
        sim.step(k)
    return time.perf_counter() - t0, sim


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="a shorter timing")
    parser.add_argument("--out", default=str(DOCS / "bench_calls.json"))
    args = parser.parse_args(argv)
    scene = pendulum(20)
    sims = {name: scene.simulator(**options) for name, options in RUNS.items()}
    seconds = {(name, k): [] for name in sims for k in STEPS}
    last = {name: replay(sim, 1)[1] for name, sim in sims.items()}     # loads the kernels
    for _ in range(3 if args.quick else 15):
        for name, sim in sims.items():
            for k in STEPS:
                seconds[name, k].append(replay(sim, k)[0])
    rows = []
    for name, sim in last.items():
        per_k = {k: 1e6 * statistics.median(seconds[name, k]) * k / TABLE1_STEPS
                 for k in STEPS}
        fixed, per_step = fixed_and_per_step(per_k)
        active = (np.mean([s.active_joints for s in sim.history])
                  if sim.adaptive is not None else scene.model.nb)
        rows.append(dict(run=name, active=float(active), us_per_call=per_k,
                         fixed_us=fixed, per_step_us=per_step))
        print(json.dumps(rows[-1]), flush=True)
    result = dict(machine=f"{platform.processor() or platform.machine()}, {os.cpu_count()} cores",
                  python=platform.python_version(), numpy=np.__version__, vdad=vdad.__version__,
                  quick=args.quick, rows=rows)
    Path(args.out).write_text(json.dumps(result, indent=1))
    write_table(result)


def write_table(result):
    full = next(r for r in result["rows"] if r["run"] == "full DCA")
    lines = ["", f"Median µs per `sim.step(k)` call over Table 1's {TABLE1_STEPS} steps of "
             f"the 20-body pendulum, timed in turns; Python {result['python']}, numpy "
             f"{result['numpy']}, {result['machine']}{' (quick run)' if result['quick'] else ''}"
             ". Fixed and per-step costs: least squares over k. Speed-up: the full DCA's "
             "time per step over the run's, at k steps per call.", "",
             "| run | active joints | " + " | ".join(f"k = {k}" for k in STEPS)
             + " | fixed µs per call | µs per step | "
             + " | ".join(f"speed-up at k = {k}" for k in STEPS) + " |",
             "|---|---|" + "---|" * (2 * len(STEPS) + 2)]
    for r in result["rows"]:
        calls = r["us_per_call"]
        lines.append(f"| {r['run']} | {r['active']:.1f} | "
                     + " | ".join(f"{calls[k]:.1f}" for k in STEPS)
                     + f" | {r['fixed_us']:.1f} | {r['per_step_us']:.2f} | "
                     + " | ".join(f"{full['us_per_call'][k] / calls[k]:.2f}x" for k in STEPS)
                     + " |")
    write_section(MARK, lines)


if __name__ == "__main__":
    main()
