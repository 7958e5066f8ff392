"""Time vdad.forward_dynamics against pin.aba and mujoco.mj_forward in one run.

Models: pendulum chains of 20, 300, 1000 and 10000 bodies, a forest of 100
sixteen-body dog-shaped trees on free joints (1600 bodies) and the 29-body
character with MuJoCo-style composite joints (three hinges for each ball); and
MuJoCo models as a user loads them (gymnasium's humanoid, ant, walker2d and
pusher arm, ``vdad.load_mjcf``): ``forward_dynamics`` and a full simulator step
against ``mj_forward`` and ``mj_step`` of the same file with contact off. Beside
each figure: the previous numpy core's time on the same model, from
``docs/bench_dynamics_numpy.json`` (kept from the run before the compiled core),
and numba's compile time in a fresh cache and load time from it (subprocesses).
Writes ``docs/bench_dynamics.json`` and the tables between the markers of
``docs/benchmarks.md``. Usage: ``python scripts/bench_dynamics.py [--quick]
[--no-compile] [--imported]`` (``--imported``: the imported models only, into
``docs/bench_imported.json``).
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import subprocess
import sys
import tempfile
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

import vdad
from vdad import dca
from vdad.dynamics import default_tree
from vdad.scenes import pendulum

DOCS = Path(__file__).resolve().parent.parent / "docs"
MARK = ("<!-- bench_dynamics:start -->", "<!-- bench_dynamics:end -->")
IMPORTED_MARK = ("<!-- bench_imported:start -->", "<!-- bench_imported:end -->")
#: gymnasium's MuJoCo models timed as imported (a humanoid, a quadruped, a walker, an arm)
IMPORTED = ("humanoid", "ant", "walker2d", "pusher")


def dog_forest(n_dogs=100):
    """``n_dogs`` free-floating trees of 16 bodies: torso, neck, head, tail and four
    three-link legs, joined by revolute joints, each body a small capsule (a
    stand-in until the dog scene), on a 10-wide grid 2 m apart."""
    bodies, joints = [], []
    inertia = np.diag([0.02, 0.02, 0.01])
    geom = (vdad.Geom("capsule", (0.04, 0.05), vdad.Pose((0, 0, -0.05))),)
    for d in range(n_dogs):
        def add(name, parent, pos, axis=(0, 1, 0), d=d):
            bodies.append(vdad.Body(f"d{d}_{name}", 0.5, (0, 0, -0.05), inertia, geom))
            kind = "free" if parent is None else "revolute"
            parent = None if parent is None else f"d{d}_{parent}"
            joints.append(vdad.Joint(f"d{d}_{name}_j", parent, f"d{d}_{name}", kind, axis=axis,
                                     placement=vdad.Pose(pos)))
        add("torso", None, (2.0 * (d % 10), 2.0 * (d // 10), 1.0))
        add("neck", "torso", (0.3, 0, 0.05))
        add("head", "neck", (0.1, 0, 0.1), (0, 0, 1))
        add("tail", "torso", (-0.3, 0, 0.05), (0, 0, 1))
        for leg, (x, y) in enumerate([(0.25, 0.1), (0.25, -0.1), (-0.25, 0.1), (-0.25, -0.1)]):
            add(f"leg{leg}a", "torso", (x, y, -0.05), (1, 0, 0))
            add(f"leg{leg}b", f"leg{leg}a", (0, 0, -0.15))
            add(f"leg{leg}c", f"leg{leg}b", (0, 0, -0.15))
    return vdad.Model(bodies, joints, name=f"{n_dogs}dogs")


def composite_character():
    """The 29-body character (:func:`vdad.scenes.character.humanoid`) with every
    ball joint replaced by three hinges about x, y and z (a composite joint, as
    MJCF import builds from MuJoCo's humanoids)."""
    from vdad.joints import Stage
    from vdad.scenes.character import humanoid

    model, _ = humanoid()
    joints = [replace(jt, kind="composite", damping=0.0, stages=tuple(
        Stage("hinge", axis, damping=jt.damping) for axis in np.eye(3)))
        if jt.kind == "spherical" else jt for jt in model.joints]
    return vdad.Model(model.bodies, joints, gravity=model.gravity, name="character-hinges")


def median_us(fn, budget_s):
    """Median µs per call of ``fn``, over batches of about 50 ms (3 to 25 of them
    within ``budget_s``)."""
    return medians_us({"fn": fn}, budget_s)["fn"]


def medians_us(fns, budget_s, max_calls=None):
    """Median µs per call of each function of the dict ``fns``, timed in turns: each
    round times a batch of about 50 ms of every function (at most ``max_calls``
    calls), so that all of them see the same machine (on a shared VM its speed
    drifts by tens of per cent within a minute, and a ratio of medians taken a
    minute apart drifts with it)."""
    number, once = {}, {}
    for key, fn in fns.items():
        fn()
        t0 = time.perf_counter()
        fn()
        once[key] = max(time.perf_counter() - t0, 1e-7)
        number[key] = max(1, min(int(0.05 / once[key]), max_calls or 10 ** 9))
    per_round = sum(once[k] * number[k] for k in fns)
    rounds = max(3, min(25, int(len(fns) * budget_s / per_round) or 3))
    times = {key: [] for key in fns}
    for _ in range(rounds):
        for key, fn in fns.items():
            t0 = time.perf_counter()
            for _ in range(number[key]):
                fn()
            times[key].append((time.perf_counter() - t0) / number[key])
    return {key: 1e6 * statistics.median(t) for key, t in times.items()}


def vdad_call(model, q, qd):
    """``vdad.forward_dynamics`` on ``model`` with reused work arrays."""
    tree = default_tree(model)
    data = dca.make_data(tree)
    return lambda: vdad.forward_dynamics(model, q, qd, tree=tree, data=data)


# pin.Model.createData allocates nv^3 tensors: 13 GB at 600 dofs (anchors.md §1)
PIN_BYTES_AT_600 = 13e9


def time_pinocchio(model, budget, copies=1):
    """Median µs of :func:`pinocchio_call`, and its note."""
    call, note = pinocchio_call(model, copies)
    return (None if call is None else median_us(call, budget)), note


def pinocchio_call(model, copies=1):
    """pin.aba on ``model`` (called ``copies`` times per call, for forests of
    identical trees), and a note; no call where createData would not fit in
    memory or Pinocchio has no counterpart of a joint."""
    import os

    import pinocchio as pin

    from vdad.interop.pinocchio import to_pinocchio

    need = PIN_BYTES_AT_600 * (model.nv / 600) ** 3
    available = os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
    if need > 0.5 * available:
        return None, f"pin: cannot allocate (createData needs ~{need / 1e9:.0f} GB)"
    try:
        pm = to_pinocchio(model)
    except vdad.UnsupportedFeatureError as exc:
        return None, f"pin: {str(exc).split(': ', 1)[-1][:60]}"
    pd = pm.createData()
    qp = pin.neutral(pm)
    vp = np.random.default_rng(0).normal(size=pm.nv)
    tau = np.zeros(pm.nv)

    def call():
        for _ in range(copies):
            pin.aba(pm, pd, qp, vp, tau)

    note = f"pin: {copies} calls on one tree" if copies > 1 else ""
    return call, note


COMPILE = """
import time
t0 = time.perf_counter()
import numpy as np
import vdad
from vdad.scenes import pendulum
t1 = time.perf_counter()
m = pendulum(20).model
vdad.forward_dynamics(m, m.q_neutral, np.zeros(m.nv))
print(t1 - t0, time.perf_counter() - t1)
"""


def time_compile():
    """Seconds of ``import vdad`` and of the first forward dynamics in a fresh
    process: with an empty numba cache (compile), then again (load from it)."""
    with tempfile.TemporaryDirectory() as cache:
        env = {**os.environ, "NUMBA_CACHE_DIR": cache}
        out = []
        for _ in range(2):
            done = subprocess.run([sys.executable, "-c", COMPILE], env=env, check=True,
                                  capture_output=True, text=True)
            out.append([float(x) for x in done.stdout.split()])
    return dict(import_s=out[1][0], compile_s=out[0][1], load_s=out[1][1])


def time_mujoco(model, budget):
    """Median µs of :func:`mujoco_call`, and its note."""
    call, note = mujoco_call(model)
    return (None if call is None else median_us(call, budget)), note


def mujoco_call(model):
    """``mujoco.mj_forward`` on ``model`` converted to MuJoCo, and a note; no call
    where MuJoCo does not compile it."""
    import mujoco

    from vdad.interop.mujoco import to_mujoco

    try:
        m, d = to_mujoco(model)
    except Exception as exc:  # noqa: BLE001 (MuJoCo raises ValueError or its own errors)
        return None, f"mujoco: does not compile ({str(exc).splitlines()[0][:60]})"
    d.qvel[:] = np.random.default_rng(0).normal(size=m.nv)
    return (lambda: mujoco.mj_forward(m, d)), ""


#: steps per timed call of a step loop
STEPS = 200


def mujoco_forward_call(m, d):
    import mujoco

    return lambda: mujoco.mj_forward(m, d)


def mujoco_steps_call(m, d):
    import mujoco

    def call():
        for _ in range(STEPS):
            mujoco.mj_step(m, d)
    return call


def imported_rows(budget):
    """``forward_dynamics`` and a full step (the compiled step loop) of gymnasium's
    :data:`IMPORTED` models loaded with ``vdad.load_mjcf``, against ``mj_forward``
    and ``mj_step`` of the same files with contact off, in turns from ``qpos0``
    and random velocities; [] without gymnasium."""
    import warnings

    import mujoco

    try:
        import gymnasium
    except ImportError:
        return []
    base = Path(gymnasium.__file__).parent / "envs" / "mujoco" / "assets"
    rows = []
    for name in IMPORTED:
        path = str(base / f"{name}.xml")
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")                    # contacts left out
            model, report = vdad.load_mjcf(path, report=True)
        m = mujoco.MjModel.from_xml_path(path)
        m.opt.disableflags |= int(mujoco.mjtDisableBit.mjDSBL_CONTACT)
        q, qd = np.array(report.q0), np.random.default_rng(0).normal(size=model.nv) * 0.1
        d, d_step = mujoco.MjData(m), mujoco.MjData(m)   # forward at (q, qd), as vdad's
        for data in (d, d_step):
            data.qpos[:], data.qvel[:] = q, qd
        sim = vdad.Simulator(model, q, qd, dt=report.dt)
        sim.step(STEPS)
        t = medians_us({"fd": lambda model=model, q=q, qd=qd: vdad.forward_dynamics(model, q, qd),
                        "mj_forward": mujoco_forward_call(m, d),
                        "step": lambda sim=sim: sim.step(STEPS),
                        "mj_step": mujoco_steps_call(m, d_step)}, budget)
        row = dict(model=name, bodies=model.nb, dofs=model.nv, forward_us=t["fd"],
                   mj_forward_us=t["mj_forward"], step_us=t["step"] / STEPS,
                   mj_step_us=t["mj_step"] / STEPS,
                   left_out=[f for f, *_ in report.left_out])
        row["forward_over_mujoco"] = row["forward_us"] / row["mj_forward_us"]
        row["step_over_mujoco"] = row["step_us"] / row["mj_step_us"]
        rows.append(row)
        print(json.dumps(row))
    return rows


def write_imported(rows, result):
    lines = [f"Median µs (vdad and MuJoCo timed in turns); {result['machine']}"
             f"{' (quick run)' if result['quick'] else ''}. `forward_dynamics(model, q, qd)` "
             f"as a user calls it (float arrays; its cached work arrays, on the welded model "
             f"where fixed joints hang below a body: `docs/design.md`, \"Welds\"); a step: the "
             f"simulator's compiled semi-implicit step loop (200 steps a call) against "
             f"`mj_step` (each file's own integrator, contact off) called 200 times from Python. "
             f"Target (issue 17): within 8x of MuJoCo.", "",
             "| model | bodies | dofs | forward_dynamics | mj_forward | ratio | step | mj_step "
             "| ratio | left out |", "|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        lines.append(f"| {r['model']} | {r['bodies']} | {r['dofs']} | {fmt(r['forward_us'])} | "
                     f"{fmt(r['mj_forward_us'])} | {fmt(r['forward_over_mujoco'], 2)}x | "
                     f"{fmt(r['step_us'])} | {fmt(r['mj_step_us'])} | "
                     f"{fmt(r['step_over_mujoco'], 2)}x | {', '.join(r['left_out'])} |")
    write_section(IMPORTED_MARK, lines)


def previous(label):
    """The numpy core's µs on ``label`` from the earlier JSON, or None."""
    path = DOCS / "bench_dynamics_numpy.json"
    rows = json.loads(path.read_text())["rows"] if path.exists() else []
    return next((r["vdad_us"] for r in rows if r["model"] == label), None)


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="short timing budget")
    parser.add_argument("--no-compile", action="store_true",
                        help="skip the compile and cache-load timing (about a minute)")
    parser.add_argument("--imported", action="store_true",
                        help="time the imported MuJoCo models only (their own table and "
                        "bench_imported.json)")
    parser.add_argument("--out", default=str(DOCS / "bench_dynamics.json"))
    args = parser.parse_args(argv)
    budget = 0.5 if args.quick else 3.0
    if args.imported:
        result = dict(machine=f"{platform.processor() or platform.machine()}, "
                      f"{os.cpu_count()} cores", quick=args.quick, imported=imported_rows(budget))
        (DOCS / "bench_imported.json").write_text(json.dumps(result, indent=1))
        write_imported(result["imported"], result)
        return
    # (label, model, one tree of a forest, a model timed in turns with this one)
    cases = [("chain 20", pendulum(20).model, None, None),
             ("chain 300", pendulum(300).model, None, None),
             ("chain 1000", pendulum(1000).model, None, None),
             ("chain 10000", pendulum(10000).model, None, pendulum(1000).model),
             ("100 dogs (1600 bodies)", dog_forest(), dog_forest(1), None),
             ("character, composite joints (29 bodies)", composite_character(), None, None)]
    rows = []
    for label, model, one_tree, paired in cases:
        rng = np.random.default_rng(1)
        q = np.array(model.q_neutral)
        qd = rng.normal(size=model.nv) * 0.1
        calls = {"vdad": vdad_call(model, q, qd)}
        if paired is not None:          # a cost per body against another size's, in turns
            calls["paired"] = vdad_call(paired, np.array(paired.q_neutral),
                                        rng.normal(size=paired.nv) * 0.1)
        pin_note = mj_note = ""
        if model.nb <= 2000:
            if one_tree is None:
                calls["pin"], pin_note = pinocchio_call(model)
            else:
                calls["pin"], pin_note = pinocchio_call(one_tree, model.nb // one_tree.nb)
            calls["mujoco"], mj_note = mujoco_call(model)
        t = medians_us({k: f for k, f in calls.items() if f is not None}, budget)
        t_vdad, t_pin, t_mj = t["vdad"], t.get("pin"), t.get("mujoco")
        t_numpy = previous(label)
        per_body_ratio = None
        if paired is not None:
            per_body_ratio = (t_vdad / model.nb) / (t["paired"] / paired.nb)
            pin_note = (f"per body {per_body_ratio:.2f}x a {paired.nb}-body chain's "
                        f"({t['paired'] / paired.nb:.2f} µs), timed in turns")
        row = dict(model=label, bodies=model.nb, dofs=model.nv, vdad_us=t_vdad,
                   us_per_body=t_vdad / model.nb, pinocchio_us=t_pin, mujoco_us=t_mj,
                   vdad_over_pinocchio=None if t_pin is None else t_vdad / t_pin,
                   vdad_over_mujoco=None if t_mj is None else t_vdad / t_mj,
                   numpy_core_us=t_numpy,
                   speedup_over_numpy=None if t_numpy is None else t_numpy / t_vdad,
                   per_body_over_paired=per_body_ratio,
                   notes="; ".join(x for x in (pin_note, mj_note) if x))
        rows.append(row)
        print(json.dumps(row))
    imported = imported_rows(budget)
    result = dict(machine=f"{platform.processor() or platform.machine()}, "
                  f"{os.cpu_count()} cores", python=platform.python_version(),
                  numpy=np.__version__, numba=__import__("numba").__version__,
                  quick=args.quick, rows=rows, imported=imported,
                  compile=None if args.no_compile else time_compile())
    print(json.dumps(result["compile"]))
    Path(args.out).write_text(json.dumps(result, indent=1))
    write_table(rows, result)
    if imported:
        write_imported(imported, result)


def fmt(x, digits=1):
    return "—" if x is None else f"{x:,.{digits}f}"


def write_table(rows, result):
    lines = [MARK[0], "",
             f"Median µs per call (vdad, Pinocchio and MuJoCo timed in turns, 50 ms batches "
             f"of each per round); Python {result['python']}, numpy {result['numpy']}, "
             f"numba {result['numba']}, {result['machine']}"
             f"{' (quick run)' if result['quick'] else ''}.", "",
             "| model | bodies | vdad DCA | µs per body | pin.aba | mj_forward | vdad / pin | "
             "vdad / MuJoCo | numpy core (earlier run) | speed-up | notes |",
             "|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        lines.append(f"| {r['model']} | {r['bodies']} | {fmt(r['vdad_us'])} | "
                     f"{fmt(r['us_per_body'], 2)} | "
                     f"{fmt(r['pinocchio_us'])} | {fmt(r['mujoco_us'])} | "
                     f"{fmt(r['vdad_over_pinocchio'], 2)} | {fmt(r['vdad_over_mujoco'], 2)} | "
                     f"{fmt(r['numpy_core_us'])} | {fmt(r['speedup_over_numpy'], 1)} | "
                     f"{r['notes']} |")
    c = result["compile"]
    if c is not None:
        lines += ["", f"Start-up in a fresh process: `import vdad` {c['import_s']:.2f} s; the "
                  f"first forward dynamics compiles the kernels in {c['compile_s']:.1f} s with "
                  f"an empty numba cache and loads them in {c['load_s']:.2f} s from it."]
    write_section(MARK, lines[1:])


def write_section(mark, lines, path=DOCS / "benchmarks.md"):
    """Replace the text between the markers ``mark`` of ``path`` (default
    ``docs/benchmarks.md``) by ``lines`` (the section is appended if the markers
    are missing)."""
    text = path.read_text() if path.exists() else "# Benchmarks\n"
    if mark[0] not in text:
        text += f"\n{mark[0]}{mark[1]}\n"
    start, end = text.index(mark[0]), text.index(mark[1]) + len(mark[1])
    path.write_text(text[:start] + "\n".join([mark[0], *lines, "", mark[1]]) + text[end:])


if __name__ == "__main__":
    main()
