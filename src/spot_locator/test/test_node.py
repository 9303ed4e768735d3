"""spot_locator_node in-process: topics, pairing by stamp, bad input, odometry speed."""
import time

from diagnostic_msgs.msg import DiagnosticArray
from nav_msgs.msg import Odometry
import numpy as np
import pytest
import rclpy
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import CameraInfo, Image, PointCloud2

from spot_locator import conversions
from spot_locator.core import synth
from spot_locator.spot_locator_node import SpotLocatorNode
from vlc_common.core.camera import StereoRig

pytestmark = pytest.mark.ros

RIG = StereoRig()
EPOCH_NS = 1704067200 * 10 ** 9
FRAME_NS = 33_333_333


def _scene(seed=0, along_m=3.0):
    """A striped, noisy stereo pair of one lamp ``along_m`` ahead (uint8 images)."""
    rng = np.random.default_rng(seed)
    K = RIG.intrinsics.K
    shape = (RIG.intrinsics.height, RIG.intrinsics.width)
    normal = RIG.R_base_cam.T @ np.array([0.0, -1.0, 0.0])
    level = synth.random_chip_level(rng)
    images = []
    for cam in (0, 1):
        C = RIG.to_camera(np.array([[along_m, 2.5, 1.4]]), np.zeros(3), np.eye(3), cam)[0]
        img = synth.render_disc(shape, K, C, normal, 0.1, radiance=150.0, level=level,
                                exposure=synth.Exposure(n_time=2), supersample=3,
                                psf_sigma_px=0.7)
        images.append(synth.add_noise(img, rng, read_noise=1.5))
    return images


def _stamp(msg, k):
    ns = EPOCH_NS + k * FRAME_NS
    msg.header.stamp.sec, msg.header.stamp.nanosec = ns // 10 ** 9, ns % 10 ** 9
    return msg


def _image(arr, k, frame_id, encoding='mono8'):
    if encoding in ('rgb8', 'bgr8'):
        arr = np.repeat(arr[:, :, None], 3, axis=2)
    arr = np.ascontiguousarray(arr)
    msg = Image(height=arr.shape[0], width=arr.shape[1], encoding=encoding,
                step=arr.shape[1] * (3 if arr.ndim == 3 else 1), data=arr.tobytes())
    msg.header.frame_id = frame_id
    return _stamp(msg, k)


class Harness:
    """The node plus a probe node that plays the camera and listens to the outputs."""

    def __init__(self, ctx, **params):
        self.node = SpotLocatorNode(context=ctx, parameter_overrides=[
            Parameter(k, value=v) for k, v in params.items()])
        self.probe = Node('probe', context=ctx)
        images = QoSProfile(depth=5, reliability=ReliabilityPolicy.RELIABLE)
        latched = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                             durability=DurabilityPolicy.TRANSIENT_LOCAL)
        self.pub_img = [self.probe.create_publisher(Image, f'stereo/{s}/image_raw', images)
                        for s in ('left', 'right')]
        self.pub_info = [self.probe.create_publisher(CameraInfo, f'stereo/{s}/camera_info',
                                                     latched) for s in ('left', 'right')]
        self.pub_odom = self.probe.create_publisher(Odometry, 'train/odometry', 10)
        self.clouds, self.diags = [], []
        self.probe.create_subscription(PointCloud2, 'spots/pairs', self.clouds.append, 10)
        self.probe.create_subscription(DiagnosticArray, 'diagnostics', self.diags.append, 10)
        self.executor = SingleThreadedExecutor(context=ctx)
        self.executor.add_node(self.node)
        self.executor.add_node(self.probe)

    def spin_until(self, condition, timeout_s=10.0):
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline and not condition():
            self.executor.spin_once(timeout_sec=0.05)
        return condition()

    def send_infos(self):
        for i, info in enumerate(RIG.camera_info_dicts()):
            msg = CameraInfo(width=info['width'], height=info['height'],
                             k=np.ravel(info['K']).tolist(), r=np.ravel(info['R']).tolist(),
                             p=np.ravel(info['P']).tolist(), d=list(info['D']),
                             distortion_model=info['distortion_model'])
            msg.header.frame_id = ('camera_left_optical_frame', 'camera_right_optical_frame')[i]
            self.pub_info[i].publish(msg)
        assert self.spin_until(lambda: self.node._located is not None), 'camera_info not used'

    def send(self, left, right, wait_for_cloud=True):
        n = len(self.clouds)
        for pub, msg in zip(self.pub_img, (left, right)):
            if msg is not None:
                pub.publish(msg)
        if wait_for_cloud:
            assert self.spin_until(lambda: len(self.clouds) > n), 'no spots/pairs message'
        else:
            self.spin_until(lambda: False, timeout_s=0.5)

    def stats(self):
        # the first diagnostics taken after clearing may have been published before the
        # last frame was counted (waiting in the queue): the second one was not
        self.diags.clear()
        assert self.spin_until(lambda: len(self.diags) >= 2, timeout_s=5.0)
        return {kv.key: kv.value for kv in self.diags[-1].status[0].values}


