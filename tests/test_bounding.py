"""Bounding volumes (vdad.bounding): bodies' volumes hold their geometry, merges hold
both children, and merges commute with rigid motions (what the group-frame cache uses)."""

import numpy as np
import pytest
import trimesh
from strategies import random_rotation

import vdad
from vdad.bounding import VOLUMES, Volumes, body_volumes, merge, place
from vdad.errors import InputError


def _model():
    """Bodies with every geom kind, off-centre poses, and one without geometry."""
    geoms = [
        (vdad.Geom("sphere", (0.2,), vdad.Pose((0.1, 0.0, 0.3))),),
        (vdad.Geom("capsule", (0.05, 0.3), vdad.Pose((0.0, 0.0, -0.3), (0.9, 0.3, 0.1, 0.0))),),
        (vdad.Geom("box", (0.3, 0.1, 0.05), vdad.Pose((0.2, 0.1, 0.0), (0.8, 0.0, 0.6, 0.0))),
         vdad.Geom("cylinder", (0.05, 0.2))),
        (vdad.Geom("mesh", mesh=trimesh.creation.annulus(0.1, 0.3, 0.1)),),
        (),
    ]
    bodies = [vdad.Body(f"b{i}", 1.0, geoms=g) for i, g in enumerate(geoms)]
    joints = [vdad.Joint(f"j{i}", None if i == 0 else f"b{i - 1}", f"b{i}", "spherical",
                         placement=vdad.Pose((0.0, 0.0, -0.6 if i else 0.0)))
              for i in range(len(geoms))]
    return vdad.Model(bodies, joints)


def _contains(v, points, tol=1e-9):
    """Whether volume ``v`` (one) holds ``points`` (m, 3)."""
    if v.kind == "sphere":
        return np.all(np.linalg.norm(points - v.c[0], axis=1) <= v.r[0] + tol)
    local = (points - v.c[0]) @ v.R[0]
    return np.all(np.abs(local) <= v.h[0] + tol)


def _samples(v, rng):
    """Points on the boundary of every volume of ``v`` (k, 200, 3)."""
    u = rng.normal(size=(len(v), 200, 3))
    if v.kind == "sphere":
        u /= np.linalg.norm(u, axis=2, keepdims=True)
        return v.c[:, None] + v.r[:, None, None] * u
    u = np.clip(u, -1, 1)
    return v.c[:, None] + np.einsum("kij,kmj->kmi", v.R, u * v.h[:, None])


@pytest.mark.parametrize("kind", VOLUMES)
def test_body_volumes_hold_their_geometry(kind):
    model = _model()
    v = body_volumes(model, kind)
    for i, body in enumerate(model.bodies):
        if not body.geoms:
            assert v.is_empty[i]
            continue
        points = np.concatenate([g.to_trimesh().vertices for g in body.geoms])
        assert _contains(v[i:i + 1], points, 1e-6), (kind, body.name)
    # placed in the world they still hold the placed geometry
    rng = np.random.default_rng(0)
    R = np.stack([random_rotation(rng) for _ in range(model.nb)])
    p = rng.normal(size=(model.nb, 3))
    w = place(v, R, p)
    for i, body in enumerate(model.bodies):
        if body.geoms:
            pts = np.concatenate([g.to_trimesh().vertices for g in body.geoms]) @ R[i].T + p[i]
            assert _contains(w[i:i + 1], pts, 1e-6)


def _random_volumes(kind, k, rng):
    v = Volumes.empty(kind, k)
    v.c[:] = rng.normal(size=(k, 3))
    if kind == "sphere":
        v.r[:] = rng.uniform(0.01, 1.5, k)
    else:
        v.h[:] = rng.uniform(0.01, 1.0, (k, 3))
        if kind == "obb":
            v.R[:] = np.stack([random_rotation(rng) for _ in range(k)])
    return v


@pytest.mark.parametrize("kind", VOLUMES)
def test_merge_holds_both_children(kind):
    rng = np.random.default_rng(3)
    a, b = _random_volumes(kind, 300, rng), _random_volumes(kind, 300, rng)
    b.c[:20] = a.c[:20]                                  # nested pairs
    m = merge(a, b)
    pa, pb = _samples(a, rng), _samples(b, rng)
    for i in range(300):
        assert _contains(m[i:i + 1], np.concatenate([pa[i], pb[i]]), 1e-9)
    if kind == "sphere":                                 # the smallest enclosing sphere
        d = np.linalg.norm(a.c - b.c, axis=1)
        expected = np.maximum(np.maximum(a.r, b.r), 0.5 * (d + a.r + b.r))
        np.testing.assert_allclose(m.r, expected, rtol=1e-12)
    if kind == "aabb":                                   # the smallest world box
        np.testing.assert_allclose(m.c - m.h, np.minimum(a.c - a.h, b.c - b.h), atol=1e-12)
        np.testing.assert_allclose(m.c + m.h, np.maximum(a.c + a.h, b.c + b.h), atol=1e-12)
        np.testing.assert_array_equal(m.R, np.eye(3)[None].repeat(300, 0))
    # an empty child leaves the other unchanged
    e = Volumes.empty(kind, 300)
    for x, y in ((merge(a, e), a), (merge(e, b), b)):
        np.testing.assert_array_equal(x.c, y.c)


@pytest.mark.parametrize("kind", ["sphere", "obb"])
def test_merge_commutes_with_rigid_motions(kind):
    """merge(T a, T b) = T merge(a, b): a rigid node's volume can be kept in its frame."""
    rng = np.random.default_rng(5)
    a, b = _random_volumes(kind, 50, rng), _random_volumes(kind, 50, rng)
    R = np.stack([random_rotation(rng) for _ in range(50)])
    p = rng.normal(size=(50, 3)) * 10
    x, y = merge(place(a, R, p), place(b, R, p)), place(merge(a, b), R, p)
    np.testing.assert_allclose(x.c, y.c, atol=1e-12)
    for name in ("r", "R", "h"):
        if getattr(x, name) is not None:
            np.testing.assert_allclose(getattr(x, name), getattr(y, name), atol=1e-12)


def test_unknown_volume():
    with pytest.raises(InputError, match="unknown bounding volume 'ball'"):
        body_volumes(_model(), "ball")


@pytest.mark.parametrize("kind,size", [("sphere", (0.3,)), ("capsule", (0.1, 0.4)),
                                       ("cylinder", (0.2, 0.3)), ("box", (0.1, 0.2, 0.3))])
def test_primitive_volumes_are_exact(kind, size):
    """One primitive is bounded in closed form; the trimesh path (two copies of
    it) of its fine tessellation agrees within the tessellation's error and never
    exceeds it."""
    from vdad.bounding import _geometry_volumes
    from vdad.spatial import quat_exp

    R = quat_exp(np.array([0.3, -0.5, 0.7]))
    g = vdad.Geom(kind, size, vdad.Pose((0.1, -0.2, 0.3), R))
    exact, mesh = _geometry_volumes((g,)), _geometry_volumes((g, g))
    np.testing.assert_allclose(exact[0], mesh[0], atol=0.02 * exact[1])
    assert mesh[1] <= exact[1] * (1 + 1e-9) and mesh[1] > 0.97 * exact[1]
    np.testing.assert_allclose(np.sort(exact[4]), np.sort(mesh[4]), rtol=0.02)
    np.testing.assert_allclose(exact[5], mesh[5], atol=0.02 * np.max(exact[6]))
    np.testing.assert_allclose(exact[6], mesh[6], rtol=0.02)
    assert np.all(mesh[6] <= exact[6] * (1 + 1e-9))
