"""train_localizer_node in-process: simulated inputs over DDS, outputs and bad input.

``spots/pairs`` and ``vlc/lamps`` messages are built in the shared record layouts
(vlc_common.core.records) that the spot locator and the decoder publish.
"""
import math
import pathlib
import time

import numpy as np
import pytest
import yaml

rclpy = pytest.importorskip('rclpy')

from diagnostic_msgs.msg import DiagnosticArray  # noqa: E402
from geometry_msgs.msg import PoseStamped, PoseWithCovarianceStamped  # noqa: E402
from nav_msgs.msg import Odometry  # noqa: E402
from rclpy.executors import SingleThreadedExecutor  # noqa: E402
from rclpy.parameter import Parameter  # noqa: E402
from rclpy.qos import qos_profile_sensor_data  # noqa: E402
from sensor_msgs.msg import Imu, PointCloud2, PointField  # noqa: E402

from train_localizer import conversions  # noqa: E402
from train_localizer.train_localizer_node import PARAMETERS, TrainLocalizerNode  # noqa: E402
from vlc_common.stamps import header  # noqa: E402
from vlc_stereo_camera.core.upstream import constant_speed_run, from_stamp_ns  # noqa: E402
from vlc_stereo_camera.upstream_messages import CAMERA_FRAME, imu_msg, lamps_msg, spots_msg  # noqa: E402

pytestmark = pytest.mark.ros

class Harness:
    """Localizer node + a test node, one executor, lock-step publishing."""

    def __init__(self, params=None):
        self.ctx = rclpy.Context()
        rclpy.init(context=self.ctx)
        overrides = [Parameter(k, value=v) for k, v in (params or {}).items()]
        self.node = TrainLocalizerNode(context=self.ctx, parameter_overrides=overrides)
        self.test = rclpy.create_node('localizer_test', context=self.ctx)
        self.executor = SingleThreadedExecutor(context=self.ctx)
        self.executor.add_node(self.node)
        self.executor.add_node(self.test)
        self.pub_imu = self.test.create_publisher(Imu, 'imu/data', qos_profile_sensor_data)
        self.pub_spots = self.test.create_publisher(PointCloud2, 'spots/pairs', 10)
        self.pub_lamps = self.test.create_publisher(PointCloud2, 'vlc/lamps', 10)
        self.got = {'pose': [], 'cov': [], 'odom': [], 'diag': [], 'aid': []}
        for topic, typ, key in (('train/pose', PoseStamped, 'pose'),
                                ('train/pose_with_covariance', PoseWithCovarianceStamped, 'cov'),
                                ('train/odometry', Odometry, 'odom'),
                                ('diagnostics', DiagnosticArray, 'diag'),
                                ('attitude_aiding', PoseWithCovarianceStamped, 'aid')):
            self.test.create_subscription(typ, topic, lambda m, k=key: self.got[k].append(m), 100)
        self.spin_until(lambda: self.pub_imu.get_subscription_count() > 0
                        and self.pub_spots.get_subscription_count() > 0
                        and self.pub_lamps.get_subscription_count() > 0)

    def spin_until(self, condition, timeout_s=5.0):
        end = time.monotonic() + timeout_s
        while not condition() and time.monotonic() < end:
            self.executor.spin_once(timeout_sec=0.01)
        return condition()

    def send_imu(self, msg):
        before = self.node.localizer.newest_ns
        n_rej = self.node.localizer.monitor.counters.imu_rejected
        self.pub_imu.publish(msg)
        assert self.spin_until(lambda: self.node.localizer.newest_ns != before
                               or self.node.localizer.monitor.counters.imu_rejected != n_rej
                               or self.node.localizer.monitor.counters.time_resets)

    def send_frame(self, stamp_ns, observations, with_lamps=True):
        joined = self.node.joiner.stats.joined
        self.pub_spots.publish(spots_msg(stamp_ns, observations))
        if with_lamps:
            self.pub_lamps.publish(lamps_msg(stamp_ns, observations))
            assert self.spin_until(lambda: self.node.joiner.stats.joined > joined)
        else:
            self.spin_until(lambda: False, 0.05)

    def close(self):
        self.executor.shutdown()
        self.node.destroy_node()
        self.test.destroy_node()
        rclpy.shutdown(context=self.ctx)


