"""The whole graph under fire: fault_injector_node publishes every malformed kind beside
the real publishers while the rig drives a 60 km/h run (about 10 s of simulated time at
half real time).

Every node stays alive and exits 0 at SIGINT; the localizer publishes poses throughout
(no gap longer than 0.5 s from its first pose to the end) and none of them is more than
0.5 m off the ground truth while its pose_with_covariance claims a 3σ under 0.5 m; the
receivers warned (throttled) about the bad input; no node reset its timeline; the
injector published every kind.
"""

import numpy as np
import pytest

rclpy = pytest.importorskip('rclpy')

from diagnostic_msgs.msg import DiagnosticArray  # noqa: E402
from geometry_msgs.msg import PoseStamped, PoseWithCovarianceStamped  # noqa: E402

from vlc_evaluation.fault_kinds import ALL_KINDS  # noqa: E402

pytestmark = [pytest.mark.graph, pytest.mark.ros]

SCENARIO = {'seed': 3, 'motion_profile': 'constant', 'speed_kmh': 60.0,
            'start_chainage_m': 3.0}
DURATION_S = 10.0
REALTIME_FACTOR = 0.5
RECEIVERS = (('imu_compensator', 'imu_compensator_node'), ('vlc_decoder', 'vlc_decoder_node'),
             ('spot_locator', 'spot_locator_node'), ('train_localizer', 'train_localizer_node'))
SIM = {'use_sim_time': True}


def _stamp_s(header):
    return header.stamp.sec + header.stamp.nanosec * 1e-9


def _positions(msgs):
    return np.array([[m.pose.position.x, m.pose.position.y, m.pose.position.z] for m in msgs])


def test_the_graph_survives_every_malformed_kind(launch, ros_env):
    procs = {exe: launch(pkg, exe, SIM) for pkg, exe in RECEIVERS}
    rig = dict(SCENARIO, duration_s=DURATION_S, realtime_factor=REALTIME_FACTOR)
    procs['adis16488_node'] = launch('vlc_stereo_camera', 'adis16488_node',
                                     dict(rig, duration_s=DURATION_S + 0.5))
    # 34 kinds in 9 s of simulated time at 5 Hz: every kind at least once. It stops
    # before the camera does: injected images alone (no real ones in between) would be
    # a sustained new time base, which the receivers rightly follow.
    procs['fault_injector_node'] = launch('vlc_evaluation', 'fault_injector_node',
                                          dict(SIM, rate_hz=5.0, start_s=0.5,
                                               duration_s=DURATION_S - 1.0))
    camera = launch('vlc_stereo_camera', 'stereo_camera_node',
                    dict(rig, clock_tail_s=0.5, wait_for_subscribers=3))

    poses, covs, truth, diagnostics = [], [], [], {}

    def on_diagnostics(msg):
        for status in msg.status:
            diagnostics[status.name.split(':')[0]] = {kv.key: kv.value for kv in status.values}

    with launch.probe('fault_test') as (node, executor):
        node.create_subscription(PoseStamped, 'train/pose', poses.append, 100)
        node.create_subscription(PoseWithCovarianceStamped, 'train/pose_with_covariance',
                                 covs.append, 100)
        node.create_subscription(PoseStamped, 'ground_truth/pose', truth.append, 100)
        node.create_subscription(DiagnosticArray, 'diagnostics', on_diagnostics, 50)
        # the image gate (this test's third image subscriber) opens once the IMU and the
        # injector listen to /clock and the camera's truth is seen (test_graph_localizer)
        launch.spin(executor, 30.0, until=lambda: launch.rig_listened(node, 2))
        launch.open_image_gate(node)
        launch.spin(executor, 40.0 + DURATION_S / REALTIME_FACTOR,
                    until=lambda: camera.poll() is not None)
        launch.spin(executor, 2.0)

    alive = {name: p.poll() is None for name, p in procs.items()}
    codes = {name: launch.stop(p) for name, p in procs.items()}
    logs = {name: launch.output(p) for name, p in procs.items()}
    tails = '\n'.join(f'--- {name}\n{text[-2500:]}' for name, text in logs.items())
    assert camera.returncode == 0, tails
    assert all(alive[exe] for _, exe in RECEIVERS + (('', 'fault_injector_node'),)), (
        alive, tails)
    assert codes == dict.fromkeys(procs, 0), (codes, tails)
    for name, text in logs.items():
        assert 'Traceback' not in text, f'{name}\n{text[-4000:]}'

    # no node reset its timeline (a lone stray stamp is dropped, not followed)
    resets = {'train_localizer': 'time_resets', 'vlc_decoder': 'resets_stamp_jump',
              'spot_locator_node': 'stamp_resets', 'imu_compensator_node': 'resets'}
    for name, key in resets.items():
        assert diagnostics[name][key] == '0', (name, diagnostics[name])
    # the injector published every kind
    injected = diagnostics['fault_injector_node']
    missing = [k for k in ALL_KINDS if int(injected.get(f'kind/{k}', 0)) < 1]
    assert not missing, (missing, injected, logs['fault_injector_node'][-2000:])
    assert injected['state'] == 'done'
    for kind in ALL_KINDS:                     # one line per kind at start
        assert f'kind {kind}: ' in logs['fault_injector_node']
    # the receivers said so, throttled (at most one line per kind every warn_throttle_s)
    for _, exe in RECEIVERS:
        warnings = logs[exe].count('[WARN]')
        assert 0 < warnings < 150, (exe, warnings, logs[exe][-3000:])

    # poses throughout, accurate where they claim to be
    assert len(truth) > 0.8 * DURATION_S * 30, tails
    t_true = np.array([_stamp_s(m.header) for m in truth])
    order = np.argsort(t_true)
    t_true, p_true = t_true[order], _positions(truth)[order]
    t = np.array([_stamp_s(m.header) for m in poses])
    assert t.size > 100 and np.all(np.diff(t) > 0), tails
    assert t[0] - t_true[0] < 3.0 and t_true[-1] - t[-1] < 0.5, (t[0], t[-1], t_true[[0, -1]])
    assert np.max(np.diff(t)) < 0.5, f'no pose for {np.max(np.diff(t)):.2f} s'
    t_cov = np.array([_stamp_s(m.header) for m in covs])
    keep = (t_cov >= t_true[0]) & (t_cov <= t_true[-1])
    mean = np.array([[m.pose.pose.position.x, m.pose.pose.position.y, m.pose.pose.position.z]
                     for m in covs])[keep]
    ref = np.stack([np.interp(t_cov[keep], t_true, p_true[:, k]) for k in range(3)], axis=1)
    err = np.linalg.norm(mean - ref, axis=1)
    sigma = np.sqrt(np.array([np.asarray(m.pose.covariance).reshape(6, 6).diagonal()[:3].sum()
                              for m in covs]))[keep]
    claimed = 3.0 * sigma < 0.5
    assert claimed.sum() > 100, tails
    assert np.max(err[claimed]) <= 0.5, f'max error {np.max(err[claimed]):.3f} m'
