"""Exact projected areas of spheres and boxes in pixels (Kim 2008 eqs. 5-6; theory §7).

The area of a volume ``K`` under a camera is the area of the set of pixels whose
ray meets ``K`` beyond the near plane, inside the viewport: what a rasteriser
covers when it draws ``K``'s surface clipped by the near plane, without back-face
culling (``docs/visibility.md`` derives the cases):

* a box cut by the near plane ``d >= znear`` or around the camera: its *back*
  faces (outward normal pointing away from the eye), clipped by the near plane,
  projected and clipped by the viewport; every ray through the clipped box
  leaves it through exactly one back face beyond the near plane, so their areas
  add up exactly; a box wholly in front: its *front* faces (at most three),
  projected and clipped by the viewport, as every ray through it enters it
  through exactly one;
* a sphere in front of the near plane: its silhouette ellipse, intersected
  exactly with the viewport (the ellipse mapped to the unit disk, the viewport to
  a parallelogram, the disk-polygon area summed over the polygon's edges);
* a sphere cut by the near plane, or around the camera: the convex hull of its
  silhouette circle beyond the near plane and its rim on the near plane,
  projected (sampled finely, relative error ~1e-5), clipped by the viewport.
  A sphere wholly behind the near plane covers nothing.

The far plane is not applied: cameras should see the whole scene within it.
Image coordinates are those of :mod:`vdad.camera` (origin bottom-left, y up).

Compiled, one volume per kernel call (:func:`sphere_area`, :func:`box_area`),
with the camera as the tuple ``view = (f, width, height, znear)``
(:func:`view_of`); :func:`sphere_areas` and :func:`box_areas` are the batch
forms for numpy callers, in camera coordinates (``vdad.bounding.areas`` in the
world).
"""

from __future__ import annotations

import numpy as np

from ._linalg import inlined, kernel

RIM_SAMPLES = 720                  # points per circle on the slow path of spheres
MAX_VERTICES = 16                  # a box face clipped by the near plane and viewport: <= 9

#: corner ``i`` of a box: the sign of its x half-extent from bit 0, y bit 1, z bit 2
CORNERS = np.array([[2.0 * ((i >> a) & 1) - 1.0 for a in range(3)] for i in range(8)])
#: the corners of faces -x, +x, -y, +y, -z, +z, in order around each face
FACES = np.array([[0, 2, 6, 4], [1, 5, 7, 3], [0, 4, 5, 1], [2, 3, 7, 6], [0, 1, 3, 2],
                  [4, 6, 7, 5]])


def view_of(camera):
    """The camera's intrinsics as the kernels take them: (focal in pixels, width,
    height, znear)."""
    return (float(camera.focal), float(camera.width), float(camera.height),
            float(camera.znear))


# --- polygons ------------------------------------------------------------------------------

@inlined
def clip_polygon(P, m, nx, ny, nz, offset, out):
    """Clip the polygon ``P[:m]`` (vertices in order; 2 or 3 columns, ``nz``
    ignored for 2) to the half-space ``x . n >= offset`` (one Sutherland-Hodgman
    stage) into ``out``; returns its vertex count (0: nothing left)."""
    dim = P.shape[1]
    k = 0
    for i in range(m):
        j = i + 1 if i + 1 < m else 0
        si = P[i, 0] * nx + P[i, 1] * ny + (P[i, 2] * nz if dim == 3 else 0.0) - offset
        sj = P[j, 0] * nx + P[j, 1] * ny + (P[j, 2] * nz if dim == 3 else 0.0) - offset
        if si >= 0:
            for c in range(dim):
                out[k, c] = P[i, c]
            k += 1
        if (si >= 0) != (sj >= 0):
            t = si / (si - sj)
            for c in range(dim):
                out[k, c] = P[i, c] + t * (P[j, c] - P[i, c])
            k += 1
    return k


@inlined
def polygon_area(P, m):
    """Unsigned area of the polygon ``P[:m]`` (m, 2) (shoelace formula)."""
    a = 0.0
    for i in range(m):
        j = i + 1 if i + 1 < m else 0
        a += P[i, 0] * P[j, 1] - P[j, 0] * P[i, 1]
    return 0.5 * abs(a)


