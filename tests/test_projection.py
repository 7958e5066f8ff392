"""Exact projected areas (vdad.projection) against ray casting through pixel centres
(tests/raycast.py), against the closed-form ellipse area, and as the resolution grows."""

import numpy as np
import pytest
from raycast import box_pixels, sphere_pixels
from strategies import random_rotation

from vdad.camera import Camera
from vdad.projection import (
    CORNERS,
    FACES,
    box_areas,
    clip_polygon,
    convex_hull,
    front_face_area,
    polygon_area,
    project,
    sphere_areas,
    view_of,
    viewport_area,
)

CAM = Camera(width=320, height=240)          # f = 207.8 px; half-width 2.31 m at 3 m
# (name, centre in camera coordinates, radius): the cases of theory §7
SPHERES = [
    ("centred", (0.0, 0.0, -3.0), 0.5),
    ("off-axis", (0.8, 0.5, -3.0), 0.4),
    ("one edge", (2.3, 0.0, -3.0), 0.5),
    ("two edges", (2.2, 1.6, -3.0), 0.5),
    ("near plane", (0.2, 0.1, -0.4), 0.37),
    ("camera plane", (0.1, 0.0, -0.3), 0.4),
    ("camera inside", (0.1, 0.0, -0.2), 1.0),
    ("inside, cap in view", (0.0, 0.0, 0.3), 0.45),
]


@pytest.mark.parametrize("name,C,r", SPHERES, ids=[s[0] for s in SPHERES])
def test_sphere_area_equals_pixel_count(name, C, r):
    C = np.array(C)
    area = sphere_areas(CAM, C[None], np.array([r]))[0]
    pixels = sphere_pixels(CAM, C, r)
    assert pixels > 1000
    assert abs(area - pixels) <= 0.01 * pixels, (name, area, pixels)
    if pixels < CAM.width * CAM.height:                      # converges with resolution
        fine = CAM.with_resolution(4 * CAM.width, 4 * CAM.height)
        fine_area = sphere_areas(fine, C[None], np.array([r]))[0]
        assert fine_area == pytest.approx(16 * area, rel=1e-9)
        assert abs(fine_area - sphere_pixels(fine, C, r)) <= 0.25 * abs(area - pixels) * 16 + 40


def test_sphere_ellipse_closed_form():
    """Wholly in view: the exact area pi f^2 r^2 sqrt(l^2 - r^2) / (d^2 - r^2)^(3/2)."""
    rng = np.random.default_rng(1)
    C = np.column_stack([rng.uniform(-0.5, 0.5, 50), rng.uniform(-0.4, 0.4, 50),
                         -rng.uniform(3, 6, 50)])
    r = rng.uniform(0.05, 0.5, 50)
    l2, d = np.sum(C * C, axis=1), -C[:, 2]
    exact = np.pi * CAM.focal**2 * r**2 * np.sqrt(l2 - r**2) / (d**2 - r**2) ** 1.5
    np.testing.assert_allclose(sphere_areas(CAM, C, r), exact, rtol=1e-11)


def test_sphere_behind_or_away_covers_nothing():
    C = np.array([[0.0, 0.0, 3.0], [0.0, 0.0, -0.02], [10.0, 0.0, -3.0], [0, 0, -3.0]])
    r = np.array([0.5, 0.01, 0.5, -1.0])                     # last: empty volume
    np.testing.assert_array_equal(sphere_areas(CAM, C, r), 0.0)


BOXES = [
    ("centred", (0.0, 0.0, -3.0), (0.5, 0.4, 0.3)),
    ("off-axis", (0.9, -0.6, -3.5), (0.4, 0.3, 0.5)),
    ("one edge", (0.0, 1.7, -3.0), (0.5, 0.4, 0.3)),
    ("two edges", (-2.2, -1.6, -3.0), (0.6, 0.5, 0.4)),
    ("near plane", (0.1, 0.0, -0.45), (0.3, 0.25, 0.42)),
    ("camera inside", (0.1, 0.05, -0.2), (1.0, 0.8, 0.9)),
]


