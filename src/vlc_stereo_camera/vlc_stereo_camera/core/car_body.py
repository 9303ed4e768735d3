"""Metro car body on its secondary suspension, driven by the track irregularity.

A drop-in alternative to :class:`~vlc_stereo_camera.core.trajectory.Vibration` (same
``evaluate(t_s, s_m, v_mps, a_mps2) -> (q, q̇, q̈)``), for
``Trajectory(profile, vibration=CarBody(CarBodyConfig(...)), alignment=...)``: the
motion of ``base_link`` — a body-fixed point at rail level under the camera, at the head
of the leading car — in the track frame (x along, y left, z up; roll, pitch, yaw about
them, REP-103), as displacement from its nominal place on the design track.

**Excitation.** A :class:`~.track_irregularity.TrackIrregularity` (vertical profile,
alignment, cross-level) under the two bogie centres, each bogie the mean of its two
wheelsets (wheelbase 2w: factor cos(Ω·w) on a harmonic of wavenumber Ω). With the
platform ``platform_ahead_m`` = L ahead of the body centre and bogie centres at ±a
(a = half the bogie centre distance), the bogies are at chainages s − L ± a when the
platform is at s; a harmonic C·e^{iΩs} of the track gives the inputs

    mean of the bogies           C·cos(Ωw)·cos(Ωa)·e^{−iΩL}          (bounce, sway, roll)
    (front − rear) / (2a)        C·cos(Ωw)·i·sin(Ωa)/a·e^{−iΩL}      (pitch, yaw)

— the classic geometric filtering of the bogie spacing (zeros of pitch and yaw at
λ = 2a/n, of bounce and sway at λ = 4a/(2n+1)).

**Modes.** Five uncoupled rigid-body modes of the car body on its secondary suspension,
each a base-excited oscillator with its own natural frequency f_n and damping ratio ζ:
bounce z and sway y (of a body reference point at ``body_reference_height_m``), pitch θ,
roll φ and yaw ψ. Spring and damper act on the relative motion, so the transfer function
from the input u to the mode q is

    H(ω) = (ω_n² + 2iζω_n·ω) / (ω_n² − ω² + 2iζω_n·ω),   ω_n = 2π·f_n,

with H(0) = 1 (at standstill the body rests on the static track geometry), a resonance
near f_n and isolation (|H| ~ 2ζω_n/ω) above it. The real body's lateral and roll motions
are coupled (lower and upper sway modes); here they are kept as separate modes at
frequencies in the same band — the modal description of the response, not a multibody
model. Signs: the front bogie rising pitches the nose up (θ < 0); the front moving left
yaws left (ψ > 0); the bogies' cross-level rolls the body the same way.

**Harmonic solution, quasi-steady in speed.** A harmonic of wavenumber Ω is met at the
angular frequency ω = Ω·v, so each mode is

    Y(s, v) = Im Σ_k H(Ω_k·v)·X_k·e^{iΩ_k·s}     (X_k: the mode's input coefficient)

— exact at constant speed (the steady state of the oscillator; transients of a speed
change are not modelled). Its time derivatives along the motion (ṡ = v, v̇ = a, ȧ = 0 in
the profile's constant-acceleration segments) are exact for this model:

    Ẏ = Y_s·v + Y_v·a,     Ÿ = Y_ss·v² + 2·Y_sv·v·a + Y_vv·a² + Y_s·a,

with ∂/∂v = Ω·H'(ω). Amplitudes therefore grow with speed through the resonances — the
energetic long wavelengths reach the modes' frequencies as v rises — and vanish at
standstill apart from the static geometry under the standing car.

**Platform.** ``base_link`` is at r = (L, 0, −h) from the body reference point, so for
small rotations its displacement is u + (φ, θ, ψ) × r:

    x = −θ·h,    y = y_b + ψ·L + φ·h,    z = z_b − θ·L,    angles (φ, θ, ψ).

**Lateral play.** The body's lateral displacement at the platform relative to the
(irregular) track under it, d = y − y_track(s), is bounded by ``lateral_play_m`` (lateral
bump stops, ±10 mm) through a smooth saturation d ↦ P·tanh(d/P) (linear for |d| ≪ P;
exact derivatives).

**Parameters** (defaults: a B-type metro car — GB 50157-2013, Code for Design of Metro:
car body 19 m, bogie centre distance 12.6 m, bogie wheelbase 2.2–2.3 m; the camera 9 m
ahead of the body centre behind the cab windscreen; body centre of gravity 1.6 m above
rail). Mode frequencies and damping ratios are representative of air-spring secondary
suspensions of passenger and metro stock — body modes between about 0.8 and 2 Hz,
damping ratios 0.1–0.3 (Iwnicki (ed.), *Handbook of Railway Vehicle Dynamics*, CRC Press
2006, chapters on suspension design and ride quality) — not the data of one vehicle.
"""
from dataclasses import dataclass, field