@inlined
def viewport_area(view, P, m, Q):
    """Area of the polygon ``P[:m]`` (pixels) inside ``[0, width] x [0, height]``,
    clipped only by the viewport edges that its bounding box crosses (clipping by
    an edge it does not cross keeps every vertex); ``P`` and ``Q`` (same shape)
    are scratch, overwritten."""
    if m < 3:
        return 0.0
    lo_u = hi_u = P[0, 0]
    lo_v = hi_v = P[0, 1]
    for i in range(1, m):
        lo_u, hi_u = min(lo_u, P[i, 0]), max(hi_u, P[i, 0])
        lo_v, hi_v = min(lo_v, P[i, 1]), max(hi_v, P[i, 1])
    W, H = view[1], view[2]
    if hi_u <= 0 or hi_v <= 0 or lo_u >= W or lo_v >= H:
        return 0.0
    if lo_u < 0:
        m = clip_polygon(P, m, 1.0, 0.0, 0.0, 0.0, Q)
        P, Q = Q, P
    if hi_u > W:
        m = clip_polygon(P, m, -1.0, 0.0, 0.0, -W, Q)
        P, Q = Q, P
    if lo_v < 0:
        m = clip_polygon(P, m, 0.0, 1.0, 0.0, 0.0, Q)
        P, Q = Q, P
    if hi_v > H:
        m = clip_polygon(P, m, 0.0, -1.0, 0.0, -H, Q)
        P, Q = Q, P
    return polygon_area(P, m)


@inlined
def project(view, x, y, z):
    """Pixel (u, v) of the camera-frame point (x, y, z) in front of the camera."""
    w = view[0] / -z
    return x * w + 0.5 * view[1], y * w + 0.5 * view[2]


# --- spheres -------------------------------------------------------------------------------

@inlined
def sector(ux, uy, vx, vy):
    """Signed area of the unit disk's sector from direction u to v."""
    return 0.5 * np.arctan2(ux * vy - uy * vx, ux * vx + uy * vy)


@inlined
def segment_disk_area(ax, ay, bx, by):
    """Signed area of the unit disk intersected with the triangle (0, a, b):
    sectors outside the disk, the triangle inside."""
    ex, ey = bx - ax, by - ay
    A = ex * ex + ey * ey
    B = ax * ex + ay * ey
    C = ax * ax + ay * ay - 1.0
    disc = B * B - A * C
    t1 = t2 = 1.0
    if A > 0 and disc > 0:
        root = np.sqrt(disc)
        t1 = min(max((-B - root) / A, 0.0), 1.0)
        t2 = min(max((-B + root) / A, 0.0), 1.0)
    p1x, p1y, p2x, p2y = ax + t1 * ex, ay + t1 * ey, ax + t2 * ex, ay + t2 * ey
    return (sector(ax, ay, p1x, p1y) + 0.5 * (p1x * p2y - p1y * p2x)
            + sector(p2x, p2y, bx, by))


@inlined
def ellipse_area(view, x, y, d, r):
    """Area of the silhouette ellipse of a sphere wholly in front of the near
    plane (centre (x, y, -d) in the camera frame, radius r), clipped to the
    viewport: the cone ``(P.C)^2 >= s |P|^2`` on the image plane is the ellipse
    ``(w - w0)^T E (w - w0) <= 1``; with ``E = L L^T`` the map ``L^T (w - w0)``
    takes it to the unit disk and the viewport to a parallelogram."""
    f, W, H = view[0], view[1], view[2]
    s = x * x + y * y + d * d - r * r                                   # l^2 - r^2
    a, b, c = x * x - s, x * y, y * y - s                               # Q2
    qx, qy = x * d, y * d
    det = a * c - b * b
    w0x, w0y = -(c * qx - b * qy) / det, -(a * qy - b * qx) / det      # ellipse centre
    k = -1.0 / ((d * d - s + qx * w0x + qy * w0y) * f * f)             # E = k Q2, pixels
    E00, E01, E11 = k * a, k * b, k * c
    p0x, p0y = 0.5 * W + f * w0x, 0.5 * H + f * w0y
    detE = E00 * E11 - E01 * E01
    rx, ry = np.sqrt(E11 / detE), np.sqrt(E00 / detE)                 # half bounding box
    if p0x + rx <= 0 or p0y + ry <= 0 or p0x - rx >= W or p0y - ry >= H:
        return 0.0
    if p0x - rx >= 0 and p0y - ry >= 0 and p0x + rx <= W and p0y + ry <= H:
        return np.pi / np.sqrt(detE)                                   # wholly in view
    L00 = np.sqrt(E00)
    L10 = E01 / L00
    L11 = np.sqrt(E11 - L10 * L10)
    unit = 0.0                              # cut by the viewport: exact disk-polygon
    for e in range(4):                      # viewport corners (0,0), (W,0), (W,H), (0,H)
        ux = (W if e == 1 or e == 2 else 0.0) - p0x
        uy = (H if e >= 2 else 0.0) - p0y
        vx = (W if e == 0 or e == 1 else 0.0) - p0x
        vy = (H if e == 1 or e == 2 else 0.0) - p0y
        unit += segment_disk_area(L00 * ux + L10 * uy, L11 * uy, L00 * vx + L10 * vy,
                                  L11 * vy)
    return abs(unit) / (L00 * L11)


