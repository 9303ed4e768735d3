"""The installed vlc_decoder_node fed by the installed rig (stereo_camera_node).

Both run as separate processes; a probe compares every lamp the decoder publishes as
confirmed with the rig's ground truth of the same frame (nearest projected lamp centre),
and the warnings of bad input with the executable's log.
"""
import pathlib
import time

import numpy as np
import pytest
import rclpy
from rclpy.context import Context
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.qos import QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import Image, PointCloud2

from vlc_decoder import conversions
from vlc_decoder.core import synth
from vlc_decoder.core.config import signal_timing_from_params_file

pytestmark = pytest.mark.graph
NODE_PARAMS = pathlib.Path(__file__).resolve().parents[1] / 'config' / 'vlc_decoder_node.yaml'

_TYPES = {PointField_type: np.dtype(code) for PointField_type, code in
          ((1, 'i1'), (2, 'u1'), (3, '<i2'), (4, '<u2'), (5, '<i4'), (6, '<u4'), (7, '<f4'),
           (8, '<f8'))}


def cloud_records(msg):
    """Any little-endian PointCloud2 → numpy structured array, from its fields."""
    dtype = np.dtype({'names': [f.name for f in msg.fields],
                      'formats': [_TYPES[f.datatype] for f in msg.fields],
                      'offsets': [f.offset for f in msg.fields],
                      'itemsize': msg.point_step})
    return np.frombuffer(bytes(msg.data), dtype=dtype, count=msg.width * msg.height)


def _ns(stamp):
    return stamp.sec * 10 ** 9 + stamp.nanosec


def _probe(ctx, topics):
    node = Node('decoder_probe', context=ctx)
    got = {name: [] for name in topics}
    reliable = QoSProfile(depth=50, reliability=ReliabilityPolicy.RELIABLE)
    for name, kind in topics.items():
        node.create_subscription(kind, name, got[name].append, reliable)
    executor = SingleThreadedExecutor(context=ctx)
    executor.add_node(node)
    return node, executor, got


def test_installed_decoder_fed_by_installed_rig_publishes_the_right_uids(launch, ros_env):
    scenario = {'seed': 4, 'motion_profile': 'constant', 'start_chainage_m': -1.0,
                'speed_kmh': 40.0}
    # lamps and decoder at the graph's timing (the decoder's params file), whatever the
    # nodes' declared defaults
    timing = {key: value for key, value in signal_timing_from_params_file(NODE_PARAMS).items()
              if key in ('chip_rate_hz', 'exposure_s')}
    decoder = launch('vlc_decoder', 'vlc_decoder_node', params=timing)
    cam = launch('vlc_stereo_camera', 'stereo_camera_node',
                 params={**scenario, **timing, 'noise_bank_size': 2, 'publish_clock': False,
                         'realtime_factor': 1.0, 'wait_for_subscribers': 1})
    ctx = Context()
    rclpy.init(context=ctx)
    node, executor, got = _probe(ctx, {'vlc/lamps': PointCloud2,
                                       'ground_truth/spots': PointCloud2})
    confirmed = []        # (stamp, record) of every confirmed lamp record
    try:
        deadline = time.monotonic() + 90.0
        def uids_with_truth():
            # the probe may join the rig's truth topic a few frames late: count only
            # confirmed records whose frame's truth it has
            stamps = {_ns(m.header.stamp) for m in got['ground_truth/spots']}
            return {int(r['uid']) for stamp, r in confirmed if stamp in stamps}

        while time.monotonic() < deadline and len(uids_with_truth()) < 2:
            executor.spin_once(timeout_sec=0.1)
            assert decoder.poll() is None, launch.output(decoder)
            assert cam.poll() is None, launch.output(cam)
            while got['vlc/lamps']:
                msg = got['vlc/lamps'].pop(0)
                lamps = conversions.cloud_to_array(msg)
                confirmed += [(_ns(msg.header.stamp), r) for r in lamps[lamps['state'] == 2]]
        executor.spin_once(timeout_sec=0.5)
    finally:
        executor.shutdown()
        node.destroy_node()
        rclpy.try_shutdown(context=ctx)
    assert launch.stop(decoder) == 0, launch.output(decoder)
    assert launch.stop(cam) == 0, launch.output(cam)
    truth_by_stamp = {_ns(m.header.stamp): cloud_records(m) for m in got['ground_truth/spots']}
    # the probe may join the rig's truth topic a few frames late: check every confirmed
    # record whose frame's truth it has
    checked = set()
    for stamp, lamp in confirmed:
        if stamp not in truth_by_stamp:
            continue
        uid = int(lamp['uid'])
        checked.add(uid)
        truth = truth_by_stamp[stamp]
        u = lamp['left_u'] if np.isfinite(lamp['left_u']) else lamp['right_u']
        v = lamp['left_v'] if np.isfinite(lamp['left_v']) else lamp['right_v']
        uu = truth['u_left'] if np.isfinite(lamp['left_u']) else truth['u_right']
        nearest = int(np.argmin(np.hypot(uu - u, truth['v_left'] - v)))
        assert int(truth['uid'][nearest]) == uid
        # the lamp map position: lamps every 10 m from chainage 10 m, 2.5 m left, 1.4 m up
        assert lamp['map_x'] == pytest.approx(10.0 * (uid - 0x1000)) and lamp['map_y'] == 2.5
    assert len(checked) >= 2, (len(confirmed), launch.output(decoder))


