"""The rig on a curved alignment: trajectory kinematics, IMU signals, rendering, nodes.

References: numerical derivatives of the trajectory, the original straight-track
formulas (re-implemented here), the pinhole projection of the foundation's StereoRig
and a projected rim polygon (independent of the renderer's conic coverage code).
"""
import copy
import pathlib

import cv2
import numpy as np
import pytest
import rclpy
from rclpy.parameter import Parameter
import yaml

from vlc_common.core.alignment import NAMED_ALIGNMENTS, Alignment
from vlc_common.core.camera import StereoRig
from vlc_common.core.lamp_map import LampMap, alignment_lamp_map
from vlc_common.core.rotations import rpy_to_matrix
from vlc_stereo_camera.adis16488_node import Adis16488Node
from vlc_stereo_camera.core.imu_model import Adis16488Model, ImuSampler, true_imu_signals
from vlc_stereo_camera.core.renderer import RendererConfig, StereoRenderer
from vlc_stereo_camera.core.sensor_noise import SensorConfig
from vlc_stereo_camera.core.trajectory import (
    GRAVITY_MPS2,
    MotionProfile,
    Trajectory,
    Vibration,
    VibrationConfig,
)
from vlc_stereo_camera.imu_conversions import imu_arrays
from vlc_stereo_camera.rig_params import SCENARIO_PARAMETERS, ScenarioConfig

CONFIG = pathlib.Path(__file__).resolve().parents[1] / 'config'
MAPS = pathlib.Path(__file__).resolve().parents[2] / 'vlc_common' / 'config'


@pytest.fixture(scope='module')
def demo():
    return Alignment.named('curved_demo')


@pytest.fixture(scope='module')
def level_demo():
    """curved_demo's horizontal geometry without its cant and vertical profile."""
    return Alignment(NAMED_ALIGNMENTS['curved_demo'], name='curved_demo')


@pytest.fixture(scope='module')
def curved_map():
    return LampMap.load(MAPS / 'lamp_map_curved_demo.yaml')


def _legacy_straight_sample(traj, t):
    """The original straight-track trajectory formulas, verbatim in substance."""
    s, v, a = traj.profile.evaluate(t)
    q, qd, qdd = traj.vibration.evaluate(t, s, v, a)
    position = np.stack([s + q[:, 0], q[:, 1], q[:, 2]], axis=1)
    velocity = np.stack([v + qd[:, 0], qd[:, 1], qd[:, 2]], axis=1)
    accel = np.stack([a + qdd[:, 0], qdd[:, 1], qdd[:, 2]], axis=1)
    roll, pitch, yaw = q[:, 3], q[:, 4], q[:, 5]
    droll, dpitch, dyaw = qd[:, 3], qd[:, 4], qd[:, 5]
    R = rpy_to_matrix(roll, pitch, yaw)
    omega = np.stack([
        droll - dyaw * np.sin(pitch),
        dpitch * np.cos(roll) + dyaw * np.sin(roll) * np.cos(pitch),
        -dpitch * np.sin(roll) + dyaw * np.cos(roll) * np.cos(pitch)], axis=1)
    f = np.einsum('nji,nj->ni', R, accel - np.array([0.0, 0.0, -GRAVITY_MPS2]))
    return position, velocity, accel, q[:, 3:6], R, omega, f


@pytest.mark.parametrize('kind', ['stationary', 'constant', 'accel_cruise_brake'])
def test_default_alignment_reproduces_the_straight_track_to_the_bit(kind):
    traj = Trajectory(MotionProfile(kind, start_chainage_m=-15.0, speed_mps=27.0),
                      Vibration(seed=5))
    t = np.linspace(-1.0, 50.0, 2001)
    got = traj.sample(t)
    want = _legacy_straight_sample(traj, t)
    for name, value in zip(('position_m', 'velocity_mps', 'acceleration_mps2', 'rpy_rad',
                            'R_map_base', 'angular_velocity_body_rps',
                            'specific_force_body_mps2'), want):
        np.testing.assert_array_equal(getattr(got, name), value, err_msg=name)


