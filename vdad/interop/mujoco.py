"""MuJoCo interoperability: import compiled models and MJCF files, export to MjSpec.

:func:`from_mujoco` turns a compiled ``mujoco.MjModel`` into a :class:`vdad.Model`
whose ``q``/``qd`` are MuJoCo's ``qpos``/``qvel`` entry by entry (bodies keep
MuJoCo's order, a body's joints become the stages of one vdad joint in MuJoCo's
order, anchors (2), references and springs as in ``mj_kinematics``/``mj_passive``).

:func:`to_mjspec`/:func:`to_mujoco` go the other way, so that MuJoCo can serve as
an independent oracle (anchors §1). MuJoCo numbers bodies depth first, which is
not always vdad's order; the exported model therefore records vdad's body index
of every body in ``body_user`` (and a text element ``vdad_layout`` says so), and
:func:`mujoco_layout` gives the index maps that :func:`mujoco_forward` applies.
On models from anywhere else the maps are the identity.

Conventions converted here (MuJoCo source, ``engine_core_smooth.c``):

* free joint: ``xpos = qpos[0:3]``, ``xquat = qpos[3:7]`` regardless of
  ``body_pos``/``body_quat``, hence an identity placement;                  (1)
* hinge/ball with ``jnt_pos = a``: rotate about the anchor, ``p = a - R a``; (2)
* ``xfrc_applied = (force, torque)`` at the centre of mass in world axes,
  vdad's ``f_ext = (torque, force)``: columns ``[3, 4, 5, 0, 1, 2]``.        (3)

``import vdad`` does not import MuJoCo: every function imports it when called.
"""

from __future__ import annotations

import os
import warnings
from dataclasses import dataclass

import numpy as np

from ..checks import check_finite, check_flag, check_vector, names_text, reject_unknown, show
from ..environment import Environment
from ..errors import InputError, ModelError, UnsupportedFeatureError
from ..joints import BALL, HINGE, TRANSLATION, Stage
from ..model import Body, Geom, Joint, Model, Pose, check_model
from ..spatial import quat_to_rot, rot_to_quat
from .actuation import Actuation, GravityCompensation

LAYOUT_TEXT = "vdad_layout"
_XFRC_FROM_FEXT = [3, 4, 5, 0, 1, 2]


def _name(m, objtype, i, prefix):
    import mujoco

    name = mujoco.mj_id2name(m, objtype, i)
    return name if name else f"{prefix}{i}"


def _unique(name, taken):
    base, k = name, 1
    while name in taken:
        name = f"{base}_{k}"
        k += 1
    taken.add(name)
    return name


def _check_mujoco(m, d=None, name="mjmodel"):
    """An InputError unless ``m`` (argument ``name``) is a ``mujoco.MjModel`` and ``d``
    (if given) a ``mujoco.MjData`` of its size."""
    import mujoco

    if not isinstance(m, mujoco.MjModel):
        raise InputError(f"{name} must be a compiled mujoco.MjModel (e.g. of to_mujoco), got "
                         f"{type(m).__name__}: {show(m)}")
    if d is None:
        return
    if not isinstance(d, mujoco.MjData):
        raise InputError(f"mjdata must be a mujoco.MjData (mujoco.MjData(mjmodel)), got "
                         f"{type(d).__name__}: {show(d)}")
    if (len(d.qpos), len(d.qvel), len(d.xfrc_applied)) != (m.nq, m.nv, m.nbody):
        raise InputError(f"mjdata does not belong to mjmodel: it has nq={len(d.qpos)}, "
                         f"nv={len(d.qvel)}, nbody={len(d.xfrc_applied)}, the model nq={m.nq}, "
                         f"nv={m.nv}, nbody={m.nbody}; make it with mujoco.MjData(mjmodel)")


#: the MuJoCo features that vdad leaves out of an imported model, and what each
#: does in MuJoCo (the :class:`ImportReport`'s notes)
LEFT_OUT = {
    "equality constraints": "connect, weld and coupling constraints between bodies and "
                            "joints: closed loops, which a tree algorithm cannot hold",
    "tendons": "spatial tendons (paths through sites and geoms), and the limits, friction "
               "and armature of fixed tendons (their springs, dampers and actuators are "
               "imported)",
    "actuators": "activation dynamics, muscles, and transmissions other than hinges, slides "
                 "and fixed tendons (the others are imported: ImportReport.actuation)",
    "contacts": "collisions between the model's geoms (a vdad scene adds FloorContact "
                "for the ground)",
    "fluid forces": "drag and lift from opt.density and opt.viscosity",
    "frictionloss": "dry friction in joints",
    "geoms": "heightfields, SDFs and other geoms without vdad geometry: neither drawn nor "
             "counted",
}


