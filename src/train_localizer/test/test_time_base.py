"""The sensor clock's continuity: lone bad stamps, clock steps, stalls, bag loops.

Every run here is scored the way a CBTC consumer would be hurt: a pose is *confidently
wrong* when it is more than 0.5 m off while its published 3σ along the track is under
0.5 m. None may be, whatever the clock does.
"""
import dataclasses
import functools

import numpy as np
import pytest

from train_localizer.core.fix import RigGeometry
from train_localizer.core.integrity import IntegrityState
from train_localizer.core.localizer import Localizer, LocalizerConfig
from train_localizer.core.time_base import (
    FRAME,
    HELD,
    IMU,
    OK,
    OUT_OF_ORDER,
    RESET,
    TimeBaseConfig,
    TimeBaseMonitor,
)
from vlc_common.core.camera import StereoRig
from vlc_common.core.lamp_map import straight_tunnel_map
from vlc_common.core.observation import NS_PER_S, ImuSample
from vlc_stereo_camera.core.trajectory import MotionProfile, Trajectory, Vibration
from vlc_stereo_camera.core.upstream import (
    EPOCH_NS,
    SensorErrors,
    SensorSimulator,
    event_stream,
    from_stamp_ns,
)

RIG = StereoRig()
LAMPS = straight_tunnel_map()
S = NS_PER_S


# ------------------------------------------------------------------ the monitor alone
def test_a_lone_stamp_from_1970_or_the_future_is_dropped_and_moves_nothing():
    mon = TimeBaseMonitor()
    t = EPOCH_NS
    for k in range(100):
        assert mon.check(IMU, t + k * 2_500_000) == OK
    newest = mon.newest_ns(IMU)
    assert mon.check(IMU, 0) == HELD                       # 1970
    assert mon.check(IMU, newest + 2_500_000) == OK         # the next real one
    assert mon.check(IMU, newest + 3600 * S) == HELD        # an hour ahead
    assert mon.check(IMU, newest + 5_000_000) == OK
    assert mon.newest_ns(IMU) == newest + 5_000_000
    assert mon.counters.dropped == 2 and mon.counters.resets == 0


def test_a_new_time_base_needs_agreeing_candidates():
    cfg = TimeBaseConfig(confirm_imu=5, confirm_frames=2)
    mon = TimeBaseMonitor(cfg)
    for k in range(10):
        mon.check(IMU, EPOCH_NS + k * 2_500_000)
    verdicts = [mon.check(IMU, EPOCH_NS - 10 * S + k * 2_500_000, item=k) for k in range(5)]
    assert verdicts == [HELD] * 4 + [RESET]
    mon.reset_streams()
    held = mon.take_held(IMU)
    assert [item for _, item in held] == list(range(5))
    assert all(mon.check(IMU, t) == OK for t, _ in held)
    # candidates that do not agree with each other confirm nothing
    mon = TimeBaseMonitor(cfg)
    mon.check(FRAME, EPOCH_NS)
    assert mon.check(FRAME, 0) == HELD
    assert mon.check(FRAME, EPOCH_NS + 3600 * S) == HELD    # not after the first one
    assert mon.check(FRAME, EPOCH_NS + 3601 * S) == RESET   # ... but agrees with this


def test_imu_back_by_more_than_a_duplicate_is_a_candidate_frames_may_be_late():
    mon = TimeBaseMonitor()
    mon.check(IMU, EPOCH_NS)
    mon.check(FRAME, EPOCH_NS)
    assert mon.check(IMU, EPOCH_NS) == OUT_OF_ORDER          # a duplicate
    assert mon.check(IMU, EPOCH_NS - 100_000_000) == HELD    # 0.1 s back
    assert mon.check(FRAME, EPOCH_NS - 500_000_000) == OUT_OF_ORDER   # a late frame
    assert mon.check(FRAME, EPOCH_NS - 2 * S) == HELD


def test_frames_queued_behind_an_imu_backlog_continue_their_stream():
    """A stalled IMU catches up with 1.5 s of samples, handed on before the frames that
    queued meanwhile: those frames are late, not from another clock. A frame that far
    behind the IMU without continuing its own stream (the first after a reset) still is
    a candidate.
    """
    mon = TimeBaseMonitor()
    mon.check(FRAME, EPOCH_NS)
    mon.check(IMU, EPOCH_NS)
    for k in range(1, 601):
        assert mon.check(IMU, EPOCH_NS + k * 2_500_000) == OK
    for k in range(1, 46):
        assert mon.check(FRAME, EPOCH_NS + k * 33_333_333) == OK
    mon.reset_streams()
    mon.check(IMU, EPOCH_NS + 3 * S)
    assert mon.check(FRAME, EPOCH_NS + 1 * S) == HELD


