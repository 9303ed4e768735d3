"""Bag core without ROS: crash-safe split writer, open_bag/write_bag, recording and
playback logic. Bags are read back with rosbags and with the independent mcap reader.
"""
from pathlib import Path
import signal
import struct
import subprocess
import sys
import textwrap
import threading

from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory
import numpy as np
import pytest
from rosbags.interfaces import QosDurability, QosReliability
from rosbags.rosbag2 import Reader
import yaml

from vlc_bags import (
    SplitBagWriter,
    bag_summary,
    iter_raw,
    jazzy_typestore,
    open_bag,
    qos_profile,
    read_receive_times,
    write_bag,
)
from vlc_bags.playback import (
    PlaybackSchedule,
    PlayerConfig,
    delayed,
    missing_topics,
    parse_remaps,
    playback_qos,
    select_topics,
    time_window,
)
from vlc_bags.recording import (
    RecorderConfig,
    RecordingSession,
    incompatible_offers,
    subscription_qos,
)
from vlc_bags.typesupport import ensure_type, has_stamp, header_stamp_ns, message_definition

TS = jazzy_typestore()
EPOCH_NS = 1_704_067_200 * 10**9
PKG_SRC = Path(__file__).resolve().parents[1]


def _string(i):
    return TS.serialize_cdr(TS.types['std_msgs/msg/String'](data=f'm{i}'), 'std_msgs/msg/String')


