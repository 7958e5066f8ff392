"""The paper's scenes end to end (Kim 2008 §6.1): every scene with every method,
seeded repeatability, and the behaviour each scene must show."""

from dataclasses import replace
from pathlib import Path

import mujoco
import numpy as np
import pytest

from vdad import Simulator
from vdad.errors import InputError
from vdad.kinematics import world_poses
from vdad.quantities import kinetic_energy
from vdad.scenes import (
    SCENES,
    Scene,
    dog_puppet,
    falling_character,
    hanging_dogs,
    pendulum,
    rod,
    toy_dog,
)
from vdad.scenes.dogs import LEGS, PUPPET_PHASES, StickPath, default_stick_path
from vdad.scenes.mjcf import mjcf_scene
from vdad.simulator import DEFAULTS, LOD_PIXELS, METHODS, lod_distance

SMALL = {"pendulum": lambda: pendulum(n_bodies=20),
         "dog_puppet": dog_puppet,
         "hanging_dogs": lambda: hanging_dogs(n_dogs=4, columns=2),
         "falling_character": falling_character}
STEPS = 100


def test_every_scene_is_registered():
    assert set(SMALL) == set(SCENES)


@pytest.mark.parametrize("method", METHODS)
@pytest.mark.parametrize("name", sorted(SMALL))
def test_scene_runs_with_every_method_and_its_defaults(name, method):
    """Nothing but the method: the scene's calibrated defaults, then the generic ones."""
    scene = SMALL[name]()
    model = scene.model
    assert scene.q0.shape == (model.nq,) and scene.qd0.shape == (model.nv,)
    assert np.all(np.isfinite(scene.q0)) and scene.camera is not None
    assert scene.description and scene.params
    sim = scene.simulator(method=method)
    mine = scene.defaults.get(method, {})
    generic = {k: v for k, v in DEFAULTS.get(method, {}).items() if not callable(v)}
    assert sim.options == {} if method == "dca" else \
        sim.options.items() >= {**generic, **mine}.items()
    sim.step(STEPS)
    assert np.all(np.isfinite(sim.q)) and np.all(np.isfinite(sim.qd))
    assert sim.t == pytest.approx(STEPS * scene.dt)
    moved = np.abs(sim.q - scene.q0).max()
    assert moved > 1e-4                                  # the forces act
    if method != "dca":
        active = [s.active_joints for s in sim.history]
        assert len(active) == STEPS and 0 < np.mean(active) <= model.nb


def test_scene_defaults_give_way_to_the_callers_options():
    scene = falling_character()
    assert scene.defaults["adaptive"]["threshold"] != 1e-3
    assert scene.simulator(method="adaptive", threshold=1e-3).options["threshold"] == 1e-3
    budget = scene.simulator(method="adaptive", budget=5).options
    assert budget["budget"] == 5 and "threshold" not in budget
    assert scene.simulator(method="adaptive", threshold=None).options["threshold"] == \
        scene.defaults["adaptive"]["threshold"]                  # None: not given
    far = scene.simulator(method="lod-distance", distance=50.0).options
    assert far["distance"] == 50.0 and far["threshold"] == 0.0


def test_generic_lod_distance_from_the_camera():
    """Without a scene's default: the distance at which the model's largest
    articulated body (the straight 2 m chain) spans LOD_PIXELS pixels."""
    scene = pendulum(n_bodies=20)
    assert "lod-distance" not in scene.defaults
    sim = Simulator(scene.model, scene.q0, method="lod-distance", camera=scene.camera)
    size = 20 * 0.1                                     # capsules end at the joints
    assert sim.options["distance"] == pytest.approx(size * scene.camera.focal / LOD_PIXELS,
                                                    rel=1e-6)
    assert lod_distance(scene.model, scene.q0, scene.camera, pixels=8) == pytest.approx(
        sim.options["distance"] / 2)


