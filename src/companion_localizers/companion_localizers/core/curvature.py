"""Companion method 4: curvature-array correlation (no camera, no lamps).

The line's horizontal curvature κ(s) is a fingerprint of the chainage: the train
measures the curvature of the track it has just run over — its yaw rate over its speed,
κ = ψ̇/v — and finds where that piece of curvature profile fits the line's template.

* **Template** (:class:`CurvatureTemplate`): κ(s) of the alignment every ``spacing_m``
  (1 m), extended by ``template_padding_m`` of straight track before and after, and
  Gaussian-smoothed with the real-time array's σ.
* **Real-time array** (:class:`CurvatureArray`): the gyro's z rate and the speed are
  integrated sample by sample (trapezoid) into heading ψ and distance d; ψ is read
  every ``spacing_m`` of d and κ_i = (ψ_i − ψ_{i−1})/spacing — the mean of ψ̇/v over
  each metre, which stays finite when the train slows down. Below ``min_speed_mps``
  nothing is integrated (a standing train adds no distance, and its gyro output is
  only bias): those samples update a running estimate of the gyro z bias, subtracted
  while moving.
* **Smoothing.** The platform's yaw vibration (±6°, 0.45–2.3 Hz in the rig) is bounded
  in heading but its rate is up to 10× the track's yaw rate. It is periodic in time,
  so in distance its wavelength grows with the speed (0.45 Hz: 49 m at 80 km/h, 74 m
  at 120 km/h): both arrays are smoothed by a Gaussian of σ = ``smoothing_time_s`` ×
  the mean speed, within [``min_smoothing_sigma_m``, ``max_smoothing_sigma_m``] (1.2 s
  attenuates the 0.45 Hz term by exp(−2π²f²τ²) ≈ 0.3 %), the template with the same σ.
* **Matching** (:func:`match`): the array is smoothed over its whole length and 3σ are
  cut at both ends (there the filter sees past the array, unlike the template's); the
  last ``window_m`` metres of the rest are resampled for each sampling ratio r = true
  distance / measured distance from 0 to 1.8 in steps of 0.01 (r absorbs a speed
  scale error, e.g. worn wheels: r = 1/(1 + error)) and slid along the template. The
  Pearson correlation coefficient ρ of every (r, position) pair comes from FFTs and
  cumulative sums. Ratios whose resampled window is shorter than
  ``min_matched_length_m`` are skipped (r → 0 squeezes the array onto a point).
* **Physical gates.** Pearson's ρ ignores the offset and scale of the curvature, and
  with r free also its stretch: a left curve followed by a straight then correlates
  perfectly with a straight followed by a right curve (after the mean is removed both
  are one step). Two quantities that ρ discards are known, and a candidate must agree
  with them: the least-squares fit x ≈ β·T + c of the array x on the template window T
  must have an amplitude β within ``max_amplitude_error`` of r (the speed error that
  stretches the array by 1/r also divides ω/v by 1/r) and an offset |c| below
  3·σ_b/v̄ + ``offset_tolerance_1pm`` (a constant gyro-bias residual σ_b at the mean
  speed v̄ is the only cause of an offset; σ_b = ``learnt_bias_sigma_rps`` once the
  bias was learnt at standstill, else ``gyro_bias_sigma_rps``).
* **Result**: the best gated (r, position), its ratio refined tenfold around the best
  step (a 0.01 step of r moves the end of a 600 m window by 6 m), gives the chainage of
  the window's last sample, refined to sub-metre by a parabola through the correlation
  peak, and extrapolated to the newest IMU sample by r × the distance run since.
* **Refusal**: an array whose smoothed curvature has a standard deviation below
  ``min_signal_std_1pm`` carries no curvature signal (straight track, or a curve too
  gentle to tell from the vibration and sensor noise): status ``no_curvature_signal``,
  no chainage. A best ρ₁ below ``min_correlation`` is refused as ``low_correlation``.
  A best whose Fisher transform atanh ρ₁ exceeds that of the best *distinct* candidate
  ρ₂ (a gated window overlapping the best one by less than half: another stretch of the
  line) by less than ``min_z_margin`` is refused as ``ambiguous``. Fisher's z, not ρ:
  0.999 against 0.98 is a tenfold difference in unexplained variance, 0.93 against 0.91
  a small one. Above ``correlation_cap`` (0.995) coefficients count as equal: there the
  remaining misfit is the model's own (smoothing and resampling), and two copies of the
  same curve would otherwise be told apart by noise. Finally, a window holding only part
  of a curve (one transition and a bit of arc) fits almost equally well stretched a
  little more or less: the window ends of the best hypothesis's candidates within
  ``spread_z`` of its z span a *spread*; above ``max_spread_m`` the match is refused as
  ``imprecise`` (typically in the first 100–200 m after acquisition).

Confidence (heuristic, [0, 1]): ρ₁·min(1, Δz/(2·min_z_margin)), Δz = atanh ρ₁ −
atanh ρ₂; 0 when no chainage is given.

Chainage 1σ of an accepted match (:func:`chainage_sigma`): sqrt(floor² + spread² +
short²), ``chainage_sigma_floor_m`` (1.5 m) for a full window, the spread, and up to
``short_window_sigma_m`` (4 m) while the window is still shorter than ``window_m``
(errors of 3–4 m occur there); fitted to the synthetic runs of ``curvature_benchmark``.
It is what ``train_localizer`` uses as the variance of a re-acquisition aid.

No ROS here.
"""
import bisect
from dataclasses import dataclass
import math
import time

