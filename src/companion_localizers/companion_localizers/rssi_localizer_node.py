"""``rssi_localizer_node``: train position by VLC + RSSI trilateration (companion method 1).

Subscribes (relative names):

* ``photodiode/rssi`` (sensor_msgs/PointCloud2; reliable, depth 10): per-lamp received
  power from ``photodiode_node`` (fields ``uid``, ``power_w``, ``power_sigma_w``);
* ``imu/data`` (sensor_msgs/Imu; ``qos_profile_sensor_data``): platform attitude, which
  turns the photodiode's mount and normal (``use_imu_attitude``).

Publishes:

* ``companion/rssi/pose`` (geometry_msgs/PoseStamped; reliable, depth 10): ``base_link``
  in ``map_frame_id``, one per photodiode sample with an accepted trilateration,
  stamped with the sample's stamp; orientation = imu/data attitude (identity without);
* ``diagnostics`` (diagnostic_msgs/DiagnosticArray; reliable, depth 10) every
  ``diagnostics_period_s`` (steady clock): counts per outcome, last solution, CPU time
  per sample.

A sample waits (at most ``attitude_wait_s`` of receive time) until ``imu/data`` covers
its stamp; then it is solved with the attitude extrapolated up to 50 ms, or with the
identity and the vibration's attitude uncertainty (warned). The roll and pitch of
``imu/data`` are fused with the level track's (``tilt_prior_sigma_deg``,
:mod:`companion_localizers.core.attitude_prior`). The train speed for the
integration-window correction is the difference of the last two accepted fixes. Bad input
(unknown UID, NaN power, missing
fields, out-of-order stamps) is skipped with a throttled warning. Parameters:
``config/rssi_localizer_node.yaml``; the channel keys (``pd_*``, ``lamp_*``) must equal
``photodiode_node``'s. Core: :mod:`companion_localizers.core.rssi`.
"""
from collections import deque
import math
import sys

from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import PoseStamped
import numpy as np
from rclpy.clock import Clock, ClockType
from rclpy.node import Node
from rclpy.qos import qos_profile_sensor_data
from sensor_msgs.msg import Imu, PointCloud2

from companion_localizers import conversions
from companion_localizers.core.attitude_prior import fuse_tilt
from companion_localizers.core.rssi import SOLVE_MODES, RssiConfig, trilaterate
from imu_compensator.core.attitude_buffer import AttitudeBuffer
from vlc_common.core.lamp_map import LampMap, resolve_lamp_map_path
from vlc_common.core.rotations import quat_to_matrix
from vlc_common.core.vehicle import load_vehicle
from vlc_common.parameters import descriptor as _desc
from vlc_common.photodiode_channel import declare_channel_parameters, photodiode_config
from vlc_common.process import run_node
from vlc_common.throttled_log import ThrottledWarnings

NS_PER_S = 1_000_000_000
#: Level values of diagnostic_msgs/DiagnosticStatus.
OK, WARN = 0, 1

