"""``marker_node``: the positioning as visualization_msgs/MarkerArray for RViz2 or Foxglove.

Subscribes (relative names; reliable, depth 10 as their publishers):

* ``vlc/lamps`` (sensor_msgs/PointCloud2, the decoder's lamp records): which lamps are
  identified now and which were recently;
* ``spots/pairs`` (sensor_msgs/PointCloud2, the spot locator's pairs): joined to the lamp
  records of the same stamp, the lamps of the last fix;
* ``train/pose_with_covariance`` (geometry_msgs/PoseWithCovarianceStamped): the train
  and its along-track 3σ.

Publishes ``markers`` (visualization_msgs/MarkerArray; reliable, depth 1) in
``frame_id`` at most ``rate_hz`` times a second (steady clock), only when something new
arrived: what :mod:`vlc_view.core.scene` describes, as :mod:`vlc_view.conversions` lists.
The lamp map and the vehicle file are read at start (exit code 2 when one cannot be).
"""
import sys

from geometry_msgs.msg import PoseWithCovarianceStamped
from rcl_interfaces.msg import ParameterType
from rclpy.clock import Clock, ClockType
from rclpy.node import Node
from rclpy.qos import QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import PointCloud2
from visualization_msgs.msg import MarkerArray

from vlc_common.core.lamp_map import LampMap, resolve_lamp_map_path
from vlc_common.core.vehicle import load_vehicle
from vlc_common.parameters import descriptor
from vlc_common.process import run_node
from vlc_common.stamps import header
from vlc_common.throttled_log import ThrottledWarnings
from vlc_view import conversions
from vlc_view.core.scene import ViewState

WARN_PERIOD_S = 5.0


def _str(text):
    return descriptor(text, ptype=ParameterType.PARAMETER_STRING)


NODE_PARAMETERS = (
    ('frame_id', 'map', _str('Frame of the markers (the lamp map\'s and the pose\'s).')),
    ('lamp_map_path', '', _str("Lamp map YAML; '' = vlc_common's installed lamp_map.yaml.")),
    ('vehicle_path', '', _str("Vehicle mount file (camera position on base_link); '' = "
                              "vlc_common's vehicle.yaml.")),
    ('rate_hz', 4.0, descriptor('Most marker updates per second (steady clock).', 0.1, 30.0)),
    ('recent_s', 5.0, descriptor('A lamp identified within this long before the newest '
                                 'frame is drawn "seen recently", s of data time.',
                                 0.0, 3600.0)),
    ('ray_max_age_s', 1.0, descriptor('Rays of a fix older than this (data time) are not '
                                      'drawn, s.', 0.0, 3600.0)),
    ('lamp_diameter_m', 0.3, descriptor('Drawn lamp diameter, m.', 0.01, 5.0)),
)


class MarkerNode(Node):
    """See the module docstring."""

    def __init__(self, **kwargs):
        super().__init__('marker_node', **kwargs)
        p = {name: self.declare_parameter(name, default, desc).value
             for name, default, desc in NODE_PARAMETERS}
        self.params = p
        lamp_map = LampMap.load(resolve_lamp_map_path(p['lamp_map_path']))
        vehicle = load_vehicle(p['vehicle_path'])
        self.state = ViewState(lamp_map, vehicle.camera, recent_s=p['recent_s'])
        self.published = 0
        self._dirty = False
        self._warnings = ThrottledWarnings(self.get_logger(), WARN_PERIOD_S)
        records_qos = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)
        self.create_subscription(PointCloud2, 'vlc/lamps', self._on_lamps, records_qos)
        self.create_subscription(PointCloud2, 'spots/pairs', self._on_pairs, records_qos)
        self.create_subscription(PoseWithCovarianceStamped, 'train/pose_with_covariance',
                                 self._on_pose, records_qos)
        self.pub = self.create_publisher(MarkerArray, 'markers', QoSProfile(
            depth=1, reliability=ReliabilityPolicy.RELIABLE))
        self.create_timer(1.0 / p['rate_hz'], self._publish,
                          clock=Clock(clock_type=ClockType.STEADY_TIME))
        self.get_logger().info(
            f'markers of {len(lamp_map)} lamps, the train and its rays on '
            f'{self.resolve_topic_name("markers")} in {p["frame_id"]} at <= {p["rate_hz"]} Hz')

    def _records(self, msg, kind):
        try:
            return conversions.cloud_records(msg)
        except ValueError as exc:
            self._warnings.warn(kind, f'{kind} message not usable, ignored: {exc}')
            return None, None

    def _on_lamps(self, msg):
        stamp_ns, records = self._records(msg, 'vlc/lamps')
        if records is None:
            return
        if not {'uid', 'state'} <= set(records.dtype.names or ()):
            self._warnings.warn('lamps_fields', 'vlc/lamps without uid and state fields')
            return
        self.state.add_lamps(stamp_ns, records)
        self._dirty = True

    def _on_pairs(self, msg):
        stamp_ns, records = self._records(msg, 'spots/pairs')
        if records is not None:
            self.state.add_pairs(stamp_ns, records)
            self._dirty = True

    def _on_pose(self, msg):
        self.state.add_pose(*conversions.pose_with_covariance(msg))
        self._dirty = True

    def _publish(self):
        if not self._dirty:
            return
        self._dirty = False
        scene = self.state.scene()
        self.pub.publish(conversions.scene_markers(
            scene, header(scene.stamp_ns, self.params['frame_id']),
            self.params['lamp_diameter_m'], self.params['ray_max_age_s']))
        self.published += 1


def main(args=None):
    return run_node(MarkerNode, 'marker_node', args)


if __name__ == '__main__':
    sys.exit(main())
