"""The localizer without ROS: IMU samples and lamp observations in, poses out.

Time handling (all stamps integer ns of the sensor clock):

* Every accepted IMU sample adds a step to a short history
  (:mod:`train_localizer.core.history`); a lamp fix, older than the newest IMU sample
  because image processing takes longer than an IMU period, is inserted where it
  belongs and the later steps are replayed, exactly as an in-order filter would have.
* A fix newer than the newest IMU sample waits for the IMU to catch up, unless the IMU
  lags the newest frame by more than ``imu_timeout_s`` (or never came); then the filter
  is extrapolated to the fix with an unknown acceleration (``unknown_accel_sigma_mps2``).
  An IMU sample that arrives later but is newer than the newest IMU sample is inserted
  into the history like a fix, so an IMU that starts late or lags is used as soon as
  it arrives.
* Poses: on a sensor-time grid and right after a fix (:mod:`train_localizer.core.publication`).
* Cold start from the first confirmed lamp and its earlier frames, or from a configured
  prior; restarts of the chainage when confirmed lamps contradict the state
  (:mod:`train_localizer.core.initialisation`, :mod:`train_localizer.core.integrity`).
* Zero-velocity updates while the IMU shows a standing platform
  (:mod:`train_localizer.core.standstill`).
* A sample older than the newest by more than ``backward_reset_s`` (a restarted clock or
  a looped bag) resets everything; a smaller step back is out of order and skipped.
"""
import bisect
import dataclasses
from dataclasses import dataclass, field
import math

import numpy as np

from imu_compensator.core.attitude_buffer import AttitudeBuffer
from train_localizer.core.cross_track import CrossTrackMotion, lateral_vertical
from train_localizer.core.disparity_map import DisparityMap
from train_localizer.core.fix import (
    FixConfig,
    RigGeometry,
    compute_fix,
    exp_so3,
    lamp_sigma,
    measurement_time_ns,
    triangulate,
    vision_attitude,
)
from train_localizer.core.history import NO_INPUT, StepHistory
from train_localizer.core.initialisation import ColdStart, prior_state, restarted_chainage
from train_localizer.core.integrity import (
    Contradiction,
    IntegrityConfig,
    IntegrityMonitor,
    Level,
    mahalanobis2,
    select_association,
)
from train_localizer.core.kalman import H_CHAINAGE, H_SPEED, KalmanConfig, initial_state, innovation
from train_localizer.core.lamp_refinement import PassRecorder
from train_localizer.core.publication import PoseGate
from train_localizer.core.reports import (
    AttitudeAid,
    Event,
    FixRecord,
    PoseEstimate,
    StepReport,
)
from train_localizer.core.self_survey import SelfSurvey
from train_localizer.core.standstill import StandstillConfig, StandstillDetector
from train_localizer.core.time_base import (
    FRAME,
    HELD,
    IMU,
    OUT_OF_ORDER,
    RESET,
    TimeBaseConfig,
    TimeBaseMonitor,
)
from vlc_common.core.observation import NS_PER_S
from vlc_common.core.rotations import matrix_to_quat_xyzw, quat_to_matrix

_DEG = math.pi / 180.0
_GRAVITY_MPS2 = 9.80665


def _cross3(a, b):
    """The cross product a × b of two 3-sequences of floats, as a tuple (np.cross's order)."""
    return (a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0])


