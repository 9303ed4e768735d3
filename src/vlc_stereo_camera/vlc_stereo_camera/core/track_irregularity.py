"""Track irregularity from published one-sided spectra, as functions of chainage.

Three channels, in the track frame (x along, y left, z up):

* ``vertical`` — vertical profile (longitudinal level) of the centreline, m, + up;
* ``alignment`` — lateral alignment of the centreline, m, + left;
* ``cross_level`` — cross-level as the roll angle of the track plane, rad, + lifts the
  left rail (REP-103 roll); the rails' height difference is b_r·angle with
  b_r = 1.5 m between the rail-head centres.

Spectra are one-sided power spectral densities S(Ω) over the spatial angular frequency
Ω = 2π/λ (rad/m), in m²/(rad/m) (vertical, alignment) and rad²/(rad/m) (cross-level), so
that the variance is ∫S(Ω)dΩ.

**German spectra** (low and high disturbance; from ORE B176 measurements, the form used
across vehicle-dynamics literature, e.g. Zhai, *Vehicle–Track Coupled Dynamics*, Springer
2020, ch. 2, and Guo, Xia, De Roeck & Liu, Computers & Structures 112–113 (2012)
205–216)::

    S_v(Ω) = A_v·Ω_c² / ((Ω² + Ω_r²)(Ω² + Ω_c²))
    S_a(Ω) = A_a·Ω_c² / ((Ω² + Ω_r²)(Ω² + Ω_c²))
    S_c(Ω) = (A_v/b²)·Ω_c²·Ω² / ((Ω² + Ω_r²)(Ω² + Ω_c²)(Ω² + Ω_s²))

with Ω_c = 0.8246, Ω_r = 0.0206, Ω_s = 0.4380 rad/m, b = 0.75 m (half the distance of
the wheel-rail contact points); low disturbance A_a = 2.119e-7, A_v = 4.032e-7 m·rad,
high disturbance A_a = 6.125e-7, A_v = 1.080e-6 m·rad. S_c has units 1/(rad/m): the PSD
of the cross-level angle.

**FRA track classes** (US Federal Railroad Administration classes 1–6, 6 the best;
Garg & Dukkipati, *Dynamics of Railway Vehicle Systems*, Academic Press 1984, after
Hamid et al., *Analytical Descriptions of Track Geometry Variations*, FRA/ORD report,
1983), in cm²/(rad/m) with k = 0.25::

    S_v(Ω) = k·A_v·Ω_c² / (Ω²·(Ω² + Ω_c²))
    S_a(Ω) = k·A_a·Ω_c² / (Ω²·(Ω² + Ω_c²))
    S_c(Ω) = 4k·A_v·Ω_c² / ((Ω² + Ω_c²)(Ω² + Ω_s²))       (cross-level height difference)

with Ω_c = 0.8245 rad/m and per class A_v, A_a (cm²·rad/m) and Ω_s (rad/m) from the
table below; converted here to m² (×1e-4) and the cross-level to the angle (÷ b_r²).

**Synthesis** (random-phase harmonic superposition, Shinozuka & Jan, J. Sound Vib. 25
(1972) 111–128): the band [2π/λ_max, 2π/λ_min] is split into log-spaced bins
(``components_per_octave``); bin k contributes A_k·sin(Ω_k·s + φ_k) with Ω_k drawn
uniformly inside the bin (no common period), A_k = √(2·∫_bin S dΩ) (the bin's exact
variance, by Gauss–Legendre quadrature) and φ_k uniform — a stationary, ergodic, Gaussian
(by the central limit theorem) realisation whose PSD is S within the band and zero
outside. The three channels share the frequencies and have independent phases (the
standard spectra are uncorrelated). Values and first and second chainage derivatives
are analytic, so a trajectory gets exact time derivatives (ṙ = r'·v, r̈ = r''·v² + r'·a).
"""
from dataclasses import dataclass

import numpy as np

CHANNELS = ('vertical', 'alignment', 'cross_level')
#: Distance between the rail-head centres of 1435 mm gauge, m (cross-level height ↔ angle).
RAIL_CENTRE_DISTANCE_M = 1.5

_GERMAN_OMEGA_C = 0.8246
_GERMAN_OMEGA_R = 0.0206
_GERMAN_OMEGA_S = 0.4380
_GERMAN_B_M = 0.75
#: (A_a, A_v), m·rad (= m²·rad/m).
_GERMAN = {'german_low': (2.119e-7, 4.032e-7), 'german_high': (6.125e-7, 1.080e-6)}

_FRA_K = 0.25
_FRA_OMEGA_C = 0.8245
#: Class: (A_v, A_a) in cm²·rad/m, Ω_s in rad/m.
_FRA = {1: (1.2107, 3.3634, 0.6046), 2: (1.0181, 1.2107, 0.9308),
        3: (0.6816, 0.4128, 0.8520), 4: (0.5376, 0.3027, 1.1312),
        5: (0.2095, 0.0762, 0.8209), 6: (0.0339, 0.0339, 0.4380)}