@pytest.mark.parametrize("name,c,h", BOXES, ids=[b[0] for b in BOXES])
@pytest.mark.parametrize("seed", [0, 1])
def test_box_area_equals_pixel_count(name, c, h, seed):
    R = random_rotation(np.random.default_rng(seed)) if name != "camera inside" else np.eye(3)
    c, h = np.array(c), np.array(h)
    area = box_areas(CAM, c[None], R[None], h[None])[0]
    pixels = box_pixels(CAM, c, R, h)
    assert pixels > 1000
    assert abs(area - pixels) <= 0.01 * pixels, (name, area, pixels)


@pytest.mark.parametrize("spread", [0.3, 2.5], ids=["in view", "across the edges"])
def test_box_in_front_equals_hull_of_its_corners(spread):
    """A box wholly in front of the near plane, summed over its front faces,
    equals the convex hull of its eight projected corners (clipped by the
    viewport), to rounding: in view, at the viewport's edges and with the camera
    inside one or two of the box's slabs."""
    rng = np.random.default_rng(7)
    k = 300
    c = np.column_stack([rng.uniform(-spread, spread, (k, 2)), -rng.uniform(2.5, 6.0, k)])
    c[:40, :2] = 0.0                                   # the camera in two slabs (axis-aligned)
    c[40:80, 0] = 0.0                                  # and in one
    R = np.stack([random_rotation(rng) for _ in range(k)])
    R[:80] = np.eye(3)
    h = rng.uniform(0.05, 0.8, (k, 3))
    view = view_of(CAM)
    hulls, clipped = np.empty(k), 0
    for i in range(k):
        X = c[i] + (CORNERS * h[i]) @ R[i].T                              # (8, 3)
        xy = np.array([project(view, *x) for x in X])
        H = np.empty((13, 2))
        m = convex_hull(xy, 8, H)
        whole = polygon_area(H, m)
        hulls[i] = viewport_area(view, H, m, np.empty((13, 2)))
        clipped += 0 < hulls[i] < whole * (1 - 1e-9)
    areas = box_areas(CAM, c, R, h)
    assert np.sum(hulls > 0) > k // 2 and (clipped > k // 4 if spread > 1 else clipped == 0)
    np.testing.assert_allclose(areas, hulls, rtol=1e-10, atol=1e-8)


def test_front_face_closed_form_equals_its_projected_quad():
    """docs/visibility.md (V3): the closed-form area of a box's front face equals
    the shoelace area of its four corners projected at unit focal length, for
    random boxes in front of the eye (at the origin, looking down -z)."""
    rng = np.random.default_rng(11)
    checked = 0
    for _ in range(400):
        c = np.array([*rng.uniform(-2, 2, 2), -rng.uniform(1.5, 6.0)])
        R, h = random_rotation(rng), rng.uniform(0.05, 1.0, 3)
        X = c + (CORNERS * h) @ R.T                                       # (8, 3)
        if X[:, 2].max() > -0.05:
            continue
        D = c @ R                                  # the centre's offsets along the axes
        t = -h * R[2]                              # depth changes along h_b R[:, b]
        for a in range(3):
            if abs(D[a]) <= h[a]:
                continue
            b, e = (a + 1) % 3, (a + 2) % 3
            face = 2 * a + 1 if D[a] < 0 else 2 * a
            xy = X[FACES[face]][:, :2] / -X[FACES[face]][:, 2:]               # (4, 2)
            closed = front_face_area(D[a], h[a], h[b], h[e], -c[2] - np.sign(D[a]) * t[a],
                                     t[b], t[e])
            assert closed == pytest.approx(polygon_area(xy, 4), rel=1e-11)
            checked += 1
    assert checked > 500


def test_box_behind_or_empty_covers_nothing():
    c = np.array([[0.0, 0.0, 3.0], [0.0, 0.0, -3.0], [0.0, 9.0, -3.0]])
    h = np.array([[0.5, 0.5, 0.5], [-1.0, -1.0, -1.0], [0.5, 0.5, 0.5]])
    R = np.broadcast_to(np.eye(3), (3, 3, 3))
    np.testing.assert_array_equal(box_areas(CAM, c, R, h), 0.0)