import numpy as np
from scipy.ndimage import gaussian_filter1d

STATUS_OK = 'ok'
STATUS_TOO_SHORT = 'too_short'
STATUS_NO_SIGNAL = 'no_curvature_signal'
STATUS_LOW_CORRELATION = 'low_correlation'
STATUS_AMBIGUOUS = 'ambiguous'
STATUS_IMPRECISE = 'imprecise'
STATUSES = (STATUS_OK, STATUS_TOO_SHORT, STATUS_NO_SIGNAL, STATUS_LOW_CORRELATION,
            STATUS_AMBIGUOUS, STATUS_IMPRECISE)
_WAIT = object()     # CurvatureLocalizer: an IMU sample's speed has not arrived yet


@dataclass
class CurvatureConfig:
    """Parameters of the curvature-correlation localizer (SI units).

    Attributes
    ----------
    spacing_m : float
        Sample spacing of the template and the real-time array, m (1 m).
    smoothing_time_s : float
        σ of the Gaussian smoothing of both arrays in time: σ = this × mean speed, s.
    min_smoothing_sigma_m, max_smoothing_sigma_m : float
        Bounds of that σ, m.
    window_m : float
        Length of the real-time array matched (after the 3σ margins), measured metres.
    min_window_m : float
        Shortest matched array (status ``too_short`` before), measured metres.
    ratio_min, ratio_max, ratio_step : float
        Sampling-ratio search r = true / measured distance (0 … 1.8 by 0.01).
    min_matched_length_m : float
        Ratios whose resampled window is shorter than this are skipped, m.
    template_padding_m : float
        Straight track added before and after the alignment's extent in the template, m.
    min_speed_mps : float
        Below this speed nothing is integrated and the gyro bias is learnt, m/s.
    bias_time_constant_s : float
        Time constant of the standstill gyro-bias average, s.
    max_gap_s : float
        A gap between IMU samples longer than this restarts the array, s.
    min_signal_std_1pm : float
        Least standard deviation of the smoothed real-time curvature that counts as a
        curvature signal, 1/m; template windows flatter than this are not candidates.
    min_correlation : float
        Least Pearson coefficient of an accepted match.
    min_z_margin : float
        Least difference of Fisher's z = atanh ρ between the best and the best distinct
        candidate.
    correlation_cap : float
        Coefficients above this count as equal in the margin test (see module docstring).
    spread_z : float
        Candidates of the best hypothesis within this Fisher z of the best count in the
        chainage spread.
    max_spread_m : float
        Largest accepted chainage spread (half the range of those candidates' window
        ends), m.
    max_amplitude_error : float
        Largest relative deviation of a candidate's fitted amplitude β from r.
    gyro_bias_sigma_rps : float
        1σ gyro z bias before it was learnt at standstill, rad/s (ADIS16488 turn-on
        bias 0.2°/s).
    learnt_bias_sigma_rps : float
        1σ gyro z bias residual after learning at standstill, rad/s.
    offset_tolerance_1pm : float
        Offset allowed besides the bias term (smoothing and resampling mismatch), 1/m.
    chainage_sigma_floor_m : float
        1σ of an accepted match's chainage with a full window and no spread, m (see
        :attr:`CurvatureMatch.chainage_sigma_m`).
    short_window_sigma_m : float
        1σ added for a window of only ``min_window_m``, decreasing linearly to 0 at
        ``window_m``, m.
    """

    spacing_m: float = 1.0
    smoothing_time_s: float = 1.2
    min_smoothing_sigma_m: float = 25.0
    max_smoothing_sigma_m: float = 70.0
    window_m: float = 600.0
    min_window_m: float = 300.0
    ratio_min: float = 0.0
    ratio_max: float = 1.8
    ratio_step: float = 0.01
    min_matched_length_m: float = 100.0
    template_padding_m: float = 1200.0
    min_speed_mps: float = 0.5
    bias_time_constant_s: float = 10.0
    max_gap_s: float = 0.5
    min_signal_std_1pm: float = 3.0e-4
    min_correlation: float = 0.8
    min_z_margin: float = 0.5
    correlation_cap: float = 0.995
    spread_z: float = 0.1
    max_spread_m: float = 8.0
    max_amplitude_error: float = 0.3
    gyro_bias_sigma_rps: float = 0.2 * math.pi / 180.0
    learnt_bias_sigma_rps: float = 1.0e-4
    offset_tolerance_1pm: float = 1.0e-4
    chainage_sigma_floor_m: float = 1.5
    short_window_sigma_m: float = 4.0

    def __post_init__(self):
        positive = ('spacing_m', 'smoothing_time_s', 'min_smoothing_sigma_m', 'window_m',
                    'min_window_m', 'ratio_step',
                    'min_matched_length_m', 'bias_time_constant_s', 'max_gap_s',
                    'min_signal_std_1pm', 'max_amplitude_error')
        for name in positive:
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0.0):
                raise ValueError(f'{name} must be finite and > 0, got {value}')
        for name in ('ratio_min', 'template_padding_m', 'min_speed_mps', 'min_z_margin',
                     'spread_z', 'max_spread_m',
                     'gyro_bias_sigma_rps', 'learnt_bias_sigma_rps', 'offset_tolerance_1pm',
                     'chainage_sigma_floor_m', 'short_window_sigma_m'):
            value = getattr(self, name)
            if not (math.isfinite(value) and value >= 0.0):
                raise ValueError(f'{name} must be finite and >= 0, got {value}')
        if not self.ratio_max > self.ratio_min:
            raise ValueError(f'ratio_max {self.ratio_max} must exceed ratio_min {self.ratio_min}')
        if not self.min_window_m <= self.window_m:
            raise ValueError(f'min_window_m {self.min_window_m} must be <= window_m '
                             f'{self.window_m}')
        if not self.max_smoothing_sigma_m >= self.min_smoothing_sigma_m:
            raise ValueError(f'max_smoothing_sigma_m {self.max_smoothing_sigma_m} must be >= '
                             f'min_smoothing_sigma_m {self.min_smoothing_sigma_m}')
        if not -1.0 <= self.min_correlation <= 1.0:
            raise ValueError(f'min_correlation must be in [-1, 1], got {self.min_correlation}')
        if not 0.0 < self.correlation_cap < 1.0:
            raise ValueError(f'correlation_cap must be in (0, 1), got {self.correlation_cap}')

    def smoothing_sigma_m(self, speed_mps):
        """σ of the smoothing at a mean speed, m (see the module docstring)."""
        return float(np.clip(self.smoothing_time_s * speed_mps, self.min_smoothing_sigma_m,
                             self.max_smoothing_sigma_m))

    @property
    def buffer_m(self):
        """Real-time array kept: the matched window plus the largest smoothing margin
        (3σ) at each end, m.
        """
        return self.window_m + 6.0 * self.max_smoothing_sigma_m

    @property
    def ratios(self):
        """The sampling ratios searched, (K,)."""
        n = int(math.floor((self.ratio_max - self.ratio_min) / self.ratio_step + 1e-9)) + 1
        return self.ratio_min + self.ratio_step * np.arange(n)


