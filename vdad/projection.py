"""Exact projected areas of spheres and boxes in pixels (Kim 2008 eqs. 5-6; theory §7).

The area of a volume ``K`` under a camera is the area of the set of pixels whose
ray meets ``K`` beyond the near plane, inside the viewport: what a rasteriser
covers when it draws ``K``'s surface clipped by the near plane, without back-face
culling (``docs/visibility.md`` derives the cases):

* a box: its *back* faces (outward normal pointing away from the eye), clipped by
  the near plane ``d >= znear``, projected and clipped by the viewport; every
  ray through the clipped box leaves it through exactly one back face beyond the
  near plane, so their areas add up exactly, whether the box is in front, cut by
  the near plane or around the camera;
* a sphere in front of the near plane: its silhouette ellipse, intersected
  exactly with the viewport (the ellipse mapped to the unit disk, the viewport to
  a parallelogram, the disk-polygon area summed over the polygon's edges);
* a sphere cut by the near plane, or around the camera: the convex hull of its
  silhouette circle beyond the near plane and its rim on the near plane,
  projected (sampled finely, relative error ~1e-5), clipped by the viewport.
  A sphere wholly behind the near plane covers nothing.

The far plane is not applied: cameras should see the whole scene within it.
Image coordinates are those of :mod:`vdad.camera` (origin bottom-left, y up).
"""

from __future__ import annotations

import numpy as np

_RIM_SAMPLES = 720                 # points per circle on the slow path of spheres


def clip_polygons(P, normal, offset):
    """Clip convex polygons ``P`` (k, n, D) (vertices in order, repeats allowed) to
    the half-space ``x . normal >= offset`` (Sutherland-Hodgman, all at once).
    Returns (k, n + 1, D); an empty result has all vertices equal (area 0)."""
    k, n, D = P.shape
    s = P @ np.asarray(normal, float) - offset                         # (k, n)
    nxt = np.roll(np.arange(n), -1)
    inside = s >= 0
    cross = inside != inside[:, nxt]
    with np.errstate(divide="ignore", invalid="ignore"):
        t = np.where(cross, s / (s - s[:, nxt]), 0.0)
    X = P + t[..., None] * (P[:, nxt] - P)                             # (k, n, D)
    out = np.stack([P, X], axis=2).reshape(k, 2 * n, D)
    keep = np.stack([inside, cross], axis=2).reshape(k, 2 * n)
    order = np.argsort(~keep, axis=1, kind="stable")[:, :n + 1]
    out = np.take_along_axis(out, order[..., None], axis=1)
    count = keep.sum(axis=1)
    pad = np.arange(n + 1)[None, :] >= count[:, None]
    return np.where(pad[..., None], out[:, :1], out)


def polygon_areas(P):
    """Areas (k,) of polygons ``P`` (k, n, 2) by the shoelace formula (unsigned)."""
    Q = np.concatenate([P[:, 1:], P[:, :1]], axis=1)                    # next vertices
    return 0.5 * np.abs(np.sum(P[..., 0] * Q[..., 1] - Q[..., 0] * P[..., 1], axis=1))


def clip_to_viewport(P, width, height):
    """Polygons ``P`` (k, n, 2) in pixels clipped to ``[0, width] x [0, height]``."""
    for normal, offset in (((1, 0), 0.0), ((-1, 0), -width), ((0, 1), 0.0), ((0, -1), -height)):
        P = clip_polygons(P, normal, offset)
    return P


def _project(camera, X):
    """Pixels (..., 2) of camera-frame points ``X`` (..., 3) in front of the camera."""
    return camera.focal * X[..., :2] / -X[..., 2:3] + 0.5 * np.array([camera.width,
                                                                      camera.height])


_FACES = np.array([[0, 2, 6, 4], [1, 5, 7, 3],      # -x, +x   (corner i: signs of its bits)
                   [0, 4, 5, 1], [2, 3, 7, 6],      # -y, +y
                   [0, 1, 3, 2], [4, 6, 7, 5]])     # -z, +z
_CORNERS = np.array([[(i >> 2) & 1, (i >> 1) & 1, i & 1] for i in range(8)]) * 2.0 - 1.0
_CORNERS = _CORNERS[:, ::-1]                         # corner i: x from bit 0, y bit 1, z bit 2


