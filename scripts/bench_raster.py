"""Visible-pixel counts rasterised on the CPU (``vdad.raster``) against OpenGL's.

Times ``RasterCounter.counts`` and ``PixelCounter.counts`` (the merged id
buffer, on whatever EGL gives: llvmpipe here) per frame, from Python, on each
scene of ``docs/reproduction.md`` at its initial state and camera, with the
scene's environment, and checks that both give the same counts (their largest
difference per body is in the table). Writes ``docs/bench_raster.json`` and a
table in ``docs/benchmarks.md``.
Usage: ``PYOPENGL_PLATFORM=egl python scripts/bench_raster.py``.
"""

from __future__ import annotations

import json
import os
import time

from bench_dynamics import DOCS, write_section

MARK = ("<!-- bench_raster:start -->", "<!-- bench_raster:end -->")


def best_ms(fn, n, repeats=5):
    fn()
    best = float("inf")
    for _ in range(repeats):
        t0 = time.perf_counter()
        for _ in range(n):
            fn()
        best = min(best, (time.perf_counter() - t0) / n)
    return 1e3 * best


def measure():
    import numpy as np

    from vdad.camera import camera_at
    from vdad.kinematics import world_poses
    from vdad.raster import RasterCounter
    from vdad.render.context import renderer_name
    from vdad.render.counting import PixelCounter
    from vdad.scenes import dog_puppet, falling_character, hanging_dogs, pendulum

    rows = []
    for name, scene in (("pendulum, Table 1", pendulum()),
                        ("pendulum, Figures 8-9", pendulum(300, radius=0.05,
                                                           resolution=(640, 480))),
                        ("dog puppet", dog_puppet()), ("falling character", falling_character()),
                        ("100 hanging dogs", hanging_dogs())):
        model, camera = scene.model, camera_at(scene.camera, 0.0)
        R, p = world_poses(model, np.array(scene.q0, float))
        w, h = camera.width, camera.height
        raster = RasterCounter(model, scene.environment, w, h)
        gl = PixelCounter(model, scene.environment, w, h, "merged")
        n = 20 if model.nb > 1000 else 100
        ours, theirs = raster.counts(camera, R, p), gl.counts(camera, R, p)
        rows.append({"scene": name, "bodies": model.nb, "resolution": f"{w}x{h}",
                     "triangles": len(raster.geometry[2]),
                     "raster_ms": best_ms(lambda c=raster, v=(camera, R, p): c.counts(*v), n),
                     "opengl_ms": best_ms(lambda c=gl, v=(camera, R, p): c.counts(*v), n),
                     "pixels": int(theirs.sum()),
                     "largest_difference": int(np.abs(ours - theirs).max())})
        print(rows[-1], flush=True)
    out = DOCS / "bench_raster.json"
    out.write_text(json.dumps({"renderer": renderer_name(), "rows": rows}, indent=1))
    lines = ["", "`python scripts/bench_raster.py`: ms per frame of every body's visible pixels "
             "from Python (best of 5 runs), at each scene's initial state: the compiled "
             f"rasteriser (`counting=\"raster\"`) and OpenGL's merged id buffer on "
             f"{renderer_name()}, and the largest difference of a body's count between "
             "them.", "",
             "| scene | bodies | resolution | triangles | raster ms | OpenGL ms | ratio | "
             "visible pixels | largest difference |",
             "|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        lines.append(f"| {r['scene']} | {r['bodies']} | {r['resolution']} | {r['triangles']} | "
                     f"{r['raster_ms']:.3f} | {r['opengl_ms']:.3f} | "
                     f"{r['opengl_ms'] / r['raster_ms']:.1f} | {r['pixels']} | "
                     f"{r['largest_difference']} |")
    write_section(MARK, lines)
    print(f"wrote {out} and docs/benchmarks.md")


if __name__ == "__main__":
    os.environ.setdefault("PYOPENGL_PLATFORM", "egl")
    measure()