def _curved_trajectory(demo, kind='constant', start=150.0, speed=25.0, scale=1.0, seed=2):
    return Trajectory(MotionProfile(kind, start_chainage_m=start, speed_mps=speed, dwell_s=2.0,
                                    cruise_s=60.0),
                      Vibration(VibrationConfig(scale=scale, enabled=scale > 0), seed=seed),
                      demo)


@pytest.mark.parametrize('kind', ['constant', 'accel_cruise_brake'])
def test_curved_trajectory_derivatives_are_consistent(demo, kind):
    """Velocity, acceleration and body rate = numerical derivatives of pose (clothoids,
    arcs, speed changes and the vibration all at once).
    """
    traj = _curved_trajectory(demo, kind)
    # Instants away from the motion-segment and element joints (jerk steps there).
    t = np.array([1.0, 4.3, 7.9, 11.1, 14.6, 19.2, 26.7, 33.3, 41.9, 52.4, 66.6])
    h = 1e-4
    lo, mid, hi = traj.sample(t - h), traj.sample(t), traj.sample(t + h)
    np.testing.assert_allclose((hi.position_m - lo.position_m) / (2 * h), mid.velocity_mps,
                               atol=2e-6)
    np.testing.assert_allclose((hi.velocity_mps - lo.velocity_mps) / (2 * h),
                               mid.acceleration_mps2, atol=2e-5)
    W = np.einsum('nji,njk->nik', mid.R_map_base, (hi.R_map_base - lo.R_map_base) / (2 * h))
    omega = np.stack([W[:, 2, 1], W[:, 0, 2], W[:, 1, 0]], axis=1)
    np.testing.assert_allclose(omega, mid.angular_velocity_body_rps, atol=1e-7)
    assert np.ptp(mid.track_heading_rad) > 0.3          # really went round curves
    assert np.ptp(mid.track_cant_rad) > 0.05 and np.ptp(mid.track_grade) > 0.02   # canted, graded


def test_pose_is_the_alignment_plus_track_frame_vibration(level_demo):
    demo = level_demo
    traj = _curved_trajectory(demo, scale=2.0)
    t = np.linspace(0.0, 80.0, 400)
    got = traj.sample(t)
    s, v, a = traj.profile.evaluate(t)
    q, _, _ = traj.vibration.evaluate(t, s, v, a)
    base = demo.to_map(s)
    p = demo.evaluate(s)
    expected = base + q[:, 0:1] * np.column_stack([p.tangent, np.zeros_like(s)]) \
        + q[:, 1:2] * np.column_stack([p.left_normal, np.zeros_like(s)])
    expected[:, 2] = q[:, 2]
    np.testing.assert_allclose(got.position_m, expected, atol=1e-12)
    np.testing.assert_allclose(got.rpy_rad[:, 2], p.heading_rad + q[:, 5], atol=1e-15)
    # Projected back: chainage = s + along-track vibration, lateral = vibration (mm), up
    # to the curve's sagitta over the along-track displacement, κ·x_v²/2 < 1e-7 m.
    chainage, lateral = demo.project(got.position_m[:, 0], got.position_m[:, 1])
    np.testing.assert_allclose(chainage, s + q[:, 0], atol=1e-9)
    np.testing.assert_allclose(lateral, q[:, 1], atol=1e-7)


