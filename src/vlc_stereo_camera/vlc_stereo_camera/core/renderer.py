"""Synthetic rolling-shutter stereo renderer of the lit tunnel (ROS-free).

Usage (tests, benchmarks, integration tests of the receiver packages)::

    from vlc_common.core.lamp_map import LampMap, resolve_lamp_map_path
    from vlc_stereo_camera.core.renderer import RendererConfig, StereoRenderer
    from vlc_stereo_camera.core.trajectory import MotionProfile, Trajectory, Vibration

    lamps = LampMap.load(resolve_lamp_map_path(''))
    trajectory = Trajectory(MotionProfile('stationary', start_chainage_m=18.0),
                            Vibration(seed=1))
    renderer = StereoRenderer(RendererConfig(), lamps, trajectory, seed=1)
    frame = renderer.render(0)        # frame k starts (row 0) at t0 = k / fps
    frame.left, frame.right           # (720, 1280) uint8 images (mono8)
    frame.t0_s, frame.stamp_s         # seconds since the epoch / absolute (epoch + t0)
    for lamp in frame.truth:          # LampTruth per lamp whose spot is in an image
        lamp.uid, lamp.uv_left, lamp.uv_right, lamp.depth_m, lamp.along_track_m,
        lamp.rows_left, lamp.t_centre_s

What is rendered, per frame and camera (see docs/arch/vlc_stereo_camera.md):

* Lamps are luminous discs in the wall plane (``LampMap``; diameter from the map or
  ``lamp_diameter_m``). Only regions of interest (ROIs) around lamps are computed; the
  rest of the frame is a pre-rendered noisy background (``sensor_noise``).
* Rolling shutter: row r is exposed over [t0 + r·row_time_s, t0 + r·row_time_s +
  exposure_s]; left and right rows at the same instants. Each ROI row is rendered with
  the train pose at its own exposure instants, split into sub-steps when the lamp's
  image moves more than ``blur_step_px`` during the exposure (motion blur).
* Disc coverage is exact under perspective: for every pose the disc's image is the
  conic Q = H⁻ᵀ·diag(1, 1, −ρ²)·H⁻¹, with H = K·[e1 e2 c] the homography from disc
  coordinates to pixels; each pixel row is cut into ``subrows`` lines, on which the
  conic's chord [u1, u2] is solved exactly and intersected with each pixel's [u − ½,
  u + ½] (analytically anti-aliased along u, supersampled along v). This gives the true
  ellipse and the perspective eccentricity between the ellipse centre and the projected
  disc centre.
* Optics: coverage × "on" electrons (``OpticsConfig``: luminance, cos⁴ vignetting),
  blurred by the PSF — a Gaussian core (``psf_sigma_px``) plus a faint wide halo
  (``halo_fraction`` of the light in a Gaussian of ``halo_sigma_px``).
* Rolling shutter: each row of that blurred image is then multiplied by the exact mean
  of the lamp's chip waveform over the row's exposure window (``LampWaveform.mean_over``;
  times since the epoch, never absolute). The modulation comes after the blur because
  the optics blur the light at every instant and the row integrates it over its own
  exposure: the halo's rows carry their own chips and stripes are not smeared.
* Sensor: shot/dark/read noise, full-well saturation, 8-bit ADC.
* Each lamp's clock: packet phase uniform over one packet and chip-rate error uniform
  in ±``lamp_clock_ppm``, drawn from (seed, UID), so a lamp keeps its clock whichever
  frames are rendered.

Ground truth (``LampTruth``): the projection of the disc centre at the exposure
mid-time of the (continuous) row where that projection lies, i.e. the fixed point
v* = v(t0 + v*·row_time_s + exposure_s/2), solved by iteration (a contraction: the
image moves far less than a row per row time). Left and right share that instant, so
v_left = v_right and u_left − u_right = fx·b/depth exactly (rectified stereo).

Determinism: the images depend only on (config, lamp map, trajectory, seed, frame
index / noise key).

A truthful camera (opt-in ``RendererConfig`` fields, all off by default, when the
rendering above is unchanged bit for bit; docs/arch/vlc_stereo_camera.md, "A truthful
camera and sensor"):

* ``optics_truth`` (:class:`~vlc_stereo_camera.core.optics_truth.OpticsTruth`): raw
  images through each camera's true K and lens distortion, the right camera at its true
  pose and exposed ``trigger_skew_s`` late. A disc is rendered exactly (the conic above)
  in the camera's ideal pinhole image, each ideal row at the instants of the sensor row it
  lands on, then resampled into the sensor through static undistortion maps, each sensor
  pixel corrected to its own row's instant (``_render_raw``); the lamp modulation is
  applied per sensor row. The truth is then the raw projection of the disc centre, per
  camera at its own sensor row's exposure mid-time.
* ``psf_sigma_corner_px``: the core PSF widening toward the corners.
* ``fixed_pattern`` (PRNU, DSNU, hot pixels, row noise) and ``noise_table_size`` (ROI
  noise from a pre-drawn table), applied to the background bank and the ROIs alike.
* ``stray_light``: each lamp's reflection on the wall, carrying its modulation;
  ``distractors``: steady or flickering lights that are not lamps (``Frame.distractors``
  says where they show).
"""
from dataclasses import dataclass, field

import cv2
import numpy as np

from vlc_common.core.camera import CameraIntrinsics, StereoCameraModel, StereoRig
from vlc_common.core.protocol import PACKET_CHIPS
from vlc_common.core.rotations import rpy_to_matrix
from vlc_stereo_camera.core import precompute_cache, sensor_noise
from vlc_stereo_camera.core.optics_truth import OpticsTruth, lens_map
from vlc_stereo_camera.core.sensor_noise import (
    FixedPattern,
    FixedPatternConfig,
    NoiseTable,
    OpticsConfig,
    SensorConfig,
    SensorModel,
)
from vlc_stereo_camera.core.stray_light import FlickerWaveform, StrayLightConfig
from vlc_stereo_camera.core.transmitter import LampWaveform

_RIM_POINTS = 32
_FIXED_POINT_ITERATIONS = 30
# Pose table step: linear interpolation error ≤ step²/8 · max|q̈| stays below 1e-6 m and
# 1e-7 rad for the eq. 21 vibration spectrum up to 200 km/h (highest term ~30 Hz).
_POSE_TABLE_STEP_S = 1e-3
# A lamp pixel counts as covered in the raw image above this remapped coverage fraction.
_RAW_COVERED = 1e-3
_RAW_SUBSAMPLES = 3
# Raw ROIs: the PSF margin less _RAW_INNER_PX sensor pixels is not resampled (no light
# before the PSF); the ideal image extends _RAW_MARGIN_PX beyond what the resampled pixels
# see, for their shift to their own row's instant (a few px at 120 km/h).
_RAW_INNER_PX = 4
_RAW_MARGIN_PX = 6
# Wall-reflection patches are evaluated on a coarse grid, σ/3 apart along the patch's
# narrower image axis (2 to 8 px), and interpolated bilinearly: the error of a Gaussian so
# interpolated is at most step²/(8σ²) ≈ 1.4 % of its peak (a fraction of an e⁻).
_PATCH_SAMPLES_PER_SIGMA = 3.0
_PATCH_MIN_STEP = 2
_PATCH_MAX_STEP = 8


