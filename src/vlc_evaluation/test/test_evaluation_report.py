"""The report writes tables beside the paper's figures, JSON and PNGs from results."""
import json

import pytest

from vlc_common.core import lamp_map
from vlc_evaluation import report, scenarios


def _static_results():
    out = []
    for i, d in enumerate(scenarios.TEST_POINTS_M):
        err = None if d == 10.0 else 0.01 * (1 + i % 4)
        raw = {'error_m': None if err is None else 2 * err,
               'along_m': None if err is None else err}
        out.append({'point_m': d, 'seed': 1, 'error_m': err,
                    'along_m': None if err is None else -err,
                    'raw': {'paper': raw, 'constrained': raw},
                    'scenario': {'name': f'static_{d}', 'realtime_factor': 1.0,
                                 'observe_s': 3.0},
                    'latency_ms': {'decoder': [10.0, 20.0], 'exposure_to_pose': [30.0]},
                    'processing_ms': {'vlc_decoder': [5.0, 9.0]},
                    'health': {'degraded': d == 0.5, 'camera_lag_max_s': 0.2 * (d == 0.5)}})
    return out


def _dynamic_results():
    A, B = '4101', '4102'
    return [{'speed_kmh': v, 'seed': 1,
             'points': [{'point_m': 1.0, 'error_m': 0.02 * k, 'along_m': 0.0}
                        for k in range(1, 5)] + [{'point_m': 9.5, 'error_m': None,
                                                   'along_m': None}],
             'every_pose': {'max_m': 0.09, 'mean_m': 0.03, 'count': 100},
             'covariance_3sigma_fraction': 0.998,
             'heading_before_deg': {'min': -5.0, 'max': 7.5},
             'heading_after_deg': {'max_abs': 0.15, 'rms': 0.05},
             'heading_series': {'t_s': [0.0, 0.02, 0.04], 'after_deg': [0.1, 0.0, -0.1],
                                'before_deg': [3.0, 4.0, 5.0]},
             'identification': {'frames': [[4101, 6.5, True, False], [4101, 5.5, True, True],
                                           [4102, 4.5, True, True]],
                                'first_confirmation_m': {A: 5.5, B: 4.5 if v == 20 else None},
                                'wrong_uids': 0, 'anomalies': 0},
             'scenario': {'name': f'dynamic_{v}', 'realtime_factor': 0.5}, 'attempts': 2,
             'health': {'degraded': False, 'camera_lag_max_s': 0.0}}
            for v in (20.0, 120.0)]


def test_static_table_counts_misses():
    table, figures = report.static_table(_static_results())
    assert figures['ours']['misses'] == 1 and figures['ours']['count'] == 19
    assert figures['ours']['max_m'] == pytest.approx(0.04)
    assert '29.73' in table and '| 1 |' in table


def test_dynamic_table_availability_and_paper_columns():
    table, figures = report.dynamic_table(_dynamic_results())
    assert figures[20]['availability'] == pytest.approx(0.8)
    assert figures[120]['test_points']['max_m'] == pytest.approx(0.08)
    assert '32.09' in table                   # paper at 20 km/h
    assert table.count('\n') == 3             # header, rule, two speeds


def test_static_table_has_the_raw_single_frame_rows():
    table, figures = report.static_table(_static_results())
    assert figures['raw_paper']['max_m'] == pytest.approx(0.08)
    assert figures['raw_constrained_along_track']['misses'] == 1
    assert 'raw single frame, paper eq. 12–14' in table


def test_detail_identification_latency_and_health_tables():
    table, figures = report.dynamic_detail_table(_dynamic_results())
    assert figures[20]['heading_before_min_deg'] == -5.0
    assert figures[120]['covariance_3sigma_fraction'] == pytest.approx(0.998)
    assert '-5.00 … +7.50' in table
    table, by_dist, figures = report.identification_table(_dynamic_results())
    assert figures[20]['lamps_identified'] == 2 and figures[120]['lamps_identified'] == 1
    # only 4102 was seen closer than 5 m (passed); at 120 km/h it was not identified
    assert figures[20]['lamps_passed'] == 1 and figures[20]['lamps_passed_identified'] == 1
    assert figures[120]['lamps_passed'] == 1 and figures[120]['lamps_passed_identified'] == 0
    assert figures[20]['first_confirmation_median_m'] == pytest.approx(5.0)
    assert figures[20]['identified_frame_rate'] == pytest.approx(2 / 3)
    assert '| 20 | – | – | – | – | 100 % | 100 % | 0 % |' in by_dist
    # latency counts only real-time runs when there are any (the static ones here)
    table, figures = report.latency_table(_static_results() + _dynamic_results())
    assert figures['runs'] == 20 and figures['decoder']['count'] == 40
    assert figures['decoder']['processing_median_ms'] == pytest.approx(5.0)
    # a result of [median, max] (a bag from before the p99) has no p99
    assert figures['decoder']['processing_max_ms'] == pytest.approx(9.0)
    assert figures['decoder']['processing_p99_ms'] is None
    assert '| vlc_decoder | frame complete → vlc/lamps sent |' in table
    assert '5.00 / – / 9.00 |' in table
    assert figures['exposure_to_pose']['median_ms'] == pytest.approx(30.0)
    text, figures = report.health_summary(_static_results() + _dynamic_results())
    assert figures['reruns'] == 2 and figures['degraded'] == ['static_0.5']
    assert figures['realtime_factor_min'] == 0.5


