"""Issue 7 in the evaluation: companion scenarios, lamp outage and forged lamp
(``evaluation/companions.py``): scenario construction, lamp maps, tables; and one short
scenario through the real graph with every companion node (about 30 s)."""
import json

import numpy as np
import pytest

from train_localizer.evaluation import companions, scenarios
from vlc_stereo_camera.core.lamp_map import LampMap, default_lamp_map_path


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
        assert p['imu_compensator_node']['heading_time_constant_s'] == 0.0
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


@pytest.mark.graph
@pytest.mark.ros
def test_companion_scenario_through_the_graph(ros_env, tmp_path):
    """One straight 120 km/h run, every method beside the graph, at half real time."""
    [scenario] = [s for s in companions.companion_scenarios(
        points_m=(), speeds_kmh=(120,), curved=False)]
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
