"""Two simplifications that game engines use, as baselines for view-dependent
dynamics (``docs/reproduction.md``): whole articulated bodies made rigid beyond
a distance from the viewer (a distance level of detail), and articulated bodies
put to sleep when they have moved slowly for a while.

Both run on the adaptive machinery of :mod:`vdad.adaptive`, so their timings
compare with the view-dependent methods' on equal terms: each is a switch
``(t, q, adaptive) -> N`` (n_nodes + 1,) of ones and zeros that takes the place of
the coverage ``N_M``, with ``threshold = 0``. A node with ``N = 1`` keeps its
joint articulated wherever its metric is not exactly zero (the full dynamics);
a node with ``N = 0`` scores zero and is rigidified. On :func:`root_last_tree`
every articulated body's joint to the world is its top node, so switching all
its other nodes off leaves one rigid body hanging from that joint (a pendulum
swings as one rod; a floating dog or character moves as one rigid body, since
a floating base is never locked). Like the coverage, a switch is evaluated once
per displayed frame by default (``coverage_every``, as a game engine decides
its levels of detail and its sleepers per frame), and it gives every node's value
(``covers_every_node``): the adaptive steps run in compiled code between frames.
"""

from __future__ import annotations

import numpy as np

from .assembly import AssemblyTree
from .camera import camera_at, check_path
from .checks import check_real
from .kinematics import plan


def articulated_bodies(model) -> np.ndarray:
    """Root joint (nb,) of each body's articulated body: the joint of the tree of
    bodies it belongs to that joins that tree to the world."""
    return plan(model).root_of


def root_last_tree(model) -> AssemblyTree:
    """The balanced assembly tree with every joint to the world assembled last,
    so that it is the top node of its articulated body."""
    balanced = AssemblyTree.balanced(model)
    roots = np.asarray(model.parent) < 0
    order = [int(j) for j in balanced.joint if not roots[j]]
    return AssemblyTree(model, order + [int(j) for j in np.flatnonzero(roots)])


class _Switch:
    """Per articulated body, whether its joints are articulated (1) or rigid (0)."""

    covers_every_node = True                 # a region change needs no new switch

    def __init__(self, tree):
        model = tree.model
        self.tree, self.model = tree, model
        nb, n = model.nb, tree.n_nodes
        body_root = articulated_bodies(model)
        self.roots = np.unique(body_root)                         # (c,) root joints
        comp_of_joint = np.searchsorted(self.roots, body_root)    # (nb,)
        self.component = np.concatenate([comp_of_joint, comp_of_joint[tree.joint]])  # (n,)
        self.top = np.zeros(n + 1, bool)                         # roots of the tree
        self.top[nb:n] = tree.up[nb:n] < 0

    def switch(self, on, keep_top):
        """N (n_nodes + 1,): 1 on the nodes of components ``on`` (c,) bool, and on
        the top nodes if ``keep_top``; 0 elsewhere and on the sentinel."""
        N = np.zeros(self.tree.n_nodes + 1)
        N[:-1] = on[self.component]
        if keep_top:
            N[self.top] = 1.0
        return N


class DistanceLOD(_Switch):
    """``docs/reproduction.md``, baselines: a game engine's distance level of detail.
    Whole articulated bodies rigid beyond ``distance`` (m) from the viewer: each
    body's distance is its root body's (the body on the joint to the world) from
    the position of ``camera`` (a :class:`~vdad.camera.Camera` or a path ``t ->
    Camera``) at time ``t``; its joint to the world stays articulated."""

    def __init__(self, tree, camera, distance):
        super().__init__(tree)
        self.path = check_path(camera)
        self.distance = check_real("distance", distance, positive=True)

    def __call__(self, t, q, adaptive):
        _, p = adaptive.body_poses(q, self.roots)                  # (c, 3)
        eye = np.asarray(camera_at(self.path, t).position, float)
        near = np.linalg.norm(p - eye, axis=1) <= self.distance
        return self.switch(near, keep_top=True)


class Sleeping(_Switch):
    """``docs/reproduction.md``, baselines: articulated bodies asleep after moving
    slowly (a game engine's sleeping).

    A body falls asleep when its speed, ``sqrt(V)`` of its top node (theory
    (T15): rad/s on hinges, link lengths per second on slides), has stayed below
    ``sleep_speed`` for ``sleep_time`` seconds; then all its joints are locked (a
    floating base still moves as one rigid body). It wakes when a released joint
    would accelerate faster than ``sleep_speed / sleep_time`` (the look-ahead at
    its front: a force that would wake it within ``sleep_time``; a front locked
    less than ``dwell`` steps before is not looked ahead, ``docs/adaptive.md``,
    "Hysteresis and dwell"), or when its floating base moves faster than
    ``sleep_speed``."""

    def __init__(self, tree, sleep_speed=0.05, sleep_time=0.5):
        super().__init__(tree)
        self.speed = check_real("sleep_speed", sleep_speed, positive=True)
        self.duration = check_real("sleep_time", sleep_time, positive=True)
        c = len(self.roots)
        self.asleep = np.zeros(c, bool)
        self.quiet_since = np.full(c, np.nan)          # time each became slow (NaN: moving)

    def __call__(self, t, q, adaptive):
        tops = np.flatnonzero(self.top)
        comp = self.component[tops]
        speed = np.full(len(self.roots), np.inf)
        live = adaptive.active[tops]                   # a locked top's V is stale
        speed[comp[live]] = np.sqrt(np.maximum(adaptive.V[tops[live]], 0.0))
        slow = speed < self.speed
        self.quiet_since = np.where(slow, np.fmin(self.quiet_since, t), np.nan)
        wake = np.isfinite(speed) & ~slow
        F = adaptive.front
        F = F[(F >= adaptive.model.nb) & ~np.isnan(adaptive.la[F])]
        if len(F):
            pushed = np.sqrt(np.maximum(adaptive.la[F], 0.0)) > self.speed / self.duration
            wake[self.component[F[pushed]]] = True
        self.asleep = (self.asleep | (t - self.quiet_since >= self.duration)) & ~wake
        return self.switch(~self.asleep, keep_top=False)