def test_write_report_files(tmp_path):
    replay = [{'bag': 'bags/x', 'poses': 10, 'first_pose_s': 0.2,
               'every_pose': {'max_m': 0.01, 'mean_m': 0.005, 'p95_m': 0.009},
               'identification': {'first_confirmation_m': {'1': 3.0, '2': None},
                                  'wrong_uids': 0, 'frames': []},
               'health': {'degraded': False, 'camera_lag_max_s': 0.0}}]
    text = report.write_report(_static_results(), _dynamic_results(), tmp_path,
                               ablations=('| ablation table |', {'baseline': {}}),
                               replays=replay)
    for name in ('static_error_vs_distance.png', 'dynamic_error_per_speed.png',
                 'heading_compensation.png'):
        assert (tmp_path / name).stat().st_size > 1000, name
    data = json.loads((tmp_path / 'report.json').read_text())
    assert data['figures']['static']['ours']['count'] == 19
    assert data['figures']['replay']['bags/x']['lamps_identified'] == 1
    # per-frame arrays stay out of the committed JSON
    assert 'latency_ms' not in json.dumps(data['dynamic'][0]['identification'])
    assert 'frames' not in data['dynamic'][0]['identification']
    assert 'heading_series' not in data['dynamic'][0]
    assert 'paper' in text and '| ablation table |' in text and '`bags/x`' in text
    assert 'after 3 s of simulated time' in text


def test_latency_runs_are_logged_and_tabled(tmp_path):
    """Each latency replay run appends its figures; the report tables every one."""
    assert report.latency_runs_table(tmp_path) == ('', [])
    for p99, after in ((58.1, 28.7 * 60), (36.0, 0.0)):
        figures = {'exposure_to_pose': {'count': 259, 'median_ms': 29.0, 'p99_ms': p99,
                                        'max_ms': p99 + 3.0},
                   'decoder': {'processing_median_ms': 4.2},
                   'spot_locator': {'processing_median_ms': None}}
        report.append_latency_run(tmp_path, 'run_evaluation --latency', figures, after)
    table, runs = report.latency_runs_table(tmp_path)
    assert [r['p99_ms'] for r in runs] == [58.1, 36.0]
    assert [r['after_min'] for r in runs] == [28.7, 0.0]
    assert table.count('\n') == 3                       # header, rule, two runs
    assert '| 259 | 29.00 / 58.10 / 61.10 | 4.20 / – / – |' in table
    replay = [{'bag': 'bags/x', 'poses': 10, 'first_pose_s': 0.2, 'latency_ms': {},
               'every_pose': {'max_m': 0.01, 'mean_m': 0.005, 'p95_m': 0.009},
               'identification': {'first_confirmation_m': {}, 'wrong_uids': 0, 'frames': []},
               'health': {'degraded': False, 'camera_lag_max_s': 0.0}}]
    text = report.write_report([], [], tmp_path, replays=replay)
    assert 'Every latency replay run into this output folder' in text and table in text


def test_scenario_lists_cover_the_protocols():
    static = scenarios.static_scenarios()
    assert len(static) == 200
    assert {s.static_point_m for s in static} == set(scenarios.TEST_POINTS_M)
    assert len({s.seed for s in static}) == 10
    dynamic = scenarios.dynamic_scenarios()
    assert len(dynamic) == 60
    assert {s.speed_kmh for s in dynamic} == {20.0, 40.0, 60.0, 80.0, 100.0, 120.0}
    # Each run starts just past a lamp of the map (the next in view at once), and after
    # its unscored lead-in (two cells, and 3 s at speed) four lamp cells are scored.
    lamps_x = lamp_map.straight_tunnel_map().positions[:, 0]
    for s in dynamic:
        assert 0.0 < s.start_chainage_m - lamps_x[lamps_x <= s.start_chainage_m].max() <= 1.0
        v = s.speed_kmh / 3.6
        settle_s = scenarios.dynamic_settle_s(s.speed_kmh)
        assert settle_s * v >= 20.0 - 1e-9 and settle_s >= scenarios.LEAD_IN_S - 1e-9
        assert s.duration_s * v - settle_s * v == pytest.approx(41.0)