@pytest.fixture
def harness(ros_env):
    made = []

    def make(params=None):
        h = Harness(params)
        made.append(h)
        return h

    yield make
    for h in made:
        h.close()


def test_node_publishes_pose_covariance_and_odometry_against_truth(harness):
    h = harness()
    traj, events = constant_speed_run(60.0, 1.2, seed=21)
    for _, kind, payload in events:
        if kind == 'imu':
            h.send_imu(imu_msg(payload))
        else:
            h.send_frame(payload[0], payload[1])
    h.spin_until(lambda: False, 0.2)
    poses = h.got['pose']
    assert len(poses) > 20
    assert all(p.header.frame_id == 'map' for p in poses)
    stamps = np.array([conversions.stamp_to_ns(p.header.stamp) for p in poses])
    assert np.all(np.diff(stamps) > 0)
    t = np.array([from_stamp_ns(s) for s in stamps])
    truth = traj.sample(t)
    est = np.array([[p.pose.position.x, p.pose.position.y, p.pose.position.z] for p in poses])
    assert np.max(np.linalg.norm(est - truth.position_m, axis=1)) < 0.06
    q = np.array([[p.pose.orientation.x, p.pose.orientation.y, p.pose.orientation.z,
                   p.pose.orientation.w] for p in poses])
    np.testing.assert_allclose(np.linalg.norm(q, axis=1), 1.0, atol=1e-9)
    assert len(h.got['cov']) == len(poses) == len(h.got['odom'])
    cov = np.array(h.got['cov'][-1].pose.covariance).reshape(6, 6)
    assert np.all(np.linalg.eigvalsh(cov) > 0.0) and cov[0, 0] < 0.05 ** 2
    odom = h.got['odom'][-1]
    assert odom.child_frame_id == 'base_link'
    assert odom.twist.twist.linear.x == pytest.approx(60.0 / 3.6, abs=0.3)
    # attitude_aiding for the compensator: a few per second, the attitude's covariance in
    # the rotation block (positive definite, the heading well seen given the tilt),
    # position unknown
    aids = h.got['aid']
    assert 2 <= len(aids) <= 1.2 / 0.2 + 1
    for aid in aids:
        c = np.array(aid.pose.covariance).reshape(6, 6)
        assert np.all(np.linalg.eigvalsh(c[3:, 3:]) > 0.0) and c[0, 0] >= 1e6
        assert 1.0 / np.linalg.inv(c[3:, 3:])[2, 2] < (0.5 * np.pi / 180.0) ** 2


def test_no_pose_before_a_confirmed_uid_and_waiting_reported(harness):
    h = harness({'diagnostics_period_s': 0.1})
    _, events = constant_speed_run(40.0, 0.5, seed=22)
    for _, kind, payload in events:
        if kind == 'imu':
            h.send_imu(imu_msg(payload))
        else:
            h.send_frame(payload[0], payload[1], with_lamps=False)
    assert h.spin_until(lambda: len(h.got['diag']) >= 2)
    assert not h.got['pose']
    status = h.got['diag'][-1].status[0]
    assert status.level == b'\x01'
    values = {kv.key: kv.value for kv in status.values}
    assert values['integrity_state'] == 'waiting_for_uid'
    assert int(values['frames_without_uids']) > 0