@pytest.fixture
def harness(ros_env):
    ctx = rclpy.Context()
    rclpy.init(context=ctx)
    made = []

    def make(**params):
        params.setdefault('diagnostics_period_s', 0.2)
        h = Harness(ctx, **params)
        made.append(h)
        return h
    yield make
    for h in made:
        h.executor.shutdown()
        h.node.destroy_node()
        h.probe.destroy_node()
    rclpy.shutdown(context=ctx)


def test_node_publishes_one_pair_per_lamp_with_the_image_header(harness):
    h = harness()
    h.send_infos()
    left, right = _scene()
    h.send(_image(left, 1, 'camera_left_optical_frame'),
           _image(right, 1, 'camera_right_optical_frame'))
    cloud = h.clouds[-1]
    assert cloud.header.frame_id == 'camera_left_optical_frame'
    assert (cloud.header.stamp.sec, cloud.header.stamp.nanosec) == divmod(
        EPOCH_NS + FRAME_NS, 10 ** 9)
    rec = conversions.cloud_to_records(cloud)
    assert len(rec) == 1
    C = RIG.to_camera(np.array([[3.0, 2.5, 1.4]]), np.zeros(3), np.eye(3), 0)[0]
    truth = synth.project(RIG.intrinsics.K, C)[0]
    assert abs(rec['u_left'][0] - truth[0]) < 0.1
    assert abs(rec['disparity'][0] - 1040.0 * 0.12 / C[2]) < 0.05
    stats = h.stats()
    assert stats['frames'] == '1' and stats['pairs'] == '1'


def test_bad_input_is_skipped_with_a_warning_and_the_node_keeps_running(harness):
    h = harness()
    left, right = _scene(seed=1)
    lf, rf = 'camera_left_optical_frame', 'camera_right_optical_frame'
    # before camera_info: skipped
    h.send(_image(left, 1, lf), _image(right, 1, rf), wait_for_cloud=False)
    h.send_infos()
    bad = [
        (_image(left, 2, lf, 'mono8'), _image(right, 2, rf, 'mono8')),
    ]
    bad[0][0].encoding = 'yuv422'                                   # unknown encoding
    empty = Image(encoding='mono8')
    truncated = _image(left, 4, lf)
    truncated.data = truncated.data[:1000]
    bad += [(_stamp(empty, 3), _image(right, 3, rf)),               # empty image
            (truncated, _image(right, 4, rf)),                      # truncated data
            (_image(left, 5, lf), _image(right[:, :640], 5, rf)),   # size mismatch
            (_image(left, 6, lf), None)]                            # never paired
    for pair in bad:
        h.send(*pair, wait_for_cloud=False)
    assert h.clouds == []
    # colour images are converted; processing goes on
    h.send(_image(left, 7, lf, 'rgb8'), _image(right, 7, rf, 'bgr8'))
    assert len(conversions.cloud_to_records(h.clouds[-1])) == 1
    # an old stamp after a newer pair is out of order
    h.send(_image(left, 3, lf), _image(right, 3, rf), wait_for_cloud=False)
    h.send(_image(left, 8, lf), _image(right, 8, rf))
    assert [c.header.stamp.nanosec for c in h.clouds] == [
        (EPOCH_NS + k * FRAME_NS) % 10 ** 9 for k in (7, 8)]
    stats = h.stats()
    assert int(stats['no_camera_info']) == 1
    assert int(stats['bad_image']) == 3
    assert int(stats['size_mismatch']) == 1
    assert int(stats['unpaired']) >= 1
    assert int(stats['out_of_order']) >= 1
    assert stats['frames'] == '2'
    assert h.diags[-1].status[0].level != b'\x00'    # WARN: input was skipped