@dataclass(frozen=True)
class ImportReport:
    """What :func:`from_mujoco` left out of a model and what it changed.

    ``left_out``: ``((feature, names, what it does in MuJoCo), ...)`` for the
    features of :data:`LEFT_OUT` that the model uses (``names``: the equality
    constraints, tendons, actuators, joints, bodies or geoms concerned);
    ``welded``: names of massless bodies without joints merged into their parent
    body or, below the world, into the environment (MuJoCo's own treatment: such
    a body has no dynamics); ``environment``: the world's geoms, those of bodies
    welded to the world and of mocap bodies (at their initial pose), as world
    geometry (:class:`~vdad.environment.Environment`); ``actuation``: the
    imported actuators and fixed-tendon springs and dampers as a force element
    (:class:`~vdad.interop.actuation.Actuation`; None without any): set its
    ``ctrl``; ``gravcomp``: the gravity compensation as a force element
    (:class:`~vdad.interop.actuation.GravityCompensation`; None without any);
    ``q0``, ``dt``: MuJoCo's initial configuration ``qpos0`` (a free body where
    the MJCF puts it) and time step ``opt.timestep``."""

    model_name: str
    left_out: tuple = ()
    welded: tuple = ()
    environment: Environment = Environment()
    actuation: object = None
    gravcomp: object = None
    q0: tuple = ()
    dt: float = 0.002

    @property
    def forces(self) -> tuple:
        """The imported force elements (:attr:`actuation`, :attr:`gravcomp`), for
        ``vdad.forces.Forces(model, report.forces)``."""
        return tuple(e for e in (self.actuation, self.gravcomp) if e is not None)

    def summary(self, hint="report=True lists what each does, strict=True refuses such "
                           "models") -> str:
        """One line: what was left out, then ``hint`` (what to do)."""
        if not self.left_out:
            return f"MuJoCo model {self.model_name!r}: imported in full"
        parts = "; ".join(f"{feature} ({names_text(names)})" if names else feature
                          for feature, names, _ in self.left_out)
        return f"MuJoCo model {self.model_name!r}: left out {parts}; {hint}"

    def __str__(self):
        lines = [self.summary()]
        for feature, names, note in self.left_out:
            lines.append(f"  {feature}: {note}" + (f" [{len(names)}: {names_text(names, 8)}]"
                                                   if names else ""))
        if self.welded:
            lines.append(f"  welded massless bodies without joints: {names_text(self.welded, 8)}")
        if self.actuation is not None:
            lines.append(f"  imported: {len(self.actuation.names)} actuators and "
                         f"{len(self.actuation.tendon_k)} fixed tendons' springs and dampers "
                         f"(ImportReport.actuation)")
        if self.gravcomp is not None:
            lines.append(f"  imported: gravity compensation of {len(self.gravcomp.bodies)} "
                         f"bodies (ImportReport.gravcomp)")
        if self.environment.geoms:
            lines.append(f"  environment geometry: {len(self.environment.geoms)} geoms of the "
                         f"world, of bodies welded to it and of mocap bodies")
        return "\n".join(lines)


def _names(m, objtype, ids, prefix):
    return tuple(_name(m, objtype, int(i), prefix) for i in ids)


def _left_out(m, actuators, sprung):
    """``[(feature, names), ...]`` of the model-wide features vdad leaves out: those
    that act on the dynamics with ``m.opt.disableflags`` as they are; the
    ``actuators`` that :class:`~vdad.interop.actuation.Actuation` left out, and
    the ids of the fixed tendons whose springs and dampers it holds, ``sprung``."""
    import mujoco

    obj, out = mujoco.mjtObj, []
    flags, off = int(m.opt.disableflags), mujoco.mjtDisableBit
    constraints = not flags & int(off.mjDSBL_CONSTRAINT)
    if m.neq and constraints and not flags & int(off.mjDSBL_EQUALITY):
        out.append(("equality constraints", _names(m, obj.mjOBJ_EQUALITY, range(m.neq),
                                                   "equality")))
    passive = ((m.tendon_stiffness > 0) & (not flags & int(off.mjDSBL_SPRING))
               | (m.tendon_damping > 0) & (not flags & int(off.mjDSBL_DAMPER)))
    passive[sprung] = False
    acting = (passive | (m.tendon_limited != 0) & constraints
              | (m.tendon_frictionloss > 0) & constraints | (m.tendon_armature != 0))
    if np.any(acting):
        out.append(("tendons", _names(m, obj.mjOBJ_TENDON, np.flatnonzero(acting), "tendon")))
    if actuators and not flags & int(off.mjDSBL_ACTUATION):
        out.append(("actuators", actuators))
    collide = np.flatnonzero((m.geom_contype != 0) | (m.geom_conaffinity != 0))
    if constraints and not flags & int(off.mjDSBL_CONTACT) and len(collide) > 1:
        out.append(("contacts", tuple(dict.fromkeys(
            _name(m, obj.mjOBJ_BODY, int(m.geom_bodyid[g]), "body") for g in collide))))
    if m.opt.density > 0 or m.opt.viscosity > 0:
        out.append(("fluid forces", ()))
    friction = np.flatnonzero(m.dof_frictionloss != 0)
    if len(friction) and constraints and not flags & int(off.mjDSBL_FRICTIONLOSS):
        out.append(("frictionloss", tuple(dict.fromkeys(
            _name(m, obj.mjOBJ_JOINT, int(m.dof_jntid[i]), "joint") for i in friction))))
    return out


