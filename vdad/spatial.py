"""Spatial vector algebra (Featherstone, RBDA ch. 2), on single items and stacks.

Conventions (theory §1): motion vectors ``v = (w; v_P)`` and force vectors
``f = (n_P; f)``, angular part first. Every function accepts leading batch
dimensions: vectors are ``(..., 6)``, matrices ``(..., 6, 6)``, rotations
``(..., 3, 3)``. Quaternions are ``(w, x, y, z)`` as in MuJoCo.
"""

from __future__ import annotations

import numpy as np


def skew(x):
    """Cross-product matrix ``[x]×`` of ``x``: (..., 3) -> (..., 3, 3)."""
    x = np.asarray(x, dtype=float)
    out = np.zeros(x.shape + (3,))
    out[..., 0, 1] = -x[..., 2]
    out[..., 0, 2] = x[..., 1]
    out[..., 1, 0] = x[..., 2]
    out[..., 1, 2] = -x[..., 0]
    out[..., 2, 0] = -x[..., 1]
    out[..., 2, 1] = x[..., 0]
    return out


def crm(v):
    """Motion cross-product matrix ``v×`` (RBDA eq. 2.31): (..., 6) -> (..., 6, 6)."""
    v = np.asarray(v, dtype=float)
    w = skew(v[..., :3])
    out = np.zeros(v.shape[:-1] + (6, 6))
    out[..., :3, :3] = w
    out[..., 3:, 3:] = w
    out[..., 3:, :3] = skew(v[..., 3:])
    return out


def crf(v):
    """Force cross-product matrix ``v×* = -crm(v)^T`` (RBDA eq. 2.32)."""
    return -np.swapaxes(crm(v), -1, -2)


def cross3(a, b):
    """``a × b`` for (..., 3) arrays (numpy's ``cross`` costs more on small stacks)."""
    a0, a1, a2 = a[..., 0], a[..., 1], a[..., 2]
    b0, b1, b2 = b[..., 0], b[..., 1], b[..., 2]
    out = np.empty(np.broadcast_shapes(a.shape, b.shape))
    out[..., 0] = a1 * b2 - a2 * b1
    out[..., 1] = a2 * b0 - a0 * b2
    out[..., 2] = a0 * b1 - a1 * b0
    return out


def mv(A, x):
    """Stacked matrix-vector product ``A x``: (..., m, n), (..., n) -> (..., m)."""
    return np.matmul(A, x[..., None])[..., 0]


def cross_motion(v, m):
    """``crm(v) m`` without forming the matrix: (..., 6), (..., 6) -> (..., 6)."""
    w, vl = v[..., :3], v[..., 3:]
    return np.concatenate([cross3(w, m[..., :3]),
                           cross3(w, m[..., 3:]) + cross3(vl, m[..., :3])], axis=-1)


def cross_force(v, f):
    """``crf(v) f`` without forming the matrix: (..., 6), (..., 6) -> (..., 6)."""
    w, vl = v[..., :3], v[..., 3:]
    return np.concatenate([cross3(w, f[..., :3]) + cross3(vl, f[..., 3:]),
                           cross3(w, f[..., 3:])], axis=-1)


def motion_transform(E, r):
    """Plücker transform ``X = [[E, 0], [-E [r]×, E]]`` (RBDA eq. 2.24).

    ``E`` (..., 3, 3) rotates vectors from frame A's axes into frame B's axes and
    ``r`` (..., 3) is B's origin expressed in A. ``X`` maps motion vectors from A
    to B; ``X^T`` maps force vectors from B to A.
    """
    E = np.asarray(E, dtype=float)
    r = np.asarray(r, dtype=float)
    X = np.zeros(np.broadcast_shapes(E.shape[:-2], r.shape[:-1]) + (6, 6))
    X[..., :3, :3] = E
    X[..., 3:, 3:] = E
    X[..., 3:, :3] = -E @ skew(r)
    return X


def pose_to_motion_transform(R, p):
    """Motion transform from a parent frame to a child frame at pose ``(R, p)``.

    ``R`` (..., 3, 3) holds the child's axes in parent coordinates and ``p``
    (..., 3) its origin; the result maps parent-frame motion vectors to the child.
    """
    return motion_transform(np.swapaxes(R, -1, -2), p)


def inertia_at_origin(mass, com, inertia_com):
    """Spatial inertia about a body's origin (RBDA eq. 2.63).

    ``mass`` (...), ``com`` (..., 3) in body coordinates, ``inertia_com``
    (..., 3, 3) about the centre of mass in body axes -> (..., 6, 6).
    """
    mass = np.asarray(mass, dtype=float)
    C = skew(com)
    m = mass[..., None, None]
    out = np.zeros(mass.shape + (6, 6))
    out[..., :3, :3] = inertia_com + m * C @ np.swapaxes(C, -1, -2)
    out[..., :3, 3:] = m * C
    out[..., 3:, :3] = m * np.swapaxes(C, -1, -2)
    out[..., 3:, 3:] = m * np.eye(3)
    return out