def test_yaw_rate_and_centripetal_force_in_the_curve(level_demo):
    """No vibration: gyro z = κ·v, accelerometer y = κ·v² (no cant), z = g."""
    demo = level_demo
    v = 25.0
    traj = _curved_trajectory(demo, speed=v, scale=0.0, start=300.0)
    t = np.linspace(0.0, 6.0, 61)              # s = 300 … 450: inside the R = 400 m arc
    sample = traj.sample(t)
    assert np.all(sample.track_curvature_1pm == pytest.approx(1 / 400))
    np.testing.assert_allclose(sample.angular_velocity_body_rps,
                               np.tile([0.0, 0.0, v / 400], (61, 1)), atol=1e-15)
    np.testing.assert_allclose(sample.specific_force_body_mps2,
                               np.tile([0.0, v * v / 400, GRAVITY_MPS2], (61, 1)), atol=1e-12)
    # Right-hand R = 600 m arc: negative yaw rate, force toward −y.
    right = traj.sample([(1070.0 - 300.0) / v])
    assert right.angular_velocity_body_rps[0, 2] == pytest.approx(-v / 600)
    assert right.specific_force_body_mps2[0, 1] == pytest.approx(-v * v / 600)
    # In a clothoid the yaw rate ramps linearly with chainage.
    ramp = traj.sample((np.array([210.0, 240.0, 270.0]) - 300.0) / v)
    np.testing.assert_allclose(ramp.angular_velocity_body_rps[:, 2],
                               v * np.array([10, 40, 70]) / 80 / 400, rtol=1e-12)


# --- cant and grade --------------------------------------------------------------------

def test_level_alignment_takes_the_3d_path_to_rounding(level_demo):
    """The grade-and-cant kinematics, run on a level alignment, are the level formulas
    (to rounding): the two code paths describe one model.
    """
    from vlc_stereo_camera.core import trajectory as module

    traj = _curved_trajectory(level_demo, 'accel_cruise_brake', scale=2.0)
    t = np.linspace(0.0, 80.0, 500)
    got = traj.sample(t)
    s, v, a = traj.profile.evaluate(t)
    q, qd, qdd = traj.vibration.evaluate(t, s, v, a)
    s, v, a = (np.broadcast_to(x, t.shape).astype(float) for x in (s, v, a))
    other = module._sample_3d(t, s, v, a, q, qd, qdd, level_demo.evaluate(s))
    for name, atol in (('position_m', 1e-12), ('velocity_mps', 1e-13),
                       ('acceleration_mps2', 1e-13), ('rpy_rad', 1e-14), ('R_map_base', 1e-14),
                       ('angular_velocity_body_rps', 1e-14),
                       ('specific_force_body_mps2', 1e-13)):
        np.testing.assert_allclose(getattr(other, name), getattr(got, name), atol=atol,
                                   err_msg=name)


@pytest.mark.parametrize('chainage_m', [100.0, 250.0, 240.0, 380.0, 1000.0, 1063.0, 1882.0])
def test_standing_pose_is_the_track_frame(demo, chainage_m):
    """Standing, no vibration: base_link at the alignment's elevation, attitude =
    Rz(ψ)·Ry(−atan G)·Rx(φ), no rotation, and the accelerometer sees gravity alone —
    tilted by the cant (f_y = g·sin φ) and the grade (f_x = g·sin(atan G)).
    """
    traj = Trajectory(MotionProfile('stationary', start_chainage_m=chainage_m),
                      Vibration(VibrationConfig(enabled=False)), demo)
    got = traj.sample([0.0, 1.0])
    p = demo.evaluate(chainage_m)
    np.testing.assert_allclose(got.position_m,
                               np.tile([p.x_m[0], p.y_m[0], p.elevation_m[0]], (2, 1)),
                               atol=1e-12)
    R = rpy_to_matrix(p.cant_rad[0], -np.arctan(p.grade[0]), p.heading_rad[0])
    np.testing.assert_allclose(got.R_map_base, np.stack([R, R]), atol=1e-15)
    np.testing.assert_allclose(got.rpy_rad[0], [p.cant_rad[0], -np.arctan(p.grade[0]),
                                                 p.heading_rad[0]], atol=1e-15)
    np.testing.assert_array_equal(got.angular_velocity_body_rps, 0.0)
    np.testing.assert_allclose(got.specific_force_body_mps2[0], R.T @ [0, 0, GRAVITY_MPS2],
                               atol=1e-12)
    np.testing.assert_allclose(got.track_cant_rad, p.cant_rad[0])
    np.testing.assert_allclose(got.track_elevation_m, p.elevation_m[0])


