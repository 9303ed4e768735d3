"""Self-survey: the stereo range calibration and each lamp's place, learnt from the lamps.

A real calibration leaves the rectified pair a disparity error of a few tenths of a
pixel (the stereo rotation about the vertical axis, the lenses' residual distortion) and
the baseline or focal length a fraction of a per mille: on a lamp 16 m ahead (7.8 px of
disparity) 0.5 px is a range error of a metre. Each lamp's survey errs by millimetres,
and now and then by centimetres. Both are systematic: the same in every frame.

**Model.** The stereo range of a lamp scales with ``λ = (1 + ε)·d/(d − δ)`` (``d`` the
measured disparity, px; ``δ`` the disparity offset, px; ``ε`` the relative error of
``fx·b``): the corrected lamp is ``λ·p_cam``. A fix of lamp k in frame f, computed at
``λ₀``, is ``s_fk(λ) ≈ s_fk(λ₀) + g_fk·(λ − λ₀)`` with ``g = ∂s/∂λ`` (a finite difference
through the fix itself), and::

    s_fk(λ_fk(δ, ε)) = S_f + e_k + noise

with ``S_f`` the train's chainage at the frame (every fix of a frame shifted to one
instant by the filter's speed) and ``e_k`` the lamp's along-track map error (its fixes
all read ``e_k`` too far). ``S_f`` is eliminated frame by frame (weighted centring: only
frames with two or more lamps inform), so neither the filter nor the IMU enters: a lamp
far ahead and a near one seen at once, whose map spacing is known to the survey's
millimetres, measure δ and ε; a lamp's fixes against its neighbours' measure ``e_k``.
Gauss–Newton over a sliding window of fixes with priors: δ, ε from the calibration (or
the saved self-calibration), ``e_k`` from the survey's 1σ (or the saved refinement).

**Robustness.** A lamp whose data alone (its posterior with its prior divided out) puts
it more than ``gross_chi2`` and ``gross_min_m`` from its prior is *flagged* (moved,
re-fitted or wrongly surveyed): its prior is loosened so that it moves alone, and it can
neither bend the calibration nor its neighbours. A lamp's constant offset is absorbed
by its own ``e_k`` anyway, so a single bad lamp does not reach δ and ε.

**Honesty.** The posterior 1σ are inflated by ``sigma_inflation`` (consecutive frames of
a pair share unmodelled errors: eccentricity, lens residuals across the field), floored,
and only replace the calibration's stated σ in the fix once they are below a fraction of
the prior's (:attr:`SelfSurvey.converged`).
"""
from collections import deque
from dataclasses import dataclass, field
import math

import numpy as np


@dataclass
class SelfSurveyConfig:
    """Switches and priors of :class:`SelfSurvey` (units: px, relative, m, s)."""

    calibrate: bool = True             # estimate δ and ε and apply them to the fixes
    refine_map: bool = True            # estimate e_k (written out; applied at the next start)
    disparity_offset_px: float = 0.0   # prior mean of δ
    disparity_offset_sigma_px: float = 0.5
    stereo_scale_error: float = 0.0    # prior mean of ε
    stereo_scale_sigma: float = 0.001
    from_file: bool = False            # the priors are a saved self-calibration
    lamp_sigma_m: float = 0.005        # prior 1σ of e_k where no lamp states its own
    fix_floor_m: float = 0.005         # per-fix noise floor (vibration, attitude), m
    max_entries: int = 3000            # sliding window of fixes
    solve_period_s: float = 0.5        # measurement time between solves
    iterations: int = 3
    sigma_inflation: float = 3.0
    disparity_floor_px: float = 0.1    # the published δ 1σ never falls below this
    scale_floor: float = 0.0002
    converged_ratio: float = 0.5       # applied once σ_δ < this × its prior σ
    gross_chi2: float = 25.0
    gross_min_m: float = 0.02
    loose_sigma_m: float = 0.5         # prior 1σ of a flagged lamp
    min_along_m: float = 2.0           # lamps nearer than this along the track: not used
    eliminate_frames: bool = False     # True: the chainages are absolute (differences within
                                       # a frame); False: relative to the filter's state


@dataclass
class LampEstimate:
    """A lamp's along-track map error ``e`` (fixes read ``e`` too far), its 1σ, the
    number of fixes behind it, and why it is flagged ('' = not).
    """

    correction_m: float
    sigma_m: float
    fixes: int
    flagged: str = ''


@dataclass
class _Entry:
    frame_ns: int
    uid: int
    disparity_px: float
    lam0: float
    s0: float
    g: float
    w: float


