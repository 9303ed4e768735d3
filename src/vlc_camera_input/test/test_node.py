"""sbs_splitter_node in-process: SBS frames in (raw and JPEG), stereo images and
camera_info out with the input's stamp; bad frames skipped and counted; calibration
changes at run time. Every test runs the node and a probe in their own rclpy Context on
an isolated DDS domain (``ros_env``).
"""
import time

import cv2
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
import numpy as np
import pytest
import rclpy
from rclpy.context import Context
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import CameraInfo, CompressedImage, Image

from vlc_camera_input.sbs_splitter_node import SbsSplitterNode
from vlc_common.core.calibration import StereoCalibration, save_ros_stereo
from vlc_common.core.camera import CameraIntrinsics, StereoCameraModel, StereoRig

pytestmark = pytest.mark.ros

W, H = 96, 48
STAMP_NS = 1704067200 * 10 ** 9 + 123_456_789


def write_calibration(folder, width=W, height=H, fx=80.0, baseline_m=0.12):
    pair = StereoCameraModel.from_rig(StereoRig(CameraIntrinsics(
        width, height, fx, fx, (width - 1) / 2, (height - 1) / 2), baseline_m))
    left, right = folder / 'left.yaml', folder / 'right.yaml'
    save_ros_stereo(StereoCalibration(pair.left, pair.right, camera_name='sbs'), left, right)
    return [str(left), str(right)]


def sbs_frame(seed):
    rng = np.random.default_rng(seed)
    return rng.integers(0, 255, size=(H, 2 * W), dtype=np.uint8)


def image_msg(array, stamp_ns=STAMP_NS, encoding='mono8'):
    msg = Image(encoding=encoding, height=array.shape[0], width=array.shape[1],
                step=array[0].nbytes)
    msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(stamp_ns, 10 ** 9)
    msg.header.frame_id = 'sbs_camera'
    msg.data = np.ascontiguousarray(array).tobytes()
    return msg


def jpeg_msg(array, stamp_ns=STAMP_NS, quality=95, data=None):
    msg = CompressedImage(format='jpeg')
    msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(stamp_ns, 10 ** 9)
    if data is None:
        data = cv2.imencode('.jpg', array, [cv2.IMWRITE_JPEG_QUALITY, quality])[1].tobytes()
    msg.data = data
    return msg


class Harness:
    def __init__(self, ctx, **params):
        overrides = [Parameter('diagnostics_period_s', value=0.1)] + [
            Parameter(k, value=v) for k, v in params.items()]
        self.node = SbsSplitterNode(context=ctx, parameter_overrides=overrides)
        self.probe = Node('probe', context=ctx)
        qos = QoSProfile(depth=5, reliability=ReliabilityPolicy.RELIABLE)
        self.pub_raw = self.probe.create_publisher(Image, 'image_raw', qos)
        self.pub_jpeg = self.probe.create_publisher(CompressedImage, 'image_raw/compressed',
                                                    qos)
        self.images = {'left': [], 'right': []}
        self.infos = {'left': [], 'right': []}
        self.diags = []
        for side in ('left', 'right'):
            self.probe.create_subscription(Image, f'stereo/{side}/image_raw',
                                           self.images[side].append, qos)
        self.probe.create_subscription(DiagnosticArray, 'diagnostics', self.diags.append, 50)
        self.executor = SingleThreadedExecutor(context=ctx)
        self.executor.add_node(self.node)
        self.executor.add_node(self.probe)
        pub = self.pub_raw if params.get('input', 'raw') == 'raw' else self.pub_jpeg
        self.spin_until(lambda: pub.get_subscription_count() > 0
                        and self.node.pub_images[1].get_subscription_count() > 0)

    def subscribe_infos(self):
        """A late subscriber (transient local): gets the last camera_info at once."""
        latched = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                             durability=DurabilityPolicy.TRANSIENT_LOCAL)
        for side in ('left', 'right'):
            self.probe.create_subscription(CameraInfo, f'stereo/{side}/camera_info',
                                           self.infos[side].append, latched)

    def spin_until(self, done, timeout=10.0):
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            self.executor.spin_once(timeout_sec=0.02)
            if done():
                return True
        return False

    def send(self, msg, expect_output=True):
        before = len(self.images['right'])
        (self.pub_raw if isinstance(msg, Image) else self.pub_jpeg).publish(msg)
        if expect_output:
            assert self.spin_until(lambda: len(self.images['right']) > before), 'no output'
        else:
            self.spin_until(lambda: False, timeout=0.3)
            return None
        return [self.images[s][-1] for s in ('left', 'right')]

    def stats(self):
        count = len(self.diags)
        self.spin_until(lambda: len(self.diags) > count + 1)
        status = self.diags[-1].status[0]
        return {kv.key: kv.value for kv in status.values}, status

    def close(self):
        self.executor.shutdown()
        self.node.destroy_node()
        self.probe.destroy_node()


