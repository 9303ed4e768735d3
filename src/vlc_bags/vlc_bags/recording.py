"""Recording logic of ``bag_recorder`` without rclpy: configuration, QoS choice, the
bag timestamp of each message, and the receive-time log written next to the bag.
"""
from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
import datetime
import logging
from pathlib import Path
import queue
import threading

from rosbags.interfaces import Qos, QosDurability, QosReliability

from vlc_bags.bagio import RECEIVE_TIMES_COLUMNS, RECEIVE_TIMES_FILE, qos_profile
from vlc_bags.split_writer import COMPRESSIONS, STORAGES, SplitBagWriter
from vlc_bags.typesupport import has_stamp, header_stamp_ns

_LOG = logging.getLogger(__name__)

TIMESTAMP_SOURCES = ('receive', 'header')


@dataclass(frozen=True)
class RecorderConfig:
    """Parameters of ``bag_recorder`` (documented in ``config/bag_recorder.yaml``)."""

    output: str = ''
    storage: str = 'mcap'
    topics: tuple[str, ...] = ()
    exclude_topics: tuple[str, ...] = ('/rosout', '/parameter_events')
    timestamp_source: str = 'receive'
    flush_interval_s: float = 1.0
    discovery_interval_s: float = 1.0
    record_receive_times: bool = True
    queue_depth: int = 100
    compression: str = 'none'
    max_backlog_mb: float = 1000.0
    poll_period_s: float = 0.02
    #: Extra ``custom_data`` of metadata.yaml as 'key=value' strings (e.g. the rig
    #: profile and seed of a run).
    metadata: tuple[str, ...] = ()

    def custom_data(self) -> dict:
        """``metadata`` as a dict (ValueError naming a malformed entry)."""
        out = {}
        for item in self.metadata:
            key, sep, value = str(item).partition('=')
            if not sep or not key.strip():
                raise ValueError(f"metadata entry {item!r} is not 'key=value'")
            out[key.strip()] = value.strip()
        return out

    def __post_init__(self) -> None:
        if self.storage not in STORAGES:
            raise ValueError(f'storage must be one of {sorted(STORAGES)}, not {self.storage!r}')
        if self.compression not in COMPRESSIONS:
            raise ValueError(f'compression must be one of {COMPRESSIONS}')
        if self.compression != 'none' and self.storage != 'mcap':
            raise ValueError('compression needs storage mcap')
        if self.timestamp_source not in TIMESTAMP_SOURCES:
            raise ValueError(f'timestamp_source must be one of {TIMESTAMP_SOURCES}')
        if not self.flush_interval_s > 0 or not self.discovery_interval_s > 0:
            raise ValueError('flush_interval_s and discovery_interval_s must be > 0')
        if self.queue_depth < 1:
            raise ValueError('queue_depth must be >= 1')
        if not self.max_backlog_mb > 0:
            raise ValueError('max_backlog_mb must be > 0')
        self.custom_data()
        if not self.poll_period_s >= 0:
            raise ValueError('poll_period_s must be >= 0')


def default_output_name(now: datetime.datetime | None = None) -> str:
    """``rosbag2_YYYY_MM_DD-HH_MM_SS``, the name ``ros2 bag record`` gives a bag."""
    return (now or datetime.datetime.now()).strftime('rosbag2_%Y_%m_%d-%H_%M_%S')


def subscription_qos(offers: Sequence[Qos], depth: int) -> Qos:
    """QoS the recorder requests so that it matches every publisher (rosbag2's rule).

    Reliable only if every publisher offers reliable (a reliable request does not match
    a best-effort offer), else best effort; transient local only if every publisher
    offers it (so latched data is received), else volatile; keep last ``depth``.
    """
    reliable = bool(offers) and all(q.reliability == QosReliability.RELIABLE for q in offers)
    transient = bool(offers) and all(q.durability == QosDurability.TRANSIENT_LOCAL for q in offers)
    return qos_profile('reliable' if reliable else 'best_effort',
                       'transient_local' if transient else 'volatile', depth)


