"""``curvature_node``: chainage from curvature-array correlation (companion method 4).

No camera and no lamps: the gyro's yaw rate over the speed gives the curvature of the
track just run over, matched against the line's curvature template
(:mod:`companion_localizers.core.curvature`).

Subscribes (relative names):

* ``imu/data_raw`` (sensor_msgs/Imu; best effort like ``qos_profile_sensor_data``, queue
  depth 1000 so that a match, tens of ms, loses no sample): the gyro z rate of
  ``base_link`` (the platform's yaw rate: track yaw rate κ·v plus vibration);
* the speed: ``odometry_topic`` (nav_msgs/Odometry; reliable, depth 50), speed =
  |twist.twist.linear|. Default ``train/odometry`` (the main localizer's speed, in every
  graph); a wheel tachometer is the better source for re-acquisition after a long lamp
  outage, because it does not depend on the lamps — remap or set the topic. A constant
  scale error of the speed is absorbed by the sampling-ratio search.

Publishes (reliable, depth 10):

* ``companion/curvature/pose`` (geometry_msgs/PoseStamped) after every accepted match
  (every ``match_period_s`` of IMU time): ``base_link`` on the alignment's centreline
  at rail level at the matched chainage, yaw = the track heading there, stamped with
  the IMU sample the chainage describes. Nothing while the match is refused — on a
  straight line never: there is no curvature signal to localise with;
* ``companion/curvature/pose_with_covariance`` (geometry_msgs/PoseWithCovarianceStamped)
  with every such pose: the same pose, covariance = chainage variance σ²·t·tᵀ along the
  track direction t (σ = the match's ``chainage_sigma_m``: floor, spread and short-window
  terms) + ``lateral_sigma_m``² across it and vertically; roll and pitch unknown (1e6),
  yaw (κ·σ)² + 1e-6. ``train_localizer`` takes it as its re-acquisition aid;
* ``diagnostics`` (diagnostic_msgs/DiagnosticArray) every ``diagnostics_period_s``
  (steady clock): status (ok / too_short / no_curvature_signal / low_correlation /
  ambiguous / imprecise), confidence, correlation, chainage spread, sampling ratio,
  CPU time per match, rejected inputs. Level OK for a match, WARN when refused or
  waiting, ERROR without IMU or speed input.

Bad input (NaN, negative speed, stamps out of order) is counted, warned about
(throttled) and skipped. Parameters: ``config/curvature_node.yaml``.
"""
from dataclasses import dataclass, fields
import math
import sys

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from geometry_msgs.msg import PoseStamped, PoseWithCovarianceStamped
from nav_msgs.msg import Odometry
from rcl_interfaces.msg import ParameterType
from rclpy.clock import Clock, ClockType
from rclpy.node import Node
from rclpy.qos import QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import Imu

from companion_localizers import conversions
from companion_localizers.core.curvature import (
    STATUS_NO_SIGNAL,
    STATUS_OK,
    STATUS_TOO_SHORT,
    CurvatureConfig,
    CurvatureLocalizer,
)
from vlc_common.core.alignment import NAMED_ALIGNMENTS, Alignment
from vlc_common.core.rotations import matrix_to_quat_xyzw, rpy_to_matrix
from vlc_common.parameters import descriptor as _desc
from vlc_common.polled import IMU_QOS
from vlc_common.process import run_node
from vlc_common.stamps import stamp_to_s
from vlc_common.throttled_log import ThrottledWarnings

_STR = ParameterType.PARAMETER_STRING
# diagnostic_msgs/DiagnosticStatus levels as ints (conversions.diagnostic_status packs them)
OK, WARN, ERROR = (level[0] for level in (DiagnosticStatus.OK, DiagnosticStatus.WARN,
                                          DiagnosticStatus.ERROR))
NS_PER_S = 1_000_000_000

