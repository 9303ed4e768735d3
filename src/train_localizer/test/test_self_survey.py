"""Self-calibration of the stereo range (core/self_survey.py) and the file a train keeps
it in (core/self_calibration_file.py).
"""
import dataclasses
import functools
import math

import numpy as np
import pytest

from train_localizer.core.fix import RigGeometry
from train_localizer.core.localizer import Localizer, LocalizerConfig
from train_localizer.core.self_calibration_file import (
    SavedCalibration,
    SelfCalibrationFileError,
    load_saved_calibration,
    save_calibration,
)
from train_localizer.core.self_survey import SelfSurvey, SelfSurveyConfig
from vlc_common.core.camera import StereoRig
from vlc_common.core.lamp_map import straight_tunnel_map
from vlc_stereo_camera.core.trajectory import MotionProfile, Trajectory, Vibration
from vlc_stereo_camera.core.upstream import (
    SensorErrors,
    SensorSimulator,
    SimTiming,
    along_track_errors,
    disparity_error_hook,
    event_stream,
    feed_localizer,
)

FB = 1040.0 * 0.12          # fx·b, px·m
LATERAL = math.hypot(1.7, 1.5)


def range_entries(survey, delta, eps, rng, lamps=8, offsets=None, state_noise_m=0.005):
    """Feed ``survey`` the range chainages of ``lamps`` lamps, each seen from 17 m to
    2 m ahead, with a disparity offset ``delta`` (px) and a stereo scale error ``eps``,
    relative to a reference chainage good to ``state_noise_m``; ``offsets`` {lamp index:
    m} moves lamps along the track (their fixes read that much too far).
    """
    offsets = offsets or {}
    seq = 0
    for k in range(lamps):
        for along in np.linspace(17.0, 2.0, 40):
            r_true = math.hypot(along, LATERAL)
            d = FB * (1.0 + eps) / r_true + delta          # measured disparity
            r_m = FB / d
            along_m = math.sqrt(r_m * r_m - LATERAL * LATERAL)
            meas = (along - along_m) + offsets.get(k, 0.0) + rng.normal(0.0, state_noise_m)
            seq += 1
            survey.add(seq, 0x1000 + k, d, meas, state_noise_m ** 2, -r_m * r_m / along_m,
                       0.003)
    assert survey.solve()


@pytest.mark.parametrize('delta,eps', [(0.5, 0.0), (-0.7, 0.002), (0.2, -0.003)])
def test_range_calibration_is_recovered(delta, eps):
    survey = SelfSurvey(SelfSurveyConfig(disparity_offset_sigma_px=0.8,
                                         stereo_scale_sigma=0.005))
    range_entries(survey, delta, eps, np.random.default_rng(3))
    assert survey.theta[0] == pytest.approx(delta, abs=0.02)
    assert survey.theta[1] == pytest.approx(eps, abs=0.001)
    assert survey.converged and survey.applied
    # the stated 1σ covers the estimate and is far below the prior's
    assert abs(survey.theta[0] - delta) < 3.0 * survey.published_sigmas()[0] < 0.4


def test_a_lamp_off_its_survey_is_flagged_and_does_not_bend_the_calibration():
    clean = SelfSurvey(SelfSurveyConfig(disparity_offset_sigma_px=0.8))
    range_entries(clean, 0.4, 0.0, np.random.default_rng(5))
    bad = SelfSurvey(SelfSurveyConfig(disparity_offset_sigma_px=0.8))
    range_entries(bad, 0.4, 0.0, np.random.default_rng(5), offsets={3: 0.05})
    assert set(bad.flagged) == {0x1003} and not clean.flagged
    assert bad.theta[0] == pytest.approx(clean.theta[0], abs=0.01)
    assert bad.lamps[0x1003].correction_m == pytest.approx(0.05, abs=0.01)


def test_nothing_is_applied_before_the_calibration_is_known():
    survey = SelfSurvey(SelfSurveyConfig(disparity_offset_sigma_px=0.8))
    p = np.array([1.0, 2.0, 10.0])
    assert survey.correct(p, np.eye(3), 12.0)[0] is p
    assert survey.range_factor(12.0) == 1.0
    assert survey.published_sigmas() == (0.8, 0.001)


# --------------------------------------------------------------- the localizer
RIG = StereoRig()
LAMPS = straight_tunnel_map(count=10)
SPEED_MPS = 60.0 / 3.6


@functools.cache
def truth_pass():
    """(trajectory, events): 60 m at 60 km/h past six lamps (IMU at 100 Hz)."""
    traj = Trajectory(MotionProfile('constant', start_chainage_m=8.0, speed_mps=SPEED_MPS),
                      Vibration(seed=2))
    sim = SensorSimulator(traj, RIG, LAMPS, SensorErrors(), np.random.default_rng(2))
    return traj, event_stream(sim, 0.0, 60.0 / SPEED_MPS, SimTiming(imu_rate_hz=100.0))