def _kept(m):
    """Whether each MuJoCo body (nbody,) becomes a vdad body: not the world, not a
    mocap body, not a massless body without joints (those are welded)."""
    keep = (m.body_mocapid < 0) & ((m.body_mass > 0) | (m.body_jntnum > 0))
    keep[0] = False
    return keep


def _frame(offset, p, quat):
    """``(R, p)`` of the frame ``offset`` (R, p) or None (identity) composed with
    ``(p, quat)``."""
    R0, p0 = (np.eye(3), np.zeros(3)) if offset is None else offset
    return R0 @ quat_to_rot(np.asarray(quat, float)), p0 + R0 @ np.asarray(p, float)


def _pose(offset, p, quat):
    """The Pose ``offset`` (R, p) or None (identity) composed with ``(p, quat)``."""
    if offset is None:
        return Pose(tuple(float(x) for x in p), tuple(float(x) for x in quat))
    R, p = _frame(offset, p, quat)
    return Pose(tuple(p.tolist()), R)


def _geoms(m, b, offset, skipped):
    """vdad geometries of MuJoCo body ``b``, posed in the frame ``offset`` (R, p) or
    None (the body's own); the names of geoms without vdad geometry go to
    ``skipped``. A plane becomes a thin box (20 m where its size is 0)."""
    import mujoco

    gt = mujoco.mjtGeom
    sphere, capsule, cylinder, box, ellipsoid, mesh_type, plane = (int(x) for x in (
        gt.mjGEOM_SPHERE, gt.mjGEOM_CAPSULE, gt.mjGEOM_CYLINDER, gt.mjGEOM_BOX,
        gt.mjGEOM_ELLIPSOID, gt.mjGEOM_MESH, gt.mjGEOM_PLANE))
    out = []
    for g in range(m.body_geomadr[b], m.body_geomadr[b] + m.body_geomnum[b]):
        kind = int(m.geom_type[g])
        size = m.geom_size[g]
        pose = _pose(offset, m.geom_pos[g], m.geom_quat[g])
        rgba = tuple(float(x) for x in m.geom_rgba[g])
        if kind == sphere:
            out.append(Geom("sphere", (float(size[0]),), pose, rgba=rgba))
        elif kind in (capsule, cylinder):
            name = "capsule" if kind == capsule else "cylinder"
            out.append(Geom(name, (float(size[0]), float(size[1])), pose, rgba=rgba))
        elif kind == box:
            out.append(Geom("box", tuple(float(x) for x in size), pose, rgba=rgba))
        elif kind == plane:
            R, p = pose.matrix()
            half = (float(size[0]) or 20.0, float(size[1]) or 20.0, 0.005)
            out.append(Geom("box", half, Pose(tuple((p - 0.005 * R[:, 2]).tolist()), R),
                            rgba=rgba))
        elif kind == ellipsoid:
            import trimesh

            mesh = trimesh.creation.icosphere(subdivisions=2, radius=1.0)
            mesh.apply_scale(np.asarray(size, dtype=float))
            out.append(Geom("mesh", (), pose, mesh=mesh, rgba=rgba))
        elif kind == mesh_type:
            import trimesh

            k = m.geom_dataid[g]
            v0, nv = m.mesh_vertadr[k], m.mesh_vertnum[k]
            f0, nf = m.mesh_faceadr[k], m.mesh_facenum[k]
            mesh = trimesh.Trimesh(vertices=np.array(m.mesh_vert[v0:v0 + nv], dtype=float),
                                   faces=np.array(m.mesh_face[f0:f0 + nf]), process=False)
            out.append(Geom("mesh", (), pose, mesh=mesh, rgba=rgba))
        else:
            skipped.append(_name(m, mujoco.mjtObj.mjOBJ_GEOM, g, "geom"))
    return out