@pytest.mark.parametrize("method, options, message", [
    ("adaptive", {"threshhold": 1e-5}, "unknown option threshhold=; method='adaptive' takes "
     "threshold=, budget=, weights="),
    ("dca", {"threshold": 1e-5}, "threshold= applies to method='adaptive', method='view-bvh' "
     "or method='view-oq', not to method='dca'"),
    ("dca", {"volumes": "obb"}, "unknown option volumes=; method='dca' takes no options"),
    ("view-oq", {"volume": "obb"}, "volume= applies to method='view-bvh', not to "
     "method='view-oq'"),
    ("sleeping", {"budget": 3}, "(a baseline runs at threshold 0)"),
])
def test_method_option_errors(method, options, message):
    scene = pendulum(n_bodies=3)
    with pytest.raises(InputError) as exc:
        scene.simulator(method=method, **options)
    assert message in str(exc.value)


def test_unknown_scene_default_method():
    scene = pendulum(n_bodies=3)
    with pytest.raises(InputError, match="unknown methods"):
        replace(scene, defaults={"adaptiv": {"threshold": 1.0}})


def test_the_paper_sizes():
    assert pendulum(n_bodies=300).model.nb == 300
    assert dog_puppet().model.nb == 16
    dogs = hanging_dogs()
    assert dogs.model.nb == 1600
    assert sum(model_nv == 6 for model_nv in dogs.model.nv_joint) == 100     # one free root each
    assert falling_character().model.nb == 29


def test_hundred_dogs_step():
    sim = hanging_dogs().simulator(method="view-oq")             # the scene's defaults
    assert sim.options["threshold"] == hanging_dogs().defaults["view-oq"]["threshold"]
    sim.step(2)
    assert np.all(np.isfinite(sim.q))


@pytest.mark.parametrize("build", [lambda seed: hanging_dogs(n_dogs=4, columns=2, seed=seed),
                                   lambda seed: falling_character(seed=seed)])
def test_seeded_runs_repeat_exactly(build):
    def run(seed):
        sim = build(seed).simulator(method="adaptive", threshold=1e-6)
        sim.step(300)
        return sim.q

    a, b, c = run(3), run(3), run(4)
    np.testing.assert_array_equal(a, b)
    assert np.abs(a - c).max() > 1e-6


def test_scene_arguments_are_checked():
    with pytest.raises(InputError, match="n_dogs"):
        hanging_dogs(n_dogs=0)
    with pytest.raises(InputError, match="floor_frequency"):
        falling_character(dt=0.01)
    with pytest.raises(InputError, match="stick"):
        dog_puppet(stick=3)
    with pytest.raises(InputError, match="increasing"):
        StickPath((0.0, 0.0), ((0, 0, 1), (1, 0, 1)))
    with pytest.raises(InputError, match="drag"):
        dog_puppet(drag=-1.0)


# --- the campaign's bad inputs: InputErrors naming the culprit --------------------------

BUILD = {"pendulum": lambda **kw: pendulum(3, **kw), "dog_puppet": dog_puppet,
         "hanging_dogs": lambda **kw: hanging_dogs(1, **kw),
         "falling_character": falling_character}


@pytest.mark.parametrize("resolution", [(0, 240), "320x240", (320.5, 240), (320,), None,
                                        (320, 240, 3), (1,), 320, (320, -1)])
@pytest.mark.parametrize("name", sorted(BUILD))
def test_every_scene_checks_its_resolution(name, resolution):
    assert set(BUILD) == set(SCENES)
    with pytest.raises(InputError, match="resolution") as exc:
        BUILD[name](resolution=resolution)
    assert "camera width" not in str(exc.value)


@pytest.mark.parametrize("name", sorted(BUILD))
def test_scene_resolution_reaches_the_camera(name):
    scene = BUILD[name](resolution=[160.0, 120])
    camera = scene.camera(0.0) if callable(scene.camera) else scene.camera
    assert (camera.width, camera.height) == (160, 120)
    assert scene.params["resolution"] == (160, 120)


