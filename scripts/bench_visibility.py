"""Time the coverage N_M and reproduce the paper's Table 1 (issue 4).

Visibility cost: one evaluation of ``N_M`` for every node of the assembly tree,
for a 20- and a 300-link pendulum (``vdad.scenes.pendulum``, whole chain in view)
and 100 sixteen-body "dogs" (1600 capsules on a 10 x 10 grid, seen from above at
an angle), at 320 x 240: bounding volumes (sphere, OBB, AABB; eq. 7, the
minimum of the node's and its bodies' areas, which places every body) and
rendered counts (occlusion queries and the merged id buffer, over EGL; the raw
per-body counts alone too). Table 1: the 20-body pendulum simulated with the
full DCA, view-bvh (spheres, eq. 6 as the paper's table, and eq. 7) and view-oq,
ms per step, mean active joints and the largest drift of the total energy
(relative to |E0|), with the coverage every step and once per displayed frame
(every 16 steps of 1 ms: 60 Hz). Writes
``docs/bench_visibility.json`` and the section between the markers of
``docs/benchmarks.md``. Usage: ``python scripts/bench_visibility.py [--quick]``.
"""

from __future__ import annotations

import argparse
import gc
import json
import os
import platform
import time

import numpy as np
from bench_dynamics import DOCS, dog_forest, fmt, median_us, medians_us, write_section
from numba import njit

import vdad
from vdad.adaptive import AdaptiveDynamics
from vdad.bounding import VOLUMES
from vdad.camera import Camera
from vdad.quantities import total_energy
from vdad.region import N_JOINTS
from vdad.render.context import renderer_name
from vdad.render.counting import PixelCounter
from vdad.scenes import pendulum
from vdad.visibility import BoundingVolumes, RenderedCounts, cover, region_bvh_pass

MARK = ("<!-- bench_visibility:start -->", "<!-- bench_visibility:end -->")
TABLE1_THRESHOLD = 0.003           # pixels x rad per step
PAPER_TABLE1 = {"dca": (0.218, 19), "view-bvh": (0.136, 10), "view-oq": (0.108, 8)}


def setups():
    """(name, model, tree, camera, q) for the three sizes."""
    out = []
    for n in (20, 300):
        scene = pendulum(n_bodies=n)
        sim = scene.simulator()
        sim.step(200)                                  # a swinging, bent chain
        out.append((f"pendulum {n}", scene.model, sim.tree, scene.camera, sim.q.copy()))
    model = dog_forest(100)
    sim = vdad.Simulator(model)
    camera = Camera(position=(9.0, -12.0, 9.0), target=(9.0, 9.0, 0.8))
    out.append(("100 dogs", model, sim.tree, camera, sim.q.copy()))
    return out


#: the timing loops compiled as the adaptive steps that call the coverage
#: (``vdad.region.region_steps``, a ``vdad._linalg.pass_kernel``): without numba's
#: reference counting, which would add an atomic increment and decrement per array
#: argument to every call (about 0.4 µs per evaluation of the 20-body tree); not
#: cached, as ``pass_kernel`` is, since a cached loop would keep the vdad kernels
#: it links after they change
in_steps = njit(error_model="numpy", _nrt=False)


@in_steps
def _in_loop(k, codes, view, Rc, pc, nb, left, right, forest, first, hybrid, since, R_top, p_top,
             poses, body, cache, world, N1, N, moved, scratch):
    """``k`` evaluations of :func:`vdad.visibility.region_bvh_pass` from compiled
    code, as the compiled adaptive steps call it once per frame (the active
    joints' poses ``R_top``, ``p_top`` given: the step computes them)."""
    for _ in range(k):
        region_bvh_pass(codes, view, Rc, pc, nb, left, right, forest, first, hybrid, since,
                        R_top, p_top, poses, body, cache, world, N1, N, moved, scratch)


@in_steps
def _placed_in_loop(k, codes, view, Rc, pc, nb, left, right, forest, body, R, p, world, N1, N,
                    moved, grouped, scratch):
    """``k`` evaluations of :func:`vdad.visibility.cover`, every body's pose given
    (as a step of the full DCA has them; ``grouped``: none)."""
    for _ in range(k):
        cover(codes, view, Rc, pc, nb, left, right, forest, body, R, p, world, N1, N, moved,
              grouped, scratch)


def hybrids(model, tree, q):
    """Adaptive dynamics at ``q`` with every joint active, and with every joint
    rigid that may be (floating bases stay active)."""
    active = AdaptiveDynamics(model, 1e-3, tree, threshold=0.0)
    rigid = AdaptiveDynamics(model, 1e-3, tree, threshold=0.0)
    nodes = [n for n in range(model.nb, tree.n_nodes) if not rigid.region.pinned[n]]
    rigid.rigidify(nodes, q, np.zeros(model.nv))
    return active, rigid


