"""Where the falling character's time goes (issue 16, ``docs/reproduction.md``):
time per step in windows of 250 steps of the full DCA, of the speed study's
"slow" family (view-bvh, moved-pixels rule, ``vdad.reproduce.SLOW_OPTIONS``)
and of its variants by coverage period, dwell and look-ahead period, of
lod-distance at 5 m,
of adaptive dynamics with every joint active, and of the ideal rule that
``docs/reproduction.md`` bounds the speed-up with (every joint active, then one
rigid body on its free joint from a given time on: :func:`frozen_from`, an
oracle that knows when the character has landed, not a method); with each
window's active joints, region changes and look-ahead tests, and each run's
mean screen error against the DCA (``vdad.visual_error.measure``, frames every
25 steps).

Each window's time is its fastest over ``ROUNDS`` runs, the runs in turn.
Writes ``docs/bench_character.json`` and the table between the markers of
``docs/benchmarks.md``. Usage: ``python scripts/bench_character.py``.
"""

from __future__ import annotations

import json
import platform
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_dynamics import DOCS, write_section  # noqa: E402

from vdad.reproduce import SLOW, SLOW_OPTIONS  # noqa: E402
from vdad.scenes import SCENES  # noqa: E402
from vdad.simulator import frame_steps  # noqa: E402
from vdad.visual_error import measure  # noqa: E402

MARK = ("<!-- bench_character:start -->", "<!-- bench_character:end -->")
STEPS, EVERY, WINDOW, ROUNDS = 2500, 25, 250, 3
MOVED = {"pixels": "moved", "threshold": 7e-3}
FAMILY = {"pixels": "moved", "threshold": 1.2e-2, **SLOW_OPTIONS}
FRAME = frame_steps(1e-3)             # steps per displayed frame (the character's dt)
RUNS = {
    "dca": ("dca", {}),
    "slow family, 1.2e-2": ("view-bvh", FAMILY),
    "slow family, 1.2e-2, coverage every frame": ("view-bvh", {**FAMILY,
                                                               "coverage_every": FRAME}),
    "slow family, 1.2e-2, coverage every 3 frames": ("view-bvh", {**FAMILY,
                                                                  "coverage_every": 3 * FRAME}),
    "slow family, 7e-3": ("view-bvh", {**FAMILY, **MOVED}),
    "look-ahead every 5, 7e-3": ("view-bvh", {**FAMILY, **MOVED, "lookahead_every": 5}),
    "dwell 10, look-ahead every 1": ("view-bvh", {**MOVED, "velocity_weights": SLOW}),
    "dwell 50, look-ahead every 1": ("view-bvh", {**MOVED, "velocity_weights": SLOW,
                                                  "dwell": 50}),
    "dwell 100, look-ahead every 1": ("view-bvh", {**MOVED, "velocity_weights": SLOW,
                                                   "dwell": 100}),
    "dwell 200, look-ahead every 5": ("view-bvh", {**MOVED, **SLOW_OPTIONS, "dwell": 200,
                                                   "lookahead_every": 5}),
    "lod-distance 5 m": ("lod-distance", {"distance": 5.0}),
    "adaptive, all joints active": ("adaptive", {"threshold": 0.0}),
    "ideal, one rigid body from 0.7 s": ("adaptive", {"threshold": 0.0}),
    "ideal, one rigid body from 0.8 s": ("adaptive", {"threshold": 0.0}),
}
FROZEN_FROM = {"ideal, one rigid body from 0.7 s": 700, "ideal, one rigid body from 0.8 s": 800}


def simulator(name):
    """The falling character's simulator for run ``name``."""
    method, options = RUNS[name]
    sim = SCENES["falling_character"]().simulator(method=method, **options)
    if name in FROZEN_FROM:
        frozen_from(sim, FROZEN_FROM[name])
    return sim


