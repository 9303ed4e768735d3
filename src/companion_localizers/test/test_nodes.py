"""The three companion nodes in-process: parameters, messages in and out, bad input.

The callbacks are driven directly with messages in the producers' own layouts
(photodiode_node's records, spot_locator's PAIR_DTYPE, vlc_decoder's LAMP_DTYPE,
imu_compensator's Imu) and the publishers are replaced by lists, so the tests are
deterministic; the DDS path is the graph test's.
"""
import math
import pathlib

import numpy as np
import pytest

rclpy = pytest.importorskip('rclpy')
from rclpy.exceptions import ParameterException  # noqa: E402
from rclpy.parameter import Parameter  # noqa: E402
from sensor_msgs.msg import Imu, PointCloud2, PointField  # noqa: E402
import yaml  # noqa: E402

from companion_localizers import frame_node  # noqa: E402
from companion_localizers.dead_reckoning_node import DeadReckoningNode  # noqa: E402
from companion_localizers.ins_beacon_node import InsBeaconNode  # noqa: E402
from companion_localizers.rssi_localizer_node import PARAMETERS, RssiLocalizerNode  # noqa: E402
from vlc_common.core.optical_channel import PhotodiodeConfig  # noqa: E402
from vlc_common.core.records import RSSI_DTYPE  # noqa: E402
from vlc_common.core.rotations import quat_from_rpy  # noqa: E402
from vlc_common.photodiode_channel import CHANNEL_PARAMETERS  # noqa: E402
from vlc_common.pointcloud import records_to_cloud  # noqa: E402
from vlc_common.stamps import header  # noqa: E402
from vlc_stereo_camera.core.photodiode import Photodiode  # noqa: E402
from vlc_stereo_camera.core.trajectory import MotionProfile, Trajectory, Vibration  # noqa: E402
from vlc_stereo_camera.core.upstream import LAMPS, constant_speed_run  # noqa: E402
from vlc_stereo_camera.photodiode_node import sample_records  # noqa: E402
from vlc_stereo_camera.upstream_messages import (  # noqa: E402
    CAMERA_FRAME,
    imu_msg,
    lamps_msg,
    spots_msg,
)

PKG = pathlib.Path(__file__).resolve().parents[1]
EPOCH_NS = 1704067200 * 10 ** 9


def _yaml(path):
    return yaml.safe_load(path.read_text())['/**']['ros__parameters']


@pytest.mark.parametrize('name, table', [
    ('rssi_localizer_node', CHANNEL_PARAMETERS + PARAMETERS),
    ('dead_reckoning_node', frame_node.COMMON_PARAMETERS + DeadReckoningNode.EXTRA_PARAMETERS),
    ('ins_beacon_node', frame_node.COMMON_PARAMETERS + InsBeaconNode.EXTRA_PARAMETERS)])
def test_config_files_document_every_parameter_with_its_default(name, table):
    assert _yaml(PKG / 'config' / f'{name}.yaml') == {k: v for k, v, _ in table}


def test_rssi_channel_keys_equal_the_photodiodes():
    pd = _yaml(PKG.parent / 'vlc_stereo_camera' / 'config' / 'photodiode_node.yaml')
    rssi = _yaml(PKG / 'config' / 'rssi_localizer_node.yaml')
    assert {k: rssi[k] for k, _, _ in CHANNEL_PARAMETERS} == \
        {k: pd[k] for k, _, _ in CHANNEL_PARAMETERS}


@pytest.fixture
def ctx(ros_env):
    context = rclpy.Context()
    rclpy.init(context=context)
    made = []
    yield context, made
    for node in made:
        node.destroy_node()
    rclpy.shutdown(context=context)


def _make(ctx, cls, **params):
    context, made = ctx
    node = cls(context=context,
               parameter_overrides=[Parameter(k, value=v) for k, v in params.items()])
    node.poses, node.diags = [], []
    node.pub_pose.publish = node.poses.append
    node.pub_diag.publish = node.diags.append
    made.append(node)
    return node


def _drive(node, events, edit=None):
    for _, kind, payload in events:
        if kind == 'imu':
            node._on_imu(imu_msg(payload))
        else:
            stamp, observations, truth = payload
            if edit is not None:
                edit(stamp, observations, truth)
            node._on_spots(spots_msg(stamp, observations))
            node._on_lamps(lamps_msg(stamp, observations))


def _errors(node, traj):
    t = np.array([(m.header.stamp.sec * 10 ** 9 + m.header.stamp.nanosec - EPOCH_NS) * 1e-9
                  for m in node.poses])
    p = np.array([[m.pose.position.x, m.pose.position.y, m.pose.position.z] for m in node.poses])
    return np.linalg.norm(p - traj.sample(t).position_m, axis=1), t


@pytest.mark.parametrize('cls', [DeadReckoningNode, InsBeaconNode])
def test_frame_nodes_publish_poses_against_truth_on_the_grid(ctx, cls):
    node = _make(ctx, cls)
    traj, events = constant_speed_run(60.0, 3.0, 2, start_chainage_m=3.0)
    _drive(node, events)
    err, t = _errors(node, traj)
    assert len(node.poses) > 50
    assert err.max() < (1.0 if cls is DeadReckoningNode else 0.15)
    assert np.all(np.diff(t) > 0)
    assert np.allclose(np.round(t * 50.0), t * 50.0, atol=1e-6)       # 50 Hz grid
    assert node.poses[0].header.frame_id == 'map'
    node._publish_diagnostics()
    values = {kv.key: kv.value for kv in node.diags[-1].status[0].values}
    assert int(values['poses_published']) == len(node.poses)
    assert float(values['processing_ms_median']) >= 0.0
    assert node.diags[-1].status[0].name == f'{node.get_name()}: {cls.METHOD}'


