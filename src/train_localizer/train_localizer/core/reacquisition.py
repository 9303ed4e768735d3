"""Re-acquisition after a long lamp outage: the curvature match as a chainage aid.

Issue 7: the curvature-array correlation (companion method 4, ``curvature_node``) is
"used to re-acquire position after a long lamp outage". In a dark stretch the localizer
coasts on the IMU and its chainage uncertainty grows to tens of metres; the curvature
match gives the chainage to metres from the shape of the track, with no lamp. This
module decides when such a match may enter the filter, as a chainage measurement with
the match's own variance (:meth:`Localizer.apply_chainage_aid`).

Rules, in order (each match gets one status, counted):

1. ``bad_input``: non-finite chainage or variance ≤ 0.
2. ``not_initialised``: the localizer has no state at the match's instant (cold start,
   or the instant is outside its history).
3. ``ignored_tracking``: the localizer does not need it — a lamp fix was accepted within
   ``coast_s`` of the match, or its chainage 1σ at the match's instant is at most
   ``min_state_sigma_m``. While lamps are seen (σ of centimetres) the aid is never
   used. The same threshold keeps consecutive matches — which share most of their
   window, so their errors are strongly correlated — from being fused as independent:
   after one aid the state's σ is about the match's, below the threshold, and the next
   aid waits until the IMU-only growth has brought σ back above it.
4. ``rejected_imprecise``: the match's 1σ exceeds ``max_match_sigma_m``.
5. ``unconfirmed``: the previous match (within ``max_match_gap_s``) does not exist or
   does not agree with this one after being carried forward by the distance the
   filter's speed ran in between (χ² ≤ ``consistency_chi2``). One isolated match never
   moves the state.
6. ``rejected_gate``: the Mahalanobis distance to the state's prediction,
   d² = (z − s)² / (P_ss + r), exceeds ``gate_chi2`` — unless the reset rule (7) fires.
7. ``reset`` (the state is hopeless): the gate failed, and a run of consecutive,
   mutually consistent matches, every one failing the gate, has lasted over at least
   ``reset_min_travel_m`` of running and ``reset_min_matches`` matches, with no lamp
   accepted meanwhile. Then the chainage is re-initialised at the match (variance r;
   speed and bias uncertainties raised as after a lamp re-initialisation, so that the
   following matches correct the speed too). A single wrong match, or a hypothesis the
   matcher held for a few seconds only, cannot do this; ``reset_min_matches`` 0
   disables the rule.
8. ``applied``: a chainage update z with variance r (the state's speed and bias follow
   through the filter's correlations).

No ROS here.
"""
from collections import deque
from dataclasses import dataclass, field
import math

import numpy as np

from vlc_common.core.observation import NS_PER_S

APPLIED = 'applied'
RESET = 'reset'
IGNORED = 'ignored_tracking'
UNCONFIRMED = 'unconfirmed'
REJECTED_GATE = 'rejected_gate'
REJECTED_IMPRECISE = 'rejected_imprecise'
NOT_INITIALISED = 'not_initialised'
BAD_INPUT = 'bad_input'
STATUSES = (APPLIED, RESET, IGNORED, UNCONFIRMED, REJECTED_GATE, REJECTED_IMPRECISE,
            NOT_INITIALISED, BAD_INPUT)


@dataclass
class ReacquisitionConfig:
    """When a chainage aid (curvature match) may enter the filter (SI units).

    Attributes
    ----------
    enabled : bool
        False: every aid is ignored (``ignored_tracking``).
    min_state_sigma_m : float
        Aid only while the state's chainage 1σ at the aid's instant exceeds this, m.
    coast_s : float
        Aid only when no lamp fix was accepted within this long before it, s.
    max_match_sigma_m : float
        Matches with a larger 1σ are refused, m.
    min_match_sigma_m : float
        Floor on the 1σ used for a match, m.
    gate_chi2 : float
        Mahalanobis gate of a match against the state (χ², 1 dof).
    consistency_chi2 : float
        Two consecutive matches agree when their difference, after carrying the older
        one by the distance run, is within this χ² (1 dof).
    max_match_gap_s : float
        A longer gap between two matches breaks the chain of consecutive matches, s.
    reset_min_matches : int
        Matches in a consistent, gate-failing run needed for a reset; 0 = never reset.
    reset_min_travel_m : float
        Running distance such a run must span, m.
    """

    enabled: bool = True
    min_state_sigma_m: float = 5.0
    coast_s: float = 1.0
    max_match_sigma_m: float = 10.0
    min_match_sigma_m: float = 0.5
    gate_chi2: float = 16.0
    consistency_chi2: float = 16.0
    max_match_gap_s: float = 3.0
    reset_min_matches: int = 5
    reset_min_travel_m: float = 200.0

    def __post_init__(self):
        for name in ('max_match_sigma_m', 'min_match_sigma_m', 'gate_chi2',
                     'consistency_chi2', 'max_match_gap_s'):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0.0):
                raise ValueError(f'{name} must be finite and > 0, got {value}')
        for name in ('min_state_sigma_m', 'coast_s', 'reset_min_travel_m'):
            value = getattr(self, name)
            if not (math.isfinite(value) and value >= 0.0):
                raise ValueError(f'{name} must be finite and >= 0, got {value}')
        if int(self.reset_min_matches) != self.reset_min_matches or self.reset_min_matches < 0:
            raise ValueError(f'reset_min_matches must be an integer >= 0, got '
                             f'{self.reset_min_matches}')
        if self.max_match_sigma_m < self.min_match_sigma_m:
            raise ValueError('max_match_sigma_m must be >= min_match_sigma_m')


