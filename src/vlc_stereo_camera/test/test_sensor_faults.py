"""core.sensor_faults: parsing, validation and the schedule (windows, bursts, offsets, jumps)."""
import math

import pytest

from vlc_stereo_camera.core.sensor_faults import NS_PER_S, SensorFaults

MS = 1_000_000
EPOCH_NS = 1704067200 * NS_PER_S


def test_defaults_are_no_fault_and_leave_every_stamp_alone():
    for faults in (SensorFaults(), SensorFaults.from_parameters()):
        assert not faults.active and not faults.imu_faults and not faults.camera_faults
        assert faults.describe() == ''
        for t_ns in (0, 1, 2_500_000, 10 * NS_PER_S):
            assert not faults.imu_dropped(t_ns) and not faults.camera_dropped(t_ns)
            assert faults.sensor_stamp_ns(EPOCH_NS + t_ns, t_ns) == EPOCH_NS + t_ns
            assert faults.imu_stamp_ns(EPOCH_NS + t_ns, t_ns) == EPOCH_NS + t_ns
            assert faults.imu_release_ns(t_ns) == t_ns
        assert faults.imu_burst_samples(400.0) == 0


def test_dropout_windows_are_half_open_and_may_overlap():
    faults = SensorFaults.from_parameters(imu_dropouts_s=[1.0, 0.5, 1.25, 0.5, 4.0, 0.01])
    assert faults.imu_dropouts_ns == ((1000 * MS, 1500 * MS), (1250 * MS, 1750 * MS),
                                      (4000 * MS, 4010 * MS))
    assert faults.imu_faults and not faults.camera_faults
    dropped = [t for t in range(0, 5000 * MS, 2_500_000) if faults.imu_dropped(t)]
    # [1.0, 1.75) s (two overlapping windows) and [4.0, 4.01) s at 400 Hz
    assert dropped == list(range(1000 * MS, 1750 * MS, 2_500_000)) + [4000 * MS, 4002_500_000,
                                                                      4005 * MS, 4007_500_000]
    assert faults.imu_dropped(1000 * MS) and not faults.imu_dropped(1000 * MS - 1)
    assert faults.imu_dropped(1750 * MS - 1) and not faults.imu_dropped(1750 * MS)
    assert not any(faults.camera_dropped(t) for t in range(0, 5000 * MS, MS))


def test_camera_dropouts_are_separate_from_the_imus():
    faults = SensorFaults.from_parameters(camera_dropouts_s=[0.5, 0.2])
    assert faults.camera_faults and not faults.imu_faults
    assert faults.camera_dropped(500 * MS) and faults.camera_dropped(699 * MS)
    assert not faults.camera_dropped(700 * MS) and not faults.imu_dropped(600 * MS)
    # a window between two frames (30 fps: 33.3 ms apart) drops none
    frames = [round(k * NS_PER_S / 30) for k in range(60)]
    narrow = SensorFaults.from_parameters(camera_dropouts_s=[0.34, 0.01])
    assert not any(narrow.camera_dropped(t) for t in frames)


def test_bursts_release_each_sample_at_the_first_boundary_after_it():
    faults = SensorFaults.from_parameters(imu_burst_s=0.5)
    assert faults.imu_burst_ns == 500 * MS and faults.imu_faults
    assert faults.imu_release_ns(0) == 500 * MS
    assert faults.imu_release_ns(497_500_000) == 500 * MS
    assert faults.imu_release_ns(500 * MS) == 1000 * MS      # on a boundary: the next one
    # 400 Hz: every burst holds [(k-1)B, kB), 200 samples
    releases = [faults.imu_release_ns(n * 2_500_000) for n in range(800)]
    assert [releases.count(k * 500 * MS) for k in range(1, 5)] == [200] * 4
    assert faults.imu_burst_samples(400.0) >= 200
    assert faults.imu_burst_samples(2460.0) >= math.ceil(0.5 * 2460)
    # bursts move no stamp
    assert faults.imu_stamp_ns(EPOCH_NS + 7, 7) == EPOCH_NS + 7


def test_imu_stamp_offset_shifts_imu_stamps_only():
    faults = SensorFaults.from_parameters(imu_stamp_offset_s=-0.0125)
    assert faults.imu_stamp_offset_ns == -12_500_000
    assert faults.imu_faults and not faults.camera_faults
    assert faults.imu_stamp_ns(EPOCH_NS + NS_PER_S, NS_PER_S) == EPOCH_NS + 987_500_000
    assert faults.sensor_stamp_ns(EPOCH_NS + NS_PER_S, NS_PER_S) == EPOCH_NS + NS_PER_S
    assert faults.imu_release_ns(NS_PER_S) == NS_PER_S        # released at the true time


