"""vdad against two independent oracles, MuJoCo and Pinocchio (anchors §1), and
the MuJoCo importer/exporter.

Tolerance. Backward-stable solvers of ``M qdd = rhs`` differ by about
``cond(M) * eps`` relative to ``|qdd|``; we allow

    max |qdd_a - qdd_b| <= C * cond(M) * eps * max(1, max |qdd_a|),   C = 100,

with ``M`` the CRBA mass matrix at the state (Drake's ``c * cond * eps``). On the
trees below (3 to 30 bodies, up to 74 dofs, cond(M) up to ~6e3) the observed
ratio ``error / (cond(M) eps max(1, |qdd|))`` stays below 0.5 for MuJoCo and
below 0.1 for Pinocchio, so C = 100 leaves a margin of 200 while still catching
any modelling error (those show up at 1e-3 and above).
"""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap
from dataclasses import replace
from pathlib import Path

import gymnasium
import mujoco
import numpy as np
import pinocchio as pin
import pytest
from strategies import (
    random_inertia,
    random_rotation,
    random_state,
    random_tree,
    with_armature,
)

import vdad
from vdad.interop.mujoco import (
    LEFT_OUT,
    from_mujoco,
    load_mjcf,
    mujoco_forward,
    mujoco_layout,
    to_mjspec,
    to_mujoco,
)
from vdad.interop.pinocchio import pinocchio_forward, to_pinocchio
from vdad.reference import aba, crba, crba_forward_dynamics

C = 100.0
EPS = np.finfo(float).eps
SEEDS = range(12)


def assert_qdd_close(model, q, expected, got, what):
    cond = np.linalg.cond(crba(model, q))
    scale = max(1.0, np.abs(expected).max())
    err = np.abs(expected - got).max()
    tol = C * cond * EPS * scale
    assert err <= tol, (f"{what}: max error {err:.3e} > tol {tol:.3e} "
                        f"(cond(M) = {cond:.3e}, max|qdd| = {scale:.3e})")


def tree(seed, composite):
    """Seeded random tree of 3..30 bodies and 1..3 roots, every joint kind.

    Even seeds put their free root joints at the origin (identity placement), so
    that the exporter writes MuJoCo freejoints; odd seeds keep random placements
    (three slides and a ball in MuJoCo). Gravity varies with the seed.
    """
    n = 3 + seed * 27 // 11
    gravity = (0.0, 0.0, -9.81) if seed % 3 == 0 else (0.7 * (seed % 5) - 1.0, 0.4, -9.81)
    model = random_tree(seed, n=n, roots=1 + seed % 3, composite=composite, gravity=gravity)
    if seed % 2 == 0:
        joints = [replace(j, placement=vdad.Pose()) if j.kind == "free" and j.parent is None
                  else j for j in model.joints]
        model = vdad.Model(model.bodies, joints, gravity=model.gravity,
                           q_spring=model.q_spring, name=model.name)
    return model


def test_trees_cover_every_joint_kind():
    kinds = set()
    for seed in SEEDS:
        model = tree(seed, composite=True)
        kinds |= {j.kind for j in model.joints}
        kinds |= {(j.kind, j.parent is None) for j in model.joints if j.kind == "free"}
    assert kinds >= {"revolute", "prismatic", "spherical", "free", "fixed", "composite",
                     ("free", True), ("free", False)}
    m, _ = to_mujoco(tree(0, composite=True))
    assert mujoco.mjtJoint.mjJNT_FREE in m.jnt_type


@pytest.mark.parametrize("seed", SEEDS)
def test_dca_matches_mujoco_and_pinocchio(seed):
    model = tree(seed, composite=False)
    q, qd, tau, f_ext = random_state(model, seed)
    qdd = vdad.forward_dynamics(model, q, qd, tau, f_ext)
    m, d = to_mujoco(model)
    assert (m.nq, m.nv) == (model.nq, model.nv)
    qdd_mj = mujoco_forward(m, d, q, qd, tau, f_ext)
    pm = to_pinocchio(model)
    qdd_pin = pinocchio_forward(pm, pm.createData(), model, q, qd, tau, f_ext)
    assert_qdd_close(model, q, qdd, qdd_mj, "DCA vs MuJoCo")
    assert_qdd_close(model, q, qdd, qdd_pin, "DCA vs Pinocchio")
    assert_qdd_close(model, q, qdd_mj, qdd_pin, "MuJoCo vs Pinocchio")


@pytest.mark.parametrize("seed", SEEDS)
def test_armature_matches_mujoco_pinocchio_and_the_reference(seed):
    """Rotor inertia on every dof ((A1)-(A2), docs/joints.md): the DCA equals the
    reference ABA and CRBA (M + diag(armature)) and MuJoCo's dof_armature; with
    none on free joints, also Pinocchio's armature (whose free-flyer applies it to
    body-frame linear velocities, where vdad and MuJoCo use world-frame ones)."""
    plain = tree(seed, composite=False)
    for model, engines in ((with_armature(plain, seed), ("MuJoCo",)),
                           (with_armature(plain, seed, free=False), ("MuJoCo", "Pinocchio"))):
        q, qd, tau, f_ext = random_state(model, seed)
        qdd = vdad.forward_dynamics(model, q, qd, tau, f_ext)
        m, d = to_mujoco(model)
        np.testing.assert_allclose(m.dof_armature[mujoco_layout(m)[2]], model.armature,
                                   rtol=1e-15)
        others = {"ABA": aba(model, q, qd, tau, f_ext),
                  "CRBA": crba_forward_dynamics(model, q, qd, tau, f_ext),
                  "MuJoCo": mujoco_forward(m, d, q, qd, tau, f_ext)}
        if "Pinocchio" in engines:
            pm = to_pinocchio(model)
            others["Pinocchio"] = pinocchio_forward(pm, pm.createData(), model, q, qd, tau,
                                                    f_ext)
        for name, other in others.items():
            assert_qdd_close(model, q, qdd, other, f"DCA with armature vs {name}")
        without = vdad.forward_dynamics(plain, q, qd, tau, f_ext)
        assert np.abs(qdd - without).max() > 1e-3 * np.abs(without).max()   # it matters


