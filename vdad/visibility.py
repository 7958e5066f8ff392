"""Screen coverage ``N_M(C)`` of every assembly-tree node (Kim 2008 §5.2-5.4; theory §7).

Two estimators, both callables ``(t, q, adaptive) -> N`` that return ``N``
(n_nodes + 1,) pixels per node (the last entry, the ground, is 0) at the
counting resolution, for the camera of the path at time ``t``:

* :class:`BoundingVolumes` (§5.3): ``N1`` the projected area of the node's
  volume, ``N2`` the sum of its bodies' (eqs. 5-6), and ``N_M = min(N1, N2)``
  (eq. 7) or either one alone (``estimate``). No occlusion.
* :class:`RenderedCounts` (§5.4): each body's visible pixels, rendered with the
  environment and every body as occluders (:mod:`vdad.render.counting`, by
  occlusion queries or the merged id buffer on OpenGL, or :mod:`vdad.raster`,
  the id buffer rasterised in compiled code), summed up the tree.

Both take the rule ``pixels``: ``"own"`` (Kim 2008 §5.2: a node is weighted by
the pixels of its own bodies) or ``"moved"`` (``docs/visibility.md``, "Pixels a
joint moves": by the pixels of the bodies its joints displace,
:func:`moved_pass`).

``adaptive`` is the :class:`~vdad.adaptive.AdaptiveDynamics` whose region is
being simulated, or None for a full evaluation at configuration ``q``. With
adaptive dynamics only the active nodes and the front need ``N_M``: under eq. 5
(``estimate="node"``) with spheres and oriented boxes each rigid front node
keeps its volume in its group frame (computed once when it became rigid) and is
only placed, so the cost follows the active region (and a region change needs a
new evaluation: :attr:`BoundingVolumes.covers_every_node`); eqs. 6-7, world
boxes and rendering touch every body, and evaluate the whole tree in one pass,
in which oriented boxes of the rigid groups' internal nodes are also placed from
those volumes kept in their group frames rather than merged.
"""

from __future__ import annotations

import numba
import numpy as np
from numba import prange

from ._linalg import as_input, compiling, inlined, parallel_kernel, pass_kernel
from .bounding import (
    KIND_CODE,
    OBB,
    body_volumes,
    camera_pose,
    check_volume,
    copy_volume,
    merge_volumes,
    pack,
    place_volume,
    volume_area,
)
from .camera import camera_at, check_path, check_resolution
from .dca import in_parallel
from .errors import InputError
from .hybrid import child_slot, down_groups, front_frames, group_poses
from .kinematics import Kinematics, kinematics_pass, plan, world_poses
from .projection import box_scratch, view_of
from .raster import raster_pass

ESTIMATES = ("min", "node", "bodies")
MIN, NODE, BODIES = 0, 1, 2                      # codes of ESTIMATES for the kernels

#: eq. 7 skips a node's area where its bodies' total is below ``1 - SKIP_MARGIN``
#: of its children's areas: above the relative error of the areas of spheres cut
#: by the near plane (1e-5, sampled), so that ``N_M`` is what it would be
#: computed (``docs/visibility.md``, "Areas that eq. 7 skips")
SKIP_MARGIN = 1e-4
PIXELS = ("own", "moved")                        # whose pixels weight a node's joints
#: view-oq's counts: OpenGL's occlusion queries or merged id buffer, or the
#: compiled rasteriser on the CPU (:class:`RenderedCounts`)
COUNTING = ("queries", "merged", "raster")


def _ids(nodes):
    """A writable int64 copy: a model's read-only arrays would give the compiled
    adaptive steps a second numba type (:func:`idle_loop_coverage`)."""
    return np.array(nodes, np.int64)


@pass_kernel
def sum_up_pass(nb, left, right, N):
    """Node totals in ``N`` (n_nodes + 1,) of the bodies' values in
    ``N[:nb]``: each internal node (post-order ids: children first) the sum of its
    children's; the ground's slot stays 0."""
    n_nodes = nb + left.shape[0]
    N[n_nodes] = 0.0
    for m in range(left.shape[0]):
        N[nb + m] = N[child_slot(left[m], n_nodes)] + N[child_slot(right[m], n_nodes)]


@pass_kernel
def id_counts_pass(image, counts):
    """Kim 2008 §5.4, the merged id buffer: the pixels of each body ``i`` (id
    ``i + 1``) in ``image`` (height, width) into ``counts`` (nb,); the background
    (id 0), most of the image, is only compared, so that the counts do not wait
    on one another (a count of every id, ``np.bincount``, cost 3.6 times as
    much at 320 x 240)."""
    nb = counts.shape[0]
    for i in range(nb):
        counts[i] = 0
    for r in range(image.shape[0]):
        for c in range(image.shape[1]):
            k = image[r, c]
            if 0 < k <= nb:
                counts[k - 1] += 1


