"""adis16488_node: message conversion, the node in-process, and the installed executable."""
import copy
import pathlib
import time
import types

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
import numpy as np
import pytest
import rclpy
from rclpy.exceptions import ParameterException
from rclpy.executors import SingleThreadedExecutor
from rclpy.qos import QoSProfile, ReliabilityPolicy, qos_profile_sensor_data
from sensor_msgs.msg import Imu
import yaml

from vlc_common.core.rotations import rpy_to_matrix
from vlc_common.core.vehicle import ImuMount, VehicleMount
from vlc_common.stamps import epoch_to_ns, sample_stamp_ns
from vlc_stereo_camera import adis16488_node
from vlc_stereo_camera.adis16488_node import NODE_PARAMETERS, Adis16488Node
from vlc_stereo_camera.core.imu_model import (
    Adis16488Model,
    Adis16488Params,
    ImuSampler,
    true_imu_signals,
)
from vlc_stereo_camera.imu_conversions import imu_arrays, imu_message
from vlc_stereo_camera.rig_params import SCENARIO_PARAMETERS, ScenarioConfig

EPOCH_NS = 1704067200 * 10 ** 9


# --- conversions ------------------------------------------------------------------------

def test_stamps_are_epoch_plus_index_over_rate_exactly():
    assert epoch_to_ns(1704067200.0) == EPOCH_NS
    assert epoch_to_ns(1704067200.25) == EPOCH_NS + 250_000_000
    stamps = [sample_stamp_ns(EPOCH_NS, n, 400.0) for n in range(0, 4_000_000, 997)]
    assert all(s == EPOCH_NS + n * 2_500_000 for s, n in zip(stamps, range(0, 4_000_000, 997)))
    # 2460 Hz has no whole-nanosecond period: each stamp is rounded once, never drifts.
    n = 10 ** 9 + 7
    assert sample_stamp_ns(0, n, 2460.0) == round(n * 10 ** 9 / 2460)
    diffs = np.diff([sample_stamp_ns(0, k, 2460.0) for k in range(5000)])
    assert set(diffs.tolist()) == {406504, 406505}


def test_imu_message_fields():
    msg = imu_message(EPOCH_NS + 2_500_000, 'imu_link', (0.1, -0.2, 0.3), (0.5, 0.0, 9.8),
                      1e-6, 2e-4)
    assert msg.header.frame_id == 'imu_link'
    assert (msg.header.stamp.sec, msg.header.stamp.nanosec) == (1704067200, 2_500_000)
    assert msg.orientation_covariance[0] == -1.0
    assert list(msg.angular_velocity_covariance) == [1e-6, 0, 0, 0, 1e-6, 0, 0, 0, 1e-6]
    assert list(msg.linear_acceleration_covariance) == [2e-4, 0, 0, 0, 2e-4, 0, 0, 0, 2e-4]
    assert imu_arrays(msg) == (EPOCH_NS + 2_500_000, (0.1, -0.2, 0.3), (0.5, 0.0, 9.8))


def test_config_file_documents_every_parameter_with_its_default():
    path = pathlib.Path(__file__).resolve().parents[1] / 'config' / 'adis16488_node.yaml'
    values = yaml.safe_load(path.read_text())['/**']['ros__parameters']
    assert values == {name: default for name, default, _ in NODE_PARAMETERS}


# --- the node in-process (its publisher replaced by a list) -----------------------------

@pytest.fixture
def make_node(node_factory):
    def make(**params):
        params.setdefault('follow_clock', False)    # self-paced unless a test gives /clock
        node = node_factory(Adis16488Node, **params)
        node.sent, node.diag_sent = [], []
        # The node refills one message per sample: keep copies.
        node._imu_pub.publish = lambda msg: node.sent.append(copy.deepcopy(msg))
        node._diag_pub.publish = node.diag_sent.append
        return node

    return make


def _run(node, ticks):
    for _ in range(ticks):
        node._on_tick()
    return node.sent


def _scenario(**overrides):
    values = {name: default for name, default, _ in SCENARIO_PARAMETERS}
    values.update(overrides)
    return ScenarioConfig(**values)


