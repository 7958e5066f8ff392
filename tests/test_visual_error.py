"""Measured visual error of a simplified simulation (vdad.visual_error, Kim 2008 §3.1).

The rendered measure draws on EGL (Mesa llvmpipe in CI); nothing is skipped.
"""

import numpy as np
import pytest
import trimesh
from imports import loaded

import vdad
from vdad import Body, Geom, InputError, Joint, Model
from vdad.camera import Camera
from vdad.scenes import pendulum
from vdad.visual_error import (
    ErrorTrace,
    StepTimer,
    Trajectory,
    VisualError,
    measure,
    poses,
    record,
    reference_simulator,
    screen_displacement,
    surface_points,
)

CAMERA = Camera(position=(3.0, 0.0, 0.0), target=(0.0, 0.0, 0.0))   # 320 x 240, yfov 60 deg


@pytest.fixture(scope="module")
def scene():
    return pendulum(n_bodies=5)


def flat_model():
    """One free body carrying a flat 5 x 5 grid of vertices in its y-z plane."""
    y, z = np.meshgrid(np.linspace(-0.3, 0.3, 5), np.linspace(-0.2, 0.2, 5))
    vertices = np.column_stack([np.zeros(25), y.ravel(), z.ravel()])
    cells = (np.arange(4)[:, None] * 5 + np.arange(4)).ravel()
    faces = np.concatenate([np.column_stack([cells, cells + 1, cells + 5]),
                            np.column_stack([cells + 1, cells + 6, cells + 5])])
    mesh = trimesh.Trimesh(vertices, faces, process=False)
    return Model([Body("plate", 1.0, geoms=(Geom("mesh", mesh=mesh),))],
                 [Joint("free", None, "plate", "free")])


def free_q(position):
    return np.array([*position, 1.0, 0.0, 0.0, 0.0])


def assert_all_zero(trace):
    for name in ("mean_px", "max_px", "differing_pixels"):
        np.testing.assert_array_equal(getattr(trace, name), 0.0)


def test_identical_runs_measure_exactly_zero(scene):
    trace, info = measure(scene.simulator(method="dca"), 60, every=10)
    assert len(trace.t) == 6
    np.testing.assert_allclose(trace.t, 0.01 * np.arange(1, 7), rtol=1e-12)
    assert_all_zero(trace)
    assert info["steps"] == 60 and info["failure"] is None
    assert info["active_joints"] == scene.model.nb
    assert info["node_visits"] == 2 * scene.model.nb            # a leaf and a joint node each
    assert info["ms_per_step"] > 0 and info["reference_ms_per_step"] > 0

    reference = record(scene.simulator(method="dca"), 60, every=10)
    trace, info = measure(scene.simulator(method="dca"), 60, every=10, reference=reference,
                          progress=True)
    assert_all_zero(trace)
    assert info["reference_ms_per_step"] == reference.ms_per_step


def test_perturbed_and_adaptive_runs_measure_positive_errors(scene):
    reference = record(scene.simulator(), 100, every=20)
    perturbed = pendulum(n_bodies=5, angle=1.01).simulator()
    trace, _ = measure(perturbed, 100, every=20, reference=reference)
    assert np.all(trace.mean_px > 0) and np.all(trace.differing_pixels > 0)
    assert np.all(trace.max_px >= trace.mean_px)

    trace, info = measure(scene.simulator(method="adaptive", threshold=1e-2), 200, every=20)
    summary = trace.summary()
    assert summary["frames"] == 10 and info["failure"] is None
    assert summary["mean_px"]["max"] > 1 and summary["differing_pixels"]["max"] > 100
    assert info["active_joints"] < scene.model.nb
    assert 0 < info["node_visits"] < 2 * scene.model.nb


def rotated(model, angle):
    q = model.q_neutral.copy()
    q[0] = angle
    return q