_CM2 = 1e-4

#: Spectrum names accepted by :func:`track_psd` and :class:`IrregularityConfig`.
SPECTRA = tuple(_GERMAN) + tuple(f'fra_{k}' for k in sorted(_FRA))

_GL_NODES, _GL_WEIGHTS = np.polynomial.legendre.leggauss(12)


def track_psd(spectrum, channel, omega_radpm):
    """One-sided PSD of a track irregularity channel (module docstring).

    Parameters
    ----------
    spectrum : str
        One of :data:`SPECTRA` (``german_low``, ``german_high``, ``fra_1`` … ``fra_6``).
    channel : str
        One of :data:`CHANNELS`.
    omega_radpm : array_like
        Spatial angular frequency Ω > 0, rad/m.

    Returns
    -------
    ndarray
        S(Ω): m²/(rad/m) for vertical and alignment, rad²/(rad/m) for cross-level.
    """
    w2 = np.square(np.asarray(omega_radpm, dtype=float))
    if channel not in CHANNELS:
        raise ValueError(f'unknown irregularity channel {channel!r}: expected one of '
                         f'{", ".join(CHANNELS)}')
    if spectrum in _GERMAN:
        a_a, a_v = _GERMAN[spectrum]
        c2, r2, s2 = _GERMAN_OMEGA_C ** 2, _GERMAN_OMEGA_R ** 2, _GERMAN_OMEGA_S ** 2
        shape = c2 / ((w2 + r2) * (w2 + c2))
        if channel == 'vertical':
            return a_v * shape
        if channel == 'alignment':
            return a_a * shape
        return a_v / _GERMAN_B_M ** 2 * shape * w2 / (w2 + s2)
    if spectrum.startswith('fra_') and spectrum[4:].isdigit() and int(spectrum[4:]) in _FRA:
        a_v, a_a, omega_s = _FRA[int(spectrum[4:])]
        c2 = _FRA_OMEGA_C ** 2
        if channel == 'cross_level':
            height = 4.0 * _FRA_K * a_v * _CM2 * c2 / ((w2 + c2) * (w2 + omega_s ** 2))
            return height / RAIL_CENTRE_DISTANCE_M ** 2
        amplitude = a_v if channel == 'vertical' else a_a
        return _FRA_K * amplitude * _CM2 * c2 / (w2 * (w2 + c2))
    raise ValueError(f'unknown track spectrum {spectrum!r}: expected one of '
                     f'{", ".join(SPECTRA)}')


def band_variance(spectrum, channel, omega_lo, omega_hi):
    """∫S(Ω)dΩ over [omega_lo, omega_hi] (rad/m, arrays allowed), Gauss–Legendre in log Ω.

    Exact to < 1e-9 relative for bins up to an octave wide (the spectra are smooth
    rational functions); for wider bands split them.
    """
    lo = np.log(np.asarray(omega_lo, dtype=float))[..., None]
    hi = np.log(np.asarray(omega_hi, dtype=float))[..., None]
    x = 0.5 * (hi - lo) * (_GL_NODES + 1.0) + lo                  # log Ω nodes
    omega = np.exp(x)
    return np.sum(0.5 * (hi - lo) * _GL_WEIGHTS * track_psd(spectrum, channel, omega) * omega,
                  axis=-1)


@dataclass
class IrregularityConfig:
    """Spectrum and synthesis band of a :class:`TrackIrregularity`.

    Attributes
    ----------
    spectrum : str
        One of :data:`SPECTRA`.
    wavelength_min_m, wavelength_max_m : float
        Band synthesised, m (default 1–120 m: shorter waves are filtered out by the
        wheelset contact and the primary suspension, longer ones are followed quasi-
        statically by a metro car at ≤ 120 km/h).
    components_per_octave : int
        Harmonic components per octave of the band (48: ≈ 330 over 1–120 m).
    scale : float
        Factor on every amplitude (1 = the standard; a 'harsh' track ≈ 3).
    """

    spectrum: str = 'german_low'
    wavelength_min_m: float = 1.0
    wavelength_max_m: float = 120.0
    components_per_octave: int = 48
    scale: float = 1.0

    def __post_init__(self):
        if self.spectrum not in SPECTRA:
            raise ValueError(f'unknown track spectrum {self.spectrum!r}: expected one of '
                             f'{", ".join(SPECTRA)}')
        if not 0.0 < self.wavelength_min_m < self.wavelength_max_m:
            raise ValueError('need 0 < wavelength_min_m < wavelength_max_m')
        if self.components_per_octave < 1 or self.scale < 0.0:
            raise ValueError('components_per_octave must be >= 1 and scale >= 0')