def test_ins_node_reports_a_forged_lamp_on_diagnostics(ctx):
    node = _make(ctx, InsBeaconNode)
    traj, events = constant_speed_run(60.0, 3.5, 4, start_chainage_m=3.0)

    def forge(stamp, observations, truth):
        for obs, tr in zip(observations, truth):
            if LAMPS.by_uid(tr['uid']).position_m[0] == 40.0 and obs.uid is not None:
                obs.uid = 0x1007                  # the lamp at 40 m claims lamp 7 (70 m)

    _drive(node, events, forge)
    node._publish_diagnostics()
    status = node.diags[-1].status[0]
    values = {kv.key: kv.value for kv in status.values}
    assert status.level == bytes([1])                     # WARN
    assert '0x1007' in status.message and 'forged or misplaced' in status.message
    assert values['last_flagged_uid'] == '0x1007'
    assert values['last_flag_verdict'] == 'distance_mismatch'
    err, _ = _errors(node, traj)
    assert err.max() < 0.2


def test_frame_node_survives_bad_input(ctx):
    node = _make(ctx, InsBeaconNode)
    traj, events = constant_speed_run(60.0, 1.5, 2, start_chainage_m=3.0)
    _drive(node, events)
    n = len(node.poses)
    broken = PointCloud2(header=header(EPOCH_NS, CAMERA_FRAME), height=1, width=1,
                         point_step=8,
                         fields=[PointField(name='u_left', offset=0, datatype=7, count=1)],
                         data=bytes(8))
    node._on_spots(broken)
    truncated = spots_msg(EPOCH_NS, [o for _, k, p in events if k == 'frame' for o in p[1]][:1])
    truncated.data = truncated.data[:10]
    node._on_spots(truncated)
    last = [p for _, k, p in events if k == 'imu'][-1]
    bad = imu_msg(last)
    bad.linear_acceleration.x = float('nan')
    node._on_imu(bad)                                     # non-finite: refused
    node._on_imu(imu_msg(last))                           # not newer: refused
    assert node.core.counters.imu_rejected == 2
    assert len(node.poses) == n


def _pd_messages(t_end=2.0, seed=3, speed_kmh=60.0):
    traj = Trajectory(MotionProfile('constant', start_chainage_m=12.0, speed_mps=speed_kmh / 3.6),
                      Vibration(seed=seed))
    pd = Photodiode(PhotodiodeConfig(), LAMPS, traj, seed=seed)
    msgs = []
    for n in range(int(t_end * 50)):
        msgs.append(records_to_cloud(sample_records(pd.sample(n, 50.0)),
                                     header(EPOCH_NS + n * 20_000_000, 'photodiode_link')))
    return traj, msgs


def _rssi_imu(traj, t_s):
    truth = traj.sample(t_s)
    msg = Imu(header=header(EPOCH_NS + int(round(t_s * 1e9)), 'base_link'))
    q = quat_from_rpy(*truth.rpy_rad[0])
    msg.orientation.x, msg.orientation.y, msg.orientation.z, msg.orientation.w = map(float, q)
    msg.orientation_covariance = [float(v) for v in np.diag(
        np.square(np.radians([0.05, 0.05, 0.1]))).ravel()]
    return msg


def test_rssi_node_trilaterates_each_sample_against_truth(ctx):
    node = _make(ctx, RssiLocalizerNode)
    traj, msgs = _pd_messages()
    k = 0
    for n, msg in enumerate(msgs):
        while k * 0.0025 <= n * 0.02 + 0.01:               # imu/data up to the sample
            node._on_imu(_rssi_imu(traj, k * 0.0025))
            k += 1
        node._on_rssi(msg)
    err, t = _errors(node, traj)
    assert len(node.poses) > 0.8 * len(msgs)
    assert err.max() < 0.3923 and err.mean() < 0.1336
    assert node._counts['no_attitude'] == 0
    node._publish_diagnostics()
    values = {kv.key: kv.value for kv in node.diags[-1].status[0].values}
    assert int(values['outcome_ok']) == len(node.poses)
    assert float(values['processing_ms_median']) > 0.0


def test_rssi_node_survives_bad_input(ctx):
    node = _make(ctx, RssiLocalizerNode, use_imu_attitude=False)
    traj, msgs = _pd_messages(t_end=0.2)
    rec = np.zeros(3, dtype=RSSI_DTYPE)
    rec['uid'] = [0x7ABC, 4098, 4099]                    # unknown UID, then a NaN power
    rec['power_w'] = [1e-6, math.nan, 1e-6]
    node._on_rssi(records_to_cloud(rec, header(EPOCH_NS + 10 ** 9, CAMERA_FRAME)))
    assert node._counts['unknown_uid'] == 1 and node._counts['bad_records'] == 1
    node._on_rssi(msgs[0])                                # older than the last: skipped
    assert node._counts['out_of_order'] == 1
    missing = PointCloud2(header=header(EPOCH_NS + 2 * 10 ** 9, CAMERA_FRAME), height=1,
                          width=1, point_step=4, data=bytes(4),
                          fields=[PointField(name='uid', offset=0, datatype=6, count=1)])
    node._on_rssi(missing)
    assert node._counts['bad_records'] == 2
    assert node.poses == []


@pytest.mark.parametrize('cls, params', [
    (RssiLocalizerNode, {'solve_mode': 'best'}),
    (RssiLocalizerNode, {'tilt_prior_sigma_deg': [0.3]}),
    (InsBeaconNode, {'attitude_sigma_deg': [0.1, 0.1]}),
    (DeadReckoningNode, {'window_samples': 0})])
def test_invalid_parameters_stop_the_node(ctx, cls, params):
    with pytest.raises((ValueError, ParameterException)):
        _make(ctx, cls, **params)
