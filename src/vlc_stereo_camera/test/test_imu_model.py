"""ADIS16488 error model and Allan deviation (core, no ROS)."""
import dataclasses

import numpy as np
import pytest

from vlc_stereo_camera.core import allan
from vlc_stereo_camera.core.imu_model import (
    DEG,
    GRAVITY_MPS2,
    MAX_RATE_HZ,
    Adis16488Model,
    Adis16488Params,
    ImuSampler,
    bias_bank_sigma,
    characterise,
    lever_arm_specific_force,
    true_imu_signals,
)
from vlc_stereo_camera.core.trajectory import MotionProfile, Trajectory, Vibration, VibrationConfig

DATASHEET = Adis16488Params()
REST_F = np.array([0.0, 0.0, GRAVITY_MPS2])


def _rest(model, n):
    return model.step(np.zeros((n, 3)), np.broadcast_to(REST_F, (n, 3)))


def _white_only(**extra):
    """Only white noise (plus whatever ``extra`` switches back on)."""
    return dataclasses.replace(DATASHEET.ideal(),
                               gyro_arw_rad_s_rthz=DATASHEET.gyro_arw_rad_s_rthz,
                               accel_vrw_mps2_rthz=DATASHEET.accel_vrw_mps2_rthz, **extra)


# --- Allan deviation -------------------------------------------------------------------

def test_cluster_sizes_log_spaced_with_decades():
    m = allan.cluster_sizes(100_000, points_per_decade=10, max_fraction=0.1)
    assert m[0] == 1 and m[-1] == 10_000
    assert {10, 100, 1000, 10_000} <= set(m.tolist())
    assert np.all(np.diff(m) > 0)
    with pytest.raises(ValueError):
        allan.cluster_sizes(5)


def test_overlapping_adev_matches_brute_force():
    rng = np.random.default_rng(3)
    y = rng.normal(size=(400, 2)) + np.cumsum(rng.normal(size=(400, 2)), axis=0) * 0.05
    rate = 50.0
    m = np.array([1, 2, 5, 13, 40, 100])
    res = allan.overlapping_adev(y, rate, m)
    for i, mi in enumerate(m):
        # Averages of every m-sample window, then half the mean square of the
        # difference of windows m apart: the textbook overlapping estimator.
        means = np.array([y[k:k + mi].mean(axis=0) for k in range(len(y) - mi + 1)])
        d = means[mi:] - means[:-mi]
        expected = np.sqrt(0.5 * np.mean(d ** 2, axis=0))
        np.testing.assert_allclose(res.adev[i], expected, rtol=1e-9)
    np.testing.assert_allclose(res.tau_s, m / rate)
    single = allan.overlapping_adev(y[:, 1], rate, m)
    np.testing.assert_allclose(single.adev, res.adev[:, 1], rtol=1e-12)


def test_overlapping_adev_of_white_noise_is_density_over_sqrt_tau():
    rate, density = 200.0, 0.03
    y = np.random.default_rng(4).normal(size=400_000) * density * np.sqrt(rate) + 7.0
    res = allan.overlapping_adev(y, rate)
    sel = res.tau_s <= 10.0
    np.testing.assert_allclose(res.adev[sel], allan.white_adev(res.tau_s[sel], density),
                               rtol=0.08)
    assert allan.fit_white_density(res.tau_s, res.adev, 0.005, 1.0) == \
        pytest.approx(density, rel=0.02)


def test_gauss_markov_adev_peak_and_small_tau_limit():
    x = np.geomspace(0.1, 10.0, 20001)
    adev = allan.gauss_markov_adev(x, 1.0, 1.0)
    assert x[np.argmax(adev)] == pytest.approx(allan.GM_PEAK_TAU_RATIO, rel=1e-3)
    assert adev.max() == pytest.approx(allan.GM_PEAK_ADEV_RATIO, rel=1e-4)
    # τ << T_c: rate random walk of the driving noise, σ² = 2σ²_GM·τ/(3 T_c); and the
    # series used there joins the closed form smoothly.
    tiny = np.array([1e-9, 1e-6])
    np.testing.assert_allclose(allan.gauss_markov_adev(tiny, 2.0, 1.0) ** 2,
                               2 * 4.0 * tiny / 3.0, rtol=1e-5)
    edge = allan.gauss_markov_adev(np.array([0.01 - 1e-12, 0.01 + 1e-12]), 1.0, 1.0)
    assert edge[0] == pytest.approx(edge[1], rel=1e-7)


