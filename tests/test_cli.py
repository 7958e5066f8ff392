"""The command line (vdad.cli)."""

import json
import subprocess
import sys

import pytest

from vdad.cli import main


def test_run_pendulum_writes_json(tmp_path, capsys):
    out = tmp_path / "run.json"
    assert main(["run", "pendulum", "--bodies", "5", "--steps", "20", "--dt", "0.002",
                 "--json", str(out), "--no-progress"]) == 0
    data = json.loads(out.read_text())
    for key in ("scene", "method", "bodies", "joints", "steps", "dt", "ms_per_step", "final_q"):
        assert key in data
    assert (data["scene"], data["method"], data["bodies"], data["steps"]) == ("pendulum", "dca",
                                                                             5, 20)
    assert len(data["final_q"]) == 5 and data["ms_per_step"] > 0
    assert "ms per step" in capsys.readouterr().out


@pytest.mark.parametrize("argv", [["--help"], ["run", "--help"]])
def test_help(argv, capsys):
    with pytest.raises(SystemExit) as exc:
        main(argv)
    assert exc.value.code == 0
    assert "usage: vdad" in capsys.readouterr().out


@pytest.mark.parametrize("argv, message", [
    (["run", "pendulum", "--steps", "0"], "--steps: must be a positive integer"),
    (["run", "pendulum", "--dt", "nan"], "--dt: must be a positive number"),
    (["run", "box"], "invalid choice: 'box'"),
])
def test_bad_arguments(argv, message, capsys):
    with pytest.raises(SystemExit) as exc:
        main(argv)
    assert exc.value.code == 2
    assert message in capsys.readouterr().err


def test_unwritable_json_is_a_clear_error(tmp_path, capsys):
    assert main(["run", "pendulum", "--bodies", "2", "--steps", "2", "--no-progress",
                 "--json", str(tmp_path / "missing" / "x.json")]) == 2
    assert "vdad: error:" in capsys.readouterr().err


def test_console_entry_point():
    result = subprocess.run([sys.executable, "-m", "vdad", "run", "pendulum", "--bodies", "3",
                             "--steps", "5", "--no-progress"], capture_output=True, text=True)
    assert result.returncode == 0, result.stderr
    assert "3-link pendulum" in result.stdout


def test_run_adaptive_reports_active_joints_and_counters(tmp_path):
    out = tmp_path / "adaptive.json"
    assert main(["run", "pendulum", "--bodies", "40", "--steps", "60", "--method", "adaptive",
                 "--threshold", "1e-4", "--json", str(out), "--no-progress"]) == 0
    data = json.loads(out.read_text())
    assert data["method"] == "adaptive" and data["adaptive"]["threshold"] == 1e-4
    assert 0 < data["active_joints_mean"] < 40
    counters = data["counters_mean"]
    for key in ("accelerated", "assembled", "back_substituted", "front", "force_update",
                "node_visits"):
        assert counters[key] >= 0
    assert counters["assembled"] == data["active_joints_mean"]
    assert set(data["ms_per_phase_mean"]) >= {"kinematics", "assemble", "back_substitute"}


def test_run_budget_keeps_the_budget(tmp_path):
    out = tmp_path / "budget.json"
    assert main(["run", "pendulum", "--bodies", "40", "--steps", "60", "--method", "adaptive",
                 "--budget", "5", "--dwell", "0", "--json", str(out), "--no-progress"]) == 0
    data = json.loads(out.read_text())
    assert data["counters_mean"]["accelerated"] <= 5


@pytest.mark.parametrize("argv, message", [
    (["run", "pendulum", "--threshold", "1e-3"], "need --method adaptive, view-bvh or view-oq"),
    (["run", "pendulum", "--method", "adaptive"], "exactly one of threshold= or budget="),
])
def test_adaptive_option_errors(argv, message, capsys):
    assert main(argv + ["--no-progress", "--steps", "1"]) == 2
    assert message in capsys.readouterr().err


@pytest.mark.parametrize("method, extra", [
    ("view-bvh", ["--volume", "obb", "--estimate", "min"]),
    ("view-oq", ["--counting", "merged", "--resolution", "160x120"]),
])
def test_run_view_methods(method, extra, tmp_path):
    """Near, most joints move; 200 m away, (almost) everything is rigid."""
    means = []
    for distance in ("2", "200"):
        out = tmp_path / f"{method}{distance}.json"
        assert main(["run", "pendulum", "--bodies", "12", "--steps", "150", "--method", method,
                     "--threshold", "1e-3", "--camera-distance", distance, *extra,
                     "--json", str(out), "--no-progress"]) == 0
        data = json.loads(out.read_text())
        assert data["method"] == method and data["ms_per_phase_mean"]["visibility"] > 0
        assert data["params"]["camera_distance"] == float(distance)
        means.append(data["active_joints_mean"])
    assert means[0] > 4 and means[1] < 1, means


def test_bad_resolution(capsys):
    with pytest.raises(SystemExit):
        main(["run", "pendulum", "--method", "view-bvh", "--resolution", "0x5"])
    assert "--resolution: must be positive pixel counts" in capsys.readouterr().err
