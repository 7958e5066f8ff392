"""The command line (vdad.cli)."""

import json
import re
import subprocess
import sys
from pathlib import Path

import pytest

from vdad.cli import in_cli_terms, main


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


def test_run_with_implicit_damping(tmp_path, capsys):
    out = tmp_path / "run.json"
    assert main(["run", "falling_character", "--steps", "20", "--implicit-damping",
                 "--json", str(out), "--no-progress"]) == 0
    assert json.loads(out.read_text())["implicit_damping"] is True
    assert "semi-implicit, implicit damping)" in capsys.readouterr().out
    assert main(["run", "pendulum", "--steps", "2", "--integrator", "rk4",
                 "--implicit-damping", "--no-progress"]) == 2
    assert "--implicit-damping) applies to integrator 'semi-implicit'" in \
        capsys.readouterr().err


def test_run_times_the_steps_after_the_first(tmp_path, capsys, monkeypatch):
    """The first step loads or compiles the kernels (0.6 s to minutes): ms per step
    leaves it out and the summary reports it apart."""
    import time

    from vdad.simulator import Simulator

    step, calls = Simulator.step, []

    def slow_first(self, n=1):
        if not calls:
            time.sleep(0.5)
        calls.append(n)
        return step(self, n)

    monkeypatch.setattr(Simulator, "step", slow_first)
    out = tmp_path / "run.json"
    assert main(["run", "pendulum", "--bodies", "3", "--steps", "200", "--json", str(out),
                 "--no-progress"]) == 0
    data = json.loads(out.read_text())
    assert calls[0] == 1 and sum(calls) == 200
    assert data["first_step_s"] >= 0.5
    assert 0 < data["ms_per_step"] < 1e3 * 0.5 / 199      # the sleep is not in it
    assert "after a first step of 0.5" in capsys.readouterr().out


@pytest.mark.parametrize("argv", [["--help"], ["run", "--help"], ["render", "--help"],
                                  ["reproduce", "--help"], ["compile", "--help"]])
def test_help(argv, capsys):
    with pytest.raises(SystemExit) as exc:
        main(argv)
    assert exc.value.code == 0
    assert "usage: vdad" in capsys.readouterr().out


@pytest.mark.parametrize("argv, message", [
    (["run", "pendulum", "--steps", "0"], "--steps: must be a positive integer"),
    (["run", "pendulum", "--dt", "nan"], "--dt: must be a positive number"),
    (["run", "pendulum", "--method", "adaptive", "--weights", "-1"],
     "--weights: must be a positive number, got -1"),
    (["run", "pendulum", "--method", "adaptive", "--velocity-weights", "nan"],
     "--velocity-weights: must be a positive number, got nan"),
    (["run", "box"], "invalid choice: 'box'"),
    (["run", "nowhere/robot.xml"], "MuJoCo model file not found: nowhere/robot.xml"),
])
def test_bad_arguments(argv, message, capsys):
    with pytest.raises(SystemExit) as exc:
        main(argv)
    assert exc.value.code == 2
    assert message in capsys.readouterr().err


@pytest.mark.parametrize("where", ["missing/x.json", "", "."])
def test_unwritable_json_is_a_clear_error_before_the_run(where, tmp_path, capsys,
                                                         monkeypatch):
    monkeypatch.chdir(tmp_path)
    assert main(["run", "pendulum", "--bodies", "2", "--steps", "2", "--no-progress",
                 "--json", where]) == 2
    out = capsys.readouterr()
    assert f"vdad: error: --json {where!r}: give a file name in an existing folder" in out.err
    assert "ms per step" not in out.out                      # nothing was simulated


@pytest.mark.parametrize("out, message", [
    ("x.jpg", "the suffix must be one of .png, .gif, .mp4"),
    ("missing/x.png", "folder 'missing' does not exist"),
])
def test_bad_render_output_is_an_error_before_the_run(out, message, tmp_path, capsys,
                                                      monkeypatch):
    import vdad.cli

    monkeypatch.chdir(tmp_path)
    monkeypatch.setattr(vdad.cli, "make_scene", lambda *a, **k: pytest.fail("simulated"))
    assert main(["render", "pendulum", "--out", out, "--no-progress"]) == 2
    assert message in capsys.readouterr().err