def run_pass(delta_px, self_survey):
    """Along-track errors, published σ (m) and the localizer of the pass with every
    disparity ``delta_px`` too large (a calibration's stereo rotation), the receiver
    stating its calibration's disparity 1σ as 0.8 px (raw images).
    """
    traj, events = truth_pass()
    geometry = dataclasses.replace(RigGeometry.from_stereo_rig(RIG),
                                   calibration_sigma_px=(0.2, 0.8), raw_images=True)
    config = LocalizerConfig(geometry=geometry, self_survey=self_survey)
    loc = Localizer(LAMPS, config)
    poses, _, _ = feed_localizer(loc, events,
                                 frame_hook=disparity_error_hook(lambda u: delta_px))
    return (*along_track_errors(traj, poses, 1.0), loc)


@pytest.mark.parametrize('delta', [0.5, -0.5])
def test_self_calibration_removes_a_disparity_offset_on_the_first_pass(delta):
    """With self-calibration a pass whose every disparity is ``delta`` off localises
    within 1.5 mm (mean) of the same pass without the offset; without it the offset
    moves the mean error by more than 3 mm (the simulation's other errors stay).
    """
    def mean_error(d, config):
        return np.mean(np.abs(run_pass(d, config)[0]))

    assert abs(mean_error(delta, None) - mean_error(0.0, None)) > 0.003
    err_on, sigma_on, loc = run_pass(delta, SelfSurveyConfig())
    assert abs(np.mean(np.abs(err_on)) - mean_error(0.0, SelfSurveyConfig())) < 0.0015
    assert loc.survey.applied
    assert loc.survey.theta[0] == pytest.approx(delta, abs=0.05)
    assert np.mean(np.abs(err_on) <= 3.0 * sigma_on) >= 0.997
    # what it learnt is stated: the disparity term of the fix shrank from the prior's
    assert loc.config.geometry.calibration_sigma_px[1] < 0.4


def test_ideal_rectified_pair_is_left_alone():
    """No raw images (an exact rectified pair): nothing to calibrate, nothing applied."""
    traj, events = truth_pass()
    loc = Localizer(LAMPS, LocalizerConfig(self_survey=SelfSurveyConfig()))
    ref = Localizer(LAMPS, LocalizerConfig())
    a = [p.chainage_m for p in feed_localizer(loc, events)[0]]
    b = [p.chainage_m for p in feed_localizer(ref, events)[0]]
    assert not loc.survey.applied and a == b


# --------------------------------------------------------------- the file
def saved(**kw):
    values = dict(vehicle_id='train_7', disparity_offset_px=0.41,
                  disparity_offset_sigma_px=0.04, stereo_scale_error=-0.0012,
                  stereo_scale_sigma=0.0008, camera_fx_b_px_m=124.8, runs=2)
    values.update(kw)
    return SavedCalibration(**values)


def test_file_round_trip_and_first_run(tmp_path):
    path = tmp_path / 'cal' / 'self_calibration.yaml'
    assert load_saved_calibration(path, 'train_7') is None
    save_calibration(path, saved())
    back = load_saved_calibration(path, 'train_7')
    assert dataclasses.replace(back, written='') == saved()
    assert back.written


@pytest.mark.parametrize('text,field', [
    ('vehicle_id: [unclosed', 'does not parse'),
    ('- a list', 'not a mapping'),
    ('vehicle_id: train_7\n', 'disparity_offset_px: missing'),
    ('disparity_offset_sigma_px: -1.0', 'disparity_offset_sigma_px: must be > 0'),
    ('stereo_scale_error: .nan', 'stereo_scale_error: not finite'),
    ('disparity_offset_px: abc', 'disparity_offset_px: '),
    ('vehicle_id: train_9', "vehicle_id: 'train_9' is another vehicle"),
])
def test_bad_files_are_refused_naming_file_and_field(tmp_path, text, field):
    path = tmp_path / 'self_calibration.yaml'
    save_calibration(path, saved())
    import yaml
    if text.startswith(('vehicle_id: [', '- ')) or text == 'vehicle_id: train_7\n':
        path.write_text(text)
    else:
        data = yaml.safe_load(path.read_text())
        data.update(yaml.safe_load(text))
        path.write_text(yaml.safe_dump(data))
    with pytest.raises(SelfCalibrationFileError) as info:
        load_saved_calibration(path, 'train_7')
    assert str(path) in str(info.value) and field in str(info.value)