@kernel
def cut_sphere_area(view, x, y, z, r):
    """Area of a sphere cut by the near plane or around the camera (the slow
    path): the convex hull of its rim on the near plane and of its silhouette
    circle beyond it, projected and clipped to the viewport."""
    n, d = view[3], -z
    P = np.empty((2 * RIM_SAMPLES, 2))
    m = 0
    rim2 = r * r - (d - n) ** 2
    if rim2 > 0:                                                        # rim on the near plane
        rho = np.sqrt(rim2)
        for i in range(RIM_SAMPLES):
            t = 2 * np.pi * i / RIM_SAMPLES
            P[m, 0], P[m, 1] = project(view, x + rho * np.cos(t), y + rho * np.sin(t), -n)
            m += 1
    l2 = x * x + y * y + z * z
    if l2 > r * r:                                                      # silhouette circle
        ln = np.sqrt(l2)
        ux, uy, uz = x / ln, y / ln, z / ln
        if abs(ux) < 0.9:                                               # u x (1, 0, 0)
            e1x, e1y, e1z = 0.0, uz, -uy
        else:                                                           # u x (0, 1, 0)
            e1x, e1y, e1z = -uz, 0.0, ux
        e1n = np.sqrt(e1x * e1x + e1y * e1y + e1z * e1z)
        e1x, e1y, e1z = e1x / e1n, e1y / e1n, e1z / e1n
        e2x, e2y, e2z = uy * e1z - uz * e1y, uz * e1x - ux * e1z, ux * e1y - uy * e1x
        rho = r * np.sqrt(l2 - r * r) / ln
        g = 1 - r * r / l2
        for i in range(RIM_SAMPLES):
            t = 2 * np.pi * i / RIM_SAMPLES
            ct, st = np.cos(t), np.sin(t)
            pz = g * z + rho * (ct * e1z + st * e2z)
            if -pz >= n:
                P[m, 0], P[m, 1] = project(view, g * x + rho * (ct * e1x + st * e2x),
                                           g * y + rho * (ct * e1y + st * e2y), pz)
                m += 1
    if m < 3:
        return 0.0
    hull = np.empty((m + 5, 2))
    k = convex_hull(P, m, hull)
    return viewport_area(view, hull, k, np.empty((m + 5, 2)))


@inlined
def turns_left(H, k, px, py):
    """Whether the chain ``H[:k]`` turns left (counter-clockwise) at (px, py)."""
    return ((H[k - 1, 0] - H[k - 2, 0]) * (py - H[k - 2, 1])
            - (H[k - 1, 1] - H[k - 2, 1]) * (px - H[k - 2, 0])) > 0


@inlined
def convex_hull(P, m, H):
    """The convex hull of the points ``P[:m]`` (m, 2) into ``H`` (counter-clockwise,
    Andrew's monotone chain); returns its vertex count."""
    order = np.argsort(P[:m, 1], kind="mergesort")                     # by x, then y
    order = order[np.argsort(P[order, 0], kind="mergesort")]
    k = 0
    for i in range(m):                                                  # lower chain
        px, py = P[order[i], 0], P[order[i], 1]
        while k >= 2 and not turns_left(H, k, px, py):
            k -= 1
        H[k, 0], H[k, 1] = px, py
        k += 1
    lower = k + 1
    for i in range(m - 2, -1, -1):                                      # upper chain
        px, py = P[order[i], 0], P[order[i], 1]
        while k >= lower and not turns_left(H, k, px, py):
            k -= 1
        H[k, 0], H[k, 1] = px, py
        k += 1
    return k - 1                                                        # the first, again


@inlined
def sphere_area(view, x, y, z, r):
    """Projected area in pixels of the sphere of camera-frame centre (x, y, z) and
    radius ``r`` (negative: empty, area 0)."""
    d = -z
    if r <= 0 or d + r <= view[3]:
        return 0.0
    if d - r >= view[3]:
        return ellipse_area(view, x, y, d, r)
    return cut_sphere_area(view, x, y, z, r)


# --- boxes ---------------------------------------------------------------------------------