def test_single_process_bank_uses_peak_relation():
    assert bias_bank_sigma(1.0, [50.0]) == pytest.approx(1.0 / allan.GM_PEAK_ADEV_RATIO,
                                                         rel=1e-3)


def test_bank_floor_is_flat_at_the_datasheet_value():
    taus = DATASHEET.gyro_bias_corr_times_s
    sigma = bias_bank_sigma(1.0, taus)
    grid = np.geomspace(30.0, 5000.0, 50)
    bank = np.sqrt(sum(allan.gauss_markov_adev(grid, sigma, t) ** 2 for t in taus))
    assert np.all(np.abs(bank - 1.0) < 0.06)


# --- the simulated sensor read back through its Allan deviation ------------------------

@pytest.fixture(scope='module')
def six_hours_at_rest():
    """6 h at 100 Hz (densities are rate independent): ≈ 7 s."""
    return characterise(hours=6.0, rate_hz=100.0, seed=11)


def test_angle_random_walk_from_allan(six_hours_at_rest):
    r = six_hours_at_rest
    arw = DATASHEET.gyro_arw_rad_s_rthz
    np.testing.assert_allclose(r['arw_1s'], arw, rtol=0.10)
    np.testing.assert_allclose(r['arw_fit'], arw, rtol=0.10)


def test_velocity_random_walk_from_allan(six_hours_at_rest):
    # At τ = 1 s the accelerometer curve already sits on its 0.1 mg floor (the
    # 0.029 m/s/√h line crosses it at 0.24 s), so VRW is read off the −1/2 slope fit.
    np.testing.assert_allclose(six_hours_at_rest['vrw_fit'], DATASHEET.accel_vrw_mps2_rthz,
                               rtol=0.10)


def test_bias_instability_floors(six_hours_at_rest):
    r = six_hours_at_rest
    gyro = DATASHEET.gyro_bias_instability_rad_s
    accel = DATASHEET.accel_bias_instability_mps2
    assert np.all((r['gyro_floor'] > gyro / 2) & (r['gyro_floor'] < gyro * 2))
    assert np.all((r['accel_floor'] > accel / 2) & (r['accel_floor'] < accel * 2))
    # The floor is a plateau, not a dip: the gyro curve reaches it after ~100 s.
    assert np.all(r['gyro_floor_tau_s'] >= 100.0)


def test_simulated_allan_curve_follows_the_analytic_model(six_hours_at_rest):
    r = six_hours_at_rest
    model, res = r['model'], r['allan']
    p = model.params
    sel = res.tau_s <= 200.0
    tau = res.tau_s[sel]
    gyro = np.sqrt(allan.white_adev(tau, p.gyro_arw_rad_s_rthz) ** 2 + sum(
        allan.gauss_markov_adev(tau, model.gyro_bank_sigma_rad_s, t) ** 2
        for t in p.gyro_bias_corr_times_s))
    accel = np.sqrt(allan.white_adev(tau, p.accel_vrw_mps2_rthz) ** 2 + sum(
        allan.gauss_markov_adev(tau, model.accel_bank_sigma_mps2, t) ** 2
        for t in p.accel_bias_corr_times_s))
    np.testing.assert_allclose(res.adev[sel, :3], np.repeat(gyro[:, None], 3, 1), rtol=0.15)
    np.testing.assert_allclose(res.adev[sel, 3:], np.repeat(accel[:, None], 3, 1), rtol=0.15)