def _dof_value(values, adr, n, what, jname, body):
    v = values[adr:adr + n]
    if np.any(v != v[0]):
        raise UnsupportedFeatureError(f"joint {jname!r} of body {body!r}: {what} differs "
                                      f"between its dofs ({v.tolist()}); vdad keeps one value "
                                      f"per joint stage: make them equal in the MJCF")
    return float(v[0])


def _joint_stages(m, b, body, taken, spring_on, damper_on):
    """(kind, stages, limits, name, free) of the joints of MuJoCo body ``b``."""
    import mujoco

    free_type, ball_type, hinge_type = (int(mujoco.mjtJoint.mjJNT_FREE),
                                        int(mujoco.mjtJoint.mjJNT_BALL),
                                        int(mujoco.mjtJoint.mjJNT_HINGE))
    stages, limits, names = [], [], []
    free = False
    j0, nj = m.body_jntadr[b], m.body_jntnum[b]
    for j in range(j0, j0 + nj):
        jname = _name(m, mujoco.mjtObj.mjOBJ_JOINT, j, "joint")
        names.append(jname)
        kind = int(m.jnt_type[j])
        dof, qadr = m.jnt_dofadr[j], m.jnt_qposadr[j]
        ndof = {free_type: 6, ball_type: 3}.get(kind, 1)
        arm = _dof_value(m.dof_armature, dof, ndof, "armature", jname, body)
        if np.any(m.jnt_stiffnesspoly[j] != 0) or np.any(m.dof_dampingpoly[dof:dof + ndof] != 0):
            raise UnsupportedFeatureError(f"joint {jname!r} of body {body!r}: polynomial "
                                          f"stiffness or damping is not supported; remove "
                                          f"stiffnesspoly/dampingpoly from the MJCF")
        if m.jnt_springyield[j] > 0 and m.jnt_stiffness[j] > 0:
            raise UnsupportedFeatureError(f"joint {jname!r} of body {body!r}: plastic springs "
                                          f"(springyield) are not supported; remove "
                                          f"springyield from the MJCF")
        k = float(m.jnt_stiffness[j]) if spring_on else 0.0
        d = _dof_value(m.dof_damping, dof, ndof, "damping", jname, body) if damper_on else 0.0
        anchor = tuple(float(x) for x in m.jnt_pos[j])
        axis = tuple(float(x) for x in m.jnt_axis[j])
        lim = (float(m.jnt_range[j, 0]), float(m.jnt_range[j, 1])) if m.jnt_limited[j] else None
        if kind == free_type:
            if nj > 1:
                raise UnsupportedFeatureError(f"free joint {jname!r} of body {body!r} shares "
                                              f"its body with other joints")
            free = True
            stages += [Stage("translation", stiffness=k, damping=d, armature=arm),
                       Stage("ball", stiffness=k, damping=d, armature=arm)]
            limits.append(None)
        elif kind == ball_type:
            stages.append(Stage("ball", anchor=anchor, stiffness=k, damping=d, armature=arm))
            limits.append(lim)
        else:
            name = "hinge" if kind == hinge_type else "slide"
            stages.append(Stage(name, axis, anchor, float(m.qpos0[qadr]), k, d, arm))
            limits.append(lim)
    if not names:
        return "fixed", (), None, _unique(f"{body}_fixed", taken), False
    name = _unique(names[0], taken)
    if free:
        return "free", tuple(stages), None, name, True
    if len(stages) == 1:
        s = stages[0]
        simple = s.ref == 0.0 and (s.kind == "slide" or not any(s.anchor))
        if simple:
            kind = {"hinge": "revolute", "slide": "prismatic", "ball": "spherical"}[s.kind]
            return kind, tuple(stages), limits[0], name, False
        return "composite", tuple(stages), limits[0], name, False
    return "composite", tuple(stages), (None if all(x is None for x in limits)
                                         else tuple(limits)), name, False


