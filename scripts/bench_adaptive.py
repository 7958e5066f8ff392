"""Time adaptive dynamics against the number of active joints (issues 3 and 15).

Pendulums of 300, 1000 and 10000 bodies (``vdad.scenes.pendulum``) released from
1 rad. Each adaptive run holds a fixed number of active joints: budget mode with
no look-ahead and no dwell, so the first step keeps the ``budget`` joints of
highest metric and rigidifies the rest for good; the time per step is then
measured on the following steps. The compiled full DCA (``Simulator.step``),
MuJoCo's ``mj_step`` (where it compiles the model) and threshold 0 (everything
active) are timed in turns with them, a batch of each per round (this shared
VM's speed drifts by tens of per cent within a minute), and the cost of the
region updates of a threshold run is timed after. Writes
``docs/bench_adaptive.json`` and the section between the markers of
``docs/benchmarks.md``. Usage: ``python scripts/bench_adaptive.py
[--quick]``.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import time
from pathlib import Path

import numpy as np
from bench_dynamics import DOCS, fmt, medians_us, write_section

import vdad
from vdad.adaptive import METRICS
from vdad.scenes import pendulum
from vdad.simulator import ADAPTIVE_DEFAULTS

MARK = ("<!-- bench_adaptive:start -->", "<!-- bench_adaptive:end -->")
DEFAULT_METRIC = ADAPTIVE_DEFAULTS["metric"]
SIZES = (300, 1000, 10000)
ACTIVE = (1, 5, 20, 50, 100, 300)
PREDECESSOR = (300, 100, 50, 20, 1)        # Redon et al. 2005, 300-joint pendulum
THRESHOLDS = (0.0, 1e-7, 1e-6, 1e-5, 1e-4, 1e-3)
VARIANTS = {"look-ahead, hysteresis, drop lock (default)": {},
            "no look-ahead": {"lookahead": False},
            "look-ahead, no hysteresis (kappa 1, dwell 0)": {"kappa": 1.0, "dwell": 0},
            "drop coast (the paper)": {"drop": "coast"}}
MUJOCO_MAX = 1000                          # mj compiles chains up to ~1000 (anchors §1)
#: the most calls of a run in one batch of the timing (of 20 steps each, at most
#: 25 batches: 10 s of simulated time): a run of a few active joints of 10000
#: bodies takes 3 µs a step, and timed in 50 ms batches it simulated 22 s, where
#: one of them (its region held, no look-ahead) diverged at step 21989
MAX_CALLS = 20


def simulators(scene):
    """The runs timed in turns on ``scene``: the full DCA (``"full"``), adaptive
    dynamics holding each number of active joints with each metric (``(active,
    metric)``), and threshold 0 with each metric (``("zero", metric)``, 300 bodies
    only), each after three steps that settle its region."""
    n = scene.model.nb
    sims = {"full": scene.simulator()}
    for active in [a for a in ACTIVE if a <= n]:
        for metric in METRICS:
            sims[(active, metric)] = scene.simulator(method="adaptive", budget=active, dwell=0,
                                                     lookahead=False, metric=metric)
    if n == 300:
        for metric in METRICS:
            sims[("zero", metric)] = scene.simulator(method="adaptive", threshold=0.0,
                                                     metric=metric)
    for sim in sims.values():
        sim.step(3)
    return sims


def fixed_and_per_node(rows, n):
    """Least-squares ``ms = fixed + per_node * active`` over the rows of ``n`` bodies."""
    pts = [(r["active_held"], r["adaptive_ms"]) for r in rows if r["bodies"] == n]
    a = np.array(pts)
    slope, intercept = np.polyfit(a[:, 0], a[:, 1], 1)
    return 1e3 * intercept, 1e3 * slope               # µs, µs per active joint


def region_cost(steps):
    """Median µs of the region update on steps of a 300-body threshold run that
    changed the region, per changed node, and on steps that changed nothing."""
    sim = pendulum(300).simulator(method="adaptive", threshold=1e-5, dwell=0)
    sim.adaptive_loop = False                  # Python-level steps: each phase timed
    sim.step(steps)
    changed = [(1e6 * s.times["region"], s.rigidified + s.released) for s in sim.history[1:]
               if s.rigidified + s.released]
    quiet = [1e6 * s.times["region"] for s in sim.history[1:] if not s.rigidified + s.released]
    return dict(steps=steps, changing_steps=len(changed),
                us_per_changing_step=statistics.median(t for t, _ in changed) if changed else None,
                nodes_per_changing_step=float(np.mean([k for _, k in changed])) if changed
                else None,
                us_per_change=statistics.median(t / k for t, k in changed) if changed else None,
                us_quiet_step=statistics.median(quiet) if quiet else None)


def mujoco_steps(model, steps):
    """A call of ``steps`` ``mj_step`` on ``model`` (None where MuJoCo is not tried),
    and a note."""
    if model.nb > MUJOCO_MAX:
        return None, f"mujoco: not tried above {MUJOCO_MAX} bodies (does not compile at 1600)"
    import mujoco

    from vdad.interop.mujoco import to_mujoco

    m, d = to_mujoco(model)
    m.opt.timestep = 1e-3
    d.qpos[:] = 0.0
    d.qpos[0] = 1.0

    def run():
        for _ in range(steps):
            mujoco.mj_step(m, d)

    return run, ""


def tip(sim):
    """World position of the pendulum's last body."""
    from vdad.kinematics import kinematics

    return kinematics(sim.model, sim.q, sim.qd).p[-1]