class CurvatureTemplate:
    """The line's curvature every ``spacing_m``, smoothed on demand, with window sums.

    Parameters
    ----------
    alignment : vlc_common.core.alignment.Alignment
    config : CurvatureConfig
    """

    def __init__(self, alignment, config):
        self.alignment = alignment
        self.config = config
        pad = config.template_padding_m
        self.chainage_m, self.curvature_raw_1pm = alignment.curvature_template(
            config.spacing_m, alignment.start_chainage_m - pad, alignment.end_chainage_m + pad)
        self._nfft = 1 << int(math.ceil(math.log2(len(self.chainage_m))))
        self._cache = {}

    @property
    def has_curvature(self):
        """False on a line with no curve: the method cannot localise there at all."""
        smooth = self.smoothed(self.config.min_smoothing_sigma_m)[0]
        return bool(np.std(smooth) >= self.config.min_signal_std_1pm)

    def smoothed(self, sigma_m):
        """(κ smoothed with σ = ``sigma_m`` rounded to 1 m, Σκ, Σκ², rfft κ); cached."""
        key = max(1, int(round(sigma_m)))
        if key not in self._cache:
            k = gaussian_filter1d(self.curvature_raw_1pm, key / self.config.spacing_m,
                                  mode='nearest')
            self._cache[key] = (k, np.concatenate([[0.0], np.cumsum(k)]),
                                np.concatenate([[0.0], np.cumsum(k * k)]),
                                np.fft.rfft(k, self._nfft))
        return self._cache[key]

    def sliding_fit(self, x, ratio, max_offset_1pm, sigma_m):
        """Pearson ρ of ``x`` (M,) with every template window of M samples, gated.

        Parameters
        ----------
        x : ndarray (M,)
            Real-time curvature resampled to true metres, 1/m.
        ratio : float
            The sampling ratio r that produced ``x``.
        max_offset_1pm : float
            Largest admissible offset |c| of the fit x ≈ β·T + c, 1/m.
        sigma_m : float
            Smoothing of the template to compare with, m.

        Returns
        -------
        ndarray (L − M + 1,)
            ρ per window start; −inf for windows flatter than ``min_signal_std_1pm``,
            with β outside r·(1 ± ``max_amplitude_error``) or with |c| above the bound.
        """
        kappa, csum, csum2, spectrum = self.smoothed(sigma_m)
        m = len(x)
        n = len(kappa) - m + 1
        if n <= 0:
            return np.full(0, -np.inf)
        x_mean = float(x.mean())
        xc = x - x_mean
        norm_x = math.sqrt(float(xc @ xc))
        # Σ_k xc[k]·T[j + k] for every window start j (circular wrap cannot reach j ≤ L − M).
        cross = np.fft.irfft(spectrum * np.conj(np.fft.rfft(xc, self._nfft)), self._nfft)[:n]
        s1 = csum[m:m + n] - csum[:n]
        s2 = csum2[m:m + n] - csum2[:n]
        var_t = np.maximum(s2 - s1 * s1 / m, 0.0)          # M × window variance
        reject = var_t < m * self.config.min_signal_std_1pm ** 2
        with np.errstate(divide='ignore', invalid='ignore'):
            rho = cross / (np.sqrt(var_t) * norm_x)
            beta = cross / var_t
            offset = x_mean - beta * s1 / m
            reject |= ~(np.abs(beta / ratio - 1.0) <= self.config.max_amplitude_error)
            reject |= ~(np.abs(offset) <= max_offset_1pm)
        rho[reject] = -np.inf
        return rho