@pytest.mark.parametrize("seed", SEEDS)
def test_armature_on_composite_joints_and_back_from_mujoco(seed):
    model = with_armature(tree(seed, composite=True), seed)
    q, qd, tau, f_ext = random_state(model, seed + 100)
    m, d = to_mujoco(model)
    qdd = vdad.forward_dynamics(model, q, qd, tau, f_ext)
    assert_qdd_close(model, q, qdd, mujoco_forward(m, d, q, qd, tau, f_ext), "DCA vs MuJoCo")
    back = from_mujoco(m)
    _, _, iv = mujoco_layout(m)
    np.testing.assert_allclose(back.armature[iv], model.armature, rtol=1e-15)


@pytest.mark.parametrize("seed", SEEDS)
def test_dca_matches_mujoco_with_composite_joints(seed):
    model = tree(seed, composite=True)
    q, qd, tau, f_ext = random_state(model, seed + 100)
    m, d = to_mujoco(model)
    for args in ((q, qd, tau, f_ext), (q, qd, None, None)):
        qdd = vdad.forward_dynamics(model, *args)
        assert_qdd_close(model, q, qdd, mujoco_forward(m, d, *args), "DCA vs MuJoCo")


def test_pinocchio_without_external_forces_or_springs():
    model = random_tree(5, n=15, roots=2, springs=False)
    q, qd, tau, _ = random_state(model, 5)
    pm = to_pinocchio(model)
    qdd = pinocchio_forward(pm, pm.createData(), model, q, qd, tau)
    assert_qdd_close(model, q, vdad.forward_dynamics(model, q, qd, tau), qdd, "DCA vs Pinocchio")
    assert isinstance(pm, pin.Model) and pm.nframes > model.nb   # joint and body frames


@pytest.mark.parametrize("seed", range(6))
def test_from_mujoco_round_trip(seed):
    model = tree(seed, composite=True)
    m, d = to_mujoco(model)
    back = from_mujoco(m)
    body, iq, iv = mujoco_layout(m)
    assert [back.body_names[b - 1] for b in body] == list(model.body_names)
    assert (back.nq, back.nv) == (model.nq, model.nv)
    np.testing.assert_allclose(back.mass[body - 1], model.mass)
    np.testing.assert_allclose(back.inertia[body - 1], model.inertia, atol=1e-12)
    q, qd, tau, f_ext = random_state(model, seed)
    qm, qdm, taum = np.empty(model.nq), np.empty(model.nv), np.empty(model.nv)
    qm[iq], qdm[iv], taum[iv] = q, qd, tau
    np.testing.assert_allclose(back.q_spring[iq], model.q_spring, atol=1e-15)
    fm = np.empty_like(f_ext)
    fm[body - 1] = f_ext
    qdd = vdad.forward_dynamics(model, q, qd, tau, f_ext)
    qdd_back = vdad.forward_dynamics(back, qm, qdm, taum, fm)[iv]
    assert_qdd_close(model, q, qdd, qdd_back, "vdad vs vdad(from_mujoco(to_mujoco))")
    # MuJoCo's own layout: back and m agree entry by entry
    assert_qdd_close(model, q, qdd_back, mujoco_forward(m, d, q, qd, tau, f_ext), "MuJoCo")


MJCF = """
<mujoco model="hip">
  <compiler angle="radian"/>
  <option gravity="0.3 -0.2 -9.81"><flag contact="disable"/></option>
  <asset><mesh name="tet" vertex="0 0 0  0.1 0 0  0 0.1 0  0 0 0.1"/></asset>
  <worldbody>
    <geom type="plane" size="5 5 0.1"/>
    <body name="pelvis" pos="0.1 0.2 1" euler="0.1 0.2 0.3">
      <joint name="root" type="free" stiffness="0.5" damping="0.1"/>
      <geom type="box" size="0.2 0.1 0.05"/>
      <body name="thigh" pos="0.1 0 -0.1" euler="0.05 -0.1 0.15">
        <joint name="hip_x" type="hinge" axis="1 0 0" pos="0 0 0.05" stiffness="2"
               springref="0.1" damping="0.3" range="-1 1"/>
        <joint name="hip_y" type="hinge" axis="0 1 0" pos="0.01 0 0.05" ref="0.2" damping="0.1"/>
        <joint name="hip_z" type="hinge" axis="0 0.6 0.8" pos="0 0.02 0.05" stiffness="1"/>
        <geom type="capsule" fromto="0 0 0 0 0 -0.4" size="0.05"/>
        <body name="shin" pos="0 0 -0.4">
          <joint name="knee" type="ball" pos="0 0.01 0.03" stiffness="1.5" damping="0.2"/>
          <geom type="cylinder" size="0.04 0.2" pos="0 0 -0.2"/>
          <body name="foot" pos="0 0 -0.4" quat="0.9 0.1 0.3 0.2">
            <joint name="ankle" type="slide" axis="0 0.3 1" stiffness="4" springref="0.05"
                   damping="0.5" ref="0.01"/>
            <geom type="sphere" size="0.05"/>
            <geom type="mesh" mesh="tet" pos="0.02 0 0"/>
          </body>
        </body>
      </body>
      <body name="tail" pos="-0.2 0 0" euler="0 0.5 0">
        <geom type="ellipsoid" size="0.05 0.03 0.02"/>
      </body>
    </body>
  </worldbody>
</mujoco>
"""


