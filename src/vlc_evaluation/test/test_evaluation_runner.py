"""Runner pieces without a graph: fork spawner, lanes, readiness counts, ablation set."""
import json
import os
import signal
import subprocess
import sys
import time

import pytest

from vlc_evaluation import ablations, budget, graph_runner, runner, scenarios


@pytest.fixture(scope='module')
def spawner():
    spawner = graph_runner.ForkSpawner([])
    return spawner


def _fork(spawner, tmp_path, entry, argv=()):
    spawner.entry_points = {'tool': entry}
    graph = graph_runner.GraphRun(tmp_path / 'logs', domain_id=7, install=tmp_path,
                                  spawner=spawner)
    exe = tmp_path / 'lib' / 'pkg' / 'tool'
    exe.parent.mkdir(parents=True, exist_ok=True)
    exe.touch()
    graph.start('pkg', 'tool', params={'a': True})
    return graph


def test_forked_entry_point_gets_argv_log_and_cpu_file(spawner, tmp_path):
    data = tmp_path / 'x.json'
    data.write_text('{"b": [1, 2]}')
    spawner.entry_points = {'tool': 'json.tool:main'}
    graph = graph_runner.GraphRun(tmp_path / 'logs', domain_id=7, install=tmp_path,
                                  spawner=spawner)
    exe = tmp_path / 'lib' / 'pkg' / 'tool'
    exe.parent.mkdir(parents=True)
    exe.touch()
    # json.tool reads its argv: the file given as its first argument
    proc = spawner.start(exe, 'tool', [str(data)], graph.env, graph.log_dir / 'tool.log')
    assert proc.wait(30) == 0
    assert json.loads((graph.log_dir / 'tool.log').read_text()) == {'b': [1, 2]}
    assert 'tool' in graph_runner.read_cpu_seconds(graph.log_dir)
    # its peak resident memory beside the CPU: a Python process, tens of MiB
    assert 5.0 < graph_runner.read_peak_rss_mib(graph.log_dir)['tool'] < 4096.0


def test_forked_process_in_its_own_group_stops_on_sigint(spawner, tmp_path):
    graph = _fork(spawner, tmp_path, 'signal:pause')
    with pytest.raises(subprocess.TimeoutExpired):
        graph.procs['tool'].wait(0.5)
    codes = graph.stop_all()
    # signal.pause interrupted: KeyboardInterrupt (exit 1), not a SIGKILL (-9)
    assert codes == {'tool': 1}
    assert 'KeyboardInterrupt' in graph.log('tool')


def _pausing_tool(tmp_path, spawner, script):
    """A graph whose executable ``pkg/tool`` waits until signalled: forked from
    ``spawner`` (``signal.pause``), or, without one, exec'ed from ``script``.
    """
    graph = graph_runner.GraphRun(tmp_path / 'logs', domain_id=7, install=tmp_path,
                                  spawner=spawner)
    exe = tmp_path / 'lib' / 'pkg' / 'tool'
    exe.parent.mkdir(parents=True, exist_ok=True)
    if spawner is not None:
        spawner.entry_points = {'tool': 'signal:pause'}
        exe.touch()
    else:
        exe.write_text(script)
        exe.chmod(0o755)
    return graph


@pytest.mark.parametrize('forked', [True, False])
def test_sigint_stops_the_child_even_when_the_runner_ignores_it(tmp_path, forked):
    # an evaluation started as a script's background job runs with SIGINT ignored, which
    # its children would inherit (across exec too) and then never stop on the runner's
    # SIGINT; the fork server is started here, after SIG_IGN, as in that case
    previous = signal.signal(signal.SIGINT, signal.SIG_IGN)
    spawner = graph_runner.ForkSpawner([]) if forked else None
    try:
        graph = _pausing_tool(tmp_path, spawner,
                              f'#!{sys.executable}\nimport signal\nsignal.pause()\n')
        graph.start('pkg', 'tool')
        with pytest.raises(subprocess.TimeoutExpired):
            graph.procs['tool'].wait(0.5)
        codes = graph.stop_all()
    finally:
        signal.signal(signal.SIGINT, previous)
    # KeyboardInterrupt (exit 1 from the fork server's child; an interpreter that dies of
    # an uncaught KeyboardInterrupt re-raises SIGINT: -2), not the runner's SIGKILL (-9)
    # after the SIGINT went unheard
    assert codes['tool'] in (1, -signal.SIGINT), graph.log('tool')
    assert 'KeyboardInterrupt' in graph.log('tool')


