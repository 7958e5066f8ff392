"""Visible pixels counted by a compiled z-buffer on the CPU (Kim 2008 §5.4).

The paper's occlusion queries count, per body, the pixels that survive the
depth test. :class:`RasterCounter` counts the same pixels without OpenGL: the
bodies' triangles (the merged triangle soup of :mod:`vdad.render.counting`, the
same tessellation) are placed at their bodies' world poses, projected by the
camera and rasterised into a depth buffer with an id per pixel, in compiled
code, one triangle per kernel (:func:`draw_triangle`), and the ids left in the
buffer are counted (``docs/visibility.md``, "Counts rasterised on the CPU").

The rules are OpenGL's: samples at pixel centres, a sample on an edge shared by
two triangles belongs to exactly one of them (the top-left rule), no back-face
culling, the near plane clips, a nearer fragment replaces a farther one and the
first drawn wins a tie (``GL_LESS``; bodies in order, then the environment,
which hides but is not counted). Depth is ``1 / d`` (``d`` the distance along
the viewing axis), interpolated linearly in the image as a rasteriser does, in
double precision (OpenGL's depth buffer holds 24 bits). The far plane is not
applied, as in :mod:`vdad.projection`. Pixels are not cleared between frames:
each holds the frame that wrote it last beside its id (``tag``), and the
pixels a frame wrote are listed (``touched``), so that a frame costs per
triangle and per
covered pixel, not per pixel of the image.
"""

from __future__ import annotations

import math

import numpy as np

from ._linalg import inlined, pass_kernel
from .bounding import camera_pose
from .environment import check_environment
from .errors import InputError
from .model import check_model
from .projection import clip_polygon, view_of


def merged_geometry(model, environment, sections):
    """Merged triangle soup of the bodies (body frames) then the environment (world).

    Returns positions (nv, 3) float32, ids (nv,) uint32 (0: the environment,
    ``i + 1``: body ``i``), indices (ni,) uint32, each body's index range:
    first (nb,), count (nb,) int64, and whether each id's meshes are all closed
    with outward faces (nb + 1,) bool (seen from outside, their back faces are
    hidden by their front faces).
    """
    positions, ids, indices = [], [], []
    first, count = np.zeros(model.nb, np.int64), np.zeros(model.nb, np.int64)
    closed = np.ones(model.nb + 1, bool)
    meshes = {}                     # id(geom) -> trimesh, for geoms shared by bodies
    nv = ni = 0

    def add(mesh, label):
        nonlocal nv, ni
        closed[label] &= bool(mesh.is_watertight and mesh.is_winding_consistent
                              and mesh.volume > 0)
        positions.append(np.asarray(mesh.vertices, np.float32))
        ids.append(np.full(len(mesh.vertices), label, np.uint32))
        indices.append(np.asarray(mesh.faces, np.uint32).ravel() + np.uint32(nv))
        nv += len(mesh.vertices)
        ni += indices[-1].size

    for i, body in enumerate(model.bodies):
        first[i] = ni
        for geom in body.geoms:
            if id(geom) not in meshes:
                meshes[id(geom)] = geom.to_trimesh(sections)
            add(meshes[id(geom)], i + 1)
        count[i] = ni - first[i]
    for geom in environment.geoms:
        add(geom.to_trimesh(sections), 0)
    if not positions:
        return (np.zeros((0, 3), np.float32), np.zeros(0, np.uint32), np.zeros(0, np.uint32),
                first, count, closed)
    return (np.concatenate(positions), np.concatenate(ids), np.concatenate(indices), first,
            count, closed)


#: a pixel's ``tag``: the frame that last wrote it above ``TAG_BITS`` bits, its id
#: below (``& LABEL``): one array read per covered sample instead of two
TAG_BITS = 32
LABEL = (1 << TAG_BITS) - 1


@inlined
def inside(e, du, dv):
    """The top-left rule: whether a sample at edge function ``e`` of an edge
    (``du``, ``dv``) of a counter-clockwise triangle (image y up) is covered: ``e > 0``,
    or ``e == 0`` on a left edge (going down) or a top edge (flat, going left)."""
    return e > 0.0 or (e == 0.0 and (dv < 0.0 or (dv == 0.0 and du < 0.0)))


@inlined
def span(lo, hi, u, v, slope, dv, y):
    """The range ``lo <= x <= hi`` of row ``y`` narrowed to the side of the edge
    through ``(u, v)`` with ``du / dv = slope`` where the triangle lies (up to
    rounding: the samples are tested by :func:`inside` after)."""
    if dv < 0.0:
        lo = max(lo, u + slope * (y - v))
    elif dv > 0.0:
        hi = min(hi, u + slope * (y - v))
    return lo, hi