def test_node_survives_bad_input_and_reports_it(harness):
    h = harness({'diagnostics_period_s': 0.1})
    _, events = constant_speed_run(40.0, 0.8, seed=23)
    for _, kind, payload in events:
        if kind == 'imu':
            h.send_imu(imu_msg(payload))
        else:
            h.send_frame(payload[0], payload[1])
    loc = h.node.localizer
    assert loc.initialized
    last = loc.newest_ns
    # NaN IMU sample, out-of-order sample.
    last_imu = [p for _, kind, p in events if kind == 'imu'][-1]
    bad = imu_msg(last_imu)
    bad.header.stamp = conversions.ns_to_stamp(last + 2_500_000)
    bad.linear_acceleration.x = float('nan')
    h.send_imu(bad)
    old = imu_msg(events[0][2])
    old.header.stamp = conversions.ns_to_stamp(last - 10_000_000)
    h.send_imu(old)
    assert loc.monitor.counters.imu_rejected == 2
    # A record for a lamp that is not in the map, and a cloud without the needed fields.
    # A record for a lamp that is not in the map (in the next frame, then the IMU moves on
    # past its rows), and clouds that cannot be read.
    stamp = max(p[0] for _, kind, p in events if kind == 'frame') + 33_333_333
    obs = [o for _, kind, p in events if kind == 'frame' for o in p[1]][-1]
    obs.uid, obs.stamp_ns = 0x7ABC, stamp
    h.send_frame(stamp, [obs])
    for k in range(1, 25):
        msg = imu_msg(last_imu)
        msg.header.stamp = conversions.ns_to_stamp(last + k * 2_500_000)
        h.send_imu(msg)
    assert loc.monitor.counters.unknown_uid == 1
    broken = PointCloud2(header=header(stamp, CAMERA_FRAME), height=1, width=1, point_step=8,
                         fields=[PointField(name='u_left', offset=0, datatype=7, count=1)],
                         data=bytes(8))
    h.pub_spots.publish(broken)
    truncated = spots_msg(stamp, [obs])
    truncated.data = truncated.data[:10]
    h.pub_spots.publish(truncated)
    h.spin_until(lambda: False, 0.2)
    # One sample stamped 1970 and one a year ahead: dropped as outliers, nothing reset.
    for k, stamp in enumerate((0, last + 365 * 86400 * 10 ** 9)):
        lone = imu_msg(last_imu)
        lone.header.stamp = conversions.ns_to_stamp(stamp)
        h.pub_imu.publish(lone)
        h.spin_until(lambda: False, 0.1)
        msg = imu_msg(last_imu)
        msg.header.stamp = conversions.ns_to_stamp(last + (25 + k) * 2_500_000)
        h.send_imu(msg)
    assert loc.initialized and loc.monitor.counters.time_resets == 0
    assert h.node._stamp_guards['imu/data'].stats.outliers == 2
    # The sensor clock goes back by 10 s for good: the node's guard hands the samples on
    # after three, the localizer resets after ten: position lost until a confirmed lamp.
    for k in range(12):
        back = imu_msg(events[0][2])
        back.header.stamp = conversions.ns_to_stamp(last - 10_000_000_000 + k * 2_500_000)
        h.pub_imu.publish(back)
    assert h.spin_until(lambda: loc.monitor.counters.time_resets == 1)
    assert not loc.initialized
    n_diag = len(h.got['diag'])
    assert h.spin_until(lambda: len(h.got['diag']) > n_diag)
    values = {kv.key: kv.value for kv in h.got['diag'][-1].status[0].values}
    assert values['unknown_uid'] == '1' and values['time_resets'] == '1'
    assert values['dropped_stamp_outliers'] == '2' and values['time_base_changes'] == '1'
    assert int(values['clouds_refused']) == 2
    assert values['last_unknown_uid'] == '0x7abc'
    assert values['integrity_state'] == 'lost'


# --- the curvature re-acquisition aid ------------------------------------------------

CONFIG = pathlib.Path(__file__).resolve().parents[1] / 'config' / 'train_localizer_node.yaml'


def test_config_file_documents_every_parameter_with_its_default():
    values = yaml.safe_load(CONFIG.read_text())['/**']['ros__parameters']
    expected = {name: default for name, default, _ in PARAMETERS}
    assert set(values) == set(expected)
    for name in expected:
        assert values[name] == pytest.approx(expected[name]), name