def test_both_measures_grow_with_the_rotation_and_shrink_with_distance(scene):
    model = scene.model
    far = pendulum(n_bodies=5, camera_distance=2 * scene.params["camera_distance"]).camera
    errors = {}
    for name, camera in (("near", scene.camera), ("far", far)):
        with VisualError(model, camera) as error:
            errors[name] = [error(0.0, model.q_neutral, rotated(model, a))
                            for a in (0.01, 0.03, 0.1, 0.3)]
    for name in ("mean_px", "max_px", "differing_pixels"):
        for rows in errors.values():
            values = [e[name] for e in rows]
            assert np.all(np.diff(values) > 0), (name, values)
        assert all(f[name] < n[name] for f, n in zip(errors["far"], errors["near"], strict=True))

    # a camera path is evaluated at the time of the frame
    def path(t):
        return scene.camera if t < 1 else far

    with VisualError(model, path) as error:
        assert error(2.0, model.q_neutral, rotated(model, 0.1)) == errors["far"][2]
        assert error(0.0, model.q_neutral, rotated(model, 0.1)) == errors["near"][2]


def test_translation_parallel_to_the_image_plane_is_exact():
    model = flat_model()
    d, depth = 0.07, 2.5                          # the plate is at x = 0.5, CAMERA at x = 3
    q_ref, q = free_q((0.5, 0.0, 0.0)), free_q((0.5, d, 0.0))
    for resolution, scale in ((None, 1.0), ((640, 480), 2.0)):
        error = VisualError(model, CAMERA, resolution=resolution, pixels=False)
        e = error(0.0, q_ref, q)
        expected = scale * CAMERA.focal * d / depth
        assert e["differing_pixels"] is None
        np.testing.assert_allclose([e["mean_px"], e["max_px"]], expected, rtol=1e-9)


def test_points_behind_the_camera_or_off_screen_are_not_counted():
    X_ref = np.array([[0, 0, 0],          # counted: on screen in both
                      [4, 0, 0],          # behind the camera
                      [0, 10, 0],         # off screen in both
                      [0, 0, 0.1],        # counted: leaves the screen
                      [0, 0, -0.1],       # crosses the near plane
                      [0, -5, 0]], float)  # counted: enters the screen
    X = np.array([[0, 0.01, 0], [4, 0.5, 0], [0, 11, 0], [0, 5, 0.1], [2.99, 0, -0.1],
                  [0, 0.02, 0]], float)
    (xy_ref, d_ref), (xy, d) = CAMERA.project(X_ref), CAMERA.project(X)
    assert d_ref[1] < 0 and d[4] < CAMERA.znear < d_ref[4]
    moved = np.linalg.norm(xy - xy_ref, axis=1)[[0, 3, 5]]
    np.testing.assert_allclose(screen_displacement(CAMERA, X_ref, X),
                               (moved.mean(), moved.max()), rtol=1e-12)
    assert screen_displacement(CAMERA, X_ref[[1, 2, 4]], X[[1, 2, 4]]) == (0.0, 0.0)
    assert screen_displacement(CAMERA, np.zeros((0, 3)), np.zeros((0, 3))) == (0.0, 0.0)


def test_surface_points_lie_on_the_geoms(scene):
    model = Model([*scene.model.bodies, Body("empty", 1.0)],
                  [*scene.model.joints, Joint("j", None, "empty", "free")])
    body, local = surface_points(model, per_body=20)
    assert body.dtype == np.int64 and local.shape == (len(body), 3)
    np.testing.assert_array_equal(np.bincount(body, minlength=model.nb), [20] * 5 + [0])
    assert len(np.unique(local[body == 0], axis=0)) == 20
    again = surface_points(model, per_body=20)
    np.testing.assert_array_equal(again[1], local)
    # each link is a capsule of radius r about the segment z in [-(L - r), -r]
    L, r = scene.params["link_length"], scene.params["radius"]
    closest = local.copy()
    closest[:, :2] = 0
    closest[:, 2] = np.clip(closest[:, 2], -(L - r), -r)
    np.testing.assert_allclose(np.linalg.norm(local - closest, axis=1), r, rtol=1e-9)
    body, _ = surface_points(model, per_body=10_000)
    assert 20 < np.bincount(body)[0] < 10_000


