"""sensor_msgs/PointCloud2 ↔ numpy structured arrays, shared by every node of the graph.

Per-lamp records travel as PointCloud2 with one named field per column (one point per
lamp, ARCHITECTURE.md). The rig, the decoder, the spot locator and the localizer all use
these two functions, so a record written by one node reads back field for field in
another. A receiver reads a topic with its documented layout
(``cloud_to_records(msg, layout)``): a cloud whose bytes do not match its own
description, or whose fields have other types than the layout's, is refused with a
ValueError saying why, never read as garbage numbers.
"""
import array

import numpy as np
from sensor_msgs.msg import PointCloud2, PointField

_NUMPY_TYPE = {PointField.INT8: 'i1', PointField.UINT8: 'u1', PointField.INT16: 'i2',
               PointField.UINT16: 'u2', PointField.INT32: 'i4', PointField.UINT32: 'u4',
               PointField.FLOAT32: 'f4', PointField.FLOAT64: 'f8'}
_POINTFIELD_TYPE = {np.dtype('<' + code).str: datatype
                    for datatype, code in _NUMPY_TYPE.items()}


# A receiver's record dtype per cloud description (a node receives the same few layouts
# at 30 Hz; deriving and checking the dtype per message cost ~0.4 ms). Bounded: a stream
# of ever-different descriptions (malformed input) only refills the cache.
_CACHE_SIZE = 64
_DTYPES = {}


def records_to_cloud(records, header):
    """Structured array (little endian, scalar fields) → unordered PointCloud2."""
    fields = []
    for name in records.dtype.names:
        dtype, offset = records.dtype.fields[name][:2]
        if dtype.str not in _POINTFIELD_TYPE:
            raise ValueError(f'field {name!r}: type {dtype} has no PointField datatype')
        fields.append(PointField(name=name, offset=offset,
                                 datatype=_POINTFIELD_TYPE[dtype.str], count=1))
    data = array.array('B')
    data.frombytes(records.tobytes())
    return PointCloud2(header=header, height=1, width=len(records), fields=fields,
                       is_bigendian=False, point_step=records.dtype.itemsize,
                       row_step=records.dtype.itemsize * len(records), data=data,
                       is_dense=True)


def cloud_to_records(msg, layout=None, required=()):
    """PointCloud2 → structured array with the message's named fields.

    Parameters
    ----------
    msg : sensor_msgs/PointCloud2
    layout : numpy.dtype, optional
        The documented layout of the topic (:mod:`vlc_common.core.records`): a field of
        the message named like one of the layout must have its type (the offsets may
        differ; fields the layout does not name are read as they are), and the cloud
        must be little endian, as the layouts are.
    required : sequence of str
        Fields the message must have (also when it has no point).

    Raises ValueError, naming the problem, for an unknown field type, a field count
    below 1, fields that overlap, a field outside the point, a repeated field name,
    data not exactly ``width·height·point_step`` bytes, an organised cloud (``height`` >
    1) with row padding (``row_step`` other than ``width·point_step``), and, with
    ``layout``, a big-endian cloud or a field of the wrong type.
    """
    key = (bool(msg.is_bigendian), int(msg.point_step), layout, tuple(required),
           tuple((f.name, f.offset, f.datatype, f.count) for f in msg.fields))
    dtype = _DTYPES.get(key)
    if dtype is None:
        dtype = _cloud_dtype(msg, layout, required)
        if len(_DTYPES) >= _CACHE_SIZE:
            _DTYPES.clear()
        _DTYPES[key] = dtype
    n = int(msg.width) * int(msg.height)
    size = len(msg.data)
    if int(msg.height) > 1 and int(msg.row_step) != int(msg.width) * int(msg.point_step):
        raise ValueError(f'row_step {msg.row_step} B is not width {msg.width} x point_step '
                         f'{msg.point_step} B')
    if size != n * int(msg.point_step):
        raise ValueError(f'point cloud data {size} B for {n} points x {msg.point_step} B')
    if dtype.names is None:
        return np.zeros(0)
    return np.frombuffer(bytes(msg.data), dtype=dtype, count=n)


def _cloud_dtype(msg, layout, required):
    """The record dtype :func:`cloud_to_records` reads ``msg`` with (no field: a plain
    float dtype); raises ValueError for a description it refuses.
    """
    if layout is not None and msg.is_bigendian:
        raise ValueError('big-endian cloud: the layout is little endian')
    endian = '>' if msg.is_bigendian else '<'
    names, formats, offsets = [], [], []
    for f in msg.fields:
        if f.datatype not in _NUMPY_TYPE:
            raise ValueError(f'field {f.name!r}: unknown PointField datatype {f.datatype}')
        if f.count < 1:
            raise ValueError(f'field {f.name!r}: count {f.count}')
        if f.name in names:
            raise ValueError(f'field {f.name!r} appears twice')
        fmt = np.dtype(endian + _NUMPY_TYPE[f.datatype])
        if layout is not None and layout.names and f.name in layout.names:
            want = layout.fields[f.name][0]
            if fmt.str[1:] != want.str[1:] or f.count != 1:
                raise ValueError(f'field {f.name!r} is {_NUMPY_TYPE[f.datatype]} x {f.count}, '
                                 f'the layout has {want.str[1:]} x 1')
        if f.count > 1:
            fmt = np.dtype((fmt, (f.count,)))
        if f.offset + fmt.itemsize > msg.point_step:
            raise ValueError(f'field {f.name!r} ends beyond point_step {msg.point_step}')
        names.append(f.name)
        formats.append(fmt)
        offsets.append(f.offset)
    spans = sorted((o, o + fmt.itemsize, n) for o, fmt, n in zip(offsets, formats, names))
    for (_, end, first), (start, _, second) in zip(spans, spans[1:]):
        if start < end:
            raise ValueError(f'fields {first!r} and {second!r} overlap')
    missing = [n for n in required if n not in names]
    if missing:
        raise ValueError(f'missing fields {", ".join(missing)}')
    if not names:
        return np.dtype(float)
    return np.dtype({'names': names, 'formats': formats, 'offsets': offsets,
                     'itemsize': msg.point_step})
