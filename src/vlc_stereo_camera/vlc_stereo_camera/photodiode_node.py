"""photodiode_node: the train-head photodiode receiving each lamp's power (VLC + RSSI).

Rides the same trajectory and vibration as ``stereo_camera_node`` and ``adis16488_node``
(the shared scenario parameters of :mod:`vlc_stereo_camera.rig_params`) past the same
lamp map, and estimates every lamp's received optical power through the Lambertian
line-of-sight channel with shot and thermal noise (:mod:`.core.photodiode`).

Publications
------------
``photodiode/rssi`` (sensor_msgs/PointCloud2, reliable, depth 10)
    One point per lamp received (SNR ≥ ``min_snr_db``) in sample n, stamped
    epoch + n / ``rate_hz`` exactly: the centre of the sample's integration window
    (1 / ``rate_hz`` long). Fields (little endian, point_step 24): ``uid`` uint32,
    ``snr_db`` float32 (dB), ``power_w`` float64 (W, estimated received "on" power),
    ``power_sigma_w`` float64 (W, 1σ of the estimate's noise). ``frame_id`` =
    ``frame_id`` (the PD; the records are not points in space).
``diagnostics`` (diagnostic_msgs/DiagnosticArray, reliable, depth 10)
    1 Hz (steady clock): samples published, lamps in the last sample, simulated time.

Time: with ``follow_clock`` (default) the node subscribes to ``/clock`` (published by
``stereo_camera_node``) and publishes every sample whose window has ended by the clock's
simulated time, so the PD never runs ahead of the camera's simulated time and needs no
wall-clock pacing of its own; samples before the first tick received are skipped. With
``follow_clock`` false it paces itself at ``realtime_factor`` × real time from its
start (``wait_for_subscribers`` N > 0: from when ``photodiode/rssi`` has N
subscribers), like ``adis16488_node``. ``duration_s`` > 0: samples with t < duration_s
are published, then the node exits 0. Invalid parameters: ``[FATAL] invalid
parameter: …`` and exit code 2. Parameters: ``config/photodiode_node.yaml`` and the
shared ``config/rig.yaml``.

Sensor faults (shared rig parameters, :mod:`.core.sensor_faults`): of them only
``sensor_clock_jumps_s`` [at_s, jump_s, ...] acts on the photodiode: samples with
t ≥ at_s are stamped Σ jump_s later (the sensor host's clock stepped; cumulative,
negative = back); their content and release are unchanged. Default: none.
"""
from dataclasses import dataclass
import math
import sys
import time

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
import numpy as np
from rcl_interfaces.msg import ParameterType
from rclpy.clock import Clock, ClockType
from rclpy.node import Node
from rclpy.task import Future
from rosgraph_msgs.msg import Clock as ClockMsg
from sensor_msgs.msg import PointCloud2
from std_msgs.msg import Header

from vlc_common.core.lamp_map import LampMap, resolve_lamp_map_path
from vlc_common.core.optical_channel import PhotodiodeConfig
from vlc_common.core.records import RSSI_DTYPE
from vlc_common.parameters import descriptor as _desc
from vlc_common.photodiode_channel import declare_channel_parameters, photodiode_config
from vlc_common.pointcloud import records_to_cloud
from vlc_common.process import run_node, spin_until_finished
from vlc_common.stamps import epoch_to_ns, ns_to_stamp, sample_stamp_ns, stamp_to_ns
from vlc_stereo_camera.core.photodiode import Photodiode
from vlc_stereo_camera.rig_params import ScenarioConfig, declare_scenario_parameters

#: Timer period of the self-paced mode, s (wall clock).
PACE_PERIOD_S = 0.005

_STR = ParameterType.PARAMETER_STRING
_ARRAY = ParameterType.PARAMETER_DOUBLE_ARRAY
_PD = PhotodiodeConfig()

