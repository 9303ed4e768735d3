"""Bag scoring of the companion poses (scoring.py) and the offline replay (replay.py)."""
import math

import numpy as np
import pytest

rclpy = pytest.importorskip('rclpy')

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue  # noqa: E402
from rclpy.serialization import serialize_message  # noqa: E402

from companion_localizers.conversions import pose_stamped  # noqa: E402
from vlc_bags.bagio import write_bag  # noqa: E402
from vlc_evaluation import companion_scoring as scoring  # noqa: E402

EPOCH_NS = 1704067200 * 10 ** 9


def _pose(stamp_ns, x):
    return pose_stamped(stamp_ns, (x, 0.0, 0.0), (0.0, 0.0, 0.0, 1.0), 'map')


def _bag(path, gap_s=(2.0, 2.5)):
    """Truth at 30 Hz moving at 10 m/s for 4 s; RSSI poses at 50 Hz 5 cm ahead, with a
    gap; dead reckoning poses with a growing error; an INS diagnostics status.
    """
    msgs = []
    for k in range(121):
        t = EPOCH_NS + k * 33_333_333
        msgs.append(('/ground_truth/pose', 'geometry_msgs/msg/PoseStamped', t,
                     serialize_message(_pose(t, 10.0 * (t - EPOCH_NS) * 1e-9))))
    for k in range(200):
        t_s = k * 0.02
        t = EPOCH_NS + int(round(t_s * 1e9))
        if not gap_s[0] <= t_s < gap_s[1]:
            msgs.append(('/companion/rssi/pose', 'geometry_msgs/msg/PoseStamped', t,
                         serialize_message(_pose(t, 10.0 * t_s + 0.05))))
        msgs.append(('/companion/dead_reckoning/pose', 'geometry_msgs/msg/PoseStamped', t,
                     serialize_message(_pose(t, 10.0 * t_s + 0.1 * t_s))))
    status = DiagnosticStatus(name='ins_beacon_node: ins_beacon', values=[
        KeyValue(key='processing_ms_median', value='0.8'),
        KeyValue(key='processing_ms_p95', value='1.5'),
        KeyValue(key='cpu_ms_per_pose', value='2.5')])
    msgs.append(('/diagnostics', 'diagnostic_msgs/msg/DiagnosticArray', EPOCH_NS + 4 * 10 ** 9,
                 serialize_message(DiagnosticArray(status=[status]))))
    msgs.sort(key=lambda m: m[2])
    write_bag(path, msgs)
    return path


def test_scores_errors_availability_and_processing_time(tmp_path):
    bag = _bag(tmp_path / 'run')
    result = scoring.score_bag(bag)
    rssi = result['rssi']
    assert rssi['max_m'] == pytest.approx(0.05, abs=1e-5)   # stamps: float s at 1.7e9
    assert rssi['mean_m'] == pytest.approx(0.05, abs=1e-5)
    # A truth instant needs a pose within 0.1 s on both sides: the gap between the poses
    # at 1.98 s and 2.50 s (longer than 0.2 s) is missed whole.
    assert rssi['availability'] == pytest.approx(1.0 - 0.52 / 4.0, abs=0.01)
    dr = result['dead_reckoning']
    assert dr['max_m'] == pytest.approx(0.4, abs=0.01)
    assert dr['p95_m'] == pytest.approx(0.38, abs=0.01)
    assert dr['availability'] == pytest.approx(1.0, abs=0.01)
    ins = result['ins_beacon']
    assert ins['poses'] == 0 and ins['availability'] == 0.0
    assert ins['processing']['processing_ms_median'] == 0.8
    assert ins['processing']['cpu_ms_per_pose'] == 2.5
    assert math.isnan(rssi['processing']['processing_ms_median'])
    assert scoring.score_rssi(bag)['max_m'] == rssi['max_m']
    assert scoring.score_dead_reckoning(bag, settle_s=2.0)['max_m'] == pytest.approx(
        0.4, abs=0.01)
    assert scoring.score_ins_beacon(bag)['poses'] == 0


def test_command_prints_a_table_and_writes_json(tmp_path, capsys):
    bag = _bag(tmp_path / 'run')
    assert scoring.main([str(bag), '--methods', 'rssi', '--json', str(tmp_path / 'f.json')]) == 0
    out = capsys.readouterr().out
    assert '| rssi |' in out and '5.00' in out
    assert (tmp_path / 'f.json').exists()


def test_poses_outside_the_truth_are_not_scored():
    truth_t = np.array([0.0, 1.0])
    truth = np.array([[0.0, 0, 0], [10.0, 0, 0]])
    s = scoring.score_poses(np.array([-1.0, 0.5, 2.0]), np.array([[5.0, 0, 0]] * 3), truth_t,
                            truth)
    assert s['poses'] == 1 and s['max_m'] == pytest.approx(0.0)