@dataclass
class AidRecord:
    """What happened to one aid (for diagnostics, tests and the benchmark).

    ``offset_m`` = z − predicted chainage (NaN without a state), ``d2`` its Mahalanobis
    distance, ``state_sigma_m`` the state's chainage 1σ at the aid's instant (before).
    """

    stamp_ns: int
    chainage_m: float
    sigma_m: float
    status: str
    offset_m: float = float('nan')
    d2: float = float('nan')
    state_sigma_m: float = float('nan')


@dataclass
class AidCounters:
    """Since start: one count per status."""

    counts: dict = field(default_factory=lambda: dict.fromkeys(STATUSES, 0))

    @property
    def received(self):
        return sum(self.counts.values())

    @property
    def applied(self):
        return self.counts[APPLIED] + self.counts[RESET]

    @property
    def rejected(self):
        return (self.counts[REJECTED_GATE] + self.counts[REJECTED_IMPRECISE]
                + self.counts[UNCONFIRMED])


def chainage_measurement(track, position_m, cov_xyz_m2):
    """(chainage m, variance m²) of a pose on the track with a map covariance (3, 3).

    The chainage is the position's foot point on the alignment; the variance is the
    covariance along the running direction there, tᵀΣt.
    """
    position = np.asarray(position_m, dtype=float)
    cov = np.asarray(cov_xyz_m2, dtype=float)
    if position.shape != (3,) or cov.shape != (3, 3) or not (
            np.all(np.isfinite(position)) and np.all(np.isfinite(cov))):
        return float('nan'), float('nan')
    s = track.chainage_of(position)
    t = track.frame(s)[1]
    return float(s), float(t @ cov @ t)


class ChainageAid:
    """Feeds chainage aids (curvature matches) to a :class:`Localizer` by the rules above.

    Parameters
    ----------
    localizer : train_localizer.core.localizer.Localizer
    config : ReacquisitionConfig
    """

    def __init__(self, localizer, config=None):
        self.localizer = localizer
        self.config = config or ReacquisitionConfig()
        self.counters = AidCounters()
        self.last = None            # newest AidRecord
        self.history = deque(maxlen=1000)   # recent AidRecords, oldest first
        self._previous = None       # (t_ns, z, r, speed) of the previous match
        self._run = []              # consecutive gate-failing consistent matches (t_ns, travel)

    def reset(self):
        """Forget the chain of matches (after a localizer reset)."""
        self._previous = None
        self._run = []

    def add(self, stamp_ns, chainage_m, var_m2):
        """One chainage aid at ``stamp_ns``; returns its :class:`AidRecord`."""
        record = self._decide(int(stamp_ns), float(chainage_m), float(var_m2))
        self.counters.counts[record.status] += 1
        self.last = record
        self.history.append(record)
        return record

    def _decide(self, t, z, var):
        cfg = self.config
        loc = self.localizer
        if not (math.isfinite(z) and math.isfinite(var) and var > 0.0):
            return AidRecord(t, z, float('nan'), BAD_INPUT)
        sigma = max(math.sqrt(var), cfg.min_match_sigma_m)
        r = sigma * sigma
        state = loc.state_at(t)
        if state is None:
            self.reset()
            return AidRecord(t, z, sigma, NOT_INITIALISED)
        s, p_ss, speed = float(state.x[0]), float(state.P[0, 0]), float(state.x[1])
        y = z - s
        d2 = y * y / (p_ss + r)
        rec = AidRecord(t, z, sigma, IGNORED, y, d2, math.sqrt(max(p_ss, 0.0)))
        consistent, travel = self._consistent(t, z, r, speed, float(state.P[1, 1]))
        self._previous = (t, z, r, speed)
        last_fix = loc.monitor.last_accept_ns
        recent_fix = last_fix is not None and t - last_fix <= cfg.coast_s * NS_PER_S
        if (not cfg.enabled or recent_fix or p_ss <= cfg.min_state_sigma_m ** 2):
            self._run = []
            return rec
        if sigma > cfg.max_match_sigma_m:
            self._run = []
            rec.status = REJECTED_IMPRECISE
            return rec
        if not consistent:
            self._run = []
            rec.status = UNCONFIRMED
            return rec
        if d2 <= cfg.gate_chi2:
            self._run = []
            if loc.apply_chainage_aid(t, z, r):
                rec.status = APPLIED
            else:
                rec.status = NOT_INITIALISED
            return rec
        # Gate failed: part of a run that may prove the state hopeless?
        if last_fix is not None and self._run and last_fix > self._run[0][0]:
            self._run = []
        run_travel = (self._run[-1][1] + travel) if self._run else 0.0
        self._run.append((t, run_travel))
        rec.status = REJECTED_GATE
        if (cfg.reset_min_matches > 0 and len(self._run) >= cfg.reset_min_matches
                and run_travel >= cfg.reset_min_travel_m):
            if loc.apply_chainage_aid(t, z, r, reset=True):
                rec.status = RESET
                self._run = []
        return rec

    def _consistent(self, t, z, r, speed, speed_var):
        """(agrees with the previous match, distance run since it in m)."""
        prev = self._previous
        if prev is None:
            return False, 0.0
        t0, z0, r0, v0 = prev
        dt = (t - t0) / NS_PER_S
        if not 0.0 < dt <= self.config.max_match_gap_s:
            return False, 0.0
        travel = 0.5 * (v0 + speed) * dt
        diff = z - (z0 + travel)
        var = r + r0 + speed_var * dt * dt
        return diff * diff / var <= self.config.consistency_chi2, abs(travel)