@pytest.fixture
def hip_xml(tmp_path):
    path = tmp_path / "hip.xml"
    path.write_text(MJCF)
    return path


def test_load_mjcf_structure(hip_xml):
    model = load_mjcf(hip_xml)
    assert model.name == "hip"
    assert model.body_names == ("pelvis", "thigh", "shin", "foot", "tail")
    assert model.joint_names == ("root", "hip_x", "knee", "ankle", "tail_fixed")
    kinds = [j.kind for j in model.joints]
    assert kinds == ["free", "composite", "composite", "composite", "fixed"]
    np.testing.assert_array_equal(model.placement_R[0], np.eye(3))
    hip = model.joints[1]
    assert [s.kind for s in hip.stages] == ["hinge"] * 3
    assert hip.stages[1].ref == pytest.approx(0.2) and hip.stages[1].anchor == (0.01, 0, 0.05)
    assert hip.limits == ((-1.0, 1.0), None, None)
    assert model.joints[2].stages[0].anchor == pytest.approx((0, 0.01, 0.03))
    np.testing.assert_allclose(model.gravity, (0.3, -0.2, -9.81))
    geoms = [[g.kind for g in b.geoms] for b in model.bodies]
    assert geoms == [["box"], ["capsule"], ["cylinder"], ["sphere", "mesh"], ["mesh"]]
    assert len(model.bodies[3].geoms[1].mesh.faces) == 4
    assert model.bodies[1].geoms[0].size == pytest.approx((0.05, 0.2))


def test_load_mjcf_matches_mujoco(hip_xml):
    model = load_mjcf(hip_xml)
    m = mujoco.MjModel.from_xml_path(str(hip_xml))
    d = mujoco.MjData(m)
    body, iq, iv = mujoco_layout(m)
    np.testing.assert_array_equal(iq, np.arange(m.nq))
    for seed in range(3):
        q, qd, tau, f_ext = random_state(model, seed)
        q[7] = 0.3                                  # hip_x inside its range
        qdd = vdad.forward_dynamics(model, q, qd, tau, f_ext)
        d.qpos[:], d.qvel[:], d.qfrc_applied[:] = q, qd, tau
        d.xfrc_applied[1:] = f_ext[:, [3, 4, 5, 0, 1, 2]]
        mujoco.mj_forward(m, d)
        assert d.nefc == 0
        assert_qdd_close(model, q, qdd, d.qacc, "DCA vs mj_forward on the MJCF")
        assert_qdd_close(model, q, qdd, mujoco_forward(m, d, q, qd, tau, f_ext), "mujoco_forward")


def test_load_mjcf_missing_file(tmp_path):
    path = tmp_path / "nowhere" / "robot.xml"
    with pytest.raises(vdad.InputError, match="robot.xml"):
        load_mjcf(path)


@pytest.mark.parametrize("path", [None, 3, ["robot.xml"]])
def test_load_mjcf_takes_a_path(path):
    with pytest.raises(vdad.InputError, match="load_mjcf takes the path of an MJCF file"):
        load_mjcf(path)


def test_load_mjcf_rejects_unknown_options(hip_xml):
    with pytest.raises(vdad.InputError, match=r"load_mjcf got unknown option\(s\) \['strickt'\]; "
                                              r"it takes \['path', 'report', 'strict'\]"):
        load_mjcf(hip_xml, strickt=False)
    assert load_mjcf(hip_xml, strict=False).nb == load_mjcf(hip_xml).nb


@pytest.mark.parametrize("m", [None, "robot.xml", lambda: 0])
def test_from_mujoco_takes_a_compiled_model(m):
    with pytest.raises(vdad.InputError, match="from_mujoco takes a compiled mujoco.MjModel"):
        vdad.from_mujoco(m)


def test_to_mjspec_keeps_names_and_geoms(hip_xml):
    model = load_mjcf(hip_xml)
    spec = to_mjspec(model)
    m = spec.compile()
    assert [m.body(i).name for i in range(1, m.nbody)] == list(model.body_names)
    assert m.opt.disableflags & mujoco.mjtDisableBit.mjDSBL_CONTACT
    assert m.ngeom == sum(len(b.geoms) for b in model.bodies)
    again = from_mujoco(m)
    assert [j.kind for j in again.joints] == [j.kind for j in model.joints]
    assert again.joints[1].limits == model.joints[1].limits
    # refs and spring references of hinges and slides survive without to_mujoco's fix-up
    _, iq, _ = mujoco_layout(m)
    hs = [model.stage_q[s] for s in range(model.ns) if model.stage_kind[s] in (0, 1)]
    np.testing.assert_allclose(m.qpos0[iq][hs], model.q_neutral[hs])
    np.testing.assert_allclose(m.qpos_spring[iq][hs], model.q_spring[hs])