def threshold_sweep(steps):
    """300-body pendulum, ``steps`` steps: adaptive against the full DCA from the
    same state, per threshold and re-activation variant."""
    scene = pendulum(300)
    ref = scene.simulator()
    ref.step(steps)
    length = scene.model.nb * scene.params["link_length"]
    out = []
    for name, options in VARIANTS.items():
        for eps in THRESHOLDS:
            sim = scene.simulator(method="adaptive", threshold=eps, **options)
            t0 = time.perf_counter()
            sim.step(steps)
            elapsed = time.perf_counter() - t0
            h = sim.history
            row = dict(variant=name, threshold=eps, steps=steps,
                       active_mean=float(np.mean([s.active_joints for s in h])),
                       accelerated_mean=float(np.mean([s.accelerated for s in h])),
                       ms_per_step=1e3 * elapsed / steps,
                       changes_per_step=float(np.mean([s.rigidified + s.released for s in h])),
                       tip_error=float(np.linalg.norm(tip(sim) - tip(ref)) / length),
                       max_angle_error=float(np.max(np.abs(sim.q - ref.q))))
            out.append(row)
            print(json.dumps(row), flush=True)
    return out


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="fewer steps and repeats")
    parser.add_argument("--out", default=str(DOCS / "bench_adaptive.json"))
    args = parser.parse_args(argv)
    steps, budget = (5, 0.3) if args.quick else (20, 1.0)
    rows = []
    for n in SIZES:
        scene = pendulum(n)
        sims = simulators(scene)                     # steps per timed call:
        chunk = {key: steps for key in sims}         # the full DCA's of 10000 bodies take
        chunk["full"] = max(1, steps // 10) if n > 1000 else steps    # 20 ms each
        calls = {key: (lambda sim=sim, k=chunk[key]: sim.step(k)) for key, sim in sims.items()}
        mj, mj_note = mujoco_steps(scene.model, steps)
        if mj is not None:
            calls["mujoco"], chunk["mujoco"] = mj, steps
        ms = {key: 1e-3 * us / chunk[key]
              for key, us in medians_us(calls, budget, MAX_CALLS).items()}
        t_full = ms["full"]
        for active in [a for a in ACTIVE if a <= n]:
            row = dict(bodies=n, active=active, full_dca_ms=t_full, mujoco_ms=ms.get("mujoco"),
                       notes=mj_note)
            for metric in METRICS:
                row[f"{metric}_ms"] = ms[(active, metric)]
            held = sims[(active, DEFAULT_METRIC)].history[3:]
            row["active_held"] = float(np.mean([s.active_joints for s in held]))
            row["adaptive_ms"] = row[f"{DEFAULT_METRIC}_ms"]
            row["speedup"] = t_full / row["adaptive_ms"]
            rows.append(row)
            print(json.dumps(row), flush=True)
        if n == 300:
            everything = dict(full_dca_ms=t_full)
            for metric in METRICS:
                everything[f"{metric}_ms"] = ms[("zero", metric)]
            everything["adaptive_ms"] = everything[f"{DEFAULT_METRIC}_ms"]
            print(json.dumps(everything), flush=True)
        del sims, calls
    fits = {n: fixed_and_per_node(rows, n) for n in SIZES}
    changes = region_cost(100 if args.quick else 500)
    print(json.dumps(changes), flush=True)
    sweep = threshold_sweep(100 if args.quick else 500)
    result = dict(machine=f"{platform.processor() or platform.machine()}, {os.cpu_count()} cores",
                  python=platform.python_version(), numpy=np.__version__, vdad=vdad.__version__,
                  quick=args.quick, rows=rows, threshold_zero=everything,
                  fixed_and_per_node_us={str(n): f for n, f in fits.items()},
                  region_changes=changes, threshold_sweep=sweep)
    Path(args.out).write_text(json.dumps(result, indent=1))
    write_tables(rows, result)


def _row(rows, n, a):
    return next(r for r in rows if r["bodies"] == n and r["active"] == a)


def write_tables(rows, result):
    at50 = {n: _row(rows, n, 50) for n in SIZES}
    ratio = at50[10000]["adaptive_ms"] / at50[1000]["adaptive_ms"]
    lines = ["", f"Median ms per step (dt = 1 ms, semi-implicit Euler); Python "
             f"{result['python']}, numpy {result['numpy']}, {result['machine']}"
             f"{' (quick run)' if result['quick'] else ''}. Adaptive runs hold the number of "
             "active joints fixed (budget mode, no look-ahead); the full DCA is the compiled "
             "step loop.", "",
             f"| bodies | active joints | adaptive ({DEFAULT_METRIC}) | "
             + " | ".join(f"metric {m}" for m in METRICS if m != DEFAULT_METRIC)
             + " | full DCA | speed-up | mj_step | notes |",
             "|---|---|---|" + "---|" * (len(METRICS) - 1) + "---|---|---|---|"]
    for r in rows:
        others = " | ".join(fmt(r[f"{m}_ms"], 3) for m in METRICS if m != DEFAULT_METRIC)
        lines.append(f"| {r['bodies']} | {r['active_held']:.0f} | {fmt(r['adaptive_ms'], 3)} | "
                     f"{others} | {fmt(r['full_dca_ms'], 3)} | {r['speedup']:.1f}x | "
                     f"{fmt(r['mujoco_ms'], 3)} | {r['notes']} |")
    z, c = result["threshold_zero"], result["region_changes"]
    fits = result["fixed_and_per_node_us"]
    lines += ["", f"At 50 active joints the 10000-body step takes {ratio:.2f}x the 1000-body "
              f"step. Threshold 0 (all 300 joints active) takes {z['adaptive_ms']:.3f} ms "
              f"per step, {z['adaptive_ms'] / z['full_dca_ms']:.2f}x the full DCA ("
              + ", ".join(f"{m}: {z[f'{m}_ms'] / z['full_dca_ms']:.2f}x" for m in METRICS)
              + "). Fixed cost "
              "per step and cost per active joint (least squares over the rows): "
              + ", ".join(f"{n} bodies {f[0]:.0f} µs + {f[1]:.2f} µs per joint"
                          for n, f in fits.items())
              + f". Region updates of a 300-body threshold run (1e-5, dwell 0, {c['steps']} "
              f"steps): {c['changing_steps']} steps changed the region, "
              f"{c['nodes_per_changing_step']:.1f} nodes each, in a median "
              f"{c['us_per_changing_step']:.0f} µs ({c['us_per_change']:.0f} µs per changed "
              f"node); a step without change spends {c['us_quiet_step']:.0f} µs in the update.",
              "", "Predecessor's series (Redon et al. 2005: 300-joint pendulum):", "",
              "| active joints | adaptive ms | full DCA ms | speed-up | mj_step ms |",
              "|---|---|---|---|---|"]
    for a in PREDECESSOR:
        r = _row(rows, 300, a)
        lines.append(f"| {a} | {fmt(r['adaptive_ms'], 3)} | {fmt(r['full_dca_ms'], 3)} | "
                     f"{r['speedup']:.1f}x | {fmt(r['mujoco_ms'], 3)} |")
    sweep = result["threshold_sweep"]
    lines += ["", f"Threshold sweep (300-body pendulum from 1 rad, {sweep[0]['steps']} steps "
              "of 1 ms): tip error is the distance between the last "
              "body's positions under adaptive dynamics and under the full DCA, over the "
              "pendulum's length; changes are nodes rigidified or released per step.", "",
              "| variant | threshold | mean active | mean accelerated | ms / step | "
              "changes / step | tip error | max joint-angle error (rad) |",
              "|---|---|---|---|---|---|---|---|"]
    for r in sweep:
        lines.append(f"| {r['variant']} | {r['threshold']:g} | {r['active_mean']:.1f} | "
                     f"{r['accelerated_mean']:.1f} | {r['ms_per_step']:.2f} | "
                     f"{r['changes_per_step']:.2f} | {r['tip_error']:.2e} | "
                     f"{r['max_angle_error']:.2e} |")
    write_section(MARK, lines)


if __name__ == "__main__":
    main()
