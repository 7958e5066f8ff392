"""Assembly trees (vdad.assembly): shape, ports and order independence (theory §5)."""

import numpy as np
import pytest
from strategies import random_state, random_tree, relative_error, tolerance

import vdad
from vdad.assembly import AssemblyTree
from vdad.scenes import pendulum


@pytest.mark.parametrize("n", [1, 2, 7, 20, 300, 1000])
def test_balanced_chain_has_log_depth_and_two_ports(n):
    tree = AssemblyTree.balanced(pendulum(n).model)
    assert tree.depth == int(np.ceil(np.log2(n + 1)))       # n joints + the ground leaf
    assert max(len(p) for p in tree.ports) <= 2
    assert len(tree.joint) == n and sorted(tree.post) == list(range(tree.n_nodes))


def test_tree_ports_stay_small_and_depth_logarithmic():
    model = random_tree(5, n=200, roots=3)
    tree = AssemblyTree.balanced(model)
    assert tree.depth <= 4 * np.log2(model.nb)
    assert len(tree.joint) == model.nb
    assert sorted(tree.post) == list(range(tree.n_nodes))


@pytest.mark.parametrize("seed", range(6))
def test_result_does_not_depend_on_assembly_order(seed):
    model = random_tree(seed, n=15, roots=2, composite=True)
    q, qd, tau, f_ext = random_state(model, seed)
    reference = vdad.forward_dynamics(model, q, qd, tau, f_ext)
    rng = np.random.default_rng(seed)
    orders = [AssemblyTree.sequential(model)]
    orders += [AssemblyTree(model, rng.permutation(model.nb)) for _ in range(4)]
    orders += [AssemblyTree(model, list(reversed(model.joint_names)))]
    for tree in orders:
        qdd = vdad.forward_dynamics(model, q, qd, tau, f_ext, tree=tree)
        assert relative_error(qdd, reference) < tolerance(model, q)


def test_invalid_orders():
    model = random_tree(0, n=4)
    with pytest.raises(vdad.InputError, match="every joint exactly once"):
        AssemblyTree(model, [0, 1, 2])
    with pytest.raises(vdad.InputError, match="every joint exactly once"):
        AssemblyTree(model, [0, 1, 2, 2])
    with pytest.raises(vdad.ModelError, match="no joint called 'j9'"):
        AssemblyTree(model, ["j0", "j1", "j2", "j9"])
    with pytest.raises(vdad.InputError, match="out of range"):
        AssemblyTree(model, [0, 1, 2, 7])


@pytest.mark.parametrize("order, match", [
    ([0, 1, 2.5], "joint index must be an integer >= 0, got 2.5"),
    ([True, False, 2], "joint index must be an integer >= 0, got True"),
    ([0, 1, None], "joint index must be an integer >= 0, got None"),
    ([0, 1, np.nan], "joint index must be an integer >= 0"),
    ([0, 1, 3], r"joint index 3 out of range 0..2"),
    (None, "an assembly order is a sequence of joint names or indices, got None"),
    (5, "an assembly order is a sequence"),
    ("joint0", "an assembly order is a sequence"),
    (["joint0", "joint1", "joint9"], "no joint called 'joint9'"),
    ([0, 1, 1], "every joint exactly once"),
])
def test_bad_assembly_orders(order, match):
    with pytest.raises((vdad.InputError, vdad.ModelError), match=match):
        AssemblyTree(pendulum(3).model, order)


@pytest.mark.parametrize("build", [lambda m: AssemblyTree(m, [0]), AssemblyTree.balanced,
                                   AssemblyTree.sequential])
def test_trees_need_models(build):
    with pytest.raises(vdad.InputError, match="model must be a vdad.Model, got str"):
        build("model")


def test_a_tree_of_other_joint_dofs_is_refused_by_name():
    tree = AssemblyTree.balanced(pendulum(3, joint="spherical").model)
    with pytest.raises(vdad.InputError, match="whose joint 'joint0' has 3 dofs where joint "
                                              "'joint0' of model 'pendulum3' has 1"):
        vdad.forward_dynamics(pendulum(3).model, np.zeros(3), np.zeros(3), tree=tree)
