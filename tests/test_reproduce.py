"""vdad reproduce: the quick reproduction's files and trends, the runs and the report."""

import csv
import json

import numpy as np
import pytest

import vdad.reproduce
from vdad import InputError, report
from vdad.cli import main
from vdad.report import best_under, decreasing
from vdad.reproduce import (
    EXPERIMENTS,
    FAMILIES,
    RESULT_FIELDS,
    SLOW,
    SLOW_FAMILY,
    TRACE,
    check_result,
    family,
    plan,
    reproduce,
    run_config,
)

FILES = ["table1.md", "table1.csv", "figure8.png", "figure8.csv", "figure9.png",
         "figure9.csv", "dogs.md", "dogs.csv", "speed_vs_error.csv", "error_over_time.csv",
         "report.md"] + [
    f"{kind}_{scene}.png" for kind in ("speed_vs_error", "error_over_time")
    for scene in ("pendulum", "hanging_dogs", "falling_character")]


@pytest.fixture(scope="module")
def quick(tmp_path_factory):
    out = tmp_path_factory.mktemp("reproduce")
    assert main(["reproduce", "--quick", "--out", str(out), "--jobs", "2",
                 "--no-progress"]) == 0
    return out


def _rows(path):
    with open(path) as fh:
        return list(csv.DictReader(fh))


def test_quick_writes_every_file(quick):
    for name in FILES:
        path = quick / name
        assert path.stat().st_size > 0, name
        if name.endswith(".png"):
            assert path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    report = (quick / "report.md").read_text()
    for heading in ("Table 1", "Figure 8", "Figure 9", "Figure 6", "Speed against measured"):
        assert heading in report
    assert "0.218" in report and "493" in report                # the paper's numbers beside
    n_configs = len({json.dumps(c, sort_keys=True) for cs in plan(True).values() for c in cs})
    assert len(list((quick / "runs").glob("*.json"))) == n_configs


def test_quick_has_the_papers_trends(quick):
    """Fewer active joints and less work (nodes the dynamics touches) as the
    threshold or the distance grows; the time per step is a benchmark's to judge
    (docs/reproduction.md), not a test's."""
    fig8 = _rows(quick / "figure8.csv")
    for method in ("view-bvh", "view-oq"):
        rows = sorted((r for r in fig8 if r["method"] == method),
                      key=lambda r: float(r["error threshold"]))
        assert all(not r["failure"] for r in rows)
        lo, hi = rows[0], rows[-1]                  # more threshold: fewer joints, less work
        assert float(hi["active joints"]) < 0.5 * float(lo["active joints"])
        assert float(hi["node visits"]) < 0.5 * float(lo["node visits"])
    fig9 = sorted((r for r in _rows(quick / "figure9.csv") if r["method"] == "view-oq"),
                  key=lambda r: float(r["viewer distance (m)"]))
    near, far = fig9[0], fig9[-1]                   # more distance: fewer joints, less work
    assert float(far["active joints"]) < 0.5 * float(near["active joints"])
    assert float(far["node visits"]) < 0.5 * float(near["node visits"])
    table1 = _rows(quick / "table1.csv")
    dca = [r for r in table1 if r["method"] == "dca"][0]
    assert float(dca["active joints"]) == 20 and float(dca["mean px error"]) == 0
    for r in table1:
        if r["method"] != "dca":
            assert float(r["active joints"]) < 20


def test_speed_study_covers_every_family_and_measures_error(quick):
    rows = _rows(quick / "speed_vs_error.csv")
    for scene in ("pendulum", "hanging_dogs", "falling_character"):
        mine = [r for r in rows if r["scene"] == scene]
        families = {r["family"] for r in mine}
        assert families >= {"adaptive", "view-bvh sphere", "view-bvh obb", "view-bvh aabb",
                            "view-oq", "lod-distance", "sleeping", "dca"}
        assert (SLOW_FAMILY in families) == (scene == "falling_character")
        dca = [r for r in mine if r["family"] == "dca"][0]
        assert float(dca["mean px (mean)"]) == 0 and float(dca["differing px (mean)"]) == 0
        assert any(float(r["mean px (mean)"]) > 0 for r in mine if not r["failure"])
    frames = _rows(quick / "error_over_time.csv")
    assert {r["family"] for r in frames} >= {"dca", "view-oq", "lod-distance"}
    for r in frames:
        if r["family"] == "dca":
            assert float(r["mean_px"]) == 0 and float(r["differing_pixels"]) == 0


def test_a_second_run_recomputes_nothing(quick):
    stamps = {p.name: p.stat().st_mtime_ns for p in (quick / "runs").glob("*.json")}
    reproduce(quick, quick=True, progress=False, only=["table1"])
    assert {p.name: p.stat().st_mtime_ns for p in (quick / "runs").glob("*.json")} == stamps


