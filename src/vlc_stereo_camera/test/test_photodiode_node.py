"""photodiode_node: parameters, the node in-process, and the installed executable."""
import pathlib
import time

from builtin_interfaces.msg import Time
import numpy as np
import pytest
import rclpy
from rclpy.exceptions import ParameterException
from rclpy.executors import SingleThreadedExecutor
from rclpy.parameter import Parameter
from rosgraph_msgs.msg import Clock as ClockMsg
from sensor_msgs.msg import PointCloud2
import yaml

from vlc_common.core.lamp_map import LampMap, resolve_lamp_map_path
from vlc_common.core.vehicle import VehicleMount
from vlc_common.photodiode_channel import CHANNEL_PARAMETERS, photodiode_config
from vlc_common.pointcloud import cloud_to_records
from vlc_stereo_camera.core.photodiode import Photodiode
from vlc_stereo_camera.photodiode_node import NODE_PARAMETERS, PhotodiodeNode

EPOCH_NS = 1704067200 * 10 ** 9
CONFIG = pathlib.Path(__file__).resolve().parents[1] / 'config' / 'photodiode_node.yaml'
SCENARIO = {'motion_profile': 'constant', 'speed_kmh': 60.0, 'start_chainage_m': 3.0, 'seed': 3}


def test_config_file_documents_every_parameter_with_its_default():
    values = yaml.safe_load(CONFIG.read_text())['/**']['ros__parameters']
    assert values == {name: default for name, default, _ in CHANNEL_PARAMETERS + NODE_PARAMETERS}


def test_channel_parameters_build_the_core_config():
    channel = {name: default for name, default, _ in CHANNEL_PARAMETERS}
    cfg = photodiode_config(channel, VehicleMount().photodiode)
    assert cfg.mount_xyz_m == (0.0, 0.8, 2.9) and cfg.fov_half_angle_deg == 80.0
    assert cfg.elevation_deg == -41.4


@pytest.fixture
def make_node(ros_env):
    ctx = rclpy.Context()
    rclpy.init(context=ctx)
    nodes = []

    def make(**params):
        node = PhotodiodeNode(context=ctx, parameter_overrides=[
            Parameter(k, value=v) for k, v in params.items()])
        node.sent = []
        node._pub.publish = node.sent.append
        nodes.append(node)
        return node

    yield make, ctx
    for node in nodes:
        node.destroy_node()
    rclpy.shutdown(context=ctx)


def _stamp_ns(msg):
    return msg.header.stamp.sec * 10 ** 9 + msg.header.stamp.nanosec


def test_self_paced_node_publishes_the_core_samples_on_the_exact_grid(make_node):
    make, ctx = make_node
    node = make(follow_clock=False, realtime_factor=0.0, duration_s=0.3, **SCENARIO)
    executor = SingleThreadedExecutor(context=ctx)
    executor.add_node(node)
    end = time.monotonic() + 10.0
    while not node.finished.done() and time.monotonic() < end:
        executor.spin_once(timeout_sec=0.01)
    executor.shutdown()
    assert node.finished.done() and node.finished.result() == 0
    assert [_stamp_ns(m) for m in node.sent] == [EPOCH_NS + n * 20_000_000 for n in range(15)]
    core = Photodiode(node.config.photodiode,
                      LampMap.load(resolve_lamp_map_path('')),
                      node.config.scenario.trajectory(), seed=3)
    for n, msg in enumerate(node.sent):
        rec = cloud_to_records(msg)
        expected = core.sample(n, 50.0)
        assert msg.header.frame_id == 'photodiode_link'
        assert rec['uid'].tolist() == expected.uid.tolist()
        assert np.array_equal(rec['power_w'], expected.power_w)
        assert np.array_equal(rec['power_sigma_w'], expected.power_sigma_w)
        assert np.allclose(rec['snr_db'], expected.snr_db, rtol=1e-6)
        assert msg.point_step == 24