def match_msg(stamp_ns, chainage_m, sigma_m, frame='map'):
    """A curvature match on the straight line (track along map x)."""
    msg = PoseWithCovarianceStamped()
    msg.header.stamp = conversions.ns_to_stamp(stamp_ns)
    msg.header.frame_id = frame
    msg.pose.pose.position.x = float(chainage_m)
    msg.pose.pose.orientation.w = 1.0
    cov = np.diag([sigma_m ** 2, 0.05 ** 2, 0.05 ** 2, 1e6, 1e6, 1e-6])
    msg.pose.covariance = [float(v) for v in cov.ravel()]
    return msg


def test_curvature_match_applied_when_uncertain_and_reported(harness):
    """A prior of 20 m 1σ and no lamp: the first match is unconfirmed, the next (consistent
    with the distance run) is applied and the chainage σ falls to the match's; a NaN
    match and one in another frame are skipped; the diagnostics count them.
    """
    h = harness({'diagnostics_period_s': 0.1, 'use_initial_prior': True,
                 'initial_chainage_m': 45.0, 'initial_chainage_sigma_m': 20.0,
                 'initial_speed_known': True, 'initial_speed_mps': 10.0})
    pub = h.test.create_publisher(PoseWithCovarianceStamped,
                                  'companion/curvature/pose_with_covariance', 10)
    assert h.spin_until(lambda: pub.get_subscription_count() > 0)
    traj, events = constant_speed_run(36.0, 0.4, seed=24)
    imu = [p for _, kind, p in events if kind == 'imu']
    for sample in imu:
        h.send_imu(imu_msg(sample))
    loc, aid = h.node.localizer, h.node.curvature_aid
    assert math.sqrt(loc.current_state().P[0, 0]) > 19.0

    def send(msg, n):
        pub.publish(msg)
        assert h.spin_until(lambda: aid.counters.received >= n)

    t1, t2 = imu[60].stamp_ns, imu[100].stamp_ns
    truth = [float(traj.sample(from_stamp_ns(t)).chainage_m[0]) for t in (t1, t2)]
    send(match_msg(t1, truth[0] + 1.0, 2.0), 1)
    assert aid.last.status == 'unconfirmed'
    send(match_msg(t2, truth[1] + 1.0, 2.0), 2)
    assert aid.last.status == 'applied'
    assert math.sqrt(loc.current_state().P[0, 0]) < 2.5
    send(match_msg(t2 + 1000, math.nan, 2.0), 3)
    assert aid.last.status == 'bad_input'
    pub.publish(match_msg(t2 + 2000, truth[1], 2.0, frame='odom'))
    h.spin_until(lambda: False, 0.2)
    assert aid.counters.received == 3
    n = len(h.got['diag'])
    assert h.spin_until(lambda: len(h.got['diag']) > n)
    values = {kv.key: kv.value for kv in h.got['diag'][-1].status[0].values}
    assert values['curvature_aids_received'] == '3'
    assert values['curvature_aids_applied'] == '1'
    assert values['curvature_aids_rejected'] == '1'          # the unconfirmed one
    assert values['curvature_aid_resets'] == '0'
    assert values['last_curvature_aid'].startswith('bad_input')


def test_curvature_aid_can_be_switched_off(harness):
    h = harness({'use_curvature_aid': False})
    h.spin_until(lambda: False, 0.2)
    assert h.node.count_subscribers('companion/curvature/pose_with_covariance') == 0
    assert not h.node.curvature_aid.config.enabled


def _self_calibration_params(path):
    """A node that learns its calibration, kept in ``path``."""
    return {'use_self_calibration': True, 'self_calibration_path': str(path)}


