"""curvature_node: parameters file, the node in-process fed with messages, the process."""
import math
import os
import pathlib
import signal
import subprocess
import sys
import time

from geometry_msgs.msg import PoseStamped
from nav_msgs.msg import Odometry
import numpy as np
import pytest
from sensor_msgs.msg import Imu
import yaml

from companion_localizers.curvature_node import (
    _CORE_DEFAULTS,
    CORE_PARAMETERS,
    NODE_PARAMETERS,
    CurvatureNode,
)
from vlc_common.core.alignment import Alignment
from vlc_common.core.rotations import quat_to_matrix

CONFIG = pathlib.Path(__file__).resolve().parents[1] / 'config' / 'curvature_node.yaml'
EPOCH = 1704067200.0
DEMO = Alignment.named('curved_demo')


def test_config_file_documents_every_parameter_with_its_default():
    values = yaml.safe_load(CONFIG.read_text())['/**']['ros__parameters']
    expected = {name: default for name, default, _ in NODE_PARAMETERS}
    expected.update({name: _CORE_DEFAULTS[name] for name, _ in CORE_PARAMETERS})
    assert values == expected


@pytest.fixture
def make_node(node_factory):
    def make(**params):
        node = node_factory(CurvatureNode, **params)
        node.poses, node.diags, node.poses_cov = [], [], []
        node._pub_pose.publish = node.poses.append
        node._pub_pose_cov.publish = node.poses_cov.append
        node._pub_diag.publish = node.diags.append
        return node

    return make


def _stamp(msg, t):
    sec = int(math.floor(t))
    msg.header.stamp.sec, msg.header.stamp.nanosec = sec, int(round((t - sec) * 1e9)) % 10 ** 9


def feed(node, alignment, start_m, distance_m, speed_mps, speed_error=0.0, imu_rate_hz=100.0,
         odom_rate_hz=50.0):
    """Feed a constant-speed run: gyro z = κ·v, speed × (1 + error). Returns truth (t, s)."""
    t = np.arange(0.0, distance_m / speed_mps, 1.0 / imu_rate_hz)
    s = start_m + speed_mps * t
    w = alignment.evaluate(s).curvature_1pm * speed_mps
    every = int(round(imu_rate_hz / odom_rate_hz))
    for k in range(len(t)):
        if k % every == 0:
            odom = Odometry()
            _stamp(odom, EPOCH + t[k])
            odom.twist.twist.linear.x = speed_mps * (1.0 + speed_error)
            node._on_odometry(odom)
        imu = Imu()
        _stamp(imu, EPOCH + t[k])
        imu.angular_velocity.z = float(w[k])
        node._on_imu(imu)
    return EPOCH + t, s


def _values(diag):
    status = diag.status[0]
    return status, {kv.key: kv.value for kv in status.values}


def test_node_publishes_the_matched_chainage_on_the_alignment(make_node):
    node = make_node(alignment='curved_demo', match_period_s=2.0)
    t, s = feed(node, DEMO, 150.0, 800.0, 20.0, speed_error=0.05)
    assert node.poses, 'no pose published'
    assert node._matches == pytest.approx(len(t) / 100.0 / 2.0, abs=1)
    for pose in node.poses:
        assert isinstance(pose, PoseStamped) and pose.header.frame_id == 'map'
        stamp = pose.header.stamp.sec + pose.header.stamp.nanosec * 1e-9
        truth_s = np.interp(stamp, t, s)
        p = pose.pose.position
        chainage, lateral = DEMO.project([p.x], [p.y])
        assert chainage[0] == pytest.approx(truth_s, abs=3.0)
        assert lateral[0] == pytest.approx(0.0, abs=1e-6) and p.z == 0.0
        q = pose.pose.orientation
        R = quat_to_matrix([q.x, q.y, q.z, q.w])
        assert math.atan2(R[1, 0], R[0, 0]) == pytest.approx(
            DEMO.evaluate(chainage[0]).heading_rad[0], abs=1e-6)
    node._publish_diagnostics()
    status, values = _values(node.diags[-1])
    assert status.level == b'\x00' and values['status'] == 'ok'
    assert 0.0 < float(values['confidence']) <= 1.0
    assert float(values['ratio']) == pytest.approx(1 / 1.05, abs=0.01)
    assert float(values['match_cpu_ms']) > 0.0


