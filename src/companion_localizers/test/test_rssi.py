"""RSSI trilateration core (companion method 1) against the rig's photodiode model."""
import math

import numpy as np
import pytest

from companion_localizers.core.rssi import (
    LampReading,
    RssiConfig,
    collinear,
    distances_from_power,
    model_power,
    trilaterate,
    window_factor,
)
from vlc_common.core.lamp_map import Lamp, LampMap, straight_tunnel_map
from vlc_common.core.optical_channel import PhotodiodeConfig, photodiode_pose
from vlc_common.core.rotations import rot_z, rpy_to_matrix
from vlc_stereo_camera.core.photodiode import Photodiode
from vlc_stereo_camera.core.trajectory import MotionProfile, Trajectory, Vibration, VibrationConfig

DEG = math.pi / 180.0
STILL = Vibration(VibrationConfig(enabled=False))
LAMPS = straight_tunnel_map()


def readings_at(x_m, R=None, cfg=None, lamp_map=LAMPS, yz=(0.0, 0.0), scale=None):
    """Noise-free readings of the lamps a PD at base (x, y, z) with attitude R (default
    level) receives.
    """
    R = np.eye(3) if R is None else R
    cfg = cfg or PhotodiodeConfig(lamp_power_sigma_rel=0.0)
    pos, normal = photodiode_pose([x_m, *yz], R, cfg)
    lamps = [lamp for lamp in lamp_map.lamps if abs(lamp.position_m[0] - x_m) < 30.0]
    power = model_power(pos[0], normal[0], np.array([la.position_m for la in lamps]),
                        np.array([la.normal for la in lamps]), cfg)[0]
    out = []
    for lamp, p in zip(lamps, power):
        if p > 0.0:
            factor = 1.0 if scale is None else scale.get(lamp.uid, 1.0)
            out.append(LampReading(lamp.uid, lamp.position_m, lamp.normal, p * factor, 0.0))
    return out


def test_distance_inversion_is_exact_for_the_model():
    cfg = PhotodiodeConfig()
    R = rpy_to_matrix(0.01, -0.02, 0.1)
    pos, normal = photodiode_pose([44.0, 0.0, 0.0], R, cfg)
    readings = readings_at(44.0, R)
    d, sigma = distances_from_power(readings, pos[0], normal[0], cfg)
    true = [np.linalg.norm(pos[0] - r.position_m) for r in readings]
    assert d == pytest.approx(true, rel=1e-12)
    # sigma_d / d = sigma_P / P / (m + 3): 2 % power -> 0.5 % distance.
    assert sigma / d == pytest.approx(np.full(len(d), 0.02 / 4.0))


@pytest.mark.parametrize('x_m', [14.0, 25.0, 36.6, 47.9])
@pytest.mark.parametrize('yaw_deg', [0.0, 6.0, -4.0])
def test_track_constrained_solution_is_exact_without_noise(x_m, yaw_deg):
    R = rot_z(yaw_deg * DEG)
    fix = trilaterate(readings_at(x_m, R), R, RssiConfig(window_s=0.0))
    assert fix.ok, fix.reason
    assert fix.mode == 'track'
    # Exact to the solver's convergence tolerance (0.1 mm).
    assert fix.position_m == pytest.approx([x_m, 0.0, 0.0], abs=2e-4)
    assert fix.chi2 < 1e-2


def test_one_lamp_is_too_few_and_collinear_lamps_are_refused_a_free_solve():
    one = readings_at(14.0)[:1]
    assert trilaterate(one, np.eye(3), RssiConfig()).reason == 'too_few_lamps'
    wall = readings_at(45.0)
    assert collinear([r.position_m for r in wall], 0.05)
    fix = trilaterate(wall, np.eye(3), RssiConfig(solve_mode='free'))
    assert not fix.ok and fix.reason in ('collinear', 'too_few_lamps')
    # Three lamps on the wall line: still collinear, the free solve refuses them.
    three = readings_at(40.3)
    assert len(three) == 3
    assert trilaterate(three, np.eye(3), RssiConfig(solve_mode='free')).reason == 'collinear'


def test_free_3d_solve_with_lamps_on_both_walls_and_the_ceiling():
    # Lamps not on one line (a lamp map a tunnel could have): the 3-D solve runs and is
    # exact, lateral and vertical position included.
    pdc = PhotodiodeConfig(lamp_power_sigma_rel=0.0, azimuth_deg=0.0, elevation_deg=90.0)
    ceiling = [0.0, 0.0, -1.0]
    lamps = LampMap([
        Lamp(uid=4097, line_id=1, lamp_id=1, position_m=[40.0, 2.5, 5.0], normal=ceiling),
        Lamp(uid=4098, line_id=1, lamp_id=2, position_m=[44.0, -2.0, 5.0], normal=ceiling),
        Lamp(uid=4099, line_id=1, lamp_id=3, position_m=[47.0, 0.5, 5.0], normal=ceiling),
        Lamp(uid=4100, line_id=1, lamp_id=4, position_m=[42.0, 0.0, 5.0], normal=ceiling)])
    readings = readings_at(43.0, cfg=pdc, lamp_map=lamps, yz=(0.05, -0.02))
    assert len(readings) == 4 and not collinear([r.position_m for r in readings], 0.05)
    cfg = RssiConfig(photodiode=pdc, window_s=0.0)
    fix = trilaterate(readings, np.eye(3), cfg)
    assert fix.ok and fix.mode == 'free', fix.reason
    assert fix.position_m == pytest.approx([43.0, 0.05, -0.02], abs=2e-4)


