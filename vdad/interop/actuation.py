"""MuJoCo's actuators and fixed tendons as a vdad joint-space force element.

MuJoCo (``engine_forward.c``, ``engine_passive.c``) turns the controls ``ctrl``
(nu,) into joint forces through a transmission: an actuator on a hinge or slide
joint has length ``l = gear q`` and moment ``gear``; on a fixed tendon, whose
length is ``L = sum_i coef_i q_i``, length ``gear L`` and moment ``gear coef``.
With ``lv`` the length's rate, an actuator without activation dynamics exerts

    F = (g0 + g1 l + g2 lv) ctrl + (b0 + b1 l + b2 lv),                       (A1)

``g`` and ``b`` the first three ``gainprm`` and ``biasprm`` (``gaintype`` fixed:
``g1 = g2 = 0``; ``biastype`` none: ``b = 0``), ``ctrl`` clamped to
``ctrlrange`` and ``F`` to ``forcerange`` where limited; the joints receive
``moment^T F``, clamped per joint to ``actfrcrange`` where limited. A fixed
tendon's spring and damper pull with ``f = k (s - L) - d Lv``, ``s`` the nearer
end of ``lengthspring = [low, high]`` when ``L`` leaves it (zero inside), and
the joints receive ``coef f``. Motor, position, velocity and affine general
actuators are all (A1); activation dynamics, muscles and other transmissions
are left out by :func:`vdad.from_mujoco` (its report names them).

``import vdad`` does not import MuJoCo; :meth:`Actuation.of` reads a compiled
``mujoco.MjModel``.
"""

from __future__ import annotations

import numpy as np

from ..checks import check_vector

#: the joint types an actuator or a fixed tendon may act on: mjJNT_SLIDE, mjJNT_HINGE
HINGE_SLIDE = (2, 3)