@inlined
def slope(du, dv):
    """``du / dv`` of an edge (0 for a flat one, which :func:`span` ignores)."""
    return du / dv if dv != 0.0 else 0.0


@inlined
def draw_triangle(T, label, cull, occluder, box, W, H, frame, tag, depth, touched, n):
    """Rasterise one triangle ``T`` (3, 3) of image points ``(u, v, 1 / d)`` with
    id ``label`` into the buffers (per pixel ``j * W + i``: its ``tag``, the
    frame that wrote it last and its id, and its depth ``1 / d``; ``touched[:n]``:
    the pixels this frame wrote) at the samples ``(i + 0.5, j + 0.5)`` it covers
    (:func:`inside`), keeping the nearer fragment (a tie keeps the first); a
    clockwise (back-facing) triangle is skipped if ``cull``. Only the samples
    in ``box`` = (first column, last column, first row, last row) are drawn,
    and with ``occluder`` only those this frame wrote already (an occluder
    changes no count elsewhere). Each row's samples are those between its edges
    (:func:`span`), widened by one, then tested. Returns the new ``n``."""
    for r in range(3):
        if not (math.isfinite(T[r, 0]) and math.isfinite(T[r, 1])):
            return n
    # the bounding box, held within a pixel of the image (whole numbers stay small)
    lo_u = max(min(T[0, 0], T[1, 0], T[2, 0]), -1.0)
    hi_u = min(max(T[0, 0], T[1, 0], T[2, 0]), W + 1.0)
    lo_v = max(min(T[0, 1], T[1, 1], T[2, 1]), -1.0)
    hi_v = min(max(T[0, 1], T[1, 1], T[2, 1]), H + 1.0)
    i0, i1 = max(box[0], int(math.ceil(lo_u - 0.5))), min(box[1], int(math.floor(hi_u - 0.5)))
    j0, j1 = max(box[2], int(math.ceil(lo_v - 0.5))), min(box[3], int(math.floor(hi_v - 0.5)))
    if i0 > i1 or j0 > j1:                      # no sample inside its bounding box
        return n
    a, b, c = 0, 1, 2
    area = ((T[1, 0] - T[0, 0]) * (T[2, 1] - T[0, 1])
            - (T[1, 1] - T[0, 1]) * (T[2, 0] - T[0, 0]))
    if area == 0.0:
        return n
    if area < 0.0:                              # counter-clockwise from here on
        if cull:
            return n
        b, c, area = 2, 1, -area
    u0, v0, z0 = T[a, 0], T[a, 1], T[a, 2]
    u1, v1, z1 = T[b, 0], T[b, 1], T[b, 2]
    u2, v2, z2 = T[c, 0], T[c, 1], T[c, 2]
    s0, s1, s2 = slope(u2 - u1, v2 - v1), slope(u0 - u2, v0 - v2), slope(u1 - u0, v1 - v0)
    for j in range(j0, j1 + 1):
        y = j + 0.5
        lo, hi = span(lo_u, hi_u, u1, v1, s0, v2 - v1, y)
        lo, hi = span(lo, hi, u2, v2, s1, v0 - v2, y)
        lo, hi = span(lo, hi, u0, v0, s2, v1 - v0, y)
        for i in range(max(i0, int(math.ceil(lo - 0.5)) - 1),
                       min(i1, int(math.floor(hi - 0.5)) + 1) + 1):
            k = j * W + i
            if occluder and tag[k] >> TAG_BITS != frame:
                continue
            x = i + 0.5
            e0 = (u2 - u1) * (y - v1) - (v2 - v1) * (x - u1)     # opposite vertex a
            e1 = (u0 - u2) * (y - v2) - (v0 - v2) * (x - u2)     # ... b
            e2 = (u1 - u0) * (y - v0) - (v1 - v0) * (x - u0)     # ... c
            if not (inside(e0, u2 - u1, v2 - v1) and inside(e1, u0 - u2, v0 - v2)
                    and inside(e2, u1 - u0, v1 - v0)):
                continue
            z = (e0 * z0 + e1 * z1 + e2 * z2) / area
            if tag[k] >> TAG_BITS != frame:
                tag[k], depth[k] = (frame << TAG_BITS) | label, z
                touched[n] = k
                n += 1
            elif z > depth[k]:
                tag[k], depth[k] = (frame << TAG_BITS) | label, z
    return n


@inlined
def written_box(touched, n, W, H):
    """The smallest box (first column, last column, first row, last row) of
    the pixels ``touched[:n]`` in an image ``W`` pixels wide; an empty one
    (first after last) if there are none."""
    i0, i1, j0, j1 = W, -1, H, -1
    for k in range(n):
        j, i = divmod(touched[k], W)
        i0, i1, j0, j1 = min(i0, i), max(i1, i), min(j0, j), max(j1, j)
    return i0, i1, j0, j1


