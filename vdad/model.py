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
from dataclasses import dataclass, field, replace

import numpy as np

from . import joints as J
from .checks import check_real, check_vector, real_array, show
from .errors import InputError, ModelError
from .spatial import quat_normalize, quat_to_rot


@dataclass(frozen=True)
class Pose:
    """A rigid placement: ``rotation`` (3x3 matrix or quaternion w,x,y,z; None:
    identity) and ``translation`` (3,), expressed in the parent frame. Checked on
    construction (a proper rotation, a nonzero quaternion, finite numbers) and
    stored as tuples."""

    translation: tuple = (0.0, 0.0, 0.0)
    rotation: object = None

    def __post_init__(self):
        p = check_vector("Pose translation", self.translation, 3, error=ModelError)
        object.__setattr__(self, "translation", tuple(p.tolist()))
        if self.rotation is None:
            return
        rot = real_array("Pose rotation", self.rotation, ModelError)
        if rot.shape == (4,):
            norm = float(np.linalg.norm(rot)) if np.all(np.isfinite(rot)) else np.nan
            if not 0 < norm < np.inf:
                raise ModelError(f"Pose rotation: the quaternion {show(self.rotation)} cannot "
                                 f"be normalised (zero or not finite)")
        elif rot.shape == (3, 3):
            if not np.all(np.isfinite(rot)):
                raise ModelError(f"Pose rotation is not finite: {show(self.rotation)}")
            if np.abs(rot.T @ rot - np.eye(3)).max() > 1e-9 or np.linalg.det(rot) < 0:
                raise ModelError(f"Pose rotation is not a proper rotation (orthonormal, "
                                 f"determinant 1): {show(rot.tolist())}")
        else:
            raise ModelError(f"Pose rotation must be a 3x3 matrix or a quaternion (w, x, y, "
                             f"z), got shape {rot.shape}")
        object.__setattr__(self, "rotation", tuple(map(tuple, rot)) if rot.ndim == 2
                           else tuple(rot.tolist()))

    def matrix(self) -> tuple[np.ndarray, np.ndarray]:
        """``(R, p)``: rotation (3, 3) and translation (3,)."""
        p = np.array(self.translation)
        if self.rotation is None:
            return np.eye(3), p
        rot = np.array(self.rotation)
        return (quat_to_rot(quat_normalize(rot)) if rot.shape == (4,) else rot), p


