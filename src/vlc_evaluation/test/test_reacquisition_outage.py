"""The curvature core as train_localizer's re-acquisition aid, closed loop on the rig's models.

A 500 m lamp outage at 80 km/h (reacquisition_benchmark.run_outage): on curved_demo the
curvature matches bring the coasting localizer's chainage σ from tens of metres back to
a few; on a straight line the curvature core never gives a match and nothing is applied.
"""
import numpy as np

from vlc_evaluation.benchmarks.reacquisition import run_outage, summary


def test_curved_outage_with_tachometer_speed_is_reacquired_to_metres():
    run = run_outage(aid=True, errors='cold', speed='tacho', start_m=400.0,
                     dark=(900.0, 1400.0), end_m=1450.0, seed=1)
    s = summary(run)
    applied = [a for a in run.aids if a.status == 'applied']
    assert applied and s['aids'].get('reset', 0) == 0
    # Applied only once the coast had made the state uncertain (σ > 5 m), never earlier.
    assert all(a.state_sigma_m > 5.0 for a in applied)
    assert all(a.status == 'ignored_tracking' for a in run.aids
               if a.chainage_m < 900.0)
    inside = run.in_outage(20.0)
    # Without the aid the coast reaches 3σ ≈ 70 m here (the benchmark's table); with it
    # the published σ stays near the trigger, and the error within 3σ throughout.
    assert s['max_3sigma_m'] < 20.0
    assert np.max(run.sigma_m[inside]) < 7.0
    assert s['covered'] == 1.0
    assert s['max_error_m'] < 10.0
    assert s['rejected_lamps'] == 0 and s['after_max_error_m'] < 0.05


def test_straight_outage_gives_no_match_and_applies_nothing():
    run = run_outage(aid=True, errors='cold', speed='localizer', alignment='straight',
                     start_m=0.0, dark=(500.0, 1000.0), end_m=1050.0, seed=2)
    s = summary(run)
    assert run.matches == [] and run.aids == []
    assert s['max_3sigma_m'] > 30.0          # the coast alone
    assert s['covered'] == 1.0 and s['after_max_error_m'] < 0.05