def from_mujoco(m, *, strict=False, report=False):
    """A :class:`vdad.Model` of the compiled ``mujoco.MjModel`` ``m``, with the
    rigid-body dynamics MuJoCo computes for it.

    Bodies keep MuJoCo's order (world body 0 skipped) and ``q``/``qd`` are
    ``qpos``/``qvel`` entry by entry. ``body_pos``/``body_quat`` become the joint
    placement (identity for free joints, (1)); ``body_mass``, ``body_ipos`` and
    ``R diag(body_inertia) R^T`` with ``R`` of ``body_iquat`` the inertial data;
    ``jnt_stiffness``, ``dof_damping``, ``qpos_spring`` and ``opt.gravity`` the
    springs, dampers and gravity (zeroed where ``opt.disableflags`` disables
    them); ``dof_armature`` each stage's rotor inertia
    (:attr:`vdad.Joint.armature`); ranges of limited joints go to
    :attr:`vdad.Joint.limits` (a pair, or one pair or None per stage of a
    composite joint; stored, not enforced). Massless bodies without joints
    (sites, attachment frames, static floors) are welded into their parent body,
    as MuJoCo treats them; mocap bodies and the world's geoms become environment
    geometry. Actuators (without activation dynamics, on hinges, slides and fixed
    tendons), fixed tendons' springs and dampers and gravity compensation become
    force elements (:mod:`vdad.interop.actuation`).

    What vdad cannot model (:data:`LEFT_OUT`: equality constraints, spatial
    tendons and fixed tendons' limits, other actuators, contacts, fluid forces,
    frictionloss, geoms without vdad geometry) is left out with one warning that
    names it, or, with ``strict=True``, refused with
    :class:`vdad.UnsupportedFeatureError`. With ``report=True`` returns ``(model,
    ImportReport)``, the report listing what was left out and welded and holding
    the environment geometry, the force elements, ``qpos0`` and the time step. Refused in any
    case, naming the culprit: massless bodies with joints, free joints below a
    body, armature or damping that differs between the dofs of one joint,
    polynomial or plastic springs.
    """
    import mujoco

    if not isinstance(m, mujoco.MjModel):
        raise InputError(f"from_mujoco takes a compiled mujoco.MjModel, got "
                         f"{type(m).__name__}: {show(m)}; for an MJCF file use "
                         f"vdad.load_mjcf(path)")
    return _import(m, check_flag("strict", strict), check_flag("report", report), 3)


def _import(m, strict, report, stacklevel):
    """:func:`from_mujoco`, its warning ``stacklevel`` frames up (the user's call)."""
    import mujoco

    model_name = bytes(m.names).split(b"\0", 1)[0].decode() or "mujoco"
    obj = mujoco.mjtObj
    flags = int(m.opt.disableflags)
    dsbl = mujoco.mjtDisableBit
    gravity = (np.zeros(3) if flags & int(dsbl.mjDSBL_GRAVITY) else np.array(m.opt.gravity, float))
    spring_on = not flags & int(dsbl.mjDSBL_SPRING)
    damper_on = not flags & int(dsbl.mjDSBL_DAMPER)
    keep, skipped = _kept(m), []
    # host[b]: the vdad body (or None, the world) that MuJoCo body b's frame is
    # fixed to, at pose offset[b] (R, p) in it (None: b's own frame)
    host, offset = [None] * m.nbody, [None] * m.nbody
    names, taken_bodies, taken_joints = {}, set(), set()
    parts, joints, welded = [], [], []
    environment = _geoms(m, 0, None, skipped)
    for b in range(1, m.nbody):
        name = _unique(_name(m, obj.mjOBJ_BODY, b, "body"), taken_bodies)
        p = int(m.body_parentid[b])
        if not keep[b]:                            # welded: to its parent's host
            host[b] = host[p]
            offset[b] = _frame(offset[p], m.body_pos[b], m.body_quat[b])
            if m.body_mocapid[b] < 0:
                welded.append(name)
            geoms = _geoms(m, b, offset[b], skipped)
            if host[b] is None:
                environment += geoms
            else:
                parts[names[host[b]]][4].extend(geoms)
            continue
        mass = float(m.body_mass[b])
        if not mass > 0:
            raise UnsupportedFeatureError(f"body {name!r} has joints but no mass: every vdad "
                                          f"body needs a positive mass; add an <inertial> "
                                          f"element (or geoms with density) to it")
        host[b], names[name] = name, len(parts)
        R = quat_to_rot(np.asarray(m.body_iquat[b], dtype=float))
        inertia = R @ np.diag(np.asarray(m.body_inertia[b], dtype=float)) @ R.T
        parts.append((name, mass, tuple(float(x) for x in m.body_ipos[b]),
                      0.5 * (inertia + inertia.T), _geoms(m, b, None, skipped)))
        kind, stages, limits, jname, free = _joint_stages(m, b, name, taken_joints,
                                                          spring_on, damper_on)
        parent = host[p]
        if free and parent is not None:
            raise UnsupportedFeatureError(f"free joint {jname!r} of body {name!r} hangs "
                                          f"below body {parent!r}; a free joint must join "
                                          f"a body to the world")
        placement = Pose() if free else _pose(offset[p], m.body_pos[b], m.body_quat[b])
        if kind == "composite":
            joint = Joint(jname, parent, name, "composite", placement=placement,
                          stages=stages, limits=limits)
        elif kind == "fixed":
            joint = Joint(jname, parent, name, "fixed", placement=placement)
        else:
            s = stages[-1]
            joint = Joint(jname, parent, name, kind, axis=s.axis, placement=placement,
                          stiffness=s.stiffness, damping=s.damping, limits=limits,
                          armature=s.armature)
        joints.append(joint)
    if not parts:
        raise ModelError(f"MuJoCo model {model_name!r} has no body with mass or joints "
                         f"besides the world")
    bodies = [Body(n, mass, com, inertia, tuple(geoms)) for n, mass, com, inertia, geoms in parts]
    model = Model(bodies, joints, gravity=gravity, q_spring=np.array(m.qpos_spring, float),
                  name=model_name)
    actuation, actuators, sprung = Actuation.of(m, model, spring_on, damper_on)
    index = np.array([names.get(host[b], -1) if keep[b] else -1 for b in range(m.nbody)])
    left_out = (_left_out(m, actuators, sprung)
                + ([("geoms", tuple(skipped))] if skipped else []))
    notes = ImportReport(model_name, tuple((f, n, LEFT_OUT[f]) for f, n in left_out),
                         tuple(welded), Environment(tuple(environment)), actuation,
                         GravityCompensation.of(m, model, index), tuple(m.qpos0.tolist()),
                         float(m.opt.timestep))
    if left_out and strict:
        raise UnsupportedFeatureError(notes.summary("strict=False leaves them out"))
    if left_out:
        warnings.warn(notes.summary(), UserWarning, stacklevel=stacklevel)
    return (model, notes) if report else model