def test_node_publishes_the_core_samples_with_exact_stamps(make_node):
    rate = 200.0
    node = make_node(rate_hz=rate, realtime_factor=0.0, seed=7, speed_kmh=60.0)
    sent = _run(node, 3)
    assert len(sent) == 3 * 20                     # 0.1 s of samples per tick
    stamps = [imu_arrays(m)[0] for m in sent]
    assert stamps == [EPOCH_NS + n * 5_000_000 for n in range(len(sent))]
    assert {m.header.frame_id for m in sent} == {'imu_link'}
    model = Adis16488Model(rate, 7, Adis16488Params())
    batch = ImuSampler(_scenario(seed=7, speed_kmh=60.0).trajectory(), model).next(len(sent))
    np.testing.assert_array_equal([imu_arrays(m)[1] for m in sent], batch.omega)
    np.testing.assert_array_equal([imu_arrays(m)[2] for m in sent], batch.f)
    assert sent[0].angular_velocity_covariance[0] == pytest.approx(model.gyro_white_variance)
    assert sent[0].linear_acceleration_covariance[8] == \
        pytest.approx(model.accel_white_variance)
    assert sent[0].orientation_covariance[0] == -1.0


def test_same_seed_same_messages_different_seed_different(make_node):
    runs = [_run(make_node(rate_hz=400.0, realtime_factor=0.0, seed=s), 2) for s in (3, 3, 4)]
    values = [[imu_arrays(m) for m in sent] for sent in runs]
    assert values[0] == values[1]
    assert values[0] != values[2]


def _vehicle_file(tmp_path, **imu):
    mount = VehicleMount()
    mount.imu = ImuMount(**imu)
    path = tmp_path / 'vehicle.yaml'
    mount.save(path)
    return str(path)


def test_truth_mode_with_lever_arm_of_the_vehicle_file(make_node, tmp_path):
    lever = [2.0, -0.5, 1.0]
    node = make_node(rate_hz=100.0, realtime_factor=0.0, noise_enabled=False,
                     vehicle_path=_vehicle_file(tmp_path, position_m=lever),
                     imu_frame_id='imu_front', speed_kmh=80.0)
    sent = _run(node, 5)
    t = np.arange(len(sent)) / 100.0
    omega, f = true_imu_signals(_scenario(speed_kmh=80.0).trajectory(), t, lever)
    np.testing.assert_allclose([imu_arrays(m)[1] for m in sent], omega, rtol=1e-12, atol=1e-15)
    np.testing.assert_allclose([imu_arrays(m)[2] for m in sent], f, rtol=1e-12, atol=1e-12)
    assert sent[0].header.frame_id == 'imu_front'
    assert sent[0].angular_velocity_covariance[0] == 0.0


def test_boresight_of_the_vehicle_file_rotates_both_signals(make_node, tmp_path):
    rpy = np.radians([1.0, -2.0, 3.0])
    node = make_node(rate_hz=100.0, realtime_factor=0.0, noise_enabled=False,
                     vehicle_path=_vehicle_file(tmp_path, rpy_rad=rpy), speed_kmh=60.0)
    sent = _run(node, 3)
    t = np.arange(len(sent)) / 100.0
    omega, f = true_imu_signals(_scenario(speed_kmh=60.0).trajectory(), t, (0.0, 0.0, 0.0))
    R = rpy_to_matrix(*rpy)                     # imu axes in base_link
    np.testing.assert_allclose([imu_arrays(m)[1] for m in sent], omega @ R, atol=1e-15)
    np.testing.assert_allclose([imu_arrays(m)[2] for m in sent], f @ R, atol=1e-12)
    assert np.linalg.norm(f[0] @ R - f[0]) > 0.1   # the rotation is seen


def test_duration_limits_the_run(make_node):
    node = make_node(rate_hz=400.0, realtime_factor=0.0, duration_s=0.25)
    assert not node.finished.done()
    assert len(_run(node, 10)) == 100               # t = 0, 2.5 ms, ..., 247.5 ms
    assert imu_arrays(node.sent[-1])[0] == EPOCH_NS + 247_500_000
    assert node.finished.done() and node.finished.result() == 0


def test_wait_for_subscribers_holds_simulated_time(make_node):
    node = make_node(rate_hz=400.0, realtime_factor=0.0, wait_for_subscribers=1)
    assert _run(node, 3) == []
    sub = node.create_subscription(Imu, 'imu/data_raw', lambda _: None,
                                   qos_profile_sensor_data)
    deadline = time.monotonic() + 10.0              # discovery of the subscription
    while not node.sent and time.monotonic() < deadline:
        node._on_tick()
        time.sleep(0.01)
    assert len(node.sent) == 40
    assert imu_arrays(node.sent[0])[0] == EPOCH_NS     # sample 0 was held back, not lost
    node.destroy_subscription(sub)


