"""Triangulation and fix geometry against the rig's own projection (the truth)."""
import copy
import math

import numpy as np
import pytest

from train_localizer.core.fix import (
    FixConfig,
    RigGeometry,
    constrained_fix,
    exp_so3,
    lamp_sigma,
    measurement_time_ns,
    paper_fix,
    triangulate,
    vision_attitude,
)
from vlc_common.core.camera import StereoRig
from vlc_common.core.lamp_map import straight_tunnel_map
from vlc_common.core.observation import LampObservation
from vlc_common.core.rotations import rpy_to_matrix

DEG = math.pi / 180.0
RIG = StereoRig()
GEOM = RigGeometry.from_stereo_rig(RIG)
LAMP = straight_tunnel_map().by_uid(4096 + 10)   # at chainage 100 m


def observe(base, R, lamp=LAMP, noise=None, sigma=0.05):
    uv_l, uv_r, _ = RIG.project(lamp.position_m[None, :], base, R)
    n = np.zeros(4) if noise is None else noise
    return LampObservation(stamp_ns=0, uid=lamp.uid, uv_left=uv_l[0] + n[:2],
                           uv_right=uv_r[0] + n[2:], sigma_u_px=sigma, sigma_v_px=sigma)


def visible_offsets():
    """Along-track camera-to-lamp offsets (m) at which the default rig sees the lamp."""
    return [1.5, 3.0, 5.0, 7.0, 8.5]


@pytest.mark.parametrize('dx', visible_offsets())
def test_triangulation_matches_rig_truth(dx):
    R = rpy_to_matrix(0.004, -0.003, 0.09)        # vibration-sized attitude, 5° heading
    base = np.array([LAMP.position_m[0] - dx, 0.003, -0.002])
    p_cam, cov = triangulate(observe(base, R), GEOM)
    truth = RIG.to_camera(LAMP.position_m[None, :], base, R, 0)[0]
    np.testing.assert_allclose(p_cam, truth, atol=1e-9)
    assert np.all(np.linalg.eigvalsh(cov) > 0.0)


def test_triangulation_covariance_matches_monte_carlo_and_depth_formula():
    R = np.eye(3)
    base = np.array([LAMP.position_m[0] - 7.0, 0.0, 0.0])
    rng = np.random.default_rng(3)
    sigma = 0.05
    samples = np.array([triangulate(observe(base, R, noise=rng.normal(0, sigma, 4)), GEOM)[0]
                        for _ in range(4000)])
    _, cov = triangulate(observe(base, R), GEOM)
    emp = np.cov(samples.T)
    np.testing.assert_allclose(np.sqrt(np.diag(emp)), np.sqrt(np.diag(cov)), rtol=0.1)
    # σz = z²·σd/(f·b) with σd = √2·σu (independent left/right centres).
    z = samples[:, 2].mean()
    expected = z * z * math.sqrt(2.0) * sigma / (GEOM.fx * GEOM.baseline_m)
    assert math.sqrt(cov[2, 2]) == pytest.approx(expected, rel=0.02)


def test_triangulation_refuses_small_or_negative_disparity():
    obs = LampObservation(0, None, [700.0, 300.0], [701.0, 300.0])
    assert triangulate(obs, GEOM, min_disparity_px=4.0) == (None, None)


@pytest.mark.parametrize('dx', visible_offsets())
def test_fixes_recover_the_truth_without_noise(dx):
    R = rpy_to_matrix(0.003, 0.002, -0.06)
    base = np.array([LAMP.position_m[0] - dx, 0.0, 0.0])
    p_cam, cov = triangulate(observe(base, R), GEOM)
    cov_att = np.diag(np.square([0.05, 0.05, 0.1])) * DEG ** 2
    c = constrained_fix(p_cam, cov, LAMP.position_m, R, cov_att, GEOM, FixConfig())
    p = paper_fix(p_cam, cov, LAMP.position_m, R, cov_att, GEOM, FixConfig())
    assert c.chainage_m == pytest.approx(base[0], abs=1e-9)
    np.testing.assert_allclose(p.position_m, base, atol=1e-9)
    assert c.chi2_geometry < 1e-12
    assert c.var_m2 == pytest.approx(c.var_random_m2 + c.var_systematic_m2)


