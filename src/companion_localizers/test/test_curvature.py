"""Curvature-array correlation (companion method 4): core, scoring and bag reading.

Synthetic inputs: the yaw rate κ(s(t))·v of a train on a known alignment plus seeded
noise, bias and a vibration-like yaw oscillation; every test scores against the truth.
Runs on the rig's IMU model: vlc_evaluation's test_curvature_benchmark.py.
"""
import math

import numpy as np
import pytest

from companion_localizers.core.curvature import (
    STATUS_AMBIGUOUS,
    STATUS_NO_SIGNAL,
    STATUS_OK,
    STATUS_TOO_SHORT,
    CurvatureArray,
    CurvatureConfig,
    CurvatureLocalizer,
    CurvatureTemplate,
    chainage_sigma,
    match,
)
from vlc_common.core.alignment import Alignment
from vlc_stereo_camera.core.upstream import yaw_rate_on_alignment

DEMO = Alignment.named('curved_demo')


def run_array(cfg, t, w, v):
    array = CurvatureArray(cfg)
    array.add(t, w, v)
    return array


# --- template and array --------------------------------------------------------------

def test_template_is_the_alignment_curvature_at_one_metre():
    cfg = CurvatureConfig()
    template = CurvatureTemplate(DEMO, cfg)
    assert np.all(np.diff(template.chainage_m) == 1.0)
    assert template.chainage_m[0] == -cfg.template_padding_m
    np.testing.assert_array_equal(template.curvature_raw_1pm,
                                  DEMO.evaluate(template.chainage_m).curvature_1pm)
    assert template.has_curvature
    assert not CurvatureTemplate(Alignment.straight(), cfg).has_curvature


def test_array_recovers_the_curvature_per_metre():
    """Noise-free yaw rate κ·v at 20 m/s: κ_i equals the mean curvature of each metre."""
    cfg = CurvatureConfig()
    t, w, s = yaw_rate_on_alignment(DEMO, 150.0, 700.0, 20.0, rate_hz=200.0)
    array = run_array(cfg, t, w, 20.0)
    window = array.window()
    assert array.distance_m == pytest.approx(s[-1] - s[0], abs=1e-6)
    chainage = 150.0 + window.distance_m
    # κ over metre (s−1, s] = (ψ(s) − ψ(s−1))/1 m; the trapezoid of a linear κ is exact
    # up to the 10 cm sample spacing.
    expected = DEMO.evaluate(chainage).heading_rad - DEMO.evaluate(chainage - 1.0).heading_rad
    np.testing.assert_allclose(window.curvature_1pm, expected, atol=2e-7)
    np.testing.assert_allclose(np.diff(window.time_s), 1.0 / 20.0, atol=1e-9)


def test_standstill_learns_the_gyro_bias_and_adds_no_distance():
    cfg = CurvatureConfig()
    array = CurvatureArray(cfg)
    bias = 0.003
    rng = np.random.default_rng(1)
    t = np.arange(0.0, 20.0, 0.01)
    array.add(t, bias + rng.normal(0.0, 1e-3, t.size), 0.0)
    assert array.bias_learnt and array.distance_m == 0.0 and array.samples == 0
    assert array.bias_rps == pytest.approx(bias, abs=2e-4)
    # Moving on a straight: the learnt bias is removed, the heading stays flat.
    t2 = 20.0 + np.arange(0.01, 30.0, 0.01)
    array.add(t2, bias, 10.0)
    assert array.distance_m == pytest.approx(300.0, abs=0.2)
    assert abs(array.heading_rad) < 2e-4 * 30.0
    assert array.window().bias_learnt


def test_array_rejects_bad_samples_and_restarts_after_a_gap():
    cfg = CurvatureConfig(max_gap_s=0.5)
    array = CurvatureArray(cfg)
    assert array.add([0.0, 0.01, 0.01, 0.005], 0.0, 10.0) == 2      # duplicate, backwards
    assert array.add([0.02, 0.03], [math.nan, 0.0], [10.0, math.inf]) == 0
    assert array.add(0.04, 0.0, -1.0) == 0
    assert array.rejected == 5
    array.add(np.arange(0.05, 3.0, 0.01), 0.0, 10.0)
    assert array.distance_m > 29.0
    array.add(5.0, 0.0, 10.0)                    # 2 s gap: restart
    assert array.restarts == 1 and array.distance_m == 0.0 and array.samples == 0


