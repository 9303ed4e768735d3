"""A rig installation: the vehicle's and the line's truth, and what the receivers believe.

A real train does not know its camera, its mount or its lamps exactly: it has a
checkerboard calibration, a measured vehicle mount file and a surveyed lamp map, each
with the errors of the procedure that produced it. For a rig profile (``ideal``,
``realistic``, ``harsh``; values and sources in ``config/rig_profiles.yaml``) and a seed
this module draws (ROS-free, deterministic per seed):

* the **vehicle truth**: each camera's true lens (:class:`OpticsTruth`: K, plumb_bob
  distortion, the right camera's pose, the trigger skew), the true row time, the stereo
  camera's and the IMU's true mount on ``base_link`` (nominal + installation deviation),
  the IMU clock's offset from the camera's;
* the **line truth**: per lamp its true normal (tilted), diameter and brightness, and
  which lamps are dead; the true positions are the nominal map's (the as-built line);
* the **belief** handed to the receivers: a stereo calibration (the truth perturbed by
  the errors a field checkerboard calibration of the stated reprojection RMS leaves, in
  milliseconds per draw; an actual calibration from boards rendered through the true
  lenses, ~10 s, is the tooling command ``calibrate_installation``), the vehicle mount
  as measured (truth + measurement error) and the surveyed lamp map (true positions +
  survey error per axis, a few gross errors, the survey 1σ in ``position_sigma_m``).

:func:`draw_installation` returns an :class:`Installation`; :meth:`Installation.write`
puts ``belief/{left,right,vehicle,lamp_map}.yaml`` and ``truth/{truth,vehicle,lamp_map,
left,right}.yaml`` into a folder (command ``make_installation``). Each part draws from
its own stream ``numpy.random.default_rng([seed, tag, ...])`` (each lamp from one keyed
by its UID), so the IMU node and the camera node draw the same vehicle without drawing
the rest, and a lamp's draw does not depend on the map around it.

The ``ideal`` profile draws nothing: truth = belief = the nominal files and the ideal
rectified pair (the rig as it always was).
"""
import copy
from dataclasses import dataclass, field, replace
import functools
import math
import pathlib

import numpy as np
import yaml

from vlc_common.core.calibration import StereoCalibration, save_ros_stereo
from vlc_common.core.camera import CameraIntrinsics, StereoCameraModel, StereoRig, mount_angles
from vlc_common.core.config_files import SAFE_DUMPER, SAFE_LOADER, config_path
from vlc_common.core.lamp_map import Lamp, LampMap
from vlc_common.core.vehicle import CameraMount, ImuMount, VehicleMount
from vlc_stereo_camera.core.optics_truth import OpticsTruth, TrueCamera

PACKAGE = 'vlc_stereo_camera'
PROFILES_FILE = 'rig_profiles.yaml'
PROFILE_NAMES = ('ideal', 'realistic', 'harsh')

#: Stream tags of the draws (one independent generator per part).
_TAG_OPTICS, _TAG_CALIBRATION, _TAG_MOUNT, _TAG_CLOCK, _TAG_LAMP = (
    0x0B71C, 0xCA11B, 0x30047, 0xC10CC, 0x1A4B5)
#: Streams added later, apart so that the draws above stay what they were: the camera
#: roll (truth, then measurement) and the per-frame stamp jitter (blocks of frames).
_TAG_ROLL, _TAG_JITTER = 0x2011, 0x717E2
_JITTER_BLOCK = 1024

# Section → key → kind: 'number' (>= 0), 'pair' ([mean, sigma >= 0]), 'range' ([lo, hi],
# 0 < lo <= hi), 'fraction' (0..1).
_SCHEMA = {
    'lens': {'focal_sigma': 'number', 'aspect_sigma': 'number',
             'principal_point_sigma_px': 'number', 'k1': 'pair', 'k2': 'pair', 'k3': 'pair',
             'tangential_sigma': 'number', 'right_rotation_sigma_deg': 'number',
             'right_position_sigma_m': 'number', 'trigger_skew_s': 'range',
             'row_time_ppm': 'number', 'stamp_jitter_s': 'number'},
    'calibration': {'reprojection_rms_px': 'number', 'focal_sigma': 'number',
                    'principal_point_sigma_px': 'number', 'k1_sigma': 'number',
                    'k2_sigma': 'number', 'k3_sigma': 'number', 'tangential_sigma': 'number',
                    'rotation_sigma_deg': 'number', 'translation_sigma_m': 'number',
                    'principal_point_in_mount': 'fraction'},
    'mount': {'camera_position_sigma_m': 'number', 'camera_angle_sigma_deg': 'number',
              'camera_position_measurement_sigma_m': 'number',
              'camera_angle_measurement_sigma_deg': 'number',
              'imu_position_sigma_m': 'number', 'imu_boresight_sigma_deg': 'number',
              'imu_position_measurement_sigma_m': 'number',
              'imu_boresight_measurement_sigma_deg': 'number',
              'imu_clock_offset_sigma_s': 'number', 'imu_clock_drift_sigma_ppm': 'number'},
    'lamps': {'survey_sigma_plan_m': 'number', 'survey_sigma_height_m': 'number',
              'gross_error_fraction': 'fraction', 'gross_error_m': 'number',
              'normal_tilt_sigma_deg': 'number', 'diameter_sigma': 'number',
              'brightness_sigma': 'number', 'dead_fraction': 'fraction'},
    'sensor': {'prnu_rms': 'number', 'dsnu_rms_e': 'number', 'row_noise_e': 'number',
               'hot_pixel_fraction': 'fraction', 'psf_sigma_corner_px': 'number',
               'wall_reflection_fraction': 'fraction'},
}
#: Keys added after the first profiles: a profile file without them draws 0 (none).
_OPTIONAL = {('lens', 'stamp_jitter_s'): 0.0, ('mount', 'imu_clock_drift_sigma_ppm'): 0.0,
             ('calibration', 'principal_point_in_mount'): 0.0}
