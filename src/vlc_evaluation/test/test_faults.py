"""The fault protocol's scoring on hand-made runs (no graph): truth segments after a
sensor clock step, the time back to tracking, the table.
"""
import numpy as np
import pytest

from vlc_evaluation import faults
from vlc_evaluation.faults import FaultRun

S = 1_000_000_000
EPOCH = 1_704_067_200 * S


def make_run(truth_stamp_s, truth_log_s, pose_stamp_s=(), pose_log_s=(), states=()):
    truth_stamp = np.array([EPOCH + int(t * S) for t in truth_stamp_s], dtype=np.int64)
    truth_log = np.array([int(t * S) for t in truth_log_s], dtype=np.int64)
    x = np.asarray(truth_log_s, dtype=float) * 20.0          # the train runs 20 m/s
    truth_xyz = np.column_stack([x, np.zeros_like(x), np.zeros_like(x)])
    n = len(pose_stamp_s)
    log = np.asarray(truth_log_s, dtype=float)
    return FaultRun(
        truth_stamp=truth_stamp, truth_log=truth_log, truth_xyz=truth_xyz,
        pose_stamp=np.array([EPOCH + int(t * S) for t in pose_stamp_s], dtype=np.int64),
        pose_log=np.array([int(t * S) for t in pose_log_s], dtype=np.int64),
        pose_xyz=np.zeros((n, 3)), pose_cov=np.tile(np.eye(3) * 1e-4, (n, 1, 1)),
        clock_log=log * S, clock_ns=EPOCH + log * S,
        states=[(int(t * S), name) for t, name in states])


def test_truth_is_split_where_the_sensor_clock_steps_back_or_runs_ahead():
    log = np.arange(0.0, 6.0, 0.5)
    stamp = log.copy()
    stamp[4:] -= 2.0            # back 2 s at log 2.0
    stamp[8:] += 5.0            # forward 5 s at log 4.0
    run = make_run(stamp, log)
    parts = faults.truth_segments(run.truth_stamp, run.truth_log)
    assert [list(p) for p in parts] == [[0, 1, 2, 3], [4, 5, 6, 7], [8, 9, 10, 11]]
    # a stalled camera (stamps stop, recording goes on) is not a step
    stamp = np.array([0.0, 0.5, 1.0, 1.1, 1.6])
    run = make_run(stamp, [0.0, 0.5, 1.0, 2.6, 3.1])
    assert len(faults.truth_segments(run.truth_stamp, run.truth_log)) == 1


def test_a_pose_is_scored_against_the_segment_it_was_made_in():
    """After a 2 s step back, stamp 1.2 s exists twice: recorded at 1.2 s (before the
    step) and at 3.2 s (after it). A pose stamped 1.2 s recorded at 1.25 s belongs to
    the first, one recorded at 3.3 s to the second.
    """
    log = np.arange(0.0, 6.0, 0.1)
    stamp = np.where(log < 2.0, log, log - 2.0)
    run = make_run(stamp, log, pose_stamp_s=[1.2, 1.2, 9.0], pose_log_s=[1.25, 3.3, 3.3])
    truth = faults.match_truth(run)
    assert truth[0, 0] == pytest.approx(1.2 * 20.0)
    assert truth[1, 0] == pytest.approx(3.2 * 20.0)
    assert np.all(np.isnan(truth[2]))          # no truth at that stamp: not scored


def test_a_pose_stamped_just_past_its_time_bases_last_truth_keeps_its_segment():
    """The truth comes with each frame, the poses also between frames: a pose stamped
    20 ms after the last truth before a 2 s step back, recorded before the step, belongs
    to the old time base (not to the new one, where its stamp lies 2 s in the future).
    """
    log = np.arange(0.0, 4.0, 1.0 / 30.0)
    stamp = np.where(log < 2.0, log, log - 2.0)
    last = float(stamp[log < 2.0][-1])
    run = make_run(stamp, log, pose_stamp_s=[last + 0.02, last + 0.2],
                   pose_log_s=[last + 0.021, last + 0.021])
    truth = faults.match_truth(run)
    assert truth[0, 0] == pytest.approx((last + 0.02) * 20.0)
    # 0.2 s past its base's truth is too far to extrapolate, and the new base's stamps
    # end before it: not scored
    assert np.all(np.isnan(truth[1]))