@pytest.mark.parametrize("stick, message", [
    (lambda t: "x", r"stick\(t\) must be a real number .*a string"),
    (lambda t: np.full((6, 3), np.nan), r"stick\(t\) must be finite"),
    (lambda t: np.zeros((5, 3)), r"stick\(t\) must give the \(6, 3\) world points .*\(5, 3\)"),
    (lambda t: np.zeros(18), r"stick\(t\) must give the \(6, 3\)"),
    (lambda: np.zeros((6, 3)), r"stick\(t\) failed at t = 0: TypeError"),
    (lambda t: [[0, 0]] * 5 + [[0, 0, 0]], r"stick\(t\) must be a real number .*ragged"),
    ("stick", "stick must be a callable"),
])
def test_puppet_stick_is_checked(stick, message):
    with pytest.raises(InputError, match=message) as exc:
        dog_puppet(stick=stick)
    assert "rest_length" not in str(exc.value)


@pytest.mark.parametrize("seed", [-1, "abc", 1.5, True, None])
def test_puppet_seed_is_checked(seed):
    with pytest.raises(InputError, match="seed must be an integer >= 0"):
        dog_puppet(seed=seed)


@pytest.mark.parametrize("args, message", [
    (dict(times="ab", positions=((0, 0, 1),)), "times must be a real number .*a string"),
    (dict(times=(0.0,), positions="xyz"), "positions must be a real number .*a string"),
    (dict(times=(0.0,), positions=((0, 0, 1),), rock="x"), "rock must be a real number"),
    (dict(times=(0.0,), positions=((0, 0, 1),), rock=np.inf), "rock must be finite"),
    (dict(times=(0.0,), positions=((0, 0, 1),), rock_hz=np.nan), "rock_hz must be finite"),
    (dict(times=(0.0,), positions=((0, 0, 1),), rock_hz=-1.0), "rock_hz must be >= 0"),
    (dict(times=(0.0,), positions=((0, 0, 1),), rock=(0.1, 0.2)),
     "rock must be a single number"),
    (dict(times=(), positions=()), "stick path needs times \\(k,\\) and positions"),
])
def test_stick_path_checks_its_parameters(args, message):
    with pytest.raises(InputError, match=message):
        StickPath(**args)


def test_stick_path_stores_floats():
    path = StickPath(np.array([0, 1]), [[0, 0, 1], [1, 0, 1]], rock=0, rock_hz=2)
    assert path.times == (0.0, 1.0) and path.positions == ((0.0, 0.0, 1.0), (1.0, 0.0, 1.0))
    assert path.rock == 0.0 and path.rock_hz == 2.0
    np.testing.assert_allclose(path(0.5)[:, 0], 0.5 + np.array([0.15, -0.15, 0.09, 0.09,
                                                                 -0.09, -0.09]))
    assert default_stick_path() == default_stick_path()


@pytest.mark.parametrize("value, message", [
    (0, "torque_duration must be positive"), ("x", "torque_duration must be a real number"),
    (np.nan, "torque_duration must be finite"), ((0.1, 0.2), "torque_duration must be a single"),
])
def test_hanging_dogs_name_their_own_torque_duration(value, message):
    with pytest.raises(InputError, match=message):
        hanging_dogs(1, torque_duration=value)


def test_hanging_dogs_bound_the_torque_rate():
    with pytest.raises(InputError, match=r"torque_rate \* n_dogs = 2e\+06 pulses per second is "
                       r"too high: at most 1e\+06"):
        hanging_dogs(2, torque_rate=1e6)


@pytest.mark.parametrize("prefix", [None, 3, b"dog/", ["dog"]])
def test_toy_dog_prefix_is_a_string(prefix):
    with pytest.raises(InputError, match="prefix must be a string"):
        toy_dog(prefix=prefix)


def test_toy_dog_prefix_names_the_bodies():
    bodies, joints = toy_dog("rex/")
    assert bodies[0].name == "rex/torso" and joints[0].name == "rex/root"


