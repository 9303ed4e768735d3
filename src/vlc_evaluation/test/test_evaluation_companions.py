"""Issue 7 in the evaluation: companion scenarios, lamp outage and forged lamp
(``evaluation/companions.py``): scenario construction, lamp maps, tables; and one short
scenario through the real graph with every companion node (about 30 s).
"""
import json

import numpy as np
import pytest

from vlc_common.core.alignment import Alignment
from vlc_common.core.lamp_map import LampMap, default_lamp_map_path
from vlc_evaluation import bag_eval, companions, scenarios


def test_companion_scenarios_start_every_method_with_the_tracks_parameters():
    made = companions.companion_scenarios(points_m=(5.0,), speeds_kmh=(60,))
    kinds = {(s.kind_params['track'], s.kind_params['motion']) for s in made}
    assert kinds == set(companions.CASES)
    curved = [s for s in made if s.kind_params['track'] == 'curved']
    for s in made:
        exes = [exe for _, exe, _ in s.extra_nodes]
        assert exes == ['photodiode_node', 'rssi_localizer_node', 'dead_reckoning_node',
                        'ins_beacon_node', 'curvature_node']
        assert '/companion/curvature/pose' in s.recorded_topics()
        assert s.extra_subscriptions['/imu/data'] == 3
        pd = s.node_params['photodiode_node']
        assert pd['start_chainage_m'] == s.start_chainage_m and pd['seed'] == s.seed
    for s in curved:
        p = s.node_params
        assert p['stereo_camera_node']['alignment'] == 'curved_demo'
        assert p['adis16488_node']['alignment'] == 'curved_demo'
        assert p['curvature_node']['alignment'] == 'curved_demo'
        assert p['imu_compensator_node']['alignment'] == 'curved_demo'
        for exe in ('vlc_decoder_node', 'train_localizer_node', 'ins_beacon_node',
                    'rssi_localizer_node'):
            assert p[exe]['lamp_map_path'].endswith('lamp_map_curved_demo.yaml')
    dynamic = [s for s in curved if s.kind_params['motion'] == 'dynamic'][0]
    # a curvature match needs >= 300 m of array plus the smoothing margins
    assert dynamic.duration_s * dynamic.speed_kmh / 3.6 > 450.0


def test_outage_map_darkens_every_second_lamp_then_a_stretch(tmp_path):
    s = companions.outage_scenario(tmp_path, speed_kmh=80.0)
    g = s.kind_params
    camera = LampMap.load(g['camera_lamp_map'])
    full = LampMap.load(default_lamp_map_path())
    x = {float(lamp.position_m[0]) for lamp in camera.lamps}
    assert len(full) - len(camera) == len(g['dark_lamps_m'])
    half = [v for v in range(50, 250, 10) if v in x]
    assert half == list(range(50, 250, 20))                  # every second lamp lit
    assert not any(250 <= v < 750 for v in x)                 # 500 m without a lamp
    assert g['last_lit_before_m'] == 230.0 and g['first_lit_after_m'] == 750.0
    assert s.node_params['stereo_camera_node']['lamp_map_path'] == g['camera_lamp_map']
    assert s.node_params['vlc_decoder_node']['lamp_map_path'] == default_lamp_map_path()
    end = s.start_chainage_m + s.duration_s * 80.0 / 3.6
    assert end > g['first_lit_after_m'] + 10.0


def test_forged_map_gives_one_lamp_another_lamps_uid(tmp_path):
    clean, forged = companions.forged_scenarios(tmp_path)
    assert clean.kind_params['camera_lamp_map'] == ''
    camera = LampMap.load(forged.kind_params['camera_lamp_map'])
    full = LampMap.load(default_lamp_map_path())
    lamp = camera.by_uid(forged.kind_params['forged_uid'])
    assert lamp.position_m[0] == companions.FORGED_LAMP_X_M
    assert full.by_uid(lamp.uid).position_m[0] == companions.FORGED_UID_OF_X_M
    assert camera.by_uid(forged.kind_params['true_uid']) is None
    # the UID's owner is never in view during the run (visibility < 10 m ahead)
    assert companions.FORGED_UID_OF_X_M - companions.FORGED_END_M > 10.0
    assert forged.node_params['train_localizer_node']['lamp_map_path'] == \
        default_lamp_map_path()


def _method(errors, covered, instants, cpu=(1.0, 2.0), **extra):
    return dict({'errors_m': list(errors), 'covered': covered, 'instants': instants,
                 'processing_ms': list(cpu)}, **extra)


