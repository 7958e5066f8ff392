"""Screen coverage ``N_M(C)`` of every assembly-tree node (Kim 2008 §5.2-5.4; theory §7).

Two estimators, both callables ``(t, q, adaptive) -> N`` that return ``N``
(n_nodes + 1,) pixels per node (the last entry, the ground, is 0) at the
counting resolution, for the camera of the path at time ``t``:

* :class:`BoundingVolumes` (§5.3): ``N1`` the projected area of the node's
  volume, ``N2`` the sum of its bodies' (eqs. 5-6), and ``N_M = min(N1, N2)``
  (eq. 7) or either one alone (``estimate``). No occlusion.
* :class:`RenderedCounts` (§5.4): each body's visible pixels, rendered with the
  environment and every body as occluders (:mod:`vdad.render.counting`, by
  occlusion queries or the merged id buffer), summed up the tree.

``adaptive`` is the :class:`~vdad.adaptive.AdaptiveDynamics` whose region is
being simulated, or None for a full evaluation at configuration ``q``. With
adaptive dynamics only the active nodes and the front need ``N_M``: for spheres
and oriented boxes each rigid front node keeps its volume in its group frame
(computed once when it became rigid) and is only placed, so ``N1`` costs
follow the active region; ``N2``, world boxes and rendering touch every body.
"""

from __future__ import annotations

import numpy as np

from .bounding import Volumes, areas, body_volumes, check_volume, merge, place
from .camera import camera_at, check_path, check_resolution
from .errors import InputError
from .kinematics import world_poses

ESTIMATES = ("min", "node", "bodies")


def sum_up(tree, per_body):
    """Node totals (n_nodes + 1,) of ``per_body`` (nb,) values: each node the sum
    of its bodies' (the last entry, the ground, 0)."""
    N = np.zeros(tree.n_nodes + 1)
    N[:tree.model.nb] = per_body
    for lv in tree.levels:
        N[lv.node] = N[lv.node_A] + N[lv.node_B]
    return N


def _by_height(tree, nodes):
    """Internal ``nodes`` (ascending: children first), batched by their height
    among ``nodes`` (nodes outside at 0), lowest first."""
    nb = tree.model.nb
    height = np.zeros(tree.n_nodes + 1, int)
    for C in nodes.tolist():
        height[C] = 1 + max(height[tree.left[C - nb]], height[tree.right[C - nb]])
    h = height[nodes]
    return [nodes[h == k] for k in range(1, int(h.max()) + 1)] if len(nodes) else []


class _Coverage:
    """A camera path and the counting resolution (default: the camera's own)."""

    def __init__(self, tree, camera, resolution=None):
        self.tree, self.model = tree, tree.model
        if not any(body.geoms for body in self.model.bodies):
            raise InputError(f"view-dependent coverage needs geometry, but no body of model "
                             f"{self.model.name!r} has any (Body(..., geoms=(Geom(...),))): "
                             f"every joint would be frozen; use method='adaptive' instead")
        self.path = check_path(camera)
        self.resolution = check_resolution(resolution)

    def camera(self, t):
        """The camera at time ``t`` at the counting resolution."""
        cam = camera_at(self.path, t)
        return cam if self.resolution is None else cam.with_resolution(*self.resolution)

    def poses(self, q, adaptive):
        """World poses of all bodies at ``q`` (from the adaptive region if given)."""
        if adaptive is not None:
            return adaptive.body_poses(q)
        return world_poses(self.model, q)