class TrackIrregularity:
    """A seeded realisation of the three irregularity channels (module docstring).

    Parameters
    ----------
    config : IrregularityConfig or None
    rng : numpy.random.Generator or None
        Draws the frequencies inside their bins and the phases; None = ``default_rng(0)``.

    Attributes
    ----------
    wavenumbers_radpm : ndarray (K,)
        Ω_k, rad/m.
    amplitudes : ndarray (3, K)
        A_ck per channel (m, m, rad).
    phases_rad : ndarray (3, K)
        φ_ck, rad.
    """

    def __init__(self, config=None, rng=None):
        self.config = config or IrregularityConfig()
        rng = rng if rng is not None else np.random.default_rng(0)
        cfg = self.config
        octaves = np.log2(cfg.wavelength_max_m / cfg.wavelength_min_m)
        count = int(np.ceil(octaves * cfg.components_per_octave))
        edges = np.geomspace(2.0 * np.pi / cfg.wavelength_max_m,
                             2.0 * np.pi / cfg.wavelength_min_m, count + 1)
        lo, hi = edges[:-1], edges[1:]
        omega = rng.uniform(lo, hi)
        amplitudes = np.stack([np.sqrt(2.0 * band_variance(cfg.spectrum, c, lo, hi))
                               for c in CHANNELS]) * cfg.scale
        phases = rng.uniform(0.0, 2.0 * np.pi, (len(CHANNELS), count))
        self._set(omega, amplitudes, phases)

    @classmethod
    def from_components(cls, wavenumbers_radpm, amplitudes, phases_rad):
        """An irregularity of given harmonic components (tests, single-wave inputs).

        ``wavenumbers_radpm`` (K,) rad/m; ``amplitudes`` and ``phases_rad`` (3, K) in
        channel order (m, m, rad; rad).
        """
        obj = cls.__new__(cls)
        obj.config = None
        obj._set(np.asarray(wavenumbers_radpm, dtype=float),
                 np.asarray(amplitudes, dtype=float), np.asarray(phases_rad, dtype=float))
        return obj

    def _set(self, omega, amplitudes, phases):
        if amplitudes.shape != (len(CHANNELS), omega.size) or phases.shape != amplitudes.shape:
            raise ValueError('amplitudes and phases must have shape (3, K) for K wavenumbers')
        self.wavenumbers_radpm = omega
        self.amplitudes = amplitudes
        self.phases_rad = phases
        # r_c(s) = Im Σ_k C_ck·exp(iΩ_k s), C = A·exp(iφ)
        self.coefficients = amplitudes * np.exp(1j * phases)

    def psd(self, channel, omega_radpm):
        """The target PSD of ``channel`` (the spectrum times ``scale``²; 0 outside the band)."""
        cfg = self.config
        omega = np.asarray(omega_radpm, dtype=float)
        inside = (omega >= 2.0 * np.pi / cfg.wavelength_max_m) \
            & (omega <= 2.0 * np.pi / cfg.wavelength_min_m)
        return np.where(inside, track_psd(cfg.spectrum, channel, omega) * cfg.scale ** 2, 0.0)

    def phasors(self, chainage_m):
        """exp(iΩ_k·s) (N, K) at chainages ``chainage_m`` (N,)."""
        phase = np.outer(np.atleast_1d(np.asarray(chainage_m, dtype=float)),
                         self.wavenumbers_radpm)
        out = np.empty(phase.shape, dtype=complex)
        np.cos(phase, out=out.real)
        np.sin(phase, out=out.imag)
        return out

    def values(self, chainage_m, chunk=4096):
        """Irregularity (N, 3) at chainages (N,), channel order (m, m, rad)."""
        s = np.atleast_1d(np.asarray(chainage_m, dtype=float))
        out = np.empty((s.size, len(CHANNELS)))
        for i in range(0, s.size, chunk):
            out[i:i + chunk] = (self.phasors(s[i:i + chunk]) @ self.coefficients.T).imag
        return out

    def evaluate(self, chainage_m, phasors=None):
        """Irregularity and its first and second chainage derivatives, (N, 3) each.

        ``phasors``: :meth:`phasors` of ``chainage_m`` if the caller has them already.

        Returns
        -------
        r, r_s, r_ss : ndarray (N, 3)
            Channel order vertical, alignment (m; m/m; 1/m), cross-level (rad; rad/m;
            rad/m²).
        """
        e = self.phasors(chainage_m) if phasors is None else phasors
        k = self.wavenumbers_radpm
        c = self.coefficients.T                                # (K, 3)
        return ((e @ c).imag, (e @ (c * k[:, None])).real,
                -(e @ (c * (k * k)[:, None])).imag)
