"""PointCloud2 ↔ records: round trip, and every malformed cloud refused with its reason."""
import math

import numpy as np
import pytest
from sensor_msgs.msg import PointField
from std_msgs.msg import Header

from vlc_common.core.records import LAMP_DTYPE, PAIR_DTYPE
from vlc_common.pointcloud import cloud_to_records, records_to_cloud


def _cloud(dtype, n=1):
    rec = np.zeros(n, dtype=dtype)
    for name in dtype.names:
        rec[name] = np.arange(n) + 1
    return rec, records_to_cloud(rec, Header(frame_id='camera_left_optical_frame'))


@pytest.mark.parametrize('layout', [PAIR_DTYPE, LAMP_DTYPE], ids=['pairs', 'lamps'])
def test_round_trip_with_the_layout(layout):
    rec, msg = _cloud(layout, 3)
    out = cloud_to_records(msg, layout, required=layout.names[:2])
    for name in layout.names:
        np.testing.assert_array_equal(out[name], rec[name])
    empty = cloud_to_records(_cloud(layout, 0)[1], layout, required=layout.names[:2])
    assert empty.size == 0 and empty.dtype.names == layout.names


def _float64_for_float32(msg):
    for f in msg.fields:
        if f.datatype == PointField.FLOAT32:
            f.datatype = PointField.FLOAT64


def _point_step(msg):
    msg.point_step -= 8
    msg.row_step = msg.point_step * msg.width
    msg.data = bytes(msg.data)[:msg.row_step]


def _data_length(msg):
    msg.width += 1
    msg.row_step = msg.point_step * msg.width


@pytest.mark.parametrize('layout', [PAIR_DTYPE, LAMP_DTYPE], ids=['pairs', 'lamps'])
@pytest.mark.parametrize('spoil, match', [
    # the fault injector's cloud kinds (vlc_evaluation.fault_kinds)
    (_float64_for_float32, 'the layout has f4'),
    (lambda m: setattr(m, 'fields', m.fields[1:]), 'missing fields'),
    (_point_step, 'beyond point_step'),
    (_data_length, 'point cloud data'),
    (lambda m: setattr(m, 'is_bigendian', True), 'big-endian'),
    (lambda m: setattr(m.fields[1], 'count', 0), 'count 0'),
    (lambda m: setattr(m.fields[1], 'offset', 2), 'overlap'),
    (lambda m: setattr(m.fields[1], 'datatype', 42), 'unknown PointField datatype'),
    (lambda m: setattr(m, 'data', bytes(m.data) + bytes(8)), 'point cloud data'),
], ids=['float64_for_float32', 'missing_field', 'wrong_point_step', 'data_length',
        'bigendian', 'count_zero', 'overlap', 'unknown_type', 'trailing_bytes'])
def test_malformed_clouds_are_refused(layout, spoil, match):
    _, msg = _cloud(layout, 1)
    spoil(msg)
    with pytest.raises(ValueError, match=match):
        cloud_to_records(msg, layout, required=layout.names[:1])


def test_without_a_layout_any_consistent_cloud_reads_and_nan_values_pass():
    """NaN values are values: the consumer decides (the localizer skips the record)."""
    rec, msg = _cloud(PAIR_DTYPE, 2)
    rec['u_left'] = math.nan
    msg = records_to_cloud(rec, msg.header)
    assert np.isnan(cloud_to_records(msg)['u_left']).all()
    big = np.zeros(1, dtype=[('a', '>f8')])
    big['a'] = 2.5
    msg = records_to_cloud(np.zeros(1, dtype=[('a', '<f8')]), Header())
    msg.is_bigendian, msg.data = True, big.tobytes()
    assert cloud_to_records(msg)['a'][0] == 2.5            # generic: big endian honoured


def test_a_known_description_is_still_checked_per_message():
    """The dtype of a description is derived once; the data length is checked on every
    message, and a description that differs in one field's type is derived (and refused)
    afresh.
    """
    rec, msg = _cloud(PAIR_DTYPE, 2)
    assert cloud_to_records(msg, PAIR_DTYPE).shape == (2,)
    msg.data = bytes(msg.data) + bytes(8)
    with pytest.raises(ValueError, match='point cloud data'):
        cloud_to_records(msg, PAIR_DTYPE)
    _, msg = _cloud(PAIR_DTYPE, 2)
    msg.fields[0].datatype = PointField.FLOAT32
    with pytest.raises(ValueError, match='the layout has'):
        cloud_to_records(msg, PAIR_DTYPE)