def test_update_markdown_replaces_only_the_marked_section(tmp_path):
    report.write_report(_static_results(), _dynamic_results(), tmp_path / 'out')
    readme = tmp_path / 'README.md'
    readme.write_text('# Title\n\nintro\n\n## Accuracy\n')
    report.update_markdown(readme, tmp_path / 'out', 'run_evaluation --protocol demo')
    first = readme.read_text()
    assert first.startswith('# Title\n\nintro') and report.BEGIN_MARK in first
    assert '| static, 0.5–10 m before a lamp' in first and '](docs/RESULTS.md)' in first
    results = (tmp_path / 'docs' / 'RESULTS.md').read_text()
    assert results.startswith('# Results') and results.count(report.BEGIN_MARK) == 1
    assert '](evaluation/static_error_vs_distance.png)' in results
    assert '](evaluation/heading_compensation.png)' in results
    assert (tmp_path / 'docs/evaluation/static_error_vs_distance.png').exists()
    assert (tmp_path / 'docs/evaluation/heading_compensation.png').exists()
    readme.write_text(first + '\nafter\n')
    report.update_markdown(readme, tmp_path / 'out', 'run_evaluation --protocol full')
    second = readme.read_text()
    assert second.count(report.BEGIN_MARK) == 1 and second.endswith('after\n')
    assert '--protocol full' in second and '--protocol demo' not in second
    results = (tmp_path / 'docs' / 'RESULTS.md').read_text()
    assert results.count(report.BEGIN_MARK) == 1 and '--protocol full' in results


def test_cpu_and_peak_rss_files_are_parsed_and_summed_per_run(tmp_path):
    from vlc_evaluation import graph_runner
    (tmp_path / 'a_node.log.cpu').write_text('1.250 0.250 204800\n')
    (tmp_path / 'b_node.log.cpu').write_text('0.500 0.100\n')      # written before RSS
    (tmp_path / 'c_node.log.cpu').write_text('garbage\n')
    assert graph_runner.read_cpu_seconds(tmp_path) == {'a_node': 1.5, 'b_node': 0.6}
    assert graph_runner.read_peak_rss_mib(tmp_path) == {'a_node': 200.0}
    assert 1024 < graph_runner.peak_rss_kib() < 4 * 1024 * 1024   # this process, KiB
    phases = {'started': 0.3, 'ready': 2.7, 'sim_started': 2.8, 'camera_done': 6.0,
              'drained': 6.4, 'stopped': 6.6}
    runs = [{'timing': dict(phases, cpu_s={'a': 1.0, 'b': 2.0},
                            rss_mib={'a': 100.0 + k, 'b': 300.0 + 10 * k})}
            for k in range(3)] + [{'timing': dict(phases, cpu_s={'a': 1.0})}]
    text, figures = report.timing_summary(runs)
    assert figures['rss_mib'] == {'a': 101.0, 'b': 310.0}
    assert figures['rss_max_mib'] == {'a': 102.0, 'b': 320.0}
    assert figures['graph_rss_mib'] == {'median': 411.0, 'max': 422.0}
    assert 'Peak RSS per node' in text and 'whole graph 411 (largest run 422) = a 101, b 310' \
        in text
    # where the ready phase went: each awaited topic's median, the last three named
    for k, run in enumerate(runs):
        run['timing']['ready_topics'] = {'/imu/data': 0.5, '/vlc/lamps': 1.0 + k,
                                         '/clock': 2.0 + k, '/ground_truth/pose': 3.0}
    text, figures = report.timing_summary(runs)
    assert list(figures['ready_topics_s']) == ['/imu/data', '/vlc/lamps',
                                               '/ground_truth/pose', '/clock']
    assert figures['ready_topics_s']['/clock'] == 3.5
    assert text.endswith('(median s since the start): /vlc/lamps 2.50, '
                         '/ground_truth/pose 3.00, /clock 3.50.')
    # runs without the memory figures (exec-spawned nodes): no RSS sentence
    text, figures = report.timing_summary(runs[3:])
    assert 'RSS' not in text and 'rss_mib' not in figures
    # no simulated length in the runs: no CPU-per-simulated-second sentence
    assert 'cpu_per_simulated_s' not in figures and 'per simulated second' not in text


