"""Rendered pixel counts per frame (``vdad.render.counting``) on whatever EGL gives.

Times ``PixelCounter.counts`` (occlusion queries, the merged id buffer with 8-
and 4-section capsules) on the 20- and 300-link pendulums and the 100 hanging
dogs at their initial states, at 320 x 240 and 1280 x 960, and writes
``docs/bench_counting_<renderer>.json`` (``llvmpipe`` or ``nvidia``). With
``--table`` it writes instead the table of every such file into
``docs/benchmarks.md``. The NVIDIA figures come from a machine lent to one
session (``docs/benchmarks.md``); CI never needs a GPU.
Usage: ``PYOPENGL_PLATFORM=egl python scripts/bench_counting.py [--table]``.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import time

from bench_dynamics import DOCS, write_section

MARK = ("<!-- bench_counting:start -->", "<!-- bench_counting:end -->")
CASES = (("queries", 8), ("merged", 8), ("merged", 4))


def median_ms(fn, n):
    fn()
    times = []
    for _ in range(n):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return 1e3 * statistics.median(times)


def measure():
    import vdad
    from vdad.render.context import renderer_name
    from vdad.render.counting import PixelCounter
    from vdad.scenes import hanging_dogs, pendulum

    rows = []
    for name, scene in (("pendulum 20", pendulum(20)), ("pendulum 300", pendulum(300)),
                        ("100 hanging dogs", hanging_dogs())):
        R, p = vdad.Simulator(scene.model, scene.q0).body_poses()
        for w, h in ((320, 240), (1280, 960)):
            camera = scene.camera.with_resolution(w, h)
            for method, sections in CASES:
                counter = PixelCounter(scene.model, None, w, h, method, sections=sections)
                ms = median_ms(lambda c=counter, cam=camera, R=R, p=p: c.counts(cam, R, p),
                               20 if scene.model.nb > 1000 else 50)
                rows.append({"scene": name, "bodies": scene.model.nb, "resolution": f"{w}x{h}",
                             "method": method, "sections": sections, "ms": ms})
                print(rows[-1], flush=True)
    renderer = renderer_name()
    tag = "nvidia" if "NVIDIA" in renderer else "llvmpipe" if "llvmpipe" in renderer else "other"
    out = DOCS / f"bench_counting_{tag}.json"
    out.write_text(json.dumps({"renderer": renderer, "rows": rows}, indent=1))
    print(f"wrote {out}")


def table():
    runs = [json.loads(f.read_text()) for f in sorted(DOCS.glob("bench_counting_*.json"))]
    lines = ["", "Median ms per frame of `PixelCounter.counts` (every body's visible pixels), "
             "from Python, at the scenes' initial states: " + "; ".join(
                 r["renderer"] for r in runs) + ".", "",
             "| scene | resolution | counting | " + " | ".join(r["renderer"] for r in runs) + " |",
             "|---|---|---|" + "---|" * len(runs)]
    for k, row in enumerate(runs[0]["rows"]):
        how = row["method"] + ("" if row["sections"] == 8 else ", 4 sections")
        lines.append(f"| {row['scene']} | {row['resolution']} | {how} | "
                     + " | ".join(f"{r['rows'][k]['ms']:.2f}" for r in runs) + " |")
    write_section(MARK, lines)


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--table", action="store_true",
                        help="write the table of the stored runs into docs/benchmarks.md")
    args = parser.parse_args()
    os.environ.setdefault("PYOPENGL_PLATFORM", "egl")
    if args.table:
        table()
    else:
        measure()


if __name__ == "__main__":
    main()
