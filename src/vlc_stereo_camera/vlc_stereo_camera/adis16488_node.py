"""adis16488_node: the simulated ADIS16488 IMU on the train head.

Follows the same trajectory and vibration as ``stereo_camera_node`` (the shared scenario
parameters of :mod:`vlc_stereo_camera.rig_params`) and adds the datasheet errors of
:mod:`vlc_stereo_camera.core.imu_model`.

Publications
------------
``imu/data_raw`` (sensor_msgs/Imu, ``qos_profile_sensor_data``)
    Sample n stamped exactly epoch + n / rate_hz (sensor faults aside, below); angular
    rate (rad/s) and specific force (m/s², +9.81 on z at rest) in ``imu_frame_id`` (axes
    of base_link); covariance diagonals = white-noise variance per sample; orientation
    absent (``orientation_covariance[0] = -1``). With ``imu_burst_s`` the history depth
    is raised to a burst's size.
``diagnostics`` (diagnostic_msgs/DiagnosticArray, reliable, depth 10)
    1 Hz (wall clock) status: samples published, simulated time, lag behind the pacing
    target, current bias.

Time: with ``follow_clock`` (default) the node publishes, at every ``/clock`` tick of
``stereo_camera_node``, every sample whose stamp the tick has reached and none beyond: the
rig has one simulated clock, the camera's, and the IMU never runs ahead of the images,
slows down and stalls with the camera and catches up in a burst after a stall of its
own. With ``follow_clock`` false samples are paced to the wall clock by
``realtime_factor`` (0 = as fast as possible), a batch per timer tick. With
``duration_s`` > 0 the node publishes every sample with t < duration_s and exits 0; with
``wait_for_subscribers`` N > 0 simulated time starts only when ``imu/data_raw`` has N
subscribers. Invalid parameters fail at start-up with a message and exit code 2 (as
``stereo_camera_node``). Parameters: ``config/adis16488_node.yaml`` and the shared
``config/rig.yaml``.

Sensor faults (shared rig parameters, :mod:`.core.sensor_faults`; every default off, and
off the node publishes exactly as without them). They act on publication only: every
sample is computed (the bias processes run on) whether it is published or not, and the
release follows the sample's *true* time t = n / rate_hz.

* ``imu_dropouts_s`` [start_s, duration_s, ...]: samples with start_s ≤ t <
  start_s + duration_s are not published (lost, not delayed).
* ``imu_burst_s`` B > 0: samples are held and published back to back, each with its own
  stamp, at the burst boundaries k·B: the burst at k·B holds the samples of
  [(k−1)·B, k·B). Following ``/clock`` a burst leaves at the first tick at or after its
  boundary (several at once after a stall of the camera); self-paced, when the node's
  simulated time reaches the boundary. With ``duration_s`` the samples still held at the
  end leave as a last, shorter burst. The publisher keeps a history as deep as a burst,
  so the node itself never drops a sample of one; a subscriber whose (best-effort) queue
  is shorter than a burst can still lose its oldest samples in DDS.
* ``imu_stamp_offset_s`` d: every stamp is d later (IMU clock offset); the release still
  waits for ``/clock`` to reach the true time.
* ``sensor_clock_jumps_s`` [at_s, jump_s, ...]: samples with t ≥ at_s are stamped
  Σ jump_s later (the sensor host's clock stepped, cumulative, negative = back).

Published stamp = epoch + t + Σ_{at_s ≤ t} jump_s + d. Diagnostics then also report
``samples_dropped`` (by a dropout window) and ``samples_held`` (waiting for a burst).
"""
from collections import deque
from dataclasses import dataclass
import math
import sys
import time

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
import numpy as np
from rcl_interfaces.msg import ParameterType
from rclpy.node import Node
from rclpy.qos import QoSProfile, qos_profile_sensor_data
from rclpy.task import Future
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import Imu

from vlc_common.parameters import descriptor as _desc
from vlc_common.process import run_node, spin_until_finished
from vlc_common.stamps import epoch_to_ns, ns_to_stamp, sample_stamp_ns, stamp_to_ns
from vlc_stereo_camera.core.imu_model import (
    DEG,
    GRAVITY_MPS2,
    MAX_RATE_HZ,
    Adis16488Model,
    Adis16488Params,
    ImuSampler,
)
from vlc_stereo_camera.imu_conversions import imu_message, set_imu_sample
from vlc_stereo_camera.rig_params import ScenarioConfig, declare_scenario_parameters