@pytest.mark.parametrize("changes, message", [
    (dict(drop=-5), "drop must be >= 0, got -5"),
    (dict(drop="x"), "drop must be a real number"),
    (dict(lean=2.0), "lean must be within \\[-pi/2, pi/2\\] rad"),
    (dict(lean=np.nan), "lean must be finite"),
    (dict(scale=0), "scale must be positive"),
    (dict(joint_damping=-1), "joint_damping must be >= 0"),
    (dict(friction=-0.5), "friction must be >= 0"),
    (dict(camera_distance=-3), "camera_distance must be positive"),
    (dict(push=np.inf), "push must be finite"),
    (dict(camera_speed="fast"), "camera_speed must be a real number"),
])
def test_falling_character_rejects_geometry_that_makes_no_sense(changes, message):
    with pytest.raises(InputError, match=message):
        falling_character(**changes)


def test_falling_character_starts_above_the_floor():
    scene = falling_character(drop=0.0)
    contact = scene.forces.elements[0]
    low = contact.points(scene.forces.states_of(contact, scene.q0, scene.qd0))[0][:, 2]
    assert low.min() == pytest.approx(0.0, abs=1e-12)


@pytest.mark.parametrize("defaults, message", [
    ({"adaptive": 5}, "scene 'pendulum': defaults\\['adaptive'\\] must be a dict {option: value}, "
     "got 5"),
    ({"adaptive": None}, "defaults\\['adaptive'\\] must be a dict"),
    ({"adaptive": {1: 2}}, "defaults\\['adaptive'\\] must be a dict {option: value}"),
    (5, "scene 'pendulum': defaults must be a dict {method: {option: value}}, got int"),
    ([("adaptive", {})], "defaults must be a dict"),
    ({5: {}, "x": {}}, "defaults for unknown methods \\[5, 'x'\\]"),
])
def test_scene_defaults_are_method_dicts(defaults, message):
    scene = pendulum(n_bodies=3)
    with pytest.raises(InputError, match=message):
        replace(scene, defaults=defaults)
    assert isinstance(Scene(**{**scene.__dict__, "defaults": {}}), Scene)


@pytest.mark.parametrize("args, message", [
    (("r", "1", (0, 0, 0), (0, 0, 1), 0.1), "rod 'r': mass must be a real number .*a string"),
    (("r", 1, (0, 0, 0), (0, 0, 1), None), "rod 'r': radius must be a real number .*None"),
    (("r", 1, (0, 0), (0, 0, 1), 0.1), "rod 'r': a must have shape \\(3,\\), got \\(2,\\)"),
    (("r", 1, (0, 0, 0), "abc", 0.1), "rod 'r': b must be a real number"),
    (("r", 1, (0, 0, np.nan), (0, 0, 1), 0.1), "rod 'r': a has non-finite entries"),
    (("r", -1, (0, 0, 0), (0, 0, 1), 0.1), "rod 'r': mass must be positive"),
    (("r", 1, (0, 0, 0), (0, 0, 1), 0), "rod 'r': radius must be positive"),
    (("r", 1, (0, 0, 1), (0, 0, 1), 0.1), "rod 'r': its ends a and b must differ"),
])
def test_rod_checks_its_arguments(args, message):
    with pytest.raises(InputError, match=message):
        rod(*args)


# --- the falling character comes to rest -------------------------------------------

@pytest.fixture(scope="module")
def fallen():
    scene = falling_character()
    sim = scene.simulator()
    contact = scene.forces.elements[0]
    ke, low, pelvis = [], [], []
    while sim.t < 3.0 - 1e-9:
        sim.step(20)
        x = contact.points(scene.forces.states_of(contact, sim.q, sim.qd))[0]
        ke.append(kinetic_energy(scene.model, sim.q, sim.qd))
        low.append(x[:, 2].min())
        pelvis.append(sim.q[:3].copy())
    return np.array(ke), np.array(low), np.array(pelvis), scene


