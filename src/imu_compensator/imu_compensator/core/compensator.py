"""Per-sample driver: input checks, zero-velocity detection, the attitude filter.

:class:`AttitudeCompensator` is everything the node does between converting an
``imu/data_raw`` message and publishing ``imu/data``, so it is tested without ROS. Each
sample is classified (:class:`SampleStatus`) and bad input never raises:

* non-finite rate or specific force → skipped;
* stamp equal to the newest → skipped (duplicate); a little older → skipped (out of
  order); older by more than ``backward_reset_s`` → the filter is reset and restarted
  at this sample (a replayed bag or a restarted clock);
* stamp later by more than ``gap_s`` → propagated over the gap with the mean of the
  two bracketing rates, the attitude variance inflated by the unknown motion
  (recent rate RMS × gap)², and the standstill window restarted.

After a start or reset, if the first full standstill window is still, the filter
restarts from the track attitude with the window's mean rate as gyro bias (static
alignment, as an INS does before departure).
"""
from dataclasses import dataclass, field
import enum
import logging
import math

import numpy as np

from imu_compensator.core.attitude_buffer import AttitudeBuffer
from imu_compensator.core.attitude_filter import AttitudeFilter, AttitudeFilterConfig
from imu_compensator.core.zero_velocity import ZeroVelocityConfig, ZeroVelocityDetector
from vlc_common.core.rotations import (
    quat_conjugate,
    quat_from_rpy,
    quat_multiply,
    quat_normalize,
    quat_to_matrix,
    quat_to_rotvec,
    quat_to_rpy,
)

_LOG = logging.getLogger(__name__)


class SampleStatus(enum.Enum):
    """What :meth:`AttitudeCompensator.process` did with a sample."""

    OK = 'ok'
    INITIALIZED = 'initialized'      # first sample: filter started, estimate published
    GAP = 'gap'                      # propagated over a gap, estimate published
    RESET = 'reset'                  # time jumped backwards: restarted, estimate published
    NONFINITE = 'nonfinite'          # skipped
    DUPLICATE = 'duplicate'          # skipped
    OUT_OF_ORDER = 'out_of_order'    # skipped

    @property
    def accepted(self):
        return self in (SampleStatus.OK, SampleStatus.INITIALIZED, SampleStatus.GAP,
                        SampleStatus.RESET)


@dataclass
class CompensatorConfig:
    """Everything :class:`AttitudeCompensator` needs (SI units, radians).

    Attributes
    ----------
    filter : AttitudeFilterConfig
    zero_velocity : ZeroVelocityConfig
    nominal_rate_hz : float
        Expected IMU rate, Hz (sizes the standstill window and the zero-rate noise).
    gap_s : float
        A step longer than this is a gap (warned, propagated), s.
    backward_reset_s : float
        A stamp older than the newest by more than this resets the filter; a smaller
        step back is an out-of-order sample and is dropped, s.
    imu_mount_rpy_rad : tuple of 3 floats
        Rotation of ``imu_link`` in ``base_link`` (roll, pitch, yaw); the filter works in
        ``base_link``.
    history_s : float
        Length of the attitude history kept for delayed (attitude or heading) aiding, s.
    """

    filter: AttitudeFilterConfig = field(default_factory=AttitudeFilterConfig)
    zero_velocity: ZeroVelocityConfig = field(default_factory=ZeroVelocityConfig)
    nominal_rate_hz: float = 400.0
    gap_s: float = 0.02
    backward_reset_s: float = 1.0
    imu_mount_rpy_rad: tuple = (0.0, 0.0, 0.0)
    history_s: float = 2.0

    def __post_init__(self):
        for name in ('nominal_rate_hz', 'gap_s', 'backward_reset_s', 'history_s'):
            value = getattr(self, name)
            if not (np.isfinite(value) and value > 0.0):
                raise ValueError(f'{name} must be finite and > 0, got {value}')
        if len(self.imu_mount_rpy_rad) != 3:
            raise ValueError('imu_mount_rpy_rad needs 3 values')


@dataclass
class SampleResult:
    """Outcome of one sample; the estimate fields are None when it was skipped.

    Attributes
    ----------
    status : SampleStatus
    t_s : float
        The sample's stamp, s.
    dt_s : float
        Step from the previous accepted sample, s (nan for the first and after a reset).
    quat_xyzw : ndarray (4,) or None
        Attitude of ``base_link`` in ``map``.
    covariance : ndarray (3, 3) or None
        Attitude error covariance about map x, y, z, rad².
    gyro_rps : ndarray (3,) or None
        Bias-corrected angular rate in ``base_link``, rad/s.
    accel_mps2 : ndarray (3,) or None
        Specific force in ``base_link`` (not bias-corrected), m/s².
    stationary : bool
    """

    status: SampleStatus
    t_s: float
    dt_s: float = float('nan')
    quat_xyzw: np.ndarray = None
    covariance: np.ndarray = None
    gyro_rps: np.ndarray = None
    accel_mps2: np.ndarray = None
    stationary: bool = False


