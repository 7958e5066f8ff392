"""Tests of vdad.sweep: configuration keys, the result store, and resumable sweeps
run serially, on joblib workers and on a local Dask cluster, including a sweep
killed half way (SIGKILL) and restarted.

The functions swept are defined at module level here: joblib and Dask worker
processes import this module by name (pytest puts ``tests/`` on ``sys.path`` and
spawned workers inherit it), and the killed subprocess imports it the same way.
"""

import hashlib
import json
import os
import signal
import subprocess
import sys
import textwrap
import time
import warnings
from collections import Counter
from datetime import datetime
from pathlib import Path

import pytest

from vdad.errors import InputError
from vdad.sweep import ResultStore, SweepError, SweepReport, config_key, run_sweep

TESTS_DIR = Path(__file__).resolve().parent


def square(config):
    return {"x": config["x"], "square": config["x"] ** 2}


def explode(config):
    raise AssertionError(f"fn called for {config!r} although its result is stored")


def fail_on_three(config):
    if config["x"] == 3:
        raise ValueError("boom at three")
    return square(config)


def not_a_dict(config):
    return [config["x"]]


def slow_logged(config):
    """Append the configuration's id to its log (one line per call), then sleep."""
    descriptor = os.open(config["log"], os.O_WRONLY | os.O_APPEND | os.O_CREAT)
    try:
        os.write(descriptor, f"{config['id']}\n".encode())
    finally:
        os.close(descriptor)
    time.sleep(config["sleep"])
    return {"id": config["id"]}


def xs(n):
    return [{"x": x} for x in range(n)]


# ---------------------------------------------------------------- keys and store


def test_config_key_is_stable_and_order_independent():
    key = config_key({"a": 1, "b": 2})
    assert key == config_key({"b": 2, "a": 1})
    assert len(key) == 16 and int(key, 16) >= 0
    assert key != config_key({"a": 1, "b": 3})
    assert config_key({"a": [1, 2]}) == config_key({"a": (1, 2)})
    # the documented recipe, so keys stay valid across versions
    expected = hashlib.sha1(b'{"a":1,"b":2}').hexdigest()[:16]
    assert key == expected


@pytest.mark.parametrize("config, match", [
    ({"a": object()}, "not JSON-serialisable"),
    ({"a": {1, 2}}, "not JSON-serialisable"),
    ([("a", 1)], "must be a dict"),
    ("a=1", "must be a dict"),
])
def test_config_key_rejects_bad_configs(config, match):
    with pytest.raises(InputError, match=match):
        config_key(config)


def test_result_store_round_trip(tmp_path):
    store = ResultStore(tmp_path / "deep" / "store")
    assert store.folder.is_dir()
    config = {"method": "adaptive", "threshold": 0.5}
    assert not store.has(config)
    record = store.save(config, {"error": 1e-3, "steps": [1, 2]}, 1.25)
    assert store.path(config) == store.folder / f"{config_key(config)}.json"
    assert store.has(config)
    assert store.load(config) == {"error": 1e-3, "steps": [1, 2]}
    on_disk = json.loads(store.path(config).read_text())
    assert on_disk == record
    assert set(on_disk) == {"key", "config", "result", "seconds", "finished"}
    assert on_disk["key"] == config_key(config) and on_disk["config"] == config
    assert on_disk["seconds"] == 1.25
    datetime.fromisoformat(on_disk["finished"])
    assert list(store) == store.records() == [record]
    assert [p.name for p in store.folder.iterdir()] == [f"{config_key(config)}.json"]


def test_result_store_errors(tmp_path):
    store = ResultStore(tmp_path)
    with pytest.raises(InputError, match="no stored result.*'x': 1"):
        store.load({"x": 1})
    with pytest.raises(InputError, match="'x': 1.*not JSON-serialisable"):
        store.save({"x": 1}, {"value": object()}, 0.0)
    with pytest.raises(InputError, match="'x': 1.*must be a dict"):
        store.save({"x": 1}, [1], 0.0)
    assert list(tmp_path.iterdir()) == []  # nothing half-written left behind
    (tmp_path / "file").write_text("")
    with pytest.raises(InputError, match="not a folder"):
        ResultStore(tmp_path / "file")


