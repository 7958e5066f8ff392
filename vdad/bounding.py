"""Bounding volumes of bodies and assembly-tree nodes (Kim 2008 §5.3).

Three types, chosen by name (:data:`VOLUMES`):

* ``"sphere"``: centre ``c`` (3,) and radius ``r``;
* ``"obb"``: an oriented box, axes ``R`` (3, 3), centre ``c``, half-extents ``h``;
* ``"aabb"``: a box whose axes are the *world* axes, updated from the bodies'
  placed boxes at every step (paper: "axis-aligned bounding volumes ... need to
  update all of them").

Each body's volume is computed once from its geometry (exactly for one sphere,
capsule, cylinder or box; with trimesh otherwise) and stored in the body frame
(:func:`body_volumes`; for ``"aabb"`` the body-frame bounds, placed in the world
as the world-axis box that encloses them). A node's volume encloses its
children's (:func:`merge`): the enclosing sphere of two spheres, the box with
``A``'s axes that holds both boxes' corners, the union of two world boxes. The
merges commute with rigid motions for spheres and oriented boxes, so a rigid
node's volume can be kept in its group frame and only placed at run time
(:class:`vdad.visibility.BoundingVolumes`).

A volume set is a :class:`Volumes` of stacked arrays; an empty volume (a body
without geometry, the ground) has ``r < 0`` or ``h < 0``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ._linalg import as_input, inlined, pass_kernel
from .errors import InputError, VdadError
from .projection import box_area, box_scratch, camera_vector, sphere_area, view_of

VOLUMES = ("sphere", "obb", "aabb")


@dataclass
class Volumes:
    """k bounding volumes of one type: ``c`` (k, 3) centres; spheres: ``r`` (k,);
    boxes: ``R`` (k, 3, 3) axes (columns) and ``h`` (k, 3) half-extents."""

    kind: str
    c: np.ndarray
    r: np.ndarray | None = None
    R: np.ndarray | None = None
    h: np.ndarray | None = None

    def __len__(self):
        return len(self.c)

    def __getitem__(self, idx):
        return Volumes(self.kind, self.c[idx], *(None if a is None else a[idx]
                                                  for a in (self.r, self.R, self.h)))

    def __setitem__(self, idx, other):
        self.c[idx] = other.c
        for name in ("r", "R", "h"):
            a = getattr(self, name)
            if a is not None:
                a[idx] = getattr(other, name)

    @classmethod
    def empty(cls, kind, k):
        if kind == "sphere":
            return cls(kind, np.zeros((k, 3)), r=np.full(k, -1.0))
        return cls(kind, np.zeros((k, 3)), R=np.broadcast_to(np.eye(3), (k, 3, 3)).copy(),
                   h=np.full((k, 3), -1.0))

    @property
    def is_empty(self):
        return self.r < 0 if self.kind == "sphere" else self.h[:, 0] < 0


def check_volume(kind):
    if kind not in VOLUMES:
        raise InputError(f"unknown bounding volume {kind!r}; choose one of {VOLUMES}")
    return kind


_CACHE = {}


def _primitive_volumes(g):
    """The volumes of one sphere, capsule, cylinder or box ``g``, exact for the
    true shape (None for a mesh)."""
    R, p = g.pose.matrix()
    size = np.asarray(g.size, float)
    if g.kind == "sphere":
        r = size[0]
        return p, r, R, p, np.full(3, r), p, np.full(3, r)
    if g.kind in ("capsule", "cylinder"):
        r, hl = size
        axial = np.abs(R[:, 2])
        if g.kind == "capsule":
            return (p, hl + r, R, p, np.array([r, r, hl + r]), p, axial * hl + r)
        across = r * np.sqrt(np.maximum(1 - axial**2, 0.0))
        return (p, float(np.hypot(r, hl)), R, p, np.array([r, r, hl]), p, axial * hl + across)
    if g.kind == "box":
        return p, float(np.linalg.norm(size)), R, p, size, p, np.abs(R) @ size
    return None


def _geometry_volumes(geoms):
    """(sphere centre, radius, OBB axes, OBB centre, OBB half, AABB centre, AABB
    half) of a tuple of geoms in the body frame (None without geometry). One
    primitive is bounded exactly; several, or a mesh, through trimesh (minimum
    bounding sphere, minimum-volume oriented box, bounds)."""
    if not geoms:
        return None
    if len(geoms) == 1 and geoms[0].kind != "mesh":
        return _primitive_volumes(geoms[0])
    try:
        import scipy  # noqa: F401  (trimesh's bounding volumes need it)
        import trimesh
    except ImportError as exc:
        raise VdadError(f"bounding volumes need trimesh and scipy: pip install "
                        f"'vdad[geometry]' ({exc})") from exc

    key = tuple((g.kind, g.size, tuple(np.concatenate([a.ravel() for a in g.pose.matrix()])),
                 id(g.mesh)) for g in geoms)
    if key not in _CACHE:
        mesh = trimesh.util.concatenate([g.to_trimesh() for g in geoms])
        sphere = mesh.bounding_sphere.primitive
        obb = mesh.bounding_box_oriented.primitive
        lo, hi = mesh.bounds
        _CACHE[key] = (np.array(sphere.center, float), float(sphere.radius),
                       np.array(obb.transform[:3, :3], float),
                       np.array(obb.transform[:3, 3], float), 0.5 * np.array(obb.extents, float),
                       (lo + hi) / 2, (hi - lo) / 2)
    return _CACHE[key]


def body_volumes(model, kind):
    """Per-body volumes (nb) of type ``kind`` in each body's frame, from its geoms
    (:func:`_geometry_volumes`)."""
    check_volume(kind)
    v = Volumes.empty(kind, model.nb)
    for i, body in enumerate(model.bodies):
        g = _geometry_volumes(tuple(body.geoms))
        if g is None:
            continue
        if kind == "sphere":
            v.c[i], v.r[i] = g[0], g[1]
        elif kind == "obb":
            v.R[i], v.c[i], v.h[i] = g[2], g[3], g[4]
        else:
            v.c[i], v.h[i] = g[5], g[6]
    return v


#: kind codes of the kernels (their volumes are packed as ``c`` (3,), ``R`` (3, 3),
#: ``h`` (3,); a sphere's radius is ``h[0]``, its ``R`` unused)
KIND_CODE = {"sphere": 0, "obb": 1, "aabb": 2}
SPHERE, OBB, AABB = 0, 1, 2


def pack(v):
    """The arrays ``(c, R, h)`` (k, 3), (k, 3, 3), (k, 3) of :class:`Volumes` ``v``."""
    k = len(v)
    if v.kind == "sphere":
        return (as_input(v.c), np.broadcast_to(np.eye(3), (k, 3, 3)).copy(),
                np.repeat(np.reshape(v.r, (k, 1)), 3, axis=1))
    return as_input(v.c), as_input(v.R), as_input(v.h)


def unpack(kind, c, R, h):
    """:class:`Volumes` of packed arrays (the inverse of :func:`pack`)."""
    if kind == "sphere":
        return Volumes(kind, c, r=h[:, 0].copy())
    return Volumes(kind, c, R=R, h=h)


@inlined
def columns(R):
    """The columns of the 3 x 3 matrix ``R`` as three 3-tuples, in registers: the
    kernels below read every input before their first store, since numba cannot
    tell that their outputs do not alias their inputs (each store would reload)."""
    return ((R[0, 0], R[1, 0], R[2, 0]), (R[0, 1], R[1, 1], R[2, 1]),
            (R[0, 2], R[1, 2], R[2, 2]))


@inlined
def dot3(u, v):
    return u[0] * v[0] + u[1] * v[1] + u[2] * v[2]


@inlined
def rows_dot(R, u):
    """``R u`` for ``R`` given by its ``columns``, a 3-tuple."""
    return (R[0][0] * u[0] + R[1][0] * u[1] + R[2][0] * u[2],
            R[0][1] * u[0] + R[1][1] * u[1] + R[2][1] * u[2],
            R[0][2] * u[0] + R[1][2] * u[1] + R[2][2] * u[2])


@inlined
def place_volume(kind, c, R, h, Rw, pw, oc, oR, oh):
    """A volume ``(c, R, h)`` given in a frame of world pose ``(Rw, pw)``, in world
    coordinates, into ``(oc, oR, oh)`` (an AABB: the world box enclosing the placed
    box; an empty volume stays empty; a sphere's ``R`` is neither read nor written)."""
    W = columns(Rw)
    x = rows_dot(W, (c[0], c[1], c[2]))
    H = (h[0], h[1], h[2])
    if kind == SPHERE:
        oc[0], oc[1], oc[2] = pw[0] + x[0], pw[1] + x[1], pw[2] + x[2]
        oh[0] = H[0]
        return
    P = (pw[0], pw[1], pw[2])
    B = columns(R)
    A = (rows_dot(W, B[0]), rows_dot(W, B[1]), rows_dot(W, B[2]))  # columns of Rw R
    oc[0], oc[1], oc[2] = P[0] + x[0], P[1] + x[1], P[2] + x[2]
    if kind == OBB:
        oh[0], oh[1], oh[2] = H[0], H[1], H[2]
        for b in range(3):
            oR[0, b], oR[1, b], oR[2, b] = A[b][0], A[b][1], A[b][2]
        return
    if H[0] >= 0:                    # AABB: the world box's half-extents
        for a in range(3):
            oh[a] = abs(A[0][a]) * H[0] + abs(A[1][a]) * H[1] + abs(A[2][a]) * H[2]
    else:
        oh[0], oh[1], oh[2] = H[0], H[1], H[2]
    for a in range(3):
        for b in range(3):
            oR[a, b] = 1.0 if a == b else 0.0


@inlined
def copy_volume(kind, c, R, h, oc, oR, oh):
    """``(c, R, h)`` into ``(oc, oR, oh)`` (a sphere: its centre and radius)."""
    for a in range(3):
        oc[a], oh[a] = c[a], h[a]
    if kind != SPHERE:
        for a in range(3):
            for b in range(3):
                oR[a, b] = R[a, b]


@inlined
def merge_volumes(kind, ca, Ra, ha, cb, Rb, hb, oc, oR, oh):
    """The volume enclosing volumes ``a`` and ``b`` (one frame), in ``a``'s axes,
    into ``(oc, oR, oh)`` (not aliasing either): the enclosing sphere of two
    spheres (centre and radius ``h[0]`` only); the box with ``a``'s axes that
    holds both boxes' corners (world axes for AABBs). An empty volume and ``v``
    give ``v``."""
    if hb[0] < 0:
        copy_volume(kind, ca, Ra, ha, oc, oR, oh)
        return
    if ha[0] < 0:
        copy_volume(kind, cb, Rb, hb, oc, oR, oh)
        return
    if kind == SPHERE:
        ra, rb = ha[0], hb[0]
        d = np.sqrt((cb[0] - ca[0]) ** 2 + (cb[1] - ca[1]) ** 2 + (cb[2] - ca[2]) ** 2)
        if ra >= d + rb:                                    # a holds b
            copy_volume(kind, ca, Ra, ha, oc, oR, oh)
            return
        if rb >= d + ra:
            copy_volume(kind, cb, Rb, hb, oc, oR, oh)
            return
        r = max(0.5 * (d + ra + rb), max(ra, rb))
        t = (r - ra) / d if d > 0 else 0.0
        for a in range(3):
            oc[a] = ca[a] + t * (cb[a] - ca[a])
        oh[0] = r
        return
    if kind == AABB:                 # world axes: the interval holding both, per axis
        lo = (min(ca[0] - ha[0], cb[0] - hb[0]), min(ca[1] - ha[1], cb[1] - hb[1]),
              min(ca[2] - ha[2], cb[2] - hb[2]))
        hi = (max(ca[0] + ha[0], cb[0] + hb[0]), max(ca[1] + ha[1], cb[1] + hb[1]),
              max(ca[2] + ha[2], cb[2] + hb[2]))
        for a in range(3):
            oc[a], oh[a] = 0.5 * (lo[a] + hi[a]), 0.5 * (hi[a] - lo[a])
            for e in range(3):
                oR[a, e] = 1.0 if a == e else 0.0
        return
    A, B = columns(Ra), columns(Rb)
    d = (cb[0] - ca[0], cb[1] - ca[1], cb[2] - ca[2])
    hB = (hb[0], hb[1], hb[2])
    m0, e0 = merged_extent(A[0], ha[0], d, B, hB)
    m1, e1 = merged_extent(A[1], ha[1], d, B, hB)
    m2, e2 = merged_extent(A[2], ha[2], d, B, hB)
    C = (ca[0], ca[1], ca[2])
    for a in range(3):
        oc[a] = C[a] + A[0][a] * m0 + A[1][a] * m1 + A[2][a] * m2
    for e in range(3):
        oR[0, e], oR[1, e], oR[2, e] = A[e][0], A[e][1], A[e][2]
    oh[0], oh[1], oh[2] = e0, e1, e2


@inlined
def merged_extent(axis, ha, d, B, hb):
    """Along box ``a``'s unit ``axis`` (half-length ``ha``): the middle (from
    ``a``'s centre) and the half-length of the interval that holds both boxes'
    extents (``b``'s centre at ``d`` from ``a``'s, its axes ``B`` (columns) and
    half-extents ``hb``: its reach along the axis)."""
    cba = dot3(d, axis)
    reach = (abs(dot3(axis, B[0])) * hb[0] + abs(dot3(axis, B[1])) * hb[1]
             + abs(dot3(axis, B[2])) * hb[2])
    lo, hi = min(-ha, cba - reach), max(ha, cba + reach)
    return 0.5 * (lo + hi), 0.5 * (hi - lo)


@inlined
def volume_area(kind, view, Rc, pc, c, R, h, scratch):
    """Projected area in pixels of the world volume ``(c, R, h)`` under the camera
    of world pose ``(Rc, pc)`` and intrinsics ``view`` (:mod:`vdad.projection`);
    ``scratch``: :func:`projection.box_scratch`."""
    if kind == SPHERE:
        x, y, z = camera_vector(Rc, c[0] - pc[0], c[1] - pc[1], c[2] - pc[2])
        return sphere_area(view, x, y, z, h[0])
    return box_area(view, Rc, pc, c, R, h, scratch[0], scratch[1], scratch[2], scratch[3])


@pass_kernel
def place_pass(kind, c, R, h, Rw, pw, oc, oR, oh):
    for i in range(c.shape[0]):
        place_volume(kind, c[i], R[i], h[i], Rw[i], pw[i], oc[i], oR[i], oh[i])


@pass_kernel
def merge_pass(kind, ca, Ra, ha, cb, Rb, hb, oc, oR, oh):
    for i in range(ca.shape[0]):
        merge_volumes(kind, ca[i], Ra[i], ha[i], cb[i], Rb[i], hb[i], oc[i], oR[i], oh[i])


@pass_kernel
def areas_pass(kind, view, Rc, pc, c, R, h, out, scratch):
    for i in range(c.shape[0]):
        out[i] = volume_area(kind, view, Rc, pc, c[i], R[i], h[i], scratch)


def _empty_like_packed(k):
    return np.zeros((k, 3)), np.zeros((k, 3, 3)), np.zeros((k, 3))


def place(v, R, p):
    """Volumes ``v`` (k) given in frames with world poses ``R`` (k, 3, 3), ``p``
    (k, 3), in world coordinates (``"aabb"``: the world box enclosing the placed
    box)."""
    out = _empty_like_packed(len(v))
    place_pass(KIND_CODE[v.kind], *pack(v), as_input(R), as_input(p), *out)
    return unpack(v.kind, *out)


def merge(a, b):
    """Volumes (k) enclosing the pairs ``a`` (k), ``b`` (k), in ``a``'s frame (both
    given in one frame); the result of an empty volume and ``v`` is ``v``."""
    out = _empty_like_packed(len(a))
    merge_pass(KIND_CODE[a.kind], *pack(a), *pack(b), *out)
    return unpack(a.kind, *out)


def camera_pose(camera):
    """The camera's world rotation (3, 3) and position (3,), as the kernels take them."""
    return as_input(camera.rotation), as_input(np.asarray(camera.position, float))


def areas(v, camera, camera_frame=False):
    """Projected areas (k,) in pixels of world volumes ``v`` under ``camera``
    (:mod:`vdad.projection`: exact, with viewport clipping and the near plane);
    with ``camera_frame``, ``v`` is given in the camera's coordinates."""
    out = np.zeros(len(v))
    pose = (np.eye(3), np.zeros(3)) if camera_frame else camera_pose(camera)
    areas_pass(KIND_CODE[v.kind], view_of(camera), *pose, *pack(v), out, box_scratch())
    return out