def test_poses_match_the_simulator(scene):
    sim = scene.simulator(method="dca").step(5)
    for a, b in zip(poses(scene.model, sim.q), sim.body_poses(), strict=True):
        np.testing.assert_array_equal(a, b)


def test_reference_simulator_copies_the_initial_state(scene):
    sim = scene.simulator(method="adaptive", threshold=1e-3, integrator="rk4")
    ref = reference_simulator(sim)
    assert ref.method == "dca" and ref.dt == sim.dt and ref.integrator_name == "rk4"
    assert ref.tree is sim.tree and ref.camera is sim.camera and ref.model is sim.model
    np.testing.assert_array_equal(ref.q, sim.q)
    assert ref.q is not sim.q and ref.qd is not sim.qd
    sim.step()
    with pytest.raises(InputError, match="same initial state"):
        reference_simulator(sim)
    damped = scene.simulator(method="adaptive", threshold=1e-3, implicit_damping=True)
    assert reference_simulator(damped).implicit_damping


def test_trajectory_round_trip_and_frame_checks(scene, tmp_path):
    trajectory = record(scene.simulator(), 20, every=5)
    assert trajectory.q.shape == (4, scene.model.nq)
    np.testing.assert_allclose(trajectory.t, [0.005, 0.01, 0.015, 0.02], rtol=1e-12)
    path = tmp_path / "reference.npz"
    trajectory.save(path)
    loaded = Trajectory.load(path)
    for name in ("t", "q"):
        np.testing.assert_array_equal(getattr(loaded, name), getattr(trajectory, name))
    assert loaded.ms_per_step == trajectory.ms_per_step

    with pytest.raises(InputError, match="frame times"):
        measure(scene.simulator(), 20, every=10, reference=trajectory)     # every differs
    with pytest.raises(InputError, match="frame times"):
        measure(scene.simulator(), 40, every=5, reference=trajectory)      # too short
    with pytest.raises(InputError, match="frame times"):
        measure(pendulum(n_bodies=5, dt=2e-3).simulator(), 20, every=5, reference=trajectory)
    with pytest.raises(InputError, match="multiple of every"):
        record(scene.simulator(), 12, every=5)


def test_bad_arguments_raise_input_error(scene):
    model = scene.model
    for per_body in (0, -3, 2.5, "many"):
        with pytest.raises(InputError, match="per_body"):
            surface_points(model, per_body=per_body)
        with pytest.raises(InputError, match="per_body"):
            VisualError(model, CAMERA, per_body=per_body, pixels=False)
    with pytest.raises(InputError, match="q must have shape"):
        poses(model, np.zeros(model.nq + 1))
    error = VisualError(model, CAMERA, pixels=False)
    with pytest.raises(InputError, match="q_ref"):
        error(0.0, np.zeros(2), model.q_neutral)
    with pytest.raises(InputError, match="resolution"):
        VisualError(model, CAMERA, resolution=(320, 0))
    with pytest.raises(InputError, match="camera"):
        VisualError(model, "front")
    with pytest.raises(InputError, match="model"):
        VisualError("pendulum", CAMERA)
    with pytest.raises(InputError, match="camera"):
        measure(vdad.Simulator(model), 10)
    with pytest.raises(InputError, match="reference"):
        measure(scene.simulator(), 10, reference=np.zeros((10, model.nq)))
    with pytest.raises(InputError, match="steps"):
        measure(scene.simulator(), 0)
    with pytest.raises(InputError, match="X_ref"):
        screen_displacement(CAMERA, np.zeros((3, 2)), np.zeros((3, 3)))
    with pytest.raises(InputError, match="a trajectory needs"):
        Trajectory(np.zeros(3), np.zeros((2, 5)))


