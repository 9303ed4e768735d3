"""Each centre method against analytic spots with exact truth; the circularity weight."""
import numpy as np
import pytest

from spot_locator.core import centres as cm
from spot_locator.core import synth
from spot_locator.core.detection import DetectConfig, detect_spots, local_background
from spot_locator.core.locator import METHODS, LocatorConfig, SpotLocator

SHAPE = (90, 80)


def _locators():
    return {m: SpotLocator(LocatorConfig(method=m, eccentricity='off', vignetting='none'))
            for m in METHODS}


def _errors(make_spot, seeds, noise=1.0):
    """RMS (u, v) error per method over spots made by ``make_spot(rng) -> (img, truth)``."""
    locators = _locators()
    errs = {m: [] for m in METHODS}
    for seed in seeds:
        rng = np.random.default_rng(seed)
        img, truth = make_spot(rng)
        regions = detect_spots(synth.add_noise(img, rng, read_noise=noise))
        assert len(regions) == 1
        for m, loc in locators.items():
            spot = loc.measure(regions[0], regions[0].roi)
            assert spot is not None, m
            errs[m].append([spot.u - truth[0], spot.v - truth[1]])
    return {m: np.sqrt(np.mean(np.square(e), axis=0)) for m, e in errs.items()}


def _centre(rng):
    return np.array([40.0, 45.0]) + rng.uniform(-0.5, 0.5, 2)


def test_gaussian_spot_every_method_finds_the_mean():
    def make(rng):
        c = _centre(rng)
        cov = np.array([[5.0, 1.5], [1.5, 9.0]])
        return synth.gaussian_spot(SHAPE, c, cov, peak=200.0), c
    rms = _errors(make, range(8))
    for m in ('centroid', 'ellipse', 'fused'):
        assert np.all(rms[m] < 0.03), (m, rms[m])
    # no stripes, no edges: the chord fit falls back to the signal-weighted row
    assert np.all(rms['chord'] < 0.05), rms['chord']


def test_uniform_ellipse_every_method_finds_the_centre():
    def make(rng):
        c = _centre(rng)
        return synth.ellipse_spot(SHAPE, c, (7.0, 18.0), np.radians(75.0), level=180.0), c
    rms = _errors(make, range(8))
    for m in METHODS:
        assert np.all(rms[m] < 0.03), (m, rms[m])


def test_striped_ellipse_chord_fit_is_unbiased_and_beats_the_paper_methods():
    """Rolling-shutter stripes (dark rows at 5 %) cut the spot's tips unevenly."""
    def make(rng):
        c = _centre(rng)
        img = synth.ellipse_spot(SHAPE, c, (7.0, 18.0), np.radians(75.0), level=180.0)
        gain = synth.square_wave_rows(SHAPE[0], 6.7, phase_rows=rng.uniform(0, 6.7))
        return img * gain[:, None], c
    rms = _errors(make, range(12))
    assert np.all(rms['chord'] < 0.06), rms['chord']
    for m in ('centroid', 'ellipse', 'fused'):
        assert rms['chord'][0] < 0.5 * rms[m][0], (m, rms)


def _hidden_tip_spot(rng, tip, shape=SHAPE, centre=(40.0, 45.0)):
    """A tilted striped ellipse with one tip in a dark stripe: the tip's rows carry the
    lamp's residual 5 % (12 DN, barely above the 8.9 DN detection threshold at this noise),
    so the threshold keeps scattered pixels of them only.
    """
    c = np.asarray(centre) + rng.uniform(-0.5, 0.5, 2)
    img = synth.ellipse_spot(shape, c, (16.0, 5.0), np.radians(70.0), level=240.0)
    gain = synth.square_wave_rows(shape[0], 5.0, duty=0.6, phase_rows=rng.uniform(0, 5))
    top, bottom = int(np.floor(c[1] - 16.0)), int(np.ceil(c[1] + 16.0))
    if tip == 'top':
        gain[:top + 9] = 0.05
    else:
        gain[bottom - 8:] = 0.05
    return img * gain[:, None], c