def test_pose_with_covariance_carries_the_chainage_variance_along_the_track(make_node):
    """Every accepted match also leaves as PoseWithCovarianceStamped (train_localizer's
    re-acquisition aid): same pose, variance σ² along the track direction, the lateral
    σ across it, and the error within 3σ.
    """
    node = make_node(alignment='curved_demo', match_period_s=2.0, lateral_sigma_m=0.05)
    t, s = feed(node, DEMO, 150.0, 800.0, 20.0, speed_error=0.05)
    assert node.poses_cov and len(node.poses_cov) == len(node.poses)
    for pose, pwc in zip(node.poses, node.poses_cov):
        assert pwc.header == pose.header and pwc.pose.pose == pose.pose
        p = pwc.pose.pose.position
        chainage = DEMO.project([p.x], [p.y])[0][0]
        heading = DEMO.evaluate(chainage).heading_rad[0]
        tangent = np.array([math.cos(heading), math.sin(heading)])
        normal = np.array([-tangent[1], tangent[0]])
        cov = np.array(pwc.pose.covariance).reshape(6, 6)
        var_along = tangent @ cov[:2, :2] @ tangent
        assert 1.5 ** 2 - 1e-9 <= var_along <= 10.0 ** 2
        assert normal @ cov[:2, :2] @ normal == pytest.approx(0.05 ** 2)
        assert tangent @ cov[:2, :2] @ normal == pytest.approx(0.0, abs=1e-12)
        assert cov[2, 2] == pytest.approx(0.05 ** 2)
        stamp = pwc.header.stamp.sec + pwc.header.stamp.nanosec * 1e-9
        assert abs(chainage - np.interp(stamp, t, s)) <= 3.0 * math.sqrt(var_along)
    node._publish_diagnostics()
    assert float(_values(node.diags[-1])[1]['chainage_sigma_m']) >= 1.5


def test_straight_line_says_it_cannot_localise_and_publishes_nothing(make_node):
    node = make_node(alignment='straight')
    feed(node, Alignment.straight(), 0.0, 900.0, 20.0)
    assert node.poses == [] and node.poses_cov == []
    node._publish_diagnostics()
    status, values = _values(node.diags[-1])
    assert status.level == b'\x01' and 'cannot localise' in status.message
    assert values['status'] == 'no_curvature_on_alignment'
    # The curved line's template, a straight stretch of it: no curvature signal.
    node = make_node(alignment='curved_demo')
    feed(node, Alignment.straight(), 0.0, 900.0, 20.0)
    assert node.poses == []
    node._publish_diagnostics()
    status, values = _values(node.diags[-1])
    assert status.level == b'\x01' and values['status'] == 'no_curvature_signal'
    assert 'cannot localise' in status.message


def test_missing_input_is_an_error_and_bad_input_is_skipped(make_node):
    node = make_node(alignment='curved_demo')
    node._publish_diagnostics()
    status, _ = _values(node.diags[-1])
    assert status.level == b'\x02' and 'imu/data_raw' in status.message
    imu = Imu()
    _stamp(imu, EPOCH + 1.0)
    imu.angular_velocity.z = math.nan
    node._on_imu(imu)
    imu.angular_velocity.z = 0.01
    node._on_imu(imu)
    node._on_imu(imu)                                 # same stamp again
    odom = Odometry()
    _stamp(odom, EPOCH + 1.0)
    odom.twist.twist.linear.x = math.inf
    node._on_odometry(odom)
    assert node.core.imu_rejected == 2 and node.core.speed_rejected == 1
    node._publish_diagnostics()
    _, values = _values(node.diags[-1])
    assert values['imu_rejected'] == '2' and values['speed_rejected'] == '1'


def test_unknown_alignment_is_rejected(make_node):
    with pytest.raises(ValueError, match='unknown alignment'):
        make_node(alignment='moebius')


def _run_module(env, *ros_args):
    return subprocess.Popen([sys.executable, '-m', 'companion_localizers.curvature_node',
                             '--ros-args', *ros_args], env=env, stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT, text=True, start_new_session=True)


def test_process_exits_2_on_invalid_configuration_and_0_on_sigint(ros_env):
    env = dict(ros_env, PYTHONPATH=os.pathsep.join(sys.path))
    bad = _run_module(env, '-p', 'alignment:=moebius')
    out, _ = bad.communicate(timeout=60)
    assert bad.returncode == 2 and 'invalid configuration' in out and 'moebius' in out
    good = _run_module(env, '-p', 'alignment:=curved_demo')
    try:
        deadline = time.monotonic() + 30.0
        lines = []
        while time.monotonic() < deadline:
            line = good.stdout.readline()
            lines.append(line)
            if 'curvature correlation on alignment' in line:
                break
        assert any('curved_demo' in line for line in lines), ''.join(lines)
        time.sleep(0.5)                                   # spinning by now
        os.killpg(good.pid, signal.SIGINT)
        rest, _ = good.communicate(timeout=20)
        assert good.returncode == 0, ''.join(lines) + rest
    finally:
        if good.poll() is None:
            os.killpg(good.pid, signal.SIGKILL)