@pytest.fixture
def harness(ros_env, tmp_path):
    ctx = Context()
    rclpy.init(context=ctx)
    made = []

    def make(**params):
        params.setdefault('calibration_files', write_calibration(tmp_path))
        made.append(Harness(ctx, **params))
        return made[-1]
    yield make
    for h in made:
        h.close()
    rclpy.try_shutdown(context=ctx)


def as_array(msg):
    assert msg.encoding == 'mono8' and msg.step == msg.width
    return np.frombuffer(bytes(msg.data), np.uint8).reshape(msg.height, msg.width)


def test_raw_frames_are_split_with_their_stamp_frames_and_calibration(harness):
    h = harness(left_frame_id='cam_l', right_frame_id='cam_r')
    frame = sbs_frame(1)
    left, right = h.send(image_msg(frame))
    assert np.array_equal(as_array(left), frame[:, :W])
    assert np.array_equal(as_array(right), frame[:, W:])
    for msg, frame_id in ((left, 'cam_l'), (right, 'cam_r')):
        assert (msg.header.stamp.sec, msg.header.stamp.nanosec) == divmod(STAMP_NS, 10 ** 9)
        assert msg.header.frame_id == frame_id
    # camera_info: transient local, the calibration's, same header as the image
    h.subscribe_infos()
    assert h.spin_until(lambda: h.infos['left'] and h.infos['right'])
    left_info, right_info = h.infos['left'][-1], h.infos['right'][-1]
    assert (left_info.width, left_info.height) == (W, H)
    assert right_info.p[3] == pytest.approx(-80.0 * 0.12)
    assert right_info.header == right.header and left_info.header == left.header
    # bgr8 and yuyv frames give the same halves
    bgr = np.repeat(frame[:, :, None], 3, axis=2)
    left, _ = h.send(image_msg(bgr, STAMP_NS + 33_333_333, 'bgr8'))
    assert np.array_equal(as_array(left), frame[:, :W])
    yuyv = np.stack([frame, np.full_like(frame, 128)], axis=2)
    _, right = h.send(image_msg(yuyv, STAMP_NS + 66_666_667, 'yuyv'))
    assert np.array_equal(as_array(right), frame[:, W:])
    stats, status = h.stats()
    assert stats['frames_split'] == '3' and status.level == DiagnosticStatus.OK, stats
    assert stats['row_time_s'] == '3e-05' and stats['readout_ms'] == '1.435'


def test_swap_halves(harness):
    h = harness(swap_halves=True)
    frame = sbs_frame(2)
    left, right = h.send(image_msg(frame))
    assert np.array_equal(as_array(left), frame[:, W:])
    assert np.array_equal(as_array(right), frame[:, :W])


def test_jpeg_frames_are_decoded_and_split(harness):
    h = harness(input='compressed')
    v, u = np.mgrid[0:H, 0:2 * W]
    frame = (40 + 150 * np.exp(-((u % W - 40.0) ** 2 + (v - 24.0) ** 2) / 50.0)).astype(np.uint8)
    left, right = h.send(jpeg_msg(np.repeat(frame[:, :, None], 3, axis=2)))
    for msg, half in ((left, frame[:, :W]), (right, frame[:, W:])):
        assert np.abs(as_array(msg).astype(int) - half).max() <= 4
        assert (msg.header.stamp.sec, msg.header.stamp.nanosec) == divmod(STAMP_NS, 10 ** 9)


