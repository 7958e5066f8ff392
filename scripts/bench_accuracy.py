"""Accuracy on hard models and the energy of long runs (``docs/accuracy.md``).

* Thin rods and point masses: the DCA's relative error, plain (the model's own
  leaves, no refinement) and as vdad runs it (raised leaves and refinement,
  (R1)-(R3)), against the exact answer and the reference ABA; and the cost of
  the refinement (median µs of the compiled pass, plain and refined, in turns).
* Featherstone's coil at 256 bodies: cond(M), the DCA and Pinocchio's ABA
  against the reference ABA and CRBA.
* z-y-x hinges near and at gimbal lock: the DCA against the reference ABA and
  MuJoCo.
* The 20-link pendulum over ``--steps`` steps (default 100000) at dt = 1 ms:
  the energy error of semi-implicit Euler, RK4 and the symplectic integrator at
  checkpoints, and their cost per step.

Writes ``docs/bench_accuracy.json`` and the tables between the markers of
``docs/accuracy.md``. Usage: ``python scripts/bench_accuracy.py [--steps N]``.
"""

from __future__ import annotations

import argparse
import json
import platform
import statistics
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "tests"))
from bench_dynamics import DOCS, write_section  # noqa: E402
from strategies import coil_chain, random_state, thin_chain, thin_rod  # noqa: E402

import vdad  # noqa: E402
from vdad import dca, reference  # noqa: E402
from vdad.dynamics import _work, default_tree  # noqa: E402
from vdad.kinematics import plan  # noqa: E402
from vdad.quantities import total_energy  # noqa: E402
from vdad.scenes import pendulum  # noqa: E402

PAGE = DOCS / "accuracy.md"
EPS = np.finfo(float).eps


def mark(name):
    return (f"<!-- bench_accuracy:{name}:start -->", f"<!-- bench_accuracy:{name}:end -->")


def dca_call(model, bodies, q, qd, tau):
    """The compiled DCA pass of ``model`` with ``bodies`` at ``(q, qd, tau)``, as a
    closure, and its accelerations."""
    tree = default_tree(model)
    data = _work(tree)
    args = (plan(model).arrays, data.layout, bodies, q, qd, tau, np.zeros((0, 6)),
            data.kin.arrays, data.arrays)

    def call():
        dca.dca_pass(*args)
        return data.qdd.copy()
    return call


def relative(a, b):
    return float(np.abs(a - b).max() / np.abs(b).max())


def thin_rods():
    rows = []
    a = np.array([0.3, 0.5, 0.8]) / np.linalg.norm([0.3, 0.5, 0.8])
    for r in [1e-2, 1e-4, 1e-6, 1e-8, 1e-10, 1e-12]:
        model = thin_rod(r)
        q, qd, tau = np.zeros(1), np.zeros(1), np.ones(1)
        exact = np.array([1.0 / (a @ np.asarray(model.inertia[0]) @ a)])
        rows.append(dict(r=r, plain=relative(dca_call(model, dca.plain_arrays(model), q, qd, tau)(),
                                             exact),
                         refined=relative(vdad.forward_dynamics(model, q, qd, tau), exact),
                         aba=relative(reference.aba(model, q, qd, tau), exact)))
    return rows


def median_us(call, n):
    times = []
    for _ in range(7):
        t0 = time.perf_counter()
        for _ in range(n):
            call()
        times.append((time.perf_counter() - t0) / n * 1e6)
    return statistics.median(times)


