"""``fault_injector_node``: feeds the running graph malformed messages on its real topics.

The project's rule for bad input is that a node gives a clear error or a logged,
throttled warning and skips the message; it never crashes on one, and one bad message
does not destroy its good state (a lone 1970-stamped image or IMU sample is dropped and
counted, it does not reset a pairing, a filter or a history). This node checks the rule
on a live graph: it publishes, beside the real publishers, one kind of defect after the
other (round robin over ``kinds``) at ``rate_hz``, from ``start_s`` after its clock first
ran for ``duration_s``; then it idles, or exits 0 with ``exit_when_done``.

Time: the node clock. With ``use_sim_time`` true (a graph with the rig's or a bag's
``/clock``) the rate, start and duration are simulated time counted from the first
``/clock``; without it, wall time from the start of the node.

Kinds (:mod:`vlc_evaluation.fault_kinds`, where each message is built; one line per kind
is logged at start):

* images, a left and right pair on ``stereo/{left,right}/image_raw``: encodings
  ``rgb8`` with mono8-sized data, ``bayer_rggb8``, ``nonsense``; width, height or step
  not matching the data; truncated data; an empty 0x0 image; a consistent image whose
  size is not camera_info's; valid black images stamped 1970 (sec 0, sec 1) or
  ``future_offset_s`` ahead;
* ``stereo/{left,right}/camera_info`` (transient local like the camera's, so a
  subscriber that joins later gets the bad one): K and P all zero, NaN in P, a size
  that is not the images';
* ``imu/data_raw`` and ``imu/data``: NaN or inf angular velocity, linear acceleration
  or orientation, a zero quaternion, a sample stamped 1970 or ``future_offset_s`` ahead,
  the newest real sample sent again (duplicate stamp);
* ``spots/pairs`` and ``vlc/lamps``: an empty cloud (valid fields), FLOAT32 fields
  declared FLOAT64, a missing field, a point_step short of the fields, data shorter than
  width·height·point_step, ``is_bigendian`` true with little-endian data, NaN values, a
  plausible record stamped 1970 or ``future_offset_s`` ahead.

A message of another type on a topic name is not a kind: DDS does not match a
publisher and a subscriber that disagree on the type, so it never reaches a node.

The injector takes the newest real camera_info and IMU messages (polled, off the
executor, at each injection) as templates, so each message carries only its named
defect, and it stamps content defects just after the newest real frame or sample. It
ignores its own messages when it reads the topics (by their stamps).

Publishes ``diagnostics`` (diagnostic_msgs/DiagnosticArray, every
``diagnostics_period_s`` of steady time): the state (waiting, injecting, done) and the
number of injections of each kind. Parameters: ``config/fault_injector_node.yaml``.
"""
from collections import Counter, deque
import math
import sys

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rcl_interfaces.msg import ParameterType
from rclpy.clock import Clock, ClockType
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy, qos_profile_sensor_data
from rclpy.task import Future
from sensor_msgs.msg import CameraInfo, Image, Imu, PointCloud2

from vlc_common.camera_info import camera_info_problem
from vlc_common.parameters import descriptor as _desc
from vlc_common.polled import PolledSubscription
from vlc_common.process import run_node, spin_until_finished
from vlc_common.stamps import NS_PER_S, stamp_to_ns
from vlc_evaluation import fault_kinds

_STR_ARRAY = ParameterType.PARAMETER_STRING_ARRAY

#: (name, default, descriptor); documented key by key in config/fault_injector_node.yaml
PARAMETERS = (
    ('kinds', list(fault_kinds.ALL_KINDS),
     _desc('Kinds of malformed message injected, round robin (default: all).',
           ptype=_STR_ARRAY)),
    ('rate_hz', 5.0, _desc('Injections per second of node-clock time, Hz.', 0.01, 1000.0)),
    ('start_s', 1.0, _desc('Node-clock time after the first tick before the first '
                           'injection, s.', 0.0, 1e6)),
    ('duration_s', 0.0, _desc('Node-clock time of injecting; then idle or exit; 0 = no '
                              'end, s.', 0.0, 1e9)),
    ('exit_when_done', False, _desc('Exit with code 0 once duration_s is over.')),
    ('future_offset_s', 365.0 * 86400.0, _desc('How far after the node clock a future stamp '
                                               'lies, s.', 1.0, 1e10)),
    ('image_width', 1280, _desc('Image width until a real camera_info told it, px.',
                                2, 100000, integer=True)),
    ('image_height', 720, _desc('Image height until a real camera_info told it, px.',
                                2, 100000, integer=True)),
    ('diagnostics_period_s', 1.0, _desc('Diagnostics period (steady clock), s.',
                                        0.05, 3600.0)),
)

_LATCHED = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                      durability=DurabilityPolicy.TRANSIENT_LOCAL)
_IMAGES = QoSProfile(depth=5, reliability=ReliabilityPolicy.RELIABLE)
# reliable: matches the best-effort IMU subscribers and any reliable one (a recorder)
_RELIABLE_10 = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)
_PUBLISHERS = {
    'left_image': (Image, _IMAGES), 'right_image': (Image, _IMAGES),
    'left_info': (CameraInfo, _LATCHED), 'right_info': (CameraInfo, _LATCHED),
    'imu_raw': (Imu, _RELIABLE_10), 'imu': (Imu, _RELIABLE_10),
    'pairs': (PointCloud2, _RELIABLE_10), 'lamps': (PointCloud2, _RELIABLE_10),
}


