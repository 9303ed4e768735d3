"""Exposure motion blur: kernel, image velocity, and blur-then-deblur."""
import numpy as np
import pytest

from spot_locator.core import deblur as db
from spot_locator.core import synth
from spot_locator.core.detection import detect_spots
from spot_locator.core.locator import LocatorConfig, SpotLocator

F = 1040.0
K = np.array([[F, 0.0, 60.0], [0.0, F, 70.0], [0.0, 0.0, 1.0]])


@pytest.mark.parametrize('shift', [(0.4, 0.0), (3.0, 1.0), (-6.0, 2.5), (0.0, -4.0)])
def test_motion_psf_is_a_centred_segment_of_the_right_length(shift):
    psf = db.motion_psf(shift)
    assert psf.shape[0] == psf.shape[1] and psf.shape[0] % 2 == 1
    assert psf.sum() == pytest.approx(1.0)
    h = psf.shape[0] // 2
    vv, uu = np.indices(psf.shape) - h
    assert (psf * uu).sum() == pytest.approx(0.0, abs=1e-9)
    assert (psf * vv).sum() == pytest.approx(0.0, abs=1e-9)
    # a uniform segment of length L has second moment L²/12 (plus the splat's spread)
    second = (psf * (uu * shift[0] + vv * shift[1])).sum() / np.hypot(*shift)
    assert second == pytest.approx(0.0, abs=1e-9)
    along = (psf * ((uu * shift[0] + vv * shift[1]) / np.hypot(*shift)) ** 2).sum()
    assert along == pytest.approx(np.hypot(*shift) ** 2 / 12, abs=0.2)


def test_image_velocity_matches_the_projection_derivative():
    P, V = np.array([0.8, -0.3, 4.0]), np.array([-20.0, 1.0, -22.0])
    dt = 1e-6
    numeric = (synth.project(K, P + V * dt)[0] - synth.project(K, P - V * dt)[0]) / (2 * dt)
    np.testing.assert_allclose(db.image_velocity(P, V, F, F), numeric, rtol=1e-6)


def _blurred_disc(rng, blur_px):
    """A lamp 6 m ahead, far off-axis, blurred by ``blur_px`` during a long exposure.

    The geometry is the rig's (disc normal and lamp velocity in the optical frame); the
    principal point is moved so the spot lands in a small image. Truth: the ellipse
    centre at mid-exposure (the stamp convention).
    """
    centre = np.array([2.653, -1.226, 5.709]) + rng.uniform(-0.002, 0.002, 3)
    uv = F * centre[:2] / centre[2]
    K = np.array([[F, 0.0, 70.0 - uv[0]], [0.0, F, 80.0 - uv[1]], [0.0, 0.0, 1.0]])
    normal = np.array([0.7547, 0.2978, -0.5846])
    normal /= np.linalg.norm(normal)
    direction = np.array([-0.656, 0.343, -0.672])
    exposure_s = 1e-3
    vel = direction * blur_px / (np.linalg.norm(db.image_velocity(centre, direction, F, F))
                                 * exposure_s)
    exposure = synth.Exposure(row_time_s=1e-9, exposure_s=exposure_s, n_time=32)
    img = synth.render_disc((160, 140), K, centre, normal, 0.1, radiance=200.0,
                            velocity_cam_mps=vel, exposure=exposure, supersample=4)
    mid = centre + vel * 0.5 * exposure_s
    truth = synth.conic_centre(synth.disc_conic(K, mid, normal, 0.1))
    psf = db.motion_psf(db.image_velocity(mid, vel, F, F) * exposure_s)
    return synth.add_noise(img, rng, read_noise=1.5), truth, psf


def test_blur_then_deblur_improves_the_centre_error():
    """A 6-px blur of an off-axis lamp is not symmetric about the mid-exposure image
    (the image velocity varies across the spot under perspective), which pulls the
    paper's centroid; Wiener deconvolution with the predicted kernel removes most of it.
    At this rig's sub-pixel blur the effect is negligible (see the benchmark).
    """
    loc = SpotLocator(LocatorConfig(method='centroid', eccentricity='off', vignetting='none'))
    raw, restored = [], []
    for seed in range(10):
        rng = np.random.default_rng(seed)
        img, truth, psf = _blurred_disc(rng, 6.0)
        region = detect_spots(img)[0]
        for out, roi in ((raw, region.roi),
                         (restored, db.wiener_deblur(region.roi, psf, 0.02))):
            spot = loc.measure(region, roi)
            out.append([spot.u - truth[0], spot.v - truth[1]])
    rms_raw = np.sqrt(np.mean(np.square(raw)))
    rms_restored = np.sqrt(np.mean(np.square(restored)))
    assert rms_restored < 0.6 * rms_raw, (rms_raw, rms_restored)
