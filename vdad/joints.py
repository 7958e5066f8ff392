"""Joint types as sequences of elementary stages (theory §3, (T4)-(T5)).

Every joint is a chain of *stages* joined by massless frames: a hinge or a slide
about a fixed axis, a ball (quaternion position) about an anchor point, or a
free translation. Revolute, prismatic and spherical joints have one stage, a free
joint has two (translation in the parent frame, then a ball: MuJoCo's ``qpos`` and
``qvel`` layout), and a body with several MuJoCo joints becomes one composite
joint whose stages follow MuJoCo's order. A fixed joint has none.

For a joint with stages ``r = 1..m`` and stage subspaces ``s_r`` in their own
post-stage frames, the joint's motion subspace in the child frame is
``S = [X_{child<-r} s_r]`` and the velocity-product term of (T4) is

    c_J = crm(v_child) S qd + sum_{r<j} crm(S_r qd_r) S_j qd_j             (J1)

(derived in ``docs/joints.md``); the second sum vanishes for one-stage joints.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .checks import check_real, check_vector
from .errors import ModelError

HINGE, SLIDE, BALL, TRANSLATION = 0, 1, 2, 3
STAGE_NAMES = ("hinge", "slide", "ball", "translation")
STAGE_NQ = (1, 1, 4, 3)
STAGE_NV = (1, 1, 3, 3)


@dataclass(frozen=True)
class Stage:
    """One elementary motion of a joint, defined in the joint's moving frame.

    kind: ``"hinge"``, ``"slide"``, ``"ball"`` or ``"translation"``.
    axis: unit axis (hinge, slide), normalised on construction.
    anchor: the point a hinge or ball turns about (MuJoCo's joint ``pos``).
    ref: position at which a hinge or slide is at its zero (MuJoCo's ``ref``).
    stiffness: spring constant towards the model's ``q_spring`` (ball: on the
        rotation vector, as MuJoCo).
    damping: viscous damping on every dof of the stage.
    armature: rotor inertia on every dof of the stage (MuJoCo's ``armature``):
        a joint-space inertia added to the mass matrix's diagonal
        (``docs/joints.md``, armature).
    """

    kind: str
    axis: tuple = (0.0, 0.0, 1.0)
    anchor: tuple = (0.0, 0.0, 0.0)
    ref: float = 0.0
    stiffness: float = 0.0
    damping: float = 0.0
    armature: float = 0.0

    def __post_init__(self):
        if not isinstance(self.kind, str) or self.kind not in STAGE_NAMES:
            raise ModelError(f"unknown stage kind {self.kind!r}; expected one of {STAGE_NAMES}")
        what = f"{self.kind} stage"
        for name in ("axis", "anchor"):
            v = check_vector(f"{what} {name}", getattr(self, name), 3, error=ModelError)
            object.__setattr__(self, name, tuple(v.tolist()))
        object.__setattr__(self, "ref", float(check_real(f"{what} ref", self.ref,
                                                         error=ModelError)))
        for name in ("stiffness", "damping", "armature"):
            object.__setattr__(self, name, float(check_real(
                f"{what} {name}", getattr(self, name), nonnegative=True, error=ModelError)))

    @property
    def code(self) -> int:
        return STAGE_NAMES.index(self.kind)

    @property
    def nq(self) -> int:
        return STAGE_NQ[self.code]

    @property
    def nv(self) -> int:
        return STAGE_NV[self.code]


def check_stage(stage: Stage, joint: str) -> Stage:
    """``stage`` of ``joint`` (a :class:`Stage`, checked on construction) with a
    unit axis; a hinge or slide about a zero axis is a ModelError."""
    axis = np.array(stage.axis)
    norm = np.linalg.norm(axis)
    if stage.kind in ("hinge", "slide") and norm < 1e-12:
        raise ModelError(f"joint {joint!r}: zero axis {tuple(axis)}")
    unit = tuple(axis / norm) if norm > 0 else (0.0, 0.0, 1.0)
    return Stage(stage.kind, unit, stage.anchor, stage.ref, stage.stiffness, stage.damping,
                 stage.armature)


def revolute(axis=(0, 0, 1), anchor=(0, 0, 0), stiffness=0.0, damping=0.0, ref=0.0,
             armature=0.0):
    """Stages of a revolute (hinge) joint about ``axis`` through ``anchor``."""
    return (Stage("hinge", axis, anchor, ref, stiffness, damping, armature),)


def prismatic(axis=(0, 0, 1), stiffness=0.0, damping=0.0, ref=0.0, armature=0.0):
    """Stages of a prismatic (slide) joint along ``axis``."""
    return (Stage("slide", axis, ref=ref, stiffness=stiffness, damping=damping,
                  armature=armature),)


def spherical(anchor=(0, 0, 0), stiffness=0.0, damping=0.0, armature=0.0):
    """Stages of a spherical (ball) joint: quaternion position, body-frame rate."""
    return (Stage("ball", anchor=anchor, stiffness=stiffness, damping=damping,
                  armature=armature),)


def free(stiffness=0.0, damping=0.0, armature=0.0):
    """Stages of a free joint: position and linear velocity in the parent frame,
    quaternion and angular velocity in the body frame (MuJoCo's layout)."""
    return (Stage("translation", stiffness=stiffness, damping=damping, armature=armature),
            Stage("ball", stiffness=stiffness, damping=damping, armature=armature))


def fixed():
    """Stages of a fixed (weld) joint: none."""
    return ()


JOINT_TYPES = {"revolute": revolute, "prismatic": prismatic, "spherical": spherical,
               "free": free, "fixed": fixed}


def stage_subspace(kind: int, axis, anchor):
    """Motion subspace ``s`` (6, nv) of one stage in its post-stage frame."""
    axis = np.asarray(axis, dtype=float)
    anchor = np.asarray(anchor, dtype=float)
    if kind == HINGE:
        return np.concatenate([axis, np.cross(anchor, axis)])[:, None]
    if kind == SLIDE:
        return np.concatenate([np.zeros(3), axis])[:, None]
    if kind == BALL:
        from .spatial import skew
        return np.vstack([np.eye(3), skew(anchor)])
    return np.vstack([np.zeros((3, 3)), np.eye(3)])


def complement(S):
    """``T`` and ``W`` of (T5) for subspaces ``S`` (k, 6, d).

    ``T`` (k, 6, 6-d) is an orthonormal basis of null(S^T) and
    ``W = S (S^T S)^-1`` (k, 6, d), so that ``S^T W = 1`` and ``S^T T = 0``.
    """
    d = S.shape[-1]
    U = np.linalg.svd(S, full_matrices=True)[0]
    T = U[..., :, d:]
    W = S @ np.linalg.inv(np.swapaxes(S, -1, -2) @ S) if d else S
    return T, W
