"""Joint sets and their subspace tables (vdad.kinematics, theory §3)."""

import numpy as np
import pytest
from strategies import random_state, random_tree, relative_error, tolerance

import vdad
from vdad import joints as J
from vdad import reference
from vdad.kinematics import (
    Kinematics,
    joint_kinematics,
    joint_set,
    kinematics,
    kinematics_pass,
    plan,
)
from vdad.scenes import pendulum


def test_equal_joint_subspaces_share_one_row():
    """Every hinge of a chain turns about the same axis: one row of S, T, W serves
    all of them, and joint_kinematics still gives each joint its own."""
    model = pendulum(50).model
    js = plan(model)
    assert js.S.shape == js.T.shape == js.W.shape == (1, 6, 6)
    assert np.array_equal(js.subspace, np.zeros(50, np.int64))
    _, _, S, T, W = joint_kinematics(js, model.q_neutral)
    assert S.shape == (50, 6, 6)
    axis = J.stage_subspace(model.stage_kind[0], model.stage_axis[0], model.stage_anchor[0])
    np.testing.assert_array_equal(S[:, :, :1], np.broadcast_to(axis, (50, 6, 1)))
    for j in range(50):                          # (T5): T^T S = 0, W^T S = 1, W^T T = 0
        np.testing.assert_allclose(T[j, :, :5].T @ S[j, :, :1], 0, atol=1e-15)
        np.testing.assert_allclose(W[j, :, :1].T @ S[j, :, :1], [[1]], rtol=1e-15)
        np.testing.assert_allclose(W[j, :, :1].T @ T[j, :, :5], 0, atol=1e-15)


def test_multi_stage_joints_own_their_rows():
    """Joints of several stages get a row each, filled from q by the kinematics;
    one-stage joints with different subspaces get different rows; a subset of the
    joints (as adaptive dynamics and force elements build) has its own table."""
    model = random_tree(3, n=24, composite=True)
    js = plan(model)
    multi = np.flatnonzero(model.n_stages_joint > 1)
    assert len(multi) > 0
    assert len(set(js.subspace[multi])) == len(multi)
    assert not set(js.subspace[multi]) & set(np.delete(js.subspace, multi))
    q, _, _, _ = random_state(model, 3)
    _, _, S, _, _ = joint_kinematics(js, q)
    first = np.cumsum(model.n_stages_joint) - model.n_stages_joint
    for j in range(model.nb):
        d = model.nv_joint[j]
        assert np.linalg.matrix_rank(S[j, :, :d]) == d
        if model.n_stages_joint[j] == 1:         # a one-stage joint: its stage's subspace
            s = first[j]
            np.testing.assert_array_equal(S[j, :, :d], J.stage_subspace(
                model.stage_kind[s], model.stage_axis[s], model.stage_anchor[s]))
    part = [0] + [j for j in range(1, model.nb) if model.parent[j] == 0]
    sub = joint_set(model, part, [-1] + [0] * (len(part) - 1))
    assert len(sub.S) <= len(part)
    np.testing.assert_array_equal(joint_kinematics(sub, q[sub.q_index])[2][1:],
                                  S[part[1:]])


def test_forward_dynamics_reads_the_shared_rows():
    """The DCA on a chain whose hinges share one row equals the reference ABA."""
    model = pendulum(30).model
    q, qd, tau, f_ext = random_state(model, 1)
    qdd = vdad.forward_dynamics(model, q, qd, tau, f_ext)
    assert relative_error(qdd, reference.aba(model, q, qd, tau, f_ext)) < tolerance(model, q)


def gimbal(seed=5):
    """One body on z-y-x hinges (a composite joint, as MJCF bodies with three
    joints), with gravity."""
    rng = np.random.default_rng(seed)
    body = vdad.Body("b", 1.0, tuple(rng.normal(size=3) * 0.2), (0.3, 0.4, 0.5))
    stages = tuple(J.Stage("hinge", axis) for axis in [(0, 0, 1), (0, 1, 0), (1, 0, 0)])
    return vdad.Model([body], [vdad.Joint("gimbal", None, "b", "composite", stages=stages)])


