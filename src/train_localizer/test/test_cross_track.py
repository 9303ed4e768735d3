"""The car body's motion across and above the track, from the IMU (core/cross_track.py),
and the published lateral/vertical 1σ that covers it.
"""
import math

import numpy as np
import pytest

from train_localizer.core.cross_track import GRAVITY_MPS2, CrossTrackMotion, lateral_vertical
from vlc_common.core.rotations import quat_from_rpy, quat_to_matrix


def feed(motion, t, a_lat, a_vert):
    for ti, ay, az in zip(t, a_lat, a_vert):
        motion.add(float(ti), float(ay), float(az))
    return motion.sigma_m()


@pytest.mark.parametrize('f_hz', [1.0, 2.5])
def test_a_bounce_above_the_corner_reads_as_its_rms_displacement(f_hz):
    t = np.arange(0.0, 12.0, 1.0 / 400.0)
    amp = 0.02
    w = 2.0 * math.pi * f_hz
    a = -amp * w * w * np.sin(w * t)                    # z = amp·sin(ωt)
    lat, vert = feed(CrossTrackMotion(0.5, 2.0), t, 0.1 * a, a)
    rms = amp / math.sqrt(2.0)
    # the two leaky integrators pass |ω²/(jω + ω_c)²| = 1/(1 + (ω_c/ω)²) of it
    gain = 1.0 / (1.0 + (0.5 / f_hz) ** 2)
    assert vert == pytest.approx(rms * gain, rel=0.1)
    assert lat == pytest.approx(0.1 * rms * gain, rel=0.1)


def test_a_bias_or_a_standing_train_reads_as_no_motion():
    t = np.arange(0.0, 12.0, 1.0 / 400.0)
    rng = np.random.default_rng(3)
    noise = 0.002 * rng.standard_normal(t.size)         # accelerometer white noise
    lat, vert = feed(CrossTrackMotion(), t, 0.01 + noise, -0.02 + noise)
    assert lat < 0.5e-3 and vert < 0.5e-3


def test_a_gap_restarts_the_integrators_instead_of_integrating_across_it():
    m = CrossTrackMotion(0.5, 2.0, max_gap_s=0.05)
    t = np.arange(0.0, 6.0, 1.0 / 400.0)
    feed(m, t, np.zeros_like(t), np.full_like(t, 0.05))
    steady = m.sigma_m()[1]
    m.add(10.0, 0.0, 5.0)                               # after a 4 s gap: not integrated
    assert m.sigma_m()[1] == steady
    m.add(9.0, 0.0, 5.0)                                # older: ignored
    assert m.sigma_m()[1] == steady
    with pytest.raises(ValueError):
        CrossTrackMotion(highpass_hz=0.0)


def test_lateral_is_square_to_the_heading_and_vertical_has_gravity_removed():
    # level, heading 90°: body x = map y; a body-left force (body +y) = map −x = left of it
    q = quat_from_rpy(0.0, 0.0, math.pi / 2)
    lat, vert = lateral_vertical(q, (0.0, 0.3, GRAVITY_MPS2))
    assert lat == pytest.approx(0.3) and vert == pytest.approx(0.0, abs=1e-12)
    # pitched 10° and rolled 5° at rest: the body reads gravity on its tilted axes; none
    # of it is motion
    q = quat_from_rpy(math.radians(5.0), math.radians(10.0), 0.3)
    f_body = quat_to_matrix(q).T @ np.array([0.0, 0.0, GRAVITY_MPS2])
    lat, vert = lateral_vertical(q, tuple(f_body))
    assert lat == pytest.approx(0.0, abs=1e-9) and vert == pytest.approx(0.0, abs=1e-9)