def test_realtime_pacing_publishes_only_what_is_due(make_node, monkeypatch):
    wall = [100.0]
    monkeypatch.setattr(adis16488_node, 'time', types.SimpleNamespace(monotonic=lambda: wall[0]))
    node = make_node(rate_hz=400.0, realtime_factor=2.0)
    node._on_tick()                                  # starts the wall clock: sample 0
    assert len(node.sent) == 1
    wall[0] += 0.015625                              # 31.25 ms of simulated time later
    node._on_tick()
    assert len(node.sent) == 13
    node._on_tick()                                  # nothing new is due
    assert len(node.sent) == 13
    wall[0] += 1.0                                   # 2 s behind: one block per tick
    node._on_tick()
    assert len(node.sent) == 53
    assert node._lag_s == pytest.approx((813 - 53) / 400.0)
    stamps = [imu_arrays(m)[0] for m in node.sent]
    assert stamps == [EPOCH_NS + n * 2_500_000 for n in range(53)]


def test_following_the_clock_publishes_every_sample_it_reached_and_none_beyond(make_node):
    from rosgraph_msgs.msg import Clock
    node = make_node(rate_hz=400.0, realtime_factor=1.0, follow_clock=True)
    assert _run(node, 3) == []                       # no /clock yet: simulated time held

    def tick(t_ns):
        msg = Clock()
        msg.clock.sec, msg.clock.nanosec = divmod(EPOCH_NS + t_ns, 1_000_000_000)
        node._on_clock(msg)
        return [imu_arrays(m)[0] - EPOCH_NS for m in node.sent]

    # the camera at t = 0.125 s: samples t = 0 .. 0.125 s (51) at once, none later
    assert tick(125_000_000) == [n * 2_500_000 for n in range(51)]
    assert tick(126_000_000)[-1] == 125_000_000      # between two samples: nothing new
    assert len(tick(900_000_000)) == 361             # a stall of the camera, then a jump
    assert len(tick(500_000_000)) == 361             # an old tick overtaken: nothing
    assert _run(node, 5)[-1] is node.sent[-1] and len(node.sent) == 361   # no wall pacing


def test_diagnostics_report_the_run(make_node):
    node = make_node(rate_hz=400.0, realtime_factor=0.0, seed=9)
    _run(node, 2)
    node._publish_diagnostics()
    (array,) = node.diag_sent
    assert isinstance(array, DiagnosticArray)
    (status,) = array.status
    assert status.level == DiagnosticStatus.OK
    values = {kv.key: kv.value for kv in status.values}
    assert values['samples_published'] == '80'
    assert values['seed'] == '9'
    assert float(values['sim_time_s']) == pytest.approx(0.2)
    assert len(values['gyro_bias_dps'].split()) == 3
    assert array.header.stamp == node.sent[-1].header.stamp


