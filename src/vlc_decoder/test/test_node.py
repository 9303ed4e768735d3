"""vlc_decoder_node in-process: synthetic stereo frames in, lamp records out; bad input.

Frames come from ``core.synth`` (a train passing lamps of the default lamp map, spots
drawn from the protocol text). Every test runs the node and a probe node in their own
rclpy Context on an isolated DDS domain (``ros_env``).
"""
import time

from diagnostic_msgs.msg import DiagnosticArray
import numpy as np
import pytest
import rclpy
from rclpy.context import Context
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.qos import QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import Image, PointCloud2

from vlc_decoder import conversions
from vlc_decoder.core import synth
from vlc_decoder.vlc_decoder_node import VlcDecoderNode

pytestmark = pytest.mark.ros

EPOCH_NS = 1704067200 * 10 ** 9
UID_FIRST = 0x1001          # line 1, lamp 1 of the default lamp map, at chainage 10 m
LAMP_FIRST_M = (10.0, 2.5, 1.4)


def image_msg(array, stamp_ns, encoding='mono8', frame_id='camera_left_optical_frame'):
    msg = Image()
    msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(int(stamp_ns), 10 ** 9)
    msg.header.frame_id = frame_id
    if encoding in ('rgb8', 'bgr8'):
        array = np.repeat(array[:, :, None], 3, axis=2)
    msg.height, msg.width = array.shape[:2]
    msg.encoding = encoding
    msg.step = msg.width * (3 if array.ndim == 3 else 1)
    msg.data = np.ascontiguousarray(array).tobytes()
    return msg


class Harness:
    """The decoder node and a probe that publishes images and collects outputs."""

    def __init__(self, ctx, **params):
        # synth renders at the protocol's 10 kchip/s with the paper's 50 us exposure; the
        # node's own defaults are the system's 20 kchip/s and 25 us (ARCHITECTURE.md)
        params = {'chip_rate_hz': 10_000.0, 'exposure_s': 50e-6, **params}
        overrides = [Parameter('diagnostics_period_s', value=0.1)] + [
            Parameter(k, value=v) for k, v in params.items()]
        self.node = VlcDecoderNode(context=ctx, parameter_overrides=overrides)
        self.probe = Node('probe', context=ctx)
        qos = QoSProfile(depth=5, reliability=ReliabilityPolicy.RELIABLE)
        self.pub = [self.probe.create_publisher(Image, f'stereo/{s}/image_raw', qos)
                    for s in ('left', 'right')]
        self.clouds, self.diags = [], []
        self.probe.create_subscription(PointCloud2, 'vlc/lamps', self.clouds.append, 50)
        self.probe.create_subscription(DiagnosticArray, 'diagnostics', self.diags.append, 50)
        self.executor = SingleThreadedExecutor(context=ctx)
        self.executor.add_node(self.node)
        self.executor.add_node(self.probe)
        deadline = time.monotonic() + 10
        while time.monotonic() < deadline and any(
                p.get_subscription_count() == 0 for p in self.pub):
            self.executor.spin_once(timeout_sec=0.05)

    def send(self, left, right, wait_output=True, timeout=5.0):
        """Publish a pair (either may be None) and spin until the node answers."""
        before = len(self.clouds)
        if left is not None:
            self.pub[0].publish(left)
        if right is not None:
            self.pub[1].publish(right)
        deadline = time.monotonic() + (timeout if wait_output else 0.3)
        while time.monotonic() < deadline:
            self.executor.spin_once(timeout_sec=0.02)
            if wait_output and len(self.clouds) > before:
                break
        return self.clouds[before:]

    def spin(self, seconds):
        deadline = time.monotonic() + seconds
        while time.monotonic() < deadline:
            self.executor.spin_once(timeout_sec=0.02)

    def stats(self):
        self.spin(0.3)
        values = {kv.key: kv.value for kv in self.diags[-1].status[0].values}
        return values, self.diags[-1].status[0]

    def close(self):
        self.executor.shutdown()
        self.node.destroy_node()
        self.probe.destroy_node()


@pytest.fixture
def harness(ros_env):
    ctx = Context()
    rclpy.init(context=ctx)
    made = []

    def make(**params):
        made.append(Harness(ctx, **params))
        return made[-1]
    yield make
    for h in made:
        h.close()
    rclpy.try_shutdown(context=ctx)


