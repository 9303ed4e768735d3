"""Track irregularity synthesis (core/track_irregularity.py) against its spectra.

References: the spectra's formulas written out here from the published constants, scipy's
adaptive quadrature of them, a Welch PSD of a long realisation, numerical derivatives.
"""
import numpy as np
import pytest
from scipy.integrate import quad
from scipy.signal import welch
from scipy.stats import kurtosis

from vlc_stereo_camera.core.track_irregularity import (
    CHANNELS,
    SPECTRA,
    IrregularityConfig,
    TrackIrregularity,
    band_variance,
    track_psd,
)

#: Octave bands of spatial frequency (cycles/m) covering 1–120 m wavelength, the top one
#: cut at 120 m.
OCTAVES = [(1.0 / 120.0, 1.0 / 64.0)] + [(2.0 ** -(k + 1), 2.0 ** -k) for k in range(5, -1, -1)]


def test_spectra_are_the_published_formulas():
    """Spot values from the formulas typed out with the published constants."""
    w = np.array([0.05, 0.3, 1.0, 4.0])
    oc, orr, os_, b = 0.8246, 0.0206, 0.4380, 0.75
    den = (w ** 2 + orr ** 2) * (w ** 2 + oc ** 2)
    for name, a_a, a_v in (('german_low', 2.119e-7, 4.032e-7),
                           ('german_high', 6.125e-7, 1.080e-6)):
        np.testing.assert_allclose(track_psd(name, 'vertical', w), a_v * oc ** 2 / den,
                                   rtol=1e-12)
        np.testing.assert_allclose(track_psd(name, 'alignment', w), a_a * oc ** 2 / den,
                                   rtol=1e-12)
        np.testing.assert_allclose(track_psd(name, 'cross_level', w),
                                   a_v / b ** 2 * oc ** 2 * w ** 2 / (den * (w ** 2 + os_ ** 2)),
                                   rtol=1e-12)
    oc = 0.8245
    for cls, a_v, a_a, os_ in ((4, 0.5376, 0.3027, 1.1312), (5, 0.2095, 0.0762, 0.8209),
                               (6, 0.0339, 0.0339, 0.4380)):
        name = f'fra_{cls}'
        shape = 0.25 * 1e-4 * oc ** 2 / (w ** 2 * (w ** 2 + oc ** 2))   # cm² → m²
        np.testing.assert_allclose(track_psd(name, 'vertical', w), a_v * shape, rtol=1e-12)
        np.testing.assert_allclose(track_psd(name, 'alignment', w), a_a * shape, rtol=1e-12)
        height = 4 * 0.25 * a_v * 1e-4 * oc ** 2 / ((w ** 2 + oc ** 2) * (w ** 2 + os_ ** 2))
        np.testing.assert_allclose(track_psd(name, 'cross_level', w), height / 1.5 ** 2,
                                   rtol=1e-12)
    # Better FRA classes are smoother; the high-disturbance German track is rougher.
    for channel in CHANNELS:
        v = [track_psd(f'fra_{k}', channel, 0.2) for k in (4, 5, 6)]
        assert v[0] > v[1] > v[2]
        assert track_psd('german_high', channel, 0.2) > track_psd('german_low', channel, 0.2)
    with pytest.raises(ValueError, match='unknown track spectrum'):
        track_psd('fra_7', 'vertical', w)
    with pytest.raises(ValueError, match='unknown irregularity channel'):
        track_psd('german_low', 'gauge', w)


def test_bin_variance_quadrature():
    lo, hi = 2 * np.pi / 120.0, 2 * np.pi / 60.0
    for name in ('german_low', 'fra_4'):
        for channel in CHANNELS:
            exact = quad(lambda w, n=name, c=channel: track_psd(n, c, w), lo, hi,
                         epsabs=0, epsrel=1e-12)[0]
            assert band_variance(name, channel, lo, hi) == pytest.approx(exact, rel=1e-9)