@dataclass
class LocalizerConfig:
    """Everything the localizer needs; see config/train_localizer_node.yaml key by key.

    Attributes
    ----------
    geometry, fix, kalman, integrity, standstill
        Sub-configurations (:class:`RigGeometry`, :class:`FixConfig`,
        :class:`KalmanConfig`, :class:`IntegrityConfig`, :class:`StandstillConfig`).
    use_imu_attitude : bool
        Use ``imu/data``'s attitude for the fix geometry and to project the specific
        force on the track; False: attitude = identity with ``attitude_sigma_unknown_rad``.
    use_exposure_stamping : bool
        Stamp each fix at its spot's exposure mid-time; False: at the image stamp.
    use_kalman : bool
        Fuse in the Kalman filter; False: publish every accepted single-frame fix raw.
    publish_rate_hz : float
        Pose grid in sensor time, Hz.
    publish_on_fix : bool
        Also publish right after a fix is applied (lower latency).
    pose_sigma_yz_m : tuple of 2 floats
        1σ of the published pose across the track and vertically, m (the larger of it
        and the fix's ``track_sigma_yz_m``): base_link's offset from its nominal place,
        which the fix's track constraint takes as a few mm but the car body on its
        suspension over a poor track exceeds (7–11 mm on the ``harsh`` profile).
    motion_sigma_factor : float
        The published lateral and vertical 1σ is at least this factor times the car
        body's motion about the track that the IMU shows
        (:class:`~train_localizer.core.cross_track.CrossTrackMotion`; 40 mm at 100 km/h
        on the ``harsh`` profile); 0 = the configured 1σ only.
    motion_highpass_hz : float
        Corner of that estimate (the motion below it is not seen), Hz.
    motion_window_s : float
        Time constant of its running variance, s.
    history_s : float
        How far back a fix may be applied, s.
    imu_timeout_s : float
        The IMU counts as absent (fixes stop waiting for it) while it lags the newest
        frame stamp by more than this, s.
    imu_max_gap_s : float
        A longer IMU interval is a gap: its acceleration is treated as unknown, s.
    backward_reset_s : float
        A frame older than the newest frame by more than this is not a late frame but a
        sensor clock that went back (:mod:`train_localizer.core.time_base`), s.
    imu_backward_s : float
        An IMU sample older than the newest by more than this is a clock that went back, s.
    blind_gap_s : float
        Nothing received for longer than this: what happened meanwhile cannot be vouched
        for, the localizer resets (position lost until a confirmed lamp), s.
    clock_tolerance_s : float
        A gap of both inputs counts as time that passed when the graph's clock advanced
        by the gap within this; otherwise the chainage is widened by the distance run, s.
    attitude_sigma_floor_rad : tuple of 3 floats
        Smallest attitude 1σ about map x, y, z assumed for ``imu/data`` (also used when
        it carries no covariance), rad.
    attitude_sigma_unknown_rad : tuple of 3 floats
        Attitude 1σ when no attitude is used (the platform vibration's span), rad.
    attitude_plausible_rad : float
        An ``imu/data`` attitude whose heading differs from the track's, or whose tilt
        from the vertical, by more than this is not the platform's (it rides on the
        track): it is ignored as if the sample had none, rad.
    attitude_distrust_s : float
        After confirmed lamps whose range and direction disagree with the ``imu/data``
        attitude but agree without it, that attitude is ignored for this long, s.
    attitude_evidence_s : float
        It takes two such lamps (two frames, or two lamps of one frame) no further apart
        than this to distrust the attitude; the first one's fix is rejected. One wrong
        stereo match can agree under the wide attitude uncertainty without the IMU's, a
        wrong attitude disagrees in every frame; 0: one lamp is enough, s.
    attitude_aiding_period_s : float
        Shortest interval between two heading aids (the heading an accepted lamp shows,
        for the compensator's ``attitude_aiding``), s; 0 = none.
    attitude_aiding_calibration_inflation : float
        Factor on the calibration's covariance (raw images,
        :func:`~train_localizer.core.fix.calibration_covariance`) in the attitude an aid
        reports: that error is the same in every aid (a biased range moves the lamp's
        chainage and with it the heading its direction shows, 0.35° per 0.4 px of
        disparity 9 m ahead), but the compensator fuses aids as independent; weighting
        it as if this many aids shared it keeps it from averaging it into its heading.
    tilt_leak_time_s : float
        Time over which the gravity leak of the pitch error (g·σ_pitch, σ from
        ``imu/data``) may wander; sets the extra bias random walk, s; 0 = off.
    systematic_weight_inflation : float
        Factor on each fix's systematic variance in the filter update (the gate uses the
        plain sum): the systematic error is shared by consecutive fixes, so each must not
        count as an independent measurement of it. 1 = white.
    imu_lever_arm_m : tuple of 3 floats
        Position of the IMU in ``base_link``, m: its rotational accelerations are
        removed before the specific force is used.
    initial_chainage_m : float
        Prior chainage at start, m; NaN = no prior (no pose until a UID is confirmed).
    initial_chainage_sigma_m : float
        1σ of that prior, m.
    initial_speed_mps : float
        Prior speed, m/s; NaN = unknown.
    max_speed_mps : float
        Highest speed the train can have, m/s (bounds the cold-start lamp track).
    init_lookback_s : float
        How far back unconfirmed observations are kept for the cold start, s.
    """

    geometry: RigGeometry = field(default_factory=RigGeometry)
    fix: FixConfig = field(default_factory=FixConfig)
    kalman: KalmanConfig = field(default_factory=KalmanConfig)
    integrity: IntegrityConfig = field(default_factory=IntegrityConfig)
    standstill: StandstillConfig = field(default_factory=StandstillConfig)
    use_imu_attitude: bool = True
    use_exposure_stamping: bool = True
    use_kalman: bool = True
    publish_rate_hz: float = 50.0
    publish_on_fix: bool = True
    pose_sigma_yz_m: tuple = (0.01, 0.01)
    motion_sigma_factor: float = 3.0
    motion_highpass_hz: float = 0.4
    motion_window_s: float = 2.0
    history_s: float = 1.0
    imu_timeout_s: float = 0.2
    imu_max_gap_s: float = 0.05
    backward_reset_s: float = 1.0
    imu_backward_s: float = 0.05
    blind_gap_s: float = 3.0
    clock_tolerance_s: float = 0.1
    attitude_sigma_floor_rad: tuple = (0.05 * _DEG, 0.05 * _DEG, 0.1 * _DEG)
    attitude_sigma_unknown_rad: tuple = (0.5 * _DEG, 0.5 * _DEG, 5.0 * _DEG)
    attitude_plausible_rad: float = 10.0 * _DEG
    attitude_distrust_s: float = 2.0
    attitude_evidence_s: float = 0.5
    imu_lever_arm_m: tuple = (0.0, 0.0, 0.0)
    tilt_leak_time_s: float = 5.0
    systematic_weight_inflation: float = 3.0
    attitude_aiding_period_s: float = 0.2
    attitude_aiding_calibration_inflation: float = 5.0
    initial_chainage_m: float = float('nan')
    initial_chainage_sigma_m: float = 1.0
    initial_speed_mps: float = float('nan')
    max_speed_mps: float = 40.0
    init_lookback_s: float = 0.5
    #: :class:`~train_localizer.core.self_survey.SelfSurveyConfig` (None: off) and the
    #: lamps' priors of a saved refinement ({uid: (mean m, 1σ m)})
    self_survey: object = None
    lamp_priors: dict = field(default_factory=dict)
    #: :class:`~train_localizer.core.lamp_refinement.RefinementConfig` (None: no pair
    #: measurements) and the corrections applied to the map at start ({uid: m})
    refinement: object = None
    refinement_applied: dict = field(default_factory=dict)
    #: :class:`~train_localizer.core.lamp_refinement_file.KeptRefinement` the node read
    refinement_kept: object = None
    #: :class:`~train_localizer.core.disparity_map.DisparityMapConfig` (None: off; learnt
    #: and applied only with raw images) and the kept cells ({(i, j): Cell})
    disparity_map: object = None
    disparity_map_kept: dict = field(default_factory=dict)
    disparity_map_kept_fx_b: float = None
    disparity_map_runs: int = 0           # runs behind the kept cells
    disparity_map_state: str = 'off'      # what the node made of the kept file

    def __post_init__(self):
        for name in ('publish_rate_hz', 'history_s', 'imu_timeout_s', 'imu_max_gap_s',
                     'attitude_plausible_rad', 'attitude_distrust_s',
                     'backward_reset_s', 'imu_backward_s', 'blind_gap_s', 'clock_tolerance_s',
                     'initial_chainage_sigma_m', 'max_speed_mps',
                     'init_lookback_s', 'systematic_weight_inflation',
                     'motion_highpass_hz', 'motion_window_s'):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0.0):
                raise ValueError(f'{name} must be finite and > 0, got {value}')
        self.imu_lever_arm_m = tuple(float(v) for v in self.imu_lever_arm_m)
        self.pose_sigma_yz_m = tuple(float(v) for v in self.pose_sigma_yz_m)
        for name in ('motion_sigma_factor', 'attitude_evidence_s'):
            value = getattr(self, name)
            if not (math.isfinite(value) and value >= 0.0):
                raise ValueError(f'{name} must be finite and >= 0, got {value}')
        if len(self.pose_sigma_yz_m) != 2 or not all(
                math.isfinite(v) and v > 0.0 for v in self.pose_sigma_yz_m):
            raise ValueError(f'pose_sigma_yz_m must be 2 finite values > 0, '
                             f'got {self.pose_sigma_yz_m}')


@dataclass
class _Prepared:
    """An observation with its geometry worked out (triangulation and attitude)."""

    t_ns: int
    obs: object
    p_cam: np.ndarray
    cov_cam: np.ndarray
    R: np.ndarray
    cov_att: np.ndarray
    disparity_sigma_px: float = None      # the learnt map's disparity 1σ (None: calibration's)
    raw_obs: object = None                # the observation before the map's correction