@pytest.mark.parametrize('field', ['backward_reset_s', 'imu_backward_s', 'blind_gap_s'])
def test_config_rejects_non_positive_windows(field):
    with pytest.raises(ValueError):
        TimeBaseConfig(**{field: 0.0})


# ------------------------------------------------------------------ the localizer
SPEED_KMH = 72.0


@functools.lru_cache(maxsize=4)
def simulate(t_end_s, seed=3):
    profile = MotionProfile('constant', start_chainage_m=3.0, speed_mps=SPEED_KMH / 3.6)
    traj = Trajectory(profile, Vibration(seed=seed))
    sim = SensorSimulator(traj, RIG, LAMPS, SensorErrors(), np.random.default_rng(seed))
    return traj, event_stream(sim, 0.0, t_end_s)


def make():
    return Localizer(LAMPS, LocalizerConfig(geometry=RigGeometry.from_stereo_rig(RIG)))


def restamp(kind, payload, offset_ns):
    """The same measurement under a sensor clock ``offset_ns`` away."""
    if kind == 'imu':
        return dataclasses.replace(payload, stamp_ns=payload.stamp_ns + offset_ns)
    stamp, observations, truth = payload
    return (stamp + offset_ns,
            [dataclasses.replace(o, stamp_ns=o.stamp_ns + offset_ns) for o in observations],
            truth)


def run(loc, events, offset_of, dropped=lambda arrival_s: False, clock=True, states=None):
    """Feed ``events``; a measurement made at true time t carries the stamp
    t + ``offset_of(t)``; returns [(pose, true time it describes)] and the reports.

    With ``clock`` the localizer is told the graph's clock at reception (the arrival
    time, which the sensor clock's steps do not move).
    """
    out, reports = [], []
    for arrival_s, kind, payload in events:
        if dropped(arrival_s):
            continue
        t_true = (payload.stamp_ns if kind == 'imu' else payload[0]) - EPOCH_NS
        offset = offset_of(t_true * 1e-9)
        received = EPOCH_NS + int(arrival_s * S) if clock else None
        stamped = restamp(kind, payload, offset)
        if kind == 'imu':
            report = loc.add_imu(stamped, received)
        else:
            report = loc.add_frame(*stamped[:2])
        reports.append(report)
        if states is not None:
            states.append(loc.status()[0])
        for pose in report.poses:
            out.append((pose, offset))
    return out, reports


def confidently_wrong(scored):
    """Number of poses > 0.5 m off whose 3σ along the track is < 0.5 m, and the fraction
    within their 3σ.
    """
    err = np.array([e for e, _ in scored])
    sigma = np.array([s for _, s in scored])
    bad = (np.abs(err) > 0.5) & (3.0 * sigma < 0.5)
    return int(bad.sum()), float(np.mean(np.abs(err) <= 3.0 * sigma))


def score(traj, poses, jump_at_s, jump_ns):
    """(along-track error, σ) per pose against the truth at the instant it describes.

    After a step forward a stamp ``t`` past the step describes ``t − jump`` and one
    inside the step's empty span the instant of the step (no time passed); after a step
    back a pose describes ``t − offset`` of the clock it was made under.
    """
    out = []
    jump_s = jump_ns * 1e-9
    for pose, offset in poses:
        t = from_stamp_ns(pose.stamp_ns)
        if jump_ns > 0:
            t_true = t if t < jump_at_s else max(jump_at_s, t - jump_s)
        else:
            t_true = t - offset * 1e-9
        x = traj.sample(np.array([t_true])).position_m[0, 0]
        out.append((pose.chainage_m - x, pose.chainage_sigma_m))
    return out


@pytest.mark.parametrize('jump_s', [0.3, 2.0, 10.0, -0.2, -0.8, -30.0])
def test_a_sensor_clock_step_never_gives_a_confidently_wrong_pose(jump_s):
    """Every stamp after t = 3 s moves by ``jump_s`` (the graph's clock does not). The
    localizer either widens the chainage by the distance the train could have run, or
    drops the state (lost) and starts again from the next confirmed lamp; it is back to
    tracking within the next lamps.
    """
    traj, events = simulate(9.0)
    jump_at, jump_ns = 3.0, int(jump_s * S)
    loc = make()
    poses, reports = run(loc, events, lambda t: jump_ns if t >= jump_at else 0)
    assert all(p.stamp_ns for p, _ in poses)
    after = [(p, o) for p, o in poses if o]
    scored = score(traj, poses, jump_at, jump_ns)
    wrong, inside = confidently_wrong(scored)
    assert wrong == 0
    assert inside >= 0.997
    # back to tracking: the last 2 s of poses are centimetre-accurate
    late = score(traj, [(p, o) for p, o in after
                        if from_stamp_ns(p.stamp_ns) - o * 1e-9 > 7.0], jump_at, jump_ns)
    assert late and max(abs(e) for e, _ in late) < 0.05
    assert loc.status()[0] == IntegrityState.TRACKING
    codes = {e.code for r in reports for e in r.events}
    if jump_s < -0.05 or jump_s > 3.0:
        assert loc.monitor.counters.time_resets == 1 and 'time_reset' in codes
    else:
        assert loc.monitor.counters.time_resets == 0 and 'time_doubt' in codes


