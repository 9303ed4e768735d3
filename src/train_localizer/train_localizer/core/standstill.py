"""Standstill detection from the IMU, for zero-velocity updates of the along-track filter.

A standing train's platform does not vibrate (the car-body response vanishes with the
speed), so the gyro and accelerometer show only their noise. Over a sliding window the
standard deviations of the angular rate and of the specific force are compared with
thresholds a few times the ADIS16488 noise; at speed the 0.3–3 Hz vibration exceeds
them by orders of magnitude. The localizer additionally requires its own speed
estimate to be near zero and well known before it applies a zero-velocity update, so a
vibration-free moving train (a rig with vibration disabled) is never stopped.
"""
from collections import deque
from dataclasses import dataclass
import math

import numpy as np


@dataclass
class StandstillConfig:
    """Thresholds of the standstill detector and the zero-velocity update.

    Attributes
    ----------
    enabled : bool
        Apply zero-velocity updates at all.
    window_s : float
        Sliding window of the detector, s.
    gyro_std_max_rps : float
        Largest per-axis standard deviation of the angular rate at standstill, rad/s.
    accel_std_max_mps2 : float
        Largest per-axis standard deviation of the specific force at standstill, m/s².
    max_speed_mps : float
        The filter's speed must be within this of zero (plus 2σ) for an update, m/s.
    max_speed_sigma_mps : float
        … and its 1σ below this, m/s.
    speed_sigma_mps : float
        1σ of one zero-velocity pseudo-measurement, m/s.
    update_period_s : float
        At most one update per this period (they are not independent), s.
    gate_chi2 : float
        An update whose innovation (the filter's speed against zero) exceeds this χ²
        (1 dof) is refused: the train has started. Without it a departure on a smooth
        track — a steady acceleration adds no variance to the window — was held at zero
        speed update after update while the bias took the traction: metres behind,
        at up to 40σ (realistic rig, 1 m/s² to 20 km/h).
    """

    enabled: bool = True
    window_s: float = 0.25
    gyro_std_max_rps: float = 0.005
    accel_std_max_mps2: float = 0.05
    max_speed_mps: float = 0.3
    max_speed_sigma_mps: float = 0.5
    speed_sigma_mps: float = 0.01
    update_period_s: float = 0.1
    gate_chi2: float = 16.0


class StandstillDetector:
    """Sliding-window standard deviations of gyro and specific force."""

    def __init__(self, config=None):
        self.config = config or StandstillConfig()
        self._samples = deque()

    def reset(self):
        self._samples.clear()

    def push(self, t_ns, gyro_rps, accel_mps2):
        """Add a sample; returns True when the window is full and quiet."""
        self.add(t_ns, gyro_rps, accel_mps2)
        return self.quiet()

    def add(self, t_ns, gyro_rps, accel_mps2):
        """Add a sample and drop those older than the window (no statistics yet)."""
        self._samples.append((t_ns, np.concatenate([gyro_rps, accel_mps2])))
        horizon = t_ns - int(self.config.window_s * 1e9)
        while self._samples and self._samples[0][0] < horizon:
            self._samples.popleft()

    def quiet(self):
        """True when the window (up to the newest sample added) is full and quiet."""
        cfg = self.config
        if not self._samples:
            return False
        horizon = self._samples[-1][0] - int(cfg.window_s * 1e9)
        if len(self._samples) < 8 or self._samples[0][0] - horizon > 0.2 * cfg.window_s * 1e9:
            return False
        std = np.std(np.array([s[1] for s in self._samples]), axis=0)
        return bool(np.all(std[:3] <= cfg.gyro_std_max_rps)
                    and np.all(std[3:] <= cfg.accel_std_max_mps2))

    @staticmethod
    def speed_allows_update(speed_mps, speed_var, config):
        """True when the filter's speed is compatible with standing still: known well
        enough, near zero, and a zero-speed measurement would pass the χ² gate.
        """
        var = max(speed_var, 0.0)
        sigma = math.sqrt(var)
        innovation_var = var + config.speed_sigma_mps ** 2
        return (sigma <= config.max_speed_sigma_mps
                and abs(speed_mps) <= config.max_speed_mps + 2.0 * sigma
                and speed_mps * speed_mps <= config.gate_chi2 * innovation_var)
