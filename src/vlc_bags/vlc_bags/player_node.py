"""``bag_player``: replay a rosbag2 bag (MCAP or sqlite3) without the ros2 CLI.

Messages are published as the stored CDR bytes (``Publisher.publish(bytes)``), so stamps
and contents are unchanged. ``/clock`` (rosgraph_msgs/Clock, reliable depth 10, which
best-effort /clock subscribers also match) carries the bag timestamp of each message
just before it is published, never going backwards within one pass.

QoS per topic from the recorded offered profiles (``playback.playback_qos``): images
reliable keep last 5, IMU best effort keep last 5 (sensor data), as recorded.

Rate: 1.0 real time, r > 0 r times real time. Rate 0 = as fast as the graph keeps up:
messages in bag order, every publisher reliable, and a pause of ``fast_pause_s`` after
each message so that subscriber callbacks get the CPU. A subscriber keeps up when its
callback takes less than the pause (plus the publish time) per message on average and
its queue depth covers bursts; a slower keep-last subscriber loses the oldest messages,
as with ``ros2 bag play``. (Waiting for acknowledgements is no use here: Fast DDS sends
the heartbeats that trigger them every 3 s by default.) See docs/arch/bags.md.

Playback runs in a worker thread; the main thread spins the node. At the end of the bag
(not looping) the node exits 0 when ``exit_when_done``; SIGINT stops it with exit 0.
"""
from __future__ import annotations

import sys
import threading
import time

from builtin_interfaces.msg import Time
import rclpy
from rclpy.executors import SingleThreadedExecutor
import rclpy.logging
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.qos import QoSProfile, ReliabilityPolicy
from rosbags.rosbag2 import ReaderError
from rosgraph_msgs.msg import Clock

from vlc_bags.bagio import bag_summary, bag_time_range, iter_raw
from vlc_bags.conversions import message_class, qos_to_rclpy
from vlc_bags.params import declare
from vlc_bags.playback import (
    PlaybackSchedule,
    PlayerConfig,
    delayed,
    missing_topics,
    parse_remaps,
    playback_qos,
    select_topics,
    time_window,
)
from vlc_common.process import keep_large_buffers, run_node, spin_until_shutdown


