"""The attitude filter on the rig's trajectory, vibration (eq. 21) and ADIS16488 model.

Scored against ground truth sample by sample (``vlc_evaluation.benchmarks.compensation.simulate``,
the same path as the node). Seed 1 is the rig's default seed.
"""
import math

import numpy as np
import pytest

from imu_compensator.core.attitude_filter import AttitudeFilterConfig
from vlc_evaluation.benchmarks.compensation import Scenario, departure, score, simulate

DEG = np.pi / 180.0


@pytest.fixture(scope='module')
def departure_80_seed1():
    # Stand 20 s, accelerate to 80 km/h, cruise 40 s, brake to a stop, stand 10 s.
    return simulate(departure(80.0, 20.0, 40.0), seed=1)


def test_heading_error_after_compensation_is_below_0p2_deg(departure_80_seed1):
    s = score(departure_80_seed1)
    # The default vibration is really there: −5.0…+7.5° class heading disturbance.
    assert s['before']['max_abs_deg'][2] > 5.0
    assert s['after']['max_abs_deg'][2] <= 0.2
    assert s['after']['rms_deg'][2] <= 0.08
    assert max(s['after']['max_abs_deg'][:2]) <= 0.1
    # The braking and the final standstill leave no heading error behind.
    tail = departure_80_seed1['t_s'] > departure_80_seed1['t_s'][-1] - 5.0
    assert departure_80_seed1['stationary'][tail].all()
    assert np.abs(departure_80_seed1['after_deg'][tail, 2]).max() <= 0.1


@pytest.mark.parametrize('seed', [1, 2, 3])
def test_heading_error_without_gyro_scale_error_over_seeds(seed):
    # The gyro scale-factor error (1 % 1σ in the model; +2.3 % for seed 3) scales the
    # integrated sway and cannot be seen without an external heading; everything else
    # the filter must remove.
    s = score(simulate(departure(80.0, 20.0, 40.0), seed=seed, ideal_scale_factor=True))
    assert s['after']['max_abs_deg'][2] <= 0.1
    assert max(s['after']['max_abs_deg'][:2]) <= 0.1


def test_gyro_bias_converges_at_standstill():
    run = simulate(Scenario('standstill', 'standstill', duration_s=60.0), seed=2)
    comp = run['compensator']
    true_bias = run['true_gyro_bias_rps']
    assert np.abs(true_bias).max() > 100 * 5e-5 * 0.2   # a real turn-on bias to find
    # 60 s of 1.5e-3 rad/s white noise: the mean is good to ~1e-5 rad/s (2 °/h).
    np.testing.assert_allclose(comp.gyro_bias_rps, true_bias, atol=5e-5)
    assert np.all(comp.gyro_bias_std_rps < 2e-5)
    assert run['stationary'][run['t_s'] > 1.0].all()
    assert np.abs(run['after_deg'][run['scored']]).max() <= 0.05


def test_cold_start_at_speed_converges():
    run = simulate(Scenario('cold', 'cold_start', 80.0, duration_s=120.0, settle_s=60.0),
                   seed=1)
    s = score(run)
    assert not run['stationary'].any()
    assert s['after']['max_abs_deg'][2] <= 0.2
    assert max(s['after']['max_abs_deg'][:2]) <= 0.1


def test_cold_start_at_speed_with_lamp_heading_aiding_converges_in_seconds():
    """The localizer's heading_aiding (σ 0.3°, 5 Hz, 60 ms late): the minute-long cold
    start at speed becomes seconds, and the heading pull stays off while aided.
    """
    run = simulate(Scenario('cold aided', 'cold_start', 80.0, duration_s=40.0, settle_s=8.0,
                            aiding_period_s=0.2, aiding_sigma_deg=0.3), seed=1)
    s = score(run)
    assert s['after']['max_abs_deg'][2] <= 0.2
    plain = score(simulate(Scenario('cold', 'cold_start', 80.0, duration_s=40.0,
                                    settle_s=8.0), seed=1))
    assert plain['after']['max_abs_deg'][2] > 1.0