@dataclass
class RendererConfig:
    """Everything the renderer needs besides the lamp map, trajectory and seed.

    Units: metres, seconds, degrees, pixels, electrons (e⁻). Defaults are the paper's rig.
    """

    intrinsics: CameraIntrinsics = field(default_factory=CameraIntrinsics)
    # Mount defaults are the foundation's StereoRig ones (one source of truth).
    baseline_m: float = StereoRig.baseline_m
    mount_xyz_m: tuple = StereoRig.mount_xyz_m
    placement_angle_deg: float = StereoRig.placement_angle_deg
    pitch_deg: float = StereoRig.pitch_deg
    roll_deg: float = StereoRig.roll_deg
    fps: float = 30.0
    row_time_s: float = 30e-6
    exposure_s: float = 50e-6
    epoch_s: float = 1704067200.0
    chip_rate_hz: float = 10_000.0
    off_level: float = 0.05
    lamp_clock_ppm: float = 100.0
    lamp_diameter_m: float = 0.0          # 0: each lamp's diameter_m from the lamp map
    optics: OpticsConfig = field(default_factory=OpticsConfig)
    sensor: SensorConfig = field(default_factory=SensorConfig)
    psf_sigma_px: float = 0.7
    halo_sigma_px: float = 6.0
    halo_fraction: float = 0.02
    vignetting: bool = True
    # Test switches: steady "on" lamps (no stripes), no sensor noise, no PSF.
    lamp_modulation: bool = True
    sensor_noise: bool = True
    optics_psf: bool = True
    subrows: int = 4
    blur_step_px: float = 0.25
    max_blur_substeps: int = 8
    lamp_search_ahead_m: float = 40.0
    lamp_search_behind_m: float = 3.0
    # A truthful camera and sensor; all off by default (the ideal rectified pair above,
    # bit for bit). See docs/arch/vlc_stereo_camera.md, "A truthful camera".
    optics_truth: OpticsTruth = None          # raw, distorted, skewed images
    psf_sigma_corner_px: float = 0.0          # core PSF σ at the sensor corner; 0: constant
    fixed_pattern: FixedPatternConfig = None  # PRNU, DSNU, hot pixels, row noise
    stray_light: StrayLightConfig = None      # each lamp's reflection on the wall
    distractors: tuple = ()                   # Distractor lights that are not lamps
    noise_table_size: int = 0                 # > 0: ROI noise from a pre-drawn table
    # Per-lamp brightness of the true line: ((uid, factor), ...), factor × the lamp's
    # luminous flux; 0 = a dead lamp (not rendered, no truth record). () = every lamp 1.
    lamp_brightness: tuple = ()

    def __post_init__(self):
        for ok, message in [
            (self.fps > 0.0, f'fps must be > 0 (got {self.fps})'),
            (self.row_time_s > 0.0, f'row_time_s must be > 0 (got {self.row_time_s})'),
            (self.exposure_s > 0.0, f'exposure_s must be > 0 (got {self.exposure_s})')]:
            if not ok:
                raise ValueError(message)
        checks = [
            (self.intrinsics.height * self.row_time_s <= 1.0 / self.fps + 1e-12,
             f'rolling-shutter readout {self.intrinsics.height} rows x {self.row_time_s} s '
             f'does not fit in one frame period 1/{self.fps} s'),
            (self.exposure_s <= 1.0 / self.fps,
             f'exposure_s {self.exposure_s} exceeds the frame period 1/{self.fps} s'),
            (2000.0 <= self.chip_rate_hz <= 40000.0,
             f'chip_rate_hz must be within 2000..40000 (got {self.chip_rate_hz})'),
            (0.0 <= self.off_level < 1.0, f'off_level must be in [0, 1) (got {self.off_level})'),
            (0.0 <= self.lamp_clock_ppm <= 20000.0,
             f'lamp_clock_ppm must be in [0, 20000] (got {self.lamp_clock_ppm})'),
            (self.lamp_diameter_m >= 0.0, 'lamp_diameter_m must be >= 0 (0 = from the map)'),
            (self.psf_sigma_px >= 0.0 and self.halo_sigma_px >= 0.0,
             'psf_sigma_px and halo_sigma_px must be >= 0'),
            (0.0 <= self.halo_fraction < 1.0, 'halo_fraction must be in [0, 1)'),
            (self.subrows >= 1 and self.max_blur_substeps >= 1 and self.blur_step_px > 0.0,
             'subrows and max_blur_substeps must be >= 1, blur_step_px > 0'),
            (self.psf_sigma_corner_px >= 0.0, 'psf_sigma_corner_px must be >= 0 (0 = constant)'),
            (self.noise_table_size >= 0, 'noise_table_size must be >= 0 (0 = fresh draws)'),
            (self.optics_truth is None or isinstance(self.optics_truth, OpticsTruth),
             'optics_truth must be an OpticsTruth or None'),
            (all(f >= 0.0 and np.isfinite(f) for _, f in self.lamp_brightness),
             'lamp_brightness factors must be finite and >= 0'),
        ]
        for ok, message in checks:
            if not ok:
                raise ValueError(message)

    @property
    def frame_period_s(self):
        return 1.0 / self.fps

    def rig(self):
        return StereoRig(intrinsics=self.intrinsics, baseline_m=self.baseline_m,
                         mount_xyz_m=tuple(self.mount_xyz_m),
                         placement_angle_deg=self.placement_angle_deg,
                         pitch_deg=self.pitch_deg, roll_deg=self.roll_deg)


@dataclass
class LampTruth:
    """Ground truth of one lamp in one stereo frame.

    ``uv_left``/``uv_right`` (2,) px: projection of the disc centre at ``t_centre_s``
    (seconds since the epoch), the exposure mid-time of the row v_left (fixed point, see
    the module docstring). ``depth_m``: left optical z of the disc centre then;
    ``range_m``: distance from the left optical centre; ``along_track_m``: lamp chainage
    minus base_link's chainage (its foot point on the alignment; map x on a straight) at
    ``t_centre_s``; ``viewing_angle_deg``: angle between
    the line of sight and the disc normal. ``rows_left``/``rows_right``: (first, last)
    image rows where the disc covers pixels (before the PSF), None if none.
    ``in_left``/``in_right``: the projected centre lies inside that image.

    With ``RendererConfig.optics_truth`` the images are raw: ``uv_left``/``uv_right`` are
    the disc centre projected through each camera's true lens (distortion, K, the right
    camera's true pose), each at the exposure mid-time of its own sensor row (fixed point
    per camera; the right camera's rows run ``trigger_skew_s`` late): ``t_centre_s`` is
    the left one's, ``t_centre_right_s`` the right one's; rows differ, and the disparity
    is no longer fx·b/depth. ``depth_m``, ``range_m``, ``along_track_m`` and
    ``viewing_angle_deg`` stay the left camera's at ``t_centre_s``.
    """

    uid: int
    uv_left: np.ndarray
    uv_right: np.ndarray
    depth_m: float
    range_m: float
    along_track_m: float
    viewing_angle_deg: float
    t_centre_s: float
    rows_left: tuple
    rows_right: tuple
    in_left: bool
    in_right: bool
    t_centre_right_s: float = None


@dataclass
class Frame:
    """One stereo exposure. Images (H, W) uint8; times in seconds.

    ``base_*``: ground truth of base_link at ``t0_s``: position (3,) m and orientation
    (x, y, z, w) in map, linear velocity (3,) m/s and angular velocity (3,) rad/s in
    base_link axes.
    """

    index: int
    t0_s: float
    stamp_s: float
    left: np.ndarray
    right: np.ndarray
    truth: list
    base_position_m: np.ndarray
    base_quat_xyzw: np.ndarray
    base_velocity_body_mps: np.ndarray
    base_angular_velocity_body_rps: np.ndarray
    distractors: list = field(default_factory=list)


@dataclass
class DistractorTruth:
    """Where a distractor light (``RendererConfig.distractors``) shows in a frame: its
    disc centre projected as a lamp's truth is (``LampTruth``), px; ``index`` into the
    configured tuple.
    """

    index: int
    name: str
    uv_left: np.ndarray
    uv_right: np.ndarray
    in_left: bool
    in_right: bool


@dataclass
class _Emitter:
    """A luminous disc that is not a lamp of the map (a distractor)."""

    position_m: np.ndarray
    normal: np.ndarray
    diameter_m: float
    uid: int = -1
    track_chainage_m: float = float('nan')


class _LampGeometry:
    """Disc frame of one lamp: centre, in-plane axes e1 (along track), e2, radius."""

    def __init__(self, lamp, diameter_m):
        self.lamp = lamp
        self.centre = lamp.position_m
        n = lamp.normal
        e1 = np.array([1.0, 0.0, 0.0]) - n[0] * n
        if np.linalg.norm(e1) < 1e-6:
            e1 = np.array([0.0, 0.0, 1.0]) - n[2] * n
        self.e1 = e1 / np.linalg.norm(e1)
        self.e2 = np.cross(n, self.e1)
        self.radius_m = 0.5 * diameter_m
        self.area_m2 = np.pi * self.radius_m ** 2
        ang = np.linspace(0.0, 2.0 * np.pi, _RIM_POINTS, endpoint=False)
        self.rim = (self.centre + self.radius_m * (np.outer(np.cos(ang), self.e1)
                                                   + np.outer(np.sin(ang), self.e2)))


class _PoseTable:
    """The trajectory sampled on a uniform time grid, linearly interpolated.

    One ``Trajectory.sample`` call per frame instead of one per query: the renderer asks
    for poses at hundreds of row instants and fixed-point iterations.
    """

    def __init__(self, trajectory, t_start_s, t_end_s, step_s=_POSE_TABLE_STEP_S,
                 closed_form=False):
        n = max(2, int(np.ceil((t_end_s - t_start_s) / step_s)) + 1)
        self.t_start_s, self.step_s = t_start_s, step_s
        s = trajectory.sample(t_start_s + step_s * np.arange(n))
        self.q = np.column_stack([s.position_m, s.rpy_rad])
        self.closed_form = closed_form

    def at(self, t_s):
        """Position (N, 3) and R_map_base (N, 3, 3) at times ``t_s`` (N,).

        ``closed_form``: the same matrix written out (a third of the cost of the
        product Rz·Ry·Rx, rounded differently in the last bit), for the opt-in models,
        which query poses three times as often; off, the default rendering is unchanged.
        """
        x = (np.asarray(t_s, dtype=float).ravel() - self.t_start_s) / self.step_s
        i = np.clip(np.floor(x).astype(np.int64), 0, len(self.q) - 2)
        w = (x - i)[:, None]
        q = self.q[i] * (1.0 - w) + self.q[i + 1] * w
        if not self.closed_form:
            return q[:, :3], rpy_to_matrix(q[:, 3], q[:, 4], q[:, 5])
        cr, sr = np.cos(q[:, 3]), np.sin(q[:, 3])
        cp, sp = np.cos(q[:, 4]), np.sin(q[:, 4])
        cy, sy = np.cos(q[:, 5]), np.sin(q[:, 5])
        R = np.empty((len(q), 3, 3))
        R[:, 0, 0], R[:, 0, 1], R[:, 0, 2] = cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr
        R[:, 1, 0], R[:, 1, 1], R[:, 1, 2] = sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr
        R[:, 2, 0], R[:, 2, 1], R[:, 2, 2] = -sp, cp * sr, cp * cr
        return q[:, :3], R


def _disc_in_camera(g, centres, R_mc):
    """The disc's axes e1, e2 and its centre relative to the camera, in the camera frame
    (each (n, k, 3)) for camera centres ``centres`` and map→camera rotations ``R_mc``
    (n, k, 3, 3); None when any part of the disc is within 1 mm of the camera plane or
    behind it (no projection).
    """
    e1c = np.einsum('nkji,j->nki', R_mc, g.e1)
    e2c = np.einsum('nkji,j->nki', R_mc, g.e2)
    dc = np.einsum('nkji,nkj->nki', R_mc, g.centre - centres)
    if np.any(dc[..., 2] - g.radius_m * np.hypot(e1c[..., 2], e2c[..., 2]) <= 1e-3):
        return None
    return e1c, e2c, dc