def test_run_config_reference_run_has_zero_error():
    config = {"scene": "pendulum", "scene_args": {"n_bodies": 4}, "method": "dca",
              "options": {}, "steps": 20, "every": 10}
    r = run_config(config)
    assert r["steps"] == 20 and r["failure"] is None and r["active_joints"] == 4
    assert r["error"]["mean_px"]["max"] == 0 and r["error"]["differing_pixels"]["max"] == 0
    assert r["trace"]["t"] == pytest.approx([0.01, 0.02])
    perturbed = run_config({**config, "method": "adaptive", "options": {"threshold": 1e-2}})
    assert perturbed["error"]["mean_px"]["max"] > 0
    assert perturbed["error"]["differing_pixels"]["max"] > 0


def test_report_helpers():
    assert decreasing([1, 2, 3], [30, 20, 10])
    assert not decreasing([1, 2, 3], [30, 35, 10])
    assert decreasing([3, 1, 2], [10, 30, 20])                 # sorted by x first
    assert not decreasing([1, 2], [10, 10])
    row = lambda method, speedup, err, failure=None, **o: {    # noqa: E731
        "config": {"method": method, "options": o}, "speedup": speedup, "failure": failure,
        "error": {"mean_px": {"mean": err}}}
    rows = [row("adaptive", 2.0, 0.5, threshold=1e-3), row("adaptive", 3.0, 5.0, threshold=1e-2),
            row("view-oq", 9.0, 0.1, "diverged", threshold=1.0), row("dca", 1.0, 0.0)]
    assert best_under(rows, 1.0) == {"adaptive": (2.0, 1e-3)}
    assert best_under(rows, 10.0) == {"adaptive": (3.0, 1e-2)}


def test_plan_names_every_experiment_and_quick_is_smaller():
    full, fast = plan(False), plan(True)
    assert tuple(full) == EXPERIMENTS == tuple(fast)
    for c in full["speed_vs_error"]:                # every run has a family of the legend
        assert c["method"] == "dca" or family(c) in FAMILIES
    slow = [c for c in full["speed_vs_error"] if "velocity_weights" in c["options"]]
    assert slow and all(c["scene"] == "falling_character" and c["method"] == "view-bvh"
                        and c["options"]["pixels"] == "moved"
                        and c["options"]["velocity_weights"] == SLOW
                        and family(c) == SLOW_FAMILY for c in slow)
    assert sum(map(len, fast.values())) < sum(map(len, full.values()))
    assert np.all([c["steps"] % c["every"] == 0 for cs in full.values() for c in cs])


def test_missing_extras_are_named_before_any_run(tmp_path, monkeypatch):
    import importlib.util

    find_spec = importlib.util.find_spec
    monkeypatch.setattr(importlib.util, "find_spec",
                        lambda name, *a: None if name == "matplotlib" else find_spec(name, *a))
    with pytest.raises(InputError, match=r"needs matplotlib: pip install \"vdad\[render,plots\]"):
        reproduce(tmp_path, quick=True, progress=False)
    assert not (tmp_path / "runs").exists()


def test_bad_arguments(tmp_path, capsys):
    with pytest.raises(InputError, match="unknown experiments"):
        reproduce(tmp_path, only=["figure10"])
    with pytest.raises(InputError, match="unknown scene"):
        run_config({"scene": "teapot", "scene_args": {}, "method": "dca", "options": {},
                    "steps": 1, "every": 1})
    assert main(["reproduce", "--out", str(tmp_path), "--jobs", "0"]) == 2
    assert "--jobs" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        main(["reproduce", "--only", "figure10"])


SMALL = {"scene": "pendulum", "scene_args": {"n_bodies": 4}, "method": "adaptive",
         "options": {"threshold": 1e-2}, "steps": 20, "every": 10}


@pytest.fixture(scope="module")
def small_result():
    return json.loads(json.dumps(run_config(SMALL)))         # as stored and read back


def _checked_only(value, fields):
    """``value`` cut down to the fields that :func:`check_result` checks."""
    return {k: _checked_only(value[k], f) if isinstance(f, dict) else value[k]
            for k, f in fields.items()}


def _leaves(fields, prefix=""):
    for key, kind in fields.items():
        if isinstance(kind, dict):
            yield from _leaves(kind, f"{prefix}{key}.")
        else:
            yield f"{prefix}{key}"


def _without(result, dotted):
    out = json.loads(json.dumps(result))
    *parents, last = dotted.split(".")
    inner = out
    for name in parents:
        inner = inner[name]
    del inner[last]
    return out