#: Samples are generated in blocks of this much simulated time and published from the
#: block as they fall due (one trajectory evaluation per block instead of per tick); it
#: is also the most one tick publishes when catching up or running as fast as possible.
BLOCK_S = 0.1
#: Timer period of the as-fast-as-possible mode (realtime_factor = 0), seconds.
ASAP_PERIOD_S = 0.001
#: Lag behind the pacing target above which diagnostics report WARN, seconds.
LAG_WARN_S = 0.5


_ARRAY = ParameterType.PARAMETER_DOUBLE_ARRAY
_DEFAULT = Adis16488Params()

#: (name, default, descriptor) of the node's own parameters; see config/adis16488_node.yaml.
NODE_PARAMETERS = (
    ('rate_hz', 400.0, _desc('Output data rate, Hz (ADIS16488: up to 2460).', 1.0, MAX_RATE_HZ)),
    ('realtime_factor', 1.0, _desc('Simulated seconds per wall-clock second; 0 = as fast '
                                   'as possible.', 0.0, 100.0)),
    ('publish_period_s', 0.01, _desc('Wall-clock period of the publishing timer, s; each '
                                     'tick publishes the samples due.', 0.001, 0.1)),
    ('duration_s', 0.0, _desc('Simulated duration, s; 0 = forever. Samples with t < '
                              'duration_s are published, then the node exits 0.', 0.0, 1.0e7)),
    ('wait_for_subscribers', 0, _desc('Hold simulated time at 0 until imu/data_raw has this '
                                      'many subscribers (0 = start at once).', 0, 100,
                                      integer=True)),
    ('follow_clock', True, _desc('Publish every sample whose stamp the /clock (the '
                                 "camera's simulated time) has reached, and no other: the "
                                 'IMU never runs ahead of the camera and slows with it. '
                                 'false: pace on the wall clock at realtime_factor.')),
    ('imu_frame_id', 'imu_link', _desc('frame_id of the messages (axes of base_link).',
                                       ptype=ParameterType.PARAMETER_STRING)),
    ('noise_enabled', True, _desc('false: publish the true rate and specific force '
                                  '(every error term off).')),
    ('gyro_arw_deg_rthr', 0.26, _desc('Gyro angle random walk, deg/sqrt(h).', 0.0, 100.0)),
    ('gyro_bias_instability_deg_hr', 5.1, _desc('Gyro in-run bias stability (Allan '
                                                'floor), deg/h.', 0.0, 1000.0)),
    ('gyro_bias_corr_times_s', list(_DEFAULT.gyro_bias_corr_times_s),
     _desc('Correlation times of the gyro Gauss-Markov bias bank, s.', ptype=_ARRAY)),
    ('gyro_turn_on_bias_dps', 0.2, _desc('1 sigma of the constant gyro turn-on bias, '
                                         'deg/s.', 0.0, 10.0)),
    ('gyro_scale_factor_sigma', 0.01, _desc('1 sigma gyro scale-factor error (0.01 = 1 %).',
                                            0.0, 0.2)),
    ('gyro_misalignment_deg', 0.05, _desc('1 sigma gyro axis-to-axis misalignment, deg.',
                                          0.0, 5.0)),
    ('gyro_range_dps', 450.0, _desc('Gyro dynamic range (outputs clipped), deg/s.',
                                    1.0, 10000.0)),
    ('accel_vrw_mps_rthr', 0.029, _desc('Accelerometer velocity random walk, m/s/sqrt(h).',
                                        0.0, 10.0)),
    ('accel_bias_instability_mg', 0.1, _desc('Accelerometer in-run bias stability (Allan '
                                             'floor), mg.', 0.0, 100.0)),
    ('accel_bias_corr_times_s', list(_DEFAULT.accel_bias_corr_times_s),
     _desc('Correlation times of the accelerometer Gauss-Markov bias bank, s.', ptype=_ARRAY)),
    ('accel_turn_on_bias_mg', 16.0, _desc('1 sigma of the constant accelerometer turn-on '
                                          'bias, mg.', 0.0, 1000.0)),
    ('accel_scale_factor_sigma', 0.005, _desc('1 sigma accelerometer scale-factor error.',
                                              0.0, 0.2)),
    ('accel_misalignment_deg', 0.035, _desc('1 sigma accelerometer axis-to-axis '
                                            'misalignment, deg.', 0.0, 5.0)),
    ('accel_range_g', 18.0, _desc('Accelerometer dynamic range (outputs clipped), g.',
                                  0.1, 1000.0)),
)