@dataclass
class ArrayWindow:
    """The newest part of the real-time array (see :meth:`CurvatureArray.window`).

    Attributes
    ----------
    distance_m : ndarray (N,)
        Measured distance of each sample since the array's restart, m.
    time_s : ndarray (N,)
        Time each sample was reached, s.
    curvature_1pm : ndarray (N,)
        κ over the metre ending at the sample, 1/m.
    distance_now_m : float
        Measured distance at the newest IMU sample, m.
    bias_learnt : bool
        The gyro z bias was learnt at standstill.
    """

    distance_m: np.ndarray
    time_s: np.ndarray
    curvature_1pm: np.ndarray
    distance_now_m: float
    bias_learnt: bool


class CurvatureArray:
    """The real-time curvature array from the gyro z rate and the speed.

    Feed samples in time order with :meth:`add`; :meth:`window` gives the newest
    ``buffer_m`` metres. See the module docstring.
    """

    def __init__(self, config):
        self.config = config
        self.bias_rps = 0.0
        self.bias_learnt = False
        self.rejected = 0
        self.restarts = 0
        self.reset()

    def reset(self):
        """Forget the array (after a gap): distance and heading restart at 0."""
        self.distance_m = 0.0
        self.heading_rad = 0.0
        keep = int(math.ceil(self.config.buffer_m / self.config.spacing_m)) + 2
        self._headings = np.zeros(keep)      # ring of ψ at d = k·spacing
        self._times = np.zeros(keep)         # and the time it was reached
        self._count = 0                      # grid samples written since the restart
        self._last = None                    # previous (t, ω, v)

    @property
    def samples(self):
        """Number of 1 m heading samples collected since the last restart."""
        return self._count

    @property
    def last_time_s(self):
        """Time of the newest accepted sample, or None."""
        return None if self._last is None else self._last[0]

    def add(self, t_s, yaw_rate_rps, speed_mps):
        """Integrate samples (arrays (N,) or scalars) in time order.

        Samples with a non-finite value, a negative speed or a time not after the previous
        sample are skipped (counted in ``rejected``); a gap longer than ``max_gap_s``
        restarts the array (counted in ``restarts``). Returns the number accepted.
        """
        t = np.atleast_1d(np.asarray(t_s, dtype=float))
        w = np.broadcast_to(np.asarray(yaw_rate_rps, dtype=float), t.shape)
        v = np.broadcast_to(np.asarray(speed_mps, dtype=float), t.shape)
        accepted = 0
        cfg = self.config
        for ti, wi, vi in zip(t.tolist(), w.tolist(), v.tolist()):
            if not (math.isfinite(ti) and math.isfinite(wi) and math.isfinite(vi)) or vi < 0.0:
                self.rejected += 1
                continue
            if self._last is not None and ti <= self._last[0]:
                self.rejected += 1
                continue
            accepted += 1
            previous, self._last = self._last, (ti, wi, vi)
            if previous is None:
                continue
            t0, w0, v0 = previous
            dt = ti - t0
            if dt > cfg.max_gap_s:
                self.restarts += 1
                self.reset()
                self._last = (ti, wi, vi)
                continue
            v_mean = 0.5 * (v0 + vi)
            w_mean = 0.5 * (w0 + wi)
            if v_mean < cfg.min_speed_mps:
                # Standstill: the gyro shows its bias (exponential average).
                alpha = min(1.0, dt / cfg.bias_time_constant_s) if self.bias_learnt else 1.0
                self.bias_rps += alpha * (w_mean - self.bias_rps)
                self.bias_learnt = True
                continue
            d0, psi0 = self.distance_m, self.heading_rad
            self.distance_m = d0 + v_mean * dt
            self.heading_rad = psi0 + (w_mean - self.bias_rps) * dt
            self._sample_between(t0, d0, psi0, ti)
        return accepted

    def _sample_between(self, t0, d0, psi0, t1):
        """Write ψ and t at every grid distance k·spacing in [d0, distance_m]."""
        sp = self.config.spacing_m
        last = int(math.floor(self.distance_m / sp))
        span = self.distance_m - d0
        n = len(self._headings)
        for k in range(self._count, last + 1):
            f = (k * sp - d0) / span
            self._headings[k % n] = psi0 + f * (self.heading_rad - psi0)
            self._times[k % n] = t0 + f * (t1 - t0)
            self._count = k + 1

    def window(self):
        """The newest ``buffer_m`` metres as an :class:`ArrayWindow`.

        κ_i = (ψ_i − ψ_{i−1})/spacing; distances in measured (odometry) metres since the
        restart.
        """
        sp = self.config.spacing_m
        n_psi = min(self._count, len(self._headings), int(round(self.config.buffer_m / sp)) + 1)
        if n_psi < 2:
            empty = np.zeros(0)
            return ArrayWindow(empty, empty, empty, self.distance_m, self.bias_learnt)
        idx = np.arange(self._count - n_psi, self._count)
        psi = self._headings[idx % len(self._headings)]
        times = self._times[idx % len(self._headings)]
        return ArrayWindow(idx[1:] * sp, times[1:], np.diff(psi) / sp, self.distance_m,
                           self.bias_learnt)


