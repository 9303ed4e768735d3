"""PolledSubscription: messages wait for take_all(); the executor never takes them."""
import time

import pytest

rclpy = pytest.importorskip('rclpy')

from rclpy.executors import SingleThreadedExecutor  # noqa: E402
from std_msgs.msg import Int32  # noqa: E402

from vlc_common.polled import PolledSubscription  # noqa: E402

pytestmark = pytest.mark.ros


def test_take_all_returns_every_message_in_order_and_the_executor_leaves_them():
    ctx = rclpy.Context()
    rclpy.init(context=ctx)
    try:
        node = rclpy.create_node('polled_test', context=ctx)
        polled = PolledSubscription(node, Int32, 'polled_numbers', 50)
        pub = node.create_publisher(Int32, 'polled_numbers', 50)
        executor = SingleThreadedExecutor(context=ctx)
        executor.add_node(node)
        deadline = time.monotonic() + 10.0
        while pub.get_subscription_count() == 0 and time.monotonic() < deadline:
            executor.spin_once(timeout_sec=0.05)
        assert polled.topic_name == '/polled_numbers'
        for i in range(20):
            pub.publish(Int32(data=i))
        got = []
        while len(got) < 20 and time.monotonic() < deadline:
            # the executor has nothing to run for the polled subscription
            executor.spin_once(timeout_sec=0.01)
            got += [m.data for m in polled.take_all(limit=7)]
        assert got == list(range(20))
        assert polled.take_all() == []
        node.destroy_node()
    finally:
        rclpy.shutdown(context=ctx)