@pass_kernel
def moved_pass(nb, parent, root, floating, left, right, joint, S, N):
    """``docs/visibility.md``, pixels a joint moves (eqs. (V1)-(V2)): from each
    body's pixels in ``N[:nb]``, each internal node's ``N`` the largest, over the
    joints of its subtree, of the pixels of the bodies the joint displaces: its
    successor's subtree in the kinematic tree (``parent`` (nb,), topological
    order), or the smaller of its two sides for a joint inside a ``floating``
    articulated body (flags per ``root`` body). ``S`` (nb,): scratch subtree sums."""
    n_nodes = nb + left.shape[0]
    for b in range(nb):
        S[b] = N[b]
    for b in range(nb - 1, -1, -1):              # children after their parents
        if parent[b] >= 0:
            S[parent[b]] += S[b]
    N[n_nodes] = 0.0
    for m in range(left.shape[0]):               # post-order: children first
        j, A, B = joint[m], left[m], right[m]
        w = S[j]
        if floating[root[j]] and j != root[j]:
            w = min(w, max(S[root[j]] - w, 0.0))
        if A >= nb:
            w = max(w, N[A])
        if B >= nb:
            w = max(w, N[B])
        N[nb + m] = w


@inlined
def combine(estimate, N1, N2):
    """``N_M`` of a node from its own volume's pixels ``N1`` and its bodies' ``N2``
    (Kim 2008 eqs. 5-7: ``min``, ``node`` or ``bodies``)."""
    if estimate == NODE:
        return N1
    if estimate == BODIES:
        return N2
    return min(N1, N2)


@inlined
def finish(estimate, nb, n_nodes, N1, N, n):
    """Kim 2008 eqs. 5-7: ``N[n]`` of internal node ``n`` from its bodies' total
    to its ``N_M`` (:func:`combine`), once its parent has summed it (a body's is
    its area, a ground child has none)."""
    if nb <= n < n_nodes:
        N[n] = combine(estimate, N1[n], N[n])


@pass_kernel
def coverage_pass(r0, r1, kind, estimate, view, Rc, pc, nb, left, right, forest, body, R, p,
                  world, N1, N, grouped, scratch):
    """``N_M`` (Kim 2008 §5.3, eqs. 5-7) of the nodes of the subtrees of roots
    ``r0`` to ``r1 - 1`` into ``N`` (n_nodes + 1,), in post-order (children
    first; ``forest`` = (post, segments) of the tree): the bodies' volumes
    ``body`` (packed ``c, R, h``, body frames) placed at their world poses ``R``,
    ``p``, their areas; each internal node's volume merged from its children's
    into ``world`` (n_nodes + 1 slots, the last an empty ground) and its area
    ``N1``, and its bodies' total (``N``, combined by :func:`finish` once its
    parent has summed it). Camera: world pose
    ``Rc``, ``pc``, intrinsics ``view``. Under eq. 7 a node's area is not
    computed where its bodies' total is below its children's areas
    (``docs/visibility.md``, "Areas that eq. 7 skips"): its volume holds
    theirs, so its area is at least the larger, and ``N_M`` is the total;
    ``N1`` keeps that bound. ``grouped`` = (active (N,), local, rel_R, rel_p):
    with ``active`` not empty, the poses ``R``, ``p`` (n_nodes + 1, ...) hold
    the front nodes' only (:func:`~vdad.hybrid.front_frames`), and the rigid
    groups' bodies and internal nodes are placed first, top-down from them
    (:func:`~vdad.hybrid.down_groups`); and an oriented box of an internal node
    inside a rigid group (not active) is its volume ``local`` in its own frame,
    kept by :func:`refresh_group`, placed at that frame's pose ``R[n]``,
    ``p[n]`` instead of merged: the merge commutes with placement, so the two
    agree to rounding, and a placement costs less than half a merge.
    ``scratch`` = (a 3 x 3 work matrix, :func:`~vdad.projection.box_scratch`).
    Compiled as a call of its own, as :func:`vdad.dca.subtree_passes`:
    :func:`forest_coverage` calls it on threads, and numba's parallel analysis
    fails on the volume kernels inlined."""
    bc, bR, bh = body
    c, Rv, h = world
    active, (lc, lR, lh), rel_R, rel_p = grouped
    post, segments = forest
    grouped_on = active.shape[0] > 0
    from_groups = kind == OBB and grouped_on
    n_nodes = nb + left.shape[0]
    if grouped_on:
        down_groups(r0, r1, nb, left, right, forest, active, rel_R, rel_p, R, p, scratch[0])
    box = scratch[1]
    for k in range(segments[r0], segments[r1]):
        n = post[k]
        if n < nb:
            place_volume(kind, bc[n], bR[n], bh[n], R[n], p[n], c[n], Rv[n], h[n])
        else:
            A, B = child_slot(left[n - nb], n_nodes), child_slot(right[n - nb], n_nodes)
            N[n] = N[A] + N[B]
            finish(estimate, nb, n_nodes, N1, N, A)
            finish(estimate, nb, n_nodes, N1, N, B)
            if estimate == BODIES:
                continue
            if from_groups and not active[n]:
                place_volume(kind, lc[n], lR[n], lh[n], R[n], p[n], c[n], Rv[n], h[n])
            else:
                merge_volumes(kind, c[A], Rv[A], h[A], c[B], Rv[B], h[B], c[n], Rv[n], h[n])
            if estimate == MIN:
                bound = max(N1[A], N1[B])
                if N[n] < (1.0 - SKIP_MARGIN) * bound:
                    N1[n] = bound
                    continue
        N1[n] = volume_area(kind, view, Rc, pc, c[n], Rv[n], h[n], box)
        if n < nb:
            N[n] = N1[n]
    for r in range(r0, r1):
        finish(estimate, nb, n_nodes, N1, N, post[segments[r + 1] - 1])


