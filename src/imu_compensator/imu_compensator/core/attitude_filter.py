"""Error-state Kalman filter for the camera-platform attitude and the gyro bias.

State: attitude quaternion ``q`` (``base_link`` → ``map``, x, y, z, w), gyro bias
``b`` (rad/s, ``base_link`` axes) and gyro scale-factor errors ``k`` (per axis, the rate
is ``(reading − b)·(1 − k)``). Error state (9,): ``δθ`` — a small rotation about the
*map* axes, ``R_true = Exp(δθ) · R_est`` — ``δb = b_true − b_est`` and ``δk``. Working
in the map frame keeps roll/pitch and heading errors on separate axes, which is what the
track-attitude references below act on.

Why this structure (paper §3.3.2: the camera heading is disturbed by −5.0…+7.5° by the
car-body vibration and must be compensated with the IMU):

* Fast attitude — the 0.3–3 Hz vibration — comes from integrating the gyro; it is
  exact up to the gyro's scale-factor error (ADIS16488: 1 %, 1σ), which scales the
  integrated sway. The track references below cannot see it (they only know the slow
  mean); an external attitude (the lamps') can, while the platform sways, so it is
  estimated as three more states.
* Slow attitude comes from the *track*: on a known alignment the platform's roll,
  pitch and heading relative to the track have a zero slow mean at speed (plus a known
  heading offset), so each is pulled toward the track attitude with a long time
  constant τ. This removes the drift of the gyro integral (turn-on and in-run bias)
  while the pull barely follows the vibration. The pulls use the innovation
  averaged over a sliding window of ``pull_window_s`` (W) — a moving average, not
  blocks, which would alias the sway to slow beats: a sinusoid of amplitude A and
  angular frequency ω then leaks into the estimate with amplitude
  ≈ A·|sinc(ωW/2π)| / (ωτ) instead of A/(ωτ), ≈ 10× less for the 0.45 Hz heading sway
  with W = 2 s. Buffered innovations are kept consistent with later corrections
  (each entry stores innovation + the cumulative correction at its time). There is no
  magnetometer in a tunnel, so heading has no other absolute reference; the residual
  drift of the gyro bias through τ is the other side of the trade-off. The window mean
  is the error about W/2 in the past; with a gyro-bias error it ramps meanwhile, so the
  pull's measurement row carries the bias coupling (see :meth:`AttitudeFilter._pull_lag`).
* Gravity is an optional tilt reference (off by default): the ADIS16488 turn-on
  accelerometer bias (16 mg, 1σ) alone tilts the gravity vector by ≈ 0.9°, and the
  train's 1 m/s² traction/braking by ≈ 5.8°, both far more than the track reference's
  error.
* The gyro bias is refined whenever the train stands still (zero-angular-rate update,
  the mean gyro reading over each update period) and, more slowly, through the pulls.

Every update period Δ a pull is a pseudo-measurement ``z = mean over the last W of
(angle_ref − angle_est)`` with variance ``R = q_g · τ² / Δ`` (q_g: gyro white-noise
density²). For a first-order loop driven by the gyro noise this is the measurement
variance whose steady-state Kalman gain is Δ/τ, i.e. whose time constant is τ.

The quaternion is integrated at every sample (trapezoidal rate, pure-Python floats:
a few µs); the covariance is propagated and the updates applied once per
``update_period_s``, using the exact composition of the per-sample transition
matrices (their attitude–bias blocks add up).
"""
from collections import deque
from dataclasses import dataclass, replace
import math

import numpy as np

from vlc_common.core.rotations import (
    quat_from_rotvec,
    quat_from_rpy,
    quat_multiply,
    quat_normalize,
    quat_to_matrix,
)

GRAVITY_MPS2 = 9.80665
#: Error state: attitude about the map axes (3), gyro bias (3), gyro scale factors (3).
N_STATES = 9
#: An aid "sees" a pull axis when its information along it is at least 1/this², rad
#: (see ``pull_pause_after_aiding_s``).
AIDED_AXIS_STD_RAD = 0.5 * math.pi / 180.0
#: Time constant with which the running sway level of the pull gate is forgotten, s.
SWAY_MEMORY_S = 600.0
#: The sway gate looks at this newest fraction of the pull window: less lag when the
#: sway fades while braking (the offset fades with it), still several sway periods long.
SWAY_GATE_FRACTION = 0.5
_DEG = math.pi / 180.0