class BoundingVolumes(_Coverage):
    """``N_M`` from bounding volumes (Kim 2008 §5.3, eqs. 5-7): ``volume`` one of
    ``"sphere"``, ``"obb"``, ``"aabb"``; ``estimate`` ``"min"`` (eq. 7),
    ``"node"`` (eq. 5, the node's own volume) or ``"bodies"`` (eq. 6, the sum
    over its bodies)."""

    def __init__(self, tree, camera, volume="sphere", estimate="min", resolution=None):
        super().__init__(tree, camera, resolution)
        if estimate not in ESTIMATES:
            raise InputError(f"unknown coverage estimate {estimate!r}; choose one of {ESTIMATES}")
        self.kind, self.estimate = check_volume(volume), estimate
        self.body = body_volumes(self.model, volume)                  # body frames
        n = tree.n_nodes
        # node volumes in their rigid group's frame, valid while stamp == adaptive.since
        self.local = Volumes.empty(volume, n + 1)
        self.local[np.arange(self.model.nb)] = self.body
        self.stamp = np.full(n + 1, np.nan)

    def __call__(self, t, q, adaptive=None):
        cam = self.camera(t)
        tree, nb = self.tree, self.model.nb
        need_bodies = self.estimate != "node" or self.kind == "aabb" or adaptive is None
        if need_bodies:
            world_bodies = place(self.body, *self.poses(q, adaptive))
        N2 = sum_up(tree, areas(world_bodies, cam)) if self.estimate != "node" else None
        if self.estimate == "bodies":
            return N2
        world = Volumes.empty(self.kind, tree.n_nodes + 1)
        if adaptive is None or self.kind == "aabb":
            world[np.arange(nb)] = world_bodies
            for lv in tree.levels:
                world[lv.node] = merge(world[lv.node_A], world[lv.node_B])
            nodes = np.arange(tree.n_nodes)
        else:
            front = adaptive.front
            self._refresh(front, adaptive)
            world[front] = place(self.local[front], *adaptive.group_poses(q, front))
            act = adaptive.act
            for rows in _by_height(tree, act):
                world[rows] = merge(world[tree.left[rows - nb]], world[tree.right[rows - nb]])
            nodes = np.concatenate([front, act])
        N1 = np.full(tree.n_nodes + 1, np.nan)
        N1[nodes] = areas(world[nodes], cam)
        N1[-1] = 0.0
        return N1 if N2 is None else np.fmin(N1, N2)

    def _refresh(self, front, adaptive):
        """Volumes in the group frame of the rigid ``front`` nodes whose cache is
        stale, and of their subtrees, bottom-up from the bodies'."""
        tree, since = self.tree, adaptive.since
        stale = front[(front >= self.model.nb) & (self.stamp[front] != since[front])]
        if not len(stale):
            return
        mark = np.zeros(tree.n_nodes + 1, bool)
        mark[stale] = True
        for lv in reversed(tree.levels):                          # down the subtrees
            mark[lv.node] |= mark[lv.node_up]
        g = adaptive.groups
        for lv in tree.levels:
            rows = np.flatnonzero(mark[lv.node])
            if len(rows):
                C = lv.node[rows]
                B = place(self.local[lv.node_B[rows]], g.rel_R[C], g.rel_p[C])
                self.local[C] = merge(self.local[lv.node_A[rows]], B)
        marked = np.flatnonzero(mark)
        self.stamp[marked] = since[marked]


class RenderedCounts(_Coverage):
    """``N_M`` from rendered visible-pixel counts (Kim 2008 §5.4): every body's
    pixels after occlusion by the ``environment`` and the other bodies and
    clipping by the viewport, summed up the tree. ``method``: ``"queries"``
    (the paper's occlusion queries after a depth pass) or ``"merged"`` (one
    draw of a merged buffer into an id image; the same counts, faster for many
    bodies). Fails at once with :class:`~vdad.errors.RenderError` without EGL."""

    def __init__(self, tree, camera, environment=None, method="queries", resolution=None):
        super().__init__(tree, camera, resolution)
        from .render.counting import PixelCounter

        start = camera_at(camera, 0.0)
        w, h = self.resolution or (start.width, start.height)
        self.counter = PixelCounter(self.model, environment, w, h, method)
        self.resolution = (w, h)

    def __call__(self, t, q, adaptive=None):
        counts = self.counter.counts(self.camera(t), *self.poses(q, adaptive))
        return sum_up(self.tree, counts)
