"""The report writes tables beside the paper's figures, JSON and PNGs from results."""
import json

import pytest

from train_localizer.evaluation import report, scenarios


def _static_results():
    out = []
    for i, d in enumerate(scenarios.TEST_POINTS_M):
        err = None if d == 10.0 else 0.01 * (1 + i % 4)
        out.append({'point_m': d, 'seed': 1, 'error_m': err,
                    'along_m': None if err is None else -err})
    return out


def _dynamic_results():
    return [{'speed_kmh': v, 'seed': 1,
             'points': [{'point_m': 1.0, 'error_m': 0.02 * k, 'along_m': 0.0}
                        for k in range(1, 5)] + [{'point_m': 9.5, 'error_m': None,
                                                   'along_m': None}]}
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


def test_write_report_files(tmp_path):
    text = report.write_report(_static_results(), _dynamic_results(), tmp_path)
    assert (tmp_path / 'static_error_vs_distance.png').stat().st_size > 1000
    assert (tmp_path / 'dynamic_error_per_speed.png').stat().st_size > 1000
    data = json.loads((tmp_path / 'report.json').read_text())
    assert data['figures']['static']['ours']['count'] == 19
    assert 'paper' in text


def test_scenario_lists_cover_the_protocols():
    static = scenarios.static_scenarios()
    assert len(static) == 200
    assert {s.static_point_m for s in static} == set(scenarios.TEST_POINTS_M)
    assert len({s.seed for s in static}) == 10
    dynamic = scenarios.dynamic_scenarios()
    assert len(dynamic) == 60
    assert {s.speed_kmh for s in dynamic} == {20.0, 40.0, 60.0, 80.0, 100.0, 120.0}


def test_update_markdown_replaces_only_the_marked_section(tmp_path):
    report.write_report(_static_results(), _dynamic_results(), tmp_path / 'out')
    readme = tmp_path / 'README.md'
    readme.write_text('# Title\n\nintro\n\n## Accuracy\n')
    report.update_markdown(readme, tmp_path / 'out', 'run_evaluation --protocol demo')
    first = readme.read_text()
    assert first.startswith('# Title\n\nintro') and report.BEGIN_MARK in first
    assert '](docs/evaluation/static_error_vs_distance.png)' in first
    assert (tmp_path / 'docs/evaluation/static_error_vs_distance.png').exists()
    readme.write_text(first + '\nafter\n')
    report.update_markdown(readme, tmp_path / 'out', 'run_evaluation --protocol full')
    second = readme.read_text()
    assert second.count(report.BEGIN_MARK) == 1 and second.endswith('after\n')
    assert '--protocol full' in second and '--protocol demo' not in second