@dataclass
class CurvatureMatch:
    """Result of one correlation search.

    Attributes
    ----------
    status : str
        One of :data:`STATUSES`.
    chainage_m : float
        Chainage at the newest IMU sample (``ok`` only; NaN otherwise), m.
    end_chainage_m : float
        Chainage of the matched window's last sample (best candidate, also when
        refused), m.
    ratio : float
        Best sampling ratio r (true / measured distance); 1/r − 1 is the speed scale error.
    correlation, second_correlation : float
        Best Pearson coefficient, and the best distinct candidate's (−1 if none).
    confidence : float
        See the module docstring; 0 unless ``ok``.
    signal_std_1pm : float
        Standard deviation of the smoothed real-time curvature, 1/m.
    measured_length_m : float
        Length of the real-time array matched, measured metres.
    cpu_s : float
        Processor time of the search, s.
    spread_m : float
        Half the range of window ends that fit almost as well (see module docstring), m.
    chainage_sigma_m : float
        1σ of ``chainage_m`` (``ok`` only; NaN otherwise), m: the root sum of squares of
        ``chainage_sigma_floor_m``, the spread and the short-window term (see
        :func:`chainage_sigma`).
    """

    status: str
    chainage_m: float = float('nan')
    end_chainage_m: float = float('nan')
    ratio: float = float('nan')
    correlation: float = float('nan')
    second_correlation: float = float('nan')
    confidence: float = 0.0
    signal_std_1pm: float = float('nan')
    measured_length_m: float = 0.0
    cpu_s: float = 0.0
    spread_m: float = float('nan')
    chainage_sigma_m: float = float('nan')

    @property
    def ok(self):
        return self.status == STATUS_OK


