"""Read and write rosbag2 bags with rosbags, for the evaluation code, tests and scenarios.

* :func:`open_bag` yields ``(topic, msgtype, timestamp_ns, message)`` with messages
  deserialized by rosbags' ROS 2 Jazzy typestore (types the bag defines but the store
  lacks are registered from the bag's own definitions);
* :func:`iter_raw` yields the stored CDR bytes instead (what the player publishes);
* :func:`bag_summary` lists topics, types, counts and recorded offered QoS;
* :func:`write_bag` writes already-built rosbags messages to a new bag;
* :func:`qos_profile` builds a rosbags QoS profile for ``offered_qos``.

No rclpy here.
"""
from __future__ import annotations

from collections.abc import Iterable, Iterator, Mapping, Sequence
import csv
from dataclasses import dataclass
import io
from pathlib import Path
from typing import NamedTuple

from rosbags.interfaces import (
    Connection,
    MessageDefinitionFormat,
    Qos,
    QosDurability,
    QosHistory,
    QosLiveliness,
    QosReliability,
    QosTime,
)
from rosbags.rosbag2 import Reader, Writer
from rosbags.rosbag2.enums import StoragePlugin
from rosbags.typesys import get_types_from_idl, get_types_from_msg
from rosbags.typesys.store import Typestore

from vlc_bags.split_writer import BAG_VERSION, STORAGES
from vlc_bags.typesupport import jazzy_typestore

#: File next to the bag's storage files with one row per recorded message (see recorder).
RECEIVE_TIMES_FILE = 'receive_times.csv'
RECEIVE_TIMES_COLUMNS = ('topic', 'bag_timestamp_ns', 'header_stamp_ns', 'source_timestamp_ns',
                         'received_timestamp_ns', 'callback_wall_ns')


class BagMessage(NamedTuple):
    """One message of a bag; unpacks as ``topic, msgtype, timestamp_ns, msg``."""

    topic: str
    msgtype: str
    timestamp_ns: int
    msg: object


class RawMessage(NamedTuple):
    """One stored message; unpacks as ``topic, msgtype, timestamp_ns, data`` (CDR bytes)."""

    topic: str
    msgtype: str
    timestamp_ns: int
    data: bytes


@dataclass(frozen=True)
class TopicSummary:
    """A topic of a bag: its type, message count and the publishers' offered QoS."""

    topic: str
    msgtype: str
    message_count: int
    offered_qos: tuple[Qos, ...]


def _infinite() -> QosTime:
    # rosbag2's spelling of RMW_DURATION_INFINITE (INT64_MAX ns)
    return QosTime(9223372036, 854775807)


def qos_profile(reliability: str = 'reliable', durability: str = 'volatile', depth: int = 10,
                history: str = 'keep_last') -> Qos:
    """Build a rosbags QoS profile (for ``write_bag(offered_qos=...)``).

    ``qos_profile('best_effort', depth=5)`` is ROS's sensor-data profile;
    ``qos_profile('reliable', depth=5)`` the camera images' profile.
    """
    return Qos(QosHistory[history.upper()], int(depth), QosReliability[reliability.upper()],
               QosDurability[durability.upper()], _infinite(), _infinite(),
               QosLiveliness.AUTOMATIC, _infinite(), False)


def _register_bag_types(typestore: Typestore, connections: Iterable[Connection]) -> None:
    """Teach ``typestore`` the types the bag defines but the Jazzy store lacks."""
    for conn in connections:
        if conn.msgtype in typestore.fielddefs:
            continue
        if conn.msgdef.format == MessageDefinitionFormat.MSG:
            typestore.register(get_types_from_msg(conn.msgdef.data, conn.msgtype))
        elif conn.msgdef.format == MessageDefinitionFormat.IDL:
            typestore.register(get_types_from_idl(conn.msgdef.data))


def _select(reader: Reader, topics: Sequence[str] | None) -> list[Connection]:
    if topics is None:
        return list(reader.connections)
    wanted = set(topics)
    return [c for c in reader.connections if c.topic in wanted]


def iter_raw(path: Path | str, topics: Sequence[str] | None = None,
             start_ns: int | None = None, stop_ns: int | None = None) -> Iterator[RawMessage]:
    """Yield the stored messages of a bag as CDR bytes, in storage order.

    Parameters
    ----------
    path : Path
        Bag folder (with ``metadata.yaml``).
    topics : sequence of str, optional
        Topics to read (absolute names as stored); None = all.
    start_ns, stop_ns : int, optional
        Keep messages with ``start_ns <= timestamp < stop_ns`` (bag time, ns).

    Notes
    -----
    Order: by timestamp within each split file, split files one after another (what
    rosbags and ``ros2 bag play`` do). Bags recorded with receive-time timestamps are thus
    in global time order; with header stamps, messages of different topics may be out of
    order by up to the pipeline latency across a split boundary.
    """
    with Reader(Path(path)) as reader:
        connections = _select(reader, topics)
        if not connections:
            return
        for conn, timestamp, data in reader.messages(connections, start=start_ns, stop=stop_ns):
            yield RawMessage(conn.topic, conn.msgtype, timestamp, data)