@parallel_kernel
def forest_coverage(kind, estimate, runs, view, Rc, pc, nb, left, right, forest, body, R, p,
                    world, N1, N, grouped):
    """:func:`coverage_pass` of a forest's root subtrees on numba's threads, in
    ``runs`` (the caller's ``numba.get_num_threads()``: called here, it would
    keep the kernel out of the cache) runs of consecutive roots of about equal
    node counts, each with its own scratch; each writes only its own nodes'
    slots."""
    post, segments = forest       # tuples of arrays unpacked outside the parallel loop:
    bc, bR, bh = body             # numba's parallel lowering takes them for scalars
    c, Rv, h = world
    active, (lc, lR, lh), rel_R, rel_p = grouped
    for r in prange(runs):
        coverage_pass(first_root(segments, r, runs), first_root(segments, r + 1, runs), kind,
                      estimate, view, Rc, pc, nb, left, right, (post, segments), (bc, bR, bh),
                      R, p, (c, Rv, h), N1, N, (active, (lc, lR, lh), rel_R, rel_p),
                      (np.empty((3, 3)), box_scratch()))


@inlined
def first_root(segments, r, runs):
    """The first root of run ``r`` of ``runs`` (``runs``: the number of roots): the
    first whose subtree starts at or after the fraction ``r / runs`` of the nodes."""
    roots, total = segments.shape[0] - 1, segments[-1]
    k = 0
    while k < roots and segments[k] * runs < r * total:
        k += 1
    return k


@inlined
def cover(codes, view, Rc, pc, nb, left, right, forest, body, R, p, world, N1, N, moved,
          grouped, scratch):
    """Kim 2008 §5.3, eqs. 5-7, of the whole tree from the bodies' world poses
    ``R``, ``p`` into ``N`` (n_nodes + 1,): :func:`coverage_pass` of every root's
    subtree (of a large forest, in ``codes[3]`` runs on numba's threads as the
    DCA's: :func:`forest_coverage`), then, under the moved-pixels rule,
    :func:`moved_pass` (``moved`` its arrays). ``codes`` (4,): volume kind,
    estimate, moved rule (0/1), runs; ``forest`` (post, segments) and
    ``grouped`` (the rigid groups), ``scratch``: of :func:`coverage_pass`."""
    n_nodes = nb + left.shape[0]
    world[2][n_nodes, 0] = -1.0                 # the ground: empty, no pixels
    N[n_nodes] = 0.0
    N1[n_nodes] = 0.0
    if in_parallel(nb, forest[1]):
        forest_coverage(codes[0], codes[1], codes[3], view, Rc, pc, nb, left, right, forest,
                        body, R, p, world, N1, N, grouped)
    else:
        coverage_pass(0, forest[1].shape[0] - 1, codes[0], codes[1], view, Rc, pc, nb, left,
                      right, forest, body, R, p, world, N1, N, grouped, scratch)
    if codes[2]:
        parent, root, floating, _, _, joint, sums = moved
        moved_pass(nb, parent, root, floating, left, right, joint, sums, N)


