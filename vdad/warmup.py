"""Compile the numba kernels ahead of a first run (``vdad compile``; ``docs/design.md``).

The first call of each compiled pass compiles it and every kernel it inlines,
one after another in one process: on two cores about three minutes for the
DCA and some fifteen for everything (the compiled adaptive step loop links the
adaptive kernels again, which takes about eight of those fifteen minutes).
:func:`compile_kernels` runs the first steps of small scenes in several
processes at once, each a share of the passes (:data:`PARTS`), so that
compiling uses every core; numba's on-disk cache keeps the result for every
later process (a test suite, a notebook, ``vdad run``). Only the argument
types of a call decide what compiles, so a few steps of each method reach the
same kernels as any run of it.
"""

from __future__ import annotations

import subprocess
import sys
import time
from concurrent.futures import ThreadPoolExecutor

from .errors import InputError, VdadError


def _dynamics():
    """The DCA: forward dynamics, the compiled step loops (semi-implicit Euler and
    RK4) with every scene's built-in forces."""
    import numpy as np

    from . import forward_dynamics
    from .scenes import SCENES

    small = {"pendulum": {"n_bodies": 4}, "hanging_dogs": {"n_dogs": 2}}
    for name, make in SCENES.items():
        scene = make(**small.get(name, {}))
        scene.simulator().step(2)
        scene.simulator(integrator="rk4").step(2)
        forward_dynamics(scene.model, scene.q0, np.zeros(scene.model.nv))


def _adaptive():
    """Adaptive dynamics one Python-level step at a time (RK4, and semi-implicit
    with ``adaptive_loop`` off): evaluations, the look-ahead, region changes with
    the locking impulse, the view-dependent coverage of the region (eq. 5) and of
    every node (eq. 7), and the bodies' poses from their groups (all of them, and
    some: lod-distance's root bodies)."""
    from .scenes import pendulum

    scene = pendulum(8)
    for options in ({"budget": 3, "dwell": 0}, {"budget": 3, "integrator": "rk4"},
                    {"method": "view-bvh", "threshold": 1e-3, "dwell": 0, "estimate": "node"},
                    {"method": "view-bvh", "threshold": 1e-3, "dwell": 0}):
        sim = scene.simulator(**{"method": "adaptive", **options})
        sim.adaptive_loop = False
        sim.step(4)
    sim.body_poses()
    sim.body_poses([0])


def _loop():
    """Whole adaptive steps in compiled code (``region.region_steps``), which
    links the adaptive kernels again: compiled beside :func:`_adaptive`, in a
    process of its own."""
    from .scenes import pendulum

    pendulum(8).simulator(method="adaptive", budget=3, dwell=0).step(4)


def _raster_loop():
    """The compiled adaptive steps that rasterise view-oq's counts once per frame
    (``visibility.region_raster_pass``): a loop of its own type, compiled in a
    process of its own."""
    from .scenes import pendulum

    pendulum(8).simulator(method="view-oq", counting="raster", threshold=1e-3,
                          coverage_every=2).step(4)


def _coverage():
    """Bounding-volume coverage of a whole tree, every volume type, and the batch
    forms of placements, merges and projected areas, and the rendered counts: the
    id buffer's per body, the rasteriser's, and their sums up the tree (every
    rule of :data:`~vdad.visibility.PIXELS`)."""
    import numpy as np

    from .bounding import VOLUMES, areas, body_volumes, merge, place
    from .scenes import pendulum
    from .visibility import PIXELS, BoundingVolumes, RenderedCounts, id_counts_pass

    scene = pendulum(4)
    sim = scene.simulator()
    R, p = sim.body_poses()
    for volume in VOLUMES:
        BoundingVolumes(sim.tree, scene.camera, volume)(0.0, sim.q)
        world = place(body_volumes(scene.model, volume), R, p)
        areas(merge(world, world), scene.camera)
    id_counts_pass(np.zeros((2, 2), np.uint32), np.zeros(4, np.int64))  # the id buffer's
    RenderedCounts(sim.tree, scene.camera, method="raster")(0.0, sim.q)
    for pixels in PIXELS:                  # the rendered counts' sums up the tree
        BoundingVolumes(sim.tree, scene.camera, pixels=pixels).node_pixels(
            np.zeros(sim.tree.n_nodes + 1))


#: the shares of the kernels, each compiled in a process of its own, the longest
#: first (on two cores: the two loops side by side, then the adaptive kernels,
#: the DCA and the coverage on whichever core is free first)
PARTS = {"loop": _loop, "raster loop": _raster_loop, "adaptive": _adaptive,
         "dynamics": _dynamics, "coverage": _coverage}


def run_part(name):
    """Compile one of :data:`PARTS` in this process."""
    PARTS[name]()


def compile_kernels(jobs=2, parts=tuple(PARTS), out=None):
    """Compile ``parts`` of :data:`PARTS` in up to ``jobs`` processes at once (each
    a fresh ``python -c``), saying on the text stream ``out`` (None: nothing) when
    each is done; returns the
    seconds it took. Bad ``jobs`` or ``parts``: an InputError; a part that fails:
    a :class:`~vdad.errors.VdadError` with the last line of its stderr."""
    if not isinstance(jobs, int) or isinstance(jobs, bool) or jobs < 1:
        raise InputError(f"jobs must be a positive whole number of processes, got {jobs!r}")
    unknown = [p for p in parts if p not in PARTS]
    if unknown:
        raise InputError(f"unknown kernel parts {unknown}; choose from {list(PARTS)}")
    t0 = time.perf_counter()

    def one(name):
        done = subprocess.run([sys.executable, "-c", f"from vdad.warmup import run_part; "
                               f"run_part({name!r})"], capture_output=True, text=True)
        if out is not None:
            print(f"vdad compile: {name} done after {time.perf_counter() - t0:.0f} s"
                  + ("" if done.returncode == 0 else " (failed)"), file=out, flush=True)
        return name, done

    with ThreadPoolExecutor(max_workers=jobs) as pool:
        results = list(pool.map(one, parts))
    failed = [(name, done.stderr.strip()) for name, done in results if done.returncode != 0]
    if failed:
        raise VdadError("compiling the kernels failed: " + "; ".join(
            f"{name}: {err.splitlines()[-1] if err else 'no message'}" for name, err in failed))
    return time.perf_counter() - t0
