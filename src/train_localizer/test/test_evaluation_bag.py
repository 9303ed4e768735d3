"""bag_eval reads a rosbag2 bag written with rosbags and scores it against truth."""
import numpy as np
import pytest

from train_localizer.bagtools.bagio import write_bag
from train_localizer.bagtools.typesupport import jazzy_typestore
from train_localizer.evaluation import bag_eval

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