class Actuation:
    """Actuators and fixed-tendon springs and dampers of a MuJoCo model, as a
    joint-space force element (``tau(t, q, qd, out)``, ``energy(q)``) of
    :class:`vdad.forces.Forces`: its ``controller`` gives the joint forces that
    ``mj_forward`` adds as ``qfrc_actuator`` and the tendons' part of
    ``qfrc_passive``. ``ctrl`` (nu,): the controls, zero until set with
    :meth:`set_ctrl`; ``names``: the actuators' names, ``ids`` their MuJoCo
    indices (``act.set_ctrl(mjdata.ctrl[act.ids])`` takes MuJoCo's controls)."""

    def __init__(self, model, names, ids, length_q, moment, gain, bias, ctrl_range, force_range,
                 joint_range, tendon_q, tendon_v, tendon_k, tendon_d, tendon_rest):
        self.model, self.names, self.ids = model, tuple(names), np.asarray(ids, np.int64)
        self.length_q, self.moment = length_q, moment          # (nu, nq), (nu, nv)
        self.gain, self.bias = gain, bias                      # (nu, 3): constant, l, lv
        self.ctrl_range, self.force_range = ctrl_range, force_range    # (nu, 2), +-inf: none
        self.joint_range = joint_range                         # (nv, 2): actfrcrange per dof
        self.tendon_q, self.tendon_v = tendon_q, tendon_v      # (nt, nq), (nt, nv)
        self.tendon_k, self.tendon_d, self.tendon_rest = tendon_k, tendon_d, tendon_rest
        self.ctrl = np.zeros(len(self.names))

    @classmethod
    def of(cls, m, model, spring_on=True, damper_on=True):
        """The actuation of the compiled ``mujoco.MjModel`` ``m`` (imported as
        ``model``): returns ``(Actuation or None, names of the actuators left out,
        ids of the fixed tendons whose springs or dampers it holds)``. Only
        actuators without activation dynamics, with fixed or affine gain and
        none or affine bias, on hinge or slide joints or fixed tendons over them
        are kept."""
        import mujoco

        from .mujoco import _name

        nq, nv = m.nq, m.nv
        clamp = not int(m.opt.disableflags) & int(mujoco.mjtDisableBit.mjDSBL_CLAMPCTRL)
        fixed = np.array([m.tendon_num[t] > 0 and all(
            int(m.wrap_type[w]) == int(mujoco.mjtWrap.mjWRAP_JOINT)
            and int(m.jnt_type[m.wrap_objid[w]]) in HINGE_SLIDE
            for w in range(m.tendon_adr[t], m.tendon_adr[t] + m.tendon_num[t]))
            for t in range(m.ntendon)], bool)
        tendon_q, tendon_v = np.zeros((m.ntendon, nq)), np.zeros((m.ntendon, nv))
        for t in np.flatnonzero(fixed):
            for w in range(m.tendon_adr[t], m.tendon_adr[t] + m.tendon_num[t]):
                j = m.wrap_objid[w]
                tendon_q[t, m.jnt_qposadr[j]] += m.wrap_prm[w]
                tendon_v[t, m.jnt_dofadr[j]] += m.wrap_prm[w]
        k = np.where(fixed & spring_on, m.tendon_stiffness, 0.0)
        d = np.where(fixed & damper_on, m.tendon_damping, 0.0)
        sprung = np.flatnonzero((k > 0) | (d > 0))
        trn_joint, trn_tendon = int(mujoco.mjtTrn.mjTRN_JOINT), int(mujoco.mjtTrn.mjTRN_TENDON)
        gains = (int(mujoco.mjtGain.mjGAIN_FIXED), int(mujoco.mjtGain.mjGAIN_AFFINE))
        biases = (int(mujoco.mjtBias.mjBIAS_NONE), int(mujoco.mjtBias.mjBIAS_AFFINE))
        keep, left = [], []
        for a in range(m.nu):
            trn, target = int(m.actuator_trntype[a]), int(m.actuator_trnid[a, 0])
            on_joint = trn == trn_joint and int(m.jnt_type[target]) in HINGE_SLIDE
            on_tendon = trn == trn_tendon and fixed[target]
            simple = (int(m.actuator_dyntype[a]) == int(mujoco.mjtDyn.mjDYN_NONE)
                      and int(m.actuator_gaintype[a]) in gains
                      and int(m.actuator_biastype[a]) in biases)
            (keep if simple and (on_joint or on_tendon) else left).append(a)
        names = [_name(m, mujoco.mjtObj.mjOBJ_ACTUATOR, a, "actuator") for a in range(m.nu)]
        left_names = tuple(names[a] for a in left)
        if not keep and not len(sprung):
            return None, left_names, sprung
        nu = len(keep)
        length_q, moment = np.zeros((nu, nq)), np.zeros((nu, nv))
        gain, bias = np.zeros((nu, 3)), np.zeros((nu, 3))
        ctrl_range = np.tile([-np.inf, np.inf], (nu, 1))
        force_range = ctrl_range.copy()
        for i, a in enumerate(keep):
            gear, target = m.actuator_gear[a, 0], int(m.actuator_trnid[a, 0])
            if int(m.actuator_trntype[a]) == trn_joint:
                length_q[i, m.jnt_qposadr[target]] = gear
                moment[i, m.jnt_dofadr[target]] = gear
            else:
                length_q[i], moment[i] = gear * tendon_q[target], gear * tendon_v[target]
            affine = int(m.actuator_gaintype[a]) == gains[1]
            gain[i] = m.actuator_gainprm[a, :3] if affine else (m.actuator_gainprm[a, 0], 0, 0)
            if int(m.actuator_biastype[a]) == biases[1]:
                bias[i] = m.actuator_biasprm[a, :3]
            if m.actuator_ctrllimited[a] and clamp:
                ctrl_range[i] = m.actuator_ctrlrange[a]
            if m.actuator_forcelimited[a]:
                force_range[i] = m.actuator_forcerange[a]
        joint_range = np.tile([-np.inf, np.inf], (nv, 1))
        for j in np.flatnonzero(m.jnt_actfrclimited):
            if int(m.jnt_type[j]) in HINGE_SLIDE:
                joint_range[m.jnt_dofadr[j]] = m.jnt_actfrcrange[j]
        element = cls(model, [names[a] for a in keep], keep, length_q, moment,
                      gain, bias, ctrl_range, force_range, joint_range, tendon_q[sprung],
                      tendon_v[sprung], k[sprung], d[sprung], m.tendon_lengthspring[sprung])
        return element, left_names, sprung

    def set_ctrl(self, ctrl):
        """The controls ``ctrl`` (nu,), in the order of :attr:`names`."""
        self.ctrl[:] = check_vector("ctrl", ctrl, len(self.names))

    def _stretch(self, L):
        """How far the tendon lengths ``L`` lie outside their spring's rest range."""
        low, high = self.tendon_rest[:, 0], self.tendon_rest[:, 1]
        return np.where(L < low, L - low, np.where(L > high, L - high, 0.0))

    def tau(self, t, q, qd, out):
        """(A1) and the tendons' springs and dampers at ``(q, qd)``, added to ``out``."""
        f = -self.tendon_k * self._stretch(self.tendon_q @ q) - self.tendon_d * (self.tendon_v
                                                                                 @ qd)
        out += self.tendon_v.T @ f
        if len(self.names):
            l, lv = self.length_q @ q, self.moment @ qd
            c = np.clip(self.ctrl, self.ctrl_range[:, 0], self.ctrl_range[:, 1])
            F = ((self.gain[:, 0] + self.gain[:, 1] * l + self.gain[:, 2] * lv) * c
                 + self.bias[:, 0] + self.bias[:, 1] * l + self.bias[:, 2] * lv)
            F = np.clip(F, self.force_range[:, 0], self.force_range[:, 1])
            out += np.clip(self.moment.T @ F, self.joint_range[:, 0], self.joint_range[:, 1])

    def energy(self, q):
        """Energy stored in the tendons' springs (actuators store none)."""
        return float(np.sum(self.tendon_k * self._stretch(self.tendon_q @ q) ** 2)) / 2


class GravityCompensation:
    """MuJoCo's gravity compensation (``body_gravcomp``) as a wrench element of
    :class:`vdad.forces.Forces`: body ``i`` of ``bodies`` feels the force
    ``-gravcomp_i m_i g`` at its centre of mass (``mj_passive``), a constant
    wrench that needs no body state."""

    needs_states = False

    def __init__(self, model, bodies, gravcomp):
        self.model, self.bodies = model, np.asarray(bodies, np.int64)
        self.gravcomp = np.asarray(gravcomp, float)
        self._f = np.zeros((len(self.bodies), 6))          # torque about the com, force
        self._f[:, 3:] = -(self.gravcomp * model.mass[self.bodies])[:, None] * model.gravity

    @classmethod
    def of(cls, m, model, index):
        """The gravity compensation of the compiled ``mujoco.MjModel`` ``m``
        imported as ``model``, ``index`` (nbody,) the vdad body of each MuJoCo
        body (-1: none); None where no body has any or gravity is off."""
        ids = np.flatnonzero((m.body_gravcomp != 0) & (index >= 0))
        if not np.any(model.gravity) or not len(ids):
            return None
        return cls(model, index[ids], m.body_gravcomp[ids])

    def wrenches(self, t, states):
        return self._f.copy()
