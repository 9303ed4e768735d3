"""The vehicle mount file: where the sensors sit on the train head, in ``base_link``.

One file, read by every node that needs an extrinsic (the rig renders and samples with
it, the receivers use it as measured), instead of a copy per node. ROS has TF for this;
the pip-installed Jazzy has no tf2_msgs wheel, so the mount travels as this file
(ARCHITECTURE.md). File format (YAML, SI units, angles in degrees)::

    vehicle_id: demo_train            # who the file belongs to (checked by calibrations)
    frame_id: base_link
    stereo_camera:                    # the left camera's optical centre and axis
      position_m: [0.0, 0.8, 2.9]
      placement_angle_deg: 49.0       # axis turned from the left-wall normal toward +x
      pitch_deg: 27.0                 # axis tilted down
      roll_deg: 0.0                   # turned about the optical axis (optional, 0)
    imu:
      position_m: [0.0, 0.0, 0.0]     # lever arm of imu_link
      rpy_deg: [0.0, 0.0, 0.0]        # boresight: imu_link in base_link (REP-103 roll, pitch, yaw)
    photodiode:
      position_m: [0.0, 0.8, 2.9]
      azimuth_deg: 0.0                # normal turned from +y (left wall) toward +x
      elevation_deg: -41.4            # normal above the horizontal

Frames: ``base_link`` x forward, y left, z up (on the track centreline at rail top);
optical frames z forward, x right, y down. The stereo baseline and the right camera's
relative rotation are the stereo calibration's (camera_info), not the mount's.
"""
from dataclasses import dataclass, field
import math
import os
import pathlib

import numpy as np
import yaml

from vlc_common.core.camera import mount_rotation
from vlc_common.core.config_files import SAFE_LOADER, config_path
from vlc_common.core.rotations import rpy_to_matrix

PACKAGE = 'vlc_common'
DEFAULT_FILE = 'vehicle.yaml'


class VehicleFileError(ValueError):
    """A vehicle mount file that cannot be used: the message names the file and field."""


def _vector3(value, where):
    v = np.asarray(value, dtype=float).reshape(-1)
    if v.shape != (3,) or not np.all(np.isfinite(v)):
        raise VehicleFileError(f'{where} must be 3 finite numbers, got {value!r}')
    return v


def _finite(value, where):
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise VehicleFileError(f'{where} must be a number, got {value!r}') from None
    if not math.isfinite(v):
        raise VehicleFileError(f'{where} must be finite, got {value!r}')
    return v


@dataclass
class CameraMount:
    """The left camera of the stereo pair on ``base_link`` (see the module docstring)."""

    position_m: np.ndarray = field(default_factory=lambda: np.array([0.0, 0.8, 2.9]))
    placement_angle_deg: float = 49.0
    pitch_deg: float = 27.0
    roll_deg: float = 0.0

    def __post_init__(self):
        self.position_m = _vector3(self.position_m, 'stereo_camera.position_m')

    @property
    def R_base_cam(self):
        """(3, 3): columns are the optical x, y, z axes in ``base_link``."""
        return mount_rotation(self.placement_angle_deg, self.pitch_deg, self.roll_deg)


@dataclass
class ImuMount:
    """``imu_link`` on ``base_link``: lever arm (m) and boresight (rad)."""

    position_m: np.ndarray = field(default_factory=lambda: np.zeros(3))
    rpy_rad: np.ndarray = field(default_factory=lambda: np.zeros(3))

    def __post_init__(self):
        self.position_m = _vector3(self.position_m, 'imu.position_m')
        self.rpy_rad = _vector3(self.rpy_rad, 'imu.rpy_deg')

    @property
    def R_base_imu(self):
        return rpy_to_matrix(*self.rpy_rad)


@dataclass
class PhotodiodeMount:
    """The photodiode on ``base_link``: position (m) and normal direction (deg)."""

    position_m: np.ndarray = field(default_factory=lambda: np.array([0.0, 0.8, 2.9]))
    azimuth_deg: float = 0.0
    elevation_deg: float = -41.4

    def __post_init__(self):
        self.position_m = _vector3(self.position_m, 'photodiode.position_m')