def test_reproduce_checks_the_scheduler_before_writing(tmp_path, capsys):
    pytest.importorskip("distributed")
    assert main(["reproduce", "--quick", "--out", str(tmp_path / "res"), "--scheduler", " ",
                 "--no-progress"]) == 2
    assert "scheduler must be a Dask scheduler address" in capsys.readouterr().err
    assert not (tmp_path / "res").exists()


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
    assert data["method"] == "adaptive" and data["options"]["threshold"] == 1e-4
    assert 0 < data["active_joints_mean"] < 40
    counters = data["counters_mean"]
    for key in ("accelerated", "assembled", "back_substituted", "front", "force_update",
                "node_visits"):
        assert counters[key] >= 0
    assert counters["assembled"] == data["active_joints_mean"]
    assert set(data["ms_per_phase_mean"]) >= {"forces", "dynamics", "integrate", "region"}


def test_run_budget_keeps_the_budget(tmp_path):
    out = tmp_path / "budget.json"
    assert main(["run", "pendulum", "--bodies", "40", "--steps", "60", "--method", "adaptive",
                 "--budget", "5", "--dwell", "0", "--json", str(out), "--no-progress"]) == 0
    data = json.loads(out.read_text())
    assert data["counters_mean"]["accelerated"] <= 5


def test_run_metric_weights_reach_the_metric(tmp_path):
    """--weights scales the acceleration metric (and the velocity metric, unless
    --velocity-weights is given): heavier weights keep more joints active."""
    means = {}
    for name, extra in (("default", []), ("heavy", ["--weights", "1e4"]),
                        ("both", ["--weights", "1e4", "--velocity-weights", "2"])):
        out = tmp_path / f"{name}.json"
        assert main(["run", "pendulum", "--bodies", "12", "--steps", "300", "--method",
                     "adaptive", "--threshold", "1e-5", *extra, "--json", str(out),
                     "--no-progress"]) == 0
        data = json.loads(out.read_text())
        means[name] = data["active_joints_mean"]
        options = data["options"]
        if name == "default":
            assert "weights" not in options and "velocity_weights" not in options
    assert options["weights"] == 1e4 and options["velocity_weights"] == 2.0
    assert means["heavy"] > means["default"] + 1


@pytest.mark.parametrize("argv, message", [
    (["run", "pendulum", "--threshold", "1e-3"],
     "--threshold applies to --method adaptive, --method view-bvh or --method view-oq, not to "
     "--method dca"),
    (["run", "pendulum", "--method", "adaptive", "--threshold", "1e-3", "--budget", "3"],
     "exactly one of --threshold or --budget"),
    (["run", "pendulum", "--method", "adaptive", "--kappa", "0.5"], "--kappa must be >= 1"),
    (["run", "pendulum", "--weights", "2"],
     "--weights applies to --method adaptive, --method view-bvh, --method view-oq, --method "
     "lod-distance or --method sleeping, not to --method dca"),
    (["run", "pendulum", "--method", "adaptive", "--volume", "obb"],
     "--volume applies to --method view-bvh, not to --method adaptive"),
    (["run", "pendulum", "--method", "view-bvh", "--counting", "merged"],
     "--counting applies to --method view-oq, not to --method view-bvh"),
    (["run", "pendulum", "--sleep-time", "2"], "--sleep-time applies to --method sleeping"),
    (["run", "pendulum", "--method", "adaptive", "--coverage-every", "2"],
     "--coverage-every applies to a coverage estimate"),
])
def test_adaptive_option_errors(argv, message, capsys):
    """Errors speak in the CLI's options, not in Python keywords."""
    assert main(argv + ["--no-progress", "--steps", "1"]) == 2
    err = capsys.readouterr().err
    assert message in err
    assert not re.search(r"\w=|_|method '", err), err                # no Python keywords