def test_tables_pool_runs_and_report_is_appended(tmp_path):
    methods = {m: _method([0.01, 0.03], 8, 10) for m, *_ in companions.METHODS}
    methods['curvature'] = _method([], 0, 10, cpu=(None, None),
                                   statuses={'no_curvature_on_alignment': 3})
    runs = [{'track': 'straight', 'motion': 'dynamic', 'speed_kmh': v,
             'methods': dict(methods, vlc_stereo=_method([0.02 * k, 0.01], 10, 10))}
            for k, v in ((1, 60), (2, 120))]
    table, figures = companions.companion_table(runs)
    assert table.count('\n') == 2 + len(companions.METHODS) - 1
    fig = figures['straight_dynamic']
    assert fig['vlc_stereo']['max_m'] == pytest.approx(0.04)
    assert fig['vlc_stereo']['availability'] == 1.0
    assert fig['rssi']['availability'] == pytest.approx(0.8)
    assert fig['curvature']['poses'] == 0 and 'no_curvature_on_alignment 6' in table
    outage = [{'speed_kmh': 80.0, 'dark_lamps': 60, 'geometry': {
        'half_dark_from_m': 50.0, 'last_lit_before_m': 230.0, 'first_lit_after_m': 750.0},
        'stretches': {'no lamp': {'poses': 5, 'max_m': 0.5, 'mean_m': 0.2,
                                  'max_3sigma_along_m': 1.2, 'within_3sigma': 1.0,
                                  'integrity_states': {'coasting': 4}}},
        'sigma_peak_m': 0.4, 'reacquire_sigma_level_m': 0.05, 'reacquired_at_m': 741.0,
        'reacquired_before_first_lit_lamp_m': 9.0, 'reacquired_within_one_lamp': True,
        'max_after_reacquisition_m': 0.02}]
    table, _ = companions.outage_table(outage)
    assert 'coasting 4' in table and 'within one lamp: **yes**' in table
    forged = [{'run': 'forged', 'speed_kmh': 60.0, 'forged_uid': 4109,
               'methods': {'vlc_stereo': {'errors_m': [0.01]}, 'ins_beacon': {'errors_m': []}},
               'localizer': {'fixes_accepted': 50.0, 'rejected_contradiction': 7.0},
               'ins_beacon': {'beacons_accepted': 4.0, 'beacons_flagged': 1.0,
                              'flags': [['4109', 'distance_mismatch']]},
               'decoder_frames_forged_uid': 12}]
    table, _ = companions.forged_table(forged)
    assert '| 12 | 50 / 7 | 4 / 1 | 4109 distance_mismatch |' in table
    (tmp_path / 'report.md').write_text('## Evaluation\n')
    (tmp_path / 'report.json').write_text(json.dumps({'figures': {}}))
    text = companions.append_to_report(tmp_path, runs, outage, forged)
    md = (tmp_path / 'report.md').read_text()
    assert md.startswith('## Evaluation') and text in md
    data = json.loads((tmp_path / 'report.json').read_text())
    assert {'companions', 'outage', 'forged'} <= set(data['figures'])
    assert 'errors_m' not in data['companions'][0]['methods']['rssi']


def test_curved_outage_scenario_darkens_curved_track_and_runs_curvature(tmp_path):
    s = companions.curved_outage_scenario(tmp_path)
    g = s.kind_params
    camera = LampMap.load(g['camera_lamp_map'])
    lit = {float(lamp.track_chainage_m) for lamp in camera.lamps}
    assert not any(900.0 <= c < 1400.0 for c in lit) and {890.0, 1400.0} <= lit
    assert g['full_dark_from_m'] == g['half_dark_from_m'] == 900.0
    assert g['last_lit_before_m'] == 890.0 and g['first_lit_after_m'] == 1400.0
    # the dark stretch holds curved track (the R 600 m arc), the run starts with a
    # curvature window before it and ends past the first lamp after it
    alignment = Alignment.named('curved_demo')
    k = np.abs(alignment.evaluate(np.arange(900.0, 1400.0)).curvature_1pm)
    assert k.max() == pytest.approx(1.0 / 600.0)
    assert g['full_dark_from_m'] - s.start_chainage_m > 450.0
    assert s.start_chainage_m + s.duration_s * s.speed_kmh / 3.6 > 1410.0
    assert [exe for _, exe, _ in s.extra_nodes] == ['curvature_node']
    assert s.node_params['curvature_node']['alignment'] == 'curved_demo'
    assert s.node_params['imu_compensator_node']['alignment'] == 'curved_demo'
    assert s.node_params['vlc_decoder_node']['lamp_map_path'] == \
        default_lamp_map_path('curved_demo')
    assert '/companion/curvature/pose' in s.recorded_topics()


