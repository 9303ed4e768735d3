"""Lamp-map refinement ("surveying by train"): each pass measures each lamp against its
neighbours through the IMU-bridged trajectory; passes accumulate; the survey stays the datum.

**What a pass measures.** A lamp surveyed ``e`` too far along the track makes every fix
of it read ``e`` too far. One fix alone cannot tell that from the train's own error, and
the filter cannot serve as the reference: it follows each lamp within a few frames, so a
lamp's offset shows as an innovation of the *next* lamp (tried: a lamp 5 cm off was
blamed on its successor, and the corrections diverged over passes), and its speed
reacts to the lamps too (pairs of lamps bridged by the filter's integrated speed read
1–4 cm wrong, most around a bad lamp). What the IMU alone knows well is the motion
*shape* over a few seconds: X(t) = ∫∫ a dt (along-track acceleration, zero initial
position and speed), good to a millimetre over 3 s. The unknown initial speed and
position leave the line c + v₀·t free, so three lamps seen one after the other are the
unit: each lamp's fixes minus X(t) average to ``m_k = c + v₀·t̄_k + e_k`` (t̄_k their
weighted mean time), and the middle lamp's departure from the line through the outer
two::

    q = m_b − λ·m_a − (1 − λ)·m_c = e_b − λ·e_a − (1 − λ)·e_c,   λ = (t̄_c − t̄_b)/(t̄_c − t̄_a)

is free of c and v₀ (:class:`PassRecorder`). The three lamps are seen through the same
range sequence, so a range-dependent bias of the calibration or the attitude (the same
for every lamp) enters each ``m_k`` alike and cancels (λ + (1 − λ) = 1).

**Across passes** (:class:`Refinement`): each triplet keeps an inverse-variance mean of
its measurements (in survey terms: a pass on an already refined map adds back what was
applied). The lamps' corrections solve ``min Σ (q − h·e)²/σ_q² + Σ e_k²/σ_k²``, ``σ_k``
the survey's along-track 1σ: the survey stays the absolute datum (second differences
have no level and no slope), and a lamp in no triplet keeps its survey. The system is
solved in overlapping blocks (a triplet links only near lamps, so the solution's
correlation dies out within a few lamps), which keeps a line of thousands of lamps cheap.

**Robustness.** A lamp whose triplets put it more than ``gross_min_m`` and
``off_survey_chi2`` from its surveyed place is *off its survey*: its survey prior is loosened
so that the triplets alone place it, and it is reported (a wrongly surveyed or re-fitted
lamp). A triplet whose new measurement contradicts its kept mean by as much *jumped*;
the lamp that weighs most in the jumping triplets is *moved*: its kept triplets are set
apart (``previous`` in the file) and restart from this pass, and it is reported — never
absorbed silently.
"""
from collections import deque
import dataclasses
from dataclasses import dataclass, field
import math

import numpy as np


@dataclass
class RefinementConfig:
    """Parameters of the refinement (units m, s)."""

    min_fixes: int = 4              # fixes per lamp for a measurement
    max_span_s: float = 8.0         # longest time over which three lamps are bridged
    close_after_s: float = 1.0      # a lamp with no fix for this long is complete
    sigma_inflation: float = 2.0    # consecutive fixes share unmodelled errors
    # A triplet's 1σ never falls below lamp_floor_m in one pass (the graph's triplets
    # scatter ~0.8-1 cm from pass to pass), nor its mean over many passes below
    # kept_floor_m. Besides, the same triplet read up to 1.5 cm off pass after pass on
    # the realistic graph (a lamp's own tilt, diameter and brightness bias its fixes
    # alike every time): repeatable_sigma_m, added when the lamps are placed, but not
    # when a triplet is compared with itself (moved lamps), where it cancels.
    lamp_floor_m: float = 0.008
    kept_floor_m: float = 0.0005
    repeatable_sigma_m: float = 0.008
    # ... and it changes with the speed (the fixes' range bias does): a triplet read at
    # another speed than its kept mean may differ by this much without a lamp moving
    speed_sigma_m: float = 0.005
    # λ of a triplet of consecutive lamps is ~0.5; one with a lamp missing between
    # (unconfirmed or dark: λ 0.33, 0.25) read up to 6 cm off on the graph: not measured
    lam_range: tuple = (0.4, 0.6)
    bias_floor_mps2: float = 0.002  # prior 1σ of the acceleration bias left over a triplet
    gross_min_m: float = 0.02
    gross_chi2: float = 25.0        # a moved lamp: its triplets against their kept means
    off_survey_chi2: float = 16.0   # a lamp off its survey (the repeatable error stays in its
                                    # σ however many passes: 5 cm is a 4-5σ finding)
    suspect_chi2: float = 9.0       # a new measurement this far from the mean is held apart
    pending_passes: int = 3         # ... and replaces it after this many such passes
    loose_sigma_m: float = 0.5
    block: int = 200                # lamps solved at once (plus ``overlap`` each side)
    overlap: int = 20