def test_check_result_names_what_is_missing_or_wrong(small_result):
    assert check_result(small_result) is None
    assert check_result(_checked_only(small_result, RESULT_FIELDS)) is None
    assert check_result({"steps": 200}).startswith("incomplete (no 'ms_per_step', ")
    for name in _leaves(RESULT_FIELDS):
        assert check_result(_without(small_result, name)) == f"incomplete (no {name!r})"
    assert check_result({**small_result, "steps": "200"}) == \
        "invalid ('steps' is not an int: a str)"
    assert check_result({**small_result, "ms_per_step": True}) == \
        "invalid ('ms_per_step' is not a number or null: a bool)"
    assert check_result({**small_result, "error": []}) == "invalid ('error' is not a dict: a list)"
    trace = {**small_result["trace"], "t": ["0.1", 0.2]}
    assert check_result({**small_result, "trace": trace}) == \
        "invalid ('trace.t' is not a list of numbers or nulls: a list)"
    trace = {**small_result["trace"], "t": [0.1]}
    assert check_result({**small_result, "trace": trace}).startswith(
        "invalid (trace columns of different lengths: ")
    assert check_result([1, 2]) == "invalid (its result is a list, not a dict)"


def test_report_reads_only_checked_fields(small_result, tmp_path):
    """Every writer runs on results holding only what check_result checks, including
    a run that diverged at its first step (no timing, no frames)."""
    kept = _checked_only(small_result, RESULT_FIELDS)
    diverged = {"ms_per_step": None, "reference_ms_per_step": None, "speedup": None,
                "active_joints": None, "node_visits": None, "joints": 4, "steps": 0,
                "failure": "diverged",
                "error": {m: {"mean": None, "max": None, "sum": None} for m in TRACE[1:]},
                "trace": {k: [] for k in TRACE}}
    assert check_result(diverged) is None
    rows = {name: [{**(diverged if i % 3 == 2 else kept), "config": c}
                   for i, c in enumerate(configs)] for name, configs in plan(True).items()}
    files = []
    for name in EXPERIMENTS:
        files += getattr(report, f"write_{name}")(rows[name], tmp_path)
    files += report.write_report(rows, tmp_path, True)
    assert all(path.stat().st_size > 0 for path in files)
    assert "diverged at step 1" in (tmp_path / "speed_vs_error.csv").read_text()


def test_damaged_stored_runs_are_recomputed_with_one_line_each(tmp_path, capsys, monkeypatch):
    out = tmp_path / "out"
    command = ["reproduce", "--quick", "--only", "table1", "--out", str(out), "--no-progress"]
    assert main(command) == 0
    runs = sorted((out / "runs").glob("*.json"))
    assert len(runs) == len(plan(True)["table1"])
    incomplete, folder = runs[1], runs[4]
    record = json.loads(incomplete.read_text())
    incomplete.write_text(json.dumps({**record, "result": {"steps": 200}}))
    damaged_configs = [record["config"], json.loads(folder.read_text())["config"]]
    folder.unlink()
    folder.mkdir()
    stamps = {p.name: p.stat().st_mtime_ns for p in runs if p not in (incomplete, folder)}
    calls = []

    def counted(config):
        calls.append(config)
        return run_config(config)

    monkeypatch.setattr(vdad.reproduce, "run_config", counted)   # --jobs 1: in this process
    capsys.readouterr()
    assert main(command) == 0
    err = capsys.readouterr().err
    lines = sorted((line for line in err.splitlines() if "stored record" in line),
                   key=lambda line: "a folder" in line)     # in the order of the plan: sort
    assert len(lines) == 2
    assert lines[0] == (
        f"vdad reproduce: stored record {incomplete} is incomplete (no 'ms_per_step', "
        f"'reference_ms_per_step', 'speedup', 'active_joints', 'node_visits', 'joints', "
        f"'failure', 'error', "
        f"'trace'); recomputing it")
    head = f"vdad reproduce: stored record {folder} is a folder, not a record file (moved aside to "
    assert lines[1].startswith(head) and lines[1].endswith(".aside); recomputing it")
    assert (out / "runs" / lines[1][len(head):-len("); recomputing it")]).is_dir()
    assert "Error" not in err and "Errno" not in err
    assert sorted(calls, key=json.dumps) == sorted(damaged_configs, key=json.dumps)
    assert {p.name: p.stat().st_mtime_ns for p in runs
            if p not in (incomplete, folder)} == stamps
    for path in (incomplete, folder):
        assert path.is_file() and check_result(json.loads(path.read_text())["result"]) is None
    assert "| dca |" in (out / "table1.md").read_text()