def load_mjcf(path, strict=False, report=False, **unknown):
    """:func:`from_mujoco` of the MJCF file ``path`` (``strict``, ``report`` as
    there)."""
    import mujoco

    reject_unknown("load_mjcf", unknown, ("path", "strict", "report"))
    strict, report = check_flag("strict", strict), check_flag("report", report)
    if not isinstance(path, (str, os.PathLike)):
        raise InputError(f"load_mjcf takes the path of an MJCF file, got "
                         f"{type(path).__name__}: {show(path)}")
    path = os.fspath(path)
    if not os.path.isfile(path):
        raise InputError(f"MJCF file not found: {path!r}")
    try:
        m = mujoco.MjModel.from_xml_path(path)
    except ValueError as exc:
        raise InputError(f"cannot load MJCF file {path!r}: {exc}") from None
    return _import(m, strict, report, 3)


# --- export ----------------------------------------------------------------------------

def _principal_axes(inertia):
    """Moments and quaternion (w,x,y,z) of a right-handed principal frame."""
    moments, V = np.linalg.eigh(np.asarray(inertia, dtype=float))
    if np.linalg.det(V) < 0:
        V[:, 2] = -V[:, 2]
    return moments, rot_to_quat(V)


def _stage_limits(model, j):
    """One (lo, hi) or None per stage of joint ``j`` from :attr:`Joint.limits`."""
    n = int(model.n_stages_joint[j])
    lim = model.joints[j].limits
    if lim is None or n == 0:
        return [None] * n
    if n == 1 and len(lim) == 2 and all(np.isscalar(x) for x in lim):
        return [tuple(float(x) for x in lim)]
    if len(lim) != n:
        raise ModelError(f"joint {model.joint_names[j]!r}: limits {lim} do not give one pair "
                         f"(or None) per stage ({n} stages)")
    return [None if x is None else tuple(float(y) for y in x) for x in lim]


def _is_world_free(model, j, stages):
    """Whether joint ``j`` maps onto one MuJoCo freejoint (1)."""
    if len(stages) != 2 or model.parent[j] >= 0:
        return False
    t, b = stages
    if model.stage_kind[t] != TRANSLATION or model.stage_kind[b] != BALL:
        return False
    return (np.array_equal(model.placement_R[j], np.eye(3)) and not np.any(model.placement_p[j])
            and not np.any(model.stage_anchor[b])
            and model.stage_stiffness[t] == model.stage_stiffness[b]
            and model.stage_damping[t] == model.stage_damping[b]
            and model.stage_armature[t] == model.stage_armature[b])


