"""Spatial algebra (vdad.spatial): stacked versions equal single-item ones."""

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from vdad import spatial

vec = arrays(np.float64, (4, 6), elements=st.floats(-10, 10))


@settings(max_examples=50, deadline=None)
@given(vec, vec)
def test_cross_products_match_matrices(v, m):
    for i in range(len(v)):
        np.testing.assert_allclose(spatial.cross_motion(v, m)[i], spatial.crm(v[i]) @ m[i],
                                   atol=1e-12)
        np.testing.assert_allclose(spatial.cross_force(v, m)[i], spatial.crf(v[i]) @ m[i],
                                   atol=1e-12)
    np.testing.assert_allclose(spatial.cross3(v[:, :3], m[:, 3:]), np.cross(v[:, :3], m[:, 3:]),
                               atol=1e-12)


def test_quaternions_round_trip():
    rng = np.random.default_rng(0)
    q = spatial.quat_normalize(rng.normal(size=(20, 4)))
    R = spatial.quat_to_rot(q)
    np.testing.assert_allclose(R @ np.swapaxes(R, 1, 2), np.broadcast_to(np.eye(3), R.shape),
                               atol=1e-14)
    for i in range(20):
        back = spatial.rot_to_quat(R[i])
        assert min(np.abs(back - q[i]).max(), np.abs(back + q[i]).max()) < 1e-12
    small = rng.normal(size=(20, 3)) * 0.1
    np.testing.assert_allclose(spatial.quat_log(spatial.quat_exp(small)), small, atol=1e-12)
    np.testing.assert_allclose(spatial.quat_to_rot(spatial.quat_exp(small)),
                               spatial.axis_angle_to_rot(
                                   small / np.linalg.norm(small, axis=1, keepdims=True),
                                   np.linalg.norm(small, axis=1)), atol=1e-12)


def test_motion_transform_composes_with_force_transform():
    rng = np.random.default_rng(1)
    R = spatial.quat_to_rot(spatial.quat_normalize(rng.normal(size=4)))
    p = rng.normal(size=3)
    X = spatial.pose_to_motion_transform(R, p)
    v, f = rng.normal(size=6), rng.normal(size=6)
    # power is frame-invariant: (X v) . f_B = v . (X^T f_B)
    assert abs((X @ v) @ f - v @ (X.T @ f)) < 1e-12
    # a point at the child origin moves with v_P + w x (p - P)
    np.testing.assert_allclose(R @ (X @ v)[3:], v[3:] + np.cross(v[:3], p), atol=1e-12)
