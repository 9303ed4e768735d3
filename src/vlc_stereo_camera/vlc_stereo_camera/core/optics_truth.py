"""The true optics of the simulated stereo camera (ROS-free).

The receivers of a real train get a calibration; the camera itself has a lens that
distorts, principal points off the sensor centre, a right camera turned by a fraction of
a degree against the left, and two sensors whose triggers are microseconds apart. This
module describes that truth for the renderer (``RendererConfig.optics_truth``) and the
static maps through which the renderer resamples each lamp's ideal image into the raw,
distorted sensor image.

* :class:`TrueCamera`: one camera's raw intrinsics K (fx, fy, cx, cy, px) and its
  plumb_bob distortion [k1, k2, p1, p2, k3] (OpenCV's model, as
  :meth:`vlc_common.core.camera.CameraModel.distort_normalized`).
* :class:`OpticsTruth`: both cameras, the right camera's pose in the left optical frame
  (rotation vector, degrees, and optical centre, m) and the trigger skew (the right
  camera's row r starts exposing ``trigger_skew_s`` after the left camera's row r).
  :meth:`OpticsTruth.example` is the lens pair of the calibration tests (a 3.9 mm M12 lens
  on the 1280×720 sensor); :meth:`OpticsTruth.draw` draws a plausible vehicle from a
  ``numpy.random.Generator``. :meth:`OpticsTruth.stereo_model` is what a perfect
  calibration of that truth reports (``cv2.stereoRectify``, as ROS camera_calibration).
* :class:`LensMap`: per camera, for every sensor pixel (and a margin of ``pad_px`` around
  the sensor) the ideal pinhole pixel it sees — the undistortion through the camera's own
  K, solved by Newton's method to 1e-9 px and checked against the forward model — and
  the relative illumination cos⁴θ / det J (natural vignetting of the ray's field angle θ,
  and the distortion's change of pixel area, which keeps the flux: a barrel lens squeezes
  the edge of the field onto fewer pixels, each brighter). ``project`` is the forward
  lens model, guarded beyond the field of view (below).

Guard: the plumb_bob polynomial is fitted to the field of view and folds back at large
field angles (r_d = r·(1 + k1 r² + k2 r⁴ + k3 r⁶) stops growing), which would put points
far outside the view into the image. Beyond ``r2_max`` (1.5² × the largest r² the sensor
sees, and below the fold) the radial factor is frozen at its value there, which keeps the
mapping monotonic; inside, the projection is OpenCV's model exactly.
"""
from dataclasses import dataclass, field
import functools
import sys

import numpy as np

from vlc_common.core.camera import CameraModel, StereoCameraModel
from vlc_common.core.rotations import quat_from_rotvec, quat_to_matrix
from vlc_stereo_camera.core import precompute_cache

#: Most Newton iterations of the undistortion of the sensor grid; it stops once no point
#: moves by more than 1e-13 (normalized, ~1e-10 px); 5 do on the 3.9 mm M12 lens (the
#: residual is checked after).
_NEWTON_ITERATIONS = 20
#: Largest residual of the undistortion maps accepted, px (re-distorted vs the pixel).
_MAP_TOLERANCE_PX = 1e-6


@dataclass(frozen=True)
class TrueCamera:
    """One camera's raw intrinsics (px) and plumb_bob distortion [k1, k2, p1, p2, k3].

    Defaults: the ideal pinhole of ``CameraIntrinsics`` (no distortion).
    """

    fx: float = 1040.0
    fy: float = 1040.0
    cx: float = 639.5
    cy: float = 359.5
    distortion: tuple = (0.0, 0.0, 0.0, 0.0, 0.0)

    def __post_init__(self):
        if not (self.fx > 0.0 and self.fy > 0.0):
            raise ValueError(f'TrueCamera: fx, fy must be > 0 (got {self.fx}, {self.fy})')
        d = tuple(float(x) for x in self.distortion)
        if len(d) != 5 or not np.all(np.isfinite(d)):
            raise ValueError('TrueCamera: distortion must be 5 finite plumb_bob coefficients '
                             f'[k1, k2, p1, p2, k3] (got {self.distortion})')
        object.__setattr__(self, 'distortion', d)

    @property
    def K(self):
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    @property
    def distorts(self):
        return any(self.distortion)

    def camera_model(self, width, height):
        """The raw camera as :class:`CameraModel` (K, D; R = I, P = [K 0])."""
        return CameraModel(width, height, self.K, np.array(self.distortion))