def _curved_outage_run(s, monkeypatch):
    """A synthetic run of ``s``: the pose error along the track grows to 8 m in the dark
    stretch, its published σ along the tangent to 4 m; two curvature matches 2 m off.
    """
    alignment = Alignment.named('curved_demo')
    v = s.speed_kmh / 3.6
    truth_t = np.arange(0.0, s.duration_s, 0.02)
    chainage = s.start_chainage_m + v * truth_t
    truth_xyz = alignment.to_map(chainage)
    g = s.kind_params
    frac = np.clip((chainage - g['full_dark_from_m'])
                   / (g['first_lit_after_m'] - g['full_dark_from_m']), 0.0, 1.0)
    dark = (chainage >= g['full_dark_from_m']) & (chainage < g['first_lit_after_m'])
    err = np.where(dark, 8.0 * frac, 0.01)
    sigma = np.where(dark, np.maximum(4.0 * frac, 0.02), 0.02)
    pose_xyz = alignment.to_map(chainage + err)
    track = alignment.evaluate(chainage)
    slope = np.column_stack([track.tangent, track.grade])      # dP/ds: the grade climbs
    cov = sigma[:, None, None] ** 2 * np.einsum('ni,nj->nij', slope, slope)
    cov += 1e-4 * np.eye(3)
    diag = [{'integrity_state': 'tracking', 'last_pose_chainage_m': '500.0'},
            {'integrity_state': 'degraded', 'last_pose_chainage_m': '1200.0'},
            {'integrity_state': 'degraded', 'last_pose_chainage_m': '1405.0',
             'curvature_aids_received': '30', 'curvature_aids_applied': '2',
             'curvature_aids_rejected': '1', 'curvature_aids_ignored': '27',
             'curvature_aid_resets': '0', 'last_curvature_aid': 'applied'}]
    # the covariance topic starts before the truth (as in a recorded bag)
    run = bag_eval.RunData(truth_t[25:], truth_xyz[25:],
                           np.tile([0.0, 0.0, 0.0, 1.0], (truth_t.size - 25, 1)),
                           truth_t.copy(), pose_xyz, truth_t.copy(), cov, pose_xyz,
                           diagnostics={'train_localizer: localizer': diag,
                                        'curvature_node: curvature': [
                                            {'status': 'matched'}, {'status': 'matched'},
                                            {'status': 'ambiguous'}]})
    at = np.searchsorted(chainage, [1100.0, 1300.0, 600.0])
    matches = (truth_t[at], alignment.to_map(chainage[at] + 2.0))
    monkeypatch.setattr(companions, '_load_poses',
                        lambda bag, topics: {'/companion/curvature/pose': matches})
    return run


def test_curved_outage_is_scored_along_the_track_with_the_aid(tmp_path, monkeypatch):
    s = companions.curved_outage_scenario(tmp_path)
    r = companions.score_outage(_curved_outage_run(s, monkeypatch), s)
    assert list(r['stretches']) == ['before', 'no lamp', 'after']   # no half-dark stretch
    dark = r['stretches']['no lamp']
    assert 7.5 < dark['max_m'] < 8.0
    # σ along the tangent (heading 19.5° at 1390 m: along map x it is 6 % less)
    assert dark['max_3sigma_along_m'] == pytest.approx(12.0, rel=0.01)
    assert dark['within_3sigma'] == 1.0
    assert dark['integrity_states'] == {'degraded': 1}
    assert r['stretches']['before']['max_m'] == pytest.approx(0.01, abs=1e-3)
    end = r['end_of_dark']
    assert 1389.0 < end['chainage_m'] < 1390.0
    assert end['error_m'] == pytest.approx(8.0 * (end['chainage_m'] - 900.0) / 500.0, rel=0.01)
    assert r['aid']['curvature_aids_applied'] == 2.0 and r['aid']['curvature_aid_resets'] == 0
    assert r['curvature_matches_dark']['matches'] == 2
    assert r['curvature_matches_dark']['matches_in_run'] == 3
    assert r['curvature_matches_dark']['max_m'] == pytest.approx(2.0, abs=1e-3)
    table, figures = companions.outage_table([r])
    name = 'curved_demo, 80 km/h, 50 lamps dark'
    assert name in figures and 'every second lamp' not in table
    assert f'| {name} | no lamp |' in table
    assert '**applied 2**' in table and 'resets 0' in table
    assert 'curvature matches while dark: 2' in table and 'matched 2, ambiguous 1' in table
    text, _ = companions.report_sections(outage=[r])
    assert 'along the track tangent' in text and table in text


@pytest.mark.graph
@pytest.mark.ros
def test_companion_scenario_through_the_graph(ros_env, tmp_path):
    """One straight 120 km/h run, every method beside the graph, at half real time."""
    [scenario] = list(companions.companion_scenarios(points_m=(), speeds_kmh=(120,),
                                                     curved=False))
    scenario.realtime_factor = 0.5
    results = scenarios.run_protocols({'companions': [scenario]}, tmp_path,
                                      LampMap.load(default_lamp_map_path()), lanes=1,
                                      retries=0)
    [r] = results['companions']
    m = r['methods']
    assert set(m) == {key for key, *_ in companions.METHODS}
    assert max(m['vlc_stereo']['errors_m']) < 0.05, r['health']
    for method in ('rssi', 'dead_reckoning', 'ins_beacon'):
        assert len(m[method]['errors_m']) > 10, (method, r['health'])
        assert np.max(m[method]['errors_m']) < 1.0, method
        assert m[method]['processing_ms'][0] is not None, method
    # curvature refuses a straight line and says why
    assert m['curvature']['errors_m'] == []
    assert m['curvature']['statuses'].get('no_curvature_on_alignment', 0) > 0
    text = companions.append_to_report(tmp_path, results['companions'])
    assert text.count('straight, dynamic') == len(companions.METHODS)