# --- matching ----------------------------------------------------------------------------

@pytest.mark.parametrize('speed_error', [-0.10, 0.0, 0.15])
def test_match_finds_the_chainage_and_absorbs_the_speed_error(speed_error):
    """Noise, bias, a ±5° yaw oscillation and a speed scale error: chainage within 3 m,
    ratio = 1/(1 + error).
    """
    cfg = CurvatureConfig()
    v = 20.0
    t, w, s = yaw_rate_on_alignment(DEMO, 100.0, 1000.0, v, seed=2, bias_rps=0.002, noise_rps=0.005,
                        vibration_deg=5.0)
    array = run_array(cfg, t, w, v * (1.0 + speed_error))
    result = match(CurvatureTemplate(DEMO, cfg), array)
    assert result.status == STATUS_OK, result
    assert result.chainage_m == pytest.approx(s[-1], abs=3.0)
    assert result.ratio == pytest.approx(1.0 / (1.0 + speed_error), abs=0.01)
    assert result.correlation > 0.98 and 0.0 < result.confidence <= 1.0
    assert result.cpu_s > 0.0


def test_straight_track_is_refused_as_no_curvature_signal():
    cfg = CurvatureConfig()
    t, w, _ = yaw_rate_on_alignment(DEMO, 560.0, 300.0, 20.0)           # inside the 300 m straight
    t2, w2, _ = yaw_rate_on_alignment(Alignment.straight(), 0.0, 1200.0, 20.0, seed=3,
                                      bias_rps=0.003,
                          noise_rps=0.005, vibration_deg=5.0)
    for alignment, (tt, ww) in ((Alignment.straight(), (t2, w2)), (DEMO, (t2, w2))):
        result = match(CurvatureTemplate(alignment, cfg), run_array(cfg, tt, ww, 20.0))
        assert result.status == STATUS_NO_SIGNAL
        assert math.isnan(result.chainage_m) and result.confidence == 0.0


def test_short_array_is_too_short():
    cfg = CurvatureConfig()
    t, w, _ = yaw_rate_on_alignment(DEMO, 150.0, 400.0, 20.0)     # 400 m − 2·3σ margins < 300 m
    result = match(CurvatureTemplate(DEMO, cfg), run_array(cfg, t, w, 20.0))
    assert result.status == STATUS_TOO_SHORT and math.isnan(result.chainage_m)


def test_two_identical_curves_are_ambiguous():
    """A line with the same curve twice: a window that holds only one of them fits both
    places equally — refused, no chainage.
    """
    curve = [('clothoid', 60.0, 500.0), ('arc', 150.0, 500.0), ('clothoid', 60.0, math.inf)]
    twins = Alignment([('straight', 600.0)] + curve + [('straight', 700.0)] + curve
                      + [('straight', 600.0)], name='twins')
    cfg = CurvatureConfig()
    t, w, s = yaw_rate_on_alignment(twins, 450.0, 850.0, 20.0, seed=4, noise_rps=0.002)
    result = match(CurvatureTemplate(twins, cfg), run_array(cfg, t, w, 20.0))
    assert result.status == STATUS_AMBIGUOUS, result
    assert math.isnan(result.chainage_m) and result.confidence == 0.0
    # Both curves in a 1300 m window (625 … 1925 m): unique again.
    long_cfg = CurvatureConfig(window_m=1300.0)
    t, w, s = yaw_rate_on_alignment(twins, 450.0, 1550.0, 20.0, seed=4, noise_rps=0.002)
    result = match(CurvatureTemplate(twins, long_cfg), run_array(long_cfg, t, w, 20.0))
    assert result.status == STATUS_OK and result.chainage_m == pytest.approx(s[-1], abs=3.0)


def test_ratio_search_is_the_issue_grid():
    ratios = CurvatureConfig().ratios
    assert ratios[0] == 0.0 and ratios[-1] == pytest.approx(1.8) and len(ratios) == 181
    np.testing.assert_allclose(np.diff(ratios), 0.01)