@pytest.mark.parametrize('spectrum', ['german_low', 'german_high', 'fra_4', 'fra_5', 'fra_6'])
def test_welch_psd_matches_the_standard_in_every_octave(spectrum):
    """Acceptance: a 20 km realisation's Welch PSD integrated over each octave of the
    1–120 m band is the standard's band variance within 25 % (all three channels).
    """
    irregularity = TrackIrregularity(IrregularityConfig(spectrum=spectrum),
                                     np.random.default_rng(11))
    dx = 0.25
    s = np.arange(0.0, 20000.0, dx)
    r = irregularity.values(s)
    f, psd = welch(r, fs=1.0 / dx, nperseg=8192, axis=0)      # m²/(cycle/m), one-sided
    df = f[1] - f[0]
    for c, channel in enumerate(CHANNELS):
        for lo, hi in OCTAVES:
            band = (f >= lo) & (f < hi)
            measured = psd[band, c].sum() * df
            expected = quad(lambda w, ch=channel: track_psd(spectrum, ch, w), 2 * np.pi * lo,
                            2 * np.pi * hi, limit=200)[0]
            assert measured / expected == pytest.approx(1.0, abs=0.25), (channel, lo, hi)
    # Nothing outside the band: below 1/120 and above 1 cycle/m only window leakage.
    outside = (f > 1.1) | (f < 1.0 / 160.0)
    assert psd[outside].sum() * df < 0.02 * np.sum(r.var(axis=0))


def test_realisation_is_gaussian_with_the_band_variance():
    """Variance = ∫S over the band (it is by construction per bin; checked on the samples),
    Gaussian (excess kurtosis near 0), zero mean, amplitudes ∝ scale.
    """
    cfg = IrregularityConfig(spectrum='german_high')
    irregularity = TrackIrregularity(cfg, np.random.default_rng(5))
    s = np.arange(0.0, 30000.0, 0.5)
    r = irregularity.values(s)
    for c, channel in enumerate(CHANNELS):
        expected = quad(lambda w, ch=channel: track_psd('german_high', ch, w),
                        2 * np.pi / 120.0, 2 * np.pi, limit=400)[0]
        assert r[:, c].var() == pytest.approx(expected, rel=0.15)
        assert abs(r[:, c].mean()) < 0.1 * r[:, c].std()
        assert abs(kurtosis(r[:, c])) < 0.3
    # German low disturbance: 2.6 mm vertical, 1.9 mm alignment, 1.2 mrad cross-level.
    low = TrackIrregularity(IrregularityConfig(), np.random.default_rng(5)).values(s)
    np.testing.assert_allclose(low.std(axis=0), [2.6e-3, 1.9e-3, 1.2e-3], rtol=0.15)
    harsh = TrackIrregularity(IrregularityConfig(scale=3.0), np.random.default_rng(5))
    np.testing.assert_allclose(harsh.values(s[:1000]), 3.0 * low[:1000], rtol=1e-12,
                               atol=1e-15)


def test_derivatives_are_analytic_and_vectorised():
    irregularity = TrackIrregularity(IrregularityConfig(spectrum='fra_5'),
                                     np.random.default_rng(2))
    s = np.linspace(-300.0, 900.0, 257)
    r, r_s, r_ss = irregularity.evaluate(s)
    assert r.shape == r_s.shape == r_ss.shape == (257, 3)
    np.testing.assert_allclose(r, irregularity.values(s), atol=1e-15)
    h = 1e-4
    lo, hi = irregularity.evaluate(s - h), irregularity.evaluate(s + h)
    np.testing.assert_allclose((hi[0] - lo[0]) / (2 * h), r_s, atol=1e-7 * np.abs(r_s).max())
    np.testing.assert_allclose((hi[1] - lo[1]) / (2 * h), r_ss, atol=1e-6 * np.abs(r_ss).max())
    scalar = irregularity.evaluate(123.4)
    np.testing.assert_allclose(scalar[0][0], irregularity.evaluate(s[:1] * 0 + 123.4)[0][0])


def test_single_components_and_determinism():
    """from_components reproduces a given sine; a seed fixes the realisation."""
    one = TrackIrregularity.from_components([2 * np.pi / 20.0], [[0.002], [0.0], [0.001]],
                                            [[0.3], [0.0], [1.0]])
    s = np.array([0.0, 5.0, 17.0])
    np.testing.assert_allclose(one.values(s)[:, 0], 0.002 * np.sin(2 * np.pi * s / 20 + 0.3),
                               atol=1e-15)
    np.testing.assert_allclose(one.values(s)[:, 2], 0.001 * np.sin(2 * np.pi * s / 20 + 1.0),
                               atol=1e-15)
    a = TrackIrregularity(rng=np.random.default_rng(8)).values(s)
    b = TrackIrregularity(rng=np.random.default_rng(8)).values(s)
    c = TrackIrregularity(rng=np.random.default_rng(9)).values(s)
    np.testing.assert_array_equal(a, b)
    assert np.all(a != c)
    assert set(SPECTRA) >= {'german_low', 'german_high', 'fra_4', 'fra_5', 'fra_6'}
    with pytest.raises(ValueError, match='unknown track spectrum'):
        IrregularityConfig(spectrum='iso_8608')
