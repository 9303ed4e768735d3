"""Message types for bags without ROS: the rosbags typestore for ROS 2 Jazzy.

Standard message types come from rosbags' built-in ``Stores.ROS2_JAZZY`` store. A type the
store does not know is looked up as a ``.msg`` file in the ament prefixes
(``$AMENT_PREFIX_PATH/share/<pkg>/msg/<Name>.msg``) together with the types it uses, so
the recorder can still write a definition readers can decode. No rclpy here.
"""
from __future__ import annotations

from collections.abc import Iterable
import logging
import os
from pathlib import Path
import struct

from rosbags.interfaces import Nodetype
from rosbags.typesys import Stores, get_types_from_msg, get_typestore
from rosbags.typesys.store import Typestore

_LOG = logging.getLogger(__name__)

#: Distribution whose definitions (and RIHS01 hashes) the bags carry.
STORE = Stores.ROS2_JAZZY

#: Types whose first field carries the message's time (sec int32, nanosec uint32).
_STAMPED_FIRST_FIELDS = ('std_msgs/msg/Header', 'builtin_interfaces/msg/Time')


def jazzy_typestore() -> Typestore:
    """Return a fresh typestore with the ROS 2 Jazzy standard message types."""
    return get_typestore(STORE)


def ament_prefixes() -> list[Path]:
    """Return the ament prefixes listed in ``$AMENT_PREFIX_PATH`` (may be empty)."""
    return [Path(p) for p in os.environ.get('AMENT_PREFIX_PATH', '').split(os.pathsep) if p]


def _referenced_types(typestore: Typestore, msgtype: str) -> Iterable[str]:
    """Yield the names of the message types ``msgtype``'s fields use."""
    for _, (nodetype, desc) in typestore.fielddefs[msgtype][1]:
        if nodetype == Nodetype.NAME:
            yield desc
        elif nodetype in (Nodetype.ARRAY, Nodetype.SEQUENCE):
            (inner_type, inner_desc), _ = desc
            if inner_type == Nodetype.NAME:
                yield inner_desc


def ensure_type(typestore: Typestore, msgtype: str,
                prefixes: Iterable[Path] | None = None) -> None:
    """Make ``msgtype`` (``pkg/msg/Name``) and its dependencies known to ``typestore``.

    Raises
    ------
    KeyError
        If neither the store nor any ament prefix defines the type.
    """
    if msgtype in typestore.fielddefs:
        return
    prefixes = list(ament_prefixes() if prefixes is None else prefixes)
    parts = msgtype.split('/')
    if len(parts) != 3:
        raise KeyError(f'not a ROS 2 message type name: {msgtype!r}')
    pkg, kind, name = parts
    for prefix in prefixes:
        path = prefix / 'share' / pkg / kind / f'{name}.msg'
        if path.is_file():
            typestore.register(get_types_from_msg(path.read_text(), msgtype))
            for dependency in _referenced_types(typestore, msgtype):
                ensure_type(typestore, dependency, prefixes)
            _LOG.info('loaded %s from %s', msgtype, path)
            return
    raise KeyError(f'message type {msgtype!r} is neither a ROS 2 Jazzy standard type '
                   f'nor found under share/{pkg}/{kind}/ in AMENT_PREFIX_PATH')


def message_definition(typestore: Typestore, msgtype: str) -> tuple[str, str]:
    """Return ``(ros2msg definition text, RIHS01 hash)`` for ``msgtype``.

    The definition is the concatenated form rosbag2 stores in MCAP schemas and in the
    sqlite3 ``message_definitions`` table; the hash matches ROS 2's type description hash.
    """
    ensure_type(typestore, msgtype)
    msgdef, _ = typestore.generate_msgdef(msgtype, ros_version=2)
    return msgdef, typestore.hash_rihs01(msgtype)


def has_stamp(typestore: Typestore, msgtype: str) -> bool:
    """Whether the type's first field is a ``std_msgs/Header`` or a ``builtin_interfaces/Time``.

    For such types :func:`header_stamp_ns` reads the stamp straight from the CDR bytes.
    """
    try:
        ensure_type(typestore, msgtype)
    except KeyError:
        return False
    fields = typestore.fielddefs[msgtype][1]
    if not fields:
        return False
    nodetype, desc = fields[0][1]
    return nodetype == Nodetype.NAME and desc in _STAMPED_FIRST_FIELDS


_LE_STAMP = struct.Struct('<iI')
_BE_STAMP = struct.Struct('>iI')


def header_stamp_ns(cdr: bytes | memoryview) -> int | None:
    """Read the stamp at the start of a CDR message whose first field is a stamp.

    Parameters
    ----------
    cdr : bytes
        Serialized message: 4-byte encapsulation header (byte 1 = 1 for little endian),
        then ``sec`` (int32) and ``nanosec`` (uint32) of the first field.

    Returns
    -------
    int or None
        The stamp in ns, or None if the buffer is too short or the stamp invalid
        (negative, or nanosec ≥ 1e9).
    """
    if len(cdr) < 12:
        return None
    sec, nanosec = (_LE_STAMP if cdr[1] & 1 else _BE_STAMP).unpack_from(cdr, 4)
    if sec < 0 or nanosec >= 1_000_000_000:
        return None
    return sec * 1_000_000_000 + nanosec