@pytest.mark.parametrize("method, extra", [
    ("view-bvh", ["--volume", "obb", "--estimate", "min"]),
    ("view-bvh", ["--pixels", "moved"]),
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
        phases = data["ms_per_phase_mean"]
        assert data["method"] == method and phases["steps"] > 0
        # rendered counts are timed from Python; bounding volumes run inside the
        # compiled steps, whose time is theirs
        assert (phases["visibility"] > 0) == (method == "view-oq"), phases
        assert data["params"]["camera_distance"] == float(distance)
        given = dict(zip(extra[::2], extra[1::2], strict=True))
        assert all(data["options"][k[2:]] == given[k] for k in ("--pixels", "--volume")
                   if k in given)
        means.append(data["active_joints_mean"])
    assert means[0] > 4 and means[1] < 1, means


def test_bad_resolution(capsys):
    with pytest.raises(SystemExit):
        main(["run", "pendulum", "--method", "view-bvh", "--resolution", "0x5"])
    assert "--resolution: must be positive pixel counts" in capsys.readouterr().err


@pytest.mark.parametrize("argv", [
    ["dog_puppet", "--method", "view-oq", "--counting", "merged", "--threshold", "0.03"],
    ["hanging_dogs", "--dogs", "2", "--seed", "5", "--method", "adaptive", "--threshold", "1e-6"],
    ["falling_character", "--method", "view-bvh", "--threshold", "0.01", "--camera-distance",
     "6"],
])
def test_run_every_scene(argv, tmp_path):
    out = tmp_path / "run.json"
    assert main(["run", *argv, "--steps", "30", "--json", str(out), "--no-progress"]) == 0
    data = json.loads(out.read_text())
    assert data["scene"] == argv[0] and data["steps"] == 30
    assert 0 < data["active_joints_mean"] <= data["joints"]
    if argv[0] == "hanging_dogs":
        assert data["bodies"] == 32 and data["params"]["seed"] == 5


@pytest.mark.parametrize("argv, message", [
    (["run", "dog_puppet", "--bodies", "3"], "scene 'dog_puppet' does not take --bodies"),
    (["run", "pendulum", "--dogs", "3"], "scene 'pendulum' does not take --dogs"),
    (["run", str(Path(__file__).parent / "data" / "arm.xml"), "--bodies", "3"],
     "arm.xml' does not take --bodies"),
    (["render", "pendulum", "--out", "x.bmp", "--steps", "1"], "suffix must be one of"),
])
def test_scene_option_errors(argv, message, capsys, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    assert main([*argv, "--no-progress"]) == 2
    assert message in capsys.readouterr().err


def test_render_gif_with_groups_and_active_joints(tmp_path):
    from PIL import Image

    out = tmp_path / "pendulum.gif"
    assert main(["render", "pendulum", "--bodies", "8", "--method", "adaptive", "--threshold",
                 "1e-4", "--steps", "40", "--every", "10", "--size", "160x120",
                 "--show-active", "--out", str(out), "--no-progress"]) == 0
    with Image.open(out) as gif:
        assert gif.n_frames >= 2 and gif.size == (160, 120)


def test_render_strip_at_two_distances(tmp_path):
    from PIL import Image

    out = tmp_path / "strip.png"
    assert main(["render", "falling_character", "--method", "view-bvh", "--threshold", "0.01",
                 "--steps", "40", "--strip", "3", "--distances", "3,30", "--size", "120x90",
                 "--out", str(out), "--no-progress"]) == 0
    with Image.open(out) as strip:
        width, height = strip.size
    assert width >= 3 * 120 and height >= 2 * 90                 # 3 frames, 2 distances


def test_render_frames_and_mp4(tmp_path):
    assert main(["render", "pendulum", "--bodies", "4", "--steps", "20", "--every", "10",
                 "--size", "64x48", "--out", str(tmp_path / "f.png"), "--no-progress"]) == 0
    assert sorted(p.name for p in tmp_path.iterdir()) == ["f_0000.png", "f_0001.png",
                                                          "f_0002.png"]
    assert main(["render", "pendulum", "--bodies", "4", "--steps", "20", "--every", "5",
                 "--size", "64x48", "--out", str(tmp_path / "f.mp4"), "--no-progress"]) == 0
    assert (tmp_path / "f.mp4").stat().st_size > 0


def test_run_baselines(tmp_path):
    far = tmp_path / "far.json"
    assert main(["run", "pendulum", "--bodies", "6", "--steps", "60", "--method",
                 "lod-distance", "--distance", "0.01", "--dwell", "0", "--json", str(far),
                 "--no-progress"]) == 0
    assert json.loads(far.read_text())["counters_mean"]["active_joints"] < 2
    sleep = tmp_path / "sleep.json"
    assert main(["run", "pendulum", "--bodies", "6", "--steps", "60", "--method", "sleeping",
                 "--sleep-speed", "0.1", "--sleep-time", "0.2", "--json", str(sleep),
                 "--no-progress"]) == 0
    assert json.loads(sleep.read_text())["options"] == {
        "threshold": 0.0, "sleep_speed": 0.1, "sleep_time": 0.2, "kappa": 4.0, "dwell": 10,
        "policy": "momentum", "lookahead": True, "lookahead_every": 1, "drop": "lock",
        "metric": "direct",
        "energy": "free", "coverage_every": 17}                  # once per 60 Hz frame


@pytest.mark.parametrize("argv, message", [
    (["run", "pendulum", "--method", "lod-distance", "--budget", "3"],
     "--budget applies to --method adaptive, --method view-bvh or --method view-oq, not to "
     "--method lod-distance (a baseline runs at threshold 0)"),
    (["run", "pendulum", "--method", "sleeping", "--threshold", "0.1"],
     "--threshold applies to"),
    (["run", "pendulum", "--method", "sleeping", "--distance", "3"],
     "--distance applies to --method lod-distance, not to --method sleeping"),
])
def test_baseline_option_errors(argv, message, capsys):
    assert main(argv + ["--no-progress"]) == 2
    assert message in capsys.readouterr().err


@pytest.mark.parametrize("message, expected", [
    ("threshold= applies to method='adaptive', not to method='dca'",
     "--threshold applies to --method adaptive, not to --method dca"),
    ("kappa must be >= 1, got 0.5", "--kappa must be >= 1, got 0.5"),
    ("sleep_time must be positive", "--sleep-time must be positive"),
    ("coverage_every= and tree= do not apply", "--coverage-every and tree= do not apply"),
    ("velocity_weights= and weights=", "--velocity-weights and --weights"),
    ("the threshold of 0 and kappa", "the threshold of 0 and kappa"),   # prose stays prose
])
def test_errors_in_cli_terms(message, expected):
    assert in_cli_terms(message) == expected


ARM = str(Path(__file__).parent / "data" / "arm.xml")


@pytest.mark.parametrize("method", ["dca", "adaptive", "view-bvh", "view-oq", "lod-distance",
                                    "sleeping"])
def test_run_a_mujoco_model_file_with_each_method(method, tmp_path):
    out = tmp_path / "arm.json"
    assert main(["run", ARM, "--method", method, "--steps", "30", "--json", str(out),
                 "--no-progress"]) == 0
    data = json.loads(out.read_text())
    assert data["scene"] == "arm" and data["bodies"] == 3 and data["dofs"] == 5
    assert data["steps"] == 30 and data["params"]["path"] == ARM
    assert data["final_q"] != mujoco_qpos0()


def mujoco_qpos0():
    import mujoco

    return mujoco.MjModel.from_xml_path(ARM).qpos0.tolist()


def test_render_a_mujoco_model_file(tmp_path):
    from PIL import Image

    out = tmp_path / "arm.png"
    assert main(["render", ARM, "--steps", "20", "--strip", "2", "--size", "80x60",
                 "--out", str(out), "--no-progress"]) == 0
    with Image.open(out) as strip:
        assert strip.size[0] >= 2 * 80
