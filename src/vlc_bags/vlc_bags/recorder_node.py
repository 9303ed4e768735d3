"""``bag_recorder``: record topics to a rosbag2 bag (MCAP or sqlite3) without ros2 CLI.

Subscriptions: one per recorded topic, ``raw=True`` (the CDR bytes are written as
received, never deserialized). QoS per topic follows its publishers, as rosbag2 does:
reliable if every publisher is reliable, else best effort; transient local if every
publisher is, else volatile; keep last ``queue_depth``. The publishers' offered QoS
profiles are stored with the topic in the bag.

Topics: the ``topics`` list, or every topic of the graph (less ``exclude_topics``) when
the list is empty; the graph is re-scanned every ``discovery_interval_s`` for topics
that appear later.

Taking: every ``poll_period_s`` (steady clock) the recorder takes what each
subscription received in one batch, off the executor (``vlc_common.polled``: the
executor's per-message cost had been most of the recorder's CPU at 400 Hz); the bag
timestamp (``receive``) is the node clock at that moment, the receive log keeps the
middleware's exact send and receive times. ``poll_period_s`` 0 = a callback per message.

Writing: the takers only stamp and queue the bytes; a writer thread writes them (see
``recording.RecordingSession``), so disk stalls never block the executor.

Crash safety: the bag is written as rolling split files; every ``flush_interval_s`` the
current split is finished and listed in ``metadata.yaml`` (see ``split_writer``), so a
SIGKILL loses at most the last flush interval (plus the writer's backlog, normally
empty). SIGINT/SIGTERM finish the bag and exit 0.
See docs/arch/bags.md.
"""
from __future__ import annotations

import functools
from pathlib import Path
import sys
import time

import rclpy
from rclpy.clock import Clock, ClockType
import rclpy.logging
from rclpy.node import Node
from rclpy.parameter import Parameter

from vlc_bags.conversions import message_class, qos_from_rclpy, qos_to_rclpy
from vlc_bags.params import declare
from vlc_bags.recording import (
    RecorderConfig,
    RecordingSession,
    default_output_name,
    incompatible_offers,
    subscription_qos,
)
from vlc_common.polled import PolledSubscription
from vlc_common.process import keep_large_buffers, run_node