@pytest.mark.parametrize('forked', [True, False])
def test_nice_lowers_the_priority_of_the_child_only(spawner, tmp_path, forked):
    graph = _pausing_tool(tmp_path, spawner if forked else None,
                          '#!/bin/sh\nexec sleep 30\n')
    proc = graph.start('pkg', 'tool', nice=7)
    base = os.getpriority(os.PRIO_PROCESS, 0)
    try:
        deadline = time.monotonic() + 10.0
        while (os.getpriority(os.PRIO_PROCESS, proc.pid) != base + 7
               and time.monotonic() < deadline):
            time.sleep(0.05)
        assert os.getpriority(os.PRIO_PROCESS, proc.pid) == base + 7
        assert os.getpriority(os.PRIO_PROCESS, 0) == base
    finally:
        graph.stop_all()
    assert graph_runner.NICE_ENV not in graph.env


def test_exit_code_of_a_failing_child(spawner, tmp_path):
    bad = tmp_path / 'bad.json'
    bad.write_text('{not json')
    spawner.entry_points = {'tool': 'json.tool:main'}
    proc = spawner.start(tmp_path / 'tool', 'tool', [str(bad)], {}, tmp_path / 'tool.log')
    assert proc.wait(30) == 1
    assert 'Expecting property name' in (tmp_path / 'tool.log').read_text()


def test_entry_points_of_the_installed_nodes():
    found = graph_runner.console_entry_points(runner.EXECUTABLES)
    assert found.get('vlc_decoder_node') == 'vlc_decoder.vlc_decoder_node:main'
    assert set(found) == set(runner.EXECUTABLES)


def test_lane_domains_are_valid_and_distinct():
    for pid in (1, 4321, 99999):
        d = runner.lane_domains(3, pid)
        assert len(set(d)) == 3 and min(d) >= 120 and max(d) <= 232


def test_lane_moves_to_another_valid_domain():
    lane = runner.Lane(domain_id=230, epoch_s=0.0)
    seen = set()
    for _ in range(113):
        lane.move_domain()
        assert 120 <= lane.domain_id <= 232
        seen.add(lane.domain_id)
    assert len(seen) == 113


def test_lane_pace_drops_under_load_and_recovers():
    lane = runner.Lane(domain_id=1, epoch_s=0.0, min_pace=0.3)
    lane.slow_down(severe=False)
    assert lane.pace == pytest.approx(0.8)
    lane.slow_down()
    assert lane.pace == pytest.approx(0.4)
    lane.slow_down()
    assert lane.pace == lane.min_pace
    assert lane.ceiling == pytest.approx(0.36)       # 90 % of the pace that failed last
    lane.recover()
    lane.recover()
    assert lane.pace == pytest.approx(0.36)          # back to the ceiling, not beyond
    paces = []
    for _ in range(60):
        lane.recover()
        paces.append(lane.pace)
    assert paces[0] == pytest.approx(0.36 * 1.02)     # then probing 2 % per clean run
    assert 0.4 < paces[9] < 0.5
    assert lane.pace == 1.0                           # ... up to real time
    assert runner.Lane(domain_id=1, epoch_s=0.0).min_pace == pytest.approx(0.15)
    lane.slow_down(severe=False)
    assert lane.ceiling == pytest.approx(0.9) and lane.pace == pytest.approx(0.8)


