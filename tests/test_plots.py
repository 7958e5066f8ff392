"""vdad.plots: the assembly tree's layout and drawing."""

import matplotlib
import numpy as np
import pytest

from vdad.errors import InputError
from vdad.plots import assembly_tree, tree_layout
from vdad.scenes import dog_puppet, pendulum

matplotlib.use("Agg")


@pytest.mark.parametrize("scene", [lambda: pendulum(n_bodies=13), dog_puppet])
def test_layout_puts_bodies_below_and_each_node_over_its_children(scene):
    sim = scene().simulator(method="adaptive")
    tree, nb = sim.tree, sim.model.nb
    x, y = tree_layout(tree)
    assert sorted(x[:nb]) == list(range(nb)) and np.all(y[:nb] == 0)
    for m in range(tree.n_nodes - nb):
        kids = [c for c in (tree.left[m], tree.right[m]) if c >= 0]
        assert x[nb + m] == pytest.approx(np.mean(x[kids]))
        assert y[nb + m] > max(y[kids])


def test_drawing_shows_the_active_region_and_values():
    sim = pendulum(n_bodies=10).simulator(method="adaptive", threshold=1e-4)
    sim.step(100)
    active = sim.adaptive.active
    ax = assembly_tree(sim.tree, active)
    filled, hollow = ax.collections[-2:]
    assert len(filled.get_offsets()) == sim.model.nb + np.sum(active[sim.model.nb:sim.tree.n_nodes])
    assert len(hollow.get_offsets()) == np.sum(~active[sim.model.nb:sim.tree.n_nodes])
    ax = assembly_tree(sim.tree, values=np.arange(sim.tree.n_nodes + 1.0))
    assert len(ax.figure.axes) == 2                             # the colour bar
    with pytest.raises(InputError, match="active must give one entry per node"):
        assembly_tree(sim.tree, active=[True])
