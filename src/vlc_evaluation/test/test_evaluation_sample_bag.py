"""The committed sample bag opens (rosbags and an independent MCAP reader) and holds the
raw sensors and ground truth of a pass by a few lamps.
"""
import pathlib

from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory
import numpy as np
import pytest

from vlc_bags import bag_summary, open_bag
from vlc_common.pointcloud import cloud_to_records
from vlc_evaluation.sample_bag import bag_size_mb, sample_scenario
from vlc_evaluation.scenarios import GROUND_TRUTH_TOPICS, SENSOR_TOPICS

BAG = pathlib.Path(__file__).resolve().parents[3] / 'bags' / 'sample_80kmh'


@pytest.fixture(scope='module')
def summary():
    if not (BAG / 'metadata.yaml').exists():
        pytest.fail(f'{BAG} missing: python -m vlc_evaluation.sample_bag')
    return {t.topic: t for t in bag_summary(BAG)}


def test_sample_bag_topics_counts_and_size(summary):
    assert set(SENSOR_TOPICS + GROUND_TRUTH_TOPICS) <= set(summary)
    frames = summary['/stereo/left/image_raw'].message_count
    assert frames == summary['/stereo/right/image_raw'].message_count == 45
    assert summary['/stereo/left/camera_info'].message_count == frames
    assert summary['/ground_truth/pose'].message_count == frames
    # 400 Hz over the 1.5 s of frames (plus the IMU's tail)
    assert summary['/imu/data_raw'].message_count >= 600
    assert summary['/stereo/left/image_raw'].msgtype == 'sensor_msgs/msg/Image'
    assert bag_size_mb(BAG) <= 20.0


def test_sample_bag_passes_several_lamps_with_truth_at_every_frame(summary):
    image_stamps, truth_stamps, lamps_in_view = [], [], set()
    for topic, _, t_ns, msg in open_bag(BAG, topics=['/stereo/left/image_raw',
                                                    '/ground_truth/pose',
                                                    '/ground_truth/spots']):
        stamp = msg.header.stamp.sec * 10 ** 9 + msg.header.stamp.nanosec
        assert t_ns == stamp                       # bag time = header stamp (sim time)
        if topic == '/stereo/left/image_raw':
            image_stamps.append(stamp)
            assert (msg.width, msg.height, msg.encoding) == (1280, 720, 'mono8')
        elif topic == '/ground_truth/pose':
            truth_stamps.append(stamp)
        else:
            rec = cloud_to_records(msg)
            lamps_in_view |= {int(u) for u, i in zip(rec['uid'], rec['in_left']) if i}
    assert sorted(image_stamps) == sorted(truth_stamps)
    assert len(lamps_in_view) >= 3


def test_independent_reader_decodes_compressed_chunks():
    [path] = sorted(BAG.glob('*.mcap'))
    with open(path, 'rb') as stream:
        reader = make_reader(stream, decoder_factories=[DecoderFactory()])
        assert {c.compression for c in reader.get_summary().chunk_indexes} == {'zstd'}
        brightest, imu = 0, None
        for _, channel, _, msg in reader.iter_decoded_messages(
                topics=['/stereo/right/image_raw', '/imu/data_raw']):
            if channel.topic == '/imu/data_raw':
                imu = imu or msg
                continue
            image = np.frombuffer(bytes(msg.data), np.uint8)
            assert image.size == 1280 * 720
            brightest = max(brightest, int(image.max()))
    assert brightest > 100                  # lamp spots in view (background ≈ 4 DN)
    assert abs(imu.linear_acceleration.z - 9.8) < 0.5


def test_sample_scenario_is_sensor_only_and_compressed():
    s = sample_scenario('x')
    assert not s.run_processing and s.record_sensors
    assert s.node_params['bag_recorder']['compression'] == 'zstd'
    assert s.node_params['bag_recorder']['timestamp_source'] == 'header'
    assert '/vlc/lamps' not in s.recorded_topics()