@dataclass
class TripletMeasurement:
    """``q_m`` = e_b − λ·e_a − (1 − λ)·e_c and its 1σ (lamps a, b, c in time order)."""

    uids: tuple
    lam: float
    q_m: float
    sigma_m: float
    fixes: int = 0


def coefficients(lam):
    """The triplet's h: how its q moves with each lamp's e (outer, middle, outer)."""
    return (-lam, 1.0, lam - 1.0)


@dataclass
class _Lamp:
    uid: int
    t: list = field(default_factory=list)
    s: list = field(default_factory=list)
    var: list = field(default_factory=list)


class PassRecorder:
    """Collects one run's along-track accelerations and the accepted fixes of confirmed
    lamps, and turns each three lamps seen one after the other into a
    :class:`TripletMeasurement` as soon as they are complete.
    """

    def __init__(self, config=None, applied=None):
        self.config = config or RefinementConfig()
        #: {uid: correction applied to the map at start, m}: measurements are returned
        #: relative to the survey
        self.applied = dict(applied or {})
        self._open = []              # _Lamp, in order of their first fix
        self._accel = deque()        # (t s, along-track acceleration m/s²)
        self._bias_var = float('inf')
        self.measurements = []

    def add_accel(self, t_s, accel_mps2, bias_var=0.0):
        """One IMU sample's along-track acceleration, the filter's bias estimate taken
        off, and that estimate's variance; None (unknown, e.g. after a gap) breaks the
        record: lamps before it are not bridged across it.
        """
        if accel_mps2 is None or not math.isfinite(float(accel_mps2)):
            self._accel.clear()
            self._open.clear()
            return
        if self._accel and t_s <= self._accel[-1][0]:
            return
        self._accel.append((float(t_s), float(accel_mps2)))
        self._bias_var = float(bias_var)
        keep_from = min((lamp.t[0] for lamp in self._open), default=t_s) - 1.0
        while len(self._accel) > 2 and self._accel[1][0] < min(keep_from,
                                                                t_s - self.config.max_span_s):
            self._accel.popleft()

    def add(self, t_s, uid, chainage_m, var_m2):
        vals = (t_s, chainage_m, var_m2)
        if not all(math.isfinite(float(x)) for x in vals) or not var_m2 > 0.0:
            return
        uid = int(uid)
        lamp = next((x for x in reversed(self._open) if x.uid == uid), None)
        if lamp is None:
            lamp = _Lamp(uid)
            self._open.append(lamp)
        lamp.t.append(float(t_s))
        lamp.s.append(float(chainage_m))
        lamp.var.append(float(var_m2))
        self._close(float(t_s))

    def _close(self, now_s):
        c = self.config
        while len(self._open) >= 3 and all(now_s - max(x.t) > c.close_after_s
                                           for x in self._open[:3]):
            self._measure(*self._open[:3])
            self._open.pop(0)
        while len(self._open) > 8:          # never grows without bound
            self._open.pop(0)

    def finish(self):
        """Measure what the run left open (at stop) and return every measurement. A lamp
        still in view when the run stopped (a fix within ``close_after_s`` of the last
        one) was seen only from afar: it is left out, as its range-dependent errors
        would not cancel against its neighbours'.
        """
        if self._open:
            last = max(max(x.t) for x in self._open)
            self._open = [x for x in self._open if last - max(x.t) > self.config.close_after_s]
        while len(self._open) >= 3:
            self._measure(*self._open[:3])
            self._open.pop(0)
        return self.measurements

    def _displacement(self, t):
        """X(t) = ∫∫ a from the first recorded sample (zero speed and position), or None
        where the record does not cover ``t``.
        """
        if len(self._accel) < 2:
            return None
        ta, a = np.array(self._accel).T
        if t.min() < ta[0] or t.max() > ta[-1] + 0.05:
            return None
        dt = np.diff(ta)
        v = np.r_[0.0, np.cumsum(0.5 * (a[1:] + a[:-1]) * dt)]
        x = np.r_[0.0, np.cumsum(0.5 * (v[1:] + v[:-1]) * dt)]
        # between samples: the speed's trapezoid (acceleration constant over a period)
        i = np.clip(np.searchsorted(ta, t, side='right') - 1, 0, len(ta) - 1)
        h = t - ta[i]
        return x[i] + v[i] * h + 0.5 * a[i] * h * h

    def _measure(self, *lamps):
        """One triplet: the residuals s − X(t) of the three lamps' fixes fitted with
        c + v₀·τ + ½·β·τ² (β: what is left of the acceleration bias, its prior the
        filter's bias 1σ) and the middle lamp's offset ``q``.
        """
        c = self.config
        if len({x.uid for x in lamps}) < 3 or min(len(x.t) for x in lamps) < c.min_fixes:
            return
        t = np.concatenate([x.t for x in lamps])
        if t.max() - t.min() > c.max_span_s:
            return
        X = self._displacement(t)
        if X is None:
            return
        r = np.concatenate([x.s for x in lamps]) - X
        w = 1.0 / np.concatenate([x.var for x in lamps])
        sizes = [len(x.t) for x in lamps]
        which = np.repeat(np.arange(3), sizes)
        times = [float(np.sum(w[which == k] * t[which == k]) / np.sum(w[which == k]))
                 for k in range(3)]
        if not times[0] < times[1] < times[2]:
            return
        lam = (times[2] - times[1]) / (times[2] - times[0])
        if not c.lam_range[0] <= lam <= c.lam_range[1]:
            return
        tau = t - times[1]
        A = np.column_stack([np.ones_like(t), tau, 0.5 * tau * tau, which == 1])
        H = A.T @ (w[:, None] * A)
        H[2, 2] += 1.0 / max(self._bias_var, c.bias_floor_mps2 ** 2)
        try:
            cov = np.linalg.inv(H)
        except np.linalg.LinAlgError:
            return
        sol = cov @ (A.T @ (w * r))
        res = r - A @ sol
        scale = max(1.0, math.sqrt(float(np.sum(w * res * res)) / max(t.size - 4, 1)))
        sigma = max(math.sqrt(max(cov[3, 3], 0.0)) * scale * c.sigma_inflation,
                    c.lamp_floor_m)
        applied = [self.applied.get(x.uid, 0.0) for x in lamps]
        q = float(sol[3]) + float(np.dot(coefficients(lam), applied))
        if math.isfinite(q) and math.isfinite(sigma):
            self.measurements.append(TripletMeasurement(
                tuple(x.uid for x in lamps), lam, q, sigma, int(t.size)))


