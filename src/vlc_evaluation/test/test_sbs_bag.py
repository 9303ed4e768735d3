"""sbs_bag convert: a seeded split stereo bag becomes one SBS frame per stereo pair whose
halves (through the splitter's own conversion) are the split images, exactly for the
lossless encodings and within a few grey levels for JPEG; the calibration files it writes
read back as the bag's camera_info; every other topic is copied.
"""
import numpy as np
import pytest

from vlc_bags.bagio import bag_summary, open_bag, qos_profile, write_bag
from vlc_bags.typesupport import jazzy_typestore
from vlc_camera_input.conversions import compressed_to_grey, image_to_grey
from vlc_camera_input.core.sbs import split
from vlc_common.core.calibration import load_stereo_calibration
from vlc_common.core.camera import CameraIntrinsics, StereoRig
from vlc_common.stamps import NS_PER_S
from vlc_evaluation import sbs_bag

STORE = jazzy_typestore()
T = STORE.types
W, H = 80, 48
EPOCH_NS = 1704067200 * NS_PER_S
RIG = StereoRig(CameraIntrinsics(W, H, 70.0, 70.0, 39.5, 23.5), baseline_m=0.12)


def _header(ns, frame_id):
    sec, nanosec = divmod(ns, NS_PER_S)
    return T['std_msgs/msg/Header'](stamp=T['builtin_interfaces/msg/Time'](
        sec=sec, nanosec=nanosec), frame_id=frame_id)


def _image(ns, array, side):
    return T['sensor_msgs/msg/Image'](header=_header(ns, f'camera_{side}_optical_frame'),
                                      height=H, width=W, encoding='mono8', is_bigendian=0,
                                      step=W, data=array.ravel())


def _info(ns, info, side):
    return T['sensor_msgs/msg/CameraInfo'](
        header=_header(ns, f'camera_{side}_optical_frame'), height=H, width=W,
        distortion_model='plumb_bob', d=np.zeros(5), k=np.ravel(info['K']),
        r=np.ravel(info['R']), p=np.ravel(info['P']),
        binning_x=0, binning_y=0, roi=T['sensor_msgs/msg/RegionOfInterest'](
            x_offset=0, y_offset=0, height=0, width=0, do_rectify=False))


@pytest.fixture(scope='module')
def split_bag(tmp_path_factory):
    """Three stereo pairs (seeded noise and a striped spot), camera_info and 400 Hz IMU."""
    rng = np.random.default_rng(11)
    msgs, pairs = [], []
    infos = RIG.camera_info_dicts()
    for k in range(3):
        ns = EPOCH_NS + k * 33_333_333
        images = []
        for side, shift in (('left', 0), ('right', 9)):
            array = rng.integers(0, 60, size=(H, W), dtype=np.uint8)
            array[20:30, 30 - shift:42 - shift][::3] = 240
            images.append(array)
            msgs.append((f'/stereo/{side}/image_raw', 'sensor_msgs/msg/Image', ns,
                         _image(ns, array, side)))
            msgs.append((f'/stereo/{side}/camera_info', 'sensor_msgs/msg/CameraInfo', ns,
                         _info(ns, infos[side == 'right'], side)))
        pairs.append(images)
    for k in range(40):
        ns = EPOCH_NS + k * 2_500_000
        msgs.append(('/imu/data_raw', 'sensor_msgs/msg/Imu', ns, T['sensor_msgs/msg/Imu'](
            header=_header(ns, 'imu_link'),
            orientation=T['geometry_msgs/msg/Quaternion'](x=0.0, y=0.0, z=0.0, w=1.0),
            orientation_covariance=np.full(9, -1.0),
            angular_velocity=T['geometry_msgs/msg/Vector3'](x=0.0, y=0.0, z=0.01 * k),
            angular_velocity_covariance=np.zeros(9),
            linear_acceleration=T['geometry_msgs/msg/Vector3'](x=0.0, y=0.0, z=9.81),
            linear_acceleration_covariance=np.zeros(9))))
    msgs.sort(key=lambda m: m[2])
    path = tmp_path_factory.mktemp('split') / 'split'
    write_bag(path, msgs, offered_qos={
        '/stereo/left/image_raw': [qos_profile('reliable', depth=5)],
        '/imu/data_raw': [qos_profile('best_effort', depth=5)]})
    return path, pairs


