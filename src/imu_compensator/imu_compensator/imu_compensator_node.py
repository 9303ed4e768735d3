"""imu_compensator_node: camera-platform attitude from the IMU (paper §3.3.2).

Subscriptions
-------------
``imu/data_raw`` (sensor_msgs/Imu, best effort, depth 1000: ``IMU_QOS``)
    Angular rate (rad/s) and specific force (m/s², +9.81 on z at rest) in
    ``imu_frame_id``, ENU; orientation ignored.
``attitude_aiding`` (geometry_msgs/PoseWithCovarianceStamped, reliable, depth 10)
    Optional external attitude (train_localizer: the attitude each accepted lamp shows),
    fused at the message's stamp: the orientation with the rotation block of the
    covariance (rows/columns 3-5, about map x, y, z) when that block is positive
    definite; otherwise only the yaw of the orientation, with variance covariance[35]
    (``heading_aiding_std_rad`` when that is not positive either), e.g. a heading
    from another source. An aid inconsistent with the estimate (Mahalanobis gate) is
    rejected, counted and warned about; see :mod:`imu_compensator.core.compensator`.
``train/odometry`` (nav_msgs/Odometry, reliable, depth 10; train_localizer's)
    Optional: the magnitude of ``twist.twist.linear`` (the along-track speed) at the
    header stamp, with its variance ``twist.covariance[0]``. While it is recent
    (``odometry_timeout_s``) and shows the train accelerating (``odometry_max_accel_mps2``)
    or moving (``odometry_max_speed_mps``, off by default), the IMU's standstill verdict
    is vetoed; without it the IMU decides alone. A non-finite message is ignored with a
    throttled warning.

Publications
------------
``imu/data`` (sensor_msgs/Imu, ``qos_profile_sensor_data``)
    Every ``publish_decimation``-th accepted sample, stamped with the raw sample's stamp,
    ``frame_id = base_frame_id``: orientation of base_link in map (ENU, x, y, z, w) and
    its covariance (small-angle errors about map x, y, z ≈ roll, pitch, heading, rad²,
    row-major); bias-corrected angular rate and raw specific force rotated into
    base_link, with covariances. Consumers interpolate with
    :class:`imu_compensator.core.attitude_buffer.AttitudeBuffer`.
``diagnostics`` (diagnostic_msgs/DiagnosticArray, reliable, depth 10)
    Every ``diagnostics_period_s`` (wall clock): gyro bias and its 1σ, zero-velocity
    state, measured sample rate, accepted / dropped / gap / reset counts, aiding counts
    (used, rejected, inconsistent, resets, re-initialisations), standstill vetoes and
    odometry counts, attitude.

Bad input (non-finite values, duplicate or out-of-order stamps, a time jump backwards,
gaps) is counted, warned about (throttled) and skipped or handled as described in
:mod:`imu_compensator.core.compensator`; it never stops the node. Before that, a sample
stamped more than ``backward_reset_s`` before or ``forward_jump_s`` after the newest one
is held (:class:`vlc_common.core.stamp_guard.StampGuard`): alone (a 1970 or far-future
stamp) it is dropped and counted, and neither resets the filter nor propagates it across
a gap of decades; ``time_base_confirm_count`` consecutive samples of a new time base (a
looped bag, a restarted IMU) are handed on, and a jump back then resets the filter as
before. Parameters: ``config/imu_compensator_node.yaml``.
"""
from dataclasses import dataclass
import math
import sys

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from geometry_msgs.msg import PoseWithCovarianceStamped
from nav_msgs.msg import Odometry
import numpy as np
from rcl_interfaces.msg import ParameterType
from rclpy.clock import Clock, ClockType
from rclpy.node import Node
from rclpy.qos import qos_profile_sensor_data
from sensor_msgs.msg import Imu