def frames(n, speed_kmh=40.0, seed=1):
    for stamp_ns, left, right, truth in synth.pass_frames(
            speed_kmh, [UID_FIRST, UID_FIRST + 1], n_frames=n, seed=seed):
        yield EPOCH_NS + stamp_ns, left, right, truth


def decode_until_confirmed(h, encodings=('mono8', 'mono8'), n=60):
    confirmed = None
    for stamp, left, right, _ in frames(n):
        out = h.send(image_msg(left, stamp, encodings[0]),
                     image_msg(right, stamp, encodings[1], 'camera_right_optical_frame'))
        assert out, 'no vlc/lamps message for a stereo pair'
        cloud = out[-1]
        assert (cloud.header.stamp.sec * 10 ** 9 + cloud.header.stamp.nanosec) == stamp
        assert cloud.header.frame_id == 'camera_left_optical_frame'
        lamps = conversions.cloud_to_array(cloud)
        done = lamps[lamps['state'] == 2]
        if len(done):
            confirmed = done[0]
            break
    return confirmed


def test_node_decodes_synthetic_pass_and_publishes_named_fields(harness):
    h = harness()
    lamp = decode_until_confirmed(h)
    assert lamp is not None, 'the lamp was never confirmed'
    assert lamp['uid'] == UID_FIRST
    np.testing.assert_allclose([lamp['map_x'], lamp['map_y'], lamp['map_z']], LAMP_FIRST_M)
    assert lamp['chips_seen'] >= 40 and lamp['bits_known'] == 24
    assert lamp['flags'] & conversions.FLAG_LEFT or lamp['flags'] & conversions.FLAG_RIGHT
    assert 0 < lamp['t_offset_s'] < 720 * 30e-6 + 50e-6
    assert np.isfinite(lamp['left_u']) and lamp['left_u_min'] <= lamp['left_u'] <= lamp[
        'left_u_max']
    names = [f.name for f in h.clouds[-1].fields]
    assert names[:3] == ['map_x', 'map_y', 'map_z'] and 'track_id' in names and 'state' in names
    values, status = h.stats()
    assert int(values['lamps_confirmed']) >= 1 and status.name.startswith('vlc_decoder')


def test_node_converts_rgb8_and_bgr8(harness):
    h = harness()
    lamp = decode_until_confirmed(h, encodings=('rgb8', 'bgr8'))
    assert lamp is not None and lamp['uid'] == UID_FIRST


def test_node_skips_bad_input_and_keeps_running(harness):
    h = harness()
    good = list(frames(3))
    stamp, left, right, _ = good[0]
    assert h.send(image_msg(left, stamp), image_msg(right, stamp))
    # unknown encoding
    bad = image_msg(left, stamp + 1000)
    bad.encoding = 'yuv422'
    assert not h.send(bad, image_msg(right, stamp + 1000), wait_output=False)
    # empty image
    empty = image_msg(left, stamp + 2000)
    empty.height = empty.width = empty.step = 0
    empty.data = b''
    assert not h.send(empty, image_msg(right, stamp + 2000), wait_output=False)
    # truncated image
    short = image_msg(left, stamp + 3000)
    short.data = bytes(short.data[:1000])
    assert not h.send(short, image_msg(right, stamp + 3000), wait_output=False)
    # left and right sizes differ
    assert not h.send(image_msg(left, stamp + 4000), image_msg(right[:480, :640], stamp + 4000),
                      wait_output=False)
    # unpaired stamps: left images whose right partner never comes
    for k in range(3):
        h.send(image_msg(left, stamp + 5000 + k), None, wait_output=False)
    # out of order: a stamp before the last decoded frame
    assert not h.send(image_msg(left, stamp - 10 ** 6), image_msg(right, stamp - 10 ** 6),
                      wait_output=False)
    # the node is alive and decodes the next good pair
    stamp, left, right, _ = good[1]
    out = h.send(image_msg(left, stamp), image_msg(right, stamp))
    assert out and out[-1].header.stamp.nanosec == stamp % 10 ** 9
    values, status = h.stats()
    assert int(values['skipped_bad_image']) == 3
    assert int(values['skipped_size_mismatch']) == 1
    assert int(values['skipped_unpaired']) == 3
    assert int(values['skipped_out_of_order']) >= 1
    assert int(values['frames_decoded']) == 2
    assert status.level == b'\x01'     # WARN while frames are being skipped


