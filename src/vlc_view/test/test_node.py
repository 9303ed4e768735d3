"""marker_node in-process: lamp records, spot pairs and poses in, one MarkerArray per
update period out, none while nothing new arrives.
"""
import time

from geometry_msgs.msg import PoseWithCovarianceStamped
import numpy as np
import pytest
import rclpy
from rclpy.context import Context
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.parameter import Parameter
from sensor_msgs.msg import PointCloud2
from visualization_msgs.msg import MarkerArray

from vlc_common.core.records import LAMP_DTYPE, PAIR_DTYPE
from vlc_common.pointcloud import records_to_cloud
from vlc_common.stamps import header
from vlc_view.marker_node import MarkerNode

pytestmark = pytest.mark.ros
EPOCH_NS = 1704067200 * 10 ** 9


@pytest.fixture
def graph(ros_env):
    ctx = Context()
    rclpy.init(context=ctx)
    node = MarkerNode(context=ctx, parameter_overrides=[Parameter('rate_hz', value=2.0),
                                                        Parameter('frame_id', value='world')])
    probe = Node('probe', context=ctx)
    got = []
    probe.create_subscription(MarkerArray, 'markers', got.append, 10)
    pubs = {'lamps': probe.create_publisher(PointCloud2, 'vlc/lamps', 10),
            'pairs': probe.create_publisher(PointCloud2, 'spots/pairs', 10),
            'pose': probe.create_publisher(PoseWithCovarianceStamped,
                                           'train/pose_with_covariance', 10)}
    executor = SingleThreadedExecutor(context=ctx)
    executor.add_node(node)
    executor.add_node(probe)

    def spin_until(done, timeout=10.0):
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            executor.spin_once(timeout_sec=0.02)
            if done():
                return True
        return False
    spin_until(lambda: all(p.get_subscription_count() for p in pubs.values()))
    yield node, pubs, got, spin_until
    executor.shutdown()
    node.destroy_node()
    probe.destroy_node()
    rclpy.try_shutdown(context=ctx)


def pose_msg(stamp_ns, x):
    msg = PoseWithCovarianceStamped(header=header(stamp_ns, 'map'))
    msg.pose.pose.position.x = x
    msg.pose.pose.orientation.w = 1.0
    cov = np.zeros(36)
    cov[0] = cov[7] = cov[14] = 0.01 ** 2
    msg.pose.covariance = cov.tolist()
    return msg


def test_markers_follow_the_graph_and_are_throttled(graph):
    node, pubs, got, spin_until = graph
    stamp = EPOCH_NS + 10 ** 9
    lamp = np.zeros(1, LAMP_DTYPE)
    lamp['uid'], lamp['state'], lamp['left_u'], lamp['left_v'] = 0x1005, 2, 600.0, 300.0
    pair = np.zeros(1, PAIR_DTYPE)
    pair['u_left'], pair['v_left'], pair['disparity'] = 600.0, 300.0, 20.0
    pubs['lamps'].publish(records_to_cloud(lamp, header(stamp, 'camera_left_optical_frame')))
    pubs['pairs'].publish(records_to_cloud(pair, header(stamp, 'camera_left_optical_frame')))
    for k in range(20):
        pubs['pose'].publish(pose_msg(stamp + k * 20_000_000, 44.0 + 0.1 * k))
    assert spin_until(lambda: node.state.scene().train is not None
                      and node.state.scene().train.position_m[0] == pytest.approx(45.9))
    assert spin_until(lambda: got and got[-1].markers[-1].ns == 'rays')
    markers = {(m.ns, m.id): m for m in got[-1].markers}
    assert all(m.header.frame_id == 'world' for m in got[-1].markers)
    assert markers[('train', 1)].points[0].x == pytest.approx(45.9)
    assert markers[('lamp_labels', [lamp.uid for lamp in node.state.lamp_map.lamps].index(
        0x1005))].text == '0x1005'
    # 22 messages in: a few updates at most (2 Hz), none while nothing new arrives
    assert len(got) < 5
    count = node.published
    spin_until(lambda: False, timeout=1.2)
    assert node.published == count