class Localizer:
    """IMU-driven along-track filter with delayed lamp fixes; see the module docstring.

    Parameters
    ----------
    lamp_map : vlc_common.core.lamp_map.LampMap
    config : LocalizerConfig
    """

    def __init__(self, lamp_map, config=None):
        self.lamp_map = lamp_map
        self.config = config or LocalizerConfig()
        self.monitor = IntegrityMonitor(self.config.integrity)
        cfg = self.config
        self._steps = StepHistory(cfg.kalman, cfg.history_s)
        self._gate = PoseGate(cfg.publish_rate_hz, cfg.integrity.max_sigma_m)
        self._cold = ColdStart(cfg.init_lookback_s, cfg.max_speed_mps)
        self._time = TimeBaseMonitor(TimeBaseConfig(
            backward_reset_s=cfg.backward_reset_s, imu_backward_s=cfg.imu_backward_s,
            blind_gap_s=cfg.blind_gap_s))
        self._lost_reason = None
        self.survey = (SelfSurvey(cfg.self_survey, dict(cfg.lamp_priors))
                       if cfg.self_survey is not None else None)
        self._survey_started = False
        self._survey_seq = 0
        self.pass_recorder = (PassRecorder(cfg.refinement, cfg.refinement_applied)
                              if cfg.refinement is not None else None)
        self.disparity_map = (DisparityMap(cfg.disparity_map, cfg.disparity_map_kept,
                                           cfg.disparity_map_kept_fx_b)
                              if cfg.disparity_map is not None else None)
        self._disparity_checked = False
        self._reset_state()

    # ----------------------------------------------------------------- state
    def _reset_state(self):
        cfg = self.config
        self._steps.clear()
        self._gate.reset()
        self._cold.clear()
        self._pending = []  # (measurement_ns, seq, observation) waiting for the IMU
        self._seq = 0
        self._att = AttitudeBuffer(horizon_s=cfg.history_s + 1.0,
                                   max_gap_s=max(cfg.imu_max_gap_s, 1e-3),
                                   max_extrapolation_s=cfg.imu_max_gap_s)
        self._standstill = StandstillDetector(cfg.standstill)
        self._motion = CrossTrackMotion(cfg.motion_highpass_hz, cfg.motion_window_s,
                                        max(cfg.imu_max_gap_s, 1e-3))
        self._last_zupt_ns = None
        self._time.reset_streams()
        self._newest_imu_ns = None
        self._imu_received_ns = None
        self._newest_frame_ns = None
        self._first_frame_ns = None
        self._prev_gyro = None
        self._last_accel = 0.0
        self._initialized = False
        self._has_fix = False
        self._systematic_var = cfg.fix.lamp_position_sigma_m ** 2
        self._last_aid_ns = None
        self._distrust_until_ns = None
        self._attitude_suspect = None     # (stamp ns, lamp uid) of a first disagreeing lamp
        self.monitor.clear()

    def reset(self):
        """Forget everything but the counters (as at start)."""
        self._reset_state()
        self._lost_reason = None

    @property
    def time_base(self):
        """The :class:`~train_localizer.core.time_base.TimeBaseMonitor` (its counters)."""
        return self._time

    @property
    def initialized(self):
        return self._initialized

    @property
    def newest_ns(self):
        return self._steps.newest_ns

    def current_state(self):
        """Newest filter state (FilterState) or None before initialisation."""
        return self._steps.newest_state

    def state_at(self, stamp_ns):
        """Filter state (FilterState) at ``stamp_ns`` within the history, else None."""
        t = int(stamp_ns)
        steps = self._steps
        if (not self.config.use_kalman or not steps.t or t < steps.t[0] or t > steps.t[-1]
                or steps.x[-1] is None):
            return None
        return steps.state_at(t)

    def apply_chainage_aid(self, stamp_ns, chainage_m, var_m2, reset=False):
        """An external chainage measurement at ``stamp_ns`` (re-acquisition aid, see
        :mod:`train_localizer.core.reacquisition`, which decides whether to call this).

        Inserted and replayed like a lamp fix: a chainage update with variance
        ``var_m2``, or with ``reset`` the chainage set to ``chainage_m`` (variance
        ``var_m2``) and, as after two lamps contradicting for ``reinit_after_s``, the
        speed and bias uncertainties raised to ``reinit_speed_sigma_mps`` and
        ``initial_bias_sigma_mps2`` (a state that far off had its speed wrong too).
        Returns False, changing nothing, when there is no state at ``stamp_ns``.
        """
        if self.state_at(stamp_ns) is None:
            return False
        i = self._insert_step(int(stamp_ns))
        if reset:
            self._set_chainage(i, chainage_m, var_m2, keep_speed=False)
        else:
            self._steps.add_update(i, ('z', H_CHAINAGE, float(chainage_m), float(var_m2)))
        self._gate.fix_pending = self.config.publish_on_fix
        return True

    @property
    def systematic_sigma_m(self):
        """1σ of the systematic error the state carries (survey, calibration, attitude;
        part of the published chainage σ), m.
        """
        return math.sqrt(self._systematic_var)

    def status(self):
        """(IntegrityState, Level, message, published chainage 1σ in m or NaN)."""
        state = self.current_state()
        sigma = (math.sqrt(state.P[0, 0] + self._extra_var()) if state is not None
                 else float('nan'))
        if not self.config.use_kalman:
            sigma = 0.0
        st, level, msg = self.monitor.status(self.newest_ns, self._initialized,
                                             self._has_fix, sigma, self._lost_reason)
        suspicion = self.monitor.suspicion_var_m2()
        if suspicion > 0.0 and self._initialized:
            msg += (f'; a confirmed lamp contradicts the state by {math.sqrt(suspicion):.2f} m: '
                    'covariance widened until one agrees')
        return st, level, msg, sigma

    def _extra_var(self):
        """Published chainage variance beyond the filter's: the systematic part the state
        carries (:meth:`_blend_systematic`) and the contradiction of a confirmed lamp not
        yet resolved, m².
        """
        return self._systematic_var + self.monitor.suspicion_var_m2()

    # ----------------------------------------------------------------- IMU
    def add_imu(self, sample, received_ns=None):
        """Add one ``imu/data`` sample; returns a :class:`StepReport`.

        ``received_ns``: the graph's clock when the sample was taken (ns; None or 0 when
        unknown). It tells a gap of both inputs in which time passed from a sensor clock
        that stepped forward (see :meth:`_bridge_gap`).
        """
        report = StepReport()
        if not sample.is_finite():
            self.monitor.counters.imu_rejected += 1
            report.events.append(Event(Level.WARN, 'imu_nonfinite',
                                       'IMU sample with NaN/inf or zero quaternion skipped'))
            return report
        verdict = self._time.check(IMU, sample.stamp_ns, (sample, received_ns))
        if verdict == RESET:
            self._time_reset(report, IMU)
            for _, (held, held_received) in self._time.take_held(IMU):
                self._time.check(IMU, held.stamp_ns)
                self._use_imu(held, held_received, report)
        elif verdict == HELD:
            self._held_event(report)
        elif verdict == OUT_OF_ORDER:
            self.monitor.counters.imu_rejected += 1
            behind_ms = (self._newest_imu_ns - sample.stamp_ns) * 1e-6
            report.events.append(Event(Level.WARN, 'imu_out_of_order',
                                       f'IMU sample {behind_ms:.3f} ms older than the newest '
                                       'skipped'))
        else:
            self._use_imu(sample, received_ns, report)
        return report

    def _held_event(self, report):
        report.events.append(Event(Level.WARN, 'time_candidate',
                                   f'{self._time.last_reason}: held until more inputs confirm '
                                   'a new time base (a lone one is dropped)'))

    def _use_imu(self, sample, received_ns, report):
        cfg = self.config
        t = int(sample.stamp_ns)
        if sample.quat_xyzw is not None and not self._attitude_usable(sample, report):
            sample = dataclasses.replace(sample, quat_xyzw=None, attitude_cov_rad2=None)
        if sample.quat_xyzw is not None:
            self._att.push(t * 1e-9, sample.quat_xyzw, sample.attitude_cov_rad2)
        accel = self._along_track_accel(sample)
        gap = (self._newest_imu_ns is not None
               and (t - self._newest_imu_ns) > cfg.imu_max_gap_s * NS_PER_S)
        if gap:
            report.events.append(Event(Level.WARN, 'imu_gap',
                                       f'IMU gap of {(t - self._newest_imu_ns) * 1e-9:.3f} s: '
                                       'acceleration unknown over it'))
        first = self._newest_imu_ns is None
        a_in = NO_INPUT if (gap or first) else (0.5 * (self._last_accel + accel),
                                                self._tilt_leak_q(sample))
        self._last_accel = accel
        if self.pass_recorder is not None:
            newest = self._steps.newest_state
            bias, bias_var = ((float(newest.x[2]), float(newest.P[2, 2]))
                              if newest is not None else (0.0, float('inf')))
            self.pass_recorder.add_accel(t / NS_PER_S, None if gap else accel - bias,
                                         bias_var)
        previous_ns, previous_received = self._newest_imu_ns, self._imu_received_ns
        self._newest_imu_ns = t
        self._imu_received_ns = received_ns if received_ns else None
        if self._steps.t and t <= self._steps.t[-1]:
            # Fixes were extrapolated past this sample while the IMU lagged: put it where
            # it belongs and replay the later steps.
            self._steps.insert_sample(t, a_in, sample.gyro_rps)
            self._gate.start_grid(t)
        else:
            self._append_step(t, a_in, sample.gyro_rps)
            if gap:
                self._bridge_gap(t, previous_ns, previous_received, report)
        # the window's statistics only when the filter would take an update (a moving
        # train fails the speed test first: 0.1 ms per sample saved at 400 Hz)
        self._standstill.add(t, sample.gyro_rps, sample.accel_mps2)
        if cfg.standstill.enabled:
            self._zero_velocity(t)
        self._process_pending(report)
        self._emit(report)

    def _attitude_usable(self, sample, report):
        """False for an ``imu/data`` attitude the platform cannot have (heading or tilt
        more than ``attitude_plausible_rad`` off the track), or while a confirmed lamp
        showed it wrong (``attitude_distrust_s``): the sample is then used as one
        without attitude (the track's, with ``attitude_sigma_unknown_rad``).
        """
        cfg = self.config
        t = sample.stamp_ns
        if self._distrust_until_ns is not None and t <= self._distrust_until_ns:
            return False
        R = quat_to_matrix(sample.quat_xyzw / np.linalg.norm(sample.quat_xyzw))
        heading = 0.0
        if self._steps.newest_state is not None or cfg.fix.track.straight_x:
            # (on a curve the track's heading is known once the chainage is)
            heading = self._heading_off_track(R)
        tilt = math.acos(min(1.0, max(-1.0, float(R[2, 2]))))
        if max(abs(heading), tilt) <= cfg.attitude_plausible_rad:
            return True
        self.monitor.counters.imu_attitude_implausible += 1
        report.events.append(Event(Level.WARN, 'attitude_implausible',
                                   f'imu/data attitude {math.degrees(heading):+.1f} deg off the '
                                   f'track heading, tilted {math.degrees(tilt):.1f} deg: not the '
                                   'platform\'s; used without attitude'))
        return False

    def _newest_chainage(self):
        """The newest chainage estimate; the start of the track before there is one."""
        state = self._steps.x[-1] if self._steps.x else None
        return float(state.x[0]) if state is not None else 0.0

    def _track_frame(self, chainage_m=None):
        """(point, tangent, left normal) of the track at ``chainage_m`` (default:
        :meth:`_newest_chainage`).
        """
        if chainage_m is None:
            chainage_m = self._newest_chainage()
        return self.config.fix.track.frame(chainage_m)

    def _heading_off_track(self, R, chainage_m=None):
        """Heading of attitude ``R`` (body x) from the track's running direction at
        ``chainage_m`` (default: the newest estimate), rad, positive to the left.
        """
        _, tangent, normal = self._track_frame(chainage_m)
        return math.atan2(float(R[:, 0] @ normal), float(R[:, 0] @ tangent))

    def _bridge_gap(self, t, previous_ns, previous_received, report):
        """An IMU gap from ``previous_ns`` to ``t`` in which no frame came either.

        A stalled process and a sensor clock stepped forward look the same in the
        stamps: in the second the train did not run the distance the state's speed
        says. Unless the graph's clock shows that the time passed (it advanced by the
        gap within ``clock_tolerance_s``), the chainage is widened by that distance.
        """
        cfg = self.config
        if self._newest_frame_ns is not None and self._newest_frame_ns > previous_ns:
            return
        gap_ns = t - previous_ns
        received = self._imu_received_ns
        if (received is not None and previous_received is not None
                and received - previous_received >= gap_ns - cfg.clock_tolerance_s * NS_PER_S):
            return
        if self._steps.x[-1] is None:
            return
        self._steps.add_update(len(self._steps) - 1, ('doubt', gap_ns * 1e-9))
        # no pose for an instant inside the gap: the widening applies from its end on
        self._gate.skip_to(t)
        report.events.append(Event(Level.WARN, 'time_doubt',
                                   f'no input for {gap_ns * 1e-9:.3f} s and nothing shows that '
                                   'the time passed: chainage widened by the distance run in it'))

    def _along_track_accel(self, sample):
        """Measured along-track acceleration of ``base_link`` (bias included), m/s².

        The specific force rotated into ``map`` plus gravity, x component (straight
        track). Gravity has no x component, so ``a_x = (R·f)_x``: the attitude matters
        because a pitch of θ leaks g·θ of gravity into the body x axis. The same specific
        force feeds the car body's motion estimate across and above the track
        (``self._motion``, :mod:`~train_localizer.core.cross_track`).
        """
        cfg = self.config
        f = sample.accel_mps2
        r = cfg.imu_lever_arm_m
        if any(r):
            w = sample.gyro_rps
            if self._prev_gyro is not None and self._newest_imu_ns is not None:
                dt = (sample.stamp_ns - self._newest_imu_ns) * 1e-9
                alpha = (w - self._prev_gyro) / dt if dt > 0.0 else np.zeros(3)
            else:
                alpha = np.zeros(3)
            # Rigid body: f_imu = f_base + α×r + ω×(ω×r) (3-vector cross products in
            # floats: np.cross costs ~15 µs a call, three per sample at 400 Hz).
            w_l = w.tolist()
            f = (np.asarray(f, dtype=float) - np.array(_cross3(alpha.tolist(), r))
                 - np.array(_cross3(w_l, _cross3(w_l, r))))
        self._prev_gyro = sample.gyro_rps
        track = cfg.fix.track
        q = (sample.quat_xyzw / np.linalg.norm(sample.quat_xyzw)
             if cfg.use_imu_attitude and sample.quat_xyzw is not None else None)
        # the whole rotation only where it is needed: the motion estimate, a curve
        R = (quat_to_matrix(q) if q is not None
             and (cfg.motion_sigma_factor > 0.0 or not track.straight_x) else None)
        if cfg.motion_sigma_factor > 0.0:
            # across the heading in map (the body's roll is not motion); body axes without
            # an attitude
            self._motion.add(sample.stamp_ns * 1e-9,
                             *(lateral_vertical(R, f) if R is not None
                               else (float(f[1]), float(f[2]))))
        if q is not None:
            x, y, z, w = q
            # First row of the rotation matrix: only the along-track component is needed.
            row_x = ((1.0 - 2.0 * (y * y + z * z)), 2.0 * (x * y - z * w), 2.0 * (x * z + y * w))
            if track.straight_x:
                return float(row_x[0] * f[0] + row_x[1] * f[1] + row_x[2] * f[2])
            return float(self._tangent() @ (R @ np.asarray(f, dtype=float)))
        # no attitude: the platform is taken as riding the track (body axes = the track
        # frame, Track.attitude). On a grade its body x is pitched, and f[0] would take
        # g·grade of gravity for acceleration: a change of grade in a dark stretch (3 % on
        # curved_demo) is then a 0.3 m/s² error that the bias learnt before cannot follow.
        if track.straight_x:
            return float(f[0])
        R = track.attitude(self._newest_chainage())
        heading = math.atan2(float(R[1, 0]), float(R[0, 0]))
        return float(math.cos(heading) * (R[0] @ f) + math.sin(heading) * (R[1] @ f))

    def _tangent(self):
        """Running direction (3,) at the newest chainage estimate (curved track)."""
        return self._track_frame()[1]

    def _zero_velocity(self, t):
        """Zero-velocity update at the newest step if the filter's speed allows it and the
        IMU's window is quiet.
        """
        cfg = self.config.standstill
        state = self._steps.x[-1]
        if state is None or not self.config.use_kalman:
            return
        period_ns = cfg.update_period_s * NS_PER_S
        if self._last_zupt_ns is not None and t - self._last_zupt_ns < period_ns:
            return
        if not StandstillDetector.speed_allows_update(state.x[1], state.P[1, 1], cfg):
            return
        if not self._standstill.quiet():
            return
        self._last_zupt_ns = t
        self._steps.add_update(len(self._steps) - 1,
                               ('z', H_SPEED, 0.0, cfg.speed_sigma_mps ** 2))

    def _tilt_leak_q(self, sample):
        """Extra bias random-walk intensity (m²/s⁵) from the pitch uncertainty of a sample.

        A pitch error δθ leaks g·δθ of gravity into the along-track acceleration. It is
        not white: it drifts with the attitude filter's error (after a cold start at
        speed the pitch is uncertain by degrees for tens of seconds, 1° = 0.17 m/s²).
        It is modelled as bias wander that can cover g·σ_pitch within
        ``tilt_leak_time_s``: intensity (g·σ_pitch)² / τ.
        """
        cfg = self.config
        tau = cfg.tilt_leak_time_s
        if tau <= 0.0:
            return 0.0
        if cfg.use_imu_attitude and sample.quat_xyzw is not None:
            floor = cfg.attitude_sigma_floor_rad[1] ** 2
            cov = sample.attitude_cov_rad2
            var = floor if cov is None else max(float(cov[1, 1]), floor)
        else:
            var = cfg.attitude_sigma_unknown_rad[1] ** 2
        return (_GRAVITY_MPS2 ** 2) * var / tau

    # ----------------------------------------------------------------- frames
    def add_frame(self, stamp_ns, observations):
        """Add the lamp observations of one stereo frame; returns a :class:`StepReport`."""
        report = StepReport()
        stamp_ns = int(stamp_ns)
        verdict = self._time.check(FRAME, stamp_ns, observations)
        if verdict == HELD:
            self._held_event(report)
            return report
        if verdict == RESET:
            self._time_reset(report, FRAME)
            for held_ns, held in self._time.take_held(FRAME):
                self._time.check(FRAME, held_ns)
                self._use_frame(held_ns, held, report)
        else:
            self._use_frame(stamp_ns, observations, report)
        return report

    def _use_frame(self, stamp_ns, observations, report):
        cfg = self.config
        if self._newest_frame_ns is None:
            self._first_frame_ns = stamp_ns
        self._newest_frame_ns = (stamp_ns if self._newest_frame_ns is None
                                 else max(self._newest_frame_ns, stamp_ns))
        for obs in observations:
            if not obs.is_finite():
                self.monitor.counters.bad_observations += 1
                report.fixes.append(FixRecord(stamp_ns, obs.uid, None, 'bad_observation'))
                report.events.append(Event(Level.WARN, 'bad_observation',
                                           'lamp record with NaN/inf centre or sigma skipped'))
                continue
            t_m = measurement_time_ns(obs, cfg.geometry, cfg.use_exposure_stamping)
            self._seq += 1
            bisect.insort(self._pending, (t_m, self._seq, obs))
        self._process_pending(report)
        self._emit(report)

    def _imu_absent(self):
        """True when the IMU lags the newest frame by more than ``imu_timeout_s``."""
        if self._newest_frame_ns is None:
            return False
        reference = (self._newest_imu_ns if self._newest_imu_ns is not None
                     else self._first_frame_ns)
        return self._newest_frame_ns - reference > self.config.imu_timeout_s * NS_PER_S

    def _process_pending(self, report):
        while self._pending:
            t_m, _, obs = self._pending[0]
            imu = self._newest_imu_ns
            if imu is not None and t_m <= imu:
                pass
            elif self._imu_absent():
                if self._steps.t and t_m > self._steps.t[-1]:
                    self._append_step(t_m, NO_INPUT, np.zeros(3))
            else:
                break
            self._pending.pop(0)
            self._handle_observation(t_m, obs, report)

    # ----------------------------------------------------------------- steps
    def _append_step(self, t, a_in, gyro):
        """Append a step at the newest end: propagated, or from the configured prior when
        it is the first step after start or a reset.
        """
        first = None
        cfg = self.config
        if not self._steps.t and cfg.use_kalman and math.isfinite(cfg.initial_chainage_m):
            first = prior_state(cfg)
            self._initialized = True
            self._gate.open_at(t)
        self._steps.append(t, a_in, gyro, first)
        self._gate.start_grid(t)

    def _insert_step(self, t):
        i = self._steps.insert(t)
        self._gate.start_grid(t)
        return i

    # ----------------------------------------------------------------- attitude
    def _attitude(self, t):
        """(R_map_base (3, 3), covariance (3, 3)) to use at ``t``."""
        cfg = self.config
        floor = np.square(cfg.attitude_sigma_floor_rad)
        if cfg.use_imu_attitude:
            q = self._att.at(t * 1e-9)
            if q is not None:
                cov = self._att.covariance_at(t * 1e-9)
                if cov is None or not np.all(np.isfinite(cov)):
                    cov = np.diag(floor)
                else:
                    cov = cov + np.diag(np.maximum(floor - np.diag(cov), 0.0))
                return quat_to_matrix(q), cov
        return self._track_attitude(t), np.diag(np.square(cfg.attitude_sigma_unknown_rad))

    def _track_attitude(self, t):
        """The attitude of a platform riding the track at the state's chainage at ``t``
        (:meth:`Track.attitude`: heading, grade and cant; identity on the straight along
        map x).
        """
        state = self._steps.state_at(t) if self._steps.t else None
        if state is None and not self.config.fix.track.straight_x:
            state = self._steps.newest_state
        return self.config.fix.track.attitude(
            self._newest_chainage() if state is None else float(state.x[0]))

    # ----------------------------------------------------------------- fixes
    def _fix_for(self, prep, lamp):
        """(FixResult, geometry_ok) of a prepared observation explained by ``lamp``."""
        cfg = self.config
        fix = compute_fix(prep.p_cam, prep.cov_cam, lamp.position_m, prep.R, prep.cov_att,
                          cfg.geometry, cfg.fix, lamp_sigma(lamp, cfg.fix),
                          prep.disparity_sigma_px)
        geometry_ok = not (fix.chi2_geometry > cfg.integrity.geometry_gate_chi2)
        return fix, geometry_ok

    def _handle_observation(self, t_m, obs, report):
        cfg = self.config
        mon = self.monitor
        if self._steps.is_too_old(t_m):
            mon.counters.records_too_old += 1
            report.fixes.append(FixRecord(t_m, obs.uid, None, 'too_old'))
            report.events.append(Event(Level.WARN, 'fix_too_old',
                                       'lamp record older than the history window dropped'))
            return
        raw_obs, disparity_sigma = obs, None
        if self.disparity_map is not None and cfg.geometry.raw_images:
            obs, disparity_sigma = self._disparity_corrected(obs)
        p_cam, cov_cam = triangulate(obs, cfg.geometry, cfg.fix.min_disparity_px)
        if p_cam is None:
            mon.counters.bad_observations += 1
            report.fixes.append(FixRecord(t_m, obs.uid, None, 'bad_observation',
                                          detail='disparity too small'))
            report.events.append(Event(Level.WARN, 'bad_observation',
                                       f'lamp record with disparity {obs.disparity_px:.2f} px '
                                       'skipped'))
            return
        if self.survey is not None:
            self._start_survey()
            p_cam, cov_cam = self.survey.correct(p_cam, cov_cam, obs.disparity_px)
        R, cov_att = self._attitude(t_m)
        prep = _Prepared(t_m, obs, p_cam, cov_cam, R, cov_att, disparity_sigma, raw_obs)
        lamp = None
        if obs.uid is not None:
            lamp = self.lamp_map.by_uid(obs.uid)
            if lamp is None:
                mon.on_unknown_uid(t_m, obs.uid)
                report.fixes.append(FixRecord(t_m, obs.uid, None, 'unknown_uid'))
                report.events.append(Event(Level.WARN, 'unknown_uid',
                                           f'UID {int(obs.uid):#06x} is not in the lamp map: '
                                           'record skipped'))
                return
        if not cfg.use_kalman:
            self._raw_fix(prep, lamp, report)
        elif not self._initialized:
            self._try_initialise(prep, lamp, report)
        else:
            self._fuse(prep, lamp, report)

    def _fuse(self, prep, lamp, report):
        """Gate one observation against the filter and apply it (initialised filter)."""
        mon = self.monitor
        t_m, obs = prep.t_ns, prep.obs
        state = self._steps.state_at(t_m)
        if state is None:
            report.fixes.append(FixRecord(t_m, obs.uid, None, 'too_old',
                                          detail='older than the initialisation'))
            return
        confirmed = lamp is not None
        if not confirmed:
            lamp, fix, d2, why = self._associate(state, prep)
            if lamp is None:
                mon.counters.unconfirmed_skipped += 1
                report.fixes.append(FixRecord(t_m, None, None, 'unconfirmed_skipped', detail=why))
                return
        else:
            fix, geometry_ok = self._fix_for(prep, lamp)
            if not geometry_ok:
                fix, geometry_ok = self._fix_without_imu_attitude(prep, lamp, fix, report)
            if not geometry_ok:
                self._geometry_rejected(prep, lamp, fix, report)
                return
            if self.survey is not None:
                self._survey_fix(prep, lamp, fix, state)
            y, S = innovation(state, fix.chainage_m, fix.var_m2)
            d2 = mahalanobis2(y, S)
            if d2 > self.config.integrity.gate_chi2:
                decision = mon.on_contradiction(Contradiction(t_m, int(obs.uid), y, S))
                if decision is not None:
                    self._reinitialise(t_m, fix, decision, report)
                    report.fixes.append(FixRecord(t_m, obs.uid, lamp.uid, 'reinitialised',
                                                  fix.chainage_m, fix.var_m2, d2))
                    return
                report.fixes.append(FixRecord(t_m, obs.uid, lamp.uid, 'rejected_gate',
                                              fix.chainage_m, fix.var_m2, d2))
                report.events.append(Event(Level.WARN, 'fix_contradiction',
                                           f'lamp {lamp.uid:#06x} contradicts the state by '
                                           f'{y:+.2f} m (d2 {d2:.0f}): skipped, moved or spoofed '
                                           'lamp; fix rejected'))
                return
        self._apply_fix(t_m, fix)
        mon.on_accepted(t_m, confirmed)
        if confirmed and self.pass_recorder is not None:
            self.pass_recorder.add(t_m / NS_PER_S, lamp.uid, fix.chainage_m, fix.var_random_m2)
        if (confirmed and self.disparity_map is not None
                and self.config.geometry.raw_images):
            self._learn_disparity(prep, lamp, state)
        report.fixes.append(FixRecord(t_m, obs.uid, lamp.uid, 'accepted', fix.chainage_m,
                                      fix.var_m2, d2))
        self._attitude_aid(prep, lamp, fix, report)

    def _attitude_aid(self, prep, lamp, fix, report):
        """At most every ``attitude_aiding_period_s``: the attitude this accepted lamp shows.

        Sent also when imu/data's attitude is not used (none, implausible, distrusted):
        the fix then took the track's, and the aid is what tells the compensator its
        attitude is wrong (after a cold start in a curve its heading is 20-30° off, and
        without aids it stayed so for the whole run).
        """
        cfg = self.config
        period = cfg.attitude_aiding_period_s
        if period <= 0.0 or not cfg.use_imu_attitude or not cfg.fix.use_range_constraint:
            return
        if self._last_aid_ns is not None and abs(prep.t_ns - self._last_aid_ns) < period * NS_PER_S:
            return
        dtheta, cov = vision_attitude(prep.p_cam, prep.cov_cam, lamp.position_m, prep.R,
                                      cfg.geometry, cfg.fix, lamp_sigma(lamp, cfg.fix),
                                      cfg.attitude_aiding_calibration_inflation,
                                      prep.disparity_sigma_px)
        cov = 0.5 * (cov + cov.T)
        if not (np.all(np.isfinite(dtheta)) and np.all(np.isfinite(cov))
                and np.all(np.linalg.eigvalsh(cov) > 0.0)):
            return
        self._last_aid_ns = prep.t_ns
        report.attitude_aids.append(AttitudeAid(prep.t_ns,
                                                matrix_to_quat_xyzw(exp_so3(dtheta) @ prep.R),
                                                cov, fix.chainage_m))

    def _fix_without_imu_attitude(self, prep, lamp, fix, report):
        """A confirmed lamp's range and direction disagree under the ``imu/data``
        attitude: the same fix with the track's attitude and ``attitude_sigma_unknown``.
        When that agrees, either the IMU attitude is wrong or the stereo match is, and
        under that wide attitude uncertainty a wrong match can agree too. A second lamp
        showing the same within ``attitude_evidence_s`` (another frame, or another lamp
        of this one) decides for the attitude: it is ignored for ``attitude_distrust_s``
        and this fix is used; until then the fix is rejected. Returns (fix, geometry_ok).
        """
        cfg = self.config
        if not cfg.use_imu_attitude or self._att.at(prep.t_ns * 1e-9) is None:
            return fix, False
        R = self._track_attitude(prep.t_ns)
        cov = np.diag(np.square(cfg.attitude_sigma_unknown_rad))
        alt = dataclasses.replace(prep, R=R, cov_att=cov)
        fallback, ok = self._fix_for(alt, lamp)
        if not ok:
            return fix, False
        window_ns = int(cfg.attitude_evidence_s * NS_PER_S)
        first, here = self._attitude_suspect, (prep.t_ns, int(lamp.uid))
        if window_ns > 0 and (first is None or first == here
                              or abs(prep.t_ns - first[0]) > window_ns):
            self._attitude_suspect = here
            report.events.append(Event(Level.WARN, 'attitude_suspect',
                                       f'lamp {lamp.uid:#06x}: range and direction disagree '
                                       f'under the imu/data attitude (chi2 '
                                       f'{fix.chi2_geometry:.1f}) and agree without it: a '
                                       'wrong attitude or a wrong stereo match; fix rejected '
                                       'unless another lamp shows the same within '
                                       f'{cfg.attitude_evidence_s:.1f} s'))
            return fix, False
        self._attitude_suspect = None
        self.monitor.counters.fixes_attitude_fallback += 1
        until = prep.t_ns + int(cfg.attitude_distrust_s * NS_PER_S)
        self._distrust_until_ns = max(self._distrust_until_ns or until, until)
        report.events.append(Event(Level.WARN, 'attitude_distrusted',
                                   f'lamp {lamp.uid:#06x}: range and direction disagree under '
                                   f'the imu/data attitude (chi2 {fix.chi2_geometry:.1f}) and '
                                   'agree without it: that attitude is ignored for '
                                   f'{cfg.attitude_distrust_s:.1f} s'))
        return fallback, True

    def _geometry_rejected(self, prep, lamp, fix, report):
        self.monitor.on_geometry_rejected(prep.t_ns, prep.obs.uid, fix.chi2_geometry)
        report.fixes.append(FixRecord(prep.t_ns, prep.obs.uid, lamp.uid, 'rejected_geometry',
                                      fix.chainage_m, fix.var_m2))
        report.events.append(Event(Level.WARN, 'fix_geometry',
                                   f'lamp {lamp.uid:#06x}: range and direction disagree '
                                   f'(chi2 {fix.chi2_geometry:.1f}): fix rejected'))

    def _associate(self, state, prep):
        """The map lamp an unconfirmed observation must be, or None (with why)."""
        cfg = self.config
        icfg = cfg.integrity
        if state.P[0, 0] + self.monitor.suspicion_var_m2() > icfg.association_max_sigma_m ** 2:
            return None, None, float('nan'), 'state too uncertain to predict the lamp'
        g = cfg.geometry
        lamp_from_base = prep.R @ (g.R_base_cam @ prep.p_cam + g.t_base_cam)
        track = cfg.fix.track
        expected = track.chainage_of(track.position(float(state.x[0])) + lamp_from_base)
        # Wide enough that a second lamp inside the gate would be seen (and refused).
        window = icfg.association_window_m + math.sqrt(icfg.gate_chi2 * state.P[0, 0])
        candidates, fixes = [], {}
        for lamp in self.lamp_map.near_chainage(expected, window, window):
            fix, geometry_ok = self._fix_for(prep, lamp)
            y, S = innovation(state, fix.chainage_m, fix.var_m2)
            d2 = mahalanobis2(y, S) if geometry_ok else math.inf
            candidates.append((lamp, d2))
            fixes[lamp.uid] = (fix, d2)
        lamp, why = select_association(candidates, icfg.gate_chi2)
        if lamp is None:
            return None, None, float('nan'), why
        fix, d2 = fixes[lamp.uid]
        return lamp, fix, d2, why

    # ------------------------------------------------------------ disparity map
    def _disparity_corrected(self, obs):
        """(observation, disparity 1σ px or None): ``obs`` with the learnt disparity error
        of its image cell taken off the right centre, and that cell's 1σ (never above the
        calibration's), or ``obs`` unchanged where the map does not know the cell.
        """
        g = self.config.geometry
        if not self._disparity_checked:       # camera_info has come by the first observation
            self._disparity_checked = True
            self.disparity_map.check_calibration(g.fx * g.baseline_m)
        corr = self.disparity_map.correction(obs.uv_left[0],
                                             0.5 * (obs.uv_left[1] + obs.uv_right[1]))
        if corr is None:
            return obs, None
        delta, sigma = corr
        corrected = dataclasses.replace(obs, uv_right=obs.uv_right + np.array([delta, 0.0]))
        return corrected, min(sigma, float(g.calibration_sigma_px[1]))

    def _learn_disparity(self, prep, lamp, state):
        """One accepted confirmed lamp's disparity residual against the filter's chainage
        before its fix (:meth:`DisparityMap.residual`: the range only, no direction).
        """
        cfg, raw = self.config, prep.raw_obs
        base, tangent, _ = cfg.fix.track.frame(float(state.x[0]))
        cam = base + prep.R @ cfg.geometry.t_base_cam
        lamp_position = np.asarray(lamp.position_m, float)
        along = float((lamp_position - cam) @ tangent)
        sigma_s = math.sqrt(max(float(state.P[0, 0]), 0.0) + self._systematic_var)
        v = 0.5 * (raw.uv_left[1] + raw.uv_right[1])
        res = self.disparity_map.residual(raw.uv_left, v, raw.disparity_px, lamp_position,
                                          cam, along, sigma_s, cfg.geometry)
        if res is not None:
            self.disparity_map.add(raw.uv_left[0], v, res[0], res[1], lamp.uid)

    # ------------------------------------------------------------ self-survey
    def _start_survey(self):
        """At the first observation (camera_info has arrived by then): the calibration
        priors are the σ the fix states; δ and ε are estimated only for raw images
        (an ideal rectified pair has none to estimate).
        """
        if self._survey_started:
            return
        self._survey_started = True
        g, s = self.config.geometry, self.survey
        s.config.calibrate = bool(s.config.calibrate and g.raw_images)
        if not s.config.calibrate:
            s.applied = False
        sig = np.array([max(float(g.calibration_sigma_px[1]), 1e-3),
                        max(self.config.fix.stereo_scale_sigma, 1e-5)])
        if not s.applied:
            s.theta_prior_sigma = sig
            s.theta_sigma = sig.copy()
        self._survey_prior_sigmas = (float(g.calibration_sigma_px[1]),
                                     self.config.fix.stereo_scale_sigma)

    def _survey_fix(self, prep, lamp, fix, state):
        """Hand one confirmed lamp's *range* to the self-survey, solve when due, and state
        the learnt calibration's σ in the fix from then on.

        The chainage the stereo range alone gives (the lamp's lateral and vertical offset
        from the camera taken from the map and the track, mm; no direction, so no mount
        angle), ``s = s_fix + Δ·t − √(r² − lat² − vert²)``, its slope ``∂s/∂λ =
        −r²/(λ·along)`` and variance ``σ_r²·(r/along)²``, moved to the frame's instant by
        the filter's speed. Lamps less than ``min_along_m`` ahead are left out (there the
        range says little about the chainage).
        """
        cfg, survey = self.config, self.survey
        base, tangent, normal = cfg.fix.track.frame(fix.chainage_m)
        cam = base + prep.R @ cfg.geometry.t_base_cam
        delta = np.asarray(lamp.position_m, float) - cam
        lat, vert = float(delta @ normal), float(delta[2])
        r2 = float(prep.p_cam @ prep.p_cam)
        along2 = r2 - lat * lat - vert * vert
        if not along2 > survey.config.min_along_m ** 2:
            return
        along = math.sqrt(along2)
        lam = survey.range_factor(prep.obs.disparity_px)
        u = prep.p_cam / math.sqrt(r2)
        var_r = float(u @ prep.cov_cam @ u)
        chainage = fix.chainage_m + float(delta @ tangent) - along
        if survey.config.eliminate_frames:
            frame_ns = int(prep.obs.stamp_ns)
            chainage -= state.speed_mps * (prep.t_ns - frame_ns) / NS_PER_S
            var_ref = 0.0
        else:
            # against the filter's chainage at the instant, before this fix
            self._survey_seq += 1
            frame_ns = self._survey_seq
            chainage -= state.chainage_m
            var_ref = float(state.P[0, 0])
        survey.add(frame_ns, lamp.uid, prep.obs.disparity_px, chainage,
                   var_r * r2 / along2 + var_ref, -r2 / (lam * along),
                   float(lamp_sigma(lamp, cfg.fix)[0]))
        if survey.maybe_solve(prep.t_ns) and survey.converged:
            sd, ss = survey.published_sigmas()
            g = cfg.geometry
            g.calibration_sigma_px = (g.calibration_sigma_px[0],
                                      min(sd, self._survey_prior_sigmas[0]))
            cfg.fix.stereo_scale_sigma = min(ss, self._survey_prior_sigmas[1])

    def _apply_fix(self, t_m, fix):
        self._blend_systematic(t_m, fix)
        i = self._insert_step(t_m)
        self._steps.add_update(i, ('z', H_CHAINAGE, fix.chainage_m, self._update_var(fix)))
        self._has_fix = True
        self._gate.fix_pending = self.config.publish_on_fix

    def _update_var(self, fix):
        """Variance a fix is given in the filter update, m²: its random part plus its
        systematic part times ``systematic_weight_inflation``. Consecutive fixes share
        the systematic error (one lamp's survey, one calibration), so N frames carry its
        information once, not N times; weighting it as larger keeps a bias that changes
        with the range (stereo scale, mount angles) from being read as speed.
        """
        return fix.var_random_m2 + self.config.systematic_weight_inflation * fix.var_systematic_m2

    def _blend_systematic(self, t_m, fix):
        """The systematic variance the state carries after a fix at ``t_m``.

        A fix moves the chainage by its gain k = P/(P + r): the state's systematic error
        becomes (1 − k)·(its own) + k·(the fix's). The errors of successive fixes are
        correlated (one calibration, one lamp seen in many frames), so their 1σ add
        linearly, the bound for any correlation: a blend of far lamps (stereo scale
        × range) stays that large after a near lamp, and no number of frames of one lamp
        brings it below that lamp's survey error.
        """
        state = self._steps.state_at(t_m) if self._steps.t else None
        if state is None:
            self._systematic_var = fix.var_systematic_m2
            return
        p = float(state.P[0, 0])
        r = self._update_var(fix)
        k = p / (p + r) if p + r > 0.0 else 1.0
        sigma = ((1.0 - k) * math.sqrt(self._systematic_var)
                 + k * math.sqrt(max(fix.var_systematic_m2, 0.0)))
        self._systematic_var = sigma * sigma

    def _try_initialise(self, prep, lamp, report):
        """Cold start: wait for a confirmed lamp, then start from its recent track."""
        cfg = self.config
        t_m, obs = prep.t_ns, prep.obs
        self._cold.forget_before(t_m)
        if lamp is None:
            self._cold.waiting.append(prep)
            self.monitor.counters.unconfirmed_skipped += 1
            report.fixes.append(FixRecord(t_m, None, None, 'waiting_for_uid'))
            return
        fix_for = self._fix_for
        if not cfg.fix.track.straight_x:
            def fix_for(p, lamp_k):
                return self._fix_for(self._cold_start_attitude(p, lamp_k, report), lamp_k)
        fix, geometry_ok = fix_for(prep, lamp)
        if not geometry_ok:
            self._geometry_rejected(prep, lamp, fix, report)
            return
        chain = self._cold.chain(prep, lamp, fix, fix_for, self.lamp_map)
        self._cold.clear()
        t0, fix0 = chain[0]
        i = self._insert_step(t0)
        self._steps.add_update(i, ('set', initial_state(fix0.chainage_m, fix0.var_m2,
                                                        cfg.kalman)))
        self._initialized = True
        self._has_fix = True
        # Published from the confirming frame on: the filtered states inside the lookback
        # span saw only part of the lamp's track.
        self._gate.start_ns = t_m
        self._systematic_var = fix0.var_systematic_m2
        self._gate.fix_pending = True
        for t_k, fix_k in chain[1:]:
            state = self._steps.state_at(t_k)
            y, S = innovation(state, fix_k.chainage_m, fix_k.var_m2)
            if mahalanobis2(y, S) <= cfg.integrity.gate_chi2:
                self._apply_fix(t_k, fix_k)
        self.monitor.on_accepted(t_m, True)
        report.fixes.append(FixRecord(t_m, obs.uid, lamp.uid, 'initialised', fix.chainage_m,
                                      fix.var_m2, detail=f'{len(chain) - 1} earlier frames'))
        report.events.append(Event(Level.OK, 'initialised',
                                   f'initialised at chainage {fix.chainage_m:.3f} m from lamp '
                                   f'{lamp.uid:#06x} and {len(chain) - 1} earlier frames of it'))

    def _cold_start_attitude(self, prep, lamp, report):
        """``prep`` with the attitude of a cold start on a curved alignment.

        Before the first fix the chainage is unknown, and the track's attitude taken at
        the alignment's start, or an ``imu/data`` heading judged against it, can be tens
        of degrees off on a curve (22° at 395 m of ``curved_demo``: every fix of the lamp
        ahead was rejected, range and direction disagreeing, and the localizer never
        started). A confirmed lamp tells where the train is: the track frame is taken
        at the chainage its observation puts the platform at (the lamp's chainage less
        the observed offset along the track, twice, so that the heading is that of the
        platform's own chainage), and an ``imu/data`` heading more than
        ``attitude_plausible_rad`` from it is not used (the track's, with
        ``attitude_sigma_unknown_rad``).
        """
        cfg, g = self.config, self.config.geometry
        track = cfg.fix.track
        chainage = float(lamp.track_chainage_m)
        for _ in range(2):
            lamp_from_base = track.attitude(chainage) @ (g.R_base_cam @ prep.p_cam
                                                         + g.t_base_cam)
            chainage = float(track.chainage_of(lamp.position_m - lamp_from_base))
        if cfg.use_imu_attitude and self._att.at(prep.t_ns * 1e-9) is not None:
            heading = self._heading_off_track(prep.R, chainage)
            if abs(heading) <= cfg.attitude_plausible_rad:
                return prep
            report.events.append(Event(Level.WARN, 'attitude_implausible',
                                       f'imu/data heading {math.degrees(heading):+.1f} deg off '
                                       f'the track at the chainage lamp {lamp.uid:#06x} shows '
                                       f'({chainage:.1f} m): the first fix uses the track\'s'))
        return dataclasses.replace(prep, R=track.attitude(chainage), cov_att=np.diag(
            np.square(cfg.attitude_sigma_unknown_rad)))

    def _set_chainage(self, i, chainage_m, var_m2, keep_speed):
        """Restart the chainage at step ``i`` (see
        :func:`~train_localizer.core.initialisation.restarted_chainage`); returns the state
        it replaced.
        """
        old = self._steps.x[i]
        cfg = self.config
        self._steps.add_update(i, ('set', restarted_chainage(
            old, chainage_m, var_m2, keep_speed, cfg.integrity.reinit_speed_sigma_mps,
            cfg.kalman.initial_bias_sigma_mps2)))
        return old

    def _reinitialise(self, t_m, fix, decision, report):
        """Restart the chainage at ``fix``; after a long contradiction also the speed."""
        icfg = self.config.integrity
        i = self._insert_step(t_m)
        old = self._set_chainage(i, fix.chainage_m, fix.var_m2, keep_speed=decision == 'offset')
        self._systematic_var = fix.var_systematic_m2
        self._gate.fix_pending = True
        self.monitor.on_reinitialised()
        self.monitor.on_accepted(t_m, True)
        why = ('two confirmed lamps contradict the state by the same offset'
               if decision == 'offset' else
               f'confirmed lamps contradicted the state for {icfg.reinit_after_s:.1f} s')
        report.events.append(Event(Level.ERROR, 'reinitialised',
                                   f'{why}: re-initialised by {fix.chainage_m - old.x[0]:+.2f} m'))

    def _raw_fix(self, prep, lamp, report):
        """use_kalman off: every confirmed, geometry-consistent fix is a pose."""
        t_m, obs = prep.t_ns, prep.obs
        if lamp is None:
            self.monitor.counters.unconfirmed_skipped += 1
            report.fixes.append(FixRecord(t_m, None, None, 'unconfirmed_skipped',
                                          detail='no filter state to predict the lamp'))
            return
        fix, geometry_ok = self._fix_for(prep, lamp)
        if not geometry_ok:
            self._geometry_rejected(prep, lamp, fix, report)
            return
        self._initialized = True
        self._has_fix = True
        self.monitor.on_accepted(t_m, True)
        report.fixes.append(FixRecord(t_m, obs.uid, lamp.uid, 'accepted', fix.chainage_m,
                                      fix.var_m2))
        gate = self._gate
        if gate.last_pub_ns is not None and t_m <= gate.last_pub_ns:
            return
        cov = self._position_cov(fix.chainage_m, fix.var_m2)
        q, att_cov = self._orientation(t_m)
        report.poses.append(PoseEstimate(t_m, fix.position_m.copy(), cov, float('nan'),
                                         float('nan'), q, att_cov, self._steps.gyro_at(t_m),
                                         'raw', fix.chainage_m, fix.var_m2))
        gate.last_pub_ns = t_m

    # ----------------------------------------------------------------- output
    @property
    def cross_track_motion_m(self):
        """(lateral, vertical) RMS motion of the car body about the track that the IMU
        shows (:class:`~train_localizer.core.cross_track.CrossTrackMotion`), m.
        """
        return self._motion.sigma_m()

    def _position_cov(self, chainage_m, chainage_var):
        """Map covariance (3, 3): along the track, across it and vertical."""
        k = self.config.motion_sigma_factor
        sy, sz = (max(float(a), float(b), k * m)
                  for a, b, m in zip(self.config.fix.track_sigma_yz_m,
                                     self.config.pose_sigma_yz_m, self._motion.sigma_m()))
        return self.config.fix.track.covariance(chainage_m, chainage_var, sy * sy, sz * sz)

    def _orientation(self, t):
        q = self._att.at(t * 1e-9)
        if q is None:
            return (np.array([0.0, 0.0, 0.0, 1.0]),
                    np.diag(np.square(self.config.attitude_sigma_unknown_rad)))
        cov = self._att.covariance_at(t * 1e-9)
        if cov is None or not np.all(np.isfinite(cov)):
            cov = np.diag(np.square(self.config.attitude_sigma_floor_rad))
        return q, cov

    def _published_var(self, t):
        """Published chainage variance at ``t``: the filter's plus :meth:`_extra_var`."""
        state = self._steps.state_at(t)
        return state.P[0, 0] + self._extra_var()

    def _pose(self, t, kind):
        state = self._steps.state_at(t)
        s = float(state.x[0])
        var = float(state.P[0, 0] + self._extra_var())
        q, att_cov = self._orientation(t)
        return PoseEstimate(t, self.config.fix.track.position(s), self._position_cov(s, var),
                            float(state.x[1]), float(state.P[1, 1]), q, att_cov,
                            self._steps.gyro_at(t), kind, s, var)

    def _emit(self, report):
        """The grid poses up to the newest step, then the post-fix pose if one is due."""
        if not self._steps.t or not self.config.use_kalman:
            return
        for t, kind in self._gate.due(self._steps.t[-1], self._initialized,
                                      self._published_var):
            report.poses.append(self._pose(t, kind))

    def _time_reset(self, report, stream):
        """A new time base confirmed by ``stream``: everything but the counters is reset;
        a state that was initialised is lost until a confirmed lamp initialises it again.
        """
        self.monitor.counters.time_resets += 1
        was = self._initialized
        reason = self._time.last_reason
        self._reset_state()
        if was:
            self._lost_reason = f'time base changed ({reason})'
        report.events.append(Event(Level.ERROR, 'time_reset',
                                   f'the sensor clock restarted ({reason}, confirmed by the '
                                   f'{stream} stream): localizer reset'
                                   + ('; position lost until a confirmed lamp' if was else '')))