@pytest.mark.parametrize('seed', [1, 3, 6])
def test_first_tilt_pull_after_a_cold_start_lands_on_the_truth(seed):
    """Cold start at 20 km/h: the turn-on gyro bias (0.2°/s 1σ) tilts the estimate by
    degrees before the first pull (6 s hold + 4 s window). The pull measures the error
    averaged over its window, half a window behind while the bias ramps it, so it must
    credit the bias with the ramp: a pull that took the mean for the current error left
    0.5-0.8° of pitch under a claimed 0.05° (seeds 3 and 6).
    """
    run = simulate(Scenario('cold 20', 'cold_start', 20.0, duration_s=25.0, settle_s=11.0,
                            aiding_period_s=0.2, aiding_sigma_deg=0.3), seed=seed)
    m = run['scored']
    tilt_err = np.abs(run['after_deg'][m, :2])
    before_pull = (run['t_s'] > 9.0) & (run['t_s'] < 10.0)
    # The bias really tilted it, the pull really removed it.
    assert np.abs(run['after_deg'][before_pull, :2]).max() > 0.5
    assert tilt_err.max() <= 0.2
    # ... and the covariance says so (the node adds a 0.05° floor on top).
    sigma = np.hypot(run['sigma_deg'][m, :2], 0.05)
    assert (tilt_err <= 3.0 * sigma).mean() >= 0.997


def test_aiding_estimates_the_gyro_scale_factor():
    """Seed 7's z gyro reads 4.3 % low (a 4σ draw of the 1 % model): it scales the
    integrated ±6° heading sway. Heading aids (σ 0.3°, 5 Hz) make it observable; the
    filter learns it from the first aid on. Unaided, the scale states stay out.
    """
    run = simulate(Scenario('cold aided', 'cold_start', 20.0, duration_s=60.0, settle_s=11.0,
                            aiding_period_s=0.2, aiding_sigma_deg=0.3), seed=7)
    f = run['compensator'].filter
    true_k = run['gyro_scale_error'][2]
    assert true_k < -0.04
    k, k_std = f.gyro_scale_error[2], math.sqrt(f.P[8, 8])
    assert abs(k - true_k) < 0.5 * abs(true_k) and abs(k - true_k) <= 3.0 * k_std
    assert score(run)['after']['max_abs_deg'][2] <= 0.25
    plain = simulate(Scenario('cold', 'cold_start', 20.0, duration_s=20.0), seed=7)
    assert not plain['compensator'].filter.gyro_scale_error.any()
    assert not plain['compensator'].filter.P[6:, 6:].any()


def test_aided_heading_does_not_follow_a_wrong_heading_offset():
    """While lamps aid the heading the heading pull pauses: a track heading offset
    configured 2° wrong then costs nothing, while unaided it becomes the heading error.
    """
    wrong = AttitudeFilterConfig(heading_offset_rad=AttitudeFilterConfig().heading_offset_rad
                                 + 2.0 * DEG)
    aided = simulate(Scenario('cold aided', 'cold_start', 80.0, duration_s=40.0,
                              settle_s=11.0, aiding_period_s=0.2, aiding_sigma_deg=0.3),
                     seed=1, filter_config=wrong)
    assert score(aided)['after']['max_abs_deg'][2] <= 0.25
    plain = simulate(Scenario('cold', 'cold_start', 80.0, duration_s=60.0, settle_s=50.0),
                     seed=1, filter_config=wrong)
    assert score(plain)['after']['rms_deg'][2] > 1.0


def test_unaided_heading_covariance_carries_the_gyro_scale_share():
    # Seed 3's gyro z reads +2.3 % (1.2σ of the filter's 2 % prior): unaided, that scales
    # the integrated sway into heading error the filter cannot see. The published
    # covariance must say so (it claimed ~0.02° while 0.18° off: a quarter of the
    # samples beyond 3σ), though the scale factors only join the estimate at the first
    # aid.
    r = simulate(departure(40.0, 5.0, 10.0), seed=3)
    moving = ~r['stationary']
    z = np.abs(r['after_deg'][moving, 2]) / r['sigma_deg'][moving, 2]
    assert np.abs(r['after_deg'][moving, 2]).max() > 0.1     # the scale share is there
    assert np.mean(z > 3.0) <= 0.01
    assert z.max() < 5.0