@pass_kernel
def bvh_pass(codes, view, Rc, pc, nb, js, q, kin, left, right, forest, body, world, N1, N,
             moved, grouped, scratch):
    """:func:`cover` at configuration ``q`` (nq,), every body placed by
    :func:`~vdad.kinematics.kinematics_pass` (poses only, into ``kin``; rigid joints
    keep their ``q``): the evaluation of :class:`BoundingVolumes` without an
    adaptive region (``grouped``: an empty ``active``, every node merged)."""
    R_rel, p_rel, S, T, W, R, p, v, c, R3, v6, work = kin
    kinematics_pass(js, q, q, False, R_rel, p_rel, S, T, W, R, p, v, c, R3, v6, work)
    cover(codes, view, Rc, pc, nb, left, right, forest, body, R, p, world, N1, N, moved,
          grouped, scratch)


@pass_kernel
def region_bvh_pass(codes, view, Rc, pc, nb, left, right, forest, first, hybrid, since, R_top,
                    p_top, poses, body, cache, world, N1, N, moved, scratch):
    """:func:`cover` of a hybrid body: every body placed from the poses ``R_top``,
    ``p_top`` (nb, ...) of the active joints' child bodies that a step of
    adaptive dynamics computes, the rigid groups' bodies from their group's
    (:func:`~vdad.hybrid.front_frames` here, then :func:`coverage_pass`, into
    ``poses`` = (R (n_nodes + 1, 3, 3), p (n_nodes + 1, 3))). ``hybrid`` =
    (visit, n_visit, active, grounded, top, rel_R, rel_p): the region's front
    and the groups' frames; ``first``: each internal node's first internal id.
    Oriented boxes: the volumes of the rigid groups' internal nodes placed from
    their frames (:func:`coverage_pass`), stale ones refreshed first (``cache``
    = (local, stamp, tmp) of :func:`refresh_group`). The evaluation of
    :class:`BoundingVolumes` with an adaptive region, once per frame inside the
    compiled adaptive steps (``vdad.region.region_steps``)."""
    visit, n_visit, active, grounded, top, rel_R, rel_p = hybrid
    local, stamp, tmp = cache
    R, p = poses
    front_frames(nb, visit, n_visit, active, grounded, top, R_top, p_top, R, p)
    if codes[0] == OBB:
        for e in range(n_visit):
            if not active[visit[e]]:
                refresh_group(codes[0], nb, left, right, first, visit[e], rel_R, rel_p, since,
                              local, stamp, tmp)
    cover(codes, view, Rc, pc, nb, left, right, forest, body, R, p, world, N1, N, moved,
          (active, local, rel_R, rel_p), scratch)


@pass_kernel
def region_raster_pass(codes, view, Rc, pc, nb, left, right, forest, hybrid, R_top, p_top, poses,
                       raster, N, moved, t):
    """Kim 2008 §5.4 of a hybrid body, in the compiled adaptive steps: every body
    placed from the poses ``R_top``, ``p_top`` of the active joints' child bodies
    (:func:`~vdad.hybrid.group_poses` into ``poses``; ``hybrid`` as
    :func:`region_bvh_pass`'s, ``t`` (3, 3) scratch), its visible pixels
    rasterised (:func:`~vdad.raster.raster_pass`; ``raster`` = (geometry,
    buffers, scratch, counts (nb,))) and summed or moved up the tree into ``N``
    (:func:`node_counts`). The evaluation of :class:`RenderedCounts` with
    ``method="raster"`` inside ``vdad.region.region_steps``, once per frame."""
    visit, n_visit, active, grounded, top, rel_R, rel_p = hybrid
    R, p = poses
    group_poses(nb, left, right, forest, visit, n_visit, active, grounded, top, rel_R, rel_p,
                R_top, p_top, R, p, t)
    geometry, buffers, scratch, counts = raster
    raster_pass(view, Rc, pc, R, p, geometry, buffers, scratch, counts)
    node_counts(codes[2], nb, left, right, counts, N, moved)


@inlined
def node_counts(moved_rule, nb, left, right, counts, N, moved):
    """Each node's ``N`` (n_nodes + 1,) from the bodies' pixel ``counts`` (nb,):
    their sum (:func:`sum_up_pass`) or, under the moved-pixels rule, the pixels
    its joints move (:func:`moved_pass`; ``moved`` its arrays)."""
    for b in range(nb):
        N[b] = counts[b]
    if moved_rule:
        parent, root, floating, _, _, joint, sums = moved
        moved_pass(nb, parent, root, floating, left, right, joint, sums, N)
    else:
        sum_up_pass(nb, left, right, N)