def test_error_trace_summary_and_csv(tmp_path):
    trace = ErrorTrace(t=[0.1, 0.2, 0.3], mean_px=[1.0, 2.0, 6.0], max_px=[2.0, 5.0, 8.0],
                       differing_pixels=[10, 0, 20])
    assert trace.summary() == {
        "frames": 3,
        "mean_px": {"mean": 3.0, "max": 6.0, "sum": 9.0},
        "max_px": {"mean": 5.0, "max": 8.0, "sum": 15.0},
        "differing_pixels": {"mean": 10.0, "max": 20.0, "sum": 30.0}}
    path = tmp_path / "errors.csv"
    trace.to_csv(path)
    lines = path.read_text().splitlines()
    assert lines[0] == "t,mean_px,max_px,differing_pixels" and len(lines) == 4
    np.testing.assert_array_equal(np.loadtxt(path, delimiter=",", skiprows=1)[:, 3],
                                  [10, 0, 20])
    unmeasured = ErrorTrace([0.1], [1.0], [1.0], [np.nan]).summary()
    assert unmeasured["differing_pixels"] == {"mean": None, "max": None, "sum": None}


def test_a_diverging_run_stops_with_its_frames_so_far(scene):
    def nan_after(t, q, qd):
        return np.full((scene.model.nb, 6), np.nan) if t > 0.0245 else None

    reference = record(scene.simulator(), 100, every=10)
    sim = vdad.Simulator(scene.model, scene.q0, external=nan_after, camera=scene.camera)
    trace, info = measure(sim, 100, every=10, reference=reference, pixels=False)
    assert "step 26" in info["failure"] and "external(t, q, qd) is not finite" in info["failure"]
    assert len(trace.t) == 2 and info["steps"] == 25
    assert_all_zero(ErrorTrace(trace.t, trace.mean_px, trace.max_px, [0, 0]))
    assert np.all(np.isnan(trace.differing_pixels))
    diverging = vdad.Simulator(scene.model, scene.q0, external=nan_after)
    with pytest.raises(vdad.errors.SimulationError, match="step 26"):     # record stops too
        record(diverging, 100, every=10)

    def broken(t, q, qd):
        raise RuntimeError("broken force")

    sim = vdad.Simulator(scene.model, scene.q0, external=broken, camera=scene.camera)
    with pytest.raises(RuntimeError, match="broken force"):
        measure(sim, 10, every=10, reference=reference, pixels=False)


def test_the_displacement_measure_needs_no_opengl():
    code = ("from vdad.scenes import pendulum; "
            "from vdad.visual_error import VisualError; s = pendulum(n_bodies=3); "
            "q = s.model.q_neutral; VisualError(s.model, s.camera, pixels=False)(0.0, q, q)")
    assert loaded(code, ("pyrender", "OpenGL")) == "[]"


@pytest.mark.parametrize("flag", ["no", 1, None, "False"])
def test_flags_must_be_booleans(scene, flag):
    with pytest.raises(InputError, match=r"pixels must be True or False, got"):
        measure(scene.simulator(), 2, pixels=flag)
    with pytest.raises(InputError, match=r"progress must be True or False, got"):
        measure(scene.simulator(), 2, pixels=False, progress=flag)
    with pytest.raises(InputError, match=r"progress must be True or False, got"):
        record(scene.simulator(), 2, progress=flag)
    with pytest.raises(InputError, match=r"pixels must be True or False, got"):
        VisualError(scene.model, CAMERA, pixels=flag)


def test_numpy_booleans_are_flags(scene):
    assert VisualError(scene.model, CAMERA, pixels=np.False_).pixels is False
    trace, _ = measure(scene.simulator(), 2, pixels=np.False_, progress=np.False_)
    assert np.all(np.isnan(trace.differing_pixels))


@pytest.mark.parametrize("ms, message", [
    ("x", "ms_per_step must be a real number"), ([1, 2], "must be a single number"),
    (-1.0, "must be >= 0"), (np.inf, "must be finite"), (None, "ms_per_step must be a real"),
    (True, r"ms_per_step must be a real number \(or numbers\), got a boolean")])