@dataclass
class Adis16488NodeConfig:
    """Every parameter of the node, read once at start-up (SI units except where named)."""

    rate_hz: float
    realtime_factor: float
    publish_period_s: float
    duration_s: float
    wait_for_subscribers: int
    follow_clock: bool
    imu_frame_id: str
    noise_enabled: bool
    imu: Adis16488Params
    scenario: ScenarioConfig


def read_config(node):
    """Declare and read the node's and the scenario's parameters.

    Raises
    ------
    rclpy.exceptions.ParameterException
        A value has the wrong type or is out of its declared range.
    ValueError
        A value is inconsistent (bad correlation times, an unusable vehicle file, ...).
    """
    for name, default, descriptor in NODE_PARAMETERS:
        node.declare_parameter(name, default, descriptor)
    v = {name: node.get_parameter(name).value for name, _, _ in NODE_PARAMETERS}
    scenario = declare_scenario_parameters(node)
    if not v['imu_frame_id']:
        raise ValueError('imu_frame_id must not be empty')
    imu = Adis16488Params.from_datasheet_units(
        gyro_arw_deg_rthr=v['gyro_arw_deg_rthr'],
        gyro_bias_instability_deg_hr=v['gyro_bias_instability_deg_hr'],
        accel_vrw_mps_rthr=v['accel_vrw_mps_rthr'],
        accel_bias_instability_mg=v['accel_bias_instability_mg'],
        gyro_bias_corr_times_s=v['gyro_bias_corr_times_s'],
        accel_bias_corr_times_s=v['accel_bias_corr_times_s'],
        gyro_turn_on_bias_sigma_dps=v['gyro_turn_on_bias_dps'],
        accel_turn_on_bias_sigma_mg=v['accel_turn_on_bias_mg'],
        gyro_scale_factor_sigma=v['gyro_scale_factor_sigma'],
        accel_scale_factor_sigma=v['accel_scale_factor_sigma'],
        gyro_misalignment_sigma_deg=v['gyro_misalignment_deg'],
        accel_misalignment_sigma_deg=v['accel_misalignment_deg'],
        gyro_range_dps=v['gyro_range_dps'], accel_range_g=v['accel_range_g'])
    if not v['noise_enabled']:
        imu = imu.ideal()
    return Adis16488NodeConfig(
        rate_hz=v['rate_hz'], realtime_factor=v['realtime_factor'],
        publish_period_s=v['publish_period_s'], duration_s=v['duration_s'],
        wait_for_subscribers=v['wait_for_subscribers'], follow_clock=v['follow_clock'],
        imu_frame_id=v['imu_frame_id'],
        noise_enabled=v['noise_enabled'], imu=imu, scenario=scenario)