def test_character_falls_and_comes_to_rest(fallen):
    ke, low, pelvis, scene = fallen
    start = scene.q0[2]
    assert pelvis[:, 2].min() < 0.3 * start              # it fell
    last = slice(-25, None)                               # the last 0.5 s
    assert ke[last].max() < 1e-3 * ke.max()               # kinetic energy decayed
    assert ke[-50:-25].mean() > ke[last].mean() * 0.2 or ke[last].mean() < 1e-2


def test_character_does_not_sink_or_jitter(fallen):
    ke, low, pelvis, scene = fallen
    g = np.linalg.norm(scene.model.gravity)
    w = scene.forces.elements[0].frequency
    last = slice(-25, None)                               # the last 0.5 s
    # at rest a body alone on its points sinks g / w^2 (0.16 mm); bodies carry
    # their neighbours' weight too: at most 5 mm, and 5 cm at the impact
    assert low[last].min() > -0.005 and g / w**2 < 0.005
    assert low.min() > -0.05
    assert np.ptp(low[last]) < 1e-3                       # no sinking, no bouncing
    assert np.linalg.norm(np.ptp(pelvis[last], axis=0)) < 2e-3


# --- the hanging dogs stay on their springs and keep moving ------------------------

def test_dogs_stay_on_springs_and_keep_moving():
    scene = hanging_dogs(n_dogs=4, columns=2)
    springs, torques = scene.forces.elements
    sim = scene.simulator(method="adaptive", threshold=1e-6)
    rest = springs.rest_length
    lengths, ke = [], []
    while sim.t < 2.0 - 1e-9:
        sim.step(25)
        states = scene.forces.states_of(springs, sim.q, sim.qd)
        lengths.append(springs.lengths(sim.t, states))
        ke.append(kinetic_energy(scene.model, sim.q, sim.qd))
    lengths, ke = np.array(lengths), np.array(ke)
    dog_mass = scene.model.mass.sum() / 4
    stretch = dog_mass * 9.81 / (2 * springs.stiffness[0])      # equilibrium, two springs
    assert lengths.min() > rest[0] and lengths.max() < rest[0] + 3 * stretch + 0.1
    assert ke[-20:].mean() > 0.2 * ke[:20].mean()                # still moving after 2 s
    first = torques.pulses(0)[1].min()                             # the first pulse
    assert first < 1.0
    runs = [hanging_dogs(n_dogs=4, columns=2, torque=tau).simulator() for tau in (0.3, 0.0)]
    for run in runs:
        run.step(int((first + 0.1) / run.dt))
    assert np.abs(runs[0].q - runs[1].q).max() > 1e-4              # the torques act


# --- the puppet's hidden legs --------------------------------------------------------

def leg_activity(method):
    scene = dog_puppet()
    model = scene.model
    legs = [model.joint_index(f"{leg}_{j}") for leg in LEGS for j in ("knee", "ankle")]
    sim = scene.simulator(method=method, threshold=0.03,
                          **({"counting": "merged"} if method == "view-oq" else {}))
    t, active = [], []
    while sim.t < 7.4 - 1e-9:
        sim.step(10)
        t.append(sim.t)
        active.append(np.isin(legs, sim.adaptive.joints).sum())
    t, active = np.array(t), np.array(active)
    return {name: active[(t >= a) & (t <= b)].mean() for name, (a, b) in PUPPET_PHASES.items()}


def test_puppet_legs_hidden_by_the_wall_are_rigid_with_view_oq():
    mean = leg_activity("view-oq")                         # 8 knees and ankles
    for name in ("open", "open_again", "back_in_view"):
        assert mean[name] >= 6, (name, mean)
    for name in ("behind_wall", "below_view"):
        assert mean[name] <= 1, (name, mean)


