"""``train_localizer_node``: train position from lamp fixes fused with the IMU.

Subscribes (relative names):

* ``spots/pairs`` (sensor_msgs/PointCloud2; reliable, depth 100): sub-pixel spot pairs
  from spot_locator, one point per lamp, header = image header;
* ``vlc/lamps`` (sensor_msgs/PointCloud2; reliable, depth 100): lamp UIDs from
  vlc_decoder, same stamps; joined with the spot pairs by stamp
  (:mod:`train_localizer.core.join`);
* ``imu/data`` (sensor_msgs/Imu; best effort, depth 1000): compensated attitude,
  rate and specific force from imu_compensator;
* ``stereo/left/camera_info``, ``stereo/right/camera_info`` (sensor_msgs/CameraInfo;
  reliable, transient local, depth 1): rectified intrinsics and baseline;
* ``curvature_aid_topic`` (geometry_msgs/PoseWithCovarianceStamped; reliable, depth 10;
  default ``companion/curvature/pose_with_covariance``, curvature_node's match with its
  chainage variance) while ``use_curvature_aid``: the re-acquisition aid after a long
  lamp outage (:mod:`train_localizer.core.reacquisition`).

Publishes, all stamped with the instant they describe (reliable, depth 10):

* ``train/pose`` (geometry_msgs/PoseStamped): ``base_link`` in ``map``, at
  ``publish_rate_hz`` on the sensor-time grid and right after every fix;
* ``train/pose_with_covariance`` (geometry_msgs/PoseWithCovarianceStamped);
* ``train/odometry`` (nav_msgs/Odometry, twist in ``base_link`` with the speed);
* ``diagnostics`` (diagnostic_msgs/DiagnosticArray) every ``diagnostics_period_s``
  (steady clock): integrity state, counters, processing time per fix.

Everything but message conversion lives in :class:`~train_localizer.core.localizer.Localizer`;
bad input is logged (throttled per kind) and skipped: a cloud that is not what it says or
not its topic's documented layout (:func:`train_localizer.conversions.records_from_cloud`),
an invalid camera_info (the last good one is kept, a different valid one taken only once
it came three times in a row). Each input stream (``imu/data``, ``spots/pairs``,
``vlc/lamps``) passes a :class:`vlc_common.core.stamp_guard.StampGuard` before the core
sees it: a message stamped more than ``backward_reset_s`` before or ``forward_jump_s``
after the newest one of its topic is held, and alone (a 1970 or far-future stamp) it is
dropped and counted; only ``time_base_confirm_count`` consecutive messages of a new time
base (a looped bag, a restarted sensor) reach the core, whose own rule then resets it as
before (and the frame join is cleared). Parameters: ``config/train_localizer_node.yaml``.
"""
from collections import deque
import math
import sys
import time

from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import PoseStamped, PoseWithCovarianceStamped
from nav_msgs.msg import Odometry
import numpy as np
from rclpy.clock import Clock, ClockType
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import CameraInfo, Imu, PointCloud2

from train_localizer import conversions
from train_localizer import node_parameters as params
from train_localizer.core.disparity_map import DisparityMapConfig
from train_localizer.core.disparity_map_file import (
    DisparityMapFileError,
    load_disparity_map,
    save_disparity_map,
)
from train_localizer.core.fix import FixConfig
from train_localizer.core.imu_pacing import ImuPacer
from train_localizer.core.integrity import IntegrityConfig, Level
from train_localizer.core.join import FrameJoiner
from train_localizer.core.lamp_refinement import RefinementConfig
from train_localizer.core.lamp_refinement_file import read_kept, save_refinement
from train_localizer.core.localizer import Localizer, LocalizerConfig
from train_localizer.core.reacquisition import (
    APPLIED,
    BAD_INPUT,
    IGNORED,
    REJECTED_GATE,
    RESET,
    ChainageAid,
    ReacquisitionConfig,
    chainage_measurement,
)
from train_localizer.core.self_calibration_file import (
    SavedCalibration,
    SelfCalibrationFileError,
    load_saved_calibration,
    save_calibration,
)
from train_localizer.core.self_survey import SelfSurveyConfig
from train_localizer.core.track import Track
from train_localizer.joined_frames import JoinedFramesNode
from vlc_common.core.lamp_map import LampMap, resolve_lamp_map_path
from vlc_common.core.stamp_guard import StampGuard
from vlc_common.parameters import descriptor as _desc
from vlc_common.polled import IMU_QOS, RECORDS_QOS, PolledSubscription
from vlc_common.process import run_node
from vlc_common.throttled_log import ThrottledWarnings

_DEG = math.pi / 180.0
SPOT_FIELDS = ('u_left', 'v_left', 'u_right', 'v_right')
LAMP_FIELDS = ('uid',)