@pytest.mark.parametrize("flag", ["mjDSBL_GRAVITY", "mjDSBL_SPRING", "mjDSBL_DAMPER"])
def test_from_mujoco_honours_disable_flags(hip_xml, flag):
    m = mujoco.MjModel.from_xml_path(str(hip_xml))
    m.opt.disableflags |= int(getattr(mujoco.mjtDisableBit, flag))
    model = from_mujoco(m)
    q, qd, tau, f_ext = random_state(model, 7)
    q[7] = 0.3
    qdd = vdad.forward_dynamics(model, q, qd, tau, f_ext)
    assert_qdd_close(model, q, qdd, mujoco_forward(m, mujoco.MjData(m), q, qd, tau, f_ext),
                     f"DCA vs MuJoCo with {flag}")


def _xml(body, extra=""):
    return (f'<mujoco><worldbody><body name="a"><joint name="j1" type="hinge"/>'
            f'<geom size="0.1"/>{body}</body></worldbody>{extra}</mujoco>')


LEFT_OUT_CASES = {
    "frictionloss": (_xml('<body name="b"><joint name="fl_j" frictionloss="0.2"/>'
                          '<geom size="0.1"/></body>'), ("fl_j",)),
    "equality constraints": (_xml('<body name="b"><joint name="j2"/><geom size="0.1"/></body>',
                                  '<equality><joint name="eq_lock" joint1="j1" joint2="j2"/>'
                                  '</equality>'), ("eq_lock",)),
    "tendons": (_xml('<body name="b"><joint name="j2"/><geom size="0.1"/></body>',
                     '<tendon><fixed name="tend" limited="true" range="-1 1">'
                     '<joint joint="j1" coef="1"/></fixed><fixed name="sprung" stiffness="3">'
                     '<joint joint="j2" coef="1"/></fixed><fixed name="measured">'
                     '<joint joint="j2" coef="1"/></fixed></tendon>'), ("tend",)),
    "actuators": (_xml("", "<actuator>" + "".join(
        f'<general name="act{i}" joint="j1" dyntype="filter" dynprm="0.1"/>'
        for i in range(5)) + '<motor name="imported" joint="j1"/></actuator>'),
                  tuple(f"act{i}" for i in range(5))),
}


def _no_contact(xml):
    return xml.replace("<mujoco>", '<mujoco><option><flag contact="disable"/></option>', 1)


@pytest.mark.parametrize("feature", sorted(LEFT_OUT_CASES))
def test_left_out_features_are_named_once_and_refused_when_strict(feature):
    """By default a feature vdad does not model is left out with one warning that
    names it (at most three names, then "and N more") and says what to do; the
    report lists exactly its names; strict=True refuses the model instead."""
    xml, names = LEFT_OUT_CASES[feature]
    m = mujoco.MjModel.from_xml_string(_no_contact(xml))
    with pytest.raises(vdad.UnsupportedFeatureError, match=f"left out {feature} .*"
                                                           f"strict=False leaves them out"):
        from_mujoco(m, strict=True)
    with pytest.warns(UserWarning) as record:
        model, report = from_mujoco(m, report=True)
    assert len(record) == 1 and record[0].filename == __file__
    text = str(record[0].message)
    assert "\n" not in text and "strict=True refuses" in text
    assert (" and 2 more" in text) == (len(names) == 5)
    assert report.left_out == ((feature, names, LEFT_OUT[feature]),)
    assert LEFT_OUT[feature] in str(report) and report.welded == ()
    assert model.nb == m.nbody - 1


def test_features_switched_off_in_mujoco_are_not_left_out():
    """A feature that does not act with the model's disable flags (or a tendon
    without spring, damper or limit) is not reported."""
    for feature in ("equality constraints", "actuators", "frictionloss"):
        m = mujoco.MjModel.from_xml_string(_no_contact(LEFT_OUT_CASES[feature][0]))
        m.opt.disableflags |= int(mujoco.mjtDisableBit.mjDSBL_CONSTRAINT
                                  | mujoco.mjtDisableBit.mjDSBL_ACTUATION)
        assert from_mujoco(m, strict=True, report=True)[1].left_out == ()
    m = mujoco.MjModel.from_xml_string(LEFT_OUT_CASES["tendons"][0])     # contacts on
    with pytest.warns(UserWarning, match=r"left out tendons \('tend'\); contacts \('a', 'b'\)"):
        assert [f for f, *_ in from_mujoco(m, report=True)[1].left_out] == ["tendons",
                                                                             "contacts"]


WELDED = """
<mujoco model="welded">
  <option><flag contact="disable"/></option>
  <worldbody>
    <geom name="floor" type="plane" size="3 2 0.1" pos="0 0 -1"/>
    <body name="stand" pos="0 0 0.5" euler="0 0 30">
      <geom name="stand_box" type="box" size="0.1 0.2 0.05" pos="0.3 0 0" mass="0"/>
      <body name="a" pos="0.1 0 0">
        <joint name="j1" axis="0 1 0"/>
        <geom size="0.1" pos="0 0 -0.2"/>
        <body name="frame" pos="0 0.1 -0.4" euler="20 10 0">
          <body name="b">
            <joint name="j2" axis="1 0 0" damping="0.3" armature="0.05"/>
            <geom type="capsule" size="0.05 0.2"/>
            <body name="foot_site" pos="0.1 0 -0.2" quat="0.9 0.1 0.3 0">
              <geom name="foot_box" type="box" size="0.05 0.03 0.02" mass="0" pos="0 0.02 0"/>
            </body>
          </body>
        </body>
      </body>
    </body>
    <body name="target" mocap="true" pos="1 1 1"><geom name="ball" size="0.05"/></body>
  </worldbody>
</mujoco>
"""