def test_installed_decoder_warns_on_bad_input_and_keeps_running(launch, ros_env):
    decoder = launch('vlc_decoder', 'vlc_decoder_node')
    ctx = Context()
    rclpy.init(context=ctx)
    node, executor, got = _probe(ctx, {'vlc/lamps': PointCloud2})
    qos = QoSProfile(depth=5, reliability=ReliabilityPolicy.RELIABLE)
    pubs = [node.create_publisher(Image, f'stereo/{s}/image_raw', qos)
            for s in ('left', 'right')]
    stamp0 = 1704067200 * 10 ** 9
    _, left, right, _ = next(synth.pass_frames(40.0, [0x1001], n_frames=1))

    def img(array, stamp, encoding='mono8'):
        msg = Image()
        msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(stamp, 10 ** 9)
        msg.height, msg.width = array.shape
        msg.encoding, msg.step, msg.data = encoding, array.shape[1], array.tobytes()
        return msg

    def spin(seconds):
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            executor.spin_once(timeout_sec=0.02)

    try:
        end = time.monotonic() + 20
        while time.monotonic() < end and any(p.get_subscription_count() == 0 for p in pubs):
            spin(0.1)
        bad = img(left, stamp0)
        bad.encoding = 'bayer_rggb8'
        short = img(left, stamp0 + 1000)
        short.data = short.data[:100]
        empty = img(left[:0], stamp0 + 1500)
        for a, b in ((bad, img(right, stamp0)), (short, img(right, stamp0 + 1000)),
                     (empty, img(right, stamp0 + 1500)),
                     (img(left, stamp0 + 2000), img(right[:100], stamp0 + 2000))):
            pubs[0].publish(a)
            pubs[1].publish(b)
            spin(0.3)
        pubs[0].publish(img(left, stamp0 + 3000))         # no right partner
        spin(0.3)
        pubs[0].publish(img(left, stamp0 + 33_000_000))
        pubs[1].publish(img(right, stamp0 + 33_000_000))
        end = time.monotonic() + 10
        while time.monotonic() < end and not got['vlc/lamps']:
            spin(0.1)
    finally:
        executor.shutdown()
        node.destroy_node()
        rclpy.try_shutdown(context=ctx)
    assert decoder.poll() is None, launch.output(decoder)
    assert launch.stop(decoder) == 0
    log = launch.output(decoder)
    assert got['vlc/lamps'], log
    for text in ('unsupported image encoding', 'truncated image', 'empty image', 'differ in size',
                 'no stereo partner'):
        assert text in log, (text, log)
