"""Overlapping Allan deviation and the analytic Allan curves of the IMU noise terms.

The estimator follows IEEE Std 952-1997 (annex C): with the integrated signal (angle or
velocity) ``θ_k = Σ_{i<k} y_i · dt`` and cluster time ``τ = m·dt``, the overlapping
Allan variance is

    σ²(τ) = 1 / (2 τ² (N − 2m + 1)) · Σ_k (θ_{k+2m} − 2 θ_{k+m} + θ_k)²

over every k, so one cumulative sum serves every cluster size. Analytic curves:

* white noise of density N (rate/√Hz): σ(τ) = N / √τ (the angle/velocity random walk
  is read off the −1/2 line at τ = 1 s);
* first-order Gauss–Markov process of stationary standard deviation σ and correlation
  time T_c (Xing & Gebre-Egziabher 2008, eq. 7, with q_c² = 2σ²/T_c):

      σ²(τ) = (2 σ² T_c / τ) · [1 − (T_c / 2τ)(3 − 4 e^{−τ/T_c} + e^{−2τ/T_c})]

  whose maximum, ≈ 0.617·σ, lies at τ ≈ 1.89·T_c (``GM_PEAK_*`` below).
"""
from dataclasses import dataclass

import numpy as np

#: τ/T_c at which a first-order Gauss–Markov Allan deviation peaks.
GM_PEAK_TAU_RATIO = 1.8926
#: Peak Allan deviation of a first-order Gauss–Markov process divided by its σ.
GM_PEAK_ADEV_RATIO = 0.6174
#: Allan floor of flicker (bias-instability) noise of coefficient B is 0.664·B.
FLICKER_FLOOR_RATIO = 0.6643


@dataclass
class AllanResult:
    """Allan deviation on a set of cluster times.

    Attributes
    ----------
    tau_s : ndarray (M,)
        Cluster times, seconds.
    adev : ndarray (M,) or (M, C)
        Overlapping Allan deviation, in the units of the input signal, per channel.
    n_terms : ndarray (M,)
        Number of overlapping second differences averaged for each cluster time.
    """

    tau_s: np.ndarray
    adev: np.ndarray
    n_terms: np.ndarray


def cluster_sizes(n_samples, points_per_decade=10, max_fraction=0.1):
    """Log-spaced distinct cluster sizes m from 1 to ``max_fraction · n_samples``.

    Parameters
    ----------
    n_samples : int
        Length of the signal.
    points_per_decade : int
        Density of the log grid before integer rounding removes duplicates.
    max_fraction : float
        Largest cluster as a fraction of the record (0.1 keeps at least ten
        non-overlapping clusters, so the longest point is still meaningful).

    Returns
    -------
    ndarray (M,) of int
    """
    m_max = int(max_fraction * n_samples)
    if m_max < 1:
        raise ValueError(f'{n_samples} samples are too few for an Allan deviation')
    # Exponents k/points_per_decade keep every power of ten on the grid.
    k = np.arange(int(np.floor(np.log10(m_max) * points_per_decade + 1e-9)) + 1)
    return np.unique(np.round(10.0 ** (k / points_per_decade)).astype(np.int64))


def overlapping_adev(y, rate_hz, m=None):
    """Overlapping Allan deviation of a uniformly sampled rate signal.

    Parameters
    ----------
    y : array_like (N,) or (N, C)
        Samples (angular rate, specific force, ...), one row per sample.
    rate_hz : float
        Sample rate, Hz.
    m : array_like of int, optional
        Cluster sizes in samples; default :func:`cluster_sizes` (N).

    Returns
    -------
    AllanResult
        ``adev`` has shape (M,) for 1-D input and (M, C) otherwise.
    """
    y = np.asarray(y, dtype=float)
    squeeze = y.ndim == 1
    if squeeze:
        y = y[:, None]
    n = y.shape[0]
    m = cluster_sizes(n) if m is None else np.asarray(m, dtype=np.int64)
    if np.any(m < 1) or np.any(2 * m > n):
        raise ValueError('cluster sizes must lie in 1 .. N/2')
    dt = 1.0 / rate_hz
    # The Allan variance ignores a constant offset; removing the mean keeps the
    # cumulative sum small so that its second differences do not lose precision.
    theta = np.zeros((n + 1, y.shape[1]))
    np.cumsum((y - y.mean(axis=0)) * dt, axis=0, out=theta[1:])
    tau = m * dt
    avar = np.empty((len(m), y.shape[1]))
    n_terms = n + 1 - 2 * m
    for i, mi in enumerate(m):
        d = theta[2 * mi:] - 2.0 * theta[mi:n + 1 - mi] + theta[:n + 1 - 2 * mi]
        avar[i] = np.einsum('ij,ij->j', d, d) / (2.0 * tau[i] ** 2 * n_terms[i])
    adev = np.sqrt(avar)
    return AllanResult(tau_s=tau, adev=adev[:, 0] if squeeze else adev, n_terms=n_terms)


