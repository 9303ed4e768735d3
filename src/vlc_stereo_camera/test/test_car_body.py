"""Car body on its secondary suspension (core/car_body.py).

References independent of the harmonic solution: numerical integration (scipy) of each
mode's equation of motion driven by the irregularity under the wheelsets, the closed-form
peak of a damped base-excited oscillator, the static geometry of a rigid body on two
bogies, numerical derivatives along a motion profile.
"""
import numpy as np
import pytest
from scipy.integrate import solve_ivp

from vlc_common.core.alignment import Alignment
from vlc_stereo_camera.core.car_body import (
    MODES,
    CarBody,
    CarBodyConfig,
    motion_statistics,
    transfer,
)
from vlc_stereo_camera.core.imu_model import true_imu_signals
from vlc_stereo_camera.core.track_irregularity import (
    IrregularityConfig,
    TrackIrregularity,
)
from vlc_stereo_camera.core.trajectory import MotionProfile, Trajectory

UNBOUNDED = dict(lateral_play_m=np.inf)
#: Mode → (irregularity channel, 'mean' of the bogies or 'difference'/2a, sign), as the
#: module docstring defines the modes' excitation.
EXCITATION = {'bounce': (0, 'mean', 1.0), 'pitch': (0, 'difference', -1.0),
              'roll': (2, 'mean', 1.0), 'sway': (1, 'mean', 1.0),
              'yaw': (1, 'difference', 1.0)}


def _bogie_inputs(irregularity, config, s, v):
    """Mode inputs (value, rate) at platform chainage s, speed v: each bogie the mean of
    its two wheelsets, bogies at s − L ± a.
    """
    a = 0.5 * config.bogie_centre_distance_m
    w = 0.5 * config.wheelbase_m
    centre = s - config.platform_ahead_m
    r, r_s, _ = irregularity.evaluate([centre + a + w, centre + a - w, centre - a + w,
                                       centre - a - w])
    front, rear = 0.5 * (r[0] + r[1]), 0.5 * (r[2] + r[3])
    front_dot, rear_dot = 0.5 * (r_s[0] + r_s[1]) * v, 0.5 * (r_s[2] + r_s[3]) * v
    out = {}
    for mode, (c, kind, sign) in EXCITATION.items():
        if kind == 'mean':
            out[mode] = (sign * 0.5 * (front[c] + rear[c]),
                         sign * 0.5 * (front_dot[c] + rear_dot[c]))
        else:
            out[mode] = (sign * (front[c] - rear[c]) / (2 * a),
                         sign * (front_dot[c] - rear_dot[c]) / (2 * a))
    return out


def _platform(config, modes):
    """Platform (x, y, z, roll, pitch, yaw) of the mode coordinates, r = (L, 0, −h)."""
    length, height = config.platform_ahead_m, config.body_reference_height_m
    return np.stack([-modes['pitch'] * height,
                     modes['sway'] + modes['yaw'] * length + modes['roll'] * height,
                     modes['bounce'] - modes['pitch'] * length,
                     modes['roll'], modes['pitch'], modes['yaw']], axis=-1)


@pytest.mark.parametrize('mode, channel, wavelength_m, axis', [
    ('bounce', 0, 12.6, 2), ('pitch', 0, 25.2, 4), ('roll', 2, 12.6, 3),
    ('sway', 1, 12.6, 1), ('yaw', 1, 25.2, 5)])