def test_cpu_per_simulated_second_is_the_wall_time_floor():
    runs = [{'scenario': {'duration_s': 2.0}, 'timing': {'cpu_s': {'a': 3.0, 'b': 1.0}}},
            {'scenario': {'duration_s': 10.0}, 'timing': {'cpu_s': {'a': 20.0}}},
            {'scenario': {'duration_s': 5.0}, 'timing': {}},          # no CPU: left out
            {'timing': {'cpu_s': {'a': 9.0}}}]                        # no length: left out
    cost = report.cpu_per_simulated_second(runs, cores=2)
    assert cost == {'runs': 2, 'cpu_s': 24.0, 'simulated_s': 12.0, 'ratio': 2.0, 'cores': 2}
    assert report.cpu_per_simulated_second(runs[2:]) is None
    phases = {'started': 0.3, 'ready': 2.7, 'sim_started': 2.8, 'camera_done': 6.0,
              'drained': 6.4, 'stopped': 6.6}
    for run in runs:
        run['timing'].update(phases)
    text, figures = report.timing_summary(runs)
    assert figures['cpu_per_simulated_s']['ratio'] == 2.0
    assert '24 CPU-s for 12 s simulated, 2.00 CPU-s per simulated second' in text


def test_a_lockstep_graphs_wall_time_is_its_start_its_run_and_its_stop():
    """A lockstep run has no ready, gate or drain phase of its own: one process builds
    its nodes and simulates the scenario (runner.run_scenario_lockstep).
    """
    runs = [{'timing': {'started': 0.01, 'ran': 2.0 + k, 'stopped': 2.1 + k,
                        'cpu_s': {'lockstep_graph': 1.9 + k}}} for k in range(3)]
    text, figures = report.timing_summary(runs, report.LOCKSTEP_PHASES)
    assert text.startswith('Wall time per run (median, s): start 0.01, build and simulate '
                           '2.99, stop 0.10, score 0.00.')
    assert set(figures['phases_s']) == {'start', 'build and simulate', 'stop', 'score'}


def test_latency_table_processing_median_p99_max():
    runs = [{'scenario': {'realtime_factor': 1.0},
             'latency_ms': {'exposure_to_pose': [20.0, 30.0], 'readout_wait': [12.0, 15.0],
                            'frame_to_pose': [8.0, 15.0]},
             'processing_ms': {'spot_locator': values}}
            for values in ([4.0, 7.0, 11.0], [6.0, 8.0, 12.0], [None, None, None])]
    table, figures = report.latency_table(runs)
    # the runs' medians' median, the largest p99 and the largest max
    assert figures['spot_locator']['processing_median_ms'] == pytest.approx(5.0)
    assert figures['spot_locator']['processing_p99_ms'] == pytest.approx(8.0)
    assert figures['spot_locator']['processing_max_ms'] == pytest.approx(12.0)
    assert '| 5.00 / 8.00 / 12.00 |' in table
    # the end-to-end latency's two parts have rows of their own
    assert figures['readout_wait']['median_ms'] == pytest.approx(13.5)
    assert figures['frame_to_pose']['max_ms'] == pytest.approx(15.0)
    assert '| … of it: the graph | frame complete → train/pose sent |' in table


def test_live_graph_alone_latency_section_and_log(tmp_path):
    live = [{'scenario': {'realtime_factor': 1.0, 'name': f'dynamic_120kmh_seed{k}'},
             'latency_ms': {'exposure_to_pose': [25.0 + k, 35.0 + k]},
             'processing_ms': {'spot_locator': [3.0, 5.0, 6.0]},
             'health': {'degraded': k == 2, 'camera_lag_max_s': 0.0}} for k in (1, 2)]
    text = report.write_report([], [], tmp_path, title='Evaluation', live_alone=live)
    assert '### Latency, the whole live graph alone at real time' in text
    assert '1 of 2 runs had a node behind' in text
    figures = json.loads((tmp_path / 'report.json').read_text())['figures']
    assert figures['latency_live']['exposure_to_pose']['count'] == 4
    assert figures['latency_live']['behind'] == 1
    # the latency log keeps the live figures beside the replay's
    replay = report.latency_table([{'scenario': {'realtime_factor': 1.0},
                                    'latency_ms': {'exposure_to_pose': [24.0]}}])[1]
    report.append_latency_run(tmp_path, 'cmd', replay, 0.0,
                              live=report.latency_table(live)[1])
    report.append_latency_run(tmp_path, 'cmd2', replay, 0.0)
    table, runs = report.latency_runs_table(tmp_path)
    assert runs[0]['live_samples'] == 4 and runs[0]['live_p99_ms'] == pytest.approx(36.97)
    assert '| 31.50 / 36.97 |' in table and table.rstrip().endswith('| – |')


