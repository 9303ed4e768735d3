"""Integrity of the fixes: gating, lamp association, contradiction tracking, status.

Rules:

* every fix is gated: its Mahalanobis distance to the filter's prediction,
  ``d² = (z − s)² / (P_ss + r)``, must not exceed ``gate_chi2`` (χ², 1 dof), and a
  constrained fix's own range-versus-direction residual must not exceed
  ``geometry_gate_chi2`` (χ², 2 dof: a wrong stereo match or a lamp off its place);
* a lamp whose UID the decoder has not confirmed is used only as the lamp the map
  predicts at that place: exactly one map lamp near the predicted position may pass
  the gate, and only while the state is certain enough to tell neighbouring lamps
  apart (``association_max_sigma_m``);
* a confirmed UID that fails the gate contradicts the state (a skipped, moved or
  spoofed lamp): it is rejected and reported. The state itself is declared wrong only
  on the evidence of two *distinct* confirmed lamps, with no confirmed lamp agreeing
  since the first contradiction: either they contradict it by the same offset (within
  their uncertainty: a wrong position, re-initialised at once) or they have kept
  contradicting it for ``reinit_after_s`` (a wrong speed too: the chainage is
  re-initialised and the speed and bias uncertainties are reset). One lamp alone never
  moves the state, so a single spoofed or moved lamp cannot capture the position;
* but it is evidence: until a confirmed lamp agrees with the state again (or the state
  is re-initialised), the published chainage variance includes the largest offset by
  which a confirmed lamp contradicted it (:meth:`IntegrityMonitor.suspicion_var_m2`),
  so a pose that may be that far off is never published as if it were right;
* a state the localizer can no longer vouch for at all (its sensor clock restarted, or
  no input for longer than ``blind_gap_s``) is *lost*: no pose until a confirmed lamp
  initialises it again.
"""
from collections import deque
from dataclasses import dataclass
import enum
import math

from vlc_common.core.observation import NS_PER_S


class IntegrityState(enum.Enum):
    """What the localizer can currently vouch for."""

    WAITING_FOR_UID = 'waiting_for_uid'   # no prior and no confirmed UID: no pose published
    LOST = 'lost'                         # state dropped (time base changed): no pose
    PRIOR_ONLY = 'prior_only'             # started from a prior, no fix accepted yet
    TRACKING = 'tracking'                 # fixes accepted within coast_warn_s
    COASTING = 'coasting'                 # no accepted fix for coast_warn_s: IMU only
    DEGRADED = 'degraded'                 # position 1σ above max_sigma_m


class Level(enum.IntEnum):
    """Severity, numerically equal to diagnostic_msgs/DiagnosticStatus levels."""

    OK = 0
    WARN = 1
    ERROR = 2


@dataclass
class IntegrityConfig:
    """Thresholds of the integrity checks.

    Attributes
    ----------
    gate_chi2 : float
        Mahalanobis gate of a fix against the prediction (χ², 1 dof; 16 = 4σ).
    geometry_gate_chi2 : float
        Gate of a constrained fix's range/direction residual (χ², 2 dof; 18.4 ≈ p 1e-4).
    association_max_sigma_m : float
        Unconfirmed lamps are used only while the chainage 1σ is below this, m.
    association_window_m : float
        Map lamps within this distance of where the observation puts the lamp are
        association candidates, m.
    reinit_agreement_chi2 : float
        Two contradicting lamps agree when their offsets differ by less than this many
        combined variances (χ², 1 dof).
    reinit_after_s : float
        Two distinct confirmed lamps contradicting the state for this long, with none
        accepted, re-initialise it even when their offsets differ, s.
    reinit_speed_sigma_mps : float
        Speed 1σ after such a re-initialisation, m/s.
    contradiction_memory_s : float
        How long a contradiction is remembered for the two-lamp re-initialisation, s.
    coast_warn_s : float
        Without an accepted fix for this long the state is COASTING (warning), s.
    max_sigma_m : float
        Above this published chainage 1σ the state is DEGRADED (error), m.
    report_hold_s : float
        A rejection stays in the diagnostics message for this long, s.
    """

    gate_chi2: float = 16.0
    geometry_gate_chi2: float = 18.4
    association_max_sigma_m: float = 1.5
    association_window_m: float = 4.0
    reinit_agreement_chi2: float = 16.0
    reinit_after_s: float = 2.0
    reinit_speed_sigma_mps: float = 2.0
    contradiction_memory_s: float = 60.0
    coast_warn_s: float = 1.0
    max_sigma_m: float = 0.5
    report_hold_s: float = 5.0


