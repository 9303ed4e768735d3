"""Crash-safe rosbag2 writer built from rosbags' Writer: a bag of rolling split files.

Why splits: an MCAP file (or a sqlite3 transaction) that is being written when its
process is killed lacks its summary and footer, and rosbags' reader refuses such a file.
So the bag is written as rosbag2 splits (``<bag>_0.mcap``, ``<bag>_1.mcap``, ...), the
same layout ``ros2 bag record --max-bag-duration`` makes:

* the split being filled is a complete little rosbags bag in the hidden staging folder
  ``<bag>/.in_progress/<bag>_<i>/``, invisible to readers;
* :meth:`SplitBagWriter.flush` closes it with rosbags' ``Writer.close`` (chunk index,
  summary, footer and the split's own ``metadata.yaml``), moves the storage file into the
  bag folder with an atomic rename, and rewrites the bag's ``metadata.yaml`` (atomic
  rename of a temporary file) listing every finished split.

At every instant the bag folder holds only finished files and a ``metadata.yaml`` that
lists only finished files, so a SIGKILL loses only the messages written since the last
flush (at most one flush interval) and the bag opens as is with rosbags' Reader, with the
``mcap`` package's reader (each split is an indexed MCAP file) and with ``ros2 bag``.
(A kill in the instant between moving a finished split in and renaming the new
``metadata.yaml`` leaves that one split unlisted; readers ignore it.)
No rclpy here.
"""
from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
import logging
from pathlib import Path
import shutil

from rosbags.interfaces import Connection, Qos
from rosbags.rosbag2 import Writer
from rosbags.rosbag2.enums import CompressionFormat, CompressionMode, StoragePlugin
from rosbags.rosbag2.metadata import dump_qos_v9
from rosbags.typesys.store import Typestore
import yaml

from vlc_bags.typesupport import jazzy_typestore, message_definition
from vlc_common.core.config_files import SAFE_DUMPER, SAFE_LOADER

_LOG = logging.getLogger(__name__)

#: rosbag2 metadata version written (the one ROS 2 Jazzy writes).
BAG_VERSION = 9
#: Hidden folder inside the bag holding the split being filled.
STAGING_DIR = '.in_progress'
STORAGES = {'mcap': (StoragePlugin.MCAP, '.mcap'), 'sqlite3': (StoragePlugin.SQLITE3, '.db3')}
COMPRESSIONS = ('none', 'zstd')


@dataclass(frozen=True)
class _Topic:
    name: str
    msgtype: str
    msgdef: str
    rihs01: str
    offered_qos: tuple[Qos, ...]


def _dump_yaml(data: dict) -> str:
    # libyaml (PyYAML's C dumper): metadata.yaml is rewritten at every flush and grows by
    # one file entry each time; ruamel, which rosbags uses, needs ~1 ms per entry.
    # width: one line per value, no folded RIHS01 hashes for line-oriented tools.
    return yaml.dump(data, Dumper=SAFE_DUMPER,
                     default_flow_style=False, width=4096)


def write_text_atomic(path: Path, text: str) -> None:
    """Replace ``path`` by ``text`` so that a reader (or a crash) sees old or new, never half."""
    tmp = path.with_name(path.name + '.tmp')
    tmp.write_text(text, 'utf8')
    tmp.replace(path)