def test_at_rest_averages_to_gravity_and_zero_rate(six_hours_at_rest):
    r = six_hours_at_rest
    model, mean = r['model'], r['mean']
    # Datasheet bounds: 4σ of turn-on bias + scale factor/misalignment on gravity.
    gyro_bound = 4 * DATASHEET.gyro_turn_on_bias_sigma_rad_s
    accel_bound = 4 * np.hypot(DATASHEET.accel_turn_on_bias_sigma_mps2,
                               (DATASHEET.accel_scale_factor_sigma
                                + DATASHEET.accel_misalignment_sigma_rad) * GRAVITY_MPS2)
    assert np.all(np.abs(mean[:3]) < gyro_bound)
    assert np.all(np.abs(mean[3:] - REST_F) < accel_bound)
    # Tighter: what remains after the model's own constants is the in-run bias, whose
    # stationary σ is √K·σ_process.
    bank_g = model.gyro_bank_sigma_rad_s * np.sqrt(len(DATASHEET.gyro_bias_corr_times_s))
    bank_a = model.accel_bank_sigma_mps2 * np.sqrt(len(DATASHEET.accel_bias_corr_times_s))
    assert np.all(np.abs(mean[:3] - model.gyro_turn_on_bias_rad_s) < 4 * bank_g)
    expected_f = model.accel_matrix @ REST_F + model.accel_turn_on_bias_mps2
    assert np.all(np.abs(mean[3:] - expected_f) < 4 * bank_a)


def test_white_noise_only_sensor_at_rest_is_unbiased():
    model = Adis16488Model(400.0, 5, _white_only())
    omega, f = _rest(model, 40_000)
    n = len(omega)
    assert np.all(np.abs(omega.mean(0)) < 4 * model.white_sigma[0] / np.sqrt(n))
    assert np.all(np.abs(f.mean(0) - REST_F) < 4 * model.white_sigma[3] / np.sqrt(n))
    assert f.mean(0)[2] == pytest.approx(9.80665, abs=1e-3)


# --- discretisation, determinism, parameters -------------------------------------------

def test_gauss_markov_discretisation_is_exact():
    rate, tau = 100.0, 0.5
    params = dataclasses.replace(DATASHEET.ideal(), gyro_bias_instability_rad_s=1.0,
                                 gyro_bias_corr_times_s=(tau,))
    model = Adis16488Model(rate, 2, params)
    assert model._phi[0] == np.exp(-1.0 / (rate * tau))
    omega, _ = _rest(model, 400_000)
    b = omega[:, 0]
    sigma = model.gyro_bank_sigma_rad_s
    # 400 000 samples ≈ 8000 correlation times: the sample statistics are good to ~3 %.
    assert b.std() == pytest.approx(sigma, rel=0.05)
    lag = int(rate * tau)
    rho = np.corrcoef(b[:-lag], b[lag:])[0, 1]
    assert rho == pytest.approx(np.exp(-1.0), abs=0.04)
    rho1 = np.corrcoef(b[:-1], b[1:])[0, 1]
    assert rho1 == pytest.approx(np.exp(-1.0 / (rate * tau)), abs=0.002)


def test_same_seed_same_samples_regardless_of_batching():
    truth_w = np.random.default_rng(0).normal(size=(1000, 3))
    truth_f = np.random.default_rng(1).normal(size=(1000, 3)) + REST_F
    a = Adis16488Model(400.0, 42).step(truth_w, truth_f)
    m = Adis16488Model(400.0, 42)
    parts = [m.step(truth_w[s], truth_f[s])
             for s in (slice(0, 1), slice(1, 300), slice(300, 300), slice(300, 340),
                       slice(340, 1000))]
    np.testing.assert_array_equal(a[0], np.concatenate([p[0] for p in parts]))
    np.testing.assert_array_equal(a[1], np.concatenate([p[1] for p in parts]))
    # The node's small batches (a loop over samples) against one long lfilter run.
    m4 = Adis16488Model(400.0, 42)
    small = [m4.step(truth_w[i:i + 4], truth_f[i:i + 4]) for i in range(0, 1000, 4)]
    np.testing.assert_array_equal(a[0], np.concatenate([p[0] for p in small]))
    np.testing.assert_array_equal(a[1], np.concatenate([p[1] for p in small]))
    c = Adis16488Model(400.0, 43).step(truth_w, truth_f)
    assert not np.allclose(a[0], c[0])