GEOM_SIZES = {"sphere": (1, "(radius,)"), "capsule": (2, "(radius, half-length)"),
              "cylinder": (2, "(radius, half-length)"), "box": (3, "(3 half-extents)"),
              "mesh": (0, "()")}


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

    def __post_init__(self):
        if not isinstance(self.kind, str) or self.kind not in GEOM_SIZES:
            raise ModelError(f"unknown geometry kind {show(self.kind)}; expected one of "
                             f"{sorted(GEOM_SIZES)}")
        n, meaning = GEOM_SIZES[self.kind]
        size = real_array(f"{self.kind} geom size", self.size, ModelError).ravel()
        if len(size) != n:
            raise ModelError(f"a {self.kind} geom takes size = {meaning}, got {show(self.size)}")
        if n and not np.all((size > 0) & np.isfinite(size)):
            raise ModelError(f"a {self.kind} geom's size {meaning} must be positive and "
                             f"finite, got {show(self.size)}")
        object.__setattr__(self, "size", tuple(size.tolist()))
        if self.kind == "mesh" and not (hasattr(self.mesh, "vertices")
                                        and hasattr(self.mesh, "faces")):
            raise ModelError(f"a mesh geom needs mesh= a trimesh.Trimesh, got "
                             f"{show(self.mesh)}")
        if not isinstance(self.pose, Pose):
            raise ModelError(f"geom pose must be a vdad.Pose, got {type(self.pose).__name__}")
        rgba = check_real("geom rgba", self.rgba, (4,), nonnegative=True, error=ModelError)
        if np.any(rgba > 1):
            raise ModelError(f"geom rgba must be 4 numbers in [0, 1], got {show(self.rgba)}")
        object.__setattr__(self, "rgba", tuple(rgba.tolist()))

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
        else:
            mesh = trimesh.creation.box(extents=2 * np.asarray(self.size, dtype=float))
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

    def __post_init__(self):
        name = self.name
        if not isinstance(name, str) or not name:
            raise ModelError(f"body name must be a non-empty string, got {show(name)}")
        what = f"body {name!r}:"
        mass = check_real(f"{what} mass", self.mass, positive=True, error=ModelError)
        com = check_vector(f"{what} com", self.com, 3, error=ModelError)
        inertia = real_array(f"{what} inertia", self.inertia, ModelError)
        if inertia.shape == (3,):
            inertia = np.diag(inertia)
        if inertia.shape != (3, 3) or not np.all(np.isfinite(inertia)):
            raise ModelError(f"{what} inertia must be a finite 3x3 matrix or 3 moments, got "
                             f"{show(self.inertia)}")
        scale = max(np.abs(inertia).max(), 1e-300)
        if np.abs(inertia - inertia.T).max() > 1e-9 * scale:
            raise ModelError(f"{what} inertia is not symmetric")
        inertia = 0.5 * (inertia + inertia.T)
        moments = np.linalg.eigvalsh(inertia)
        if moments[0] <= 0:
            raise ModelError(f"{what} inertia is not positive definite (principal moments "
                             f"{moments})")
        if moments[0] + moments[1] < moments[2] * (1 - 1e-9):
            raise ModelError(f"{what} principal moments {moments} violate the triangle "
                             f"inequality I1 + I2 >= I3")
        geoms = self.geoms
        if isinstance(geoms, Geom) or not isinstance(geoms, (tuple, list)):
            raise ModelError(f"{what} geoms must be a tuple of vdad.Geom, got {show(geoms)}")
        for g in geoms:
            if not isinstance(g, Geom):
                raise ModelError(f"{what} geoms must be vdad.Geom objects, got {show(g)}")
        object.__setattr__(self, "mass", float(mass))
        object.__setattr__(self, "com", tuple(com.tolist()))
        object.__setattr__(self, "inertia", tuple(map(tuple, inertia.tolist())))
        object.__setattr__(self, "geoms", tuple(geoms))