def test_canted_pose_is_the_track_frame_plus_vibration(demo):
    """Position P(s) + R_T·w and attitude R_T·R_v on curved_demo (cant and grade)."""
    traj = _curved_trajectory(demo, scale=2.0)
    t = np.linspace(0.0, 80.0, 400)
    got = traj.sample(t)
    s, v, a = traj.profile.evaluate(t)
    q, _, _ = traj.vibration.evaluate(t, s, v, a)
    p = demo.evaluate(s)
    R_T = rpy_to_matrix(p.cant_rad, -np.arctan(p.grade), p.heading_rad)
    centre = np.column_stack([p.x_m, p.y_m, p.elevation_m])
    np.testing.assert_allclose(got.position_m, centre + np.einsum('nij,nj->ni', R_T, q[:, :3]),
                               atol=1e-12)
    np.testing.assert_allclose(got.R_map_base, R_T @ rpy_to_matrix(q[:, 3], q[:, 4], q[:, 5]),
                               atol=1e-14)
    assert np.ptp(p.elevation_m) > 15.0 and np.ptp(p.cant_rad) > 0.1     # really 3-D


@pytest.mark.parametrize('speed_mps', [25.0, None])
def test_cant_and_grade_in_the_arc(demo, speed_mps):
    """R = 400 m left arc (120 mm cant, −28 ‰): gyro = R_Tᵀ·(0, 0, v/R); specific force
    lateral κ·v²·cos φ + g·cos θ·sin φ, along the track −g·sin θ (the brakes' pull on the
    down grade). At the equilibrium speed v² = g·R·cos θ·tan|φ| the cant cancels the
    lateral force.
    """
    cant_rad = -np.arcsin(0.12 / 1.5)
    theta = np.arctan(0.028)
    if speed_mps is None:
        speed_mps = np.sqrt(GRAVITY_MPS2 * 400.0 * np.cos(theta) * np.tan(-cant_rad))
    traj = _curved_trajectory(demo, speed=speed_mps, scale=0.0, start=330.0)
    sample = traj.sample(np.linspace(0.0, 5.0, 51))          # s = 330 … 455: arc, constant grade
    np.testing.assert_allclose(sample.track_cant_rad, cant_rad, rtol=1e-12)
    np.testing.assert_allclose(sample.track_grade, -0.028, rtol=1e-12)
    gyro, force = _canted_arc_imu(speed_mps, 400.0, cant_rad, -0.028)
    np.testing.assert_allclose(sample.angular_velocity_body_rps, np.tile(gyro, (51, 1)),
                               atol=1e-14)
    np.testing.assert_allclose(sample.specific_force_body_mps2, np.tile(force, (51, 1)),
                               atol=1e-12)
    lateral = speed_mps ** 2 / 400.0 * np.cos(cant_rad) \
        + GRAVITY_MPS2 * np.cos(theta) * np.sin(cant_rad)
    assert force[1] == pytest.approx(lateral, abs=1e-12)
    assert force[0] == pytest.approx(-GRAVITY_MPS2 * np.sin(theta), abs=1e-12)
    if speed_mps < 20.0:
        assert speed_mps * 3.6 == pytest.approx(63.9, abs=0.1)
        assert abs(force[1]) < 1e-12


def test_cant_ramp_rolls_the_platform_in_the_transition(demo):
    """Entering the R = 400 m curve (clothoid 200–280 m, cant 0 → 120 mm, in the vertical
    curve 187.5–312.5 m): the roll rate is φ̇ − ψ̇·sin θ with φ = −asin(D/b), D ramped
    linearly, ψ̇ = κ·v, κ ramped linearly; the roll reaches the cant angle.
    """
    v = 20.0
    traj = _curved_trajectory(demo, speed=v, scale=0.0, start=190.0)
    t = np.linspace(0.0, 5.0, 5001)                          # s = 190 … 290
    sample = traj.sample(t)
    s = sample.chainage_m
    inside = (s > 201.0) & (s < 279.0)
    d = 0.12 * (s - 200.0) / 80.0 / 1.5                      # D/b on the ramp
    phi_dot = -0.12 / 80.0 / 1.5 / np.sqrt(1.0 - d * d) * v
    psi_dot = (s - 200.0) / 80.0 / 400.0 * v
    theta = -np.arctan(sample.track_grade)
    expected = phi_dot - psi_dot * np.sin(theta)
    np.testing.assert_allclose(sample.angular_velocity_body_rps[inside, 0], expected[inside],
                               rtol=1e-10)
    assert np.ptp(sample.track_grade[inside]) > 0.01          # through the vertical curve
    np.testing.assert_allclose(sample.rpy_rad[-1, 0], -np.arcsin(0.08), atol=1e-12)
    np.testing.assert_allclose(sample.rpy_rad[0, 0], 0.0, atol=1e-15)


