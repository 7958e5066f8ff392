"""The swinging pendulum (Kim 2008 §6.1: 20 bodies for Table 1, 300 for Figures 8-9)."""

from __future__ import annotations

import numpy as np

from ..camera import Camera, check_resolution
from ..checks import check_count, check_real
from ..errors import InputError
from ..model import Joint, Model, Pose
from ..spatial import quat_exp
from .base import Scene, rod

# Method defaults calibrated at pendulum()'s defaults (docs/scenes.md, method
# defaults); lod-distance and sleeping keep the generic ones (vdad.simulator.DEFAULTS)
DEFAULTS = {"adaptive": {"threshold": 1e-5}, "view-bvh": {"threshold": 1e-4},
            "view-oq": {"threshold": 3e-5}}


def pendulum(n_bodies=20, link_length=0.1, link_mass=0.1, radius=None, angle=1.0,
             axes="y", joint="revolute", damping=0.0, dt=1e-3, gravity=9.81,
             camera_distance=None, resolution=(320, 240)):
    """A chain of ``n_bodies`` capsule links hanging from a fixed point.

    Each link is a solid capsule-like rod of ``link_mass`` and ``link_length``
    (radius ``radius``, default a tenth of the length), its frame at the joint on
    its top end, pointing down -z. Joints are revolute about ``axes`` (``"y"``:
    a planar swing; ``"alternate"``: y, x, y, ... for motion in 3D) or spherical
    (``joint="spherical"``), with optional viscous ``damping``. The chain is
    released at rest with its first joint at ``angle`` rad (for ``"alternate"``
    the second joint too, at half the angle, so that it swings in 3D).

    The camera looks at the chain's middle along +y (square to the swing plane)
    from ``camera_distance`` (default: the whole chain in view, 1.1 chain
    lengths), at ``resolution`` pixels with a 60 degree vertical field of view.
    Method defaults (:data:`DEFAULTS`, ``docs/scenes.md``): calibrated on the
    20 links at 320 x 240; longer chains seen at more pixels need smaller
    thresholds.
    """
    width, height = check_resolution(resolution, allow_none=False)
    n = check_count("n_bodies", n_bodies)
    for name, value in (("link_length", link_length), ("link_mass", link_mass), ("dt", dt)):
        check_real(name, value, positive=True)
    angle, gravity = float(check_real("angle", angle)), float(check_real("gravity", gravity))
    damping = float(check_real("damping", damping, nonnegative=True))
    if radius is not None:
        check_real("radius", radius, positive=True)
    if axes not in ("y", "alternate"):
        raise InputError(f"axes must be 'y' or 'alternate', got {axes!r}")
    if joint not in ("revolute", "spherical"):
        raise InputError(f"joint must be 'revolute' or 'spherical', got {joint!r}")
    L, m = float(link_length), float(link_mass)
    D = 1.1 * n * L if camera_distance is None else float(
        check_real("camera_distance", camera_distance, positive=True))
    camera = Camera(position=(0.0, -D, -n * L / 2), target=(0.0, 0.0, -n * L / 2),
                    width=width, height=height, znear=0.01 * L,
                    zfar=10 * (D + n * L))
    r = L / 10 if radius is None else float(radius)

    def axis_of(i):
        return np.array([1.0, 0.0, 0.0] if axes == "alternate" and i % 2 else [0.0, 1.0, 0.0])

    bodies, joints = [], []
    for i in range(n):
        bodies.append(rod(f"link{i}", m, (0.0, 0.0, 0.0), (0.0, 0.0, -L), r))
        joints.append(Joint(f"joint{i}", None if i == 0 else f"link{i - 1}", f"link{i}", joint,
                            axis=tuple(axis_of(i)), damping=damping,
                            placement=Pose((0.0, 0.0, 0.0 if i == 0 else -L))))
    model = Model(bodies, joints, gravity=(0.0, 0.0, -gravity), name=f"pendulum{n}")
    q0 = np.array(model.q_neutral)
    first = [(0, angle)] + ([(1, angle / 2)] if axes == "alternate" and n > 1 else [])
    for j, a in first:
        i = model.q_start[j]
        if joint == "revolute":
            q0[i] = a
        else:
            q0[i:i + 4] = quat_exp(a * axis_of(j))
    return Scene("pendulum", f"{n}-link pendulum of {L} m, {m} kg capsule links, released from "
                 f"{angle} rad", model, q0, np.zeros(model.nv), dt, camera=camera,
                 params=dict(n_bodies=n, link_length=L, link_mass=m, radius=r, angle=angle,
                             axes=axes, joint=joint, damping=damping, gravity=gravity,
                             camera_distance=D, resolution=(width, height)),
                 defaults={m: dict(o) for m, o in DEFAULTS.items()})

