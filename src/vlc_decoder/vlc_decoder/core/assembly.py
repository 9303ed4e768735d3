"""Packet assembly for one tracked lamp from the fragments its spot shows frame by frame.

A far lamp shows a few chips per frame. Because every image row has a known absolute
exposure time and the lamp's clock is crystal-accurate (±100 ppm, VLC_PROTOCOL.md), the
chip *count* between two frames follows from their stamps: the assembler keeps a chip
clock ``n(t) = (t − t_b)·f`` for the lamp, checks each new fragment's chip edges against
it (a 0.04-chip drift per frame at most) and refits ``t_b`` and ``f`` on all edges seen
(so the lamp's true rate is learnt and long gaps stay safe). Every fragment is then read
on that one chip grid and folded modulo the 54-chip packet; the header is located in the
fold by its pattern ``111000`` — a run of three equal chips occurs nowhere else — and
the packet is decided once, where the header says, with one CRC check. No packet phase
is ever tried against the CRC.

A lamp whose clock is off by more than the tolerance shows up as fragments whose edges
do not fall where the clock predicts. The assembler then aligns by content: a fragment
that shows a header fixes its own packet phase; two such fragments close in time give
the lamp's rate (the packet count between them is unique within the ±3 % search span),
after which the clock is restarted at that rate and assembly proceeds as above.
"""
from dataclasses import dataclass
import logging

import numpy as np

from .chips import (OFF, ON, STATUS_INCONSISTENT, STATUS_OK, chip_states, decide_fold,
                    find_crossings, fold_votes, header_positions, packet_states,
                    recover_clock, slice_chips)
from .protocol import PACKET_CHIPS

LOG = logging.getLogger(__name__)

SEARCHING, PARTIAL, CONFIRMED = 0, 1, 2
STATE_NAMES = {SEARCHING: 'searching', PARTIAL: 'partial', CONFIRMED: 'confirmed'}

# a fragment whose chip edges sit more than this far (chips) from the clock's grid
# breaks the clock hypothesis (crystal drift is < 0.04 chip per frame)
PHASE_TOLERANCE_CHIPS = 0.25
# timing noise of one measured chip edge, chips (weights the clock fit)
EDGE_SIGMA_CHIPS = 0.1

# a fragment is read again on the clock's grid when a refit moved its chips this far
REREAD_CHIPS = 0.05
# this many fragments in a row off the clock's grid restart the clock on them (a bad
# first fragment) or, if they disagree among themselves too, mean an off-spec lamp clock
MISFITS_TO_RESTART = 3


@dataclass(eq=False)
class Fragment:
    """One frame's view of the lamp.

    Rows' exposure mid-times (s, assembler origin), normalised levels and weights, the
    chip edges found in them, and caches: the packet starts its own headers show (read
    on its own edges) and its votes on the clock's fold.
    """

    t_s: np.ndarray
    level: np.ndarray
    weight: np.ndarray
    edges_s: np.ndarray
    edge_w: np.ndarray
    own_starts_s: list = None
    own_rate_hz: float = 0.0
    on_clock: bool = True        # its edges fit the lamp's clock (else set aside)
    votes: tuple = None          # (n_on, n_off, sum_vw, sum_w), each (54,)
    sighted: frozenset = frozenset()
    read_at: float = np.nan      # clock position (chips) of mid_s when the votes were read

    @property
    def mid_s(self):
        return 0.5 * (self.t_s[0] + self.t_s[-1])


class ChipClock:
    """Weighted least-squares chip clock ``n = a + f·t`` with a prior on the rate ``f``."""

    def __init__(self, rate_hz, rate_sigma_hz):
        self.prior_rate = float(rate_hz)
        self.rate_sigma = float(rate_sigma_hz)
        self.f = float(rate_hz)
        self.a = 0.0
        # normal-equation sums over assigned edges (weights in 1/chip²)
        self._s = np.zeros(6)   # Σw, Σw·t, Σw·t², Σw·n, Σw·t·n, count
        self.frames = 0

    def start(self, t_b):
        self.a = -t_b * self.f

    @property
    def t_b(self):
        return -self.a / self.f

    def position(self, t_s):
        return self.a + self.f * np.asarray(t_s)

    def add(self, t_s, n, w):
        wt = w / EDGE_SIGMA_CHIPS ** 2
        self._s += [wt.sum(), (wt * t_s).sum(), (wt * t_s ** 2).sum(), (wt * n).sum(),
                    (wt * t_s * n).sum(), len(t_s)]
        self.frames += 1
        self._solve()

    def _solve(self):
        sw, st, stt, sn, stn, _ = self._s
        p = 1.0 / self.rate_sigma ** 2
        # minimise Σ w (a + f t − n)² + p (f − f_prior)²
        m = np.array([[sw, st], [st, stt + p]])
        rhs = np.array([sn, stn + p * self.prior_rate])
        if sw <= 0 or abs(np.linalg.det(m)) < 1e-30:
            return
        self.a, self.f = np.linalg.solve(m, rhs)


