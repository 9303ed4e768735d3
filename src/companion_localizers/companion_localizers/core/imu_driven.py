"""What the two IMU-driven companion localizers share: IMU input, standstill, output grid.

:class:`ImuDrivenLocalizer` takes ``imu/data`` samples (attitude of ``base_link`` in
``map`` plus the raw specific force rotated into ``base_link``), forms the
gravity-free along-track acceleration ``a_x = (R·f)_x`` (``map`` x is horizontal, so
gravity has no x component; the attitude removes the ``g·sin(pitch)`` leak of the body
x axis), drives an :class:`~.along_track.AlongTrackFilter` with it, applies
zero-velocity updates when the IMU shows a standing platform, and emits pose estimates
on a grid of sensor time as the IMU passes each grid instant. Subclasses add their
measurements (landmarks, beacon ranges) through :meth:`add_frame`.

The motion constraint of a train is built in: ``base_link`` moves along the track only
(lateral and vertical offsets are the nominal track's, to vibration level), so the
navigation state is one-dimensional.

No ROS here; times are integer ns.
"""
from collections import deque
from dataclasses import dataclass, field
import math
import time

import numpy as np

from companion_localizers.core.along_track import H_SPEED, AlongTrackFilter, FilterSettings
from companion_localizers.core.attitude_prior import fuse_tilt
from imu_compensator.core.attitude_buffer import AttitudeBuffer
from train_localizer.core.standstill import StandstillConfig, StandstillDetector
from vlc_common.core.observation import ImuSample
from vlc_common.core.rotations import quat_to_matrix

NS_PER_S = 1_000_000_000
GRAVITY_MPS2 = 9.80665
IDENTITY_QUAT = np.array([0.0, 0.0, 0.0, 1.0])


@dataclass
class ImuDrivenConfig:
    """Attributes
    ----------
    filter : FilterSettings
    standstill : train_localizer.core.standstill.StandstillConfig
        IMU standstill detector and zero-velocity update.
    publish_rate_hz : float
        Output grid, Hz (stamps k / rate exactly).
    max_sigma_m : float
        Estimates are emitted only while the chainage 1σ is below this, m …
    max_speed_sigma_mps : float
        … and the speed 1σ below this, m/s (right after a first position fix the speed
        is still unknown and the chainage 1σ, though small, grows by metres per
        second).
    track_offset_yz_m : tuple of 2 floats
        Nominal lateral and vertical position of ``base_link`` in ``map``, m.
    use_imu_attitude : bool
        Rotate the specific force with the ``imu/data`` attitude (False: body x =
        along track, the pitch leak of gravity stays in the input).
    attitude_horizon_s : float
        Attitude history kept for measurements in the past, s.
    tilt_leak_time_s : float
        The gravity leak g·δθ of the pitch error δθ is not white: it drifts with the
        attitude filter's error. It is modelled as extra bias random walk that can
        cover g·σ_pitch within this time (σ_pitch from ``imu/data``'s covariance,
        at least ``pitch_sigma_floor_rad``), as train_localizer does, s; 0 = off.
    pitch_sigma_floor_rad : float
        Smallest pitch 1σ assumed for ``imu/data``, rad.
    pitch_sigma_unknown_rad : float
        Pitch 1σ without an attitude (``use_imu_attitude`` false or none given), rad.
    tilt_prior_sigma_rad : tuple of 2 floats
        Roll and pitch 1σ of the platform about the (level) track, rad: ``imu/data``'s
        roll and pitch are fused with it (:mod:`.attitude_prior`); (0, 0) = off.
    frame_span_s : float
        Latest measurement instant of a frame after its stamp (rolling-shutter readout
        plus exposure), s: a frame waits until ``imu/data`` covers it.
    max_waiting_frames : int
        Frames kept waiting for ``imu/data`` at most; beyond, the oldest is processed
        with the attitude extrapolated or unknown (counted).
    """

    filter: FilterSettings = field(default_factory=FilterSettings)
    standstill: StandstillConfig = field(default_factory=StandstillConfig)
    publish_rate_hz: float = 50.0
    max_sigma_m: float = 1.0
    max_speed_sigma_mps: float = 2.0
    track_offset_yz_m: tuple = (0.0, 0.0)
    use_imu_attitude: bool = True
    attitude_horizon_s: float = 2.0
    tilt_leak_time_s: float = 5.0
    pitch_sigma_floor_rad: float = 0.05 * math.pi / 180.0
    pitch_sigma_unknown_rad: float = 0.5 * math.pi / 180.0
    tilt_prior_sigma_rad: tuple = (0.3 * math.pi / 180.0, 0.3 * math.pi / 180.0)
    frame_span_s: float = 0.025
    max_waiting_frames: int = 30

    def __post_init__(self):
        if not (self.publish_rate_hz > 0.0 and self.max_sigma_m > 0.0
                and self.max_speed_sigma_mps > 0.0):
            raise ValueError('publish_rate_hz, max_sigma_m and max_speed_sigma_mps must be > 0')