# name, default, descriptor — documented key by key in config/curvature_node.yaml
NODE_PARAMETERS = (
    ('alignment', 'straight', _desc('Track alignment of the line (its curvature is the '
                                    'template): ' + ', '.join(NAMED_ALIGNMENTS) + '.',
                                    ptype=_STR)),
    ('odometry_topic', 'train/odometry', _desc('nav_msgs/Odometry topic giving the speed '
                                               '(|twist.linear|).', ptype=_STR)),
    ('map_frame_id', 'map', _desc('Frame of the published pose.', ptype=_STR)),
    ('match_period_s', 1.0, _desc('Interval between two matches, seconds of IMU time.',
                                  0.05, 60.0)),
    ('speed_timeout_s', 0.5, _desc('Longest wait for a speed sample; also the longest hold '
                                   'of the last speed, s.', 0.01, 3600.0)),
    ('speed_scale', 1.0, _desc('Factor applied to every input speed (tachometer wheel '
                               'calibration), -.', 0.1, 10.0)),
    ('diagnostics_period_s', 1.0, _desc('Diagnostics period (steady clock), s.', 0.1, 60.0)),
    ('warn_throttle_s', 5.0, _desc('Minimum interval between two warnings of one kind, s.',
                                   0.0, 600.0)),
    ('lateral_sigma_m', 0.05, _desc('1-sigma lateral and vertical position of base_link on '
                                    'the centreline in pose_with_covariance, m.', 1e-4, 10.0)),
)

# CurvatureConfig fields as parameters: (name, descriptor); defaults from the dataclass.
CORE_PARAMETERS = (
    ('spacing_m', _desc('Sample spacing of template and real-time array, m.', 0.1, 10.0)),
    ('smoothing_time_s', _desc('Gaussian smoothing sigma = this x mean speed, s.', 0.01, 10.0)),
    ('min_smoothing_sigma_m', _desc('Lower bound of the smoothing sigma, m.', 0.5, 500.0)),
    ('max_smoothing_sigma_m', _desc('Upper bound of the smoothing sigma, m.', 0.5, 500.0)),
    ('window_m', _desc('Length of the real-time array matched, measured m.', 10.0, 10000.0)),
    ('min_window_m', _desc('Shortest array matched, measured m.', 10.0, 10000.0)),
    ('ratio_min', _desc('Sampling-ratio search start (true / measured distance).', 0.0, 10.0)),
    ('ratio_max', _desc('Sampling-ratio search end.', 0.01, 10.0)),
    ('ratio_step', _desc('Sampling-ratio search step.', 0.0001, 1.0)),
    ('min_matched_length_m', _desc('Ratios giving a shorter resampled window are skipped, m.',
                                   1.0, 10000.0)),
    ('template_padding_m', _desc('Straight track added before and after the alignment in '
                                 'the template, m.', 0.0, 100000.0)),
    ('min_speed_mps', _desc('Below this speed nothing is integrated and the gyro bias is '
                            'learnt, m/s.', 0.0, 10.0)),
    ('bias_time_constant_s', _desc('Time constant of the standstill gyro-bias average, s.',
                                   0.01, 3600.0)),
    ('max_gap_s', _desc('A longer IMU gap restarts the array, s.', 0.001, 60.0)),
    ('min_signal_std_1pm', _desc('Least std of the smoothed curvature that counts as a '
                                 'curvature signal, 1/m.', 1e-7, 0.1)),
    ('min_correlation', _desc('Least Pearson coefficient of an accepted match.', -1.0, 1.0)),
    ('min_z_margin', _desc('Least Fisher-z margin of the best over the best distinct '
                           'candidate.', 0.0, 10.0)),
    ('correlation_cap', _desc('Coefficients above this count as equal in the margin test.',
                              0.001, 0.999999)),
    ('spread_z', _desc('Fisher-z band of the candidates counted in the chainage spread.',
                       0.0, 10.0)),
    ('max_spread_m', _desc('Largest accepted chainage spread, m.', 0.0, 10000.0)),
    ('max_amplitude_error', _desc('Largest relative deviation of the fitted amplitude from '
                                  'the ratio.', 0.001, 10.0)),
    ('gyro_bias_sigma_rps', _desc('1 sigma gyro z bias before it is learnt, rad/s.', 0.0, 1.0)),
    ('learnt_bias_sigma_rps', _desc('1 sigma gyro z bias after standstill learning, rad/s.',
                                    0.0, 1.0)),
    ('offset_tolerance_1pm', _desc('Curvature offset allowed besides the bias term, 1/m.',
                                   0.0, 0.1)),
    ('chainage_sigma_floor_m', _desc('1-sigma chainage of a full-window match without '
                                     'spread, m.', 0.01, 1000.0)),
    ('short_window_sigma_m', _desc('1-sigma added for a window of min_window_m (linearly 0 '
                                   'at window_m), m.', 0.0, 1000.0)),
)
_CORE_DEFAULTS = {f.name: f.default for f in fields(CurvatureConfig)}