class BagRecorderNode(Node):
    """Record raw CDR messages of chosen topics into a crash-safe rosbag2 bag."""

    def __init__(self, **kwargs) -> None:
        super().__init__('bag_recorder', **kwargs)
        self.config = self._read_config()
        output = Path(self.config.output or default_output_name())
        self.session = RecordingSession(self.config, output)
        self._requested = {self.resolve_topic_name(t) for t in self.config.topics}
        self._excluded = {self.resolve_topic_name(t) for t in self.config.exclude_topics}
        self._recorded: dict[str, object] = {}
        self._requested_qos = {}
        self._ignored: set[str] = set()
        self._warned_incompatible: set[str] = set()
        self._closed = False
        self.create_timer(self.config.discovery_interval_s, self._scan)
        self.create_timer(self.config.flush_interval_s, self._flush)
        self._polled: dict[str, PolledSubscription] = {}
        if self.config.poll_period_s > 0:
            self.create_timer(self.config.poll_period_s, self._take_all,
                              clock=Clock(clock_type=ClockType.STEADY_TIME))
        self.get_logger().info(
            f'recording {sorted(self._requested) or "all topics"} to {output} '
            f'({self.config.storage}, timestamps: {self.config.timestamp_source}, '
            f'flush every {self.config.flush_interval_s} s)')
        self._scan()

    def _read_config(self) -> RecorderConfig:
        d = RecorderConfig()
        return RecorderConfig(
            output=declare(self, 'output', d.output,
                           'Bag folder to create (must not exist); empty = '
                           'rosbag2_YYYY_MM_DD-HH_MM_SS in the working directory'),
            storage=declare(self, 'storage', d.storage, 'rosbag2 storage: mcap or sqlite3'),
            topics=declare(self, 'topics', Parameter.Type.STRING_ARRAY,
                           'Topics to record (relative names resolve in the node namespace); '
                           'empty = every topic of the graph, re-scanned periodically'),
            exclude_topics=tuple(declare(self, 'exclude_topics', list(d.exclude_topics),
                                         'Topics never recorded when topics is empty')),
            timestamp_source=declare(self, 'timestamp_source', d.timestamp_source,
                                     'Bag timestamp of a message: receive (recorder clock at '
                                     'reception, as ros2 bag) or header (header.stamp)'),
            flush_interval_s=declare(self, 'flush_interval_s', d.flush_interval_s,
                                     'Period of finishing a split file; a SIGKILL loses at '
                                     'most this much recording [s]', float_range=(0.1, 60.0)),
            discovery_interval_s=declare(self, 'discovery_interval_s', d.discovery_interval_s,
                                         'Period of scanning the graph for topics [s]',
                                         float_range=(0.1, 60.0)),
            record_receive_times=declare(self, 'record_receive_times', d.record_receive_times,
                                         'Write receive_times.csv (wall-clock receive times '
                                         'for latency evaluation) in the bag folder'),
            queue_depth=declare(self, 'queue_depth', d.queue_depth,
                                'Keep-last depth of each subscription [messages]',
                                int_range=(1, 10000)),
            compression=declare(self, 'compression', d.compression,
                                'MCAP chunk compression: none or zstd'),
            max_backlog_mb=declare(self, 'max_backlog_mb', d.max_backlog_mb,
                                   'Messages waiting for the writer thread beyond this are '
                                   'dropped [MB]', float_range=(1.0, 100000.0)),
            poll_period_s=declare(self, 'poll_period_s', d.poll_period_s,
                                  'Take the received messages in batches this often (steady '
                                  'clock); 0 = a callback per message [s]',
                                  float_range=(0.0, 1.0)),
            metadata=declare(self, 'metadata', Parameter.Type.STRING_ARRAY,
                             "Extra custom_data of metadata.yaml, 'key=value' strings "
                             '(e.g. rig_profile=realistic, seed=7)'),
        )

    def _scan(self) -> None:
        """Subscribe to wanted topics that have publishers and are not recorded yet."""
        for topic, types in self.get_topic_names_and_types():
            if topic in self._ignored:
                continue
            if topic in self._recorded:
                self._check_new_publishers(topic)
                continue
            if self._requested and topic not in self._requested:
                continue
            if not self._requested and topic in self._excluded:
                continue
            infos = self.get_publishers_info_by_topic(topic)
            if not infos:
                continue
            self._subscribe(topic, types, infos)

    def _subscribe(self, topic: str, types: list[str], infos) -> None:
        msgtype = types[0]
        if len(types) > 1:
            self.get_logger().warning(f'{topic} has several types {types}; recording {msgtype}')
        offers = [qos_from_rclpy(info.qos_profile) for info in infos]
        request = subscription_qos(offers, self.config.queue_depth)
        try:
            msg_class = message_class(msgtype)
            self.session.add_topic(topic, msgtype, offers)
        except (ImportError, KeyError) as exc:
            self.get_logger().warning(f'not recording {topic}: {exc}')
            self._ignored.add(topic)
            return
        self._requested_qos[topic] = request
        if self.config.poll_period_s > 0:
            self._polled[topic] = PolledSubscription(self, msg_class, topic,
                                                     qos_to_rclpy(request), raw=True)
            self._recorded[topic] = self._polled[topic].subscription
        else:
            self._recorded[topic] = self.create_subscription(
                msg_class, topic, functools.partial(self._on_message, topic),
                qos_to_rclpy(request), raw=True)
        self.get_logger().info(f'recording {topic} [{msgtype}] '
                               f'{request.reliability.name.lower()} '
                               f'{request.durability.name.lower()} depth {request.depth}')

    def _check_new_publishers(self, topic: str) -> None:
        if topic in self._warned_incompatible:
            return
        offers = [qos_from_rclpy(i.qos_profile) for i in self.get_publishers_info_by_topic(topic)]
        if incompatible_offers(self._requested_qos[topic], offers):
            self._warned_incompatible.add(topic)
            self.get_logger().warning(
                f'{topic}: a publisher appeared whose QoS the recording subscription '
                f'({self._requested_qos[topic].reliability.name.lower()}) cannot match; its '
                'messages are not recorded')

    def _on_message(self, topic: str, data: bytes, info: dict) -> None:
        callback_wall_ns = time.time_ns()
        problem = self.session.record(
            topic, data, self.get_clock().now().nanoseconds,
            info.get('source_timestamp') or 0, info.get('received_timestamp') or 0,
            callback_wall_ns)
        if problem is not None:
            self.get_logger().warning(f'{topic}: {problem}; recorded at its receive time',
                                      throttle_duration_sec=5.0)

    def _take_all(self) -> None:
        for topic, sub in self._polled.items():
            for data, info in sub.take_all(with_info=True):
                self._on_message(topic, data, info)

    def _flush(self) -> None:
        self.session.flush()
        if self.session.error is not None:
            self.get_logger().error(f'writing the bag fails: {self.session.error}',
                                    throttle_duration_sec=10.0)

    def close(self) -> None:
        """Finish the bag (idempotent)."""
        if self._closed:
            return
        self._closed = True
        if self.context.ok():
            self._take_all()      # what arrived since the last batch
        self.session.close()
        meta = self.session.writer.metadata()['rosbag2_bagfile_information']
        # after SIGINT the context is gone and the node logger can no longer reach /rosout
        logger = self.get_logger() if self.context.ok() else rclpy.logging.get_logger(
            'bag_recorder_shutdown')
        logger.info(f'bag {self.session.path} closed: {meta["message_count"]} '
                               f'messages in {len(meta["files"])} files')

    #: what run_node calls before destroy_node (vlc_common.process)
    on_stop = close


def main(args=None) -> int:
    keep_large_buffers()
    return run_node(BagRecorderNode, 'bag_recorder', args)


if __name__ == '__main__':
    sys.exit(main())
