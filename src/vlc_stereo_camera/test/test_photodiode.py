"""Photodiode model (core/photodiode.py): Lambertian LOS channel, noise, per-lamp samples."""
import math

import numpy as np
import pytest

from vlc_common.core.lamp_map import Lamp, LampMap, straight_tunnel_map
from vlc_common.core.optical_channel import (
    BOLTZMANN_J_PER_K,
    ELECTRON_CHARGE_C,
    PhotodiodeConfig,
    channel_gain,
    noise_variance_a2,
    photodiode_pose,
)
from vlc_stereo_camera.core.photodiode import Photodiode
from vlc_stereo_camera.core.trajectory import MotionProfile, Trajectory, Vibration, VibrationConfig

STILL = Vibration(VibrationConfig(enabled=False))


def _one_lamp_gain(pd_pos, pd_normal, lamp_pos, lamp_normal, cfg):
    gain, d, cphi, cpsi = channel_gain(np.array([pd_pos], float), np.array([pd_normal], float),
                                       np.array([lamp_pos], float),
                                       np.array([lamp_normal], float), cfg)
    return gain[0, 0], d[0, 0], cphi[0, 0], cpsi[0, 0]


def test_lambertian_order_of_the_60_degree_semi_angle_is_one():
    assert PhotodiodeConfig().order_m == pytest.approx(1.0)
    # m = -ln 2 / ln cos(semi-angle): 30 deg gives 4.82.
    assert PhotodiodeConfig(lamp_half_power_angle_deg=30.0).order_m == pytest.approx(
        -math.log(2.0) / math.log(math.cos(math.radians(30.0))))


def test_on_axis_gain_is_the_textbook_formula_and_falls_with_distance_squared():
    cfg = PhotodiodeConfig()
    g = cfg.refractive_index ** 2 / math.sin(math.radians(cfg.fov_half_angle_deg)) ** 2
    for d in (2.0, 4.0, 8.0):
        # Lamp at the origin facing +y, PD on its axis facing the lamp: phi = psi = 0.
        h, dist, cphi, cpsi = _one_lamp_gain([0.0, d, 0.0], [0.0, -1.0, 0.0], [0.0, 0.0, 0.0],
                                             [0.0, 1.0, 0.0], cfg)
        expected = (cfg.order_m + 1.0) * cfg.area_m2 / (2.0 * math.pi * d * d) * g
        assert dist == pytest.approx(d)
        assert (cphi, cpsi) == (pytest.approx(1.0), pytest.approx(1.0))
        assert h == pytest.approx(expected, rel=1e-12)


def test_gain_follows_cos_phi_power_m_and_cos_psi():
    cfg = PhotodiodeConfig(lamp_half_power_angle_deg=30.0)        # m = 4.82
    phi = math.radians(35.0)
    pos = [0.0, 3.0 * math.cos(phi), 3.0 * math.sin(phi)]
    toward_lamp = -np.asarray(pos) / 3.0
    h_axis, *_ = _one_lamp_gain(pos, toward_lamp, [0, 0, 0], [0, 1, 0], cfg)
    # Same distance, on the lamp axis: only cos^m phi differs.
    h_on, *_ = _one_lamp_gain([0, 3.0, 0], [0, -1, 0], [0, 0, 0], [0, 1, 0], cfg)
    assert h_axis / h_on == pytest.approx(math.cos(phi) ** cfg.order_m, rel=1e-12)
    # Turning the PD by psi multiplies by cos psi (inside the field of view).
    psi = math.radians(50.0)
    turned = [0.0, -math.cos(psi), math.sin(psi)]
    h_turned, _, _, cpsi = _one_lamp_gain([0, 3.0, 0], turned, [0, 0, 0], [0, 1, 0], cfg)
    assert cpsi == pytest.approx(math.cos(psi))
    assert h_turned / h_on == pytest.approx(math.cos(psi), rel=1e-12)


def test_no_power_outside_the_field_of_view_or_behind_the_lamp():
    cfg = PhotodiodeConfig(fov_half_angle_deg=40.0)
    psi = math.radians(41.0)
    h, *_ = _one_lamp_gain([0, 3.0, 0], [0.0, -math.cos(psi), math.sin(psi)], [0, 0, 0],
                           [0, 1, 0], cfg)
    assert h == 0.0
    h_behind, *_ = _one_lamp_gain([0, -3.0, 0], [0, 1, 0], [0, 0, 0], [0, 1, 0], cfg)
    assert h_behind == 0.0


def test_pd_pose_rides_the_platform():
    cfg = PhotodiodeConfig()
    yaw = math.radians(90.0)
    R = np.array([[math.cos(yaw), -math.sin(yaw), 0], [math.sin(yaw), math.cos(yaw), 0],
                  [0, 0, 1]])
    pos, normal = photodiode_pose([10.0, 0.0, 0.0], R, cfg)
    assert pos[0] == pytest.approx([10.0 - 0.8, 0.0, 2.9])
    n = cfg.normal_base
    assert normal[0] == pytest.approx([-n[1], n[0], n[2]])
    # The default normal points at the lamp line 1.7 m left and 1.5 m below the mount.
    assert n == pytest.approx(np.array([0.0, 1.7, -1.5]) / math.hypot(1.7, 1.5), abs=1e-3)


