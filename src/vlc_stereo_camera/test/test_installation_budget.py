"""The rig's timing and roll draws and the error-budget variants of a profile.

``<profile>/only-<source>`` keeps one error source of a drawn profile and switches every
other off; ``<profile>/none`` switches all off. The camera's roll about its optical axis,
the IMU clock drift and the per-frame stamp jitter are drawn with the profile's sigmas.
"""
import numpy as np
import pytest
import yaml

from vlc_common.core.camera import StereoRig, mount_rotation
from vlc_common.core.lamp_map import LampMap, resolve_lamp_map_path
from vlc_common.core.vehicle import CameraMount, VehicleMount, load_vehicle
from vlc_stereo_camera.core.installation import (
    BUDGET_SOURCES,
    ProfileError,
    default_profiles_path,
    draw_imu_clock,
    draw_installation,
    draw_vehicle,
    frame_stamp_jitter_s,
    load_profile,
)
from vlc_stereo_camera.core.sensor_faults import SensorFaults

N = 1000


def _within(measured, expected, rel=0.10):
    return abs(measured - expected) <= rel * expected


# ------------------------------------------------------------------ roll
def test_roll_zero_is_the_mount_as_it_was_and_roll_turns_the_image_about_its_centre():
    assert np.array_equal(mount_rotation(49.0, 27.0), mount_rotation(49.0, 27.0, 0.0))
    R0, R = mount_rotation(49.0, 27.0), mount_rotation(49.0, 27.0, 2.0)
    assert np.allclose(R.T @ R, np.eye(3), atol=1e-12)
    assert np.allclose(R[:, 2], R0[:, 2])                 # the optical axis stays
    # a point on the image-right axis of the unrolled camera: turned +2 deg toward image down
    p_base = R0 @ np.array([1.0, 0.0, 5.0])
    x, y, _ = R.T @ p_base
    assert np.degrees(np.arctan2(-y, x)) == pytest.approx(2.0, abs=1e-9)
    rig = StereoRig(roll_deg=2.0)
    assert np.allclose(rig.t_base_cams[1] - rig.t_base_cams[0], rig.baseline_m * R[:, 0])


def test_roll_round_trips_through_the_vehicle_file(tmp_path):
    VehicleMount().save(tmp_path / 'plain.yaml', 'no roll')
    assert 'roll_deg' not in (tmp_path / 'plain.yaml').read_text()
    mount = VehicleMount(camera=CameraMount(roll_deg=0.4))
    mount.save(tmp_path / 'rolled.yaml', 'rolled')
    back = load_vehicle(tmp_path / 'rolled.yaml')
    assert back.camera.roll_deg == pytest.approx(0.4)
    assert np.allclose(back.camera.R_base_cam, mount.camera.R_base_cam)


def test_roll_and_clock_draws_have_the_profiles_statistics():
    realistic = load_profile('realistic')
    m = realistic.mount
    nominal = VehicleMount()
    draws = [draw_vehicle(realistic, seed, nominal) for seed in range(N)]
    roll = np.array([t.camera.roll_deg for t, _, _ in draws])
    measured = np.array([b.camera.roll_deg - t.camera.roll_deg for t, b, _ in draws])
    assert _within(roll.std(), m['camera_angle_sigma_deg'])
    assert _within(measured.std(), m['camera_angle_measurement_sigma_deg'])
    clocks = np.array([draw_imu_clock(realistic, seed) for seed in range(N)])
    assert _within(clocks[:, 0].std(), m['imu_clock_offset_sigma_s'])
    assert _within(clocks[:, 1].std(), m['imu_clock_drift_sigma_ppm'])
    # the offset is the one draw_vehicle has always given
    assert np.array_equal(clocks[:, 0], [o for _, _, o in draws])
    jitter = np.array([frame_stamp_jitter_s(realistic, 7, k) for k in range(3 * N)])
    assert _within(jitter.std(), realistic.lens['stamp_jitter_s'])
    assert abs(jitter.mean()) < 4 * realistic.lens['stamp_jitter_s'] / np.sqrt(3 * N)
    assert jitter[5] == frame_stamp_jitter_s(realistic, 7, 5)          # deterministic
    assert frame_stamp_jitter_s(load_profile('ideal'), 7, 5) == 0.0


