"""sensor_msgs/PointCloud2 ↔ numpy structured arrays, shared by every node of the graph.

Per-lamp records travel as PointCloud2 with one named field per column (one point per
lamp, ARCHITECTURE.md). The rig, the decoder, the spot locator and the localizer all use
these two functions, so a record written by one node reads back field for field in
another.
"""
import array

import numpy as np
from sensor_msgs.msg import PointCloud2, PointField

_NUMPY_TYPE = {PointField.INT8: 'i1', PointField.UINT8: 'u1', PointField.INT16: 'i2',
               PointField.UINT16: 'u2', PointField.INT32: 'i4', PointField.UINT32: 'u4',
               PointField.FLOAT32: 'f4', PointField.FLOAT64: 'f8'}
_POINTFIELD_TYPE = {np.dtype('<' + code).str: datatype
                    for datatype, code in _NUMPY_TYPE.items()}


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


def cloud_to_records(msg):
    """PointCloud2 → structured array with the message's named fields.

    Raises ValueError for an unknown field type, a field outside the point, or data
    shorter than ``width·height`` points.
    """
    endian = '>' if msg.is_bigendian else '<'
    names, formats, offsets = [], [], []
    for f in msg.fields:
        if f.datatype not in _NUMPY_TYPE:
            raise ValueError(f'field {f.name!r}: unknown PointField datatype {f.datatype}')
        fmt = np.dtype(endian + _NUMPY_TYPE[f.datatype])
        if f.count > 1:
            fmt = np.dtype((fmt, (f.count,)))
        if f.offset + fmt.itemsize > msg.point_step:
            raise ValueError(f'field {f.name!r} ends beyond point_step {msg.point_step}')
        names.append(f.name)
        formats.append(fmt)
        offsets.append(f.offset)
    if not names:
        return np.zeros(0)
    dtype = np.dtype({'names': names, 'formats': formats, 'offsets': offsets,
                      'itemsize': msg.point_step})
    n = int(msg.width) * int(msg.height)
    buf = np.frombuffer(bytes(msg.data), dtype=np.uint8)
    if buf.size < n * msg.point_step:
        raise ValueError(f'point cloud data {buf.size} B < {n} points x {msg.point_step} B')
    return np.frombuffer(buf[:n * msg.point_step].tobytes(), dtype=dtype)
