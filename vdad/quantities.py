"""Physical quantities of a state: energy and spatial momentum (theory §8 checks).

Body velocities come from :func:`vdad.kinematics.kinematics`; spatial momentum
is expressed in world axes about the world origin, angular part first.
"""

from __future__ import annotations

import numpy as np

from .checks import check_vector
from .dynamics import spring_displacements
from .kinematics import kinematics
from .model import check_configuration, check_model
from .spatial import cross3, mv


def _state(model, q, qd):
    """``(q, qd)`` of ``model``, checked."""
    check_model(model)
    return check_configuration(model, "q", q), check_vector("qd", qd, model.nv)


def kinetic_energy(model, q, qd):
    """``sum_i 1/2 m |v_c|^2 + 1/2 w^T I_c w`` over bodies, plus the rotors'
    ``1/2 armature qd^2`` (``docs/joints.md``, armature)."""
    q, qd = _state(model, q, qd)
    kin = kinematics(model, q, qd)
    w = kin.v[:, :3]
    vc = kin.v[:, 3:] + cross3(w, model.com)
    return 0.5 * float(np.sum(model.mass * np.sum(vc * vc, axis=1))
                       + np.einsum("ki,kij,kj->", w, model.inertia, w)
                       + np.dot(model.armature, qd * qd))


def potential_energy(model, q):
    """Gravity ``-sum m g · c`` plus the joint springs' energy."""
    check_model(model)
    q = check_configuration(model, "q", q)
    kin = kinematics(model, q, np.zeros(model.nv))
    c = kin.p + mv(kin.R, model.com)
    energy = -float(np.sum(model.mass * (c @ model.gravity)))
    for k, _, d in spring_displacements(model, q):
        energy += 0.5 * k * float(np.dot(d, d))
    return energy


def total_energy(model, q, qd):
    """Kinetic plus potential energy."""
    return kinetic_energy(model, q, qd) + potential_energy(model, q)


def spatial_momentum(model, q, qd):
    """Total momentum (6,): (angular about the world origin; linear), world axes."""
    q, qd = _state(model, q, qd)
    kin = kinematics(model, q, qd)
    w_body = kin.v[:, :3]
    vc_body = kin.v[:, 3:] + cross3(w_body, model.com)
    vc = mv(kin.R, vc_body)
    c = kin.p + mv(kin.R, model.com)
    L_com = mv(kin.R, mv(model.inertia, w_body))
    p = model.mass[:, None] * vc
    return np.concatenate([np.sum(L_com + cross3(c, p), axis=0), np.sum(p, axis=0)])
