"""Quaternion helpers against explicit rotation matrices (R = Rz·Ry·Rx, x, y, z, w)."""
import numpy as np

from vlc_common.core.rotations import (
    quat_from_rotvec,
    quat_from_rpy,
    quat_multiply,
    quat_slerp,
    quat_to_matrix,
    quat_to_rotvec,
    quat_to_rpy,
    wrap_angle,
)


def _rz(a):
    return np.array([[np.cos(a), -np.sin(a), 0], [np.sin(a), np.cos(a), 0], [0, 0, 1]])


def _ry(a):
    return np.array([[np.cos(a), 0, np.sin(a)], [0, 1, 0], [-np.sin(a), 0, np.cos(a)]])


def _rx(a):
    return np.array([[1, 0, 0], [0, np.cos(a), -np.sin(a)], [0, np.sin(a), np.cos(a)]])


def test_rpy_matches_zyx_matrices_and_round_trips():
    rng = np.random.default_rng(0)
    rpy = rng.uniform([-1.0, -1.4, -3.0], [1.0, 1.4, 3.0], (50, 3))
    q = quat_from_rpy(rpy[:, 0], rpy[:, 1], rpy[:, 2])
    for k in range(50):
        expected = _rz(rpy[k, 2]) @ _ry(rpy[k, 1]) @ _rx(rpy[k, 0])
        np.testing.assert_allclose(quat_to_matrix(q[k]), expected, atol=1e-12)
    np.testing.assert_allclose(quat_to_rpy(q), rpy, atol=1e-12)


def test_rotvec_exp_log_and_product():
    v = np.array([0.3, -0.2, 0.5])
    q = quat_from_rotvec(v)
    np.testing.assert_allclose(quat_to_rotvec(q), v, atol=1e-14)
    # Two rotations about one axis add up.
    np.testing.assert_allclose(quat_multiply(quat_from_rotvec(0.4 * v), quat_from_rotvec(0.6 * v)),
                               q, atol=1e-14)
    np.testing.assert_allclose(quat_from_rotvec(np.zeros(3)), [0, 0, 0, 1])


def test_slerp_is_exact_for_a_constant_rate_rotation_and_takes_the_short_arc():
    axis = np.array([1.0, 2.0, -0.5]) / np.linalg.norm([1.0, 2.0, -0.5])
    q0 = quat_from_rpy(0.1, -0.2, 2.5)
    q1 = quat_multiply(q0, quat_from_rotvec(axis * 0.8))
    for f in (0.0, 0.25, 0.5, 0.9, 1.0):
        expected = quat_multiply(q0, quat_from_rotvec(axis * 0.8 * f))
        got = quat_slerp(q0, -q1, f)  # −q1 is the same rotation
        assert min(np.abs(got - expected).max(), np.abs(got + expected).max()) < 1e-12


def test_wrap_angle():
    np.testing.assert_allclose(wrap_angle([np.pi + 0.1, -np.pi - 0.1, 0.3]),
                               [-np.pi + 0.1, np.pi - 0.1, 0.3], atol=1e-12)


def test_one_quaternion_gives_the_array_codes_numbers():
    """The float path for one quaternion (the IMU nodes' 400 Hz calls) returns exactly
    what the array code returns for it in a batch of one, and NaNs where it would.
    """
    rng = np.random.default_rng(7)
    quats = np.vstack([rng.normal(size=(500, 4)),
                       np.column_stack([rng.normal(0.0, 1e-3, (500, 3)), np.ones(500)]),
                       [[0.0, 0.0, 0.0, 2.0], [1e-200, 0.0, 0.0, 1e-200]]])
    for q in quats:
        np.testing.assert_array_equal(quat_to_matrix(q), quat_to_matrix(q[None])[0])
        np.testing.assert_array_equal(quat_to_rpy(q), quat_to_rpy(q[None])[0])
    with np.errstate(invalid='ignore', divide='ignore'):
        for bad in ([0.0, 0.0, 0.0, 0.0], [np.nan, 0.0, 0.0, 1.0], [np.inf, 0.0, 0.0, 1.0]):
            q = np.array(bad)
            assert np.isnan(quat_to_matrix(q)).any() and np.isnan(quat_to_rpy(q)).any()
            np.testing.assert_array_equal(quat_to_matrix(q), quat_to_matrix(q[None])[0])
            np.testing.assert_array_equal(quat_to_rpy(q), quat_to_rpy(q[None])[0])
