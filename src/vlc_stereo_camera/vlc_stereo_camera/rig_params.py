"""Scenario parameters shared by ``stereo_camera_node`` and ``adis16488_node``.

Both nodes declare the same parameters (documented in ``config/rig.yaml``) and build the
same :class:`~vlc_stereo_camera.core.trajectory.Trajectory` from them, so the images and
the IMU samples describe one motion. Pass ``config/rig.yaml`` to both.

``alignment`` selects the track geometry (:mod:`.core.alignment`): ``straight`` (the
default, along map x) or a named curved alignment such as ``curved_demo``; the rig's
lamp map must be the alignment's (``lamp_map_path`` = ``lamp_map_<alignment>.yaml``,
see :meth:`ScenarioConfig.default_lamp_map_path`).

The sensor-fault parameters (``imu_dropouts_s``, ``camera_dropouts_s``, ``imu_burst_s``,
``imu_stamp_offset_s``, ``sensor_clock_jumps_s``; every default off) are scenario
parameters too, so every rig node has them and one ``rig.yaml`` gives the whole rig one
fault schedule (:class:`~vlc_stereo_camera.core.sensor_faults.SensorFaults`, semantics
there). They act at publication time only: the physics is the same with and without.

``rig_profile`` (``config/rig_profiles.yaml``; :mod:`.core.installation`) makes the rig a
real installation: ``ideal`` (the default) is the rig as it always was; ``realistic``
and ``harsh`` draw, from the profile and ``seed``, the vehicle's true camera, mount,
IMU boresight and clock offset, the line's true lamps, and the belief the receivers get
(calibration, mount file as measured, surveyed lamp map); ``installation_seed`` (when
not 0) draws the installation instead, so one train and line can be run again with new
sensor noise, platform motion and IMU biases (``seed``). Every rig node draws the same
installation: :meth:`ScenarioConfig.vehicle` is then the TRUE mount, the trajectory's
platform motion is the profile's car body, and the IMU stamps carry the drawn clock
offset. ``installation_dir`` (camera node) receives ``belief/`` and ``truth/``.
"""
from dataclasses import dataclass

from rcl_interfaces.msg import ParameterType
from rclpy.parameter import Parameter

from vlc_common.core.alignment import NAMED_ALIGNMENTS, Alignment
from vlc_common.core.lamp_map import default_lamp_map_path
from vlc_common.core.vehicle import load_vehicle
from vlc_common.parameters import descriptor as _desc
from vlc_common.stamps import epoch_to_ns
from vlc_stereo_camera.core.car_body import CarBody, CarBodyConfig
from vlc_stereo_camera.core.installation import draw_imu_clock, draw_vehicle, load_profile
from vlc_stereo_camera.core.sensor_faults import SensorFaults
from vlc_stereo_camera.core.trajectory import MotionProfile, Trajectory, Vibration, VibrationConfig

_ARRAY = ParameterType.PARAMETER_DOUBLE_ARRAY

