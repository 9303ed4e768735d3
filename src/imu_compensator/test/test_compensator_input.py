"""AttitudeCompensator on bad input: classified, counted, never raised."""
import math

import numpy as np
import pytest

from imu_compensator.core.compensator import (
    AidingStatus,
    AttitudeCompensator,
    CompensatorConfig,
    SampleStatus,
)

T0 = 1704067200.0
DT = 0.0025
G = np.array([0.0, 0.0, 9.80665])


def still(comp, t0, n, rng, gyro_bias=(0.002, -0.001, 0.0005)):
    out = []
    for k in range(n):
        out.append(comp.process(t0 + k * DT, np.asarray(gyro_bias) + rng.normal(0, 1.5e-3, 3),
                                G + rng.normal(0, 0.01, 3)))
    return out


def test_each_kind_of_bad_sample_is_classified_and_skipped():
    rng = np.random.default_rng(0)
    comp = AttitudeCompensator()
    res = still(comp, T0, 10, rng)
    assert res[0].status is SampleStatus.INITIALIZED
    assert all(r.status is SampleStatus.OK for r in res[1:])
    t_last = T0 + 9 * DT
    q_before = comp.filter.quat.copy()
    bad = [
        (t_last + DT, [np.nan, 0, 0], G, SampleStatus.NONFINITE),
        (t_last + DT, [0, 0, 0], [0, np.inf, 9.8], SampleStatus.NONFINITE),
        (float('nan'), [0, 0, 0], G, SampleStatus.NONFINITE),
        (t_last, [0, 0, 0], G, SampleStatus.DUPLICATE),
        (t_last - 0.1, [0, 0, 0], G, SampleStatus.OUT_OF_ORDER),
    ]
    for t, gyro, accel, expected in bad:
        r = comp.process(t, gyro, accel)
        assert r.status is expected
        assert not r.status.accepted and r.quat_xyzw is None
    np.testing.assert_array_equal(comp.filter.quat, q_before)
    assert comp.last_t_s == t_last
    s = comp.stats
    assert (s.nonfinite, s.duplicate, s.out_of_order, s.accepted) == (3, 1, 1, 10)
    assert s.dropped == 5


def test_gap_is_propagated_with_inflated_covariance_and_warned_as_gap():
    rng = np.random.default_rng(1)
    comp = AttitudeCompensator()
    res = still(comp, T0, 400, rng)
    cov_before = res[-1].covariance[2, 2]
    # Swaying at 0.1 rad/s amplitude (2 Hz) about z before a 0.5 s hole: what the
    # platform did inside the hole is unknown to about that rate times the hole.
    t = T0 + 399 * DT
    for k in range(1, 400):
        comp.process(t + k * DT, [0.0, 0.0, 0.1 * np.sin(4.0 * np.pi * k * DT)], G)
    t += 399 * DT
    gap = comp.process(t + 0.5, [0.0, 0.0, 0.0], G)
    assert gap.status is SampleStatus.GAP and gap.dt_s == pytest.approx(0.5)
    assert comp.stats.gaps == 1
    assert gap.covariance[2, 2] > cov_before + (0.05 * 0.5) ** 2
    assert np.isfinite(gap.quat_xyzw).all()
    assert not comp.stationary   # the standstill window restarted
    after = comp.process(t + 0.5 + DT, [0.0, 0.0, 0.0], G)
    assert after.status is SampleStatus.OK


def test_backward_jump_resets_and_restarts_from_the_new_stamp():
    rng = np.random.default_rng(2)
    comp = AttitudeCompensator()
    still(comp, T0, 400, rng)
    for k in range(400):
        comp.process(T0 + (400 + k) * DT, [0.0, 0.0, 0.1], G)   # turn ~5.7°
    assert abs(comp.filter.rpy_rad[2]) > 0.05
    r = comp.process(T0 - 5.0, [0.0, 0.0, 0.0], G)
    assert r.status is SampleStatus.RESET and r.dt_s < -1.0
    assert comp.stats.resets == 1
    assert r.quat_xyzw == pytest.approx([0.0, 0.0, 0.0, 1.0])   # track attitude again
    nxt = comp.process(T0 - 5.0 + DT, [0.0, 0.0, 0.0], G)
    assert nxt.status is SampleStatus.OK