@dataclass(frozen=True)
class OpticsTruth:
    """The true stereo camera: two :class:`TrueCamera`, the right one's pose, the skew.

    ``right_rotation_deg``: rotation vector (deg) of the right optical frame in the left
    optical frame (columns of R_left_right = the right camera's axes in left optical
    coordinates); ``right_position_m``: the right optical centre in the left optical
    frame (m; the nominal rig has (baseline, 0, 0)); ``trigger_skew_s``: the right
    camera's row r is exposed ``trigger_skew_s`` later than the left camera's row r (s;
    negative = earlier). The left camera sits where the rig's mount puts it.
    """

    left: TrueCamera = field(default_factory=TrueCamera)
    right: TrueCamera = field(default_factory=TrueCamera)
    right_rotation_deg: tuple = (0.0, 0.0, 0.0)
    right_position_m: tuple = (0.12, 0.0, 0.0)
    trigger_skew_s: float = 0.0

    def __post_init__(self):
        rot = tuple(float(x) for x in self.right_rotation_deg)
        pos = tuple(float(x) for x in self.right_position_m)
        if len(rot) != 3 or len(pos) != 3 or not np.all(np.isfinite(rot + pos)):
            raise ValueError('OpticsTruth: right_rotation_deg and right_position_m must be 3 '
                             'finite values each')
        if not pos[0] > 0.0:
            raise ValueError('OpticsTruth: the right camera must be right of the left one '
                             f'(right_position_m[0] > 0, got {pos[0]})')
        if np.linalg.norm(rot) > 10.0:
            raise ValueError('OpticsTruth: a relative rotation over 10 deg is not a stereo '
                             f'pair (got {np.linalg.norm(rot):.3g} deg)')
        if not abs(self.trigger_skew_s) <= 1e-3:
            raise ValueError(f'OpticsTruth: |trigger_skew_s| must be <= 1 ms '
                             f'(got {self.trigger_skew_s})')
        object.__setattr__(self, 'right_rotation_deg', rot)
        object.__setattr__(self, 'right_position_m', pos)

    @property
    def cameras(self):
        return (self.left, self.right)

    @property
    def R_left_right(self):
        """(3, 3) rotation: right optical frame → left optical frame."""
        return quat_to_matrix(quat_from_rotvec(np.radians(self.right_rotation_deg)))

    def extrinsics(self):
        """(R, T) in OpenCV's convention x_right = R·x_left + T (T in m)."""
        R = self.R_left_right.T
        return R, -R @ np.asarray(self.right_position_m)

    def stereo_model(self, width, height, alpha=0.0):
        """The rectified pair a perfect calibration of this truth reports."""
        R, T = self.extrinsics()
        return StereoCameraModel.from_stereo_extrinsics(
            self.left.K, np.array(self.left.distortion), self.right.K,
            np.array(self.right.distortion), (width, height), R, T, alpha=alpha)

    @classmethod
    def example(cls):
        """The lens pair of the calibration tests: a 3.9 mm M12 lens (64° HFOV on
        1280×720, fx ≈ 1040 px, k1 ≈ −0.30, k2 ≈ 0.10, small tangential terms), principal
        points off centre, the right camera turned by 0.24° and 0.2 mm long of 120 mm,
        triggered 15 µs after the left.
        """
        return cls(
            left=TrueCamera(1040.0, 1041.5, 643.2, 356.1, (-0.30, 0.10, 0.0008, -0.0005, -0.015)),
            right=TrueCamera(1043.0, 1044.2, 635.7, 362.4,
                             (-0.29, 0.095, -0.0006, 0.0004, -0.012)),
            right_rotation_deg=(0.10, -0.20, 0.08), right_position_m=(0.1202, 0.0004, -0.0003),
            trigger_skew_s=15e-6)

    @classmethod
    def draw(cls, rng, width=1280, height=720, nominal_fx=1040.0, baseline_m=0.12):
        """A plausible vehicle's camera, drawn from ``rng`` (numpy Generator).

        Per camera: fx ~ N(nominal, 0.5 %) (focal-length tolerance of an M12 lens), fy/fx ~
        N(1, 0.1 %), principal point ~ N(sensor centre, 6 px) per axis (lens-holder
        decentring of ~20 µm), k1 ~ N(−0.30, 0.02), k2 ~ N(0.10, 0.015), p1, p2 ~
        N(0, 5e-4), k3 ~ N(−0.015, 0.005). Right camera: each rotation-vector component
        ~ N(0, 0.12°) (~0.2° in all), centre (b + N(0, 0.3 mm), N(0, 0.3 mm),
        N(0, 0.3 mm)); trigger skew log-uniform in 2…40 µs.
        """
        def camera():
            fx = nominal_fx * (1.0 + 0.005 * rng.standard_normal())
            return TrueCamera(
                fx=fx, fy=fx * (1.0 + 1e-3 * rng.standard_normal()),
                cx=0.5 * (width - 1) + 6.0 * rng.standard_normal(),
                cy=0.5 * (height - 1) + 6.0 * rng.standard_normal(),
                distortion=(-0.30 + 0.02 * rng.standard_normal(),
                            0.10 + 0.015 * rng.standard_normal(),
                            5e-4 * rng.standard_normal(), 5e-4 * rng.standard_normal(),
                            -0.015 + 0.005 * rng.standard_normal()))
        left, right = camera(), camera()
        return cls(left=left, right=right,
                   right_rotation_deg=tuple(0.12 * rng.standard_normal(3)),
                   right_position_m=tuple(np.array([baseline_m, 0.0, 0.0])
                                          + 3e-4 * rng.standard_normal(3)),
                   trigger_skew_s=float(np.exp(rng.uniform(np.log(2e-6), np.log(40e-6)))))