@pass_kernel
def region_coverage_pass(kind, view, Rc, pc, nb, left, right, front, act, grounded, top, R, p,
                         local, world, N, scratch):
    """``N_M`` by eq. 5 (the node's own volume) of the adaptive region's nodes
    (``front`` rigid groups and ``act`` active nodes, ascending) into ``N``;
    every other node NaN. Each front node's
    volume kept in its group frame (``local``) is placed at the group's world pose
    (the world for a ``grounded`` group, else the pose ``R``, ``p`` of its ``top``
    body from the active joints' kinematics); each active node's is merged from
    its children's."""
    lc, lR, lh = local
    c, Rv, h = world
    n_nodes = nb + left.shape[0]
    for n in range(n_nodes + 1):
        N[n] = np.nan
    h[n_nodes, 0] = -1.0
    N[n_nodes] = 0.0
    nf = front.shape[0]
    for k in range(nf + act.shape[0]):   # the front, then the active nodes (children first)
        if k < nf:
            n = front[k]
            if grounded[n]:
                copy_volume(kind, lc[n], lR[n], lh[n], c[n], Rv[n], h[n])
            else:
                b = top[n]
                place_volume(kind, lc[n], lR[n], lh[n], R[b], p[b], c[n], Rv[n], h[n])
        else:
            n = act[k - nf]
            A, B = child_slot(left[n - nb], n_nodes), child_slot(right[n - nb], n_nodes)
            merge_volumes(kind, c[A], Rv[A], h[A], c[B], Rv[B], h[B], c[n], Rv[n], h[n])
        N[n] = volume_area(kind, view, Rc, pc, c[n], Rv[n], h[n], scratch)


@inlined
def refresh_group(kind, nb, left, right, first, F, rel_R, rel_p, since, local, stamp, tmp):
    """Kim 2008 §5.3, a rigid node's volume computed once and then only placed
    (``docs/visibility.md``, "Bounding volumes"): volumes in their own frame (that
    of their top body) of the rigid front node ``F`` and of its subtree (internal
    ids ``first[F - nb]`` to ``F``, children first) into ``local``, where they are
    stale: ``F`` internal and its ``stamp`` not its ``since`` (the step it became
    rigid). Each node ``C`` encloses its ``A`` child's volume and its ``B`` child's
    placed at the pose of ``B``'s top body in ``C``'s frame (``rel_R``,
    ``rel_p``); their ``stamp`` becomes their ``since``. ``tmp``: one volume's
    scratch."""
    if F < nb or stamp[F] == since[F]:
        return
    lc, lR, lh = local
    tc, tR, th = tmp
    n_nodes = nb + left.shape[0]
    for m in range(first[F - nb], F - nb + 1):
        C, A, B = nb + m, child_slot(left[m], n_nodes), child_slot(right[m], n_nodes)
        place_volume(kind, lc[B], lR[B], lh[B], rel_R[C], rel_p[C], tc, tR, th)
        merge_volumes(kind, lc[A], lR[A], lh[A], tc, tR, th, lc[C], lR[C], lh[C])
        stamp[C] = since[C]


@pass_kernel
def refresh_local(kind, nb, left, right, first, front, rel_R, rel_p, since, local, stamp, tmp):
    """:func:`refresh_group` of each of the rigid ``front`` nodes."""
    for k in range(front.shape[0]):
        refresh_group(kind, nb, left, right, first, front[k], rel_R, rel_p, since, local, stamp,
                      tmp)


def moved_arrays(tree):
    """The arrays of :func:`moved_pass` for ``tree``: each body's parent and root
    body, whether each root is a floating base, the tree's ``left``, ``right``,
    ``joint``, and scratch sums (nb,)."""
    model = tree.model
    root = plan(model).root_of                           # root body of each body's tree
    return (_ids(model.parent), _ids(root), (model.parent[root] < 0) & (model.nv_joint[root] == 6),
            tree.arrays[0], tree.arrays[1], tree.arrays[2], np.empty(model.nb))


def _empty_like(x):
    return (tuple(_empty_like(a) for a in x) if isinstance(x, tuple)
            else np.zeros((0,) + x.shape[1:], x.dtype))


def idle_loop_coverage(tree):
    """The coverage arguments of the compiled adaptive steps
    (``vdad.region.region_steps``) when nothing is evaluated in the loop:
    ``((constants, None), frames)`` of the types of
    :meth:`BoundingVolumes.loop_coverage`, empty, so that numba compiles the loop
    once for both; :meth:`RenderedCounts.loop_coverage` fills some of them."""
    box = (np.zeros((1, 3)), np.zeros((1, 3, 3)), np.zeros((1, 3)))
    cache = (box, np.zeros(1), tuple(a[0] for a in box))
    constants = (np.zeros(4, np.int64), np.zeros(1, np.int64), box[1:], box, cache, box,
                 np.zeros(1), moved_arrays(tree), (np.empty((3, 3)), box_scratch()))
    return (_empty_like(constants), None), _frames(0)