def _header(stamp_ns, frame='camera_left_optical_frame'):
    Header, Time = TS.types['std_msgs/msg/Header'], TS.types['builtin_interfaces/msg/Time']
    return Header(stamp=Time(sec=stamp_ns // 10**9, nanosec=stamp_ns % 10**9), frame_id=frame)


def _imu(stamp_ns, k):
    t = TS.types
    v3, q = t['geometry_msgs/msg/Vector3'], t['geometry_msgs/msg/Quaternion']
    return t['sensor_msgs/msg/Imu'](
        header=_header(stamp_ns, 'imu_link'), orientation=q(x=0.0, y=0.0, z=0.0, w=1.0),
        orientation_covariance=np.full(9, -1.0),
        angular_velocity=v3(x=0.01 * k, y=0.0, z=-0.02), angular_velocity_covariance=np.zeros(9),
        linear_acceleration=v3(x=0.1, y=0.0, z=9.81), linear_acceleration_covariance=np.zeros(9))


def _image(stamp_ns, value, width=32, height=8):
    data = np.full(width * height, value, dtype=np.uint8)
    return TS.types['sensor_msgs/msg/Image'](header=_header(stamp_ns), height=height,
                                             width=width, encoding='mono8', is_bigendian=0,
                                             step=width, data=data)


def _pose(stamp_ns, x):
    t = TS.types
    return t['geometry_msgs/msg/PoseStamped'](header=_header(stamp_ns, 'map'), pose=t[
        'geometry_msgs/msg/Pose'](position=t['geometry_msgs/msg/Point'](x=x, y=0.5, z=-1.5),
                                  orientation=t['geometry_msgs/msg/Quaternion'](
                                      x=0.0, y=0.0, z=0.0, w=1.0)))


def _mcap_messages(bag):
    """(topic, log_time, decoded) of every listed split, read by the mcap package alone."""
    out = []
    meta = (bag / 'metadata.yaml').read_text()
    for path in sorted(bag.glob('*.mcap')):
        assert path.name in meta
        with open(path, 'rb') as f:
            reader = make_reader(f, decoder_factories=[DecoderFactory()])
            assert reader.get_summary() is not None, 'split without summary/index'
            for _, channel, message, decoded in reader.iter_decoded_messages():
                out.append((channel.topic, message.log_time, decoded))
    return out


# -- write_bag / open_bag --------------------------------------------------------------
@pytest.mark.parametrize('storage', ['mcap', 'sqlite3'])
def test_write_bag_then_open_bag_round_trip(tmp_path, storage):
    msgs = []
    for k in range(5):
        t = EPOCH_NS + k * 33_333_333
        msgs += [('/stereo/left/image_raw', 'sensor_msgs/msg/Image', t, _image(t, 10 * k)),
                 ('/imu/data_raw', 'sensor_msgs/msg/Imu', t + 1, _imu(t, k)),
                 ('/train/pose', 'geometry_msgs/msg/PoseStamped', t + 2, _pose(t, 100.0 + k))]
    qos = {'/stereo/left/image_raw': [qos_profile('reliable', depth=5)],
           '/imu/data_raw': [qos_profile('best_effort', depth=5)]}
    assert write_bag(tmp_path / 'bag', msgs, storage=storage, offered_qos=qos) == 15
    suffix = '.mcap' if storage == 'mcap' else '.db3'
    assert (tmp_path / 'bag' / f'bag{suffix}').exists()

    got = list(open_bag(tmp_path / 'bag'))
    assert [(m.topic, m.timestamp_ns) for m in got] == [(m[0], m[2]) for m in msgs]
    images = [m.msg for m in got if m.topic == '/stereo/left/image_raw']
    assert [int(im.data[0]) for im in images] == [0, 10, 20, 30, 40]
    assert images[2].encoding == 'mono8' and images[2].width == 32
    poses = [m for m in got if m.msgtype == 'geometry_msgs/msg/PoseStamped']
    assert poses[3].msg.pose.position.x == 103.0
    assert poses[3].msg.header.stamp.sec == (EPOCH_NS + 3 * 33_333_333) // 10**9
    imu = [m.msg for m in got if m.topic == '/imu/data_raw']
    assert imu[4].angular_velocity.x == pytest.approx(0.04)

    summary = {s.topic: s for s in bag_summary(tmp_path / 'bag')}
    assert summary['/imu/data_raw'].offered_qos[0].reliability == QosReliability.BEST_EFFORT
    assert summary['/stereo/left/image_raw'].offered_qos[0].depth == 5
    assert summary['/train/pose'].offered_qos == ()
    only_pose = list(open_bag(tmp_path / 'bag', topics=['/train/pose']))
    assert len(only_pose) == 5
    assert list(open_bag(tmp_path / 'bag', topics=['/not/there'])) == []
    window = list(iter_raw(tmp_path / 'bag', start_ns=EPOCH_NS + 33_333_333,
                           stop_ns=EPOCH_NS + 2 * 33_333_333))
    assert len(window) == 3


def test_write_bag_refuses_existing_folder(tmp_path):
    (tmp_path / 'bag').mkdir()
    with pytest.raises(Exception, match='exists'):
        write_bag(tmp_path / 'bag', [('/a', 'std_msgs/msg/String', 1, _string(0))])


# -- crash-safe split writer ------------------------------------------------------------
KILL_SCRIPT = textwrap.dedent('''
    import os, signal, sys
    sys.path.insert(0, {src!r})
    from vlc_bags import SplitBagWriter, jazzy_typestore, qos_profile
    ts = jazzy_typestore()
    S = ts.types['std_msgs/msg/String']
    w = SplitBagWriter({path!r}, storage={storage!r})
    w.add_topic('/chatter', 'std_msgs/msg/String', [qos_profile('reliable', depth=7)])
    for i in range(25):
        w.write('/chatter', 1000 + i, ts.serialize_cdr(S(data=f'm{{i}}'), 'std_msgs/msg/String'))
        if i in (9, 19):
            w.flush()
    os.kill(os.getpid(), signal.SIGKILL)
''')


@pytest.mark.parametrize('storage', ['mcap', 'sqlite3'])
def test_split_writer_killed_keeps_every_flushed_message(tmp_path, storage):
    bag = tmp_path / 'bag'
    script = KILL_SCRIPT.format(src=str(PKG_SRC), path=str(bag), storage=storage)
    proc = subprocess.run([sys.executable, '-c', script], timeout=60)
    assert proc.returncode == -signal.SIGKILL
    # 20 messages were flushed in two splits; the 5 written after the last flush are lost
    got = [(m.timestamp_ns, m.msg.data) for m in open_bag(bag)]
    assert got == [(1000 + i, f'm{i}') for i in range(20)]
    with Reader(bag) as reader:
        assert reader.message_count == 20
        assert len(reader.connections) == 1
    if storage == 'mcap':
        assert [d.data for _, _, d in _mcap_messages(bag)] == [f'm{i}' for i in range(20)]


def test_split_writer_close_lists_every_split_and_cleans_staging(tmp_path):
    bag = tmp_path / 'b'
    with SplitBagWriter(bag, custom_data={'scenario': 'unit'}) as w:
        w.add_topic('/chatter', 'std_msgs/msg/String')
        assert w.flush() == 0  # nothing to flush: no empty split file
        for i in range(7):
            w.write('/chatter', 10 + i, _string(i))
            if i % 3 == 2:
                assert w.flush() == 3
        w.add_topic('/imu', 'sensor_msgs/msg/Imu', [qos_profile('best_effort')])
        w.write('/imu', 30, TS.serialize_cdr(_imu(30, 1), 'sensor_msgs/msg/Imu'))
        assert w.pending_messages == 2
    assert sorted(p.name for p in bag.iterdir()) == ['b_0.mcap', 'b_1.mcap', 'b_2.mcap',
                                                     'metadata.yaml']
    with Reader(bag) as reader:
        assert reader.message_count == 8
        assert {c.topic: c.msgcount for c in reader.connections} == {'/chatter': 7, '/imu': 1}
        assert reader.start_time == 10 and reader.end_time == 31
    meta = yaml.safe_load((bag / 'metadata.yaml').read_text())['rosbag2_bagfile_information']
    assert meta['custom_data'] == {'scenario': 'unit'}
    assert meta['relative_file_paths'] == ['b_0.mcap', 'b_1.mcap', 'b_2.mcap']
    assert [f['message_count'] for f in meta['files']] == [3, 3, 2]
    assert len(_mcap_messages(bag)) == 8
    with pytest.raises(FileExistsError):
        SplitBagWriter(bag)


def test_split_writer_zstd_chunks_read_by_both_readers(tmp_path):
    with SplitBagWriter(tmp_path / 'z', compression='zstd') as w:
        w.add_topic('/cam', 'sensor_msgs/msg/Image')
        for k in range(3):
            image = _image(k, k + 1, 640, 480)
            w.write('/cam', k, TS.serialize_cdr(image, 'sensor_msgs/msg/Image'))
    assert (tmp_path / 'z' / 'z_0.mcap').stat().st_size < 640 * 480  # compressed
    assert [int(m.msg.data[5]) for m in open_bag(tmp_path / 'z')] == [1, 2, 3]
    assert [d.data[5] for _, _, d in _mcap_messages(tmp_path / 'z')] == [1, 2, 3]
    with pytest.raises(ValueError):
        SplitBagWriter(tmp_path / 'q', storage='sqlite3', compression='zstd')


# -- types and stamps -----------------------------------------------------------------
def test_header_stamp_read_from_cdr_bytes():
    stamp = EPOCH_NS + 123_456_789
    le = TS.serialize_cdr(_imu(stamp, 0), 'sensor_msgs/msg/Imu')
    assert header_stamp_ns(le) == stamp
    be = TS.serialize_cdr(_imu(stamp, 0), 'sensor_msgs/msg/Imu', little_endian=False)
    assert be[1] == 0 and header_stamp_ns(be) == stamp
    assert header_stamp_ns(le[:11]) is None
    bad = bytearray(le)
    struct.pack_into('<I', bad, 8, 1_000_000_000)
    assert header_stamp_ns(bytes(bad)) is None
    assert has_stamp(TS, 'sensor_msgs/msg/Image')
    assert has_stamp(TS, 'rosgraph_msgs/msg/Clock')
    assert not has_stamp(TS, 'std_msgs/msg/String')
    assert not has_stamp(TS, 'no_pkg/msg/Nothing')


def test_type_outside_the_store_loaded_from_ament_share(tmp_path, monkeypatch):
    share = tmp_path / 'prefix' / 'share'
    (share / 'lamp_msgs' / 'msg').mkdir(parents=True)
    (share / 'lamp_msgs' / 'msg' / 'Lamp.msg').write_text(
        'std_msgs/Header header\nuint32 uid\nlamp_msgs/Spot[] spots\n')
    (share / 'lamp_msgs' / 'msg' / 'Spot.msg').write_text('float64 u_px\nfloat64 v_px\n')
    monkeypatch.setenv('AMENT_PREFIX_PATH', str(tmp_path / 'prefix'))
    store = jazzy_typestore()
    msgdef, rihs01 = message_definition(store, 'lamp_msgs/msg/Lamp')
    assert 'lamp_msgs/Spot' in msgdef and rihs01.startswith('RIHS01_')
    assert has_stamp(store, 'lamp_msgs/msg/Lamp')
    lamp = store.types['lamp_msgs/msg/Lamp'](header=_header(EPOCH_NS), uid=4097, spots=[
        store.types['lamp_msgs/msg/Spot'](u_px=1.5, v_px=2.5)])
    write_bag(tmp_path / 'bag', [('/lamps', 'lamp_msgs/msg/Lamp', 5, lamp)], typestore=store)
    monkeypatch.setenv('AMENT_PREFIX_PATH', '')
    # a reader without the .msg files decodes it from the definition stored in the bag
    (msg,) = open_bag(tmp_path / 'bag')
    assert msg.msg.uid == 4097 and msg.msg.spots[0].v_px == 2.5
    with pytest.raises(KeyError):
        ensure_type(jazzy_typestore(), 'lamp_msgs/msg/Lamp')


# -- recording logic ---------------------------------------------------------------------
def test_subscription_qos_follows_publishers():
    rel, be = qos_profile('reliable'), qos_profile('best_effort')
    latched = qos_profile('reliable', 'transient_local', 1)
    assert subscription_qos([rel, rel], 50).reliability == QosReliability.RELIABLE
    assert subscription_qos([rel, be], 50).reliability == QosReliability.BEST_EFFORT
    assert subscription_qos([], 50).reliability == QosReliability.BEST_EFFORT
    assert subscription_qos([latched], 3).durability == QosDurability.TRANSIENT_LOCAL
    assert subscription_qos([latched, rel], 3).durability == QosDurability.VOLATILE
    assert subscription_qos([rel], 42).depth == 42
    assert incompatible_offers(subscription_qos([rel], 5), [rel, be]) == [be]
    assert incompatible_offers(subscription_qos([rel, be], 5), [rel, be]) == []


@pytest.mark.parametrize('source', ['receive', 'header'])
def test_recording_session_timestamps_and_receive_log(tmp_path, source):
    cfg = RecorderConfig(timestamp_source=source)
    session = RecordingSession(cfg, tmp_path / 'bag')
    session.add_topic('/imu/data_raw', 'sensor_msgs/msg/Imu', [qos_profile('best_effort')])
    session.add_topic('/chatter', 'std_msgs/msg/String', [qos_profile('reliable')])
    stamp = EPOCH_NS + 2_500_000
    imu = TS.serialize_cdr(_imu(stamp, 1), 'sensor_msgs/msg/Imu')
    assert session.record('/imu/data_raw', imu, 7_000, 11, 12, 13) is None
    problem = session.record('/chatter', _string(1), 8_000, 21, 22, 23)
    assert (problem is None) == (source == 'receive')
    # a truncated message is still recorded, at its receive time, and reported
    assert session.record('/imu/data_raw', imu[:10], 9_000, 31, 32, 33) is not None
    session.close()
    got = [(m.topic, m.timestamp_ns) for m in iter_raw(tmp_path / 'bag')]
    first = stamp if source == 'header' else 7_000
    assert sorted(got, key=lambda x: x[1]) == sorted(
        [('/imu/data_raw', first), ('/chatter', 8_000), ('/imu/data_raw', 9_000)],
        key=lambda x: x[1])
    rows = read_receive_times(tmp_path / 'bag')
    assert [(r['topic'], r['header_stamp_ns'], r['source_timestamp_ns'],
             r['received_timestamp_ns'], r['callback_wall_ns']) for r in rows] == [
        ('/imu/data_raw', stamp, 11, 12, 13), ('/chatter', None, 21, 22, 23),
        ('/imu/data_raw', None, 31, 32, 33)]
    assert rows[0]['bag_timestamp_ns'] == first


def test_receive_log_line_cut_by_a_kill_is_dropped(tmp_path):
    session = RecordingSession(RecorderConfig(), tmp_path / 'bag')
    session.add_topic('/chatter', 'std_msgs/msg/String', [])
    for i in range(3):
        session.record('/chatter', _string(i), 100 + i, 1, 2, 3)
    session.flush(wait=True)
    with open(tmp_path / 'bag' / 'receive_times.csv', 'a') as f:
        f.write('/chatter,104,,1,2')  # what a kill inside write() leaves
    assert [r['bag_timestamp_ns'] for r in read_receive_times(tmp_path / 'bag')] == [100, 101, 102]


def test_recording_session_drops_beyond_backlog_and_survives_write_errors(tmp_path):
    session = RecordingSession(RecorderConfig(max_backlog_mb=0.001), tmp_path / 'bag')
    session.add_topic('/chatter', 'std_msgs/msg/String', [])
    gate = threading.Event()
    session.call(gate.wait, wait=False)  # hold the writer thread so the queue fills
    problems = [session.record('/chatter', bytes(600), 100 + i) for i in range(3)]
    assert problems[:2] == [None, None] and 'dropped' in problems[2]
    gate.set()
    session.flush(wait=True)
    session.writer.write = lambda *a: (_ for _ in ()).throw(OSError('disk full'))
    session.record('/chatter', _string(9), 300)
    session.flush(wait=True)
    assert isinstance(session.error, OSError)
    assert session.backlog_bytes == 0 and session.dropped == 1
    session.close()
    assert [m.timestamp_ns for m in iter_raw(tmp_path / 'bag')] == [100, 101]


def test_recorder_config_rejects_bad_values():
    with pytest.raises(ValueError):
        RecorderConfig(storage='rosbag1')
    with pytest.raises(ValueError):
        RecorderConfig(timestamp_source='sent')
    with pytest.raises(ValueError):
        RecorderConfig(storage='sqlite3', compression='zstd')
    with pytest.raises(ValueError):
        RecorderConfig(flush_interval_s=0.0)


# -- playback logic ----------------------------------------------------------------------
def test_remaps_topic_selection_and_config():
    assert parse_remaps(['/imu/data_raw:=/replay/imu', 'a/b := c']) == {
        '/imu/data_raw': '/replay/imu', '/a/b': 'c'}
    for bad in (['/a'], [':=/b'], ['/a:=']):
        with pytest.raises(ValueError):
            parse_remaps(bad)
    with pytest.raises(ValueError):
        PlayerConfig(bag='x', remap=('nothing',))
    with pytest.raises(ValueError):
        PlayerConfig(bag='')
    with pytest.raises(ValueError):
        PlayerConfig(bag='x', rate=-1.0)
    from vlc_bags.bagio import TopicSummary
    summary = [TopicSummary('/a', 't', 1, ()), TopicSummary('/b/c', 't', 1, ())]
    assert [t.topic for t in select_topics(summary, [])] == ['/a', '/b/c']
    assert [t.topic for t in select_topics(summary, ['b/c', '/x'])] == ['/b/c']
    assert missing_topics(summary, ['b/c', '/x']) == ['/x']


def test_playback_qos_from_recorded_offers():
    image = [qos_profile('reliable', depth=5)]
    discovered_imu = [qos_profile('best_effort', history='unknown', depth=0)]
    q = playback_qos(discovered_imu, fast=False, default_depth=5)
    assert (q.reliability, q.depth) == (QosReliability.BEST_EFFORT, 5)
    q = playback_qos(image, fast=False, default_depth=9)
    assert (q.reliability, q.durability, q.depth) == (QosReliability.RELIABLE,
                                                      QosDurability.VOLATILE, 5)
    assert playback_qos(discovered_imu, fast=True, default_depth=5).reliability == \
        QosReliability.RELIABLE
    assert playback_qos([qos_profile('reliable', 'transient_local', 1)], False, 5).durability \
        == QosDurability.TRANSIENT_LOCAL
    assert playback_qos([], False, 7).reliability == QosReliability.RELIABLE


def test_delayed_topics_are_released_in_time_order():
    ms = 1_000_000
    # images stamped at exposure start every 33 ms, IMU every 2.5 ms
    messages = sorted([('/imu', None, k * 2.5 * ms, b'i') for k in range(40)]
                      + [('/img', None, k * 33 * ms, b'f') for k in range(3)],
                      key=lambda m: m[2])
    out = list(delayed(iter(messages), ['img'], 21.6 * ms))
    assert sorted(out, key=lambda m: m[2]) == out          # time order kept
    frames = [m[2] for m in out if m[0] == '/img']
    assert frames == pytest.approx([21.6 * ms, 54.6 * ms, 87.6 * ms])
    assert [m[2] for m in out if m[0] == '/imu'] == [m[2] for m in messages if m[0] == '/imu']
    # the first frame comes after the IMU samples of its readout, before later ones
    first = [m[0] for m in out].index('/img')
    assert out[first - 1][2] <= 21.6 * ms < out[first + 1][2]
    assert list(delayed(iter(messages), ['/img'], 0)) == messages


def test_time_window_and_schedule():
    assert time_window(1_000, 5_000_000_000, 0.0, 0.0) == (1_000, 5_000_000_000)
    assert time_window(0, 5_000_000_000, 1.0, 2.0) == (1_000_000_000, 3_000_000_000)
    assert time_window(0, 5_000_000_000, 4.0, 2.0) == (4_000_000_000, 5_000_000_000)
    assert time_window(0, 5_000_000_000, 9.0, 0.0) == (9_000_000_000, 9_000_000_000)
    s = PlaybackSchedule(2.0)
    s.restart(10_000_000_000, 100.0)
    assert s.due_s(11_000_000_000) == pytest.approx(100.5)
    assert s.due_s(9_000_000_000) < 100.0  # older stamp: due at once
    fast = PlaybackSchedule(0.0)
    fast.restart(0, 0.0)
    assert fast.due_s(5) is None


def test_recorder_metadata_entries_go_to_custom_data(tmp_path):
    config = RecorderConfig(metadata=('rig_profile=realistic', 'seed = 7',
                                      'installation=/runs/a.installation'))
    session = RecordingSession(config, tmp_path / 'bag')
    session.add_topic('/chatter', 'std_msgs/msg/String', [])
    session.record('/chatter', _string(1), 100)
    session.close()
    meta = yaml.safe_load((tmp_path / 'bag' / 'metadata.yaml').read_text())
    custom = meta['rosbag2_bagfile_information']['custom_data']
    assert custom['rig_profile'] == 'realistic' and custom['seed'] == '7'
    assert custom['installation'] == '/runs/a.installation'
    assert custom['recorder'] == 'vlc_bags/bag_recorder'
    with pytest.raises(ValueError, match="metadata entry 'seed' is not 'key=value'"):
        RecorderConfig(metadata=('seed',))