def test_trajectory_checks_ms_per_step(ms, message):
    with pytest.raises(InputError, match=message):
        Trajectory([0.1, 0.2], np.zeros((2, 3)), ms)


def test_step_timer_leaves_out_the_first_frame():
    """The first frame of a process loads or compiles the kernels: the time per
    step is that of the later frames (all of them when there is one)."""
    import time

    sim = pendulum(3).simulator()
    timer = StepTimer()
    with timer.frame(sim):
        time.sleep(0.3)
        sim.step(4)
    assert np.isclose(timer.ms_per_step, 1e3 * timer.frames[0][0] / 4)
    for _ in range(3):
        with timer.frame(sim):
            sim.step(4)
    assert [n for _, n in timer.frames] == [4, 4, 4, 4]
    assert timer.ms_per_step < 1e3 * 0.3 / 12
    assert np.isclose(timer.ms_per_step, 1e3 * sum(s for s, _ in timer.frames[1:]) / 12)


def test_trajectory_ms_per_step_may_be_unknown():
    assert np.isnan(Trajectory([0.1], np.zeros((1, 3))).ms_per_step)
    assert np.isnan(Trajectory([0.1], np.zeros((1, 3)), np.nan).ms_per_step)
    trajectory = Trajectory([0.1], np.zeros((1, 3)), np.float32(2.5))
    assert type(trajectory.ms_per_step) is float and trajectory.ms_per_step == 2.5


@pytest.mark.parametrize("t, culprit", [([1.0, 0.0], r"t\[1\] = 0.0 after t\[0\] = 1.0"),
                                        ([0.1, 0.2, 0.2], r"t\[2\] = 0.2 after t\[1\] = 0.2")])
def test_trajectory_frames_are_at_increasing_times(t, culprit):
    with pytest.raises(InputError, match=f"t must increase from frame to frame, got {culprit}"):
        Trajectory(t, np.zeros((len(t), 3)))


def test_trajectory_files_that_cannot_be_read_or_written(tmp_path):
    trajectory = Trajectory([0.1, 0.2], np.zeros((2, 3)), 1.0)
    missing = tmp_path / "nowhere.npz"
    with pytest.raises(InputError, match=r"cannot read a Trajectory from .*nowhere\.npz.*: "
                                         r"No such file or directory"):
        Trajectory.load(missing)
    with pytest.raises(InputError, match=r"cannot read a Trajectory from .*: Is a directory"):
        Trajectory.load(tmp_path)
    text = tmp_path / "notes.txt"
    text.write_text("not an archive\n")
    with pytest.raises(InputError, match=r"notes\.txt' is not a Trajectory written by "
                                         r"Trajectory.save: it is not an \.npz archive"):
        Trajectory.load(text)
    broken = tmp_path / "broken.npz"
    broken.write_bytes(b"PK\x03\x04 truncated")
    with pytest.raises(InputError, match=r"broken\.npz' .*not an \.npz archive"):
        Trajectory.load(broken)
    array = tmp_path / "array.npy"
    np.save(array, np.zeros(3))
    with pytest.raises(InputError, match=r"array\.npy' .*one array \(\.npy\)"):
        Trajectory.load(array)
    other = tmp_path / "other.npz"
    np.savez(other, t=np.zeros(2))
    with pytest.raises(InputError, match=r"other\.npz' .*lacks \['ms_per_step', 'q'\]"):
        Trajectory.load(other)
    backwards = tmp_path / "backwards.npz"
    np.savez(backwards, t=np.array([0.2, 0.1]), q=np.zeros((2, 3)), ms_per_step=1.0)
    with pytest.raises(InputError, match=r"backwards\.npz' .*: t must increase"):
        Trajectory.load(backwards)
    with pytest.raises(InputError, match=r"cannot write the Trajectory to .*no_dir.*x\.npz.*: "
                                         r"No such file or directory"):
        trajectory.save(tmp_path / "no_dir" / "x.npz")
    for call in (trajectory.save, Trajectory.load):
        with pytest.raises(InputError, match="path must be a file path .*got NoneType"):
            call(None)


