"""Zero-velocity (standstill) detection from the IMU alone.

A standing train's IMU reads only its noise and bias: over a short window the standard
deviation of every gyro and accelerometer axis stays near the sensor's white noise
(ADIS16488 at 400 Hz: 1.5e-3 rad/s and 9.7e-3 m/s² per sample), and the mean rate
equals the gyro bias. A moving train adds the car-body vibration — hundreds of times
larger at speed, and still above the thresholds at ~1 km/h, since the rig scales the
vibration with speed — and traction or braking, whose onset shifts the accelerometer
mean within one sample. A slow sway looks steady over a short window near its rate
peaks, which the mean-rate test catches once the bias is known; a steady turn has no
variance at all and is caught the same way.

What the IMU cannot tell apart: a train accelerating or braking steadily on a smooth
track at low speed (little vibration, and a constant acceleration adds no variance) —
:class:`OdometryVeto` lets the train's measured speed overrule the verdict then.
"""
from collections import deque
from dataclasses import dataclass
import math

import numpy as np


@dataclass
class ZeroVelocityConfig:
    """Thresholds of :class:`ZeroVelocityDetector`.

    Attributes
    ----------
    window_s : float
        Length of the sliding window, s.
    gyro_std_threshold_rps : float
        Standstill needs the standard deviation of every gyro axis over the window
        below this, rad/s. Default ≈ 2× the ADIS16488 white noise per sample at
        400 Hz; scale it with √(rate/400 Hz) for another rate.
    accel_std_threshold_mps2 : float
        Same for every accelerometer axis, m/s².
    max_rate_rps : float
        When a gyro bias estimate is supplied, standstill also needs the window's mean
        rate within this of it on every axis, rad/s.
    """

    window_s: float = 0.5
    gyro_std_threshold_rps: float = 3.0e-3
    accel_std_threshold_mps2: float = 0.02
    max_rate_rps: float = 2.0e-3

    def __post_init__(self):
        for name in ('window_s', 'gyro_std_threshold_rps', 'accel_std_threshold_mps2',
                     'max_rate_rps'):
            value = getattr(self, name)
            if not (np.isfinite(value) and value > 0.0):
                raise ValueError(f'{name} must be finite and > 0, got {value}')


class ZeroVelocityDetector:
    """Sliding-window variance test on the six IMU channels.

    Parameters
    ----------
    config : ZeroVelocityConfig
    rate_hz : float
        Nominal IMU rate, Hz; sets the window length in samples.
    """

    def __init__(self, config, rate_hz):
        self.config = config
        self.window_samples = max(3, int(round(config.window_s * rate_hz)))
        self._buf = np.empty((self.window_samples, 6))
        self.reset()

    def reset(self):
        """Forget the window (after a gap or a filter reset); standstill is unknown."""
        self._n = 0
        self._i = 0
        # Running sums of (x − offset) and its square; the offset (the first sample of
        # the window) keeps the variance of the ≈ 9.8 m/s² axis free of cancellation.
        self._offset = None
        self._s1 = np.zeros(6)
        self._s2 = np.zeros(6)
        self.stationary = False
        self.gyro_std_rps = np.full(3, np.nan)
        self.accel_std_mps2 = np.full(3, np.nan)

    def push(self, gyro_rps, accel_mps2, gyro_bias_rps=None):
        """Add one sample (gyro rad/s (3,), specific force m/s² (3,)).

        Parameters
        ----------
        gyro_bias_rps : array_like (3,), optional
            Current bias estimate, rad/s; when given (i.e. when it is known to better
            than ``max_rate_rps``) the mean-rate test applies too.

        Returns
        -------
        bool
            True when the window is full and every test passes.
        """
        x = np.concatenate([gyro_rps, accel_mps2])
        if self._offset is None:
            self._offset = x.copy()
        x = x - self._offset
        n_win = self.window_samples
        if self._n == n_win:
            old = self._buf[self._i]
            self._s1 += x - old
            self._s2 += x * x - old * old
        else:
            self._s1 += x
            self._s2 += x * x
            self._n += 1
        self._buf[self._i] = x
        self._i += 1
        if self._i == n_win:
            self._i = 0
            if self._n == n_win:
                # Recompute once per window so rounding in the running sums cannot build up.
                self._s1 = self._buf.sum(axis=0)
                self._s2 = np.square(self._buf).sum(axis=0)
        if self._n < n_win:
            self.stationary = False
            return False
        mean = self._s1 / n_win
        std = np.sqrt(np.maximum(self._s2 / n_win - mean * mean, 0.0))
        self.gyro_std_rps = std[:3]
        self.accel_std_mps2 = std[3:]
        cfg = self.config
        still = std[:3].max() < cfg.gyro_std_threshold_rps \
            and std[3:].max() < cfg.accel_std_threshold_mps2
        if still and gyro_bias_rps is not None:
            turn = mean[:3] + self._offset[:3] - gyro_bias_rps
            still = np.abs(turn).max() < cfg.max_rate_rps
        self.stationary = bool(still)
        return self.stationary

    @property
    def full(self):
        """Whether the window holds ``window_samples`` samples."""
        return self._n == self.window_samples

    @property
    def window_mean(self):
        """Mean of gyro (rad/s) and specific force (m/s²) over the window, (6,)."""
        if self._n == 0:
            return np.full(6, np.nan)
        return self._s1 / self._n + self._offset

    def gyro_rms_rps(self, gyro_bias_rps):
        """Per-axis RMS (3,) of the gyro less ``gyro_bias_rps`` over the samples the window
        holds so far (full or not), rad/s; nan when it is empty.
        """
        if self._n == 0:
            return np.full(3, np.nan)
        mean = self._s1[:3] / self._n
        var = np.maximum(self._s2[:3] / self._n - mean * mean, 0.0)
        return np.sqrt(var + np.square(mean + self._offset[:3] - gyro_bias_rps))


