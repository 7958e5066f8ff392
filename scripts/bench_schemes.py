"""Dropped accelerations and energy: the ``drop`` schemes and the energy cap of adaptive
dynamics on the paper's scenes (issue 15).

Every configuration of ``vdad reproduce`` that runs adaptive dynamics
(``adaptive``, ``view-bvh``, ``view-oq``), each scene's calibrated defaults (what
``vdad run`` uses) and the 10000-body budget run, once per scheme (``coast``: the
paper's, ``lock``: the consistent one, each without the energy cap (``energy="free"``)
and with it (``+cap``, the default), ``docs/adaptive.md``). Each run steps beside
the full DCA from the same state and records, every ``every`` steps, the total
energy of both (on the conservative scenes: pendulums without damping), the
screen-space error of ``vdad.visual_error`` (surface points, no rendering),
the active joints, the time per step, and whether and where it diverged. The
runs are a resumable sweep (``vdad.sweep``: results are written as they come, a
killed run resumes) in ``--store``; the summary goes to
``docs/bench_schemes.json`` and the table between the markers of
``docs/adaptive.md``. Usage: ``python scripts/bench_schemes.py [--quick]
[--store DIR] [--only SCENE ...]``.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np
from bench_dynamics import DOCS, write_section

from vdad.errors import SimulationError
from vdad.quantities import total_energy
from vdad.reproduce import plan
from vdad.scenes import SCENES
from vdad.sweep import ResultStore, run_sweep
from vdad.visual_error import VisualError

MARK = ("<!-- bench_schemes:start -->", "<!-- bench_schemes:end -->")
METHODS = ("adaptive", "view-bvh", "view-oq")
#: the scenes' own defaults (``vdad run``), and the run of the issue
EXTRA = [("pendulum", {"n_bodies": 20}, 1000, 10), ("pendulum", {"n_bodies": 300}, 600, 20),
         ("dog_puppet", {}, 1000, 10), ("hanging_dogs", {}, 300, 10),
         ("falling_character", {}, 2500, 25)]
BUDGET_RUN = ("pendulum", {"n_bodies": 10000}, "adaptive", {"budget": 50}, 100, 10)
#: (drop, energy) of each scheme compared
SCHEMES = (("coast", "free"), ("lock", "free"), ("coast", "cap"), ("lock", "cap"))


def configs(quick):
    """Every run of the study: (scene, args, method, options, steps, every) per scheme."""
    runs = []
    for experiment in plan(quick).values():
        for c in experiment:
            if c["method"] in METHODS:
                runs.append((c["scene"], c["scene_args"], c["method"], c["options"], c["steps"],
                             c["every"]))
    for scene, args, steps, every in EXTRA:
        for method in METHODS:
            runs.append((scene, args, method, {}, steps // 4 if quick else steps, every))
    runs.append(BUDGET_RUN)
    out = []
    for scene, args, method, options, steps, every in runs:
        for drop, energy in SCHEMES:
            out.append(dict(scene=scene, scene_args=args, method=method,
                            options={**options, "drop": drop, "energy": energy}, steps=steps,
                            every=every))
    return out


def conservative(name, scene):
    """Pendulums without damping conserve energy; their ``m g L``."""
    if name != "pendulum" or scene.params.get("damping", 0.0) != 0.0:
        return None
    m = float(np.sum(scene.model.mass))
    return m * abs(scene.params["gravity"]) * scene.model.nb * scene.params["link_length"]


def run_scheme(config):
    """One run beside the full DCA: energy, error, activity, time, divergence."""
    args = dict(config["scene_args"])
    if "resolution" in args:
        args["resolution"] = tuple(args["resolution"])
    scene = SCENES[config["scene"]](**args)
    sim = scene.simulator(method=config["method"], **config["options"])
    ref = scene.simulator()
    mgL = conservative(config["scene"], scene)
    E0 = total_energy(scene.model, sim.q, sim.qd) if mgL else None
    gain, ref_gain, errors, failure, elapsed, ref_elapsed = -np.inf, -np.inf, [], None, 0.0, 0.0
    frames = config["steps"] // config["every"]
    with VisualError(scene.model, scene.camera, scene.environment, pixels=False) as error:
        for _ in range(frames):
            t0 = time.perf_counter()
            try:
                sim.step(config["every"])
            except SimulationError as exc:
                failure = str(exc)
                break
            finally:
                elapsed += time.perf_counter() - t0
            t0 = time.perf_counter()
            ref.step(config["every"])
            ref_elapsed += time.perf_counter() - t0
            if mgL:
                gain = max(gain, total_energy(scene.model, sim.q, sim.qd) - E0)
                ref_gain = max(ref_gain, total_energy(scene.model, ref.q, ref.qd) - E0)
            errors.append(error(sim.t, ref.q, sim.q)["max_px"])
    steps = sim.step_count
    history = sim.history
    return dict(steps=steps, failure=failure, diverged=failure is not None,
                ms_per_step=1e3 * elapsed / max(steps, 1),
                dca_ms_per_step=1e3 * ref_elapsed / max(ref.step_count, 1),
                active_mean=float(np.mean([s.active_joints for s in history])) if history else None,
                max_px=float(np.nanmax(errors)) if errors else None,
                mean_px=float(np.nanmean(errors)) if errors else None,
                energy_gain=float(gain) if mgL else None,
                dca_energy_gain=float(ref_gain) if mgL else None,
                energy_removed=sim.adaptive.energy_removed,
                mgL=mgL, bound=float(max(ref_gain, 0.0) + 1e-3 * mgL) if mgL else None)


def label(c):
    args = ", ".join(f"{k}={v}" for k, v in c["scene_args"].items())
    options = ", ".join(f"{k}={v}" for k, v in c["options"].items()
                        if k not in ("drop", "energy"))
    return f"{c['scene']}({args})", c["method"], options


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="the short plan of vdad reproduce")
    parser.add_argument("--store", default="bench_schemes_runs", help="folder of the sweep")
    parser.add_argument("--only", nargs="*", help="scenes to run (default: all)")
    parser.add_argument("--out", default=str(DOCS / "bench_schemes.json"))
    args = parser.parse_args(argv)
    runs = [c for c in configs(args.quick) if not args.only or c["scene"] in args.only]
    report = run_sweep(run_scheme, runs, ResultStore(args.store), desc="schemes")
    rows = [{**r, "config": c} for c, r in zip(runs, report.results, strict=True)]
    Path(args.out).write_text(json.dumps(dict(quick=args.quick, rows=rows), indent=1))
    write_table(rows)


def scheme(c):
    """``coast``, ``lock``, ``coast+cap`` or ``lock+cap``."""
    return c["options"]["drop"] + ("+cap" if c["options"]["energy"] == "cap" else "")


def write_table(rows):
    """Per scheme and method family: runs, divergences, energy gains against the
    bound, error and speed (medians over the configurations)."""
    lines = ["", "| scheme | scene | method | runs | diverged | energy over bound | worst gain / "
             "bound | most removed by the cap (J) | median max error (px) | median active | "
             "median speed-up |",
             "|---|---|---|---|---|---|---|---|---|---|---|"]
    groups = {}
    for r in rows:
        c = r["config"]
        groups.setdefault((scheme(c), label(c)[0].split("(")[0], c["method"]),
                          []).append(r)
    for (name, scene, method), rs in sorted(groups.items()):
        energy = [r for r in rs if r["energy_gain"] is not None and not r["diverged"]]
        over = sum(r["energy_gain"] > r["bound"] for r in energy)
        worst = max((r["energy_gain"] / r["bound"] for r in energy), default=None)
        removed = max(r.get("energy_removed", 0.0) for r in rs)
        px = [r["max_px"] for r in rs if r["max_px"] is not None]
        act = [r["active_mean"] for r in rs if r["active_mean"] is not None]
        speed = [r["dca_ms_per_step"] / r["ms_per_step"] for r in rs if r["ms_per_step"]]
        lines.append(f"| {name} | {scene} | {method} | {len(rs)} | "
                     f"{sum(r['diverged'] for r in rs)} | "
                     f"{over} of {len(energy)} | "
                     f"{'—' if worst is None else f'{worst:.2g}'} | {removed:.3g} | "
                     f"{np.median(px) if px else float('nan'):.3g} | "
                     f"{np.median(act) if act else float('nan'):.1f} | "
                     f"{np.median(speed) if speed else float('nan'):.2f}x |")
    write_section(MARK, lines, DOCS / "adaptive.md")


if __name__ == "__main__":
    main()