@inlined
def project(P, k, view, T, r):
    """Row ``r`` of ``T``: the image point ``(u, v, 1 / d)`` of the camera-frame
    point ``P[k]`` (``d = -z > 0``)."""
    d = -P[k, 2]
    T[r, 0] = 0.5 * view[1] + view[0] * P[k, 0] / d
    T[r, 1] = 0.5 * view[2] + view[0] * P[k, 1] / d
    T[r, 2] = 1.0 / d


@pass_kernel
def raster_pass(view, Rc, pc, R, p, geometry, buffers, scratch, counts):
    """Kim 2008 §5.4 on the CPU: the visible pixels of every body into ``counts``
    (nb,), the bodies posed at ``R`` (nb, 3, 3), ``p`` (nb, 3) (world), seen by
    the camera at ``Rc``, ``pc`` with intrinsics ``view`` (:func:`view_of`).
    ``geometry`` = (vertices (nv, 3) in their body's frame or the world's, their
    ids (nv,): 0 the environment, ``i + 1`` body ``i``; triangles (nt, 3);
    whether each id's meshes are closed (nb + 1,), and a sphere around them in
    its frame (nb + 1, 4): centre, radius). ``buffers`` = (frame (1,), tag,
    depth, touched (W H,)): the z-buffer (:func:`draw_triangle`), kept from
    frame to frame; ``scratch`` = (camera coordinates (nv, 3) and image points
    (nv, 3) of the vertices, two polygons (8, 3), a triangle (3, 3), each id's
    culling (nb + 1,) bool). The back faces of closed meshes are culled where
    the camera is outside their sphere: its front faces hide them there, so the
    counts do not change. A triangle cut by the near plane is clipped
    (:func:`~vdad.projection.clip_polygon`) and drawn as a fan. The
    environment, drawn after the bodies, is drawn only where they are
    (:func:`written_box`, ``occluder``): it hides, it is not counted, so its
    other pixels would change nothing. Returns the number of pixels written."""
    vertices, labels, triangles, closed, spheres = geometry
    frame, tag, depth, touched = buffers
    C, U, P, Q, T, cull = scratch
    W, H, znear = int(view[1]), int(view[2]), view[3]
    frame[0] += 1
    now = frame[0]
    for label in range(cull.shape[0]):          # back faces hidden: the camera outside
        x, y, z = pc[0], pc[1], pc[2]
        b = label - 1
        if b >= 0:                              # the camera in the body's frame
            x, y, z = x - p[b, 0], y - p[b, 1], z - p[b, 2]
            x, y, z = (R[b, 0, 0] * x + R[b, 1, 0] * y + R[b, 2, 0] * z,
                       R[b, 0, 1] * x + R[b, 1, 1] * y + R[b, 2, 1] * z,
                       R[b, 0, 2] * x + R[b, 1, 2] * y + R[b, 2, 2] * z)
        x, y, z = x - spheres[label, 0], y - spheres[label, 1], z - spheres[label, 2]
        cull[label] = closed[label] and x * x + y * y + z * z > spheres[label, 3] ** 2
    for v in range(vertices.shape[0]):          # body frame -> world -> camera -> image
        x, y, z = vertices[v, 0], vertices[v, 1], vertices[v, 2]
        b = labels[v] - 1
        if b >= 0:
            x, y, z = (R[b, 0, 0] * x + R[b, 0, 1] * y + R[b, 0, 2] * z + p[b, 0],
                       R[b, 1, 0] * x + R[b, 1, 1] * y + R[b, 1, 2] * z + p[b, 1],
                       R[b, 2, 0] * x + R[b, 2, 1] * y + R[b, 2, 2] * z + p[b, 2])
        x, y, z = x - pc[0], y - pc[1], z - pc[2]
        for r in range(3):
            C[v, r] = Rc[0, r] * x + Rc[1, r] * y + Rc[2, r] * z
        if -C[v, 2] >= znear:
            project(C, v, view, U, v)
    n = 0
    box, boxed = (0, W - 1, 0, H - 1), False
    for t in range(triangles.shape[0]):
        label = labels[triangles[t, 0]]
        if label == 0 and not boxed:            # the environment, after the bodies
            box, boxed = written_box(touched, n, W, H), True
        behind = 0
        for r in range(3):
            if -C[triangles[t, r], 2] < znear:
                behind += 1
        if behind == 0:
            for r in range(3):
                for c in range(3):
                    T[r, c] = U[triangles[t, r], c]
            n = draw_triangle(T, label, cull[label], label == 0, box, W, H, now, tag, depth,
                              touched, n)
        elif behind < 3:
            for r in range(3):
                for c in range(3):
                    P[r, c] = C[triangles[t, r], c]
            m = clip_polygon(P, 3, 0.0, 0.0, -1.0, znear, Q)
            for f in range(1, m - 1):               # a fan
                project(Q, 0, view, T, 0)
                project(Q, f, view, T, 1)
                project(Q, f + 1, view, T, 2)
                n = draw_triangle(T, label, cull[label], label == 0, box, W, H, now, tag,
                                  depth, touched, n)
    for b in range(counts.shape[0]):
        counts[b] = 0
    for k in range(n):
        label = tag[touched[k]] & LABEL
        if label > 0:
            counts[label - 1] += 1
    return n


