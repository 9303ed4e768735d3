"""The departure protocol (evaluation/departures.py): stand, pull away, cruise, brake,
stand; scored per phase against the published covariance.
"""
import numpy as np
import pytest

from vlc_evaluation import departures
from vlc_evaluation.bag_eval import RunData


def test_groups_run_the_station_cycle_on_the_same_seeds_per_variant():
    groups = departures.departure_groups([3, 4])
    assert set(groups) == {'departures/defaults', 'departures/no_gate'}
    a, b = groups['departures/defaults'], groups['departures/no_gate']
    assert [s.seed for s in a] == [s.seed for s in b] == [3, 4]
    s = a[0]
    assert (s.kind, s.motion_profile, s.rig_profile) == ('departure', 'accel_cruise_brake',
                                                         'realistic')
    assert s.node_params['adis16488_node'] == s.node_params['stereo_camera_node']
    assert s.duration_s == pytest.approx(departures.phase_bounds()[-1] + departures.STAND_S)
    assert 'train_localizer_node' not in s.node_params
    assert b[0].node_params['train_localizer_node'] == {'zero_velocity_gate_chi2': 1.0e9}


def _run(lag_m, sigma_m):
    """A run whose poses lag the truth by ``lag_m(t)`` with along-track 1σ ``sigma_m``."""
    t = np.arange(0.0, 24.0, 0.1)
    x = np.interp(t, [0, 5, 10.56, 15.56, 21.1, 24], [10.5, 10.5, 25.9, 53.7, 69.1, 69.1])
    truth = np.column_stack([x, np.zeros_like(t), np.zeros_like(t)])
    est = truth - np.column_stack([lag_m(t), np.zeros_like(t), np.zeros_like(t)])
    cov = np.zeros((t.size, 3, 3))
    cov[:, 0, 0], cov[:, 1, 1], cov[:, 2, 2] = sigma_m ** 2, 1e-4, 1e-4
    return RunData(t, truth, np.tile([0, 0, 0, 1.0], (t.size, 1)), t, est, t, cov, est)


def test_a_departure_left_behind_shows_in_its_phase():
    scenario = departures.departure_groups([1])['departures/defaults'][0]
    good = departures.score_departure(_run(lambda t: 0.01 + 0 * t, 0.02), scenario)
    assert good['all']['within_3sigma'] == 1.0
    assert good['phases']['accelerating']['max_along_m'] == pytest.approx(0.01)
    # held back by up to 5 m while pulling away, at 2 cm of stated σ
    held = departures.score_departure(
        _run(lambda t: np.clip((t - 5.0) * 1.0, 0.0, 5.0) * (t < 10.56), 0.02), scenario)
    acc = held['phases']['accelerating']
    assert acc['max_along_m'] > 4.0 and acc['max_sigmas'] > 100 and acc['within_3sigma'] < 0.2
    assert held['phases']['standing']['within_3sigma'] == 1.0
    table, figures = departures.departures_table({'departures/defaults': [good],
                                                  'departures/no_gate': [held]})
    lines = table.splitlines()
    assert len(lines) == 4 and lines[2].startswith('| the defaults | 1 | 1.0 / 0.5 |')
    assert figures['no_gate']['accelerating'][0] > 4.0