@dataclass(frozen=True)
class Joint:
    """The joint that carries body ``child`` on body ``parent`` (None: world).

    ``kind`` is ``"revolute"``, ``"prismatic"``, ``"spherical"``, ``"free"``,
    ``"fixed"`` or ``"composite"`` (give ``stages`` then). ``placement`` is the
    joint frame in the parent body's frame; at zero joint motion the child body
    frame coincides with it. ``axis``, ``stiffness``, ``damping`` and
    ``armature`` (rotor inertia on each dof) are passed to the stage
    constructors of :mod:`vdad.joints`.
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
    armature: float = 0.0

    def __post_init__(self):
        if not isinstance(self.name, str) or not self.name:
            raise ModelError(f"joint name must be a non-empty string, got {show(self.name)}")
        what = f"joint {self.name!r}:"
        if not isinstance(self.child, str) or not self.child:
            raise ModelError(f"{what} child must be a body name, got {show(self.child)}")
        if self.parent is not None and not isinstance(self.parent, str):
            raise ModelError(f"{what} parent must be a body name or None (the world), got "
                             f"{show(self.parent)}")
        kinds = sorted(J.JOINT_TYPES) + ["composite"]
        if not isinstance(self.kind, str) or self.kind not in kinds:
            raise ModelError(f"{what} unknown kind {show(self.kind)}; expected one of {kinds}")
        axis = check_vector(f"{what} axis", self.axis, 3, error=ModelError)
        if self.kind in ("revolute", "prismatic") and np.linalg.norm(axis) < 1e-12:
            raise ModelError(f"{what} zero axis {tuple(axis)}")
        if not isinstance(self.placement, Pose):
            raise ModelError(f"{what} placement must be a vdad.Pose (e.g. Pose((0, 0, -1))), "
                             f"got {type(self.placement).__name__}: {show(self.placement)}")
        gains = {k: float(check_real(f"{what} {k}", getattr(self, k), nonnegative=True,
                                     error=ModelError))
                 for k in ("stiffness", "damping", "armature")}
        if self.kind == "fixed" and any(gains.values()):
            raise ModelError(f"{what} a fixed joint has no dofs: stiffness, damping and "
                             f"armature do not apply")
        if self.kind == "composite" and any(gains.values()):
            raise ModelError(f"{what} a composite joint takes stiffness, damping and armature "
                             f"per stage (vdad.joints.Stage), not per joint")
        stages = self.stages
        if not isinstance(stages, (tuple, list)):
            raise ModelError(f"{what} stages must be a tuple of vdad.joints.Stage, got "
                             f"{show(stages)}")
        if stages and self.kind != "composite":
            raise ModelError(f"{what} stages apply to kind='composite' only")
        if not stages and self.kind == "composite":
            raise ModelError(f"{what} a composite joint needs stages")
        for r, stage in enumerate(stages):
            if not isinstance(stage, J.Stage):
                raise ModelError(f"{what} stage {r} must be a vdad.joints.Stage (e.g. from "
                                 f"vdad.joints.revolute(...)), got {show(stage)}")
        object.__setattr__(self, "axis", tuple(axis.tolist()))
        object.__setattr__(self, "stages", tuple(stages))
        for k, v in gains.items():
            object.__setattr__(self, k, v)
        object.__setattr__(self, "limits", self._checked_limits())

    def _checked_limits(self):
        """:attr:`limits` as ``(low, high)`` floats with ``low < high``, or, for a
        composite joint, one such pair or None per stage."""
        lim, what = self.limits, f"joint {self.name!r}: limits"
        if lim is None:
            return None
        n_stages = len(self.stages) if self.kind == "composite" else 1
        if self.kind in ("free", "fixed"):
            raise ModelError(f"{what}: a {self.kind} joint has no limits")

        def pair(x, label):
            a = real_array(label, x, ModelError)
            if a.shape != (2,) or not np.all(np.isfinite(a)) or not a[0] < a[1]:
                raise ModelError(f"{label} must be (low, high) with low < high, got {show(x)}")
            return tuple(a.tolist())

        if isinstance(lim, (str, bytes)) or not hasattr(lim, "__len__"):
            raise ModelError(f"{what} must be (low, high), got {show(lim)}")
        if len(lim) == 2 and all(np.isscalar(x) for x in lim):
            if n_stages != 1:
                raise ModelError(f"{what}: a joint of {n_stages} stages takes one (low, high) "
                                 f"or None per stage, got {show(lim)}")
            return pair(lim, what)
        if self.kind != "composite" or len(lim) != n_stages:
            raise ModelError(f"{what} must be (low, high)"
                             + (f" or one pair or None per stage ({n_stages})"
                                if self.kind == "composite" else "") + f", got {show(lim)}")
        return tuple(None if x is None else pair(x, f"{what}[{r}]") for r, x in enumerate(lim))

    def build_stages(self) -> tuple:
        """The joint's stages (:mod:`vdad.joints`)."""
        if self.kind == "composite":
            return self.stages
        make = J.JOINT_TYPES[self.kind]
        if self.kind == "fixed":
            return make()
        gains = dict(stiffness=self.stiffness, damping=self.damping, armature=self.armature)
        return make(axis=self.axis, **gains) if self.kind in ("revolute", "prismatic") else (
            make(**gains))


def _sequence_of(name, items, cls):
    """``items`` as a list of ``cls`` objects, or a ModelError naming ``name``."""
    if isinstance(items, (str, bytes, dict)) or not hasattr(items, "__iter__"):
        raise ModelError(f"{name} must be a sequence of vdad.{cls.__name__}, got "
                         f"{show(items)}")
    items = list(items)
    for k, item in enumerate(items):
        if not isinstance(item, cls):
            raise ModelError(f"{name}[{k}] must be a vdad.{cls.__name__}, got "
                             f"{type(item).__name__}: {show(item)}")
    return items