def test_scale_factor_misalignment_and_turn_on_bias_are_applied():
    params = dataclasses.replace(DATASHEET, gyro_arw_rad_s_rthz=0.0, accel_vrw_mps2_rthz=0.0,
                                 gyro_bias_instability_rad_s=0.0,
                                 accel_bias_instability_mps2=0.0)
    model = Adis16488Model(100.0, 9, params)
    w = np.random.default_rng(2).normal(size=(50, 3))
    f = np.random.default_rng(3).normal(size=(50, 3)) * 5.0
    om, fm = model.step(w, f)
    np.testing.assert_allclose(om, w @ model.gyro_matrix.T + model.gyro_turn_on_bias_rad_s,
                               atol=1e-15)
    np.testing.assert_allclose(fm, f @ model.accel_matrix.T + model.accel_turn_on_bias_mps2,
                               atol=1e-14)
    assert not np.allclose(model.gyro_matrix, np.eye(3))
    assert np.all(np.abs(np.diag(model.gyro_matrix) - 1) < 5 * params.gyro_scale_factor_sigma)


def test_outputs_saturate_at_the_dynamic_range():
    model = Adis16488Model(100.0, 1, DATASHEET.ideal())
    om, f = model.step([[0.0, 5.0, -20.0]], [[0.0, 0.0, -300.0]])
    assert om[0, 1] == 5.0 and om[0, 2] == pytest.approx(-450 * DEG)
    assert f[0, 2] == pytest.approx(-18 * GRAVITY_MPS2)


@pytest.mark.parametrize('rate', [0.0, -5.0, MAX_RATE_HZ + 1, float('nan')])
def test_invalid_rate_is_rejected(rate):
    with pytest.raises(ValueError, match='rate_hz'):
        Adis16488Model(rate, 0)


def test_invalid_params_are_rejected():
    with pytest.raises(ValueError, match='gyro_arw'):
        Adis16488Params(gyro_arw_rad_s_rthz=-1.0)
    with pytest.raises(ValueError, match='accel_bias_corr_times_s'):
        Adis16488Params(accel_bias_corr_times_s=())
    with pytest.raises(ValueError, match='gyro_bias_corr_times_s'):
        Adis16488Params(gyro_bias_corr_times_s=(10.0, 0.0))
    with pytest.raises(ValueError, match='rows'):
        Adis16488Model(100.0, 0).step(np.zeros((3, 3)), np.zeros((2, 3)))


def test_datasheet_units_convert_to_the_defaults():
    p = Adis16488Params.from_datasheet_units(
        gyro_arw_deg_rthr=0.26, gyro_bias_instability_deg_hr=5.1, accel_vrw_mps_rthr=0.029,
        accel_bias_instability_mg=0.1, gyro_bias_corr_times_s=[10, 100, 1000, 10000],
        accel_bias_corr_times_s=[1, 10, 100, 1000, 10000], gyro_turn_on_bias_sigma_dps=0.2,
        accel_turn_on_bias_sigma_mg=16.0, gyro_scale_factor_sigma=0.01,
        accel_scale_factor_sigma=0.005, gyro_misalignment_sigma_deg=0.05,
        accel_misalignment_sigma_deg=0.035, gyro_range_dps=450.0, accel_range_g=18.0)
    for field in dataclasses.fields(p):
        assert getattr(p, field.name) == pytest.approx(getattr(DATASHEET, field.name),
                                                       rel=1e-12), field.name
    assert DATASHEET.gyro_arw_rad_s_rthz == pytest.approx(0.26 * np.pi / 180 / 60)
    assert DATASHEET.accel_vrw_mps2_rthz == pytest.approx(0.029 / 60)


def test_white_variance_is_density_squared_times_rate():
    model = Adis16488Model(400.0, 0)
    assert model.gyro_white_variance == pytest.approx(DATASHEET.gyro_arw_rad_s_rthz ** 2 * 400)
    assert model.accel_white_variance == pytest.approx(DATASHEET.accel_vrw_mps2_rthz ** 2 * 400)


# --- moving platform --------------------------------------------------------------------

def _trajectory(seed=3):
    profile = MotionProfile(kind='accel_cruise_brake', speed_mps=80 / 3.6, dwell_s=1.0,
                            cruise_s=3.0, accel_mps2=1.2, brake_mps2=1.1)
    return Trajectory(profile, Vibration(VibrationConfig(), seed=seed))


