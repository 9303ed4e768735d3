"""The multi-pass protocol (evaluation/passes.py): one train, one line, run again and
again; and ``installation_seed``, which makes that possible.
"""
import pathlib

import pytest
import yaml

from vlc_evaluation import passes
from vlc_evaluation.runner import write_installation
from vlc_evaluation.scenarios import Scenario


def test_installation_seed_draws_the_installation_and_seed_the_run(tmp_path):
    a = Scenario(name='a', seed=11, installation_seed=3, rig_profile='realistic')
    b = Scenario(name='b', seed=12, installation_seed=3, rig_profile='realistic')
    c = Scenario(name='c', seed=3, rig_profile='realistic')
    for s in (a, b, c):
        write_installation(s, tmp_path)
    truth = {s.name: yaml.safe_load((tmp_path / f'{s.name}.installation' / 'truth'
                                     / 'truth.yaml').read_text()) for s in (a, b, c)}
    assert truth['a'] == truth['b'] == truth['c'] and truth['a']['seed'] == 3
    assert Scenario(name='d', seed=4).drawn_seed == 4


def test_uncorrected_calibration_tells_the_receivers_the_raw_images_are_rectified(tmp_path):
    """The undistortion ablation: the same drawn calibration, distortion and
    rectification dropped, which the spot locator then takes as a rectified pair.
    """
    from spot_locator.conversions import stereo_geometry
    from vlc_evaluation.localizer_replay import camera_info_messages

    def infos(name):
        folder = tmp_path / f'{name}.installation' / 'belief'
        return camera_info_messages([folder / 'left.yaml', folder / 'right.yaml'])
    drawn = Scenario(name='drawn', seed=3, rig_profile='realistic')
    plain = Scenario(name='plain', seed=3, rig_profile='realistic', calibration='uncorrected')
    for s in (drawn, plain):
        write_installation(s, tmp_path)
    raw, rectified = stereo_geometry(*infos('drawn')), stereo_geometry(*infos('plain'))
    assert raw.raw_cameras is not None and rectified.raw_cameras is None
    # the same rectified projection and baseline
    assert (rectified.fx, rectified.cx, rectified.baseline_m) == pytest.approx(
        (raw.fx, raw.cx, raw.baseline_m))
    with pytest.raises(ValueError, match='uncorrected'):
        write_installation(Scenario(name='x', seed=3, rig_profile='realistic',
                                    calibration='undistorted'), tmp_path)
    ablated = passes.ABLATIONS['no_undistortion']
    assert ablated[2] == {'calibration': 'uncorrected'}


def test_rig_nodes_draw_the_installation_from_installation_seed():
    from vlc_stereo_camera.rig_params import ScenarioConfig
    base = dict(epoch_s=0.0, motion_profile='constant', start_chainage_m=0.0,
                speed_kmh=40.0, accel_mps2=1.0, brake_mps2=1.0, dwell_s=0.0, cruise_s=1.0,
                vibration_enabled=True, vibration_scale=1.0, rig_profile='realistic')
    one = ScenarioConfig(seed=5, installation_seed=2, **base)
    two = ScenarioConfig(seed=6, installation_seed=2, **base)
    own = ScenarioConfig(seed=2, **base)
    assert one.drawn_seed == two.drawn_seed == own.drawn_seed == 2
    assert one.imu_clock_offset_s() == two.imu_clock_offset_s() == own.imu_clock_offset_s()
    assert one.vehicle().camera.pitch_deg == own.vehicle().camera.pitch_deg
    # the run's own randomness still follows seed: the car body differs
    t = [0.5, 1.0]
    assert not (one.trajectory().sample(t).position_m
                == two.trajectory().sample(t).position_m).all()


def test_learning_passes_and_scored_runs_keep_their_train_and_seeds(tmp_path):
    learn = [passes.learning_pass(2, k, tmp_path / 'kept', localizer_params={'x': 1})
             for k in (1, 2)]
    assert [s.installation_seed for s in learn] == [2, 2]
    assert len({s.seed for s in learn}) == 2 and learn[0].name == 'pass01_060kmh'
    assert learn[0].node_params['train_localizer_node'] == {
        'x': 1, 'self_calibration_path': str(tmp_path / 'kept' / 'self_calibration.yaml'),
        'lamp_refinement_path': str(tmp_path / 'kept' / 'lamp_refinement.yaml'),
        'disparity_map_path': str(tmp_path / 'kept' / 'disparity_map.yaml')}
    first = passes.scored_runs(2, tmp_path / 'after00')
    later = passes.scored_runs(2, tmp_path / 'after03')
    seeds = [[s.seed for s in group] for group in first]
    # the same noise at every checkpoint, never a learning pass's
    assert seeds == [[s.seed for s in group] for group in later]
    assert not set(sum(seeds, [])) & {s.seed for s in learn}
    assert [s.static_point_m for s in first[0]] == list(passes.STATIC_POINTS_M)
    assert [s.speed_kmh for s in first[1]] == [float(v) for v in passes.SPEEDS_KMH]
    own = first[0][0].node_params['train_localizer_node']['self_calibration_path']
    assert own == str(tmp_path / 'after00' / first[0][0].name / 'self_calibration.yaml')
    assert {s.rig_profile for s in first[0] + first[1]} == {'realistic'}