def _readonly(a, dtype=float):
    a = np.array(a, dtype=dtype)
    a.setflags(write=False)
    return a


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


class Immutable:
    """An object that never changes after construction: :func:`copy.copy` and
    :func:`copy.deepcopy` return it. A copy would be useless, and it would also
    lose the read-only flags of its arrays, a different array type for numba:
    every kernel it reaches would compile again (two minutes for the adaptive
    passes)."""

    def __copy__(self):
        return self

    def __deepcopy__(self, memo):
        return self


class Model(Immutable):
    """An immutable, validated forest of rigid bodies and joints.

    Parameters: ``bodies`` (sequence of :class:`Body`), ``joints`` (sequence of
    :class:`Joint`, one per body), ``gravity`` (3,) in world coordinates,
    ``q_spring`` (optional rest configuration of the joint springs), ``name``.

    Array attributes (read-only; shapes in brackets, nb bodies = nj joints,
    ns stages): ``parent`` [nb] (-1 = world), ``mass`` [nb], ``com`` [nb, 3],
    ``inertia`` [nb, 3, 3], ``placement_R`` [nj, 3, 3], ``placement_p`` [nj, 3],
    ``q_start``/``nq_joint``/``v_start``/``nv_joint`` [nj], per-stage arrays
    ``stage_*`` [ns], ``q_neutral`` [nq], ``q_spring`` [nq], ``armature`` [nv]
    (rotor inertia per dof, ``docs/joints.md``), ``ball_q`` (the first ``q`` index
    of every ball stage's quaternion).
    """

    def __init__(self, bodies, joints, gravity=(0.0, 0.0, -9.81), q_spring=None, name="model"):
        bodies = _sequence_of("bodies", bodies, Body)
        joints = _sequence_of("joints", joints, Joint)
        if not isinstance(name, str) or not name:
            raise ModelError(f"the model's name must be a non-empty string, got {show(name)}")
        self.name = name
        if not bodies:
            raise ModelError("a model needs at least one body")
        body_names = [b.name for b in bodies]
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
        self.com = _readonly([bodies[i].com for i in order])
        self.inertia = _readonly([bodies[i].inertia for i in order])
        self.gravity = _readonly(check_vector("gravity", gravity, 3, error=ModelError))

        placements, stage_rows, q_start, v_start, nqj, nvj = [], [], [], [], [], []
        nq = nv = 0
        for j, jt in enumerate(self.joints):
            placements.append(jt.placement.matrix())
            q_start.append(nq)
            v_start.append(nv)
            stages = [J.check_stage(s, jt.name) for s in jt.build_stages()]
            if any(s.kind == "translation" for s in stages[1:]) and jt.kind == "composite":
                raise ModelError(f"joint {jt.name!r}: a translation stage must come first")
            for rank, s in enumerate(stages):
                stage_rows.append((j, rank, s.code, s.axis, s.anchor, s.ref, s.stiffness,
                                   s.damping, nq, nv, s.armature))
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
        cols = list(zip(*stage_rows, strict=False)) if stage_rows else [[]] * 11
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
        self.stage_armature = _readonly(cols[10])
        self.n_stages_joint = _readonly(np.bincount(self.stage_joint, minlength=self.nb), int)
        self.ball_q = _readonly(self.stage_q[self.stage_kind == J.BALL], int)

        q0 = np.zeros(nq)
        for s in range(self.ns):
            if self.stage_kind[s] == J.BALL:
                q0[self.stage_q[s]] = 1.0
            elif self.stage_kind[s] in (J.HINGE, J.SLIDE):
                q0[self.stage_q[s]] = self.stage_ref[s]
        self.q_neutral = _readonly(q0)
        self.q_spring = _readonly(q0 if q_spring is None else
                                  check_configuration(self, "q_spring", q_spring, ModelError))
        self.children = tuple(tuple(np.flatnonzero(self.parent == i)) for i in range(self.nb))
        self.depth = _readonly(self._depths(), int)
        self.dof_joint = _readonly(np.repeat(np.arange(self.nb), nvj), int)
        self.armature = _readonly(np.repeat(self.stage_armature,
                                            np.asarray(J.STAGE_NV, int)[self.stage_kind]))

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


