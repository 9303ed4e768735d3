"""rosbag2 recording and replay without the ros2 CLI, built on the rosbags library.

Core helpers (no rclpy) for evaluation code, tests and scenario generation::

    from vlc_bags import open_bag, write_bag
    for topic, msgtype, timestamp_ns, msg in open_bag('bags/run1'):
        ...

Executables: ``bag_recorder`` (``recorder_node``) and ``bag_player`` (``player_node``).
See docs/arch/bags.md.
"""
from vlc_bags.bagio import (
                    BagMessage,
                    RawMessage,
                    TopicSummary,
                    bag_summary,
                    bag_time_range,
                    iter_raw,
                    open_bag,
                    qos_profile,
                    read_receive_times,
                    write_bag,
)
from vlc_bags.split_writer import SplitBagWriter
from vlc_bags.typesupport import jazzy_typestore

__all__ = ['BagMessage', 'RawMessage', 'SplitBagWriter', 'TopicSummary', 'bag_summary',
           'bag_time_range', 'iter_raw', 'jazzy_typestore', 'open_bag', 'qos_profile',
           'read_receive_times', 'write_bag']