def _parabola_offset(y_minus, y0, y_plus):
    """Vertex offset (−0.5 … 0.5) of the parabola through three equally spaced values."""
    den = y_minus - 2.0 * y0 + y_plus
    if not (np.isfinite(den) and den < 0.0):
        return 0.0
    return float(np.clip(0.5 * (y_minus - y_plus) / den, -0.5, 0.5))


def match(template, array, config=None):
    """Find the chainage of the real-time array on the template (see module docstring).

    Parameters
    ----------
    template : CurvatureTemplate
    array : CurvatureArray or ArrayWindow
    config : CurvatureConfig, optional
        Default the template's.

    Returns
    -------
    CurvatureMatch
    """
    start = time.process_time()
    cfg = config or template.config
    window = array.window() if isinstance(array, CurvatureArray) else array
    result = _match(template, window, cfg)
    result.cpu_s = time.process_time() - start
    return result


def _match(template, window, cfg):
    sp = cfg.spacing_m
    kappa, d, t = window.curvature_1pm, window.distance_m, window.time_s
    if len(kappa) < 2:
        return CurvatureMatch(STATUS_TOO_SHORT)
    v_mean = (d[-1] - d[0]) / max(t[-1] - t[0], 1e-9)
    sigma = cfg.smoothing_sigma_m(v_mean)
    cut = int(round(3.0 * sigma / sp))
    end = len(kappa) - cut
    begin = max(cut, end - int(round(cfg.window_m / sp)))
    length = float(max(end - begin, 0) * sp)
    if length < cfg.min_window_m - 1e-9:
        return CurvatureMatch(STATUS_TOO_SHORT, measured_length_m=length)
    # Smooth the whole buffer, then keep the window inside the 3σ margins: there the
    # filter would see past the array (padding), unlike the template's.
    smooth = gaussian_filter1d(kappa, sigma / sp, mode='nearest')[begin:end]
    d_end = d[end - 1]
    signal = float(np.std(smooth))
    if signal < cfg.min_signal_std_1pm:
        return CurvatureMatch(STATUS_NO_SIGNAL, signal_std_1pm=signal, measured_length_m=length)
    bias_sigma = cfg.learnt_bias_sigma_rps if window.bias_learnt else cfg.gyro_bias_sigma_rps
    n = len(smooth)

    def candidate(r):
        """(ρ, r, window start j, M, ρ array) of the best window at ratio r, or None."""
        m = int(round(r * (n - 1))) + 1
        if (m - 1) * sp < cfg.min_matched_length_m:
            return None
        # True-metre sample k of the window lies at measured position k·(n−1)/(m−1) ≈ k/r.
        x = np.interp(np.arange(m) * ((n - 1) / (m - 1)), np.arange(n, dtype=float), smooth)
        # A bias residual b gives the measured curvature the offset b/v_measured.
        max_offset = 3.0 * bias_sigma / v_mean + r * cfg.offset_tolerance_1pm
        rho = template.sliding_fit(x, r, max_offset, sigma * r)
        if not (rho.size and np.isfinite(rho.max())):
            return None
        j = int(np.argmax(rho))
        return float(rho[j]), float(r), j, m, rho

    candidates = [c for c in map(candidate, cfg.ratios) if c is not None]
    if not candidates:
        return CurvatureMatch(STATUS_LOW_CORRELATION, signal_std_1pm=signal,
                              measured_length_m=length)
    best = max(candidates, key=lambda c: c[0])
    # Refine the ratio around the best tenfold: one step of r moves the window's end by
    # r_step × the window length (6 m for 600 m at 0.01).
    fine = [c for c in map(candidate, best[1] + cfg.ratio_step * np.linspace(-1, 1, 21))
            if c is not None]
    rho1, r1, j1, m1, rho_arr = max(fine + [best], key=lambda c: c[0])
    offset = 0.0
    if 0 < j1 < len(rho_arr) - 1:
        offset = _parabola_offset(rho_arr[j1 - 1], rho_arr[j1], rho_arr[j1 + 1])
    end_chainage = float(template.chainage_m[j1 + m1 - 1] + offset * sp)
    rho2 = _best_distinct(candidates, j1, m1)
    # Ratios that fit almost as well (Fisher z within spread_z of the best) with the
    # same hypothesis put the window's end elsewhere: a partial curve in the window can
    # be stretched. Their extent is the chainage spread.
    z1 = _fisher_z(rho1)
    ends = [template.chainage_m[j + m - 1] for rho, _, j, m, _ in candidates
            if z1 - _fisher_z(rho) <= cfg.spread_z
            and min(j + m, j1 + m1) - max(j, j1) >= 0.5 * min(m, m1)]
    spread = 0.5 * float(max(ends) - min(ends)) if ends else 0.0
    result = CurvatureMatch(STATUS_OK, end_chainage_m=end_chainage, ratio=r1,
                            correlation=rho1, second_correlation=rho2,
                            signal_std_1pm=signal, measured_length_m=length,
                            spread_m=spread)
    cap = cfg.correlation_cap
    z_margin = _fisher_z(min(rho1, cap)) - _fisher_z(min(rho2, cap))
    if rho1 < cfg.min_correlation:
        result.status = STATUS_LOW_CORRELATION
    elif z_margin < cfg.min_z_margin:
        result.status = STATUS_AMBIGUOUS
    elif spread > cfg.max_spread_m:
        result.status = STATUS_IMPRECISE
    else:
        # The window's last sample lies at d_end; the newest IMU sample a little further.
        result.chainage_m = end_chainage + r1 * max(window.distance_now_m - d_end, 0.0)
        result.chainage_sigma_m = chainage_sigma(spread, length, cfg)
        reference = 2.0 * cfg.min_z_margin if cfg.min_z_margin > 0.0 else 1.0
        result.confidence = float(max(rho1, 0.0) * min(1.0, z_margin / reference))
    return result


