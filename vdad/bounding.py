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

from .errors import InputError, VdadError
from .spatial import mv

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


def place(v, R, p):
    """Volumes ``v`` (k) given in frames with world poses ``R`` (k, 3, 3), ``p``
    (k, 3), in world coordinates (``"aabb"``: the world box enclosing the placed
    box)."""
    c = p + mv(R, v.c)
    if v.kind == "sphere":
        return Volumes("sphere", c, r=v.r.copy())
    if v.kind == "obb":
        return Volumes("obb", c, R=R @ v.R, h=v.h.copy())
    h = np.where(v.h[:, :1] < 0, v.h, mv(np.abs(R @ v.R), v.h))
    return Volumes("aabb", c, R=np.broadcast_to(np.eye(3), R.shape).copy(), h=h)


def merge(a, b):
    """Volumes (k) enclosing the pairs ``a`` (k), ``b`` (k), in ``a``'s frame (both
    given in one frame); the result of an empty volume and ``v`` is ``v``."""
    if a.kind == "sphere":
        d = np.linalg.norm(b.c - a.c, axis=1)
        r = np.maximum(0.5 * (d + a.r + b.r), np.maximum(a.r, b.r))
        with np.errstate(divide="ignore", invalid="ignore"):
            t = np.where(d > 0, (r - a.r) / d, 0.0)
        c = a.c + t[:, None] * (b.c - a.c)
        holds_b = a.r >= d + b.r                    # one sphere holds the other
        holds_a = b.r >= d + a.r
        c = np.where(holds_b[:, None], a.c, np.where(holds_a[:, None], b.c, c))
        r = np.where(holds_b, a.r, np.where(holds_a, b.r, r))
        out = Volumes("sphere", c, r=r)
    else:
        # both boxes' corners in a's axes (world axes for "aabb")
        RT = np.swapaxes(a.R, 1, 2)
        rel = RT @ b.R
        cb = mv(RT, b.c - a.c)
        hb = mv(np.abs(rel), b.h)
        lo = np.minimum(-a.h, cb - hb)
        hi = np.maximum(a.h, cb + hb)
        out = Volumes(a.kind, a.c + mv(a.R, (lo + hi) / 2), R=a.R.copy(), h=(hi - lo) / 2)
    a_empty, b_empty = a.is_empty, b.is_empty
    if a_empty.any() or b_empty.any():
        out[a_empty] = b[a_empty]
        out[b_empty & ~a_empty] = a[b_empty & ~a_empty]
    return out


def areas(v, camera):
    """Projected areas (k,) in pixels of world volumes ``v`` under ``camera``
    (:mod:`vdad.projection`: exact, with viewport clipping and the near plane)."""
    from .projection import box_areas, sphere_areas

    Rc = camera.rotation
    c = (v.c - np.asarray(camera.position, float)) @ Rc
    if v.kind == "sphere":
        return sphere_areas(camera, c, v.r)
    return box_areas(camera, c, Rc.T @ v.R, v.h)