def white_adev(tau_s, density):
    """Allan deviation σ(τ) = N/√τ of white noise of density N (units/√Hz)."""
    return density / np.sqrt(np.asarray(tau_s, dtype=float))


def gauss_markov_adev(tau_s, sigma, corr_time_s):
    """Allan deviation of a first-order Gauss–Markov process (module docstring formula).

    Parameters
    ----------
    tau_s : array_like (M,)
        Cluster times, seconds.
    sigma : float
        Stationary standard deviation of the process.
    corr_time_s : float
        Correlation time T_c, seconds.
    """
    x = np.asarray(tau_s, dtype=float) / corr_time_s
    small = x < 1e-2
    xs = np.where(small, 1.0, x)
    exact = (1.0 - (3.0 - 4.0 * np.exp(-xs) + np.exp(-2.0 * xs)) / (2.0 * xs)) / xs
    # The bracket cancels catastrophically for τ << T_c: use its Taylor series there
    # (leading term 2σ²·x/3, the rate random walk of the driving noise).
    series = x / 3.0 - x ** 2 / 4.0 + 7.0 * x ** 3 / 60.0
    return np.sqrt(2.0 * sigma ** 2 * np.where(small, series, exact))


def fit_white_density(tau_s, adev, tau_min_s, tau_max_s):
    """Density N of the −1/2-slope line σ = N/√τ fitted over [tau_min_s, tau_max_s].

    Least squares in log–log with the slope fixed at −1/2, i.e. the geometric mean of
    σ(τ)·√τ; the result is the random walk read at τ = 1 s on that line.

    Returns
    -------
    float or ndarray (C,)
    """
    tau_s = np.asarray(tau_s, dtype=float)
    sel = (tau_s >= tau_min_s) & (tau_s <= tau_max_s)
    if not np.any(sel):
        raise ValueError(f'no cluster time within [{tau_min_s}, {tau_max_s}] s')
    adev = np.asarray(adev, dtype=float)[sel]
    scaled = adev * (np.sqrt(tau_s[sel]) if adev.ndim == 1 else np.sqrt(tau_s[sel])[:, None])
    return np.exp(np.mean(np.log(scaled), axis=0))


def allan_floor(tau_s, adev, tau_min_s, tau_max_s):
    """Minimum of the Allan deviation over [tau_min_s, tau_max_s] and where it lies.

    The in-run bias stability of a datasheet is this minimum (the "lowest point of the
    Allan curve").

    Returns
    -------
    floor : float or ndarray (C,)
    tau_at_floor_s : float or ndarray (C,)
    """
    tau_s = np.asarray(tau_s, dtype=float)
    sel = np.flatnonzero((tau_s >= tau_min_s) & (tau_s <= tau_max_s))
    if sel.size == 0:
        raise ValueError(f'no cluster time within [{tau_min_s}, {tau_max_s}] s')
    adev = np.asarray(adev, dtype=float)[sel]
    i = np.argmin(adev, axis=0)
    floor = np.take_along_axis(adev, np.atleast_1d(i)[None, ...], axis=0)[0] \
        if adev.ndim > 1 else adev[i]
    return floor, tau_s[sel][i]