def _frames(path):
    return [(topic, msg) for topic, _, _, msg in open_bag(path)
            if topic in (sbs_bag.RAW_TOPIC, sbs_bag.COMPRESSED_TOPIC)]


@pytest.mark.parametrize('encoding', ['mono8', 'bgr8', 'rgb8', 'yuyv', 'uyvy'])
def test_lossless_encodings_give_back_the_split_images_exactly(split_bag, tmp_path, encoding):
    path, pairs = split_bag
    done = sbs_bag.convert(path, tmp_path / 'sbs', encoding)
    assert done['frames'] == 3 and done['topic'] == '/image_raw'
    frames = _frames(tmp_path / 'sbs')
    assert len(frames) == 3
    for k, ((_, msg), (left, right)) in enumerate(zip(frames, pairs)):
        assert (msg.width, msg.height) == (2 * W, H)
        assert msg.encoding == sbs_bag.ENCODINGS[encoding]
        assert msg.header.stamp.nanosec == k * 33_333_333 and msg.header.frame_id == 'camera'
        a, b = split(image_to_grey(msg), (W, H))
        assert np.array_equal(a, left) and np.array_equal(b, right)


def test_jpeg_frames_keep_the_luma_within_a_few_levels(split_bag, tmp_path):
    path, pairs = split_bag
    done = sbs_bag.convert(path, tmp_path / 'sbs', 'jpeg', jpeg_quality=95)
    assert done['topic'] == '/image_raw/compressed'
    frames = _frames(tmp_path / 'sbs')
    assert len(frames) == 3
    for (_, msg), (left, right) in zip(frames, pairs):
        assert msg.format == 'jpeg'
        halves = split(compressed_to_grey(msg), (W, H))
        for got, want in zip(halves, (left, right)):
            diff = np.abs(got.astype(int) - want)
            assert 0 < diff.mean() < 4.0, diff.mean()


def test_calibration_files_and_copied_topics(split_bag, tmp_path):
    path, _ = split_bag
    done = sbs_bag.convert(path, tmp_path / 'sbs', 'mono8')
    infos = RIG.camera_info_dicts()
    for files in (done['calibration']['ros'], done['calibration']['opencv']):
        calibration = load_stereo_calibration(files)
        assert calibration.image_size == (W, H)
        assert calibration.baseline_m == pytest.approx(0.12, abs=1e-12)
        for got, want in zip(calibration.camera_info_dicts(), infos):
            assert np.allclose(got['P'], want['P'], atol=1e-9)
    assert files == sbs_bag.calibration_files(tmp_path / 'sbs', 'opencv')
    topics = {t.topic: t for t in bag_summary(tmp_path / 'sbs')}
    assert set(topics) == {'/image_raw', '/imu/data_raw'}
    assert topics['/imu/data_raw'].message_count == 40
    split_qos = {t.topic: t.offered_qos for t in bag_summary(path)}
    assert topics['/image_raw'].offered_qos == split_qos['/stereo/left/image_raw']
    assert len(topics['/image_raw'].offered_qos) == 1
    imu = [m for t, _, _, m in open_bag(tmp_path / 'sbs', ['/imu/data_raw'])]
    assert imu[7].angular_velocity.z == pytest.approx(0.07)


def test_refuses_a_bag_without_stereo_images(tmp_path, split_bag):
    path, _ = split_bag
    sbs_bag.convert(path, tmp_path / 'sbs', 'mono8')
    with pytest.raises(ValueError, match='not a split stereo sensor bag'):
        sbs_bag.convert(tmp_path / 'sbs', tmp_path / 'again', 'mono8')
    assert sbs_bag.main(['convert', str(tmp_path / 'sbs'), str(tmp_path / 'x')]) == 2
