"""The toy dog of Kim 2008 §6.1: the haptic dog puppet (Figure 2) and the 100
hanging dogs (Figure 6)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..camera import Camera, check_resolution
from ..checks import check_callable, check_count, check_real, real_array, show
from ..environment import wall
from ..errors import InputError, VdadError
from ..forces import MAX_PULSE_RATE, BodyStates, Drag, Forces, RandomTorques, Springs
from ..model import Joint, Model, Pose
from ..spatial import mv, quat_exp, quat_to_rot
from .base import Scene, rod

BROWN, DARK, LIGHT = (0.62, 0.42, 0.25, 1.0), (0.35, 0.22, 0.12, 1.0), (0.8, 0.65, 0.45, 1.0)
LEGS = ("front_left", "front_right", "back_left", "back_right")


def toy_dog(prefix=""):
    """Bodies and joints of a toy dog of 16 rigid bodies (Kim 2008 §6.1), about
    0.45 m long and 2 kg, names prefixed by ``prefix``.

    The torso (body frame at its centre, x forward, z up) hangs from a free joint
    to the world; a neck (ball joint) carries the head (hinge about y); a tail
    (ball joint); four legs of three links: upper leg (ball joint at the hip or
    shoulder), lower leg (hinge about y) and paw (hinge about y). Joints are toy
    joints: weak springs towards the standing pose and light damping.
    Returns ``(bodies, joints)`` lists to build a :class:`~vdad.Model` from.
    """
    if not isinstance(prefix, str):
        raise InputError(f"prefix must be a string (prepended to the body and joint names), "
                         f"got {type(prefix).__name__}: {show(prefix)}")

    def n(name):
        return f"{prefix}{name}"

    bodies = [rod(n("torso"), 1.0, (-0.12, 0, 0), (0.12, 0, 0), 0.06, BROWN),
              rod(n("neck"), 0.12, (0, 0, 0), (0.04, 0, 0.07), 0.03, BROWN),
              rod(n("head"), 0.3, (0, 0, 0), (0.09, 0, 0), 0.045, LIGHT),
              rod(n("tail"), 0.04, (0, 0, 0), (-0.1, 0, 0.06), 0.015, DARK)]
    joints = [Joint(n("root"), None, n("torso"), "free"),
              Joint(n("neck"), n("torso"), n("neck"), "spherical", stiffness=0.3,
                    damping=0.005, placement=Pose((0.14, 0, 0.03))),
              Joint(n("head"), n("neck"), n("head"), "revolute", axis=(0, 1, 0),
                    stiffness=0.2, damping=0.003, placement=Pose((0.04, 0, 0.07))),
              Joint(n("tail"), n("torso"), n("tail"), "spherical", stiffness=0.02,
                    damping=0.0005, placement=Pose((-0.16, 0, 0.03)))]
    for leg in LEGS:
        x = 0.09 if leg.startswith("front") else -0.09
        y = 0.045 if leg.endswith("left") else -0.045
        bodies += [rod(n(f"{leg}_upper"), 0.09, (0, 0, 0), (0, 0, -0.08), 0.022, BROWN),
                   rod(n(f"{leg}_lower"), 0.06, (0, 0, 0), (0, 0, -0.07), 0.018, BROWN),
                   rod(n(f"{leg}_paw"), 0.03, (-0.01, 0, 0), (0.03, 0, 0), 0.015, DARK)]
        joints += [Joint(n(f"{leg}_hip"), n("torso"), n(f"{leg}_upper"), "spherical",
                         stiffness=0.2, damping=0.004, placement=Pose((x, y, -0.04))),
                   Joint(n(f"{leg}_knee"), n(f"{leg}_upper"), n(f"{leg}_lower"), "revolute",
                         axis=(0, 1, 0), stiffness=0.08, damping=0.002,
                         placement=Pose((0, 0, -0.08))),
                   Joint(n(f"{leg}_ankle"), n(f"{leg}_lower"), n(f"{leg}_paw"), "revolute",
                         axis=(0, 1, 0), stiffness=0.01, damping=0.0003,
                         placement=Pose((0, 0, -0.07)))]
    return bodies, joints


def _place(model, q, prefix, position, yaw=0.0):
    """Set the free root joint of the dog ``prefix`` in ``q`` to ``position`` and
    a turn of ``yaw`` rad about the vertical."""
    i = model.q_start[model.joint_index(f"{prefix}root")]
    q[i:i + 3] = position
    q[i + 3:i + 7] = quat_exp(np.array([0.0, 0.0, yaw]))


# --- the dog puppet ----------------------------------------------------------------

STICK_POINTS = np.array([[0.15, 0, 0], [-0.15, 0, 0], [0.09, 0.09, 0], [0.09, -0.09, 0],
                         [-0.09, 0.09, 0], [-0.09, -0.09, 0]])
STRUNG = (("head", (0.04, 0, 0.04)), ("torso", (-0.1, 0, 0.06)),
          ("front_left_lower", (0, 0, -0.07)), ("front_right_lower", (0, 0, -0.07)),
          ("back_left_lower", (0, 0, -0.07)), ("back_right_lower", (0, 0, -0.07)))


@dataclass(frozen=True)
class StickPath:
    """The puppet's control stick: keyframed ``positions`` (k, 3) at ``times``
    (k,), eased in and out between keyframes (smoothstep: no jerk at the keys),
    held after the last, and rocked about its long x axis by ``rock`` rad at
    ``rock_hz`` (rocking lifts the left and right legs in turn: the dog walks).
    ``anchors(t)`` gives the world points of the strings' upper ends (6, 3).
    The fields are checked and stored as tuples of floats and floats."""

    times: tuple
    positions: tuple
    rock: float = 0.35
    rock_hz: float = 1.5

    def __post_init__(self):
        t = real_array("times", self.times)
        p = real_array("positions", self.positions)
        if t.ndim != 1 or p.shape != (len(t), 3) or len(t) == 0:
            raise InputError(f"stick path needs times (k,) and positions (k, 3), k >= 1, got "
                             f"{t.shape} and {p.shape}")
        if not (np.all(np.isfinite(t)) and np.all(np.isfinite(p))) or np.any(np.diff(t) <= 0):
            raise InputError("stick path times must be finite and increasing, positions "
                             "finite")
        rock = float(check_real("rock", self.rock))
        rock_hz = float(check_real("rock_hz", self.rock_hz, nonnegative=True))
        for name, value in (("times", tuple(t.tolist())),
                            ("positions", tuple(map(tuple, p.tolist()))),
                            ("rock", rock), ("rock_hz", rock_hz)):
            object.__setattr__(self, name, value)

    def pose(self, t):
        """Stick positions (..., 3) and rotations (..., 3, 3) at times ``t`` (a
        number or an array)."""
        t = np.asarray(t, float)
        times, pos = np.asarray(self.times, float), np.asarray(self.positions, float)
        i = np.clip(np.searchsorted(times, t, "right") - 1, 0, len(times) - 1)
        j = np.minimum(i + 1, len(times) - 1)              # held after the last key
        span = np.where(j > i, times[j] - times[i], 1.0)
        s = np.where(j > i, np.clip((t - times[i]) / span, 0.0, 1.0), 0.0)
        p = pos[i] + (3 * s**2 - 2 * s**3)[..., None] * (pos[j] - pos[i])
        roll = self.rock * np.sin(2 * np.pi * self.rock_hz * t)
        axis = np.stack([roll, np.zeros_like(roll), np.zeros_like(roll)], axis=-1)
        return p, quat_to_rot(quat_exp(axis))

    def many(self, t):
        """The anchors (E, 6, 3) at the times ``t`` (E,), in one evaluation:
        :class:`~vdad.forces.Springs` tabulates a chunk of steps with it."""
        p, R = self.pose(np.asarray(t, float).reshape(-1))
        return p[:, None, :] + np.einsum("kj,eij->eki", STICK_POINTS, R)

    def __call__(self, t):
        return self.many([t])[0]


def default_stick_path(height=1.02, open_x=-0.05, hidden_x=0.7, drop=0.55):
    """The scripted path of :func:`dog_puppet` (``PUPPET_PHASES`` names its
    windows): rocking in the open (0-0.8 s), carried behind the wall (0.8-2 s)
    and rocking there with the legs hidden (until 3 s), back into the open
    (3-4.2 s, rocking until 4.8 s), lowered so that the legs leave the bottom of
    the view (4.8-5.4 s, held until 6.2 s), and raised into view again
    (6.2-6.8 s, until 7.4 s)."""
    key = [(0.0, open_x, height), (0.8, open_x, height), (2.0, hidden_x, height),
           (3.0, hidden_x, height), (4.2, open_x, height), (4.8, open_x, height),
           (5.4, open_x, height - drop), (6.2, open_x, height - drop),
           (6.8, open_x, height), (7.4, open_x, height)]
    return StickPath(tuple(k[0] for k in key), tuple((k[1], 0.0, k[2]) for k in key))


PUPPET_PHASES = {"open": (0.3, 0.8), "behind_wall": (2.4, 3.0), "open_again": (4.4, 4.8),
                 "below_view": (5.8, 6.2), "back_in_view": (7.0, 7.4)}


def _stick_ends(stick):
    """``stick(0)``, the strings' upper ends at the start, checked to be finite
    (6, 3) world points."""
    try:
        top = stick(0.0)
    except VdadError:
        raise
    except Exception as e:
        raise InputError(f"stick(t) failed at t = 0: {type(e).__name__}: {e}") from e
    top = real_array("stick(t)", top)
    if top.shape != (6, 3):
        raise InputError(f"stick(t) must give the (6, 3) world points of the strings' upper "
                         f"ends, got shape {top.shape} at t = 0")
    if not np.all(np.isfinite(top)):
        raise InputError(f"stick(t) must be finite, got {show(top.tolist())} at t = 0")
    return top


def dog_puppet(stick=None, dt=2e-3, string_stiffness=1000.0, string_damping=2.0, drag=3.0,
               camera_distance=2.0, resolution=(320, 240), seed=0):
    """The haptic-enabled dog puppet (Kim 2008 §6.1, Figure 2).

    A toy dog (:func:`toy_dog`) hangs by six virtual strings (head, rump and
    the four lower legs; tension only) from a control stick that the paper moved
    with a haptic device. Here the stick follows ``stick``: a
    :class:`StickPath` or any callable ``t -> (6, 3)`` world points of the
    strings' upper ends (default :func:`default_stick_path`: rocking so that the
    legs walk, behind a wall that hides the legs, and below the view); a linear
    ``drag`` (1/s, :class:`~vdad.forces.Drag`) calms the swinging. The
    environment is that wall, 0.48 m tall, between the viewer and the path for
    0.25 < x < 1.2; the camera (30 degree field of view) looks at it from
    ``camera_distance`` m in front.
    ``PUPPET_PHASES`` names the default path's time windows (legs in the open,
    behind the wall, below the view). ``seed`` only names the run: the scene is
    deterministic (a whole number >= 0, like the other scenes' seeds). Method
    defaults (``Scene.defaults``, calibrated at these parameters,
    ``docs/scenes.md``): thresholds 1e-4 (adaptive), 0.1 (view-bvh) and 1e-3
    (view-oq); lod-distance and sleeping keep the generic ones.
    """
    width, height = check_resolution(resolution, allow_none=False)
    for name, v in (("dt", dt), ("string_stiffness", string_stiffness),
                    ("camera_distance", camera_distance)):
        check_real(name, v, positive=True)
    for name, v in (("string_damping", string_damping), ("drag", drag)):
        check_real(name, v, nonnegative=True)
    seed = check_count("seed", seed, 0)
    stick = default_stick_path() if stick is None else stick
    check_callable("stick", stick, "t -> (6, 3) points (a StickPath)")
    top = _stick_ends(stick)
    bodies, joints = toy_dog()
    model = Model(bodies, joints, name="dog_puppet")
    q0 = np.array(model.q_neutral)
    _place(model, q0, "", top[:2].mean(axis=0) - (0.0, 0.0, 0.5))
    names = [b for b, _ in STRUNG]
    points = np.array([p for _, p in STRUNG], float)
    # rest lengths: the strings as they hang at the start, the leg strings 2 cm slack
    R, p = BodyStates(model, [model.body_index(b) for b in names])(q0, np.zeros(model.nv))[:2]
    length = np.linalg.norm(p + mv(R, points) - top, axis=1)
    length[2:] += 0.02
    strings = Springs(model, names, points, stick, string_stiffness, string_damping,
                      rest_length=length, string=True)
    forces = Forces(model, [strings, Drag(model, drag)])
    camera = Camera(position=(0.35, -camera_distance, 0.52), target=(0.35, 0.0, 0.45),
                    yfov=np.pi / 6, width=width, height=height, znear=0.05,
                    zfar=10 * camera_distance + 10)
    environment = wall((0.25, -0.15), (1.2, -0.15), height=0.48)
    return Scene("dog_puppet", "toy dog of 16 bodies on six virtual strings from a scripted "
                 "control stick that takes it behind a wall", model, q0, np.zeros(model.nv),
                 dt, controller=forces.controller, external=forces.external, camera=camera,
                 environment=environment, forces=forces,
                 params=dict(dt=dt, string_stiffness=string_stiffness,
                             string_damping=string_damping, drag=drag,
                             camera_distance=camera_distance, resolution=(width, height),
                             seed=seed),
                 defaults={"adaptive": {"threshold": 1e-4}, "view-bvh": {"threshold": 0.1},
                           "view-oq": {"threshold": 1e-3}})


# --- the hanging dogs --------------------------------------------------------------

def hanging_dogs(n_dogs=100, columns=10, spacing=(0.7, 0.9), dt=1e-3, twist=1.0,
                 spring_stiffness=60.0, spring_damping=0.2, torque=0.3, torque_rate=0.5,
                 torque_duration=0.1, seed=0, camera_distance=3.0, resolution=(320, 240)):
    """100 toy dogs hanging from springs (Kim 2008 §6.1, Figure 6).

    ``n_dogs`` dogs (:func:`toy_dog`, 16 bodies each) in rows of ``columns``,
    ``spacing`` = (across, in depth) m apart, each hanging level from two
    springs (``spring_stiffness`` N/m, ``spring_damping`` N s/m, rest length
    0.3 m) between its shoulders and rump and fixed points above, where it hangs
    in equilibrium. Each dog
    is released from rest, turned from its equilibrium about the vertical by
    ``twist`` rad times a random factor in [0.5, 1] of random sign, so that the
    springs spin it; ``torque`` N m pulses of ``torque_duration`` s hit each torso
    at ``torque_rate`` per second (:class:`~vdad.forces.RandomTorques`). All
    randomness comes from ``seed``.

    The camera stands ``camera_distance`` m in front of the first row, a little
    above, and looks into the grid: near dogs hide far ones, the outer columns
    are cut by the viewport and the back rows are far away.
    Method defaults (``Scene.defaults``, calibrated on the 100 dogs,
    ``docs/scenes.md``): threshold 0.01 for adaptive, view-bvh and view-oq;
    lod-distance rigid beyond twice ``camera_distance`` (6 m); sleeping generic.
    """
    pixels = check_resolution(resolution, allow_none=False)
    n, columns = check_count("n_dogs", n_dogs), check_count("columns", columns)
    sx, sy = check_real("spacing", spacing, (2,), positive=True)
    seed = check_count("seed", seed, 0)
    for name, v in (("dt", dt), ("spring_stiffness", spring_stiffness),
                    ("camera_distance", camera_distance)):
        check_real(name, v, positive=True)
    for name, v in (("twist", twist), ("spring_damping", spring_damping), ("torque", torque),
                    ("torque_rate", torque_rate)):
        check_real(name, v, nonnegative=True)
    check_real("torque_duration", torque_duration, positive=True)
    if float(torque_rate) * n > MAX_PULSE_RATE:
        raise InputError(f"torque_rate * n_dogs = {float(torque_rate) * n:g} pulses per second "
                         f"is too high: at most {MAX_PULSE_RATE:g} (RandomTorques draws each "
                         f"1 s window's pulses at once)")
    bodies, joints = [], []
    for d in range(n):
        b, j = toy_dog(f"dog{d:03d}/")
        bodies += b
        joints += j
    model = Model(bodies, joints, name=f"hanging_dogs{n}")
    rng = np.random.default_rng(seed)
    q0 = np.array(model.q_neutral)
    height = 1.5
    points = np.array([[0.1, 0, 0.06], [-0.1, 0, 0.06]])
    rest = 0.3
    dog_mass = float(np.sum(model.mass)) / n
    drop = points[0, 2] + rest + dog_mass * np.linalg.norm(model.gravity) / (2 * spring_stiffness)
    grid = []
    for d in range(n):
        x = (d % columns - (columns - 1) / 2) * sx
        y = (d // columns) * sy
        grid.append((x, y))
        turn = twist * rng.uniform(0.5, 1.0) * rng.choice([-1.0, 1.0])
        _place(model, q0, f"dog{d:03d}/", (x, y, height), turn)
    grid = np.array(grid)
    anchors = np.concatenate([np.column_stack([grid[:, 0] + px, grid[:, 1],
                                               np.full(n, height + drop)])
                              for px in points[:, 0]])
    torsos = [f"dog{d:03d}/torso" for d in range(n)]
    springs = Springs(model, torsos * 2, np.repeat(points, n, axis=0), anchors,
                      spring_stiffness, spring_damping, rest_length=rest)
    pulses = RandomTorques(model, torsos, torque, torque_rate, torque_duration, seed=seed)
    forces = Forces(model, [springs, pulses])
    rows = -(-n // columns)
    camera = Camera(position=(0.0, -camera_distance, height + 0.6),
                    target=(0.0, 0.15 * (rows - 1) * sy, height - 0.1), width=pixels[0],
                    height=pixels[1], znear=0.05,
                    zfar=10 * (camera_distance + rows * sy))
    return Scene("hanging_dogs", f"{n} toy dogs ({model.nb} bodies) hanging from springs, "
                 f"released twisted, with random torques", model, q0, np.zeros(model.nv), dt,
                 controller=forces.controller, external=forces.external, camera=camera,
                 forces=forces,
                 params=dict(n_dogs=n, columns=columns, spacing=(sx, sy), dt=dt, twist=twist,
                             spring_stiffness=spring_stiffness, spring_damping=spring_damping,
                             torque=torque, torque_rate=torque_rate,
                             torque_duration=torque_duration, seed=seed,
                             camera_distance=camera_distance, resolution=pixels),
                 defaults={"adaptive": {"threshold": 1e-2}, "view-bvh": {"threshold": 1e-2},
                           "view-oq": {"threshold": 1e-2},
                           "lod-distance": {"distance": 2.0 * camera_distance}})
