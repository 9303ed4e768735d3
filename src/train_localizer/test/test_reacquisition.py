"""Re-acquisition aid (core/reacquisition.py): chainage matches after a long lamp outage.

The localizer core runs on simulated lamps and IMU along curved_demo; the aid gets
synthetic matches (truth + seeded noise of the stated σ, or deliberately wrong ones) once
per second of sensor time. The closed loop with the real curvature core is tested in
companion_localizers (test_reacquisition_outage.py).
"""
import math

import numpy as np
import pytest

from train_localizer.core.fix import RigGeometry
from train_localizer.core.localizer import Localizer, LocalizerConfig
from train_localizer.core.reacquisition import (
    APPLIED,
    IGNORED,
    REJECTED_GATE,
    RESET,
    UNCONFIRMED,
    ChainageAid,
    ReacquisitionConfig,
    chainage_measurement,
)
from train_localizer.core.track import Track
from vlc_common.core.alignment import Alignment
from vlc_common.core.camera import StereoRig
from vlc_common.core.lamp_map import alignment_lamp_map
from vlc_stereo_camera.core.trajectory import MotionProfile, Trajectory, Vibration
from vlc_stereo_camera.core.upstream import (
    SensorErrors,
    SensorSimulator,
    dark_lamps,
    event_stream,
    feed_localizer,
    from_stamp_ns,
)

RIG = StereoRig()
DEMO = Alignment.named('curved_demo')
LAMPS = alignment_lamp_map(DEMO)
_DEG = math.pi / 180.0
# A compensator whose pitch is off by 0.5° (10 s correlation, reported): the IMU-only
# coast drifts and its σ grows to tens of metres over 500 m.
COLD = SensorErrors(attitude_sigma_rad=(0.03 * _DEG, 0.5 * _DEG, 0.1 * _DEG),
                    attitude_corr_time_s=10.0)


def run(dark, start_m=700.0, end_m=1300.0, matches=None, aid_config=None, errors=COLD,
        seed=3, prior=None, frames=True):
    """Localizer along curved_demo at 80 km/h, lamps in ``dark`` removed; ``matches(t_s,
    truth_m)`` → (chainage, σ) or None, once per second. Returns (poses arrays, aid, fixes).
    """
    v = 80.0 / 3.6
    traj = Trajectory(MotionProfile('constant', start_chainage_m=start_m, speed_mps=v),
                      Vibration(seed=seed), alignment=DEMO)
    sim = SensorSimulator(traj, RIG, LAMPS, errors, np.random.default_rng(seed))
    cfg = LocalizerConfig(geometry=RigGeometry.from_stereo_rig(RIG))
    cfg.fix.track = Track(DEMO)
    if prior is not None:
        cfg.initial_chainage_m, cfg.initial_chainage_sigma_m = prior
        cfg.initial_speed_mps = v
    loc = Localizer(LAMPS, cfg)
    aid = ChainageAid(loc, aid_config or ReacquisitionConfig())
    next_match = 1.0

    def match_once_a_second(kind, payload, report):
        nonlocal next_match
        if kind != 'imu' or matches is None:
            return
        t = from_stamp_ns(payload.stamp_ns)
        if t >= next_match:
            next_match += 1.0
            m = matches(t, float(traj.sample(t).chainage_m[0]))
            if m is not None:
                aid.add(payload.stamp_ns, m[0], m[1] ** 2)

    events = event_stream(sim, 0.0, (end_m - start_m) / v)
    if not frames:
        events = [e for e in events if e[1] == 'imu']
    poses, fixes, _ = feed_localizer(loc, events, dark_lamps(LAMPS, dark),
                                     match_once_a_second)
    t = np.array([from_stamp_ns(p.stamp_ns) for p in poses])
    truth = traj.sample(t).chainage_m
    est = np.array([p.chainage_m for p in poses])
    sigma = np.array([p.chainage_sigma_m for p in poses])
    return (t, truth, est - truth, sigma), aid, fixes


def noisy(sigma_m, seed=5, offset_m=0.0):
    rng = np.random.default_rng(seed)
    return lambda t, truth: (truth + offset_m + rng.normal(0.0, sigma_m), sigma_m)


DARK = (750.0, 1250.0)


@pytest.fixture(scope='module')
def outage_without_aid():
    return run(DARK, matches=noisy(2.0), aid_config=ReacquisitionConfig(enabled=False))


def test_outage_on_a_curve_aid_bounds_error_and_sigma_to_the_match(outage_without_aid):
    """500 m dark at 80 km/h: without the aid the 3σ grows to tens of metres; with
    matches of σ = 2 m it stays at a few metres, the error within it, and the first lamp
    after the outage is accepted at once (its gate needs the state within metres).
    """
    (t0, x0, e0, s0), aid0, fixes0 = outage_without_aid
    (t1, x1, e1, s1), aid1, fixes1 = run(DARK, matches=noisy(2.0))
    late0 = (x0 > DARK[0] + 300.0) & (x0 < DARK[1])
    late1 = (x1 > DARK[0] + 300.0) & (x1 < DARK[1])
    assert aid0.counters.applied == 0
    assert np.max(s0[late0]) > 15.0                  # 3σ > 45 m without the aid
    assert aid1.counters.applied >= 2
    assert np.max(s1[late1]) < 6.0                   # ≤ the trigger σ (5 m) + one step
    assert np.max(np.abs(e1[late1])) < 8.0
    assert np.all(np.abs(e1) <= 3.0 * s1 + 1e-9)
    assert np.all(np.abs(e0) <= 3.0 * s0 + 1e-9)
    assert np.max(s1[late1]) < np.max(s0[late0]) / 3.0
    for x, e, fixes in ((x0, e0, fixes0), (x1, e1, fixes1)):
        assert not [f for f in fixes if f.status.startswith('rejected')]
        after = x > DARK[1] + 15.0
        assert after.any() and np.max(np.abs(e[after])) < 0.05
    # While lamps were seen every match was ignored.
    early = [a for a in aid1.history if a.chainage_m < DARK[0] - 10.0]
    assert early and all(a.status == IGNORED for a in early)


