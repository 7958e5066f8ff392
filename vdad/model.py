"""The immutable articulated-body model (Pinocchio's Model, anchors §4).

A :class:`Model` is a forest of rigid bodies. Body ``i`` has exactly one inbound
joint, also numbered ``i``, that joins it to its parent body (or to the world).
Generalised coordinates are laid out joint by joint in body order, each joint's
stages in order (:mod:`vdad.joints`); this matches MuJoCo's ``qpos``/``qvel``
for imported models. State (``q``, ``qd``) and work arrays live elsewhere.

Gravity and external wrenches enter as forces on bodies (theory §1).
"""

from __future__ import annotations

import heapq
from dataclasses import dataclass, field

import numpy as np

from . import joints as J
from .errors import InputError, ModelError
from .spatial import quat_normalize, quat_to_rot


@dataclass(frozen=True)
class Pose:
    """A rigid placement: ``rotation`` (3x3 matrix or quaternion w,x,y,z) and
    ``translation`` (3,), expressed in the parent frame."""

    translation: tuple = (0.0, 0.0, 0.0)
    rotation: object = None

    def matrix(self) -> tuple[np.ndarray, np.ndarray]:
        """``(R, p)``: rotation (3, 3) and translation (3,)."""
        p = np.asarray(self.translation, dtype=float)
        if self.rotation is None:
            R = np.eye(3)
        else:
            rot = np.asarray(self.rotation, dtype=float)
            R = quat_to_rot(quat_normalize(rot)) if rot.shape == (4,) else rot
        return R, p