def _frames(k):
    """Room for ``k`` frames as the compiled adaptive steps take them: their
    steps (k,), and the intrinsics (k, 4) and world poses (k, 3, 3), (k, 3) of
    their cameras (:func:`camera_arrays`)."""
    return np.zeros(k, np.int64), np.zeros((k, 4)), np.zeros((k, 3, 3)), np.zeros((k, 3))


def camera_arrays(camera):
    """A camera's intrinsics (:func:`~vdad.projection.view_of`) and world pose
    (:func:`~vdad.bounding.camera_pose`)."""
    return (view_of(camera), *camera_pose(camera))


class _Coverage:
    """A camera path, the counting resolution (default: the camera's own) and the
    rule ``pixels`` that turns the bodies' pixels into the nodes' (:data:`PIXELS`)."""

    def __init__(self, tree, camera, resolution=None, pixels="own"):
        self.tree, self.model = tree, tree.model
        if not any(body.geoms for body in self.model.bodies):
            raise InputError(f"view-dependent coverage needs geometry, but no body of model "
                             f"{self.model.name!r} has any (Body(..., geoms=(Geom(...),))): "
                             f"every joint would be frozen; use method='adaptive' instead")
        if pixels not in PIXELS:
            raise InputError(f"unknown pixels rule {pixels!r}; choose one of {PIXELS}")
        self.path = check_path(camera)
        self.resolution = check_resolution(resolution)
        self.pixels = pixels
        self._last = (None, None)                        # a path's camera, at resolution
        self._last_arrays = (None, None)                 # ... and its camera_arrays
        self._kin = Kinematics.empty(plan(self.model))
        self._moved = moved_arrays(tree)
        self._no_frames = self._frame_rows = _frames(0)
        self._held = []                  # the camera arrays each frame row holds

    def node_pixels(self, N):
        """Each node's ``N`` (n_nodes + 1,) from its bodies' pixels in ``N[:nb]``,
        in place, by the rule :attr:`pixels`: the sum over its bodies
        (:func:`sum_up_pass`) or the pixels its joints move (:func:`moved_pass`)."""
        nb, left, right = self.model.nb, self._moved[3], self._moved[4]
        node_counts(self.pixels == "moved", nb, left, right, N[:nb], N, self._moved)
        return N

    def camera(self, t):
        """The camera at time ``t`` at the counting resolution (the last one again
        while the path returns the same camera)."""
        cam = camera_at(self.path, t)
        if self.resolution is None:
            return cam
        if cam is not self._last[0]:
            self._last = (cam, cam.with_resolution(*self.resolution))
        return self._last[1]

    def poses(self, q, adaptive):
        """World poses of all bodies at ``q`` (from the adaptive region if given)."""
        if adaptive is not None:
            return adaptive.body_poses(q)
        return world_poses(self.model, q, self._kin)

    def _loop_frames(self, steps, times):
        """The frames of the compiled adaptive steps' coverage: its ``steps`` (k,)
        (counted from a call's first) and the camera arrays at ``times`` (k,)
        (:func:`_frames`, rows kept from call to call)."""
        k = len(times)
        if not k:
            return self._no_frames
        if k > len(self._frame_rows[0]):
            self._frame_rows, self._held = _frames(2 * k), [None] * (2 * k)
        due, views, Rc, pc = self._frame_rows
        for i in range(k):
            due[i] = steps[i]
            camera = self._camera_arrays(times[i])
            if camera is not self._held[i]:
                views[i], Rc[i], pc[i] = self._held[i] = camera
        return due[:k], views[:k], Rc[:k], pc[:k]

    def _camera_arrays(self, t):
        """:func:`camera_arrays` of the camera at ``t`` (the last ones again while
        the path returns the same camera)."""
        cam = self.camera(t)
        if cam is not self._last_arrays[0]:
            self._last_arrays = (cam, camera_arrays(cam))
        return self._last_arrays[1]