def in_loop_calls(cov, q, k, adaptives):
    """Calls of ``k`` in-loop evaluations of ``cov``: from the step's kinematics of
    each of ``adaptives`` (:func:`hybrids`), and from every body's pose."""
    model, tree = cov.model, cov.tree
    constants, (_, views, Rc, pc) = cov.loop_coverage([0], [0.0], adaptives[-1])
    codes, first, poses, body, cache, world, N1, moved, scratch = constants
    camera = (codes, tuple(views[0]), Rc[0], pc[0], model.nb, tree.arrays[0], tree.arrays[1],
              (tree.arrays[13], tree.arrays[14]))
    N = np.empty(tree.n_nodes + 1)
    calls = []
    for ad in adaptives:
        kin = ad.front_kinematics(q)
        args = camera + (first, ad.group_frames, ad.since, kin.R, kin.p, poses, body, cache, world,
                         N1, N, moved, scratch)
        calls.append(lambda a=args: _in_loop(k, *a))
    R, p = vdad.Simulator(model, q).body_poses()
    args = camera + (body, R, p, world, N1, N, moved, cov._ungrouped, scratch)
    return calls + [lambda: _placed_in_loop(k, *args)]


#: the in-loop evaluations timed: from the step's kinematics with every joint
#: active and every joint rigid, and with every body's pose given
IN_LOOP = ("loop", "rigid", "placed")


