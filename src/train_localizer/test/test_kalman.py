"""The along-track Kalman filter against analytic trajectories."""
import math

import numpy as np
import pytest

from train_localizer.core.kalman import (
    H_SPEED,
    KalmanConfig,
    initial_state,
    predict,
    process_noise,
    update,
)


def test_prediction_integrates_constant_acceleration_exactly():
    cfg = KalmanConfig()
    state = initial_state(10.0, 1e-4, cfg, speed_mps=5.0, speed_var_m2s2=1e-4)
    state.x[2] = 0.05                                   # known bias
    accel_true = 0.8
    for _ in range(400):
        state = predict(state, 0.0025, accel_true + 0.05, cfg)
    t = 1.0
    assert state.x[0] == pytest.approx(10.0 + 5.0 * t + 0.5 * accel_true * t * t, abs=1e-9)
    assert state.x[1] == pytest.approx(5.0 + accel_true * t, abs=1e-12)


def test_process_noise_is_symmetric_positive_semidefinite_and_additive():
    cfg = KalmanConfig()
    for dt in (1e-4, 0.0025, 0.1, 2.0):
        Q = process_noise(dt, cfg, accel_var=0.5)
        np.testing.assert_allclose(Q, Q.T)
        assert np.linalg.eigvalsh(Q).min() > -1e-15
    # Two half steps of a pure random walk give the variance of one full step.
    cfg0 = KalmanConfig(bias_random_walk_mps3_rthz=0.0)
    s = initial_state(0.0, 0.0, cfg0, speed_var_m2s2=0.0)
    s.P[:] = 0.0
    one = predict(s, 0.2, 0.0, cfg0)
    two = predict(predict(s, 0.1, 0.0, cfg0), 0.1, 0.0, cfg0)
    np.testing.assert_allclose(one.P, two.P, rtol=1e-9, atol=1e-18)


def _run_analytic(rng, outage=None, fix_sigma=0.02):
    """s(t) = 3 + 12 t + 0.4 sin(1.3 t); IMU 400 Hz with bias; fixes 30 Hz."""
    cfg = KalmanConfig()
    bias = 0.12
    imu_dt = 1.0 / 400.0
    state = initial_state(3.0 + rng.normal(0, fix_sigma), fix_sigma ** 2, cfg)

    def truth(t):
        return (3.0 + 12.0 * t + 0.4 * math.sin(1.3 * t),
                12.0 + 0.52 * math.cos(1.3 * t), -0.676 * math.sin(1.3 * t))

    errors, sigmas, times, speed_err = [], [], [], []
    next_fix = 1.0 / 30.0
    t = 0.0
    for k in range(1, int(20.0 / imu_dt) + 1):
        t_new = k * imu_dt
        a_mid = truth(t + 0.5 * imu_dt)[2]
        meas = a_mid + bias + rng.normal(0, 5e-4 * math.sqrt(400.0))
        state = predict(state, imu_dt, meas, cfg)
        t = t_new
        if t >= next_fix - 1e-12:
            next_fix += 1.0 / 30.0
            if outage is None or not (outage[0] <= t < outage[1]):
                state = update(state, truth(t)[0] + rng.normal(0, fix_sigma), fix_sigma ** 2)
        errors.append(state.x[0] - truth(t)[0])
        sigmas.append(math.sqrt(state.P[0, 0]))
        speed_err.append(state.x[1] - truth(t)[1])
        times.append(t)
    return (np.array(times), np.array(errors), np.array(sigmas), np.array(speed_err),
            state, bias)


def test_filter_tracks_an_analytic_trajectory_within_its_covariance():
    times, err, sig, speed_err, state, bias = _run_analytic(np.random.default_rng(5))
    settled = times > 2.0
    assert np.max(np.abs(err[settled])) < 0.02
    assert np.mean(np.abs(err[settled]) <= 3.0 * sig[settled]) >= 0.997
    assert np.max(np.abs(speed_err[settled])) < 0.05
    assert state.x[2] == pytest.approx(bias, abs=0.03)


def test_position_stays_bounded_and_covered_during_a_lamp_outage():
    times, err, sig, _, _, _ = _run_analytic(np.random.default_rng(6), outage=(8.0, 11.0))
    during = (times >= 8.0) & (times < 11.0)
    assert np.max(np.abs(err[during])) < 0.3           # IMU-only for 3 s with a 0.12 m/s² bias
    assert np.all(np.abs(err[during]) <= 3.0 * sig[during])
    assert sig[during][-1] > 3.0 * sig[during][0]      # the covariance grows honestly
    after = times > 12.0
    assert np.max(np.abs(err[after])) < 0.02


def test_zero_velocity_update_pins_the_speed():
    cfg = KalmanConfig()
    state = initial_state(5.0, 0.01, cfg, speed_mps=0.4, speed_var_m2s2=1.0)
    state = update(state, 0.0, 1e-4, H_SPEED)
    assert abs(state.x[1]) < 0.001
    assert state.P[1, 1] < 1.1e-4
    assert np.linalg.eigvalsh(state.P).min() > 0.0