@inlined
def camera_vector(Rc, x, y, z):
    """The world vector (x, y, z) in the frame of a camera of world rotation ``Rc``
    (3, 3): ``Rc^T (x, y, z)``, as three scalars."""
    return (Rc[0, 0] * x + Rc[1, 0] * y + Rc[2, 0] * z, Rc[0, 1] * x + Rc[1, 1] * y + Rc[2, 1] * z,
            Rc[0, 2] * x + Rc[1, 2] * y + Rc[2, 2] * z)


@inlined
def front_face_area(Da, ha, hb, hc, t, tb, tc):
    """``docs/visibility.md`` (V3): the projected area, on the image plane at unit
    focal length, of the front face of a box along axis ``a`` (the eye outside its
    slab: the centre's offset ``Da`` along the unit axis, ``|Da| > ha``), the face
    wholly in front of the eye: ``t`` the depth of the face's centre, ``tb``,
    ``tc`` the depth changes along its half edges (``hb``, ``hc`` long)."""
    p, m = tb + tc, tb - tc
    return 4.0 * hb * hc * (abs(Da) - ha) * t / ((t * t - p * p) * (t * t - m * m))


@inlined
def front_faces_area(D, H, t, depth):
    """The sum of :func:`front_face_area` over a box's front faces (one per axis
    whose slab the eye lies outside, ``|D_a| > H_a``), at unit focal length:
    ``D`` (3-tuple) the centre's offsets along the unit axes, ``H`` the
    half-extents, ``t`` the depth changes along the scaled axes, ``depth`` the
    centre's."""
    area = 0.0
    for a in range(3):
        if abs(D[a]) > H[a]:
            b, e = (a + 1) % 3, (a + 2) % 3
            area += front_face_area(D[a], H[a], H[b], H[e], depth - np.sign(D[a]) * t[a], t[b],
                                    t[e])
    return area