#: A lamp's brightness factor is clipped to this range (a dead lamp is 0, drawn apart).
BRIGHTNESS_RANGE = (0.2, 1.5)

#: The error sources of the error budget: name → (what it is, its (section, key)s; the
#: ``track`` source is the profile's car body). Every key of a profile belongs to exactly
#: one source, except the calibration's stated reprojection RMS (a statement, not an
#: error) and the mean lens distortion (the lens design: always drawn, always calibrated).
BUDGET_SOURCES = {
    'lens': ('lens spread, each camera and the pair (focal length, principal point, '
             'distortion, right camera pose), known from the calibration',
             [('lens', k) for k in ('focal_sigma', 'aspect_sigma', 'principal_point_sigma_px',
                                    'k1', 'k2', 'k3', 'tangential_sigma',
                                    'right_rotation_sigma_deg', 'right_position_sigma_m')]),
    'calibration': ('stereo calibration errors (intrinsics, distortion, extrinsics)',
                    [('calibration', k) for k in _SCHEMA['calibration']
                     if k != 'reprojection_rms_px']),
    'camera_mount': ('camera mount: installation and its measurement (position, angles, '
                     'roll)', [('mount', k) for k in _SCHEMA['mount']
                               if k.startswith('camera_')]),
    'imu_mount': ('IMU mount: lever arm and boresight, installation and measurement',
                  [('mount', k) for k in _SCHEMA['mount'] if k.startswith('imu_')
                   and 'clock' not in k]),
    'timing': ('timing: trigger skew, row time, frame stamp jitter, IMU clock offset '
               'and drift', [('lens', 'trigger_skew_s'), ('lens', 'row_time_ppm'),
                             ('lens', 'stamp_jitter_s'), ('mount', 'imu_clock_offset_sigma_s'),
                             ('mount', 'imu_clock_drift_sigma_ppm')]),
    'survey': ('lamp survey: 1σ per axis and gross errors',
               [('lamps', k) for k in ('survey_sigma_plan_m', 'survey_sigma_height_m',
                                       'gross_error_fraction', 'gross_error_m')]),
    'lamps': ('lamp hardware: normal tilt, diameter, brightness, dead lamps',
              [('lamps', k) for k in ('normal_tilt_sigma_deg', 'diameter_sigma',
                                      'brightness_sigma', 'dead_fraction')]),
    'track': ('car body on the track irregularity (instead of the eq. 21 vibration)', []),
    'sensor': ('sensor and scene: fixed pattern, row noise, hot pixels, corner blur, wall '
               'reflections', [('sensor', k) for k in _SCHEMA['sensor']]),
}


class ProfileError(ValueError):
    """An unusable rig profile: the message is ``<file>: <field>: <problem>``."""

    def __init__(self, source, field, problem):
        self.source, self.field, self.problem = str(source), str(field), str(problem)
        super().__init__(f'{self.source}: {self.field}: {self.problem}')


def default_profiles_path():
    """``share/vlc_stereo_camera/config/rig_profiles.yaml`` (installed, else source)."""
    return str(config_path(PACKAGE, PROFILES_FILE))


@dataclass(frozen=True)
class RigProfile:
    """One profile of ``rig_profiles.yaml``: ``sections`` maps section → key → value
    (empty for ``ideal``); ``car_body`` is None or {spectrum, scale}.
    """

    name: str
    sections: dict = field(default_factory=dict)
    car_body: dict = None
    source: str = ''

    @property
    def ideal(self):
        """True for a profile that draws nothing (the nominal rig)."""
        return not self.sections

    @property
    def lens(self):
        return self.sections.get('lens', {})

    @property
    def calibration(self):
        return self.sections.get('calibration', {})

    @property
    def mount(self):
        return self.sections.get('mount', {})

    @property
    def lamps(self):
        return self.sections.get('lamps', {})

    @property
    def sensor(self):
        return self.sections.get('sensor', {})


def _check_value(source, where, kind, value):
    def number(v):
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
            raise ProfileError(source, where, f'{v!r} is not a finite number')
        return float(v)
    if kind in ('number', 'fraction'):
        v = number(value)
        if v < 0.0 or (kind == 'fraction' and v > 1.0):
            raise ProfileError(source, where, f'{v} must be in '
                               + ('[0, 1]' if kind == 'fraction' else '[0, inf)'))
        return v
    if not isinstance(value, (list, tuple)) or len(value) != 2:
        form = 'mean, sigma' if kind == 'pair' else 'lo, hi'
        raise ProfileError(source, where, f'expected [{form}], got {value!r}')
    a, b = number(value[0]), number(value[1])
    if kind == 'pair' and b < 0.0:
        raise ProfileError(source, where, f'sigma {b} must be >= 0')
    if kind == 'range' and not (0.0 < a <= b or a == b == 0.0):
        raise ProfileError(source, where, f'[{a}, {b}] must satisfy 0 < lo <= hi (or be '
                           '[0, 0]: none)')
    return (a, b)


