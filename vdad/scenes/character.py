"""The falling character of Kim 2008 §6.1 (Figures 1 and 7)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from ..camera import Camera, Dolly, check_resolution
from ..checks import check_count, check_real
from ..environment import floor
from ..errors import InputError
from ..forces import BodyStates, FloorContact, Forces, JointLimits, joint_inertia
from ..model import Joint, Model, Pose
from ..spatial import quat_exp, quat_mul
from .base import Scene, rod

SKIN, SHIRT, TROUSERS = (0.9, 0.75, 0.62, 1.0), (0.25, 0.45, 0.75, 1.0), (0.3, 0.3, 0.35, 1.0)

# (body, parent, joint kind, axis, placement in the parent, rod start, rod end, radius,
#  mass, limit, colour): the CMU motion-capture skeleton without its two hip offsets
# (29 bodies). Limits: (low, high) rad for hinges, a cone angle for ball joints.
_SPINE = [
    ("pelvis", None, "free", None, (0, 0, 0), (0, -0.09, 0), (0, 0.09, 0), 0.08, 10.0, None,
     TROUSERS),
    ("lowerback", "pelvis", "spherical", None, (0, 0, 0.08), (0, 0, 0), (0, 0, 0.12), 0.08, 6.0,
     0.5, SHIRT),
    ("upperback", "lowerback", "spherical", None, (0, 0, 0.12), (0, 0, 0), (0, 0, 0.12), 0.09,
     7.0, 0.4, SHIRT),
    ("thorax", "upperback", "spherical", None, (0, 0, 0.12), (0, -0.08, 0.08), (0, 0.08, 0.08),
     0.1, 8.0, 0.4, SHIRT),
    ("lowerneck", "thorax", "spherical", None, (0, 0, 0.18), (0, 0, 0), (0, 0, 0.06), 0.045, 1.5,
     0.6, SKIN),
    ("upperneck", "lowerneck", "spherical", None, (0, 0, 0.06), (0, 0, 0), (0, 0, 0.05), 0.04,
     1.2, 0.6, SKIN),
    ("head", "upperneck", "spherical", None, (0, 0, 0.05), (0.02, 0, 0.05), (0.02, 0, 0.13),
     0.09, 4.0, 0.7, SKIN),
]


def _limb(side, s):
    """Arm and leg of one ``side`` ("l" or "r", ``s`` = +1 or -1 along y)."""
    return [
        (f"{side}clavicle", "thorax", "spherical", None, (0, 0.03 * s, 0.15), (0, 0, 0),
         (0, 0.15 * s, 0.02), 0.04, 1.5, 0.3, SHIRT),
        (f"{side}humerus", f"{side}clavicle", "spherical", None, (0, 0.15 * s, 0.02), (0, 0, 0),
         (0, 0, -0.28), 0.045, 2.2, 1.6, SHIRT),
        (f"{side}radius", f"{side}humerus", "revolute", (0, 1, 0), (0, 0, -0.28), (0, 0, 0),
         (0, 0, -0.25), 0.035, 1.3, (-2.5, 0.0), SKIN),
        (f"{side}wrist", f"{side}radius", "revolute", (0, 0, 1), (0, 0, -0.25), (0, 0, 0),
         (0, 0, -0.04), 0.03, 0.3, (-1.0, 1.0), SKIN),
        (f"{side}hand", f"{side}wrist", "revolute", (1, 0, 0), (0, 0, -0.04), (0, 0, 0),
         (0, 0, -0.08), 0.03, 0.4, (-1.0, 1.0), SKIN),
        (f"{side}fingers", f"{side}hand", "revolute", (0, 1, 0), (0, 0, -0.08), (0, 0, 0),
         (0, 0, -0.05), 0.02, 0.1, (-1.5, 0.0), SKIN),
        (f"{side}thumb", f"{side}hand", "spherical", None, (0.02, 0, -0.02), (0, 0, 0),
         (0.03, 0, -0.04), 0.015, 0.05, 0.8, SKIN),
        (f"{side}femur", "pelvis", "spherical", None, (0, 0.09 * s, -0.02), (0, 0, 0),
         (0, 0, -0.42), 0.07, 8.0, 1.4, TROUSERS),
        (f"{side}tibia", f"{side}femur", "revolute", (0, 1, 0), (0, 0, -0.42), (0, 0, 0),
         (0, 0, -0.42), 0.05, 3.5, (0.0, 2.5), TROUSERS),
        (f"{side}foot", f"{side}tibia", "revolute", (0, 1, 0), (0, 0, -0.42), (-0.04, 0, -0.05),
         (0.13, 0, -0.05), 0.04, 1.0, (-0.7, 0.7), TROUSERS),
        (f"{side}toes", f"{side}foot", "revolute", (0, 1, 0), (0.14, 0, -0.05), (0, 0, 0),
         (0.05, 0, 0), 0.03, 0.2, (-0.8, 0.5), TROUSERS),
    ]


SKELETON = _SPINE + _limb("l", 1) + _limb("r", -1)


def humanoid(scale=1.0, joint_damping=10.0):
    """The 29-body character (Kim 2008 §6.1): the CMU motion-capture skeleton
    without its two hip offsets: pelvis (free joint), lower back, upper back,
    thorax, two neck links and head (ball joints); per side a clavicle and
    humerus (ball), forearm (elbow hinge), wrist (twist hinge), hand and fingers
    (hinges), thumb (ball); femur (ball), tibia (knee hinge), foot (ankle hinge)
    and toes (hinge). About 1.75 m and 75 kg at ``scale`` 1 (lengths scale with
    ``scale``, masses with its cube). Each joint has a viscous damping of
    ``2 I joint_damping``, ``I`` its lighter side's moment of inertia
    (:func:`~vdad.forces.joint_inertia`): limp muscles, a ragdoll. Returns
    ``(model, limits)``, the limits in the form :class:`~vdad.forces.JointLimits`
    takes."""
    check_real("scale", scale, positive=True)
    check_real("joint_damping", joint_damping, nonnegative=True)
    sc = float(scale)
    bodies, joints, limits = [], [], {}
    for name, parent, kind, axis, at, a, b, r, m, limit, rgba in SKELETON:
        bodies.append(rod(name, m * sc**3, np.multiply(a, sc), np.multiply(b, sc), r * sc, rgba))
        joints.append(Joint(name, parent, name, kind, axis=axis or (0, 0, 1),
                            placement=Pose(tuple(np.multiply(at, sc)))))
        if limit is not None:
            limits[name] = limit
    undamped = Model(bodies, joints, name="character")
    joints = [replace(jt, damping=2 * joint_inertia(undamped, undamped.joint_index(jt.name))
                      * joint_damping if jt.kind != "free" else 0.0) for jt in joints]
    return Model(bodies, joints, name="character"), limits


def falling_character(dt=1e-3, scale=1.0, lean=0.35, drop=0.05, push=1.0, seed=0,
                      joint_damping=40.0, floor_frequency=250.0, friction=0.8,
                      camera_distance=3.0, camera_speed=3.0, resolution=(320, 240)):
    """A character of 29 bodies falls onto a floor under gravity while the viewer
    moves away (Kim 2008 §6.1, Figures 1 and 7).

    The :func:`humanoid` starts upright, ``drop`` m above the floor ``z = 0``,
    leaning forward by ``lean`` rad, with a forward ``push`` (m/s at the pelvis)
    and small random joint angles (``seed``); its joints are damped by
    ``joint_damping`` (:func:`humanoid`); ``drop`` >= 0 and ``|lean|`` <= pi/2
    (it starts above the floor, leaning, not upside down). Contact:
    :class:`~vdad.forces.FloorContact` on every body's capsule (natural frequency
    ``floor_frequency`` rad/s, Coulomb ``friction``); joint limits:
    :class:`~vdad.forces.JointLimits` (knees and elbows bend one way, ball joints
    within cones). The camera looks at the character from ``camera_distance`` m
    in front and to the side, and moves away at ``camera_speed`` m/s (a
    :class:`~vdad.camera.Dolly`).
    Method defaults (``Scene.defaults``, calibrated at these parameters,
    ``docs/scenes.md``): thresholds 1e-5 (adaptive), 3e-3 (view-bvh) and 3e-5
    (view-oq); lod-distance rigid beyond twice ``camera_distance`` (6 m: after
    about 1 s of the dolly); sleeping generic.
    """
    width, height = check_resolution(resolution, allow_none=False)
    for name, v in (("dt", dt), ("camera_distance", camera_distance),
                    ("floor_frequency", floor_frequency), ("scale", scale)):
        check_real(name, v, positive=True)
    seed = check_count("seed", seed, 0)
    if floor_frequency * dt > 0.5:
        raise InputError(f"floor_frequency * dt = {floor_frequency * dt:.3g} > 0.5: the floor "
                         f"contact is unstable at this time step; lower one of them")
    for name, v in (("push", push), ("camera_speed", camera_speed)):
        check_real(name, v)
    for name, v in (("drop", drop), ("joint_damping", joint_damping), ("friction", friction)):
        check_real(name, v, nonnegative=True)
    if abs(float(check_real("lean", lean))) > np.pi / 2:
        raise InputError(f"lean must be within [-pi/2, pi/2] rad (a lean from upright), got "
                         f"{lean}")
    model, limits = humanoid(scale, joint_damping)
    rng = np.random.default_rng(seed)
    q0 = np.array(model.q_neutral)
    for j in range(1, model.nb):
        i, nq = model.q_start[j], model.nq_joint[j]
        if nq == 4:
            q0[i:i + 4] = quat_exp(rng.normal(scale=0.05, size=3))
        else:
            low, high = limits[model.joint_names[j]]
            q0[i] = np.clip(rng.normal(scale=0.05), low, high)
    for side in ("l", "r"):                       # arms a little out, knees a little bent
        i = model.q_start[model.joint_index(f"{side}humerus")]
        s = 1.0 if side == "l" else -1.0
        q0[i:i + 4] = quat_mul(quat_exp(np.array([-0.3 * s, 0.0, 0.0])), q0[i:i + 4])
        q0[model.q_start[model.joint_index(f"{side}tibia")]] = 0.1
    root = model.q_start[model.joint_index("pelvis")]
    q0[root + 3:root + 7] = quat_exp(np.array([0.0, lean, 0.0]))
    contact = FloorContact(model, 0.0, floor_frequency, friction=friction)
    lowest = contact.points(BodyStates(model, contact.bodies)(q0, np.zeros(model.nv)))[0]
    q0[root + 2] = drop - lowest[:, 2].min()
    qd0 = np.zeros(model.nv)
    qd0[model.v_start[model.joint_index("pelvis")]] = push
    forces = Forces(model, [contact, JointLimits(model, limits)])
    camera = Camera(position=(0.6 * camera_distance, -0.8 * camera_distance, 1.0 * scale),
                    target=(0.5 * scale, 0.0, 0.45 * scale), width=width,
                    height=height, znear=0.05, zfar=200.0)
    path = Dolly(camera, camera_speed) if camera_speed else camera
    return Scene("falling_character", f"a {model.nb}-body character falling onto a floor "
                 f"while the viewer moves away", model, q0, qd0, dt,
                 controller=forces.controller, external=forces.external, camera=path,
                 environment=floor(0.0), forces=forces,
                 params=dict(dt=dt, scale=scale, lean=lean, drop=drop, push=push, seed=seed,
                             joint_damping=joint_damping, floor_frequency=floor_frequency,
                             friction=friction, camera_distance=camera_distance,
                             camera_speed=camera_speed, resolution=(width, height)),
                 defaults={"adaptive": {"threshold": 1e-5}, "view-bvh": {"threshold": 3e-3},
                           "view-oq": {"threshold": 3e-5},
                           "lod-distance": {"distance": 2.0 * camera_distance}})