def test_node_reports_uid_absent_from_the_map_as_anomaly(harness, tmp_path):
    lamp_map = tmp_path / 'map.yaml'
    lamp_map.write_text('frame_id: map\nlamps:\n- {uid: 4101, line_id: 1, lamp_id: 5, '
                        'position_m: [50.0, 2.5, 1.4]}\n')
    h = harness(lamp_map_path=str(lamp_map))
    anomaly = None
    for stamp, left, right, _ in frames(60):
        out = h.send(image_msg(left, stamp), image_msg(right, stamp))
        lamps = conversions.cloud_to_array(out[-1])
        assert not np.any(lamps['state'] == 2), 'a UID absent from the map published as a lamp'
        if np.any(lamps['state'] == 3):
            anomaly = lamps[lamps['state'] == 3][0]
            break
    assert anomaly is not None and anomaly['uid'] == UID_FIRST
    assert np.isnan(anomaly['map_x'])
    values, status = h.stats()
    assert status.level == b'\x01' and f'{UID_FIRST:#06x}' in values['anomalous_uids']


def test_node_starts_afresh_when_a_looped_bag_jumps_back(harness):
    """Stamps jumping back by more than stamp_jump_reset_s (a looped replay) reset the
    lamp tracks with a warning and decoding goes on, from the first frame of the replay
    (held until the third image of the new time base confirmed it); a smaller step back
    is skipped.
    """
    h = harness()
    run = list(frames(45))
    track_ids = set()
    for stamp, left, right, _ in run:
        out = h.send(image_msg(left, stamp), image_msg(right, stamp))
        track_ids |= set(conversions.cloud_to_array(out[-1])['track_id'].tolist())
    assert track_ids
    last = run[-1][0]
    # 10 ms back: a late frame, skipped
    stamp, left, right, _ = run[-2]
    assert not h.send(image_msg(left, last - 10 ** 7), image_msg(right, last - 10 ** 7),
                      wait_output=False)
    before = len(h.clouds)
    stamp, left, right, _ = run[20]
    assert not h.send(image_msg(left, stamp), image_msg(right, stamp), wait_output=False)
    for stamp, left, right, _ in run[21:26]:
        assert h.send(image_msg(left, stamp), image_msg(right, stamp)), \
            'the replay after the jump is decoded, not skipped'
    h.spin(0.3)
    replayed = h.clouds[before:]
    # the held first pair is decoded, or superseded by the second when both were
    # complete at once (the node keeps up with the newest pair)
    stamps = [c.header.stamp.sec * 10 ** 9 + c.header.stamp.nanosec for c in replayed]
    assert stamps in ([r[0] for r in run[20:26]], [r[0] for r in run[21:26]])
    first = conversions.cloud_to_array(replayed[0])
    assert len(first) and not np.any(first['state'] == 2), 'state carried across the jump'
    assert min(first['track_id']) > max(track_ids)
    values, _ = h.stats()
    assert int(values['resets_stamp_jump']) == 1 and int(values['skipped_stamp_outliers']) == 0
    assert int(values['skipped_out_of_order']) == 2      # both images of the pair