def test_imu_model_sees_the_track_yaw_rate(level_demo):
    """The ADIS16488 sampler takes the kinematics from the trajectory: in the arc the
    mean measured gyro z is κ·v (plus the sensor's bias and scale error).
    """
    demo = level_demo
    traj = _curved_trajectory(demo, speed=20.0, start=300.0, scale=0.0)
    model = Adis16488Model(200.0, 3)
    batch = ImuSampler(traj, model).next(1600)     # 8 s, s = 300 … 460 (arc)
    truth_omega, truth_f = true_imu_signals(traj, batch.t_s)
    np.testing.assert_array_equal(batch.omega_true, truth_omega)
    np.testing.assert_allclose(truth_omega[:, 2], 20.0 / 400, rtol=1e-12)
    # Measured = scale factor × truth + turn-on bias (+ white noise and in-run bias,
    # ~3e-5 rad/s over 8 s).
    expected = model.gyro_matrix[2, 2] * 20.0 / 400 + model.gyro_turn_on_bias_rad_s[2]
    assert batch.omega[:, 2].mean() == pytest.approx(expected, abs=2e-4)
    assert batch.f[:, 1].mean() == pytest.approx(
        model.accel_matrix[1, 1] * 20.0 ** 2 / 400 + model.accel_matrix[1, 2] * GRAVITY_MPS2
        + model.accel_turn_on_bias_mps2[1], abs=2e-3)
    # Lever arm: ω × (ω × r) of the track rate shows up too.
    _, f_arm = true_imu_signals(traj, np.array([2.0]), lever_arm_m=(0.0, 1.0, 0.0))
    assert f_arm[0, 1] == pytest.approx(400 / 400 - (20.0 / 400) ** 2 * 1.0, abs=1e-9)


# --- rendering ------------------------------------------------------------------------

def _geometry_only():
    return RendererConfig(lamp_modulation=False, sensor_noise=False, optics_psf=False,
                          vignetting=False,
                          sensor=SensorConfig(background_dn=0.0, dark_current_e_per_s=0.0,
                                              full_well_e=1e12, noise_bank_size=1))


def _rim(lamp, n=4000):
    nh = lamp.normal
    e1 = np.array([1.0, 0.0, 0.0]) - nh[0] * nh
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(nh, e1)
    a = np.linspace(0.0, 2.0 * np.pi, n, endpoint=False)
    return lamp.position_m + 0.1 * (np.outer(np.cos(a), e1) + np.outer(np.sin(a), e2))