@inlined
def box_area(view, Rc, pc, c, R, h, corners, xy, P, Q):
    """Projected area in pixels of the box of world centre ``c`` (3,), axes ``R``
    (3, 3) (columns) and half-extents ``h`` (3,) (any negative: empty, 0) under
    the camera of world pose ``Rc``, ``pc``. A box wholly in front of the near
    plane: the sum over its front faces (at most one per axis, the camera
    outside that axis's slab), each projected quad clipped by the viewport
    (a box wholly in view: each face's closed form, :func:`front_face_area`); a
    box cut by the near plane: the sum over its back faces, clipped by the near
    plane and the viewport. ``corners`` (8, 3), ``xy`` (8, 2), ``P``, ``Q``
    (:data:`MAX_VERTICES`, 3): scratch."""
    H = (h[0], h[1], h[2])
    if H[0] < 0 or H[1] < 0 or H[2] < 0:
        return 0.0
    n, fl = view[3], view[0]
    wx, wy, wz = c[0] - pc[0], c[1] - pc[1], c[2] - pc[2]      # from the eye, world axes
    cx, cy, cz = camera_vector(Rc, wx, wy, wz)
    # wholly in view: beyond the near plane, |f x| <= width/2 d and |f y| <=
    # height/2 d at the smallest depth d, first by the enclosing sphere (radius
    # rho), else by the box's extent along the camera's axes (its corners' x in
    # cx -/+ xr, ...); then the front faces' areas in closed form, from the
    # centre's offset D along each axis and the depth changes t along the scaled
    # axes h_b R[:, b]; a box near the viewport's edges takes the clipped path
    hw, hv = 0.5 * view[1], 0.5 * view[2]
    rho = np.sqrt(H[0] * H[0] + H[1] * H[1] + H[2] * H[2])
    d = -cz - rho
    if d >= n and fl * (abs(cx) + rho) <= hw * d and fl * (abs(cy) + rho) <= hv * d:
        D = (wx * R[0, 0] + wy * R[1, 0] + wz * R[2, 0], wx * R[0, 1] + wy * R[1, 1] + wz * R[2, 1],
             wx * R[0, 2] + wy * R[1, 2] + wz * R[2, 2])
        t = (-H[0] * (Rc[0, 2] * R[0, 0] + Rc[1, 2] * R[1, 0] + Rc[2, 2] * R[2, 0]),
             -H[1] * (Rc[0, 2] * R[0, 1] + Rc[1, 2] * R[1, 1] + Rc[2, 2] * R[2, 1]),
             -H[2] * (Rc[0, 2] * R[0, 2] + Rc[1, 2] * R[1, 2] + Rc[2, 2] * R[2, 2]))
        return fl * fl * front_faces_area(D, H, t, -cz)
    # in the camera frame, in registers (the scratch written below may alias the
    # inputs): the axes, the scaled axes and the centre's offsets D
    ax, ay, az = camera_vector(Rc, R[0, 0], R[1, 0], R[2, 0])
    bx, by, bz = camera_vector(Rc, R[0, 1], R[1, 1], R[2, 1])
    ex, ey, ez = camera_vector(Rc, R[0, 2], R[1, 2], R[2, 2])
    D = (cx * ax + cy * ay + cz * az, cx * bx + cy * by + cz * bz, cx * ex + cy * ey + cz * ez)
    ax, ay, az = H[0] * ax, H[0] * ay, H[0] * az
    bx, by, bz = H[1] * bx, H[1] * by, H[1] * bz
    ex, ey, ez = H[2] * ex, H[2] * ey, H[2] * ez
    d = -cz - (abs(az) + abs(bz) + abs(ez))
    if (d >= n and fl * (abs(cx) + abs(ax) + abs(bx) + abs(ex)) <= hw * d
            and fl * (abs(cy) + abs(ay) + abs(by) + abs(ey)) <= hv * d):
        return fl * fl * front_faces_area(D, H, (-az, -bz, -ez), -cz)
    front = behind = True
    lo_u = lo_v = np.inf
    hi_u = hi_v = -np.inf
    for i in range(8):           # each corner, and its pixel where all lie in front
        s0, s1, s2 = CORNERS[i, 0], CORNERS[i, 1], CORNERS[i, 2]
        x = cx + s0 * ax + s1 * bx + s2 * ex
        y = cy + s0 * ay + s1 * by + s2 * ey
        z = cz + s0 * az + s1 * bz + s2 * ez
        corners[i, 0], corners[i, 1], corners[i, 2] = x, y, z
        front = front and -z >= n
        behind = behind and -z < n
        if front:
            u, v = project(view, x, y, z)
            xy[i, 0], xy[i, 1] = u, v
            lo_u, hi_u = min(lo_u, u), max(hi_u, u)
            lo_v, hi_v = min(lo_v, v), max(hi_v, v)
    if behind:
        return 0.0
    area = 0.0
    if front:
        if hi_u <= 0 or hi_v <= 0 or lo_u >= view[1] or lo_v >= view[2]:
            return 0.0
        for a in range(3):
            if abs(D[a]) <= H[a]:
                continue                     # the camera in the slab: both faces edge-on or away
            face = 2 * a + 1 if D[a] < 0 else 2 * a
            for v in range(4):
                P[v, 0], P[v, 1] = xy[FACES[face, v], 0], xy[FACES[face, v], 1]
            area += viewport_area(view, P[:, :2], 4, Q[:, :2])
        return area
    for f in range(6):
        a, sign = f // 2, 2.0 * (f % 2) - 1.0
        # back face: its centre c + sign h_a R[:, a] seen along its normal sign R[:, a]
        if sign * D[a] + H[a] <= 0:
            continue
        for v in range(4):
            for b in range(3):
                P[v, b] = corners[FACES[f, v], b]
        m = clip_polygon(P, 4, 0.0, 0.0, -1.0, n, Q)  # the near plane: -z >= znear
        for v in range(m):
            Q[v, 0], Q[v, 1] = project(view, Q[v, 0], Q[v, 1], min(Q[v, 2], -n))
        area += viewport_area(view, Q[:, :2], m, P[:, :2])
    return area


@kernel
def box_scratch():
    """Scratch arrays of :func:`box_area`: corners, their pixels, two polygons
    (compiled: the parallel passes allocate one per thread)."""
    return (np.empty((8, 3)), np.empty((8, 2)), np.empty((MAX_VERTICES, 3)),
            np.empty((MAX_VERTICES, 3)))


# --- batches -------------------------------------------------------------------------------

def sphere_areas(camera, center, radius):
    """Projected areas (k,) in pixels of spheres with centres ``center`` (k, 3) in
    *camera* coordinates and ``radius`` (k,) (negative: empty, area 0)."""
    from .bounding import Volumes, areas

    return areas(Volumes("sphere", np.reshape(center, (-1, 3)),
                         r=np.reshape(np.asarray(radius, float), -1)), camera, camera_frame=True)


def box_areas(camera, center, R, half):
    """Projected areas (k,) in pixels of boxes given in *camera* coordinates:
    centres ``center`` (k, 3), axes ``R`` (k, 3, 3) (columns), half-extents
    ``half`` (k, 3) (any negative: empty box, area 0)."""
    from .bounding import Volumes, areas

    return areas(Volumes("obb", np.reshape(center, (-1, 3)), R=np.reshape(R, (-1, 3, 3)),
                         h=np.reshape(half, (-1, 3))), camera, camera_frame=True)