from imu_compensator.conversions import fill_imu_data, fuse_aiding, imu_sample, odometry_speed
from imu_compensator.core.attitude_filter import AttitudeFilterConfig, pulls_on_alignment
from imu_compensator.core.compensator import (
    AidingStatus,
    AttitudeCompensator,
    CompensatorConfig,
    SampleStatus,
)
from imu_compensator.core.zero_velocity import OdometryVeto, OdometryVetoConfig, ZeroVelocityConfig
from vlc_common.core.alignment import Alignment
from vlc_common.core.rotations import quat_from_rpy, quat_to_matrix
from vlc_common.core.stamp_guard import StampGuard
from vlc_common.core.vehicle import load_vehicle
from vlc_common.parameters import descriptor as _desc
from vlc_common.polled import IMU_QOS, PolledSubscription
from vlc_common.process import run_node
from vlc_common.stamps import stamp_to_ns
from vlc_common.throttled_log import ThrottledWarnings

DEG = math.pi / 180.0

_ARRAY = ParameterType.PARAMETER_DOUBLE_ARRAY
_STRING = ParameterType.PARAMETER_STRING



_F = AttitudeFilterConfig()
_Z = ZeroVelocityConfig()
_O = OdometryVetoConfig()
_C = CompensatorConfig()

#: (name, default, descriptor); documented key by key in config/imu_compensator_node.yaml.
NODE_PARAMETERS = (
    ('imu_frame_id', 'imu_link', _desc('Expected frame_id of imu/data_raw (a different one '
                                       'is warned about once).', ptype=_STRING)),
    ('base_frame_id', 'base_link', _desc('frame_id of imu/data: the platform whose attitude '
                                         'is estimated.', ptype=_STRING)),
    ('alignment', 'straight', _desc('Track alignment (straight, curved_demo, ...). On one '
                                    'with curves, grade or cant the pulls toward a constant '
                                    'track attitude are switched off.', ptype=_STRING)),
    ('vehicle_path', '', _desc("Vehicle mount file (the IMU's boresight: imu_link in "
                               "base_link); '' = share/vlc_common/config/vehicle.yaml.",
                               ptype=_STRING)),
    ('nominal_rate_hz', _C.nominal_rate_hz, _desc('Expected IMU rate, Hz.', 1.0, 5000.0)),
    ('publish_decimation', 1, _desc('Publish imu/data for every N-th accepted sample.',
                                    1, 1000, integer=True)),
    ('gyro_noise_density_rps_rthz', _F.gyro_noise_density_rps_rthz,
     _desc('Gyro white-noise density (ARW), rad/s/sqrt(Hz).', 1e-7, 1e-1)),
    ('gyro_bias_random_walk_rps2_rthz', _F.gyro_bias_random_walk_rps2_rthz,
     _desc('Gyro bias random-walk density assumed by the filter, rad/s^2/sqrt(Hz).',
           0.0, 1e-2)),
    ('initial_gyro_bias_std_rps', _F.initial_gyro_bias_std_rps,
     _desc('1 sigma of the gyro bias at a cold start, rad/s.', 1e-7, 1.0)),
    ('gyro_scale_factor_std', _F.gyro_scale_factor_std,
     _desc('1 sigma of each gyro scale-factor error, estimated from the first attitude '
           'aiding on; 0 = not estimated.', 0.0, 0.2)),
    ('initial_attitude_std_rad', list(_F.initial_attitude_std_rad),
     _desc('1 sigma [roll, pitch, heading] at a cold start, rad.', ptype=_ARRAY)),
    ('aligned_attitude_std_rad', list(_F.aligned_attitude_std_rad),
     _desc('1 sigma [roll, pitch, heading] after a static alignment, rad.', ptype=_ARRAY)),
    ('tilt_time_constant_s', _F.tilt_time_constant_s,
     _desc('Time constant of the roll/pitch pull toward the track attitude, s; 0 = off.',
           0.0, 1e5)),
    ('heading_time_constant_s', _F.heading_time_constant_s,
     _desc('Time constant of the heading pull toward the track heading, s; 0 = off.',
           0.0, 1e5)),
    ('pull_window_s', _F.pull_window_s,
     _desc('Sliding window over which the pull innovations are averaged, s.', 0.01, 1e3)),
    ('pull_hold_s', _F.pull_hold_s,
     _desc('Moving time after departure before the pulls start, s.', 0.0, 1e3)),
    ('pull_min_sway_ratio', _F.pull_min_sway_ratio,
     _desc('Pulls act only while the sway RMS over the pull window is at least this '
           'fraction of the running sway level.', 0.0, 1.0)),
    ('pull_min_sway_rps', _F.pull_min_sway_rps,
     _desc('Absolute floor of the sway gate, rad/s.', 0.0, 10.0)),
    ('pull_pause_after_aiding_s', _F.pull_pause_after_aiding_s,
     _desc('A pull pauses this long after an aiding that sees its axis, s; 0 = never.',
           0.0, 600.0)),
    ('track_roll_rad', _F.track_roll_rad, _desc('Track cant (roll) in map, rad.', -0.5, 0.5)),
    ('track_pitch_rad', _F.track_pitch_rad,
     _desc('Track grade as pitch in map (nose down positive), rad.', -0.5, 0.5)),
    ('track_heading_rad', _F.track_heading_rad,
     _desc('Track direction (yaw) in map, rad.', -math.pi, math.pi)),
    ('heading_offset_rad', _F.heading_offset_rad,
     _desc('Known slow mean of the platform heading relative to the track at speed, rad.',
           -0.5, 0.5)),
    ('gravity_time_constant_s', _F.gravity_time_constant_s,
     _desc('Time constant of the optional gravity tilt reference, s; 0 = off.', 0.0, 1e5)),
    ('gravity_gate_mps2', _F.gravity_gate_mps2,
     _desc('Gravity updates skipped when | |f| - g | exceeds this, m/s^2.', 1e-3, 100.0)),
    ('update_period_s', _F.update_period_s,
     _desc('Period of the covariance propagation and of the updates, s.', 1e-3, 10.0)),
    ('zero_velocity_window_s', _Z.window_s,
     _desc('Window of the zero-velocity (standstill) test, s.', 0.01, 60.0)),
    ('zero_velocity_gyro_std_rps', _Z.gyro_std_threshold_rps,
     _desc('Standstill: every gyro axis std over the window below this, rad/s.', 1e-6, 1.0)),
    ('zero_velocity_accel_std_mps2', _Z.accel_std_threshold_mps2,
     _desc('Standstill: every accelerometer axis std over the window below this, m/s^2.',
           1e-5, 10.0)),
    ('zero_velocity_max_rate_rps', _Z.max_rate_rps,
     _desc('Standstill (once the bias is known): window mean rate within this of the bias '
           'on every axis, rad/s.', 1e-6, 1.0)),
    ('odometry_timeout_s', _O.timeout_s,
     _desc('train/odometry vetoes standstill only for IMU samples stamped within this of '
           'its newest usable message, s.', 1e-3, 60.0)),
    ('odometry_accel_window_s', _O.accel_window_s,
     _desc('The acceleration is the least-squares slope of the odometry speed over this '
           'much of its newest stamps, s.', 0.05, 60.0)),
    ('odometry_max_accel_mps2', _O.max_accel_mps2,
     _desc('Standstill is vetoed while that acceleration exceeds this in magnitude, '
           'm/s^2; 0 = off.', 0.0, 10.0)),
    ('odometry_max_speed_mps', _O.max_speed_mps,
     _desc('Standstill is vetoed while the odometry speed exceeds this, m/s; 0 = off.',
           0.0, 100.0)),
    ('odometry_max_speed_std_mps', _O.max_speed_std_mps,
     _desc('Odometry whose speed 1 sigma exceeds this carries no usable speed, m/s.',
           1e-4, 100.0)),
    ('gap_s', _C.gap_s, _desc('A step longer than this is a gap (warned, propagated), s.',
                              1e-4, 60.0)),
    ('backward_reset_s', _C.backward_reset_s,
     _desc('A stamp this much older than the newest resets the filter; less is dropped as '
           'out of order, s.', 1e-4, 1e6)),
    ('forward_jump_s', 1.0, _desc('A sample stamped more than this after the newest one is '
                                  'held as a possible outlier, s.', 0.0, 3600.0)),
    ('time_base_confirm_count', 3, _desc('Consecutive samples of a new time base (stamped '
                                         'beyond backward_reset_s before or forward_jump_s '
                                         'after the newest one) that confirm it; fewer are '
                                         'outliers, dropped.', 1, 1000, integer=True)),
    ('history_s', _C.history_s, _desc('Attitude history kept for delayed aiding, s.',
                                      0.1, 60.0)),
    ('aiding_gate_probability', _C.aiding_gate_probability,
     _desc('An aid is fused only when its squared Mahalanobis distance is within this '
           'chi-square quantile (3 dof attitude, 1 dof heading); 1 = no gate.', 0.5, 1.0)),
    ('aiding_max_correction_rad', _C.aiding_max_correction_rad,
     _desc('A consistent aid that would turn the attitude by more than this is applied as '
           'an attitude reset (no bias or scale correction through it), rad.', 1e-3, 3.2)),
    ('aiding_reinit_count', _C.aiding_reinit_count,
     _desc('This many consecutive inconsistent aids that agree re-initialise the attitude '
           'from them; 0 = never.', 0, 1000, integer=True)),
    ('orientation_std_floor_rad', [0.05 * DEG, 0.05 * DEG, 0.1 * DEG],
     _desc('1 sigma [roll, pitch, heading] added in quadrature to the published orientation '
           'covariance (errors the filter does not model), rad.', ptype=_ARRAY)),
    ('heading_aiding_std_rad', 1.0 * DEG,
     _desc('1 sigma of the heading of an attitude_aiding message without a usable '
           'covariance, rad.', 1e-6, 1.0)),
    ('poll_period_s', 0.01, _desc('imu/data_raw is taken in batches this often (steady '
                                   'clock), off the executor; 0 = a callback per sample, s.',
                                   0.0, 0.05)),
    ('diagnostics_period_s', 1.0, _desc('Wall-clock period of diagnostics, s.', 0.05, 60.0)),
    ('warn_throttle_s', 1.0, _desc('Minimum wall-clock interval between repeated warnings '
                                   'of one kind, s.', 0.0, 3600.0)),
)