def test_each_mode_resonates_at_its_configured_frequency(mode, channel, wavelength_m, axis):
    """A single harmonic of the track swept through in speed (wavelengths that excite one
    mode alone: bogie spacing 12.6 m cancels pitch and yaw at λ = 12.6 m, bounce, sway and
    roll at λ = 25.2 m): the platform's response peaks within 10 % of the mode's natural
    frequency — at the damped base-excitation maximum f_n·√(√(1 + 8ζ²) − 1)/(2ζ).
    """
    config = CarBodyConfig(**UNBOUNDED)
    amplitudes = np.zeros((3, 1))
    amplitudes[channel, 0] = 1e-3
    body = CarBody(config, TrackIrregularity.from_components([2 * np.pi / wavelength_m],
                                                             amplitudes, np.zeros((3, 1))))
    s = np.linspace(0.0, wavelength_m, 65)[:-1]
    f = np.arange(0.3, 3.0, 0.002)
    # Amplitude of the sinusoidal response: √2 × its RMS over one period (exact).
    gain = np.array([np.sqrt(2.0 * np.mean(body.evaluate(s, s, fi * wavelength_m, 0.0)[0][:, axis]
                                           ** 2)) for fi in f])
    f_peak = f[np.argmax(gain)]
    f_n, zeta = config.frequencies_hz[mode], config.damping[mode]
    assert f_peak == pytest.approx(f_n, rel=0.10)
    theory = f_n * np.sqrt(np.sqrt(1 + 8 * zeta ** 2) - 1) / (2 * zeta)
    assert f_peak == pytest.approx(theory, abs=0.003)
    # Only this mode moves the platform: the other angles stay zero.
    others = [k for k in (3, 4, 5) if k != axis]
    q = body.evaluate(s, s, f_n * wavelength_m, 0.0)[0]
    assert np.abs(q[:, others]).max() < 1e-15


def test_harmonic_solution_is_the_steady_state_of_the_equations_of_motion():
    """At constant speed each mode is the steady state of q̈ + 2ζω_n·q̇ + ω_n²·q =
    ω_n²·u + 2ζω_n·u̇, u from the irregularity under the wheelsets — integrated here with
    scipy (DOP853) from rest; after the transient the platform agrees to 1e-6 of its RMS.
    """
    config = CarBodyConfig(seed=4, components_per_octave=8, **UNBOUNDED)
    body = CarBody(config)
    v = 70.0 / 3.6

    def rhs(t, y):
        u = _bogie_inputs(body.irregularity, config, v * t, v)
        dy = np.empty(10)
        for i, mode in enumerate(MODES):
            wn, zeta = 2 * np.pi * config.frequencies_hz[mode], config.damping[mode]
            dy[2 * i] = y[2 * i + 1]
            dy[2 * i + 1] = wn * wn * (u[mode][0] - y[2 * i]) \
                + 2 * zeta * wn * (u[mode][1] - y[2 * i + 1])
        return dy

    t = np.linspace(20.0, 24.0, 201)
    sol = solve_ivp(rhs, (0.0, t[-1]), np.zeros(10), method='DOP853', rtol=1e-10,
                    atol=1e-13, t_eval=t)
    ode = _platform(config, {mode: sol.y[2 * i] for i, mode in enumerate(MODES)})
    q, qd, _ = body.evaluate(t, v * t, v, 0.0)
    for k in range(6):
        assert np.abs(q[:, k] - ode[:, k]).max() < 1e-6 * ode[:, k].std() + 1e-15, k
    ode_rate = _platform(config, {mode: sol.y[2 * i + 1] for i, mode in enumerate(MODES)})
    np.testing.assert_allclose(qd, ode_rate, atol=1e-6 * np.abs(ode_rate).max())


def test_standing_car_rests_on_the_static_track_geometry():
    """At standstill no motion, and the platform pose is the rigid body on the bogies."""
    config = CarBodyConfig(seed=3, **UNBOUNDED)
    body = CarBody(config)
    s = np.linspace(100.0, 400.0, 31)
    q, qd, qdd = body.evaluate(s, s, 0.0, 0.0)
    np.testing.assert_array_equal(qd, 0.0)
    np.testing.assert_array_equal(qdd, 0.0)
    for n, chainage in enumerate(s):
        static = {m: u[0] for m, u in _bogie_inputs(body.irregularity, config, chainage,
                                                    0.0).items()}
        np.testing.assert_allclose(q[n], _platform(config, static), atol=1e-15)