def _parse_profile(name, data, source):
    if data is None or data == {}:
        return RigProfile(name, {}, None, source)
    if not isinstance(data, dict):
        raise ProfileError(source, name, 'expected a mapping of sections')
    unknown = sorted(set(data) - set(_SCHEMA) - {'car_body'})
    if unknown:
        raise ProfileError(source, f'{name}.{unknown[0]}', 'unknown section (known: '
                           + ', '.join([*_SCHEMA, 'car_body']) + ')')
    sections = {}
    for section, keys in _SCHEMA.items():
        values = data.get(section)
        if not isinstance(values, dict):
            raise ProfileError(source, f'{name}.{section}', 'missing' if values is None
                               else 'expected a mapping')
        for key in values:
            if key not in keys:
                raise ProfileError(source, f'{name}.{section}.{key}', 'unknown key (known: '
                                   + ', '.join(keys) + ')')
        sections[section] = {}
        for key, kind in keys.items():
            if key not in values and (section, key) in _OPTIONAL:
                sections[section][key] = _OPTIONAL[section, key]
                continue
            if key not in values:
                raise ProfileError(source, f'{name}.{section}.{key}', 'missing')
            sections[section][key] = _check_value(source, f'{name}.{section}.{key}', kind,
                                                  values[key])
    car_body = data.get('car_body')
    if car_body is not None:
        from vlc_stereo_camera.core.track_irregularity import SPECTRA
        if (not isinstance(car_body, dict) or car_body.get('spectrum') not in SPECTRA
                or set(car_body) - {'spectrum', 'scale'}):
            raise ProfileError(source, f'{name}.car_body', 'expected null or {spectrum: '
                               + '|'.join(SPECTRA) + f', scale: number}}, got {car_body!r}')
        car_body = {'spectrum': car_body['spectrum'],
                    'scale': _check_value(source, f'{name}.car_body.scale', 'number',
                                          car_body.get('scale', 1.0))}
    return RigProfile(name, sections, car_body, source)


def load_profiles(path=''):
    """Every profile of a profiles file ('' = the shipped one) as {name: RigProfile}.

    Raises :class:`ProfileError` naming the file and the field when the file is missing,
    is not YAML, or a value is missing, unknown or out of range.
    """
    path = str(path) if path else default_profiles_path()
    try:
        text = pathlib.Path(path).read_text(encoding='utf-8')
    except OSError as exc:
        raise ProfileError(path, '(file)', f'cannot read: {exc.strerror}') from None
    # a node asks several times at start-up (each profile field): the same text is
    # parsed once, and each caller gets its own copy (a profile holds dicts)
    return copy.deepcopy(_parse_profiles(path, text))


@functools.lru_cache(maxsize=8)
def _parse_profiles(path, text):
    """:func:`load_profiles` of the file ``path`` whose content is ``text``."""
    try:
        data = yaml.load(text, Loader=SAFE_LOADER)
    except yaml.YAMLError as exc:
        raise ProfileError(path, '(file)', f'not valid YAML ({exc})') from None
    if not isinstance(data, dict) or not data:
        raise ProfileError(path, '(file)', 'expected a mapping of profile names')
    if 'ideal' not in data:
        raise ProfileError(path, 'ideal', 'missing (the ideal profile must be defined)')
    return {str(name): _parse_profile(str(name), body, path) for name, body in data.items()}


def load_profile(name, path=''):
    """The profile ``name`` of a profiles file; :class:`ProfileError` if unknown.

    ``<profile>/only-<source>`` is ``<profile>`` with every error source of
    :data:`BUDGET_SOURCES` but ``<source>`` switched off, ``<profile>/none`` with all of
    them off (the error budget; :func:`isolate_source`).
    """
    profiles = load_profiles(path)
    base, _, variant = str(name).partition('/')
    if base not in profiles:
        raise ProfileError(profiles['ideal'].source, 'rig_profile',
                           f'unknown profile {base!r} (known: {", ".join(profiles)})')
    if not variant:
        return profiles[base]
    keep = variant[len('only-'):] if variant.startswith('only-') else variant
    if not (variant == 'none' or (variant.startswith('only-') and keep in BUDGET_SOURCES)):
        raise ProfileError(profiles['ideal'].source, 'rig_profile',
                           f'unknown variant {variant!r} of {base!r} (known: none, '
                           + ', '.join(f'only-{s}' for s in BUDGET_SOURCES) + ')')
    if profiles[base].ideal:
        raise ProfileError(profiles['ideal'].source, 'rig_profile',
                           f'{base!r} draws nothing: it has no error sources to isolate')
    return isolate_source(profiles[base], None if variant == 'none' else keep)


def isolate_source(profile, keep):
    """``profile`` with every error source but ``keep`` (a :data:`BUDGET_SOURCES` name,
    or None: all) off: sigmas, fractions and the trigger skew 0, distortion means kept,
    the car body replaced by the eq. 21 vibration; named ``<name>/only-<keep>`` or
    ``<name>/none``. Each source draws from its own stream, so a source on alone draws
    the same values for a seed as in the whole profile.
    """
    kept = set(BUDGET_SOURCES[keep][1]) if keep else set()
    sections = copy.deepcopy(profile.sections)
    for section, keys in _SCHEMA.items():
        for key, kind in keys.items():
            if (section, key) in kept or (section, key) == ('calibration',
                                                            'reprojection_rms_px'):
                continue
            value = sections[section][key]
            sections[section][key] = ((value[0], 0.0) if kind == 'pair' else
                                      (0.0, 0.0) if kind == 'range' else 0.0)
    return RigProfile(f'{profile.name}/' + (f'only-{keep}' if keep else 'none'), sections,
                      profile.car_body if keep == 'track' else None, profile.source)


# ------------------------------------------------------------------ draws
_DESIGN = CameraIntrinsics()


@dataclass(frozen=True)
class NominalCamera:
    """The stereo camera as designed: image size (px), pinhole (px), baseline (m); by
    default the paper camera of :class:`~vlc_common.core.camera.CameraIntrinsics`.
    """

    width: int = _DESIGN.width
    height: int = _DESIGN.height
    fx: float = _DESIGN.fx
    fy: float = _DESIGN.fy
    cx: float = _DESIGN.cx
    cy: float = _DESIGN.cy
    baseline_m: float = StereoRig.baseline_m
    row_time_s: float = 30e-6

    def rig(self):
        return StereoRig(intrinsics=CameraIntrinsics(self.width, self.height, self.fx,
                                                     self.fy, self.cx, self.cy),
                         baseline_m=self.baseline_m)