# --- rotations -----------------------------------------------------------------

def quat_normalize(q):
    """Unit quaternion(s) ``(..., 4)``."""
    q = np.asarray(q, dtype=float)
    return q / np.linalg.norm(q, axis=-1, keepdims=True)


def quat_to_rot(q):
    """Rotation matrix of unit quaternion(s) ``(w, x, y, z)``: (..., 4) -> (..., 3, 3)."""
    q = np.asarray(q, dtype=float)
    w, x, y, z = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    out = np.empty(q.shape[:-1] + (3, 3))
    out[..., 0, 0] = 1 - 2 * (y * y + z * z)
    out[..., 0, 1] = 2 * (x * y - w * z)
    out[..., 0, 2] = 2 * (x * z + w * y)
    out[..., 1, 0] = 2 * (x * y + w * z)
    out[..., 1, 1] = 1 - 2 * (x * x + z * z)
    out[..., 1, 2] = 2 * (y * z - w * x)
    out[..., 2, 0] = 2 * (x * z - w * y)
    out[..., 2, 1] = 2 * (y * z + w * x)
    out[..., 2, 2] = 1 - 2 * (x * x + y * y)
    return out


def rot_to_quat(R):
    """Unit quaternion ``(w, x, y, z)``, ``w >= 0``, of rotation matrix ``R`` (3, 3)."""
    R = np.asarray(R, dtype=float)
    t = np.trace(R)
    if t > 0:
        s = 2.0 * np.sqrt(1.0 + t)
        q = [0.25 * s, (R[2, 1] - R[1, 2]) / s, (R[0, 2] - R[2, 0]) / s, (R[1, 0] - R[0, 1]) / s]
    else:
        i = int(np.argmax(np.diag(R)))
        j, k = (i + 1) % 3, (i + 2) % 3
        s = 2.0 * np.sqrt(1.0 + R[i, i] - R[j, j] - R[k, k])
        q = np.empty(4)
        q[0] = (R[k, j] - R[j, k]) / s
        q[1 + i] = 0.25 * s
        q[1 + j] = (R[j, i] + R[i, j]) / s
        q[1 + k] = (R[k, i] + R[i, k]) / s
    q = np.asarray(q, dtype=float)
    return q if q[0] >= 0 else -q


def quat_mul(a, b):
    """Hamilton product ``a b`` of quaternions (..., 4)."""
    aw, ax, ay, az = np.moveaxis(np.asarray(a, dtype=float), -1, 0)
    bw, bx, by, bz = np.moveaxis(np.asarray(b, dtype=float), -1, 0)
    return np.stack([aw * bw - ax * bx - ay * by - az * bz,
                     aw * bx + ax * bw + ay * bz - az * by,
                     aw * by - ax * bz + ay * bw + az * bx,
                     aw * bz + ax * by - ay * bx + az * bw], axis=-1)


def quat_exp(omega):
    """Quaternion of the rotation vector ``omega`` (..., 3) (angle = |omega|)."""
    omega = np.asarray(omega, dtype=float)
    angle = np.linalg.norm(omega, axis=-1, keepdims=True)
    half = 0.5 * angle
    # sin(half)/angle, with its Taylor series near zero
    k = np.where(angle > 1e-8, np.sin(half) / np.where(angle > 1e-8, angle, 1.0),
                 0.5 - angle**2 / 48.0)
    return np.concatenate([np.cos(half), k * omega], axis=-1)


def quat_log(q):
    """Rotation vector (..., 3) of unit quaternion(s) ``q``, angle in [0, pi]."""
    q = np.asarray(q, dtype=float)
    q = np.where(q[..., :1] < 0, -q, q)
    s = np.linalg.norm(q[..., 1:], axis=-1, keepdims=True)
    angle = 2.0 * np.arctan2(s, q[..., :1])
    small = s <= 1e-12
    k = np.where(small, 2.0 / np.maximum(q[..., :1], 1e-300), angle / np.where(small, 1.0, s))
    return k * q[..., 1:]


def axis_angle_to_rot(axis, angle):
    """Rodrigues' formula: unit ``axis`` (..., 3), ``angle`` (...) -> (..., 3, 3)."""
    axis = np.asarray(axis, dtype=float)
    angle = np.asarray(angle, dtype=float)[..., None, None]
    K = skew(axis)
    return np.eye(3) + np.sin(angle) * K + (1.0 - np.cos(angle)) * (K @ K)