@dataclass
class CurvatureNodeConfig:
    """Everything the node reads from its parameters (see config/curvature_node.yaml)."""

    alignment: str
    odometry_topic: str
    map_frame_id: str
    match_period_s: float
    speed_timeout_s: float
    speed_scale: float
    diagnostics_period_s: float
    warn_throttle_s: float
    lateral_sigma_m: float
    core: CurvatureConfig


def declare_and_read(node):
    """Declare every parameter on ``node``; return a CurvatureNodeConfig (ValueError if
    inconsistent).
    """
    for name, default, descriptor in NODE_PARAMETERS:
        node.declare_parameter(name, default, descriptor)
    for name, descriptor in CORE_PARAMETERS:
        node.declare_parameter(name, float(_CORE_DEFAULTS[name]), descriptor)
    v = {name: node.get_parameter(name).value for name, _, _ in NODE_PARAMETERS}
    core = CurvatureConfig(**{name: float(node.get_parameter(name).value)
                              for name, _ in CORE_PARAMETERS})
    if not v['odometry_topic'] or not v['map_frame_id']:
        raise ValueError('odometry_topic and map_frame_id must not be empty')
    return CurvatureNodeConfig(core=core, **v)


class CurvatureNode(Node):
    """ROS wrapper of :class:`CurvatureLocalizer`; see the module docstring."""

    def __init__(self, **kwargs):
        super().__init__('curvature_node', **kwargs)
        self.config = cfg = declare_and_read(self)
        self.core = CurvatureLocalizer(Alignment.named(cfg.alignment), cfg.core,
                                       cfg.match_period_s, cfg.speed_timeout_s, cfg.speed_scale)
        self._steady = Clock(clock_type=ClockType.STEADY_TIME)
        self._warnings = ThrottledWarnings(self.get_logger(), self.config.warn_throttle_s)
        self._imu_count = 0
        self._speed_count = 0
        self._matches = 0
        self._published = 0
        self._pub_pose = self.create_publisher(PoseStamped, 'companion/curvature/pose', 10)
        self._pub_pose_cov = self.create_publisher(
            PoseWithCovarianceStamped, 'companion/curvature/pose_with_covariance', 10)
        self._pub_diag = self.create_publisher(DiagnosticArray, 'diagnostics', 10)
        # a match blocks the executor for tens of ms: the deep IMU queue rides it out
        self.create_subscription(Imu, 'imu/data_raw', self._on_imu, IMU_QOS)
        self.create_subscription(Odometry, cfg.odometry_topic, self._on_odometry,
                                 QoSProfile(depth=50, reliability=ReliabilityPolicy.RELIABLE))
        self.create_timer(cfg.diagnostics_period_s, self._publish_diagnostics,
                          clock=self._steady)
        if not self.core.template.has_curvature:
            self.get_logger().warn(
                f'alignment {cfg.alignment!r} has no curvature: the curvature method cannot '
                'localise on this line and will publish no pose')
        self.get_logger().info(
            f'curvature correlation on alignment {cfg.alignment!r} '
            f'({self.core.alignment.length_m:.0f} m), speed from {cfg.odometry_topic}, '
            f'match every {cfg.match_period_s:g} s, ratios {cfg.core.ratio_min:g}..'
            f'{cfg.core.ratio_max:g} step {cfg.core.ratio_step:g}')

    # ------------------------------------------------------------------ inputs
    def _warn(self, kind, text):
        self._warnings.warn(kind, text)

    def _on_imu(self, msg):
        self._imu_count += 1
        rejected = self.core.imu_rejected
        t = stamp_to_s(msg.header.stamp)
        matches = self.core.add_imu(t, float(msg.angular_velocity.z))
        if self.core.imu_rejected > rejected:
            self._warn('imu', f'imu/data_raw: skipped a sample at {t:.6f} s (non-finite rate '
                              f'or stamp not after the previous one; {self.core.imu_rejected} '
                              'so far)')
        self._publish(matches)

    def _on_odometry(self, msg):
        self._speed_count += 1
        rejected = self.core.speed_rejected
        v = msg.twist.twist.linear
        speed = math.sqrt(v.x * v.x + v.y * v.y + v.z * v.z)
        t = stamp_to_s(msg.header.stamp)
        matches = self.core.add_speed(t, speed)
        if self.core.speed_rejected > rejected:
            self._warn('speed', f'{self.config.odometry_topic}: skipped a speed at {t:.6f} s '
                                f'(non-finite or stamp not after the previous one; '
                                f'{self.core.speed_rejected} so far)')
        self._publish(matches)

    # ------------------------------------------------------------------ outputs
    def _publish(self, matches):
        for timed in matches:
            self._matches += 1
            if not timed.match.ok:
                continue
            position, yaw = self.core.pose(timed.match.chainage_m)
            quat = matrix_to_quat_xyzw(rpy_to_matrix(0.0, 0.0, yaw))
            pose = conversions.pose_stamped(int(round(timed.t_s * NS_PER_S)), position, quat,
                                            self.config.map_frame_id)
            self._pub_pose.publish(pose)
            self._pub_pose_cov.publish(self._with_covariance(pose, timed.match, yaw))
            self._published += 1

    def _with_covariance(self, pose, match, yaw):
        """PoseWithCovarianceStamped of ``pose`` (see the module docstring)."""
        msg = PoseWithCovarianceStamped()
        msg.header = pose.header
        msg.pose.pose = pose.pose
        sigma = float(match.chainage_sigma_m)
        kappa = float(self.core.alignment.evaluate(match.chainage_m).curvature_1pm[0])
        lateral = self.config.lateral_sigma_m ** 2
        t = (math.cos(yaw), math.sin(yaw))
        cov = [0.0] * 36
        for i in range(2):
            for j in range(2):
                # σ² along t, lateral² along the left normal n = (−t_y, t_x)
                n_i, n_j = (-t[1], t[0])[i], (-t[1], t[0])[j]
                cov[6 * i + j] = sigma * sigma * t[i] * t[j] + lateral * n_i * n_j
        cov[14] = lateral
        cov[21] = cov[28] = 1e6
        cov[35] = (kappa * sigma) ** 2 + 1e-6
        msg.pose.covariance = cov
        return msg

    def _status(self):
        """(level, message, values) of the diagnostics."""
        core = self.core
        values = {'alignment': self.config.alignment, 'imu_received': self._imu_count,
                  'speed_received': self._speed_count, 'matches': self._matches,
                  'poses_published': self._published, 'imu_rejected': core.imu_rejected,
                  'speed_rejected': core.speed_rejected,
                  'imu_without_speed': core.imu_without_speed,
                  'array_restarts': core.array.restarts,
                  'array_length_m': f'{core.array.distance_m:.1f}',
                  'gyro_bias_learnt': core.array.bias_learnt,
                  'gyro_bias_rps': f'{core.array.bias_rps:.3e}'}
        if not core.template.has_curvature:
            values['status'] = 'no_curvature_on_alignment'
            return (WARN, 'no curvature on this alignment: cannot localise',
                    values)
        if self._imu_count == 0 or self._speed_count == 0:
            missing = [name for name, n in (('imu/data_raw', self._imu_count),
                                            (self.config.odometry_topic, self._speed_count))
                       if n == 0]
            return ERROR, 'no input on ' + ', '.join(missing), values
        last = core.last
        if last is None:
            return WARN, 'waiting for the first match', values
        m = last.match
        values.update({'status': m.status, 'confidence': f'{m.confidence:.3f}',
                       'chainage_m': f'{m.chainage_m:.3f}', 'correlation': f'{m.correlation:.4f}',
                       'second_correlation': f'{m.second_correlation:.4f}',
                       'spread_m': f'{m.spread_m:.2f}', 'ratio': f'{m.ratio:.3f}',
                       'chainage_sigma_m': f'{m.chainage_sigma_m:.2f}',
                       'signal_std_1pm': f'{m.signal_std_1pm:.3e}',
                       'matched_length_m': f'{m.measured_length_m:.0f}',
                       'match_cpu_ms': f'{m.cpu_s * 1e3:.1f}', 'match_stamp_s': f'{last.t_s:.3f}'})
        if m.status == STATUS_OK:
            return OK, f'chainage {m.chainage_m:.1f} m', values
        if m.status == STATUS_NO_SIGNAL:
            return (WARN, 'no curvature signal (straight track): cannot '
                    'localise', values)
        if m.status == STATUS_TOO_SHORT:
            return (WARN, f'array too short ({m.measured_length_m:.0f} of '
                    f'{self.config.core.min_window_m:.0f} m)', values)
        return WARN, f'match refused: {m.status}', values

    def _publish_diagnostics(self):
        level, message, values = self._status()
        msg = DiagnosticArray()
        msg.header.stamp = self.get_clock().now().to_msg()
        msg.status = [conversions.diagnostic_status(
            f'{self.get_name()}: curvature correlation', self.config.alignment, level, message,
            values)]
        self._pub_diag.publish(msg)


def main(args=None):
    return run_node(CurvatureNode, 'curvature_node', args)


if __name__ == '__main__':
    sys.exit(main())