def test_motion_grows_with_speed_from_40_to_120_kmh():
    """Dynamic motion (response minus the standing car's static geometry) and its rates
    grow with speed on every axis but roll; roll peaks where its 0.9 Hz meets the
    cross-level spectrum's most energetic wavelengths (≈ 14 m: about 45 km/h).
    """
    body = CarBody(CarBodyConfig(seed=1, **UNBOUNDED))
    s = np.arange(0.0, 3000.0, 0.5)
    static = body.evaluate(s, s, 0.0, 0.0)[0]
    dyn, rate = {}, {}
    for kmh in (20.0, 40.0, 80.0, 120.0):
        q, qd, _ = body.evaluate(s, s, kmh / 3.6, 0.0)
        dyn[kmh], rate[kmh] = (q - static).std(axis=0), qd.std(axis=0)
    for k in (0, 1, 2, 4, 5):                              # x, y, z, pitch, yaw
        assert dyn[40.0][k] < dyn[80.0][k] < dyn[120.0][k], k
        assert rate[40.0][k] < rate[80.0][k] < rate[120.0][k], k
    assert dyn[40.0][3] > max(dyn[20.0][3], dyn[120.0][3])
    # Harsh = 3× the amplitudes (linear model; play unbounded here).
    harsh = CarBody(CarBodyConfig(seed=1, scale=3.0, **UNBOUNDED))
    np.testing.assert_allclose(harsh.evaluate(s[:500], s[:500], 20.0, 0.0)[0],
                               3.0 * body.evaluate(s[:500], s[:500], 20.0, 0.0)[0],
                               rtol=1e-9, atol=1e-15)


def test_lateral_play_relative_to_the_track_is_bounded():
    """|y − y_track(s)| < 10 mm even on a track 10× the standard's amplitude; on the
    standard track the bound hardly acts (the linear response).
    """
    s = np.arange(0.0, 2000.0, 0.5)
    rough = CarBody(CarBodyConfig(seed=2, scale=10.0))
    track = rough.irregularity.values(s)[:, 1]
    for kmh in (0.0, 60.0, 120.0):
        q, _, _ = rough.evaluate(s, s, kmh / 3.6, 0.0)
        relative = q[:, 1] - track
        assert np.abs(relative).max() < 0.010
        assert np.abs(relative).max() > 0.009                # the bound is reached
    smooth = CarBody(CarBodyConfig(seed=2))
    free = CarBody(CarBodyConfig(seed=2, **UNBOUNDED))
    q_bounded = smooth.evaluate(s, s, 60.0 / 3.6, 0.0)[0][:, 1]
    q_free = free.evaluate(s, s, 60.0 / 3.6, 0.0)[0][:, 1]
    small = np.abs(q_free - track / 10.0) < 0.002
    np.testing.assert_allclose(q_bounded[small], q_free[small], atol=6e-5)


@pytest.mark.parametrize('play', [0.010, np.inf])
def test_derivatives_match_finite_differences_through_speed_changes(play):
    """q̇, q̈ = numerical derivatives of q along dwell, acceleration, cruise and braking."""
    body = CarBody(CarBodyConfig(seed=6, spectrum='german_high', lateral_play_m=play))
    profile = MotionProfile('accel_cruise_brake', start_chainage_m=50.0, speed_mps=25.0,
                            accel_mps2=1.0, brake_mps2=1.2, dwell_s=2.0, cruise_s=8.0)
    t = np.array([1.0, 3.3, 9.7, 20.0, 28.1, 33.0, 39.5, 55.0])

    def motion(times):
        s, v, a = profile.evaluate(times)
        return body.evaluate(times, s, v, a)

    h = 1e-4
    lo, mid, hi = motion(t - h), motion(t), motion(t + h)
    np.testing.assert_allclose((hi[0] - lo[0]) / (2 * h), mid[1],
                               atol=2e-6 * np.abs(mid[1]).max())
    np.testing.assert_allclose((hi[1] - lo[1]) / (2 * h), mid[2],
                               atol=2e-5 * np.abs(mid[2]).max())
    assert np.abs(mid[2][:, 2]).max() > 0.05               # really vibrating


