"""view_picture: a recorded bag (written here with seeded records) → the scene the marker
node would show → a PNG with the top and side views.
"""
import numpy as np
import pytest

from vlc_bags.bagio import write_bag
from vlc_bags.typesupport import jazzy_typestore
from vlc_common.core.lamp_map import LampMap, default_lamp_map_path
from vlc_common.core.records import LAMP_DTYPE, PAIR_DTYPE
from vlc_common.core.vehicle import CameraMount
from vlc_view import picture

STORE = jazzy_typestore()
T = STORE.types
EPOCH_NS = 1704067200 * 10 ** 9


def _header(ns, frame):
    return T['std_msgs/msg/Header'](stamp=T['builtin_interfaces/msg/Time'](
        sec=ns // 10 ** 9, nanosec=ns % 10 ** 9), frame_id=frame)


def _cloud(ns, records):
    fields = [T['sensor_msgs/msg/PointField'](
        name=name, offset=records.dtype.fields[name][1],
        datatype={'f8': 8, 'f4': 7, 'u4': 6}[records.dtype.fields[name][0].str[1:]], count=1)
        for name in records.dtype.names]
    return T['sensor_msgs/msg/PointCloud2'](
        header=_header(ns, 'camera_left_optical_frame'), height=1, width=len(records),
        fields=fields, is_bigendian=False, point_step=records.dtype.itemsize,
        row_step=records.nbytes, data=np.frombuffer(records.tobytes(), np.uint8),
        is_dense=True)


def _pose(ns, x, sigma, truth=False):
    pose = T['geometry_msgs/msg/Pose'](
        position=T['geometry_msgs/msg/Point'](x=x, y=0.0, z=0.0),
        orientation=T['geometry_msgs/msg/Quaternion'](x=0.0, y=0.0, z=0.0, w=1.0))
    if truth:
        return T['geometry_msgs/msg/PoseStamped'](header=_header(ns, 'map'), pose=pose)
    cov = np.zeros(36)
    cov[0] = cov[7] = cov[14] = sigma ** 2
    return T['geometry_msgs/msg/PoseWithCovarianceStamped'](
        header=_header(ns, 'map'), pose=T['geometry_msgs/msg/PoseWithCovariance'](
            pose=pose, covariance=cov))


@pytest.fixture(scope='module')
def bag(tmp_path_factory):
    """A train at 22 m/s from x = 44 m for 0.5 s: poses (2 cm ahead of the truth), lamp
    0x1005 identified from 0.2 s on, spot pairs in every frame.
    """
    rng = np.random.default_rng(3)
    msgs = []
    for k in range(26):                                  # truth and poses at 50 Hz
        ns = EPOCH_NS + k * 20_000_000
        x = 44.0 + 22.0 * k * 0.02
        msgs.append(('/ground_truth/pose', 'geometry_msgs/msg/PoseStamped', ns,
                     _pose(ns, x, 0.0, truth=True)))
        msgs.append(('/train/pose_with_covariance',
                     'geometry_msgs/msg/PoseWithCovarianceStamped', ns + 1,
                     _pose(ns, x + 0.02, 0.01)))
    for k in range(15):                                  # frames at 30 Hz
        ns = EPOCH_NS + k * 33_333_333
        u, v = 600.0 + rng.normal(0, 1), 300.0
        lamp = np.zeros(1, LAMP_DTYPE)
        lamp['uid'], lamp['state'] = (0x1005, 2) if k >= 6 else (0, 1)
        lamp['left_u'], lamp['left_v'] = u + 2, v
        pair = np.zeros(1, PAIR_DTYPE)
        pair['u_left'], pair['v_left'], pair['disparity'] = u, v, 20.0
        msgs.append(('/vlc/lamps', 'sensor_msgs/msg/PointCloud2', ns + 5, _cloud(ns, lamp)))
        msgs.append(('/spots/pairs', 'sensor_msgs/msg/PointCloud2', ns + 6, _cloud(ns, pair)))
    msgs.sort(key=lambda m: m[2])
    path = tmp_path_factory.mktemp('view') / 'recording'
    write_bag(path, msgs)
    return path


def test_scene_from_a_bag(bag):
    lamp_map = LampMap.load(default_lamp_map_path())
    scene, truth = picture.scene_from_bag(bag, lamp_map, CameraMount())
    assert scene.train.position_m[0] == pytest.approx(44.0 + 22.0 * 0.5 + 0.02)
    assert truth == pytest.approx([55.0, 0.0, 0.0])
    assert scene.ray_uids == [0x1005] and scene.fix_stamp_ns == EPOCH_NS + 14 * 33_333_333
    assert len(scene.history_m) == 26
    # up to 0.1 s after the first pose: the lamp is not confirmed yet, no ray
    early, _ = picture.scene_from_bag(bag, lamp_map, CameraMount(), at_s=0.1)
    assert early.ray_uids == [] and len(early.history_m) == 6


def test_view_picture_writes_a_png(bag, tmp_path):
    out = tmp_path / 'images' / 'view.png'
    assert picture.main([str(bag), '-o', str(out), '--dpi', '40']) == 0
    data = out.read_bytes()
    assert data[:8] == b'\x89PNG\r\n\x1a\n' and len(data) > 5000


def test_view_picture_refuses_a_bag_without_poses(tmp_path):
    path = tmp_path / 'empty'
    write_bag(path, [('/ground_truth/pose', 'geometry_msgs/msg/PoseStamped', EPOCH_NS,
                      _pose(EPOCH_NS, 1.0, 0.0, truth=True))])
    assert picture.main([str(path), '-o', str(tmp_path / 'x.png')]) == 2