def test_replays_of_a_drawn_installation_have_their_own_latency_table(tmp_path):
    """The realistic profile's latency bags are tabled apart from the ideal rig's, named
    in the README's summary and kept in the latency log.
    """
    def replay(profile, e2e):
        return {'bag': f'bags/{profile}', 'poses': 10, 'first_pose_s': 0.2,
                'scenario': {'realtime_factor': 1.0, 'rig_profile': profile},
                'latency_ms': {'exposure_to_pose': e2e},
                'processing_ms': {'vlc_decoder': [7.0, 9.0, 9.5]},
                'every_pose': {'max_m': 0.01, 'mean_m': 0.005, 'p95_m': 0.009},
                'identification': {'first_confirmation_m': {}, 'wrong_uids': 0, 'frames': []},
                'health': {'degraded': False, 'camera_lag_max_s': 0.0}}
    replays = [replay('ideal', [25.0, 27.0]), replay('realistic', [33.0, 35.0, 37.0])]
    ideal, drawn = report.replays_by_profile(replays)
    assert [r['bag'] for r in ideal] == ['bags/ideal']
    assert [r['bag'] for r in drawn] == ['bags/realistic']
    text = report.write_report([], [], tmp_path, replays=replays)
    assert '### Latency, sensor bags of a drawn installation replayed' in text
    figures = json.loads((tmp_path / 'report.json').read_text())['figures']
    assert figures['latency_replay']['exposure_to_pose']['count'] == 2
    assert figures['latency_replay_realistic']['exposure_to_pose']['count'] == 3
    summary = report.summary_markdown(figures, 'docs/RESULTS.md')
    assert 'median 26.0 ms' in summary and '`realistic` rig profile: median 35.0 ms' in summary
    report.append_latency_run(tmp_path, 'cmd', report.latency_table(ideal)[1], 0.0,
                              realistic=report.latency_table(drawn)[1])
    table, runs = report.latency_runs_table(tmp_path)
    assert runs[0]['realistic_samples'] == 3
    assert runs[0]['realistic_decoder_processing_ms'] == pytest.approx(7.0)
    assert table.rstrip().endswith('| 35.00 / 36.96, 7.00 / – |')


def test_lockstep_runs_are_left_out_of_latency_and_timed_apart(tmp_path):
    phases = {'started': 0.0, 'ready': 0.0, 'sim_started': 0.0, 'camera_done': 2.0,
              'drained': 2.0, 'stopped': 2.1}
    static = _static_results()
    for k, r in enumerate(static):
        r['timing'] = dict(phases, cpu_s=({'lockstep_graph': 1.5} if k % 2 else
                                          {'train_localizer_node': 1.0, 'bag_recorder': 0.5}))
        r['scenario']['lockstep'] = bool(k % 2)
        r['scenario']['duration_s'] = 2.0
    lockstep = [r for r in static if r['scenario']['lockstep']]
    text, figures = report.health_summary(static)
    assert figures['lockstep_runs'] == len(lockstep) > 0
    assert f'{len(lockstep)} of the {len(static)} runs were lockstep graphs' in text
    report.write_report(static, [], tmp_path)
    data = json.loads((tmp_path / 'report.json').read_text())['figures']
    # latency over the protocol runs: the graph's only (a lockstep run takes no time)
    assert data['latency']['runs'] == len(static) - len(lockstep)
    assert data['timing']['cpu_s'] == {'bag_recorder': 0.5, 'train_localizer_node': 1.0}
    assert data['timing_lockstep']['cpu_s'] == {'lockstep_graph': 1.5}
    text = (tmp_path / 'report.md').read_text()
    assert f'Lockstep graphs ({len(lockstep)}): Wall time per run' in text
    # all of them lockstep: no latency table over the protocol runs at all
    for r in static:
        r['scenario']['lockstep'] = True
    report.write_report(static, [], tmp_path / 'all')
    data = json.loads((tmp_path / 'all' / 'report.json').read_text())['figures']
    assert 'latency' not in data and 'timing' not in data and 'timing_lockstep' in data