def test_transfer_function_derivatives():
    w = np.linspace(-15.0, 15.0, 301)
    h = 1e-5
    H, H1, H2 = transfer(w, 1.2, 0.2)
    np.testing.assert_allclose((transfer(w + h, 1.2, 0.2)[0] - transfer(w - h, 1.2, 0.2)[0])
                               / (2 * h), H1, atol=1e-8)
    np.testing.assert_allclose((transfer(w + h, 1.2, 0.2)[1] - transfer(w - h, 1.2, 0.2)[1])
                               / (2 * h), H2, atol=1e-7)
    assert H[150] == 1.0 and H1[150] == 0.0                 # ω = 0: static, smooth start
    np.testing.assert_allclose(H[::-1], np.conj(H), atol=1e-15)


def test_seeded_and_plugs_into_the_trajectory():
    """Same seed, same motion; the car body drives Trajectory (curved, canted, graded) with
    consistent kinematics, and the IMU model takes it unchanged.
    """
    config = CarBodyConfig(seed=7, spectrum='fra_5', scale=3.0)
    s = np.linspace(0.0, 500.0, 101)
    a = CarBody(config).evaluate(s, s, 15.0, 0.0)
    b = CarBody(CarBodyConfig(seed=7, spectrum='fra_5', scale=3.0)).evaluate(s, s, 15.0, 0.0)
    c = CarBody(CarBodyConfig(seed=8, spectrum='fra_5', scale=3.0)).evaluate(s, s, 15.0, 0.0)
    for x, y in zip(a, b):
        np.testing.assert_array_equal(x, y)
    assert np.all(a[0][:, 2] != c[0][:, 2])
    traj = Trajectory(MotionProfile('accel_cruise_brake', start_chainage_m=150.0,
                                    speed_mps=20.0, dwell_s=1.0, cruise_s=20.0),
                      CarBody(config), Alignment.named('curved_demo'))
    t = np.array([0.5, 3.0, 11.5, 19.0, 27.0, 40.0])         # away from element joints
    h = 1e-4
    lo, mid, hi = traj.sample(t - h), traj.sample(t), traj.sample(t + h)
    np.testing.assert_allclose((hi.position_m - lo.position_m) / (2 * h), mid.velocity_mps,
                               atol=1e-6)
    # Central differences lose ~ (hω)²/6 on the 1 m waves met at 20 Hz: relative 3e-5.
    np.testing.assert_allclose((hi.velocity_mps - lo.velocity_mps) / (2 * h),
                               mid.acceleration_mps2,
                               atol=1e-4 * np.abs(mid.acceleration_mps2).max())
    W = np.einsum('nji,njk->nik', mid.R_map_base, (hi.R_map_base - lo.R_map_base) / (2 * h))
    omega = np.stack([W[:, 2, 1], W[:, 0, 2], W[:, 1, 0]], axis=1)
    np.testing.assert_allclose(omega, mid.angular_velocity_body_rps, atol=1e-7)
    gyro, force = true_imu_signals(traj, t)
    assert gyro.shape == force.shape == (6, 3) and np.all(np.isfinite(force))


def test_motion_statistics_reports_every_axis():
    stats = motion_statistics(CarBodyConfig(seed=1), speeds_kmh=(20.0, 120.0),
                              distance_m=400.0)
    assert set(stats) == {20.0, 120.0}
    for axes in stats.values():
        for name in ('x', 'y', 'z', 'roll', 'pitch', 'yaw'):
            assert 0.0 < axes[name]['rms'] <= axes[name]['peak']
    assert stats[120.0]['yaw']['rate_rms'] > stats[20.0]['yaw']['rate_rms']
    assert IrregularityConfig().spectrum == CarBodyConfig().spectrum