def _add_geom(spec, body, geom, tag):
    import mujoco

    gt = mujoco.mjtGeom
    R, p = geom.pose.matrix()
    common = dict(pos=p, quat=rot_to_quat(R), rgba=np.asarray(geom.rgba, dtype=float),
                  contype=0, conaffinity=0)
    if geom.kind == "mesh":
        mesh = geom.mesh
        spec.add_mesh(name=tag, uservert=np.asarray(mesh.vertices, float).ravel(),
                      userface=np.asarray(mesh.faces, np.int32).ravel())
        body.add_geom(type=gt.mjGEOM_MESH, meshname=tag, **common)
        return
    size = np.zeros(3)
    size[:len(geom.size)] = geom.size
    kind = {"sphere": gt.mjGEOM_SPHERE, "capsule": gt.mjGEOM_CAPSULE,
            "cylinder": gt.mjGEOM_CYLINDER, "box": gt.mjGEOM_BOX}[geom.kind]
    body.add_geom(type=kind, size=size, **common)


def to_mjspec(model):
    """A ``mujoco.MjSpec`` of ``model`` whose joints are vdad's stages one by one.

    Every hinge/slide/ball stage becomes one MuJoCo joint of the child body (axis,
    anchor as ``pos``, ``ref``, stiffness, damping, ``springref``); a translation
    stage three slides along the joint frame's axes, except that translation +
    ball of a world-rooted free joint with identity placement becomes one
    ``freejoint``. Body ``pos``/``quat`` are the joint placement; inertial data
    come from the eigen-decomposition of the inertia (right-handed). Joint
    limits are copied but MuJoCo's limit constraints, like contacts, are
    disabled (vdad does not enforce them). Geometries are added without
    collisions. The spring reference of ball and free stages cannot be given in
    a spec: :func:`to_mujoco` writes ``qpos_spring`` after compiling.
    """
    import mujoco

    check_model(model)
    spec = mujoco.MjSpec()
    spec.modelname = model.name
    spec.compiler.inertiafromgeom = mujoco.mjtInertiaFromGeom.mjINERTIAFROMGEOM_FALSE
    spec.compiler.alignfree = False
    spec.compiler.degree = False                 # ref, springref, range in radians
    spec.compiler.autolimits = True
    spec.option.gravity = np.asarray(model.gravity, dtype=float)
    dsbl = mujoco.mjtDisableBit
    spec.option.disableflags |= int(dsbl.mjDSBL_CONTACT) | int(dsbl.mjDSBL_LIMIT)
    spec.nuser_body = 1
    jt = mujoco.mjtJoint
    handles = []
    for i in range(model.nb):
        parent = spec.worldbody if model.parent[i] < 0 else handles[model.parent[i]]
        stages = np.flatnonzero(model.stage_joint == i)
        moments, iquat = _principal_axes(model.inertia[i])
        body = parent.add_body(name=model.body_names[i], pos=model.placement_p[i],
                               quat=rot_to_quat(model.placement_R[i]))
        body.mass = float(model.mass[i])
        body.ipos = np.asarray(model.com[i], dtype=float)
        body.iquat = iquat
        body.inertia = moments
        body.explicitinertial = True
        body.userdata = [float(i)]
        handles.append(body)
        name = model.joint_names[i]
        if _is_world_free(model, i, stages):
            t = stages[0]
            fj = body.add_freejoint(name=name)
            fj.stiffness = [model.stage_stiffness[t], 0.0, 0.0]
            fj.damping = [model.stage_damping[t], 0.0, 0.0]
            fj.armature = model.stage_armature[t]
            fj.align = mujoco.mjtAlignFree.mjALIGNFREE_FALSE
        else:
            limits = _stage_limits(model, i)
            for r, s in enumerate(stages):
                kind, q0 = model.stage_kind[s], model.stage_q[s]
                k, d = model.stage_stiffness[s], model.stage_damping[s]
                jname = name if r == 0 else f"{name}:{r}"
                common = dict(stiffness=[k, 0.0, 0.0], damping=[d, 0.0, 0.0],
                              armature=model.stage_armature[s])
                if kind == TRANSLATION:
                    for c in range(3):
                        body.add_joint(name=f"{jname}:{'xyz'[c]}" if c else jname,
                                       type=jt.mjJNT_SLIDE, axis=np.eye(3)[c],
                                       springref=model.q_spring[q0 + c], **common)
                    continue
                if kind == BALL:
                    joint = body.add_joint(name=jname, type=jt.mjJNT_BALL,
                                           pos=model.stage_anchor[s], **common)
                else:
                    joint = body.add_joint(name=jname,
                                           type=jt.mjJNT_HINGE if kind == HINGE
                                           else jt.mjJNT_SLIDE,
                                           axis=model.stage_axis[s], pos=model.stage_anchor[s],
                                           ref=model.stage_ref[s],
                                           springref=model.q_spring[q0], **common)
                if limits[r] is not None:
                    joint.limited = mujoco.mjtLimited.mjLIMITED_TRUE
                    joint.range = np.asarray(limits[r], dtype=float)
        for g, geom in enumerate(model.bodies[i].geoms):
            _add_geom(spec, body, geom, f"{model.body_names[i]}:geom{g}")
    spec.add_text(name=LAYOUT_TEXT, data="body_user[:, 0] is the vdad body index")
    return spec