def _buffers(pixels, nv, nb):
    """The z-buffer of ``pixels`` pixels and the scratch of :func:`raster_pass`
    for ``nv`` vertices and ``nb`` bodies."""
    buffers = (np.zeros(1, np.int64), np.zeros(pixels, np.int64), np.zeros(pixels),
               np.zeros(pixels, np.int64))
    scratch = (np.zeros((nv, 3)), np.zeros((nv, 3)), np.zeros((8, 3)), np.zeros((8, 3)),
               np.zeros((3, 3)), np.zeros(nb + 1, bool))
    return buffers, scratch


class RasterCounter:
    """Kim 2008 §5.4: the visible pixels of every body of ``model``, occluded by the
    other bodies and by ``environment`` (drawn, not counted), at ``width`` x
    ``height`` pixels, rasterised in compiled code on the CPU
    (:func:`raster_pass`): the counts of :class:`vdad.render.counting.PixelCounter`'s
    merged id buffer without OpenGL, from the same tessellation (``sections``).
    Its buffers are its own: one counter per thread."""

    def __init__(self, model, environment=None, width=320, height=240, sections=8):
        check_model(model)
        for name, value in (("width", width), ("height", height)):
            if isinstance(value, bool) or int(value) != value or value < 1:
                raise InputError(f"{name} must be a positive whole number of pixels, "
                                 f"got {value!r}")
        if not (isinstance(sections, (int, np.integer)) and sections >= 3):
            raise InputError(f"sections must be a whole number >= 3, got {sections!r}")
        self.model, self.nb = model, model.nb
        self.width, self.height = int(width), int(height)
        positions, labels, indices, _, _, closed = merged_geometry(
            model, check_environment(environment), int(sections))
        positions, labels = positions.astype(float), labels.astype(np.int64)
        spheres = np.zeros((self.nb + 1, 4))
        for label in np.unique(labels):         # around each id's vertices
            x = positions[labels == label]
            centre = 0.5 * (x.min(axis=0) + x.max(axis=0))
            spheres[label] = *centre, np.linalg.norm(x - centre, axis=1).max() * (1 + 1e-9)
        self.geometry = (positions, labels, indices.astype(np.int64).reshape(-1, 3), closed,
                         spheres)
        self.buffers, self.scratch = _buffers(self.width * self.height, len(positions), self.nb)
        self._camera = self._view = None

    @property
    def arrays(self):
        """What :func:`raster_pass` takes beside the camera and the poses, and a
        counts array (nb,): (geometry, buffers, scratch, counts)."""
        return self.geometry, self.buffers, self.scratch, np.zeros(self.nb, np.int64)

    def _draw(self, camera, R, p, counts):
        from .render.context import check_view

        R, p = check_view(camera, R, p, self.nb)
        if camera is not self._camera:
            at = camera.with_resolution(self.width, self.height)
            self._view = (view_of(at), *camera_pose(at))
            self._camera = camera
        view, Rc, pc = self._view
        return raster_pass(view, Rc, pc, R, p, self.geometry, self.buffers, self.scratch,
                           counts)

    def counts(self, camera, R, p) -> np.ndarray:
        """Visible pixels (nb,) int64 of each body posed at ``R`` (nb, 3, 3), ``p``
        (nb, 3) (world frame) seen by ``camera`` at the counter's resolution."""
        counts = np.zeros(self.nb, np.int64)
        self._draw(camera, R, p, counts)
        return counts

    def id_image(self, camera, R, p) -> np.ndarray:
        """The id image (height, width) uint32, rows from the bottom: 0 where
        nothing or the environment is seen, ``i + 1`` where body ``i`` is (as
        :meth:`vdad.render.counting.PixelCounter.id_image`)."""
        n = self._draw(camera, R, p, np.zeros(self.nb, np.int64))
        _, tag, _, touched = self.buffers
        image = np.zeros(self.width * self.height, np.uint32)
        written = touched[:n]
        image[written] = tag[written] & LABEL
        return image.reshape(self.height, self.width)