import numpy as np

from vlc_stereo_camera.core.track_irregularity import (
    CHANNELS,
    IrregularityConfig,
    TrackIrregularity,
)

MODES = ('bounce', 'pitch', 'roll', 'sway', 'yaw')
#: Irregularity channel and input kind ('mean' of the bogies or their 'difference'/2a)
#: driving each mode, and the sign of the response.
_MODE_INPUT = {'bounce': ('vertical', 'mean', 1.0), 'pitch': ('vertical', 'difference', -1.0),
               'roll': ('cross_level', 'mean', 1.0), 'sway': ('alignment', 'mean', 1.0),
               'yaw': ('alignment', 'difference', 1.0)}


def _default_frequencies():
    return {'bounce': 1.0, 'pitch': 1.3, 'roll': 0.9, 'sway': 1.1, 'yaw': 1.4}


def _default_damping():
    return {'bounce': 0.20, 'pitch': 0.20, 'roll': 0.15, 'sway': 0.15, 'yaw': 0.15}


@dataclass
class CarBodyConfig:
    """Track spectrum, car geometry and suspension modes of a :class:`CarBody` (SI units).

    Attributes
    ----------
    spectrum : str
        Track spectrum (``track_irregularity.SPECTRA``: ``german_low``, ``german_high``,
        ``fra_1`` … ``fra_6``).
    scale : float
        Factor on the irregularity amplitudes (1 = the standard; about 3 for a 'harsh'
        profile with ≈ 3× the motion). The lateral play bound does not scale.
    seed : int
        Seed of the irregularity realisation (``numpy.random.default_rng(seed)``).
    wavelength_min_m, wavelength_max_m : float
        Band of the irregularity, m.
    components_per_octave : int
        Harmonic components per octave.
    bogie_centre_distance_m : float
        2a, m.
    wheelbase_m : float
        2w, bogie wheelbase, m.
    platform_ahead_m : float
        L, ``base_link`` ahead of the body centre, m.
    body_reference_height_m : float
        h, height of the body reference point (≈ centre of gravity) above rail, m.
    frequencies_hz : dict
        Natural frequency per mode (``bounce``, ``pitch``, ``roll``, ``sway``, ``yaw``), Hz.
    damping : dict
        Damping ratio per mode.
    lateral_play_m : float
        Bound of the lateral displacement relative to the track, m (``inf``: unbounded).
    """

    spectrum: str = 'german_low'
    scale: float = 1.0
    seed: int = 0
    wavelength_min_m: float = 1.0
    wavelength_max_m: float = 120.0
    components_per_octave: int = 48
    bogie_centre_distance_m: float = 12.6
    wheelbase_m: float = 2.2
    platform_ahead_m: float = 9.0
    body_reference_height_m: float = 1.6
    frequencies_hz: dict = field(default_factory=_default_frequencies)
    damping: dict = field(default_factory=_default_damping)
    lateral_play_m: float = 0.010

    def __post_init__(self):
        if set(self.frequencies_hz) != set(MODES) or set(self.damping) != set(MODES):
            raise ValueError(f'frequencies_hz and damping need exactly the modes {MODES}')
        if any(f <= 0.0 for f in self.frequencies_hz.values()) \
                or any(not 0.0 < z < 1.0 for z in self.damping.values()):
            raise ValueError('mode frequencies must be > 0 and damping ratios in (0, 1)')
        if self.bogie_centre_distance_m <= 0.0 or self.wheelbase_m < 0.0 \
                or self.lateral_play_m <= 0.0:
            raise ValueError('bogie_centre_distance_m and lateral_play_m must be > 0, '
                             'wheelbase_m >= 0')

    def irregularity_config(self):
        """The :class:`IrregularityConfig` of this car's track."""
        return IrregularityConfig(spectrum=self.spectrum, wavelength_min_m=self.wavelength_min_m,
                                  wavelength_max_m=self.wavelength_max_m,
                                  components_per_octave=self.components_per_octave,
                                  scale=self.scale)


def transfer(omega_rps, natural_hz, damping):
    """Base-excitation transfer function and its first two ω-derivatives.

    Parameters
    ----------
    omega_rps : ndarray
        Angular frequency ω, rad/s (any sign: H(−ω) = conj H(ω)).
    natural_hz, damping : float
        f_n (Hz) and ζ.

    Returns
    -------
    H, dH/dω, d²H/dω² : complex ndarray
        Dimensionless; s/rad; s²/rad².
    """
    wn = 2.0 * np.pi * natural_hz
    num = wn * wn + 2j * damping * wn * omega_rps
    den = wn * wn - omega_rps * omega_rps + 2j * damping * wn * omega_rps
    dnum = 2j * damping * wn
    dden = -2.0 * omega_rps + 2j * damping * wn
    h = num / den
    h1 = (dnum - h * dden) / den
    h2 = (2.0 * num / den - 2.0 * h1 * dden) / den               # num'' = 0, den'' = −2
    return h, h1, h2


