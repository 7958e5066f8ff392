"""The DCA against the reference algorithms (theory §8, checks 1, 2 and 7)."""

import numpy as np
import pytest
from strategies import (
    coil_chain,
    node_bodies,
    random_chain,
    random_configuration,
    random_state,
    random_tree,
    relative_error,
    tolerance,
    with_armature,
)

import vdad
from vdad import dca, reference
from vdad.assembly import AssemblyTree
from vdad.kinematics import kinematics


@pytest.mark.parametrize("seed", range(12))
def test_dca_equals_aba_and_crba_on_random_forests(seed):
    model = random_tree(seed, n=6 + 3 * seed, roots=1 + seed % 3, composite=seed % 2 == 1)
    q, qd, tau, f_ext = random_state(model, seed)
    qdd = vdad.forward_dynamics(model, q, qd, tau, f_ext)
    tol = tolerance(model, q)
    assert relative_error(qdd, reference.aba(model, q, qd, tau, f_ext)) < tol
    assert relative_error(qdd, reference.crba_forward_dynamics(model, q, qd, tau, f_ext)) < tol


def test_large_forests_run_their_trees_in_parallel_with_the_same_result():
    """A forest of at least dca.PARALLEL_BODIES bodies runs each root's subtree on
    numba's threads (dca.forest_passes): the same accelerations as ABA, and, to the
    last bit, as the serial passes of each tree alone."""
    model = with_armature(random_tree(7, n=dca.PARALLEL_BODIES + 40, roots=24,
                                      composite=True), 7)
    q, qd, tau, f_ext = random_state(model, 7)
    tree = AssemblyTree.balanced(model)
    assert len(tree.segments) - 1 == 24 and model.nb >= dca.PARALLEL_BODIES
    qdd = vdad.forward_dynamics(model, q, qd, tau, f_ext, tree=tree)
    assert relative_error(qdd, reference.aba(model, q, qd, tau, f_ext)) < tolerance(model, q)
    serial = vdad.dca.make_data(tree)
    passes = (vdad.kinematics.plan(model).arrays, tree.arrays, dca.body_arrays(model))
    dca.kinematics_pass(passes[0], q, qd, True, *serial.kin.arrays)
    Phi, b, Y, Wm, beta, gamma, f_J, qdd_s, tau_s, X, GY, tmp = serial.arrays
    dca.passive_forces_pass(*passes[2][5:11], q, qd, tau_s)
    tau_s += tau
    for r in range(len(tree.segments) - 1):
        dca.subtree_passes(tree.segments[r], tree.segments[r + 1], model.nb, *passes[:2],
                           passes[2], f_ext, serial.kin.arrays, tau_s, Phi, b, Y, Wm, beta,
                           gamma, f_J, qdd_s, X, GY, tmp)
    np.testing.assert_array_equal(qdd, qdd_s)


@pytest.mark.parametrize("seed", range(4))
def test_rnea_inverts_the_dca(seed):
    model = random_tree(seed, n=10, roots=2, composite=True)
    q, qd, tau, f_ext = random_state(model, seed)
    qdd = vdad.forward_dynamics(model, q, qd, tau, f_ext)
    tau_back = reference.rnea(model, q, qd, qdd, f_ext)
    assert relative_error(tau_back, tau) < tolerance(model, q)


@pytest.mark.parametrize("armature", [False, True])
def test_mass_matrix_gives_kinetic_energy(armature):
    from vdad.quantities import kinetic_energy

    model = random_tree(3, n=9, roots=2, composite=True)
    model = with_armature(model, 3) if armature else model
    q, qd, _, _ = random_state(model, 3)
    M = reference.crba(model, q)
    np.testing.assert_allclose(M, M.T, atol=1e-14 * np.abs(M).max())
    assert np.linalg.eigvalsh(M)[0] > 0
    assert kinetic_energy(model, q, qd) == pytest.approx(0.5 * qd @ M @ qd, rel=1e-12)


def test_port_inverse_inertia_is_J_Minv_JT():
    """Phi = J M^-1 J^T for free-floating sub-assemblies (theory §2, check 2).

    Each 2-port node of a free-floating chain covers bodies i..k; the same bodies
    as a model of their own (body i on a free joint) give M, and the port
    Jacobians are the velocities of body i in its frame and of body k in the
    frame of joint k+1.
    """
    model = random_chain(7, n=9, root="free")
    rng = np.random.default_rng(7)
    q = random_configuration(model, rng)
    tree = AssemblyTree.balanced(model)
    data = dca.make_data(tree)
    vdad.forward_dynamics(model, q, np.zeros(model.nv), tree=tree, data=data)
    kin = kinematics(model, q, np.zeros(model.nv))
    checked = 0
    for node, ports in enumerate(tree.ports):
        if node < model.nb or len(ports) == 0:
            continue
        bodies = node_bodies(tree, node)
        i, k = bodies[0], bodies[-1]
        sub = _submodel(model, bodies)
        q_sub = np.concatenate([kin.p[i], vdad.spatial.rot_to_quat(kin.R[i]),
                                q[model.q_start[i + 1]:model.q_start[k] + model.nq_joint[k]]])
        M = reference.crba(sub, q_sub)
        J = []
        for joint, side in ports:
            cols = []
            for d in range(sub.nv):
                e = np.zeros(sub.nv)
                e[d] = 1.0
                v = kinematics(sub, q_sub, e).v
                if side > 0:
                    cols.append(v[joint - i])
                else:
                    X = vdad.spatial.pose_to_motion_transform(kin.R_rel[joint], kin.p_rel[joint])
                    cols.append(X @ v[model.parent[joint] - i])
            J.append(np.array(cols).T)
        J = np.vstack(J)
        expected = J @ np.linalg.solve(M, J.T)
        assert relative_error(dca.node_blocks(tree, data, node), expected) < tolerance(sub, q_sub)
        checked += 1
    assert checked >= 4
    for bad, message in ((tree.n_nodes, "node must be below the tree's"),
                         (-1, "node must be an integer >= 0"), (1.5, "node must be an integer")):
        with pytest.raises(vdad.InputError, match=message):
            dca.node_blocks(tree, data, bad)