@dataclass(frozen=True)
class Geom:
    """Geometry attached to a body, for visibility and rendering.

    kind: ``"sphere"`` (size = (radius,)), ``"capsule"`` (radius, half-length
    along z), ``"cylinder"`` (radius, half-length), ``"box"`` (half-extents) or
    ``"mesh"`` (``mesh``: a trimesh.Trimesh). ``pose`` places it in the body frame.
    """

    kind: str
    size: tuple = ()
    pose: Pose = field(default_factory=Pose)
    mesh: object = None
    rgba: tuple = (0.7, 0.7, 0.7, 1.0)

    def to_trimesh(self, sections=None):
        """This geometry as a trimesh.Trimesh in the body frame (imports trimesh).

        sections: tessellation of round shapes, segments around the axis (None:
        trimesh's fine defaults; e.g. 8 gives a 64-triangle capsule and an
        80-triangle sphere, enough to count pixels at a few hundred pixels wide)."""
        import trimesh

        if self.kind == "mesh":
            mesh = self.mesh.copy()
        elif self.kind == "sphere":
            level = 2 if sections is None or sections > 8 else 1
            mesh = trimesh.creation.icosphere(subdivisions=level, radius=self.size[0])
        elif self.kind == "capsule":
            count = {} if sections is None else {"count": [sections, max(2, sections // 2)]}
            mesh = trimesh.creation.capsule(height=2 * self.size[1], radius=self.size[0],
                                            **count)
        elif self.kind == "cylinder":
            mesh = trimesh.creation.cylinder(radius=self.size[0], height=2 * self.size[1],
                                             sections=sections or 32)
        elif self.kind == "box":
            mesh = trimesh.creation.box(extents=2 * np.asarray(self.size, dtype=float))
        else:
            raise ModelError(f"unknown geometry kind {self.kind!r}")
        R, p = self.pose.matrix()
        T = np.eye(4)
        T[:3, :3], T[:3, 3] = R, p
        mesh.apply_transform(T)
        return mesh


@dataclass(frozen=True)
class Body:
    """A rigid body: ``mass``, centre of mass ``com`` and rotational
    ``inertia`` about the centre of mass, both in the body frame."""

    name: str
    mass: float
    com: tuple = (0.0, 0.0, 0.0)
    inertia: object = ((1.0, 0, 0), (0, 1.0, 0), (0, 0, 1.0))
    geoms: tuple = ()


@dataclass(frozen=True)
class Joint:
    """The joint that carries body ``child`` on body ``parent`` (None: world).

    ``kind`` is ``"revolute"``, ``"prismatic"``, ``"spherical"``, ``"free"``,
    ``"fixed"`` or ``"composite"`` (give ``stages`` then). ``placement`` is the
    joint frame in the parent body's frame; at zero joint motion the child body
    frame coincides with it. ``axis``, ``stiffness``, ``damping`` and ``ref``
    are passed to the stage constructors of :mod:`vdad.joints`.
    """

    name: str
    parent: str | None
    child: str
    kind: str = "revolute"
    axis: tuple = (0.0, 0.0, 1.0)
    placement: Pose = field(default_factory=Pose)
    stiffness: float = 0.0
    damping: float = 0.0
    stages: tuple = ()
    limits: tuple | None = None

    def build_stages(self) -> tuple:
        if self.kind == "composite":
            if not self.stages:
                raise ModelError(f"joint {self.name!r}: a composite joint needs stages")
            return tuple(self.stages)
        if self.kind not in J.JOINT_TYPES:
            raise ModelError(f"joint {self.name!r}: unknown kind {self.kind!r}; expected one of "
                             f"{sorted(J.JOINT_TYPES) + ['composite']}")
        make = J.JOINT_TYPES[self.kind]
        if self.kind in ("revolute", "prismatic"):
            return make(axis=self.axis, stiffness=self.stiffness, damping=self.damping)
        if self.kind == "fixed":
            return make()
        return make(stiffness=self.stiffness, damping=self.damping)


def _readonly(a, dtype=float):
    a = np.array(a, dtype=dtype)
    a.setflags(write=False)
    return a


def _check_body(body: Body):
    name = body.name
    if not isinstance(name, str) or not name:
        raise ModelError(f"body name must be a non-empty string, got {name!r}")
    if not np.isfinite(body.mass) or body.mass <= 0:
        raise ModelError(f"body {name!r}: mass must be positive and finite, got {body.mass}")
    com = np.asarray(body.com, dtype=float)
    if com.shape != (3,) or not np.all(np.isfinite(com)):
        raise ModelError(f"body {name!r}: com must be 3 finite numbers, got {body.com}")
    inertia = np.asarray(body.inertia, dtype=float)
    if inertia.shape == (3,):
        inertia = np.diag(inertia)
    if inertia.shape != (3, 3) or not np.all(np.isfinite(inertia)):
        raise ModelError(f"body {name!r}: inertia must be a finite 3x3 matrix or 3 moments")
    scale = max(np.abs(inertia).max(), 1e-300)
    if np.abs(inertia - inertia.T).max() > 1e-9 * scale:
        raise ModelError(f"body {name!r}: inertia is not symmetric")
    inertia = 0.5 * (inertia + inertia.T)
    moments = np.linalg.eigvalsh(inertia)
    if moments[0] <= 0:
        raise ModelError(f"body {name!r}: inertia is not positive definite "
                         f"(principal moments {moments})")
    if moments[0] + moments[1] < moments[2] * (1 - 1e-9):
        raise ModelError(f"body {name!r}: principal moments {moments} violate the triangle "
                         f"inequality I1 + I2 >= I3")
    return com, inertia


def _topological_order(parent_index: list[int | None], names: list[str]) -> list[int]:
    """Body order with parents first, keeping the given order where possible."""
    n = len(parent_index)
    children = [[] for _ in range(n)]
    heap = []
    for i, p in enumerate(parent_index):
        if p is None:
            heap.append(i)
        else:
            children[p].append(i)
    heapq.heapify(heap)
    order = []
    while heap:
        i = heapq.heappop(heap)
        order.append(i)
        for c in children[i]:
            heapq.heappush(heap, c)
    if len(order) < n:
        stuck = sorted(set(range(n)) - set(order))
        raise ModelError("kinematic cycle through bodies "
                         + ", ".join(repr(names[i]) for i in stuck[:8]))
    return order


class Model:
    """An immutable, validated forest of rigid bodies and joints.

    Parameters: ``bodies`` (sequence of :class:`Body`), ``joints`` (sequence of
    :class:`Joint`, one per body), ``gravity`` (3,) in world coordinates,
    ``q_spring`` (optional rest configuration of the joint springs), ``name``.

    Array attributes (read-only; shapes in brackets, nb bodies = nj joints,
    ns stages): ``parent`` [nb] (-1 = world), ``mass`` [nb], ``com`` [nb, 3],
    ``inertia`` [nb, 3, 3], ``placement_R`` [nj, 3, 3], ``placement_p`` [nj, 3],
    ``q_start``/``nq_joint``/``v_start``/``nv_joint`` [nj], per-stage arrays
    ``stage_*`` [ns], ``q_neutral`` [nq], ``q_spring`` [nq].
    """

    def __init__(self, bodies, joints, gravity=(0.0, 0.0, -9.81), q_spring=None, name="model"):
        bodies, joints = list(bodies), list(joints)
        self.name = name
        if not bodies:
            raise ModelError("a model needs at least one body")
        body_names = [b.name for b in bodies]
        checked = [_check_body(b) for b in bodies]
        seen = set()
        for nm in body_names:
            if nm in seen:
                raise ModelError(f"duplicate body name {nm!r}")
            seen.add(nm)
        index = {nm: i for i, nm in enumerate(body_names)}
        joint_of = [None] * len(bodies)
        joint_names = set()
        for jt in joints:
            if jt.name in joint_names:
                raise ModelError(f"duplicate joint name {jt.name!r}")
            joint_names.add(jt.name)
            if jt.child not in index:
                raise ModelError(f"joint {jt.name!r}: unknown child body {jt.child!r}")
            if jt.parent is not None and jt.parent not in index:
                raise ModelError(f"joint {jt.name!r}: unknown parent body {jt.parent!r}")
            if jt.parent == jt.child:
                raise ModelError(f"joint {jt.name!r}: body {jt.child!r} cannot be its own parent")
            c = index[jt.child]
            if joint_of[c] is not None:
                raise ModelError(f"body {jt.child!r} has two inbound joints: "
                                 f"{joint_of[c].name!r} and {jt.name!r}")
            joint_of[c] = jt
        for i, jt in enumerate(joint_of):
            if jt is None:
                raise ModelError(f"body {body_names[i]!r} has no inbound joint "
                                 f"(give it a joint to its parent or to the world)")
        parent_index = [None if jt.parent is None else index[jt.parent] for jt in joint_of]
        order = _topological_order(parent_index, body_names)
        new_index = {old: new for new, old in enumerate(order)}

        self.bodies = tuple(bodies[i] for i in order)
        self.joints = tuple(joint_of[i] for i in order)
        self.body_names = tuple(body_names[i] for i in order)
        self.joint_names = tuple(jt.name for jt in self.joints)
        self.nb = len(order)
        self.parent = _readonly([-1 if parent_index[i] is None else new_index[parent_index[i]]
                                 for i in order], int)
        self.mass = _readonly([bodies[i].mass for i in order])
        self.com = _readonly([checked[i][0] for i in order])
        self.inertia = _readonly([checked[i][1] for i in order])
        self.gravity = _readonly(gravity)
        if self.gravity.shape != (3,) or not np.all(np.isfinite(self.gravity)):
            raise ModelError(f"gravity must be 3 finite numbers, got {gravity}")

        placements, stage_rows, q_start, v_start, nqj, nvj = [], [], [], [], [], []
        nq = nv = 0
        for j, jt in enumerate(self.joints):
            try:
                R, p = jt.placement.matrix()
            except (ValueError, TypeError) as exc:
                raise ModelError(f"joint {jt.name!r}: invalid placement ({exc})") from None
            if (R.shape != (3, 3) or p.shape != (3,) or not np.all(np.isfinite(R))
                    or not np.all(np.isfinite(p))):
                raise ModelError(f"joint {jt.name!r}: placement must be a finite rotation and "
                                 f"translation")
            if np.abs(R.T @ R - np.eye(3)).max() > 1e-9 or np.linalg.det(R) < 0:
                raise ModelError(f"joint {jt.name!r}: placement rotation is not a proper rotation")
            placements.append((R, p))
            q_start.append(nq)
            v_start.append(nv)
            stages = [J.check_stage(s, jt.name) for s in jt.build_stages()]
            if any(s.kind == "translation" for s in stages[1:]) and jt.kind == "composite":
                raise ModelError(f"joint {jt.name!r}: a translation stage must come first")
            for rank, s in enumerate(stages):
                stage_rows.append((j, rank, s.code, s.axis, s.anchor, s.ref, s.stiffness,
                                   s.damping, nq, nv))
                nq += s.nq
                nv += s.nv
            nqj.append(nq - q_start[-1])
            nvj.append(nv - v_start[-1])
            if nvj[-1] > 6:
                raise ModelError(f"joint {jt.name!r}: {nvj[-1]} dofs; a joint has at most 6")
        self.nq, self.nv = nq, nv
        self.placement_R = _readonly([R for R, _ in placements])
        self.placement_p = _readonly([p for _, p in placements])
        self.q_start = _readonly(q_start, int)
        self.v_start = _readonly(v_start, int)
        self.nq_joint = _readonly(nqj, int)
        self.nv_joint = _readonly(nvj, int)
        cols = list(zip(*stage_rows, strict=False)) if stage_rows else [[]] * 10
        self.ns = len(stage_rows)
        self.stage_joint = _readonly(cols[0], int)
        self.stage_rank = _readonly(cols[1], int)
        self.stage_kind = _readonly(cols[2], int)
        self.stage_axis = _readonly(np.reshape(cols[3], (-1, 3)))
        self.stage_anchor = _readonly(np.reshape(cols[4], (-1, 3)))
        self.stage_ref = _readonly(cols[5])
        self.stage_stiffness = _readonly(cols[6])
        self.stage_damping = _readonly(cols[7])
        self.stage_q = _readonly(cols[8], int)
        self.stage_v = _readonly(cols[9], int)
        self.n_stages_joint = _readonly(np.bincount(self.stage_joint, minlength=self.nb), int)

        q0 = np.zeros(nq)
        for s in range(self.ns):
            if self.stage_kind[s] == J.BALL:
                q0[self.stage_q[s]] = 1.0
            elif self.stage_kind[s] in (J.HINGE, J.SLIDE):
                q0[self.stage_q[s]] = self.stage_ref[s]
        self.q_neutral = _readonly(q0)
        if q_spring is None:
            q_spring = q0
        q_spring = np.asarray(q_spring, dtype=float)
        if q_spring.shape != (nq,) or not np.all(np.isfinite(q_spring)):
            raise ModelError(f"q_spring must be {nq} finite numbers")
        self.q_spring = _readonly(q_spring)
        self.children = tuple(tuple(np.flatnonzero(self.parent == i)) for i in range(self.nb))
        self.depth = _readonly(self._depths(), int)
        self.dof_joint = _readonly(np.repeat(np.arange(self.nb), nvj), int)

    def _depths(self):
        depth = np.zeros(self.nb, dtype=int)
        for i in range(self.nb):
            p = self.parent[i]
            depth[i] = 0 if p < 0 else depth[p] + 1
        return depth

    def body_index(self, name: str) -> int:
        """Index of the body called ``name``."""
        try:
            return self.body_names.index(name)
        except ValueError:
            raise ModelError(f"no body called {name!r} in model {self.name!r}") from None

    def joint_index(self, name: str) -> int:
        """Index of the joint called ``name``."""
        try:
            return self.joint_names.index(name)
        except ValueError:
            raise ModelError(f"no joint called {name!r} in model {self.name!r}") from None

    def __repr__(self):
        return (f"Model({self.name!r}, bodies={self.nb}, nq={self.nq}, nv={self.nv}, "
                f"roots={int(np.sum(self.parent < 0))})")


def check_model(model):
    """``model`` checked to be a :class:`Model`."""
    if not isinstance(model, Model):
        raise InputError(f"model must be a vdad.Model, got {type(model).__name__}")
    return model