@pytest.mark.parametrize('chainage_m, lamp_id', [(377.0, 38), (1063.0, 107), (1882.0, 189)])
def test_curved_frame_shows_the_lamps_where_the_camera_model_projects_them(
        demo, curved_map, chainage_m, lamp_id):
    """Standing in the R = 400 m (left), 600 m (right) and 300 m (right) arcs: every
    rendered lamp's truth is the StereoRig projection of its map position, and the
    rendered spot (its coverage centroid and area) is the projected disc.
    """
    traj = Trajectory(MotionProfile('stationary', start_chainage_m=chainage_m),
                      Vibration(VibrationConfig(enabled=False)), demo)
    renderer = StereoRenderer(_geometry_only(), curved_map, traj)
    frame = renderer.render_at(0.0, electrons=True)
    pose = traj.sample([0.0])
    uids = {t.uid: t for t in frame.truth}
    assert (2 << 12 | lamp_id) in uids, sorted(uids)
    for truth in frame.truth:
        lamp = curved_map.by_uid(truth.uid)
        uv_l, uv_r, depth = renderer.rig.project(lamp.position_m[None], pose.position_m[0],
                                                 pose.R_map_base[0])
        np.testing.assert_allclose(truth.uv_left, uv_l[0], atol=1e-6)
        np.testing.assert_allclose(truth.uv_right, uv_r[0], atol=1e-6)
        assert truth.depth_m == pytest.approx(depth[0], abs=1e-9)
    truth = uids[2 << 12 | lamp_id]
    lamp = curved_map.by_uid(truth.uid)
    u, v = np.round(truth.uv_left).astype(int)
    window = frame.left[max(v - 60, 0):v + 60, max(u - 60, 0):u + 60].astype(np.float64)
    m = cv2.moments(window)
    cu, cv_ = m['m10'] / m['m00'] + max(u - 60, 0), m['m01'] / m['m00'] + max(v - 60, 0)
    rim, _, _ = renderer.rig.project(_rim(lamp), pose.position_m[0], pose.R_map_base[0])
    poly = cv2.moments(rim.astype(np.float32).reshape(-1, 1, 2))
    assert cu == pytest.approx(poly['m10'] / poly['m00'], abs=0.02)
    assert cv_ == pytest.approx(poly['m01'] / poly['m00'], abs=0.02)
    # The spot is the disc's image: within its eccentricity (< 1.5 px) of the centre.
    assert np.hypot(cu - truth.uv_left[0], cv_ - truth.uv_left[1]) < 1.5


# --- nodes ------------------------------------------------------------------------------

def test_rig_yaml_documents_the_alignment_parameter():
    values = yaml.safe_load((CONFIG / 'rig.yaml').read_text())['/**']['ros__parameters']
    assert values == {name: default for name, default, _ in SCENARIO_PARAMETERS}


@pytest.fixture
def imu_node(node_factory):
    def make(**params):
        params.setdefault('follow_clock', False)    # self-paced: no camera /clock here
        node = node_factory(Adis16488Node, **params)
        node.sent = []
        node._imu_pub.publish = lambda msg: node.sent.append(copy.deepcopy(msg))
        node._diag_pub.publish = lambda msg: None
        return node

    return make


def _canted_arc_imu(v, radius_m, cant_rad, grade):
    """Gyro and specific force on an arc of constant cant and grade (no vibration): the
    track's yaw rate v/R and centripetal κ·v² plus gravity, rotated into R_T =
    Rz·Ry(−atan G)·Rx(φ) — written out here, independent of the trajectory code.
    """
    theta = -np.arctan(grade)
    R_T = rpy_to_matrix(cant_rad, theta, 0.0)            # heading 0 without loss of generality
    yaw_rate = v / radius_m
    gyro = R_T.T @ np.array([0.0, 0.0, yaw_rate])
    force = R_T.T @ (np.array([0.0, v * v / radius_m, 0.0]) + [0.0, 0.0, GRAVITY_MPS2])
    return gyro, force


def test_adis16488_node_follows_the_alignment_parameter(imu_node, demo):
    """In the R = 400 m arc of curved_demo (120 mm cant, −28 ‰ grade) the node's gyro and
    accelerometer show the yaw rate and the centripetal force in the canted, pitched
    track frame.
    """
    v = 72.0 / 3.6
    node = imu_node(rate_hz=100.0, realtime_factor=0.0, noise_enabled=False,
                    vibration_enabled=False, alignment='curved_demo',
                    start_chainage_m=330.0, speed_kmh=72.0)
    for _ in range(5):
        node._on_tick()
    gyro = np.array([imu_arrays(m)[1] for m in node.sent])
    accel = np.array([imu_arrays(m)[2] for m in node.sent])
    assert len(gyro) >= 50
    track = demo.evaluate(330.0 + v * len(gyro) / 100.0)
    assert track.grade[0] == pytest.approx(-0.028) and track.cant_m[0] == pytest.approx(0.12)
    gyro_expected, force_expected = _canted_arc_imu(v, 400.0, track.cant_rad[0], -0.028)
    np.testing.assert_allclose(gyro, np.tile(gyro_expected, (len(gyro), 1)), atol=1e-12)
    np.testing.assert_allclose(accel, np.tile(force_expected, (len(gyro), 1)), atol=1e-9)