def incompatible_offers(request: Qos, offers: Sequence[Qos]) -> list[Qos]:
    """Offers a subscription with QoS ``request`` cannot match (for a warning)."""
    return [q for q in offers
            if (request.reliability == QosReliability.RELIABLE
                and q.reliability != QosReliability.RELIABLE)
            or (request.durability == QosDurability.TRANSIENT_LOCAL
                and q.durability != QosDurability.TRANSIENT_LOCAL)]


class ReceiveTimesLog:
    """``receive_times.csv`` in the bag folder: one row per recorded message.

    Rows are buffered and written as whole lines at each :meth:`flush` (the same instant
    the bag's split is flushed), so after a SIGKILL the file and the bag agree to within
    one flush interval and a line is never half-written except by a kill inside the
    write call (which :func:`bagio.read_receive_times` drops).
    """

    def __init__(self, bag_path: Path) -> None:
        self._file = open(Path(bag_path) / RECEIVE_TIMES_FILE, 'x', encoding='utf8')
        self._file.write(','.join(RECEIVE_TIMES_COLUMNS) + '\n')
        self._file.flush()
        self._lines: list[str] = []

    def add(self, topic: str, bag_timestamp_ns: int, header_stamp: int | None,
            source_timestamp_ns: int, received_timestamp_ns: int, callback_wall_ns: int) -> None:
        self._lines.append(f'{topic},{bag_timestamp_ns},'
                           f'{"" if header_stamp is None else header_stamp},'
                           f'{source_timestamp_ns},{received_timestamp_ns},{callback_wall_ns}\n')

    def flush(self) -> None:
        if self._lines:
            self._file.write(''.join(self._lines))
            self._lines.clear()
        self._file.flush()

    def close(self) -> None:
        self.flush()
        self._file.close()