@dataclass
class OdometryVetoConfig:
    """When recent odometry overrules the IMU's standstill verdict
    (:class:`OdometryVeto`).

    Attributes
    ----------
    timeout_s : float
        Odometry counts for IMU samples stamped within this of its newest usable
        message (either side: the two clocks differ by the IMU's stamp offset), s; older
        or absent, the IMU-only test decides alone.
    accel_window_s : float
        The acceleration is the least-squares slope of the odometry speed over this much
        of its newest stamps, s (smooths the speed's noise; needs at least three speeds
        spanning half of it).
    max_accel_mps2 : float
        Veto while that slope's magnitude exceeds this, m/s²; 0 = off.
    max_speed_mps : float
        Veto while the newest speed exceeds this, m/s; 0 = off.
    max_speed_std_mps : float
        A message whose speed 1σ (from its covariance) exceeds this carries no usable
        speed (the localizer's raw fix before its filter knows the speed: variance 1e6)
        and is not used, m/s.
    """

    timeout_s: float = 0.5
    accel_window_s: float = 1.0
    max_accel_mps2: float = 0.2
    max_speed_mps: float = 0.0
    max_speed_std_mps: float = 0.5

    def __post_init__(self):
        for name in ('timeout_s', 'accel_window_s', 'max_speed_std_mps'):
            value = getattr(self, name)
            if not (np.isfinite(value) and value > 0.0):
                raise ValueError(f'{name} must be finite and > 0, got {value}')
        for name in ('max_accel_mps2', 'max_speed_mps'):
            value = getattr(self, name)
            if not (np.isfinite(value) and value >= 0.0):
                raise ValueError(f'{name} must be finite and >= 0, got {value}')


class OdometryVeto:
    """Vetoes the standstill verdict while odometry shows the train accelerating (or,
    optionally, moving).

    A train accelerating or braking steadily on a smooth track at low speed barely
    vibrates, and a constant acceleration adds no variance to the window: the variance
    test then calls it standing (the realistic rig: 60–69 % of the acceleration and braking
    samples of a 1 m/s² departure to 20 km/h and stop). The speed the localizer measures
    says otherwise.

    Parameters
    ----------
    config : OdometryVetoConfig
    """

    #: What :meth:`push` did with a message.
    USED, UNCERTAIN, OUT_OF_ORDER, INVALID = 'used', 'uncertain', 'out_of_order', 'invalid'

    def __init__(self, config=None):
        self.config = config or OdometryVetoConfig()
        self.reset()

    def reset(self):
        """Forget every speed."""
        self._speeds = deque()             # (t_s, speed_mps), oldest first
        self.acceleration_mps2 = float('nan')
        self.speed_mps = float('nan')
        self.newest_t_s = None

    def push(self, t_s, speed_mps, speed_var_m2ps2=None):
        """Add one odometry speed (its magnitude is used) at its stamp ``t_s``.

        Parameters
        ----------
        speed_var_m2ps2 : float, optional
            Its variance; None or ≤ 0: not stated (used).

        Returns
        -------
        str
            ``INVALID`` (non-finite stamp, speed or variance: nothing kept),
            ``UNCERTAIN`` (speed 1σ above ``max_speed_std_mps``: not used),
            ``OUT_OF_ORDER`` (not newer than the newest by up to ``timeout_s``: dropped;
            older by more is a new time base, which restarts the history) or ``USED``.
        """
        t_s, speed = float(t_s), float(speed_mps)
        if not (math.isfinite(t_s) and math.isfinite(speed)):
            return self.INVALID
        if speed_var_m2ps2 is not None:
            var = float(speed_var_m2ps2)
            if not math.isfinite(var):
                return self.INVALID
            if var > self.config.max_speed_std_mps ** 2:
                return self.UNCERTAIN
        if self.newest_t_s is not None and t_s <= self.newest_t_s:
            if self.newest_t_s - t_s <= self.config.timeout_s:
                return self.OUT_OF_ORDER
            self.reset()
        speeds = self._speeds
        speeds.append((t_s, abs(speed)))
        window = self.config.accel_window_s
        while speeds[0][0] < t_s - window:
            speeds.popleft()
        self.newest_t_s = t_s
        self.speed_mps = abs(speed)
        self.acceleration_mps2 = self._slope(speeds, window)
        return self.USED

    @staticmethod
    def _slope(speeds, window):
        if len(speeds) < 3 or speeds[-1][0] - speeds[0][0] < 0.5 * window:
            return float('nan')
        t = np.array([s[0] for s in speeds])
        v = np.array([s[1] for s in speeds])
        t = t - t.mean()
        return float(t @ (v - v.mean()) / (t @ t))

    def recent(self, t_s):
        """Whether the newest usable odometry is within ``timeout_s`` of ``t_s``."""
        return self.newest_t_s is not None \
            and abs(t_s - self.newest_t_s) <= self.config.timeout_s

    def vetoes(self, t_s):
        """Whether an IMU sample stamped ``t_s`` must not count as standing."""
        if not self.recent(t_s):
            return False
        c = self.config
        accel = self.acceleration_mps2
        return (c.max_accel_mps2 > 0.0 and math.isfinite(accel)
                and abs(accel) > c.max_accel_mps2) \
            or (c.max_speed_mps > 0.0 and self.speed_mps > c.max_speed_mps)