@pytest.mark.parametrize('text,why', [
    ('vehicle_id: [unclosed', 'does not parse'),
    ('vehicle_id: another_train\ndisparity_offset_px: 0.3\ndisparity_offset_sigma_px: 0.05\n'
     'stereo_scale_error: 0.0\nstereo_scale_sigma: 0.001\ncamera_fx_b_px_m: 124.8\n',
     'another vehicle'),
])
def test_a_bad_self_calibration_file_is_refused_and_left_alone(harness, tmp_path, text, why):
    """Refused with a message naming the file; the node runs on the given calibration,
    its diagnostics say so, and the file is not overwritten at stop.
    """
    path = tmp_path / 'self_calibration.yaml'
    path.write_text(text)
    h = harness(_self_calibration_params(path))
    assert h.node._self_cal_state.startswith('refused') and why in h.node._self_cal_state
    assert str(path) in h.node._self_cal_state
    assert not h.node.localizer.survey.applied
    h.node._publish_diagnostics()
    assert h.spin_until(lambda: h.got['diag'])
    values = {kv.key: kv.value for kv in h.got['diag'][-1].status[0].values}
    assert values['self_calibration'].startswith('learning; refused')
    h.node.save_self_calibration()
    assert path.read_text() == text


def test_a_saved_self_calibration_is_applied_from_the_start_and_written_back(harness,
                                                                             tmp_path):
    path = tmp_path / 'self_calibration.yaml'
    path.write_text('vehicle_id: demo_train\ndisparity_offset_px: 0.3\n'
                    'disparity_offset_sigma_px: 0.05\nstereo_scale_error: 0.001\n'
                    'stereo_scale_sigma: 0.0005\ncamera_fx_b_px_m: 124.8\nruns: 2\n')
    h = harness(_self_calibration_params(path))
    survey = h.node.localizer.survey
    assert h.node._self_cal_state == 'from file (2 run(s))'
    assert survey.applied and list(survey.theta) == [0.3, 0.001]
    assert survey.range_factor(10.0) == pytest.approx(1.001 * 10.0 / 9.7)
    h.node.save_self_calibration()
    saved = yaml.safe_load(path.read_text())
    assert saved['runs'] == 3 and saved['disparity_offset_px'] == 0.3


@pytest.mark.parametrize('text,why', [
    ('vehicle_id: [unclosed', 'does not parse'),
    ('vehicle_id: another_train\ncamera_fx_b_px_m: 124.8\ncell_px: 64\ncells: []\n',
     'another vehicle'),
    ('vehicle_id: demo_train\ncamera_fx_b_px_m: 124.8\ncell_px: 64\ncells: [[1, 2]]\n',
     'cells[0]'),
])
def test_a_bad_disparity_map_file_is_refused_and_left_alone(harness, tmp_path, text, why):
    """Refused with a message naming the file and field; the node learns afresh, its
    diagnostics say so, and the file is not overwritten (not even with what it learnt).
    """
    path = tmp_path / 'disparity_map.yaml'
    path.write_text(text)
    h = harness({'disparity_map_path': str(path)})
    state = h.node.localizer_config.disparity_map_state
    assert state.startswith('refused') and why in state and str(path) in state
    assert not h.node.localizer.disparity_map.kept
    h.node.localizer.disparity_map.add(900.0, 300.0, 0.4, 0.05, 0x1001)
    h.node._publish_diagnostics()
    assert h.spin_until(lambda: h.got['diag'])
    values = {kv.key: kv.value for kv in h.got['diag'][-1].status[0].values}
    assert values['disparity_map'].startswith('refused')
    assert values['disparity_map_residuals_this_run'] == '1'
    h.node.save_kept()
    assert path.read_text() == text


def test_a_kept_disparity_map_is_read_and_this_run_added_to_it(harness, tmp_path):
    path = tmp_path / 'disparity_map.yaml'
    path.write_text('vehicle_id: demo_train\ncamera_fx_b_px_m: 124.8\ncell_px: 64\nruns: 2\n'
                    'cells: [[14, 4, 3, 40, 400.0, 0.0, 1.0e5, 160.0, 0.0, 70.0]]\n')
    h = harness({'disparity_map_path': str(path)})
    dm = h.node.localizer.disparity_map
    assert h.node.localizer_config.disparity_map_state == 'from file (2 run(s), 1 cells)'
    delta, sigma = dm.correction(14 * 64 + 32, 4 * 64 + 10)
    assert delta == pytest.approx(0.4) and sigma >= dm.config.sigma_floor_px
    h.node.save_disparity_map()                       # nothing learnt this run: no write
    assert 'runs: 2' in path.read_text()
    dm.add(14 * 64 + 32, 4 * 64 + 10, 0.5, 0.05, 0x1001)
    h.node.save_kept()
    saved = yaml.safe_load(path.read_text())
    assert saved['runs'] == 3 and saved['cells'][0][:4] == [14, 4, 4, 41]


