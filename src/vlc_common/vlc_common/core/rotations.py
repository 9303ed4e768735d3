"""Rotations and quaternions in ROS order ``x, y, z, w`` (REP-103 frames, Hamilton product).

Vectorised: angles are scalars or arrays (N,), matrices (3, 3) or (N, 3, 3), quaternions
(4,) or (N, 4); angles in radians. A quaternion ``q`` (or matrix ``R``) rotates vectors
from the body frame to the parent frame: ``v_parent = R(q) · v_body``.
"""
import math

import numpy as np


def rot_x(angle_rad):
    """Rotation about x by ``angle_rad``; returns (3, 3) or (N, 3, 3)."""
    c, s = np.cos(angle_rad), np.sin(angle_rad)
    o, z = np.ones_like(c), np.zeros_like(c)
    return np.moveaxis(np.array([[o, z, z], [z, c, -s], [z, s, c]]), (0, 1), (-2, -1))


def rot_y(angle_rad):
    """Rotation about y by ``angle_rad``; returns (3, 3) or (N, 3, 3)."""
    c, s = np.cos(angle_rad), np.sin(angle_rad)
    o, z = np.ones_like(c), np.zeros_like(c)
    return np.moveaxis(np.array([[c, z, s], [z, o, z], [-s, z, c]]), (0, 1), (-2, -1))


def rot_z(angle_rad):
    """Rotation about z by ``angle_rad``; returns (3, 3) or (N, 3, 3)."""
    c, s = np.cos(angle_rad), np.sin(angle_rad)
    o, z = np.ones_like(c), np.zeros_like(c)
    return np.moveaxis(np.array([[c, -s, z], [s, c, z], [z, z, o]]), (0, 1), (-2, -1))


def rpy_to_matrix(roll, pitch, yaw):
    """R = Rz(yaw)·Ry(pitch)·Rx(roll): body → parent frame (REP-103 roll/pitch/yaw)."""
    return rot_z(yaw) @ rot_y(pitch) @ rot_x(roll)


def matrix_to_rpy(R):
    """Inverse of :func:`rpy_to_matrix`; returns (..., 3) roll, pitch, yaw."""
    R = np.asarray(R, dtype=float)
    roll = np.arctan2(R[..., 2, 1], R[..., 2, 2])
    pitch = -np.arcsin(np.clip(R[..., 2, 0], -1.0, 1.0))
    yaw = np.arctan2(R[..., 1, 0], R[..., 0, 0])
    return np.stack([roll, pitch, yaw], axis=-1)


def matrix_to_quat_xyzw(R):
    """Rotation matrix (…, 3, 3) → unit quaternion (…, 4) in x, y, z, w order, w ≥ 0."""
    R = np.asarray(R, dtype=float)
    m = R.reshape(-1, 3, 3)
    tr = np.trace(m, axis1=1, axis2=2)
    # Shepperd's method: pick the largest of w, x, y, z for numerical stability.
    cand = np.stack([tr, m[:, 0, 0], m[:, 1, 1], m[:, 2, 2]], axis=1)
    k = np.argmax(cand, axis=1)
    q = np.empty((m.shape[0], 4))
    for i in range(m.shape[0]):
        r = m[i]
        if k[i] == 0:
            s = 2.0 * np.sqrt(1.0 + tr[i])
            q[i] = [(r[2, 1] - r[1, 2]) / s, (r[0, 2] - r[2, 0]) / s,
                    (r[1, 0] - r[0, 1]) / s, 0.25 * s]
        elif k[i] == 1:
            s = 2.0 * np.sqrt(1.0 + r[0, 0] - r[1, 1] - r[2, 2])
            q[i] = [0.25 * s, (r[0, 1] + r[1, 0]) / s, (r[0, 2] + r[2, 0]) / s,
                    (r[2, 1] - r[1, 2]) / s]
        elif k[i] == 2:
            s = 2.0 * np.sqrt(1.0 + r[1, 1] - r[0, 0] - r[2, 2])
            q[i] = [(r[0, 1] + r[1, 0]) / s, 0.25 * s, (r[1, 2] + r[2, 1]) / s,
                    (r[0, 2] - r[2, 0]) / s]
        else:
            s = 2.0 * np.sqrt(1.0 + r[2, 2] - r[0, 0] - r[1, 1])
            q[i] = [(r[0, 2] + r[2, 0]) / s, (r[1, 2] + r[2, 1]) / s, 0.25 * s,
                    (r[1, 0] - r[0, 1]) / s]
    q *= np.where(q[:, 3:4] < 0.0, -1.0, 1.0)
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    return q.reshape(R.shape[:-2] + (4,))


def quat_multiply(p, q):
    """Hamilton product ``p ⊗ q`` of quaternions (..., 4) in x, y, z, w order."""
    p = np.asarray(p, dtype=float)
    q = np.asarray(q, dtype=float)
    px, py, pz, pw = p[..., 0], p[..., 1], p[..., 2], p[..., 3]
    qx, qy, qz, qw = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    return np.stack([
        pw * qx + px * qw + py * qz - pz * qy,
        pw * qy - px * qz + py * qw + pz * qx,
        pw * qz + px * qy - py * qx + pz * qw,
        pw * qw - px * qx - py * qy - pz * qz,
    ], axis=-1)