def frozen_from(sim, step):
    """Make the adaptive ``sim`` (threshold 0: every joint active) one rigid body
    on its free joint from simulator step ``step`` on: its threshold is set to
    infinity before the first call of ``sim.step`` that starts at or after
    ``step`` (here every call is a frame of ``EVERY`` steps), so the next region
    update rigidifies every node it may."""
    step_calls = sim.step

    def step_then_frozen(n=1):
        if sim.step_count >= step:
            sim.adaptive.threshold = np.inf
        return step_calls(n)

    sim.step = step_then_frozen


def windows(name):
    """Seconds per window of ``WINDOW`` steps of run ``name`` (the first frame,
    which loads the kernels, left out of the first window) and its history."""
    sim = simulator(name)
    sim.step(EVERY)
    seconds = np.zeros(STEPS // WINDOW)
    for f in range(1, STEPS // EVERY):
        t0 = time.perf_counter()
        sim.step(EVERY)
        seconds[f * EVERY // WINDOW] += time.perf_counter() - t0
    return seconds, sim.history


def main():
    best, history = {}, {}
    for _ in range(ROUNDS):
        for name in RUNS:
            seconds, history[name] = windows(name)
            best[name] = np.minimum(best.get(name, np.inf), seconds)
    rows = []
    for name, (method, options) in RUNS.items():
        steps = np.full(STEPS // WINDOW, WINDOW)
        steps[0] -= EVERY
        us = 1e6 * best[name] / steps                          # (windows,)
        h = history[name]
        per = [h[k * WINDOW:(k + 1) * WINDOW] for k in range(STEPS // WINDOW)]
        error = None
        if method != "dca":
            trace, _ = measure(simulator(name), STEPS, EVERY)
            error = float(np.mean(trace.mean_px))
        rows.append(dict(
            run=name, method=method, options=options, us_per_window=us.tolist(),
            us_per_step=float(1e6 * best[name].sum() / steps.sum()),
            active_joints=[float(np.mean([s.active_joints for s in w])) if w else 29.0
                           for w in per],
            changes=[int(sum(s.rigidified + s.released for s in w)) for w in per],
            lookahead=[float(np.mean([s.lookahead for s in w])) if w else 0.0 for w in per],
            mean_px=error))
        print(json.dumps({k: rows[-1][k] for k in ("run", "us_per_step", "mean_px")}),
              flush=True)
    dca = rows[0]["us_per_step"]
    result = dict(machine=platform.machine(), steps=STEPS, window=WINDOW, rounds=ROUNDS,
                  rows=rows)
    (DOCS / "bench_character.json").write_text(json.dumps(result, indent=1))
    lines = ["", f"`python scripts/bench_character.py`: the falling character, {STEPS} steps, "
             f"µs a step in windows of {WINDOW} steps (the fastest of {ROUNDS} runs, taken in "
             "turn), the whole run's speed-up over the DCA of the same rounds, and the mean "
             "screen error against the DCA (frames every 25 steps). View-bvh rows: the "
             "moved-pixels rule at 7e-3 with velocity weights 1e-4 unless named; \"slow family\" "
             "is the speed study's (velocity weights {velocity_weights:g}, dwell {dwell}, "
             "look-ahead every {lookahead_every}, coverage every {coverage_every} steps); "
             "the others' coverage is every frame ({frame} steps); \"ideal\" rows are the "
             "oracle of `frozen_from`, not a method. Below each: active joints, then region "
             "changes (nodes rigidified and released) per window.".format(**SLOW_OPTIONS,
                                                                          frame=FRAME), "",
             "| run | µs a step, windows 1-10 | whole run | speed-up | mean px |",
             "|---|---|---|---|---|"]
    for r in rows:
        px = "" if r["mean_px"] is None else f"{r['mean_px']:.2f}"
        lines.append(f"| {r['run']} | {', '.join(f'{u:.1f}' for u in r['us_per_window'])} | "
                     f"{r['us_per_step']:.1f} | {dca / r['us_per_step']:.2f}x | {px} |")
        if r["method"] != "dca":
            lines.append(f"| | joints {', '.join(f'{a:.0f}' for a in r['active_joints'])}; "
                         f"changes {', '.join(str(c) for c in r['changes'])} | | | |")
    write_section(MARK, lines)


if __name__ == "__main__":
    main()