class RecordingSession:
    """One recording: the crash-safe bag plus the receive-time log, written by a thread.

    :meth:`record` (called from the subscription callbacks) decides the bag timestamp —
    the receive time (ROS time of the recorder's clock at the callback, like ``ros2 bag
    record``) or the message's header stamp — and queues the message; a writer thread
    writes queued messages and performs queued flushes in order. The callbacks therefore
    never wait for the disk: a sqlite3 commit or a zstd chunk can take 100 ms and more,
    during which a 400 Hz IMU would overflow a subscription queue.

    Parameters
    ----------
    config : RecorderConfig
    path : Path
        Bag folder to create.
    custom_data : dict, optional
        Extra ``custom_data`` entries for ``metadata.yaml``.
    """

    _STOP = object()

    def __init__(self, config: RecorderConfig, path: Path | str,
                 custom_data: dict | None = None) -> None:
        self.config = config
        self.path = Path(path)
        data = {'recorder': 'vlc_bags/bag_recorder',
                'timestamp_source': config.timestamp_source,
                'flush_interval_s': str(config.flush_interval_s), **config.custom_data(),
                **(custom_data or {})}
        self.writer = SplitBagWriter(self.path, storage=config.storage,
                                     compression=config.compression, custom_data=data)
        self.log = ReceiveTimesLog(self.path) if config.record_receive_times else None
        self._stamped: dict[str, bool] = {}
        self._max_backlog_bytes = int(config.max_backlog_mb * 1e6)
        # each counter has a single writing thread, so no lock is needed
        self._queued_bytes = 0
        self._written_bytes = 0
        self.dropped = 0
        self.error: Exception | None = None
        self._queue: queue.SimpleQueue = queue.SimpleQueue()
        self._thread = threading.Thread(target=self._run, name='bag_writer', daemon=True)
        self._thread.start()

    @property
    def backlog_bytes(self) -> int:
        """Bytes queued but not yet written."""
        return self._queued_bytes - self._written_bytes

    def add_topic(self, topic: str, msgtype: str, offered_qos: Sequence[Qos]) -> None:
        """Register a topic; waits for the writer thread (KeyError: type without definition)."""
        def register() -> None:
            self.writer.add_topic(topic, msgtype, offered_qos)
            self._stamped[topic] = has_stamp(self.writer.typestore, msgtype)
        self.call(register)

    def record(self, topic: str, data: bytes, receive_ns: int, source_timestamp_ns: int = 0,
               received_timestamp_ns: int = 0, callback_wall_ns: int = 0) -> str | None:
        """Queue one message for writing; returns a problem description or None.

        A message with a problem is still recorded (at its receive time) unless the
        writer's backlog exceeds ``max_backlog_mb``, in which case it is dropped.

        Parameters
        ----------
        topic : str
            A topic registered with :meth:`add_topic`.
        data : bytes
            CDR-serialized message.
        receive_ns : int
            Recorder clock at the callback (ns); the bag timestamp in receive mode.
        source_timestamp_ns, received_timestamp_ns : int
            The middleware's publish and receive wall-clock times (ns) for the log.
        callback_wall_ns : int
            Wall clock at the callback (ns) for the log.
        """
        if self.backlog_bytes > self._max_backlog_bytes:
            self.dropped += 1
            return (f'writer backlog over {self.config.max_backlog_mb} MB: message dropped '
                    f'({self.dropped} so far)')
        problem = None
        stamp = header_stamp_ns(data) if self._stamped[topic] else None
        if self._stamped[topic] and stamp is None:
            problem = 'truncated message or invalid header stamp'
        timestamp = receive_ns
        if self.config.timestamp_source == 'header':
            if stamp is not None:
                timestamp = stamp
            elif problem is None:
                problem = 'type has no header stamp'
        row = (topic, timestamp, stamp, source_timestamp_ns, received_timestamp_ns,
               callback_wall_ns)
        self._queued_bytes += len(data)
        self._queue.put((topic, timestamp, data, row))
        return problem

    def flush(self, wait: bool = False) -> None:
        """Queue a flush (finish the split, write the log lines); ``wait`` until done."""
        self.call(self._flush_now, wait=wait)

    def close(self) -> None:
        """Write everything queued, finish the bag and stop the writer thread."""
        if not self._thread.is_alive():
            return
        self.call(self._close_now)
        self._queue.put(self._STOP)
        self._thread.join()

    def call(self, fn, wait: bool = True):
        """Run ``fn()`` in the writer thread after everything queued before it.

        Every storage operation runs in that one thread (a sqlite3 connection may only be
        used by the thread that opened it). With ``wait`` the result is returned and an
        exception raised here; without, an exception only sets :attr:`error`.
        """
        job = _Job(fn, waited_for=wait)
        self._queue.put(job)
        if not wait:
            return None
        job.done.wait()
        if job.exception is not None:
            raise job.exception
        return job.result

    def _flush_now(self) -> None:
        self.writer.flush()
        if self.log is not None:
            self.log.flush()

    def _close_now(self) -> None:
        self.writer.close()
        if self.log is not None:
            self.log.close()

    def _run(self) -> None:
        while True:
            item = self._queue.get()
            if item is self._STOP:
                return
            if isinstance(item, _Job):
                item.run()
                if item.exception is not None and not item.waited_for:
                    self._failed(item.exception)
                continue
            topic, timestamp, data, row = item
            try:
                self.writer.write(topic, timestamp, data)
                if self.log is not None:
                    self.log.add(*row)
            except Exception as exc:  # disk full, permissions: keep the recorder alive
                self._failed(exc)
            finally:
                self._written_bytes += len(data)

    def _failed(self, exc: Exception) -> None:
        if self.error is None:
            _LOG.error('writing the bag failed: %s', exc)
        self.error = exc


class _Job:
    """A function to run in the writer thread, with its outcome."""

    def __init__(self, fn, waited_for: bool) -> None:
        self.fn = fn
        self.waited_for = waited_for
        self.done = threading.Event()
        self.result = None
        self.exception: Exception | None = None

    def run(self) -> None:
        try:
            self.result = self.fn()
        except Exception as exc:
            self.exception = exc
        finally:
            self.done.set()