def test_error_trace_checks_its_columns(tmp_path):
    with pytest.raises(InputError, match="t must be a real number .*got a string"):
        ErrorTrace(["a"], [0], [0], [0])
    with pytest.raises(InputError, match="t must be finite"):
        ErrorTrace([np.nan], [0], [0], [0])
    for name in ("mean_px", "max_px", "differing_pixels"):
        columns = dict(t=[0.1], mean_px=[1.0], max_px=[2.0], differing_pixels=[3])
        columns[name] = ["x"]
        with pytest.raises(InputError, match=f"{name} must be a real number"):
            ErrorTrace(**columns)
    with pytest.raises(InputError, match="arrays of one shape"):
        ErrorTrace([0.1, 0.2], [0], [0], [0])
    trace = ErrorTrace([0.1], [1.0], [2.0], [np.nan])
    with pytest.raises(InputError, match=r"cannot write the error trace to .*no_dir.*x\.csv.*: "
                                         r"No such file or directory"):
        trace.to_csv(tmp_path / "no_dir" / "x.csv")
    with pytest.raises(InputError, match="path must be a file path"):
        trace.to_csv(3)


def test_the_fastest_frames_of_repeated_timers():
    """Each frame at its fastest over the timers that reached it; the first
    timer's frames and step counts."""
    timers = [StepTimer() for _ in range(3)]
    timers[0].frames = [(0.5, 10), (0.2, 10), (0.4, 10)]
    timers[1].frames = [(0.3, 10), (0.6, 10), (0.1, 10)]
    timers[2].frames = [(0.9, 10)]                        # a repeat that stopped early
    fastest = StepTimer.fastest(timers)
    assert fastest.frames == [(0.3, 10), (0.2, 10), (0.1, 10)]
    assert np.isclose(fastest.ms_per_step, 1e3 * (0.2 + 0.1) / 20)


def test_repeated_timing_measures_the_same_frames_again(scene):
    """``repeats`` times the run again from ``restart()``: the error, steps and
    counts are those of the first pass, each frame is timed at its fastest."""
    made = []

    def restart():
        made.append(scene.simulator(method="adaptive", threshold=1e-3))
        return made[-1]

    once, info_once = measure(restart(), 120, every=20)
    again, info = measure(restart(), 120, every=20, repeats=3, restart=restart)
    assert len(made) == 4                                 # 1 + 1 + 2 restarts
    for name in ("t", "mean_px", "max_px", "differing_pixels"):
        np.testing.assert_array_equal(getattr(again, name), getattr(once, name))
    assert info["steps"] == 120 and info["failure"] is None
    assert info["active_joints"] == info_once["active_joints"]
    assert all(s.step_count == 120 for s in made)         # every pass took every frame
    assert info["ms_per_step"] > 0 and info["reference_ms_per_step"] > 0


def test_repeated_timing_needs_a_restart_in_the_initial_state(scene):
    with pytest.raises(InputError, match="repeats=2 needs restart"):
        measure(scene.simulator(), 20, every=10, repeats=2)
    with pytest.raises(InputError, match="repeats"):
        measure(scene.simulator(), 20, every=10, repeats=0)
    with pytest.raises(InputError, match="restart must be a callable"):
        measure(scene.simulator(), 20, every=10, repeats=2, restart="again")

    def stepped():
        sim = scene.simulator()
        sim.step(3)
        return sim

    with pytest.raises(InputError, match=r"restart\(\) must return a simulator in the "
                                         r"measured one's initial state \(step 0"):
        measure(scene.simulator(), 20, every=10, repeats=2, restart=stepped)
    with pytest.raises(InputError, match=r"restart\(\) must be a vdad.Simulator"):
        measure(scene.simulator(), 20, every=10, repeats=2, restart=lambda: "sim")
