"""AttitudeBuffer: slerp interpolation exact on known rotations, gaps, bad pushes."""
import numpy as np
import pytest

from imu_compensator.core.attitude_buffer import AttitudeBuffer
from vlc_common.core.rotations import quat_from_rotvec, quat_from_rpy, quat_multiply

T0 = 1704067200.0
OMEGA = np.array([0.3, -0.7, 1.9])   # rad/s, body frame
Q0 = quat_from_rpy(0.05, -0.02, 0.4)


def truth(t):
    """Constant body rate from Q0 at T0: q(t) = Q0 ⊗ Exp(ω (t − T0))."""
    return quat_multiply(Q0, quat_from_rotvec(OMEGA * (t - T0)))


def same_rotation(a, b, tol):
    a, b = np.asarray(a), np.asarray(b)
    return min(np.abs(a - b).max(), np.abs(a + b).max()) < tol


def filled(period=0.0025, n=400, **kw):
    buf = AttitudeBuffer(**kw)
    for k in range(n):
        t = T0 + k * period
        # Alternate the sign: ±q is one rotation, the buffer must not care.
        assert buf.push(t, truth(t) * (-1.0 if k % 3 == 0 else 1.0))
    return buf


def test_interpolation_is_exact_for_constant_rate():
    buf = filled()
    rng = np.random.default_rng(3)
    # Rows of a rolling-shutter frame: exposure mid-times between IMU samples.
    times = T0 + rng.uniform(0.0, 399 * 0.0025, 200)
    for t in times:
        assert same_rotation(buf.at(t), truth(t), 1e-9)
    many = buf.at_many(times)
    for t, q in zip(times, many):
        assert same_rotation(q, truth(t), 1e-9)
    assert same_rotation(buf.at(T0 + 10 * 0.0025), truth(T0 + 10 * 0.0025), 1e-12)
    assert buf.at(T0 + 0.9)[3] >= 0.0
    np.testing.assert_allclose(buf.angular_velocity_at(T0 + 0.5), OMEGA, rtol=1e-6)


def test_outside_history_gap_and_extrapolation():
    buf = filled(max_gap_s=0.01)
    assert buf.at(T0 - 0.001) is None
    assert buf.at(buf.newest_s + 0.001) is None
    ext = filled(max_gap_s=0.01, max_extrapolation_s=0.02)
    t = ext.newest_s + 0.015
    assert same_rotation(ext.at(t), truth(t), 1e-9)
    assert ext.at(ext.newest_s + 0.03) is None
    # A hole longer than max_gap_s is not interpolated across.
    gap = AttitudeBuffer(max_gap_s=0.01)
    for t in (T0, T0 + 0.0025, T0 + 0.1, T0 + 0.1025):
        gap.push(t, truth(t))
    assert gap.at(T0 + 0.05) is None
    assert gap.at(T0 + 0.101) is not None


def test_bad_pushes_are_refused_and_horizon_is_kept():
    buf = AttitudeBuffer(horizon_s=0.5)
    assert buf.push(T0, truth(T0))
    assert not buf.push(T0, truth(T0))                 # duplicate stamp
    assert not buf.push(T0 - 0.1, truth(T0))           # older
    assert not buf.push(T0 + 0.1, [np.nan, 0, 0, 1])   # non-finite
    assert not buf.push(T0 + 0.1, [0, 0, 0, 0])        # not a rotation
    assert not buf.push(float('nan'), truth(T0))
    assert len(buf) == 1
    for k in range(1, 3000):
        buf.push(T0 + k * 0.0025, truth(T0 + k * 0.0025))
    assert buf.newest_s - buf.oldest_s == pytest.approx(0.5, abs=0.003)
    t = buf.newest_s - 0.3
    assert same_rotation(buf.at(t), truth(t), 1e-9)
    buf.clear()
    assert len(buf) == 0 and buf.at(t) is None


def test_covariance_is_interpolated_linearly():
    buf = AttitudeBuffer()
    buf.push(T0, truth(T0), np.eye(3) * 1e-6)
    buf.push(T0 + 0.01, truth(T0 + 0.01), np.eye(3) * 3e-6)
    # Stamps ~1.7e9 s as float seconds resolve ~0.24 µs: the weight is exact to ~1e-4.
    np.testing.assert_allclose(buf.covariance_at(T0 + 0.0025), np.eye(3) * 1.5e-6, rtol=1e-4)
    assert buf.covariance_at(T0 + 0.02) is None
    assert buf.rpy_at(T0) == pytest.approx([0.05, -0.02, 0.4], abs=1e-12)


@pytest.mark.parametrize('extrapolation_s', [0.0, 0.01])
def test_at_is_at_many_to_the_bit(extrapolation_s):
    """The one-instant path gives at_many's row exactly: samples, between them, across a
    gap, before the oldest, past the newest (with and without extrapolation), NaN.
    """
    rng = np.random.default_rng(1)
    buf = AttitudeBuffer(horizon_s=2.0, max_gap_s=0.05, max_extrapolation_s=extrapolation_s)
    t = 0.0
    for i in range(900):
        t += 0.0025 if i != 400 else 0.2
        buf.push(t, rng.normal(size=4) * 0.01 + [0.0, 0.0, 0.0, 1.0])
    kept = buf._t[buf._start:buf._end]
    times = np.concatenate([rng.uniform(buf.oldest_s - 0.1, buf.newest_s + 0.05, 2000),
                            kept[::7], [np.nan, buf.oldest_s, buf.newest_s]])
    known = 0
    for t_s, row in zip(times, buf.at_many(times)):
        q = buf.at(t_s)
        if np.isnan(row[0]):
            assert q is None, t_s
        else:
            known += 1
            assert np.array_equal(q, row), t_s
    assert 0 < known < times.size