def test_paper_fix_keeps_the_vibration_offsets():
    R = rpy_to_matrix(0.002, 0.001, 0.02)
    base = np.array([LAMP.position_m[0] - 4.0, 0.004, -0.003])
    p_cam, cov = triangulate(observe(base, R), GEOM)
    p = paper_fix(p_cam, cov, LAMP.position_m, R, np.eye(3) * 1e-8, GEOM, FixConfig())
    np.testing.assert_allclose(p.position_m, base, atol=1e-9)


def test_stereo_range_makes_the_constrained_fix_attitude_independent():
    """A 0.5° heading error moves the paper fix by centimetres, the range fix by mm."""
    R_true = rpy_to_matrix(0.0, 0.0, 0.05)
    R_est = rpy_to_matrix(0.0, 0.0, 0.05 + 0.5 * DEG)
    cov_att = np.diag(np.square([0.05, 0.05, 0.5])) * DEG ** 2
    for dx in (5.0, 7.0, 8.5):
        base = np.array([LAMP.position_m[0] - dx, 0.0, 0.0])
        p_cam, cov = triangulate(observe(base, R_true), GEOM)
        c = constrained_fix(p_cam, cov, LAMP.position_m, R_est, cov_att, GEOM, FixConfig())
        p = paper_fix(p_cam, cov, LAMP.position_m, R_est, cov_att, GEOM, FixConfig())
        assert abs(c.chainage_m - base[0]) < 0.006, dx
        assert abs(p.chainage_m - base[0]) > 0.015, dx
        # Each error is inside its own 3σ.
        assert abs(c.chainage_m - base[0]) < 3.0 * c.sigma_m
        assert abs(p.chainage_m - base[0]) < 3.0 * p.sigma_m


@pytest.mark.parametrize('dx', [1.5, 5.0, 8.5])
@pytest.mark.parametrize('err_deg', [(0.0, 0.0, 5.0), (0.0, 0.0, -5.0), (1.3, -1.3, 3.0)])
def test_constrained_fix_estimates_a_large_attitude_error(dx, err_deg):
    """Cold-start attitude errors (degrees): the fit stays unbiased and recovers δθ.

    A single linearised step about the IMU attitude is off by 2–3 cm at 5° of heading
    error (second-order term) while claiming ~0.6 cm.
    """
    R_true = rpy_to_matrix(0.002, -0.001, 0.03)
    delta = np.array(err_deg) * DEG
    R_est = rpy_to_matrix(*delta) @ R_true        # IMU attitude = Exp(δ)·truth, about map axes
    cov_att = np.diag(np.square([1.3, 1.3, 5.0])) * DEG ** 2
    base = np.array([LAMP.position_m[0] - dx, 0.0, 0.0])
    p_cam, cov = triangulate(observe(base, R_true), GEOM)
    c = constrained_fix(p_cam, cov, LAMP.position_m, R_est, cov_att, GEOM, FixConfig())
    assert abs(c.chainage_m - base[0]) < 0.002
    assert abs(c.chainage_m - base[0]) < 3.0 * c.sigma_m
    # true = Exp(δθ)·R_est ⇒ δθ ≈ −δ; heading is observed best
    assert abs(c.attitude_error_rad[2] + delta[2]) < 0.2 * DEG
    assert c.chi2_geometry < 1.0