# name, default, descriptor — documented key by key in config/train_localizer_node.yaml
PARAMETERS = (
    ('map_frame_id', 'map', _desc('Frame of the published poses.')),
    ('base_frame_id', 'base_link', _desc('Child frame of the odometry (the train head).')),
    ('lamp_map_path', '', _desc("Lamp map YAML; '' = vlc_common's default map.")),
    ('alignment', '', _desc("Track alignment (vlc_common.core.alignment names: "
                            "straight, curved_demo, ...); '' = the one the lamp map names.")),
    ('publish_rate_hz', 50.0, _desc('Pose grid in sensor time, Hz.', 1.0, 1000.0)),
    ('publish_on_fix', True, _desc('Also publish right after each fix (lower latency).')),
    ('pose_sigma_y_m', 0.01, _desc('1-sigma of the published pose across the track, m (at '
                                   'least track_sigma_y_m).', 1e-6, 1.0)),
    ('pose_sigma_z_m', 0.01, _desc('1-sigma of the published pose vertically, m (at least '
                                   'track_sigma_z_m).', 1e-6, 1.0)),
    ('motion_sigma_factor', 3.0, _desc('The published lateral and vertical 1-sigma is at '
                                       'least this factor times the car body motion about '
                                       'the track that imu/data shows; 0 = pose_sigma_* '
                                       'only.', 0.0, 100.0)),
    ('motion_highpass_hz', 0.4, _desc('Corner of that motion estimate (slower motion is '
                                      'not seen), Hz.', 0.01, 10.0)),
    ('motion_window_s', 2.0, _desc('Time constant of its running variance, s.', 0.05, 60.0)),
    ('diagnostics_period_s', 1.0, _desc('Diagnostics period (steady clock), s.', 0.1, 60.0)),
    ('imu_poll_period_s', 0.01, _desc('imu/data and camera_info are taken in batches this '
                                      'often (steady clock) and before every frame, off '
                                      'the executor; 0 = a callback per IMU message, s.',
                                      0.0, 0.1)),
    ('warn_throttle_s', 2.0, _desc('Minimum interval between two warnings of one kind, s.',
                                   0.0, 600.0)),
    ('use_range_constraint', True, _desc('Constrained GLS fix (track + stereo range); false = '
                                         'paper eq. 13-14 fix.')),
    ('use_imu_attitude', True, _desc('Use imu/data attitude; false = identity.')),
    ('use_exposure_stamping', True, _desc('Stamp fixes at the spot exposure mid-time; false = '
                                          'image stamp.')),
    ('use_kalman', True, _desc('Kalman fusion with the IMU; false = raw single-frame fixes.')),
    ('lamp_position_sigma_m', 0.005, _desc('1-sigma survey error per lamp coordinate, m.',
                                           0.0, 1.0)),
    ('stereo_scale_sigma', 0.001, _desc('Relative 1-sigma of the calibrated stereo scale '
                                        'fx*baseline (systematic: every range scales).',
                                        0.0, 0.1)),
    ('focal_length_sigma', 0.001, _desc('Relative 1-sigma of the calibrated focal length at a '
                                        'fixed fx*baseline (systematic).', 0.0, 0.1)),
    ('principal_point_sigma_px', 0.5, _desc('1-sigma of the calibrated principal point cx, cy, '
                                            'px (systematic).', 0.0, 100.0)),
    ('mount_angle_sigma_deg', [0.05, 0.1, 0.1],
     _desc('1-sigma of the calibrated camera mount angles about base_link x, y, z (roll, '
           'pitch, yaw), deg (systematic).')),
    ('systematic_weight_inflation', 3.0, _desc('Factor on each fix\'s systematic variance '
                                               'in the filter update (shared by consecutive '
                                               'fixes); 1 = white.', 1.0, 1000.0)),
    ('min_disparity_px', 4.0, _desc('Smallest usable disparity, px.', 0.0, 1000.0)),
    ('calibration_sigma_px', 0.5, _desc('Raw images (camera_info with D or R): 1-sigma '
                                        'systematic error of the calibration in the '
                                        'rectified centres, px.', 0.0, 100.0)),
    ('calibration_disparity_sigma_px', 0.8, _desc('Raw images: 1-sigma systematic error of '
                                                  'the calibration in the disparity, px.',
                                                  0.0, 100.0)),
    ('use_self_calibration', False, _desc('Raw images: learn the stereo range calibration '
                                         '(disparity offset, fx*b scale) from the lamps '
                                         'and apply it (core/self_survey.py).')),
    ('self_calibration_path', '', _desc("File the learnt calibration is kept in: read at "
                                        "start (this vehicle's only), written at stop and "
                                        "every self_calibration_save_s; '' = none.")),
    ('self_calibration_save_s', 10.0, _desc('Steady-clock period of writing the learnt '
                                            'calibration, s.', 1.0, 3600.0)),
    ('use_disparity_map', True, _desc('Raw images: learn the rectified pair\'s disparity '
                                      'error cell by cell of the image from the confirmed '
                                      'lamps\' ranges against the filter, and correct and '
                                      'weight the fixes with it where it is known '
                                      '(core/disparity_map.py).')),
    ('disparity_map_path', '', _desc("File the learnt disparity map is kept in: read at start "
                                     "(this vehicle's and calibration's only) and added to, "
                                     "written at stop and every disparity_map_save_s; '' = "
                                     "learnt afresh every run.")),
    ('disparity_map_save_s', 10.0, _desc('Steady-clock period of writing the disparity map, s.',
                                         1.0, 3600.0)),
    ('disparity_map_extrapolate_cells', 6, _desc('A cell of the image no lamp taught the '
                                                 'map borrows the nearest learnt cell this '
                                                 'many cells away, with a wider sigma; 0 = '
                                                 'off.', 0, 16, integer=True)),
    ('disparity_map_max_state_sigma_m', 0.10, _desc('The filter is a reference for the '
                                                    'disparity map only while its stated '
                                                    'chainage sigma is below this, m.',
                                                    0.001, 1.0)),
    ('lamp_refinement_path', '', _desc("Lamp-map refinement file of the line (surveying by "
                                       "train, core/lamp_refinement.py): read at start and "
                                       "applied to the surveyed map, this run's lamp "
                                       "triplets added and written at stop and every "
                                       "lamp_refinement_save_s; '' = off.")),
    ('lamp_refinement_save_s', 10.0, _desc('Steady-clock period of writing the lamp-map '
                                           'refinement, s.', 1.0, 3600.0)),
    ('attitude_weight_inflation', 4.0, _desc('Factor on the attitude covariance in the fix '
                                             'weights (correlated error).', 1.0, 1000.0)),
    ('attitude_sigma_floor_deg', [0.05, 0.05, 0.1],
     _desc('Smallest attitude 1-sigma about map x, y, z assumed for imu/data, deg.')),
    ('attitude_sigma_unknown_deg', [0.5, 0.5, 5.0],
     _desc('Attitude 1-sigma without an attitude (use_imu_attitude false), deg.')),
    ('unknown_accel_sigma_mps2', 1.5, _desc('1-sigma acceleration over an IMU gap, m/s^2.',
                                            0.0, 20.0)),
    ('attitude_aiding_calibration_inflation', 5.0, _desc(
        'Raw images: factor on the calibration covariance in the attitude an aid reports '
        '(the same error in every aid; the compensator fuses them as independent).',
        1.0, 1e6)),
    ('attitude_aiding_period_s', 0.2, _desc('Shortest interval between two attitude_aiding '
                                            'messages (the attitude an accepted lamp shows), '
                                            's; 0 = none.', 0.0, 60.0)),
    ('tilt_leak_time_s', 5.0, _desc('Time over which the gravity leak of the pitch error may '
                                    'wander (extra bias random walk), s; 0 = off.', 0.0, 1000.0)),
    ('gate_chi2', 16.0, _desc('Mahalanobis gate of a fix (chi2, 1 dof).', 1.0, 1e4)),
    ('geometry_gate_chi2', 18.4, _desc('Range/direction residual gate (chi2, 2 dof).',
                                       1.0, 1e6)),
    ('association_max_sigma_m', 1.5, _desc('Unconfirmed lamps used only below this chainage '
                                           '1-sigma, m.', 0.0, 100.0)),
    ('association_window_m', 4.0, _desc('Association candidate window, m.', 0.0, 100.0)),
    ('reinit_agreement_chi2', 16.0, _desc('Two contradicting lamps agree below this chi2.',
                                          1.0, 1e4)),
    ('reinit_after_s', 2.0, _desc('Two lamps contradicting this long re-initialise, s.',
                                  0.0, 600.0)),
    ('reinit_speed_sigma_mps', 2.0, _desc('Speed 1-sigma after such a re-initialisation, m/s.',
                                          0.0, 100.0)),
    ('contradiction_memory_s', 60.0, _desc('Memory of contradicting lamps, s.', 0.0, 3600.0)),
    ('coast_warn_s', 1.0, _desc('Warn after this long without an accepted fix, s.',
                                0.0, 3600.0)),
    ('max_sigma_m', 0.5, _desc('Error above this published chainage 1-sigma, m.', 0.0, 1e4)),
    ('report_hold_s', 5.0, _desc('A rejection stays in the diagnostics for this long, s.',
                                 0.0, 3600.0)),
    ('history_s', 1.0, _desc('How far back a fix may be applied, s.', 0.05, 60.0)),
    ('imu_timeout_s', 0.2, _desc('Fixes stop waiting for an IMU lagging the frames by more '
                                 'than this, s.', 0.001, 60.0)),
    ('imu_max_gap_s', 0.05, _desc('Longer IMU intervals are gaps (unknown acceleration), s.',
                                  1e-4, 60.0)),
    ('backward_reset_s', 1.0, _desc('A frame this much older than the newest frame is a '
                                    'sensor clock that went back, not a late frame, s.',
                                    1e-3, 1e6)),
    ('imu_backward_s', 0.05, _desc('An IMU sample this much older than the newest is a '
                                   'sensor clock that went back, s.', 1e-4, 1e6)),
    ('attitude_plausible_deg', 10.0, _desc('An imu/data attitude more than this off the '
                                           "track's heading or the vertical is not the "
                                           "platform's: ignored, deg.", 0.1, 180.0)),
    ('attitude_distrust_s', 2.0, _desc('After confirmed lamps showed the imu/data attitude '
                                       'wrong, it is ignored for this long, s.', 0.01, 600.0)),
    ('attitude_evidence_s', 0.5, _desc('It takes two lamps (frames) this close in time '
                                       'to show the imu/data attitude wrong; the first '
                                       "one's fix is rejected. 0: one lamp, s.", 0.0, 60.0)),
    ('blind_gap_s', 3.0, _desc('No input for longer than this: the position is lost (reset) '
                               'until a confirmed lamp, s.', 0.01, 1e6)),
    ('clock_tolerance_s', 0.1, _desc('A gap of both inputs counts as elapsed time when the '
                                     "node's clock advanced by the gap within this; "
                                     'otherwise the chainage is widened by the distance run, '
                                     's.', 1e-3, 60.0)),
    ('forward_jump_s', 1.0, _desc('A stamp more than this after the newest one of its topic '
                                  'is held as a possible outlier, s.', 0.0, 3600.0)),
    ('time_base_confirm_count', 3, _desc('Consecutive messages of a topic with a new time base '
                                         'that confirm it; fewer are outliers, dropped.',
                                         1, 1000, integer=True)),
    ('max_speed_mps', 40.0, _desc('Highest possible train speed (cold start), m/s.',
                                  0.1, 200.0)),
    ('init_lookback_s', 0.5, _desc('Unconfirmed observations kept for the cold start, s.',
                                   0.01, 10.0)),
    ('use_initial_prior', False, _desc('Start from initial_chainage_m (publish at once).')),
    ('initial_chainage_m', 0.0, _desc('Prior chainage of base_link, m.', -1e7, 1e7)),
    ('initial_chainage_sigma_m', 1.0, _desc('1-sigma of the prior chainage, m.', 1e-6, 1e6)),
    ('initial_speed_known', False, _desc('The prior includes the speed initial_speed_mps.')),
    ('initial_speed_mps', 0.0, _desc('Prior speed, m/s.', -200.0, 200.0)),
    ('use_curvature_aid', True, _desc('Use curvature matches to re-acquire after a long lamp '
                                      'outage.')),
    ('curvature_aid_topic', 'companion/curvature/pose_with_covariance',
     _desc('PoseWithCovarianceStamped topic of the curvature matches.')),
    ('curvature_aid_min_state_sigma_m', 5.0, _desc('Aid only while the chainage 1-sigma '
                                                   'exceeds this, m.', 0.0, 1e4)),
    ('curvature_aid_max_match_sigma_m', 10.0, _desc('Matches with a larger 1-sigma are '
                                                    'refused, m.', 0.01, 1e4)),
    ('curvature_aid_min_match_sigma_m', 0.5, _desc('Floor on the 1-sigma of a match, m.',
                                                   0.01, 1e4)),
    ('curvature_aid_gate_chi2', 16.0, _desc('Mahalanobis gate of a match (chi2, 1 dof).',
                                            1.0, 1e4)),
    ('curvature_aid_consistency_chi2', 16.0, _desc('Two consecutive matches agree below this '
                                                   'chi2.', 1.0, 1e4)),
    ('curvature_aid_max_gap_s', 3.0, _desc('A longer gap between matches breaks their chain, '
                                           's.', 0.01, 3600.0)),
    ('curvature_aid_reset_min_matches', 5, _desc('Consistent gate-failing matches that reset '
                                                 'the chainage; 0 = never.', 0, 1000)),
    ('curvature_aid_reset_min_travel_m', 200.0, _desc('Running distance such a run must span, '
                                                      'm.', 0.0, 1e5)),
) + (params.STEREO_PARAMETERS + params.TRACK_PARAMETERS + params.KALMAN_PARAMETERS
     + params.STANDSTILL_PARAMETERS + params.JOIN_PARAMETERS)


