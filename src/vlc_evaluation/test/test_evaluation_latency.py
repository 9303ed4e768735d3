"""Latency from the recorder's receive log: a constructed timeline gives back its delays."""
import csv
import pathlib

import numpy as np
import pytest

from vlc_bags.bagio import RECEIVE_TIMES_COLUMNS, RECEIVE_TIMES_FILE
from vlc_evaluation import latency
from vlc_evaluation.bag_eval import RunData

EPOCH = 1_704_067_200_000_000_000
WALL0 = 1_800_000_000_000_000_000          # wall clock at simulated t = 0
MS = 1_000_000
PAIRS = np.dtype([('u_left', '<f8'), ('stamp_offset_s', '<f8')])
LAMPS = np.dtype([('uid', '<u4'), ('state', '<u4')])


def _write_log(path, rows):
    with open(path / RECEIVE_TIMES_FILE, 'w', newline='') as stream:
        writer = csv.writer(stream)
        writer.writerow(RECEIVE_TIMES_COLUMNS)
        for topic, header, source in rows:
            writer.writerow([topic, source, '' if header is None else header, source,
                             source + 1000, source + 2000])


def _timeline(tmp_path, rtf=1.0):
    """Frames every 33 ms; decoder 30 ms, spot locator 20 ms after readout, pose 5 ms after
    the later input; IMU 2 ms in the compensator. Clock ticks every 10 ms (simulated).
    """
    def wall(sim_ns):
        return WALL0 + round(sim_ns / rtf)

    rows = [('/clock', EPOCH + k * 10 * MS, wall(k * 10 * MS)) for k in range(40)]
    readout = latency.READOUT_S * 1e9
    pairs, lamps = {}, {}
    for k in range(6):
        t0 = k * 33 * MS
        stamp = EPOCH + t0
        ready = wall(t0 + readout)
        rows += [('/vlc/lamps', stamp, ready + 30 * MS), ('/spots/pairs', stamp, ready + 20 * MS),
                 ('/train/pose', EPOCH + t0 + 20 * MS, ready + 35 * MS)]
        pairs[stamp] = np.array([(600.0, 0.010)], dtype=PAIRS)
        lamps[stamp] = np.array([(0x1005, 2 if k else 1)], dtype=LAMPS)
    for k in range(5):
        rows += [('/imu/data_raw', EPOCH + k * 2_500_000, WALL0 + k * 2_500_000),
                 ('/imu/data', EPOCH + k * 2_500_000, WALL0 + k * 2_500_000 + 2 * MS)]
    rows.sort(key=lambda r: r[2])
    _write_log(tmp_path, rows)
    empty = np.zeros(0)
    return RunData(empty, np.zeros((0, 3)), np.zeros((0, 4)), empty, np.zeros((0, 3)),
                   pairs=pairs, lamps=lamps, bag_path=pathlib.Path(tmp_path))


def test_latencies_of_a_constructed_timeline(tmp_path):
    out = latency.frame_latencies(_timeline(tmp_path))
    # frame 0 has no confirmed lamp; frames 1..5 count
    np.testing.assert_allclose(out['decoder'], [30.0] * 5, atol=1e-3)
    np.testing.assert_allclose(out['spot_locator'], [20.0] * 5, atol=1e-3)
    np.testing.assert_allclose(out['localizer'], [5.0] * 5, atol=1e-3)
    # pose 35 ms after readout + readout − spot exposure offset (10 ms)
    expected = 35.0 + (latency.READOUT_S - 0.010) * 1e3
    np.testing.assert_allclose(out['exposure_to_pose'], [expected] * 5, atol=1e-3)
    # split into the camera's readout after the spot's rows and what the graph adds
    np.testing.assert_allclose(out['readout_wait'], [(latency.READOUT_S - 0.010) * 1e3] * 5,
                               atol=1e-3)
    np.testing.assert_allclose(out['frame_to_pose'], [35.0] * 5, atol=1e-3)
    np.testing.assert_allclose(out['imu_compensator'], [2.0] * 5, atol=1e-6)
    s = latency.summarize_ms(out['decoder'])
    assert s['count'] == 5 and s['median_ms'] == pytest.approx(30.0, abs=1e-3)


def test_slowed_run_keeps_processing_in_wall_time(tmp_path):
    out = latency.frame_latencies(_timeline(tmp_path, rtf=0.5))
    np.testing.assert_allclose(out['decoder'], [30.0] * 5, atol=1e-3)
    np.testing.assert_allclose(out['exposure_to_pose'],
                               [35.0 + (latency.READOUT_S - 0.010) * 1e3] * 5, atol=1e-3)


def test_no_receive_log_gives_no_samples(tmp_path):
    run = _timeline(tmp_path)
    (tmp_path / RECEIVE_TIMES_FILE).unlink()
    assert all(v == [] for v in latency.frame_latencies(run).values())
    assert latency.summarize_ms([])['median_ms'] is None


def test_latency_replays_take_their_installation_from_the_bag(tmp_path):
    """An output folder from before the realistic latency bags: rescoring replays what it
    has. A bag recorded from a drawn installation says so in its custom_data, and its
    replay hands the receivers that installation's belief; other bags replay as ideal.
    """
    from rosbags.typesys.stores.ros2_jazzy import std_msgs__msg__String as String
    import yaml

    from vlc_bags.bagio import write_bag
    from vlc_evaluation import cli, scenarios

    def bag(name, custom=None):
        path = tmp_path / 'latency_bags' / name
        write_bag(path, [('/a', 'std_msgs/msg/String', t, String(data='x')) for t in (1, 2)])
        if custom is not None:
            meta = yaml.safe_load((path / 'metadata.yaml').read_text())
            meta['rosbag2_bagfile_information']['custom_data'] = custom
            (path / 'metadata.yaml').write_text(yaml.safe_dump(meta))
        return path
    for speed in cli.LATENCY_SPEEDS_KMH:
        bag(f'sensors_{speed:03d}kmh')
    replays = cli.latency_replays(tmp_path, rescore=True)
    assert [(s.rig_profile, pathlib.Path(s.replay_bag).name) for s in replays] == [
        ('ideal', f'sensors_{speed:03d}kmh') for speed in cli.LATENCY_SPEEDS_KMH]
    bag(f'realistic_sensors_{cli.LATENCY_SPEEDS_KMH[0]:03d}kmh',
        {'rig_profile': 'realistic', 'seed': '1', 'installation_seed': '7'})
    replays = cli.latency_replays(tmp_path, rescore=True)
    assert [s.rig_profile for s in replays] == ['ideal', 'ideal', 'realistic']
    assert replays[-1].drawn_seed == 7 and replays[-1].lean_recording
    # a bag whose custom_data says something unreadable replays as ideal
    odd = bag('odd', {'rig_profile': 'realistic', 'seed': 'x'})
    assert scenarios.recorded_installation(odd) == ('ideal', 1, 0)