def _rng(seed, tag, *more):
    return np.random.default_rng([int(seed), tag, *[int(m) for m in more]])


def draw_optics(profile, seed, nominal=NominalCamera()):
    """(OpticsTruth, row_time_s): the true stereo camera of the vehicle (``lens`` section).

    None and the nominal row time for the ideal profile.
    """
    if profile.ideal:
        return None, nominal.row_time_s
    p = profile.lens
    rng = _rng(seed, _TAG_OPTICS)

    def camera():
        fx = nominal.fx * (1.0 + p['focal_sigma'] * rng.standard_normal())
        fy = fx * nominal.fy / nominal.fx * (1.0 + p['aspect_sigma'] * rng.standard_normal())
        pp = p['principal_point_sigma_px'] * rng.standard_normal(2)
        k1, k2, k3 = (m + s * rng.standard_normal() for m, s in (p['k1'], p['k2'], p['k3']))
        p1, p2 = p['tangential_sigma'] * rng.standard_normal(2)
        return TrueCamera(fx=float(fx), fy=float(fy), cx=float(nominal.cx + pp[0]),
                          cy=float(nominal.cy + pp[1]),
                          distortion=tuple(float(v) for v in (k1, k2, p1, p2, k3)))
    left, right = camera(), camera()
    rotation = p['right_rotation_sigma_deg'] * rng.standard_normal(3)
    position = (np.array([nominal.baseline_m, 0.0, 0.0])
                + p['right_position_sigma_m'] * rng.standard_normal(3))
    lo, hi = p['trigger_skew_s']
    skew = float(np.exp(rng.uniform(np.log(lo), np.log(hi)))) if hi > 0.0 else (
        rng.uniform() * 0.0)       # none: the stream goes on as with a skew
    row_time = nominal.row_time_s * (1.0 + 1e-6 * p['row_time_ppm'] * rng.standard_normal())
    return OpticsTruth(left=left, right=right, right_rotation_deg=tuple(rotation.tolist()),
                       right_position_m=tuple(position.tolist()),
                       trigger_skew_s=skew), float(row_time)


def calibration_error(profile, rng):
    """One draw of the calibration's errors (belief − truth), a dict of arrays:
    ``focal`` (2, 2) relative (camera, fx/fy), ``principal_point_px`` (2, 2),
    ``distortion`` (2, 5) [k1, k2, p1, p2, k3], ``rotation_deg`` (3,),
    ``translation_m`` (3,).

    The focal error is common to both cameras (row 1 = row 0): a stereo calibration
    sees each board through both cameras, so the board's size fixes the ratio of the two
    focal lengths far better than either (a 0.15 % difference would put the rectified
    rows ~0.6 px and the disparity ~1 px apart at the image edge, a 10 % range error at
    12 m, which no calibration of 0.15 px RMS leaves); the scale common to both only
    scales the directions and the range by that fraction. The principal points and the
    extrinsics are made consistent by :func:`fitted_extrinsics`.
    """
    c = profile.calibration
    d_sigma = np.array([c['k1_sigma'], c['k2_sigma'], c['tangential_sigma'],
                        c['tangential_sigma'], c['k3_sigma']])
    focal = c['focal_sigma'] * rng.standard_normal((2, 2))
    focal[1] = focal[0]
    return {'focal': focal,
            'principal_point_px': c['principal_point_sigma_px'] * rng.standard_normal((2, 2)),
            'distortion': d_sigma * rng.standard_normal((2, 5)),
            'rotation_deg': c['rotation_sigma_deg'] * rng.standard_normal(3),
            'translation_m': c['translation_sigma_m'] * rng.standard_normal(3)}


#: The target views of the extrinsic fit in :func:`believed_optics`: an 8×5-corner
#: board whose square grows with the distance (50 mm at 0.75 m: the extent of a 15×10
#: board of 25 mm, every other corner; noise-free corners need no more) at these
#: distances (m),
#: from the calibration's 0.55–1 m out to the far end of the lamps' range, its centre at
#: these normalized directions of the left camera, tilted by ±20° and ±12°.
_BOARD_CORNERS, _BOARD_SQUARE_M = (8, 5), 0.05
_BOARD_DISTANCES_M = (0.6, 1.0, 3.0, 10.0)
_BOARD_DIRECTIONS = tuple((x, y) for x in (-0.4, 0.0, 0.4) for y in (-0.22, 0.0, 0.22))