def test_clock_jumps_are_cumulative_from_their_instant_on_either_sign():
    # given out of order: +0.2 s at 1 s, -0.5 s at 2 s, +0.05 s at 2 s
    faults = SensorFaults.from_parameters(sensor_clock_jumps_s=[2.0, -0.5, 1.0, 0.2,
                                                                2.0, 0.05])
    assert faults.imu_faults and faults.camera_faults
    assert faults.clock_jump_ns(0) == 0
    assert faults.clock_jump_ns(1000 * MS - 1) == 0
    assert faults.clock_jump_ns(1000 * MS) == 200 * MS
    assert faults.clock_jump_ns(2000 * MS - 1) == 200 * MS
    assert faults.clock_jump_ns(2000 * MS) == 200 * MS - 500 * MS + 50 * MS
    assert faults.clock_jump_ns(100 * NS_PER_S) == -250 * MS
    t = 2100 * MS
    assert faults.sensor_stamp_ns(EPOCH_NS + t, t) == EPOCH_NS + t - 250 * MS
    # a backward jump repeats stamps: t = 1.9 s and t = 2.35 s are stamped alike
    assert faults.sensor_stamp_ns(EPOCH_NS + 1900 * MS, 1900 * MS) == \
        faults.sensor_stamp_ns(EPOCH_NS + 2350 * MS, 2350 * MS)


def test_offset_and_jumps_add_up_on_the_imu():
    faults = SensorFaults.from_parameters(imu_stamp_offset_s=0.003,
                                          sensor_clock_jumps_s=[1.0, -0.1])
    assert faults.imu_stamp_ns(EPOCH_NS, 0) == EPOCH_NS + 3 * MS
    assert faults.imu_stamp_ns(EPOCH_NS + NS_PER_S, NS_PER_S) == \
        EPOCH_NS + NS_PER_S + 3 * MS - 100 * MS
    text = faults.describe()
    assert 'IMU stamps +0.003 s' in text and '-0.1 s at 1 s' in text


def test_describe_names_every_fault():
    faults = SensorFaults.from_parameters(imu_dropouts_s=[1.0, 0.5], camera_dropouts_s=[2.0, 1.0],
                                          imu_burst_s=0.25)
    text = faults.describe()
    assert 'IMU dropouts [1, 1.5) s' in text and 'camera dropouts [2, 3) s' in text
    assert 'IMU bursts every 0.25 s' in text


@pytest.mark.parametrize('kwargs, words', [
    ({'imu_dropouts_s': [1.0]}, ['imu_dropouts_s', 'pairs']),
    ({'camera_dropouts_s': [1.0, 0.5, 2.0]}, ['camera_dropouts_s', 'pairs']),
    ({'imu_dropouts_s': [1.0, 0.0]}, ['imu_dropouts_s', 'duration_s must be > 0']),
    ({'imu_dropouts_s': [1.0, -0.5]}, ['imu_dropouts_s', 'duration_s must be > 0']),
    ({'imu_dropouts_s': [1.0, 1e-12]}, ['imu_dropouts_s', 'duration_s must be > 0']),
    ({'camera_dropouts_s': [-1.0, 2.0]}, ['camera_dropouts_s', 'start_s must be >= 0']),
    ({'imu_dropouts_s': [1.0, math.inf]}, ['imu_dropouts_s', 'finite']),
    ({'camera_dropouts_s': [math.nan, 1.0]}, ['camera_dropouts_s', 'finite']),
    ({'sensor_clock_jumps_s': [1.0]}, ['sensor_clock_jumps_s', 'pairs']),
    ({'sensor_clock_jumps_s': [-0.5, 1.0]}, ['sensor_clock_jumps_s', 'at_s must be >= 0']),
    ({'sensor_clock_jumps_s': [1.0, math.inf]}, ['sensor_clock_jumps_s', 'finite']),
    ({'imu_burst_s': -0.1}, ['imu_burst_s']),
    ({'imu_burst_s': math.nan}, ['imu_burst_s']),
    ({'imu_burst_s': 1e-12}, ['imu_burst_s', '1 ns']),
    ({'imu_stamp_offset_s': math.inf}, ['imu_stamp_offset_s', 'finite']),
])
def test_invalid_schedules_raise_value_error_naming_the_parameter(kwargs, words):
    with pytest.raises(ValueError) as err:
        SensorFaults.from_parameters(**kwargs)
    for word in words:
        assert word in str(err.value)


def test_a_jump_before_the_unix_epoch_is_rejected():
    faults = SensorFaults.from_parameters(sensor_clock_jumps_s=[1.0, -10.0])
    faults.check_epoch(EPOCH_NS)
    with pytest.raises(ValueError, match='before the Unix epoch'):
        faults.check_epoch(5 * NS_PER_S)
    SensorFaults.from_parameters(imu_stamp_offset_s=-1.0).check_epoch(NS_PER_S)
    with pytest.raises(ValueError, match='imu_stamp_offset_s'):
        SensorFaults.from_parameters(imu_stamp_offset_s=-1.5).check_epoch(NS_PER_S)


def test_zero_jump_and_zero_offset_are_allowed():
    faults = SensorFaults.from_parameters(sensor_clock_jumps_s=[1.0, 0.0])
    assert faults.sensor_stamp_ns(EPOCH_NS + 2 * NS_PER_S, 2 * NS_PER_S) == \
        EPOCH_NS + 2 * NS_PER_S