@dataclass
class Contradiction:
    """A confirmed lamp that disagreed with the state.

    ``offset_m`` = fix − prediction (m), ``var_m2`` its variance (m²).
    """

    stamp_ns: int
    uid: int
    offset_m: float
    var_m2: float
    reason: str = 'contradicts state'


@dataclass
class IntegrityCounters:
    """Since start (or the last reset of the counters)."""

    fixes_accepted: int = 0
    fixes_unconfirmed_used: int = 0
    rejected_contradiction: int = 0
    rejected_geometry: int = 0
    unconfirmed_skipped: int = 0
    unknown_uid: int = 0
    bad_observations: int = 0
    reinitialisations: int = 0
    time_resets: int = 0
    imu_rejected: int = 0
    records_too_old: int = 0      # lamp records older than the history window (late inputs)
    imu_attitude_implausible: int = 0   # imu/data attitudes the platform cannot have
    fixes_attitude_fallback: int = 0    # fixes that agreed only without the imu/data attitude


def mahalanobis2(innovation_m, variance_m2):
    """Squared Mahalanobis distance of a scalar innovation."""
    return innovation_m * innovation_m / variance_m2 if variance_m2 > 0.0 else math.inf


def select_association(candidates, gate_chi2):
    """The single map lamp that explains an unconfirmed observation, if there is one.

    Parameters
    ----------
    candidates : list of (lamp, d2)
        Each map lamp considered with the Mahalanobis d² of its fix (inf when its fix
        failed the geometry gate).
    gate_chi2 : float

    Returns
    -------
    (lamp or None, reason str)
        The lamp when exactly one candidate passes the gate; else None and why.
    """
    passing = [c for c in candidates if c[1] <= gate_chi2]
    if len(passing) == 1:
        return passing[0][0], 'predicted lamp'
    if not passing:
        return None, 'no map lamp predicted at this place'
    return None, 'ambiguous: several map lamps fit'


