"""Common ROS wrapper of the two IMU-and-frames companion localizers.

:class:`ImuFrameNode` declares the parameters both share (frames, lamp map, output
grid, filter noise, standstill, rig geometry, ranging, frame join), subscribes to
``imu/data``, ``spots/pairs``, ``vlc/lamps`` and the stereo ``camera_info``, joins the
two per-frame record streams by stamp (train_localizer's FrameJoiner), feeds an
:class:`~companion_localizers.core.imu_driven.ImuDrivenLocalizer` and publishes its
poses on ``companion/<method>/pose`` and a diagnostics status with the CPU time per
frame and per IMU sample. Subclasses (``dead_reckoning_node``, ``ins_beacon_node``)
add their own parameters, build their core, and add diagnostic values.

QoS: ``imu/data`` sensor data; ``spots/pairs`` and ``vlc/lamps`` reliable, depth 10;
camera_info reliable, transient local, depth 1; poses and diagnostics reliable, depth 10.
"""
import math

from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import PoseStamped
from rclpy.clock import Clock, ClockType
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy, qos_profile_sensor_data
from sensor_msgs.msg import CameraInfo, Imu, PointCloud2

from companion_localizers import conversions
from companion_localizers.core.along_track import FilterSettings
from companion_localizers.core.ranging import RangingConfig
from train_localizer import node_parameters as params
from train_localizer.core.join import FrameJoiner
from train_localizer.joined_frames import JoinedFramesNode
from vlc_common.core.lamp_map import LampMap, resolve_lamp_map_path
from vlc_common.parameters import descriptor as _desc
from vlc_common.polled import RECORDS_QOS
from vlc_common.throttled_log import ThrottledWarnings

_DEG = math.pi / 180.0
OK, WARN = 0, 1

# name, default, descriptor — documented key by key in each node's config/<node>.yaml
COMMON_PARAMETERS = (
    ('map_frame_id', 'map', _desc('Frame of the published poses.')),
    ('lamp_map_path', '', _desc("Lamp map YAML; '' = vlc_common's default map.")),
    ('publish_rate_hz', 50.0, _desc('Pose grid in sensor time, Hz.', 1.0, 1000.0)),
    ('max_sigma_m', 1.0, _desc('Poses are published only while the chainage 1-sigma is below '
                               'this, m ...', 1e-3, 1e4)),
    ('max_speed_sigma_mps', 2.0, _desc('... and the speed 1-sigma below this, m/s.', 1e-3,
                                       1e3)),
    ('use_imu_attitude', True, _desc('Rotate the specific force (and the camera lever) with '
                                     'the imu/data attitude; false = identity.')),
    ('tilt_prior_sigma_deg', [0.3, 0.3], _desc('Roll and pitch 1-sigma of the platform about '
                                               'the level track, fused with imu/data\'s; '
                                               '[0, 0] = off, deg.')),
    ('tilt_leak_time_s', 5.0, _desc('Time over which the gravity leak of the pitch error may '
                                    'wander (extra bias random walk), s; 0 = off.',
                                    0.0, 1000.0)),
    ('frame_span_s', 0.025, _desc('Latest measurement instant of a frame after its stamp '
                                  '(readout + exposure): frames wait until imu/data covers '
                                  'it, s.', 0.0, 1.0)),
    ('max_waiting_frames', 30, _desc('Frames waiting for imu/data at most; then processed '
                                     'without it (counted).', 1, 10000, integer=True)),
    ('diagnostics_period_s', 1.0, _desc('Diagnostics period (steady clock), s.', 0.1, 60.0)),
    ('warn_throttle_s', 2.0, _desc('Minimum interval between two warnings of one kind, s.',
                                   0.0, 600.0)),
    ('history_s', 2.0, _desc('How far back a measurement may be applied, s.', 0.05, 60.0)),
    ('survey_sigma_m', 0.005, _desc('1-sigma of a lamp\'s surveyed chainage, m.', 0.0, 10.0)),
    ('min_along_m', 0.3, _desc('Lamps nearer than this along the track (abeam) are not '
                               'ranged, m.', 0.0, 10.0)),
    ('min_disparity_px', 4.0, _desc('Smallest usable disparity, px.', 0.0, 1000.0)),
    ('attitude_sigma_deg', [0.05, 0.05, 0.1], _desc('Attitude 1-sigma about map x, y, z when '
                                                    'imu/data carries no covariance, deg.')),
    ('join_max_pending', 40, _desc('Frames waiting for their other half at most.', 1, 1000,
                                   integer=True)),
) + (params.STEREO_PARAMETERS + params.TRACK_PARAMETERS + params.KALMAN_PARAMETERS
     + params.STANDSTILL_PARAMETERS
     + params.with_defaults(params.JOIN_PARAMETERS, join_timeout_s=1.0))