def test_puppet_legs_below_the_view_are_rigid_with_view_bvh():
    mean = leg_activity("view-bvh")
    for name in ("open", "open_again", "back_in_view"):
        assert mean[name] >= 6, (name, mean)
    assert mean["below_view"] <= 4 < mean["open"]
    # bounding volumes model no occlusion: the wall hides nothing from them
    assert mean["behind_wall"] >= 6


def test_a_rigid_character_still_falls():
    """Every internal joint rigid (a huge threshold): the floating base keeps its
    accelerations, so the character falls as one body instead of hovering."""
    scene = falling_character()
    sim = scene.simulator(method="adaptive", threshold=1e3)
    sim.step(1000)
    assert max(s.active_joints for s in sim.history[10:]) < scene.model.nb
    assert sim.q[2] < 0.3 * scene.q0[2]


ARM = Path(__file__).parent / "data" / "arm.xml"


def test_a_mujoco_model_file_is_a_scene_with_its_forces_limits_and_a_framing_camera():
    """``mjcf_scene``: MuJoCo's qpos0 and time step, the imported actuators,
    tendon and gravity compensation and the joint ranges as force elements, the
    floor, stand and mocap target as environment, and a camera that has every
    body in view; it runs with every method."""
    scene = mjcf_scene(ARM)
    m = mujoco.MjModel.from_xml_path(str(ARM))
    assert scene.model.body_names == ("upper", "fore", "hand") and scene.dt == 0.004
    np.testing.assert_array_equal(scene.q0, m.qpos0)
    kinds = [type(e).__name__ for e in scene.forces.elements]
    assert kinds == ["Actuation", "GravityCompensation", "JointLimits"]
    limits = scene.forces.elements[2]
    assert limits.angle.tolist() == [1.2] and limits.low.tolist() == [-2.0, -0.05]
    assert len(scene.environment.geoms) == 3                   # floor, stand, target
    R, p = world_poses(scene.model, scene.q0)
    xy, depth = scene.camera.project(p)
    assert np.all(depth > scene.camera.znear)
    assert np.all((xy > 0) & (xy < (scene.camera.width, scene.camera.height)))
    far = mjcf_scene(ARM, camera_distance=20.0, dt=0.001, resolution=(64, 48))
    assert np.linalg.norm(np.subtract(far.camera.position, far.camera.target)) == \
        pytest.approx(20.0) and far.dt == 0.001 and far.camera.width == 64
    scene.forces.elements[0].set_ctrl([1.0, 0.02])
    for method in METHODS:
        sim = scene.simulator(method=method)
        sim.step(25)
        assert np.all(np.isfinite(sim.q)) and sim.q[4] != scene.q0[4]     # the elbow moves


def test_a_mujoco_scene_limits_every_limited_hinge_and_slide():
    """gymnasium's humanoid: every limited hinge of MuJoCo, in one-dof and in
    multi-hinge (composite) joints, has its range in the scene's JointLimits."""
    import gymnasium

    path = Path(gymnasium.__file__).parent / "envs" / "mujoco" / "assets" / "humanoid.xml"
    with pytest.warns(UserWarning, match="left out contacts"):
        scene = mjcf_scene(path)
    m = mujoco.MjModel.from_xml_path(str(path))
    limited = [j for j in range(m.njnt) if m.jnt_limited[j] and m.jnt_type[j] in (2, 3)]
    limits = scene.forces.elements[-1]
    order = np.argsort(limits.h_dof)
    np.testing.assert_array_equal(limits.h_dof[order], np.sort(m.jnt_dofadr[limited]))
    by_dof = dict(zip(m.jnt_dofadr[limited], m.jnt_range[limited], strict=True))
    for dof, low, high in zip(limits.h_dof, limits.low, limits.high, strict=True):
        assert (low, high) == tuple(by_dof[dof])
    assert any(len(j.build_stages()) > 1 and j.name in limits_names(scene)
               for j in scene.model.joints)


def limits_names(scene):
    limits = scene.forces.elements[-1]
    return {scene.model.joint_names[scene.model.dof_joint[d]] for d in limits.h_dof}