def test_a_lamp_that_disagrees_makes_the_solution_inconsistent():
    readings = readings_at(40.4, scale={4101: 1.3})        # lamp at 50 m 30 % too bright
    fix = trilaterate(readings, np.eye(3), RssiConfig(window_s=0.0))
    assert not fix.ok and fix.reason == 'inconsistent'


def test_near_a_lamp_with_an_uncertain_heading_the_side_is_ambiguous():
    # Abeam of a lamp only the far lamps (grazing incidence, power set by the heading)
    # tell which side: with a 5 deg heading sigma they cannot.
    readings = readings_at(40.3)
    uncertain = np.diag(np.square([0.5 * DEG, 0.5 * DEG, 5.0 * DEG]))
    fix = trilaterate(readings, np.eye(3), RssiConfig(window_s=0.0), attitude_cov_rad2=uncertain)
    assert not fix.ok and fix.reason == 'ambiguous'
    known = np.diag(np.square([0.05 * DEG, 0.05 * DEG, 0.1 * DEG]))
    fix = trilaterate(readings, np.eye(3), RssiConfig(window_s=0.0), attitude_cov_rad2=known)
    assert fix.ok and fix.position_m[0] == pytest.approx(40.3, abs=2e-4)


def test_window_factor_removes_the_integration_bias_at_speed():
    speed = 33.3
    cfg = PhotodiodeConfig(lamp_power_sigma_rel=0.0)
    traj = Trajectory(MotionProfile('constant', start_chainage_m=0.0, speed_mps=speed), STILL)
    pd = Photodiode(cfg, LAMPS, traj, subsamples=5)
    errors = {}
    for window in (0.0, 0.02):
        err = []
        for n in range(40, 100):
            sample = pd.sample(n, 50.0)
            readings = [LampReading(int(u), LAMPS.by_uid(u).position_m, LAMPS.by_uid(u).normal,
                                    p, 0.0) for u, p in zip(sample.uid, sample.true_power_w)]
            fix = trilaterate(readings, np.eye(3), RssiConfig(photodiode=cfg, window_s=window),
                              speed_mps=speed)
            if fix.ok:
                err.append(abs(fix.position_m[0] - traj.sample(sample.t_s).chainage_m[0]))
        errors[window] = np.max(err)
    assert errors[0.02] < 1e-3 < errors[0.0]
    assert window_factor(photodiode_pose([5.0, 0, 0], np.eye(3), cfg)[0][0], cfg.normal_base,
                         readings_at(5.0), np.zeros(3), 0.02, cfg) == pytest.approx(1.0)


@pytest.mark.parametrize('speed_kmh', [20.0, 120.0])
def test_accuracy_on_the_rig_photodiode_beats_the_papers_rssi_figures(speed_kmh):
    """Photodiode with 2 % lamp tolerance, shot and thermal noise, vibration; the receiver
    knows the attitude to 0.05 deg (a converged compensator). Paper: max 39.23 cm, mean
    13.36 cm.
    """
    rng = np.random.default_rng(7)
    traj = Trajectory(MotionProfile('constant', start_chainage_m=12.0,
                                    speed_mps=speed_kmh / 3.6), Vibration(seed=7))
    pd = Photodiode(PhotodiodeConfig(), LAMPS, traj, seed=7)
    att_sigma = np.array([0.05, 0.05, 0.1]) * DEG
    errors, solved = [], 0
    for n in range(0, 600, 4):
        sample = pd.sample(n, 50.0)
        truth = traj.sample(sample.t_s)
        R = rpy_to_matrix(*(truth.rpy_rad[0] + rng.normal(0.0, att_sigma)))
        readings = [LampReading(int(u), LAMPS.by_uid(u).position_m, LAMPS.by_uid(u).normal,
                                p, s) for u, p, s in zip(sample.uid, sample.power_w,
                                                         sample.power_sigma_w)]
        fix = trilaterate(readings, R, RssiConfig(), speed_mps=speed_kmh / 3.6,
                          attitude_cov_rad2=np.diag(att_sigma ** 2))
        if fix.ok:
            solved += 1
            errors.append(np.linalg.norm(fix.position_m - truth.position_m[0]))
    errors = np.array(errors)
    assert solved >= 0.85 * 150
    assert errors.max() < 0.3923 and errors.mean() < 0.1336
    assert errors.mean() < 0.05


def test_non_finite_and_non_positive_powers_are_left_out():
    readings = readings_at(45.0)
    bad = [LampReading(4102, LAMPS.by_uid(4102).position_m, LAMPS.by_uid(4102).normal, math.nan),
           LampReading(4103, LAMPS.by_uid(4103).position_m, LAMPS.by_uid(4103).normal, -1.0)]
    fix = trilaterate(readings + bad, np.eye(3), RssiConfig(window_s=0.0))
    assert fix.ok and fix.lamps_used == len(readings)
    assert trilaterate([], np.eye(3), RssiConfig()).reason == 'too_few_lamps'


@pytest.mark.parametrize('bad', [dict(solve_mode='best'), dict(min_lamps=1),
                                 dict(chi2_probability=1.0), dict(window_s=-1.0)])
def test_invalid_configuration_is_refused(bad):
    with pytest.raises(ValueError):
        RssiConfig(**bad)