def test_readiness_counts_include_the_recorder():
    static = scenarios.static_scenarios(points_m=(5.0,), trials=1)[0]
    need = runner.required_subscriptions(static.recorded_topics())
    assert need['/vlc/lamps'] == 2 and need['/train/pose'] == 2       # localizer|probe + rec
    assert need['/stereo/left/image_raw'] == 2                        # decoder, spot locator
    assert '/ground_truth/spots' not in need                          # static: not recorded
    dynamic = scenarios.dynamic_scenarios(speeds_kmh=(60,), runs=1)[0]
    assert runner.required_subscriptions(dynamic.recorded_topics())['/imu/data_raw'] == 2
    sensors = scenarios.Scenario(name='s', run_processing=False, record_sensors=True)
    need = runner.required_subscriptions(sensors.recorded_topics(), processing=False)
    assert need['/stereo/left/image_raw'] == 1 and '/vlc/lamps' not in need


def test_ablation_groups_and_table():
    groups = ablations.ablation_groups(trials=1, runs=1)
    assert len(groups) == 2 * len(ablations.VARIANTS)
    off = groups['ablations/no_fusion/static'][0]
    assert off.node_params == {'train_localizer_node': {'use_kalman': False}}
    assert groups['ablations/wiener_on/dynamic'][0].node_params == {
        'spot_locator_node': {'wiener': True}}
    assert groups['ablations/baseline/static'][0].node_params == {}
    results = {'ablations/baseline/static': [{'error_m': 0.01}, {'error_m': None}],
               'ablations/baseline/dynamic': [
                   {'speed_kmh': 20.0, 'points': [{'error_m': 0.02}, {'error_m': 0.04}],
                    'every_pose': {'max_m': 0.05}}],
               'ablations/no_fusion/static': [{'error_m': 0.03}]}
    table, figures = ablations.ablation_table(results)
    assert set(figures) == {'baseline', 'no_fusion'}
    assert figures['baseline']['static']['misses'] == 1
    assert figures['baseline']['dynamic'][20]['mean_m'] == pytest.approx(0.03)
    assert '| 4.00 / 3.00 |' in table and table.count('\n') == 3


def test_budget_groups_isolate_one_source_per_row_on_the_same_seeds():
    from vlc_evaluation import budget
    from vlc_stereo_camera.core.installation import BUDGET_SOURCES, load_profile
    groups = budget.budget_groups('realistic', trials=1, runs=1, first_seed=5)
    rows = [name for name, _, _ in budget.budget_rows('realistic')]
    assert rows == ['none', *BUDGET_SOURCES, 'all']
    assert len(groups) == 2 * len(rows)
    for name, rig_profile, _ in budget.budget_rows('realistic'):
        load_profile(rig_profile)                       # every row names a real profile
        for kind in ('static', 'dynamic'):
            group = groups[f'budget/{name}/{kind}']
            assert {s.rig_profile for s in group} == {rig_profile}
            assert [s.seed for s in group] == [s.seed for s in groups[f'budget/all/{kind}']]
    assert groups['budget/survey/static'][0].rig_profile == 'realistic/only-survey'
    assert groups['budget/all/dynamic'][0].seed == 5


