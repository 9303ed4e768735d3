"""receivers_benchmark's recorded-bag input and its pacing."""
import time

import numpy as np
import pytest
from rclpy.serialization import serialize_message
from sensor_msgs.msg import CameraInfo, Image

from vlc_bags.bagio import write_bag
from vlc_evaluation.benchmarks import receivers


def _image(stamp_ns, value):
    msg = Image(height=2, width=3, encoding='mono8', step=3, data=bytes([value] * 6))
    msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(stamp_ns, 10**9)
    return msg


def _bag(path, stamps_left, stamps_right, infos=True):
    messages = []
    if infos:
        for side in ('left', 'right'):
            messages.append((f'/stereo/{side}/camera_info', 'sensor_msgs/msg/CameraInfo', 1,
                             serialize_message(CameraInfo(width=3, height=2))))
    for side, stamps in (('left', stamps_left), ('right', stamps_right)):
        for k, stamp in enumerate(stamps):
            messages.append((f'/stereo/{side}/image_raw', 'sensor_msgs/msg/Image', stamp,
                             serialize_message(_image(stamp, k + (side == 'right') * 100))))
    write_bag(path, messages)
    return path


def test_a_bag_gives_its_stereo_pairs_in_stamp_order(tmp_path):
    # an image without its partner (stamp 30) is left out; --frames caps the count
    bag = _bag(tmp_path / 'bag', [20, 10, 30, 40], [10, 40, 20])
    infos, frames = receivers.bag_sequence(bag, 10)
    assert [i.width for i in infos] == [3, 3]
    assert [f[0] for f in frames] == [10, 20, 40]
    assert [f[1].data[0] for f in frames] == [1, 0, 3]       # the left image of each stamp
    assert [f[2].data[0] for f in frames] == [100, 102, 101]
    assert [f[0] for f in receivers.bag_sequence(bag, 2)[1]] == [10, 20]


def test_a_bag_without_camera_info_or_pairs_is_refused(tmp_path):
    with pytest.raises(ValueError, match='camera_info'):
        receivers.bag_sequence(_bag(tmp_path / 'a', [10], [10], infos=False), 10)
    with pytest.raises(ValueError, match='no stereo pair'):
        receivers.bag_sequence(_bag(tmp_path / 'b', [10], [20]), 10)


def test_paced_frames_start_one_period_apart():
    # frame k is due (k + 1) periods after the call, as a camera's fixed period gives
    # them: never earlier (a frame woken late on a loaded machine does not delay the next)
    starts = []
    t_call = time.monotonic()
    receivers._run(range(5), lambda frame: starts.append(time.monotonic()), [], None,
                   pace_s=0.02)
    assert np.all(np.array(starts) - t_call >= 0.02 * np.arange(1, 6) - 1e-3)
    starts.clear()
    receivers._run(range(5), lambda frame: starts.append(time.monotonic()), [], None)
    assert starts[-1] - starts[0] < 0.05          # back to back (paced: >= 0.08 s)