def test_every_attempt_starts_from_a_fresh_copy_of_the_kept_files(tmp_path):
    kept = tmp_path / 'kept'
    static, _ = passes.scored_runs(2, tmp_path / 'files', kept_dir=kept)
    run = static[0]
    assert run.files_to == str(tmp_path / 'files' / run.name)
    run.restore_files()                                  # nothing kept yet
    assert list(pathlib.Path(run.files_to).iterdir()) == []
    kept.mkdir()
    (kept / 'self_calibration.yaml').write_text('disparity_offset_px: 0.3\n')
    run.restore_files()
    own = pathlib.Path(run.files_to) / 'self_calibration.yaml'
    assert own.read_text() == 'disparity_offset_px: 0.3\n'
    # what a failed attempt wrote back is gone at the next one
    own.write_text('disparity_offset_px: 9\n')
    (pathlib.Path(run.files_to) / 'lamp_refinement.yaml').write_text('passes: 1\n')
    run.restore_files()
    assert own.read_text() == 'disparity_offset_px: 0.3\n'
    assert sorted(p.name for p in pathlib.Path(run.files_to).iterdir()) == [
        'self_calibration.yaml']
    learn = passes.learning_pass(2, 1, tmp_path / 'pass01', kept_dir=kept)
    assert (learn.files_from, learn.files_to) == (str(kept), str(tmp_path / 'pass01'))


def test_kept_state_reads_both_files(tmp_path):
    assert passes.kept_state(tmp_path) == {}
    (tmp_path / 'lamp_refinement.yaml').write_text(
        'passes: 3\ntriplets: [[1, 2, 3, 0.5, 0.001, 0.004, 3], [2, 3, 4, 0.5, 0.0, 0.004, 3]]\n'
        'flags: [{uid: 3}]\n')
    assert passes.kept_state(tmp_path) == {'refinement_passes': 3, 'refinement_triplets': 2,
                                           'refinement_flags': 1}
    (tmp_path / 'self_calibration.yaml').write_text(': not yaml [')
    assert passes.kept_state(tmp_path)['refinement_triplets'] == 2
    # the disparity map: cells in use (two passes or more) and their mean |δd|
    (tmp_path / 'disparity_map.yaml').write_text(
        'vehicle_id: t\ncamera_fx_b_px_m: 124.8\ncell_px: 64\nruns: 4\ncells:\n'
        '- [14, 4, 3, 40, 400.0, 0.0, 1.0e5, 160.0, 0.0, 70.0]\n'
        '- [15, 4, 1, 10, 100.0, 0.0, 1.0e4, -90.0, 0.0, 90.0]\n')
    state = passes.kept_state(tmp_path)
    assert state['disparity_map_runs'] == 4 and state['disparity_map_cells'] == 1
    assert state['disparity_map_mean_abs_px'] == pytest.approx(0.4)
    (tmp_path / 'disparity_map.yaml').write_text('cells: 3\n')
    assert 'disparity_map_cells' not in passes.kept_state(tmp_path)


def test_parse_params():
    assert passes.parse_params(['use_self_calibration:=true', 'a:=0.5']) == {
        'use_self_calibration': True, 'a': 0.5}
    with pytest.raises(ValueError, match='NAME:=VALUE'):
        passes.parse_params(['use_self_calibration=true'])