def _shipped_map():
    from vlc_common.core.lamp_map import LampMap, default_lamp_map_path
    return LampMap.load(default_lamp_map_path())


def _kept_refinement(lamp_map, gross_uid, passes=3):
    """A refinement of the shipped map whose passes put ``gross_uid`` 5 cm further."""
    from train_localizer.core.lamp_refinement import Refinement, TripletMeasurement
    uids = [lamp.uid for lamp in lamp_map.lamps[:12]]
    ref = Refinement()
    for _ in range(passes):
        ms = []
        for a, b, c in zip(uids, uids[1:], uids[2:]):
            e = [0.05 if u == gross_uid else 0.0 for u in (a, b, c)]
            ms.append(TripletMeasurement((a, b, c), 0.5, e[1] - 0.5 * e[0] - 0.5 * e[2], 0.004))
        ref = ref.merged(ms)
    return ref


def test_a_kept_lamp_refinement_is_applied_and_a_bad_one_refused(harness, tmp_path):
    from train_localizer.core.lamp_refinement_file import save_refinement
    survey = _shipped_map()
    gross = survey.lamps[5].uid
    path = tmp_path / 'refinement.yaml'
    save_refinement(path, _kept_refinement(survey, gross), survey)
    h = harness({'lamp_refinement_path': str(path)})
    moved = h.node.lamp_map.by_uid(gross).position_m[0] - survey.by_uid(gross).position_m[0]
    assert moved == pytest.approx(-0.05, abs=0.005)
    assert h.node.lamp_map.by_uid(survey.lamps[20].uid).position_m[0] == \
        survey.lamps[20].position_m[0]
    h.node._publish_diagnostics()
    assert h.spin_until(lambda: h.got['diag'])
    values = {kv.key: kv.value for kv in h.got['diag'][-1].status[0].values}
    assert values['lamp_refinement'].startswith('from file (3 pass(es))')
    assert values['lamps_off_survey'] == f'{gross:#06x}' and values['lamps_moved'] == 'none'
    # the same file against another survey of the line: refused, the survey used, kept
    other = tmp_path / 'other.yaml'
    other.write_text(path.read_text().replace('survey_digest: ', 'survey_digest: 0'))
    text = other.read_text()
    h2 = harness({'lamp_refinement_path': str(other)})
    assert h2.node.lamp_map.by_uid(gross).position_m[0] == survey.by_uid(gross).position_m[0]
    assert h2.node.localizer_config.refinement_kept.state.startswith('refused')
    assert 'another survey' in h2.node.localizer_config.refinement_kept.state
    h2.node.save_kept()
    assert other.read_text() == text


def test_a_run_adds_its_lamp_triplets_to_the_file_at_stop(harness, tmp_path):
    path = tmp_path / 'refinement.yaml'
    # the periodic save an hour away: the run (4.4 s simulated) takes longer than the
    # default 10 s of wall time on a loaded machine, and the file would be written then
    h = harness({'lamp_refinement_path': str(path), 'lamp_refinement_save_s': 3600.0})
    traj, events = constant_speed_run(60.0, 4.4, seed=22, start_chainage_m=5.0)
    for _, kind, payload in events:
        if kind == 'imu':
            h.send_imu(imu_msg(payload))
        else:
            h.send_frame(payload[0], payload[1])
    assert not path.exists()
    h.node.save_kept()
    saved = yaml.safe_load(path.read_text())
    assert saved['passes'] == 1 and len(saved['triplets']) >= 2
    # an exact survey: every middle lamp where its neighbours put it, within 3σ
    for row in saved['triplets']:
        assert abs(row[4]) < max(3.0 * row[5], 0.01)
