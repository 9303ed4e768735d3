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
"""
from dataclasses import dataclass, field

import cv2
import numpy as np

from vlc_common.core.camera import CameraIntrinsics, StereoRig
from vlc_common.core.protocol import PACKET_CHIPS
from vlc_common.core.rotations import rpy_to_matrix
from vlc_stereo_camera.core.sensor_noise import OpticsConfig, SensorConfig, SensorModel
from vlc_stereo_camera.core.transmitter import LampWaveform

_RIM_POINTS = 32
_FIXED_POINT_ITERATIONS = 30
# Pose table step: linear interpolation error ≤ step²/8 · max|q̈| stays below 1e-6 m and
# 1e-7 rad for the eq. 21 vibration spectrum up to 200 km/h (highest term ~30 Hz).
_POSE_TABLE_STEP_S = 1e-3


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
                         pitch_deg=self.pitch_deg)


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

    def __init__(self, trajectory, t_start_s, t_end_s, step_s=_POSE_TABLE_STEP_S):
        n = max(2, int(np.ceil((t_end_s - t_start_s) / step_s)) + 1)
        self.t_start_s, self.step_s = t_start_s, step_s
        s = trajectory.sample(t_start_s + step_s * np.arange(n))
        self.q = np.column_stack([s.position_m, s.rpy_rad])

    def at(self, t_s):
        """Position (N, 3) and R_map_base (N, 3, 3) at times ``t_s`` (N,)."""
        x = (np.asarray(t_s, dtype=float).ravel() - self.t_start_s) / self.step_s
        i = np.clip(np.floor(x).astype(np.int64), 0, len(self.q) - 2)
        w = (x - i)[:, None]
        q = self.q[i] * (1.0 - w) + self.q[i + 1] * w
        return q[:, :3], rpy_to_matrix(q[:, 3], q[:, 4], q[:, 5])


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
        self._bank = self.sensor.background_bank(
            self._background_e, np.random.default_rng([self.seed, 0xBA4C]))
        if config.vignetting:
            uu = (np.arange(self.width) - k.cx) / k.fx
            vv = (np.arange(self.height) - k.cy) / k.fy
            cos2 = 1.0 / (1.0 + uu[None, :] ** 2 + vv[:, None] ** 2)
            self._vignette = (cos2 * cos2).astype(np.float32)    # cos⁴θ
        else:
            self._vignette = np.ones((self.height, self.width), np.float32)
        self._pad_px = int(np.ceil(3.0 * max(config.halo_sigma_px if config.halo_fraction > 0
                                             else 0.0, config.psf_sigma_px))) + 2
        self._waveforms = {}
        self._geometry = {}

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
        return g

    # ---------------------------------------------------------------- poses
    def _camera_poses(self, t_s, camera, pose=None):
        """Camera centres (N, 3) and R_map_cam (N, 3, 3) at times ``t_s`` (N,).

        Poses come from the frame's pose table unless ``pose`` = (position (N, 3),
        R_map_base (N, 3, 3)) is given.
        """
        position, R = self._poses.at(t_s) if pose is None else pose
        centre = position + R @ self.rig.t_base_cams[camera]
        return centre, R @ self.rig.R_base_cam

    def _begin_frame(self, t0_s):
        """Pose table covering every instant this frame's rendering may query."""
        c = self.config
        span = self.height * c.row_time_s
        self._poses = _PoseTable(self.trajectory, t0_s - 0.5 * span - 2 * _POSE_TABLE_STEP_S,
                                 t0_s + 1.5 * span + c.exposure_s + 2 * _POSE_TABLE_STEP_S)

    def _project(self, points, t_s, camera):
        """Points (M, 3) at times (T,) → uv (T, M, 2), z (T, M)."""
        centre, R_mc = self._camera_poses(t_s, camera)
        p_cam = np.einsum('tji,tmj->tmi', R_mc, points[None, :, :] - centre[:, None, :])
        k = self.config.intrinsics
        z = p_cam[..., 2]
        with np.errstate(divide='ignore', invalid='ignore'):
            uv = np.stack([k.fx * p_cam[..., 0] / z + k.cx, k.fy * p_cam[..., 1] / z + k.cy],
                          axis=-1)
        return uv, z

    def _may_be_in_view(self, g, t0_s):
        """Cheap cull: whether the disc's image may touch either image during this frame.

        The centre is projected at the first and last row's exposure; the box of the two
        is grown by the disc's projected radius and the PSF pad.
        """
        c = self.config
        t = [t0_s, t0_s + self.height * c.row_time_s + c.exposure_s]
        for camera in (0, 1):
            uv, z = self._project(g.centre[None, :], t, camera)
            z = z[:, 0]
            if not np.all(z > 0.0):
                if np.any(z > 0.0):
                    return True     # crossing the camera plane: let the full test decide
                continue
            grow = c.intrinsics.fx * g.radius_m / z.min() + self._pad_px + 2.0
            u, v = uv[:, 0, 0], uv[:, 0, 1]
            if (u.min() - grow < self.width and u.max() + grow > 0.0
                    and v.min() - grow < self.height and v.max() + grow > 0.0):
                return True
        return False

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

    def _base_chainage(self, sample):
        """Chainage of base_link's foot point on the alignment (its map x on a straight)."""
        chainage, _ = self.trajectory.alignment.project(sample.position_m[:1, 0],
                                                         sample.position_m[:1, 1])
        return float(chainage[0])

    # ---------------------------------------------------------------- ROI
    def _rim_box(self, g, t_s, camera):
        """(umin, umax, vmin, vmax) of the projected rim over times ``t_s``, or None."""
        uv, z = self._project(g.rim, np.ravel(t_s), camera)
        if not np.all(z > 1e-3):
            return None
        return (uv[..., 0].min(), uv[..., 0].max(), uv[..., 1].min(), uv[..., 1].max())

    def _roi(self, g, t0_s, v_centre, camera):
        """Integer ROI (u0, u1, v0, v1), half-open, clipped to the image; or None.

        The box holds the disc's image over the exposure windows of every row it may
        cover (rolling shutter and motion), padded for the PSF halo.
        """
        c = self.config
        box = self._rim_box(g, [self._row_mid_time(t0_s, v_centre)], camera)
        if box is None:
            return None
        for _ in range(2):
            rows = np.linspace(box[2] - 1.0, box[3] + 1.0, 4)
            t = (t0_s + rows[:, None] * c.row_time_s + np.array([0.0, c.exposure_s])).ravel()
            more = self._rim_box(g, t, camera)
            if more is None:
                return None
            box = (min(box[0], more[0]), max(box[1], more[1]),
                   min(box[2], more[2]), max(box[3], more[3]))
        p = self._pad_px
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
        """
        c = self.config
        u0, u1, v0, v1 = roi
        n_rows, K = levels.shape
        k = c.intrinsics
        e1c = np.einsum('rkji,j->rki', R_mc, g.e1)
        e2c = np.einsum('rkji,j->rki', R_mc, g.e2)
        dc = np.einsum('rkji,rkj->rki', R_mc, g.centre - centres)
        if np.any(dc[..., 2] - g.radius_m * np.hypot(e1c[..., 2], e2c[..., 2]) <= 1e-3):
            return None
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

    def _render_lamp(self, g, t0_s, truth, rois):
        """Electrons of lamp ``g`` in each camera's ROI: list of (roi, array, rows)."""
        c = self.config
        K = self._blur_substeps(g, t0_s, truth['uv_left'][1])
        v_lo = min(r[2] for r in rois if r is not None)
        v_hi = max(r[3] for r in rois if r is not None)
        rows = np.arange(v_lo, v_hi)
        t_row = t0_s + rows * c.row_time_s
        edges = t_row[:, None] + c.exposure_s * np.arange(K + 1) / K
        if c.lamp_modulation:
            levels = self.lamp_waveform(g.lamp.uid).mean_over(edges[:, :-1], edges[:, 1:])
        else:
            levels = np.ones((len(rows), K))
        steady = np.ones_like(levels)
        row_level = levels.mean(axis=1).astype(np.float32)
        t_mid = 0.5 * (edges[:, :-1] + edges[:, 1:])
        on_e = c.optics.on_electrons(g.area_m2, truth['cos_phi'], c.exposure_s)
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
            electrons = self._apply_psf(electrons) * row_level[sl, None]
            idx = np.flatnonzero(covered)
            out.append((roi, electrons, (roi[2] + int(idx[0]), roi[2] + int(idx[-1]))))
        return out

    # ---------------------------------------------------------------- frame
    def _apply_psf(self, electrons):
        c = self.config
        if not c.optics_psf:
            return electrons
        core = (cv2.GaussianBlur(electrons, (0, 0), c.psf_sigma_px,
                                 borderType=cv2.BORDER_CONSTANT)
                if c.psf_sigma_px > 0 else electrons)
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
        (float32, after the PSF, before saturation and quantization) instead of mono8.
        """
        c = self.config
        rng = np.random.default_rng([self.seed, 0x5EED, int(noise_key)])
        if electrons:
            images = [self._background_e + np.float32(self.sensor.dark_e) for _ in (0, 1)]
        else:
            n_bank = len(self._bank)
            picks = rng.choice(n_bank, size=2, replace=n_bank < 2)
            images = [self._bank[picks[0]].copy(), self._bank[picks[1]].copy()]
        pose0 = self.trajectory.sample([t0_s])
        x0 = pose0.position_m[0, 0]
        self._begin_frame(t0_s)
        items = ([], [])
        truth = []
        for lamp in self.lamp_map.near(x0, c.lamp_search_ahead_m, c.lamp_search_behind_m):
            g = self._lamp_geometry(lamp)
            if not self._may_be_in_view(g, t0_s):
                continue
            centre = self._centre_truth(g, t0_s)
            if centre is None:
                continue
            rois = [self._roi(g, t0_s, centre['uv_left'][1], cam) for cam in (0, 1)]
            if rois[0] is None and rois[1] is None:
                continue
            rendered = self._render_lamp(g, t0_s, centre, rois)
            if rendered[0] is None and rendered[1] is None:
                continue
            for cam in (0, 1):
                if rendered[cam] is not None:
                    items[cam].append(rendered[cam][:2])
            truth.append(self._truth_record(lamp.uid, centre, rendered))
        for cam in (0, 1):
            for box, members in self._merge(items[cam]):
                u0, u1, v0, v1 = box
                signal = np.zeros((v1 - v0, u1 - u0), np.float32)
                for (a0, a1, b0, b1), lamp_e in members:
                    signal[b0 - v0:b1 - v0, a0 - u0:a1 - u0] += lamp_e
                if electrons:
                    images[cam][v0:v1, u0:u1] += signal
                else:
                    images[cam][v0:v1, u0:u1] = self.sensor.expose(
                        signal + self._background_e[v0:v1, u0:u1], rng)
        return Frame(index=index, t0_s=float(t0_s), stamp_s=c.epoch_s + float(t0_s),
                     left=images[0], right=images[1], truth=truth,
                     base_position_m=pose0.position_m[0], base_quat_xyzw=pose0.quat_xyzw[0],
                     base_velocity_body_mps=pose0.R_map_base[0].T @ pose0.velocity_mps[0],
                     base_angular_velocity_body_rps=pose0.angular_velocity_body_rps[0])

    def _truth_record(self, uid, centre, rendered):
        def inside(uv):
            return bool(-0.5 <= uv[0] <= self.width - 0.5 and -0.5 <= uv[1] <= self.height - 0.5)
        return LampTruth(uid=int(uid), uv_left=centre['uv_left'], uv_right=centre['uv_right'],
                         depth_m=centre['depth_m'], range_m=centre['range_m'],
                         along_track_m=centre['along_track_m'],
                         viewing_angle_deg=centre['viewing_angle_deg'],
                         t_centre_s=centre['t_centre_s'],
                         rows_left=rendered[0][2] if rendered[0] is not None else None,
                         rows_right=rendered[1][2] if rendered[1] is not None else None,
                         in_left=inside(centre['uv_left']), in_right=inside(centre['uv_right']))

    def camera_info_dicts(self):
        """CameraInfo contents of the left and right cameras (see StereoRig)."""
        return self.rig.camera_info_dicts()