def coverage_row(name, model, tree, camera, q, budget):
    """Median ms of one N_M evaluation per estimator (bounding volumes from Python
    and inside compiled code), of a step of the compiled full DCA timed in turns
    with them, and of the raw counts."""
    row = {"model": name, "bodies": model.nb}
    sim = vdad.Simulator(model, q)                     # the compiled DCA step loop
    k = max(10, 20000 // model.nb)
    fns = {"dca_step_ms": lambda: sim.step(k), "dca_call_ms": lambda: sim.step(1)}
    per = {"dca_step_ms": k, "dca_call_ms": 1}
    adaptives = hybrids(model, tree, q)
    row["rigid_joints"] = int(model.nb - adaptives[1].region.counts[N_JOINTS])
    for volume in VOLUMES:
        cov = BoundingVolumes(tree, camera, volume, "min")
        fns[f"bvh_{volume}_ms"], per[f"bvh_{volume}_ms"] = (lambda c=cov: c(0.0, q)), 1
        for where, call in zip(IN_LOOP, in_loop_calls(cov, q, k, adaptives), strict=True):
            fns[f"bvh_{volume}_{where}_ms"], per[f"bvh_{volume}_{where}_ms"] = call, k
    for key, us in medians_us(fns, 3 * budget).items():
        row[key] = us / 1e3 / per[key]
    for volume in VOLUMES:
        for where in ("",) + tuple(f"_{w}" for w in IN_LOOP):
            row[f"bvh_{volume}{where}_of_dca"] = (row[f"bvh_{volume}{where}_ms"]
                                                  / row["dca_step_ms"])
    R, p = vdad.Simulator(model, q).body_poses()
    for method in ("queries", "merged"):
        cov = RenderedCounts(tree, camera, method=method)
        row[f"oq_{method}_ms"] = median_us(lambda c=cov: c(0.0, q), budget) / 1e3
        counter = PixelCounter(model, None, camera.width, camera.height, method)
        row[f"counts_{method}_ms"] = median_us(lambda c=counter: c.counts(camera, R, p),
                                               budget) / 1e3
    coarse = PixelCounter(model, None, camera.width, camera.height, "merged", sections=4)
    row["counts_merged_coarse_ms"] = median_us(lambda: coarse.counts(camera, R, p),
                                               budget) / 1e3
    counts = counter.counts(camera, R, p)
    row["visible_bodies"] = int(np.sum(counts > 0))
    row["pixels"] = int(counts.sum())
    return row


def time_coverage(quick):
    rows = []
    for setup in setups():
        rows.append(coverage_row(*setup, 0.3 if quick else 2.0))
        print(rows[-1], flush=True)
    return rows


TABLE1 = [
    ("full DCA", "dca", {}),
    ("view-bvh, spheres, eq. 6", "view-bvh", {"volume": "sphere", "estimate": "bodies"}),
    ("view-bvh, spheres, eq. 7", "view-bvh", {"volume": "sphere", "estimate": "min"}),
    ("view-bvh, OBB, eq. 7", "view-bvh", {"volume": "obb", "estimate": "min"}),
    ("view-oq, occlusion queries", "view-oq", {"counting": "queries"}),
    ("view-oq, merged id buffer", "view-oq", {"counting": "merged"}),
]


def table1(quick):
    scene = pendulum(n_bodies=20)
    steps = 300 if quick else 2000
    rows = []
    for every in (1, 16):
        for label, method, options in TABLE1:
            if method == "dca" and every > 1:
                continue
            opts = dict(options)
            if method != "dca":
                opts.update(threshold=TABLE1_THRESHOLD, coverage_every=every)
            scene.simulator(method=method, **opts).step(50)     # loads its kernels
            gc.collect()                # the last run's renderer released before timing
            sim = scene.simulator(method=method, **opts)
            E0 = total_energy(scene.model, sim.q, sim.qd)
            ms, drift = 0.0, 0.0
            for _ in range(4):
                t0 = time.perf_counter()
                sim.step(steps // 4)
                ms += 1e3 * (time.perf_counter() - t0) / steps
                drift = max(drift, abs(total_energy(scene.model, sim.q, sim.qd) - E0))
            active = (float(np.mean([s.active_joints for s in sim.history]))
                      if sim.history else float(scene.model.nb))
            vis = (1e3 * float(np.mean([s.times["visibility"] for s in sim.history]))
                   if sim.history else 0.0)
            if method == "view-bvh":            # evaluated inside the compiled steps
                vis = None
            rows.append({"method": label, "every": every, "ms_per_step": ms,
                         "active_joints": active, "visibility_ms": vis,
                         "energy_drift": drift / abs(E0)})
            print(rows[-1], flush=True)
    return rows


def write(result):
    cov, t1 = result["coverage"], result["table1"]
    lines = ["", f"Median ms per evaluation of `N_M` for every node; {result['gl_renderer']}, "
             f"Python {result['python']}, numpy {result['numpy']}, {result['machine']}"
             f"{' (quick run)' if result['quick'] else ''}. Counting at 320 x 240.", "",
             "| scene | bodies | visible | BVH sphere | BVH OBB | BVH AABB | OQ queries | "
             "OQ merged | counts only: queries | counts only: merged | merged, 4 sections |",
             "|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in cov:
        lines.append(f"| {r['model']} | {r['bodies']} | {r['visible_bodies']} | "
                     + " | ".join(fmt(r[k], 3) for k in (
                         "bvh_sphere_ms", "bvh_obb_ms", "bvh_aabb_ms", "oq_queries_ms",
                         "oq_merged_ms", "counts_queries_ms", "counts_merged_ms",
                         "counts_merged_coarse_ms")) + " |")
    lines += ["", "Bounding-volume coverage of every node (eq. 7) against one step of the "
              "compiled full DCA of the same model, timed in turns (the step loop's time "
              "per step; one `step(1)` call from Python in brackets): called from Python "
              "(every body placed at q); inside compiled code as the adaptive steps "
              "evaluate it once per frame, from the active joints' kinematics of the step, "
              "with every joint active (*active*) and with every joint rigid that may be "
              "(*rigid*: all but the dogs' free joints; the bodies placed from their "
              "groups); and every body's pose given (*posed*). Target (issue 16): at most "
              "10 %.", "",
              "| scene | DCA step ms | rigid joints | " + " | ".join(
                  f"{v}: Python / active / rigid / posed" for v in VOLUMES) + " |",
              "|---|---|---|---|---|---|"]
    for r in cov:
        lines.append(f"| {r['model']} | {fmt(r['dca_step_ms'], 3)} ({fmt(r['dca_call_ms'], 3)}) | "
                     f"{r['rigid_joints']} | "
                     + " | ".join(" / ".join(f"{100 * r[f'bvh_{v}{w}_of_dca']:.1f} %"
                                             for w in ("", "_loop", "_rigid", "_placed"))
                                  for v in VOLUMES) + " |")
    lines += ["", f"Table 1 (20-body pendulum, 19 revolute joints + the root, dt = 1 ms, "
              f"threshold {TABLE1_THRESHOLD} pixel rad per step, default camera: the whole "
              f"chain in view at 320 x 240). Paper (C++, 2008): DCA 0.218 ms / 19 joints, "
              f"BVH 0.136 / 10, OQ 0.108 / 8.", "",
              "| method | N_M every | ms per step | of which N_M | active joints | "
              "speed-up over DCA | energy drift |", "|---|---|---|---|---|---|---|"]
    dca = next(r["ms_per_step"] for r in t1 if r["method"] == "full DCA")
    for r in t1:
        every = "—" if r["method"] == "full DCA" else f"{r['every']} step(s)"
        vis = "in the steps" if r["visibility_ms"] is None else fmt(r["visibility_ms"], 3)
        lines.append(f"| {r['method']} | {every} | {fmt(r['ms_per_step'], 3)} | {vis} | "
                     f"{fmt(r['active_joints'], 1)} | "
                     f"{dca / r['ms_per_step']:.2f}x | {100 * r['energy_drift']:.1f} % |")
    write_section(MARK, lines)


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="short runs (CI smoke test)")
    args = parser.parse_args()
    result = {"python": platform.python_version(), "numpy": np.__version__,
              "machine": f"{platform.machine()}, {os.cpu_count()} cores",
              "quick": args.quick, "gl_renderer": None}
    t0 = time.perf_counter()
    result["coverage"] = time_coverage(args.quick)
    result["gl_renderer"] = renderer_name()
    result["table1"] = table1(args.quick)
    result["paper_table1"] = PAPER_TABLE1
    result["seconds"] = time.perf_counter() - t0
    out = DOCS / ("bench_visibility_quick.json" if args.quick else "bench_visibility.json")
    out.write_text(json.dumps(result, indent=1))
    if not args.quick:
        write(result)
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