class CarBody:
    """Car-body response to a track irregularity; see the module docstring.

    Parameters
    ----------
    config : CarBodyConfig or None
    irregularity : TrackIrregularity or None
        The track; None = a realisation of ``config``'s spectrum seeded by
        ``config.seed``.
    """

    def __init__(self, config=None, irregularity=None):
        self.config = config or CarBodyConfig()
        cfg = self.config
        self.irregularity = irregularity if irregularity is not None else TrackIrregularity(
            cfg.irregularity_config(), np.random.default_rng(cfg.seed))
        omega = self.irregularity.wavenumbers_radpm
        a = 0.5 * cfg.bogie_centre_distance_m
        wheelsets = np.cos(omega * 0.5 * cfg.wheelbase_m)
        shift = np.exp(-1j * omega * cfg.platform_ahead_m)
        kinds = {'mean': wheelsets * np.cos(omega * a) * shift,
                 'difference': wheelsets * 1j * np.sin(omega * a) / a * shift}
        coefficients = dict(zip(CHANNELS, self.irregularity.coefficients))
        #: Mode → complex input coefficients X_k (K,) of Y = Im Σ H·X·e^{iΩs}.
        self.inputs = {mode: sign * coefficients[channel] * kinds[kind]
                       for mode, (channel, kind, sign) in _MODE_INPUT.items()}

    def modal_coordinates(self, s_m, v_mps, a_mps2, chunk=2048):
        """Mode coordinates and their time derivatives at chainages, speeds, accelerations.

        Parameters
        ----------
        s_m, v_mps, a_mps2 : array_like (N,) or scalar
            Chainage of the platform (m), speed (m/s), acceleration (m/s²).

        Returns
        -------
        dict
            Mode name → (Y, Ẏ, Ÿ), arrays (N,): bounce and sway in m (of the body
            reference point), pitch, roll, yaw in rad.
        """
        s = np.atleast_1d(np.asarray(s_m, dtype=float))
        v = np.broadcast_to(np.asarray(v_mps, dtype=float), s.shape)
        a = np.broadcast_to(np.asarray(a_mps2, dtype=float), s.shape)
        return self._chunked(s, v, a, chunk)[0]

    def _chunked(self, s, v, a, chunk=2048, lateral=False):
        """Modes (and, if ``lateral``, the alignment channel r, r_s, r_ss) in chunks of N."""
        out = {mode: tuple(np.empty(s.shape) for _ in range(3)) for mode in MODES}
        track = tuple(np.empty(s.shape) for _ in range(3)) if lateral else None
        c = CHANNELS.index('alignment')
        for i in range(0, s.size, chunk):
            part = slice(i, i + chunk)
            e = self.irregularity.phasors(s[part])              # shared by both
            for mode, values in self._modes(e, v[part], a[part]).items():
                for target, value in zip(out[mode], values):
                    target[part] = value
            if lateral:
                for target, value in zip(track, self.irregularity.evaluate(s[part], e)):
                    target[part] = value[:, c]
        return out, track

    def _modes(self, e, v, a):
        """Modes at the phasors e = exp(iΩs) (n, K) of n samples."""
        cfg = self.config
        omega = self.irregularity.wavenumbers_radpm
        accelerating = bool(np.any(a != 0.0))
        steady = not accelerating and bool(np.all(v == v[0]))
        result = {}
        for mode in MODES:
            x = self.inputs[mode]
            # Y, Y_s, Y_ss share H: one product with the three coefficient columns.
            columns = np.stack([x, 1j * omega * x, -omega * omega * x], axis=1)    # (K, 3)
            f_n, zeta = cfg.frequencies_hz[mode], cfg.damping[mode]
            if steady:                          # one speed: H is a row, fold it into X
                h = transfer(omega * v[0], f_n, zeta)[0]
                y, y_s, y_ss = (e @ (h[:, None] * columns)).imag.T
            else:
                h, h1, h2 = transfer(np.outer(v, omega), f_n, zeta)   # ω = Ω·v
                y, y_s, y_ss = ((e * h) @ columns).imag.T
            y_dot = y_s * v
            y_ddot = y_ss * v * v + y_s * a
            if accelerating:
                # ∂H/∂v = Ω·H'(ω): Y_v and Y_sv from H', Y_vv from H''.
                y_v, y_sv = ((e * h1) @ np.stack([omega * x, 1j * omega * omega * x],
                                                 axis=1)).imag.T
                y_vv = ((e * h2) @ (omega * omega * x)).imag
                y_dot = y_dot + y_v * a
                y_ddot = y_ddot + 2.0 * y_sv * v * a + y_vv * a * a
            result[mode] = (y, y_dot, y_ddot)
        return result

    def evaluate(self, t_s, s_m, v_mps, a_mps2):
        """Platform motion of all six axes with first and second time derivatives.

        Parameters
        ----------
        t_s : array_like (N,)
            Times, s (the response depends on them only through s, v, a).
        s_m, v_mps, a_mps2 : array_like (N,) or scalar
            Chainage (m), speed (m/s) and acceleration (m/s²) at those times.

        Returns
        -------
        q, q̇, q̈ : ndarray (N, 6)
            Axis order x, y, z (m; m/s; m/s²), roll, pitch, yaw (rad; rad/s; rad/s²),
            in the track frame, as :meth:`Vibration.evaluate`.
        """
        cfg = self.config
        t = np.atleast_1d(np.asarray(t_s, dtype=float))
        s = np.broadcast_to(np.asarray(s_m, dtype=float), t.shape)
        v = np.broadcast_to(np.asarray(v_mps, dtype=float), t.shape)
        a = np.broadcast_to(np.asarray(a_mps2, dtype=float), t.shape)
        bounded = bool(np.isfinite(cfg.lateral_play_m))
        modes, track = self._chunked(s, v, a, lateral=bounded)
        length, height = cfg.platform_ahead_m, cfg.body_reference_height_m
        q, qd, qdd = (np.empty((t.size, 6)) for _ in range(3))
        for k, out in enumerate((q, qd, qdd)):
            bounce, pitch, roll, sway, yaw = (modes[m][k] for m in MODES)
            out[:, 0] = -pitch * height
            out[:, 1] = sway + yaw * length + roll * height
            out[:, 2] = bounce - pitch * length
            out[:, 3], out[:, 4], out[:, 5] = roll, pitch, yaw
        if bounded:
            self._bound_lateral(q, qd, qdd, track, v, a)
        return q, qd, qdd

    def _bound_lateral(self, q, qd, qdd, alignment, v, a):
        """Bound the lateral: y = y_track + P·tanh(d/P), d = y_linear − y_track (exact
        derivatives); ``alignment`` = the track's (r, r_s, r_ss) at the platform.
        """
        play = self.config.lateral_play_m
        r, r_s, r_ss = alignment
        track = r
        track_dot = r_s * v
        track_ddot = r_ss * v * v + r_s * a
        d, d_dot, d_ddot = q[:, 1] - track, qd[:, 1] - track_dot, qdd[:, 1] - track_ddot
        th = np.tanh(d / play)
        sech2 = 1.0 - th * th
        q[:, 1] = track + play * th
        qd[:, 1] = track_dot + sech2 * d_dot
        qdd[:, 1] = track_ddot + sech2 * d_ddot - 2.0 * th * sech2 * d_dot * d_dot / play