def test_passes_table_has_a_row_per_checkpoint(tmp_path):
    def dynamic(speed, err):
        return {'speed_kmh': speed, 'seed': 1, 'points': [{'error_m': err}],
                'every_pose': {'max_m': err, 'count': 10}, 'covariance_3sigma_fraction': 1.0}
    results = {1: {0: {'static': [{'error_m': 0.08, 'seed': 1}], 'dynamic': [dynamic(40.0, 0.05)],
                       'kept': {}},
                   3: {'static': [{'error_m': 0.02, 'seed': 1}], 'dynamic': [dynamic(40.0, 0.01)],
                       'kept': {'disparity_offset_px': 0.25, 'disparity_offset_sigma_px': 0.1,
                                'refinement_passes': 3, 'refinement_triplets': 40,
                                'refinement_flags': 1}}}}
    table, figures = passes.passes_table(results)
    lines = table.splitlines()
    assert len(lines) == 4 and lines[2].startswith('| first pass | 8.00 / 8.00 | 5.00 / 5.00')
    assert lines[3].startswith('| 3 | 2.00 / 2.00 | 1.00 / 1.00 | 100.0 % | 0 | '
                               '1: δ +0.250 ± 0.100 px, 40 triplets, 1 flagged |')
    # an ablation at the last checkpoint: a row of its own under it
    results[1][3]['ablations'] = {'no_refinement': {
        'static': [{'error_m': 0.03, 'seed': 1}], 'dynamic': [dynamic(40.0, 0.02)]}}
    lines = passes.passes_table(results)[0].splitlines()
    assert len(lines) == 5 and lines[4].startswith(
        '| 3, lamp-map refinement off | 3.00 / 3.00 | 2.00 / 2.00 |')
    doc = tmp_path / 'doc.md'
    doc.write_text('a\n<!-- passes:begin -->\nold\n<!-- passes:end -->\nb\n')
    passes.update_docs(doc, table, 'run_evaluation --passes 3')
    assert 'old' not in doc.read_text() and '| first pass |' in doc.read_text()


def test_kept_text_names_the_disparity_map_without_a_table_pipe():
    assert passes._kept_text(8, {'disparity_map_cells': 7, 'disparity_map_mean_abs_px': 0.17,
                                 'refinement_passes': 3, 'refinement_triplets': 5,
                                 'refinement_flags': 0}) == (
        '8: disparity map 7 cells, mean abs δd 0.17 px, 5 triplets, 0 flagged')
    assert passes._kept_text(8, {'disparity_map_cells': 0,
                                 'disparity_map_mean_abs_px': float('nan')}) == (
        '8: disparity map: no cell in use yet')


def test_cli_scores_the_passes_at_the_speeds_given(tmp_path, monkeypatch):
    """``--passes-speeds`` and ``--passes-end-speeds`` reach the protocol (defaults:
    passes.SPEEDS_KMH, passes.END_SPEEDS_KMH).
    """
    from vlc_evaluation import cli
    given = []

    class Stop(Exception):
        pass

    def run_passes(*args, **kwargs):
        given.append((kwargs['speeds_kmh'], kwargs['end_speeds_kmh']))
        raise Stop

    monkeypatch.setattr(passes, 'run_passes', run_passes)
    for extra, expected in (
            ([], (list(passes.SPEEDS_KMH), list(passes.END_SPEEDS_KMH))),
            (['--passes-speeds', '20', '120', '--passes-end-speeds'], ([20, 120], []))):
        with pytest.raises(Stop):
            cli.main(['--protocol', 'none', '--passes', '1', '--lockstep',
                      '--out', str(tmp_path / 'out')] + extra)
        assert given[-1] == expected


def test_first_and_last_checkpoints_score_every_speed_with_the_same_seeds(tmp_path,
                                                                            monkeypatch):
    """Issue 17's two columns (first pass, after n passes) at every speed of
    ``end_speeds_kmh``; the checkpoints between and the ablations at ``speeds_kmh``; a
    speed's run has one seed at every checkpoint that scores it.
    """
    from vlc_evaluation import scenarios
    groups = {}

    def run_protocols(todo, *args, **kwargs):
        groups.update(todo)
        for name, runs in todo.items():
            if '/pass' in name:    # what a learning pass leaves: its (empty) files folder
                pathlib.Path(runs[0].files_to).mkdir(parents=True, exist_ok=True)
        return {}

    monkeypatch.setattr(scenarios, 'run_protocols', run_protocols)
    passes.run_passes(tmp_path, '', trains=(5,), passes=3, checkpoints=(0, 1, 3),
                      speeds_kmh=(40, 100), end_speeds_kmh=(20, 120),
                      ablations=('no_refinement',))
    speeds = {name: [s.speed_kmh for s in runs] for name, runs in groups.items()
              if name.endswith('/dynamic')}
    assert speeds == {'passes/train5/after00/dynamic': [20.0, 40.0, 100.0, 120.0],
                      'passes/train5/after01/dynamic': [40.0, 100.0],
                      'passes/train5/after03/dynamic': [20.0, 40.0, 100.0, 120.0],
                      'passes/train5/after03/no_refinement/dynamic': [40.0, 100.0]}
    seeds = {}
    for name, runs in groups.items():
        for s in runs if name.endswith('/dynamic') else ():
            seeds.setdefault(s.speed_kmh, set()).add(s.seed)
    assert all(len(v) == 1 for v in seeds.values()) and len(seeds) == 4
    assert len({v.pop() for v in seeds.values()}) == 4
