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
"""
from dataclasses import dataclass

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