def with_implicit_damping(model, dt):
    """The model whose semi-implicit Euler step integrates its joint dampers
    implicitly (MuJoCo's implicit damping in its Euler integrator;
    ``docs/joints.md``, "Implicit damping"): every damped stage carries
    ``dt * damping`` more armature. A step of ``qd+ = qd + dt qdd`` with ``(M +
    dt D) qdd = tau - D qd - ...`` is backward Euler in the damper's velocity,
    ``M (qd+ - qd) = dt (... - D qd+)``, stable and dissipative for any ``D >=
    0`` and ``dt``; every other force stays as explicit as before. ``model``
    itself where no stage is damped. The returned model is for the step's
    solve only: its energy counts the added armature."""
    check_model(model)
    dt = float(check_real("dt", dt, positive=True))
    if not np.any(model.stage_damping):
        return model

    def heavier(part):
        return replace(part, armature=part.armature + dt * part.damping)

    joints = [replace(jt, stages=tuple(heavier(s) for s in jt.stages))
              if jt.kind == "composite" else heavier(jt) for jt in model.joints]
    return Model(model.bodies, joints, model.gravity, model.q_spring, model.name)


def check_model(model):
    """``model`` checked to be a :class:`Model`."""
    if not isinstance(model, Model):
        raise InputError(f"model must be a vdad.Model, got {type(model).__name__}")
    return model


def whole_index(model, b):
    """``b`` as a body (or joint) index of ``model`` if it is a whole number (not a
    boolean) in range, else None."""
    if isinstance(b, (bool, np.bool_)):
        return None
    if isinstance(b, (int, np.integer)) or (isinstance(b, (float, np.floating))
                                            and float(b).is_integer()):
        return int(b) if 0 <= b < model.nb else None
    return None


def body_indices(model, bodies, name="bodies"):
    """Body indices (k,), k >= 1, from a body name or index or a sequence of them,
    checked."""
    if isinstance(bodies, (str, int, np.integer, float, np.floating)) \
            and not isinstance(bodies, (bool, np.bool_)):
        bodies = [bodies]
    if isinstance(bodies, np.ndarray) and bodies.ndim <= 1:
        bodies = np.atleast_1d(bodies).tolist()
    if not isinstance(bodies, (list, tuple, range)):
        raise InputError(f"{name} must be a body name or index or a list of them, got "
                         f"{type(bodies).__name__}: {show(bodies)}")
    if not len(bodies):
        raise InputError(f"{name} is empty: give at least one body of {model.name!r}")
    out = []
    for b in bodies:
        i = model.body_index(b) if isinstance(b, str) else whole_index(model, b)
        if i is None:
            raise InputError(f"{name}: {b!r} is neither a body name nor a body index of "
                             f"{model.name!r} (0..{model.nb - 1})")
        out.append(i)
    return np.array(out, int)


def check_configuration(model, name, q, error=InputError):
    """``q`` as a finite configuration vector (nq,) of ``model`` whose quaternions
    (ball stages) can be normalised, or an error naming ``name`` and the joint."""
    q = check_vector(name, q, model.nq, error=error)
    balls = model.ball_q                                            # first entry of each
    if len(balls):
        norms = np.linalg.norm(q[balls[:, None] + np.arange(4)], axis=1)
        zero = np.flatnonzero(~(norms > 1e-150))
        if len(zero):
            i = balls[zero[0]]
            joint = model.joint_names[model.stage_joint[model.stage_q == i][0]]
            raise error(f"{name}[{i}:{i + 4}], the quaternion of joint {joint!r}, is zero "
                        f"({show(q[i:i + 4].tolist())}); a rotation needs a nonzero "
                        f"quaternion (w, x, y, z), e.g. (1, 0, 0, 0)")
    return q