class FaultInjectorNode(Node):
    """See the module docstring."""

    def __init__(self, **kwargs):
        super().__init__('fault_injector_node', **kwargs)
        for name, default, descriptor in PARAMETERS:
            self.declare_parameter(name, default, descriptor)
        p = {name: self.get_parameter(name).value for name, _, _ in PARAMETERS}
        unknown = [k for k in p['kinds'] if k not in fault_kinds.KINDS]
        if unknown or not p['kinds']:
            raise ValueError(f'unknown kinds {unknown} (known: '
                             f'{", ".join(fault_kinds.ALL_KINDS)})' if unknown
                             else 'kinds is empty')
        self.params = p
        self.kinds = list(p['kinds'])
        self.finished = Future()
        self.counts = Counter()
        self.messages = 0
        self._next = 0
        self._t0_ns = None
        self._state = 'waiting'
        self._own = {key: deque(maxlen=256) for key in _PUBLISHERS}
        self._templates = fault_kinds.Templates(
            now_ns=0, future_offset_ns=int(round(p['future_offset_s'] * NS_PER_S)),
            width=p['image_width'], height=p['image_height'])

        self._pubs = {key: self.create_publisher(msg_type, fault_kinds.TOPICS[key], qos)
                      for key, (msg_type, qos) in _PUBLISHERS.items()}
        self._info_subs = [PolledSubscription(self, CameraInfo, fault_kinds.TOPICS[key],
                                              _LATCHED) for key in ('left_info', 'right_info')]
        self._imu_subs = {key: PolledSubscription(self, Imu, fault_kinds.TOPICS[key],
                                                  qos_profile_sensor_data)
                          for key in ('imu_raw', 'imu')}
        self._pub_diag = self.create_publisher(DiagnosticArray, 'diagnostics', 10)
        self._timer = self.create_timer(1.0 / p['rate_hz'], self._tick)
        self.create_timer(p['diagnostics_period_s'], self._publish_diagnostics,
                          clock=Clock(clock_type=ClockType.STEADY_TIME))
        log = self.get_logger()
        end = f'for {p["duration_s"]:g} s' if p['duration_s'] > 0 else 'until stopped'
        log.info(f'{len(self.kinds)} kinds at {p["rate_hz"]:g} Hz from {p["start_s"]:g} s '
                 f'{end} ({"simulated" if self._sim_time() else "wall"} time)')
        for kind in self.kinds:
            info = fault_kinds.KINDS[kind]
            topics = ', '.join(fault_kinds.TOPICS[k] for k in fault_kinds.topics_of(kind))
            log.info(f'kind {kind}: {info["text"]} -> {topics}')

    def _sim_time(self):
        return bool(self.get_parameter('use_sim_time').value)

    # ------------------------------------------------------------------ templates
    def _refresh_templates(self):
        """The newest real camera_info and IMU messages (not the injector's own)."""
        t = self._templates
        for side, (key, sub) in enumerate(zip(('left_info', 'right_info'), self._info_subs)):
            for msg in sub.take_all():
                if self._usable(key, msg) and camera_info_problem(msg) is None:
                    t.infos[side] = msg
        for key, sub in self._imu_subs.items():
            for msg in sub.take_all():
                a, w = msg.linear_acceleration, msg.angular_velocity
                if self._usable(key, msg) and all(
                        math.isfinite(v) for v in (a.x, a.y, a.z, w.x, w.y, w.z)):
                    t.imu[key] = msg

    def _usable(self, key, msg):
        """A real message (not one of the injector's own, not stamped in 1970) is the
        newest template, in arrival order (a looped bag's stamps go back).
        """
        stamp = stamp_to_ns(msg.header.stamp)
        return stamp not in self._own[key] and stamp >= NS_PER_S

    # ------------------------------------------------------------------ injection
    def _tick(self):
        now_ns = self.get_clock().now().nanoseconds
        if now_ns <= 0 or self.finished.done():
            return                      # simulated time before the first /clock
        if self._t0_ns is None:
            self._t0_ns = now_ns
        elapsed_s = (now_ns - self._t0_ns) * 1e-9
        p = self.params
        if elapsed_s < p['start_s']:
            return
        if p['duration_s'] > 0.0 and elapsed_s >= p['start_s'] + p['duration_s']:
            self._done()
            return
        if self._state == 'waiting':
            self._state = 'injecting'
            self.get_logger().info('injecting')
        self._templates.now_ns = now_ns
        self._refresh_templates()
        kind = self.kinds[self._next % len(self.kinds)]
        self._next += 1
        for key, msg in fault_kinds.build(kind, self._templates):
            self._own[key].append(stamp_to_ns(msg.header.stamp))
            self._pubs[key].publish(msg)
            self.messages += 1
        self.counts[kind] += 1

    def _done(self):
        if self._state == 'done':
            return
        self._state = 'done'
        self._timer.cancel()
        self.get_logger().info(
            f'done: {sum(self.counts.values())} injections ({self.messages} messages) of '
            f'{len(self.counts)} kinds: '
            + ', '.join(f'{k} {self.counts[k]}' for k in self.kinds))
        self._publish_diagnostics()
        if self.params['exit_when_done']:
            self.finished.set_result(0)

    # ------------------------------------------------------------------ diagnostics
    def _publish_diagnostics(self):
        status = DiagnosticStatus(name=f'{self.get_name()}: injected faults',
                                  hardware_id='fault_injector', level=DiagnosticStatus.OK,
                                  message=self._state)
        values = {'state': self._state, 'injections': sum(self.counts.values()),
                  'messages': self.messages}
        values.update({f'kind/{k}': self.counts[k] for k in self.kinds})
        status.values = [KeyValue(key=k, value=str(v)) for k, v in values.items()]
        msg = DiagnosticArray(status=[status])
        msg.header.stamp = self.get_clock().now().to_msg()
        self._pub_diag.publish(msg)


def main(args=None):
    return run_node(FaultInjectorNode, 'fault_injector_node', args, spin=spin_until_finished)


if __name__ == '__main__':
    sys.exit(main())