def test_noise_variance_is_komine_shot_plus_thermal():
    cfg = PhotodiodeConfig(noise_bandwidth_hz=1e6)
    P = 2e-5
    B = 1e6
    q, k, T = ELECTRON_CHARGE_C, BOLTZMANN_J_PER_K, cfg.temperature_k
    shot = 2 * q * cfg.responsivity_a_per_w * P * B + 2 * q * cfg.background_current_a * \
        cfg.noise_factor_i2 * B
    eta_a = cfg.capacitance_per_area_f_m2 * cfg.area_m2
    thermal = (8 * math.pi * k * T / cfg.open_loop_gain * eta_a * cfg.noise_factor_i2 * B ** 2
               + 16 * math.pi ** 2 * k * T * cfg.fet_noise_factor / cfg.fet_transconductance_s
               * eta_a ** 2 * cfg.noise_factor_i3 * B ** 3)
    assert noise_variance_a2(P, cfg) == pytest.approx(shot + thermal, rel=1e-12)
    # Shot noise grows with the received power, thermal noise does not.
    assert noise_variance_a2(2 * P, cfg) - noise_variance_a2(P, cfg) == pytest.approx(
        2 * q * cfg.responsivity_a_per_w * P * B, rel=1e-9)


def _standing_pd(x_m, seed=1, **cfg):
    traj = Trajectory(MotionProfile('stationary', start_chainage_m=x_m), STILL)
    return Photodiode(PhotodiodeConfig(**cfg), straight_tunnel_map(), traj, seed=seed)


def test_lamps_received_are_those_inside_the_field_of_view():
    pd = _standing_pd(45.0, lamp_power_sigma_rel=0.0)
    sample = pd.sample(0, 50.0)
    # FOV 80 deg around the nearest point of the lamp line (2.27 m away): +-12.86 m.
    assert sorted(sample.uid.tolist()) == [4100, 4101]          # lamps at 40 and 50 m
    pd_near = _standing_pd(40.2, lamp_power_sigma_rel=0.0)
    assert sorted(pd_near.sample(0, 50.0).uid.tolist()) == [4099, 4100, 4101]
    # Symmetric geometry, no vibration, no tolerance: equal powers.
    p = pd.sample(0, 50.0).true_power_w
    assert p[0] == pytest.approx(p[1], rel=1e-9)


def test_samples_are_deterministic_per_seed_and_index():
    a = _standing_pd(45.0, seed=4).sample(7, 50.0)
    b = _standing_pd(45.0, seed=4)
    b.sample(3, 50.0)
    b = b.sample(7, 50.0)
    assert np.array_equal(a.power_w, b.power_w)
    c = _standing_pd(45.0, seed=5).sample(7, 50.0)
    assert not np.array_equal(a.power_w, c.power_w)


def test_measurement_noise_has_the_reported_sigma():
    # A wide bandwidth makes the noise visible next to the power.
    pd = _standing_pd(45.0, noise_bandwidth_hz=1e8, lamp_power_sigma_rel=0.0, min_snr_db=-50.0)
    samples = [pd.sample(n, 50.0) for n in range(400)]
    err = np.array([s.power_w - s.true_power_w for s in samples])
    sigma = samples[0].power_sigma_w
    assert np.all(sigma > 0.0)
    assert np.std(err, axis=0) == pytest.approx(sigma, rel=0.15)
    assert abs(np.mean(err)) < 4.0 * sigma[0] / math.sqrt(err.size)
    snr = samples[0].snr_db
    assert snr == pytest.approx(20.0 * np.log10(np.abs(samples[0].power_w) / sigma))


def test_lamp_power_tolerance_is_fixed_per_lamp_with_the_given_spread():
    pd = _standing_pd(45.0, seed=2, lamp_power_sigma_rel=0.05)
    factors = np.array([pd.power_factor(uid) for uid in range(4097, 4097 + 2000)])
    assert np.std(factors) == pytest.approx(0.05, rel=0.1)
    assert np.mean(factors) == pytest.approx(1.0, abs=0.005)
    assert pd.power_factor(4100) == pd.power_factor(4100)
    assert _standing_pd(45.0, lamp_power_sigma_rel=0.0).power_factor(4100) == 1.0


def test_a_sample_is_the_mean_over_its_window():
    traj = Trajectory(MotionProfile('constant', start_chainage_m=36.0, speed_mps=30.0), STILL)
    cfg = PhotodiodeConfig(lamp_power_sigma_rel=0.0)
    lamp_map = LampMap([Lamp(uid=4100, line_id=1, lamp_id=4, position_m=[40.0, 2.5, 1.4])])
    pd = Photodiode(cfg, lamp_map, traj, subsamples=8)
    sample = pd.sample(5, 20.0)                  # window [0.225, 0.275] s
    t = 0.25 + ((np.arange(8) + 0.5) / 8 - 0.5) * 0.05
    truth = traj.sample(t)
    pos, normal = photodiode_pose(truth.position_m, truth.R_map_base, cfg)
    gain, *_ = channel_gain(pos, normal, lamp_map.positions, np.array([[0, -1.0, 0]]), cfg)
    assert sample.true_power_w[0] == pytest.approx(cfg.lamp_optical_power_w * gain.mean())
    assert sample.t_s == pytest.approx(0.25)


@pytest.mark.parametrize('bad', [dict(fov_half_angle_deg=90.0), dict(area_m2=0.0),
                                 dict(mount_xyz_m=(0.0, 1.0)), dict(lamp_power_sigma_rel=-0.1),
                                 dict(lamp_half_power_angle_deg=0.0)])
def test_invalid_configuration_is_refused(bad):
    with pytest.raises(ValueError):
        PhotodiodeConfig(**bad)