SCENARIO_PARAMETERS = (
    # name, default, descriptor
    ('seed', 1, _desc('Seed of every random process of the scenario (vibration phases, '
                      'lamp clocks, sensor noise).', 0, 2 ** 31 - 1, integer=True)),
    ('epoch_s', 1704067200.0, _desc('Simulated clock epoch: ROS time of t = 0, seconds '
                                    '(2024-01-01T00:00:00Z).', 0.0, 4.0e9)),
    ('motion_profile', 'constant', _desc('Train motion: stationary, constant or '
                                         'accel_cruise_brake.',
                                         ptype=ParameterType.PARAMETER_STRING)),
    ('start_chainage_m', 0.0, _desc('Chainage of base_link at t = 0, metres.', -1.0e5, 1.0e6)),
    ('speed_kmh', 20.0, _desc('Constant or cruise speed, km/h.', 0.0, 200.0)),
    ('accel_mps2', 1.0, _desc('Acceleration of accel_cruise_brake, m/s^2.', 0.01, 3.0)),
    ('brake_mps2', 1.0, _desc('Braking deceleration of accel_cruise_brake, m/s^2.', 0.01, 3.0)),
    ('dwell_s', 5.0, _desc('Standstill before accelerating (accel_cruise_brake), s.', 0.0, 3600.0)),
    ('cruise_s', 20.0, _desc('Cruise duration (accel_cruise_brake), s.', 0.0, 36000.0)),
    ('vibration_enabled', True, _desc('Platform vibration per paper eq. 21 on or off.')),
    ('vibration_scale', 1.0, _desc('Scale of all vibration amplitudes (1 = paper: heading '
                                   '-5.0..+7.5 deg).', 0.0, 5.0)),
    ('vehicle_path', '', _desc("Vehicle mount file (sensor extrinsics in base_link); '' = "
                               "share/vlc_common/config/vehicle.yaml.",
                               ptype=ParameterType.PARAMETER_STRING)),
    ('alignment', 'straight', _desc('Track alignment: ' + ', '.join(NAMED_ALIGNMENTS)
                                    + ' (straight = along map x).',
                                    ptype=ParameterType.PARAMETER_STRING)),
    ('rig_profile', 'ideal', _desc('Rig profile of config/rig_profiles.yaml: ideal (the '
                                   'nominal rig, receivers share its truth), realistic, '
                                   'harsh (drawn installation: truth vs belief, per seed).',
                                   ptype=ParameterType.PARAMETER_STRING)),
    ('installation_seed', 0, _desc('Seed of the drawn installation (vehicle, optics, '
                                   'calibration, IMU mount and clock, the line\'s lamps) of '
                                   'a drawn rig_profile; 0 = seed. The same installation '
                                   'with another seed is the same train on the same line '
                                   'on another run (multi-pass evaluation).',
                                   0, 2 ** 31 - 1, integer=True)),
    ('rig_profiles_path', '', _desc("Rig profiles file; '' = share/vlc_stereo_camera/"
                                    'config/rig_profiles.yaml.',
                                    ptype=ParameterType.PARAMETER_STRING)),
    ('installation_dir', '', _desc("stereo_camera_node with a drawn profile: folder that "
                                   "receives belief/ and truth/ of the installation; '' = "
                                   'none written.', ptype=ParameterType.PARAMETER_STRING)),
    # --- sensor faults (core/sensor_faults.py), applied at publication; default off ---
    ('imu_dropouts_s', [], _desc('IMU samples lost: flat pairs [start_s, duration_s, ...] '
                                 'of simulated time; samples with start_s <= t < start_s + '
                                 'duration_s are not published. [] = none.', ptype=_ARRAY)),
    ('camera_dropouts_s', [], _desc('Camera frames lost: flat pairs [start_s, duration_s, '
                                    '...]; frames with t0 in a window publish no image and '
                                    'no camera_info (truth and /clock go on). [] = none.',
                                    ptype=_ARRAY)),
    ('imu_burst_s', 0.0, _desc('IMU samples held and published in bursts at every '
                               'multiple of this much simulated time, s; 0 = off.',
                               0.0, 60.0)),
    ('imu_stamp_offset_s', 0.0, _desc('Added to every IMU stamp (IMU clock offset from the '
                                      "camera's), s; release still at the true time.",
                                      -3600.0, 3600.0)),
    ('sensor_clock_jumps_s', [], _desc('Steps of the sensor clock: flat pairs [at_s, '
                                       'jump_s, ...]; every sensor and truth stamp of '
                                       'simulated time t >= at_s is jump_s later '
                                       '(cumulative, negative = back); /clock is not '
                                       'stepped. [] = none.', ptype=_ARRAY)),
)

#: Scenario parameters declared as DOUBLE_ARRAY with no value (rclpy infers no type
#: from ``[]``); unset means empty.
_EMPTY_ARRAYS = {name for name, default, d in SCENARIO_PARAMETERS
                 if default == [] and d.type == _ARRAY}