@pytest.mark.parametrize('tip', ['top', 'bottom'])
def test_chord_fit_is_not_pulled_by_a_tip_hidden_in_a_dark_stripe(tip):
    """The detection's closing joins the dim tip rows' scattered supra-threshold pixels
    into windows that cut their chords short; the one-pass fit (each row over its own
    support) then puts the centre row off by ~0.15 rows, and u by k times that. The
    two-pass fit measures every row between the chord ends of a first ellipse drawn
    through complete rows only.
    """
    new = SpotLocator(LocatorConfig(method='chord', eccentricity='off', vignetting='none'))
    old = SpotLocator(LocatorConfig(method='chord', eccentricity='off', vignetting='none',
                                    chord=cm.ChordConfig(two_pass=False)))
    errs = {'new': [], 'old': []}
    for seed in range(16):
        rng = np.random.default_rng(seed)
        img, c = _hidden_tip_spot(rng, tip)
        region = detect_spots(synth.add_noise(img, rng, read_noise=1.5))[0]
        for name, loc in (('new', new), ('old', old)):
            spot = loc.measure(region, region.roi)
            errs[name].append([spot.u - c[0], spot.v - c[1]])
            if name == 'new':
                assert spot.est.info['passes'] == 2 and spot.est.info['v_from_width']
    rms = {k: np.sqrt(np.mean(np.square(e), axis=0)) for k, e in errs.items()}
    assert rms['new'][0] < 0.025 and rms['new'][1] < 0.06, rms
    assert rms['old'][0] > 2.0 * rms['new'][0] and rms['old'][1] > 2.0 * rms['new'][1], rms


def test_each_spot_is_measured_against_its_own_background_plane():
    """The tunnel background is not flat: the frame's median is 2 DN off at this spot,
    which is a tenth of a dim row's signal; the ring around the spot gives its level and
    its gradient, and the plane is what the ROI has removed.
    """
    shape = (240, 200)
    vv, uu = np.indices(shape)
    ramp = 5.0 * (vv / shape[0] + uu / shape[1])
    for seed in range(4):
        rng = np.random.default_rng(seed)
        img, c = _hidden_tip_spot(rng, 'top', shape, centre=(60.0, 70.0))
        noisy = synth.add_noise(img + ramp, rng, read_noise=1.5, background=4.0)
        region = detect_spots(noisy)[0]
        flat = detect_spots(noisy, DetectConfig(background_plane=False))[0]
        frame = detect_spots(noisy, DetectConfig(local_background=False))[0]
        # the plane's level is given at the centre of the spot's box
        box_c = (region.u0 + 3 + 0.5 * (region.support.shape[1] - 7),
                 region.row_min + 0.5 * (region.row_max - region.row_min))
        truth = 4.0 + 5.0 * (box_c[1] / shape[0] + box_c[0] / shape[1])
        assert abs(region.background - truth) < 0.2, (region.background, truth)
        assert abs(frame.background - truth) > 1.5
        np.testing.assert_allclose(region.background_slope, (5.0 / shape[1], 5.0 / shape[0]),
                                   atol=0.004)
        assert flat.background_slope == (0.0, 0.0)
        # what the ROI had subtracted, pixel by pixel: the plane
        removed = frame.roi - region.roi + frame.background
        expected = ramp[region.v0:region.v0 + region.roi.shape[0],
                        region.u0:region.u0 + region.roi.shape[1]] + 4.0
        assert np.abs(removed - expected).max() < 0.3
    # another lamp in the ring is left out, the ring cut by the image edge still works
    img = np.full((100, 100), 3.0)
    img[0:10, 40:60] = 250.0
    assert local_background(img, (45, 20, 10, 10), 5, 5, 99.0, 12.0) == pytest.approx(
        (3.0, 0.0, 0.0))
    assert local_background(img, (45, 40, 10, 10), 60, 5, 99.0, 12.0) == (99.0, 0.0, 0.0)
    # a gradient, the ring cut by the bottom edge: the plane extrapolates
    ramp = 3.0 + 0.02 * np.indices((100, 100))[1] - 0.03 * np.indices((100, 100))[0]
    level, gu, gv = local_background(ramp, (40, 80, 20, 20), 5, 5, 99.0, 50.0)
    assert (level, gu, gv) == pytest.approx((3.0 + 0.02 * 49.5 - 0.03 * 89.5, 0.02, -0.03))