def test_massless_bodies_without_joints_are_welded_as_mujoco_does():
    """Massless bodies without joints (a stand below the world, a frame between two
    links, a foot site) are welded into their parents, mocap bodies and the
    world's geoms become environment geometry: the accelerations equal
    mj_forward's, and every geom sits where MuJoCo puts it."""
    m = mujoco.MjModel.from_xml_string(WELDED)
    d = mujoco.MjData(m)
    model, report = from_mujoco(m, strict=True, report=True)
    assert model.body_names == ("a", "b") and report.welded == ("stand", "frame", "foot_site")
    assert report.left_out == ()
    body, _, _ = mujoco_layout(m)
    np.testing.assert_array_equal(body, [2, 4])
    for seed in range(3):
        q, qd, tau, f_ext = random_state(model, seed)
        assert_qdd_close(model, q, vdad.forward_dynamics(model, q, qd, tau, f_ext),
                         mujoco_forward(m, d, q, qd, tau, f_ext), "DCA vs mj_forward, welded")
    # geoms: the floor (a thin box whose top is the plane), the stand's, the mocap ball
    env = {g.kind: g for g in report.environment.geoms}
    assert [g.kind for g in report.environment.geoms] == ["box", "box", "sphere"]
    np.testing.assert_allclose(report.environment.geoms[0].size, (3, 2, 0.005))
    np.testing.assert_allclose(report.environment.geoms[0].pose.translation, (0, 0, -1.005))
    np.testing.assert_allclose(env["sphere"].pose.translation, (1, 1, 1))
    R, p = vdad.kinematics.world_poses(model, d.qpos)
    placed = [(R[i] @ g.pose.matrix()[0], p[i] + R[i] @ g.pose.matrix()[1])
              for i, b in enumerate(model.bodies) for g in b.geoms]
    placed.insert(0, report.environment.geoms[1].pose.matrix())
    mujoco.mj_forward(m, d)              # MuJoCo's geoms 1-4: stand_box, a's, b's, foot_box
    for (Rg, pg), g in zip(placed, range(1, 5), strict=True):
        np.testing.assert_allclose(pg, d.geom_xpos[g], atol=1e-12)
        np.testing.assert_allclose(Rg, d.geom_xmat[g].reshape(3, 3), atol=1e-12)


def test_a_massless_body_with_joints_is_refused_by_name():
    xml = _xml('<body name="ghost"><joint name="gj"/><body name="c"><geom size="0.1"/>'
               '</body></body>')
    with pytest.raises(vdad.UnsupportedFeatureError, match="body 'ghost' has joints but no "
                                                           "mass.*<inertial>"):
        from_mujoco(mujoco.MjModel.from_xml_string(xml))


def test_free_joint_below_a_body_is_unsupported():
    # MuJoCo's compiler refuses this, so hang a compiled free body below "a" afterwards
    m = mujoco.MjModel.from_xml_string(
        '<mujoco><worldbody><body name="a"><joint name="j1"/><geom size="0.1"/></body>'
        '<body name="c"><freejoint name="ff"/><geom size="0.1"/></body></worldbody></mujoco>')
    m.body_parentid[2] = 1
    with pytest.raises(vdad.UnsupportedFeatureError, match="ff.*'c'.*'a'"):
        from_mujoco(m)


def test_mujocos_own_test_model_loads_by_default_with_mujocos_dynamics():
    """The MJCF file that the mujoco package ships for its tests (ellipsoids, a
    heightfield, armature, damping, springs, actuators, tendons, an equality
    constraint, gravity compensation, fluid forces) loads with its defaults;
    the report names what was left out; with those switched off in MuJoCo its
    accelerations equal mj_forward's."""
    path = os.path.join(os.path.dirname(mujoco.__file__), "testdata", "model.xml")
    with pytest.warns(UserWarning, match="left out equality constraints"):
        model, report = load_mjcf(path, report=True)
    assert [f for f, *_ in report.left_out] == [
        "equality constraints", "tendons", "actuators", "contacts", "fluid forces", "geoms"]
    left = report.left_out[2][1]
    assert left == ("actuator1", "actuator6", "actuator7", "actuator8", "actuator9")
    assert report.left_out[1][1] == ("spatial",) and report.left_out[5][1] == ("geom1",)
    assert report.gravcomp.bodies.tolist() == [0] and report.forces[1] is report.gravcomp
    np.testing.assert_array_equal(report.q0[:3], (0, 0, 0.7))           # the head's pos
    assert report.dt == 0.002
    assert len(report.actuation.names) == 5 and np.any(model.armature > 0)
    assert report.environment.geoms
    m = mujoco.MjModel.from_xml_path(path)
    m.opt.disableflags |= int(mujoco.mjtDisableBit.mjDSBL_CONSTRAINT)
    m.opt.density = m.opt.viscosity = 0.0
    dropped = np.setdiff1d(np.arange(m.nu), report.actuation.ids)        # unnamed there
    m.actuator_gainprm[dropped] = m.actuator_biasprm[dropped] = 0.0
    assert_matches_mujoco_with_controls(m, model, report.actuation, report.gravcomp)