def test_moving_trajectory_reproduced_within_noise():
    rate = 400.0
    params = _white_only(gyro_bias_instability_rad_s=DATASHEET.gyro_bias_instability_rad_s,
                         accel_bias_instability_mps2=DATASHEET.accel_bias_instability_mps2,
                         gyro_turn_on_bias_sigma_rad_s=DATASHEET.gyro_turn_on_bias_sigma_rad_s,
                         accel_turn_on_bias_sigma_mps2=DATASHEET.accel_turn_on_bias_sigma_mps2)
    sampler = ImuSampler(_trajectory(), Adis16488Model(rate, 8, params))
    batch = sampler.next(int(30 * rate))
    assert np.all(batch.valid)
    np.testing.assert_allclose(batch.t_s, np.arange(len(batch.t_s)) / rate)
    # The motion is well above the noise: speed changes and vibration.
    assert np.ptp(batch.f_true[:, 0]) > 1.5 and np.ptp(batch.omega_true[:, 2]) > 0.05
    model = sampler.model
    err_w = batch.omega - batch.omega_true - model.gyro_turn_on_bias_rad_s
    err_f = batch.f - batch.f_true - model.accel_turn_on_bias_mps2
    np.testing.assert_allclose(err_w.std(0), model.white_sigma[:3], rtol=0.05)
    np.testing.assert_allclose(err_f.std(0), model.white_sigma[3:], rtol=0.05)
    bank_g = 5 * model.gyro_bank_sigma_rad_s * 2
    bank_a = 5 * model.accel_bank_sigma_mps2 * np.sqrt(5)
    assert np.all(np.abs(err_w.mean(0)) < bank_g)
    assert np.all(np.abs(err_f.mean(0)) < bank_a)


def test_lever_arm_matches_second_derivative_of_the_offset_point():
    traj = _trajectory(seed=5)
    r = np.array([1.5, -0.4, 0.8])
    t = np.array([0.5, 10.0, 21.0, 30.0, 45.0])  # dwell, accelerate, cruise, brake, stand
    _, f_r = true_imu_signals(traj, t, r)
    h = 1e-3

    def point(tt):
        s = traj.sample(tt)
        return s.position_m + np.einsum('nij,j->ni', s.R_map_base, r)

    accel = (point(t + h) - 2 * point(t) + point(t - h)) / h ** 2
    R = traj.sample(t).R_map_base
    expected = np.einsum('nji,nj->ni', R, accel - np.array([0.0, 0.0, -GRAVITY_MPS2]))
    np.testing.assert_allclose(f_r, expected, atol=2e-3)
    # The lever-arm terms are not negligible here, so the comparison means something.
    _, f_0 = true_imu_signals(traj, t)
    assert np.max(np.abs(f_r - f_0)) > 0.02


def test_lever_arm_terms():
    omega = np.array([[0.0, 0.0, 2.0]])
    alpha = np.array([[0.0, 0.0, 3.0]])
    f = lever_arm_specific_force(np.zeros((1, 3)), omega, alpha, [1.0, 0.0, 0.0])
    # centripetal −ω²r towards the axis, tangential α×r
    np.testing.assert_allclose(f, [[-4.0, 3.0, 0.0]])


def test_non_finite_truth_is_flagged_and_does_not_shift_later_samples():
    class Broken:
        def __init__(self, inner, bad_t):
            self.inner, self.bad_t = inner, bad_t

        def sample(self, t):
            s = self.inner.sample(t)
            bad = np.isin(np.round(t * 100), self.bad_t)
            s.angular_velocity_body_rps[bad] = np.nan
            return s

    good = ImuSampler(_trajectory(), Adis16488Model(100.0, 4)).next(50)
    broken = ImuSampler(Broken(_trajectory(), [10, 11]), Adis16488Model(100.0, 4)).next(50)
    assert broken.valid.tolist() == [i not in (10, 11) for i in range(50)]
    np.testing.assert_array_equal(good.omega[12:], broken.omega[12:])
    assert np.all(np.isfinite(broken.omega))