@dataclass
class NodeConfig:
    """Every parameter of the node, read once at start-up."""

    imu_frame_id: str
    base_frame_id: str
    publish_decimation: int
    orientation_std_floor_rad: tuple
    heading_aiding_std_rad: float
    poll_period_s: float
    diagnostics_period_s: float
    warn_throttle_s: float
    forward_jump_s: float
    time_base_confirm_count: int
    compensator: CompensatorConfig
    pull_note: str = None        # why the pulls are off (alignment), None if not changed


def _triple(name, values, non_negative=False):
    out = tuple(float(v) for v in values)
    if len(out) != 3 or not all(math.isfinite(v) for v in out) \
            or (non_negative and min(out) < 0.0):
        raise ValueError(f'{name} must be 3 finite{" non-negative" if non_negative else ""} '
                         f'numbers, got {list(values)}')
    return out


def read_config(node):
    """Declare and read every parameter.

    Raises
    ------
    rclpy.exceptions.ParameterException
        A value has the wrong type or is outside its declared range.
    ValueError
        A value is inconsistent (wrong array length, empty frame id, ...).
    """
    for name, default, descriptor in NODE_PARAMETERS:
        node.declare_parameter(name, default, descriptor)
    v = {name: node.get_parameter(name).value for name, _, _ in NODE_PARAMETERS}
    for name in ('imu_frame_id', 'base_frame_id'):
        if not v[name]:
            raise ValueError(f'{name} must not be empty')
    filt = AttitudeFilterConfig(
        gyro_noise_density_rps_rthz=v['gyro_noise_density_rps_rthz'],
        gyro_bias_random_walk_rps2_rthz=v['gyro_bias_random_walk_rps2_rthz'],
        initial_gyro_bias_std_rps=v['initial_gyro_bias_std_rps'],
        gyro_scale_factor_std=v['gyro_scale_factor_std'],
        initial_attitude_std_rad=_triple('initial_attitude_std_rad',
                                         v['initial_attitude_std_rad']),
        aligned_attitude_std_rad=_triple('aligned_attitude_std_rad',
                                         v['aligned_attitude_std_rad']),
        tilt_time_constant_s=v['tilt_time_constant_s'],
        heading_time_constant_s=v['heading_time_constant_s'],
        pull_window_s=v['pull_window_s'], pull_hold_s=v['pull_hold_s'],
        pull_min_sway_ratio=v['pull_min_sway_ratio'], pull_min_sway_rps=v['pull_min_sway_rps'],
        pull_pause_after_aiding_s=v['pull_pause_after_aiding_s'],
        track_roll_rad=v['track_roll_rad'], track_pitch_rad=v['track_pitch_rad'],
        track_heading_rad=v['track_heading_rad'], heading_offset_rad=v['heading_offset_rad'],
        gravity_time_constant_s=v['gravity_time_constant_s'],
        gravity_gate_mps2=v['gravity_gate_mps2'], update_period_s=v['update_period_s'])
    filt, pull_note = pulls_on_alignment(filt, Alignment.named(v['alignment']))
    zv = ZeroVelocityConfig(window_s=v['zero_velocity_window_s'],
                            gyro_std_threshold_rps=v['zero_velocity_gyro_std_rps'],
                            accel_std_threshold_mps2=v['zero_velocity_accel_std_mps2'],
                            max_rate_rps=v['zero_velocity_max_rate_rps'])
    odo = OdometryVetoConfig(timeout_s=v['odometry_timeout_s'],
                             accel_window_s=v['odometry_accel_window_s'],
                             max_accel_mps2=v['odometry_max_accel_mps2'],
                             max_speed_mps=v['odometry_max_speed_mps'],
                             max_speed_std_mps=v['odometry_max_speed_std_mps'])
    comp = CompensatorConfig(filter=filt, zero_velocity=zv, odometry=odo,
                             nominal_rate_hz=v['nominal_rate_hz'], gap_s=v['gap_s'],
                             backward_reset_s=v['backward_reset_s'],
                             imu_mount_rpy_rad=tuple(
                                 float(a) for a in load_vehicle(v['vehicle_path']).imu.rpy_rad),
                             history_s=v['history_s'],
                             aiding_gate_probability=v['aiding_gate_probability'],
                             aiding_max_correction_rad=v['aiding_max_correction_rad'],
                             aiding_reinit_count=v['aiding_reinit_count'])
    return NodeConfig(
        imu_frame_id=v['imu_frame_id'], base_frame_id=v['base_frame_id'],
        publish_decimation=v['publish_decimation'],
        orientation_std_floor_rad=_triple('orientation_std_floor_rad',
                                          v['orientation_std_floor_rad'], non_negative=True),
        heading_aiding_std_rad=v['heading_aiding_std_rad'],
        poll_period_s=v['poll_period_s'], diagnostics_period_s=v['diagnostics_period_s'],
        warn_throttle_s=v['warn_throttle_s'], forward_jump_s=v['forward_jump_s'],
        time_base_confirm_count=v['time_base_confirm_count'], compensator=comp,
        pull_note=pull_note)