def assert_matches_mujoco_with_controls(m, model, actuation, gravcomp=None, seeds=range(3)):
    """vdad's accelerations with ``actuation`` at random controls (some beyond
    their ranges), and ``gravcomp`` if given, equal mj_forward's with the same
    ``ctrl``."""
    d = mujoco.MjData(m)
    for seed in seeds:
        q, qd, tau, f_ext = random_state(model, seed)
        ctrl = np.random.default_rng(seed).normal(scale=2.0, size=m.nu)
        actuation.set_ctrl(ctrl[actuation.ids])
        total = tau.copy()
        actuation.tau(0.0, q, qd, total)
        if gravcomp is not None:
            f_ext = f_ext.copy()
            f_ext[gravcomp.bodies] += gravcomp.wrenches(0.0, None)
        expected = mujoco_forward(m, d, q, qd, tau, f_ext)       # ctrl zeroed there
        d.ctrl[:] = ctrl
        mujoco.mj_forward(m, d)
        assert d.nefc == 0
        passive = d.qfrc_passive - d.qfrc_gravcomp           # gravcomp: in f_ext above
        np.testing.assert_allclose(total - tau, d.qfrc_actuator + passive
                                   - vdad.passive_forces(model, q, qd), rtol=0,
                                   atol=C * EPS * max(1.0, np.abs(total).max()))
        # the accelerations: the reference ABA to 100 cond(M) eps; the DCA, whose
        # formulation loses up to 5e3 eps relative to |qdd| on ACTUATED even without
        # actuators (issue "Numerically hard cases"), to 1e4 cond(M) eps
        assert_qdd_close(model, q, aba(model, q, qd, total, f_ext), d.qacc,
                         f"reference ABA with actuation vs mj_forward, seed {seed}")
        qdd = vdad.forward_dynamics(model, q, qd, total, f_ext)
        err, scale = np.abs(qdd - d.qacc).max(), max(1.0, np.abs(qdd).max())
        assert err <= 1e4 * np.linalg.cond(crba(model, q)) * EPS * scale, (
            f"DCA with actuation vs mj_forward, seed {seed}: {err:.3e}")
        assert not np.allclose(expected, d.qacc)                  # the controls act


ACTUATED = """
<mujoco model="actuated">
  <option><flag contact="disable"/></option>
  <worldbody>
    <body name="a"><joint name="j1" axis="0 1 0" actuatorfrclimited="true"
                          actuatorfrcrange="-3 3"/>
      <geom size="0.1" pos="0 0 -0.2"/>
      <body name="b" pos="0 0 -0.4"><joint name="j2" axis="1 0 0" springref="0.2"/>
        <geom type="capsule" size="0.1 0.2"/>
        <body name="c" pos="0 0 -0.4"><joint name="s3" type="slide" axis="0 0 1"/>
          <geom type="box" size="0.1 0.1 0.1"/>
        </body>
      </body>
    </body>
  </worldbody>
  <tendon>
    <fixed name="t_spring" stiffness="7" springlength="-0.1 0.2" damping="0.4">
      <joint joint="j1" coef="1"/><joint joint="j2" coef="-0.5"/>
    </fixed>
    <fixed name="t_drive"><joint joint="j2" coef="2"/><joint joint="s3" coef="1"/></fixed>
  </tendon>
  <actuator>
    <motor name="m1" joint="j1" gear="2"/>
    <position name="p2" joint="j2" kp="30" ctrlrange="-0.5 0.5" gear="1.5"/>
    <velocity name="v3" joint="s3" kv="4" forcerange="-0.2 0.2"/>
    <general name="g4" tendon="t_drive" gaintype="affine" gainprm="2 0.5 0.1"
             biastype="affine" biasprm="0.3 -1 -0.2" gear="0.7"/>
    <motor name="m5" tendon="t_spring" gear="3"/>
  </actuator>
</mujoco>
"""


def test_actuators_and_fixed_tendons_act_as_in_mujoco():
    """Motor, position, velocity and affine general actuators with gears on hinges,
    a slide and fixed tendons, clamped controls, a force range and a joint's
    actuator-force range, and a fixed tendon's spring (with a dead band) and
    damper: the joint forces of :class:`Actuation` give mj_forward's accelerations."""
    m = mujoco.MjModel.from_xml_string(ACTUATED)
    model, report = from_mujoco(m, strict=True, report=True)
    assert report.left_out == () and report.actuation.names == ("m1", "p2", "v3", "g4", "m5")
    np.testing.assert_array_equal(report.actuation.ids, range(5))
    assert_matches_mujoco_with_controls(m, model, report.actuation, seeds=range(6))
    act = report.actuation
    q = np.zeros(model.nq)
    q[:2] = (0.5, 0.1)                              # t_spring length 0.45: 0.25 past 0.2
    assert act.energy(q) == pytest.approx(0.5 * 7 * 0.25**2)
    with pytest.raises(vdad.InputError, match=r"ctrl must have shape \(5,\)"):
        act.set_ctrl([1.0])
    forces = vdad.forces.Forces(model, [act])
    sim = vdad.Simulator(model, controller=forces.controller)
    act.set_ctrl([1, 0.2, -1, 0.5, 0.1])
    sim.step(20)
    assert np.all(np.isfinite(sim.q)) and np.any(sim.q != 0)