class BagPlayerNode(Node):
    """Publish the messages of a bag with their original bytes and timing."""

    def __init__(self) -> None:
        super().__init__('bag_player')
        self.config = self._read_config()
        cfg = self.config
        summary = bag_summary(cfg.bag)
        for topic in missing_topics(summary, cfg.topics):
            self.get_logger().warning(f'{topic} is not in {cfg.bag}')
        remaps = parse_remaps(cfg.remap)
        self._topic_publishers = {}
        for topic in select_topics(summary, cfg.topics):
            try:
                msg_class = message_class(topic.msgtype)
            except ImportError as exc:
                self.get_logger().warning(f'not playing {topic.topic}: {exc}')
                continue
            qos = playback_qos(topic.offered_qos, fast=cfg.rate == 0,
                               default_depth=cfg.default_depth)
            name = remaps.get(topic.topic, topic.topic)
            self._topic_publishers[topic.topic] = self.create_publisher(msg_class, name,
                                                                  qos_to_rclpy(qos))
            self.get_logger().info(
                f'playing {topic.topic} -> {self.resolve_topic_name(name)} [{topic.msgtype}] '
                f'{qos.reliability.name.lower()} {qos.durability.name.lower()} depth {qos.depth}')
        self._clock_pub = self.create_publisher(
            Clock, '/clock', QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)) \
            if cfg.publish_clock else None
        bag_start, bag_end = bag_time_range(cfg.bag)
        self._window = time_window(bag_start, bag_end, cfg.start_offset_s, cfg.duration_s)
        self.published = 0
        self.failure: Exception | None = None
        self.done = threading.Event()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._play, name='bag_player', daemon=True)
        self._thread.start()

    def _read_config(self) -> PlayerConfig:
        d = PlayerConfig.__dataclass_fields__
        return PlayerConfig(
            bag=declare(self, 'bag', '', 'Bag folder to play (with metadata.yaml)'),
            rate=declare(self, 'rate', d['rate'].default,
                         'Playback speed: 1.0 real time; 0 = as fast as subscribers keep up',
                         float_range=(0.0, 100.0)),
            topics=declare(self, 'topics', Parameter.Type.STRING_ARRAY,
                           'Topics of the bag to play; empty = all'),
            remap=declare(self, 'remap', Parameter.Type.STRING_ARRAY,
                          'Renames as "from:=to" (from = topic in the bag)'),
            loop=declare(self, 'loop', d['loop'].default, 'Play the bag again and again'),
            start_offset_s=declare(self, 'start_offset_s', d['start_offset_s'].default,
                                   'Skip this much of the bag start [s]',
                                   float_range=(0.0, 1e6)),
            duration_s=declare(self, 'duration_s', d['duration_s'].default,
                               'Play only this much bag time; 0 = to the end [s]',
                               float_range=(0.0, 1e6)),
            publish_clock=declare(self, 'publish_clock', d['publish_clock'].default,
                                  'Publish /clock from the bag timestamps'),
            exit_when_done=declare(self, 'exit_when_done', d['exit_when_done'].default,
                                   'Exit (code 0) at the end of the bag when not looping'),
            start_delay_s=declare(self, 'start_delay_s', d['start_delay_s'].default,
                                  'Wait before the first message so subscribers can match [s]',
                                  float_range=(0.0, 60.0)),
            wait_for_subscriptions=declare(
                self, 'wait_for_subscriptions', d['wait_for_subscriptions'].default,
                'Before start_delay_s, wait until every played topic has a subscriber'),
            default_depth=declare(self, 'default_depth', d['default_depth'].default,
                                  'Publisher keep-last depth when the bag records none',
                                  int_range=(1, 10000)),
            fast_pause_s=declare(self, 'fast_pause_s', d['fast_pause_s'].default,
                                 'Rate 0: pause after each message [s]',
                                 float_range=(0.0, 1.0)),
            delay_topics=declare(self, 'delay_topics', Parameter.Type.STRING_ARRAY,
                                 'Topics published topic_delay_s after their bag timestamp'),
            topic_delay_s=declare(self, 'topic_delay_s', d['topic_delay_s'].default,
                                  'Delay of delay_topics (e.g. a rolling-shutter readout) [s]',
                                  float_range=(0.0, 10.0)),
            clock_rate_hz=declare(self, 'clock_rate_hz', d['clock_rate_hz'].default,
                                  '/clock at most this often (bag time) [Hz]; 0 = before '
                                  'every message', float_range=(0.0, 10000.0)),
        )

    def _play(self) -> None:
        cfg = self.config
        try:
            if cfg.wait_for_subscriptions:
                self.get_logger().info('waiting for a subscriber on every played topic')
                while any(p.get_subscription_count() == 0
                          for p in self._topic_publishers.values()):
                    if self._stop.wait(0.05):
                        return
            if self._stop.wait(cfg.start_delay_s):
                return
            schedule = PlaybackSchedule(cfg.rate)
            while not self._stop.is_set():
                before = self.published
                self._play_once(schedule)
                if not cfg.loop:
                    break
                if self.published == before:
                    self.get_logger().warning('nothing to play in the chosen window: not looping')
                    break
            self.get_logger().info(f'end of bag: {self.published} messages published')
        except Exception as exc:  # unreadable bag: report, and let main exit non-zero
            if self._stop.is_set() or not self.context.ok():
                # a SIGINT/SIGTERM shut the context down under a publish (RCLError
                # "publisher's context is invalid"): that is the stop, not a failure
                return
            self.failure = exc
            self.get_logger().error(f'playback failed: {exc!r}')
        finally:
            self.done.set()

    def _play_once(self, schedule: PlaybackSchedule) -> None:
        cfg = self.config
        start, stop = self._window
        schedule.restart(start, time.monotonic())
        last_clock = -1
        clock_period_ns = round(1e9 / cfg.clock_rate_hz) if cfg.clock_rate_hz > 0 else 1
        messages = delayed(iter_raw(cfg.bag, list(self._topic_publishers), start, stop),
                           cfg.delay_topics, round(cfg.topic_delay_s * 1e9))
        for topic, _, timestamp, data in messages:
            due = schedule.due_s(timestamp)
            if due is not None and self._stop.wait(max(0.0, due - time.monotonic())):
                return
            if self._stop.is_set():
                return
            if self._clock_pub is not None and timestamp >= last_clock + clock_period_ns:
                last_clock = timestamp
                self._clock_pub.publish(Clock(clock=Time(sec=timestamp // 1_000_000_000,
                                                         nanosec=timestamp % 1_000_000_000)))
            self._topic_publishers[topic].publish(data)
            self.published += 1
            if cfg.rate == 0 and cfg.fast_pause_s > 0 and self._stop.wait(cfg.fast_pause_s):
                return

    def stop(self) -> None:
        """Stop playback and wait for the worker thread."""
        self._stop.set()
        self._thread.join(timeout=5.0)

    #: what run_node calls before destroy_node (vlc_common.process)
    on_stop = stop


def _play(node):
    """Spin until the bag is done (and ``exit_when_done``) or the node is stopped."""
    executor = SingleThreadedExecutor()
    executor.add_node(node)

    def spin():
        while rclpy.ok() and not (node.done.is_set() and node.config.exit_when_done):
            executor.spin_once(timeout_sec=0.1)
    # a SIGINT between rclpy.ok() and the wait set shuts the context down under
    # spin_once (RCLError "the given context is not valid"): part of the stop, exit 0
    spin_until_shutdown(spin)
    return 1 if node.failure is not None else 0


def main(args=None) -> int:
    keep_large_buffers()
    return run_node(BagPlayerNode, 'bag_player', args, spin=_play,
                    startup_errors=(ReaderError,))


if __name__ == '__main__':
    sys.exit(main())
