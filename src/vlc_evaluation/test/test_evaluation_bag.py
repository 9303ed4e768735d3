"""bag_eval reads a rosbag2 bag written with rosbags and scores it against truth."""
import numpy as np
import pytest

from vlc_bags.bagio import write_bag
from vlc_bags.typesupport import jazzy_typestore
from vlc_evaluation import bag_eval

STORE = jazzy_typestore()
T = STORE.types


def _header(t, frame='map'):
    sec = int(np.floor(t))
    return T['std_msgs/msg/Header'](
        stamp=T['builtin_interfaces/msg/Time'](sec=sec, nanosec=int(round((t - sec) * 1e9))),
        frame_id=frame)


def _pose(t, xyz, yaw=0.0):
    quat = T['geometry_msgs/msg/Quaternion'](x=0.0, y=0.0, z=float(np.sin(yaw / 2)),
                                             w=float(np.cos(yaw / 2)))
    point = T['geometry_msgs/msg/Point'](x=float(xyz[0]), y=float(xyz[1]), z=float(xyz[2]))
    return T['geometry_msgs/msg/PoseStamped'](
        header=_header(t), pose=T['geometry_msgs/msg/Pose'](position=point, orientation=quat))


@pytest.fixture
def run_bag(tmp_path):
    epoch = 1704067200.0
    msgs = []
    for k in range(101):                      # truth at 100 Hz, 5 m/s, yaw oscillating
        t = epoch + k * 0.01
        msgs.append(('/ground_truth/pose', 'geometry_msgs/msg/PoseStamped', int(t * 1e9),
                     _pose(t, [5.0 * k * 0.01, 0, 0], yaw=np.radians(3.0) * np.sin(k / 10))))
    for k in range(1, 50):                    # estimates at 50 Hz, 2 cm ahead
        t = epoch + k * 0.02
        msgs.append(('/train/pose', 'geometry_msgs/msg/PoseStamped', int(t * 1e9),
                     _pose(t, [5.0 * k * 0.02 + 0.02, 0, 0])))
        cov = np.zeros(36)
        cov[0] = cov[7] = cov[14] = 0.01 ** 2  # sigma 1 cm: 3 sigma = 3 cm holds 2 cm
        pwc = T['geometry_msgs/msg/PoseWithCovarianceStamped'](
            header=_header(t), pose=T['geometry_msgs/msg/PoseWithCovariance'](
                pose=_pose(t, [5.0 * k * 0.02 + 0.02, 0, 0]).pose, covariance=cov))
        msgs.append(('/train/pose_with_covariance',
                     'geometry_msgs/msg/PoseWithCovarianceStamped', int(t * 1e9), pwc))
    msgs.sort(key=lambda m: m[2])
    path = tmp_path / 'run'
    write_bag(path, msgs)
    return path


def test_load_and_score(run_bag):
    run = bag_eval.load_run(run_bag)
    assert run.truth_t.size == 101 and run.pose_t.size == 49
    scores = bag_eval.score_run(run, lamp_chainages=[10.0, 20.0])
    assert scores['every_pose']['max_m'] == pytest.approx(0.02, abs=1e-6)
    assert scores['every_pose_along_track']['mean_m'] == pytest.approx(0.02, abs=1e-6)
    assert scores['covariance_3sigma_fraction'] == 1.0
    # distance to the next lamp: truth x = 0.1 m at the first estimate -> 9.9 m
    assert scores['distance_to_lamp_m'][0] == pytest.approx(9.9, abs=1e-6)


def test_distance_to_next_lamp_past_the_last_is_nan():
    d = bag_eval.distance_to_next_lamp(np.array([5.0, 10.0, 25.0]), [10.0, 20.0])
    np.testing.assert_allclose(d[:2], [5.0, 10.0])
    assert np.isnan(d[2])


def _diag(t, name, values):
    kv = [T['diagnostic_msgs/msg/KeyValue'](key=k, value=str(v)) for k, v in values.items()]
    status = T['diagnostic_msgs/msg/DiagnosticStatus'](level=0, name=name, message='',
                                                      hardware_id='', values=kv)
    return T['diagnostic_msgs/msg/DiagnosticArray'](header=_header(t, ''), status=[status])