def open_bag(path: Path | str, topics: Sequence[str] | None = None,
             start_ns: int | None = None, stop_ns: int | None = None) -> Iterator[BagMessage]:
    """Yield ``(topic, msgtype, timestamp_ns, message)`` for every message of a bag.

    Messages are rosbags dataclasses from the ROS 2 Jazzy typestore (e.g. an Image's
    ``data`` is a numpy uint8 array). Arguments and order as :func:`iter_raw`.
    """
    typestore = jazzy_typestore()
    with Reader(Path(path)) as reader:
        connections = _select(reader, topics)
        if not connections:
            return
        _register_bag_types(typestore, connections)
        for conn, timestamp, data in reader.messages(connections, start=start_ns, stop=stop_ns):
            yield BagMessage(conn.topic, conn.msgtype, timestamp,
                             typestore.deserialize_cdr(data, conn.msgtype))


def bag_summary(path: Path | str) -> list[TopicSummary]:
    """List the topics of a bag with type, message count and recorded offered QoS."""
    with Reader(Path(path)) as reader:
        return [TopicSummary(c.topic, c.msgtype, c.msgcount,
                             tuple(c.ext.offered_qos_profiles)) for c in reader.connections]


def bag_time_range(path: Path | str) -> tuple[int, int]:
    """Return ``(start_ns, end_ns)`` of a bag (end exclusive; ``(0, 0)`` when empty)."""
    with Reader(Path(path)) as reader:
        if not reader.message_count:
            return 0, 0
        return reader.start_time, reader.end_time


def write_bag(path: Path | str, messages: Iterable[tuple[str, str, int, object]],
              storage: str = 'mcap',
              offered_qos: Mapping[str, Sequence[Qos]] | None = None,
              typestore: Typestore | None = None) -> int:
    """Write already-built rosbags messages to a new single-file rosbag2 bag.

    Parameters
    ----------
    path : Path
        Bag folder to create (must not exist).
    messages : iterable of (topic, msgtype, timestamp_ns, message)
        Messages built with the typestore's classes (e.g. ``typestore.types[
        'sensor_msgs/msg/Imu'](...)``), or already-serialized CDR ``bytes``.
    storage : {'mcap', 'sqlite3'}
    offered_qos : mapping topic → sequence of Qos, optional
        Offered QoS profiles recorded per topic (the player uses them); default none.
    typestore : Typestore, optional
        Default: ROS 2 Jazzy.

    Returns
    -------
    int
        Number of messages written.
    """
    if storage not in STORAGES:
        raise ValueError(f'storage must be one of {sorted(STORAGES)}, not {storage!r}')
    typestore = typestore or jazzy_typestore()
    offered_qos = offered_qos or {}
    plugin = StoragePlugin.MCAP if storage == 'mcap' else StoragePlugin.SQLITE3
    count = 0
    with Writer(Path(path), version=BAG_VERSION, storage_plugin=plugin) as writer:
        connections: dict[str, Connection] = {}
        for topic, msgtype, timestamp, msg in messages:
            conn = connections.get(topic)
            if conn is None:
                conn = writer.add_connection(topic, msgtype, typestore=typestore,
                                             offered_qos_profiles=list(offered_qos.get(topic, ())))
                connections[topic] = conn
            elif conn.msgtype != msgtype:
                raise ValueError(f'{topic}: type {msgtype} after {conn.msgtype}')
            data = msg if isinstance(msg, (bytes, bytearray, memoryview)) \
                else typestore.serialize_cdr(msg, msgtype)
            writer.write(conn, int(timestamp), bytes(data))
            count += 1
    return count


def read_receive_times(path: Path | str) -> list[dict]:
    """Read the recorder's ``receive_times.csv`` of a bag.

    Returns one dict per recorded message with the keys of ``RECEIVE_TIMES_COLUMNS``:
    ``topic`` (str) and the times in ns (int; ``header_stamp_ns`` None for types without
    a header). A row cut short by a kill is skipped.
    """
    text = (Path(path) / RECEIVE_TIMES_FILE).read_text()
    if not text.endswith('\n'):
        # the recorder writes whole lines; a last line without newline was cut by a kill
        text = text[:text.rfind('\n') + 1]
    rows = []
    for row in csv.DictReader(io.StringIO(text)):
        try:
            rows.append({
                'topic': row['topic'],
                **{k: int(row[k]) for k in RECEIVE_TIMES_COLUMNS[1:] if k != 'header_stamp_ns'},
                'header_stamp_ns': int(row['header_stamp_ns']) if row['header_stamp_ns'] else None,
            })
        except (TypeError, ValueError, KeyError):
            continue
    return rows