def common_config_kwargs(p):
    """ImuDrivenConfig keyword arguments and the shared sub-configs from parameter values."""
    for name, size in (('attitude_sigma_deg', 3), ('tilt_prior_sigma_deg', 2)):
        if len(p[name]) != size:
            raise ValueError(f'{name} needs {size} values, got {list(p[name])}')
    kalman = params.kalman_config(p)
    standstill = params.standstill_config(p)
    geometry = params.rig_geometry(p)
    ranging = RangingConfig(track_offset_yz_m=(p['track_offset_y_m'], p['track_offset_z_m']),
                            track_sigma_yz_m=(p['track_sigma_y_m'], p['track_sigma_z_m']),
                            min_along_m=p['min_along_m'],
                            min_disparity_px=p['min_disparity_px'],
                            attitude_sigma_rad=tuple(v * _DEG for v in p['attitude_sigma_deg']))
    return dict(filter=FilterSettings(kalman=kalman, history_s=p['history_s']),
                standstill=standstill, publish_rate_hz=p['publish_rate_hz'],
                max_sigma_m=p['max_sigma_m'], max_speed_sigma_mps=p['max_speed_sigma_mps'],
                track_offset_yz_m=(p['track_offset_y_m'], p['track_offset_z_m']),
                use_imu_attitude=p['use_imu_attitude'],
                tilt_prior_sigma_rad=tuple(v * _DEG for v in p['tilt_prior_sigma_deg']),
                tilt_leak_time_s=p['tilt_leak_time_s'], frame_span_s=p['frame_span_s'],
                max_waiting_frames=p['max_waiting_frames'], ranging=ranging, geometry=geometry,
                survey_sigma_m=p['survey_sigma_m'])


