"""Pinocchio as an independent oracle for vdad's forward dynamics (anchors §1).

:func:`to_pinocchio` builds a ``pinocchio.Model`` of a vdad model whose joints
are single stages without anchor or reference (revolute, prismatic, spherical,
free) or fixed; :func:`pinocchio_forward` runs ``pinocchio.aba`` on a vdad state
and returns vdad's ``qdd``. Pinocchio has neither vdad's springs nor its
dampers: they enter as ``vdad.passive_forces`` added to ``tau``.

Conventions converted here (vdad: MuJoCo's layout):

* quaternions: vdad (w, x, y, z), Pinocchio (x, y, z, w);
* free joint: vdad's linear velocity ``xd`` is in the joint's placement frame,
  Pinocchio's ``v`` in the body frame, ``v = R^T xd`` with ``R`` the joint's
  rotation; forces transform alike, ``tau_pin = R^T tau``;                     (1)
* free-joint accelerations: ``xdd = R (a + w x v)``;                           (2)
* a fixed joint adds its body's inertia to the parent's Pinocchio joint; a body
  below it hangs on that joint with the composed placement;                    (3)
* external forces: vdad's (torque about the centre of mass; force) in world
  axes become ``pin.Force`` in the local frame of the body's Pinocchio joint,
  about the joint origin.                                                      (4)

``import vdad`` does not import Pinocchio: functions import it when called.
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np

from ..checks import check_vector, check_wrenches, show
from ..dynamics import passive_forces
from ..errors import InputError, UnsupportedFeatureError
from ..joints import BALL, HINGE, SLIDE, STAGE_NAMES, TRANSLATION
from ..model import check_model
from ..spatial import quat_to_rot

_KINDS = {(HINGE,): "revolute", (SLIDE,): "prismatic", (BALL,): "spherical",
          (TRANSLATION, BALL): "free", (): "fixed"}
_PIN_JOINTS = {"revolute": "JointModelRevoluteUnaligned",       # Pinocchio joint of each kind
               "prismatic": "JointModelPrismaticUnaligned",
               "spherical": "JointModelSpherical", "free": "JointModelFreeFlyer"}


@lru_cache(maxsize=64)
def _layout(model):
    """Per body: (kind, Pinocchio joint id, R, p, joint).

    ``R, p``: the body frame in the frame of that Pinocchio joint; ``joint``: None
    for a fixed joint, else (parent joint id, R, p of the joint placement). Joint
    ids follow body order, skipping fixed joints (3); raises
    UnsupportedFeatureError on joints Pinocchio's standard joints cannot express.
    """
    rows, next_id = [], 1
    for i in range(model.nb):
        name = model.joint_names[i]
        stages = np.flatnonzero(model.stage_joint == i)
        codes = tuple(int(model.stage_kind[s]) for s in stages)
        kind = _KINDS.get(codes)
        if kind is None:
            raise UnsupportedFeatureError(
                f"joint {name!r}: stages {' + '.join(STAGE_NAMES[c] for c in codes)} have no "
                f"Pinocchio counterpart (revolute, prismatic, spherical, free or fixed only)")
        for s in stages:
            if model.stage_kind[s] in (HINGE, BALL) and np.any(model.stage_anchor[s]):
                raise UnsupportedFeatureError(f"joint {name!r}: anchor "
                                              f"{tuple(model.stage_anchor[s])} is not supported "
                                              f"(Pinocchio joints turn about their origin)")
            if model.stage_ref[s] != 0:
                raise UnsupportedFeatureError(f"joint {name!r}: nonzero ref "
                                              f"{model.stage_ref[s]} is not supported")
        R, p = model.placement_R[i], model.placement_p[i]
        parent = model.parent[i]
        if parent >= 0:
            _, jid, Rp, pp, _ = rows[parent]
            R, p = Rp @ R, pp + Rp @ p
        else:
            jid = 0
        if kind == "fixed":
            rows.append((kind, jid, R, p, None))
        else:
            rows.append((kind, next_id, np.eye(3), np.zeros(3), (jid, R, p)))
            next_id += 1
    return tuple(rows)


def to_pinocchio(model):
    """A ``pinocchio.Model`` of ``model`` with a joint frame and a body frame per body.

    Joints map to ``JointModelRevoluteUnaligned``, ``JointModelPrismaticUnaligned``,
    ``JointModelSpherical`` and ``JointModelFreeFlyer``; fixed joints merge their
    body into the parent's joint (3). Raises :class:`vdad.UnsupportedFeatureError`
    naming the joint for composite joints, anchors and nonzero ``ref``.
    """
    import pinocchio as pin

    check_model(model)
    moving = np.flatnonzero((model.stage_kind == TRANSLATION) & (model.stage_armature > 0))
    if len(moving):
        raise UnsupportedFeatureError(
            f"joint {model.joint_names[model.stage_joint[moving[0]]]!r}: armature on a "
            f"translation stage; Pinocchio's free-flyer applies armature to body-frame "
            f"linear velocities, vdad (as MuJoCo) to world-frame ones")
    pm = pin.Model()
    pm.name = model.name
    pm.gravity = pin.Motion(np.asarray(model.gravity, dtype=float), np.zeros(3))
    frame_of_joint = {0: 0}
    for i, row in enumerate(_layout(model)):
        kind, jid, R, p, joint = row
        inertia = pin.Inertia(float(model.mass[i]), np.asarray(model.com[i], dtype=float),
                              np.asarray(model.inertia[i], dtype=float))
        name = model.body_names[i]
        if kind == "fixed":
            if jid > 0:
                pm.appendBodyToJoint(jid, inertia, pin.SE3(R, p))
            pm.addBodyFrame(name, jid, pin.SE3(R, p), frame_of_joint[jid])
            continue
        parent_jid, Rp, pp = joint
        axis = np.asarray(model.stage_axis[model.stage_joint == i][0], dtype=float)
        jtype = getattr(pin, _PIN_JOINTS[kind])
        jmodel = jtype(axis) if kind in ("revolute", "prismatic") else jtype()
        new = pm.addJoint(parent_jid, jmodel, pin.SE3(Rp, pp), model.joint_names[i])
        assert new == jid
        frame_of_joint[jid] = pm.addJointFrame(jid, frame_of_joint[parent_jid])
        pm.appendBodyToJoint(jid, inertia, pin.SE3.Identity())
        pm.addBodyFrame(name, jid, pin.SE3.Identity(), frame_of_joint[jid])
    armature = np.zeros(pm.nv)          # isotropic per stage, so frame-free (free joints)
    for i, row in enumerate(_layout(model)):
        if row[0] != "fixed":
            pv, iv, nv = pm.joints[row[1]].idx_v, model.v_start[i], model.nv_joint[i]
            armature[pv:pv + nv] = model.armature[iv:iv + nv]
    pm.armature = armature
    return pm


def _to_pin_state(pmodel, vmodel, q, qd, tau):
    """Pinocchio's q, v, tau of vdad's state and generalised force (1)."""
    qp, vp, taup = np.zeros(pmodel.nq), np.zeros(pmodel.nv), np.zeros(pmodel.nv)
    rot = {}
    for i, row in enumerate(_layout(vmodel)):
        kind, jid = row[0], row[1]
        if kind == "fixed":
            continue
        iq, iv = vmodel.q_start[i], vmodel.v_start[i]
        pq, pv = pmodel.joints[jid].idx_q, pmodel.joints[jid].idx_v
        nv = vmodel.nv_joint[i]
        if kind in ("revolute", "prismatic"):
            qp[pq], vp[pv], taup[pv] = q[iq], qd[iv], tau[iv]
            continue
        off = 3 if kind == "free" else 0
        quat = q[iq + off:iq + off + 4] / np.linalg.norm(q[iq + off:iq + off + 4])
        qp[pq:pq + off] = q[iq:iq + off]
        qp[pq + off:pq + off + 4] = quat[[1, 2, 3, 0]]
        vp[pv:pv + nv], taup[pv:pv + nv] = qd[iv:iv + nv], tau[iv:iv + nv]
        if kind == "free":
            R = rot[i] = quat_to_rot(quat)
            vp[pv:pv + 3] = R.T @ qd[iv:iv + 3]
            taup[pv:pv + 3] = R.T @ tau[iv:iv + 3]
    return qp, vp, taup, rot


def _check_pinocchio(pmodel, pdata, vmodel):
    """An InputError unless ``pmodel`` is a ``pinocchio.Model`` laid out as
    :func:`to_pinocchio` (``vmodel``) (as many body frames as ``vmodel`` has bodies,
    its ``nq``/``nv``, a Pinocchio joint of the kind it makes for each moving joint)
    and ``pdata`` a ``pinocchio.Data`` of its size. Returns ``_layout(vmodel)``."""
    import pinocchio as pin

    if not isinstance(pmodel, pin.Model):
        raise InputError(f"pmodel must be a pinocchio.Model (to_pinocchio(vmodel)), got "
                         f"{type(pmodel).__name__}: {show(pmodel)}")
    if not isinstance(pdata, pin.Data):
        raise InputError(f"pdata must be a pinocchio.Data (pmodel.createData()), got "
                         f"{type(pdata).__name__}: {show(pdata)}")
    check_model(vmodel)
    layout = _layout(vmodel)
    moving = [(i, row[1]) for i, row in enumerate(layout) if row[0] != "fixed"]
    bodies = sum(f.type == pin.FrameType.BODY for f in pmodel.frames)
    got = (bodies, pmodel.njoints - 1, pmodel.nq, pmodel.nv)
    want = (vmodel.nb, len(moving), vmodel.nq, vmodel.nv)
    if got != want:
        raise InputError(f"pmodel does not match vmodel {vmodel.name!r}: it has {got[0]} bodies, "
                         f"{got[1]} moving joints, nq={got[2]}, nv={got[3]}, vmodel {want[0]}, "
                         f"{want[1]}, nq={want[2]}, nv={want[3]}; pass "
                         f"pmodel = to_pinocchio(vmodel)")
    for i, jid in moving:
        got, want = pmodel.joints[jid].shortname(), _PIN_JOINTS[layout[i][0]]
        if got != want:
            raise InputError(f"pmodel does not match vmodel {vmodel.name!r}: its joint {jid} "
                             f"({pmodel.names[jid]!r}) is a {got}, vmodel's joint "
                             f"{vmodel.joint_names[i]!r} needs a {want}; pass "
                             f"pmodel = to_pinocchio(vmodel)")
    # sizes only: pinocchio's Model.check(data) also fails on fresh data of trees whose
    # joints are not in depth-first order, which to_pinocchio keeps (vdad's body order)
    if (len(pdata.oMi), len(pdata.ddq)) != (pmodel.njoints, pmodel.nv):
        raise InputError(f"pdata does not belong to pmodel: it has {len(pdata.oMi)} joints and "
                         f"nv={len(pdata.ddq)}, pmodel {pmodel.njoints} and nv={pmodel.nv}; "
                         f"make it with pmodel.createData()")
    return layout


def pinocchio_forward(pmodel, pdata, vmodel, q, qd, tau=None, f_ext=None):
    """``qdd`` (vdad layout) of vdad model ``vmodel`` by ``pinocchio.aba``.

    ``pmodel``/``pdata``: :func:`to_pinocchio` (``vmodel``) and its data; ``tau``
    (nv,) actuation, to which vdad's springs and dampers are added; ``f_ext``
    (nb, 6) as in :func:`vdad.forward_dynamics`. Body poses for (4) come from
    Pinocchio's own forward kinematics. A ``pmodel`` whose joints do not match
    ``vmodel``'s, or a ``pdata`` of another model, is an :class:`~vdad.InputError`.
    """
    import pinocchio as pin

    layout = _check_pinocchio(pmodel, pdata, vmodel)
    q = check_vector("q", q, vmodel.nq)
    qd = check_vector("qd", qd, vmodel.nv)
    tau = check_vector("tau", tau, vmodel.nv, allow_none=True)
    f_ext = check_wrenches(vmodel, f_ext)
    tau_total = passive_forces(vmodel, q, qd) + (0.0 if tau is None else tau)
    qp, vp, taup, rot = _to_pin_state(pmodel, vmodel, q, qd, tau_total)
    if f_ext is None:
        a = pin.aba(pmodel, pdata, qp, vp, taup)
    else:
        pin.forwardKinematics(pmodel, pdata, qp)
        fext = np.zeros((pmodel.njoints, 6))                        # (linear; angular)
        for i, row in enumerate(layout):
            _, jid, R, p, _ = row
            if jid == 0:
                continue                                            # welded to the world
            Rb = pdata.oMi[jid].rotation @ R                        # body axes in world
            n, f = Rb.T @ f_ext[i, :3], Rb.T @ f_ext[i, 3:]
            n = n + np.cross(vmodel.com[i], f)                      # about the body origin
            fj = R @ f
            fext[jid] += np.concatenate([fj, R @ n + np.cross(p, fj)])
        forces = pin.StdVec_Force()
        for row in fext:
            forces.append(pin.Force(row[:3], row[3:]))
        a = pin.aba(pmodel, pdata, qp, vp, taup, forces)
    qdd = np.zeros(vmodel.nv)
    for i, row in enumerate(layout):
        kind, jid = row[0], row[1]
        if kind == "fixed":
            continue
        iv, nv, pv = vmodel.v_start[i], vmodel.nv_joint[i], pmodel.joints[jid].idx_v
        qdd[iv:iv + nv] = a[pv:pv + nv]
        if kind == "free":
            w, v = vp[pv + 3:pv + 6], vp[pv:pv + 3]
            qdd[iv:iv + 3] = rot[i] @ (a[pv:pv + 3] + np.cross(w, v))   # (2)
    return qdd


__all__ = ["pinocchio_forward", "to_pinocchio"]