@dataclass
class AttitudeFilterConfig:
    """Noise model, references and tuning of :class:`AttitudeFilter` (SI, radians).

    Attributes
    ----------
    gyro_noise_density_rps_rthz : float
        Gyro white-noise density (angle random walk), rad/s/√Hz. ADIS16488: 0.26 °/√h.
    gyro_bias_random_walk_rps2_rthz : float
        Density of the bias random walk the filter assumes, rad/s²/√Hz (rad/s/√s); it
        stands in for the sensor's in-run bias wander (a 5.1 °/h flicker floor).
    initial_gyro_bias_rps : tuple of 3 floats
        Bias the filter starts from, rad/s (a calibration, if one is known).
    initial_gyro_bias_std_rps : float
        1σ of the bias at start, rad/s. ADIS16488 turn-on bias: 0.2 °/s.
    gyro_scale_factor_std : float
        1σ of each gyro axis' scale-factor error at start (ADIS16488: 1 %); estimated
        as three more states, observable only through attitude aiding while the
        platform sways; 0 = not estimated.
    initial_attitude_std_rad : tuple of 3 floats
        1σ of roll, pitch, heading at a cold start, rad: the filter starts at the
        track attitude, but a moving platform may be anywhere in its sway envelope, so
        the first full pull window sets the attitude.
    aligned_attitude_std_rad : tuple of 3 floats
        1σ of roll, pitch, heading after a static alignment (standing on the track:
        only the track irregularity separates platform and track), rad. Small, so that
        after departure the pulls act at their time constant instead of chasing the
        sway with an optimal but over-confident gain.
    tilt_time_constant_s : float
        τ of the roll and pitch pull toward the track attitude while moving, s; 0 = off.
    heading_time_constant_s : float
        τ of the heading pull toward the track heading (+ offset) while moving, s;
        0 = off.
    pull_window_s : float
        W: the pull innovations are averaged over this much moving time, s.
    pull_hold_s : float
        The pulls act only while moving, and only once the train has been moving for
        this long (the window then fills, so the first pull comes ``pull_hold_s + W``
        after departure), s. Standing, the attitude is held and the bias learnt from
        the zero-rate update; the track irregularity under a standing train is a
        constant offset that a pull would turn into an error. Right after departure
        the car body has not reached its running attitude (the rig scales the sway
        and the heading offset with speed up to 20 km/h, 5.6 s at 1 m/s²), so pulling
        toward the running heading offset then would bias the heading.
    pull_min_sway_ratio : float
        The pulls act only while the RMS of the bias-corrected angular rate over the
        newest half of the pull window (the car-body sway) is at least this fraction of
        the running sway level (the largest whole-window RMS seen, forgotten with time
        constant ``SWAY_MEMORY_S``). The sway is the IMU's own evidence that the train runs at
        speed, where the slow-mean assumption holds: the rig's sway (≈ 0.22 rad/s RMS
        from 20 km/h) and heading offset both fade below 20 km/h, so 0.8 stops the
        pulls under ≈ 16 km/h, e.g. while braking to a stop — a pull toward the offset
        then would leave ≈ 0.3° of error for the whole following standstill. 0 disables.
    pull_min_sway_rps : float
        Absolute floor of that gate, rad/s (well above the gyro noise).
    pull_pause_after_aiding_s : float
        A pull (roll, pitch or heading) pauses for this long after an external aiding
        that sees its axis (information along it of at least 1/``AIDED_AXIS_STD_RAD``²),
        s; 0 = never. An aid measures the attitude itself, the pull only its slow mean
        with the sway leaking in (its gain grows with the attitude variance, e.g. the
        scale factors' share of it), so where lamps are in view the pulls add error;
        they resume in a lamp outage, and a heading-only aid leaves the tilt pulls on.
    track_roll_rad, track_pitch_rad, track_heading_rad : float
        Track attitude in ``map`` (cant, grade as nose-down pitch, direction); 0, 0, 0
        on the default straight level track.
    heading_offset_rad : float
        Known slow mean of the platform heading relative to the track while moving
        (rig default 1.25°, the centre of the −5.0…+7.5° disturbance), rad.
    gravity_time_constant_s : float
        τ of the optional gravity (accelerometer) tilt reference, s; 0 = off.
    gravity_gate_mps2 : float
        A gravity update is skipped when | |mean f| − g | exceeds this, m/s².
    update_period_s : float
        Covariance propagation and zero-rate / gravity updates happen this often, s.
    zero_rate_std_rps : float
        1σ of one gyro sample in the zero-rate update, rad/s; ≤ 0 uses the white
        noise per sample (density·√rate).
    gravity_mps2 : float
        Local gravity, m/s².
    """

    gyro_noise_density_rps_rthz: float = 0.26 * _DEG / 60.0
    gyro_bias_random_walk_rps2_rthz: float = 2.0e-6
    initial_gyro_bias_rps: tuple = (0.0, 0.0, 0.0)
    initial_gyro_bias_std_rps: float = 0.2 * _DEG
    gyro_scale_factor_std: float = 0.02
    initial_attitude_std_rad: tuple = (0.5 * _DEG, 0.5 * _DEG, 5.0 * _DEG)
    aligned_attitude_std_rad: tuple = (0.02 * _DEG, 0.02 * _DEG, 0.02 * _DEG)
    tilt_time_constant_s: float = 10.0
    heading_time_constant_s: float = 10.0
    pull_window_s: float = 4.0
    pull_hold_s: float = 6.0
    pull_min_sway_ratio: float = 0.8
    pull_min_sway_rps: float = 0.02
    pull_pause_after_aiding_s: float = 4.0
    track_roll_rad: float = 0.0
    track_pitch_rad: float = 0.0
    track_heading_rad: float = 0.0
    heading_offset_rad: float = 1.25 * _DEG
    gravity_time_constant_s: float = 0.0
    gravity_gate_mps2: float = 1.0
    update_period_s: float = 0.05
    zero_rate_std_rps: float = 0.0
    gravity_mps2: float = GRAVITY_MPS2

    def __post_init__(self):
        positive = ('gyro_noise_density_rps_rthz', 'initial_gyro_bias_std_rps',
                    'pull_window_s', 'gravity_gate_mps2', 'update_period_s', 'gravity_mps2')
        non_negative = ('gyro_bias_random_walk_rps2_rthz', 'gyro_scale_factor_std',
                        'tilt_time_constant_s', 'pull_hold_s', 'pull_pause_after_aiding_s',
                        'pull_min_sway_rps', 'pull_min_sway_ratio',
                        'heading_time_constant_s', 'gravity_time_constant_s')
        for name in positive:
            if not (math.isfinite(getattr(self, name)) and getattr(self, name) > 0.0):
                raise ValueError(f'{name} must be finite and > 0, got {getattr(self, name)}')
        for name in non_negative:
            if not (math.isfinite(getattr(self, name)) and getattr(self, name) >= 0.0):
                raise ValueError(f'{name} must be finite and >= 0, got {getattr(self, name)}')
        for name in ('initial_gyro_bias_rps', 'initial_attitude_std_rad',
                     'aligned_attitude_std_rad'):
            if len(getattr(self, name)) != 3:
                raise ValueError(f'{name} needs 3 values')
        if min(self.initial_attitude_std_rad) <= 0.0 or min(self.aligned_attitude_std_rad) <= 0.0:
            raise ValueError('initial_attitude_std_rad and aligned_attitude_std_rad must be > 0')
        for tau in (self.tilt_time_constant_s, self.heading_time_constant_s):
            if 0.0 < tau < self.pull_window_s:
                raise ValueError('pull time constants must be 0 (off) or >= pull_window_s')
        if self.update_period_s > self.pull_window_s:
            raise ValueError('update_period_s must not exceed pull_window_s')