def test_non_finite_truth_is_skipped_with_a_warning(make_node):
    node = make_node(rate_hz=100.0, realtime_factor=0.0)
    inner = node._sampler.trajectory

    class Broken:
        def sample(self, t):
            s = inner.sample(t)
            s.specific_force_body_mps2[np.round(np.asarray(t) * 100) == 3] = np.nan
            return s

    node._sampler.trajectory = Broken()
    sent = _run(node, 1)
    assert len(sent) == 9
    assert 3 not in [(imu_arrays(m)[0] - EPOCH_NS) // 10_000_000 for m in sent]
    assert node._skipped == 1


@pytest.mark.parametrize('params, error, text', [
    ({'rate_hz': 0.0}, ParameterException, 'rate_hz'),
    ({'rate_hz': 3000.0}, ParameterException, 'rate_hz'),
    ({'vehicle_path': '/nonexistent/vehicle.yaml'}, ValueError, 'vehicle.yaml'),
    ({'gyro_bias_corr_times_s': [10.0, -1.0]}, ValueError, 'gyro_bias_corr_times_s'),
    ({'motion_profile': 'teleport'}, ValueError, 'motion profile'),
])
def test_invalid_parameters_raise_in_process(make_node, params, error, text):
    with pytest.raises(error, match=text):
        make_node(**params)


# --- sensor faults (rig parameters, core/sensor_faults.py) -------------------------------

def _clock_tick(node, t_ns):
    from rosgraph_msgs.msg import Clock
    msg = Clock()
    msg.clock.sec, msg.clock.nanosec = divmod(EPOCH_NS + t_ns, 1_000_000_000)
    node._on_clock(msg)
    return [imu_arrays(m)[0] - EPOCH_NS for m in node.sent]


def test_faults_off_publish_exactly_as_before(make_node):
    plain = _run(make_node(rate_hz=400.0, realtime_factor=0.0, seed=5), 3)
    explicit = _run(make_node(rate_hz=400.0, realtime_factor=0.0, seed=5, imu_burst_s=0.0,
                              imu_stamp_offset_s=0.0), 3)
    assert [imu_arrays(m) for m in plain] == [imu_arrays(m) for m in explicit]
    node = make_node(rate_hz=400.0, realtime_factor=0.0)
    assert node._imu_pub.qos_profile.depth == qos_profile_sensor_data.depth
    node._publish_diagnostics()
    keys = {kv.key for kv in node.diag_sent[0].status[0].values}
    assert 'samples_dropped' not in keys and 'samples_held' not in keys


def test_dropout_windows_lose_samples_and_keep_the_others_unchanged(make_node):
    reference = _run(make_node(rate_hz=400.0, realtime_factor=0.0, seed=5), 5)
    node = make_node(rate_hz=400.0, realtime_factor=0.0, seed=5,
                     imu_dropouts_s=[0.1, 0.05, 0.3, 0.0125, 0.31, 0.01])
    sent = _run(node, 5)
    lost = [n for n in range(200) if 40 <= n < 60 or 120 <= n < 128]   # overlapping 2nd/3rd
    assert [imu_arrays(m)[0] for m in sent] == \
        [EPOCH_NS + n * 2_500_000 for n in range(200) if n not in lost]
    kept = [imu_arrays(m) for i, m in enumerate(reference) if i not in lost]
    assert [imu_arrays(m) for m in sent] == kept          # content as without the fault
    node._publish_diagnostics()
    values = {kv.key: kv.value for kv in node.diag_sent[0].status[0].values}
    assert values['samples_dropped'] == str(len(lost)) and values['samples_published'] == '172'


def test_bursts_follow_the_clock_to_the_boundaries(make_node):
    node = make_node(rate_hz=400.0, follow_clock=True, imu_burst_s=0.1)
    assert node._imu_pub.qos_profile.depth >= 40            # a burst fits the history
    assert _clock_tick(node, 0) == []                       # sample 0 waits for 0.1 s
    assert _clock_tick(node, 99_000_000) == []
    # the tick at the boundary: samples [0, 0.1 s), back to back, own stamps
    assert _clock_tick(node, 100_000_000) == [n * 2_500_000 for n in range(40)]
    assert len(_clock_tick(node, 150_000_000)) == 40        # t = 0.1 s is held
    assert len(_clock_tick(node, 205_000_000)) == 80        # first tick after 0.2 s
    assert len(_clock_tick(node, 420_000_000)) == 160       # two bursts after a stall
    node._publish_diagnostics()
    values = {kv.key: kv.value for kv in node.diag_sent[0].status[0].values}
    assert values['samples_held'] == '9'                    # t = 0.4 .. 0.42 s


def test_bursts_self_paced_and_the_last_burst_at_duration(make_node):
    node = make_node(rate_hz=400.0, realtime_factor=0.0, imu_burst_s=0.25, duration_s=0.6)
    counts = []
    for _ in range(8):
        node._on_tick()                                     # 0.1 s of samples per tick
        counts.append(len(node.sent))
    # the boundaries 0.25 s and 0.5 s are reached by the samples of ticks 3 and 6, which
    # also ends the run (duration_s): the 40 samples still held leave as a last burst
    assert counts == [0, 0, 100, 100, 100, 240, 240, 240]
    assert [imu_arrays(m)[0] - EPOCH_NS for m in node.sent] == \
        [n * 2_500_000 for n in range(240)]
    assert node.finished.done()


def test_stamp_offset_and_clock_jumps_move_stamps_not_the_release(make_node):
    node = make_node(rate_hz=400.0, follow_clock=True, imu_stamp_offset_s=-0.0101,
                     sensor_clock_jumps_s=[0.05, 0.2, 0.1, -0.5])
    stamps = _clock_tick(node, 125_000_000)
    assert len(stamps) == 51                                 # t = 0 .. 0.125 s released
    expected = [n * 2_500_000 - 10_100_000 + (200_000_000 if n >= 20 else 0)
                - (500_000_000 if n >= 40 else 0) for n in range(51)]
    assert stamps == expected
    # same content as the unshifted run
    ref = make_node(rate_hz=400.0, follow_clock=True)
    _clock_tick(ref, 125_000_000)
    assert [imu_arrays(m)[1:] for m in node.sent] == [imu_arrays(m)[1:] for m in ref.sent]


@pytest.mark.parametrize('params, text', [
    ({'imu_dropouts_s': [1.0]}, 'imu_dropouts_s must hold pairs'),
    ({'camera_dropouts_s': [1.0, 0.0]}, 'duration_s must be > 0'),
    ({'sensor_clock_jumps_s': [-1.0, 0.5]}, 'at_s must be >= 0'),
    ({'imu_burst_s': -1.0}, 'imu_burst_s'),
    ({'imu_dropouts_s': [1, 2]}, 'DOUBLE_ARRAY'),
])
def test_invalid_fault_parameters_raise_in_process(make_node, params, text):
    with pytest.raises((ValueError, ParameterException), match=text):
        make_node(**params)


# --- the installed executable -----------------------------------------------------------

def _wait_exit(proc, timeout_s=30.0):
    deadline = time.monotonic() + timeout_s
    while proc.poll() is None and time.monotonic() < deadline:
        time.sleep(0.1)
    return proc.poll()


@pytest.mark.graph
@pytest.mark.parametrize('params, text', [
    ({'rate_hz': 0.0}, 'rate_hz'),
    ({'rate_hz': 3000.0}, 'rate_hz'),
])
def test_installed_node_rejects_invalid_rate(launch, params, text):
    proc = launch('vlc_stereo_camera', 'adis16488_node', params=params)
    code = _wait_exit(proc)
    out = launch.output(proc)
    assert code not in (None, 0), out
    assert 'invalid configuration' in out and text in out and 'out of range' in out


@pytest.mark.graph
def test_installed_node_exits_0_after_duration(launch):
    proc = launch('vlc_stereo_camera', 'adis16488_node',
                  params={'duration_s': 0.5, 'realtime_factor': 0.0, 'follow_clock': False})
    assert _wait_exit(proc) == 0, launch.output(proc)
    assert 'duration_s reached: 200 samples published' in launch.output(proc)


@pytest.mark.graph
def test_installed_node_publishes_at_the_configured_rate(launch):
    rate = 250.0
    period_ns = 4_000_000
    proc = launch('vlc_stereo_camera', 'adis16488_node',
                  params={'rate_hz': rate, 'imu_frame_id': 'imu_test',
                          'follow_clock': False})
    ctx = rclpy.Context()
    rclpy.init(context=ctx)
    node = rclpy.create_node('imu_listener', context=ctx)
    executor = SingleThreadedExecutor(context=ctx)
    executor.add_node(node)
    imu, diag = [], []
    # Best effort to match qos_profile_sensor_data, with a deep queue so that a slow
    # spin here does not lose samples.
    node.create_subscription(Imu, 'imu/data_raw', imu.append,
                             QoSProfile(depth=2000, reliability=ReliabilityPolicy.BEST_EFFORT))
    node.create_subscription(DiagnosticArray, 'diagnostics', diag.append, 10)
    try:
        deadline = time.monotonic() + 30.0
        while not imu and time.monotonic() < deadline:
            executor.spin_once(timeout_sec=0.1)
        assert imu, launch.output(proc)
        wall_start = time.monotonic()
        while time.monotonic() - wall_start < 2.5 or not diag:
            executor.spin_once(timeout_sec=0.05)
            assert time.monotonic() < deadline, 'no diagnostics'
        wall_s = time.monotonic() - wall_start
    finally:
        executor.shutdown()
        node.destroy_node()
        rclpy.shutdown(context=ctx)
    stamps = np.array([imu_arrays(m)[0] for m in imu], dtype=np.int64)
    steps = np.diff(stamps)
    assert np.all((steps > 0) & (steps % period_ns == 0)), 'stamps off the 1/rate grid'
    assert np.all((stamps - EPOCH_NS) % period_ns == 0)
    span = (stamps[-1] - stamps[0]) // period_ns + 1
    assert len(stamps) >= 0.95 * span                 # (almost) nothing lost
    assert np.count_nonzero(steps == period_ns) >= 0.95 * len(steps)
    # Paced to real time: the simulated span follows the wall clock (loose bound).
    assert 0.5 * wall_s < (stamps[-1] - stamps[0]) * 1e-9 < 1.5 * wall_s + 0.5
    assert {m.header.frame_id for m in imu} == {'imu_test'}
    assert imu[0].orientation_covariance[0] == -1.0
    assert imu[0].angular_velocity_covariance[0] > 0.0
    mean_z = np.mean([m.linear_acceleration.z for m in imu])
    assert abs(mean_z - 9.80665) < 1.0
    assert diag[0].status[0].name.startswith('adis16488_node')
    assert launch.stop(proc) == 0