class StereoRenderer:
    """Render stereo frames of the tunnel; see the module docstring.

    Parameters
    ----------
    config : RendererConfig
    lamp_map : LampMap
    trajectory : Trajectory
        Pose of base_link in map at any time (seconds since the epoch).
    seed : int
        Seeds the lamp clocks and the sensor noise.
    """

    def __init__(self, config, lamp_map, trajectory, seed=0):
        self.config = config
        self.lamp_map = lamp_map
        self.trajectory = trajectory
        self.seed = int(seed)
        self.rig = config.rig()
        k = config.intrinsics
        self.height, self.width = k.height, k.width
        self.sensor = SensorModel(config.sensor, config.exposure_s, noise=config.sensor_noise)
        self._background_e = self.sensor.background_electrons(self.height, self.width)
        bank_rng = np.random.default_rng([self.seed, 0xBA4C])
        # the banks come from the disk memo when an earlier node drew the same ones
        # (precompute_cache: off unless the camera node's precompute_cache_dir is set)
        def bank_key():
            return (self.seed, config.sensor, float(config.exposure_s),
                    bool(config.sensor_noise), self.height, self.width,
                    precompute_cache.array_digest(self._background_e),
                    precompute_cache.source_digest(sensor_noise))
        if config.fixed_pattern is None:
            self._bank = precompute_cache.cached(
                'noise_bank', bank_key,
                lambda: {'bank': self.sensor.background_bank(self._background_e,
                                                             bank_rng)})['bank']
            self._patterns = self._banks = None
        else:
            # Two sensors, two patterns: each camera has its own bank, drawn with its pattern.
            self._patterns = [FixedPattern(config.fixed_pattern, self.height, self.width,
                                           config.exposure_s,
                                           np.random.default_rng([self.seed, 0xF1ED, cam]))
                              for cam in (0, 1)]

            def banks():
                out = {}
                for cam, pattern in enumerate(self._patterns):
                    out[f'frames{cam}'], out[f'rows{cam}'] = self.sensor.pattern_bank(
                        self._background_e, bank_rng, pattern)
                return out
            b = precompute_cache.cached(
                'pattern_banks', lambda: bank_key() + (
                    config.fixed_pattern, precompute_cache.array_digest(
                        *(a for p in self._patterns for a in (p.gain, p.offset_e)))), banks)
            self._banks = [(b['frames0'], b['rows0']), (b['frames1'], b['rows1'])]
        self._noise = (NoiseTable(config.noise_table_size,
                                  np.random.default_rng([self.seed, 0x7AB1]))
                       if config.noise_table_size > 0 else None)
        self._vignette = self._cos4(k) if config.vignetting else np.ones(
            (self.height, self.width), np.float32)
        sigma_core = max(config.psf_sigma_px, config.psf_sigma_corner_px)
        self._pad_px = int(np.ceil(3.0 * max(config.halo_sigma_px if config.halo_fraction > 0
                                             else 0.0, sigma_core))) + 2
        self._waveforms = {}
        self._geometry = {}
        self._brightness = {int(uid): float(f) for uid, f in config.lamp_brightness}
        self._setup_cameras()
        self._distractors = [self._distractor_geometry(i, d)
                             for i, d in enumerate(config.distractors)]
        # Any opt-in model of a truthful camera; without one, the same arithmetic as ever.
        self._truthful = any([config.optics_truth is not None, config.psf_sigma_corner_px > 0,
                              config.fixed_pattern is not None, config.stray_light is not None,
                              len(config.distractors) > 0, config.noise_table_size > 0])

    def _cos4(self, k):
        """(H, W) float32 cos⁴θ of the field angle of each pixel of a pinhole ``k``."""
        uu = (np.arange(self.width) - k.cx) / k.fx
        vv = (np.arange(self.height) - k.cy) / k.fy
        cos2 = 1.0 / (1.0 + uu[None, :] ** 2 + vv[:, None] ** 2)
        return (cos2 * cos2).astype(np.float32)    # cos⁴θ

    def _setup_cameras(self):
        """Per camera: pose in base_link, intrinsics, lens maps and illumination, skew.

        Without ``optics_truth`` both cameras are the rig's (same arrays, so the default
        rendering is the same arithmetic as ever).
        """
        c = self.config
        truth = c.optics_truth
        R = self.rig.R_base_cam
        if truth is None:
            self._t_base, self._R_base = self.rig.t_base_cams, (R, R)
            self._skew_s = (0.0, 0.0)
            self._intrinsics = (c.intrinsics, c.intrinsics)
            self._lens = (None, None)
            self._illumination = (self._vignette, self._vignette)
        else:
            left = np.asarray(c.mount_xyz_m, dtype=float)
            self._t_base = np.stack([left, left + R @ np.asarray(truth.right_position_m)])
            self._R_base = (R, R @ truth.R_left_right)
            self._skew_s = (0.0, float(truth.trigger_skew_s))
            self._intrinsics = truth.cameras
            self._lens = tuple(
                lens_map(cam, self.width, self.height, _PATCH_MAX_STEP, c.vignetting)
                if cam.distorts else None for cam in truth.cameras)
            self._illumination = tuple(
                lens.illumination[lens.window(0, self.width, 0, self.height)]
                if lens is not None else (self._cos4(cam) if c.vignetting else self._vignette)
                for cam, lens in zip(truth.cameras, self._lens))
        corners = np.array([[-0.5, -0.5], [self.width - 0.5, -0.5], [-0.5, self.height - 0.5],
                            [self.width - 0.5, self.height - 0.5]])
        self._corner_radius_px = [float(np.hypot(*(corners - (k.cx, k.cy)).T).max())
                                  for k in self._intrinsics]

    def _distractor_geometry(self, index, distractor):
        emitter = _Emitter(np.asarray(distractor.position_m, dtype=float),
                           np.asarray(distractor.normal, dtype=float), distractor.diameter_m)
        g = _LampGeometry(emitter, distractor.diameter_m)
        rng = np.random.default_rng([self.seed, 0xD157, index])
        g.waveform = (FlickerWaveform(distractor.flicker_hz, distractor.flicker_depth,
                                      rng.uniform(0.0, 2.0 * np.pi))
                      if self.config.lamp_modulation else FlickerWaveform())
        g.on_e = (self.config.optics.electrons_per_luminance(self.config.exposure_s)
                  * distractor.luminance_cd_m2)
        g.index, g.name = index, distractor.name
        return g

    # ---------------------------------------------------------------- lamps
    def lamp_waveform(self, uid):
        """The LampWaveform of lamp ``uid``: its seeded packet phase and clock error."""
        wf = self._waveforms.get(uid)
        if wf is None:
            c = self.config
            rng = np.random.default_rng([self.seed, 0x1A4F, int(uid)])
            rate = c.chip_rate_hz * (1.0 + c.lamp_clock_ppm * 1e-6 * rng.uniform(-1.0, 1.0))
            phase = rng.uniform(0.0, PACKET_CHIPS / rate)
            wf = LampWaveform(uid=int(uid), chip_rate_hz=rate, phase_s=phase,
                              off_level=c.off_level)
            self._waveforms[uid] = wf
        return wf

    def _lamp_geometry(self, lamp):
        g = self._geometry.get(lamp.uid)
        if g is None:
            d = self.config.lamp_diameter_m or lamp.diameter_m
            g = self._geometry[lamp.uid] = _LampGeometry(lamp, d)
            g.brightness = self._brightness.get(int(lamp.uid), 1.0)
        return g

    # ---------------------------------------------------------------- poses
    def _camera_poses(self, t_s, camera, pose=None):
        """Camera centres (N, 3) and R_map_cam (N, 3, 3) at times ``t_s`` (N,).

        Poses come from the frame's pose table unless ``pose`` = (position (N, 3),
        R_map_base (N, 3, 3)) is given. With the opt-in models, the poses of a few instants
        are kept for the frame (culling, fixed points and ROIs of lamps, reflections and
        distractors ask for the same instants again); the arrays returned are shared.
        """
        key = None
        if pose is None and self._truthful and np.size(t_s) <= 16:
            key = (camera, tuple(np.ravel(t_s).tolist()))
            cached = self._pose_cache.get(key)
            if cached is not None:
                return cached
        position, R = self._poses.at(t_s) if pose is None else pose
        centre = position + R @ self._t_base[camera]
        out = centre, R @ self._R_base[camera]
        if key is not None:
            self._pose_cache[key] = out
        return out

    def _begin_frame(self, t0_s):
        """Pose table covering every instant this frame's rendering may query."""
        c = self.config
        span = self.height * c.row_time_s
        self._poses = _PoseTable(self.trajectory, t0_s - 0.5 * span - 2 * _POSE_TABLE_STEP_S,
                                 t0_s + 1.5 * span + c.exposure_s + 2 * _POSE_TABLE_STEP_S,
                                 closed_form=self._truthful)
        self._pose_cache = {}

    def _project(self, points, t_s, camera, ideal=False):
        """Points (M, 3) at times (T,) → uv (T, M, 2), z (T, M).

        Raw sensor pixels through the camera's lens, or with ``ideal`` the pinhole
        (undistorted) pixels of the camera's K.
        """
        centre, R_mc = self._camera_poses(t_s, camera)
        p_cam = np.einsum('tji,tmj->tmi', R_mc, points[None, :, :] - centre[:, None, :])
        return self._project_camera(p_cam, camera, ideal)

    def _project_camera(self, p_cam, camera, ideal=False):
        """Optical-frame points (..., 3) → uv (..., 2), z (...) (see ``_project``)."""
        k = self._intrinsics[camera]
        lens = self._lens[camera]
        z = p_cam[..., 2]
        with np.errstate(divide='ignore', invalid='ignore'):
            if lens is None or ideal:
                uv = np.stack([k.fx * p_cam[..., 0] / z + k.cx,
                               k.fy * p_cam[..., 1] / z + k.cy], axis=-1)
            else:
                uv = np.stack(lens.project_normalized(p_cam[..., 0] / z, p_cam[..., 1] / z),
                              axis=-1)
        return uv, z

    def _may_be_in_view(self, g, t0_s):
        """Cheap cull: whether the disc's image may touch either image during this frame.

        The centre is projected at the first and last row's exposure; the box of the two
        is grown by the disc's projected radius and the PSF pad.
        """
        c = self.config
        for camera in (0, 1):
            t0c = t0_s + self._skew_s[camera]
            t = [t0c, t0c + self.height * c.row_time_s + c.exposure_s]
            uv, z = self._project(g.centre[None, :], t, camera)
            z = z[:, 0]
            if not np.all(z > 0.0):
                if np.any(z > 0.0):
                    return True     # crossing the camera plane: let the full test decide
                continue
            grow = self._intrinsics[camera].fx * g.radius_m / z.min() + self._pad_px + 2.0
            u, v = uv[:, 0, 0], uv[:, 0, 1]
            if (u.min() - grow < self.width and u.max() + grow > 0.0
                    and v.min() - grow < self.height and v.max() + grow > 0.0):
                return True
        return False

    def _in_view_many(self, geometries, t0_s):
        """``_may_be_in_view`` of several discs at once (one projection per camera)."""
        if not geometries:
            return np.zeros(0, bool)
        c = self.config
        centres = np.stack([g.centre for g in geometries])
        radius = np.array([g.radius_m for g in geometries])
        keep = np.zeros(len(geometries), bool)
        for camera in (0, 1):
            t0c = t0_s + self._skew_s[camera]
            uv, z = self._project(centres, [t0c, t0c + self.height * c.row_time_s
                                            + c.exposure_s], camera)
            front = np.all(z > 0.0, axis=0)
            crossing = ~front & np.any(z > 0.0, axis=0)
            with np.errstate(divide='ignore', invalid='ignore'):
                grow = (self._intrinsics[camera].fx * radius / z.min(axis=0)
                        + self._pad_px + 2.0)
            u, v = uv[..., 0], uv[..., 1]
            box = ((u.min(axis=0) - grow < self.width) & (u.max(axis=0) + grow > 0.0)
                   & (v.min(axis=0) - grow < self.height) & (v.max(axis=0) + grow > 0.0))
            keep |= crossing | (front & box)
        return keep

    def _row_mid_time(self, t0_s, v):
        c = self.config
        return t0_s + v * c.row_time_s + 0.5 * c.exposure_s

    def _centre_truth(self, g, t0_s):
        """Fixed point of the centre's row and the truth quantities at that instant.

        Iterates on the pose table, then evaluates the truth with the exact trajectory
        at the converged instant (the table's interpolation error moves v* by < 1e-4 px).
        """
        v = 0.5 * (self.height - 1)
        for _ in range(_FIXED_POINT_ITERATIONS):
            uv, z = self._project(g.centre[None, :], [self._row_mid_time(t0_s, v)], 0)
            if not z[0, 0] > 0.0:
                return None
            # Outside the image the row time is an extrapolation; bound it to the pose
            # table's span (such lamps are out of view anyway).
            v_new = float(np.clip(uv[0, 0, 1], -0.5 * self.height, 1.5 * self.height))
            if abs(v_new - v) < 1e-6:
                v = v_new
                break
            v = v_new
        t_c = self._row_mid_time(t0_s, v)
        s = self.trajectory.sample([t_c])
        pose = (s.position_m, s.R_map_base)
        centre_l, R_l = self._camera_poses(None, 0, pose)
        centre_r, R_r = self._camera_poses(None, 1, pose)
        p_l = R_l[0].T @ (g.centre - centre_l[0])
        p_r = R_r[0].T @ (g.centre - centre_r[0])
        uv_l, _ = self.rig.project_camera(p_l[None, :])
        uv_r, _ = self.rig.project_camera(p_r[None, :])
        line_of_sight = centre_l[0] - g.centre
        cos_phi = line_of_sight @ g.lamp.normal / np.linalg.norm(line_of_sight)
        return dict(t_centre_s=t_c, uv_left=uv_l[0], uv_right=uv_r[0],
                    depth_m=float(p_l[2]), range_m=float(np.linalg.norm(p_l)),
                    along_track_m=float(g.lamp.track_chainage_m - self._base_chainage(s)),
                    viewing_angle_deg=float(np.degrees(np.arccos(np.clip(cos_phi, -1, 1)))),
                    cos_phi=float(cos_phi))

    def _centre_truths_raw(self, geometries, t0_s):
        """The truth of ``_centre_truth`` for raw images (``optics_truth``), for several
        discs (a list of dicts or None, one per disc).

        Per camera, the fixed point of the centre's *sensor* row (through the lens) with
        that camera's row instants (the right camera's ``trigger_skew_s`` late), then the
        exact trajectory at each camera's own instant (one ``Trajectory.sample`` for all
        discs). ``uv`` holds both cameras' raw centres.
        """
        rows = [self._sensor_row_fixed_points(g, t0_s) for g in geometries]
        found = [i for i, v in enumerate(rows) if v is not None]
        out = [None] * len(geometries)
        if not found:
            return out
        t_centre = np.array([[self._row_mid_time(t0_s + self._skew_s[cam], rows[i][cam])
                              for cam in (0, 1)] for i in found])
        s = self.trajectory.sample(t_centre.ravel())
        chainage, _ = self.trajectory.alignment.project(s.position_m[0::2, 0],
                                                         s.position_m[0::2, 1])
        for n, i in enumerate(found):
            g, uv = geometries[i], []
            for camera in (0, 1):
                j = 2 * n + camera
                centre, R = self._camera_poses(None, camera, (s.position_m[j:j + 1],
                                                              s.R_map_base[j:j + 1]))
                p_cam = R[0].T @ (g.centre - centre[0])
                uv.append(self._project_camera(p_cam[None, :], camera)[0][0])
                if camera == 0:
                    p_left, centre_left = p_cam, centre[0]
            line_of_sight = centre_left - g.centre
            cos_phi = line_of_sight @ g.lamp.normal / np.linalg.norm(line_of_sight)
            out[i] = dict(
                t_centre_s=float(t_centre[n, 0]), t_centre_right_s=float(t_centre[n, 1]),
                uv_left=uv[0], uv_right=uv[1], uv=uv, depth_m=float(p_left[2]),
                range_m=float(np.linalg.norm(p_left)),
                along_track_m=float(g.lamp.track_chainage_m - chainage[n]),
                viewing_angle_deg=float(np.degrees(np.arccos(np.clip(cos_phi, -1, 1)))),
                cos_phi=float(cos_phi))
        return out

    def _sensor_row_fixed_points(self, g, t0_s):
        """v*[cam] = v_sensor(t0 + skew_cam + v*·row_time + exposure/2) of the disc centre,
        both cameras at once (2,), or None if the centre is behind a camera.

        Secant steps on v_sensor(t(v)) − v (smooth and nearly linear: the image moves far
        less than a row per row time), to 1e-6 px. Bounded to the pose table's span, as
        ``_centre_truth``.
        """
        c = self.config
        skew = np.array(self._skew_s)

        def f(v):
            position, R = self._poses.at(t0_s + skew + v * c.row_time_s + 0.5 * c.exposure_s)
            out = np.empty(2)
            for cam in (0, 1):
                centre, R_mc = self._camera_poses(None, cam, (position[cam:cam + 1],
                                                              R[cam:cam + 1]))
                p_cam = R_mc[0].T @ (g.centre - centre[0])
                if not p_cam[2] > 0.0:
                    return None
                out[cam] = self._project_camera(p_cam[None, :], cam)[0][0, 1]
            return np.clip(out, -0.5 * self.height, 1.5 * self.height)
        v0 = np.full(2, 0.5 * (self.height - 1))
        f0 = f(v0)
        if f0 is None:
            return None
        v1 = f0
        for _ in range(_FIXED_POINT_ITERATIONS):
            f1 = f(v1)
            if f1 is None:
                return None
            if np.all(np.abs(f1 - v1) < 1e-6):
                return v1
            g0, g1 = f0 - v0, f1 - v1
            with np.errstate(divide='ignore', invalid='ignore'):
                v_next = np.where(g1 != g0, v1 - g1 * (v1 - v0) / (g1 - g0), f1)
            wild = ~np.isfinite(v_next) | (np.abs(v_next - v1) > 2.0 * np.abs(f1 - v1) + 1.0)
            v_next = np.where(wild, f1, v_next)      # a wild secant step: plain iteration
            converged = np.abs(f1 - v1) < 1e-6
            v_next = np.where(converged, v1, v_next)
            v0, f0, v1 = v1, f1, v_next
        return v1

    def _rois_pair(self, g, t0_s, v_centre, rim=None, pad_px=None, iterations=2):
        """Both cameras' ``_roi`` at once (one pose-table query per step): each camera with
        its own row instants (trigger skew included) from its centre row ``v_centre[cam]``.
        """
        c = self.config
        rim = g.rim if rim is None else rim
        t0c = [t0_s + self._skew_s[cam] for cam in (0, 1)]

        def boxes(times):
            position, R = self._poses.at(np.concatenate(times))
            out, start = [], 0
            for cam in (0, 1):
                n = len(times[cam])
                sl, start = slice(start, start + n), start + n
                if n == 0:
                    out.append(None)
                    continue
                centre, R_mc = self._camera_poses(None, cam, (position[sl], R[sl]))
                p_cam = np.einsum('tji,tmj->tmi', R_mc, rim[None, :, :] - centre[:, None, :])
                uv, z = self._project_camera(p_cam, cam)
                out.append((uv[..., 0].min(), uv[..., 0].max(), uv[..., 1].min(),
                            uv[..., 1].max()) if np.all(z > 1e-3) else None)
            return out
        box = boxes([np.array([self._row_mid_time(t0c[cam], v_centre[cam])]) for cam in (0, 1)])
        for _ in range(iterations):
            times = []
            for cam in (0, 1):
                if box[cam] is None:
                    times.append(np.zeros(0))
                    continue
                rows = np.linspace(box[cam][2] - 1.0, box[cam][3] + 1.0, 4)
                times.append((t0c[cam] + rows[:, None] * c.row_time_s
                              + np.array([0.0, c.exposure_s])).ravel())
            more = boxes(times)
            box = [None if b is None or m is None else
                   (min(b[0], m[0]), max(b[1], m[1]), min(b[2], m[2]), max(b[3], m[3]))
                   for b, m in zip(box, more)]
        return [None if b is None else self._box_roi(b, pad_px) for b in box]

    def _base_chainage(self, sample):
        """Chainage of base_link's foot point on the alignment (its map x on a straight)."""
        chainage, _ = self.trajectory.alignment.project(sample.position_m[:1, 0],
                                                         sample.position_m[:1, 1])
        return float(chainage[0])

    # ---------------------------------------------------------------- ROI
    def _rim_box(self, g, t_s, camera, rim=None):
        """(umin, umax, vmin, vmax) of the projected rim over times ``t_s``, or None."""
        uv, z = self._project(g.rim if rim is None else rim, np.ravel(t_s), camera)
        if not np.all(z > 1e-3):
            return None
        return (uv[..., 0].min(), uv[..., 0].max(), uv[..., 1].min(), uv[..., 1].max())

    def _roi(self, g, t0_s, v_centre, camera, rim=None, pad_px=None, iterations=2):
        """Integer ROI (u0, u1, v0, v1), half-open, clipped to the image; or None.

        The box holds the disc's image over the exposure windows of every row it may
        cover (rolling shutter and motion), padded for the PSF halo. ``t0_s`` is the
        camera's row-0 start (its trigger skew included); ``rim`` (another outline than
        the disc's), ``pad_px`` and the number of rolling-shutter ``iterations`` override
        the disc's.
        """
        c = self.config
        box = self._rim_box(g, [self._row_mid_time(t0_s, v_centre)], camera, rim)
        if box is None:
            return None
        for _ in range(iterations):
            rows = np.linspace(box[2] - 1.0, box[3] + 1.0, 4)
            t = (t0_s + rows[:, None] * c.row_time_s + np.array([0.0, c.exposure_s])).ravel()
            more = self._rim_box(g, t, camera, rim)
            if more is None:
                return None
            box = (min(box[0], more[0]), max(box[1], more[1]),
                   min(box[2], more[2]), max(box[3], more[3]))
        return self._box_roi(box, pad_px)

    def _box_roi(self, box, pad_px=None):
        """(umin, umax, vmin, vmax) → integer ROI padded by ``pad_px`` (default the PSF's),
        clipped to the image; None if empty.
        """
        p = self._pad_px if pad_px is None else pad_px
        u0 = max(0, int(np.floor(box[0])) - p)
        u1 = min(self.width, int(np.ceil(box[1])) + p + 1)
        v0 = max(0, int(np.floor(box[2])) - p)
        v1 = min(self.height, int(np.ceil(box[3])) + p + 1)
        if u0 >= u1 or v0 >= v1:
            return None
        return (u0, u1, v0, v1)

    # ---------------------------------------------------------------- coverage
    def _blur_substeps(self, g, t0_s, v_centre):
        """Sub-steps per exposure so the spot moves ≤ blur_step_px between them."""
        c = self.config
        t = self._row_mid_time(t0_s, v_centre)
        uv, _ = self._project(g.centre[None, :], [t - 0.5 * c.exposure_s,
                                                  t + 0.5 * c.exposure_s], 0)
        shift = float(np.hypot(*(uv[1, 0] - uv[0, 0])))
        if not np.isfinite(shift):
            return 1
        return int(np.clip(np.ceil(shift / c.blur_step_px), 1, c.max_blur_substeps))

    def _coverage(self, g, roi, camera, centres, R_mc, levels):
        """Exposure-weighted disc coverage of the ROI pixels.

        ``centres`` (n_rows, K, 3), ``R_mc`` (n_rows, K, 3, 3): camera poses at the K
        sub-steps of each ROI row's exposure; ``levels`` (n_rows, K) the lamp's mean
        output over each sub-step. Returns (weighted (n_rows, n_cols) float64 in "on"
        units, covered (n_rows,) bool) or None if the disc crosses the camera plane.
        The ROI is in the pinhole pixels of the camera's K (its ideal image).
        """
        c = self.config
        u0, u1, v0, v1 = roi
        n_rows, K = levels.shape
        k = self._intrinsics[camera]
        axes = _disc_in_camera(g, centres, R_mc)
        if axes is None:
            return None
        e1c, e2c, dc = axes
        K_roi = np.array([[k.fx, 0.0, k.cx - u0], [0.0, k.fy, k.cy - v0], [0.0, 0.0, 1.0]])
        H = K_roi @ np.stack([e1c, e2c, dc], axis=-1)          # (r, k, 3, 3)
        Hi = np.linalg.inv(H)
        C0 = np.array([1.0, 1.0, -g.radius_m ** 2])
        Q = np.einsum('rkai,a,rkaj->rkij', Hi, C0, Hi)
        Q /= Q[..., 0:1, 0:1]
        # Sub-row lines y (ROI coordinates) of each row: pixel centres at integers.
        S = c.subrows
        y = (np.arange(n_rows)[:, None] + (np.arange(S) + 0.5) / S - 0.5)[:, None, :]
        q01, q02 = Q[..., 0, 1][..., None], Q[..., 0, 2][..., None]
        q11, q12, q22 = Q[..., 1, 1][..., None], Q[..., 1, 2][..., None], Q[..., 2, 2][..., None]
        b = q01 * y + q02
        cc = q11 * y * y + 2.0 * q12 * y + q22
        disc = b * b - cc
        root = np.sqrt(np.maximum(disc, 0.0))
        lo = np.where(disc > 0.0, -b - root, 0.0)[..., None]    # (r, k, S, 1)
        hi = np.where(disc > 0.0, -b + root, 0.0)[..., None]
        x = np.arange(u1 - u0, dtype=float)
        overlap = np.minimum(hi, x + 0.5) - np.maximum(lo, x - 0.5)
        np.maximum(overlap, 0.0, out=overlap)                  # (r, k, S, n_cols)
        cover = overlap.sum(axis=2)                             # (r, k, n_cols)
        weighted = np.einsum('rkc,rk->rc', cover, levels) / (K * S)
        covered = cover.sum(axis=(1, 2)) > 0.0
        return weighted, covered

    def _render_lamp(self, g, t0_s, truth, rois, waveform=None, on_e=None):
        """Electrons of lamp ``g`` in each camera's ROI: list of (roi, array, rows).

        ``waveform`` and ``on_e`` (electrons of a fully covered on-axis pixel when "on")
        default to the lamp's; a distractor brings its own.
        """
        c = self.config
        K = self._blur_substeps(g, t0_s, truth['uv_left'][1])
        v_lo = min(r[2] for r in rois if r is not None)
        v_hi = max(r[3] for r in rois if r is not None)
        rows = np.arange(v_lo, v_hi)
        t_row = t0_s + rows * c.row_time_s
        edges = t_row[:, None] + c.exposure_s * np.arange(K + 1) / K
        if c.lamp_modulation:
            wf = self.lamp_waveform(g.lamp.uid) if waveform is None else waveform
            levels = wf.mean_over(edges[:, :-1], edges[:, 1:])
        else:
            levels = np.ones((len(rows), K))
        steady = np.ones_like(levels)
        row_level = levels.mean(axis=1).astype(np.float32)
        t_mid = 0.5 * (edges[:, :-1] + edges[:, 1:])
        if on_e is None:
            on_e = c.optics.on_electrons(g.area_m2, truth['cos_phi'], c.exposure_s)
            if g.brightness != 1.0:
                on_e *= g.brightness
        pose = self._poses.at(t_mid)
        out = []
        for camera, roi in enumerate(rois):
            if roi is None:
                out.append(None)
                continue
            centres, R_mc = self._camera_poses(None, camera, pose)
            sl = slice(roi[2] - v_lo, roi[3] - v_lo)
            # The optics blur the lamp's image; the sensor row then integrates that
            # blurred light while the lamp is modulated. So coverage is computed steady
            # ("on"), blurred by the PSF, and only then multiplied by each row's mean lamp
            # output: halo rows carry the stripes of their own exposure time, sharp.
            res = self._coverage(g, roi, camera, centres.reshape(len(rows), K, 3)[sl],
                                 R_mc.reshape(len(rows), K, 3, 3)[sl], steady[sl])
            if res is None or not res[1].any():
                out.append(None)
                continue
            weighted, covered = res
            electrons = (weighted * on_e).astype(np.float32)
            electrons *= self._vignette[roi[2]:roi[3], roi[0]:roi[1]]
            electrons = self._apply_psf(electrons, self._psf_sigma(
                camera, truth['uv_left' if camera == 0 else 'uv_right'])) * row_level[sl, None]
            idx = np.flatnonzero(covered)
            out.append((roi, electrons, (roi[2] + int(idx[0]), roi[2] + int(idx[-1]))))
        return out

    # ---------------------------------------------------------------- raw images
    def _image_velocities(self, g, t_mid_s):
        """Per camera, the velocity field of the disc's ideal (pinhole) image at
        ``t_mid_s[camera]``, affine in the image: (p0 (2,), w0 (2,), G (2, 2)) with
        w(p) = w0 + G·(p − p0) px/s, from the motion of the centre and two rim points over
        one exposure; None if the disc is not in front of that camera.
        """
        c = self.config
        points = np.stack([g.centre, g.centre + g.radius_m * g.e1, g.centre + g.radius_m * g.e2])
        half = 0.5 * c.exposure_s
        position, R = self._poses.at([t_mid_s[0] - half, t_mid_s[0] + half,
                                      t_mid_s[1] - half, t_mid_s[1] + half])
        out = []
        for camera in (0, 1):
            sl = slice(2 * camera, 2 * camera + 2)
            centre, R_mc = self._camera_poses(None, camera, (position[sl], R[sl]))
            p_cam = np.einsum('tji,tmj->tmi', R_mc, points[None, :, :] - centre[:, None, :])
            uv, z = self._project_camera(p_cam, camera, ideal=True)
            if not np.all(z > 0.0):
                out.append(None)
                continue
            p, w = 0.5 * (uv[0] + uv[1]), (uv[1] - uv[0]) / c.exposure_s
            G = np.linalg.solve((p[1:] - p[0]), (w[1:] - w[0])).T
            out.append((p[0], w[0], G))
        return out

    def _coverage_steady(self, g, iroi, camera, centres, R_mc):
        """Steady disc coverage (n_rows, n_cols) float32 of an ideal ROI, or None if the
        disc crosses the camera plane.

        ``centres`` (n_rows, K, 3), ``R_mc`` (n_rows, K, 3, 3): the camera poses of each
        row at K sub-steps of its exposure. The exact conic coverage of ``_coverage``
        (sub-row chords intersected with each pixel), the conic written out: Q ∝
        H⁻ᵀ·diag(1, 1, −ρ²)·H⁻¹ with H = K_roi·[e1 e2 c] and H⁻¹ ∝ adj(H), whose rows
        are the cross products of H's columns (the scale cancels when Q is normalized).

        The overlap of a chord [lo, hi] with pixel x is F(hi − x + ½) − F(lo − x + ½),
        F(t) = min(max(t, 0), 1); summed over a row's chords, F(a − x + ½) is 1 for every
        pixel left of the one holding the end a and its fractional part in that one: a
        count and a weighted histogram per row, cumulated, instead of every chord against
        every pixel.
        """
        c = self.config
        iu0, iu1, iv0, iv1 = iroi
        n_rows, K = centres.shape[:2]
        k = self._intrinsics[camera]
        axes = _disc_in_camera(g, centres, R_mc)
        if axes is None:
            return None
        e1c, e2c, dc = axes

        def pixel(v):
            return np.stack([k.fx * v[..., 0] + (k.cx - iu0) * v[..., 2],
                             k.fy * v[..., 1] + (k.cy - iv0) * v[..., 2], v[..., 2]], axis=-1)
        def cross(a, b):
            return (a[..., 1] * b[..., 2] - a[..., 2] * b[..., 1],
                    a[..., 2] * b[..., 0] - a[..., 0] * b[..., 2],
                    a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0])
        h1, h2, h3 = pixel(e1c), pixel(e2c), pixel(dc)
        r1, r2, r3 = cross(h2, h3), cross(h3, h1), cross(h1, h2)
        rho2 = g.radius_m ** 2

        def q(i, j):
            return r1[i] * r1[j] + r2[i] * r2[j] - rho2 * r3[i] * r3[j]
        q00 = q(0, 0)
        q01, q02, q11, q12, q22 = (q(i, j)[..., None] / q00[..., None]
                                   for i, j in ((0, 1), (0, 2), (1, 1), (1, 2), (2, 2)))
        S = c.subrows
        y = (np.arange(n_rows)[:, None] + (np.arange(S) + 0.5) / S - 0.5)[:, None, :]
        b = q01 * y + q02                                             # (n, K, S)
        disc = b * b - (q11 * y * y + 2.0 * q12 * y + q22)
        root = np.sqrt(np.maximum(disc, 0.0))
        lo = np.where(disc > 0.0, -b - root, 0.0)
        hi = np.where(disc > 0.0, -b + root, 0.0)
        n_cols = iu1 - iu0
        row = np.broadcast_to(np.arange(n_rows)[:, None, None], lo.shape).ravel() * (n_cols + 1)

        def ramp_sums(a):
            """Σ over a row's chord ends of F(a − x + ½), (n_rows, n_cols)."""
            a = np.clip(a.ravel(), -0.5, n_cols - 0.5) + 0.5
            p = np.floor(a)
            index = row + p.astype(np.int64)
            size = n_rows * (n_cols + 1)
            beyond = np.bincount(index, minlength=size).reshape(n_rows, n_cols + 1)
            inside = np.bincount(index, weights=a - p, minlength=size).reshape(n_rows,
                                                                              n_cols + 1)
            # ends in a pixel right of x count 1; an end in pixel x its fraction
            right = np.cumsum(beyond[:, ::-1], axis=1)[:, ::-1][:, 1:]
            return right + inside[:, :-1]
        coverage = ramp_sums(hi) - ramp_sums(lo)
        return (coverage / (K * S)).astype(np.float32)

    def _ideal_roi(self, roi, camera):
        """What the sensor ROI needs of the ideal image: (iroi, maps), maps = (map_x,
        map_y, inner) or None without a lens.

        The ROI's margin for the PSF spill (``_pad_px``) holds no light before the PSF, so
        only its inner window ``inner`` = (u0, u1, v0, v1) (the margin less
        _RAW_INNER_PX) is resampled; ``map_x``/``map_y`` are the inner pixels' ideal
        coordinates relative to the ideal box ``iroi`` = (iu0, iu1, iv0, iv1), which covers
        them with _RAW_MARGIN_PX to spare for the samples' shift to their own row's instant
        (samples outside it read zero).
        """
        lens = self._lens[camera]
        if lens is None:
            return roi, None
        u0, u1, v0, v1 = roi
        trim = max(self._pad_px - _RAW_INNER_PX, 0)
        a0 = min(u0 + trim, u1 - 1) if u0 > 0 else u0
        a1 = max(u1 - trim, a0 + 1) if u1 < self.width else u1
        b0 = min(v0 + trim, v1 - 1) if v0 > 0 else v0
        b1 = max(v1 - trim, b0 + 1) if v1 < self.height else v1
        sl = lens.window(a0, a1, b0, b1)
        mx, my = lens.map_x[sl], lens.map_y[sl]
        m = _RAW_MARGIN_PX
        iu0, iv0 = int(np.floor(mx.min())) - m, int(np.floor(my.min())) - m
        iroi = (iu0, int(np.floor(mx.max())) + m + 2, iv0, int(np.floor(my.max())) + m + 2)
        return iroi, (mx - np.float32(iu0), my - np.float32(iv0), (a0, a1, b0, b1))

    @staticmethod
    def _resample(ideal, map_x, map_y, lens, roi):
        """The ideal image ``ideal`` seen by the sensor ROI ``roi``: each sensor pixel the
        mean of _RAW_SUBSAMPLES² bilinear samples spread over its footprint (through the
        lens map's local derivatives), ``map_x``/``map_y`` its centre's ideal coordinates
        relative to ``ideal``.

        One sample per pixel point-samples an image box-filtered by *ideal* pixels, which
        at the edge of the field (a pixel's footprint 1.4 ideal pixels wide) aliases a
        hard edge: a small steady disc's centroid was off by up to 0.06 px against the
        exact flux centroid; 3 × 3 samples per pixel bring that under 0.01 px.
        """
        n_sub = _RAW_SUBSAMPLES
        if n_sub == 1:
            return cv2.remap(ideal, map_x, map_y, cv2.INTER_LINEAR,
                             borderMode=cv2.BORDER_CONSTANT, borderValue=0.0)
        window = lens.window(*roi)
        dxu, dxv, dyu, dyv = (d[window] for d in lens.derivatives)
        offsets = ((np.arange(n_sub) + 0.5) / n_sub - 0.5).astype(np.float32)
        along_u = [(map_x + a * dxu, map_y + a * dyu) for a in offsets]
        along_v = [(b * dxv, b * dyv) for b in offsets]
        out = np.zeros(map_x.shape, np.float32)
        for x_u, y_u in along_u:
            for x_v, y_v in along_v:
                out += cv2.remap(ideal, x_u + x_v, y_u + y_v, cv2.INTER_LINEAR,
                                 borderMode=cv2.BORDER_CONSTANT, borderValue=0.0)
        out *= np.float32(1.0 / (n_sub * n_sub))
        return out

    def _render_raw(self, g, t0_s, truth, rois, waveform=None, on_e=None):
        """``_render_lamp`` for raw images (``optics_truth``): list of (roi, array, rows).

        Per camera: the disc's exact coverage in the camera's ideal pinhole image (an
        ideal ROI covering what the sensor ROI sees), each ideal row y rendered at the
        exposure instants of the sensor row v_ref(y) it lands on at the disc centre's
        column; then resampled into the sensor (cv2.remap, bilinear) through the static
        ``LensMap``, each sensor pixel at its own row's instants: where the lens tilts the
        rows, the sensor pixel (u, v) sees ideal point m at t(v) = t0 + v·row_time, while
        the ideal image shows that row at t_ref = t0 + v_ref(m_y)·row_time, so it is sampled
        at m − w·Δt/(1 − α·w_y·row_time), Δt = t(v) − t_ref, w the image velocity of the disc
        centre, α = dv_ref/dy (the rolling shutter's own stretch of that shift). Then the
        relative illumination (cos⁴θ / det J), the PSF in the sensor image (σ by field
        position), and each *sensor* row times the lamp's mean output over that row's own
        exposure window.
        """
        c = self.config
        if on_e is None:
            on_e = c.optics.on_electrons(g.area_m2, truth['cos_phi'], c.exposure_s)
            if g.brightness != 1.0:
                on_e *= g.brightness
        if waveform is None:
            waveform = self.lamp_waveform(g.lamp.uid)
        out = []
        motions = truth['motions'] = self._image_velocities(
            g, [self._row_mid_time(t0_s + self._skew_s[cam], truth['uv'][cam][1])
                for cam in (0, 1)])
        for camera, roi in enumerate(rois):
            if roi is None:
                out.append(None)
                continue
            t0c = t0_s + self._skew_s[camera]
            uv_c = truth['uv'][camera]
            lens = self._lens[camera]
            iroi, maps = self._ideal_roi(roi, camera)
            iu0, iu1, iv0, iv1 = iroi
            motion = motions[camera]
            if motion is None:
                out.append(None)
                continue
            p0, w, G = motion
            shift = float(np.hypot(*w)) * c.exposure_s
            K = int(np.clip(np.ceil(shift / c.blur_step_px), 1, c.max_blur_substeps))
            ys = np.arange(iv0, iv1, dtype=float)
            if lens is None:
                v_ref = ys
            else:
                v_ref = lens.distort_ideal(np.full_like(ys, p0[0]), ys)[1]
            edges = ((t0c + v_ref * c.row_time_s)[:, None]
                     + c.exposure_s * np.arange(K + 1) / K)
            pose = self._poses.at(0.5 * (edges[:, :-1] + edges[:, 1:]))
            centres, R_mc = self._camera_poses(None, camera, pose)
            coverage = self._coverage_steady(g, iroi, camera, centres.reshape(len(ys), K, 3),
                                             R_mc.reshape(len(ys), K, 3, 3))
            if coverage is None:          # the disc crosses the camera plane
                out.append(None)
                continue
            u0, u1, v0, v1 = roi
            if lens is None:
                sensor = coverage
                illumination = self._illumination[camera][v0:v1, u0:u1]
            else:
                map_x, map_y, inner = maps
                if w[0] != 0.0 or w[1] != 0.0:
                    x_abs, y_abs = map_x + np.float32(iu0), map_y + np.float32(iv0)
                    wx = w[0] + G[0, 0] * (x_abs - p0[0]) + G[0, 1] * (y_abs - p0[1])
                    wy = w[1] + G[1, 0] * (x_abs - p0[0]) + G[1, 1] * (y_abs - p0[1])
                    alpha = np.interp(y_abs, ys, np.gradient(v_ref))
                    dt = (np.arange(inner[2], inner[3])[:, None] - np.interp(y_abs, ys, v_ref)) * (
                        c.row_time_s / (1.0 - alpha * wy * c.row_time_s))
                    map_x = (map_x - wx * dt).astype(np.float32)
                    map_y = (map_y - wy * dt).astype(np.float32)
                sensor = np.zeros((v1 - v0, u1 - u0), np.float32)
                sensor[inner[2] - v0:inner[3] - v0, inner[0] - u0:inner[1] - u0] = self._resample(
                    coverage, map_x, map_y, lens, inner)
                illumination = lens.illumination[lens.window(u0, u1, v0, v1)]
            covered = np.flatnonzero(sensor.max(axis=1) > _RAW_COVERED)
            if covered.size == 0:
                out.append(None)
                continue
            electrons = sensor * np.float32(on_e)
            electrons *= illumination
            electrons = self._apply_psf(electrons, self._psf_sigma(camera, uv_c))
            if c.lamp_modulation:
                t_row = t0c + np.arange(v0, v1) * c.row_time_s
                electrons *= waveform.mean_over(t_row, t_row + c.exposure_s).astype(
                    np.float32)[:, None]
            out.append((roi, electrons, (v0 + int(covered[0]), v0 + int(covered[-1]))))
        return out

    # ---------------------------------------------------------------- stray light
    def _reflection_geometry(self, g):
        """(patch centre (3,), outline at 3σ (32, 3), peak luminance cd/m²) of a lamp."""
        cached = getattr(g, 'reflection', None)
        if cached is None:
            sl, optics = self.config.stray_light, self.config.optics
            centre = (g.centre + sl.reflection_offset_m[0] * g.e1
                      + sl.reflection_offset_m[1] * g.e2)
            ang = np.linspace(0.0, 2.0 * np.pi, _RIM_POINTS, endpoint=False)
            rim = centre + 3.0 * sl.reflection_sigma_m * (np.outer(np.cos(ang), g.e1)
                                                          + np.outer(np.sin(ang), g.e2))
            exitance = (sl.reflection_fraction * optics.luminous_flux_lm
                        / (2.0 * np.pi * sl.reflection_sigma_m ** 2))
            if getattr(g, 'brightness', 1.0) != 1.0:
                exitance *= g.brightness
            cached = g.reflection = (centre, rim, exitance / np.pi)
        return cached

    def _render_reflection(self, g, t0_s, truth, waveform):
        """Each camera's (roi, electrons) of lamp ``g``'s wall reflection, or None.

        The Gaussian exitance of ``StrayLightConfig`` in the wall plane, evaluated exactly
        under perspective: every sample's ray (through the lens's undistortion map in raw
        mode) is intersected with the wall plane at the instant of its sensor row. Samples
        on a coarse grid (σ/3 apart, 2 to 8 px) are interpolated bilinearly; no PSF (the
        patch is tens of pixels wide); the lamp's mean output per sensor row.
        """
        c = self.config
        sigma_m = c.stray_light.reflection_sigma_m
        centre, rim, peak_cd_m2 = self._reflection_geometry(g)
        scale_e = c.optics.electrons_per_luminance(c.exposure_s) * peak_cd_m2
        out = []
        v_centre = [truth['uv'][cam][1] if 'uv' in truth else truth['uv_left'][1]
                    for cam in (0, 1)]
        rois = self._reflection_rois(g, t0_s, v_centre, rim, truth.get('motions'))
        for camera, roi in enumerate(rois):
            t0c = t0_s + self._skew_s[camera]
            v_guess = v_centre[camera]
            if roi is None:
                out.append(None)
                continue
            u0, u1, v0, v1 = roi
            k = self._intrinsics[camera]
            lens = self._lens[camera]
            # The patch's narrower image axis: σ foreshortened by the viewing angle.
            range_m = np.linalg.norm(centre - self._camera_poses(
                [self._row_mid_time(t0c, v_guess)], camera)[0][0])
            sigma_px = k.fx * sigma_m * abs(truth['cos_phi']) / max(float(range_m), 1e-3)
            step = int(np.clip(sigma_px / _PATCH_SAMPLES_PER_SIGMA, _PATCH_MIN_STEP,
                               _PATCH_MAX_STEP))
            us = u0 + step * np.arange(-(-(u1 - u0 - 1) // step) + 1)
            vs = v0 + step * np.arange(-(-(v1 - v0 - 1) // step) + 1)
            if lens is None:
                x = np.broadcast_to(us[None, :].astype(float), (len(vs), len(us)))
                y = np.broadcast_to(vs[:, None].astype(float), (len(vs), len(us)))
                xn, yn = (x - k.cx) / k.fx, (y - k.cy) / k.fy
                cos2 = 1.0 / (1.0 + xn * xn + yn * yn)
                illumination = cos2 * cos2 if c.vignetting else 1.0
            else:
                p = lens.pad
                jj, ii = np.ix_(np.minimum(vs, self.height - 1 + p) + p,
                                np.minimum(us, self.width - 1 + p) + p)
                xn = (lens.map_x[jj, ii] - k.cx) / k.fx
                yn = (lens.map_y[jj, ii] - k.cy) / k.fy
                illumination = lens.illumination[jj, ii]
            # Rays of the samples in map, each row at its sensor row's mid-exposure.
            cam_centre, R_mc = self._camera_poses(self._row_mid_time(t0c, vs), camera)
            rays = np.stack([xn, yn, np.ones_like(xn)], axis=-1)           # (nv, nu, 3)
            rays_map = np.einsum('rij,ruj->rui', R_mc, rays)
            n = g.lamp.normal
            denominator = rays_map @ n
            with np.errstate(divide='ignore', invalid='ignore'):
                lam = ((centre - cam_centre) @ n)[:, None] / denominator
            d = cam_centre[:, None, :] + lam[..., None] * rays_map - centre
            a, b = d @ g.e1, d @ g.e2
            value = np.where(lam > 0.0, np.exp(-(a * a + b * b) / (2.0 * sigma_m ** 2)), 0.0)
            coarse = (value * illumination * scale_e).astype(np.float32)
            if step > 1:
                electrons = cv2.warpAffine(
                    coarse, np.array([[1.0 / step, 0.0, 0.0], [0.0, 1.0 / step, 0.0]]),
                    (u1 - u0, v1 - v0), flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP,
                    borderMode=cv2.BORDER_REPLICATE)
            else:
                electrons = coarse[:v1 - v0, :u1 - u0].copy()
            if c.lamp_modulation:
                t_row = t0c + np.arange(v0, v1) * c.row_time_s
                electrons *= waveform.mean_over(t_row, t_row + c.exposure_s).astype(
                    np.float32)[:, None]
            out.append((roi, electrons))
        return out

    def _reflection_rois(self, g, t0_s, v_centre, rim, motions):
        """Both cameras' ROIs of a reflection patch (outline ``rim``). With the disc's image
        motion known (raw images), the outline at the centre row's instant, widened by the
        motion over the patch's rows (the rolling shutter; a third to spare for its
        stretch); else one rolling-shutter iteration of ``_roi``. Either may miss a sliver
        of the 3σ tail.
        """
        if motions is None:
            return self._rois_pair(g, t0_s, v_centre, rim=rim, pad_px=0, iterations=1)
        rois = self._rois_pair(g, t0_s, v_centre, rim=rim, pad_px=0, iterations=0)
        out = []
        for roi, motion, v in zip(rois, motions, v_centre):
            if roi is None or motion is None:
                out.append(roi)
                continue
            span_s = max(v - roi[2], roi[3] - v) * self.config.row_time_s
            grow = int(np.ceil(1.3 * np.hypot(*motion[1]) * span_s)) + 1
            out.append((max(roi[0] - grow, 0), min(roi[1] + grow, self.width),
                        max(roi[2] - grow, 0), min(roi[3] + grow, self.height)))
        return out

    # ---------------------------------------------------------------- frame
    def _psf_sigma(self, camera, uv):
        """Core PSF σ (px) at raw pixel ``uv``: ``psf_sigma_px`` on axis, growing with the
        square of the radius from the principal point to ``psf_sigma_corner_px`` at the
        farthest sensor corner (off-axis blur of the lens); constant when that is 0.
        """
        c = self.config
        if c.psf_sigma_corner_px <= 0.0:
            return c.psf_sigma_px
        k = self._intrinsics[camera]
        r = min(float(np.hypot(uv[0] - k.cx, uv[1] - k.cy)) / self._corner_radius_px[camera],
                1.0)
        return c.psf_sigma_px + (c.psf_sigma_corner_px - c.psf_sigma_px) * r * r

    def _apply_psf(self, electrons, sigma_px=None):
        c = self.config
        if not c.optics_psf:
            return electrons
        sigma_px = c.psf_sigma_px if sigma_px is None else sigma_px
        core = (cv2.GaussianBlur(electrons, (0, 0), sigma_px,
                                 borderType=cv2.BORDER_CONSTANT)
                if sigma_px > 0 else electrons)
        if c.halo_fraction <= 0.0 or c.halo_sigma_px <= 0.0:
            return core
        halo = cv2.GaussianBlur(electrons, (0, 0), c.halo_sigma_px,
                                borderType=cv2.BORDER_CONSTANT)
        return (1.0 - c.halo_fraction) * core + c.halo_fraction * halo

    @staticmethod
    def _merge(items):
        """Merge overlapping (roi, electrons) items into clusters of one box each."""
        clusters = []
        for roi, electrons in items:
            box, members = list(roi), [(roi, electrons)]
            merged = True
            while merged:
                merged = False
                for other in clusters:
                    ob = other[0]
                    if box[0] < ob[1] and ob[0] < box[1] and box[2] < ob[3] and ob[2] < box[3]:
                        box = [min(box[0], ob[0]), max(box[1], ob[1]),
                               min(box[2], ob[2]), max(box[3], ob[3])]
                        members += other[1]
                        clusters.remove(other)
                        merged = True
                        break
            clusters.append((box, members))
        return clusters

    def frame_time_s(self, frame_index):
        """t0 of frame ``frame_index``: start of row-0 exposure, seconds since the epoch."""
        return frame_index / self.config.fps

    def render(self, frame_index, electrons=False):
        """Render frame ``frame_index`` (t0 = frame_index / fps); returns a Frame."""
        return self.render_at(self.frame_time_s(frame_index), noise_key=int(frame_index),
                              index=int(frame_index), electrons=electrons)

    def render_at(self, t0_s, noise_key=0, index=-1, electrons=False):
        """Render the stereo frame whose row 0 starts exposing at ``t0_s`` (since epoch).

        ``noise_key`` selects the sensor-noise realisation (with the seed). With
        ``electrons`` the images are the noise-free expected electrons per pixel
        (float32, after the PSF, before saturation and quantization; the optical image:
        no fixed pattern) instead of mono8.
        """
        c = self.config
        rng = np.random.default_rng([self.seed, 0x5EED, int(noise_key)])
        row_offsets = (None, None)
        if electrons:
            images = [self._background_e + np.float32(self.sensor.dark_e) for _ in (0, 1)]
        elif self._banks is None:
            n_bank = len(self._bank)
            picks = rng.choice(n_bank, size=2, replace=n_bank < 2)
            images = [self._bank[picks[0]].copy(), self._bank[picks[1]].copy()]
        else:
            picks = rng.integers(0, len(self._banks[0][0]), size=2)
            images = [self._banks[cam][0][picks[cam]].copy() for cam in (0, 1)]
            row_offsets = [self._banks[cam][1][picks[cam]] for cam in (0, 1)]
        pose0 = self.trajectory.sample([t0_s])
        x0 = pose0.position_m[0, 0]
        self._begin_frame(t0_s)
        raw = c.optics_truth is not None
        render_disc = self._render_raw if raw else self._render_lamp
        items = ([], [])
        truth = []
        near = self.lamp_map.near(x0, c.lamp_search_ahead_m, c.lamp_search_behind_m)
        if self._brightness:
            near = [lamp for lamp in near if self._brightness.get(int(lamp.uid), 1.0) > 0.0]
        candidates = [g for g in self._distractors
                      if x0 - c.lamp_search_behind_m <= g.centre[0] <= x0 + c.lamp_search_ahead_m]
        if self._truthful:
            geometries = [self._lamp_geometry(lamp) for lamp in near]
            near = [lamp for lamp, keep in zip(near, self._in_view_many(geometries, t0_s))
                    if keep]
            candidates = [g for g, keep in zip(candidates, self._in_view_many(candidates, t0_s))
                          if keep]
        if raw:
            centres = self._centre_truths_raw(
                [self._lamp_geometry(lamp) for lamp in near] + candidates, t0_s)
            centre_truth = dict(zip([id(self._lamp_geometry(lamp)) for lamp in near]
                                    + [id(g) for g in candidates], centres))
        for lamp in near:
            g = self._lamp_geometry(lamp)
            if not self._truthful and not self._may_be_in_view(g, t0_s):
                continue
            centre = centre_truth[id(g)] if raw else self._centre_truth(g, t0_s)
            if centre is None:
                continue
            rois = self._disc_rois(g, t0_s, centre)
            if rois[0] is None and rois[1] is None:
                continue
            rendered = render_disc(g, t0_s, centre, rois)
            if rendered[0] is None and rendered[1] is None:
                continue
            for cam in (0, 1):
                if rendered[cam] is not None:
                    items[cam].append(rendered[cam][:2])
            truth.append(self._truth_record(lamp.uid, centre, rendered))
            if c.stray_light is not None and c.stray_light.reflection_fraction > 0.0:
                for cam, item in enumerate(self._render_reflection(
                        g, t0_s, centre, self.lamp_waveform(lamp.uid))):
                    if item is not None:
                        items[cam].append(item)
        distractors = []
        for g in candidates:
            centre = centre_truth[id(g)] if raw else self._centre_truth(g, t0_s)
            if centre is None:
                continue
            rois = self._disc_rois(g, t0_s, centre)
            if rois[0] is None and rois[1] is None:
                continue
            rendered = render_disc(g, t0_s, centre, rois, waveform=g.waveform, on_e=g.on_e)
            for cam in (0, 1):
                if rendered[cam] is not None:
                    items[cam].append(rendered[cam][:2])
            if rendered[0] is not None or rendered[1] is not None:
                distractors.append(DistractorTruth(
                    index=g.index, name=g.name, uv_left=centre['uv_left'],
                    uv_right=centre['uv_right'], in_left=self._inside(centre['uv_left']),
                    in_right=self._inside(centre['uv_right'])))
        for cam in (0, 1):
            for box, members in self._merge(items[cam]):
                u0, u1, v0, v1 = box
                signal = np.zeros((v1 - v0, u1 - u0), np.float32)
                for (a0, a1, b0, b1), lamp_e in members:
                    signal[b0 - v0:b1 - v0, a0 - u0:a1 - u0] += lamp_e
                if electrons:
                    images[cam][v0:v1, u0:u1] += signal
                elif self._patterns is None and self._noise is None:
                    images[cam][v0:v1, u0:u1] = self.sensor.expose(
                        signal + self._background_e[v0:v1, u0:u1], rng)
                else:
                    signal += self._background_e[v0:v1, u0:u1]
                    images[cam][v0:v1, u0:u1] = self.sensor.expose(
                        signal, rng,
                        pattern=None if self._patterns is None else self._patterns[cam],
                        window=box,
                        row_offset_e=None if row_offsets[cam] is None else row_offsets[cam][v0:v1],
                        normal=(None if self._noise is None or not c.sensor_noise
                                else self._noise.take(signal.shape, rng)))
        return Frame(index=index, t0_s=float(t0_s), stamp_s=c.epoch_s + float(t0_s),
                     left=images[0], right=images[1], truth=truth,
                     base_position_m=pose0.position_m[0], base_quat_xyzw=pose0.quat_xyzw[0],
                     base_velocity_body_mps=pose0.R_map_base[0].T @ pose0.velocity_mps[0],
                     base_angular_velocity_body_rps=pose0.angular_velocity_body_rps[0],
                     distractors=distractors)

    def _disc_rois(self, g, t0_s, centre):
        """Each camera's ROI of disc ``g`` (the rectified pair: both from the left row)."""
        if self.config.optics_truth is None:
            return [self._roi(g, t0_s, centre['uv_left'][1], cam) for cam in (0, 1)]
        return self._rois_pair(g, t0_s, [centre['uv'][cam][1] for cam in (0, 1)])

    def _inside(self, uv):
        return bool(-0.5 <= uv[0] <= self.width - 0.5 and -0.5 <= uv[1] <= self.height - 0.5)

    def _truth_record(self, uid, centre, rendered):
        inside = self._inside
        return LampTruth(uid=int(uid), uv_left=centre['uv_left'], uv_right=centre['uv_right'],
                         depth_m=centre['depth_m'], range_m=centre['range_m'],
                         along_track_m=centre['along_track_m'],
                         viewing_angle_deg=centre['viewing_angle_deg'],
                         t_centre_s=centre['t_centre_s'],
                         rows_left=rendered[0][2] if rendered[0] is not None else None,
                         rows_right=rendered[1][2] if rendered[1] is not None else None,
                         in_left=inside(centre['uv_left']), in_right=inside(centre['uv_right']),
                         t_centre_right_s=centre.get('t_centre_right_s', centre['t_centre_s']))

    def camera_info_dicts(self):
        """CameraInfo contents of the left and right cameras: the rig's ideal pair (see
        StereoRig), or with ``optics_truth`` what a perfect calibration of the true
        camera reports (:meth:`true_calibration`).
        """
        if self.config.optics_truth is None:
            return self.rig.camera_info_dicts()
        return self.true_calibration().camera_info_dicts()

    def true_calibration(self, alpha=0.0):
        """The StereoCameraModel of a perfect calibration of the rendered camera (raw K
        and D, the true extrinsics rectified by cv2.stereoRectify); the ideal pair of the
        rig without ``optics_truth``.
        """
        if self.config.optics_truth is None:
            return StereoCameraModel.from_rig(self.rig)
        return self.config.optics_truth.stereo_model(self.width, self.height, alpha)