@dataclass
class ScenarioConfig:
    seed: int
    epoch_s: float
    motion_profile: str
    start_chainage_m: float
    speed_kmh: float
    accel_mps2: float
    brake_mps2: float
    dwell_s: float
    cruise_s: float
    vibration_enabled: bool
    vibration_scale: float
    alignment: str = 'straight'
    vehicle_path: str = ''
    rig_profile: str = 'ideal'
    rig_profiles_path: str = ''
    installation_seed: int = 0
    installation_dir: str = ''
    imu_dropouts_s: tuple = ()
    camera_dropouts_s: tuple = ()
    imu_burst_s: float = 0.0
    imu_stamp_offset_s: float = 0.0
    sensor_clock_jumps_s: tuple = ()

    @property
    def drawn_seed(self):
        """The seed the installation is drawn from: ``installation_seed``, else ``seed``."""
        return int(self.installation_seed) or int(self.seed)

    def profile(self):
        """The RigProfile named by ``rig_profile`` (ProfileError, a ValueError, naming the
        file and field if unknown or unparsable).
        """
        return load_profile(self.rig_profile, self.rig_profiles_path)

    def nominal_vehicle(self):
        """The VehicleMount of ``vehicle_path`` (the drawing; VehicleFileError if unusable)."""
        return load_vehicle(self.vehicle_path)

    def vehicle(self):
        """The VehicleMount the rig's sensors truly sit on: the nominal file for the ideal
        profile, else the installation's drawn truth (same draw in every rig node).
        """
        profile = self.profile()
        nominal = self.nominal_vehicle()
        return nominal if profile.ideal else draw_vehicle(profile, self.drawn_seed, nominal)[0]

    def imu_clock_offset_s(self):
        """The drawn IMU-minus-camera clock offset of the installation, s (0 for ideal)."""
        return draw_imu_clock(self.profile(), self.drawn_seed)[0]

    def imu_clock_drift_ppm(self):
        """The drawn IMU clock drift against the camera's, ppm (0 for ideal)."""
        return draw_imu_clock(self.profile(), self.drawn_seed)[1]

    def track_alignment(self):
        """The Alignment named by ``alignment`` (raises ValueError if unknown)."""
        return Alignment.named(self.alignment)

    def default_lamp_map_path(self):
        """The shipped lamp map of this alignment (``lamp_map_path`` '' should mean it)."""
        return default_lamp_map_path(self.alignment)

    def trajectory(self):
        """The Trajectory these parameters describe (raises ValueError if invalid)."""
        profile = MotionProfile(kind=self.motion_profile,
                                start_chainage_m=self.start_chainage_m,
                                speed_mps=self.speed_kmh / 3.6, accel_mps2=self.accel_mps2,
                                brake_mps2=self.brake_mps2, dwell_s=self.dwell_s,
                                cruise_s=self.cruise_s)
        car_body = self.profile().car_body
        if car_body is not None and self.vibration_enabled:
            vibration = CarBody(CarBodyConfig(spectrum=car_body['spectrum'],
                                              scale=car_body['scale'], seed=self.seed))
        else:
            vibration = Vibration(VibrationConfig(enabled=self.vibration_enabled,
                                                  scale=self.vibration_scale), seed=self.seed)
        return Trajectory(profile, vibration, self.track_alignment())

    def sensor_faults(self):
        """The SensorFaults these parameters describe (raises ValueError if invalid)."""
        offset_s, drift_ppm = draw_imu_clock(self.profile(), self.drawn_seed)
        faults = SensorFaults.from_parameters(
            imu_dropouts_s=self.imu_dropouts_s, camera_dropouts_s=self.camera_dropouts_s,
            imu_burst_s=self.imu_burst_s,
            imu_stamp_offset_s=self.imu_stamp_offset_s + offset_s,
            sensor_clock_jumps_s=self.sensor_clock_jumps_s, imu_clock_drift_ppm=drift_ppm)
        faults.check_epoch(epoch_to_ns(self.epoch_s))
        return faults


def declare_scenario_parameters(node):
    """Declare the shared scenario parameters on ``node`` and return a ScenarioConfig.

    Raises
    ------
    rclpy.exceptions.ParameterException
        A value has the wrong type (the fault lists take floats: ``[1.0, 0.5]``) or is
        out of its declared range.
    ValueError
        The sensor-fault schedule is invalid (:meth:`ScenarioConfig.sensor_faults`).
    """
    values = {}
    for name, default, descriptor in SCENARIO_PARAMETERS:
        if name in _EMPTY_ARRAYS:
            # unset (no override, or [] in a parameter file) = empty
            value = node.declare_parameter(name, Parameter.Type.DOUBLE_ARRAY, descriptor).value
            values[name] = tuple(float(v) for v in value or ())
        else:
            values[name] = node.declare_parameter(name, default, descriptor).value
    config = ScenarioConfig(**values)
    config.profile()                # an unknown profile or a bad file stops the node (exit 2)
    config.sensor_faults()          # validate at start-up, in every rig node
    return config
