"""A scene from a MuJoCo model file: ``vdad run robot.xml`` (``docs/mujoco.md``)."""

from __future__ import annotations

import numpy as np

from ..camera import Camera, check_resolution
from ..checks import check_real
from ..forces import Forces, JointLimits
from ..interop.mujoco import load_mjcf
from ..kinematics import world_poses
from .base import Scene

#: the direction from the model's centre to the default camera, before scaling
VIEW_DIRECTION = np.array([1.0, -1.6, 0.7])


def _limits(model):
    """``{joint name: (low, high), cone angle or a pair or None per stage}`` of the
    joints whose MuJoCo range :class:`~vdad.forces.JointLimits` can hold: one-dof
    and ball joints, and composite joints of hinges and slides."""
    out = {}
    for joint, stages in ((j, j.build_stages()) for j in model.joints):
        kinds = {s.kind for s in stages}
        if joint.limits is None or (len(stages) > 1 and not kinds <= {"hinge", "slide"}):
            continue
        if len(stages) == 1 and stages[0].kind == "ball":
            out[joint.name] = float(joint.limits[1])
        else:
            out[joint.name] = joint.limits
    return out


def framing_camera(model, q, distance=None, resolution=(320, 240)) -> Camera:
    """A camera that sees every body of ``model`` at ``q``: looking at the centre of
    the bodies' origins and centres of mass from a three-quarter view above,
    ``distance`` m away (default: 2.5 times the radius of the sphere around them
    and their geoms' sizes), with ``up`` against gravity (world z without it)."""
    R, p = world_poses(model, q)
    points = np.concatenate([p, p + np.einsum("bij,bj->bi", R, model.com)])
    centre = 0.5 * (points.min(axis=0) + points.max(axis=0))
    size = max([float(np.max(g.size)) for b in model.bodies for g in b.geoms if g.size]
               + [0.05])
    radius = float(np.linalg.norm(points - centre, axis=1).max()) + size
    g = np.asarray(model.gravity, float)
    up = -g / np.linalg.norm(g) + 0.0 if np.any(g) else np.array([0.0, 0.0, 1.0])
    d = 2.5 * radius if distance is None else float(check_real("camera_distance", distance,
                                                                positive=True))
    direction = VIEW_DIRECTION / np.linalg.norm(VIEW_DIRECTION)
    if abs(np.dot(direction, up)) > 0.95:                 # gravity along the view
        direction = np.cross(up, (1.0, 0.0, 0.0)) + np.cross(up, (0.0, 1.0, 0.0))
        direction = direction / np.linalg.norm(direction)
    w, h = check_resolution(resolution, allow_none=False)
    return Camera(position=tuple(centre + d * direction), target=tuple(centre), up=tuple(up),
                  width=w, height=h, znear=0.01 * d, zfar=10 * d + 10 * radius)


def mjcf_scene(path, dt=None, camera_distance=None, resolution=(320, 240)) -> Scene:
    """``docs/mujoco.md``: the MuJoCo model file ``path`` as a scene: the model of
    :func:`~vdad.load_mjcf` (what it leaves out said in its warning), at rest in
    MuJoCo's initial configuration ``qpos0``, with MuJoCo's time step unless
    ``dt``; forces: the imported actuators (controls at zero; set them with
    ``scene.forces.elements[0].set_ctrl``), fixed tendons' springs and dampers,
    gravity compensation, and the ranges of limited one-dof and ball joints as
    :class:`~vdad.forces.JointLimits`; environment: the world's and mocap
    bodies' geoms; camera: :func:`framing_camera` from ``camera_distance``."""
    model, report = load_mjcf(path, report=True)
    elements = list(report.forces)
    limits = _limits(model)
    if limits:
        elements.append(JointLimits(model, limits))
    forces = Forces(model, elements) if elements else None
    q0 = np.array(report.q0, float)
    dt = report.dt if dt is None else float(check_real("dt", dt, positive=True))
    camera = framing_camera(model, q0, camera_distance, resolution)
    return Scene(model.name, f"MuJoCo model {model.name!r} ({model.nb} bodies, {model.nv} "
                 f"dofs) from {path}", model, q0, np.zeros(model.nv), dt,
                 controller=None if forces is None else forces.controller,
                 external=None if forces is None else forces.external, camera=camera,
                 environment=report.environment, forces=forces,
                 params={"path": str(path), "dt": dt, "camera_distance": camera_distance,
                         "resolution": [camera.width, camera.height]})