def box_areas(camera, center, R, half):
    """Projected areas (k,) in pixels of boxes given in *camera* coordinates:
    centres ``center`` (k, 3), axes ``R`` (k, 3, 3) (columns), half-extents
    ``half`` (k, 3) (any negative: empty box, area 0)."""
    k = len(center)
    area = np.zeros(k)
    if k == 0:
        return area
    local = _CORNERS * np.maximum(half, 0)[:, None]                       # (k, 8, 3)
    corners = center[:, None] + local @ np.swapaxes(R, 1, 2)
    axis = np.repeat(np.arange(3), 2)
    normal = R[:, :, axis] * np.tile([-1.0, 1.0], 3)                    # (k, 3, 6)
    face_c = center[:, None] + np.swapaxes(normal, 1, 2) * np.take(half, axis, axis=1)[..., None]
    back = (np.einsum("kfi,kif->kf", face_c, normal) > 0) & np.all(half >= 0, axis=1)[:, None]
    depth = -corners[..., 2]
    front = np.all(depth >= camera.znear, axis=1)
    xy = _project(camera, np.where(front[:, None, None], corners, [0.0, 0.0, -1.0]))
    lo, hi = np.min(xy, axis=1), np.max(xy, axis=1)
    size = np.array([camera.width, camera.height])
    inside = front & np.all(lo >= 0, axis=1) & np.all(hi <= size, axis=1)
    away = front & (np.any(hi <= 0, axis=1) | np.any(lo >= size, axis=1))
    behind = np.all(depth < camera.znear, axis=1)
    # wholly inside the viewport: the back faces' projections, no clipping
    fx = xy[inside][:, _FACES]                                          # (m, 6, 4, 2)
    shoelace = polygon_areas(fx.reshape(-1, 4, 2)).reshape(-1, 6)
    area[inside] = np.sum(shoelace * back[inside], axis=1)
    # cut by the near plane or the viewport: clip each back face
    kk, ff = np.nonzero(back & ~(inside | away | behind)[:, None])
    if len(kk):
        P = clip_polygons(corners[kk[:, None], _FACES[ff]], (0.0, 0.0, -1.0), camera.znear)
        P[..., 2] = np.minimum(P[..., 2], -camera.znear)             # empty faces: area 0
        clipped = clip_to_viewport(_project(camera, P), camera.width, camera.height)
        area += np.bincount(kk, polygon_areas(clipped), minlength=k)
    return area


def _segment_disk_areas(a, b):
    """Signed areas (...) of the unit disk intersected with triangles (0, a, b),
    ``a``, ``b`` (..., 2): sectors outside the disk, triangles inside."""
    e = b - a
    A = np.einsum("...i,...i->...", e, e)
    B = np.einsum("...i,...i->...", a, e)
    C = np.einsum("...i,...i->...", a, a) - 1.0
    disc = B * B - A * C
    ok = (A > 0) & (disc > 0)
    root = np.sqrt(np.where(ok, disc, 0.0))
    A_safe = np.where(A > 0, A, 1.0)
    t1 = np.where(ok, np.clip((-B - root) / A_safe, 0, 1), 1.0)
    t2 = np.where(ok, np.clip((-B + root) / A_safe, 0, 1), 1.0)
    P1, P2 = a + t1[..., None] * e, a + t2[..., None] * e

    def cross(u, v):
        return u[..., 0] * v[..., 1] - u[..., 1] * v[..., 0]

    def sector(u, v):
        return 0.5 * np.arctan2(cross(u, v), np.einsum("...i,...i->...", u, v))

    return sector(a, P1) + 0.5 * cross(P1, P2) + sector(P2, b)