#: Noise and node parameters of the PD itself.
NODE_PARAMETERS = (
    ('rate_hz', 50.0, _desc('Sample rate, Hz; each sample integrates 1/rate_hz.', 1.0, 1000.0)),
    ('follow_clock', True, _desc('Publish the samples whose window the /clock has passed '
                                 '(simulated time of stereo_camera_node); false = pace '
                                 'on the wall clock with realtime_factor.')),
    ('realtime_factor', 1.0, _desc('follow_clock false: simulated seconds per wall second; '
                                   '0 = as fast as possible.', 0.0, 100.0)),
    ('duration_s', 0.0, _desc('Simulated duration, s; 0 = forever. Samples with t < '
                              'duration_s are published, then the node exits 0.', 0.0, 1.0e7)),
    ('wait_for_subscribers', 0, _desc('follow_clock false: hold simulated time at 0 until '
                                      'photodiode/rssi has this many subscribers.', 0, 100,
                                      integer=True)),
    ('frame_id', 'photodiode_link', _desc('frame_id of the published records.', ptype=_STR)),
    ('lamp_map_path', '', _desc("Lamp map YAML; '' = share/vlc_common/config/"
                                'lamp_map.yaml.', ptype=_STR)),
    ('subsamples', 5, _desc('Instants averaged over one integration window.', 1, 100,
                            integer=True)),
    ('noise_bandwidth_hz', _PD.noise_bandwidth_hz, _desc('Noise bandwidth of one per-lamp '
                                                         'power estimate, Hz (half the rate: '
                                                         'one window).', 1e-3, 1e9)),
    ('background_current_a', _PD.background_current_a, _desc('Background photocurrent '
                                                             '(tunnel lighting), A.',
                                                             0.0, 1.0)),
    ('temperature_k', _PD.temperature_k, _desc('Receiver temperature, K.', 1.0, 500.0)),
    ('open_loop_gain', _PD.open_loop_gain, _desc('Pre-amplifier open-loop voltage gain.',
                                                 1.0, 1e6)),
    ('fet_transconductance_s', _PD.fet_transconductance_s, _desc('FET transconductance, S.',
                                                                 1e-6, 10.0)),
    ('fet_noise_factor', _PD.fet_noise_factor, _desc('FET channel noise factor.', 0.0, 10.0)),
    ('capacitance_per_area_f_m2', _PD.capacitance_per_area_f_m2,
     _desc('PD fixed capacitance per unit area, F/m^2 (112 pF/cm^2 = 1.12e-6).', 1e-9, 1e-3)),
    ('noise_factor_i2', _PD.noise_factor_i2, _desc('Noise bandwidth factor I2.', 0.0, 10.0)),
    ('noise_factor_i3', _PD.noise_factor_i3, _desc('Noise bandwidth factor I3.', 0.0, 10.0)),
    ('min_snr_db', _PD.min_snr_db, _desc('Lamps with a lower estimate SNR are not reported, '
                                         'dB.', -50.0, 200.0)),
)


@dataclass
class PhotodiodeNodeConfig:
    """Every parameter of the node, read once at start-up."""

    rate_hz: float
    follow_clock: bool
    realtime_factor: float
    duration_s: float
    wait_for_subscribers: int
    frame_id: str
    lamp_map_path: str
    subsamples: int
    photodiode: PhotodiodeConfig
    scenario: ScenarioConfig


def read_config(node):
    """Declare and read every parameter; raises ParameterException or ValueError."""
    channel = declare_channel_parameters(node)
    for name, default, descriptor in NODE_PARAMETERS:
        node.declare_parameter(name, default, descriptor)
    v = {name: node.get_parameter(name).value for name, _, _ in NODE_PARAMETERS}
    scenario = declare_scenario_parameters(node)
    if not v['frame_id']:
        raise ValueError('frame_id must not be empty')
    noise = {k: v[k] for k in ('noise_bandwidth_hz', 'background_current_a', 'temperature_k',
                               'open_loop_gain', 'fet_transconductance_s', 'fet_noise_factor',
                               'capacitance_per_area_f_m2', 'noise_factor_i2',
                               'noise_factor_i3', 'min_snr_db')}
    return PhotodiodeNodeConfig(
        rate_hz=v['rate_hz'], follow_clock=v['follow_clock'],
        realtime_factor=v['realtime_factor'], duration_s=v['duration_s'],
        wait_for_subscribers=v['wait_for_subscribers'], frame_id=v['frame_id'],
        lamp_map_path=v['lamp_map_path'], subsamples=v['subsamples'],
        photodiode=photodiode_config(channel, scenario.vehicle().photodiode, **noise),
        scenario=scenario)


def sample_records(sample):
    """PhotodiodeSample → structured array of :data:`RSSI_DTYPE`."""
    rec = np.zeros(sample.uid.size, dtype=RSSI_DTYPE)
    rec['uid'] = sample.uid
    rec['snr_db'] = sample.snr_db
    rec['power_w'] = sample.power_w
    rec['power_sigma_w'] = sample.power_sigma_w
    return rec