def pulls_on_alignment(config, alignment):
    """(config, note): ``config`` (AttitudeFilterConfig) for a platform running on
    ``alignment`` (``vlc_common.core.alignment.Alignment``).

    The pulls hold the attitude's slow mean to one constant track attitude
    (``track_roll_rad``, ``track_pitch_rad``, ``track_heading_rad``): right on a straight,
    level track only. On curves, grades or cant the track's attitude changes along it
    and the compensator does not know the chainage, so a pull would drag the estimate
    toward a wrong attitude wherever no lamp aids it: with them on curved_demo its
    heading ended 20-30° off and its pitch 1.6° (the grade) in a dark stretch, while its
    covariance said 0.1°, and the localizer's dead reckoning through it was 30 m off.
    There both pulls are off (``note`` says so; None when nothing changed): the attitude
    follows the gyro, kept right by the lamps' attitude aids.
    """
    if alignment.is_straight and alignment.is_level:
        return config, None
    if config.tilt_time_constant_s == 0.0 and config.heading_time_constant_s == 0.0:
        return config, None
    name = getattr(alignment, 'name', 'custom')
    return (replace(config, tilt_time_constant_s=0.0, heading_time_constant_s=0.0),
            f'alignment {name} has curves, grade or cant: the pulls toward one constant '
            'track attitude are off; the attitude follows the gyro and the lamps\' aids')


def left_jacobian(phi):
    """J_l(φ) of SO(3): Exp(φ + δ) = Exp(J_l(φ)·δ)·Exp(φ) + O(δ²)."""
    phi = np.asarray(phi, dtype=float)
    angle = float(np.linalg.norm(phi))
    k = np.array([[0.0, -phi[2], phi[1]], [phi[2], 0.0, -phi[0]], [-phi[1], phi[0], 0.0]])
    if angle < 1e-6:
        return np.eye(3) + 0.5 * k + k @ k / 6.0
    return (np.eye(3) + (1.0 - math.cos(angle)) / angle ** 2 * k
            + (angle - math.sin(angle)) / angle ** 3 * (k @ k))


def _wrap(angle_rad):
    """Wrap a float angle to [−π, π)."""
    return (angle_rad + math.pi) % (2.0 * math.pi) - math.pi


def _rpy_of(x, y, z, w):
    """Roll, pitch, yaw of a unit quaternion (floats); R = Rz·Ry·Rx."""
    roll = math.atan2(2.0 * (w * x + y * z), 1.0 - 2.0 * (x * x + y * y))
    pitch = math.asin(max(-1.0, min(1.0, 2.0 * (w * y - z * x))))
    yaw = math.atan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))
    return roll, pitch, yaw