# name, default, descriptor — documented key by key in config/rssi_localizer_node.yaml
PARAMETERS = (
    ('map_frame_id', 'map', _desc('Frame of the published poses.')),
    ('lamp_map_path', '', _desc("Lamp map YAML; '' = vlc_common's default map.")),
    ('vehicle_path', '', _desc("Vehicle mount file (the photodiode's position and normal); "
                               "'' = share/vlc_common/config/vehicle.yaml.")),
    ('track_offset_y_m', 0.0, _desc('Nominal lateral position of base_link in map, m.',
                                    -10.0, 10.0)),
    ('track_offset_z_m', 0.0, _desc('Nominal height of base_link in map, m.', -10.0, 10.0)),
    ('track_sigma_y_m', 0.004, _desc('1-sigma lateral offset of base_link from the track, m.',
                                     0.0, 1.0)),
    ('track_sigma_z_m', 0.004, _desc('1-sigma vertical offset of base_link from the track, m.',
                                     0.0, 1.0)),
    ('solve_mode', 'auto', _desc('auto (3-D when the lamps are not collinear, else along '
                                 'the track), track, or free (3-D; collinear lamps rejected).')),
    ('min_lamps', 2, _desc('Fewest lamps for a track-constrained solve.', 2, 100,
                           integer=True)),
    ('collinear_tolerance_m', 0.05, _desc('RMS distance from a line below which lamps count '
                                          'as collinear, m.', 0.0, 100.0)),
    ('max_sigma_m', 0.5, _desc('Solutions with a larger along-track 1-sigma are rejected, m.',
                               1e-4, 1e3)),
    ('chi2_probability', 0.999, _desc('Residual chi2 quantile above which a solution is '
                                      'rejected as inconsistent.', 0.5, 0.999999)),
    ('window_s', 0.02, _desc('Integration window of one photodiode sample (1 / its rate), s; '
                             '0 = point samples.', 0.0, 1.0)),
    ('use_imu_attitude', True, _desc('Turn the photodiode mount and normal with the imu/data '
                                     'attitude; false = identity.')),
    ('attitude_sigma_deg', [0.06, 0.06, 0.11], _desc('Attitude 1-sigma about map x, y, z when '
                                                     'imu/data carries no covariance, deg.')),
    ('attitude_sigma_unknown_deg', [0.3, 0.3, 4.0], _desc('Attitude 1-sigma without an '
                                                          'attitude (the platform vibration '
                                                          'about the track), deg.')),
    ('tilt_prior_sigma_deg', [0.3, 0.3], _desc('Roll and pitch 1-sigma of the platform about '
                                               'the level track, fused with imu/data\'s; '
                                               '[0, 0] = off, deg.')),
    ('attitude_wait_s', 1.0, _desc('Longest wait (receive time) for imu/data to cover a '
                                   'sample, s.', 0.0, 10.0)),
    ('speed_max_age_s', 0.2, _desc('The speed from the last two fixes is used while they are '
                                   'at most this far apart, s.', 0.0, 10.0)),
    ('diagnostics_period_s', 1.0, _desc('Diagnostics period (steady clock), s.', 0.1, 60.0)),
    ('warn_throttle_s', 2.0, _desc('Minimum interval between two warnings of one kind, s.',
                                   0.0, 600.0)),
)