def _cut_near_lamp(rng, ramp_dn_per_px=(-0.004, 0.008)):
    """The rig's lamp 0.5 m ahead, striped, PSF and halo, on a background gradient, in a
    120 × 200 crop whose bottom edge is the image's: the edge cuts the ellipse 20 rows
    below its centre (its top tip is in, its bottom tip 28 rows off the image).

    Returns the image and the imaged ellipse's centre (crop pixels).
    """
    from vlc_common.core.camera import StereoRig
    rig = StereoRig()
    normal = rig.R_base_cam.T @ np.array([0.0, -1.0, 0.0])
    centre = rig.to_camera(np.array([[0.5, 2.5, 1.4]]), np.zeros(3), np.eye(3), 0)[0]
    K = rig.intrinsics.K.copy()
    K[0, 2] -= 56.0                  # crop columns 56…255, rows 600…719 of the frame
    K[1, 2] -= 600.0
    shape = (120, 200)
    img = synth.render_disc(shape, K, centre, normal, 0.1, radiance=150.0,
                            level=synth.random_chip_level(rng), supersample=4,
                            psf_sigma_px=0.7, halo_sigma_px=6.0, halo_fraction=0.02)
    vv, uu = np.indices(shape)
    img = img + ramp_dn_per_px[0] * uu + ramp_dn_per_px[1] * vv
    truth = synth.conic_centre(synth.disc_conic(K, centre, normal, 0.1))
    return synth.add_noise(img, rng, read_noise=1.5, background=6.0), truth


def test_chord_fit_of_a_spot_cut_by_the_image_edge():
    """The nearest lamp, cut by the bottom edge: the width parabola sees one tip only, so
    the PSF's widening of the tip rows is no longer balanced by the other tip (the vertex
    moves), and the background gradient across its 100-px rows moves every midpoint. The
    symmetric row band and the background plane remove both; each alone is not enough,
    and the reported σ covers the error.
    """
    def locator(plane, symmetric):
        return SpotLocator(LocatorConfig(
            method='chord', eccentricity='off', vignetting='none',
            detect=DetectConfig(background_plane=plane),
            chord=cm.ChordConfig(symmetric_width_rows=symmetric)))
    variants = {'both': locator(True, True), 'plane only': locator(True, False),
                'band only': locator(False, True), 'neither': locator(False, False)}
    errs = {k: [] for k in variants}
    sigma_u = []
    for seed in range(8):
        rng = np.random.default_rng(seed)
        img, c = _cut_near_lamp(rng)
        for name, loc in variants.items():
            region = detect_spots(img, loc.cfg.detect)[0]
            assert region.row_max == img.shape[0] - 1 or region.row_max >= img.shape[0] - 4
            spot = loc.measure(region, region.roi)
            errs[name].append([spot.u - c[0], spot.v - c[1]])
            if name == 'both':
                assert spot.est.info['v_from_width']
                sigma_u.append(spot.est.sigma_u)
    rms = {k: np.sqrt(np.mean(np.square(e), axis=0)) for k, e in errs.items()}
    assert rms['both'][0] < 0.035 and rms['both'][1] < 0.09, rms
    for name in ('plane only', 'band only', 'neither'):
        assert rms[name][0] > 1.3 * rms['both'][0], (name, rms)
    assert rms['neither'][0] > 2.0 * rms['both'][0], rms
    assert np.median(sigma_u) > rms['both'][0], (sigma_u, rms['both'])


def test_chord_fit_on_a_striped_perspective_disc_finds_the_ellipse_centre():
    K = np.array([[1040.0, 0, 60.0], [0, 1040.0, 60.0], [0, 0, 1]])
    normal = np.array([0.75, 0.29, -0.59])
    normal /= np.linalg.norm(normal)
    errs = []
    for seed in range(6):
        rng = np.random.default_rng(seed)
        centre = np.array(rng.uniform(-0.05, 0.05, 3)) + [0.0, 0.0, 3.5]
        Q = synth.disc_conic(K, centre, normal, 0.1)
        img = synth.render_disc((120, 120), K, centre, normal, 0.1, radiance=150.0,
                                level=synth.random_chip_level(rng),
                                exposure=synth.Exposure(t0_s=rng.uniform(0, 0.1), n_time=4),
                                supersample=5)
        region = detect_spots(synth.add_noise(img, rng, read_noise=1.5))[0]
        est = cm.chord_fit(region.roi, region.support, region.noise_sigma)
        errs.append([est.u + region.u0, est.v + region.v0] - synth.conic_centre(Q))
        assert est.conic is not None and est.info['v_from_width']
    rms = np.sqrt(np.mean(np.square(errs), axis=0))
    assert rms[0] < 0.05 and rms[1] < 0.15, rms


