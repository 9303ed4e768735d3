"""poll_qos_events: the QoS event handlers leave the executor's wait set and still fire."""
import time

import pytest

rclpy = pytest.importorskip('rclpy')

from rclpy.event_handler import EventHandler  # noqa: E402
from rclpy.executors import SingleThreadedExecutor  # noqa: E402
from rclpy.qos import QoSProfile, ReliabilityPolicy  # noqa: E402
from std_msgs.msg import Int32  # noqa: E402

from vlc_common.qos_events import poll_qos_events  # noqa: E402

pytestmark = pytest.mark.ros

BEST_EFFORT = QoSProfile(depth=5, reliability=ReliabilityPolicy.BEST_EFFORT)
RELIABLE = QoSProfile(depth=5, reliability=ReliabilityPolicy.RELIABLE)


def test_incompatible_qos_is_reported_by_the_poll_not_by_the_executor():
    ctx = rclpy.Context()
    rclpy.init(context=ctx)
    try:
        node = rclpy.create_node('qos_events_test', context=ctx)
        # a reliable reader cannot take from a best-effort writer: both sides get an event
        node.create_publisher(Int32, 'qos_events_numbers', BEST_EFFORT)
        node.create_subscription(Int32, 'qos_events_numbers', lambda msg: None, RELIABLE)
        polled = poll_qos_events(node, period_s=3600.0)    # the test polls by hand
        assert polled.handlers and all(isinstance(h, EventHandler) for h in polled.handlers)
        assert polled.timer is not None
        calls = []
        for handler in polled.handlers:
            handler.callback = lambda event, h=handler: calls.append((h.event_type, event))
        executor = SingleThreadedExecutor(context=ctx)
        executor.add_node(node)
        # the executor waits on none of them
        assert not [w for w in node.waitables if executor.can_execute(w)]
        handled = 0
        deadline = time.monotonic() + 10.0
        while handled < 2 and time.monotonic() < deadline:
            executor.spin_once(timeout_sec=0.05)
            assert not calls or handled     # only the poll calls them
            handled += polled.poll()
        assert handled == 2 and len(calls) == 2
        names = sorted(type_.name for type_, _ in calls)
        assert names == ['RCL_PUBLISHER_OFFERED_INCOMPATIBLE_QOS',
                         'RCL_SUBSCRIPTION_REQUESTED_INCOMPATIBLE_QOS']
        assert polled.poll() == 0       # taken once
        # the node still tears down (destroy_node removes the handlers from its waitables)
        node.destroy_node()
        assert polled.poll() == 0
    finally:
        rclpy.shutdown(context=ctx)



def test_the_environment_switch_leaves_the_handlers_with_the_executor(monkeypatch):
    monkeypatch.setenv('VLC_POLL_QOS_EVENTS', '0')
    ctx = rclpy.Context()
    rclpy.init(context=ctx)
    try:
        node = rclpy.create_node('qos_events_off', context=ctx)
        node.create_publisher(Int32, 'qos_events_off', BEST_EFFORT)
        assert poll_qos_events(node) is None
        executor = SingleThreadedExecutor(context=ctx)
        executor.add_node(node)
        handlers = [w for w in node.waitables if isinstance(w, EventHandler)]
        assert handlers and all(executor.can_execute(h) for h in handlers)
        node.destroy_node()
    finally:
        rclpy.shutdown(context=ctx)