def test_a_bag_that_loops_resets_and_works_again():
    traj, events = simulate(3.0)
    loc = make()
    poses, _ = run(loc, events, lambda t: 0)
    assert loc.initialized
    n = len(poses)
    states = []
    again, _ = run(loc, events, lambda t: 0, states=states)
    assert loc.monitor.counters.time_resets == 1
    assert IntegrityState.LOST in states
    err = [e for e, _ in score(traj, again, 0.0, 0)]
    assert len(again) > 0.5 * n and max(abs(e) for e in err) < 0.05


@pytest.mark.parametrize('stall_s, lost', [(1.5, False), (5.0, True)])
def test_a_stalled_localizer_bridges_short_stalls_and_restarts_after_long_ones(stall_s, lost):
    """Everything that arrives while the process is stopped is lost (overflowing queues);
    the graph's clock ran on, so a short stall is a gap in which time passed.
    """
    traj, events = simulate(9.0)
    loc = make()
    poses, reports = run(loc, events, lambda t: 0,
                         dropped=lambda a: 3.0 <= a < 3.0 + stall_s)
    wrong, inside = confidently_wrong(score(traj, poses, 0.0, 0))
    assert wrong == 0 and inside >= 0.997
    assert loc.monitor.counters.time_resets == int(lost)
    codes = [e.code for r in reports for e in r.events]
    assert ('time_reset' in codes) == lost
    assert 'time_doubt' not in codes           # the clock showed the time passed
    assert loc.status()[0] == IntegrityState.TRACKING


def test_an_imu_backlog_worked_off_before_the_queued_frames_is_no_new_clock():
    """The IMU process stalled for 1.5 s and catches up at once; the node hands all of
    its samples on before the frames that queued meanwhile (reliable, none lost): the
    frames are fused late, the localizer neither resets nor loses track.
    """
    traj, events = simulate(9.0)
    before = [e for e in events if e[0] < 3.0]
    during = [e for e in events if 3.0 <= e[0] < 4.5]
    after = [e for e in events if e[0] >= 4.5]
    reordered = (before + [e for e in during if e[1] == 'imu']
                 + [e for e in during if e[1] != 'imu'] + after)
    loc = make()
    states = []
    poses, _ = run(loc, reordered, lambda t: 0, states=states)
    assert loc.monitor.counters.time_resets == 0
    assert loc.time_base.counters.dropped == 0
    assert IntegrityState.LOST not in states[len(before):]
    wrong, inside = confidently_wrong(score(traj, poses, 0.0, 0))
    assert wrong == 0 and inside >= 0.997
    assert loc.status()[0] == IntegrityState.TRACKING


def test_without_the_graph_clock_a_stall_widens_the_chainage_honestly():
    traj, events = simulate(9.0)
    loc = make()
    poses, reports = run(loc, events, lambda t: 0, dropped=lambda a: 3.0 <= a < 4.0,
                         clock=False)
    codes = [e.code for r in reports for e in r.events]
    assert 'time_doubt' in codes
    wrong, inside = confidently_wrong(score(traj, poses, 0.0, 0))
    assert wrong == 0 and inside >= 0.997


def test_lone_bad_stamps_change_nothing():
    """A sample from 1970, one from the far future and a frame from 1970 amid a run:
    dropped, counted, and the poses are those of the run without them.
    """
    traj, events = simulate(9.0)
    bad = []
    for arrival, kind, payload in events:
        bad.append((arrival, kind, payload))
        if kind == 'imu' and abs(arrival - 2.0) < 1e-3:
            bad.append((arrival, 'imu', ImuSample(0, payload.accel_mps2, payload.gyro_rps,
                                                  payload.quat_xyzw)))
            bad.append((arrival, 'imu', dataclasses.replace(
                payload, stamp_ns=payload.stamp_ns + 10 ** 6 * S)))
    frames = [i for i, e in enumerate(bad) if e[1] == 'frame' and e[0] > 2.5]
    stamp, obs, truth = bad[frames[0]][2]
    bad.insert(frames[0], (bad[frames[0]][0], 'frame', (S, obs, truth)))
    clean_loc, bad_loc = make(), make()
    clean, _ = run(clean_loc, events, lambda t: 0)
    dirty, _ = run(bad_loc, bad, lambda t: 0)
    assert bad_loc.monitor.counters.time_resets == 0
    assert bad_loc.time_base.counters.dropped == 3
    assert [p.stamp_ns for p, _ in dirty] == [p.stamp_ns for p, _ in clean]
    assert np.allclose([p.chainage_m for p, _ in dirty], [p.chainage_m for p, _ in clean])