def test_bad_frames_are_skipped_counted_and_the_node_keeps_splitting(harness):
    h = harness()
    good = sbs_frame(3)
    bad = {
        'skipped_size': image_msg(np.zeros((H, 2 * W + 8), np.uint8)),
        'skipped_odd_width': image_msg(np.zeros((H, 2 * W + 1), np.uint8)),
        'skipped_encoding': image_msg(np.zeros((H, 2 * W), np.uint8), encoding='bayer_rggb8'),
    }
    tall = image_msg(np.zeros((H + 2, 2 * W), np.uint8))
    for msg in list(bad.values()) + [tall]:
        h.send(msg, expect_output=False)
    left, _ = h.send(image_msg(good, STAMP_NS + 10))
    assert np.array_equal(as_array(left), good[:, :W])
    stats, status = h.stats()
    assert stats['skipped_size'] == '2', stats
    assert stats['skipped_odd_width'] == '1' and stats['skipped_encoding'] == '1'
    assert stats['frames_split'] == '1'
    assert status.level == DiagnosticStatus.WARN and '4 frames skipped' in status.message
    assert len(h.images['left']) == 1


def test_corrupt_jpeg_is_skipped(harness):
    h = harness(input='compressed')
    data = cv2.imencode('.jpg', sbs_frame(4), [cv2.IMWRITE_JPEG_QUALITY, 95])[1].tobytes()
    h.send(jpeg_msg(None, data=data[:len(data) // 3]), expect_output=False)
    h.send(jpeg_msg(None, data=b'\x00' * 500), expect_output=False)
    h.send(jpeg_msg(sbs_frame(4), STAMP_NS + 10))
    stats, _ = h.stats()
    assert stats['skipped_corrupt'] == '2' and stats['frames_split'] == '1', stats


def test_frames_closer_than_the_readout_are_reported(harness):
    h = harness(row_time_s=1e-3)        # 48 rows: a readout of 47.025 ms
    h.send(image_msg(sbs_frame(5), STAMP_NS))
    h.send(image_msg(sbs_frame(6), STAMP_NS + 33_333_333))
    stats, status = h.stats()
    assert stats['timing_inconsistent'] == '1' and stats['frames_split'] == '2'
    assert stats['frame_interval_ms_min'] == '33.333'
    assert status.level == DiagnosticStatus.WARN and 'readout' in status.message


def test_calibration_set_at_run_time_refused_when_bad_taken_when_good(harness, tmp_path):
    h = harness()
    broken = (tmp_path / 'left.yaml').read_text().replace('camera_matrix:', 'camera_matrx:')
    (tmp_path / 'broken.yaml').write_text(broken + 'camera_matrix: [1, 2]\n')
    result = h.node.set_parameters([Parameter('calibration_files', value=[
        str(tmp_path / 'broken.yaml'), str(tmp_path / 'right.yaml')])])[0]
    assert not result.successful
    assert 'broken.yaml: camera_matrix: expected a mapping' in result.reason
    h.send(image_msg(sbs_frame(7)))                 # still the old calibration
    other = tmp_path / 'wide'
    other.mkdir()
    files = write_calibration(other, width=2 * W, height=H)
    assert h.node.set_parameters([Parameter('calibration_files', value=files)])[0].successful
    h.send(image_msg(sbs_frame(8), STAMP_NS + 10), expect_output=False)   # now too narrow
    left, _ = h.send(image_msg(np.zeros((H, 4 * W), np.uint8), STAMP_NS + 20))
    assert left.width == 2 * W
    stats, _ = h.stats()
    assert stats['calibration_refused'] == '1' and stats['skipped_size'] == '1', stats


def test_rectify_publishes_the_rectified_camera_info(harness, tmp_path):
    h = harness(rectify=True)
    h.send(image_msg(sbs_frame(9)))
    h.subscribe_infos()
    assert h.spin_until(lambda: h.infos['right'])
    info = h.infos['right'][-1]
    assert list(info.d) == [0.0] * 5 and list(info.r) == [1.0, 0, 0, 0, 1.0, 0, 0, 0, 1.0]