def quat_conjugate(q):
    """Inverse of a unit quaternion (..., 4)."""
    q = np.asarray(q, dtype=float)
    return q * np.array([-1.0, -1.0, -1.0, 1.0])


def quat_normalize(q):
    """Unit quaternion (..., 4) with w ≥ 0 (one representative of ±q)."""
    q = np.asarray(q, dtype=float)
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    return np.where(q[..., 3:4] < 0.0, -q, q)


def quat_from_rotvec(rotvec):
    """Exponential map: rotation vector (..., 3) [rad] → unit quaternion (..., 4)."""
    v = np.asarray(rotvec, dtype=float)
    angle = np.linalg.norm(v, axis=-1, keepdims=True)
    half = 0.5 * angle
    # sin(x/2)/x → 1/2 − x²/48 for small x; avoids 0/0 at the identity.
    small = angle < 1e-8
    scale = np.where(small, 0.5 - angle ** 2 / 48.0, np.sin(half) / np.where(small, 1.0, angle))
    return np.concatenate([v * scale, np.cos(half)], axis=-1)


def quat_to_rotvec(q):
    """Logarithm map: unit quaternion (..., 4) → rotation vector (..., 3), angle ≤ π."""
    q = quat_normalize(q)
    vec = q[..., :3]
    s = np.linalg.norm(vec, axis=-1, keepdims=True)
    angle = 2.0 * np.arctan2(s, q[..., 3:4])
    small = s < 1e-12
    scale = np.where(small, 2.0, angle / np.where(small, 1.0, s))
    return vec * scale


def quat_to_matrix(q):
    """Unit quaternion (..., 4) → rotation matrix (..., 3, 3), body → parent."""
    q = np.asarray(q, dtype=float)
    x, y, z, w = _unit_xyzw(q)
    m = np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
        [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
        [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
    ])
    return m if m.ndim == 2 else np.moveaxis(m, (0, 1), (-2, -1))


def _unit_xyzw(q):
    """(x, y, z, w) of ``q`` (..., 4) over its norm. One finite, non-zero quaternion (the
    IMU paths' call at every sample) as floats, a fraction of the array code's time and
    rounded as it rounds them (the sum of squares in order, then the square root); any
    other input as arrays (NaNs where the norm is zero or not finite).
    """
    if q.shape == (4,):
        x, y, z, w = q.tolist()
        n = math.sqrt(x * x + y * y + z * z + w * w)
        if 0.0 < n < math.inf:
            return x / n, y / n, z / n, w / n
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    return q[..., 0], q[..., 1], q[..., 2], q[..., 3]


def quat_from_rpy(roll, pitch, yaw):
    """Quaternion of R = Rz(yaw)·Ry(pitch)·Rx(roll) (REP-103); inputs scalar or (N,)."""
    roll, pitch, yaw = np.broadcast_arrays(np.asarray(roll, dtype=float),
                                           np.asarray(pitch, dtype=float),
                                           np.asarray(yaw, dtype=float))
    cr, sr = np.cos(0.5 * roll), np.sin(0.5 * roll)
    cp, sp = np.cos(0.5 * pitch), np.sin(0.5 * pitch)
    cy, sy = np.cos(0.5 * yaw), np.sin(0.5 * yaw)
    return np.stack([
        sr * cp * cy - cr * sp * sy,
        cr * sp * cy + sr * cp * sy,
        cr * cp * sy - sr * sp * cy,
        cr * cp * cy + sr * sp * sy,
    ], axis=-1)


def quat_to_rpy(q):
    """Unit quaternion (..., 4) → (..., 3) roll, pitch, yaw with R = Rz·Ry·Rx."""
    x, y, z, w = _unit_xyzw(np.asarray(q, dtype=float))
    roll = np.arctan2(2.0 * (w * x + y * z), 1.0 - 2.0 * (x * x + y * y))
    pitch = np.arcsin(np.clip(2.0 * (w * y - z * x), -1.0, 1.0))
    yaw = np.arctan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))
    return np.stack([roll, pitch, yaw], axis=-1)


def quat_slerp(q0, q1, fraction):
    """Spherical linear interpolation between unit quaternions (..., 4).

    ``fraction`` (...,) in [0, 1]; 0 gives ``q0``, 1 gives ``q1``. Takes the short arc
    (``q1`` is flipped when ``q0·q1 < 0``). Exact for a constant-rate rotation between
    the two end points.
    """
    q0 = np.asarray(q0, dtype=float)
    q1 = np.asarray(q1, dtype=float)
    frac = np.asarray(fraction, dtype=float)[..., None]
    dot = np.sum(q0 * q1, axis=-1, keepdims=True)
    q1 = np.where(dot < 0.0, -q1, q1)
    # Relative rotation q0⁻¹ ⊗ q1 scaled by the fraction in the tangent space.
    rel = quat_multiply(quat_conjugate(q0), q1)
    out = quat_multiply(q0, quat_from_rotvec(quat_to_rotvec(rel) * frac))
    return out / np.linalg.norm(out, axis=-1, keepdims=True)


def wrap_angle(angle_rad):
    """Wrap angles (any shape) to [−π, π)."""
    return (np.asarray(angle_rad, dtype=float) + np.pi) % (2.0 * np.pi) - np.pi