def test_adis16488_node_rejects_an_unknown_alignment(imu_node):
    with pytest.raises(ValueError, match='unknown alignment'):
        imu_node(alignment='figure_eight')


@pytest.mark.ros
def test_stereo_camera_node_ground_truth_follows_the_curve(ros_env):
    """stereo_camera_node with alignment=curved_demo and the curved map: the truth pose
    is the alignment's (position, heading), and the lamp ahead in the R = 400 m arc is
    in the truth spots with its rectified geometry.
    """
    from geometry_msgs.msg import PoseStamped
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.node import Node
    from rclpy.qos import QoSProfile, ReliabilityPolicy
    from sensor_msgs.msg import Image, PointCloud2

    from vlc_common.core.rotations import quat_to_matrix
    from vlc_stereo_camera import conversions
    from vlc_stereo_camera.stereo_camera_node import StereoCameraNode

    ctx = rclpy.Context()
    rclpy.init(context=ctx)
    params = {'alignment': 'curved_demo',
              'lamp_map_path': str(MAPS / 'lamp_map_curved_demo.yaml'),
              'start_chainage_m': 375.0, 'speed_kmh': 18.0, 'vibration_enabled': False,
              'duration_s': 0.2, 'realtime_factor': 0.0, 'wait_for_subscribers': 1,
              'publish_clock': False, 'noise_bank_size': 1}
    node = StereoCameraNode(context=ctx, parameter_overrides=[
        Parameter(k, value=v) for k, v in params.items()])
    probe = Node('probe', context=ctx)
    got = {'pose': [], 'spots': []}
    qos = QoSProfile(depth=50, reliability=ReliabilityPolicy.RELIABLE)
    probe.create_subscription(PoseStamped, 'ground_truth/pose', got['pose'].append, qos)
    probe.create_subscription(PointCloud2, 'ground_truth/spots', got['spots'].append, qos)
    probe.create_subscription(Image, 'stereo/left/image_raw', lambda m: None, qos)
    probe.create_subscription(Image, 'stereo/right/image_raw', lambda m: None, qos)
    executor = SingleThreadedExecutor(context=ctx)
    executor.add_node(node)
    executor.add_node(probe)
    try:
        executor.spin_until_future_complete(node.finished, timeout_sec=60.0)
        assert node.finished.done() and node.finished.result() == 0
        for _ in range(10):
            executor.spin_once(timeout_sec=0.05)
    finally:
        node.stop()
        executor.shutdown()
        node.destroy_node()
        probe.destroy_node()
        rclpy.shutdown(context=ctx)
    assert len(got['pose']) >= 4
    demo = Alignment.named('curved_demo')
    for msg in got['pose']:
        t = (msg.header.stamp.sec - 1704067200) + msg.header.stamp.nanosec * 1e-9
        expected = demo.evaluate(375.0 + 5.0 * t)
        p = msg.pose.position
        # Stamps are whole nanoseconds: 5 m/s × 0.5 ns.
        assert (p.x, p.y, p.z) == (pytest.approx(expected.x_m[0], abs=1e-8),
                                   pytest.approx(expected.y_m[0], abs=1e-8),
                                   pytest.approx(expected.elevation_m[0], abs=1e-8))
        o = msg.pose.orientation
        R = quat_to_matrix([o.x, o.y, o.z, o.w])
        assert np.arctan2(R[1, 0], R[0, 0]) == pytest.approx(expected.heading_rad[0], abs=1e-9)
    rec = conversions.cloud_to_records(got['spots'][-1])
    assert (2 << 12 | 38) in rec['uid'].tolist()
    r = rec[rec['uid'] == (2 << 12 | 38)][0]
    assert r['u_left'] - r['u_right'] == pytest.approx(1040 * 0.12 / r['depth_m'])