def chainage_sigma(spread_m, matched_length_m, config):
    """1σ of an accepted match's chainage, m.

    sqrt(floor² + spread² + short²), short = ``short_window_sigma_m`` × the share of
    ``window_m − min_window_m`` the matched window falls short of ``window_m``. Fitted
    to the synthetic runs of ``curvature_benchmark`` (tachometer speed, 40–120 km/h,
    475 matches): the errors of full windows have an RMS of 0.8 m, those of windows
    under 500 m (the first 200 m after acquisition) 3–4 m; with floor 1.5 m and short
    4 m the normalised errors have an RMS of 0.51 and a maximum of 3.0.
    """
    span = max(config.window_m - config.min_window_m, 1e-9)
    short = config.short_window_sigma_m * float(
        np.clip((config.window_m - matched_length_m) / span, 0.0, 1.0))
    return math.sqrt(config.chainage_sigma_floor_m ** 2 + spread_m ** 2 + short ** 2)


def _fisher_z(rho):
    """Atanh ρ, finite at ρ = ±1."""
    return float(np.arctanh(np.clip(rho, -1.0 + 1e-12, 1.0 - 1e-12)))


def _best_distinct(candidates, j1, m1):
    """Best ρ of a window overlapping the best one [j1, j1 + m1) by less than half.

    Windows that share most of their track with the best are the same hypothesis seen
    with another ratio; a distinct one is another stretch of the line.
    """
    best = -1.0
    for _, _, _, m, rho in candidates:
        j = np.arange(len(rho))
        overlap = np.minimum(j + m, j1 + m1) - np.maximum(j, j1)
        distinct = overlap < 0.5 * min(m, m1)
        if np.any(distinct):
            best = max(best, float(np.max(rho[distinct])))
    return best


@dataclass
class TimedMatch:
    """A :class:`CurvatureMatch` at the IMU sample time ``t_s`` it describes."""

    t_s: float
    match: CurvatureMatch


