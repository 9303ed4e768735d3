"""INS + ZUPT + stereo beacon ranging with beacon plausibility (companion method 3)."""
import pytest

from companion_localizers.core.ins_beacon import InsBeacon, InsBeaconConfig
from vlc_stereo_camera.core.upstream import LAMPS, SensorErrors, run_core


@pytest.mark.parametrize('speed_kmh', [20.0, 100.0])
def test_constant_speed_run_is_at_centimetre_level(speed_kmh):
    ins = InsBeacon(InsBeaconConfig(), LAMPS)
    err, _, flags = run_core(ins, speed_kmh, t_end_s=5.0)
    assert len(err) > 150
    assert err.max() < 0.15 and err.mean() < 0.03
    assert flags == [] and ins.ins_counters.beacons_flagged == 0
    assert ins.ins_counters.beacons_accepted >= 2
    assert ins.ins_counters.position_updates > 20


def test_unidentified_lamps_still_give_the_speed():
    # UIDs only after 12 frames: the first frames of every lamp are velocity updates.
    ins = InsBeacon(InsBeaconConfig(), LAMPS)
    err, _, _ = run_core(ins, 60.0, t_end_s=5.0,
                         errors=SensorErrors(confirm_after_frames=12))
    assert ins.ins_counters.velocity_updates > 10
    assert err.max() < 0.2 and err.mean() < 0.05


def _forge(forged_lamp_x, claimed_k):
    """Observation hook: the lamp at ``forged_lamp_x`` broadcasts lamp k's valid UID."""
    def observe(stamp, observations, truth):
        for obs, tr in zip(observations, truth):
            if LAMPS.by_uid(tr['uid']).position_m[0] == forged_lamp_x and obs.uid is not None:
                obs.uid = 0x1000 | claimed_k
    return observe


def test_a_forged_lamp_is_flagged_and_does_not_move_the_position():
    clean = InsBeacon(InsBeaconConfig(), LAMPS)
    err_clean, _, _ = run_core(clean, 60.0, t_end_s=5.0, seed=4)
    ins = InsBeacon(InsBeaconConfig(), LAMPS)
    # The lamp at 50 m broadcasts lamp 8's UID (80 m).
    err, _, flags = run_core(ins, 60.0, t_end_s=5.0, seed=4, observe=_forge(50.0, 8))
    assert flags, 'the forged lamp was not flagged'
    assert {f.uid for f in flags} == {0x1008}
    assert flags[0].verdict == 'distance_mismatch'
    assert flags[0].offset_m == pytest.approx(30.0, abs=1.0)
    assert err.max() < 0.2 and err.mean() < 1.5 * err_clean.mean() + 0.005


def test_a_repeated_uid_ahead_is_flagged_out_of_sequence():
    ins = InsBeacon(InsBeaconConfig(), LAMPS)
    # The lamp at 60 m repeats lamp 5's UID (50 m), which the train has just passed.
    err, _, flags = run_core(ins, 60.0, t_end_s=5.0, seed=5, observe=_forge(60.0, 5))
    assert flags and all(f.uid == 0x1005 for f in flags)
    assert flags[0].verdict == 'out_of_sequence'
    assert err.max() < 0.2


def test_odometer_reading_and_bound():
    ins = InsBeacon(InsBeaconConfig(), LAMPS)
    assert ins.odometer_at(0) is None
    run_core(ins, 36.0, t_end_s=2.0)
    t = ins.filter.newest_ns
    d1, b1 = ins.odometer_at(t - 500_000_000)
    d2, b2 = ins.odometer_at(t)
    assert d2 - d1 == pytest.approx(5.0, abs=0.2)            # 10 m/s for 0.5 s
    assert b2 >= b1 >= 0.0


def test_invalid_configuration_is_refused():
    with pytest.raises(ValueError):
        InsBeaconConfig(velocity_baseline_s=0.0)
    with pytest.raises(ValueError):
        InsBeaconConfig(gate_chi2=-1.0)