@dataclass
class VehicleMount:
    """Every sensor's mount on one vehicle; :meth:`load` / :meth:`save` the YAML file."""

    vehicle_id: str = 'demo_train'
    frame_id: str = 'base_link'
    camera: CameraMount = field(default_factory=CameraMount)
    imu: ImuMount = field(default_factory=ImuMount)
    photodiode: PhotodiodeMount = field(default_factory=PhotodiodeMount)
    source: str = ''

    @classmethod
    def from_dict(cls, data, source=''):
        """The mount of a parsed file; :class:`VehicleFileError` names the bad field."""
        where = f'{source or "vehicle file"}: '
        if not isinstance(data, dict):
            raise VehicleFileError(f'{where}expected a mapping at the top level')
        try:
            cam = data.get('stereo_camera', {}) or {}
            imu = data.get('imu', {}) or {}
            pd = data.get('photodiode', {}) or {}
            camera = CameraMount(
                position_m=cam.get('position_m', CameraMount().position_m),
                placement_angle_deg=_finite(cam.get('placement_angle_deg', 49.0),
                                            'stereo_camera.placement_angle_deg'),
                pitch_deg=_finite(cam.get('pitch_deg', 27.0), 'stereo_camera.pitch_deg'),
                roll_deg=_finite(cam.get('roll_deg', 0.0), 'stereo_camera.roll_deg'))
            rpy_deg = _vector3(imu.get('rpy_deg', [0.0, 0.0, 0.0]), 'imu.rpy_deg')
            imu_mount = ImuMount(position_m=imu.get('position_m', [0.0, 0.0, 0.0]),
                                 rpy_rad=np.radians(rpy_deg))
            photodiode = PhotodiodeMount(
                position_m=pd.get('position_m', PhotodiodeMount().position_m),
                azimuth_deg=_finite(pd.get('azimuth_deg', 0.0), 'photodiode.azimuth_deg'),
                elevation_deg=_finite(pd.get('elevation_deg', -41.4),
                                      'photodiode.elevation_deg'))
        except VehicleFileError as exc:
            raise VehicleFileError(where + str(exc)) from None
        return cls(vehicle_id=str(data.get('vehicle_id', '')),
                   frame_id=str(data.get('frame_id', 'base_link')), camera=camera,
                   imu=imu_mount, photodiode=photodiode, source=str(source))

    def to_dict(self):
        c, i, p = self.camera, self.imu, self.photodiode
        return {
            'vehicle_id': self.vehicle_id,
            'frame_id': self.frame_id,
            'stereo_camera': {'position_m': [float(v) for v in c.position_m],
                              'placement_angle_deg': float(c.placement_angle_deg),
                              'pitch_deg': float(c.pitch_deg),
                              **({'roll_deg': float(c.roll_deg)} if c.roll_deg else {})},
            'imu': {'position_m': [float(v) for v in i.position_m],
                    'rpy_deg': [float(v) for v in np.degrees(i.rpy_rad)]},
            'photodiode': {'position_m': [float(v) for v in p.position_m],
                           'azimuth_deg': float(p.azimuth_deg),
                           'elevation_deg': float(p.elevation_deg)},
        }

    @classmethod
    def load(cls, path):
        """Read a vehicle mount file; :class:`VehicleFileError` if it does not parse or a
        field is invalid (the message names the file and the field).
        """
        path = pathlib.Path(path)
        try:
            data = yaml.load(path.read_text(encoding='utf-8'), Loader=SAFE_LOADER)
        except OSError as exc:
            raise VehicleFileError(f'{path}: cannot read: {exc.strerror}') from None
        except yaml.YAMLError as exc:
            raise VehicleFileError(f'{path}: not YAML: {exc}') from None
        return cls.from_dict(data, source=str(path))

    def save(self, path, header=''):
        text = ''.join(f'# {line}\n' for line in header.splitlines())
        pathlib.Path(path).write_text(text + yaml.safe_dump(self.to_dict(), sort_keys=False,
                                                            default_flow_style=None),
                                      encoding='utf-8')


def default_vehicle_path():
    """``share/vlc_common/config/vehicle.yaml``: the nominal vehicle (installed, else source)."""
    return str(config_path(PACKAGE, DEFAULT_FILE))


def resolve_vehicle_path(path):
    """An explicit path as given; '' means the nominal vehicle's file."""
    return os.path.expanduser(path) if path else default_vehicle_path()


def load_vehicle(path=''):
    """The :class:`VehicleMount` of ``path`` ('' = the nominal vehicle)."""
    return VehicleMount.load(resolve_vehicle_path(path))