class PacketAssembler:
    """Assembles one lamp's packet from its per-frame row profiles.

    Parameters
    ----------
    cfg : DecoderConfig
    origin_ns : time origin of the assembler's float times (ns since the epoch), so
        that sub-microsecond edge times survive in float64
    """

    def __init__(self, cfg, origin_ns):
        self.cfg = cfg
        self.origin_ns = int(origin_ns)
        self.fragments = []
        self.clock = None
        self.content_mode = False
        self.rate_hz = cfg.chip_rate_hz
        self.uid = None
        self.status = None
        self.bits_known = 0
        self.chips_seen = 0
        self.contradictions = 0
        self.misfits = 0

    @property
    def state(self):
        if self.uid is not None:
            return CONFIRMED
        return PARTIAL if self.chips_seen > 0 else SEARCHING

    # ------------------------------------------------------------------ input
    def add(self, stamp_ns, rows, level, weight):
        """Add one frame's fragment: image rows (R,), levels (R,), weights (R,)."""
        cfg = self.cfg
        t = ((int(stamp_ns) - self.origin_ns) * 1e-9
             + np.asarray(rows, float) * cfg.row_time_s + 0.5 * cfg.exposure_s)
        level = np.asarray(level, float)
        weight = np.asarray(weight, float)
        if len(t) == 0:
            return
        tc, wc = find_crossings(t[None], level[None], weight[None])
        keep = wc[0] > 0
        frag = Fragment(t, level, weight, tc[0][keep], wc[0][keep])
        self.fragments.append(frag)
        if len(self.fragments) > cfg.max_fragments:
            self.fragments.pop(0)
            self._rebuild_clock()
        else:
            self._place(frag)
        self._assemble()

    def accepts(self, stamp_ns, rows, level, weight):
        """Whether a new fragment's chip edges fall on this lamp's chip grid.

        False only when the clock is established (fitted on several frames, not in
        content mode) and the fragment's edges are clearly off it: then the spot is
        another lamp. Without a clock, or without edges, there is no evidence against.
        """
        if self.clock is None or self.content_mode or self.clock.frames < 2:
            return True
        cfg = self.cfg
        t = ((int(stamp_ns) - self.origin_ns) * 1e-9
             + np.asarray(rows, float) * cfg.row_time_s + 0.5 * cfg.exposure_s)
        tc, wc = find_crossings(t[None], np.asarray(level, float)[None],
                                np.asarray(weight, float)[None])
        keep = wc[0] > 0
        if np.count_nonzero(keep) < 2:
            return True
        x = self.clock.position(tc[0][keep])
        resid = x - np.round(x)
        phase = np.angle(np.sum(wc[0][keep] * np.exp(2j * np.pi * resid))) / (2 * np.pi)
        return abs(phase) <= PHASE_TOLERANCE_CHIPS

    # ------------------------------------------------------------------ clock
    def _start_clock(self, frag, rate_hz, rate_sigma_hz):
        self.clock = ChipClock(rate_hz, rate_sigma_hz)
        t_b, _, _ = recover_clock(frag.edges_s[None], frag.edge_w[None], rate_hz,
                                  np.array([frag.mid_s]))
        self.clock.start(t_b[0])

    def _phase_error(self, frag):
        """Weighted mean offset (chips, ±0.5) of ``frag``'s edges from the clock's grid."""
        x = self.clock.position(frag.edges_s)
        resid = x - np.round(x)
        return np.angle(np.sum(frag.edge_w * np.exp(2j * np.pi * resid))) / (2 * np.pi)

    def _fit(self, frag):
        phase = self._phase_error(frag)
        x = self.clock.position(frag.edges_s)
        self.clock.add(frag.edges_s, np.round(x - phase), frag.edge_w)

    def _place(self, frag):
        """Check ``frag``'s chip edges against the clock and add them to its fit.

        A fragment off the grid is set aside (a glitch, or a spot of another lamp); a run
        of them restarts the clock on them when they agree among themselves, otherwise
        the lamp's clock is off-spec and the assembler aligns by content.
        """
        if len(frag.edges_s) == 0 or self.content_mode:
            return
        if self.clock is None:
            self._start_clock(frag, self.rate_hz,
                              self.cfg.chip_rate_hz * self.cfg.clock_tolerance_ppm * 1e-6)
        if abs(self._phase_error(frag)) <= PHASE_TOLERANCE_CHIPS:
            frag.on_clock = True
            self.misfits = 0
            self._fit(frag)
            return
        frag.on_clock = False
        self.misfits += 1
        if self.misfits >= MISFITS_TO_RESTART:
            self._restart_on_recent()

    def _restart_on_recent(self):
        """Restart the clock on the latest run of misfits, if they agree with each other."""
        recent = [f for f in self.fragments if len(f.edges_s)][-self.misfits:]
        rate_sigma = self.cfg.chip_rate_hz * self.cfg.clock_tolerance_ppm * 1e-6
        self._start_clock(recent[0], self.rate_hz, rate_sigma)
        self._fit(recent[0])
        for frag in recent[1:]:
            if abs(self._phase_error(frag)) > PHASE_TOLERANCE_CHIPS:
                LOG.debug('fragments disagree with any one clock: aligning by content')
                self.content_mode = True
                return
            self._fit(frag)
        LOG.debug('chip clock restarted on the latest %d fragments', len(recent))
        self.misfits = 0
        for frag in self.fragments:
            frag.read_at = np.nan
            if len(frag.edges_s):
                frag.on_clock = frag in recent or abs(
                    self._phase_error(frag)) <= PHASE_TOLERANCE_CHIPS

    def _rebuild_clock(self):
        """Refit the clock on the kept fragments, in time order."""
        self.clock = None
        self.content_mode = False
        self.misfits = 0
        for frag in self.fragments:
            frag.read_at = np.nan
            self._place(frag)

    # ------------------------------------------------------------------ folding
    def _read(self, frags, t_b, rate):
        """Read fragments on one chip grid: n0 (F,), states, value, weight (F, K)."""
        cfg = self.cfg
        n_rows = max(len(f.t_s) for f in frags)
        count = len(frags)
        t = np.zeros((count, n_rows))
        y = np.zeros((count, n_rows))
        w = np.zeros((count, n_rows))
        for i, frag in enumerate(frags):
            r = len(frag.t_s)
            t[i, :r], y[i, :r], w[i, :r] = frag.t_s, frag.level, frag.weight
            t[i, r:] = frag.t_s[-1]
        k = int(np.ceil((n_rows * cfg.row_time_s + cfg.exposure_s) * np.max(rate))) + 4
        n0, value, weight = slice_chips(t, y, w, np.broadcast_to(t_b, (count,)).astype(float),
                                        np.broadcast_to(rate, (count,)).astype(float),
                                        cfg.exposure_s, k)
        states = chip_states(value, weight, cfg.chip_margin, cfg.min_chip_weight)
        return n0, states, value, weight

    def _update_votes(self):
        """(Re)read the fragments whose chips the latest clock fit moved."""
        stale = [f for f in self.fragments if f.on_clock
                 and not abs(self.clock.position(f.mid_s) - f.read_at) < REREAD_CHIPS]
        if not stale:
            return
        n0, states, value, weight = self._read(stale, self.clock.t_b, self.clock.f)
        shift = n0 % PACKET_CHIPS
        n_on, n_off, sum_vw, sum_w = fold_votes(states, value, weight, shift)
        heads = header_positions(states)
        for i, frag in enumerate(stale):
            frag.votes = (n_on[i], n_off[i], sum_vw[i], sum_w[i])
            frag.sighted = frozenset(int(p) for p in (n0[i] + np.flatnonzero(heads[i]))
                                     % PACKET_CHIPS)
            frag.read_at = float(self.clock.position(frag.mid_s))

    def _assemble(self):
        if self.content_mode:
            self._content_alignment()
        if self.clock is None or self.content_mode:
            self.status = None
            self.bits_known = 0
            return
        self._update_votes()
        used = [f for f in self.fragments if f.on_clock and f.votes is not None]
        if not used:
            return
        n_on, n_off, sum_vw, sum_w = (np.sum([f.votes[j] for f in used], axis=0)
                                      for j in range(4))
        fold = packet_states(n_on[None], n_off[None], sum_vw[None], sum_w[None],
                             self.cfg.chip_margin, self.cfg.min_chip_weight)[0]
        sighted = frozenset().union(*(f.sighted for f in used))
        if len(sighted) > 1:
            # fragments showing a header on their own put it at different places: the
            # clock does not hold for this lamp
            LOG.debug('header sightings disagree on the packet phase: aligning by content')
            self.content_mode = True
            self._content_alignment()
            self.status = None
            self.bits_known = 0
            return
        self._decide(fold, sighted)

    def _decide(self, fold, sighted):
        """Locate the packet start in the fold and decide there (one CRC check)."""
        self.chips_seen = int(np.count_nonzero((fold == ON) | (fold == OFF)))
        uid, status, bits, origin = decide_fold(fold[None])
        self.status = int(status[0])
        self.bits_known = int(bits[0])
        if sighted and origin[0] >= 0 and int(origin[0]) not in sighted:
            self.status = STATUS_INCONSISTENT
            return
        if status[0] == STATUS_OK:
            self._confirm(int(uid[0]))

    def _confirm(self, uid):
        if self.uid is None:
            self.uid = uid
        elif uid != self.uid:
            self.contradictions += 1
            LOG.warning('lamp track decoded UID %#06x after confirming %#06x', uid, self.uid)

    # ------------------------------------------------------------------ content mode
    def _own_starts(self, frag):
        """Packet-start times (s) of the headers ``frag`` shows on its own edges."""
        if frag.own_starts_s is not None and frag.own_rate_hz == self.rate_hz:
            return frag.own_starts_s
        frag.own_rate_hz = self.rate_hz
        frag.own_starts_s = []
        if len(frag.edges_s):
            t_b, f, _ = recover_clock(frag.edges_s[None], frag.edge_w[None], self.rate_hz,
                                      np.array([frag.mid_s]))
            n0, states, _, _ = self._read([frag], t_b[0], f[0])
            heads = np.flatnonzero(header_positions(states)[0])
            frag.own_starts_s = [float(t_b[0] + (n0[0] + p) / f[0]) for p in heads[:1]]
        return frag.own_starts_s

    def _content_alignment(self):
        """Restart the clock from two header-showing fragments close in time.

        Each header sighting gives the time a packet starts. Between two sightings lie a
        whole number of packets; with the rate known to ±rate_search_tolerance that number
        is unique when the sightings are a few frames apart, and gives the rate.
        """
        cfg = self.cfg
        starts = [t for frag in self.fragments for t in self._own_starts(frag)]
        if len(starts) < 2:
            return
        lo = cfg.chip_rate_hz * (1 - cfg.rate_search_tolerance)
        hi = cfg.chip_rate_hz * (1 + cfg.rate_search_tolerance)
        for j in range(len(starts) - 1, 0, -1):
            dt = starts[j] - starts[j - 1]
            if dt <= 0:
                continue
            packets = np.arange(np.ceil(lo * dt / PACKET_CHIPS),
                                np.floor(hi * dt / PACKET_CHIPS) + 1)
            if len(packets) != 1:
                continue
            rate = packets[0] * PACKET_CHIPS / dt
            # the pair's timing (≈0.1 chip) bounds the rate error
            sigma = max(0.1 / dt, cfg.chip_rate_hz * cfg.clock_tolerance_ppm * 1e-6)
            LOG.debug('content alignment: lamp rate %.1f Hz', rate)
            self.rate_hz = rate
            self.content_mode = False
            self.clock = None
            self.misfits = 0
            for frag in self.fragments:
                frag.read_at = np.nan
                if self.clock is None and len(frag.edges_s):
                    self._start_clock(frag, rate, sigma)
                self._place(frag)
            if self.content_mode:
                # the restarted clock fails too: keep only the latest fragment
                self.fragments = self.fragments[-1:]
                self.content_mode = False
                self.clock = None
                self.misfits = 0
                self.rate_hz = cfg.chip_rate_hz
                self.fragments[0].read_at = np.nan
                self._place(self.fragments[0])
            return
