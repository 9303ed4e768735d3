"""The car body's motion across and above the track, from the IMU (core/cross_track.py),
and the published lateral/vertical 1σ that covers it.
"""
import math

import numpy as np
import pytest

from train_localizer.core.cross_track import CrossTrackMotion

G = 9.80665


def feed(motion, t, f_lat, f_vert):
    for ti, fy, fz in zip(t, f_lat, f_vert):
        motion.add(float(ti), float(fy), float(fz))
    return motion.sigma_m()


@pytest.mark.parametrize('f_hz', [1.0, 2.5])
def test_a_bounce_above_the_corner_reads_as_its_rms_displacement(f_hz):
    t = np.arange(0.0, 12.0, 1.0 / 400.0)
    amp = 0.02
    w = 2.0 * math.pi * f_hz
    a = -amp * w * w * np.sin(w * t)                    # z = amp·sin(ωt)
    lat, vert = feed(CrossTrackMotion(0.5, 2.0), t, 0.1 * a, G + a)
    rms = amp / math.sqrt(2.0)
    # |ω²·jω/(jω + ω_c)³| = 1/(1 + (ω_c/ω)²)^1.5 of it
    gain = (1.0 + (0.5 / f_hz) ** 2) ** -1.5
    assert vert == pytest.approx(rms * gain, rel=0.1)
    assert lat == pytest.approx(0.1 * rms * gain, rel=0.1)


def test_gravity_a_bias_or_a_standing_train_read_as_no_motion():
    t = np.arange(0.0, 12.0, 1.0 / 400.0)
    noise = 0.002 * np.random.default_rng(3).standard_normal(t.size)   # accelerometer noise
    tilt = math.radians(2.0)                           # a standing body, rolled 2°
    lat, vert = feed(CrossTrackMotion(), t, G * math.sin(tilt) + 0.01 + noise,
                     G * math.cos(tilt) + noise)
    assert lat < 0.3e-3 and vert < 0.3e-3


def test_a_curve_and_its_transition_read_as_no_motion():
    """Centripetal acceleration ramping to 1 m/s² through a 3 s transition, then steady:
    metres of 'displacement' to a plain double integrator; here about a centimetre while
    the ramp starts and ends (its slope is a step), none in the curve.
    """
    t = np.arange(0.0, 20.0, 1.0 / 400.0)
    a = np.clip((t - 2.0) / 3.0, 0.0, 1.0)
    m = CrossTrackMotion()
    sigmas = [m.sigma_m()[0] for _ in feed_each(m, t, a, np.full_like(t, G))]
    assert max(sigmas) < 12e-3 and sigmas[-1] < 0.5e-3


def feed_each(motion, t, f_lat, f_vert):
    for ti, fy, fz in zip(t, f_lat, f_vert):
        motion.add(float(ti), float(fy), float(fz))
        yield ti


def test_a_gap_restarts_the_filter_instead_of_integrating_across_it():
    m = CrossTrackMotion(0.5, 2.0, max_gap_s=0.05)
    t = np.arange(0.0, 6.0, 1.0 / 400.0)
    feed(m, t, np.zeros_like(t), G + 0.5 * np.sin(2 * math.pi * 1.5 * t))
    moving = m.sigma_m()[1]
    assert moving > 1e-3
    m.add(5.0, 0.0, G + 5.0)                           # older: ignored
    assert m.sigma_m()[1] == moving
    m.add(10.0, 0.0, G)                  # after a 4 s gap: a restart, nothing until settled
    assert m.sigma_m() == (0.0, 0.0)
    t2 = 10.0 + np.arange(1, 400 * 6) / 400.0
    feed(m, t2, np.zeros_like(t2), G + 0.5 * np.sin(2 * math.pi * 1.5 * t2))
    assert m.sigma_m()[1] == pytest.approx(moving, rel=0.2)
    with pytest.raises(ValueError):
        CrossTrackMotion(highpass_hz=0.0)