def test_batches_equal_single_items():
    """Batched areas equal the same volumes one at a time (fast and slow paths mixed)."""
    C = np.array([s[1] for s in SPHERES])
    r = np.array([s[2] for s in SPHERES])
    single = [sphere_areas(CAM, C[i:i + 1], r[i:i + 1])[0] for i in range(len(r))]
    np.testing.assert_allclose(sphere_areas(CAM, C, r), single, rtol=1e-12)
    c = np.array([b[1] for b in BOXES])
    h = np.array([b[2] for b in BOXES])
    R = np.stack([random_rotation(np.random.default_rng(i)) for i in range(len(c))])
    single = [box_areas(CAM, c[i:i + 1], R[i:i + 1], h[i:i + 1])[0] for i in range(len(c))]
    np.testing.assert_allclose(box_areas(CAM, c, R, h), single, rtol=1e-12)


def test_clip_polygon():
    """One Sutherland-Hodgman stage of a square: half-planes through it, past it and
    around it, and a 3D polygon clipped by the near plane."""
    square = np.array([[0.0, 0.0], [2.0, 0.0], [2.0, 2.0], [0.0, 2.0]])
    out = np.empty((8, 2))
    for normal, offset, area in (((1.0, 0.0), 0.5, 3.0), ((1.0, 1.0), 3.0, 0.5),
                                 ((1.0, 0.0), 5.0, 0.0), ((1.0, 0.0), -1.0, 4.0)):
        m = clip_polygon(square, 4, *normal, 0.0, offset, out)
        assert polygon_area(out, m) == pytest.approx(area)
    assert clip_polygon(square, 4, 1.0, 0.0, 0.0, 5.0, out) == 0
    quad = np.array([[0.0, 0.0, -1.0], [1.0, 0.0, -1.0], [1.0, 1.0, 0.0], [0.0, 1.0, 0.0]])
    out3 = np.empty((8, 3))
    m = clip_polygon(quad, 4, 0.0, 0.0, -1.0, 0.5, out3)          # keep -z >= 0.5
    assert m == 4 and np.all(-out3[:m, 2] >= 0.5 - 1e-15)
    assert polygon_area(out3, m) == pytest.approx(0.5)            # its (x, y) shadow


def test_viewport_area_clips_only_the_edges_it_crosses():
    """The viewport area of convex polygons inside, across one to four edges and
    outside the viewport equals the polygon clipped by all four edges in turn
    (clipping by an edge a polygon does not cross keeps it whole): exactly where
    it crosses none, and to rounding otherwise; fewer than three vertices cover
    nothing."""
    view = view_of(CAM)
    W, H = view[1], view[2]
    rng = np.random.default_rng(3)
    crossed = np.zeros(5, int)
    for _ in range(2000):
        centre = rng.uniform((-0.5 * W, -0.5 * H), (1.5 * W, 1.5 * H))
        angles = np.sort(rng.uniform(0, 2 * np.pi, rng.integers(3, 9)))
        radius = rng.uniform(5.0, 1.2 * W)
        P = centre + radius * np.column_stack([np.cos(angles), np.sin(angles)])
        m = len(P)
        lo, hi = P.min(axis=0), P.max(axis=0)
        crossed[int(lo[0] < 0) + int(hi[0] > W) + int(lo[1] < 0) + int(hi[1] > H)] += 1
        A, B = np.zeros((16, 2)), np.zeros((16, 2))
        A[:m] = P
        for normal, offset in (((1.0, 0.0), 0.0), ((-1.0, 0.0), -W), ((0.0, 1.0), 0.0),
                               ((0.0, -1.0), -H)):
            m = clip_polygon(A, m, *normal, 0.0, offset, B)
            A, B = B, A
        expected = polygon_area(A, m)
        Q = np.zeros((16, 2))
        Q[:len(P)] = P
        area = viewport_area(view, Q, len(P), np.zeros((16, 2)))
        assert area == pytest.approx(expected, rel=1e-12, abs=1e-9)
        if lo[0] >= 0 and hi[0] <= W and lo[1] >= 0 and hi[1] <= H:
            assert area == polygon_area(P, len(P))
    assert np.all(crossed >= 20), crossed
    assert viewport_area(view, np.full((16, 2), 10.0), 2, np.zeros((16, 2))) == 0.0