class PhotodiodeNode(Node):
    """Publishes the per-lamp received power; see the module docstring."""

    def __init__(self, **kwargs):
        super().__init__('photodiode_node', **kwargs)
        self.config = cfg = read_config(self)
        lamp_map = LampMap.load(resolve_lamp_map_path(cfg.lamp_map_path))
        self._pd = Photodiode(cfg.photodiode, lamp_map, cfg.scenario.trajectory(),
                              seed=cfg.scenario.seed, subsamples=cfg.subsamples)
        self._epoch_ns = epoch_to_ns(cfg.scenario.epoch_s)
        self._faults = cfg.scenario.sensor_faults()
        self._next_index = None          # next sample to publish; None until time starts
        self._end_index = (math.ceil(cfg.duration_s * cfg.rate_hz - 1e-9)
                           if cfg.duration_s > 0.0 else None)
        self._wall_start = None
        self._published = 0
        self._last_lamps = 0
        self._last_stamp_ns = self._epoch_ns
        #: Done (result: the exit code) once duration_s has been published.
        self.finished = Future()

        self._pub = self.create_publisher(PointCloud2, 'photodiode/rssi', 10)
        self._diag_pub = self.create_publisher(DiagnosticArray, 'diagnostics', 10)
        if cfg.follow_clock:
            self.create_subscription(ClockMsg, '/clock', self._on_clock, 10)
        else:
            period = PACE_PERIOD_S if cfg.realtime_factor > 0.0 else 0.001
            self._timer = self.create_timer(period, self._on_pace,
                                            clock=Clock(clock_type=ClockType.STEADY_TIME))
        self.create_timer(1.0, self._publish_diagnostics,
                          clock=Clock(clock_type=ClockType.STEADY_TIME))
        self.get_logger().info(
            f'photodiode at {cfg.rate_hz:g} Hz on {self._pub.topic_name}, '
            f'{len(lamp_map)} lamps, FOV {cfg.photodiode.fov_half_angle_deg:g} deg, '
            f'{"following /clock" if cfg.follow_clock else "self-paced"}, '
            f'seed {cfg.scenario.seed}, motion {cfg.scenario.motion_profile}')

    def _window_end_s(self, index):
        return (index + 0.5) / self.config.rate_hz

    def _on_clock(self, msg):
        t_s = (stamp_to_ns(msg.clock) - self._epoch_ns) / 1e9
        if self._next_index is None:
            # First tick: samples stamped before it are not published.
            self._next_index = max(0, math.ceil(t_s * self.config.rate_hz - 1e-9))
        self._publish_until(t_s)

    def _on_pace(self):
        cfg = self.config
        if self._next_index is None:
            if self._pub.get_subscription_count() < cfg.wait_for_subscribers:
                return
            self._next_index = 0
            self._wall_start = time.monotonic()
        if cfg.realtime_factor == 0.0:
            # As fast as possible: a tenth of a simulated second per tick.
            self._publish_until(self._window_end_s(self._next_index) + 0.1)
        else:
            self._publish_until((time.monotonic() - self._wall_start) * cfg.realtime_factor)

    def _publish_until(self, t_s):
        """Publish every sample whose window ends by simulated time ``t_s``."""
        cfg = self.config
        while self._window_end_s(self._next_index) <= t_s + 1e-9:
            if self._end_index is not None and self._next_index >= self._end_index:
                if not self.finished.done():
                    self.get_logger().info(f'duration_s reached: {self._published} samples '
                                           'published')
                    self.finished.set_result(0)
                return
            n = self._next_index
            sample = self._pd.sample(n, cfg.rate_hz)
            stamp_ns = sample_stamp_ns(self._epoch_ns, n, cfg.rate_hz)
            stamp_ns = self._faults.sensor_stamp_ns(stamp_ns, stamp_ns - self._epoch_ns)
            header = Header(stamp=ns_to_stamp(stamp_ns), frame_id=cfg.frame_id)
            self._pub.publish(records_to_cloud(sample_records(sample), header))
            self._published += 1
            self._last_lamps = int(sample.uid.size)
            self._last_stamp_ns = stamp_ns
            self._next_index += 1

    def _publish_diagnostics(self):
        cfg = self.config
        status = DiagnosticStatus(name=f'{self.get_name()}: photodiode',
                                  hardware_id='photodiode (simulated)')
        waiting = self._next_index is None
        status.level = DiagnosticStatus.OK
        status.message = ('waiting for /clock' if waiting and cfg.follow_clock
                          else 'waiting for subscribers' if waiting else 'publishing')
        sim_s = (self._last_stamp_ns - self._epoch_ns) / 1e9
        values = {'rate_hz': f'{cfg.rate_hz:g}', 'samples_published': str(self._published),
                  'lamps_in_last_sample': str(self._last_lamps), 'sim_time_s': f'{sim_s:.3f}',
                  'seed': str(cfg.scenario.seed)}
        status.values = [KeyValue(key=k, value=v) for k, v in values.items()]
        msg = DiagnosticArray(status=[status])
        msg.header.stamp = ns_to_stamp(self._last_stamp_ns)
        self._diag_pub.publish(msg)


def main(args=None):
    return run_node(PhotodiodeNode, 'photodiode_node', args, spin=spin_until_finished)


if __name__ == '__main__':
    sys.exit(main())