def test_static_alignment_takes_the_window_mean_as_bias():
    rng = np.random.default_rng(3)
    comp = AttitudeCompensator()
    bias = np.array([0.0035, -0.0039, 0.0002])   # ADIS16488 turn-on bias ~0.2 °/s
    res = still(comp, T0, 2000, rng, bias)
    assert res[-1].stationary
    # 2000 still samples of 1.5e-3 rad/s noise: the mean is good to 3.4e-5 rad/s (1σ).
    np.testing.assert_allclose(comp.gyro_bias_rps, bias, atol=1.4e-4)
    assert np.all((comp.gyro_bias_std_rps > 2.5e-5) & (comp.gyro_bias_std_rps < 5e-5))
    # The attitude was held: no drift from integrating the bias before alignment.
    assert np.abs(comp.filter.rpy_rad).max() < 1e-4
    np.testing.assert_allclose(res[-1].gyro_rps, 0.0, atol=8e-3)


# The aids below are 0.6° off an aligned filter that claims 0.02°: the consistency gate
# would refuse them (test_aiding); these two check the delayed-aid arithmetic without it.
NO_GATE = CompensatorConfig(aiding_gate_probability=1.0)


def test_heading_aiding_at_a_past_stamp_corrects_the_present():
    rng = np.random.default_rng(4)
    comp = AttitudeCompensator(NO_GATE)
    still(comp, T0, 800, rng)
    yaw0 = comp.filter.rpy_rad[2]
    t_meas = T0 + 700 * DT
    assert comp.heading_aiding(t_meas, yaw0 + 0.01, 1e-10).status is AidingStatus.USED
    assert comp.filter.rpy_rad[2] == pytest.approx(yaw0 + 0.01, abs=1e-4)
    assert comp.heading_aiding(T0 - 10.0, 0.0, 1e-6).status is AidingStatus.OUTSIDE_HISTORY
    assert comp.heading_aiding(t_meas, math.nan, 1e-6).status is AidingStatus.INVALID
    assert not comp.heading_aiding(t_meas, 0.0, -1.0)
    assert (comp.stats.aiding_used, comp.stats.aiding_rejected) == (1, 3)


def test_attitude_aiding_corrects_what_it_sees_and_keeps_what_it_cannot():
    from vlc_common.core.rotations import quat_from_rotvec, quat_multiply
    rng = np.random.default_rng(5)
    comp = AttitudeCompensator(NO_GATE)
    still(comp, T0, 800, rng)
    rpy0 = comp.filter.rpy_rad.copy()
    t_meas = T0 + 700 * DT
    then = comp.history.at(t_meas)
    # The measurement sees roll and heading (1e-10 rad²) but not pitch (1 rad²): it says
    # roll +0.01, pitch -0.02 (unseen), heading +0.005.
    q_meas = quat_multiply(quat_from_rotvec([0.01, -0.02, 0.005]), then)
    cov = np.diag([1e-10, 1.0, 1e-10])
    assert comp.attitude_aiding(t_meas, q_meas, cov)
    rpy = comp.filter.rpy_rad
    assert rpy[0] - rpy0[0] == pytest.approx(0.01, abs=2e-4)
    assert rpy[2] - rpy0[2] == pytest.approx(0.005, abs=2e-4)
    assert abs(rpy[1] - rpy0[1]) < 2e-4                      # pitch kept: its σ was 0.02°
    # and the filter is now sure of roll and heading
    assert comp.filter.attitude_covariance[0, 0] < 1e-9
    bad = [(T0 - 10.0, q_meas, cov),                          # outside the history
           (t_meas, [math.nan, 0, 0, 1], cov),
           (t_meas, q_meas, np.diag([1.0, -1.0, 1.0])),       # not positive definite
           (t_meas, q_meas, np.array([[1.0, 0.5, 0], [0.0, 1.0, 0], [0, 0, 1.0]])),  # asymmetric
           (t_meas, q_meas, np.eye(2))]
    for args in bad:
        assert not comp.attitude_aiding(*args)
    assert (comp.stats.aiding_used, comp.stats.aiding_rejected) == (1, len(bad))