@pytest.mark.parametrize('name, lamp_chainage_m, near_m, far_m, level_near_m, level_far_m', [
    ('straight', 700.0, 0.48, 9.58, 0.44, 9.55),
    ('R400 left', 380.0, 0.40, 9.36, 0.44, 10.21),
    ('R600 right', 1010.0, 0.54, 9.55, 0.44, 9.18),
    ('R800 left', 1510.0, 0.37, 9.58, 0.44, 9.86),
    ('R300 right', 1890.0, 0.57, 9.44, 0.44, 8.86)])
def test_visibility_window_on_curves(demo, level_demo, curved_map, name, lamp_chainage_m,
                                     near_m, far_m, level_near_m, level_far_m):
    """Lamp centre inside both images at rest (documented in docs/arch/vlc_stereo_camera.md).

    Level track (curved_demo's horizontal geometry alone): the wall curving toward the
    camera (left curves) lengthens the far limit, away from it (right curves) shortens
    it; the near limit (bottom image edge) does not change. curved_demo with its cant
    and grade: the cant rolls the camera toward the curve's centre — away from the left
    wall's lamps in a left curve, toward them in a right curve — which undoes most of
    that; the grade moves the near limit by a few centimetres.
    """
    rig = StereoRig()
    d = np.arange(0.0, 12.0, 0.01)
    for alignment, lamps, near, far in (
            (demo, curved_map, near_m, far_m),
            (level_demo, alignment_lamp_map(level_demo, line_id=2), level_near_m, level_far_m)):
        lamp = lamps.by_uid(2 << 12 | int(lamp_chainage_m / 10))
        # A standing train without vibration: base_link = alignment point, attitude = the
        # track frame (test_standing_pose_is_the_track_frame checks the trajectory agrees).
        p = alignment.evaluate(lamp_chainage_m - d)
        base = np.column_stack([p.x_m, p.y_m, p.elevation_m])
        R = rpy_to_matrix(p.cant_rad, -np.arctan(p.grade), p.heading_rad)
        uv_l, uv_r, z = rig.project(np.repeat(lamp.position_m[None], len(d), axis=0), base, R)
        visible = (z > 0) & np.all([(uv[:, 0] >= -0.5) & (uv[:, 0] <= 1279.5)
                                    & (uv[:, 1] >= -0.5) & (uv[:, 1] <= 719.5)
                                    for uv in (uv_l, uv_r)], axis=0)
        inside = d[visible]
        assert inside.min() == pytest.approx(near, abs=0.011)
        assert inside.max() == pytest.approx(far, abs=0.011)
        assert np.all(np.diff(inside) < 0.011)              # one contiguous window


# --- rig parameter -------------------------------------------------------------------

def _scenario(**overrides):
    values = {name: default for name, default, _ in SCENARIO_PARAMETERS}
    values.update(overrides)
    return ScenarioConfig(**values)


def test_rig_parameter_selects_the_alignment():
    assert {n: d for n, d, _ in SCENARIO_PARAMETERS}['alignment'] == 'straight'
    assert _scenario().trajectory().alignment.is_straight
    traj = _scenario(alignment='curved_demo', start_chainage_m=380.0,
                     motion_profile='stationary', vibration_enabled=False).trajectory()
    s = traj.sample([0.0])
    expected = Alignment.named('curved_demo').evaluate(380.0)
    assert s.position_m[0, :2] == pytest.approx([expected.x_m[0], expected.y_m[0]])
    assert s.rpy_rad[0, 2] == pytest.approx(expected.heading_rad[0])
    assert _scenario(alignment='curved_demo').default_lamp_map_path().endswith(
        'lamp_map_curved_demo.yaml')
    with pytest.raises(ValueError, match='unknown alignment'):
        _scenario(alignment='zigzag').trajectory()