def test_corrupt_records_are_recomputed(tmp_path):
    store = ResultStore(tmp_path)
    configs = xs(4)
    run_sweep(square, configs, store, progress=False)
    store.path(configs[1]).write_text('{"key": "' + config_key(configs[1]) + '", "resu')
    store.path(configs[2]).write_bytes(b"\xff\x00 not json")
    assert not store.has(configs[1]) and not store.has(configs[2])
    assert len(store.records()) == 2
    report = run_sweep(square, configs, store, progress=False)
    assert list(report.damaged) == [config_key(configs[1]), config_key(configs[2])]
    assert all(p.startswith("corrupt (not JSON: ") for p in report.damaged.values())
    assert report.computed == [config_key(configs[1]), config_key(configs[2])]
    assert report.reused == [config_key(configs[0]), config_key(configs[3])]
    assert report.results == [square(c) for c in configs]
    assert store.load(configs[1]) == square(configs[1])


def needs_square(result):
    """A consumer's validation: the result must hold an int ``square``."""
    if "square" not in result:
        return "incomplete (no 'square')"
    if not isinstance(result["square"], int):
        return f"invalid ('square' is a {type(result['square']).__name__})"
    return None


def counting(calls):
    """``square`` that appends each configuration it computes to ``calls``."""
    def fn(config):
        calls.append(config["x"])
        return square(config)
    return fn


def damaged_lines(err):
    return [line for line in err.splitlines() if "stored record" in line]


def test_incomplete_record_is_recomputed_once_and_named(tmp_path, capsys):
    store = ResultStore(tmp_path)
    configs = xs(4)
    run_sweep(square, configs, store, progress=False, validate=needs_square)
    path = store.path(configs[2])
    record = json.loads(path.read_text())
    path.write_text(json.dumps({**record, "result": {"steps": 200}}))   # valid JSON, incomplete
    capsys.readouterr()
    calls = []
    report = run_sweep(counting(calls), configs, store, progress=False, validate=needs_square)
    assert calls == [2]
    assert report.computed == [config_key(configs[2])]
    assert report.reused == [config_key(c) for c in configs if c["x"] != 2]
    assert report.damaged == {config_key(configs[2]): "incomplete (no 'square')"}
    assert report.results == [square(c) for c in configs]
    lines = damaged_lines(capsys.readouterr().err)
    assert lines == [f"sweep: stored record {path} is incomplete (no 'square'); recomputing it"]
    assert store.load(configs[2]) == square(configs[2])            # the new record is complete
    again = run_sweep(explode, configs, store, progress=False, validate=needs_square)
    assert again.computed == [] and again.damaged == {}
    assert damaged_lines(capsys.readouterr().err) == []


def test_wrong_type_and_bare_records_are_recomputed(tmp_path, capsys):
    store = ResultStore(tmp_path)
    configs = xs(3)
    run_sweep(square, configs, store, progress=False)
    record = json.loads(store.path(configs[0]).read_text())
    store.path(configs[0]).write_text(json.dumps({**record, "result": {"square": "zero"}}))
    store.path(configs[1]).write_text('{"steps": 200}')        # not even a record
    capsys.readouterr()
    report = run_sweep(square, configs, store, progress=False, validate=needs_square)
    assert report.computed == [config_key(c) for c in configs[:2]]
    assert report.damaged == {config_key(configs[0]): "invalid ('square' is a str)",
                              config_key(configs[1]): "incomplete (no 'key', 'config', 'result')"}
    lines = damaged_lines(capsys.readouterr().err)
    assert len(lines) == 2
    assert str(store.path(configs[0])) in lines[0] and "'square' is a str" in lines[0]
    assert str(store.path(configs[1])) in lines[1] and "no 'key', 'config', 'result'" in lines[1]
    assert [store.load(c) for c in configs] == [square(c) for c in configs]