@pytest.mark.parametrize("gap", [1e-4, 1e-8])
def test_composite_joints_near_gimbal_lock_are_computed(gap):
    """z-y-x hinges at pitch pi/2 - gap: cond(M) = 3e8 and 1e18. The DCA computes
    both (it raised numpy's LinAlgError at 1e-8 before W came from a QR factor),
    within c cond(M) eps of the reference ABA and of MuJoCo (the CRBA's Cholesky
    fails at 1e-8)."""
    model = gimbal()
    q, qd = np.array([0.3, np.pi / 2 - gap, -0.2]), np.array([0.1, 0.2, 0.3])
    qdd = vdad.forward_dynamics(model, q, qd)
    assert np.all(np.isfinite(qdd))
    tol = tolerance(model, q, c=10.0)
    assert relative_error(qdd, reference.aba(model, q, qd)) < tol
    from vdad.interop.mujoco import mujoco_forward, to_mujoco

    assert relative_error(qdd, mujoco_forward(*to_mujoco(model), q, qd)) < tol


def test_a_composite_joint_in_gimbal_lock_is_a_simulation_error():
    """At pitch pi/2 the three axes span two directions: no accelerations exist.
    forward_dynamics and a simulation stop with a SimulationError naming the joint
    and its coordinates (not numpy's LinAlgError, not a NaN)."""
    model = gimbal()
    q, qd = np.array([0.3, np.pi / 2, -0.2]), np.array([0.1, 0.2, 0.3])
    with pytest.raises(vdad.SimulationError, match=r"joint 'gimbal' is in gimbal lock at q = "
                                                   r"\[ 0\.3 +1\.570796 -0\.2 *\]: its 3 axes "
                                                   r"span only 2 directions"):
        vdad.forward_dynamics(model, q, qd)
    sim = vdad.Simulator(model, q, qd, dt=1e-3)
    with pytest.raises(vdad.SimulationError, match=r"step 1 \(t = 0 s\): joint 'gimbal' is in "
                                                   r"gimbal lock"):
        sim.step()


def test_fresh_joints_keep_their_placement():
    """``kinematics_pass(..., fresh)``: the joints marked fresh keep the placement
    and subspaces that the work arrays hold, the others are placed at ``q`` and
    marked; every body's pose and velocity follows from the placements (the
    forces' kinematics of adaptive dynamics, whose rigid joints keep their ``q``)."""
    model = random_tree(5, n=12, composite=True)
    js = plan(model)
    q0, qd, _, _ = random_state(model, 5)
    q1 = random_state(model, 6)[0]
    kin, fresh = Kinematics.empty(js), np.zeros(model.nb, bool)
    kinematics_pass(js.arrays, q0, qd, True, *kin.arrays, fresh)
    assert fresh.all()
    names = ("R_rel", "p_rel", "S", "T", "W", "R", "p", "v", "c")
    at0 = kinematics(model, q0, qd)
    for name in names:
        np.testing.assert_array_equal(getattr(kin, name), getattr(at0, name))

    moved = np.arange(model.nb) % 2 == 1            # these joints' q changes; theirs only
    q = q0.copy()
    for j in np.flatnonzero(moved):
        i = slice(model.q_start[j], model.q_start[j] + model.nq_joint[j])
        q[i] = q1[i]
    fresh[moved] = False
    kinematics_pass(js.arrays, q, qd, True, *kin.arrays, fresh)
    assert fresh.all()
    at = kinematics(model, q, qd)
    for name in names:
        np.testing.assert_array_equal(getattr(kin, name), getattr(at, name))
    assert not np.allclose(at.R, at0.R)

    j = 2                                            # moved while marked fresh: stale
    i = slice(model.q_start[j], model.q_start[j] + model.nq_joint[j])
    q[i] = q1[i]
    kinematics_pass(js.arrays, q, qd, True, *kin.arrays, fresh)
    now = kinematics(model, q, qd)
    for name in ("R_rel", "p_rel"):
        np.testing.assert_array_equal(getattr(kin, name)[j], getattr(at, name)[j])
    assert not (np.allclose(kin.R_rel[j], now.R_rel[j]) and np.allclose(kin.p_rel[j],
                                                                        now.p_rel[j]))