# ------------------------------------------------------------------------------ lens
def _radial(r2, d):
    k1, k2, _, _, k3 = d
    return 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))


def _radial_slope(r2, d):
    k1, k2, _, _, k3 = d
    return k1 + r2 * (2.0 * k2 + r2 * 3.0 * k3)


def _distort(x, y, d, r2_max=np.inf):
    """Normalized ideal (x, y) → distorted; the radial factor frozen beyond ``r2_max``."""
    _, _, p1, p2, _ = d
    r2 = x * x + y * y
    radial = _radial(np.minimum(r2, r2_max), d)
    xd = x * radial + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x)
    yd = y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y
    return xd, yd


def _distort_jacobian(x, y, d):
    """∂(xd, yd)/∂(x, y) of :func:`_distort` (unguarded): four arrays."""
    _, _, p1, p2, _ = d
    r2 = x * x + y * y
    f = _radial(r2, d)
    g = 2.0 * _radial_slope(r2, d)
    xy = g * x * y
    return (f + g * x * x + 2.0 * p1 * y + 6.0 * p2 * x, xy + 2.0 * p1 * x + 2.0 * p2 * y,
            xy + 2.0 * p1 * x + 2.0 * p2 * y, f + g * y * y + 6.0 * p1 * y + 2.0 * p2 * x)


def _undistort(xd, yd, d):
    """Distorted normalized (xd, yd) → ideal (x, y) by Newton's method from (xd, yd)."""
    x, y = xd.copy(), yd.copy()
    for _ in range(_NEWTON_ITERATIONS):
        ex, ey = _distort(x, y, d)
        ex -= xd
        ey -= yd
        a, b, c, e = _distort_jacobian(x, y, d)
        det = a * e - b * c
        dx = (e * ex - b * ey) / det
        dy = (a * ey - c * ex) / det
        x -= dx
        y -= dy
        if max(np.abs(dx).max(), np.abs(dy).max()) < 1e-13:
            break
    return x, y


def _fold_r2(d, r2_limit=16.0):
    """Smallest r² where the radial mapping r → r·f(r²) stops increasing (inf if none)."""
    r2 = np.linspace(0.0, r2_limit, 16001)
    slope = _radial(r2, d) + 2.0 * r2 * _radial_slope(r2, d)
    bad = np.flatnonzero(slope <= 0.05)
    return float(r2[bad[0]]) if bad.size else np.inf