def test_record_replaced_by_a_folder_is_moved_aside_and_recomputed(tmp_path, capsys):
    store = ResultStore(tmp_path)
    configs = xs(3)
    run_sweep(square, configs, store, progress=False)
    path = store.path(configs[1])
    path.unlink()
    path.mkdir()
    (path / "keep.txt").write_text("user data")
    capsys.readouterr()
    assert not store.has(configs[1]) and len(store.records()) == 2
    assert store.inspect(configs[1]) == (None, "a folder, not a record file")
    calls = []
    report = run_sweep(counting(calls), configs, store, progress=False)
    assert calls == [1] and report.computed == [config_key(configs[1])]
    assert report.results == [square(c) for c in configs]
    lines = damaged_lines(capsys.readouterr().err)
    assert len(lines) == 1
    assert lines[0].startswith(f"sweep: stored record {path} is a folder, not a record file "
                               f"(moved aside to {path.name}.")
    assert lines[0].endswith(".aside); recomputing it")
    assert path.is_file() and store.load(configs[1]) == square(configs[1])
    aside = [p for p in tmp_path.iterdir() if p.name.endswith(".aside")]
    assert len(aside) == 1 and (aside[0] / "keep.txt").read_text() == "user data"
    assert sorted(r["config"]["x"] for r in store) == [0, 1, 2]    # the folder aside is ignored


def test_save_over_a_folder_moves_it_aside(tmp_path):
    store = ResultStore(tmp_path)
    store.path({"x": 1}).mkdir()
    store.save({"x": 1}, square({"x": 1}), 0.5)
    assert store.load({"x": 1}) == square({"x": 1})
    assert len([p for p in tmp_path.iterdir() if p.name.endswith(".aside")]) == 1


def test_record_whose_result_is_a_list_is_recomputed(tmp_path, capsys):
    store = ResultStore(tmp_path)
    configs = xs(2)
    run_sweep(square, configs, store, progress=False)
    path = store.path(configs[0])
    record = json.loads(path.read_text())
    path.write_text(json.dumps({**record, "result": [0, 0]}))
    capsys.readouterr()
    calls = []
    report = run_sweep(counting(calls), configs, store, progress=False, validate=needs_square)
    assert calls == [0] and report.reused == [config_key(configs[1])]
    assert report.damaged == {config_key(configs[0]): "invalid (its result is a list, not a dict)"}
    assert damaged_lines(capsys.readouterr().err) == [
        f"sweep: stored record {path} is invalid (its result is a list, not a dict); "
        f"recomputing it"]
    assert store.load(configs[0]) == square(configs[0])


def test_unreadable_record_is_recomputed(tmp_path, capsys, monkeypatch):
    store = ResultStore(tmp_path)
    configs = xs(2)
    run_sweep(square, configs, store, progress=False)
    locked = store.path(configs[0])
    read_bytes = Path.read_bytes

    def denied(self):
        if self == locked:
            raise PermissionError(13, "Permission denied", str(self))
        return read_bytes(self)

    monkeypatch.setattr(Path, "read_bytes", denied)      # chmod does not stop root
    capsys.readouterr()
    report = run_sweep(square, configs, store, progress=False)
    assert report.computed == [config_key(configs[0])]
    assert report.damaged == {config_key(configs[0]): "unreadable (Permission denied)"}
    assert damaged_lines(capsys.readouterr().err) == [
        f"sweep: stored record {locked} is unreadable (Permission denied); recomputing it"]
    monkeypatch.undo()
    assert store.load(configs[0]) == square(configs[0])


def test_complete_records_are_reused_under_validation(tmp_path, capsys):
    configs = xs(5)
    first = run_sweep(square, configs, tmp_path, jobs=2, progress=False, validate=needs_square)
    capsys.readouterr()
    again = run_sweep(explode, configs, tmp_path, jobs=2, progress=False, validate=needs_square)
    assert again.computed == [] and again.damaged == {}
    assert again.reused == first.computed and again.results == first.results
    assert capsys.readouterr().err == ""


# ---------------------------------------------------------------- sweeps


