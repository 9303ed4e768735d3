"""Evaluation metrics against hand-computed cases (pure numpy)."""
import numpy as np
import pytest

from vlc_evaluation import metrics


def test_interpolation_and_errors():
    t_true = np.array([0.0, 1.0, 2.0])
    xyz_true = np.array([[0.0, 0, 0], [10.0, 0, 0], [20.0, 0, 0]])
    t_est = np.array([0.5, 1.5, 3.0])
    xyz_est = np.array([[5.03, 0.04, 0.0], [15.0, 0.0, 0.0], [30.0, 0, 0]])
    err, along = metrics.pose_errors(t_est, xyz_est, t_true, xyz_true)
    assert err[0] == pytest.approx(0.05)
    assert along[0] == pytest.approx(0.03)
    assert err[1] == pytest.approx(0.0)
    assert np.isnan(err[2])          # truth does not cover t = 3 s


def test_summary_counts_misses_and_percentiles():
    s = metrics.summarize(np.r_[np.arange(1, 101) / 100.0, np.nan], misses=2)
    assert s.count == 100 and s.misses == 3
    assert s.max_m == pytest.approx(1.0)
    assert s.mean_m == pytest.approx(0.505)
    assert s.p90_m == pytest.approx(np.percentile(np.arange(1, 101) / 100.0, 90))
    empty = metrics.summarize([], misses=5)
    assert empty.count == 0 and empty.misses == 5 and np.isnan(empty.max_m)


def test_test_point_instants_at_constant_speed():
    t = np.linspace(0.0, 10.0, 1001)
    s = 3.0 + 5.0 * t                       # 5 m/s from chainage 3 m
    inst, dist, lamp = metrics.test_point_instants(t, s, [20.0, 40.0], [0.5, 10.0])
    # 20 - 10 = 10 m reached at 1.4 s, 19.5 at 3.3 s, 30 at 5.4 s, 39.5 at 7.3 s
    np.testing.assert_allclose(np.sort(inst), [1.4, 3.3, 5.4, 7.3], atol=1e-9)
    assert set(dist) == {0.5, 10.0} and set(lamp) == {20.0, 40.0}


def test_errors_at_instants_marks_gaps_as_misses():
    t_true = np.linspace(0, 10, 101)
    xyz_true = np.stack([t_true, 0 * t_true, 0 * t_true], 1)
    t_est = np.r_[np.arange(0, 4, 0.02), np.arange(6, 10, 0.02)]   # outage 4..6 s
    xyz_est = np.stack([t_est + 0.01, 0 * t_est, 0 * t_est], 1)
    err, along = metrics.errors_at_instants([1.0, 5.0, 8.01], t_est, xyz_est, t_true, xyz_true)
    assert err[0] == pytest.approx(0.01) and along[2] == pytest.approx(0.01)
    assert np.isnan(err[1])


def test_covariance_consistency():
    diff = np.array([[0.1, 0, 0], [0.5, 0, 0]])
    cov = np.array([np.diag([0.04, 1, 1])] * 2)    # sigma_x = 0.2 m -> 3 sigma 0.6 m
    assert metrics.covariance_consistency(diff, cov) == 1.0
    assert metrics.covariance_consistency(diff, cov, n_sigma=1.0) == 0.5