@dataclass
class CompensatorStats:
    """Counters for diagnostics (since start)."""

    accepted: int = 0
    nonfinite: int = 0
    duplicate: int = 0
    out_of_order: int = 0
    gaps: int = 0
    resets: int = 0
    stationary_samples: int = 0
    aiding_used: int = 0
    aiding_rejected: int = 0

    @property
    def dropped(self):
        return self.nonfinite + self.duplicate + self.out_of_order


class AttitudeCompensator:
    """Attitude of the camera platform from raw IMU samples; see the module docstring.

    Parameters
    ----------
    config : CompensatorConfig
    """

    def __init__(self, config=None):
        self.config = config or CompensatorConfig()
        self.filter = AttitudeFilter(self.config.filter)
        self.zero_velocity = ZeroVelocityDetector(self.config.zero_velocity,
                                                  self.config.nominal_rate_hz)
        self.history = AttitudeBuffer(horizon_s=self.config.history_s,
                                      max_gap_s=max(1.0, 4.0 * self.config.gap_s))
        self.stats = CompensatorStats()
        self.last_t_s = None
        self._rate_rms_rps = 0.0
        self._aligning = True
        self._bias_known_rps = self.config.zero_velocity.max_rate_rps / 3.0
        mount = self.config.imu_mount_rpy_rad
        self._r_base_imu = quat_to_matrix(quat_from_rpy(*mount))
        self._mounted = bool(np.any(np.asarray(mount) != 0.0))

    # ------------------------------------------------------------------ samples
    def process(self, t_s, gyro_rps, accel_mps2):
        """Feed one raw IMU sample (``imu_link`` axes); see the module docstring.

        Parameters
        ----------
        t_s : float
            Sample stamp, s.
        gyro_rps : array_like (3,)
            Angular rate, rad/s.
        accel_mps2 : array_like (3,)
            Specific force, m/s² (+g on z at rest).

        Returns
        -------
        SampleResult
        """
        gyro = np.asarray(gyro_rps, dtype=float).reshape(3)
        accel = np.asarray(accel_mps2, dtype=float).reshape(3)
        # One sum catches any NaN or ±inf among the six values (and absurd ~1e308 ones).
        if not (math.isfinite(t_s) and math.isfinite(float(gyro.sum() + accel.sum()))):
            self.stats.nonfinite += 1
            return SampleResult(SampleStatus.NONFINITE, t_s)
        if self._mounted:
            gyro = self._r_base_imu @ gyro
            accel = self._r_base_imu @ accel

        if self.last_t_s is None:
            return self._start(t_s, gyro, accel, SampleStatus.INITIALIZED)
        dt = t_s - self.last_t_s
        if dt == 0.0:
            self.stats.duplicate += 1
            return SampleResult(SampleStatus.DUPLICATE, t_s, dt)
        if dt < 0.0:
            if -dt > self.config.backward_reset_s:
                self.stats.resets += 1
                return self._start(t_s, gyro, accel, SampleStatus.RESET, dt)
            self.stats.out_of_order += 1
            return SampleResult(SampleStatus.OUT_OF_ORDER, t_s, dt)

        status = SampleStatus.OK
        extra_var = 0.0
        if dt > self.config.gap_s:
            status = SampleStatus.GAP
            self.stats.gaps += 1
            # What the platform did during the gap is unknown beyond its recent rate.
            rate_rms = self.zero_velocity.rate_rms_rps
            if math.isfinite(rate_rms):
                self._rate_rms_rps = rate_rms
            extra_var = (self._rate_rms_rps * dt) ** 2
            self.zero_velocity.reset()
        # The mean-rate test needs a bias known to well within its threshold (after the
        # static alignment or a long enough run), not the cold-start guess.
        known = self.filter.gyro_bias_std_rps.max() < self._bias_known_rps
        stationary = self.zero_velocity.push(gyro, accel,
                                             self.filter.gyro_bias_rps if known else None)
        if stationary:
            self.stats.stationary_samples += 1
        if self._aligning and self.zero_velocity.full:
            self._aligning = False
            if stationary:
                self._align(gyro)
                return self._accept(t_s, dt, gyro, accel, status, stationary)
        self.filter.step(gyro, accel, dt, stationary, self.config.nominal_rate_hz, extra_var)
        return self._accept(t_s, dt, gyro, accel, status, stationary)

    def _align(self, gyro):
        # Static alignment: the first window after a start was still, so the platform
        # has not turned since the start — go back to the starting (track) attitude and
        # take the window's mean rate as the bias, instead of keeping the drift the
        # unknown turn-on bias caused while the window filled.
        n = self.zero_velocity.window_samples
        noise = self.config.filter.gyro_noise_density_rps_rthz \
            * math.sqrt(self.config.nominal_rate_hz)
        self.filter.initialize(gyro, aligned_gyro_bias_rps=self.zero_velocity.window_mean[:3],
                               gyro_bias_std_rps=noise / math.sqrt(n))
        _LOG.info('static alignment over %d still samples: gyro bias %s rad/s', n,
                  np.array2string(self.filter.gyro_bias_rps, precision=6))

    def _start(self, t_s, gyro, accel, status, dt=float('nan')):
        if status is SampleStatus.RESET:
            _LOG.info('IMU time jumped back by %.3f s: attitude filter reset', -dt)
        self.filter.initialize(gyro)
        self.zero_velocity.reset()
        self.zero_velocity.push(gyro, accel)
        self._aligning = True
        self.history.clear()
        return self._accept(t_s, dt, gyro, accel, status, False)

    def _accept(self, t_s, dt, gyro, accel, status, stationary):
        self.last_t_s = t_s
        self.stats.accepted += 1
        quat = self.filter.quat.copy()
        cov = self.filter.attitude_covariance
        self.history.push(t_s, quat)
        return SampleResult(status, t_s, dt, quat, cov, self.filter.corrected_rate(gyro),
                            accel, stationary)

    # ------------------------------------------------------------------ aiding
    def heading_aiding(self, t_s, yaw_rad, variance_rad2):
        """Fuse an external heading measurement (e.g. from vision) taken at ``t_s``.

        The innovation is formed against the estimate at ``t_s`` (slerp in the kept
        history) and applied to the current state: the heading change since ``t_s``
        comes from the gyro, which is far more accurate over a few hundred ms than any
        aiding measurement.

        Returns
        -------
        bool
            False (counted, not raised) when ``t_s`` is outside the kept history or the
            values are not finite / the variance not positive.
        """
        if not (np.isfinite(t_s) and np.isfinite(yaw_rad) and np.isfinite(variance_rad2)
                and variance_rad2 > 0.0):
            self.stats.aiding_rejected += 1
            return False
        then = self.history.at(t_s)
        if then is None:
            self.stats.aiding_rejected += 1
            return False
        self.filter.update_heading(yaw_rad - quat_to_rpy(then)[2], variance_rad2)
        self.stats.aiding_used += 1
        return True

    def attitude_aiding(self, t_s, quat_xyzw, covariance_rad2):
        """Fuse an external attitude measurement (e.g. the one a lamp shows) taken at
        ``t_s``: the attitude of ``base_link`` in ``map`` and its covariance about the
        map axes (3, 3), rad².

        As :meth:`heading_aiding`: the innovation is formed against the estimate at
        ``t_s`` and applied to the current state. With the full covariance the filter
        sees which combination of roll, pitch and heading the measurement constrains, so
        an aid whose heading depends on the platform's tilt corrects the tilt as well,
        instead of passing the tilt error on to the heading as if it were noise.

        Returns
        -------
        bool
            False (counted, not raised) when ``t_s`` is outside the kept history, or the
            values are not finite, or the covariance is not symmetric positive definite.
        """
        q = np.asarray(quat_xyzw, dtype=float).reshape(-1)
        cov = np.asarray(covariance_rad2, dtype=float)
        ok = (q.size == 4 and cov.shape == (3, 3) and np.isfinite(t_s)
              and np.all(np.isfinite(q)) and np.all(np.isfinite(cov))
              and np.linalg.norm(q) > 1e-6 and np.allclose(cov, cov.T, atol=1e-12)
              and np.all(np.linalg.eigvalsh(cov) > 0.0))
        then = self.history.at(t_s) if ok else None
        if then is None:
            self.stats.aiding_rejected += 1
            return False
        # R_meas = Exp(δ)·R_then  ⇒  δ = log(q_meas ⊗ q_then⁻¹)
        delta = quat_to_rotvec(quat_multiply(quat_normalize(q), quat_conjugate(then)))
        self.filter.update_attitude(delta, cov)
        self.stats.aiding_used += 1
        return True

    # ------------------------------------------------------------------ read-outs
    @property
    def stationary(self):
        return self.zero_velocity.stationary

    @property
    def gyro_bias_rps(self):
        return self.filter.gyro_bias_rps.copy()

    @property
    def gyro_bias_std_rps(self):
        return self.filter.gyro_bias_std_rps