@pytest.mark.parametrize('kwargs, words', [
    ({'spacing_m': 0.0}, 'spacing_m'),
    ({'ratio_max': 0.0}, 'ratio_max'),
    ({'min_window_m': 700.0}, 'min_window_m'),
    ({'min_correlation': 2.0}, 'min_correlation'),
    ({'max_smoothing_sigma_m': 10.0}, 'max_smoothing_sigma_m'),
    ({'gyro_bias_sigma_rps': math.nan}, 'gyro_bias_sigma_rps'),
])
def test_invalid_configuration(kwargs, words):
    with pytest.raises(ValueError, match=words):
        CurvatureConfig(**kwargs)


# --- the localizer (what the node runs) ---------------------------------------------------

def test_localizer_waits_for_speed_interpolates_and_matches_periodically():
    loc = CurvatureLocalizer(DEMO, CurvatureConfig(), match_period_s=1.0, speed_timeout_s=0.5)
    assert loc.add_imu(0.00, 0.0) == [] and loc.add_imu(0.01, 0.0) == []
    assert loc.array.last_time_s is None                  # waiting for a speed
    loc.add_speed(0.0, 10.0)
    assert loc.array.last_time_s == 0.0
    loc.add_speed(0.02, 12.0)
    assert loc.array.last_time_s == 0.01
    # Interpolated 11 m/s over (0, 0.01]: distance = trapezoid of 10 and 11.
    assert loc.array.distance_m == pytest.approx(0.105)
    # No more speed: samples up to 0.5 s after the last speed (0.02 s) are processed with
    # it held once they are 0.5 s old; later ones are dropped.
    for k in range(2, 131):
        loc.add_imu(0.01 * k, 0.0)
    assert loc.array.last_time_s == pytest.approx(0.52)
    assert loc.imu_without_speed == 28                    # 0.53 … 0.80 s
    assert loc.add_speed(0.01, 5.0) == [] and loc.speed_rejected == 1       # out of order
    assert loc.add_speed(1.0, math.nan) == [] and loc.speed_rejected == 2
    assert loc.add_imu(0.5, 0.0) == [] and loc.imu_rejected == 1            # out of order
    # Matches every match_period_s of IMU time.
    loc2 = CurvatureLocalizer(DEMO, CurvatureConfig(), match_period_s=1.0)
    times = []
    for k in range(500):
        t = 0.01 * k
        out = loc2.add_speed(t, 20.0) + loc2.add_imu(t, 0.0)
        times += [m.t_s for m in out]
    np.testing.assert_allclose(times, [1.0, 2.0, 3.0, 4.0], atol=1e-9)
    assert loc2.last.match.status == STATUS_TOO_SHORT


def test_localizer_pose_is_on_the_alignment():
    loc = CurvatureLocalizer(DEMO, CurvatureConfig())
    position, yaw = loc.pose(380.0)
    p = DEMO.evaluate(380.0)
    np.testing.assert_allclose(position, [p.x_m[0], p.y_m[0], 0.0])
    assert yaw == pytest.approx(p.heading_rad[0])


# --- the whole chain on the rig's models, scored --------------------------------------------


def test_chainage_sigma_grows_with_spread_and_short_windows():
    """The 1σ each accepted match carries (train_localizer's aid variance): floor for
    a full window, larger for a short window or a spread; NaN for a refused match.
    """
    cfg = CurvatureConfig()
    assert chainage_sigma(0.0, cfg.window_m, cfg) == pytest.approx(cfg.chainage_sigma_floor_m)
    assert chainage_sigma(0.0, cfg.min_window_m, cfg) == pytest.approx(
        math.hypot(cfg.chainage_sigma_floor_m, cfg.short_window_sigma_m))
    assert chainage_sigma(3.0, cfg.window_m, cfg) == pytest.approx(
        math.hypot(cfg.chainage_sigma_floor_m, 3.0))
    short = yaw_rate_on_alignment(DEMO, 150.0, 400.0, 20.0)
    refused = match(CurvatureTemplate(DEMO, cfg), run_array(cfg, *short[:2], 20.0))
    assert math.isnan(refused.chainage_sigma_m)