def test_a_joint_of_six_dofs_gathers_its_childrens_blocks():
    """(T7) with no constrained direction gives Y = 0, so (T11) keeps each child's
    blocks and couples none across the joint (the merge skips its products):
    a free joint inside a random tree, without armature and with it (Y != 0)."""
    base = random_tree(4, n=10, kinds=("revolute", "free", "spherical"))
    for model, zero in ((base, True), (with_armature(base, 4), False)):
        q, qd, tau, f_ext = random_state(model, 4)
        tree = AssemblyTree.balanced(model)
        data = dca.make_data(tree)
        qdd = vdad.forward_dynamics(model, q, qd, tau, f_ext, tree=tree, data=data)
        assert relative_error(qdd, reference.aba(model, q, qd, tau, f_ext)) < tolerance(model, q)
        nb, checked = model.nb, 0
        for i, j in enumerate(tree.joint):
            if model.joints[j].kind != "free" or tree.left[i] < 0:
                continue
            C, A, B = nb + i, tree.left[i], tree.right[i]
            assert (np.abs(data.Y[i]).max() == 0) == zero
            Phi = dca.node_blocks(tree, data, C)
            gathered = np.zeros_like(Phi)
            for a, port in enumerate(tree.ports[C]):
                for c, other in enumerate(tree.ports[C]):
                    X = A if port in tree.ports[A] else B
                    if other not in tree.ports[X]:
                        continue
                    blocks = dca.node_blocks(tree, data, X)
                    ia, ic = tree.ports[X].index(port), tree.ports[X].index(other)
                    block = blocks[6 * ia:6 * ia + 6, 6 * ic:6 * ic + 6]
                    if a == c:                           # (T11) keeps it symmetric
                        block = 0.5 * (block + block.T)
                    gathered[6 * a:6 * a + 6, 6 * c:6 * c + 6] = block
            if zero:
                np.testing.assert_array_equal(Phi, gathered)
            else:
                assert np.abs(Phi - gathered).max() > 1e-6 * np.abs(Phi).max()
            checked += 1
        assert checked >= 1


def _submodel(model, bodies):
    out_bodies = [model.bodies[b] for b in bodies]
    joints = [vdad.Joint("root", None, model.body_names[bodies[0]], "free")]
    joints += [model.joints[b] for b in bodies[1:]]
    return vdad.Model(out_bodies, joints, gravity=model.gravity)


@pytest.mark.parametrize("root", ["revolute", "free"])
def test_translation_by_one_kilometre(root):
    """Port frames make the DCA translation-invariant (theory §1, check 7)."""
    model = random_chain(11, n=32, root=root)
    q, qd, tau, f_ext = random_state(model, 11)
    qdd = vdad.forward_dynamics(model, q, qd, tau, f_ext)
    if root == "free":
        q_far = q.copy()
        q_far[:3] += [1000.0, -700.0, 300.0]
        far = model
    else:
        joints = list(model.joints)
        R, p = joints[0].placement.matrix()
        joints[0] = vdad.Joint("j0", None, "b0", root, axis=joints[0].axis,
                               placement=vdad.Pose(tuple(p + [1000.0, -700.0, 300.0]), R))
        far = vdad.Model(model.bodies, joints, gravity=model.gravity)
        q_far = q
    # f_ext's torques are about each centre of mass, so they do not change
    qdd_far = vdad.forward_dynamics(far, q_far, qd, tau, f_ext)
    assert relative_error(qdd_far, qdd) < 1e-9


@pytest.mark.parametrize("n", [8, 32, 128, 256])
def test_coil_chain(n):
    """Featherstone's coil: error grows with cond(M) and stays within c·cond·eps."""
    model = coil_chain(n)
    rng = np.random.default_rng(n)
    q, qd, tau = rng.normal(size=n), rng.normal(size=n), rng.normal(size=n)
    qdd = vdad.forward_dynamics(model, q, qd, tau)
    expected = reference.crba_forward_dynamics(model, q, qd, tau)
    assert relative_error(qdd, expected) < tolerance(model, q, c=10.0)


def test_bad_inputs_raise_vdad_errors():
    model = random_tree(0, n=4)
    q, qd, tau, f_ext = random_state(model, 0)
    with pytest.raises(vdad.InputError, match=rf"q must have shape \({model.nq},\)"):
        vdad.forward_dynamics(model, q[:-1], qd)
    with pytest.raises(vdad.InputError, match="qd has non-finite entries at indices \\[2\\]"):
        bad = qd.copy()
        bad[2] = np.nan
        vdad.forward_dynamics(model, q, bad)
    with pytest.raises(vdad.InputError, match="f_ext is not finite on body 'b1'"):
        bad = f_ext.copy()
        bad[1, 4] = np.inf
        vdad.forward_dynamics(model, q, qd, tau, bad)
    with pytest.raises(vdad.InputError, match="f_ext must have shape"):
        vdad.forward_dynamics(model, q, qd, tau, f_ext[:, :3])