class AttitudeFilter:
    """ESKF over attitude and gyro bias; see the module docstring.

    Parameters
    ----------
    config : AttitudeFilterConfig
    """

    def __init__(self, config=None):
        self.config = config or AttitudeFilterConfig()
        self.initialized = False
        self._sway_ref2 = 0.0
        #: How far back a delayed aid may reach, s (the caller's attitude history).
        self.delayed_horizon_s = 2.0
        self.initialize()
        self.initialized = False

    # ------------------------------------------------------------------ set-up
    def initialize(self, gyro_rps=None, aligned_gyro_bias_rps=None, gyro_bias_std_rps=None):
        """Start at the track attitude with the configured bias and covariance.

        Parameters
        ----------
        gyro_rps : array_like (3,), optional
            Latest gyro sample, kept for the trapezoidal rate average of the next step.
        aligned_gyro_bias_rps : array_like (3,), optional
            Static alignment: the platform stands on the track and this is the mean
            rate it read meanwhile, rad/s. Starts from this bias (1σ
            ``gyro_bias_std_rps``) and ``aligned_attitude_std_rad``; otherwise a cold
            start from ``initial_gyro_bias_rps`` and ``initial_attitude_std_rad``.
        gyro_bias_std_rps : float, optional
            1σ of ``aligned_gyro_bias_rps``, rad/s.
        """
        c = self.config
        self._q = [float(v) for v in quat_normalize(
            quat_from_rpy(c.track_roll_rad, c.track_pitch_rad, c.track_heading_rad))]
        aligned = aligned_gyro_bias_rps is not None
        bias = aligned_gyro_bias_rps if aligned else c.initial_gyro_bias_rps
        bias_std = gyro_bias_std_rps if aligned else c.initial_gyro_bias_std_rps
        att_std = c.aligned_attitude_std_rad if aligned else c.initial_attitude_std_rad
        self.gyro_bias_rps = np.array(bias, dtype=float)
        self._bias = self.gyro_bias_rps.tolist()
        self.gyro_scale_error = np.zeros(3)
        self._scale = [0.0, 0.0, 0.0]
        self.P = np.zeros((N_STATES, N_STATES))
        self.P[:3, :3] = np.diag(np.square(att_std))
        self.P[3:6, 3:6] = np.eye(3) * bias_std ** 2
        # The scale factors join the estimate at the first aiding (_activate_scale):
        # nothing else sees them, and their variance in P would change the gains of the
        # pulls, which are not optimal measurements. Until then _P_true carries them: P
        # with the scale prior, propagated alike and updated with the same gains
        # (consider covariance), so the published attitude covariance includes the
        # share of the integrated sway that the scale factors leave unknown, and the
        # first aid finds the attitude-scale correlation already built.
        self._P_true = None
        if self.config.gyro_scale_factor_std > 0.0:
            self._P_true = self.P.copy()
            self._P_true[6:, 6:] = np.eye(3) * self.config.gyro_scale_factor_std ** 2
        self._last_gyro = None if gyro_rps is None else [float(v) for v in gyro_rps]
        # Every correction the updates made since the start, composed (map frame,
        # R = C·U with U the gyro integral alone): delayed aiding needs it at its stamp.
        self._correction_q = [0.0, 0.0, 0.0, 1.0]
        # ∫R dt (9, row-major) and ∫R·b dt (3, b the bias estimate in use) over the
        # integrated time, up to the last covariance flush (the rest: _sum_r_dt,
        # _sum_rb_dt); see lag_integrals.
        self._int_a = [0.0] * 9
        self._int_rb = [0.0] * 3
        self._reset_accumulators()
        self.initialized = True

    def _reset_accumulators(self):
        # Covariance propagation pending since the last flush: Σ R_i·dt_i, Σ R_i·diag(ω_i)·dt_i
        # (the scale-factor coupling) and Σ dt_i.
        self._sum_r_dt = [0.0] * 9
        self._sum_rw_dt = [0.0] * 9
        self._sum_rb_dt = [0.0] * 3
        self._pending_dt = 0.0
        self._pending_bias_dt = 0.0
        self._pending_extra_cov = np.zeros((3, 3))
        # The unknown motion over each IMU gap, kept apart for delayed aiding: per gap its
        # filter-clock time, its attitude variance Q_g (3, 3) and the covariance M_g
        # (N_STATES, 3) of the error state with it, which the propagation and every
        # update carry on like the state (a delayed aid measures the attitude before the
        # gaps after its stamp: see update_aiding).
        self._gap_terms = []
        self._pending_gap_clock_s = 0.0
        # Zero-rate update: sum of gyro readings and their count while standing.
        self._zaru_sum = [0.0, 0.0, 0.0]
        self._zaru_n = 0
        # Gravity update: sum of specific force and the moving flag of the period.
        self._grav_sum = [0.0, 0.0, 0.0]
        self._grav_n = 0
        self._grav_time = 0.0
        self._grav_moving = False
        self._since_update = 0.0
        self._since_pull = 0.0
        # Filter time since the accumulators were reset, and when an aid last saw the
        # roll, pitch and heading pull axes (see pull_pause_after_aiding_s).
        self._clock_s = 0.0
        self._aided_at_s = [-math.inf] * 3
        self._moving_s = 0.0
        self._reset_pull()

    def _reset_pull(self):
        # Cumulative roll, pitch, heading corrections applied by any update since the
        # window (re)started; each buffered innovation carries the value at its time.
        self._corr = [0.0, 0.0, 0.0]
        self._pull_ring = deque()
        # Sums over the window: roll, pitch, heading innovations, squared sway rate,
        # then A (9, row-major) and G (3) of each entry (see _accumulate_pull).
        self._pull_sum = [0.0] * 16
        self._pull_time = 0.0
        self._pull_full = False
        # Lag bookkeeping since the window (re)started: A = ∫R dt (9, row-major, the
        # bias → attitude-error coupling), the cumulative bias correction CB (3) of
        # every update, and G = ∫R·CB dt (3) kept as G_ref + (A − A_ref)·CB, exact
        # because CB only changes at an update.
        self._cum_a = [0.0] * 9
        self._bias_corr = [0.0, 0.0, 0.0]
        self._g_ref = [0.0, 0.0, 0.0]
        self._a_ref = [0.0] * 9

    # ------------------------------------------------------------------ per sample
    def step(self, gyro_rps, accel_mps2, dt_s, stationary, sample_rate_hz,
             extra_attitude_var_rad2=0.0):
        """Process one sample: integrate the gyro, accumulate and apply the updates.

        Parameters
        ----------
        gyro_rps : array_like (3,)
            Measured angular rate at the end of the interval, rad/s, ``base_link``.
        accel_mps2 : array_like (3,)
            Measured specific force, m/s², ``base_link``.
        dt_s : float
            Interval since the previous sample, s (> 0).
        stationary : bool
            Verdict of the zero-velocity detector for this sample.
        sample_rate_hz : float
            Nominal IMU rate (noise per sample in the zero-rate update), Hz.
        extra_attitude_var_rad2 : float or array_like (3,)
            Attitude variance added for unknown motion (over a gap), rad²: the same on
            every axis, or one per ``base_link`` axis (rotated into the map frame).
        """
        gx, gy, gz = (float(v) for v in gyro_rps)
        if stationary:
            # Standing still the platform does not turn: hold the attitude instead of
            # integrating noise (the bias is meanwhile learnt by the zero-rate update).
            self._last_gyro = (gx, gy, gz)
        else:
            self._propagate(gx, gy, gz, dt_s)
        self._pending_bias_dt += dt_s
        if np.any(extra_attitude_var_rad2):
            self._add_extra_attitude_variance(extra_attitude_var_rad2)
            self._pending_gap_clock_s = self._clock_s + dt_s
        c = self.config
        if stationary:
            s = self._zaru_sum
            s[0] += gx
            s[1] += gy
            s[2] += gz
            self._zaru_n += 1
        if c.gravity_time_constant_s > 0.0:
            ax, ay, az = (float(v) for v in accel_mps2)
            g = self._grav_sum
            g[0] += ax
            g[1] += ay
            g[2] += az
            self._grav_n += 1
            self._grav_time += dt_s
            self._grav_moving |= not stationary
        if stationary:
            self._moving_s = 0.0
            if self._pull_ring:
                # A standstill interrupts the window.
                self._reset_pull()
        else:
            self._moving_s += dt_s
            if self._moving_s >= c.pull_hold_s:
                b = self._bias
                sway2 = (gx - b[0]) ** 2 + (gy - b[1]) ** 2 + (gz - b[2]) ** 2
                self._accumulate_pull(dt_s, sway2)
        self._since_update += dt_s
        self._since_pull += dt_s
        self._clock_s += dt_s
        if self._since_update >= c.update_period_s:
            self._since_update = 0.0
            self._flush_covariance()
            if self._zaru_n:
                self._apply_zero_rate(sample_rate_hz)
            if self._grav_n:
                self._apply_gravity()
            if self._pull_full and self._at_speed():
                self._apply_pull(self._since_pull)
            self._since_pull = 0.0

    def _add_extra_attitude_variance(self, var_rad2):
        var = np.asarray(var_rad2, dtype=float)
        if var.ndim == 0:
            self._pending_extra_cov += np.eye(3) * float(var)
        else:
            r = quat_to_matrix(np.array(self._q))
            self._pending_extra_cov += (r * var.reshape(3)) @ r.T

    def _propagate(self, gx, gy, gz, dt):
        prev = self._last_gyro or (gx, gy, gz)
        self._last_gyro = (gx, gy, gz)
        b, k = self._bias, self._scale
        # Trapezoidal rate over the interval, minus the bias, over the scale factor;
        # q ← q ⊗ Exp(ω·dt).
        ox = (0.5 * (prev[0] + gx) - b[0]) * (1.0 - k[0])
        oy = (0.5 * (prev[1] + gy) - b[1]) * (1.0 - k[1])
        oz = (0.5 * (prev[2] + gz) - b[2]) * (1.0 - k[2])
        wx, wy, wz = ox * dt, oy * dt, oz * dt
        angle = math.sqrt(wx * wx + wy * wy + wz * wz)
        if angle > 1e-12:
            s = math.sin(0.5 * angle) / angle
            dx, dy, dz, dw = wx * s, wy * s, wz * s, math.cos(0.5 * angle)
        else:
            dx, dy, dz, dw = 0.5 * wx, 0.5 * wy, 0.5 * wz, 1.0
        x, y, z, w = self._q
        # R before the step (bias → attitude-error coupling), row-major; Σ R·dt.
        r = (1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w),
             2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w),
             2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y))
        self._step_r = r
        self._sum_r_dt = [a + b * dt for a, b in zip(self._sum_r_dt, r)]
        rb = self._sum_rb_dt
        b0, b1, b2 = b
        rb[0] += (r[0] * b0 + r[1] * b1 + r[2] * b2) * dt
        rb[1] += (r[3] * b0 + r[4] * b1 + r[5] * b2) * dt
        rb[2] += (r[6] * b0 + r[7] * b1 + r[8] * b2) * dt
        self._sum_rw_dt = [a + b * w for a, b, w in zip(
            self._sum_rw_dt, r, (wx, wy, wz, wx, wy, wz, wx, wy, wz))]
        self._pending_dt += dt
        qx = w * dx + x * dw + y * dz - z * dy
        qy = w * dy - x * dz + y * dw + z * dx
        qz = w * dz + x * dy - y * dx + z * dw
        qw = w * dw - x * dx - y * dy - z * dz
        n = math.sqrt(qx * qx + qy * qy + qz * qz + qw * qw)
        self._q = [qx / n, qy / n, qz / n, qw / n]

    def _flush_covariance(self):
        """P ← F P Fᵀ + Q for the samples since the last flush.

        F = [[I, −Σ R_i dt_i, −Σ R_i diag(ω_i) dt_i], [0, I, 0], [0, 0, I]] (map-frame
        attitude error, body-frame bias, gyro scale-factor errors); the product of such
        matrices adds their off-diagonal blocks, so it is exact.
        """
        if self._pending_bias_dt <= 0.0:
            return
        c = self.config
        f = np.eye(N_STATES)
        f[:3, 3:6] = -np.array(self._sum_r_dt).reshape(3, 3)
        f[:3, 6:] = -np.array(self._sum_rw_dt).reshape(3, 3)
        q_att = c.gyro_noise_density_rps_rthz ** 2 * self._pending_dt
        q_bias = c.gyro_bias_random_walk_rps2_rthz ** 2 * self._pending_bias_dt
        q = np.zeros((N_STATES, N_STATES))
        q[:3, :3] = np.eye(3) * q_att + self._pending_extra_cov
        q[3:6, 3:6] = np.eye(3) * q_bias
        self._map_covariances(lambda p: f @ p @ f.T + q)
        for term in self._gap_terms:
            term[2] = f @ term[2]
        if np.any(self._pending_extra_cov):
            m = np.zeros((N_STATES, 3))
            m[:3] = self._pending_extra_cov
            self._gap_terms.append([self._pending_gap_clock_s, self._pending_extra_cov, m])
        horizon = self._clock_s - self.delayed_horizon_s
        self._gap_terms = [t for t in self._gap_terms if t[0] >= horizon]
        self._int_a = [a + b for a, b in zip(self._int_a, self._sum_r_dt)]
        self._int_rb = [a + b for a, b in zip(self._int_rb, self._sum_rb_dt)]
        self._sum_r_dt = [0.0] * 9
        self._sum_rw_dt = [0.0] * 9
        self._sum_rb_dt = [0.0] * 3
        self._pending_dt = 0.0
        self._pending_bias_dt = 0.0
        self._pending_extra_cov = np.zeros((3, 3))

    # ------------------------------------------------------------------ updates
    def _accumulate_pull(self, dt, sway2):
        c = self.config
        roll, pitch, yaw = _rpy_of(*self._q)
        ref_yaw = c.track_heading_rad + c.heading_offset_rad
        corr = self._corr
        # Lag model: A_i = ∫R dt up to this sample, G_i = ∫R·CB dt (see _reset_pull).
        r = self._step_r
        cum = self._cum_a = [a + b * dt for a, b in zip(self._cum_a, r)]
        cb0, cb1, cb2 = self._bias_corr
        d = [a - b for a, b in zip(cum, self._a_ref)]
        g0, g1, g2 = self._g_ref
        entry = (dt, _wrap(c.track_roll_rad - roll) + corr[0],
                 _wrap(c.track_pitch_rad - pitch) + corr[1], _wrap(ref_yaw - yaw) + corr[2],
                 sway2, *cum, g0 + d[0] * cb0 + d[1] * cb1 + d[2] * cb2,
                 g1 + d[3] * cb0 + d[4] * cb1 + d[5] * cb2,
                 g2 + d[6] * cb0 + d[7] * cb1 + d[8] * cb2)
        ring = self._pull_ring
        ring.append(entry)
        s = [a + b for a, b in zip(self._pull_sum, entry[1:])]
        self._pull_time += dt
        while self._pull_time - ring[0][0] >= c.pull_window_s:
            old = ring.popleft()
            self._pull_time -= old[0]
            s = [a - b for a, b in zip(s, old[1:])]
            self._pull_full = True
        self._pull_sum = s

    def _pull_lag(self):
        """(M̄ (3, 3), β (3,)) of the pull window (map frame).

        The window's mean innovation measures the attitude error averaged over the last
        W, not the current one: with a gyro-bias error δb the error grows along the
        window, δθ(t_i) = δθ(now) + (A_now − A_i)·δb, so the mean measures
        δθ(now) + M̄·δb with M̄ = A_now − mean(A_i) (≈ W/2 on a straight track). Left
        out, a cold start's turn-on bias (0.2°/s) makes the first pull land W/2·δb
        (~0.4°) short with a covariance that claims 0.05°. β removes from the buffered
        innovations what the bias corrections made since each entry already explain:
        mean over i of ∫_{t_i}^{now} R·(CB_now − CB(t)) dt.
        """
        n = len(self._pull_ring)
        s, cum = self._pull_sum, self._cum_a
        m = np.array([cum[k] - s[4 + k] / n for k in range(9)]).reshape(3, 3)
        beta = m @ np.array(self._bias_corr) - (self._g_now() - np.array(s[13:16]) / n)
        return m, beta

    def _g_now(self):
        """G = ∫R·CB dt up to now (3,), as G_ref + (A − A_ref)·CB (see _reset_pull)."""
        m = np.array(self._cum_a).reshape(3, 3) - np.array(self._a_ref).reshape(3, 3)
        return np.array(self._g_ref) + m @ np.array(self._bias_corr)

    def _at_speed(self):
        """Sway gate of the pulls (see ``pull_min_sway_ratio``), updating the reference."""
        c = self.config
        sway2 = self._pull_sum[3] / len(self._pull_ring)
        self._sway_ref2 = max(sway2, self._sway_ref2
                              * math.exp(-2.0 * self._since_pull / SWAY_MEMORY_S))
        ring = self._pull_ring
        k = max(1, int(len(ring) * SWAY_GATE_FRACTION))
        recent2 = sum(ring[-i][4] for i in range(1, k + 1)) / k
        return recent2 >= max(c.pull_min_sway_rps ** 2,
                              c.pull_min_sway_ratio ** 2 * self._sway_ref2)

    def _apply_pull(self, period_s):
        """Pull roll, pitch and heading toward the track (time constants τ)."""
        c = self.config
        n = len(self._pull_ring)
        corr = self._corr
        # Mean innovation over the window, shifted by the corrections made since.
        mean = [self._pull_sum[k] / n - corr[k] for k in range(3)]
        lag, beta = self._pull_lag()
        axes = self._pull_axes()
        taus = (c.tilt_time_constant_s, c.tilt_time_constant_s, c.heading_time_constant_s)
        rows = [(axes[k], mean[k], taus[k]) for k in range(3)   # (map-frame axis, z, τ)
                if taus[k] > 0.0
                and self._clock_s - self._aided_at_s[k] >= c.pull_pause_after_aiding_s]
        if not rows:
            return
        h = np.zeros((len(rows), N_STATES))
        h[:, :3] = [r[0] for r in rows]
        h[:, 3:6] = h[:, :3] @ lag
        tau = np.array([r[2] for r in rows])
        var = c.gyro_noise_density_rps_rthz ** 2 * tau ** 2 / period_s
        self._update(h, np.array([r[1] for r in rows]) - h[:, :3] @ beta, var,
                     estimate_scale=False)

    def _pull_axes(self):
        """Map-frame axes (3, 3) of a roll, a pitch and a heading increment of the current
        R = Rz·Ry·Rx: Rz·Ry·x̂, Rz·ŷ, ẑ (exact for this parametrisation).
        """
        _, pitch, yaw = _rpy_of(*self._q)
        sy, cy = math.sin(yaw), math.cos(yaw)
        sp, cp = math.sin(pitch), math.cos(pitch)
        return np.array([[cy * cp, sy * cp, -sp], [-sy, cy, 0.0], [0.0, 0.0, 1.0]])

    def _apply_zero_rate(self, sample_rate_hz):
        """Zero-angular-rate update: standing, the mean gyro reading is its bias."""
        c = self.config
        n = self._zaru_n
        std = c.zero_rate_std_rps if c.zero_rate_std_rps > 0.0 else \
            c.gyro_noise_density_rps_rthz * math.sqrt(sample_rate_hz)
        mean = np.array(self._zaru_sum) / n
        self._zaru_sum = [0.0, 0.0, 0.0]
        self._zaru_n = 0
        h = np.zeros((3, N_STATES))
        h[:, 3:6] = np.eye(3)
        self._update(h, mean - self.gyro_bias_rps, np.full(3, std ** 2 / n),
                     estimate_scale=False)

    def _apply_gravity(self):
        """Optional tilt update from the mean specific force of the update period.

        Moving, only the component about the track direction (roll) is used, since
        traction and braking tilt the apparent gravity about the cross-track axis.
        """
        c = self.config
        f = np.array(self._grav_sum) / self._grav_n
        duration, moving = self._grav_time, self._grav_moving
        self._grav_sum = [0.0, 0.0, 0.0]
        self._grav_n = 0
        self._grav_time = 0.0
        self._grav_moving = False
        norm = float(np.linalg.norm(f))
        if not abs(norm - c.gravity_mps2) <= c.gravity_gate_mps2:
            return
        # u = R_est·f̂ is ẑ when the estimate is right; for R_true = Exp(δθ)·R_est,
        # u × ẑ = (δθx, δθy, 0) to first order.
        u = quat_to_matrix(np.array(self._q)) @ (f / norm)
        resid = np.cross(u, [0.0, 0.0, 1.0])
        along = np.array([math.cos(c.track_heading_rad), math.sin(c.track_heading_rad), 0.0])
        axes = [along] if moving else [along, np.array([-along[1], along[0], 0.0])]
        h = np.zeros((len(axes), N_STATES))
        h[:, :3] = axes
        var = c.gyro_noise_density_rps_rthz ** 2 * c.gravity_time_constant_s ** 2 / duration
        self._update(h, np.array([a @ resid for a in axes]), np.full(len(axes), var),
                     estimate_scale=False)

    def aiding_statistics(self, h, innovation, covariance, since_s=None, g=None):
        """What an aiding update would do, without doing it.

        Parameters are those of :meth:`update_aiding`.

        Returns
        -------
        (float, ndarray (3,))
            The innovation's squared Mahalanobis distance under the state's covariance
            plus the measurement's (nan when that is not positive definite), and the
            attitude correction (map axes, rad) a linear update would apply.
        """
        self._flush_covariance()
        h, innovation, r = self._aiding_arrays(h, innovation, covariance)
        p = self.P if self._P_true is None else self._P_true   # with the scale prior
        pz, s, _ = self._delayed_moments(p, h, r, since_s, g)
        try:
            np.linalg.cholesky(s)
        except np.linalg.LinAlgError:
            return float('nan'), np.zeros(3)
        w = np.linalg.solve(s, innovation)
        return float(innovation @ w), pz[:3] @ w

    def update_aiding(self, h, innovation, covariance, since_s=None, g=None, reset=False,
                      inflate_rad2=None):
        """Fuse an external attitude or heading measurement.

        Parameters
        ----------
        h : array_like (m, N_STATES)
            What it measures, as rows on the current error state (for a measurement
            taken earlier: the attitude error then is the current one plus the drift
            the bias and scale errors caused since, see
            :class:`~imu_compensator.core.compensator.AttitudeCompensator`).
        innovation : array_like (m,)
            Measurement minus estimate, rad.
        covariance : array_like (m, m)
            The measurement's covariance, rad².
        since_s : float, optional
            Filter clock (:attr:`clock_s`) of the measurement's stamp. The unknown motion
            over the IMU gaps after it is in the current attitude error but not in the
            measured one: z = H·x − G·n + e, with ``n`` their sum, whose covariance with
            the state the filter keeps; the update is then exact (to first order)
            instead of taking the measurement for one of the present.
        g : array_like (m, 3), optional
            G: how that motion enters the measurement (default: the attitude columns of
            ``h``).
        reset : bool
            Apply as an attitude reset: the bias and scale factors are consider states
            of this update (gain rows zeroed, covariance updated for that gain), so only
            the attitude moves. For a correction too large for the linearisation: the
            cross-covariances were built with Jacobians taken at an attitude now known
            to be that far off, good enough to weigh the measurement but not to move
            the bias and scale by.
        inflate_rad2 : array_like (3, 3), optional
            Added to the attitude covariance first (re-initialisation).
        """
        self._flush_covariance()
        self._activate_scale()
        h, innovation, r = self._aiding_arrays(h, innovation, covariance)
        att = h[:, :3]
        info = att.T @ np.linalg.solve(r, att)
        for k, axis in enumerate(self._pull_axes()):
            if axis @ info @ axis >= AIDED_AXIS_STD_RAD ** -2:
                self._aided_at_s[k] = self._clock_s
        if inflate_rad2 is not None:
            self.P[:3, :3] += np.asarray(inflate_rad2, float).reshape(3, 3)
        pz, s, g = self._delayed_moments(self.P, h, r, since_s, g)
        gain = np.linalg.solve(s, pz.T).T
        if reset:
            gain[3:] = 0.0
        # Cov(z, n_g) = H·M_g − G·Q_g for a gap after the stamp, H·M_g for one before.
        cross = [(h @ m - (g @ q if since_s is not None and when > since_s else 0.0))
                 for when, q, m in self._gap_terms]
        dx = gain @ innovation
        self._apply_correction(dx)
        for term, c in zip(self._gap_terms, cross):
            term[2] = term[2] - gain @ c
        # Error after: e − K·z with Cov(e, z) = pz, Cov(z) = S; any gain K.
        kp = gain @ pz.T
        p = self.P - kp - kp.T + gain @ s @ gain.T
        # ... about the corrected attitude: δθ' = log(Exp(δθ)·Exp(−dx)) ≈ J_l(dx)·(δθ − dx).
        # Negligible for the small corrections of the other updates, not for an aid that
        # turns the attitude by degrees while leaving degrees unseen along its line of
        # sight (a 28° reset left 0.6° of that in the seen plane, 3.5σ).
        j = left_jacobian(dx[:3])
        p[:3] = j @ p[:3]
        p[:, :3] = p[:, :3] @ j.T
        for term in self._gap_terms:
            term[2][:3] = j @ term[2][:3]
        self.P = 0.5 * (p + p.T)

    def _delayed_moments(self, p, h, r, since_s, g):
        """(Cov(x, z) (N, m), Cov(z) (m, m), G (m, 3)) of z = H·x − G·n + e, with n the
        unknown motion over the gaps after ``since_s`` (none when it is None).
        """
        g = h[:, :3] if g is None else np.asarray(g, float).reshape(-1, 3)
        pz = p @ h.T
        s = h @ pz + r
        if since_s is not None:
            after = [(q, m) for when, q, m in self._gap_terms if when > since_s]
            if after:
                m = sum(t[1] for t in after)
                q = sum(t[0] for t in after)
                pz = pz - m @ g.T
                hm = h @ m @ g.T
                s = s - hm - hm.T + g @ q @ g.T
        return pz, 0.5 * (s + s.T), g

    @staticmethod
    def _aiding_arrays(h, innovation, covariance):
        h = np.asarray(h, float).reshape(-1, N_STATES)
        m = h.shape[0]
        return (h, np.asarray(innovation, float).reshape(m),
                np.asarray(covariance, float).reshape(m, m))

    def _activate_scale(self):
        """At the first external aiding: the scale factors become states, with the
        consider covariance ``_P_true`` (their prior, propagated and updated alongside P)
        as the filter's covariance from then on. Only aiding observes them, and an
        unaided filter keeps exactly its attitude-and-bias estimates.
        """
        if self._P_true is not None:
            self.P, self._P_true = self._P_true, None

    def _map_covariances(self, step):
        """P ← step(P), and the same for the consider covariance while it is kept
        (see :meth:`initialize`); both symmetrised.
        """
        p = step(self.P)
        self.P = 0.5 * (p + p.T)
        if self._P_true is not None:
            p = step(self._P_true)
            self._P_true = 0.5 * (p + p.T)

    def _update(self, h, innovation, variance, estimate_scale=True):
        """Kalman update with H (m, N_STATES), innovation (m,) and R: diagonal (m,) or full
        (m, m); Joseph form.

        ``estimate_scale=False`` keeps the scale factors as consider states (Schmidt):
        their gain rows are zeroed and the Joseph form keeps P consistent. The track
        pulls, zero-rate and gravity updates do so: they do not see the scale (standing
        there is no rate; the pulls know only the slow mean and their window mean does
        not model the scale's share), so only attitude and heading aiding estimate it.
        """
        r = np.diag(variance) if np.ndim(variance) == 1 else variance
        ph = self.P @ h.T
        s = h @ ph + r
        gain = np.linalg.solve(s, ph.T).T
        if not estimate_scale:
            gain[6:, :] = 0.0
        self._apply_correction(gain @ innovation)
        ikh = np.eye(N_STATES) - gain @ h
        for term in self._gap_terms:
            term[2] = ikh @ term[2]
        noise = gain @ r @ gain.T
        self._map_covariances(lambda p: ikh @ p @ ikh.T + noise)

    def _apply_correction(self, dx):
        """Error state (N_STATES,) → estimate, with the pull window's bookkeeping."""
        before = _rpy_of(*self._q)
        step = quat_from_rotvec(dx[:3])
        q = quat_multiply(step, np.array(self._q))
        self._q = [float(v) for v in q / np.linalg.norm(q)]
        c = quat_multiply(step, np.array(self._correction_q))
        self._correction_q = [float(v) for v in c / np.linalg.norm(c)]
        after = _rpy_of(*self._q)
        for k in range(3):
            self._corr[k] += _wrap(after[k] - before[k])
        self.gyro_bias_rps = self.gyro_bias_rps + dx[3:6]
        self._bias = self.gyro_bias_rps.tolist()
        self.gyro_scale_error = self.gyro_scale_error + dx[6:]
        self._scale = self.gyro_scale_error.tolist()
        # Lag bookkeeping of the pull window: fold ∫R·CB dt up to now into G_ref, then
        # add this correction to CB.
        self._g_ref = self._g_now().tolist()
        self._a_ref = list(self._cum_a)
        self._bias_corr = (np.array(self._bias_corr) + dx[3:6]).tolist()

    # ------------------------------------------------------------------ outputs
    def corrected_rate(self, gyro_rps):
        """Angular rate (3,) of a gyro reading with the estimated bias and scale removed."""
        return (np.asarray(gyro_rps, float) - self.gyro_bias_rps) * (1.0 - self.gyro_scale_error)

    @property
    def quat(self):
        """Attitude (4,) x, y, z, w of ``base_link`` in ``map``, w ≥ 0."""
        q = np.array(self._q)
        return -q if q[3] < 0.0 else q

    @property
    def clock_s(self):
        """Filter time since the start (sum of the sample intervals), s."""
        return self._clock_s

    @property
    def correction_quat(self):
        """Every correction the updates made since the start, composed (4,) x, y, z, w:
        the estimate is ``C·U`` with ``U`` the integral of the gyro alone.
        """
        return np.array(self._correction_q)

    def lag_integrals(self):
        """(∫R dt (9,) row-major, ∫R·b dt (3,)) since the start, over the time the gyro was
        integrated (``R`` the attitude, ``b`` the bias estimate in use at each sample).

        Between two instants their differences give what a delayed measurement needs:
        the bias-error coupling ``A`` of the attitude error (δθ_then = δθ_now + A·δb) and
        the attitude the bias corrections made since explain (``A·b_now − Δ∫R·b dt``).
        """
        return ([a + b for a, b in zip(self._int_a, self._sum_r_dt)],
                [a + b for a, b in zip(self._int_rb, self._sum_rb_dt)])

    @property
    def rpy_rad(self):
        """Roll, pitch, yaw (3,) of ``base_link`` in ``map``, rad (R = Rz·Ry·Rx)."""
        return np.array(_rpy_of(*self._q))

    @property
    def attitude_covariance(self):
        """Covariance (3, 3) of the small attitude error about map x, y, z, rad².

        The covariance is propagated once per update period; the gyro noise of the
        samples since then is added here (the bias coupling over < 0.1 s is negligible).
        """
        cov = (self.P if self._P_true is None else self._P_true)[:3, :3].copy()
        cov.flat[::4] += self.config.gyro_noise_density_rps_rthz ** 2 * self._pending_dt
        return cov + self._pending_extra_cov

    @property
    def gyro_bias_std_rps(self):
        """1σ of the gyro bias estimate per axis (3,), rad/s."""
        return np.sqrt(np.diag(self.P[3:6, 3:6]))