@dataclass
class SelfSurvey:
    """Online estimator; see the module docstring.

    ``lamp_priors``: {uid: (mean m, 1σ m)} of ``e_k`` (the saved refinement, relative to
    the map as given); lamps not in it take (0, their survey σ or ``lamp_sigma_m``).
    """

    config: SelfSurveyConfig = field(default_factory=SelfSurveyConfig)
    lamp_priors: dict = field(default_factory=dict)

    def __post_init__(self):
        c = self.config
        self._entries = deque(maxlen=max(int(c.max_entries), 10))
        self.theta = np.array([c.disparity_offset_px, c.stereo_scale_error], float)
        self.theta_prior = self.theta.copy()
        self.theta_prior_sigma = np.array([c.disparity_offset_sigma_px, c.stereo_scale_sigma])
        self.theta_sigma = self.theta_prior_sigma.copy()
        self.lamps = {}               # uid -> LampEstimate (every lamp solved so far)
        self.flagged = {}             # uid -> reason
        self.solves = 0
        self._last_solve_ns = None
        self._new_pairs = False
        # a saved calibration is applied from the first fix on
        self.applied = bool(c.calibrate and c.from_file)

    # ------------------------------------------------------------------ use
    @property
    def converged(self):
        """δ and ε known well enough to replace the calibration's stated σ."""
        return bool(self.config.calibrate and self.solves > 0
                    and self.theta_sigma[0] < self.config.converged_ratio
                    * self.theta_prior_sigma[0])

    def range_factor(self, disparity_px, theta=None):
        """λ of a disparity (px) for θ = (δ, ε) (default: the applied estimate)."""
        delta, eps = self.theta if theta is None else theta
        if not self.applied:
            return 1.0
        d = float(disparity_px)
        if not d - delta > 0.0:
            return 1.0
        return (1.0 + eps) * d / (d - delta)

    def correct(self, p_cam, cov_cam, disparity_px):
        """The triangulated lamp and its covariance with the applied δ, ε."""
        lam = self.range_factor(disparity_px)
        if lam == 1.0:
            return p_cam, cov_cam
        return p_cam * lam, cov_cam * (lam * lam)

    def published_sigmas(self):
        """(σ_δ px, σ_ε) to state in the fix's calibration terms: the prior's until
        converged, then the inflated posterior's above the floors.
        """
        c = self.config
        if not self.converged:
            return tuple(float(v) for v in self.theta_prior_sigma)
        return (max(float(self.theta_sigma[0]), c.disparity_floor_px),
                max(float(self.theta_sigma[1]), c.scale_floor))

    def prior_of(self, uid, survey_sigma_m=float('nan')):
        mean, sigma = self.lamp_priors.get(int(uid), (0.0, float('nan')))
        if not math.isfinite(sigma):
            sigma = survey_sigma_m if math.isfinite(survey_sigma_m) else self.config.lamp_sigma_m
        if int(uid) in self.flagged:
            sigma = max(sigma, self.config.loose_sigma_m)
        return float(mean), float(sigma)

    # ------------------------------------------------------------------ data
    def add(self, frame_ns, uid, disparity_px, chainage_m, var_m2, slope_m, survey_sigma_m):
        """One confirmed fix: chainage (m, already moved to the frame's instant), its
        random variance (m²), ``slope_m`` = ∂s/∂λ at the applied λ, the lamp's survey
        along-track 1σ (m; NaN = unknown).
        """
        if not (self.config.calibrate or self.config.refine_map):
            return
        vals = (disparity_px, chainage_m, var_m2, slope_m)
        if not all(math.isfinite(float(v)) for v in vals) or not disparity_px > 0.0:
            return
        self._survey = getattr(self, '_survey', {})
        self._survey[int(uid)] = float(survey_sigma_m)
        w = 1.0 / (float(var_m2) + self.config.fix_floor_m ** 2)
        self._entries.append(_Entry(int(frame_ns), int(uid), float(disparity_px),
                                    self.range_factor(disparity_px), float(chainage_m),
                                    float(slope_m), w))
        self._new_pairs = True

    def maybe_solve(self, now_ns):
        """Solve when ``solve_period_s`` of measurement time passed since the last."""
        if not self._new_pairs:
            return False
        if (self._last_solve_ns is not None
                and now_ns - self._last_solve_ns < self.config.solve_period_s * 1e9):
            return False
        self._last_solve_ns = now_ns
        self._new_pairs = False
        return self.solve()

    def solve(self):
        """Gauss–Newton over the window; True when the frames held two lamps or more."""
        entries = list(self._entries)
        if len(entries) < 2:
            return False
        frame = np.array([e.frame_ns for e in entries], dtype=np.int64)
        uids = np.array([e.uid for e in entries], dtype=np.int64)
        _, fidx = np.unique(frame, return_inverse=True)
        counts = np.bincount(fidx)
        keep = counts[fidx] >= (2 if self.config.eliminate_frames else 1)
        lamp_uids = np.unique(uids[keep])
        if lamp_uids.size < (2 if self.config.eliminate_frames else 1):
            return False
        entries = [e for e, k in zip(entries, keep) if k]
        fidx = np.unique(frame[keep], return_inverse=True)[1]
        col = {int(u): i for i, u in enumerate(lamp_uids)}
        kcol = np.array([col[e.uid] for e in entries])
        d = np.array([e.disparity_px for e in entries])
        lam0 = np.array([e.lam0 for e in entries])
        s0 = np.array([e.s0 for e in entries])
        g = np.array([e.g for e in entries])
        w = np.array([e.w for e in entries])
        n_f, n_l, m = int(fidx.max()) + 1, lamp_uids.size, len(entries)
        survey = getattr(self, '_survey', {})
        c = self.config
        for _pass in range(2):          # a second pass after flagging gross lamps
            priors = np.array([self.prior_of(u, survey.get(int(u), float('nan')))
                               for u in lamp_uids])
            e_mean, e_sig = priors[:, 0], priors[:, 1]
            th = self.theta.copy() if self.solves else self.theta_prior.copy()
            e = e_mean.copy()
            wsum = np.bincount(fidx, weights=w, minlength=n_f)
            for _ in range(max(int(c.iterations), 1)):
                delta, eps = th
                den = d - delta
                if np.any(den <= 0.0):
                    break
                lam = (1.0 + eps) * d / den
                r = s0 + g * (lam - lam0) - e[kcol]
                J = np.zeros((m, 2 + n_l))
                J[:, 0] = g * (1.0 + eps) * d / (den * den)
                J[:, 1] = g * d / den
                J[np.arange(m), 2 + kcol] = -1.0
                if c.eliminate_frames:
                    # eliminate each frame's chainage: weighted centring per frame
                    r_mean = np.bincount(fidx, weights=w * r, minlength=n_f) / wsum
                    rc = r - r_mean[fidx]
                    Jc = np.empty_like(J)
                    for j in range(J.shape[1]):
                        mean = np.bincount(fidx, weights=w * J[:, j], minlength=n_f) / wsum
                        Jc[:, j] = J[:, j] - mean[fidx]
                else:
                    rc, Jc = r, J
                x = np.concatenate([th, e])
                x0 = np.concatenate([self.theta_prior, e_mean])
                p0 = 1.0 / np.square(np.concatenate([self.theta_prior_sigma, e_sig]))
                if not c.calibrate:
                    p0[:2] = 1e12
                H = Jc.T @ (w[:, None] * Jc) + np.diag(p0)
                grad = Jc.T @ (w * rc) + p0 * (x - x0)
                try:
                    step = -np.linalg.solve(H, grad)
                except np.linalg.LinAlgError:
                    return False
                x = x + step
                th, e = x[:2], x[2:]
                if np.all(np.abs(step[:2]) < [1e-5, 1e-8]):
                    break
            try:
                cov = np.linalg.inv(H)
            except np.linalg.LinAlgError:
                return False
            sig = np.sqrt(np.clip(np.diag(cov), 0.0, None))
            newly = self._flag_gross(lamp_uids, e, sig[2:], e_mean, e_sig)
            if not newly:
                break
        if c.calibrate and np.all(np.isfinite(th)):
            self.theta = th
            self.theta_sigma = sig[:2] * c.sigma_inflation
        per_lamp = np.bincount(kcol, minlength=n_l)
        for i, u in enumerate(lamp_uids):
            self.lamps[int(u)] = LampEstimate(float(e[i]), float(sig[2 + i] * c.sigma_inflation),
                                              int(per_lamp[i]), self.flagged.get(int(u), ''))
        self.solves += 1
        self.applied = bool(c.calibrate and self.converged) or self.applied
        return True

    def _flag_gross(self, uids, e, sig, e_mean, e_sig):
        """Flag lamps whose own data contradict their prior; True if any was new."""
        c = self.config
        new = False
        for i, u in enumerate(uids):
            if int(u) in self.flagged:
                continue
            post_p, prior_p = 1.0 / max(sig[i], 1e-9) ** 2, 1.0 / max(e_sig[i], 1e-9) ** 2
            data_p = post_p - prior_p
            if data_p <= 1e-12:
                continue
            data_mean = (e[i] * post_p - e_mean[i] * prior_p) / data_p
            diff = data_mean - e_mean[i]
            chi2 = diff * diff / (1.0 / data_p + e_sig[i] ** 2)
            if chi2 > c.gross_chi2 and abs(diff) > c.gross_min_m:
                self.flagged[int(u)] = (f'{diff * 100:+.1f} cm from its '
                                        f'{"refined" if int(u) in self.lamp_priors else "surveyed"}'
                                        ' place')
                new = True
        return new