@dataclass
class PoseEstimate:
    """One output pose.

    Attributes
    ----------
    stamp_ns : int
        The instant described, ns.
    position_m : ndarray (3,)
        ``base_link`` in ``map``: chainage and the nominal track offsets, m.
    chainage_var_m2 : float
    speed_mps, speed_var : float
        Along-track speed and its variance.
    quat_xyzw : ndarray (4,)
        Attitude from ``imu/data`` at that instant (identity without one).
    """

    stamp_ns: int
    position_m: np.ndarray
    chainage_var_m2: float
    speed_mps: float
    speed_var: float
    quat_xyzw: np.ndarray


@dataclass
class Counters:
    imu_samples: int = 0
    imu_rejected: int = 0
    zero_velocity_updates: int = 0
    frames: int = 0
    frames_without_attitude: int = 0
    bad_observations: int = 0
    measurements_dropped_old: int = 0


class ImuDrivenLocalizer:
    """Base of the dead-reckoning and INS/beacon localizers; see the module docstring."""

    def __init__(self, config):
        self.config = config
        self.filter = AlongTrackFilter(config.filter)
        self.standstill = StandstillDetector(config.standstill)
        self.attitude = AttitudeBuffer(horizon_s=config.attitude_horizon_s, max_gap_s=0.1,
                                       max_extrapolation_s=0.05)
        self.counters = Counters()
        self._grid_ns = NS_PER_S / config.publish_rate_hz
        self._last_zupt_ns = None
        self._prev_accel = None
        self._waiting = []             # frames waiting for imu/data: (stamp_ns, observations)
        self._results = []             # what process_frame returned, not yet taken
        #: CPU time of the thread per processed frame, ms (the last 500).
        self.frame_cpu_ms = deque(maxlen=500)
        self.still = False

    # ------------------------------------------------------------------ IMU
    def along_track_acceleration(self, sample):
        """``(R·f)_x`` of an ImuSample, m/s² (body x without an attitude)."""
        if self.config.use_imu_attitude and sample.quat_xyzw is not None:
            return float(quat_to_matrix(sample.quat_xyzw)[0] @ sample.accel_mps2)
        return float(sample.accel_mps2[0])

    def _fused(self, sample):
        """The sample with its roll and pitch fused with the track's (a copy)."""
        prior = self.config.tilt_prior_sigma_rad
        if not any(p > 0.0 for p in prior):
            return sample
        q, cov = fuse_tilt(sample.quat_xyzw, sample.attitude_cov_rad2, prior)
        return ImuSample(stamp_ns=sample.stamp_ns, accel_mps2=sample.accel_mps2,
                         gyro_rps=sample.gyro_rps, quat_xyzw=q, attitude_cov_rad2=cov)

    def tilt_leak_q(self, sample):
        """Extra bias random-walk intensity (m²/s⁵): (g·σ_pitch)² / ``tilt_leak_time_s``."""
        cfg = self.config
        if cfg.tilt_leak_time_s <= 0.0:
            return 0.0
        if cfg.use_imu_attitude and sample.quat_xyzw is not None:
            cov = sample.attitude_cov_rad2
            var = cfg.pitch_sigma_floor_rad ** 2
            if cov is not None and math.isfinite(cov[1, 1]):
                var = max(float(cov[1, 1]), var)
        else:
            var = cfg.pitch_sigma_unknown_rad ** 2
        return GRAVITY_MPS2 ** 2 * var / cfg.tilt_leak_time_s

    def accel_input(self, accel_x):
        """Filter input over the step ending at this sample: trapezoid of the last two
        samples (subclasses may smooth further).
        """
        prev = self._prev_accel if self._prev_accel is not None else accel_x
        self._prev_accel = accel_x
        return 0.5 * (prev + accel_x)

    def add_imu(self, sample):
        """One ``imu/data`` sample; returns the PoseEstimates of the grid instants passed.

        Non-finite or out-of-order samples are refused (counted) and return [].
        """
        if not sample.is_finite() or (self.filter.newest_ns is not None
                                      and sample.stamp_ns <= self.filter.newest_ns):
            self.counters.imu_rejected += 1
            return []
        self.counters.imu_samples += 1
        t_prev = self.filter.newest_ns
        if sample.quat_xyzw is not None:
            sample = self._fused(sample)
            self.attitude.push(sample.stamp_ns / NS_PER_S, sample.quat_xyzw,
                               sample.attitude_cov_rad2)
        self.filter.add_imu(sample.stamp_ns,
                            self.accel_input(self.along_track_acceleration(sample)),
                            self.tilt_leak_q(sample))
        self.still = self.standstill.push(sample.stamp_ns, sample.gyro_rps, sample.accel_mps2)
        self._zero_velocity(sample.stamp_ns)
        self._drain_frames()
        return self._grid_estimates(t_prev, sample.stamp_ns)

    def zero_velocity_allowed(self, t_ns, state):
        """A zero-velocity update at ``t_ns``? The IMU's standstill evidence is trusted only
        while the filter's speed is near zero and well known: a platform without
        vibration (a rig with it switched off) would look standing at any constant
        speed (train_localizer's rule). Subclasses may add unambiguous evidence.
        """
        cfg = self.config.standstill
        return self.still and StandstillDetector.speed_allows_update(state.x[1], state.P[1, 1],
                                                                    cfg)

    def _zero_velocity(self, t_ns):
        cfg = self.config.standstill
        if not cfg.enabled:
            return
        if (self._last_zupt_ns is not None
                and t_ns - self._last_zupt_ns < cfg.update_period_s * NS_PER_S):
            return
        if not self.zero_velocity_allowed(t_ns, self.filter.state):
            return
        self.filter.add_measurement(t_ns, H_SPEED, 0.0, cfg.speed_sigma_mps ** 2)
        self._last_zupt_ns = t_ns
        self.counters.zero_velocity_updates += 1

    # ------------------------------------------------------------------ output
    def _grid_estimates(self, t_prev_ns, t_ns):
        if t_prev_ns is None:
            first = math.ceil(t_ns / self._grid_ns - 1e-9)
        else:
            first = math.floor(t_prev_ns / self._grid_ns + 1e-9) + 1
        out = []
        k = first
        while True:
            stamp = int(round(k * self._grid_ns))
            if stamp > t_ns:
                break
            est = self.estimate_at(stamp)
            if est is not None:
                out.append(est)
            k += 1
        return out

    def estimate_at(self, t_ns):
        """PoseEstimate at ``t_ns`` if chainage and speed are known well enough there, else
        None.
        """
        state = self.filter.state_at(t_ns)
        if (state is None or not state.P[0, 0] <= self.config.max_sigma_m ** 2
                or not state.P[1, 1] <= self.config.max_speed_sigma_mps ** 2):
            return None
        q = self.attitude_at(t_ns)
        y0, z0 = self.config.track_offset_yz_m
        return PoseEstimate(stamp_ns=int(t_ns), position_m=np.array([state.x[0], y0, z0]),
                            chainage_var_m2=float(state.P[0, 0]), speed_mps=float(state.x[1]),
                            speed_var=float(state.P[1, 1]),
                            quat_xyzw=IDENTITY_QUAT.copy() if q is None else q)

    def attitude_at(self, t_ns):
        """Quaternion (x, y, z, w) at ``t_ns`` from the imu/data history, or None."""
        if not self.config.use_imu_attitude:
            return None
        return self.attitude.at(t_ns / NS_PER_S)

    def rotation_at(self, t_ns):
        """R_map_base at ``t_ns`` (identity when unknown) and the attitude covariance."""
        q = self.attitude_at(t_ns)
        if q is None:
            return np.eye(3), None
        cov = self.attitude.covariance_at(t_ns / NS_PER_S)
        return quat_to_matrix(q), (cov if cov is not None and np.all(np.isfinite(cov))
                                   else None)

    def add_frame(self, stamp_ns, observations):
        """One stereo frame's lamp observations (LampObservation list).

        The frame is processed once ``imu/data`` covers its exposure (the attitude at its
        measurement instants is needed), at once if it already does. Returns the results
        of the frames processed by this call (see :meth:`take_results`).
        """
        self._waiting.append((int(stamp_ns), observations))
        self._waiting.sort(key=lambda f: f[0])
        self._drain_frames()
        return self.take_results()

    def take_results(self):
        """Results of :meth:`process_frame` since the last call, in processing order
        (frames processed when an IMU sample released them included).
        """
        out, self._results = self._results, []
        return out

    def _drain_frames(self):
        newest = self.filter.newest_ns
        span = int(self.config.frame_span_s * NS_PER_S)
        while self._waiting:
            stamp_ns, observations = self._waiting[0]
            covered = newest is not None and newest >= stamp_ns + span
            if not covered and len(self._waiting) <= self.config.max_waiting_frames:
                return
            self._waiting.pop(0)
            if not covered:
                self.counters.frames_without_attitude += 1
            start = time.thread_time()
            self._results.extend(self.process_frame(stamp_ns, observations))
            self.frame_cpu_ms.append(1e3 * (time.thread_time() - start))

    def process_frame(self, stamp_ns, observations):
        """Process one frame whose attitude is known (subclasses); returns a list."""
        raise NotImplementedError
