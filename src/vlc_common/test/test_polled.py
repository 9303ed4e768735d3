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


def test_pair_images_pairs_warns_for_each_event_and_for_images_left_unpaired():
    """The image nodes' callback (vlc_common.polled.pair_images): complete pairs oldest
    first, one warning per pairing event through the node's table, and a warning for
    images dropped with no stereo partner (the spot locator used not to say so).
    """
    from sensor_msgs.msg import Image

    from vlc_common.core.stereo_pairing import StereoPairing
    from vlc_common.polled import pair_images

    def image(ms):
        msg = Image()
        msg.header.stamp.sec, msg.header.stamp.nanosec = 100, ms * 1_000_000
        return msg

    pairing, said = StereoPairing(max_pending=2), []
    table = {'out_of_order': ('order', 'stamp not newer'), 'outlier': ('far', 'far'),
             'reset': ('reset', 'reset')}

    def offer(side, ms, max_pairs=2):
        return pair_images(pairing, side, image(ms), [], lambda *w: said.append(w), table,
                           max_pairs)

    assert offer(0, 0) == ([], []) and said == []
    events, pairs = offer(1, 0)
    assert events == [] and [(p[0], p[1].header.stamp.nanosec) for p in pairs] == [
        (100 * 10**9, 0)]
    events, pairs = offer(1, 0)                   # a stamp already handed over
    assert events == ['out_of_order'] and pairs == [] and said == [('order', 'stamp not newer')]
    # three lefts without a right: the oldest is pushed out of max_pending unpaired
    for ms in (33, 66, 100):
        offer(0, ms)
    assert said[-1] == ('unpaired', '1 image(s) with no stereo partner dropped')
    events, pairs = offer(1, 100)
    assert [p[1].header.stamp.nanosec for p in pairs] == [100_000_000]