class ImuFrameNode(JoinedFramesNode, Node):
    """See the module docstring. Subclasses set ``METHOD`` and implement
    :meth:`make_core` and :meth:`extra_diagnostics`.
    """

    METHOD = ''
    EXTRA_PARAMETERS = ()

    def __init__(self, name, **kwargs):
        super().__init__(name, **kwargs)
        for pname, default, descriptor in COMMON_PARAMETERS + self.EXTRA_PARAMETERS:
            self.declare_parameter(pname, default, descriptor)
        p = {pname: self.get_parameter(pname).value
             for pname, _, _ in COMMON_PARAMETERS + self.EXTRA_PARAMETERS}
        self.params = p
        path = resolve_lamp_map_path(p['lamp_map_path'])
        self.lamp_map = LampMap.load(path)
        self.core = self.make_core(p, self.lamp_map)
        self.joiner = FrameJoiner(params.join_config(p, max_pending=p['join_max_pending']))
        self._steady = Clock(clock_type=ClockType.STEADY_TIME)
        self._warnings = ThrottledWarnings(self.get_logger(), self.params['warn_throttle_s'],
                                           clock=self._now_s)
        self._intrinsics = conversions.CameraInfoIntrinsics(self.core.config.geometry,
                                                            p['use_camera_info'],
                                                            self.joiner.config)
        self._published = 0
        self._last_pose = None
        self._join_timer = conversions.CpuTimer()
        self._imu_timer = conversions.CpuTimer(window=4000)

        latched = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                             durability=DurabilityPolicy.TRANSIENT_LOCAL)
        self.pub_pose = self.create_publisher(PoseStamped, f'companion/{self.METHOD}/pose', 10)
        self.pub_diag = self.create_publisher(DiagnosticArray, 'diagnostics', 10)
        self.create_subscription(Imu, 'imu/data', self._on_imu, qos_profile_sensor_data)
        self.create_subscription(PointCloud2, 'spots/pairs', self._on_spots, RECORDS_QOS)
        self.create_subscription(PointCloud2, 'vlc/lamps', self._on_lamps, RECORDS_QOS)
        for side, index in (('left', 0), ('right', 1)):
            self.create_subscription(CameraInfo, f'stereo/{side}/camera_info',
                                     lambda msg, i=index: self._on_camera_info(i, msg), latched)
        self.create_timer(0.02, self._flush_joiner, clock=self._steady)
        self.create_timer(p['diagnostics_period_s'], self._publish_diagnostics,
                          clock=self._steady)
        self.get_logger().info(f'lamp map {path} ({len(self.lamp_map)} lamps); publishing '
                               f'{self.pub_pose.topic_name} at {p["publish_rate_hz"]:g} Hz')

    def make_core(self, params, lamp_map):
        raise NotImplementedError

    def extra_diagnostics(self):
        """(level, message, values) of the method; level None keeps the common one."""
        return None, '', {}

    # ------------------------------------------------------------------ inputs
    def _on_imu(self, msg):
        with self._imu_timer:
            sample = conversions.imu_from_msg(msg)
            if not sample.is_finite():
                self._warn('imu', 'imu/data sample with non-finite values skipped')
            newest = self.core.filter.newest_ns
            if newest is not None and sample.stamp_ns <= newest:
                self._warn('imu_order', f'imu/data stamp {sample.stamp_ns} not after {newest}: '
                           'skipped')
            estimates = self.core.add_imu(sample)
            self.handle_frame_result(self.core.take_results())
            for est in estimates:
                self.pub_pose.publish(conversions.pose_stamped(
                    est.stamp_ns, est.position_m, est.quat_xyzw, self.params['map_frame_id']))
                self._published += 1
                self._last_pose = est

    def _records(self, msg, topic, required=()):
        try:
            records = conversions.cloud_to_records(msg)
            conversions.require_fields(records, required, topic)
            return records
        except ValueError as exc:
            self._warn('bad_cloud', f'{topic} message skipped: {exc}')
            return None

    def _on_spots(self, msg):
        records = self._records(msg, 'spots/pairs', conversions.SPOT_FIELDS)
        if records is not None:
            stamp = conversions.stamp_to_ns(msg.header.stamp)
            self._process(self.joiner.add_spots(stamp, records, self._now_s()))

    def _on_lamps(self, msg):
        records = self._records(msg, 'vlc/lamps')
        if records is not None:
            stamp = conversions.stamp_to_ns(msg.header.stamp)
            self._process(self.joiner.add_lamps(stamp, records, self._now_s()))

    def _process(self, frames):
        for stamp_ns, observations in frames:
            with self._join_timer:
                self.handle_frame_result(self.core.add_frame(stamp_ns, observations))

    def handle_frame_result(self, result):
        """Hook for the subclass: the results of the frames the core processed."""

    # ------------------------------------------------------------------ outputs
    def _publish_diagnostics(self):
        c = self.core.counters
        j = self.joiner.stats
        state = self.core.filter.state
        values = {'poses_published': self._published, 'imu_samples': c.imu_samples,
                  'imu_rejected': c.imu_rejected, 'frames': c.frames,
                  'frames_without_uids': j.spots_without_lamps,
                  'frames_without_attitude': c.frames_without_attitude,
                  'bad_observations': c.bad_observations,
                  'zero_velocity_updates': c.zero_velocity_updates,
                  'measurements_dropped_old': c.measurements_dropped_old,
                  'intrinsics': self._intrinsics.source}
        level, message = OK, 'positioning'
        if state is None:
            level, message = WARN, 'waiting for imu/data'
        else:
            sigma = math.sqrt(max(state.P[0, 0], 0.0))
            values['chainage_sigma_m'] = f'{sigma:.4f}'
            values['speed_mps'] = f'{state.x[1]:.3f}'
            values['accel_bias_mps2'] = f'{state.x[2]:.4f}'
            speed_sigma = math.sqrt(max(state.P[1, 1], 0.0))
            values['speed_sigma_mps'] = f'{speed_sigma:.4f}'
            if (sigma > self.params['max_sigma_m']
                    or speed_sigma > self.params['max_speed_sigma_mps']):
                level, message = WARN, (f'chainage 1-sigma {sigma:.2f} m, speed 1-sigma '
                                        f'{speed_sigma:.2f} m/s: not publishing')
        if self._last_pose is not None:
            values['last_pose_chainage_m'] = f'{self._last_pose.position_m[0]:.3f}'
        values.update(conversions.summary_ms(self.core.frame_cpu_ms, 'processing_ms'))
        values.update(self._imu_timer.summary('imu_callback_ms'))
        if self._published:
            total = self._join_timer.total_s + self._imu_timer.total_s
            values['cpu_ms_per_pose'] = f'{1e3 * total / self._published:.3f}'
        extra_level, extra_message, extra = self.extra_diagnostics()
        values.update(extra)
        if extra_level is not None and extra_level > level:
            level, message = extra_level, extra_message
        msg = DiagnosticArray()
        msg.header.stamp = self.get_clock().now().to_msg()
        msg.status = [conversions.diagnostic_status(f'{self.get_name()}: {self.METHOD}',
                                                    'companion_localizers', level, message,
                                                    values)]
        self.pub_diag.publish(msg)