def test_budget_table_weights_containment_by_poses_and_writes_its_block(tmp_path):
    from vlc_evaluation import budget
    results = {'budget/none/static': [{'error_m': 0.01, 'seed': 1}, {'error_m': None, 'seed': 2}],
               'budget/none/dynamic': [
                   {'speed_kmh': 40.0, 'seed': 1, 'points': [{'error_m': 0.02}],
                    'every_pose': {'max_m': 0.05, 'count': 300},
                    'covariance_3sigma_fraction': 1.0},
                   {'speed_kmh': 40.0, 'seed': 2, 'points': [{'error_m': 0.04}],
                    'every_pose': {'max_m': 0.06, 'count': 100},
                    'covariance_3sigma_fraction': 0.9}],
               'budget/survey/static': [{'error_m': 0.03, 'seed': 1}]}
    table, figures = budget.budget_table(results)
    assert list(figures) == ['none', 'survey']
    assert figures['none']['within_3sigma'] == pytest.approx(0.975)
    assert '| 4.00 / 3.00 | 97.5 % | 1 |' in table
    assert figures['survey']['within_3sigma'] is None and table.count('\n') == 3
    doc = tmp_path / 'doc.md'
    doc.write_text('# x\n\n<!-- budget:begin -->\nold\n<!-- budget:end -->\n\ntail\n')
    budget.update_docs(doc, table, figures, 'run_evaluation --budget')
    text = doc.read_text()
    assert 'old' not in text and text.endswith('tail\n') and '`survey`' in text
    assert 'seeds 1, 2' in text


def test_budget_of_a_profile_without_sources_exits_2(capsys):
    from vlc_evaluation import cli
    with pytest.raises(SystemExit) as exc:
        cli.main(['--protocol', 'none', '--budget', '--budget-profile', 'ideal',
                  '--out', '/nonexistent/budget'])
    assert exc.value.code == 2
    assert "'ideal' draws nothing" in capsys.readouterr().err


def test_param_text_quotes_strings_in_lists_so_a_colon_stays_in_them():
    import yaml

    from vlc_evaluation.graph_runner import param_text
    text = param_text(['rig_profile=realistic/only:lens', 'seed=1', 2.5, True])
    assert yaml.safe_load(text) == ['rig_profile=realistic/only:lens', 'seed=1', 2.5, True]
    assert param_text([1, 2]) == '[1,2]' and param_text(False) == 'false'
    # strings rcl would read as no value, a bool or a number stay strings
    for value in ('', 'true', '1.5', '/tmp/a b/file.yaml', "it's"):
        assert yaml.safe_load(param_text(value)) == value
    assert param_text('/tmp/kept/lamp_refinement.yaml') == '/tmp/kept/lamp_refinement.yaml'


@pytest.mark.parametrize('fixed, paces', [(False, [0.5, 0.25, 0.15]), (True, [1.0, 1.0, 1.0])])
def test_fixed_pace_keeps_every_run_at_the_starting_pace(fixed, paces):
    # each job finds its lane as the previous one left it, then reports a degraded run
    def job(lane):
        lane.slow_down()
        return lane.pace
    assert runner.run_jobs([job] * 3, lanes=1, spawn='exec', fixed_pace=fixed) == paces


def test_a_child_that_does_not_stop_leaves_its_stacks_in_its_log(tmp_path):
    """SIGINT ignored, as by a node hung in its shutdown: after the timeout the runner
    asks for the stacks (SIGUSR1, on which every node dumps them) and then SIGKILLs.
    """
    script = ('#!' + sys.executable + '\n'
              'import faulthandler, signal, time\n'
              'signal.signal(signal.SIGINT, signal.SIG_IGN)\n'
              'faulthandler.register(signal.SIGUSR1, all_threads=True, chain=False)\n'
              'print("waiting", flush=True)\n'
              'def hung_in_shutdown():\n'
              '    while True:\n'
              '        time.sleep(0.01)\n'
              'hung_in_shutdown()\n')
    graph = _pausing_tool(tmp_path, None, script)
    graph.start('pkg', 'tool')
    deadline = time.monotonic() + 30.0
    while 'waiting' not in graph.log('tool') and time.monotonic() < deadline:
        time.sleep(0.05)
    codes = graph.stop_many(['tool'], timeout_s=0.5)
    assert codes == {'tool': -signal.SIGKILL}
    log = graph.log('tool')
    assert 'most recent call first' in log and 'hung_in_shutdown' in log