class Adis16488Node(Node):
    """Publishes the simulated IMU; see the module docstring."""

    def __init__(self, **kwargs):
        super().__init__('adis16488_node', **kwargs)
        self.config = cfg = read_config(self)
        model = Adis16488Model(cfg.rate_hz, cfg.scenario.seed, cfg.imu)
        mount = cfg.scenario.vehicle().imu
        # The mount's lever arm adds w x (w x r) + dw/dt x r to the specific force; its
        # boresight rotates both signals into the IMU's axes.
        self._sampler = ImuSampler(cfg.scenario.trajectory(), model, mount.position_m,
                                   mount.R_base_imu if np.any(mount.rpy_rad) else None)
        self._epoch_ns = epoch_to_ns(cfg.scenario.epoch_s)
        self._faults = cfg.scenario.sensor_faults()
        self._held = deque()        # (release_ns, stamp_ns, omega, f) waiting for a burst
        self._dropped = 0
        # One message refilled per sample: frame and covariances never change.
        self._msg = imu_message(self._epoch_ns, cfg.imu_frame_id, (0.0, 0.0, 0.0),
                                (0.0, 0.0, 0.0), model.gyro_white_variance,
                                model.accel_white_variance)
        self._block = max(1, math.ceil(cfg.rate_hz * BLOCK_S))
        self._buffer = None          # ImuBatch generated ahead, published from _buffer_pos
        self._buffer_pos = 0
        self._next_index = 0         # next sample to publish
        # Samples 0 .. end_index-1 (t < duration_s) are published; None = endless.
        self._end_index = (math.ceil(cfg.duration_s * cfg.rate_hz - 1e-9)
                           if cfg.duration_s > 0.0 else None)
        #: Done (result: the exit code) once duration_s has been published.
        self.finished = Future()
        self._published = 0
        self._skipped = 0
        self._lag_s = 0.0
        self._last_stamp_ns = None
        self._wall_start = None

        qos = qos_profile_sensor_data
        burst_samples = self._faults.imu_burst_samples(cfg.rate_hz)
        if burst_samples > qos.depth:
            # a history as deep as a burst: the node never overwrites a sample of a burst
            # before the middleware has sent it
            qos = QoSProfile(history=qos.history, depth=burst_samples,
                             reliability=qos.reliability, durability=qos.durability)
        self._imu_pub = self.create_publisher(Imu, 'imu/data_raw', qos)
        self._diag_pub = self.create_publisher(DiagnosticArray, 'diagnostics', 10)
        self._clock_ns = None       # newest /clock received (follow_clock)
        if cfg.follow_clock:
            self._clock_sub = self.create_subscription(Clock, '/clock', self._on_clock, 100)
            self._timer = None
        else:
            period = cfg.publish_period_s if cfg.realtime_factor > 0.0 else ASAP_PERIOD_S
            self._timer = self.create_timer(period, self._on_tick)
        self._diag_timer = self.create_timer(1.0, self._publish_diagnostics)
        self.get_logger().info(
            f'ADIS16488 at {cfg.rate_hz:g} Hz on {self._imu_pub.topic_name}, frame '
            f'{cfg.imu_frame_id}, seed {cfg.scenario.seed}, motion '
            f'{cfg.scenario.motion_profile}, realtime factor {cfg.realtime_factor:g}, '
            f'errors {"on" if cfg.noise_enabled else "off"}')
        if cfg.scenario.rig_profile != 'ideal':
            self.get_logger().info(
                f'rig_profile {cfg.scenario.rig_profile}, installation seed '
                f'{cfg.scenario.drawn_seed}: the drawn installation (IMU lever arm '
                f'{np.round(mount.position_m, 4).tolist()} m, '
                f'boresight {np.round(np.degrees(mount.rpy_rad), 3).tolist()} deg, clock '
                f'offset {cfg.scenario.imu_clock_offset_s() * 1e3:+.3f} ms and drift '
                f'{cfg.scenario.imu_clock_drift_ppm():+.2f} ppm in the stamps)')
        if self._faults.imu_faults:
            self.get_logger().warn(f'sensor faults: {self._faults.describe()}')

    def _due_count(self):
        """Samples to publish this tick and the pacing lag in simulated seconds."""
        cfg = self.config
        if cfg.follow_clock:
            if self._clock_ns is None:
                return 0, 0.0
            # every sample n with epoch + n / rate <= clock
            due = (self._clock_ns - self._epoch_ns) * cfg.rate_hz // 1_000_000_000 + 1
            while due > 0 and sample_stamp_ns(self._epoch_ns, due - 1, cfg.rate_hz) \
                    > self._clock_ns:
                due -= 1
            due = int(due)
            if self._end_index is not None:
                due = min(due, self._end_index)
            return max(due - self._next_index, 0), 0.0
        if cfg.realtime_factor == 0.0:
            if (self._next_index == 0 and self._imu_pub.get_subscription_count()
                    < cfg.wait_for_subscribers):
                return 0, 0.0
            due = self._next_index + self._block
        else:
            now = time.monotonic()
            if self._wall_start is None:
                if cfg.follow_clock:
                    return 0, 0.0
                if self._imu_pub.get_subscription_count() < cfg.wait_for_subscribers:
                    return 0, 0.0
                self._wall_start = now
            due = math.floor((now - self._wall_start) * cfg.realtime_factor * cfg.rate_hz) + 1
        if self._end_index is not None:
            due = min(due, self._end_index)
        behind = due - self._next_index
        count = min(max(behind, 0), self._block)
        return count, (behind - count) / cfg.rate_hz

    def _on_clock(self, msg):
        """A /clock tick: publish every sample up to it (in order, at once)."""
        clock_ns = stamp_to_ns(msg.clock)
        if self._clock_ns is None:
            self.get_logger().info(f'following /clock from simulated time '
                                   f'{(clock_ns - self._epoch_ns) * 1e-9:.3f} s')
        elif clock_ns < self._clock_ns:
            return          # a tick overtaken by a newer one: nothing new is due
        self._clock_ns = clock_ns
        self._on_tick()

    def _on_tick(self):
        count, self._lag_s = self._due_count()
        while count > 0:
            if self._buffer is None or self._buffer_pos == len(self._buffer.index):
                self._buffer = self._generate_block()
                self._buffer_pos = 0
            take = min(count, len(self._buffer.index) - self._buffer_pos)
            self._publish_rows(self._buffer, self._buffer_pos, take)
            self._buffer_pos += take
            self._next_index += take
            count -= take
        if self._faults.imu_burst_ns:
            self._release_bursts()
        if self._end_index is not None and self._next_index >= self._end_index \
                and not self.finished.done():
            while self._held:           # the last, shorter burst
                self._publish_sample(*self._held.popleft()[1:])
            if self._timer is not None:
                self._timer.cancel()
            self.get_logger().info(f'duration_s reached: {self._published} samples published')
            self.finished.set_result(0)

    def _generate_block(self):
        batch = self._sampler.next(self._block)
        if not np.all(batch.valid):
            bad = int(np.count_nonzero(~batch.valid))
            self._skipped += bad
            self.get_logger().warn(f'non-finite truth from the trajectory: skipping {bad} '
                                   f'samples from n = {int(batch.index[0])}',
                                   throttle_duration_sec=1.0)
        return batch

    def _publish_rows(self, batch, start, count):
        rate_hz = self.config.rate_hz
        rows = slice(start, start + count)
        omega, f = batch.omega[rows].tolist(), batch.f[rows].tolist()
        valid = batch.valid[rows].tolist()
        faults = self._faults if self._faults.imu_faults else None
        for i, n in enumerate(batch.index[rows].tolist()):
            if not valid[i]:
                continue
            stamp_ns = sample_stamp_ns(self._epoch_ns, n, rate_hz)
            if faults is not None:
                t_ns = stamp_ns - self._epoch_ns          # the sample's true time
                if faults.imu_dropped(t_ns):
                    self._dropped += 1
                    continue
                stamp_ns = faults.imu_stamp_ns(stamp_ns, t_ns)
                if faults.imu_burst_ns:
                    self._held.append((faults.imu_release_ns(t_ns), stamp_ns, omega[i], f[i]))
                    continue
            self._publish_sample(stamp_ns, omega[i], f[i])

    def _publish_sample(self, stamp_ns, omega, f):
        self._imu_pub.publish(set_imu_sample(self._msg, stamp_ns, omega, f))
        self._last_stamp_ns = stamp_ns
        self._published += 1

    def _release_bursts(self):
        """Publish, back to back, every held sample whose burst boundary has been reached:
        by the /clock (follow_clock), else by the newest sample generated.
        """
        if self.config.follow_clock:
            if self._clock_ns is None:
                return
            now_ns = self._clock_ns - self._epoch_ns
        elif self._next_index > 0:
            now_ns = sample_stamp_ns(self._epoch_ns, self._next_index - 1,
                                     self.config.rate_hz) - self._epoch_ns
        else:
            return
        held = self._held
        while held and held[0][0] <= now_ns:
            self._publish_sample(*held.popleft()[1:])

    def _publish_diagnostics(self):
        cfg = self.config
        model = self._sampler.model
        status = DiagnosticStatus(name=f'{self.get_name()}: IMU',
                                  hardware_id='ADIS16488 (simulated)')
        if self._lag_s > LAG_WARN_S:
            status.level = DiagnosticStatus.WARN
            status.message = f'{self._lag_s:.2f} s behind the real-time pacing target'
        else:
            status.level = DiagnosticStatus.OK
            status.message = 'publishing'
        bias = model.last_bias
        values = {
            'rate_hz': f'{cfg.rate_hz:g}',
            'samples_published': str(self._published),
            'samples_skipped': str(self._skipped),
            'sim_time_s': f'{self._next_index / cfg.rate_hz:.3f}',
            'lag_s': f'{self._lag_s:.3f}',
            'realtime_factor': f'{cfg.realtime_factor:g}',
            'seed': str(cfg.scenario.seed),
            'gyro_bias_dps': ' '.join(f'{b / DEG:.5f}' for b in bias[:3]),
            'accel_bias_mg': ' '.join(f'{b / GRAVITY_MPS2 * 1e3:.3f}' for b in bias[3:]),
        }
        if self._faults.imu_faults:
            values['samples_dropped'] = str(self._dropped)
            values['samples_held'] = str(len(self._held))
        status.values = [KeyValue(key=k, value=v) for k, v in values.items()]
        msg = DiagnosticArray(status=[status])
        # Stamped on the simulated clock, like the samples it reports on.
        msg.header.stamp = ns_to_stamp(self._last_stamp_ns if self._last_stamp_ns is not None
                                      else self._epoch_ns)
        self._diag_pub.publish(msg)


def main(args=None):
    return run_node(Adis16488Node, 'adis16488_node', args, spin=spin_until_finished)


if __name__ == '__main__':
    sys.exit(main())