def _ellipse_areas(camera, C, r):
    """Areas of the silhouette ellipses of spheres wholly in front of the camera
    (centres ``C`` (k, 3) camera frame, radii ``r`` (k,)), clipped to the viewport."""
    f = camera.focal
    x, y, d = C[:, 0], C[:, 1], -C[:, 2]
    s = x * x + y * y + d * d - r * r                                   # l^2 - r^2
    # cone (P.C)^2 >= s |P|^2 on the plane P = (u, v, 1): w^T Q2 w + 2 q.w + q0 >= 0
    Q2 = np.empty((len(C), 2, 2))
    Q2[:, 0, 0], Q2[:, 1, 1] = x * x - s, y * y - s
    Q2[:, 0, 1] = Q2[:, 1, 0] = x * y
    q = np.stack([x * d, y * d], axis=1)
    w0 = -np.linalg.solve(Q2, q[..., None])[..., 0]                     # ellipse centre
    kappa = d * d - s + np.einsum("ki,ki->k", q, w0)
    E = -Q2 / (kappa * f * f)[:, None, None]                            # in pixels
    L = np.linalg.cholesky(E)                                           # E = L L^T
    p0 = 0.5 * np.array([camera.width, camera.height]) + f * w0
    size = np.array([camera.width, camera.height])
    reach = np.sqrt(np.diagonal(np.linalg.inv(E), axis1=1, axis2=2))  # half bounding box
    unit = np.full(len(C), np.pi)                                       # disk area
    cut = np.any(p0 - reach < 0, axis=1) | np.any(p0 + reach > size, axis=1)
    unit[np.any(p0 + reach <= 0, axis=1) | np.any(p0 - reach >= size, axis=1)] = 0.0
    cut &= unit > 0
    if cut.any():                                      # exact disk-polygon intersection
        W, H = size
        rect = np.array([[0.0, 0.0], [W, 0.0], [W, H], [0.0, H]])
        z = np.einsum("kji,kcj->kci", L[cut], rect[None] - p0[cut][:, None])  # L^T (x - p0)
        unit[cut] = np.abs(_segment_disk_areas(z, np.roll(z, -1, axis=1)).sum(axis=1))
    return unit / (L[:, 0, 0] * L[:, 1, 1])


def _cut_sphere_area(camera, C, r):
    """Area of one sphere cut by the near plane or around the camera (slow path)."""
    n, d = camera.znear, -C[2]
    theta = np.linspace(0, 2 * np.pi, _RIM_SAMPLES, endpoint=False)
    ring = np.stack([np.cos(theta), np.sin(theta)], axis=1)
    pts = []
    rim2 = r * r - (d - n) ** 2
    if rim2 > 0:                                                        # rim on the near plane
        rim = np.sqrt(rim2) * ring
        pts.append(np.column_stack([C[0] + rim[:, 0], C[1] + rim[:, 1], np.full(len(rim), -n)]))
    l2 = C @ C
    if l2 > r * r:                                                      # silhouette circle
        u = C / np.sqrt(l2)
        e1 = np.cross(u, [1.0, 0, 0] if abs(u[0]) < 0.9 else [0, 1.0, 0])
        e1 /= np.linalg.norm(e1)
        e2 = np.cross(u, e1)
        rho = r * np.sqrt(l2 - r * r) / np.sqrt(l2)
        circle = C * (1 - r * r / l2) + rho * (ring[:, :1] * e1 + ring[:, 1:] * e2)
        pts.append(circle[-circle[:, 2] >= n])
    pts = np.concatenate(pts) if pts else np.zeros((0, 3))
    if len(pts) < 3:
        return 0.0
    hull = _convex_hull(_project(camera, pts))
    return float(polygon_areas(clip_to_viewport(hull[None], camera.width, camera.height))[0])


def _convex_hull(P):
    """Convex hull (m, 2) of points ``P`` (k, 2), counter-clockwise (monotone chain)."""
    P = P[np.lexsort((P[:, 1], P[:, 0]))]

    def chain(points):
        out = []
        for p in points:
            while len(out) >= 2 and ((out[-1][0] - out[-2][0]) * (p[1] - out[-2][1])
                                     - (out[-1][1] - out[-2][1]) * (p[0] - out[-2][0])) <= 0:
                out.pop()
            out.append(p)
        return out[:-1]

    return np.array(chain(P) + chain(P[::-1]))


def sphere_areas(camera, center, radius):
    """Projected areas (k,) in pixels of spheres with centres ``center`` (k, 3) in
    *camera* coordinates and ``radius`` (k,) (negative: empty, area 0)."""
    center = np.asarray(center, float).reshape(-1, 3)
    r = np.asarray(radius, float).reshape(-1)
    d = -center[:, 2]
    area = np.zeros(len(r))
    front = (r > 0) & (d - r >= camera.znear)
    if front.any():
        area[front] = _ellipse_areas(camera, center[front], r[front])
    for i in np.flatnonzero((r > 0) & ~front & (d + r > camera.znear)):
        area[i] = _cut_sphere_area(camera, center[i], r[i])
    return area