class RssiLocalizerNode(Node):
    """ROS wrapper of :func:`~companion_localizers.core.rssi.trilaterate`."""

    def __init__(self, **kwargs):
        super().__init__('rssi_localizer_node', **kwargs)
        channel = declare_channel_parameters(self)
        for name, default, descriptor in PARAMETERS:
            self.declare_parameter(name, default, descriptor)
        p = {name: self.get_parameter(name).value for name, _, _ in PARAMETERS}
        self.params = p
        if p['solve_mode'] not in SOLVE_MODES:
            raise ValueError(f'solve_mode must be one of {SOLVE_MODES}, got {p["solve_mode"]!r}')
        for name, size in (('attitude_sigma_deg', 3), ('attitude_sigma_unknown_deg', 3),
                           ('tilt_prior_sigma_deg', 2)):
            if len(p[name]) != size:
                raise ValueError(f'{name} needs {size} values, got {list(p[name])}')
        self._tilt_prior = tuple(math.radians(v) for v in p['tilt_prior_sigma_deg'])
        self._unknown_cov = np.diag(np.square(np.radians(p['attitude_sigma_unknown_deg'])))
        self.config = RssiConfig(
            photodiode=photodiode_config(channel, load_vehicle(p['vehicle_path']).photodiode),
            track_offset_yz_m=(p['track_offset_y_m'], p['track_offset_z_m']),
            track_sigma_yz_m=(p['track_sigma_y_m'], p['track_sigma_z_m']),
            solve_mode=p['solve_mode'], min_lamps=p['min_lamps'],
            collinear_tolerance_m=p['collinear_tolerance_m'], max_sigma_m=p['max_sigma_m'],
            chi2_probability=p['chi2_probability'], window_s=p['window_s'],
            attitude_sigma_rad=tuple(math.radians(v) for v in p['attitude_sigma_deg']))
        path = resolve_lamp_map_path(p['lamp_map_path'])
        self.lamp_map = LampMap.load(path)
        self.attitude = AttitudeBuffer(horizon_s=2.0, max_gap_s=0.1, max_extrapolation_s=0.05)
        self._steady = Clock(clock_type=ClockType.STEADY_TIME)
        self._pending = deque()          # (stamp_ns, records, received_s)
        self._last_stamp_ns = None
        self._fixes = deque(maxlen=2)    # (stamp_ns, chainage_m) of the last accepted fixes
        self._outcomes = {}
        self._counts = {'samples': 0, 'poses_published': 0, 'unknown_uid': 0,
                        'bad_records': 0, 'out_of_order': 0, 'no_attitude': 0}
        self._last_fix = None
        self._timer = conversions.CpuTimer()
        self._warnings = ThrottledWarnings(self.get_logger(), self.params['warn_throttle_s'],
                                           clock=self._now_s)

        self.pub_pose = self.create_publisher(PoseStamped, 'companion/rssi/pose', 10)
        self.pub_diag = self.create_publisher(DiagnosticArray, 'diagnostics', 10)
        self.create_subscription(PointCloud2, 'photodiode/rssi', self._on_rssi, 10)
        if p['use_imu_attitude']:
            self.create_subscription(Imu, 'imu/data', self._on_imu, qos_profile_sensor_data)
        self.create_timer(0.02, self._drain, clock=self._steady)
        self.create_timer(p['diagnostics_period_s'], self._publish_diagnostics,
                          clock=self._steady)
        self.get_logger().info(
            f'lamp map {path} ({len(self.lamp_map)} lamps); solve {p["solve_mode"]}, FOV '
            f'{self.config.photodiode.fov_half_angle_deg:g} deg, IMU attitude '
            f'{p["use_imu_attitude"]}')

    # ------------------------------------------------------------------ inputs
    def _on_imu(self, msg):
        sample = conversions.imu_from_msg(msg)
        if sample.quat_xyzw is not None and sample.is_finite():
            q, cov = fuse_tilt(sample.quat_xyzw, sample.attitude_cov_rad2, self._tilt_prior,
                               self.config.attitude_sigma_rad[:2])
            self.attitude.push(sample.stamp_ns / NS_PER_S, q, cov)

    def _on_rssi(self, msg):
        stamp_ns = conversions.stamp_to_ns(msg.header.stamp)
        try:
            records = conversions.cloud_to_records(msg)
            conversions.require_fields(records, conversions.RSSI_FIELDS, 'photodiode/rssi')
        except ValueError as exc:
            self._warn('bad_cloud', f'photodiode/rssi message skipped: {exc}')
            self._counts['bad_records'] += 1
            return
        newest = self._pending[-1][0] if self._pending else self._last_stamp_ns
        if newest is not None and stamp_ns <= newest:
            self._counts['out_of_order'] += 1
            self._warn('order', f'photodiode/rssi stamp {stamp_ns} not after {newest}: skipped')
            return
        self._pending.append((stamp_ns, records, self._now_s()))
        self._drain()

    def _drain(self):
        now = self._now_s()
        while self._pending:
            stamp_ns, records, received = self._pending[0]
            covered = (not self.params['use_imu_attitude']
                       or (self.attitude.newest_s is not None
                           and self.attitude.newest_s >= stamp_ns / NS_PER_S))
            if not covered and now - received < self.params['attitude_wait_s']:
                return
            self._pending.popleft()
            self._process(stamp_ns, records)

    def _process(self, stamp_ns, records):
        with self._timer:
            self._counts['samples'] += 1
            self._last_stamp_ns = stamp_ns
            readings, unknown = conversions.rssi_readings(records, self.lamp_map)
            if unknown:
                self._counts['unknown_uid'] += len(unknown)
                self._warn('unknown_uid', f'photodiode/rssi: UIDs not in the lamp map skipped: '
                           f'{", ".join(f"{u:#06x}" for u in unknown)}')
            bad = records.size - len(readings) - len(unknown)
            if bad:
                self._counts['bad_records'] += bad
                self._warn('bad_power', f'photodiode/rssi: {bad} record(s) with a non-finite '
                           'or non-positive power skipped')
            q, cov = None, None
            if self.params['use_imu_attitude']:
                q = self.attitude.at(stamp_ns / NS_PER_S)
                if q is None:
                    self._counts['no_attitude'] += 1
                    self._warn('attitude', 'no imu/data attitude at a photodiode sample: '
                               'solved with the identity')
                    cov = self._unknown_cov
                else:
                    cov = self.attitude.covariance_at(stamp_ns / NS_PER_S)
            else:
                cov = self._unknown_cov
            R = quat_to_matrix(q) if q is not None else quat_to_matrix([0.0, 0.0, 0.0, 1.0])
            speed = self._speed(stamp_ns)
            fix = trilaterate(readings, R, self.config, speed, cov,
                              predicted_chainage_m=self._predict(stamp_ns, speed))
            self._outcomes[fix.reason] = self._outcomes.get(fix.reason, 0) + 1
            self._last_fix = fix
            if not fix.ok:
                return
            self._fixes.append((stamp_ns, float(fix.position_m[0])))
            self.pub_pose.publish(conversions.pose_stamped(
                stamp_ns, fix.position_m, q if q is not None else (0.0, 0.0, 0.0, 1.0),
                self.params['map_frame_id']))
            self._counts['poses_published'] += 1

    def _predict(self, stamp_ns, speed_mps):
        """The last fix moved on by the speed: the solver's first start (or None)."""
        if not self._fixes:
            return None
        t, s = self._fixes[-1]
        return s + speed_mps * (stamp_ns - t) / NS_PER_S

    def _speed(self, stamp_ns):
        """Along-track speed from the last two accepted fixes (0 when too old)."""
        if len(self._fixes) < 2:
            return 0.0
        (t0, s0), (t1, s1) = self._fixes
        max_age = self.params['speed_max_age_s'] * NS_PER_S
        if stamp_ns - t0 > 2 * max_age or t1 - t0 > max_age or t1 <= t0:
            return 0.0
        return (s1 - s0) / ((t1 - t0) / NS_PER_S)

    # ------------------------------------------------------------------ outputs
    def _warn(self, code, message):
        self._warnings.warn(code, message)

    def _now_s(self):
        return self._steady.now().nanoseconds * 1e-9

    def _publish_diagnostics(self):
        values = dict(self._counts)
        values.update({f'outcome_{k}': v for k, v in sorted(self._outcomes.items())})
        fix = self._last_fix
        level, message = OK, 'trilaterating'
        if fix is not None:
            values['last_mode'] = fix.mode
            values['last_reason'] = fix.reason
            values['last_lamps_used'] = fix.lamps_used
            if fix.ok:
                values['last_chainage_m'] = f'{fix.position_m[0]:.3f}'
                values['last_sigma_m'] = f'{fix.chainage_sigma_m:.4f}'
            else:
                level, message = WARN, f'last sample not solved: {fix.reason}'
        else:
            level, message = WARN, 'waiting for photodiode/rssi'
        values.update(self._timer.summary('processing_ms'))
        if self._counts['poses_published']:
            values['cpu_ms_per_pose'] = (
                f'{1e3 * self._timer.total_s / self._counts["poses_published"]:.3f}')
        msg = DiagnosticArray()
        msg.header.stamp = self.get_clock().now().to_msg()
        msg.status = [conversions.diagnostic_status(f'{self.get_name()}: rssi',
                                                    'companion_localizers', level, message,
                                                    values)]
        self.pub_diag.publish(msg)


def main(args=None):
    return run_node(RssiLocalizerNode, 'rssi_localizer_node', args)


if __name__ == '__main__':
    sys.exit(main())