class BoundingVolumes(_Coverage):
    """``N_M`` from bounding volumes (Kim 2008 §5.3, eqs. 5-7): ``volume`` one of
    ``"sphere"``, ``"obb"``, ``"aabb"``; ``estimate`` ``"min"`` (eq. 7),
    ``"node"`` (eq. 5, the node's own volume) or ``"bodies"`` (eq. 6, the sum
    over its bodies). Compiled per node (:func:`coverage_pass`,
    :func:`region_coverage_pass`). With ``pixels="moved"`` a body's pixels are
    the area of its own volume (where eqs. 5-7 agree), moved up the tree by
    :func:`moved_pass`; ``estimate="node"`` has no per-body meaning then."""

    def __init__(self, tree, camera, volume="sphere", estimate="min", resolution=None,
                 pixels="own"):
        super().__init__(tree, camera, resolution, pixels)
        if estimate not in ESTIMATES:
            raise InputError(f"unknown coverage estimate {estimate!r}; choose one of {ESTIMATES}")
        if pixels == "moved" and estimate == "node":
            raise InputError("estimate='node' (the node's own volume, eq. 5) does not apply to "
                             "pixels='moved', which sums the bodies' own volumes (eq. 6): give "
                             "estimate='min' or 'bodies', or pixels='own'")
        self.kind, self.estimate = check_volume(volume), estimate
        self._kind, self._estimate = KIND_CODE[volume], ESTIMATES.index(estimate)
        nb, n = self.model.nb, tree.n_nodes
        self.body = pack(body_volumes(self.model, volume))                # body frames
        self._left, self._right = tree.arrays[0], tree.arrays[1]
        self._forest = tree.arrays[13], tree.arrays[14]                  # post, segments
        # node volumes in world coordinates, and in their rigid group's frame (valid
        # while stamp == adaptive.since, for the adaptive region whose since array
        # is _bound); the last slot is the ground, empty
        self.world = tuple(np.zeros((n + 1,) + a.shape[1:]) for a in self.body)
        self.local = tuple(np.zeros((n + 1,) + a.shape[1:]) for a in self.body)
        for a, b in zip(self.local, self.body, strict=True):
            a[:nb] = b
        self.local[2][nb:] = -1.0
        self.stamp = np.full(n + 1, np.nan)
        self._bound = None
        self._ungrouped = (np.zeros(0, bool), self.local, np.zeros((0, 3, 3)),   # bvh_pass:
                           np.zeros((0, 3)))                    # every node merged
        self._cache = (self.local, self.stamp, tuple(np.zeros(a.shape[1:]) for a in self.local))
        self._N1 = np.zeros(n + 1)
        self._poses = (np.zeros((n + 1, 3, 3)), np.zeros((n + 1, 3)))   # the groups' poses
        self._scratch = (np.empty((3, 3)), box_scratch())
        self._codes = np.array([self._kind, BODIES if pixels == "moved" else self._estimate,
                                pixels == "moved", 1], np.int64)   # [3]: set at each call
        self._threaded = bool(in_parallel(self.model.nb, self._forest[1]))

    @property
    def covers_every_node(self):
        """Whether a call gives every node its value (False: only the adaptive
        region's nodes, the others NaN; then a region change needs a new call)."""
        return self.pixels == "moved" or self.kind == "aabb" or self.estimate != "node"

    def __call__(self, t, q, adaptive=None):
        cam = self.camera(t)
        view, (Rc, pc) = view_of(cam), camera_pose(cam)
        nb, N = self.model.nb, np.empty(self.tree.n_nodes + 1)
        self._runs()
        if adaptive is None:             # every body placed at q (rigid joints keep their q)
            with compiling(bvh_pass):
                bvh_pass(self._codes, view, Rc, pc, nb, plan(self.model).arrays, as_input(q),
                         self._kin.arrays, self._left, self._right, self._forest, self.body,
                         self.world, self._N1, N, self._moved, self._ungrouped, self._scratch)
            return N
        self._bind(adaptive)
        if self.covers_every_node:       # eqs. 6-7 and world boxes place every body
            kin = adaptive.front_kinematics(q)
            with compiling(region_bvh_pass):
                region_bvh_pass(self._codes, view, Rc, pc, nb, self._left, self._right,
                                self._forest, self.tree.first, adaptive.group_frames,
                                adaptive.since, kin.R, kin.p, self._poses, self.body, self._cache,
                                self.world, self._N1, N, self._moved, self._scratch)
            return N
        front, act = adaptive.front, adaptive.act
        self._refresh(front, adaptive)
        kin = adaptive.front_kinematics(q)
        region_coverage_pass(self._kind, view, Rc, pc, nb, self._left, self._right,
                             _ids(front), _ids(act), adaptive.groups.grounded, adaptive.top,
                             kin.R, kin.p, self.local, self.world, N, self._scratch[1])
        return N

    def loop_coverage(self, steps, times, adaptive):
        """The coverage arguments of the compiled adaptive steps
        (``vdad.region.region_steps``) of ``adaptive``, which evaluate
        :func:`region_bvh_pass` before each of the ``steps`` (k,) of a call
        (ascending, counted from its first) with the camera at the given ``times``
        (k,): ``(constants, frames)``, or None where this estimator does not cover
        every node (its region evaluation needs Python)."""
        if not self.covers_every_node:
            return None
        self._bind(adaptive)
        self._runs()
        # the tree's own array: a deep copy's would be writable, and numba would
        # compile the steps again for it
        constants = (self._codes, self.tree.first, self._poses, self.body, self._cache,
                     self.world, self._N1, self._moved, self._scratch)
        return (constants, None), self._loop_frames(steps, times)

    def _runs(self):
        """The runs of a large forest's subtrees on threads (``codes[3]``,
        :func:`forest_coverage`): numba's thread count, asked only of a forest
        that runs on threads (a few µs a call)."""
        if self._threaded:
            self._codes[3] = numba.get_num_threads()

    def _bind(self, adaptive):
        """The volumes kept in group frames hold for one adaptive region (its
        ``since`` counts its own steps): another region's clears them."""
        if adaptive.since is not self._bound:
            self._bound = adaptive.since
            self.stamp[:] = np.nan

    def _refresh(self, front, adaptive):
        """Volumes in the group frame of the rigid ``front`` nodes whose cache is
        stale, and of their subtrees, bottom-up from the bodies'
        (:func:`refresh_local`)."""
        g = adaptive.groups
        refresh_local(self._kind, self.model.nb, self._left, self._right, self.tree.first,
                      _ids(front), g.rel_R, g.rel_p, adaptive.since, *self._cache)