def test_chord_fit_reports_a_plausible_uncertainty():
    """The reported σu is of the order of the actual scatter (within a factor of 3)."""
    errs, sigmas = [], []
    for seed in range(16):
        rng = np.random.default_rng(100 + seed)
        c = _centre(rng)
        img = synth.ellipse_spot(SHAPE, c, (5.0, 14.0), np.radians(80.0), level=120.0)
        region = detect_spots(synth.add_noise(img, rng, read_noise=3.0))[0]
        est = cm.chord_fit(region.roi, region.support, region.noise_sigma)
        errs.append(est.u + region.u0 - c[0])
        sigmas.append(est.sigma_u)
    actual = np.sqrt(np.mean(np.square(errs)))
    assert actual / 3 < np.median(sigmas) < 3 * actual, (actual, np.median(sigmas))


def _polygon(a, b, n=2000):
    t = np.linspace(0, 2 * np.pi, n, endpoint=False)
    return np.column_stack([a * np.cos(t), b * np.sin(t)])


def _ramanujan_alpha(a, b):
    perimeter = np.pi * (3 * (a + b) - np.sqrt((3 * a + b) * (a + 3 * b)))
    return 4 * np.pi * np.pi * a * b / perimeter ** 2


def test_circularity_of_known_shapes():
    assert cm.circularity(_polygon(10, 10)) == pytest.approx(1.0, abs=1e-5)
    assert cm.circularity(_polygon(10, 5)) == pytest.approx(_ramanujan_alpha(10, 5), abs=1e-4)
    square = np.array([[0, 0], [1, 0], [1, 1], [0, 1]], float)
    assert cm.circularity(square) == pytest.approx(np.pi / 4, abs=1e-9)
    assert cm.circularity(np.zeros((2, 2))) == 0.0
    # the fitted-ellipse form agrees with the polygon form
    Q = cm._conic_from_params(3.0, 4.0, 10.0, 5.0, 0.3)
    assert cm.ellipse_circularity(Q) == pytest.approx(cm.circularity(_polygon(10, 5)), abs=1e-4)


def test_circularity_of_a_rasterised_disc_is_near_one():
    img = synth.ellipse_spot((60, 60), (30.2, 29.7), (15.0, 15.0), 0.0, level=200.0)
    contour = cm.spot_contour(img, 100.0)
    assert cm.circularity(contour) > 0.99
    img = synth.ellipse_spot((60, 60), (30.2, 29.7), (20.0, 5.0), 0.4, level=200.0)
    assert cm.circularity(cm.spot_contour(img, 100.0)) == pytest.approx(
        _ramanujan_alpha(20, 5), abs=0.02)


def test_fusion_weights_the_centroid_by_circularity():
    c = cm.CentreEstimate(1.0, 2.0, 0.1, 0.1, True)
    e = cm.CentreEstimate(3.0, 6.0, 0.2, 0.2, True, conic=np.eye(3))
    f = cm.fuse_by_circularity(c, e, 1.0)
    assert (f.u, f.v) == (1.0, 2.0)
    f = cm.fuse_by_circularity(c, e, 0.0)
    assert (f.u, f.v) == (3.0, 6.0)
    f = cm.fuse_by_circularity(c, e, 0.25)
    assert (f.u, f.v) == pytest.approx((2.5, 5.0))
    assert cm.fuse_by_circularity(cm.CentreEstimate(), e, 0.5) is e
    assert cm.fuse_by_circularity(c, cm.CentreEstimate(), 0.5) is c


def test_closing_joins_stripes_without_eating_the_tips():
    img = synth.ellipse_spot((60, 30), (15.0, 30.0), (6.0, 20.0), np.pi / 2, level=100.0)
    striped = img * synth.square_wave_rows(60, 8.0, duty=0.5, off_level=0.0)[:, None]
    closed = cm.close_stripes(striped, 9)
    rows_lit = np.nonzero(striped.max(axis=1) > 50)[0]
    rows_closed = np.nonzero(closed.max(axis=1) > 50)[0]
    assert rows_closed[0] == rows_lit[0] and rows_closed[-1] == rows_lit[-1]
    assert len(rows_closed) == rows_closed[-1] - rows_closed[0] + 1   # no gaps left