@pytest.mark.parametrize("jobs", [1, 2])
def test_sweep_results_in_order_then_reused(tmp_path, jobs):
    configs = [{"x": x} for x in (5, 3, 8, 1, 0, 7, 2, 6)]
    report = run_sweep(square, configs, tmp_path, jobs=jobs, progress=False)
    assert isinstance(report, SweepReport)
    assert report.results == [square(c) for c in configs]
    assert report.computed == [config_key(c) for c in configs]
    assert report.reused == []
    store = ResultStore(tmp_path)
    assert len(store.records()) == len(configs)
    for record in store:
        assert record["result"] == square(record["config"]) and record["seconds"] >= 0.0

    again = run_sweep(explode, configs, store, jobs=jobs, progress=False)
    assert again.results == report.results
    assert again.computed == []
    assert again.reused == report.computed


def test_duplicate_configs_are_computed_once(tmp_path):
    calls = []

    def counted(config):
        calls.append(dict(config))
        return {"sum": config["a"] + config["b"]}

    configs = [{"a": 1, "b": 2}, {"b": 2, "a": 1}, {"a": 2, "b": 2}, {"a": 1, "b": 2}]
    report = run_sweep(counted, configs, tmp_path, progress=False)
    assert calls == [{"a": 1, "b": 2}, {"a": 2, "b": 2}]
    assert report.results == [{"sum": 3}, {"sum": 3}, {"sum": 4}, {"sum": 3}]
    assert report.computed == [config_key(configs[0]), config_key(configs[2])]


def test_partially_stored_sweep_computes_only_the_rest(tmp_path):
    configs = xs(6)
    run_sweep(square, configs[::2], tmp_path, progress=False)
    report = run_sweep(square, configs, tmp_path, jobs=2, progress=False)
    assert report.reused == [config_key(c) for c in configs[::2]]
    assert report.computed == [config_key(c) for c in configs[1::2]]
    assert report.results == [square(c) for c in configs]


@pytest.mark.parametrize("jobs", [1, 2])
def test_failing_configuration_raises_sweep_error(tmp_path, jobs):
    configs = xs(6)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        with pytest.raises(SweepError, match=r"\{'x': 3\}.*ValueError: boom at three") as info:
            run_sweep(fail_on_three, configs, tmp_path, jobs=jobs, progress=False)
    assert isinstance(info.value.__cause__, ValueError)
    assert not [w for w in caught if "tasks" in str(w.message)]  # joblib's early-exit warning
    store = ResultStore(tmp_path)
    assert not store.has(configs[3])
    stored = sorted(record["config"]["x"] for record in store)
    if jobs == 1:
        assert stored == [0, 1, 2]
    for record in store:
        assert record["result"] == square(record["config"])
    report = run_sweep(square, configs, store, jobs=jobs, progress=False)
    assert sorted(report.reused) == sorted(config_key({"x": x}) for x in stored)
    assert report.results == [square(c) for c in configs]


def test_non_dict_result_raises_input_error(tmp_path):
    with pytest.raises(InputError, match=r"\{'x': 0\}.*must be a dict, got list"):
        run_sweep(not_a_dict, xs(2), tmp_path, progress=False)
    assert ResultStore(tmp_path).records() == []


@pytest.mark.parametrize("kwargs, match", [
    (dict(fn=3), "fn must be a callable"),
    (dict(configs={"x": 1}), "configs must be a list of dicts"),
    (dict(configs=[{"x": 1}, 2]), r"configs\[1\] must be a dict"),
    (dict(configs=[{"x": object()}]), "not JSON-serialisable"),
    (dict(jobs=0), "jobs must be a nonzero int"),
    (dict(jobs=1.5), "jobs must be a nonzero int"),
    (dict(jobs=True), "jobs must be a nonzero int"),
    (dict(store=3), "store must be a ResultStore or a folder path"),
    (dict(scheduler=42), "scheduler must be a Dask scheduler address or a distributed.Client"),
    (dict(scheduler=" "), "empty string"),
    (dict(validate=("square",)), "validate must be None or a callable"),
])
def test_run_sweep_validates_arguments(tmp_path, kwargs, match):
    arguments = dict(fn=square, configs=xs(2), store=tmp_path / "store", progress=False)
    arguments.update(kwargs)
    with pytest.raises(InputError, match=match):
        run_sweep(**arguments)