def test_to_pinocchio_refuses_armature_on_a_free_joint():
    model = with_armature(random_tree(1, n=4), 1)
    with pytest.raises(vdad.UnsupportedFeatureError, match="joint 'j0': armature on a "
                                                           "translation stage"):
        to_pinocchio(model)


@pytest.mark.parametrize("change, culprit", [
    ("composite", "j3"), ("anchor", "j1"), ("ref", "j2")])
def test_to_pinocchio_rejects_what_it_cannot_express(change, culprit):
    J = vdad.joints
    bodies = [vdad.Body(f"b{i}", 1.0) for i in range(4)]
    stages = {"anchor": {"j1": J.revolute(anchor=(0.1, 0, 0))},
              "ref": {"j2": J.prismatic(ref=0.3)},
              "composite": {"j3": J.revolute() + J.revolute(axis=(1, 0, 0))}}[change]
    joints = []
    for i in range(4):
        name, parent = f"j{i}", (None if i == 0 else f"b{i - 1}")
        if name in stages:
            joints.append(vdad.Joint(name, parent, f"b{i}", "composite", stages=stages[name]))
        else:
            joints.append(vdad.Joint(name, parent, f"b{i}", "revolute"))
    with pytest.raises(vdad.UnsupportedFeatureError, match=culprit):
        to_pinocchio(vdad.Model(bodies, joints))


def test_fixed_joints_merge_into_parent_in_pinocchio():
    J = vdad.joints
    rng = np.random.default_rng(3)
    bodies = [vdad.Body(f"b{i}", 1.0 + i, tuple(rng.normal(size=3) * 0.2),
                        random_inertia(rng, 0.1)) for i in range(5)]
    kinds = ["fixed", "revolute", "fixed", "fixed", "spherical"]
    joints = [vdad.Joint(f"j{i}", None if i == 0 else f"b{i - 1}", f"b{i}", kinds[i],
                         axis=tuple(rng.normal(size=3)),
                         placement=vdad.Pose(tuple(rng.normal(size=3)), random_rotation(rng)))
              for i in range(5)]
    model = vdad.Model(bodies, joints)
    assert model.ns == len(J.revolute()) + len(J.spherical())
    pm = to_pinocchio(model)
    assert pm.njoints == 3
    for seed in range(3):
        q, qd, tau, f_ext = random_state(model, seed)
        qdd = vdad.forward_dynamics(model, q, qd, tau, f_ext)
        qdd_pin = pinocchio_forward(pm, pm.createData(), model, q, qd, tau, f_ext)
        assert_qdd_close(model, q, qdd, qdd_pin, "DCA vs Pinocchio (fixed joints)")


def test_importing_vdad_loads_neither_oracle():
    code = textwrap.dedent("""
        import sys
        import vdad, vdad.interop.mujoco, vdad.interop.pinocchio
        assert "mujoco" not in sys.modules and "pinocchio" not in sys.modules
    """)
    subprocess.run([sys.executable, "-c", code], check=True)


def chain(kinds, name="chain"):
    """A chain of unit bodies b0, b1, ... joined by joints of ``kinds``."""
    rng = np.random.default_rng(len(kinds))
    bodies = [vdad.Body(f"b{i}", 1.0, inertia=random_inertia(rng, 0.1))
              for i in range(len(kinds))]
    joints = [vdad.Joint(f"j{i}", None if i == 0 else f"b{i - 1}", f"b{i}", kind,
                         placement=vdad.Pose((0.0, 0.0, -0.5)))
              for i, kind in enumerate(kinds)]
    return vdad.Model(bodies, joints, name=name)


@pytest.mark.parametrize("strict", ["no", 0, None, "True"])
def test_strict_must_be_a_bool(hip_xml, strict):
    with pytest.raises(vdad.InputError, match="strict must be True or False, got"):
        load_mjcf(hip_xml, strict=strict)
    m = mujoco.MjModel.from_xml_path(str(hip_xml))
    with pytest.raises(vdad.InputError, match="strict must be True or False, got"):
        from_mujoco(m, strict=strict)
    assert from_mujoco(m, strict=np.False_).nb == 5


@pytest.mark.parametrize("export", [to_mujoco, to_mjspec, to_pinocchio])
@pytest.mark.parametrize("model", ["x", None, 3])
def test_exporters_take_a_vdad_model(export, model):
    with pytest.raises(vdad.InputError, match="model must be a vdad.Model, got"):
        export(model)


def test_mujoco_forward_checks_its_arguments():
    model = chain(["revolute", "spherical", "prismatic"])
    m, d = to_mujoco(model)
    q, qd = model.q_neutral, np.zeros(model.nv)
    f_ext = np.zeros((model.nb, 6))
    np.testing.assert_allclose(mujoco_forward(m, d, q, qd, f_ext=f_ext),
                               vdad.forward_dynamics(model, q, qd), atol=1e-9)
    with pytest.raises(vdad.InputError, match="f_ext must be a real number .*got a string"):
        mujoco_forward(m, d, q, qd, f_ext="x")
    with pytest.raises(vdad.InputError, match=r"f_ext must have shape \(3, 6\) .*got \(3, 5\)"):
        mujoco_forward(m, d, q, qd, f_ext=np.zeros((3, 5)))
    f_ext[1, 2] = np.nan
    with pytest.raises(vdad.InputError, match="f_ext must be finite"):
        mujoco_forward(m, d, q, qd, f_ext=f_ext)
    with pytest.raises(vdad.InputError, match="mjmodel must be a compiled mujoco.MjModel .*str"):
        mujoco_forward("m", "d", q, qd)
    with pytest.raises(vdad.InputError, match="mjdata must be a mujoco.MjData .*str"):
        mujoco_forward(m, "d", q, qd)
    other, other_data = to_mujoco(chain(["revolute", "revolute"]))
    with pytest.raises(vdad.InputError, match="mjdata does not belong to mjmodel"):
        mujoco_forward(m, other_data, q, qd)
    with pytest.raises(vdad.InputError,
                       match=r"^m must be a compiled mujoco.MjModel \(.*\), got str"):
        mujoco_layout("m")
    with pytest.raises(vdad.InputError, match="q must have shape"):
        mujoco_forward(other, other_data, q, qd)


