"""What evaluating the coverage once per displayed frame instead of every step
changes (issue 16): error, active joints and time per step of view-bvh and
view-oq at each scene's defaults, with ``coverage_every`` 1 and the steps of a
60 Hz frame, measured as ``docs/scenes.md`` measures the defaults
(``vdad.visual_error.measure(sim, steps, 10)`` against a full-DCA run).

Writes ``docs/bench_coverage_every.json`` and the table between the markers of
``docs/visibility.md``. Usage: ``python scripts/bench_coverage_every.py``.
"""

from __future__ import annotations

import json
import platform
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_dynamics import DOCS, write_section  # noqa: E402

from vdad.scenes import SCENES  # noqa: E402
from vdad.visual_error import measure  # noqa: E402

MARK = ("<!-- bench_coverage_every:start -->", "<!-- bench_coverage_every:end -->")
FRAME_RATE = 60.0                                    # displayed frames per second
STEPS = {"pendulum": 1000, "dog_puppet": 1000, "hanging_dogs": 100, "falling_character": 1000}


def main():
    rows = []
    for name, steps in STEPS.items():
        scene = SCENES[name]()
        frame = max(1, round(1.0 / (FRAME_RATE * scene.dt)))
        for method in ("view-bvh", "view-oq"):
            extra = {"counting": "merged"} if method == "view-oq" else {}
            for every in (1, frame):
                sim = scene.simulator(method=method, coverage_every=every, **extra)
                trace, info = measure(sim, steps, 10)
                row = dict(scene=name, method=method, coverage_every=every, steps=info["steps"],
                           mean_px=float(np.mean(trace.mean_px)),
                           max_px=float(np.max(trace.max_px)),
                           active_joints=info["active_joints"], joints=scene.model.nb,
                           ms_per_step=info["ms_per_step"],
                           reference_ms_per_step=info["reference_ms_per_step"],
                           failure=info["failure"], options={
                               k: v for k, v in sim.options.items() if k != "coverage"})
                rows.append(row)
                print(json.dumps({k: row[k] for k in row if k != "options"}), flush=True)
    result = dict(machine=f"{platform.machine()}", frame_rate=FRAME_RATE, rows=rows)
    (DOCS / "bench_coverage_every.json").write_text(json.dumps(result, indent=1))
    lines = ["", f"`python scripts/bench_coverage_every.py`: each scene's view-bvh and view-oq "
             f"(merged counting) at its defaults, coverage every step and once per frame at "
             f"{FRAME_RATE:g} Hz; mean px over frames every 10 steps against a full-DCA run.",
             "", "| scene | method | coverage every | mean px | max px | active joints | "
             "ms per step | DCA ms per step |", "|---|---|---|---|---|---|---|---|"]
    for r in rows:
        lines.append(f"| {r['scene']} | {r['method']} | {r['coverage_every']} step(s) | "
                     f"{r['mean_px']:.3g} | {r['max_px']:.3g} | {r['active_joints']:.1f} of "
                     f"{r['joints']} | {r['ms_per_step']:.3f} | "
                     f"{r['reference_ms_per_step']:.3f} |"
                     + (f" diverged: {r['failure']}" if r["failure"] else ""))
    write_section(MARK, lines, DOCS / "visibility.md")


if __name__ == "__main__":
    main()