@dataclass
class KeptTriplet:
    """A triplet's mean over passes; ``pending``: later measurements that disagreed
    with it (held apart, not averaged in, until they make a lamp *moved* or, after
    ``pending_passes``, replace the mean as the new state of the line).
    """

    lam: float
    q_m: float
    sigma_m: float
    passes: int = 1
    pending: list = field(default_factory=list)     # [(λ, q, σ)]


@dataclass
class Flag:
    """A lamp set apart: ``kind`` 'moved' (a jump between passes); ``previous``: the
    kept triplets it was in before (``{uids: KeptTriplet}``).
    """

    uid: int
    kind: str
    reason: str
    at_pass: int
    previous: dict = field(default_factory=dict)


def _mean(items, floor):
    """Inverse-variance mean of [(λ, q, σ)] as a KeptTriplet (one pass)."""
    w = np.array([1.0 / s ** 2 for _, _, s in items])
    lam = float(np.sum(w * [x[0] for x in items]) / np.sum(w))
    q = float(np.sum(w * [x[1] for x in items]) / np.sum(w))
    return KeptTriplet(lam, q, max(1.0 / math.sqrt(float(np.sum(w))), floor))


class Refinement:
    """The triplets kept over passes, the flags, and the lamps' corrections they give."""

    def __init__(self, config=None, triplets=None, flags=None, passes=0):
        self.config = config or RefinementConfig()
        self.triplets = dict(triplets or {})    # (uid_a, uid_b, uid_c) -> KeptTriplet
        self.flags = list(flags or [])
        self.passes = int(passes)

    @property
    def moved(self):
        return {f.uid for f in self.flags if f.kind == 'moved'}

    # ---------------------------------------------------------------- passes
    def merged(self, measurements):
        """A new Refinement: this one plus one pass's ``measurements`` (several of one
        triplet in a pass — the line run twice — are averaged first).

        A lamp moved by δ shifts the three triplets it is in by h·δ (h = −λ, 1,
        −(1 − λ) as outer, middle, outer lamp): each lamp's δ is estimated from its
        triplets' recent measurements (this pass's and those held apart) against their
        kept means, and a lamp beyond ``gross_min_m`` and ``gross_chi2`` is *moved*
        (:class:`Flag`): its kept triplets are set apart and restart from the recent
        measurements. Otherwise a measurement within ``suspect_chi2`` of its mean is
        averaged in, one further off is held apart (``pending``), and ``pending_passes``
        held measurements replace the mean (a change too small to call a moved lamp).
        """
        c = self.config
        this = {}
        for m in measurements:
            this.setdefault(tuple(int(u) for u in m.uids), []).append(
                (m.lam, m.q_m, m.sigma_m))
        new = {key: _mean(items, c.lamp_floor_m) for key, items in this.items()}
        recent = {}
        for key, kept in self.triplets.items():
            items = list(kept.pending) + ([(new[key].lam, new[key].q_m, new[key].sigma_m)]
                                          if key in new else [])
            if items:
                recent[key] = _mean(items, c.lamp_floor_m)
        out = Refinement(c, {k: KeptTriplet(t.lam, t.q_m, t.sigma_m, t.passes,
                                            list(t.pending))
                             for k, t in self.triplets.items()},
                         self.flags, self.passes + (1 if new else 0))
        moved = set()
        for uid, delta, chi2 in self._jumps(recent):
            if not (abs(delta) > c.gross_min_m and chi2 > c.gross_chi2):
                continue
            moved.add(uid)
            previous = {k: v for k, v in self.triplets.items() if uid in k}
            for k in previous:
                if k in recent:
                    out.triplets[k] = dataclasses.replace(recent[k], passes=len(
                        self.triplets[k].pending) + (k in new), pending=[])
                else:
                    del out.triplets[k]
            out.flags = out.flags + [Flag(
                # e is how much too far the fixes read: the lamp itself moved by −e
                uid, 'moved', f'moved {-delta * 100:+.1f} cm along the track against the '
                f'passes before (chi2 {chi2:.0f}), seen in pass {out.passes}', out.passes,
                {k: KeptTriplet(v.lam, v.q_m, v.sigma_m, v.passes)
                 for k, v in previous.items()})]
        for key, m in new.items():
            if any(u in moved for u in key) and key in self.triplets:
                continue                     # restarted above
            kept = out.triplets.get(key)
            if kept is None:
                out.triplets[key] = m
                continue
            diff = m.q_m - kept.q_m
            if diff * diff / (m.sigma_m ** 2 + kept.sigma_m ** 2) > c.suspect_chi2:
                kept.pending.append((m.lam, m.q_m, m.sigma_m))
                continue
            merged = _mean([(kept.lam, kept.q_m, kept.sigma_m), (m.lam, m.q_m, m.sigma_m)],
                           c.kept_floor_m)
            merged.passes = kept.passes + 1
            out.triplets[key] = merged
        for key, kept in list(out.triplets.items()):
            if len(kept.pending) >= c.pending_passes:
                fresh = _mean(kept.pending, c.lamp_floor_m)
                fresh.passes = len(kept.pending)
                out.triplets[key] = fresh
        return out

    def _jumps(self, recent):
        """[(uid, δ m, chi2)]: each lamp's displacement as its triplets' ``recent``
        measurements ({key: KeptTriplet}) show it against their kept means, strongest
        first, one lamp per neighbourhood (a moved lamp's neighbours share its triplets).
        """
        by_lamp = {}
        for key, r in recent.items():
            t = self.triplets[key]
            diff = r.q_m - t.q_m
            var = r.sigma_m ** 2 + t.sigma_m ** 2 + self.config.speed_sigma_m ** 2
            for uid, h in zip(key, coefficients(t.lam)):
                by_lamp.setdefault(uid, []).append((h, diff, var))
        out = []
        for uid, rows in by_lamp.items():
            hw = sum(h * h / v for h, _, v in rows)
            if hw > 0.0:
                delta = sum(h * d / v for h, d, v in rows) / hw
                out.append((uid, delta, delta * delta * hw))
        out.sort(key=lambda x: -x[2])
        chosen, taken = [], set()
        for uid, delta, chi2 in out:
            if uid in taken:
                continue
            chosen.append((uid, delta, chi2))
            taken |= {u for k in self.triplets if uid in k for u in k}
        return chosen

    # --------------------------------------------------------------- lamps
    def corrections(self, survey_sigma):
        """({uid: (e m, 1σ m)} of every lamp in a kept triplet, {uid: reason} of the
        lamps off their survey). ``survey_sigma``: {uid: along-track survey 1σ, m}; a
        triplet naming a lamp not in it is ignored.
        """
        c = self.config
        rows = [(key, t) for key, t in self.triplets.items()
                if all(u in survey_sigma for u in key)]
        uids = sorted({u for key, _ in rows for u in key})
        if not uids:
            return {}, {}
        prior = {u: max(float(survey_sigma[u]), 1e-4) for u in uids}
        off = {}
        est = self._solve(uids, rows, prior)
        for _ in range(len(uids)):
            best = None
            for u in uids:
                # the survey prior pulls a gross lamp most of the way back: screen on
                # being pulled off by more than its survey 1σ, then solve without it
                if u in off or abs(est[u][0]) < min(0.5 * c.gross_min_m, prior[u]):
                    continue
                e2, s2 = self._solve(uids, rows, {**prior, u: c.loose_sigma_m})[u]
                chi2 = e2 * e2 / (s2 * s2 + prior[u] ** 2)
                if abs(e2) > c.gross_min_m and chi2 > c.off_survey_chi2 and (
                        best is None or chi2 > best[2]):
                    best = (u, e2, chi2)
            if best is None:
                break
            off[best[0]] = f'{-best[1] * 100:+.1f} cm along the track from its surveyed place'
            prior[best[0]] = c.loose_sigma_m
            est = self._solve(uids, rows, prior)
        return est, off

    def _solve(self, uids, rows, prior):
        """{uid: (e, σ)}: the least-squares solution, in overlapping blocks of lamps."""
        c = self.config
        index = {u: i for i, u in enumerate(uids)}
        n = len(uids)
        out = {}
        step = max(int(c.block), 1)
        for start in range(0, n, step):
            lo, hi = max(0, start - c.overlap), min(n, start + step + c.overlap)
            m = hi - lo
            H = np.diag([1.0 / prior[uids[i]] ** 2 for i in range(lo, hi)])
            g = np.zeros(m)
            for key, t in rows:
                idx = [index[u] - lo for u in key]
                if not all(0 <= i < m for i in idx):
                    continue
                h = np.zeros(m)
                h[idx] = coefficients(t.lam)
                w = 1.0 / (t.sigma_m ** 2 + c.repeatable_sigma_m ** 2)
                H += w * np.outer(h, h)
                g += w * t.q_m * h
            cov = np.linalg.inv(H)
            e = cov @ g
            for k in range(start, min(n, start + step)):
                out[uids[k]] = (float(e[k - lo]),
                                float(math.sqrt(max(cov[k - lo, k - lo], 0.0))))
        return out
