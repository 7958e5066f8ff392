"""Pictures of the algorithms' state for notebooks and docs: an assembly tree with
its active region (Kim 2008 §4, Figure 3) and per-node values such as ``N_M``.

matplotlib is imported when a function is called, never by ``import vdad``, and
its backend is left as the caller set it (inline in Jupyter).
"""

from __future__ import annotations

import numpy as np

from .errors import InputError


def tree_layout(tree):
    """Positions ``x``, ``y`` (n_nodes,) of the nodes of an assembly tree: bodies
    (leaves) on ``y = 0`` in the order of the tree's post-order walk
    (``tree.post``), an internal node at its height (``tree.height``) above the
    mean ``x`` of its children."""
    nb, n = tree.model.nb, tree.n_nodes
    x, y = np.zeros(n), np.asarray(tree.height, float)[:n]
    leaves = [v for v in tree.post if v < nb]
    x[leaves] = np.arange(len(leaves))
    for v in tree.post:
        if v >= nb:
            kids = [c for c in (tree.left[v - nb], tree.right[v - nb]) if c >= 0]
            x[v] = np.mean(x[kids])
    return x, y


def assembly_tree(tree, active=None, values=None, ax=None, title=None):
    """Draw ``tree`` (an :class:`~vdad.assembly.AssemblyTree`): bodies at the bottom,
    each internal node (a joint's sub-assembly) above its children. ``active``
    (n_nodes,) bool, e.g. ``sim.adaptive.active``: active nodes filled, rigid ones
    hollow; ``values`` (n_nodes,): shown by colour (e.g. ``N_M``), with a colour
    bar. Returns the matplotlib Axes."""
    import matplotlib.pyplot as plt

    n = tree.n_nodes
    for name, a in (("active", active), ("values", values)):
        if a is not None and np.shape(a)[0] < n:
            raise InputError(f"{name} must give one entry per node of the tree ({n}), got "
                             f"shape {np.shape(a)}")
    if ax is None:
        ax = plt.subplots(figsize=(min(12, 2 + 0.25 * tree.model.nb), 3))[1]
    x, y = tree_layout(tree)
    nb = tree.model.nb
    for m in range(n - nb):
        for c in (tree.left[m], tree.right[m]):
            if c >= 0:
                ax.plot([x[nb + m], x[c]], [y[nb + m], y[c]], color="0.6", lw=0.8, zorder=1)
    color = "tab:blue" if values is None else np.asarray(values, float)[:n]
    kw = dict(s=28, zorder=2, edgecolors="k", linewidths=0.6)
    if values is not None:
        kw.update(cmap="viridis")
    if active is None:
        points = ax.scatter(x, y, c=color, **kw)
    else:
        on = np.asarray(active, bool)[:n].copy()
        on[:nb] = True                                  # bodies are always there
        points = ax.scatter(x[on], y[on], c=color if values is None else color[on], **kw)
        ax.scatter(x[~on], y[~on], facecolors="white", edgecolors="0.4", s=28, zorder=2,
                   linewidths=0.8)
    if values is not None:
        ax.figure.colorbar(points, ax=ax, fraction=0.03, pad=0.01)
    ax.set_xticks([])
    ax.set_ylabel("height")
    ax.set_title(title or f"assembly tree of {tree.model.name!r} ({nb} bodies)"
                 + ("" if active is None else ": filled = active, hollow = rigid"))
    return ax