def _board_views(truth, width, height):
    """(object points, left raw corners, right raw corners) of the board views of the
    extrinsic fit whose corners all lie inside both images of the true camera ``truth``.
    """
    from vlc_common.core.rotations import rot_x, rot_y
    nx, ny = _BOARD_CORNERS
    grid = np.zeros((nx * ny, 3))
    grid[:, :2] = np.mgrid[0:nx, 0:ny].T.reshape(-1, 2) * _BOARD_SQUARE_M
    grid[:, :2] -= grid[:, :2].mean(axis=0)
    left = truth.left.camera_model(width, height)
    right = truth.right.camera_model(width, height)
    R_lr, t_lr = truth.R_left_right, np.asarray(truth.right_position_m)
    objects, uv_left, uv_right = [], [], []
    k = 0
    for z in _BOARD_DISTANCES_M:
        for x, y in _BOARD_DIRECTIONS:
            k += 1
            R = rot_x(np.radians(12.0 * (-1) ** k)) @ rot_y(np.radians(20.0 * (-1) ** (k // 2)))
            board = (z / 0.75) * grid
            p_left = board @ R.T + np.array([x * z, y * z, z])
            uv_l = left.project(p_left)[0]
            uv_r = right.project((p_left - t_lr) @ R_lr)[0]
            inside = all(np.all((uv[:, 0] > 2.0) & (uv[:, 0] < width - 3.0) & (uv[:, 1] > 2.0)
                                & (uv[:, 1] < height - 3.0)) for uv in (uv_l, uv_r))
            if inside:
                objects.append(board.astype(np.float32))
                uv_left.append(uv_l.astype(np.float32))
                uv_right.append(uv_r.astype(np.float32))
    return objects, uv_left, uv_right


def fitted_extrinsics(truth, cameras, width, height):
    """(right_rotation_deg, right_position_m): the right camera's pose a stereo
    calibration finds when its intrinsics are ``cameras`` (two :class:`TrueCamera`, the
    believed lenses) and the images are the true camera ``truth``'s.

    A calibration estimates the extrinsics together with the intrinsics: board corners
    seen through both true lenses are explained best by a relative pose that absorbs
    the intrinsic errors (a principal point 1 px off is a 0.06° turn of that camera), so
    that the rectified rows and the disparity stay consistent to the reprojection RMS.
    Perturbing the true extrinsics independently of the intrinsics would instead leave
    rows 1–2 px apart and a disparity offset of ~1 px (a 3 % range error at 2 m), which
    no calibration of 0.15 px RMS leaves. ``cv2.stereoCalibrate`` with the intrinsics
    fixed, on the noise-free corners of the boards of :func:`_board_views`.
    """
    import cv2

    from vlc_common.core.rotations import matrix_to_quat_xyzw, quat_to_rotvec
    objects, uv_left, uv_right = _board_views(truth, width, height)
    if len(objects) < 3:
        raise ValueError('fitted_extrinsics: fewer than 3 board views inside both images')
    criteria = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-12)
    K1, K2 = cameras[0].K, cameras[1].K
    D1, D2 = np.array(cameras[0].distortion), np.array(cameras[1].distortion)
    _, _, _, _, _, R, T, _, _ = cv2.stereoCalibrate(
        objects, uv_left, uv_right, K1, D1, K2, D2, (int(width), int(height)),
        flags=cv2.CALIB_FIX_INTRINSIC, criteria=criteria)
    # x_right = R·x_left + T: the right frame's axes in the left frame are Rᵀ, its centre
    # −Rᵀ·T
    rotation = np.degrees(quat_to_rotvec(np.reshape(matrix_to_quat_xyzw(R.T), 4)))
    position = -R.T @ np.asarray(T, dtype=float).ravel()
    return tuple(float(v) for v in rotation), tuple(float(v) for v in position)


def believed_optics(truth, error, width=None, height=None):
    """The optics a calibration with ``error`` (:func:`calibration_error`) reports.

    The intrinsics are the truth's with the error; with an image size (``width``,
    ``height``) the extrinsics are those a calibration with these intrinsics fits
    (:func:`fitted_extrinsics`) plus the error's rotation and translation, else the
    truth's plus the error (inconsistent with the intrinsic errors; for tests of the
    draw only).
    """
    cams = []
    for i, cam in enumerate(truth.cameras):
        cams.append(TrueCamera(fx=float(cam.fx * (1.0 + error['focal'][i, 0])),
                               fy=float(cam.fy * (1.0 + error['focal'][i, 1])),
                               cx=float(cam.cx + error['principal_point_px'][i, 0]),
                               cy=float(cam.cy + error['principal_point_px'][i, 1]),
                               distortion=tuple(np.asarray(cam.distortion)
                                                + error['distortion'][i])))
    rotation, position = truth.right_rotation_deg, truth.right_position_m
    if width is not None and height is not None:
        rotation, position = fitted_extrinsics(truth, cams, width, height)
    return OpticsTruth(left=cams[0], right=cams[1],
                       right_rotation_deg=tuple(np.asarray(rotation) + error['rotation_deg']),
                       right_position_m=tuple(np.asarray(position) + error['translation_m']),
                       trigger_skew_s=truth.trigger_skew_s)


def draw_calibration(profile, seed, optics, nominal=NominalCamera(), camera_name='stereo'):
    """(StereoCalibration, error dict): the belief calibration of ``optics``.

    Ideal profile: the rig's ideal rectified pair (what the camera node always published).
    """
    if profile.ideal or optics is None:
        pair = StereoCameraModel.from_rig(nominal.rig())
        return StereoCalibration(pair.left, pair.right, camera_name=camera_name), {}
    error = calibration_error(profile, _rng(seed, _TAG_CALIBRATION))
    pair = believed_optics(optics, error, nominal.width, nominal.height).stereo_model(
        nominal.width, nominal.height)
    rms = profile.calibration['reprojection_rms_px']
    return StereoCalibration(pair.left, pair.right, camera_name=camera_name, rms_px=rms,
                             left_rms_px=rms, right_rms_px=rms), error


def _perturbed_mount(camera, imu, rng, pos_sigma, angle_sigma, imu_pos_sigma, imu_rpy_sigma):
    """A copy of (camera, imu) mounts with normal deviations drawn in a fixed order."""
    d_pos = pos_sigma * rng.standard_normal(3)
    d_ang = angle_sigma * rng.standard_normal(2)
    d_imu_pos = imu_pos_sigma * rng.standard_normal(3)
    d_imu_rpy = np.radians(imu_rpy_sigma) * rng.standard_normal(3)
    return (CameraMount(position_m=camera.position_m + d_pos,
                        placement_angle_deg=camera.placement_angle_deg + d_ang[0],
                        pitch_deg=camera.pitch_deg + d_ang[1], roll_deg=camera.roll_deg),
            ImuMount(position_m=imu.position_m + d_imu_pos, rpy_rad=imu.rpy_rad + d_imu_rpy))


def draw_vehicle(profile, seed, nominal):
    """(truth, belief, imu_clock_offset_s): the mount of the sensors on ``base_link``.

    truth = ``nominal`` (a VehicleMount) + installation deviation; belief (the mount file
    as measured) = truth + measurement error; the camera's roll about its optical axis
    draws with the same angle sigmas from a stream of its own; the photodiode is left
    nominal. The ideal profile returns the nominal mount for both and 0.
    """
    if profile.ideal:
        return nominal, nominal, 0.0
    m = profile.mount
    rng = _rng(seed, _TAG_MOUNT)
    cam, imu = _perturbed_mount(nominal.camera, nominal.imu, rng, m['camera_position_sigma_m'],
                                m['camera_angle_sigma_deg'], m['imu_position_sigma_m'],
                                m['imu_boresight_sigma_deg'])
    roll = _rng(seed, _TAG_ROLL).standard_normal(2)
    cam.roll_deg = float(cam.roll_deg + m['camera_angle_sigma_deg'] * roll[0])
    truth = VehicleMount(vehicle_id=nominal.vehicle_id, frame_id=nominal.frame_id, camera=cam,
                         imu=imu, photodiode=nominal.photodiode, source='(truth)')
    cam_b, imu_b = _perturbed_mount(cam, imu, rng, m['camera_position_measurement_sigma_m'],
                                    m['camera_angle_measurement_sigma_deg'],
                                    m['imu_position_measurement_sigma_m'],
                                    m['imu_boresight_measurement_sigma_deg'])
    cam_b.roll_deg = float(cam.roll_deg + m['camera_angle_measurement_sigma_deg'] * roll[1])
    belief = VehicleMount(vehicle_id=nominal.vehicle_id, frame_id=nominal.frame_id,
                          camera=cam_b, imu=imu_b, photodiode=nominal.photodiode,
                          source='(as measured)')
    return truth, belief, draw_imu_clock(profile, seed)[0]


def mount_through_calibration(belief, error, optics, share):
    """The measured mount ``belief`` (VehicleMount) as a camera-to-body calibration made
    *through* the calibrated camera finds it: ``share`` of the left camera's
    principal-point error (``error['principal_point_px'][0]``, belief − truth) turns the
    measured camera angles.

    Targets seen through a camera model whose principal point is δ px off are explained
    by a camera turned by δ/f (the whole image shifts by δ): the extrinsic fit takes that
    turn into the mount angles, so the believed camera + the measured mount still point
    every ray where it goes (to first order, exactly at the image centre). A mount
    measured independently of the camera (a total station on its housing) keeps both
    errors apart: ``share`` 0. The returned mount is a copy; ``belief`` unchanged when
    there is nothing to take (no calibration error, no true optics, share 0).
    """
    if not share or not error or optics is None:
        return belief
    from vlc_common.core.rotations import rot_x, rot_y
    dcx, dcy = (float(v) for v in np.asarray(error['principal_point_px'])[0])
    a = share * dcx / optics.left.fx
    b = share * dcy / optics.left.fy
    # believed optical-frame direction = R_c · true direction (x − a, y − b); the
    # extrinsic fit returns R_base_cam(believed) = R_base_cam(measured) · R_cᵀ
    R_c = rot_y(-a) @ rot_x(b)
    placement, pitch, roll = mount_angles(belief.camera.R_base_cam @ R_c.T)
    return replace(belief, camera=replace(belief.camera, placement_angle_deg=placement,
                                          pitch_deg=pitch, roll_deg=roll))


def draw_imu_clock(profile, seed):
    """(offset_s, drift_ppm): the IMU clock against the camera's, stamp_imu − stamp_cam
    = offset + drift·1e-6·t (t: seconds since the start); (0, 0) for the ideal profile.
    """
    if profile.ideal:
        return 0.0, 0.0
    m = profile.mount
    rng = _rng(seed, _TAG_CLOCK)
    offset = float(m['imu_clock_offset_sigma_s'] * rng.standard_normal())
    return offset, float(m['imu_clock_drift_sigma_ppm'] * rng.standard_normal())


def frame_stamp_jitter_s(profile, seed, frame_index):
    """The stamp error of camera frame ``frame_index`` (s): a driver that stamps a frame
    on its arrival adds a transfer delay that varies from frame to frame; its mean is
    part of the IMU–camera offset, its spread is this zero-mean normal draw of
    ``lens.stamp_jitter_s`` (0 for the ideal profile). Drawn in blocks of frames.
    """
    sigma = 0.0 if profile.ideal else profile.lens['stamp_jitter_s']
    if not sigma:
        return 0.0
    block, k = divmod(int(frame_index), _JITTER_BLOCK)
    return float(sigma * _jitter_block(int(seed), block)[k])


@functools.lru_cache(maxsize=4)
def _jitter_block(seed, block):
    return _rng(seed, _TAG_JITTER, block).standard_normal(_JITTER_BLOCK)


@dataclass
class LampDraw:
    """One lamp's draw: true normal, diameter (m), brightness factor (0 = dead), survey
    error (3,) m in map axes (including a gross error), ``gross``.
    """

    uid: int
    normal: np.ndarray
    diameter_m: float
    brightness: float
    survey_error_m: np.ndarray
    gross: bool
    dead: bool


def _wall_axes(normal):
    """Two unit vectors in the disc plane: along (≈ +x) and across (≈ up)."""
    e1 = np.array([1.0, 0.0, 0.0]) - normal[0] * normal
    if np.linalg.norm(e1) < 1e-6:
        e1 = np.array([0.0, 0.0, 1.0]) - normal[2] * normal
    e1 /= np.linalg.norm(e1)
    return e1, np.cross(normal, e1)


def draw_lamp(profile, seed, lamp):
    """The :class:`LampDraw` of ``lamp`` (a nominal Lamp), from its own stream."""
    p = profile.lamps
    rng = _rng(seed, _TAG_LAMP, lamp.uid)
    e1, e2 = _wall_axes(lamp.normal)
    tilt = np.radians(p['normal_tilt_sigma_deg']) * rng.standard_normal(2)
    normal = lamp.normal + tilt[0] * e1 + tilt[1] * e2
    normal /= np.linalg.norm(normal)
    diameter = lamp.diameter_m * (1.0 + p['diameter_sigma'] * rng.standard_normal())
    brightness = float(np.clip(1.0 + p['brightness_sigma'] * rng.standard_normal(),
                               *BRIGHTNESS_RANGE))
    sigma = np.array([p['survey_sigma_plan_m'], p['survey_sigma_plan_m'],
                      p['survey_sigma_height_m']])
    error = sigma * rng.standard_normal(3)
    gross = bool(rng.uniform() < p['gross_error_fraction'])
    angle = rng.uniform(0.0, 2.0 * np.pi)
    if gross:
        error = error + p['gross_error_m'] * (np.cos(angle) * e1 + np.sin(angle) * e2)
    dead = bool(rng.uniform() < p['dead_fraction'])
    return LampDraw(uid=int(lamp.uid), normal=normal, diameter_m=float(diameter),
                    brightness=0.0 if dead else brightness, survey_error_m=error,
                    gross=gross, dead=dead)


def draw_line(profile, seed, lamp_map):
    """(truth LampMap, surveyed LampMap, {uid: LampDraw}) of the nominal ``lamp_map``.

    The true lamps sit at the nominal positions with their drawn normals and diameters;
    the surveyed map has the nominal normals and diameters, positions + survey error and
    ``position_sigma_m`` = the profile's survey 1σ. Ideal: the map itself twice, {}.
    """
    if profile.ideal:
        return lamp_map, lamp_map, {}
    p = profile.lamps
    sigma = [p['survey_sigma_plan_m'], p['survey_sigma_plan_m'], p['survey_sigma_height_m']]
    draws, truth, survey = {}, [], []
    for lamp in lamp_map.lamps:
        d = draws[lamp.uid] = draw_lamp(profile, seed, lamp)
        common = {'uid': lamp.uid, 'line_id': lamp.line_id, 'lamp_id': lamp.lamp_id,
                  'chainage_m': lamp.chainage_m}
        truth.append(Lamp(position_m=lamp.position_m, normal=d.normal,
                          diameter_m=d.diameter_m, **common))
        survey.append(Lamp(position_m=lamp.position_m + d.survey_error_m, normal=lamp.normal,
                           diameter_m=lamp.diameter_m, position_sigma_m=sigma, **common))
    return (LampMap(truth, lamp_map.frame_id, lamp_map.alignment),
            LampMap(survey, lamp_map.frame_id, lamp_map.alignment), draws)


# ------------------------------------------------------------------ the installation
@dataclass
class Installation:
    """A drawn installation (see the module docstring); ``lamp_*`` None when drawn
    without a lamp map.
    """

    profile: RigProfile
    seed: int
    nominal: NominalCamera
    optics: OpticsTruth
    row_time_s: float
    vehicle_truth: VehicleMount
    vehicle_belief: VehicleMount
    imu_clock_offset_s: float
    calibration: StereoCalibration
    calibration_error: dict
    lamp_map_truth: LampMap = None
    lamp_map_belief: LampMap = None
    lamp_draws: dict = field(default_factory=dict)
    imu_clock_drift_ppm: float = 0.0

    def frame_stamp_jitter_s(self, frame_index):
        """The stamp error of camera frame ``frame_index``, s (:func:`frame_stamp_jitter_s`)."""
        return frame_stamp_jitter_s(self.profile, self.seed, frame_index)

    @property
    def lamp_brightness(self):
        """((uid, factor), ...) of every lamp whose brightness is not 1 (0 = dead)."""
        return tuple((uid, d.brightness) for uid, d in sorted(self.lamp_draws.items())
                     if d.brightness != 1.0)

    def renderer_fields(self):
        """RendererConfig keyword arguments of the truth (empty for the ideal profile)."""
        if self.profile.ideal:
            return {}
        from vlc_stereo_camera.core.sensor_noise import FixedPatternConfig
        from vlc_stereo_camera.core.stray_light import StrayLightConfig
        s = self.profile.sensor
        return {'optics_truth': self.optics, 'row_time_s': self.row_time_s,
                'psf_sigma_corner_px': s['psf_sigma_corner_px'],
                'fixed_pattern': FixedPatternConfig(prnu_rms=s['prnu_rms'],
                                                    dsnu_rms_e=s['dsnu_rms_e'],
                                                    row_noise_e=s['row_noise_e'],
                                                    hot_pixel_fraction=s['hot_pixel_fraction']),
                'stray_light': StrayLightConfig(reflection_fraction=s['wall_reflection_fraction']),
                'noise_table_size': 1 << 22,
                'lamp_brightness': self.lamp_brightness}

    def truth_dict(self):
        """Every drawn value, for the evaluation (YAML-safe)."""
        def floats(v):
            return [float(x) for x in np.ravel(v)]
        out = {'profile': self.profile.name, 'seed': int(self.seed),
               'profiles_file': self.profile.source,
               'nominal_camera': {k: getattr(self.nominal, k) + 0 for k in (
                   'width', 'height', 'fx', 'fy', 'cx', 'cy', 'baseline_m', 'row_time_s')},
               'row_time_s': float(self.row_time_s),
               'imu_clock_offset_s': float(self.imu_clock_offset_s),
               'imu_clock_drift_ppm': float(self.imu_clock_drift_ppm),
               'frame_stamp_jitter_sigma_s': (0.0 if self.profile.ideal
                                              else float(self.profile.lens['stamp_jitter_s'])),
               'vehicle_truth': self.vehicle_truth.to_dict(),
               'vehicle_belief': self.vehicle_belief.to_dict(),
               'car_body': self.profile.car_body}
        if self.optics is not None:
            o = self.optics
            out['optics'] = {
                side: {'fx': cam.fx, 'fy': cam.fy, 'cx': cam.cx, 'cy': cam.cy,
                       'distortion': floats(cam.distortion)}
                for side, cam in (('left', o.left), ('right', o.right))}
            out['optics'].update({'right_rotation_deg': floats(o.right_rotation_deg),
                                  'right_position_m': floats(o.right_position_m),
                                  'trigger_skew_s': float(o.trigger_skew_s)})
        if self.calibration_error:
            out['calibration_error'] = {k: np.asarray(v).tolist()
                                        for k, v in self.calibration_error.items()}
        out['calibration'] = {'stated_rms_px': float(self.calibration.rms_px)
                              if math.isfinite(self.calibration.rms_px) else None,
                              'baseline_m': float(self.calibration.baseline_m)}
        if self.lamp_draws:
            out['lamps'] = [{'uid': d.uid, 'normal': floats(d.normal),
                             'diameter_m': d.diameter_m, 'brightness': d.brightness,
                             'survey_error_m': floats(d.survey_error_m), 'gross': d.gross,
                             'dead': d.dead} for _, d in sorted(self.lamp_draws.items())]
            out['dead_lamps'] = [d.uid for _, d in sorted(self.lamp_draws.items()) if d.dead]
            out['gross_survey_errors'] = [d.uid for _, d in sorted(self.lamp_draws.items())
                                          if d.gross]
        return out

    def write(self, out_dir):
        """Write ``belief/`` (what the receivers get) and ``truth/`` (the evaluation's
        only) into ``out_dir``; returns {name: path}.
        """
        out = pathlib.Path(out_dir)
        belief, truth = out / 'belief', out / 'truth'
        belief.mkdir(parents=True, exist_ok=True)
        truth.mkdir(parents=True, exist_ok=True)
        tag = f'rig profile {self.profile.name}, seed {self.seed}'
        paths = {'belief/left.yaml': belief / 'left.yaml',
                 'belief/right.yaml': belief / 'right.yaml',
                 'belief/vehicle.yaml': belief / 'vehicle.yaml',
                 'truth/truth.yaml': truth / 'truth.yaml',
                 'truth/vehicle.yaml': truth / 'vehicle.yaml',
                 'truth/left.yaml': truth / 'left.yaml',
                 'truth/right.yaml': truth / 'right.yaml'}
        save_ros_stereo(self.calibration, paths['belief/left.yaml'], paths['belief/right.yaml'])
        self.vehicle_belief.save(paths['belief/vehicle.yaml'],
                                 f'Vehicle mount as measured ({tag}).')
        self.vehicle_truth.save(paths['truth/vehicle.yaml'],
                                f'TRUE vehicle mount ({tag}): for the evaluation only.')
        if self.optics is not None:
            pair = self.optics.stereo_model(self.nominal.width, self.nominal.height)
        else:
            pair = StereoCameraModel.from_rig(self.nominal.rig())
        save_ros_stereo(StereoCalibration(pair.left, pair.right,
                                          camera_name=self.calibration.camera_name),
                        paths['truth/left.yaml'], paths['truth/right.yaml'])
        if self.lamp_map_belief is not None:
            paths['belief/lamp_map.yaml'] = belief / 'lamp_map.yaml'
            paths['truth/lamp_map.yaml'] = truth / 'lamp_map.yaml'
            self.lamp_map_belief.save(paths['belief/lamp_map.yaml'],
                                      f'Surveyed lamp map ({tag}): positions with survey '
                                      'error,\nposition_sigma_m the survey 1 sigma per axis.')
            self.lamp_map_truth.save(paths['truth/lamp_map.yaml'],
                                     f'TRUE lamp map ({tag}): for the evaluation only.')
        with open(paths['truth/truth.yaml'], 'w', encoding='utf-8') as stream:
            stream.write(f'# Every drawn value of the installation ({tag}); for the '
                         'evaluation only:\n# no receiver may read this folder.\n')
            yaml.dump(self.truth_dict(), stream, Dumper=SAFE_DUMPER, sort_keys=False,
                      default_flow_style=None, width=100)
        return {k: str(v) for k, v in paths.items()}


def draw_installation(profile, seed, vehicle, lamp_map=None, nominal=NominalCamera()):
    """Draw the :class:`Installation` of ``profile`` (a RigProfile or a name of the
    shipped file) and ``seed`` on the nominal ``vehicle`` (VehicleMount) and, when given,
    the nominal ``lamp_map``.
    """
    if isinstance(profile, str):
        profile = load_profile(profile)
    optics, row_time = draw_optics(profile, seed, nominal)
    truth, belief, _ = draw_vehicle(profile, seed, vehicle)
    offset, drift = draw_imu_clock(profile, seed)
    calibration, error = draw_calibration(profile, seed, optics, nominal,
                                          camera_name=vehicle.vehicle_id or 'stereo')
    belief = mount_through_calibration(belief, error, optics, profile.calibration.get(
        'principal_point_in_mount', 0.0))
    inst = Installation(profile=profile, seed=int(seed), nominal=nominal, optics=optics,
                        row_time_s=row_time, vehicle_truth=truth, vehicle_belief=belief,
                        imu_clock_offset_s=offset, calibration=calibration,
                        calibration_error=error, imu_clock_drift_ppm=drift)
    if lamp_map is not None:
        inst.lamp_map_truth, inst.lamp_map_belief, inst.lamp_draws = draw_line(
            profile, seed, lamp_map)
    return inst
