"""Perspective eccentricity: closed form, stereo correction, disc normal from the ellipse."""
import numpy as np
import pytest

from spot_locator.core import eccentricity as ecc
from spot_locator.core import synth

F = 1040.0
K = np.array([[F, 0.0, 639.5], [0.0, F, 359.5], [0.0, 0.0, 1.0]])
B = 0.12
R = 0.1


def _normal(rng):
    n = np.array([0.75, 0.29, -0.59]) + rng.normal(0, 0.1, 3)
    return n / np.linalg.norm(n)


def test_closed_form_offset_equals_the_conic_centre_offset():
    rng = np.random.default_rng(0)
    for _ in range(50):
        C = np.array([rng.uniform(-2, 2), rng.uniform(-1, 1), rng.uniform(1.5, 10)])
        n = _normal(rng)
        e = synth.conic_centre(synth.disc_conic(K, C, n, R))
        c = synth.project(K, C)[0]
        np.testing.assert_allclose(ecc.ellipse_centre_offset(C, n, R, F, F), e - c,
                                   atol=1e-7)


def test_rasterised_disc_centroid_is_the_ellipse_centre_not_the_projected_centre():
    C, n = np.array([-0.4, 0.3, 2.0]), np.array([0.75, 0.29, -0.59])
    n /= np.linalg.norm(n)
    img = synth.render_disc((720, 1280), K, C, n, R, supersample=8,
                            exposure=synth.Exposure(n_time=1))
    vv, uu = np.indices(img.shape)
    centroid = np.array([(uu * img).sum(), (vv * img).sum()]) / img.sum()
    e = synth.conic_centre(synth.disc_conic(K, C, n, R))
    c = synth.project(K, C)[0]
    assert np.linalg.norm(centroid - e) < 0.01
    assert np.linalg.norm(e - c) > 0.5        # at 2 m the eccentricity is large


def test_offset_falls_with_range_and_the_disparity_bias_follows_the_cubic_law():
    n = np.array([0.75, 0.29, -0.59])
    n /= np.linalg.norm(n)
    zs = np.linspace(1.5, 10.0, 18)
    C = np.column_stack([0.3 * zs, -0.2 * zs, zs])
    off = np.linalg.norm(ecc.ellipse_centre_offset(C, n, R, F, F), axis=1)
    assert np.all(np.diff(off) < 0)
    bias = (ecc.ellipse_centre_offset(C, n, R, F, F)[:, 0]
            - ecc.ellipse_centre_offset(C - [B, 0, 0], n, R, F, F)[:, 0])
    approx = F * R ** 2 * B * (1 - n[2] ** 2) / zs ** 3
    np.testing.assert_allclose(bias, approx, rtol=0.05)


def test_correct_pair_recovers_the_projected_centres_from_exact_ellipse_centres():
    rng = np.random.default_rng(1)
    for _ in range(20):
        C = np.array([rng.uniform(-1.5, 1.5), rng.uniform(-0.8, 0.8), rng.uniform(1.8, 10)])
        n = _normal(rng)
        e_l = synth.conic_centre(synth.disc_conic(K, C, n, R))
        e_r = synth.conic_centre(synth.disc_conic(K, C - [B, 0, 0], n, R))
        c_l, c_r = synth.project(K, C)[0], synth.project(K, C - [B, 0, 0])[0]
        uv_l, uv_r, off_l, off_r = ecc.correct_pair(e_l, e_r, n, R, F, F, 639.5, 359.5, B)
        np.testing.assert_allclose(uv_l, c_l, atol=2e-4)
        np.testing.assert_allclose(uv_r, c_r, atol=2e-4)
        np.testing.assert_allclose(off_l, e_l - c_l, atol=2e-4)
        # the uncorrected disparity is biased, the corrected one is not
        d_true = c_l[0] - c_r[0]
        assert abs((uv_l[0] - uv_r[0]) - d_true) < 1e-4


def test_triangulation_inverts_projection():
    P = np.array([0.7, -0.4, 6.0])
    P_est = ecc.triangulate(synth.project(K, P)[0], synth.project(K, P - [B, 0, 0])[0],
                            F, F, 639.5, 359.5, B)
    np.testing.assert_allclose(P_est, P, atol=1e-9)


def test_disc_normal_from_the_imaged_ellipse():
    rng = np.random.default_rng(2)
    for _ in range(20):
        C = np.array([rng.uniform(-1, 1), rng.uniform(-0.5, 0.5), rng.uniform(2, 8)])
        n = _normal(rng)
        candidates = ecc.normals_from_conic(synth.disc_conic(K, C, n, R), K)
        assert candidates.shape == (2, 3)
        assert min(ecc.angle_deg(c, n) for c in candidates) < 0.01
        picked = ecc.pick_normal(candidates, n + rng.normal(0, 0.05, 3), 20.0)
        assert ecc.angle_deg(picked, n) < 0.01
    assert ecc.pick_normal(candidates, -n, 20.0) is None


@pytest.mark.parametrize('z', [2.0, 5.0, 9.0])
def test_a_wrong_nominal_normal_leaves_a_residual_that_the_measured_normal_removes(z):
    """A 7.5° heading disturbance turns the disc in the camera frame."""
    n = np.array([0.75, 0.29, -0.59])
    n /= np.linalg.norm(n)
    c, s = np.cos(np.radians(7.5)), np.sin(np.radians(7.5))
    n_true = np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]]) @ n
    C = np.array([0.25 * z, 0.1 * z, z])
    Q = synth.disc_conic(K, C, n_true, R)
    e_l = synth.conic_centre(Q)
    e_r = synth.conic_centre(synth.disc_conic(K, C - [B, 0, 0], n_true, R))
    c_l = synth.project(K, C)[0]
    nominal, _, _, _ = ecc.correct_pair(e_l, e_r, n, R, F, F, 639.5, 359.5, B)
    measured_n = ecc.pick_normal(ecc.normals_from_conic(Q, K), n, 20.0)
    measured, _, _, _ = ecc.correct_pair(e_l, e_r, measured_n, R, F, F, 639.5, 359.5, B)
    assert np.linalg.norm(measured - c_l) < 1e-3
    assert np.linalg.norm(nominal - c_l) > np.linalg.norm(measured - c_l)