def test_following_the_clock_publishes_each_window_once_it_has_passed(make_node):
    make, _ = make_node
    node = make(**SCENARIO)                     # follow_clock is the default
    assert node.sent == []

    def tick(t_s):
        ns = EPOCH_NS + int(round(t_s * 1e9))
        node._on_clock(ClockMsg(clock=Time(sec=ns // 10 ** 9, nanosec=ns % 10 ** 9)))

    tick(0.10)                                  # first tick: samples stamped >= 0.10 s
    assert node.sent == []
    tick(0.115)                                 # sample 5 (0.10 s) window ends at 0.11 s
    assert [_stamp_ns(m) for m in node.sent] == [EPOCH_NS + 100_000_000]
    tick(0.20)
    assert [_stamp_ns(m) for m in node.sent][-1] == EPOCH_NS + 180_000_000
    assert len(node.sent) == 5


def test_sensor_clock_jumps_step_the_stamps_not_the_samples(make_node):
    make, _ = make_node
    node = make(sensor_clock_jumps_s=[0.12, 0.25, 0.16, -0.5], **SCENARIO)
    ref = make(**SCENARIO)
    for n in (node, ref):
        n._on_clock(ClockMsg(clock=Time(sec=EPOCH_NS // 10 ** 9, nanosec=0)))
        n._on_clock(ClockMsg(clock=Time(sec=EPOCH_NS // 10 ** 9, nanosec=200_000_000)))
    # samples t = 0 .. 0.18 s; from 0.12 s on +0.25 s, from 0.16 s on -0.25 s in all
    jump = [0] * 6 + [250_000_000] * 2 + [-250_000_000] * 2
    assert [_stamp_ns(m) for m in node.sent] == \
        [EPOCH_NS + n * 20_000_000 + jump[n] for n in range(10)]
    assert [bytes(m.data) for m in node.sent] == [bytes(m.data) for m in ref.sent]


def test_invalid_parameters_stop_the_node(make_node):
    make, _ = make_node
    with pytest.raises(ParameterException):
        make(rate_hz=0.0)
    with pytest.raises(ValueError):
        make(vehicle_path='/nonexistent/vehicle.yaml')


@pytest.mark.graph
def test_installed_node_publishes_rssi_records_and_exits_after_its_duration(launch, ros_env):
    ctx = rclpy.Context()
    rclpy.init(context=ctx)
    node = rclpy.create_node('photodiode_test', context=ctx)
    got = []
    node.create_subscription(PointCloud2, 'photodiode/rssi', got.append, 100)
    executor = SingleThreadedExecutor(context=ctx)
    executor.add_node(node)
    proc = launch('vlc_stereo_camera', 'photodiode_node',
                  dict(SCENARIO, follow_clock=False, realtime_factor=1.0, duration_s=1.0,
                       wait_for_subscribers=1))
    try:
        end = time.monotonic() + 20.0
        while proc.poll() is None and time.monotonic() < end:
            executor.spin_once(timeout_sec=0.05)
        for _ in range(20):
            executor.spin_once(timeout_sec=0.02)
    finally:
        executor.shutdown()
        node.destroy_node()
        rclpy.shutdown(context=ctx)
    assert proc.returncode == 0, launch.output(proc)
    assert len(got) >= 45, launch.output(proc)          # 50 samples in 1 s
    rec = cloud_to_records(got[-1])
    assert set(rec.dtype.names) == {'uid', 'snr_db', 'power_w', 'power_sigma_w'}
    assert rec.size >= 2 and np.all(rec['power_w'] > 0.0)


@pytest.mark.graph
def test_installed_node_refuses_an_invalid_rate(launch):
    proc = launch('vlc_stereo_camera', 'photodiode_node', {'rate_hz': 0.0})
    assert proc.wait(20) == 2
    assert 'invalid configuration' in launch.output(proc)