def test_the_protocols_run_on_the_lamp_map_they_are_scored_against(tmp_path, capsys):
    """``run_evaluation --lamp-map``: the rig renders the given map and the receivers are
    given it (they used to run on the shipped map while the test points came from the
    given one), and the static trials stand before, the dynamic runs start at and cover
    cells of its lamps. The shipped map keeps the paper's geometry.
    """
    from vlc_common.core.lamp_map import LampMap, default_lamp_map_path, straight_tunnel_map
    from vlc_evaluation import cli
    shipped = LampMap.load(default_lamp_map_path())
    assert scenarios.protocol_geometry(shipped) == (scenarios.LAMP_X_M,
                                                    scenarios.DYNAMIC_START_M, 10.0)
    path = tmp_path / 'spaced_15m.yaml'
    straight_tunnel_map(spacing_m=15.0, count=20).save(path)
    spaced = LampMap.load(path)
    assert scenarios.protocol_geometry(spaced) == (55.0, 10.5, 15.0)

    class Args:
        protocol, trials, observe_s, first_seed = 'full', 1, 2.0, 1
        speeds, runs, cells, realtime_factor = [60], 1, 6, 1.0

    geometry = scenarios.protocol_geometry(spaced)
    static, dynamic = cli.build_scenarios(Args, geometry)
    assert {s.start_chainage_m + s.static_point_m for s in static} == {55.0}
    # the ablation and budget rows stand and start alike
    for group in (ablations.ablation_groups(trials=1, runs=1, geometry=geometry),
                  budget.budget_groups(trials=1, runs=1, geometry=geometry)):
        assert {s.start_chainage_m + s.static_point_m for name, runs in group.items()
                if name.endswith('/static') for s in runs} == {55.0}
        assert {s.start_chainage_m for name, runs in group.items()
                if name.endswith('/dynamic') for s in runs} == {10.5}
    default_static, default_dynamic = cli.build_scenarios(Args, None)
    assert {s.start_chainage_m + s.static_point_m for s in default_static} == {50.0}
    # four scored cells of 15 m instead of 10 m
    assert dynamic[0].duration_s - default_dynamic[0].duration_s == pytest.approx(
        4 * 5.0 / (60 / 3.6))
    run = static[0]
    scenarios.use_lamp_map(run, spaced)
    assert {exe: p['lamp_map_path'] for exe, p in run.node_params.items()} == {
        exe: os.path.realpath(path) for exe in scenarios.LAMP_MAP_NODES}
    # the shipped map, a map built in code and a scenario's own rig map: left as they are
    for lamp_map in (shipped, straight_tunnel_map(spacing_m=15.0, count=20)):
        untouched = scenarios.static_scenarios(trials=1)[0]
        scenarios.use_lamp_map(untouched, lamp_map)
        assert untouched.node_params == {}
    own = scenarios.static_scenarios(trials=1)[0]
    own.node_params = {'stereo_camera_node': {'lamp_map_path': 'rig.yaml'}}
    scenarios.use_lamp_map(own, spaced)
    assert own.node_params == {'stereo_camera_node': {'lamp_map_path': 'rig.yaml'}}
    # a map the protocols cannot stand on is refused with a message
    short = tmp_path / 'one_lamp.yaml'
    straight_tunnel_map(count=1).save(short)
    with pytest.raises(SystemExit) as exc:
        cli.main(['--protocol', 'static', '--lamp-map', str(short), '--out',
                  str(tmp_path / 'out')])
    assert exc.value.code == 2 and 'two lamps or more' in capsys.readouterr().err
    with pytest.raises(SystemExit) as exc:      # a curved line's map on the straight rig
        cli.main(['--protocol', 'none', '--lamp-map', default_lamp_map_path('curved_demo'),
                  '--out', str(tmp_path / 'out')])
    assert exc.value.code == 2 and "'curved_demo' alignment" in capsys.readouterr().err