class SplitBagWriter:
    """Write a rosbag2 bag as rolling split files that survive SIGKILL of the writer.

    Parameters
    ----------
    path : Path
        Bag folder to create; must not exist.
    storage : {'mcap', 'sqlite3'}
        rosbag2 storage plugin.
    compression : {'none', 'zstd'}
        MCAP chunk compression (rosbag2's storage-side compression); sqlite3 takes none.
    custom_data : mapping of str to str, optional
        Written to ``custom_data`` of ``metadata.yaml`` (rosbag2 ≥ Iron).
    typestore : Typestore, optional
        Where message definitions come from; default ROS 2 Jazzy plus ament ``.msg`` files.
    """

    def __init__(self, path: Path | str, *, storage: str = 'mcap', compression: str = 'none',
                 custom_data: Mapping[str, str] | None = None,
                 typestore: Typestore | None = None) -> None:
        if storage not in STORAGES:
            raise ValueError(f'storage must be one of {sorted(STORAGES)}, not {storage!r}')
        if compression not in COMPRESSIONS:
            raise ValueError(f'compression must be one of {COMPRESSIONS}, not {compression!r}')
        if compression != 'none' and storage != 'mcap':
            raise ValueError('chunk compression needs the mcap storage')
        self.path = Path(path)
        if self.path.exists():
            raise FileExistsError(f'{self.path} exists already; a bag is never overwritten')
        self.storage = storage
        self.compression = compression
        self.custom_data = {str(k): str(v) for k, v in (custom_data or {}).items()}
        self.typestore = typestore or jazzy_typestore()
        self._plugin, self._suffix = STORAGES[storage]
        self._staging = self.path / STAGING_DIR
        self._staging.mkdir(parents=True)
        self._topics: dict[str, _Topic] = {}
        self._counts: dict[str, int] = {}
        self._files: list[dict] = []
        self._split: Writer | None = None
        self._split_connections: dict[str, Connection] = {}
        self._split_messages = 0
        self._next_index = 0
        self._closed = False
        self._write_metadata()

    # -- topics and messages -------------------------------------------------------------
    @property
    def topics(self) -> dict[str, str]:
        """Registered topics: name → message type."""
        return {name: t.msgtype for name, t in self._topics.items()}

    @property
    def pending_messages(self) -> int:
        """Messages written since the last flush (lost if the process dies now)."""
        return self._split_messages

    def add_topic(self, topic: str, msgtype: str, offered_qos: Sequence[Qos] = ()) -> None:
        """Register a topic; its definition comes from the typestore.

        ``offered_qos`` (the publishers' offered profiles, as rosbag2 stores them) is fixed
        for the life of the bag: readers match every split's connection to the bag's topic
        list by topic, type and QoS.

        Raises
        ------
        KeyError
            Unknown message type. ValueError: topic registered already.
        """
        if topic in self._topics:
            raise ValueError(f'topic {topic} registered already')
        msgdef, rihs01 = message_definition(self.typestore, msgtype)
        entry = _Topic(topic, msgtype, msgdef, rihs01, tuple(offered_qos))
        self._topics[topic] = entry
        self._counts[topic] = 0
        if self._split is not None:
            self._add_connection(entry)
        self._write_metadata()

    def write(self, topic: str, timestamp_ns: int, data: bytes | memoryview) -> None:
        """Append one CDR-serialized message with its bag timestamp (ns)."""
        if self._closed:
            raise RuntimeError('bag is closed')
        if self._split is None:
            self._open_split()
        self._split.write(self._split_connections[topic], int(timestamp_ns), data)
        self._split_messages += 1

    # -- splits --------------------------------------------------------------------------
    def _add_connection(self, topic: _Topic) -> None:
        self._split_connections[topic.name] = self._split.add_connection(
            topic.name, topic.msgtype, msgdef=topic.msgdef, rihs01=topic.rihs01,
            offered_qos_profiles=list(topic.offered_qos))

    def _open_split(self) -> None:
        name = f'{self.path.name}_{self._next_index}'
        writer = Writer(self._staging / name, version=BAG_VERSION, storage_plugin=self._plugin)
        if self.compression == 'zstd':
            writer.set_compression(CompressionMode.STORAGE, CompressionFormat.ZSTD)
        writer.open()
        self._split = writer
        self._split_connections = {}
        for topic in self._topics.values():
            self._add_connection(topic)
        self._split_messages = 0

    def flush(self) -> int:
        """Finish the split being filled and list it in ``metadata.yaml``.

        Returns
        -------
        int
            Number of messages the call made durable (0 if there was nothing to flush).
        """
        if self._split is None or self._split_messages == 0:
            return 0
        writer, self._split = self._split, None
        writer.close()
        split_dir = writer.path
        split_meta = yaml.load((split_dir / 'metadata.yaml').read_text(),
                               Loader=SAFE_LOADER)
        info = split_meta['rosbag2_bagfile_information']
        (file_info,) = info['files']
        self._files.append(file_info)
        for entry in info['topics_with_message_count']:
            self._counts[entry['topic_metadata']['name']] += entry['message_count']
        # the YAML is rendered before the file moves in: a kill between the two atomic
        # renames leaves one finished split that metadata.yaml does not list yet
        metadata_text = self._metadata_text()
        (split_dir / file_info['path']).replace(self.path / file_info['path'])
        write_text_atomic(self.path / 'metadata.yaml', metadata_text)
        shutil.rmtree(split_dir)
        self._next_index += 1
        flushed, self._split_messages = self._split_messages, 0
        return flushed

    def close(self) -> None:
        """Flush, drop the staging folder and write the final ``metadata.yaml``."""
        if self._closed:
            return
        self.flush()
        if self._split is not None:
            # an open split without messages: nothing worth keeping
            self._split.abort()
            self._split = None
        shutil.rmtree(self._staging, ignore_errors=True)
        self._closed = True
        self._write_metadata()

    # -- metadata ------------------------------------------------------------------------
    def metadata(self) -> dict:
        """The bag's metadata as written to ``metadata.yaml`` (rosbag2 version 9 layout)."""
        count = sum(f['message_count'] for f in self._files)
        if self._files:
            start = min(f['starting_time']['nanoseconds_since_epoch'] for f in self._files)
            end = max(f['starting_time']['nanoseconds_since_epoch'] + f['duration']['nanoseconds']
                      for f in self._files)
        else:
            start = end = 0
        return {'rosbag2_bagfile_information': {
            'version': BAG_VERSION,
            'storage_identifier': self.storage,
            'relative_file_paths': [f['path'] for f in self._files],
            'duration': {'nanoseconds': end - start},
            'starting_time': {'nanoseconds_since_epoch': start},
            'message_count': count,
            'topics_with_message_count': [
                {'topic_metadata': {'name': t.name, 'type': t.msgtype,
                                    'serialization_format': 'cdr',
                                    'offered_qos_profiles': dump_qos_v9(list(t.offered_qos)),
                                    'type_description_hash': t.rihs01},
                 'message_count': self._counts[t.name]}
                for t in self._topics.values()],
            'compression_format': '',
            'compression_mode': '',
            'files': list(self._files),
            'custom_data': self.custom_data or None,
            'ros_distro': 'rosbags',
        }}

    def _metadata_text(self) -> str:
        return _dump_yaml(self.metadata())

    def _write_metadata(self) -> None:
        write_text_atomic(self.path / 'metadata.yaml', self._metadata_text())

    def __enter__(self) -> SplitBagWriter:
        return self

    def __exit__(self, *exc) -> None:
        self.close()