def test_to_pinocchio_names_the_stage_kinds():
    J = vdad.joints
    model = vdad.Model([vdad.Body("b0", 1.0)], [vdad.Joint(
        "elbow", None, "b0", "composite", stages=J.revolute() + J.revolute(axis=(1, 0, 0)))])
    with pytest.raises(vdad.UnsupportedFeatureError,
                       match=r"joint 'elbow': stages hinge \+ hinge have no Pinocchio"):
        to_pinocchio(model)


def test_pinocchio_forward_checks_its_models():
    model = chain(["revolute", "spherical", "fixed"], name="arm")
    pm = to_pinocchio(model)
    pd = pm.createData()
    q, qd = model.q_neutral, np.zeros(model.nv)
    np.testing.assert_allclose(pinocchio_forward(pm, pd, model, q, qd),
                               vdad.forward_dynamics(model, q, qd), atol=1e-9)
    with pytest.raises(vdad.InputError, match="pmodel must be a pinocchio.Model .*got str"):
        pinocchio_forward("pm", "pd", model, q, qd)
    with pytest.raises(vdad.InputError, match="pdata must be a pinocchio.Data .*got str"):
        pinocchio_forward(pm, "pd", model, q, qd)
    with pytest.raises(vdad.InputError, match="model must be a vdad.Model, got str"):
        pinocchio_forward(pm, pd, "arm", q, qd)
    for other in (chain(["free", "revolute", "revolute"]),      # more dofs
                  chain(["revolute", "spherical"]),             # one body fewer
                  chain(["spherical", "revolute", "fixed"])):   # same counts, other order
        with pytest.raises(vdad.InputError, match="pmodel does not match vmodel 'chain'"):
            pinocchio_forward(pm, pd, other, other.q_neutral, np.zeros(other.nv))
    with pytest.raises(vdad.InputError, match=r"joint 1 \('j0'\) is a JointModelRevolute"):
        pinocchio_forward(pm, pd, chain(["prismatic", "spherical", "fixed"]), q, qd)
    small = to_pinocchio(chain(["revolute"]))
    with pytest.raises(vdad.InputError, match="pdata does not belong to pmodel"):
        pinocchio_forward(pm, small.createData(), model, q, qd)


GYMNASIUM = Path(gymnasium.__file__).parent / "envs" / "mujoco" / "assets"
#: gymnasium's pusher has point-mass bodies (object 1.3e-8 kg, goal 4e-10 kg): there
@pytest.mark.parametrize("name", sorted(p.stem for p in GYMNASIUM.glob("*.xml")))
def test_gymnasium_models_load_by_default_with_mujocos_dynamics(name):
    """Every MuJoCo model that gymnasium ships loads with load_mjcf's defaults,
    leaving out contacts only (and the swimmer's fluid forces); with those off in
    MuJoCo, the accelerations under the imported actuators at random controls
    equal mj_forward's: the reference ABA's to 100 cond(M) eps, the DCA's too
    (pusher's thin tip, whose plain leaf lost up to 5e-9, through the raised leaf
    that the wrist pays back and one step of refinement, (R4) of
    docs/accuracy.md)."""
    path = str(GYMNASIUM / f"{name}.xml")
    with pytest.warns(UserWarning, match="left out") as record:
        model, report = load_mjcf(path, report=True)
    assert len(record) == 1
    assert {f for f, *_ in report.left_out} <= {"contacts", "fluid forces"}
    m = mujoco.MjModel.from_xml_path(path)
    m.opt.disableflags |= int(mujoco.mjtDisableBit.mjDSBL_CONSTRAINT)
    m.opt.density = m.opt.viscosity = 0.0
    d = mujoco.MjData(m)
    for seed in range(2):
        q, qd, tau, f_ext = random_state(model, seed)
        ctrl = np.random.default_rng(seed).uniform(-1.5, 1.5, m.nu)
        total = tau.copy()
        if report.actuation is not None:
            report.actuation.set_ctrl(ctrl[report.actuation.ids])
            report.actuation.tau(0.0, q, qd, total)
        mujoco_forward(m, d, q, qd, tau, f_ext)
        d.ctrl[:] = ctrl
        mujoco.mj_forward(m, d)
        assert_qdd_close(model, q, aba(model, q, qd, total, f_ext), d.qacc,
                         f"{name}: reference ABA vs mj_forward")
        qdd = vdad.forward_dynamics(model, q, qd, total, f_ext)
        assert_qdd_close(model, q, qdd, d.qacc, f"{name}: DCA vs mj_forward")