def hard_models():
    import os

    import gymnasium

    assets = Path(os.path.dirname(gymnasium.__file__)) / "envs" / "mujoco" / "assets"
    models = {f"gymnasium {name}": lambda name=name: vdad.load_mjcf(assets / f"{name}.xml")
              for name in ("walker2d", "hopper", "pusher")}
    models.update({
        "10 thin rods (1, 1, 1e-8)": lambda: thin_chain(10, [1.0, 1.0, 1e-8]),
        "100 thin rods (1, 1, 1e-8)": lambda: thin_chain(100, [1.0, 1.0, 1e-8]),
        "5 point-mass bobs (1e-12)": lambda: thin_chain(5, [1e-12] * 3, com=(0.0, 0.1, -0.9)),
        "pendulum scene, 20 links": lambda: pendulum().model,
    })
    rows = []
    for name, make in models.items():
        import warnings

        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            model = make()
        q, qd, tau, _ = random_state(model, 1)
        q = vdad.integrators.normalize_configuration(model, q)
        refined, plain = (dca_call(model, dca.body_arrays(model), q, qd, tau),
                          dca_call(model, dca.plain_arrays(model), q, qd, tau))
        expected = reference.aba(model, q, qd, tau)
        cond = float(np.linalg.cond(reference.crba(model, q)))
        err_plain, err_refined = relative(plain(), expected), relative(refined(), expected)
        n = max(20, 20000 // model.nb)
        t_plain, t_refined = [], []
        for _ in range(3):                                 # in turns: the VM's speed drifts
            t_plain.append(median_us(plain, n))
            t_refined.append(median_us(refined, n))
        rows.append(dict(model=name, nb=model.nb,
                         raised=int(dca.leaf_inertias(model)[1].sum()), cond=cond,
                         plain_error=err_plain, refined_error=err_refined,
                         plain_us=min(t_plain), refined_us=min(t_refined)))
    return rows


def coil():
    from vdad.interop.pinocchio import pinocchio_forward, to_pinocchio

    rows = []
    for branching in (1, 2):
        model = coil_chain(256, branching=branching)
        rng = np.random.default_rng(256)
        q, qd, tau = rng.normal(size=256), rng.normal(size=256), rng.normal(size=256)
        aba = reference.aba(model, q, qd, tau)
        crba = reference.crba_forward_dynamics(model, q, qd, tau)
        qdd = vdad.forward_dynamics(model, q, qd, tau)
        pm = to_pinocchio(model)
        pin = pinocchio_forward(pm, pm.createData(), model, q, qd, tau)
        rows.append(dict(branching=branching,
                         cond=float(np.linalg.cond(reference.crba(model, q))),
                         dca_aba=relative(qdd, aba), dca_crba=relative(qdd, crba),
                         aba_crba=relative(aba, crba), pin_aba=relative(pin, aba),
                         pin_crba=relative(pin, crba)))
    return rows


def gimbal():
    from vdad.interop.mujoco import mujoco_forward, to_mujoco

    body = vdad.Body("b", 1.0, (0.1, -0.2, 0.15), (0.3, 0.4, 0.5))
    stages = tuple(vdad.joints.Stage("hinge", axis) for axis in [(0, 0, 1), (0, 1, 0), (1, 0, 0)])
    model = vdad.Model([body], [vdad.Joint("gimbal", None, "b", "composite", stages=stages)])
    mj = to_mujoco(model)
    rows = []
    for gap in (1e-4, 1e-8, 0.0):
        q, qd = np.array([0.3, np.pi / 2 - gap, -0.2]), np.array([0.1, 0.2, 0.3])
        row = dict(gap=gap, cond=float(np.linalg.cond(reference.crba(model, q))))
        try:
            qdd = vdad.forward_dynamics(model, q, qd)
            row.update(aba=relative(qdd, reference.aba(model, q, qd)),
                       mujoco=relative(qdd, mujoco_forward(*mj, q, qd)))
        except vdad.SimulationError as exc:
            row.update(error=str(exc))
        rows.append(row)
    return rows


def energy(steps, dt):
    scene = pendulum(dt=dt)
    checkpoints = sorted({c for c in (2000, 10000, 32000, 48000, 100000, steps) if c <= steps})
    rows = []
    for integrator in ("semi-implicit", "rk4", "symplectic"):
        sim = vdad.Simulator(scene.model, scene.q0, dt=scene.dt, integrator=integrator)
        E0 = total_energy(scene.model, sim.q, sim.qd)
        scale = scene.params["link_mass"] * 9.81 * scene.params["link_length"] * scene.model.nb
        row, worst, done, seconds = dict(integrator=integrator, dt=dt), 0.0, 0, 0.0
        samples = []                                   # |error| every 1000 steps
        for c in checkpoints:
            try:
                while done < c:
                    t0 = time.perf_counter()
                    sim.step(min(1000, c - done))
                    seconds += time.perf_counter() - t0
                    done = sim.step_count
                    samples.append(abs(total_energy(scene.model, sim.q, sim.qd) - E0) / scale)
                    worst = max(worst, samples[-1] * scale)
            except vdad.SimulationError as exc:
                row["diverged"] = str(exc)[:120]
                break
            row[str(c)] = worst / scale
        tenth = max(1, len(samples) // 10)          # the typical error, first and last tenth
        row["median_first"] = float(np.median(samples[:tenth])) if samples else None
        row["median_last"] = (float(np.median(samples[-tenth:]))
                              if samples and "diverged" not in row else None)
        row["us_per_step"] = seconds / max(done, 1) * 1e6
        rows.append(row)
    return rows, checkpoints


def fmt(x):
    return f"{x:.1e}" if x else "0"


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=100000)
    steps = parser.parse_args().steps
    result = dict(machine=platform.machine(), rods=thin_rods(), models=hard_models(),
                  coil=coil(), gimbal=gimbal())
    result["energy"], checkpoints = energy(steps, 1e-3)
    fine, _ = energy(steps, 2.5e-4)
    result["energy"] += fine
    (DOCS / "bench_accuracy.json").write_text(json.dumps(result, indent=1))

    lines = ["", "| model | bodies (raised) | cond(M) | error plain | error refined | µs plain "
             "| µs refined | ratio |", "|---|---|---|---|---|---|---|---|"]
    for r in result["models"]:
        lines.append(f"| {r['model']} | {r['nb']} ({r['raised']}) | {r['cond']:.1e} | "
                     f"{fmt(r['plain_error'])} | {fmt(r['refined_error'])} | "
                     f"{r['plain_us']:.1f} | {r['refined_us']:.1f} | "
                     f"{r['refined_us'] / r['plain_us']:.2f} |")
    write_section(mark("cost"), lines, PAGE)
    lines = ["", "| n = 256 | cond(M) | DCA vs ABA | DCA vs CRBA | ABA vs CRBA | Pinocchio's "
             "ABA vs ABA | Pinocchio's ABA vs CRBA |", "|---|---|---|---|---|---|---|"]
    for c in result["coil"]:
        name = "coil (chain)" if c["branching"] == 1 else "autoTree, binary"
        lines.append(f"| {name} | {c['cond']:.1e} | {fmt(c['dca_aba'])} | {fmt(c['dca_crba'])} | "
                     f"{fmt(c['aba_crba'])} | {fmt(c['pin_aba'])} | {fmt(c['pin_crba'])} |")
    write_section(mark("coil"), lines, PAGE)
    lines = ["", "| pitch | cond(M) | DCA vs reference ABA | DCA vs MuJoCo |", "|---|---|---|---|"]
    for g in result["gimbal"]:
        pitch = "pi/2" if g["gap"] == 0 else f"pi/2 - {g['gap']:g}"
        if "error" in g:
            lines.append(f"| {pitch} | {g['cond']:.1e} | SimulationError: "
                         f"{g['error'][:60]}... | |")
        else:
            lines.append(f"| {pitch} | {g['cond']:.1e} | {fmt(g['aba'])} | {fmt(g['mujoco'])} |")
    write_section(mark("gimbal"), lines, PAGE)
    lines = ["", "| integrator | dt | " + " | ".join(f"step {c}" for c in checkpoints)
             + " | median, first tenth | median, last tenth | µs per step |",
             "|---|---|" + "---|" * (len(checkpoints) + 3)]
    for r in result["energy"]:
        cells = [fmt(r[str(c)]) if str(c) in r else "diverged" for c in checkpoints]
        cells += [fmt(r[k]) if r[k] is not None else "—" for k in ("median_first", "median_last")]
        lines.append(f"| {r['integrator']} | {r['dt'] * 1e3:g} ms | " + " | ".join(cells)
                     + f" | {r['us_per_step']:.1f} |")
    lines += ["", "Largest energy error up to each step, in units of `n m g L` (the chain's "
              "weight times one link length); then the median of the error sampled every "
              "1000 steps over the run's first and last tenth (a drift shows as a rise)."]
    write_section(mark("energy"), lines, PAGE)
    print(json.dumps(result, indent=1))


if __name__ == "__main__":
    main()