def test_back_to_tracking_counts_every_spell_the_fault_caused():
    states = [(0.1, 'waiting_for_uid'), (0.3, 'tracking'), (6.2, 'coasting'),
              (7.0, 'degraded'), (8.5, 'tracking'), (12.0, 'coasting'), (12.5, 'tracking')]
    run = make_run(np.arange(0.0, 14.0, 0.5), np.arange(0.0, 14.0, 0.5), states=states)
    # the fault 6–8 s: coasting then degraded until 8.5 s; the spell at 12 s is not its doing
    assert faults.back_to_tracking_s(run, (6.0, 8.0), EPOCH) == pytest.approx(0.5)
    # tracking throughout a fault
    assert faults.back_to_tracking_s(run, (2.0, 3.0), EPOCH) == 0.0
    # a stalled process reports after the fault: within the grace it is the fault's
    assert faults.back_to_tracking_s(run, (4.5, 5.0), EPOCH) == pytest.approx(3.5)
    never = make_run(np.arange(0.0, 14.0, 0.5), np.arange(0.0, 14.0, 0.5),
                     states=[(0.3, 'tracking'), (6.5, 'lost')])
    assert faults.back_to_tracking_s(never, (6.0, 7.0), EPOCH) is None


def test_every_fault_becomes_a_scenario_and_rig_faults_reach_both_rig_nodes():
    scenarios = faults.fault_scenarios()
    assert [s.kind_params['fault'] for s in scenarios] == [f.name for f in faults.FAULTS]
    by_name = {s.kind_params['fault']: s for s in scenarios}
    dropout = by_name['imu_dropout_5s']
    assert dropout.node_params['adis16488_node']['imu_dropouts_s'] == [faults.FAULT_AT_S, 5.0]
    assert dropout.node_params['stereo_camera_node'] == dropout.node_params['adis16488_node']
    assert dropout.duration_s == faults.FAULT_AT_S + 5.0 + faults.RECOVERY_S
    assert by_name['cpu_4'].duration_s >= faults.FAULT_AT_S + 20.0
    assert by_name['malformed'].extra_nodes[0][1] == 'fault_injector_node'
    assert faults.stamp_shift_s(faults.BY_NAME['clock_back']) == -2.0
    assert [s.name for s in faults.fault_scenarios(names=['none'])] == ['fault_none']


def test_the_table_says_what_failed():
    ok = {'fault': 'none', 'label': 'no fault', 'poses': 10, 'max_error_m': 0.01,
          'inside_3sigma': 1.0, 'confidently_wrong': 0, 'fault_window_s': None,
          'back_to_tracking_s': None, 'state_shares': {'tracking': 1.0}, 'passed': True,
          'timing': {'exit_codes': {'a': 0, 'b': 0}}}
    bad = dict(ok, fault='kill_localizer', label='killed', confidently_wrong=3,
               fault_window_s=[6.0, 6.1], back_to_tracking_s=2.5,
               back_to_tracking_lamps=5.6, passed=False, killed_exit_code=-9,
               timing={'exit_codes': {'a': 0, 'b': 1}})
    table, figures = faults.fault_table([bad, ok])
    lines = table.splitlines()
    assert lines[2].startswith('| no fault |') and 'all 0' in lines[2]
    assert lines[2].endswith('| yes |') and lines[3].endswith('| **no** |')
    assert '| 3 |' in lines[3] and '2.50 s (5.6 lamps)' in lines[3] and 'b 1' in lines[3]
    assert '(killed: -9)' in lines[3]
    assert figures['kill_localizer']['passed'] is False


def test_the_docs_block_is_written_between_its_markers_and_replaced_in_place(tmp_path):
    ok = {'fault': 'none', 'label': 'no fault', 'poses': 10, 'max_error_m': 0.01,
          'inside_3sigma': 1.0, 'confidently_wrong': 0, 'fault_window_s': None,
          'back_to_tracking_s': None, 'state_shares': {'tracking': 1.0}, 'passed': True,
          'timing': {'exit_codes': {'a': 0}}}
    doc = tmp_path / 'README.md'
    doc.write_text(f'# t\n\n{faults.DOCS_BEGIN}\nold\n{faults.DOCS_END}\n\n## after\n',
                   encoding='utf-8')
    faults.update_docs(doc, [ok], 'run_evaluation --faults')
    faults.update_docs(doc, [dict(ok, poses=11)], 'run_evaluation --faults')
    text = doc.read_text(encoding='utf-8')
    assert text.count(faults.DOCS_BEGIN) == 1 and 'old' not in text
    assert '| no fault | 11 |' in text and '| no fault | 10 |' not in text
    assert text.endswith('## after\n') and 'Generated by `run_evaluation --faults`' in text