def test_a_bad_camera_info_or_a_lone_stray_stamp_leaves_the_node_as_it_was(harness):
    """camera_info with all-zero K/P, NaN in P, half the images' size (each once, latched
    like the camera's) and image pairs stamped 1970 and a year ahead: refused or dropped
    and counted; the geometry and the pairing stay, the next frames are located.
    """
    h = harness()
    h.send_infos()
    located = h.node._located
    left, right = _scene(seed=5)
    lf, rf = 'camera_left_optical_frame', 'camera_right_optical_frame'
    h.send(_image(left, 10, lf), _image(right, 10, rf))
    good = [h.node._infos.current[i] for i in (0, 1)]
    spoilt = []
    for change in ('zero', 'nan', 'size'):
        for i, info in enumerate(good):
            bad = CameraInfo(width=info.width, height=info.height, k=list(info.k),
                             r=list(info.r), p=list(info.p), d=list(info.d))
            if change == 'zero':
                bad.k, bad.p = [0.0] * 9, [0.0] * 12
            elif change == 'nan':
                bad.p[2] = float('nan')
            else:
                bad.width, bad.height = info.width // 2, info.height // 2
            h.pub_info[i].publish(bad)
            spoilt.append(bad)
        h.spin_until(lambda: False, timeout_s=0.3)
    assert h.node._located is located
    for k, stamp_ns in ((11, 0), (12, EPOCH_NS + 365 * 86400 * 10 ** 9)):
        stray_left, stray_right = _image(left, 0, lf), _image(right, 0, rf)
        for msg in (stray_left, stray_right):
            msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(stamp_ns, 10 ** 9)
        h.send(stray_left, stray_right, wait_for_cloud=False)
        h.send(_image(left, k, lf), _image(right, k, rf))
    assert [c.header.stamp.nanosec for c in h.clouds] == [
        (EPOCH_NS + k * FRAME_NS) % 10 ** 9 for k in (10, 11, 12)]
    stats = h.stats()
    assert stats['camera_info_refused'] == '4' and stats['camera_info_ignored'] == '0'
    assert stats['stamp_outliers'] == '4' and stats['stamp_resets'] == '0'
    assert stats['frames'] == '3'


def test_a_stamp_jumping_back_resets_the_pairing_and_the_replay_is_processed(harness):
    """A looped bag: stamps restart 3.3 s earlier; the node resets instead of dropping."""
    h = harness(backward_reset_s=1.0)
    h.send_infos()
    left, right = _scene(seed=4)
    lf, rf = 'camera_left_optical_frame', 'camera_right_optical_frame'
    for k in (100, 101):
        h.send(_image(left, k, lf), _image(right, k, rf))
    h.send(_image(left, 102, lf), None, wait_for_cloud=False)      # its partner never comes
    h.send(_image(left, 99, lf), _image(right, 99, rf), wait_for_cloud=False)   # 67 ms back
    assert len(h.clouds) == 2
    # the replay starts over: its first pair is held until a third image of the new time
    # base confirms it, then handed on with it (processed, or superseded by pair 2 when
    # both are complete at once: the node keeps up with the newest pair)
    h.send(_image(left, 1, lf), _image(right, 1, rf), wait_for_cloud=False)
    assert len(h.clouds) == 2
    h.send(_image(left, 2, lf), _image(right, 2, rf))
    assert h.spin_until(lambda: h.clouds[-1].header.stamp.nanosec
                        == (EPOCH_NS + 2 * FRAME_NS) % 10 ** 9)
    stamps = [c.header.stamp.sec * 10 ** 9 + c.header.stamp.nanosec for c in h.clouds]
    assert stamps in ([EPOCH_NS + k * FRAME_NS for k in (100, 101, 1, 2)],
                      [EPOCH_NS + k * FRAME_NS for k in (100, 101, 2)])
    assert len(conversions.cloud_to_records(h.clouds[-1])) == 1
    stats = h.stats()
    assert stats['stamp_resets'] == '1' and stats['stamp_outliers'] == '0'
    assert int(stats['out_of_order']) == 2 and stats['frames'] == str(len(stamps))
    assert int(stats['superseded']) == 2 * (4 - len(stamps))
    assert stats['unpaired'] == '1'                                  # left 102
    assert not h.node._pairing._pending