@pytest.mark.parametrize('dx', [2.0, 6.0])
def test_constrained_fix_variance_matches_its_scatter(dx):
    R = np.eye(3)
    base = np.array([LAMP.position_m[0] - dx, 0.0, 0.0])
    # pixel noise alone: the calibration taken as exact
    cfg = FixConfig(track_sigma_yz_m=(1e-9, 1e-9), lamp_position_sigma_m=1e-9)
    cfg = cfg.without_calibration()
    rng = np.random.default_rng(11)
    cov_att = np.eye(3) * 1e-14
    est, var = [], []
    for _ in range(3000):
        p_cam, cov = triangulate(observe(base, R, noise=rng.normal(0, 0.05, 4)), GEOM)
        fix = constrained_fix(p_cam, cov, LAMP.position_m, R, cov_att, GEOM, cfg)
        est.append(fix.chainage_m)
        var.append(fix.var_m2)
    assert np.std(est) == pytest.approx(math.sqrt(np.mean(var)), rel=0.1)
    assert abs(np.mean(est) - base[0]) < 3.0 * np.std(est) / math.sqrt(len(est)) + 1e-4


def test_geometry_residual_flags_a_wrong_stereo_match():
    base = np.array([LAMP.position_m[0] - 4.0, 0.0, 0.0])
    obs = observe(base, np.eye(3))
    good = constrained_fix(*triangulate(obs, GEOM), LAMP.position_m, np.eye(3),
                           np.eye(3) * 1e-6, GEOM, FixConfig())
    obs.uv_right = obs.uv_right + np.array([3.0, 0.0])     # right spot of another blob
    bad = constrained_fix(*triangulate(obs, GEOM), LAMP.position_m, np.eye(3),
                          np.eye(3) * 1e-6, GEOM, FixConfig())
    assert good.chi2_geometry < 1.0
    assert bad.chi2_geometry > 100.0


def test_measurement_time_is_the_spot_rows_exposure_mid_time():
    obs = LampObservation(1_000_000_000, None, [500.0, 400.0], [480.0, 402.0])
    # Row 401 (mean of both centres) starts 401·30 µs after row 0, mid-exposure +25 µs.
    assert measurement_time_ns(obs, GEOM) == 1_000_000_000 + 12_055_000
    assert measurement_time_ns(obs, GEOM, use_exposure_stamping=False) == 1_000_000_000
    obs.exposure_mid_offset_s = 0.004
    assert measurement_time_ns(obs, GEOM) == 1_004_000_000


@pytest.mark.parametrize('dx', [1.5, 5.0, 8.5])
@pytest.mark.parametrize('err_deg', [(0.0, 0.0, 30.0), (1.0, -2.0, -30.0), (3.0, 3.0, 0.5)])
def test_vision_attitude_recovers_the_attitude_without_the_imu_prior(dx, err_deg):
    """The attitude one lamp shows (attitude_aiding) from an IMU attitude off by up to
    30° of heading (a cold start on a curve): consistent with the truth in its own
    covariance and, once the tilt is known, a tight heading. With an equally weak prior
    on every axis the unseen share of a 30° heading error went into the tilt (6° of
    roll) and wrecked the curved outage run.
    """
    R_true = rpy_to_matrix(0.002, -0.001, 0.03)
    delta = np.array(err_deg) * DEG
    R_est = rpy_to_matrix(*delta) @ R_true
    base = np.array([LAMP.position_m[0] - dx, 0.0, 0.0])
    p_cam, cov = triangulate(observe(base, R_true), GEOM)
    dtheta, cov_att = vision_attitude(p_cam, cov, LAMP.position_m, R_est, GEOM, FixConfig())
    r = exp_so3(dtheta) @ R_est @ R_true.T          # aid vs truth
    e = 0.5 * np.array([r[2, 1] - r[1, 2], r[0, 2] - r[2, 0], r[1, 0] - r[0, 1]])
    assert e @ np.linalg.solve(cov_att, e) < 11.3            # 3 dof, 99 %
    # the tilt is not made worse than the IMU's own (the unseen share stays where it was)
    assert np.abs(e[:2]).max() <= np.abs(delta[:2]).max() + 1.0 * DEG
    assert 1.0 / np.sqrt(np.linalg.inv(cov_att)[2, 2]) < 0.3 * DEG


