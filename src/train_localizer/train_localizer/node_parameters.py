"""Parameter tables shared by every node that runs the along-track filter on lamp fixes.

``train_localizer_node`` and the companion localizers (dead reckoning, INS + beacon
ranging) declare these tables, so a key means the same thing with the same range in
each; every node documents them in its own ``config/<node>.yaml``. Each table is a tuple
of ``(name, default, ParameterDescriptor)``; :func:`with_defaults` changes a default
where a node needs another one. The camera mount comes from the vehicle file
(``vehicle_path``), never from a node parameter.
"""
from train_localizer.core.fix import RigGeometry
from train_localizer.core.join import JoinConfig
from train_localizer.core.kalman import KalmanConfig
from train_localizer.core.standstill import StandstillConfig
from vlc_common.core.camera import StereoRig
from vlc_common.core.vehicle import load_vehicle
from vlc_common.parameters import descriptor as _desc

_RIG = StereoRig()

#: The stereo camera: intrinsics until camera_info arrives, its timing, the mount's file.
STEREO_PARAMETERS = (
    ('vehicle_path', '', _desc("Vehicle mount file (camera and IMU extrinsics in base_link); "
                               "'' = share/vlc_common/config/vehicle.yaml.")),
    ('use_camera_info', True, _desc('Take intrinsics and baseline from camera_info.')),
    ('fx', _RIG.intrinsics.fx, _desc('Rectified focal length x (until camera_info), px.',
                                     1.0, 1e5)),
    ('fy', _RIG.intrinsics.fy, _desc('Rectified focal length y, px.', 1.0, 1e5)),
    ('cx', _RIG.intrinsics.cx, _desc('Principal point x, px.', -1e5, 1e5)),
    ('cy', _RIG.intrinsics.cy, _desc('Principal point y, px.', -1e5, 1e5)),
    ('baseline_m', _RIG.baseline_m, _desc('Stereo baseline, m.', 1e-3, 10.0)),
    ('row_time_s', 30e-6, _desc('Rolling-shutter row time, s.', 0.0, 1e-2)),
    ('exposure_s', 25e-6, _desc('Row exposure time, s.', 0.0, 0.1)),
)

#: base_link's place about the track centreline.
TRACK_PARAMETERS = (
    ('track_sigma_y_m', 0.004, _desc('1-sigma lateral offset of base_link from the track, m.',
                                     1e-6, 1.0)),
    ('track_sigma_z_m', 0.004, _desc('1-sigma vertical offset of base_link from the track, m.',
                                     1e-6, 1.0)),
    ('track_offset_y_m', 0.0, _desc('Nominal lateral position of base_link in map, m.',
                                    -10.0, 10.0)),
    ('track_offset_z_m', 0.0, _desc('Nominal height of base_link in map, m.', -10.0, 10.0)),
)

#: The along-track process model.
KALMAN_PARAMETERS = (
    ('accel_noise_density_mps2_rthz', 0.01, _desc('Along-track acceleration white noise, '
                                                  'm/s^2/sqrt(Hz).', 0.0, 10.0)),
    ('bias_random_walk_mps3_rthz', 2e-3, _desc('Acceleration bias random walk, '
                                               'm/s^3/sqrt(Hz).', 0.0, 10.0)),
    ('initial_bias_sigma_mps2', 0.2, _desc('1-sigma acceleration bias at start, m/s^2.',
                                           0.0, 10.0)),
    ('initial_speed_sigma_mps', 40.0, _desc('1-sigma speed at a cold start, m/s.', 0.0, 200.0)),
)

#: Zero-velocity updates while the IMU shows a standing platform.
STANDSTILL_PARAMETERS = (
    ('use_zero_velocity', True, _desc('Zero-velocity updates at standstill.')),
    ('standstill_window_s', 0.25, _desc('Standstill detector window, s.', 0.01, 10.0)),
    ('standstill_gyro_std_max_rps', 0.005, _desc('Standstill: max angular-rate std, rad/s.',
                                                 0.0, 10.0)),
    ('standstill_accel_std_max_mps2', 0.05, _desc('Standstill: max specific-force std, m/s^2.',
                                                  0.0, 100.0)),
    ('zero_velocity_max_speed_mps', 0.3, _desc('Zero-velocity update only below this speed '
                                               '(+2 sigma), m/s.', 0.0, 10.0)),
    ('zero_velocity_sigma_mps', 0.01, _desc('1-sigma of a zero-velocity update, m/s.',
                                            1e-6, 10.0)),
    ('zero_velocity_gate_chi2', 16.0, _desc('A zero-velocity update whose innovation (the '
                                            'speed against zero) exceeds this chi2 is refused: '
                                            'the train has started.', 1.0, 1e9)),
)

#: Joining spots/pairs and vlc/lamps of one frame.
JOIN_PARAMETERS = (
    ('join_match_radius_px', 12.0, _desc('Max left-image distance lamp record - spot pair, px.',
                                         0.0, 2000.0)),
    ('join_timeout_s', 0.15, _desc('Longest wait for the other half of a frame, s.',
                                   0.0, 10.0)),
)


def with_defaults(table, **defaults):
    """``table`` with the defaults of the named parameters replaced."""
    unknown = set(defaults) - {name for name, _, _ in table}
    if unknown:
        raise KeyError(f'not in the table: {sorted(unknown)}')
    return tuple((name, defaults.get(name, default), desc) for name, default, desc in table)


def load_mount(p):
    """The :class:`~vlc_common.core.vehicle.VehicleMount` of ``vehicle_path``."""
    return load_vehicle(p['vehicle_path'])


def rig_geometry(p, mount=None):
    """RigGeometry of the stereo parameters and the vehicle file's camera mount."""
    camera = (mount or load_mount(p)).camera
    return RigGeometry.from_mount(
        tuple(float(v) for v in camera.position_m), camera.placement_angle_deg,
        camera.pitch_deg, camera.roll_deg, fx=p['fx'], fy=p['fy'], cx=p['cx'], cy=p['cy'],
        baseline_m=p['baseline_m'], row_time_s=p['row_time_s'], exposure_s=p['exposure_s'],
        calibration_sigma_px=(float(p.get('calibration_sigma_px', 0.0)),
                              float(p.get('calibration_disparity_sigma_px', 0.0))))


def kalman_config(p, **extra):
    """KalmanConfig of the process-model parameters (plus keyword extras)."""
    return KalmanConfig(accel_noise_density_mps2_rthz=p['accel_noise_density_mps2_rthz'],
                        bias_random_walk_mps3_rthz=p['bias_random_walk_mps3_rthz'],
                        initial_bias_sigma_mps2=p['initial_bias_sigma_mps2'],
                        initial_speed_sigma_mps=p['initial_speed_sigma_mps'], **extra)


def standstill_config(p):
    return StandstillConfig(
        enabled=p['use_zero_velocity'], window_s=p['standstill_window_s'],
        gyro_std_max_rps=p['standstill_gyro_std_max_rps'],
        accel_std_max_mps2=p['standstill_accel_std_max_mps2'],
        max_speed_mps=p['zero_velocity_max_speed_mps'],
        speed_sigma_mps=p['zero_velocity_sigma_mps'], gate_chi2=p['zero_velocity_gate_chi2'])


def join_config(p, **extra):
    return JoinConfig(match_radius_px=p['join_match_radius_px'], timeout_s=p['join_timeout_s'],
                      **extra)
