"""Benchmark of the paper's scenes (Kim 2008 §6.1) with every method.

For each scene and method: ms per step, mean active joints, and the share of the
step spent on visibility (coverage ``N_M``); beside them, in the same run, one
forward-dynamics evaluation of the scene's model by Pinocchio (ABA) and MuJoCo
(``mj_forward``) as ratios. The headline is the 100 hanging dogs with
``view-oq`` (paper: 14 ms per frame in C++ on 2008 hardware, 493 of 1500
joints active). Beside each figure, the same run of the previous numpy core
(``docs/bench_scenes_numpy.json``, kept from before the compiled core) and the
speed-up. Writes ``docs/bench_scenes.json`` and a section of
``docs/benchmarks.md``. ``--quick`` runs fewer steps; ``--methods dca`` runs only
some methods (the others keep the rows of the previous ``bench_scenes.json``,
marked as from an earlier run).
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import time

import numpy as np
from bench_dynamics import DOCS, fmt, time_mujoco, time_pinocchio, write_section

from vdad.errors import SimulationError
from vdad.render.context import renderer_name
from vdad.scenes import dog_puppet, falling_character, hanging_dogs, pendulum

METHODS = ("dca", "adaptive", "view-bvh", "view-oq")
# scene, steps (full, quick), threshold per method (adaptive: weighted displacement per
# step; view methods: pixels times displacement per step)
SCENES = [
    ("pendulum (20 links)", lambda: pendulum(n_bodies=20), (1000, 200),
     {"adaptive": 1e-6, "view-bvh": 0.003, "view-oq": 0.003}),
    ("dog puppet (16 bodies)", dog_puppet, (3700, 600),
     {"adaptive": 1e-5, "view-bvh": 0.03, "view-oq": 0.03}),
    ("100 hanging dogs (1600 bodies)", hanging_dogs, (300, 40),
     {"adaptive": 1e-6, "view-bvh": 0.01, "view-oq": 0.01}),
    ("falling character (29 bodies)", falling_character, (2500, 400),
     {"adaptive": 1e-6, "view-bvh": 0.003, "view-oq": 0.003}),
]


def run(scene, method, threshold, steps):
    """ms per step, mean active joints and ms of visibility per step of one run, and
    the error message if it diverged (the means are then over the steps done). A
    throwaway step first loads the compiled kernels (start-up is timed by
    bench_dynamics.py)."""
    options = {} if method == "dca" else {"threshold": threshold}
    if method == "view-oq":
        options["counting"] = "merged"
    scene.simulator(method=method, **options).step(1)   # numba loads its kernels once
    sim = scene.simulator(method=method, **options)
    t0 = time.perf_counter()
    try:
        sim.step(steps)
        failure = None
    except SimulationError as exc:
        failure = str(exc).split(":")[0] + ": diverged"
    ms = 1e3 * (time.perf_counter() - t0) / max(sim.step_count, 1)
    if not sim.history:
        return ms, float(scene.model.nb), 0.0, failure
    active = float(np.mean([s.active_joints for s in sim.history]))
    vis = 1e3 * float(np.mean([s.times.get("visibility", 0.0) for s in sim.history]))
    return ms, active, vis, failure


def oracle_us(model):
    """µs of one forward dynamics by Pinocchio and MuJoCo (None, with the reason
    printed, where one cannot run the model)."""
    out = {}
    for name, fn in (("pinocchio", time_pinocchio), ("mujoco", time_mujoco)):
        out[name], note = fn(model, 0.5)
        if note:
            print(f"  {note}")
    return out


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="fewer steps")
    parser.add_argument("--methods", nargs="+", choices=METHODS, default=list(METHODS),
                        help="methods to run (default: all)")
    args = parser.parse_args(argv)
    path = DOCS / "bench_scenes.json"
    kept = [dict(r, earlier=True) for r in
            (json.loads(path.read_text())["rows"] if path.exists() else [])
            if r["method"] not in args.methods]
    rows = []
    for name, build, steps, thresholds in SCENES:
        scene = build()
        n = steps[1] if args.quick else steps[0]
        print(f"{name}: {n} steps")
        oracles = oracle_us(scene.model)
        for method in args.methods:
            ms, active, vis, failure = run(scene, method, thresholds.get(method), n)
            rows.append(dict(scene=name, method=method, steps=n, dt=scene.dt, failure=failure,
                             threshold=thresholds.get(method), ms_per_step=ms,
                             active_joints=active, joints=scene.model.nb,
                             visibility_ms=vis, **{f"{k}_us": v for k, v in oracles.items()}))
            print(f"  {method:9s} {ms:8.2f} ms/step, {active:7.1f} active, "
                  f"visibility {vis:6.2f} ms" + (f" ({failure})" if failure else ""))
    result = dict(machine=platform.processor() or platform.machine(), cpus=os.cpu_count(),
                  python=platform.python_version(), numpy=np.__version__,
                  renderer=renderer_name(), quick=args.quick,
                  rows=sorted(rows + kept, key=lambda r: (
                      [s[0] for s in SCENES].index(r["scene"]), METHODS.index(r["method"]))))
    path.write_text(json.dumps(result, indent=1))
    write_tables(result)


def write_tables(result):
    lines = [
        "## bench_scenes: the paper's scenes with every method",
        "",
        f"`python scripts/bench_scenes.py` on {result['cpus']} CPUs, numpy "
        f"{result['numpy']}, counting on {result['renderer']}"
        + (" (quick)" if result["quick"] else "") + ". Each run starts at the scene's "
        "initial state; ms per step over the whole run, active joints averaged over "
        "its steps; visibility: ms per step spent on `N_M` (view-oq counts with the "
        "merged id buffer). Pinocchio and MuJoCo: one forward dynamics of the same "
        "model (no scene forces), µs, and the DCA step as a multiple of it. numpy core: "
        "the same run before the compiled core (`bench_scenes_numpy.json`); rows marked "
        "* are from an earlier run than the others.",
        "",
        "| scene | method | threshold | ms/step | active joints | visibility ms | "
        "DCA / Pinocchio ABA | DCA / MuJoCo | numpy core ms/step | speed-up |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    old_path = DOCS / "bench_scenes_numpy.json"
    old = {(r["scene"], r["method"]): r["ms_per_step"]
           for r in (json.loads(old_path.read_text())["rows"] if old_path.exists() else [])}
    dca = {r["scene"]: r["ms_per_step"] for r in result["rows"] if r["method"] == "dca"}
    for r in result["rows"]:
        ratios = ["" if r[f"{k}_us"] is None or r["method"] != "dca"
                  else fmt(1e3 * dca[r["scene"]] / r[f"{k}_us"], 0) + "x"
                  for k in ("pinocchio", "mujoco")]
        before = None if r.get("earlier") else old.get((r["scene"], r["method"]))
        lines.append(f"| {r['scene']} | {r['method']}{' *' if r.get('earlier') else ''} | "
                     f"{'' if r['threshold'] is None else r['threshold']} | "
                     f"{fmt(r['ms_per_step'], 2)} | {fmt(r['active_joints'])} of {r['joints']} "
                     f"| {fmt(r['visibility_ms'], 2)} | {ratios[0]} | {ratios[1]} | "
                     f"{fmt(before, 2)} | "
                     f"{'' if before is None else fmt(before / r['ms_per_step'], 1) + 'x'} |"
                     + (f" {r['failure']}" if r["failure"] else ""))
    head = [r for r in result["rows"] if r["scene"].startswith("100") and r["method"] == "view-oq"]
    if head:
        h = head[0]
        lines += ["", f"**Headline, 100 hanging dogs with view-oq**: {fmt(h['ms_per_step'], 1)} "
                  f"ms per step with {fmt(h['active_joints'])} of {h['joints']} joints active "
                  f"(100 of them the dogs' free roots, never rigidified); the paper: 14 ms per "
                  f"frame in C++ (2008) with 493 of 1500 internal joints active."]
    write_section(("<!-- bench_scenes:start -->", "<!-- bench_scenes:end -->"), lines)


if __name__ == "__main__":
    main()