class RenderedCounts(_Coverage):
    """``N_M`` from rendered visible-pixel counts (Kim 2008 §5.4): every body's
    pixels after occlusion by the ``environment`` and the other bodies and
    clipping by the viewport, summed up the tree. ``method``: ``"queries"``
    (the paper's occlusion queries after a depth pass) or ``"merged"`` (one
    draw of a merged buffer into an id image; the same counts, faster for many
    bodies), both on OpenGL (:class:`~vdad.render.counting.PixelCounter`; fail
    at once with :class:`~vdad.errors.RenderError` without EGL), or
    ``"raster"``: the merged id buffer's counts rasterised in compiled code on
    the CPU, no OpenGL (:class:`~vdad.raster.RasterCounter`)."""

    def __init__(self, tree, camera, environment=None, method="queries", resolution=None,
                 pixels="own"):
        super().__init__(tree, camera, resolution, pixels)
        if method not in COUNTING:
            raise InputError(f"the counting method (counting= of view-oq) must be one of "
                             f"{COUNTING}, got {method!r}")
        start = camera_at(camera, 0.0)
        w, h = self.resolution or (start.width, start.height)
        self.method = method
        if method == "raster":
            from .raster import RasterCounter

            self.counter = RasterCounter(self.model, environment, w, h)
            # the idle coverage arguments of the compiled steps (writable arrays of
            # one type), with what the rasteriser's evaluation needs, and its arrays
            ((_, first, _, volumes, cache, world, N1, _, scratch), _), _ = \
                idle_loop_coverage(tree)
            n = tree.n_nodes
            self._constants = ((np.array([0, 0, pixels == "moved", 1], np.int64), first,
                                (np.zeros((n + 1, 3, 3)), np.zeros((n + 1, 3))), volumes,
                                cache, world, N1, tuple(np.array(a) for a in self._moved),
                                (np.zeros((3, 3)), scratch[1])), self.counter.arrays)
        else:
            from .render.counting import PixelCounter

            self.counter = PixelCounter(self.model, environment, w, h, method)
        self.resolution = (w, h)

    covers_every_node = True           # every body counted, summed or moved up the tree

    def __call__(self, t, q, adaptive=None):
        N = np.zeros(self.tree.n_nodes + 1)
        N[:self.model.nb] = self.counter.counts(self.camera(t), *self.poses(q, adaptive))
        return self.node_pixels(N)

    def loop_coverage(self, steps, times, adaptive):
        """The coverage arguments of the compiled adaptive steps
        (``vdad.region.region_steps``), which evaluate :func:`region_raster_pass`
        before each of the ``steps`` (k,) of a call with the camera at the given
        ``times`` (k,) (as :meth:`BoundingVolumes.loop_coverage`); None for the
        counts on OpenGL, which Python draws."""
        if self.method != "raster":
            return None
        return self._constants, self._loop_frames(steps, times)