def mujoco_layout(m):
    """Index maps between vdad's and MuJoCo's layouts of ``m``.

    Returns ``body`` (nb,), ``qpos`` (nq,) and ``qvel`` (nv,): the MuJoCo body id of
    vdad body ``i`` and the ``qpos``/``qvel`` index of each vdad ``q``/``qd``
    entry. MuJoCo's order (the bodies :func:`from_mujoco` keeps, welded ones
    skipped) unless ``m`` came from :func:`to_mujoco`.
    """
    import mujoco

    _check_mujoco(m, name="m")
    nb = m.nbody - 1
    if mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_TEXT, LAYOUT_TEXT) < 0:
        return np.flatnonzero(_kept(m)), np.arange(m.nq), np.arange(m.nv)
    body = np.empty(nb, dtype=int)
    body[np.asarray(m.body_user[1:, 0]).round().astype(int)] = np.arange(1, nb + 1)
    qpos, qvel = [], []
    nq_jnt = np.array([7, 4, 1, 1])[m.jnt_type]
    nv_jnt = np.array([6, 3, 1, 1])[m.jnt_type]
    for b in body:
        j0, nj = m.body_jntadr[b], m.body_jntnum[b]
        if nj:
            qpos.append(m.jnt_qposadr[j0] + np.arange(nq_jnt[j0:j0 + nj].sum()))
            qvel.append(m.jnt_dofadr[j0] + np.arange(nv_jnt[j0:j0 + nj].sum()))
    empty = [np.zeros(0, int)]
    return body, np.concatenate(qpos + empty), np.concatenate(qvel + empty)


def to_mujoco(model):
    """``(mjModel, mjData)`` of :func:`to_mjspec` (``model``), with ``qpos_spring`` set."""
    import mujoco

    m = to_mjspec(check_model(model)).compile()
    _, qpos, _ = mujoco_layout(m)
    m.qpos_spring[qpos] = model.q_spring
    return m, mujoco.MjData(m)


def mujoco_forward(mjmodel, mjdata, q, qd, tau=None, f_ext=None):
    """MuJoCo's ``qacc`` in vdad's layout for vdad's state ``(q, qd)``.

    Sets ``qpos``, ``qvel``, ``qfrc_applied`` (``tau``) and ``xfrc_applied``
    (``f_ext`` (nb, 6): torque about the centre of mass, force; world axes (3)),
    zeroes ``ctrl`` and calls ``mj_forward``. ``mjdata`` is ``mujoco.MjData(mjmodel)``.
    """
    import mujoco

    m, d = mjmodel, mjdata
    _check_mujoco(m, d)
    body, qpos, qvel = mujoco_layout(m)
    q = check_vector("q", q, m.nq)
    qd = check_vector("qd", qd, m.nv)
    tau = check_vector("tau", tau, m.nv, allow_none=True)
    if f_ext is not None:
        f_ext = check_finite("f_ext", f_ext)
        if f_ext.shape != (len(body), 6):
            raise InputError(f"f_ext must have shape ({len(body)}, 6) (torque about the centre "
                             f"of mass; force, world axes), got {f_ext.shape}")
    d.qpos[qpos] = q
    d.qvel[qvel] = qd
    d.qfrc_applied[:] = 0.0
    if tau is not None:
        d.qfrc_applied[qvel] = tau
    d.xfrc_applied[:] = 0.0
    if f_ext is not None:
        d.xfrc_applied[body] = f_ext[:, _XFRC_FROM_FEXT]
    if m.nu:
        d.ctrl[:] = 0.0
    mujoco.mj_forward(m, d)
    return np.array(d.qacc[qvel])


__all__ = ["ImportReport", "LEFT_OUT", "from_mujoco", "load_mjcf", "mujoco_forward",
           "mujoco_layout", "to_mjspec", "to_mujoco"]