def test_matches_are_ignored_while_lamps_are_tracked():
    """All lamps lit: even matches 4 m off never touch the state (σ of cm)."""
    (t, x, e, s), aid, _ = run((0.0, 0.0), end_m=900.0, matches=noisy(2.0, offset_m=4.0),
                               errors=SensorErrors())
    assert aid.counters.received >= 7
    assert aid.counters.counts[IGNORED] == aid.counters.received
    assert np.max(np.abs(e)) < 0.06


def test_wrong_and_isolated_matches_never_move_the_state():
    """In the outage: matches 150 m off (another curve) fail the gate, and an isolated
    match (no predecessor within the gap) or one that jumps is unconfirmed. Nothing is
    applied; the state stays what the IMU says.
    """
    calls = []

    def wrong(t, truth):
        calls.append(t)
        if len(calls) % 7 == 3:
            return truth + 30.0 * (-1) ** len(calls), 2.0      # jumps: inconsistent
        return truth + 150.0, 2.0

    (t, x, e, s), aid, _ = run(DARK, end_m=1200.0, matches=wrong,
                               aid_config=ReacquisitionConfig(reset_min_matches=0))
    c = aid.counters.counts
    assert c[APPLIED] == 0 and c[RESET] == 0
    assert c[REJECTED_GATE] >= 5 and c[UNCONFIRMED] >= 2
    inside = (x > DARK[0] + 50.0) & (x < 1200.0)
    assert np.max(np.abs(e[inside])) < 20.0 and np.all(np.abs(e) <= 3.0 * s + 1e-9)
    # An isolated match, alone, is unconfirmed.
    fresh = ChainageAid(aid.localizer)
    state = aid.localizer.current_state()
    rec = fresh.add(aid.localizer.newest_ns, float(state.x[0]) + 1.0, 4.0)
    assert rec.status == UNCONFIRMED


def test_hopeless_state_is_reset_by_a_long_consistent_run_of_matches():
    """No lamp at all, a prior 60 m off claiming 6 m: every match fails the gate; once
    they have agreed over 200 m of running the chainage is reset to them. Without the
    reset rule the state stays 60 m off until its own σ has grown enough (~15 m) for the
    gate to admit the matches.
    """
    (t, x, e, s), aid, _ = run((0.0, 1e9), start_m=700.0, end_m=1050.0, matches=noisy(2.0),
                               prior=(760.0, 6.0), frames=False)
    c = aid.counters.counts
    assert c[RESET] == 1 and c[REJECTED_GATE] >= 4
    reset = [a for a in aid.history if a.status == RESET][0]
    t_reset = from_stamp_ns(reset.stamp_ns)
    assert reset.offset_m < -50.0                 # the prior's 60 m, plus the coast's drift
    assert abs(e[0]) > 50.0
    after = t > t_reset + 0.1
    assert np.all(np.abs(e[after]) <= 3.0 * s[after])
    assert np.max(np.abs(e[t > t[-1] - 2.0])) < 6.0
    (t2, x2, e2, s2), aid2, _ = run((0.0, 1e9), start_m=700.0, end_m=1050.0,
                                    matches=noisy(2.0), prior=(760.0, 6.0), frames=False,
                                    aid_config=ReacquisitionConfig(reset_min_matches=0))
    assert aid2.counters.counts[RESET] == 0
    assert np.min(np.abs(e2[t2 <= t_reset + 0.1])) > 50.0


def test_chainage_measurement_projects_the_pose_and_its_covariance_on_the_track():
    track = Track(DEMO)
    s0 = 380.0
    p, tangent, normal = track.frame(s0)
    cov = 9.0 * np.outer(tangent, tangent) + 0.01 * np.outer(normal, normal)
    s, var = chainage_measurement(track, p + 0.05 * normal, cov)
    assert s == pytest.approx(s0, abs=1e-3) and var == pytest.approx(9.0, rel=1e-6)
    assert all(math.isnan(v) for v in chainage_measurement(track, [math.nan, 0, 0], cov))


def test_bad_input_and_invalid_configuration():
    loc = Localizer(LAMPS, LocalizerConfig(geometry=RigGeometry.from_stereo_rig(RIG)))
    aid = ChainageAid(loc)
    assert aid.add(0, math.nan, 1.0).status == 'bad_input'
    assert aid.add(0, 10.0, 0.0).status == 'bad_input'
    assert aid.add(0, 10.0, 1.0).status == 'not_initialised'
    for kwargs in ({'gate_chi2': 0.0}, {'reset_min_matches': 1.5},
                   {'max_match_sigma_m': 0.1, 'min_match_sigma_m': 1.0},
                   {'min_state_sigma_m': -1.0}):
        with pytest.raises(ValueError):
            ReacquisitionConfig(**kwargs)