class CurvatureLocalizer:
    """IMU yaw rate and speed in, periodic curvature matches out (what the node runs).

    IMU samples wait until a speed sample at or after their time has arrived (the speed
    is then interpolated), or until they are ``speed_timeout_s`` older than the newest
    IMU sample: then the last speed is held if it is at most ``speed_timeout_s`` old,
    else the sample is dropped (``imu_without_speed``). A match runs every
    ``match_period_s`` of IMU time.

    Parameters
    ----------
    alignment : vlc_common.core.alignment.Alignment
        The line (its curvature is the template).
    config : CurvatureConfig
    match_period_s, speed_timeout_s : float
        Seconds of sensor time.
    speed_scale : float
        Factor applied to every input speed (a tachometer's wheel-diameter calibration;
        1 = none).
    """

    def __init__(self, alignment, config, match_period_s=1.0, speed_timeout_s=0.5,
                 speed_scale=1.0):
        if not (match_period_s > 0.0 and speed_timeout_s > 0.0 and speed_scale > 0.0):
            raise ValueError('match_period_s, speed_timeout_s and speed_scale must be > 0')
        self.config = config
        self.template = CurvatureTemplate(alignment, config)
        self.array = CurvatureArray(config)
        self.match_period_s = float(match_period_s)
        self.speed_timeout_s = float(speed_timeout_s)
        self.speed_scale = float(speed_scale)
        self._speed_t, self._speed_v = [], []       # speed samples in time order, pruned
        self._pending = []                 # (t, ω) waiting for a speed
        self._newest_imu = -math.inf
        self._next_match = None
        self.imu_rejected = 0
        self.speed_rejected = 0
        self.imu_without_speed = 0
        self.last = None                   # newest TimedMatch

    @property
    def alignment(self):
        return self.template.alignment

    def add_speed(self, t_s, speed_mps):
        """One speed sample (m/s ≥ 0); returns the matches it made due (list)."""
        if not (math.isfinite(t_s) and math.isfinite(speed_mps) and speed_mps >= 0.0) or (
                self._speed_t and t_s <= self._speed_t[-1]):
            self.speed_rejected += 1
            return []
        self._speed_t.append(float(t_s))
        self._speed_v.append(float(speed_mps) * self.speed_scale)
        return self._drain()

    def add_imu(self, t_s, yaw_rate_rps):
        """One gyro z sample (rad/s); returns the matches it made due (list)."""
        if not (math.isfinite(t_s) and math.isfinite(yaw_rate_rps)) or t_s <= self._newest_imu:
            self.imu_rejected += 1
            return []
        self._newest_imu = float(t_s)
        self._pending.append((float(t_s), float(yaw_rate_rps)))
        return self._drain()

    def _speed_at(self, t):
        """Speed at ``t`` (interpolated or held), None if unknown, _WAIT to wait for it."""
        ts, vs, timeout = self._speed_t, self._speed_v, self.speed_timeout_s
        if ts and ts[-1] >= t:
            i = bisect.bisect_left(ts, t)
            if ts[i] == t:
                return vs[i]
            if i == 0:
                return vs[0] if ts[0] - t <= timeout else None
            if ts[i] - ts[i - 1] > 2.0 * timeout:
                return None
            return vs[i - 1] + (vs[i] - vs[i - 1]) * (t - ts[i - 1]) / (ts[i] - ts[i - 1])
        if self._newest_imu - t < timeout:
            return _WAIT
        if ts and t - ts[-1] <= timeout:
            return vs[-1]
        return None

    def _drain(self):
        out = []
        done = 0
        for t, w in self._pending:
            v = self._speed_at(t)
            if v is _WAIT:
                break
            done += 1
            if v is None:
                self.imu_without_speed += 1
                continue
            self.array.add(t, w, v)
            if self._next_match is None:
                self._next_match = t + self.match_period_s
            elif t >= self._next_match:
                self._next_match = t + self.match_period_s
                self.last = TimedMatch(t, match(self.template, self.array))
                out.append(self.last)
        del self._pending[:done]
        # Keep only the speeds a pending IMU sample may still be interpolated with.
        oldest = self._pending[0][0] if self._pending else self._newest_imu
        drop = max(bisect.bisect_left(self._speed_t, oldest) - 1, 0)
        del self._speed_t[:drop], self._speed_v[:drop]
        return out

    def pose(self, chainage_m):
        """(position (3,), yaw rad) of base_link in map at a chainage: the alignment's
        centreline at rail level, heading along the track.
        """
        p = self.alignment.evaluate(chainage_m)
        return np.array([p.x_m[0], p.y_m[0], 0.0]), float(p.heading_rad[0])