class LensMap:
    """Static maps of one camera: sensor pixel → ideal pinhole pixel, and illumination.

    Parameters
    ----------
    camera : TrueCamera
    width, height : int
        Sensor size, px.
    pad_px : int
        Margin around the sensor covered by the maps (for samples just outside it).
    vignetting : bool
        Include cos⁴θ in ``illumination`` (else only the area factor 1/det J).

    Attributes
    ----------
    map_x, map_y : (height + 2·pad, width + 2·pad) float32
        Ideal pixel coordinates (pinhole with the camera's own K) of sensor pixel
        (u, v) at index [v + pad, u + pad]; pixel centres at integers.
    illumination : same shape, float32
        cos⁴θ / det J: multiplies an image rendered per ideal pixel into electrons per
        sensor pixel.
    derivatives : (∂map_x/∂u, ∂map_x/∂v, ∂map_y/∂u, ∂map_y/∂v), each of the same shape,
        float32: the footprint of a sensor pixel in the ideal image.
    r2_max : float
        Normalized r² beyond which the projection's radial factor is frozen.
    """

    def __init__(self, camera, width, height, pad_px=8, vignetting=True):
        self.camera = camera
        self.width, self.height, self.pad = int(width), int(height), int(pad_px)
        # the same arrays from the disk memo when an earlier node computed them
        # (precompute_cache: off unless the camera node's precompute_cache_dir is set)
        a = precompute_cache.cached(
            'lens_map', lambda: (camera, self.width, self.height, self.pad, bool(vignetting),
                                 precompute_cache.source_digest(sys.modules[__name__])),
            lambda: _lens_map_arrays(camera, self.width, self.height, self.pad, vignetting))
        self.r2_max = float(a['r2_max'])
        self.map_x, self.map_y, self.illumination = a['map_x'], a['map_y'], a['illumination']
        self.derivatives = (a['d_xu'], a['d_xv'], a['d_yu'], a['d_yv'])

    def window(self, u0, u1, v0, v1):
        """Slices of the map arrays for sensor pixels u0 ≤ u < u1, v0 ≤ v < v1."""
        p = self.pad
        return (slice(v0 + p, v1 + p), slice(u0 + p, u1 + p))

    def distort_ideal(self, x_px, y_px):
        """Ideal pixel coordinates (arrays) → sensor pixel coordinates (guarded)."""
        c = self.camera
        xd, yd = _distort((np.asarray(x_px, dtype=float) - c.cx) / c.fx,
                          (np.asarray(y_px, dtype=float) - c.cy) / c.fy,
                          c.distortion, self.r2_max)
        return c.fx * xd + c.cx, c.fy * yd + c.cy

    def project_normalized(self, x, y):
        """Normalized ideal coordinates (arrays) → sensor pixels (guarded)."""
        c = self.camera
        xd, yd = _distort(x, y, c.distortion, self.r2_max)
        return c.fx * xd + c.cx, c.fy * yd + c.cy


def _lens_map_arrays(camera, width, height, pad, vignetting):
    """The arrays of a :class:`LensMap` (see there), as a dict."""
    d = camera.distortion
    u = np.arange(-pad, width + pad, dtype=float)
    v = np.arange(-pad, height + pad, dtype=float)
    xd = np.broadcast_to(((u - camera.cx) / camera.fx)[None, :], (len(v), len(u))).copy()
    yd = np.broadcast_to(((v - camera.cy) / camera.fy)[:, None], (len(v), len(u))).copy()
    x, y = _undistort(xd, yd, d)
    ex, ey = _distort(x, y, d)
    residual_px = max(np.abs(ex - xd).max() * camera.fx, np.abs(ey - yd).max() * camera.fy)
    if not residual_px <= _MAP_TOLERANCE_PX:
        raise ValueError(f'LensMap: the undistortion of the sensor did not converge '
                         f'(residual {residual_px:.3g} px); is the distortion monotonic '
                         'over the field of view?')
    a, b, c, e = _distort_jacobian(x, y, d)
    det = a * e - b * c
    if not np.all(det > 0.0):
        raise ValueError('LensMap: the distortion folds over inside the field of view')
    r2 = x * x + y * y
    cos4 = 1.0 / (1.0 + r2) ** 2 if vignetting else 1.0
    # ∂(ideal px)/∂(sensor px) = diag(f)·J⁻¹·diag(1/f), J = ∂(xd, yd)/∂(x, y)
    d_xu, d_xv, d_yu, d_yv = ((w / det).astype(np.float32) for w in (
        e, -b * camera.fx / camera.fy, -c * camera.fy / camera.fx, a))
    return {'r2_max': np.float64(min(2.25 * float(r2.max()), 0.95 * _fold_r2(d))),
            'map_x': (camera.fx * x + camera.cx).astype(np.float32),
            'map_y': (camera.fy * y + camera.cy).astype(np.float32),
            'illumination': np.asarray(cos4 / det).astype(np.float32),
            'd_xu': d_xu, 'd_xv': d_xv, 'd_yu': d_yu, 'd_yv': d_yv}


@functools.lru_cache(maxsize=4)
def lens_map(camera, width, height, pad_px=8, vignetting=True):
    """Cached :class:`LensMap` (the maps of one lens: ~0.5 s here and 27 MB)."""
    return LensMap(camera, width, height, pad_px, vignetting)