def test_graph_health_processing_and_heading_series(tmp_path, run_bag):
    epoch = 1704067200.0
    run = bag_eval.load_run(run_bag)
    clean = bag_eval.graph_health(run)
    assert clean['degraded'] is False and clean['camera_lag_max_s'] == 0.0
    # the run_bag's truth yaws by 3 deg * sin(k/10) and it has no imu/data: no heading
    assert bag_eval.heading_series(run)['t_s'] == []
    msgs = [('/diagnostics', 'diagnostic_msgs/msg/DiagnosticArray', int((epoch + t) * 1e9), m)
            for t, m in ((0.1, _diag(epoch + 0.1, 'stereo_camera_node: renderer',
                                     {'lag_behind_realtime_s': '0.250'})),
                         (0.2, _diag(epoch + 0.2, 'stereo_camera_node: renderer',
                                     {'lag_behind_realtime_s': '0.000'})),
                         (0.3, _diag(epoch + 0.3, 'spot_locator_node: spots',
                                     {'unpaired': '0', 'processing_ms_median': '3.5',
                                      'processing_ms_p99': '9.0',
                                      'processing_ms_max': '12.0'})),
                         (0.4, _diag(epoch + 0.4, 'vlc_decoder: lamp identification',
                                     {'decode_ms_median': 'nan', 'decode_ms_max': 'nan'})))]
    write_bag(tmp_path / 'diag', msgs)
    run = bag_eval.load_run(tmp_path / 'diag')
    health = bag_eval.graph_health(run)
    assert health['camera_lag_max_s'] == 0.25 and health['degraded'] is True
    proc = bag_eval.processing_times(run)
    assert proc['spot_locator'] == [3.5, 9.0, 12.0]
    assert proc['vlc_decoder'] == [None] * 3 and proc['train_localizer'] == [None] * 3


def test_heading_errors_before_and_after():
    from vlc_common.core.rotations import matrix_to_quat_xyzw, rpy_to_matrix
    t = np.linspace(0.0, 2.0, 201)
    yaw = np.radians(5.0) * np.sin(2 * np.pi * 0.5 * t)          # the platform's sway
    truth_q = np.array([matrix_to_quat_xyzw(rpy_to_matrix(0, 0, y)) for y in yaw])
    est_q = np.array([matrix_to_quat_xyzw(rpy_to_matrix(0, 0, y + np.radians(0.1)))
                      for y in yaw])
    run = bag_eval.RunData(t, np.zeros((t.size, 3)), truth_q, np.zeros(0), np.zeros((0, 3)),
                           imu_t=t, imu_quat=est_q)
    _, after, before = bag_eval.heading_errors(run)
    np.testing.assert_allclose(after, 0.1, atol=1e-9)
    np.testing.assert_allclose(before, np.degrees(yaw), atol=1e-9)
    series = bag_eval.heading_series(run, rate_hz=10.0)
    assert len(series['t_s']) == 20 and series['t_s'][0] == 0.0
    np.testing.assert_allclose(series['after_deg'], 0.1, atol=1e-4)
    scores = bag_eval.score_run(run, [10.0], settle_s=1.0)
    assert scores['heading_after_deg']['max_abs'] == pytest.approx(0.1, abs=1e-9)
    # after the 1 s settle only the negative half of the sway is left
    assert scores['heading_before_deg']['min'] == pytest.approx(-5.0, abs=0.01)
    assert scores['heading_before_deg']['max'] == pytest.approx(0.0, abs=1e-9)


def test_heading_settling_time():
    from vlc_common.core.rotations import matrix_to_quat_xyzw, rpy_to_matrix
    t = np.linspace(0.0, 4.0, 401)
    truth_q = np.array([matrix_to_quat_xyzw(rpy_to_matrix(0, 0, 0.0))] * t.size)

    def run_with(err_deg):
        est_q = np.array([matrix_to_quat_xyzw(rpy_to_matrix(0, 0, np.radians(e)))
                          for e in err_deg])
        return bag_eval.RunData(t, np.zeros((t.size, 3)), truth_q, np.zeros(0),
                                np.zeros((0, 3)), imu_t=t, imu_quat=est_q)

    # 3° at the cold start, decaying; back above the bound once at 1.5 s
    err = 3.0 * np.exp(-3.0 * t)
    err[(t > 1.495) & (t < 1.505)] = -0.25
    assert bag_eval.heading_settling_s(run_with(err), 0.5) == pytest.approx(1.01, abs=1e-6)
    assert bag_eval.heading_settling_s(run_with(err), 1.6) == 0.0
    err[-1] = 0.3                                   # not within the bound at the end
    assert bag_eval.heading_settling_s(run_with(err), 0.5) is None
    assert bag_eval.heading_settling_s(run_with(err), 5.0) is None   # no sample after it


def test_severity_of_a_degraded_run():
    assert not bag_eval.severely_degraded({'camera_lag_max_s': 0.0, 'compensator_gaps': 1})
    assert bag_eval.severely_degraded({'camera_lag_max_s': 0.3})
    assert bag_eval.severely_degraded({'camera_lag_max_s': 0.0, 'spot_skipped': 6})
    assert bag_eval.severely_degraded({'camera_lag_max_s': 0.0, 'localizer_records_too_old': 9})