def believed_geometry(rng, cfg):
    """The rig as a calibration with ``cfg``'s uncertainty describes it: one draw of its
    stereo scale, focal length, principal point and mount angles around the truth.
    """
    k = RIG.intrinsics
    scale = 1.0 + rng.normal(0.0, cfg.stereo_scale_sigma)
    focal = 1.0 + rng.normal(0.0, cfg.focal_length_sigma)
    mount = rng.normal(0.0, 1.0, 3) * np.asarray(cfg.mount_angle_sigma_rad)
    return RigGeometry(fx=k.fx * focal, fy=k.fy * focal,
                       cx=k.cx + rng.normal(0.0, cfg.principal_point_sigma_px),
                       cy=k.cy + rng.normal(0.0, cfg.principal_point_sigma_px),
                       baseline_m=RIG.baseline_m * scale / focal,
                       t_base_cam=RIG.cam_positions_base()[0],
                       R_base_cam=exp_so3(mount) @ RIG.R_base_cam)


@pytest.mark.parametrize('dx', [1.5, 5.0, 8.5])
def test_calibration_errors_match_the_fix_systematic_variance(dx):
    """Noise-free spots read through calibrations drawn with the configured σ (3× the
    defaults, so they dominate): the fixes scatter as their systematic variance says;
    with the calibration taken as exact the fix claims almost nothing.
    """
    defaults = FixConfig()
    cfg = FixConfig(track_sigma_yz_m=(1e-9, 1e-9), lamp_position_sigma_m=1e-9,
                    stereo_scale_sigma=3.0 * defaults.stereo_scale_sigma,
                    focal_length_sigma=3.0 * defaults.focal_length_sigma,
                    principal_point_sigma_px=3.0 * defaults.principal_point_sigma_px,
                    mount_angle_sigma_rad=tuple(3.0 * v for v in defaults.mount_angle_sigma_rad))
    R = rpy_to_matrix(0.002, -0.001, 0.01)
    base = np.array([LAMP.position_m[0] - dx, 0.0, 0.0])
    obs = observe(base, R)
    cov_att = np.eye(3) * 1e-14
    rng = np.random.default_rng(int(dx * 10))
    err, var_sys, var_exact = [], [], []
    for _ in range(800):
        geometry = believed_geometry(rng, cfg)
        p_cam, cov = triangulate(obs, geometry)
        fix = constrained_fix(p_cam, cov, LAMP.position_m, R, cov_att, geometry, cfg)
        err.append(fix.chainage_m - base[0])
        var_sys.append(fix.var_systematic_m2)
        var_exact.append(constrained_fix(p_cam, cov, LAMP.position_m, R, cov_att, geometry,
                                         cfg.without_calibration()).var_m2)
    rms = math.sqrt(np.mean(np.square(err)))
    assert rms == pytest.approx(math.sqrt(np.mean(var_sys)), rel=0.1)
    assert math.sqrt(np.mean(var_exact)) < 0.5 * rms


def test_a_lamp_map_sigma_replaces_the_configured_survey_sigma():
    base = np.array([LAMP.position_m[0] - 4.0, 0.0, 0.0])
    p_cam, cov = triangulate(observe(base, np.eye(3)), GEOM)
    cfg = FixConfig().without_calibration()
    att = np.eye(3) * 1e-14
    default = constrained_fix(p_cam, cov, LAMP.position_m, np.eye(3), att, GEOM, cfg)
    lamp = copy.copy(LAMP)
    lamp.position_sigma_m = np.array([0.05, np.nan, np.nan])   # a poorly surveyed x
    own = constrained_fix(p_cam, cov, LAMP.position_m, np.eye(3), att, GEOM, cfg,
                          lamp_sigma(lamp, cfg))
    np.testing.assert_allclose(lamp_sigma(lamp, cfg), [0.05, 0.005, 0.005])
    np.testing.assert_allclose(lamp_sigma(LAMP, cfg), [0.005] * 3)
    assert own.var_systematic_m2 > default.var_systematic_m2 + 0.5 * 0.05 ** 2
    pf = paper_fix(p_cam, cov, LAMP.position_m, np.eye(3), att, GEOM, cfg, [0.05, 0.0, 0.0])
    assert pf.var_systematic_m2 == pytest.approx(0.05 ** 2, rel=0.01)