class ImuCompensatorNode(Node):
    """Raw IMU in, attitude out; see the module docstring."""

    def __init__(self, **kwargs):
        super().__init__('imu_compensator_node', **kwargs)
        self.config = cfg = read_config(self)
        self.compensator = AttitudeCompensator(cfg.compensator)
        fc = cfg.compensator.filter
        self._floor_var = np.square(cfg.orientation_std_floor_rad)
        self._gyro_white_var = (fc.gyro_noise_density_rps_rthz ** 2
                                * cfg.compensator.nominal_rate_hz)
        mount = cfg.compensator.imu_mount_rpy_rad
        self._r_base_imu = quat_to_matrix(quat_from_rpy(*mount)) if any(mount) else None
        self._out = Imu()
        self._out.header.frame_id = cfg.base_frame_id
        self._accepted_since_publish = 0
        self._frame_warned = False
        self._warnings = ThrottledWarnings(self.get_logger(), cfg.warn_throttle_s)
        self._last_stamp = None
        self._guard = StampGuard.from_seconds(cfg.compensator.backward_reset_s,
                                              cfg.forward_jump_s, cfg.time_base_confirm_count)
        self._diag_count = 0
        self._diag_t0 = None
        self._diag_stats = None

        self._pub = self.create_publisher(Imu, 'imu/data', qos_profile_sensor_data)
        self._diag_pub = self.create_publisher(DiagnosticArray, 'diagnostics', 10)
        if cfg.poll_period_s > 0.0:
            # 400 Hz: taken in batches, one executor wake-up per batch (vlc_common.polled)
            self._raw = PolledSubscription(self, Imu, 'imu/data_raw', IMU_QOS)
            self.create_timer(cfg.poll_period_s, self._on_poll,
                              clock=Clock(clock_type=ClockType.STEADY_TIME))
        else:
            self.create_subscription(Imu, 'imu/data_raw', self._on_imu, IMU_QOS)
        self.create_subscription(PoseWithCovarianceStamped, 'attitude_aiding',
                                 self._on_attitude_aiding, 10)
        self.create_subscription(Odometry, 'train/odometry', self._on_odometry, 10)
        self.create_timer(cfg.diagnostics_period_s, self._publish_diagnostics)
        self.get_logger().info(
            f'attitude of {cfg.base_frame_id} from {self.resolve_topic_name("imu/data_raw")} at '
            f'{cfg.compensator.nominal_rate_hz:g} Hz nominal; heading tau '
            f'{fc.heading_time_constant_s:g} s, tilt tau {fc.tilt_time_constant_s:g} s, '
            f'track heading {fc.track_heading_rad / DEG:.3f} deg + offset '
            f'{fc.heading_offset_rad / DEG:.3f} deg at speed')
        if cfg.pull_note:
            self.get_logger().info(cfg.pull_note)

    # ------------------------------------------------------------------ callbacks
    def _on_poll(self):
        for msg in self._raw.take_all():
            self._on_imu(msg)

    def _on_imu(self, msg):
        """Pass the sample's stamp through the guard; process what it releases."""
        result = self._guard.push(stamp_to_ns(msg.header.stamp), msg)
        if result.dropped:
            self._warnings.warn('stamp_outlier', lambda: f'{len(result.dropped)} IMU sample(s) '
                                'stamped far from the stream (beyond backward_reset_s before or '
                                'forward_jump_s after the newest) dropped')
        if result.rebased:
            self._warnings.warn('time_base', lambda: f'IMU stamps moved by '
                                f'{result.rebased * 1e-9:+.3f} s for '
                                f'{len(result.released)} samples in a row: new time base')
        for _, sample in result.released:
            self._process(sample)

    def _process(self, msg):
        cfg = self.config
        if not self._frame_warned and msg.header.frame_id != cfg.imu_frame_id:
            self._frame_warned = True
            self.get_logger().warn(f'imu/data_raw frame_id {msg.header.frame_id!r}, expected '
                                   f'{cfg.imu_frame_id!r}: treating it as {cfg.imu_frame_id}')
        t_s, gyro, accel = imu_sample(msg)
        result = self.compensator.process(t_s, gyro, accel)
        status = result.status
        if not status.accepted:
            self._warn_skipped(result)
            return
        if status is SampleStatus.GAP:
            self._warnings.warn('gap', lambda: f'IMU gap of {result.dt_s * 1e3:.1f} ms before '
                                f't = {t_s:.6f} s: attitude propagated across it')
        elif status is SampleStatus.RESET:
            self._warnings.warn('reset', lambda: f'IMU time jumped back by {-result.dt_s:.3f} s '
                                f'to t = {t_s:.6f} s: attitude filter reset')
        self._last_stamp = msg.header.stamp
        self._diag_count += 1
        self._accepted_since_publish += 1
        if self._accepted_since_publish < cfg.publish_decimation \
                and status is SampleStatus.OK:
            return
        self._accepted_since_publish = 0
        comp = self.compensator
        fill_imu_data(self._out, msg.header, result, self._floor_var, self._gyro_white_var,
                      np.square(comp.gyro_bias_std_rps), msg.angular_velocity_covariance,
                      msg.linear_acceleration_covariance, self._r_base_imu)
        self._pub.publish(self._out)

    def _warn_skipped(self, result):
        status = result.status
        if status is SampleStatus.NONFINITE:
            self._warnings.warn('nonfinite', 'non-finite IMU sample skipped')
        elif status is SampleStatus.DUPLICATE:
            self._warnings.warn('duplicate',
                                lambda: f'duplicate IMU stamp t = {result.t_s:.6f} s skipped')
        else:
            self._warnings.warn('out_of_order', lambda: f'out-of-order IMU sample '
                                f'({result.dt_s * 1e3:.1f} ms before the newest) skipped')

    def _on_odometry(self, msg):
        try:
            t_s, speed, var = odometry_speed(msg)
            status = self.compensator.odometry(t_s, speed, var)
        except (TypeError, ValueError, OverflowError) as exc:   # never stop the node
            status, t_s = f'invalid ({exc})', float('nan')
        if status == OdometryVeto.OUT_OF_ORDER:
            self._warnings.warn('odometry_order', lambda: f'train/odometry at t = {t_s:.6f} s '
                                'not newer than the newest: ignored')
        elif status not in (OdometryVeto.USED, OdometryVeto.UNCERTAIN):
            self._warnings.warn('odometry_invalid', 'train/odometry with a non-finite stamp '
                                'or speed ignored')

    def _on_attitude_aiding(self, msg):
        result, t_s = fuse_aiding(self.compensator, msg, self.config.heading_aiding_std_rad)
        status = result.status
        if status is AidingStatus.INCONSISTENT:
            self._warnings.warn('aiding_inconsistent', lambda: (
                f'attitude aiding at t = {t_s:.6f} s rejected: inconsistent with the estimate '
                f'(Mahalanobis d2 {result.d2:.1f} > {result.gate_d2:.1f}, {result.dof} dof; '
                f'innovation {math.degrees(result.innovation_rad):.2f} deg)'))
        elif status is AidingStatus.REINITIALISED:
            self.get_logger().warn(
                f'attitude re-initialised from the aid at t = {t_s:.6f} s: '
                f'{self.config.compensator.aiding_reinit_count} consecutive aids agreed on a '
                f'correction the estimate excluded (innovation '
                f'{math.degrees(result.innovation_rad):.2f} deg)')
        elif status is AidingStatus.RESET:
            self._warnings.warn('aiding_reset', lambda: (
                f'attitude aiding at t = {t_s:.6f} s applied as an attitude reset: '
                f'correction {math.degrees(result.correction_rad):.2f} deg, too large to '
                'linearise'))
        elif not status.applied:
            why = ('outside the attitude history' if status is AidingStatus.OUTSIDE_HISTORY
                   else 'not finite or covariance not positive definite')
            self._warnings.warn('aiding_rejected', lambda: f'attitude aiding at t = {t_s:.6f} s '
                                f'rejected ({why})')

    # ------------------------------------------------------------------ diagnostics
    def _publish_diagnostics(self):
        comp = self.compensator
        stats = comp.stats
        status = DiagnosticStatus(name=f'{self.get_name()}: attitude',
                                  hardware_id=self.config.imu_frame_id)
        now_t = comp.last_t_s
        rate = float('nan')
        if self._diag_t0 is not None and now_t is not None and now_t > self._diag_t0:
            rate = self._diag_count / (now_t - self._diag_t0)
        prev = self._diag_stats
        dropped = stats.dropped + self._guard.stats.outliers
        new_problems = prev is not None and (dropped > prev[0] or stats.gaps > prev[1]
                                              or stats.resets > prev[2])
        new_inconsistent = prev is not None and stats.aiding_inconsistent > prev[3]
        # an inconsistency a more pressing message hid this period is said in the next one
        reported_inconsistent = prev[3] if new_inconsistent else stats.aiding_inconsistent
        if now_t is None:
            status.level, status.message = DiagnosticStatus.WARN, 'no IMU sample yet'
        # events (bad input, a rejected aid) before the state "no sample this period",
        # which the next period says again: an event is said once or lost
        elif new_problems:
            status.level = DiagnosticStatus.WARN
            status.message = 'bad IMU input this period (dropped, gap or reset)'
        elif new_inconsistent:
            status.level = DiagnosticStatus.WARN
            status.message = 'attitude aiding inconsistent with the estimate this period'
            reported_inconsistent = stats.aiding_inconsistent
        elif self._diag_count == 0:
            status.level, status.message = DiagnosticStatus.WARN, 'no IMU sample this period'
        else:
            status.level, status.message = DiagnosticStatus.OK, 'tracking'
        bias = comp.gyro_bias_rps
        bias_std = comp.gyro_bias_std_rps
        rpy = comp.filter.rpy_rad
        values = {
            'gyro_bias_deg_h': ' '.join(f'{b / DEG * 3600.0:.2f}' for b in bias),
            'gyro_bias_std_deg_h': ' '.join(f'{b / DEG * 3600.0:.2f}' for b in bias_std),
            'zero_velocity': str(comp.stationary).lower(),
            'stationary_samples': str(stats.stationary_samples),
            'standstill_vetoed': str(stats.standstill_vetoed),
            'odometry_used': str(stats.odometry_used),
            'odometry_rejected': str(stats.odometry_rejected),
            'odometry_accel_mps2': f'{comp.odometry_veto.acceleration_mps2:.3f}',
            'sample_rate_hz': f'{rate:.1f}',
            'samples_accepted': str(stats.accepted),
            'samples_dropped': str(dropped),
            'dropped_stamp_outliers': str(self._guard.stats.outliers),
            'time_base_changes': str(self._guard.stats.rebases),
            'dropped_nonfinite': str(stats.nonfinite),
            'dropped_duplicate': str(stats.duplicate),
            'dropped_out_of_order': str(stats.out_of_order),
            'gaps': str(stats.gaps),
            'resets': str(stats.resets),
            'attitude_aiding_used': str(stats.aiding_used),
            'attitude_aiding_rejected': str(stats.aiding_rejected),
            'attitude_aiding_inconsistent': str(stats.aiding_inconsistent),
            'attitude_aiding_resets': str(stats.aiding_resets),
            'attitude_aiding_reinitialisations': str(stats.aiding_reinitialisations),
            'rpy_deg': ' '.join(f'{a / DEG:.3f}' for a in rpy),
            'heading_std_deg': f'{math.sqrt(comp.filter.attitude_covariance[2, 2]) / DEG:.4f}',
        }
        status.values = [KeyValue(key=k, value=v) for k, v in values.items()]
        msg = DiagnosticArray(status=[status])
        # Stamped with the newest sample's time, like everything else this node publishes.
        if self._last_stamp is not None:
            msg.header.stamp = self._last_stamp
        self._diag_pub.publish(msg)
        self._diag_t0 = now_t
        self._diag_count = 0
        self._diag_stats = (dropped, stats.gaps, stats.resets, reported_inconsistent)


def main(args=None):
    return run_node(ImuCompensatorNode, 'imu_compensator_node', args)


if __name__ == '__main__':
    sys.exit(main())
