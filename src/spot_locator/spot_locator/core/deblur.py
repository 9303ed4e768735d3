"""Exposure-time motion blur of a spot and its Wiener deconvolution (paper eq. 15–20).

While a row integrates light (``exposure_s``), the lamp's image moves by
``(u̇, v̇)·exposure_s``. For a lamp at P = (X, Y, Z) in the optical frame moving at
Ṗ relative to the camera, ``u̇ = fx (Ẋ Z − X Ż) / Z²`` and ``v̇ = fy (Ẏ Z − Y Ż) / Z²``
(paper eq. 15–17 give the blur length from the train speed and the viewing geometry).
The blur kernel is a line segment of that length centred on the origin, because a spot
is stamped at the mid-time of its exposure. The restoration itself is scikit-image's
Wiener–Hunt deconvolution (paper eq. 18–20).
"""
import numpy as np
from skimage.restoration import wiener


def image_velocity(point_cam, velocity_cam, fx, fy):
    """Image velocity (u̇, v̇) in px/s of a point (3,) m moving at (3,) m/s (optical frame)."""
    X, Y, Z = np.asarray(point_cam, float)
    dX, dY, dZ = np.asarray(velocity_cam, float)
    return np.array([fx * (dX * Z - X * dZ) / Z ** 2, fy * (dY * Z - Y * dZ) / Z ** 2])


def motion_psf(displacement_px, samples=64):
    """Normalised line-segment PSF of length ``|displacement_px|`` centred at the origin.

    ``displacement_px`` (2,) = (Δu, Δv) over the exposure. Returns an odd-sized
    (rows, cols) kernel whose centre pixel is the origin (skimage's convention), built
    by bilinear splatting of points spread evenly along the segment.
    """
    d = np.asarray(displacement_px, float)
    half = int(np.ceil(0.5 * np.abs(d).max())) + 1
    size = 2 * half + 1
    psf = np.zeros((size, size))
    s = (np.arange(samples) + 0.5) / samples - 0.5
    us, vs = half + s * d[0], half + s * d[1]
    u0, v0 = np.floor(us).astype(int), np.floor(vs).astype(int)
    fu, fv = us - u0, vs - v0
    for du, dv, wt in ((0, 0, (1 - fu) * (1 - fv)), (1, 0, fu * (1 - fv)),
                       (0, 1, (1 - fu) * fv), (1, 1, fu * fv)):
        np.add.at(psf, (v0 + dv, u0 + du), wt)
    return psf / psf.sum()


def wiener_deblur(roi, psf, balance):
    """Wiener–Hunt deconvolution of a background-subtracted ROI (paper eq. 18–20).

    The ROI is zero-padded by the kernel size so the FFT's wrap-around meets dark
    background; ``balance`` is skimage's regularisation weight (Laplacian prior).
    """
    pad = psf.shape[0]
    padded = np.pad(np.asarray(roi, float), pad)
    out = wiener(padded, psf, balance, clip=False)
    return out[pad:-pad, pad:-pad]