class TrainLocalizerNode(JoinedFramesNode, Node):
    """ROS wrapper of :class:`Localizer`; see the module docstring."""

    def __init__(self, **kwargs):
        super().__init__('train_localizer', **kwargs)
        for name, default, descriptor in PARAMETERS:
            self.declare_parameter(name, default, descriptor)
        p = {name: self.get_parameter(name).value for name, _, _ in PARAMETERS}
        self.params = p
        # Subscribed before the rest is built: a respawned localizer's subscriptions are
        # discovered while it loads its map (messages wait in their queues until it spins).
        # The 400 Hz IMU (and the per-frame camera_info, of which only the latest matters)
        # bypass the executor: taken in batches by _drain() (vlc_common.polled).
        poll_s = p['imu_poll_period_s']
        latched = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                             durability=DurabilityPolicy.TRANSIENT_LOCAL)
        self._imu_polled = (PolledSubscription(self, Imu, 'imu/data', IMU_QOS)
                            if poll_s > 0.0 else None)
        if self._imu_polled is None:
            self.create_subscription(Imu, 'imu/data', self._on_imu, IMU_QOS)
        self.create_subscription(PointCloud2, 'spots/pairs', self._on_spots, RECORDS_QOS)
        self.create_subscription(PointCloud2, 'vlc/lamps', self._on_lamps, RECORDS_QOS)
        if p['use_curvature_aid']:
            self.create_subscription(PoseWithCovarianceStamped, p['curvature_aid_topic'],
                                     self._on_curvature, 10)
        self._info_polled = [PolledSubscription(self, CameraInfo, f'stereo/{side}/camera_info',
                                                latched) for side in ('left', 'right')]
        self.lamp_map, self.localizer_config = self.setup(p)
        self._self_cal_state, saved = self._load_self_calibration(p)
        self._report_refinement()
        self._report_disparity_map()
        self._self_cal_runs = 1 + (saved.runs if saved is not None else 0)
        fix = self.localizer_config.fix
        self._calibration_text = (
            f'stereo scale {fix.stereo_scale_sigma:.2%}, focal {fix.focal_length_sigma:.2%}, '
            f'principal point {fix.principal_point_sigma_px:.2f} px, mount '
            + '/'.join(f'{math.degrees(v):.3f}' for v in fix.mount_angle_sigma_rad)
            + f' deg; survey {sum(lamp.has_position_sigma for lamp in self.lamp_map.lamps)}/'
            f'{len(self.lamp_map)} lamps with their own sigma, else '
            f'{fix.lamp_position_sigma_m * 1000:.1f} mm')
        path = resolve_lamp_map_path(p['lamp_map_path'], p['alignment'] or 'straight')
        self.localizer = Localizer(self.lamp_map, self.localizer_config)
        self.curvature_aid = ChainageAid(self.localizer, self.reacquisition_config(p))
        self.joiner = FrameJoiner(params.join_config(p))
        self._imu_pacer = ImuPacer()
        self._steady = Clock(clock_type=ClockType.STEADY_TIME)
        self._warnings = ThrottledWarnings(self.get_logger(), p['warn_throttle_s'],
                                           clock=self._now_s)
        self._fix_ms = deque(maxlen=500)
        self._latency_ms = deque(maxlen=500)
        self._intrinsics = conversions.CameraInfoIntrinsics(self.localizer_config.geometry,
                                                            p['use_camera_info'],
                                                            self.joiner.config)
        self._published = 0
        self._last_pose = None
        self._state = None
        self._state_since = (None, 0)     # (integrity state, node-clock ns it began at)
        self._stamp_guards = {topic: StampGuard.from_seconds(p['backward_reset_s'],
                                                       p['forward_jump_s'],
                                                       p['time_base_confirm_count'])
                        for topic in ('imu/data', 'spots/pairs', 'vlc/lamps')}
        self._clouds_refused = 0

        estimate_qos = 10
        self.pub_pose = self.create_publisher(PoseStamped, 'train/pose', estimate_qos)
        self.pub_pose_cov = self.create_publisher(PoseWithCovarianceStamped,
                                                  'train/pose_with_covariance', estimate_qos)
        self.pub_odom = self.create_publisher(Odometry, 'train/odometry', estimate_qos)
        self.pub_diag = self.create_publisher(DiagnosticArray, 'diagnostics', 10)
        self.pub_aid = self.create_publisher(PoseWithCovarianceStamped, 'attitude_aiding', 10)
        self.create_timer(poll_s if poll_s > 0.0 else 0.02, self._on_poll, clock=self._steady)
        self.create_timer(p['diagnostics_period_s'], self._publish_diagnostics,
                          clock=self._steady)
        if p['self_calibration_path'] and self.localizer.survey is not None:
            self.create_timer(p['self_calibration_save_s'], self.save_self_calibration,
                              clock=self._steady)
        if self.localizer.pass_recorder is not None:
            self.create_timer(p['lamp_refinement_save_s'], self.save_lamp_refinement,
                              clock=self._steady)
        if p['disparity_map_path'] and self.localizer.disparity_map is not None:
            self.create_timer(p['disparity_map_save_s'], self.save_disparity_map,
                              clock=self._steady)
        self.get_logger().info(
            f'lamp map {path} ({len(self.lamp_map)} lamps), track '
            f'{self.localizer_config.fix.track.name}; range constraint '
            f'{p["use_range_constraint"]}, IMU attitude {p["use_imu_attitude"]}, exposure '
            f'stamping {p["use_exposure_stamping"]}, Kalman {p["use_kalman"]}')

    # ------------------------------------------------------------------ config
    @classmethod
    def setup(cls, p):
        """(LampMap, LocalizerConfig) of a parameter dict; the track is the alignment
        named by ``alignment`` or by the lamp map file (ValueError if unknown).
        """
        config = cls._config(p)
        lamp_map = LampMap.load(resolve_lamp_map_path(p['lamp_map_path'],
                                                      p['alignment'] or 'straight'))
        config.fix.track = Track.for_lamp_map(lamp_map, p['alignment'],
                                              config.fix.track_offset_yz_m)
        if p.get('lamp_refinement_path'):
            track = config.fix.track

            def tangent_of(lamp):
                return track.frame(lamp.track_chainage_m)[1]

            config.refinement = RefinementConfig()
            lamp_map, config.refinement_kept = read_kept(
                p['lamp_refinement_path'], lamp_map, tangent_of,
                config.fix.lamp_position_sigma_m, config.refinement)
            config.refinement_applied = dict(config.refinement_kept.applied)
        config.disparity_map_state = cls._load_disparity_map(p, config)
        return lamp_map, config

    @staticmethod
    def _load_disparity_map(p, config):
        """Put the kept disparity map (``disparity_map_path``) into ``config``; returns the
        state text for diagnostics ('off', 'learning ...', 'from file ...', 'refused: ...').
        A refused file is left untouched and never written over.
        """
        if config.disparity_map is None:
            return 'off'
        path = p.get('disparity_map_path', '')
        if not path:
            return 'learning (not kept: no disparity_map_path)'
        vehicle_id = params.load_mount(p).vehicle_id
        try:
            kept = load_disparity_map(path, vehicle_id, config.disparity_map.cell_px)
        except DisparityMapFileError as exc:
            return f'refused: {exc}'
        if kept is None:
            return f'learning (first run of {vehicle_id})'
        config.disparity_map_kept, config.disparity_map_runs, config.disparity_map_kept_fx_b = kept
        return f'from file ({config.disparity_map_runs} run(s), {len(kept[0])} cells)'

    def _load_self_calibration(self, p):
        """The saved self-calibration as the self-survey's prior: (state text, saved or
        None). A refused file is logged and the node runs on the given calibration.
        """
        cfg = self.localizer_config
        if cfg.self_survey is None:
            return 'off', None
        path = p['self_calibration_path']
        if not path:
            return 'learning (not kept: no self_calibration_path)', None
        vehicle_id = params.load_mount(p).vehicle_id
        try:
            saved = load_saved_calibration(path, vehicle_id)
        except SelfCalibrationFileError as exc:
            self.get_logger().error(f'self-calibration file refused, running on the given '
                                    f'calibration: {exc}')
            return f'refused: {exc}', None
        if saved is None:
            return f'learning (first run of {vehicle_id})', None
        sc = cfg.self_survey
        sc.disparity_offset_px, sc.disparity_offset_sigma_px = (
            saved.disparity_offset_px, saved.disparity_offset_sigma_px)
        sc.stereo_scale_error, sc.stereo_scale_sigma = (saved.stereo_scale_error,
                                                        saved.stereo_scale_sigma)
        sc.from_file = True
        self.get_logger().info(
            f'self-calibration of {vehicle_id} from {path} ({saved.runs} run(s)): disparity '
            f'offset {saved.disparity_offset_px:+.3f} px (1-sigma '
            f'{saved.disparity_offset_sigma_px:.3f}), stereo scale '
            f'{saved.stereo_scale_error:+.2e} (1-sigma {saved.stereo_scale_sigma:.1e})')
        return f'from file ({saved.runs} run(s))', saved

    def save_self_calibration(self):
        """Write the learnt calibration (once it has converged) to
        ``self_calibration_path``; errors are logged, never raised.
        """
        survey = self.localizer.survey
        path = self.params['self_calibration_path']
        if not path or survey is None or not survey.applied or self._self_cal_state.startswith(
                'refused'):
            return
        sd, ss = survey.published_sigmas()
        g = self.localizer_config.geometry
        saved = SavedCalibration(
            vehicle_id=params.load_mount(self.params).vehicle_id,
            disparity_offset_px=float(survey.theta[0]), disparity_offset_sigma_px=sd,
            stereo_scale_error=float(survey.theta[1]), stereo_scale_sigma=ss,
            camera_fx_b_px_m=float(g.fx * g.baseline_m), runs=self._self_cal_runs)
        try:
            save_calibration(path, saved)
        except OSError as exc:
            self._warn('self_calibration_save', f'self-calibration not written to {path}: {exc}')

    def _report_refinement(self):
        kept = self.localizer_config.refinement_kept
        # moved lamps already logged (at start from the file, then as passes find them)
        self._flags_reported = ({f.uid for f in kept.base.flags}
                                if kept is not None and kept.base is not None else set())
        if kept is None:
            return
        if kept.refused:
            self.get_logger().error(f'lamp refinement file refused, running on the survey: '
                                    f'{kept.state[len("refused: "):]}')
            return
        self.get_logger().info(f'lamp refinement {kept.path}: {kept.state}')
        for uid, reason in sorted(kept.off_survey.items()):
            self.get_logger().warn(f'lamp {uid:#06x} is {reason} (lamp refinement): '
                                   'placed where the passes put it; re-survey it')
        for flag in kept.base.flags if kept.base is not None else ():
            self.get_logger().warn(f'lamp {flag.uid:#06x} {flag.reason} (lamp refinement)')

    def _merged_refinement(self, finish=False):
        kept, recorder = self.localizer_config.refinement_kept, self.localizer.pass_recorder
        if kept is None or kept.refused or recorder is None:
            return None
        measurements = recorder.finish() if finish else recorder.measurements
        return kept.base.merged(measurements)

    def save_lamp_refinement(self, finish=False):
        """Write the kept refinement plus this run's triplets to
        ``lamp_refinement_path`` (never over a refused file); errors are logged, never
        raised. Newly moved lamps are logged.
        """
        merged = self._merged_refinement(finish)
        if merged is None or not self.localizer.pass_recorder.measurements:
            return
        kept = self.localizer_config.refinement_kept
        for flag in merged.flags:
            if flag.uid not in self._flags_reported:
                self._flags_reported.add(flag.uid)
                self.get_logger().warn(f'lamp {flag.uid:#06x} {flag.reason} (lamp refinement):'
                                       ' its earlier triplets are kept apart in the file')
        try:
            save_refinement(kept.path, merged, kept.survey_map,
                            params.load_mount(self.params).vehicle_id)
        except OSError as exc:
            self._warn('lamp_refinement_save', f'lamp refinement not written to {kept.path}: '
                       f'{exc}')

    def _report_disparity_map(self):
        state = self.localizer_config.disparity_map_state
        if state.startswith('refused'):
            self.get_logger().error(f'disparity map file {self.params["disparity_map_path"]} '
                                    f'refused, learning afresh (the file is kept as it is): '
                                    f'{state[len("refused: "):]}')
        elif state != 'off':
            self.get_logger().info(f'disparity map: {state}')

    def save_disparity_map(self):
        """Write the kept cells plus this run's to ``disparity_map_path`` (never over a
        refused file, nor before this run added a residual); errors are logged, never
        raised.
        """
        dm, cfg = self.localizer.disparity_map, self.localizer_config
        path = self.params['disparity_map_path']
        if (not path or dm is None or not dm.run or dm.refused
                or cfg.disparity_map_state.startswith('refused')):
            return
        g = cfg.geometry
        try:
            save_disparity_map(path, dm.cells(), params.load_mount(self.params).vehicle_id,
                               g.fx * g.baseline_m, dm.config.cell_px,
                               cfg.disparity_map_runs + 1)
        except OSError as exc:
            self._warn('disparity_map_save', f'disparity map not written to {path}: {exc}')

    def save_kept(self):
        """At stop: what the train keeps (self-calibration, lamp refinement, disparity
        map).
        """
        self.save_self_calibration()
        self.save_lamp_refinement(finish=True)
        self.save_disparity_map()

    #: what run_node calls before destroy_node (vlc_common.process), and the lockstep
    #: graph's driver
    on_stop = save_kept

    @staticmethod
    def reacquisition_config(p):
        """ReacquisitionConfig of a parameter dict (coasting = no fix for coast_warn_s)."""
        return ReacquisitionConfig(
            enabled=p['use_curvature_aid'], min_state_sigma_m=p['curvature_aid_min_state_sigma_m'],
            coast_s=p['coast_warn_s'], max_match_sigma_m=p['curvature_aid_max_match_sigma_m'],
            min_match_sigma_m=p['curvature_aid_min_match_sigma_m'],
            gate_chi2=p['curvature_aid_gate_chi2'],
            consistency_chi2=p['curvature_aid_consistency_chi2'],
            max_match_gap_s=p['curvature_aid_max_gap_s'],
            reset_min_matches=p['curvature_aid_reset_min_matches'],
            reset_min_travel_m=p['curvature_aid_reset_min_travel_m'])

    @staticmethod
    def _config(p):
        mount = params.load_mount(p)
        geometry = params.rig_geometry(p, mount)
        for name in ('attitude_sigma_floor_deg', 'attitude_sigma_unknown_deg',
                     'mount_angle_sigma_deg'):
            if len(p[name]) != 3:
                raise ValueError(f'{name} needs 3 values, got {list(p[name])}')
        fix = FixConfig(use_range_constraint=p['use_range_constraint'],
                        track_sigma_yz_m=(p['track_sigma_y_m'], p['track_sigma_z_m']),
                        track_offset_yz_m=(p['track_offset_y_m'], p['track_offset_z_m']),
                        lamp_position_sigma_m=p['lamp_position_sigma_m'],
                        stereo_scale_sigma=p['stereo_scale_sigma'],
                        focal_length_sigma=p['focal_length_sigma'],
                        principal_point_sigma_px=p['principal_point_sigma_px'],
                        mount_angle_sigma_rad=tuple(v * _DEG for v in p['mount_angle_sigma_deg']),
                        min_disparity_px=p['min_disparity_px'],
                        attitude_weight_inflation=p['attitude_weight_inflation'])
        kalman = params.kalman_config(p, unknown_accel_sigma_mps2=p['unknown_accel_sigma_mps2'])
        integrity = IntegrityConfig(
            gate_chi2=p['gate_chi2'], geometry_gate_chi2=p['geometry_gate_chi2'],
            association_max_sigma_m=p['association_max_sigma_m'],
            association_window_m=p['association_window_m'],
            reinit_agreement_chi2=p['reinit_agreement_chi2'],
            reinit_after_s=p['reinit_after_s'],
            reinit_speed_sigma_mps=p['reinit_speed_sigma_mps'],
            contradiction_memory_s=p['contradiction_memory_s'],
            coast_warn_s=p['coast_warn_s'], max_sigma_m=p['max_sigma_m'],
            report_hold_s=p['report_hold_s'])
        standstill = params.standstill_config(p)
        return LocalizerConfig(
            geometry=geometry, fix=fix, kalman=kalman, integrity=integrity,
            standstill=standstill, use_imu_attitude=p['use_imu_attitude'],
            use_exposure_stamping=p['use_exposure_stamping'], use_kalman=p['use_kalman'],
            publish_rate_hz=p['publish_rate_hz'], publish_on_fix=p['publish_on_fix'],
            pose_sigma_yz_m=(p['pose_sigma_y_m'], p['pose_sigma_z_m']),
            motion_sigma_factor=p['motion_sigma_factor'],
            motion_highpass_hz=p['motion_highpass_hz'], motion_window_s=p['motion_window_s'],
            history_s=p['history_s'], imu_timeout_s=p['imu_timeout_s'],
            imu_max_gap_s=p['imu_max_gap_s'], backward_reset_s=p['backward_reset_s'],
            imu_backward_s=p['imu_backward_s'], blind_gap_s=p['blind_gap_s'],
            clock_tolerance_s=p['clock_tolerance_s'],
            attitude_plausible_rad=p['attitude_plausible_deg'] * _DEG,
            attitude_distrust_s=p['attitude_distrust_s'],
            attitude_evidence_s=p['attitude_evidence_s'],
            attitude_sigma_floor_rad=tuple(v * _DEG for v in p['attitude_sigma_floor_deg']),
            attitude_sigma_unknown_rad=tuple(v * _DEG for v in p['attitude_sigma_unknown_deg']),
            imu_lever_arm_m=tuple(float(v) for v in mount.imu.position_m),
            tilt_leak_time_s=p['tilt_leak_time_s'],
            systematic_weight_inflation=p['systematic_weight_inflation'],
            attitude_aiding_period_s=p['attitude_aiding_period_s'],
            attitude_aiding_calibration_inflation=p['attitude_aiding_calibration_inflation'],
            initial_chainage_m=p['initial_chainage_m'] if p['use_initial_prior'] else math.nan,
            initial_chainage_sigma_m=p['initial_chainage_sigma_m'],
            initial_speed_mps=p['initial_speed_mps'] if p['initial_speed_known'] else math.nan,
            max_speed_mps=p['max_speed_mps'], init_lookback_s=p['init_lookback_s'],
            self_survey=(SelfSurveyConfig(refine_map=False)
                         if p['use_self_calibration'] else None),
            disparity_map=(DisparityMapConfig(
                extrapolate_cells=p['disparity_map_extrapolate_cells'],
                max_state_sigma_m=p['disparity_map_max_state_sigma_m'])
                if p['use_disparity_map'] else None))

    # ------------------------------------------------------------------ inputs
    def _guarded(self, topic, stamp_ns, item):
        """[(stamp_ns, item)] to hand on after ``topic``'s StampGuard judged one message."""
        result = self._stamp_guards[topic].push(stamp_ns, item)
        if result.dropped:
            self._warn(f'stamp_outlier:{topic}', lambda: f'{len(result.dropped)} {topic} '
                       'message(s) stamped far from the stream (beyond backward_reset_s before '
                       'or forward_jump_s after the newest) dropped')
        if result.rebased:
            self._warn(f'time_base:{topic}', lambda: f'{topic} stamps moved by '
                       f'{result.rebased * 1e-9:+.3f} s for {len(result.released)} messages '
                       'in a row: new time base')
            if result.rebased < 0 and topic != 'imu/data':
                self.joiner.clear()      # frames of the old time base never join the new
        return result.released

    def _on_imu(self, msg, received_ns=None):
        if received_ns is None:
            received_ns = self.get_clock().now().nanoseconds
        for _, sample in self._guarded('imu/data', conversions.stamp_to_ns(msg.header.stamp),
                                       msg):
            start = time.perf_counter()
            report = self.localizer.add_imu(conversions.imu_from_msg(sample), received_ns)
            if report.fixes:
                # a frame that waited for this sample (_on_spots): its fixes' cost
                self._fix_ms.append((time.perf_counter() - start) * 1e3 / len(report.fixes))
            self._publish(report)

    def _drain(self):
        """Hand the localizer every camera_info received so far (every one in order: the
        last one of a batch may be a bad one, which must not hide the good one before it)
        and the IMU samples received so far that are not too far ahead of the frames.
        """
        self._drain_camera_info()
        self._drain_imu()

    def _drain_camera_info(self):
        for index, sub in enumerate(self._info_polled):
            for info in sub.take_all():
                self._on_camera_info(index, info)

    def _drain_imu(self):
        if self._imu_polled is not None:
            msgs = self._imu_polled.take_all()
            if msgs:
                received_ns = self.get_clock().now().nanoseconds
                for msg in msgs:
                    self._imu_pacer.push(conversions.stamp_to_ns(msg.header.stamp),
                                         (msg, received_ns))
            # no further ahead of the frames than they need (core.imu_pacing)
            start = self._now_s()
            released = self._imu_pacer.release(start)
            for msg, received_ns in released:
                self._on_imu(msg, received_ns)
            if released:
                self._imu_pacer.credit(self._now_s() - start)

    def _on_poll(self):
        self._drain()
        self._flush_joiner()

    def _records(self, msg, topic, required=()):
        try:
            return conversions.records_from_cloud(msg, topic, required)
        except ValueError as exc:
            self._clouds_refused += 1
            self._warn(f'bad_cloud:{topic}', f'message skipped: {exc}')
            return None

    def _on_spots(self, msg):
        """A frame's spot pairs. The frame goes to the core before the IMU samples taken
        since the last poll: its fixes wait in the core only for the samples up to their
        exposure (usually handed on by the poll already), so the pose after the fix is
        published at once and the newer samples follow, instead of the other way round
        (measured: docs/arch/train_localizer.md, "Latency: the frame before the IMU samples
        behind it"). The core puts every observation where its stamp belongs, whatever
        the order it receives them in.
        """
        records = self._records(msg, 'spots/pairs', SPOT_FIELDS)
        if records is not None:
            stamp = conversions.stamp_to_ns(msg.header.stamp)
            self._imu_pacer.on_frame(stamp, self._now_s())     # before the IMU it releases
            self._drain_camera_info()
            for stamp_ns, rec in self._guarded('spots/pairs', stamp, records):
                self._process(self.joiner.add_spots(stamp_ns, rec, self._now_s()))
            self._drain_imu()     # after the frame: see _on_spots

    def _on_lamps(self, msg):
        records = self._records(msg, 'vlc/lamps', LAMP_FIELDS)
        if records is not None:
            stamp = conversions.stamp_to_ns(msg.header.stamp)
            self._imu_pacer.on_frame(stamp, self._now_s())     # before the IMU it releases
            self._drain_camera_info()
            for stamp_ns, rec in self._guarded('vlc/lamps', stamp, records):
                self._process(self.joiner.add_lamps(stamp_ns, rec, self._now_s()))
            self._drain_imu()     # after the frame: see _on_spots

    def _on_curvature(self, msg):
        """A curvature match: chainage and its variance along the track, to the aid."""
        frame = self.params['map_frame_id']
        if msg.header.frame_id and msg.header.frame_id != frame:
            self._warn('curvature_frame', f'{self.params["curvature_aid_topic"]}: frame '
                       f'{msg.header.frame_id!r} is not {frame!r}: match skipped')
            return
        p = msg.pose.pose.position
        cov = np.asarray(msg.pose.covariance, dtype=float).reshape(6, 6)[:3, :3]
        chainage, var = chainage_measurement(self.localizer_config.fix.track,
                                             (p.x, p.y, p.z), cov)
        stamp = conversions.stamp_to_ns(msg.header.stamp)
        self._drain()
        rec = self.curvature_aid.add(stamp, chainage, var)
        if rec.status == APPLIED:
            self.get_logger().info(
                f'curvature match applied: chainage {rec.chainage_m:.1f} m (1-sigma '
                f'{rec.sigma_m:.1f} m), {rec.offset_m:+.1f} m from the state (1-sigma '
                f'{rec.state_sigma_m:.1f} m)')
        elif rec.status == RESET:
            self.get_logger().error(
                f'curvature matches contradicted the state for '
                f'{self.curvature_aid.config.reset_min_travel_m:.0f} m: chainage reset by '
                f'{rec.offset_m:+.1f} m to {rec.chainage_m:.1f} m')
        elif rec.status == BAD_INPUT:
            self._warn('curvature_bad', f'{self.params["curvature_aid_topic"]}: non-finite '
                       'pose or non-positive variance along the track: match skipped')
        elif rec.status == REJECTED_GATE:
            self._warn('curvature_gate', f'curvature match rejected: {rec.offset_m:+.1f} m from '
                       f'the state (d2 {rec.d2:.0f})')

    def _process(self, frames):
        for stamp_ns, observations in frames:
            start = time.perf_counter()
            report = self.localizer.add_frame(stamp_ns, observations)
            elapsed_ms = (time.perf_counter() - start) * 1e3
            if report.fixes:
                self._fix_ms.append(elapsed_ms / len(report.fixes))
            self._publish(report)

    # ------------------------------------------------------------------ outputs
    def _publish(self, report):
        # the poses first: they are what the train waits for; the log lines and the
        # compensator's attitude aids follow
        map_frame = self.params['map_frame_id']
        if report.poses:
            base_frame = self.params['base_frame_id']
            now_ns = self.get_clock().now().nanoseconds
            for est in report.poses:
                ps, pwc, odom = conversions.pose_messages(est, map_frame, base_frame)
                self.pub_pose.publish(ps)
                self.pub_pose_cov.publish(pwc)
                self.pub_odom.publish(odom)
                self._published += 1
                self._last_pose = est
            self._record_latency(report, now_ns)
        for event in report.events:
            self._log_event(event)
        for aid in report.attitude_aids:
            self.pub_aid.publish(conversions.attitude_aid_message(aid, map_frame))
        if report.poses or report.fixes or report.events:
            self._check_state()

    def _check_state(self):
        """Diagnostics at once when the integrity state changes (not only periodically),
        so a consumer and the evaluation see the sensor time of every transition.
        """
        state = self.localizer.status()[0]
        if state != self._state:
            previous, self._state = self._state, state
            if previous is not None:
                self.get_logger().info(f'integrity {previous.value} -> {state.value}')
            self._publish_diagnostics()

    def _record_latency(self, report, now_ns):
        used = [f.measurement_ns for f in report.fixes if f.status in ('accepted', 'initialised',
                                                                       'reinitialised')]
        for t in used:
            latency_ms = (now_ns - t) * 1e-6
            # Only meaningful when the node clock and the sensor stamps share a time base
            # (a real camera, or use_sim_time with the rig's /clock).
            if -1e3 < latency_ms < 1e4:
                self._latency_ms.append(latency_ms)

    def _log_event(self, event):
        if event.level == Level.OK:
            self.get_logger().info(event.message)
        elif event.level == Level.ERROR:
            self.get_logger().error(event.message)
        else:
            self._warn(event.code, event.message)

    def _publish_diagnostics(self):
        state, level, message, sigma = self.localizer.status()
        now = self.get_clock().now()
        if state != self._state_since[0]:
            self._state_since = (state, now.nanoseconds)
        c = self.localizer.monitor.counters
        j = self.joiner.stats
        values = {
            'integrity_state': state.value,
            # how long ago (node clock) it began: a subscriber that matched late, or lost
            # the message of the transition, still learns when it happened
            'integrity_state_age_s': f'{(now.nanoseconds - self._state_since[1]) * 1e-9:.3f}',
            'chainage_sigma_m': f'{sigma:.4f}',
            'chainage_sigma_systematic_m': f'{self.localizer.systematic_sigma_m:.4f}',
            'calibration_sigma': self._calibration_text,
            'poses_published': self._published,
            'fixes_accepted': c.fixes_accepted,
            'fixes_unconfirmed_used': c.fixes_unconfirmed_used,
            'rejected_contradiction': c.rejected_contradiction,
            'rejected_geometry': c.rejected_geometry,
            'unconfirmed_skipped': c.unconfirmed_skipped,
            'unknown_uid': c.unknown_uid,
            'bad_observations': c.bad_observations,
            'reinitialisations': c.reinitialisations,
            'time_resets': c.time_resets,
            'stamps_dropped': self.localizer.time_base.counters.dropped,
            'sensor_stamp_ns': self.localizer.newest_ns or 0,
            'dropped_stamp_outliers': sum(g.stats.outliers for g in self._stamp_guards.values()),
            'time_base_changes': sum(g.stats.rebases for g in self._stamp_guards.values()),
            'clouds_refused': self._clouds_refused,
            'camera_info_refused': self._intrinsics.keeper.refused,
            'imu_rejected': c.imu_rejected,
            'records_too_old': c.records_too_old,
            'imu_samples_held_max': self._imu_pacer.held_max,
            'imu_attitude_implausible': c.imu_attitude_implausible,
            'fixes_attitude_fallback': c.fixes_attitude_fallback,
            'frames_joined': j.joined,
            'frames_without_uids': j.spots_without_lamps,
            'lamp_records_unmatched': j.unmatched_lamp_records,
            'intrinsics': self._intrinsics.source,
            # the car body's motion about the track that the lateral/vertical 1σ covers
            'cross_track_motion_mm': '{:.1f} / {:.1f}'.format(
                *(1e3 * v for v in self.localizer.cross_track_motion_m)),
        }
        survey = self.localizer.survey
        if survey is not None:
            sd, ss = survey.published_sigmas()
            values.update({
                'self_calibration': (('applied' if survey.applied else 'learning')
                                     + f'; {self._self_cal_state}'),
                'disparity_offset_px': f'{survey.theta[0]:+.4f}',
                'disparity_offset_sigma_px': f'{sd:.4f}',
                'stereo_scale_error': f'{survey.theta[1]:+.2e}',
                'stereo_scale_sigma': f'{ss:.2e}',
                'self_survey_lamps_inconsistent': len(survey.flagged)})
        else:
            values['self_calibration'] = 'off'
        dm = self.localizer.disparity_map
        state = self.localizer_config.disparity_map_state
        values['disparity_map'] = (f'{state}; {dm.refused}' if dm is not None and dm.refused
                                   else state)
        if dm is not None:
            cells, residuals, mean_abs = dm.summary()
            values.update({'disparity_map_cells_in_use': cells,
                           'disparity_map_residuals_this_run': residuals,
                           'disparity_map_mean_abs_px': f'{mean_abs:.3f}'})
        kept = self.localizer_config.refinement_kept
        if kept is None:
            values['lamp_refinement'] = 'off'
        else:
            values['lamp_refinement'] = kept.state
            recorder = self.localizer.pass_recorder
            if recorder is not None and not kept.refused:
                merged = self._merged_refinement()
                values['lamp_refinement_triplets_this_run'] = len(recorder.measurements)
                values['lamps_off_survey'] = ' '.join(f'{u:#06x}' for u in sorted(
                    kept.off_survey)) or 'none'
                values['lamps_moved'] = ' '.join(f'{u:#06x}' for u in sorted(
                    merged.moved)) or 'none'
        aid = self.curvature_aid.counters
        values.update({'curvature_aids_received': aid.received,
                       'curvature_aids_applied': aid.applied,
                       'curvature_aids_rejected': aid.rejected,
                       'curvature_aids_ignored': aid.counts[IGNORED],
                       'curvature_aid_resets': aid.counts[RESET]})
        last = self.curvature_aid.last
        if last is not None:
            values['last_curvature_aid'] = (f'{last.status} {last.offset_m:+.2f} m '
                                            f'(1-sigma {last.sigma_m:.2f} m)')
        if self._last_pose is not None:
            values['last_pose_chainage_m'] = f'{self._last_pose.chainage_m:.3f}'
            values['last_pose_speed_mps'] = f'{self._last_pose.speed_mps:.3f}'
        for key, data in (('processing_ms_per_fix', self._fix_ms),
                          ('fix_to_publish_latency_ms', self._latency_ms)):
            if data:
                arr = np.asarray(data)
                values[key + '_median'] = f'{np.median(arr):.3f}'
                values[key + '_p99'] = f'{np.percentile(arr, 99):.3f}'
                values[key + '_max'] = f'{arr.max():.3f}'
        rej = self.localizer.monitor.last_rejection
        if rej is not None:
            values['last_rejected_uid'] = f'{rej.uid:#06x}' if rej.uid is not None else 'none'
            values['last_rejection'] = rej.reason
        unknown = self.localizer.monitor.last_unknown_uid
        if unknown is not None:
            values['last_unknown_uid'] = f'{int(unknown[1]):#06x}'
        msg = DiagnosticArray()
        msg.header.stamp = now.to_msg()
        msg.status = [conversions.diagnostic_status(f'{self.get_name()}: integrity',
                                                    'train_localizer', level, message, values)]
        self.pub_diag.publish(msg)


def main(args=None):
    return run_node(TrainLocalizerNode, 'train_localizer', args)


if __name__ == '__main__':
    sys.exit(main())