@pytest.mark.parametrize('catch_up, located', [(2, (12, 13)), (1, (13,))])
def test_a_node_that_fell_behind_catches_up_its_newest_pairs(harness, catch_up, located):
    """Four pairs waiting at once (the node was busy): the newest ``catch_up_pairs`` are
    located, oldest first; the older ones are dropped and counted; nothing queues up.
    """
    h = harness(catch_up_pairs=catch_up)
    h.send_infos()
    left, right = _scene(seed=5)
    lf, rf = 'camera_left_optical_frame', 'camera_right_optical_frame'
    for k in (10, 11, 12, 13):
        h.pub_img[0].publish(_image(left, k, lf))
        h.pub_img[1].publish(_image(right, k, rf))
    time.sleep(0.5)                     # delivered while the node does not spin
    assert h.spin_until(lambda: len(h.clouds) >= len(located))
    h.spin_until(lambda: False, timeout_s=0.3)
    assert [c.header.stamp.sec * 10 ** 9 + c.header.stamp.nanosec for c in h.clouds] == [
        EPOCH_NS + k * FRAME_NS for k in located]
    stats = h.stats()
    assert stats['superseded'] == str(2 * (4 - len(located)))
    assert stats['frames'] == str(len(located))


def test_odometry_speed_sets_the_blur_length(harness):
    h = harness(wiener=True)
    h.send_infos()
    left, right = _scene(seed=2, along_m=2.0)
    lf, rf = 'camera_left_optical_frame', 'camera_right_optical_frame'
    h.send(_image(left, 1, lf), _image(right, 1, rf))
    assert conversions.cloud_to_records(h.clouds[-1])['blur_px'][0] == 0.0   # standing
    odom = Odometry()
    odom.twist.twist.linear.x = 120 / 3.6
    h.pub_odom.publish(odom)
    h.spin_until(lambda: h.node._speed[0] > 30.0)
    h.send(_image(left, 2, lf), _image(right, 2, rf))
    assert 0.2 < conversions.cloud_to_records(h.clouds[-1])['blur_px'][0] < 1.5


def test_invalid_parameters_are_refused(ros_env):
    ctx = rclpy.Context()
    rclpy.init(context=ctx)
    try:
        with pytest.raises(ValueError):
            SpotLocatorNode(context=ctx, parameter_overrides=[
                Parameter('method', value='magic')])
        with pytest.raises(ValueError):
            SpotLocatorNode(context=ctx, parameter_overrides=[
                Parameter('min_disparity_px', value=500.0)])
    finally:
        rclpy.shutdown(context=ctx)


def test_repeated_camera_info_does_not_derive_the_geometry_again(harness, monkeypatch):
    """camera_info comes with every frame: the geometry is derived when a pair is kept."""
    h = harness()
    h.send_infos()
    located = h.node._located
    calls = []
    derive = conversions.stereo_geometry
    monkeypatch.setattr(conversions, 'stereo_geometry',
                        lambda *infos: calls.append(infos) or derive(*infos))
    infos = [h.node._infos.current[i] for i in (0, 1)]
    for _ in range(10):
        for i, info in enumerate(infos):
            h.node._on_info(i, info)
    assert calls == [] and h.node._located is located