def test_lone_1970_and_future_stamped_pairs_neither_reset_nor_stop_the_tracks(harness):
    """A black pair stamped 1970 (sec 0, sec 1) or a year ahead between real frames is
    dropped as an outlier; the lamp tracks go on (same track ids) and the lamp is still
    confirmed; images whose data do not match their header, or whose size is not
    camera_info's, are skipped.
    """
    from sensor_msgs.msg import CameraInfo
    h = harness()
    run = list(frames(40))
    black = np.zeros_like(run[0][1])
    strays = {8: 0, 14: 10 ** 9, 20: EPOCH_NS + 365 * 86400 * 10 ** 9}
    track_ids = []
    for k, (stamp, left, right, _) in enumerate(run):
        if k in strays:
            assert not h.send(image_msg(black, strays[k]), image_msg(black, strays[k]),
                              wait_output=False)
        if k == 26:
            short = image_msg(left, stamp)
            short.height -= 1                      # the data hold one row more
            assert not h.send(short, image_msg(right, stamp), wait_output=False)
            continue
        out = h.send(image_msg(left, stamp), image_msg(right, stamp))
        assert out
        track_ids.append(set(conversions.cloud_to_array(out[-1])['track_id'].tolist()))
    assert h.node.tracker.resets == 0
    for k in strays:                          # the same lamp track before and after
        assert track_ids[k - 1] & track_ids[k], (k, track_ids[k - 1], track_ids[k])
    values, _ = h.stats()
    assert int(values['skipped_stamp_outliers']) == 6 and int(values['resets_stamp_jump']) == 0
    assert int(values['lamps_confirmed']) >= 1 and int(values['skipped_bad_image']) == 1
    # a camera_info of half the size is not taken at once; frames keep being decoded
    pub_info = h.probe.create_publisher(CameraInfo, 'stereo/left/camera_info', 10)
    info = CameraInfo(width=run[0][1].shape[1], height=run[0][1].shape[0],
                      k=[900.0, 0, 100, 0, 900.0, 80, 0, 0, 1.0],
                      p=[900.0, 0, 100, 0, 0, 900.0, 80, 0, 0, 0, 1.0, 0])
    half = CameraInfo(width=info.width // 2, height=info.height // 2, k=info.k, p=info.p)
    h.spin(0.5)
    for msg in (info, half):
        pub_info.publish(msg)
        h.spin(0.3)
    assert h.node.infos[0].width == info.width
    stamp = run[-1][0] + 33_333_333
    assert h.send(image_msg(run[-1][1], stamp), image_msg(run[-1][2], stamp))
    values, _ = h.stats()
    assert values['camera_info_ignored'] == '0' and 'skipped_size_mismatch' not in values


def test_parameter_file_and_declared_defaults_carry_the_same_signal_timing():
    """The node's params file is where the graph's timing is written (benchmarks and the
    fuzz read it there); the node's declared defaults must say the same.
    """
    import pathlib

    from vlc_decoder.core.config import SIGNAL_TIMING_KEYS, signal_timing_from_params_file
    from vlc_decoder.vlc_decoder_node import CORE_PARAMETERS
    path = pathlib.Path(__file__).resolve().parents[1] / 'config' / 'vlc_decoder_node.yaml'
    timing = signal_timing_from_params_file(path)
    declared = {name: default for name, default, _ in CORE_PARAMETERS}
    assert set(timing) == set(SIGNAL_TIMING_KEYS)
    for key, value in timing.items():
        assert declared[key] == pytest.approx(value), key


def test_warm_up_runs_the_confirming_path_on_a_throwaway_tracker():
    from vlc_common.core.lamp_map import straight_tunnel_map
    from vlc_decoder.core.config import DecoderConfig
    from vlc_decoder.vlc_decoder_node import warm_up
    lamp_map = straight_tunnel_map(count=3)
    assert warm_up(DecoderConfig(), lamp_map) == 1      # the near lamp, from the map
    assert warm_up(DecoderConfig(), None) == 1          # no map: the worked example's UID


@pytest.mark.parametrize('catch_up, decoded', [(2, (2, 3)), (1, (3,))])
def test_a_decoder_that_fell_behind_catches_up_its_newest_pairs(harness, catch_up, decoded):
    """Four pairs waiting at once (the node was busy): the newest ``catch_up_pairs`` are
    decoded, oldest first; the older ones are dropped and counted (skipped_superseded).
    """
    h = harness(catch_up_pairs=catch_up)
    run = list(frames(4))
    for stamp, left, right, _ in run:
        h.pub[0].publish(image_msg(left, stamp))
        h.pub[1].publish(image_msg(right, stamp, frame_id='camera_right_optical_frame'))
    time.sleep(0.5)                     # delivered while the node does not spin
    h.spin(1.0)
    assert [c.header.stamp.sec * 10 ** 9 + c.header.stamp.nanosec for c in h.clouds] == [
        run[k][0] for k in decoded]
    values, _ = h.stats()
    assert int(values['skipped_superseded']) == 2 * (4 - len(decoded))
