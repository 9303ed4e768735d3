"""The whole graph: all five packages' installed executables, train/pose vs ground truth.

stereo_camera_node and adis16488_node drive one 60 km/h scenario at half real time;
imu_compensator_node, vlc_decoder_node, spot_locator_node and train_localizer_node run
as they would on the train. The test records ``train/pose``,
``train/pose_with_covariance`` and ``ground_truth/pose`` and scores the poses against
the truth interpolated at their stamps: every pose, from the first one of the cold
start on, inside the 3σ bound of its own published covariance; the poses from two lamp
cells after the first pose on (shorter than the dynamic protocol's lead-in, which is
at least 3 s at speed: scenarios.lead_in_m; the cold start
initialises from a lamp up to 9.5 m ahead with the compensator's heading not yet
converged, and the localizer publishes once its 1σ is below 0.5 m) within the issue's
dynamic bounds (max 15 cm, mean 5 cm). Skipped, with the reason, while an executable
or the module behind it is not installed yet.
"""
import importlib.util
import pathlib

import numpy as np
import pytest

rclpy = pytest.importorskip('rclpy')

from geometry_msgs.msg import PoseStamped, PoseWithCovarianceStamped  # noqa: E402

pytestmark = pytest.mark.graph

INSTALL_LIB = pathlib.Path(__file__).resolve().parents[3] / 'install' / 'lib'
NODES = (('vlc_stereo_camera', 'stereo_camera_node'), ('vlc_stereo_camera', 'adis16488_node'),
         ('imu_compensator', 'imu_compensator_node'), ('vlc_decoder', 'vlc_decoder_node'),
         ('spot_locator', 'spot_locator_node'), ('train_localizer', 'train_localizer_node'))
SCENARIO = {'seed': 3, 'motion_profile': 'constant', 'speed_kmh': 60.0,
            'start_chainage_m': 3.0}
DURATION_S = 3.0
SETTLE_M = 20.0          # two lamp cells (scenarios.SETTLE_CELLS)
REALTIME_FACTOR = 0.5


def _missing():
    missing = []
    for package, executable in NODES:
        if not (INSTALL_LIB / package / executable).exists():
            missing.append(f'{package}/{executable} (not installed)')
        elif importlib.util.find_spec(f'{package}.{executable}') is None:
            missing.append(f'{package}.{executable} (module not written yet)')
    return missing


def _stamp_s(header):
    return header.stamp.sec + header.stamp.nanosec * 1e-9


@pytest.mark.skipif(bool(_missing()), reason='graph incomplete: ' + ', '.join(_missing()))
def test_graph_train_pose_matches_ground_truth(launch, ros_env):
    procs = {
        'train_localizer_node': launch('train_localizer', 'train_localizer_node'),
        'imu_compensator_node': launch('imu_compensator', 'imu_compensator_node'),
        'vlc_decoder_node': launch('vlc_decoder', 'vlc_decoder_node'),
        'spot_locator_node': launch('spot_locator', 'spot_locator_node'),
    }
    rig = dict(SCENARIO, duration_s=DURATION_S, realtime_factor=REALTIME_FACTOR)
    # The IMU follows the camera's /clock: both sensors share one time base however late
    # the camera's subscribers come up (two independent starts drifted apart by more than
    # the localizer's 1 s history on a slow CI machine, and every lamp record was dropped).
    procs['adis16488_node'] = launch('vlc_stereo_camera', 'adis16488_node',
                                     dict(rig, duration_s=DURATION_S + 0.5))
    # Both image topics have three subscribers: the decoder, the spot locator and this
    # test's gate, opened only once the IMU listens to /clock and this test sees the
    # camera's ground truth (as the evaluation runner's probe does): a camera that starts
    # at the first two lost its first second to late discovery on a slow machine.
    camera = launch('vlc_stereo_camera', 'stereo_camera_node',
                    dict(rig, clock_tail_s=0.5, wait_for_subscribers=3))
    procs['stereo_camera_node'] = camera

    poses, truth, covs = [], [], []
    with launch.probe('graph_test') as (node, executor):
        node.create_subscription(PoseStamped, 'train/pose', poses.append, 100)
        node.create_subscription(PoseWithCovarianceStamped, 'train/pose_with_covariance',
                                 covs.append, 100)
        node.create_subscription(PoseStamped, 'ground_truth/pose', truth.append, 100)
        launch.spin(executor, 30.0, until=lambda: launch.rig_listened(node))
        launch.open_image_gate(node)
        launch.spin(executor, 60.0 + DURATION_S / REALTIME_FACTOR,
                    until=lambda: camera.poll() is not None)
        launch.spin(executor, 3.0)      # let the pipeline finish the last frames
    logs = '\n'.join(f'--- {name}\n{launch.output(p)[-3000:]}' for name, p in procs.items())
    assert camera.returncode == 0, logs
    for name, proc in procs.items():
        assert proc.poll() is None or proc.returncode == 0, f'{name} died\n{logs}'
    assert len(truth) > 0.8 * DURATION_S * 30, logs
    assert poses, f'no train/pose published\n{logs}'

    t_true = np.array([_stamp_s(m.header) for m in truth])
    order = np.argsort(t_true)
    t_true = t_true[order]
    p_true = np.array([[m.pose.position.x, m.pose.position.y, m.pose.position.z]
                       for m in truth])[order]
    t = np.array([_stamp_s(m.header) for m in poses])
    p = np.array([[m.pose.position.x, m.pose.position.y, m.pose.position.z] for m in poses])
    inside = (t >= t_true[0]) & (t <= t_true[-1])
    assert inside.sum() > 20, logs
    ref = np.stack([np.interp(t[inside], t_true, p_true[:, k]) for k in range(3)], axis=1)
    err = np.linalg.norm(p[inside] - ref, axis=1)
    assert np.all(np.diff(t) > 0), 'train/pose stamps must increase'

    # integrity from the first pose on: the error inside 3 sigma of the published covariance
    t_cov = np.array([_stamp_s(m.header) for m in covs])
    keep = (t_cov >= t_true[0]) & (t_cov <= t_true[-1])
    assert keep.sum() > 20, logs
    mean = np.array([[m.pose.pose.position.x, m.pose.pose.position.y, m.pose.pose.position.z]
                     for m in covs])[keep]
    sigma = np.sqrt(np.array([np.asarray(m.pose.covariance).reshape(6, 6).diagonal()[:3]
                              for m in covs])[keep])
    ref_cov = np.stack([np.interp(t_cov[keep], t_true, p_true[:, k]) for k in range(3)], axis=1)
    outside = np.any(np.abs(mean - ref_cov) > 3.0 * sigma, axis=1)
    assert outside.mean() <= 0.02, (
        f'{outside.sum()} of {outside.size} poses outside 3 sigma; worst error / sigma '
        f'{np.max(np.abs(mean - ref_cov) / sigma):.1f}\n{logs}')

    # accuracy after the settle time
    speed = SCENARIO['speed_kmh'] / 3.6
    settled = t[inside] >= t[inside][0] + SETTLE_M / speed
    assert settled.sum() > 20, logs
    assert err[settled].max() <= 0.15, f'max error {err[settled].max():.3f} m\n{logs}'
    assert err[settled].mean() <= 0.05, f'mean error {err[settled].mean():.3f} m\n{logs}'