def test_imu_clock_drift_moves_the_imu_stamps_with_time():
    faults = SensorFaults.from_parameters(imu_stamp_offset_s=0.001, imu_clock_drift_ppm=20.0)
    assert faults.imu_faults and 'drift +20.00 ppm' in faults.describe()
    assert faults.imu_stamp_ns(0, 0) == 1_000_000
    assert faults.imu_stamp_ns(10_000_000_000, 10_000_000_000) == 10_000_000_000 + 1_200_000
    with pytest.raises(ValueError, match='imu_clock_drift_ppm'):
        SensorFaults.from_parameters(imu_clock_drift_ppm=float('nan'))


def test_a_profile_file_without_the_later_keys_draws_none_of_them(tmp_path):
    body = yaml.safe_load(open(default_profiles_path(), encoding='utf-8').read())['realistic']
    body['lens'].pop('stamp_jitter_s')
    body['mount'].pop('imu_clock_drift_sigma_ppm')
    path = tmp_path / 'old.yaml'
    path.write_text(yaml.safe_dump({'ideal': {}, 'old': body}))
    old = load_profile('old', path)
    assert old.lens['stamp_jitter_s'] == 0.0 and old.mount['imu_clock_drift_sigma_ppm'] == 0.0
    assert draw_imu_clock(old, 3)[1] == 0.0 and frame_stamp_jitter_s(old, 3, 9) == 0.0


# ------------------------------------------------------------------ error budget
def _nonzero_keys(profile):
    keys = set()
    for section, values in profile.sections.items():
        for key, value in values.items():
            spread = value[1] if key in ('k1', 'k2', 'k3') else (
                max(value) if isinstance(value, tuple) else value)
            if spread:
                keys.add((section, key))
    return keys


def test_every_error_of_a_profile_belongs_to_exactly_one_budget_source():
    realistic = load_profile('realistic')
    owned = [key for _, keys in BUDGET_SOURCES.values() for key in keys]
    assert len(owned) == len(set(owned))
    assert _nonzero_keys(realistic) - set(owned) == {('calibration', 'reprojection_rms_px')}


@pytest.mark.parametrize('source', sorted(BUDGET_SOURCES))
def test_only_one_source_keeps_its_values_and_nothing_else(source):
    realistic = load_profile('realistic')
    only = load_profile(f'realistic/only-{source}')
    assert only.name == f'realistic/only-{source}' and not only.ideal
    kept = set(BUDGET_SOURCES[source][1])
    assert _nonzero_keys(only) - {('calibration', 'reprojection_rms_px')} == (
        kept & _nonzero_keys(realistic))
    for section, key in kept:
        assert only.sections[section][key] == realistic.sections[section][key]
    assert only.car_body == (realistic.car_body if source == 'track' else None)
    # the distortion of the lens design is always there (raw images)
    assert only.lens['k1'][0] == realistic.lens['k1'][0]


def test_a_source_alone_draws_what_it_draws_in_the_whole_profile():
    lamp_map = LampMap.load(resolve_lamp_map_path(''))
    whole = draw_installation('realistic', 4, VehicleMount(), lamp_map)
    survey = draw_installation(load_profile('realistic/only-survey'), 4, VehicleMount(),
                               lamp_map)
    for uid, d in whole.lamp_draws.items():
        assert np.array_equal(survey.lamp_draws[uid].survey_error_m, d.survey_error_m)
        assert survey.lamp_draws[uid].brightness == 1.0
    assert survey.optics.trigger_skew_s == 0.0 and survey.imu_clock_offset_s == 0.0
    assert survey.vehicle_belief.camera.roll_deg == 0.0
    mount = draw_installation(load_profile('realistic/only-camera_mount'), 4, VehicleMount())
    assert mount.vehicle_truth.camera.roll_deg == whole.vehicle_truth.camera.roll_deg != 0.0
    assert np.array_equal(mount.vehicle_belief.camera.position_m,
                          whole.vehicle_belief.camera.position_m)
    none = draw_installation(load_profile('realistic/none'), 4, VehicleMount())
    # nothing drawn: the calibration is the true lens exactly
    assert not np.any(none.calibration_error['focal'])
    assert none.calibration.left.K == pytest.approx(none.optics.left.K)


@pytest.mark.parametrize('name, message', [
    ('realistic/only-weather', r"unknown variant 'only-weather' of 'realistic' \(known: "
                               r'none, only-lens'),
    ('realistic/all', r"unknown variant 'all'"),
    ('ideal/none', r"'ideal' draws nothing"),
    ('fancy/none', r"unknown profile 'fancy'"),
])
def test_bad_variants_name_the_file_and_the_field(name, message):
    with pytest.raises(ProfileError, match=r'rig_profiles\.yaml: rig_profile: ' + message):
        load_profile(name)