def motion_statistics(config=None, speeds_kmh=(20.0, 60.0, 120.0), distance_m=2000.0,
                      step_m=0.25, start_m=0.0):
    """RMS and peak of the platform motion at constant speeds over a stretch of track.

    Parameters
    ----------
    config : CarBodyConfig or None
    speeds_kmh : sequence of float
        Constant speeds, km/h.
    distance_m, step_m, start_m : float
        Stretch [start, start + distance) sampled every ``step_m`` (uniform in time at
        constant speed), m.

    Returns
    -------
    dict
        Speed (km/h) → axis name (``x``, ``y``, ``z``, ``roll``, ``pitch``, ``yaw``) →
        dict with ``rms`` and ``peak`` of q (m or rad, about zero: the irregularity's
        mean) and ``rate_rms`` of q̇ (m/s or rad/s).
    """
    body = CarBody(config)
    s = np.arange(start_m, start_m + distance_m, step_m)
    axes = ('x', 'y', 'z', 'roll', 'pitch', 'yaw')
    result = {}
    for speed in speeds_kmh:
        q, qd, _ = body.evaluate(np.zeros_like(s), s, speed / 3.6, 0.0)
        result[speed] = {name: {'rms': float(np.sqrt(np.mean(q[:, k] ** 2))),
                                'peak': float(np.max(np.abs(q[:, k]))),
                                'rate_rms': float(np.sqrt(np.mean(qd[:, k] ** 2)))}
                         for k, name in enumerate(axes)}
    return result
