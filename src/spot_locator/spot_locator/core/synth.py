"""Analytic lamp spots with exact ground truth, for tests and the benchmark.

Three kinds of spot, each rasterised by supersampling the pixel area:

* a 2-D Gaussian (the paper's spot model, eq. 1), truth = its mean;
* a uniform ellipse, truth = its centre;
* a perspective-projected luminous disc (the real lamp), truth = the projection of
  the disc centre, which differs from the centre of the imaged ellipse (the
  eccentricity error of circular targets).

Discs can be rendered the way the rolling-shutter rig sees them: every row integrates
the lamp's on/off output over its own exposure window (VLC stripes), while the disc moves
during the exposure (motion blur) and from row to row (rolling-shutter skew).

Pixel convention: pixel (row r, column c) covers ``[c - 0.5, c + 0.5] × [r - 0.5, r + 0.5]``
in image coordinates (u right, v down), so an integer coordinate is a pixel centre.
"""
from dataclasses import dataclass

import numpy as np


def disc_conic(K, centre_cam, normal_cam, radius_m):
    """Image conic (3, 3) of a disc: ``x^T Q x < 0`` inside, ``x = (u, v, 1)``.

    Parameters
    ----------
    K : (3, 3) camera matrix (pixels).
    centre_cam : (3,) disc centre in the optical frame (m), z > 0.
    normal_cam : (3,) unit normal of the disc plane in the optical frame.
    radius_m : disc radius (m).

    Notes
    -----
    The disc plane maps to the image by the homography ``H = K [e1 e2 C]`` (e1, e2 an
    orthonormal basis of the plane); the circle ``x² + y² = R²`` becomes
    ``Q = H^-T diag(1, 1, -R²) H^-1``.
    """
    n = np.asarray(normal_cam, float)
    n = n / np.linalg.norm(n)
    e1 = np.cross(n, [0.0, 1.0, 0.0])
    if np.linalg.norm(e1) < 1e-6:
        e1 = np.cross(n, [1.0, 0.0, 0.0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(n, e1)
    H = K @ np.column_stack([e1, e2, np.asarray(centre_cam, float)])
    Hinv = np.linalg.inv(H)
    Q = Hinv.T @ np.diag([1.0, 1.0, -radius_m ** 2]) @ Hinv
    Q = 0.5 * (Q + Q.T)
    return Q / np.abs(Q).max()


def conic_centre(Q):
    """Centre (u, v) of the ellipse with conic matrix ``Q`` (pole of the line at infinity)."""
    c = np.linalg.solve(Q[:2, :2], -Q[:2, 2])
    return c


def project(K, p_cam):
    """Pinhole projection of (N, 3) optical-frame points → (N, 2) pixels."""
    p = np.atleast_2d(p_cam)
    uv = (K @ p.T).T
    return uv[:, :2] / uv[:, 2:3]


def _subpixel_grid(rows, cols, supersample):
    """Sample coordinates (len(rows), len(cols), ss*ss) of each pixel's area."""
    off = (np.arange(supersample) + 0.5) / supersample - 0.5
    du, dv = np.meshgrid(off, off)
    uu = cols[None, :, None] + du.ravel()[None, None, :]
    vv = rows[:, None, None] + dv.ravel()[None, None, :]
    return np.broadcast_to(uu, (len(rows), len(cols), du.size)), \
        np.broadcast_to(vv, (len(rows), len(cols), du.size))


def gaussian_spot(shape, centre_uv, cov_px2, peak=200.0, supersample=5):
    """Pixel-integrated 2-D Gaussian spot (paper eq. 1), (H, W) float array.

    ``cov_px2`` (2, 2) is the covariance in (u, v) pixel² ; truth is ``centre_uv``.
    """
    rows = np.arange(shape[0], dtype=float)
    cols = np.arange(shape[1], dtype=float)
    uu, vv = _subpixel_grid(rows, cols, supersample)
    d = np.stack([uu - centre_uv[0], vv - centre_uv[1]], -1)
    icov = np.linalg.inv(np.asarray(cov_px2, float))
    m = np.einsum('...i,ij,...j->...', d, icov, d)
    return peak * np.exp(-0.5 * m).mean(-1)


def ellipse_spot(shape, centre_uv, semi_axes_px, angle_rad, level=200.0, supersample=8):
    """Uniform ellipse, (H, W) float array; truth is ``centre_uv``.

    ``semi_axes_px`` (a, b) lie along ``angle_rad`` (from +u toward +v) and across it.
    """
    rows = np.arange(shape[0], dtype=float)
    cols = np.arange(shape[1], dtype=float)
    uu, vv = _subpixel_grid(rows, cols, supersample)
    c, s = np.cos(angle_rad), np.sin(angle_rad)
    x = (uu - centre_uv[0]) * c + (vv - centre_uv[1]) * s
    y = -(uu - centre_uv[0]) * s + (vv - centre_uv[1]) * c
    inside = (x / semi_axes_px[0]) ** 2 + (y / semi_axes_px[1]) ** 2 <= 1.0
    return level * inside.mean(-1)


def square_wave_rows(n_rows, period_rows, duty=0.5, phase_rows=0.0, off_level=0.05):
    """Per-row gain of a square-wave stripe pattern (for quick analytic striped spots)."""
    r = (np.arange(n_rows) + phase_rows) / period_rows
    on = (r - np.floor(r)) < duty
    return np.where(on, 1.0, off_level)


def random_chip_level(rng, chip_rate_hz=10_000.0, off_level=0.05, n_chips=4096,
                      max_run=3):
    """A random on/off lamp output ``level(t_s)`` with runs of at most ``max_run`` chips.

    Stands in for the Manchester-coded packets (runs of 1–2 chips, and the 3-chip header
    runs) without depending on the transmitter model.
    """
    chips = np.empty(n_chips, dtype=bool)
    state, k = bool(rng.integers(2)), 0
    while k < n_chips:
        run = int(rng.integers(1, max_run + 1))
        chips[k:k + run] = state
        k += run
        state = not state
    levels = np.where(chips, 1.0, off_level)

    def level(t_s):
        idx = np.floor(np.asarray(t_s) * chip_rate_hz).astype(np.int64) % n_chips
        return levels[idx]
    return level


@dataclass
class Exposure:
    """Rolling-shutter timing: row r integrates ``[t0 + r·row_time_s, … + exposure_s]``."""

    row_time_s: float = 30e-6
    exposure_s: float = 50e-6
    t0_s: float = 0.0
    n_time: int = 8

    def row_mid_time(self, row):
        return self.t0_s + np.asarray(row, float) * self.row_time_s + 0.5 * self.exposure_s


def render_disc(shape, K, centre_cam, normal_cam, radius_m, radiance=220.0,
                velocity_cam_mps=None, level=None, exposure=None, supersample=6,
                psf_sigma_px=0.0, halo_sigma_px=0.0, halo_fraction=0.0, margin_px=3):
    """Render a luminous disc as the rolling-shutter camera sees it.

    Parameters
    ----------
    shape : (H, W) image size.
    K : (3, 3) camera matrix.
    centre_cam, normal_cam : (3,) disc centre (m) and unit normal at time 0, optical frame.
    radius_m : disc radius (m).
    radiance : pixel value of a fully covered pixel with the lamp on for the whole
        exposure (before clipping; no clipping is applied here).
    velocity_cam_mps : (3,) velocity of the disc in the optical frame (m/s); None = static.
    level : callable ``level(t_s) -> relative output``; None = always on (no stripes).
    exposure : :class:`Exposure`; None = defaults.
    supersample : samples per pixel side.
    psf_sigma_px : optional Gaussian optics blur (pixels).
    halo_sigma_px, halo_fraction : optional wide Gaussian halo holding that fraction of
        the light (glare), as the rig's optics model has.

    Returns
    -------
    image : (H, W) float array.
    """
    from scipy.ndimage import gaussian_filter

    exposure = exposure or Exposure()
    vel = np.zeros(3) if velocity_cam_mps is None else np.asarray(velocity_cam_mps, float)
    centre_cam = np.asarray(centre_cam, float)
    img = np.zeros(shape)
    # time samples inside each row's window (midpoint rule)
    frac = (np.arange(exposure.n_time) + 0.5) / exposure.n_time
    frame_span = shape[0] * exposure.row_time_s + exposure.exposure_s
    # bounding box over the whole frame time (the disc moves)
    corners = []
    for t in (0.0, frame_span):
        Q = disc_conic(K, centre_cam + vel * t, normal_cam, radius_m)
        corners.append(_conic_bbox(Q))
    corners = np.array(corners)
    u0 = max(int(np.floor(corners[:, 0].min())) - margin_px, 0)
    u1 = min(int(np.ceil(corners[:, 1].max())) + margin_px, shape[1] - 1)
    v0 = max(int(np.floor(corners[:, 2].min())) - margin_px, 0)
    v1 = min(int(np.ceil(corners[:, 3].max())) + margin_px, shape[0] - 1)
    if u1 < u0 or v1 < v0:
        return img
    rows = np.arange(v0, v1 + 1, dtype=float)
    cols = np.arange(u0, u1 + 1, dtype=float)
    uu, vv = _subpixel_grid(rows, cols, supersample)
    acc = np.zeros((len(rows), len(cols)))
    for f in frac:
        # every row at its own instant: t = t0 + r·row_time + f·exposure
        t_rows = exposure.t0_s + rows * exposure.row_time_s + f * exposure.exposure_s
        w = np.ones_like(t_rows) if level is None else level(t_rows)
        if np.allclose(vel, 0.0):
            Q = disc_conic(K, centre_cam, normal_cam, radius_m)
            inside = _inside(Q, uu, vv)
        else:
            inside = np.empty(uu.shape, bool)
            for i, t in enumerate(t_rows):
                Q = disc_conic(K, centre_cam + vel * t, normal_cam, radius_m)
                inside[i] = _inside(Q, uu[i], vv[i])
        acc += w[:, None] * inside.mean(-1)
    img[v0:v1 + 1, u0:u1 + 1] = radiance * acc / exposure.n_time
    # blur only a window around the spot: the rest of the frame is empty
    pad = int(np.ceil(4.0 * max(psf_sigma_px, halo_sigma_px if halo_fraction > 0 else 0.0)))
    if pad == 0:
        return img
    win = (slice(max(v0 - pad, 0), min(v1 + pad + 1, shape[0])),
           slice(max(u0 - pad, 0), min(u1 + pad + 1, shape[1])))
    part = img[win]
    core = gaussian_filter(part, psf_sigma_px, mode='constant') if psf_sigma_px > 0 else part
    if halo_fraction > 0.0 and halo_sigma_px > 0.0:
        core = ((1.0 - halo_fraction) * core
                + halo_fraction * gaussian_filter(part, halo_sigma_px, mode='constant'))
    img[win] = core
    return img


def _inside(Q, uu, vv):
    """Boolean mask of the samples (uu, vv) inside the ellipse ``Q``."""
    val = (Q[0, 0] * uu * uu + 2 * Q[0, 1] * uu * vv + Q[1, 1] * vv * vv
           + 2 * Q[0, 2] * uu + 2 * Q[1, 2] * vv + Q[2, 2])
    # The conic is only defined up to sign: the inside is the side holding its centre.
    c = conic_centre(Q)
    s = (Q[0, 0] * c[0] ** 2 + 2 * Q[0, 1] * c[0] * c[1] + Q[1, 1] * c[1] ** 2
         + 2 * Q[0, 2] * c[0] + 2 * Q[1, 2] * c[1] + Q[2, 2])
    return val * np.sign(s) > 0


def _conic_bbox(Q):
    """(u_min, u_max, v_min, v_max) of an ellipse with conic ``Q``."""
    D = np.linalg.inv(Q)          # dual conic: tangent lines l with l^T D l = 0
    # vertical tangents u = const: l = (1, 0, -u) → D00 - 2u D02 + u² D22 = 0
    us = np.roots([D[2, 2], -2 * D[0, 2], D[0, 0]]).real
    vs = np.roots([D[2, 2], -2 * D[1, 2], D[1, 1]]).real
    return us.min(), us.max(), vs.min(), vs.max()


def projected_centre_at(K, centre_cam, velocity_cam_mps, t_s):
    """True projected disc centre (u, v) at time ``t_s`` (s)."""
    vel = np.zeros(3) if velocity_cam_mps is None else np.asarray(velocity_cam_mps, float)
    return project(K, np.asarray(centre_cam, float) + vel * t_s)[0]


def add_noise(image, rng, read_noise=1.0, shot_gain=0.0, background=4.0, bits=8):
    """Background, Gaussian read noise and optional shot noise; quantise and clip to ``bits``."""
    img = image + background
    if shot_gain > 0.0:
        img = img + rng.standard_normal(img.shape) * np.sqrt(np.maximum(img, 0.0) * shot_gain)
    img = img + rng.standard_normal(img.shape) * read_noise
    top = 2 ** bits - 1
    return np.clip(np.round(img), 0, top).astype(np.uint8 if bits == 8 else np.uint16)