def _biased_disparity(dx, bias_px):
    """A lamp ``dx`` ahead seen with the disparity ``bias_px`` too large (a calibration's
    stereo error), the attitude exact; returns (p_cam, cov_cam, base, R).
    """
    R = np.eye(3)
    base = np.array([LAMP.position_m[0] - dx, 0.0, 0.0])
    obs = observe(base, R, sigma=0.02)
    obs = LampObservation(stamp_ns=0, uid=obs.uid, uv_left=obs.uv_left,
                          uv_right=obs.uv_right - np.array([bias_px, 0.0]),
                          sigma_u_px=0.02, sigma_v_px=0.02)
    p_cam, cov = triangulate(obs, GEOM)
    return p_cam, cov, base, R


def test_raw_images_weight_the_calibrations_disparity_error():
    # The realistic rig's calibration leaves ~0.4 px of disparity error: 9 m ahead that
    # is a 3 % (~30 cm) range error the spot's own 0.02 px hides. Weighted as the
    # calibration's (raw images), the fix rests on the lamp's direction under the
    # attitude (0.1° heading 1σ) instead; with the ideal rig (no raw images) nothing
    # changes.
    import dataclasses
    cov_att = np.diag(np.square([0.05 * DEG, 0.05 * DEG, 0.1 * DEG]))
    config = FixConfig()
    p_cam, cov, base, R = _biased_disparity(8.5, 0.4)
    ideal = constrained_fix(p_cam, cov, LAMP.position_m, R, cov_att, GEOM, config)
    geom = dataclasses.replace(GEOM, calibration_sigma_px=(0.5, 0.4))
    assert constrained_fix(p_cam, cov, LAMP.position_m, R, cov_att, geom,
                           config).chainage_m == ideal.chainage_m     # not raw: unchanged
    raw = constrained_fix(p_cam, cov, LAMP.position_m, R, cov_att,
                          dataclasses.replace(geom, raw_images=True), config)
    assert abs(ideal.chainage_m - base[0]) > 0.15                       # the biased range
    assert abs(raw.chainage_m - base[0]) < 0.06
    assert abs(raw.chainage_m - base[0]) < 2.0 * math.sqrt(raw.var_m2)  # honest variance
    assert raw.var_systematic_m2 > ideal.var_systematic_m2              # not averaged away


def test_vision_attitude_of_raw_images_carries_the_calibration_error():
    # A biased range moves the lamp's chainage and with it the heading its direction
    # shows; the aid's covariance must say so (inflated: the same error in every aid).
    import dataclasses
    p_cam, cov, base, R = _biased_disparity(8.5, 0.4)
    geom = dataclasses.replace(GEOM, calibration_sigma_px=(0.5, 0.4), raw_images=True)
    dtheta, cov_aid = vision_attitude(p_cam, cov, LAMP.position_m, R, GEOM, FixConfig())
    assert np.linalg.norm(dtheta) > 0.2 * DEG             # the true attitude error is 0
    assert dtheta @ np.linalg.solve(cov_aid, dtheta) > 25.0          # and it claims > 5σ
    raw, cov_raw = vision_attitude(p_cam, cov, LAMP.position_m, R, geom, FixConfig(),
                                   calibration_scale=25.0)
    assert raw @ np.linalg.solve(cov_raw, raw) < 1.0 / 25.0 * 9.0    # within 3σ/√25