def test_scheduler_without_dask_names_the_extra(tmp_path, monkeypatch):
    monkeypatch.setitem(sys.modules, "distributed", None)
    with pytest.raises(InputError, match=r'pip install "vdad\[cluster\]"'):
        run_sweep(square, xs(2), tmp_path, scheduler="tcp://127.0.0.1:8786", progress=False)


def test_progress_bar(tmp_path, capsys):
    run_sweep(square, xs(3), tmp_path, progress=False)
    assert capsys.readouterr().err == ""
    run_sweep(square, xs(5), tmp_path, progress=True, desc="demo")
    err = capsys.readouterr().err
    assert "demo (3 reused)" in err and "2/2" in err


# ---------------------------------------------------------------- Dask


def test_dask_cluster(tmp_path):
    distributed = pytest.importorskip("distributed")  # in the test extra: never skipped there
    configs = xs(6)
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True,
                                  dashboard_address=None) as cluster:
        report = run_sweep(square, configs, tmp_path / "a", scheduler=cluster.scheduler_address,
                           progress=False)
        assert report.results == [square(c) for c in configs]
        assert report.computed == [config_key(c) for c in configs]
        store = ResultStore(tmp_path / "a")
        assert sorted(r["config"]["x"] for r in store) == list(range(6))
        assert all(r["result"] == square(r["config"]) for r in store)

        with distributed.Client(cluster, set_as_default=False) as client:
            again = run_sweep(explode, configs, store, scheduler=client, progress=False)
            assert again.reused == report.computed and again.computed == []
            with pytest.raises(SweepError, match=r"\{'x': 3\}.*boom at three") as info:
                run_sweep(fail_on_three, configs, tmp_path / "b", scheduler=client,
                          progress=False)
            assert "worker traceback" in str(info.value)
            assert client.status == "running"  # a given client is left open
        assert not ResultStore(tmp_path / "b").has({"x": 3})


# ---------------------------------------------------------------- kill and resume

KILLED_SWEEP = textwrap.dedent("""
    import sys
    import time

    sys.path.insert(0, {tests!r})
    from test_sweep import slow_logged

    from vdad.sweep import run_sweep


    def stalling(config):
        # past the first 8 configurations, hang after logging: the kill always
        # lands half way, however slowly the test polls
        result = slow_logged(config)
        if config["id"] >= 8:
            time.sleep(600)
        return result


    run_sweep(stalling, {configs!r}, {store!r}, jobs=1, progress=False)
""")


@pytest.mark.parametrize("jobs", [1, 2])
def test_killed_sweep_resumes_with_missing_configurations_only(tmp_path, jobs):
    log = tmp_path / "calls.log"
    store = tmp_path / "store"
    configs = [{"id": i, "sleep": 0.1, "log": str(log)} for i in range(12)]
    script = tmp_path / "sweep_script.py"
    script.write_text(KILLED_SWEEP.format(tests=str(TESTS_DIR), configs=configs,
                                          store=str(store)))
    process = subprocess.Popen([sys.executable, str(script)], stderr=subprocess.PIPE)
    try:
        deadline = time.monotonic() + 60.0
        while len(list(store.glob("*.json"))) < 6:
            assert process.poll() is None, process.stderr.read().decode()
            assert time.monotonic() < deadline, "the sweep subprocess stored too few results"
            time.sleep(0.02)
    finally:
        process.send_signal(signal.SIGKILL)
        process.wait()
        process.stderr.close()

    stored = {record["key"] for record in ResultStore(store)}
    assert 6 <= len(stored) <= 8
    keys = [config_key(c) for c in configs]
    report = run_sweep(slow_logged, configs, store, jobs=jobs, progress=False)
    assert set(report.reused) == stored
    assert set(report.computed) == set(keys) - stored
    assert report.results == [{"id": c["id"]} for c in configs]
    calls = Counter(int(line) for line in log.read_text().split())
    assert set(calls) == set(range(12))
    finished_before = {c["id"] for c, key in zip(configs, keys, strict=True) if key in stored}
    assert all(calls[i] == 1 for i in finished_before)
    assert sum(calls.values()) <= 13  # at most the one configuration in flight ran twice
