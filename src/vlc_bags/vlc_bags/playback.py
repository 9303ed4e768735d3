"""Playback logic of ``bag_player`` without rclpy: configuration, topic selection and
remapping, publisher QoS from the recorded offers, and the wall-clock schedule.
"""
from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import dataclass
import heapq

from rosbags.interfaces import Qos, QosDurability, QosHistory, QosReliability

from vlc_bags.bagio import TopicSummary, qos_profile


@dataclass(frozen=True)
class PlayerConfig:
    """Parameters of ``bag_player`` (documented in ``config/bag_player.yaml``)."""

    bag: str = ''
    rate: float = 1.0
    topics: tuple[str, ...] = ()
    remap: tuple[str, ...] = ()
    loop: bool = False
    start_offset_s: float = 0.0
    duration_s: float = 0.0
    publish_clock: bool = True
    exit_when_done: bool = True
    start_delay_s: float = 1.0
    wait_for_subscriptions: bool = False
    default_depth: int = 5
    fast_pause_s: float = 0.001
    delay_topics: tuple[str, ...] = ()
    topic_delay_s: float = 0.0
    clock_rate_hz: float = 0.0

    def __post_init__(self) -> None:
        if not self.bag:
            raise ValueError('parameter bag (path of the bag folder) is required')
        if not self.rate >= 0:
            raise ValueError('rate must be >= 0 (0 = as fast as subscribers keep up)')
        for name in ('start_offset_s', 'duration_s', 'start_delay_s', 'fast_pause_s',
                     'topic_delay_s', 'clock_rate_hz'):
            if not getattr(self, name) >= 0:
                raise ValueError(f'{name} must be >= 0')
        if self.default_depth < 1:
            raise ValueError('default_depth must be >= 1')
        parse_remaps(self.remap)


def absolute(topic: str) -> str:
    """Bag topics are absolute; accept ``stereo/left/image_raw`` for ``/stereo/...``."""
    return topic if topic.startswith('/') else '/' + topic


def parse_remaps(items: Iterable[str]) -> dict[str, str]:
    """Parse ``["from:=to", ...]`` into ``{absolute from: to}``.

    ``to`` is kept as given: an absolute name is used as is, a relative one is resolved
    in the player's namespace by ROS.

    Raises
    ------
    ValueError
        An item without ``:=`` or with an empty side.
    """
    remaps = {}
    for item in items:
        src, sep, dst = item.partition(':=')
        if not sep or not src.strip() or not dst.strip():
            raise ValueError(f'remap {item!r} is not "from:=to"')
        remaps[absolute(src.strip())] = dst.strip()
    return remaps


def select_topics(summary: Sequence[TopicSummary], wanted: Sequence[str]) -> list[TopicSummary]:
    """Topics of the bag to play: all when ``wanted`` is empty, else those named."""
    if not wanted:
        return list(summary)
    names = {absolute(t) for t in wanted}
    return [t for t in summary if t.topic in names]


def missing_topics(summary: Sequence[TopicSummary], wanted: Sequence[str]) -> list[str]:
    """Requested topics the bag does not have (for a warning)."""
    present = {t.topic for t in summary}
    return sorted({absolute(t) for t in wanted} - present)


def playback_qos(offers: Sequence[Qos], fast: bool, default_depth: int) -> Qos:
    """Publisher QoS for a topic from its recorded offered profiles.

    Reliability and durability follow the recorded publishers (reliable / transient local
    only if every recorded offer was, like ``ros2 bag play``): images replay reliable,
    IMU best effort as ROS's sensor-data profile. A bag without recorded offers replays
    reliable volatile. History is keep last: the recorded depth when the offers carry one
    (offers discovered over DDS do not), else ``default_depth``. ``fast`` (rate 0) forces
    reliable: with no real-time pacing, lost samples must be resent.
    """
    reliable = fast or not offers or all(q.reliability == QosReliability.RELIABLE
                                         for q in offers)
    transient = bool(offers) and all(q.durability == QosDurability.TRANSIENT_LOCAL
                                     for q in offers)
    depths = [q.depth for q in offers
              if q.history in (QosHistory.KEEP_LAST, QosHistory.KEEP_ALL) and q.depth > 0]
    return qos_profile('reliable' if reliable else 'best_effort',
                       'transient_local' if transient else 'volatile',
                       max(depths) if depths else default_depth)


def time_window(bag_start_ns: int, bag_end_ns: int, start_offset_s: float,
                duration_s: float) -> tuple[int, int]:
    """Bag-time window ``[start, stop)`` in ns to play (``duration_s`` 0 = to the end)."""
    start = bag_start_ns + round(start_offset_s * 1e9)
    stop = bag_end_ns if duration_s <= 0 else min(bag_end_ns, start + round(duration_s * 1e9))
    return start, max(start, stop)


class PlaybackSchedule:
    """Wall-clock instant at which each message is due, for a playback rate.

    ``rate`` 1.0 is real time, 2.0 twice as fast; 0 means no schedule (publish as fast
    as the subscribers keep up). A message with a stamp older than the latest one played
    (possible across split files in header-stamp bags) is due at once.
    """

    def __init__(self, rate: float) -> None:
        self.rate = rate
        self._bag_t0_ns: int | None = None
        self._wall_t0_s = 0.0

    def restart(self, bag_t0_ns: int, wall_t0_s: float) -> None:
        """Anchor bag time ``bag_t0_ns`` to wall time ``wall_t0_s`` (start and each loop)."""
        self._bag_t0_ns = bag_t0_ns
        self._wall_t0_s = wall_t0_s

    def due_s(self, timestamp_ns: int) -> float | None:
        """Wall time (s, same clock as ``wall_t0_s``) at which to publish, or None (rate 0)."""
        if self.rate == 0 or self._bag_t0_ns is None:
            return None
        return self._wall_t0_s + (timestamp_ns - self._bag_t0_ns) * 1e-9 / self.rate


def delayed(messages: Iterable[tuple], delay_topics: Iterable[str], delay_ns: int):
    """Yield ``(topic, connection, timestamp, data)`` with the messages of ``delay_topics``
    moved ``delay_ns`` later, in the order of the new timestamps (``delay_ns`` >= 0).

    A rolling-shutter camera's image carries the stamp of its first row's exposure but
    exists only once the last row is read out; a bag whose timestamps are header stamps
    (the sample and latency bags) would otherwise replay each frame a readout early,
    before the IMU samples the camera saw. Messages of other topics keep their order.
    """
    delay_topics = {absolute(t) for t in delay_topics}
    if not delay_topics or delay_ns <= 0:
        yield from messages
        return
    held = []                   # heap of (new timestamp, sequence, message)
    for seq, (topic, conn, timestamp, data) in enumerate(messages):
        # every later message is due at or after ``timestamp``: release what is due before
        while held and held[0][0] <= timestamp:
            yield heapq.heappop(held)[2]
        if topic in delay_topics:
            heapq.heappush(held, (timestamp + delay_ns, seq,
                                  (topic, conn, timestamp + delay_ns, data)))
        else:
            yield topic, conn, timestamp, data
    while held:
        yield heapq.heappop(held)[2]