class IntegrityMonitor:
    """Counts, remembers contradictions, decides re-initialisation, reports the state."""

    def __init__(self, config=None):
        self.config = config or IntegrityConfig()
        self.counters = IntegrityCounters()
        self._contradictions = deque(maxlen=256)
        self.last_rejection = None
        self.last_unknown_uid = None
        self.last_accept_ns = None

    def clear(self):
        """Forget contradictions and the last accept (after a reset or re-init)."""
        self._contradictions.clear()
        self.last_accept_ns = None

    def on_accepted(self, stamp_ns, confirmed):
        """A fix passed the gates; a confirmed one vouches for the state."""
        self.counters.fixes_accepted += 1
        if not confirmed:
            self.counters.fixes_unconfirmed_used += 1
        self.last_accept_ns = stamp_ns if self.last_accept_ns is None else max(
            self.last_accept_ns, stamp_ns)
        if confirmed:
            self._contradictions.clear()

    def on_unknown_uid(self, stamp_ns, uid):
        self.counters.unknown_uid += 1
        self.last_unknown_uid = (stamp_ns, uid)

    def on_geometry_rejected(self, stamp_ns, uid, chi2):
        self.counters.rejected_geometry += 1
        self.last_rejection = Contradiction(stamp_ns, uid, float('nan'), float('nan'),
                                            f'range and direction disagree (chi2 {chi2:.1f})')

    def on_contradiction(self, contradiction):
        """Record a confirmed lamp that failed the gate.

        Returns
        -------
        str or None
            ``'offset'`` when a different confirmed lamp contradicted the state by the
            same offset (the position is wrong: re-initialise it from this fix);
            ``'full'`` when two distinct confirmed lamps have contradicted it for
            ``reinit_after_s`` with none accepted (re-initialise position, speed and
            bias uncertainty); None otherwise (reject the fix only).
        """
        cfg = self.config
        self.counters.rejected_contradiction += 1
        self.last_rejection = contradiction
        horizon = contradiction.stamp_ns - int(cfg.contradiction_memory_s * NS_PER_S)
        while self._contradictions and self._contradictions[0].stamp_ns < horizon:
            self._contradictions.popleft()
        others = [c for c in self._contradictions if c.uid != contradiction.uid]
        self._contradictions.append(contradiction)
        if not others:
            return None
        if any(mahalanobis2(c.offset_m - contradiction.offset_m, c.var_m2 + contradiction.var_m2)
               <= cfg.reinit_agreement_chi2 for c in others):
            return 'offset'
        span_ns = contradiction.stamp_ns - self._contradictions[0].stamp_ns
        if span_ns >= cfg.reinit_after_s * NS_PER_S:
            return 'full'
        return None

    def suspicion_var_m2(self):
        """Square of the largest offset by which a confirmed lamp contradicted the state
        since a confirmed lamp last agreed with it (0 when none did), m².
        """
        offsets = [c.offset_m for c in self._contradictions if math.isfinite(c.offset_m)]
        return max(offsets, key=abs) ** 2 if offsets else 0.0

    def on_reinitialised(self):
        self.counters.reinitialisations += 1
        self._contradictions.clear()

    def status(self, now_ns, initialized, has_fix, sigma_m, lost_reason=None):
        """Integrity state, severity and a one-line message at sensor time ``now_ns``."""
        cfg = self.config
        if not initialized:
            if lost_reason:
                return (IntegrityState.LOST, Level.ERROR,
                        f'position lost: {lost_reason}; no pose published until a '
                        'confirmed lamp UID')
            return (IntegrityState.WAITING_FOR_UID, Level.WARN,
                    'no pose published: waiting for a confirmed lamp UID')
        if sigma_m > cfg.max_sigma_m:
            state, level = IntegrityState.DEGRADED, Level.ERROR
            msg = f'position 1-sigma {sigma_m:.3f} m above {cfg.max_sigma_m:.3f} m'
        elif not has_fix:
            state, level = IntegrityState.PRIOR_ONLY, Level.WARN
            msg = 'no lamp fix yet (prior only)'
        elif (now_ns is not None and self.last_accept_ns is not None
              and now_ns - self.last_accept_ns > cfg.coast_warn_s * NS_PER_S):
            gap = (now_ns - self.last_accept_ns) / NS_PER_S
            state, level = IntegrityState.COASTING, Level.WARN
            msg = f'no lamp fix for {gap:.1f} s: IMU only'
        else:
            state, level, msg = IntegrityState.TRACKING, Level.OK, 'tracking'
        rej = self.last_rejection
        if (rej is not None and now_ns is not None
                and now_ns - rej.stamp_ns <= cfg.report_hold_s * NS_PER_S):
            level = max(level, Level.WARN)
            uid = f'{rej.uid:#06x}' if rej.uid is not None else 'unconfirmed lamp'
            if math.isfinite(rej.offset_m):
                msg += (f'; rejected lamp {uid}: {rej.reason} by {rej.offset_m:+.2f} m '
                        '(skipped, moved or spoofed lamp)')
            else:
                msg += f'; rejected lamp {uid}: {rej.reason}'
        return state, level, msg
