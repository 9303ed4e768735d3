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
after which the clock is restarted at that rate and assembly proceeds as above. Until
then fragments are aligned by their overlaps: each is read on its own edges and placed
where its chips agree with the fold of the others at one cyclic shift only
(:meth:`PacketAssembler._overlap_decision`); the packet start is then located by
structure as on the clock. A decision is refused when it contradicts the track's first
fragments (the track is the lamp it started on) or, by overlaps, any fragment it holds.
"""
from dataclasses import dataclass
import logging

import numpy as np

from vlc_common.core.protocol import PACKET_CHIPS, packet_chips
from vlc_decoder.core.chips import (
    MIN_CONTRADICTIONS,
    OFF,
    ON,
    STATUS_INCONSISTENT,
    STATUS_OK,
    chip_states,
    decide_fold,
    find_crossings,
    fold_votes,
    header_positions,
    known_bits,
    packet_states,
    recover_clock,
    slice_chips,
)

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
# alignment by overlap: a fragment's own chips are placed in a fold at the one cyclic
# shift where they agree with the fold's on at least this many chips, while every other
# shift has at least MIN_CONTRADICTIONS disagreements (periodic Manchester runs make
# several shifts agree: then the fragment waits for more of the fold)
MIN_OVERLAP_CHIPS = 8
# consecutive fragments off the clock's grid after which alignment by overlap is tried
# while the clock still stands
OVERLAP_AFTER_MISFITS = 2
# the first fragments of a track, which a decision must not outvote (the track is the
# lamp it started on)
FOUNDERS = 2
# fragments kept for alignment by overlap (each new one is matched against their fold)
MAX_CONTENT_FRAGMENTS = 30
# an undecided track whose fragments contradict each other on the clock for this many
# frames in a row forgets its oldest ones until the rest agree: a lamp entering at the
# image's edge leaves clipped, misread stripes (_forget_inconsistent). Bounded: at most
# FORGET_PER_FRAME a frame (each costs a refit of the clock and a read of every kept
# fragment: 15 ms with 120 kept), only while the track holds at most
# FORGET_MAX_KEPT fragments (a young track: its entry frames), at most MAX_FORGOTTEN in
# its life, and never below MIN_KEPT_FRAGMENTS
FORGET_AFTER_INCONSISTENT = 2
FORGET_PER_FRAME = 2
FORGET_MAX_KEPT = 20
MAX_FORGOTTEN = 12
MIN_KEPT_FRAGMENTS = 3


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
    own: dict = None             # its chips read on its own edges (alignment by overlap)
    sighted: frozenset = frozenset()
    read_at: float = np.nan      # clock position (chips) of mid_s when the votes were read

    @property
    def mid_s(self):
        return 0.5 * (self.t_s[0] + self.t_s[-1])


def overlap_contradictions(states, fold):
    """Disagreements and overlap of a chip sequence with a fold at every cyclic shift.

    Parameters
    ----------
    states : (K,) ON/OFF/UNKNOWN chip reads of one fragment
    fold : (54,) ON/OFF/UNKNOWN/CONFLICT folded packet chips (any origin)

    Returns
    -------
    contradictions, overlap : (54,) int, for chip j of ``states`` at fold index
    (j + shift) % 54: reads opposite to the fold's, and reads where both are decided
    """
    idx = (np.arange(PACKET_CHIPS)[:, None] + np.arange(len(states))[None, :]) % PACKET_CHIPS
    f = fold[idx]
    both = ((f == ON) | (f == OFF)) & ((states == ON) | (states == OFF))[None, :]
    return (np.count_nonzero(both & (f != states[None, :]), axis=1),
            np.count_nonzero(both, axis=1))


def unique_shift(contradictions, overlap):
    """The one shift where a fragment fits a fold (see MIN_OVERLAP_CHIPS), or None."""
    fits = (contradictions == 0) & (overlap >= MIN_OVERLAP_CHIPS)
    if np.count_nonzero(fits) != 1:
        return None
    shift = int(np.argmax(fits))
    if np.delete(contradictions, shift).min() < MIN_CONTRADICTIONS:
        return None
    return shift


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
        # data bits read once the packet start is located (word UID << 8 | CRC, MSB
        # first, and the mask of the known bits): what a partial packet says, to be
        # matched against the lamp a map predicts, never a UID
        self.data_word = 0
        self.data_mask = 0
        self.chips_seen = 0
        self.contradictions = 0
        self.misfits = 0
        self.inconsistent_frames = 0  # frames in a row with an inconsistent fold, undecided
        self.forgotten = 0            # fragments forgotten for it (_forget_inconsistent)
        self.fold = None             # (54,) packet chips on the clock's fold
        self.content_fold = None     # (54,) packet chips of the fragments placed by overlap
        self.placed = {}             # fragment -> its shift in the content fold

    @property
    def state(self):
        if self.uid is not None:
            return CONFIRMED
        return PARTIAL if self.chips_seen > 0 else SEARCHING

    # ------------------------------------------------------------------ input
    def _fragment(self, stamp_ns, rows, level, weight):
        cfg = self.cfg
        t = ((int(stamp_ns) - self.origin_ns) * 1e-9
             + np.asarray(rows, float) * cfg.row_time_s + 0.5 * cfg.exposure_s)
        level = np.asarray(level, float)
        weight = np.asarray(weight, float)
        if len(t) == 0:
            return None
        tc, wc = find_crossings(t[None], level[None], weight[None])
        keep = wc[0] > 0
        return Fragment(t, level, weight, tc[0][keep], wc[0][keep])

    def add(self, stamp_ns, rows, level, weight):
        """Add one frame's fragment: image rows (R,), levels (R,), weights (R,)."""
        cfg = self.cfg
        frag = self._fragment(stamp_ns, rows, level, weight)
        if frag is None:
            return
        self.fragments.append(frag)
        if len(self.fragments) > cfg.max_fragments:
            self.fragments.pop(0)
            self._rebuild_clock()
        else:
            self._place(frag)
        if self.uid is None:
            # once confirmed, the clock still follows the lamp (its grid and the packet
            # it places check the spots offered to the track) but nothing is left to
            # decide
            self._assemble()
            self._forget_inconsistent()

    def _forget_inconsistent(self):
        """Forget the oldest fragments of a young, undecided track whose fold has been
        inconsistent on the clock for ``FORGET_AFTER_INCONSISTENT`` frames in a row, one
        at a time until the rest agree (bounds: see ``FORGET_PER_FRAME``).

        A lamp that enters the image at its top or bottom edge is seen for its first
        frames as a spot clipped to a few rows, whose stripes can read wrong (with the
        lens's distortion and vignetting a far lamp stays in a raw image's corner for a
        third of a second); kept, they contradict every later fragment, the lamp is
        decided only once the track has left the clock for alignment by content, and
        that costs 10–20 ms a frame. Forgetting weakens no check of a decision: the
        kept fragments must still agree, fit the clock and pass the CRC; the track's
        founders are then its oldest kept fragments. Alignment by content (an off-spec
        lamp clock) is left as it is, and so is an older track: there the fold's
        inconsistency is not its entry, and every refit would read every fragment
        again.
        """
        if self.status != STATUS_INCONSISTENT or self.content_mode:
            self.inconsistent_frames = 0
            return
        self.inconsistent_frames += 1
        if self.inconsistent_frames < FORGET_AFTER_INCONSISTENT:
            return
        for _ in range(FORGET_PER_FRAME):
            if (self.status != STATUS_INCONSISTENT or self.uid is not None
                    or self.content_mode or self.forgotten >= MAX_FORGOTTEN
                    or not MIN_KEPT_FRAGMENTS < len(self.fragments) <= FORGET_MAX_KEPT):
                break
            self.fragments.pop(0)
            self.forgotten += 1
            self._rebuild_clock()
            self._assemble()
            LOG.debug('inconsistent fold: the oldest fragment forgotten (%d so far), %d '
                      'kept', self.forgotten, len(self.fragments))

    def accepts(self, stamp_ns, rows, level, weight, tight=False):
        """Whether a new spot's stripes can be this lamp's.

        A ``tight`` geometric match (the track seen in the last frame, the spot close to
        its prediction) is this lamp unless the lamp is confirmed and the spot is off its
        clock's grid and no cyclic shift of the spot's own chips agrees with its packet.
        Otherwise the spot's edges must
        fall on the chip grid of a clock fitted on several frames and, once the fold
        holds ``MIN_OVERLAP_CHIPS`` decided chips, its chips must agree with them where
        the clock places them; without such a clock only an unconfirmed track may take
        it. Content alone never carries a track to a spot far from it: a spot of another
        lamp of the line may show just the header and line bits that they all share.
        Spots without edges are accepted.
        """
        frag = self._fragment(stamp_ns, rows, level, weight)
        if frag is None or len(frag.edges_s) < 2:
            return True
        if tight and self.uid is None:
            return True
        clocked = (self.clock is not None and not self.content_mode
                   and self.clock.frames >= 2)
        fold = self.fold
        if clocked and abs(self._phase_error(frag)) <= PHASE_TOLERANCE_CHIPS:
            if tight or fold is None or np.count_nonzero((fold == ON) | (fold == OFF)) \
                    < MIN_OVERLAP_CHIPS:
                return True
            n0, states, _, _ = self._read([frag], self.clock.t_b, self.clock.f)
            pos = (n0[0] + np.arange(states.shape[1])) % PACKET_CHIPS
            read = (states[0] == ON) | (states[0] == OFF)
            decided = (fold[pos] == ON) | (fold[pos] == OFF)
            if np.count_nonzero(read & decided & (states[0] != fold[pos])) \
                    < MIN_CONTRADICTIONS:
                return True
        if not tight:
            # no clock, or off its grid, or against its fold: geometry alone may extend
            # a lamp still being read, never carry a confirmed UID
            return not clocked and self.uid is None
        own = self._own_read(frag)['states']
        packet = np.where(packet_chips(self.uid) == 1, ON, OFF).astype(np.int8)
        contradictions, _ = overlap_contradictions(own, packet)
        return contradictions.min() < MIN_CONTRADICTIONS

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
        # no noise margin here (unlike a single profile's decision): a noisy fragment's
        # reads are outvoted or conflict in the fold, and its conflicts are what stops
        # a few clean spots of another lamp from deciding the packet alone
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
        if self.content_mode:
            self.fold = None
            self._apply(self._overlap_decision())
            return
        if self.clock is None:
            self.status = None
            self.bits_known = self.data_word = self.data_mask = 0
            return
        self._update_votes()
        used = [f for f in self.fragments if f.on_clock and f.votes is not None]
        if not used:
            return
        fold = self._clock_fold(used)
        sighted = frozenset().union(*(f.sighted for f in used))
        if len(sighted) > 1:
            # fragments showing a header on their own put it at different places: the
            # clock does not hold for this lamp
            LOG.debug('header sightings disagree on the packet phase: aligning by content')
            self.content_mode = True
            self.fold = None
            self._apply(self._overlap_decision())
            return
        self.fold = fold
        outcomes = [self._decide(fold, sighted)]
        if outcomes[0]['uid'] is not None and self._outvoted(used[:FOUNDERS], outcomes[0]):
            outcomes[0].update(status=STATUS_INCONSISTENT, uid=None)
        if outcomes[0]['uid'] is None and self.misfits >= OVERLAP_AFTER_MISFITS:
            # the latest fragments are off the clock's grid (a lamp clock drifting
            # off-spec, before it is declared so): they can still be placed by their
            # overlaps. One misfit alone is more likely another lamp's spot. The
            # decision must then place the misfits that asked for it.
            overlap = self._overlap_decision()
            misfits = [f for f in self.fragments if len(f.edges_s)][-self.misfits:]
            if not all(f in self.placed for f in misfits):
                overlap.update(status=STATUS_INCONSISTENT, uid=None)
            outcomes.append(overlap)
        self._apply(*outcomes)
        if self.uid is not None and outcomes[0]['uid'] == self.uid:
            # the whole packet where the clock places it: what later spots must show
            packet = np.where(packet_chips(self.uid) == 1, ON, OFF).astype(np.int8)
            self.fold = np.roll(packet, outcomes[0]['origin'])

    @staticmethod
    def _outvoted(used, outcome):
        """Whether the decided packet overrides one of ``used`` fragments' reads in two
        places.

        Applied to the track's first fragments: a track is the lamp it started on. The
        fold's majority vote tolerates a misread and outvotes the odd spot of another
        lamp taken later; but a few clean spots of a neighbouring lamp that landed on
        the clock's grid can also outvote the lamp's own noisy reads, and then the
        decision contradicts the fragments the track was founded on.
        """
        packet = np.where(packet_chips(outcome['uid']) == 1, ON, OFF).astype(np.int8)
        in_fold = np.roll(packet, outcome['origin'])
        for frag in used:
            n_on, n_off = frag.votes[0], frag.votes[1]
            read = np.where(n_on > n_off, ON, np.where(n_off > n_on, OFF, 0))
            if np.count_nonzero((read != 0) & (read != in_fold)) >= MIN_CONTRADICTIONS:
                return True
        return False

    def _clock_fold(self, used):
        """Packet chips from the votes of ``used`` fragments on the clock's fold."""
        n_on, n_off, sum_vw, sum_w = (np.sum([f.votes[j] for f in used], axis=0)
                                      for j in range(4))
        return packet_states(n_on[None], n_off[None], sum_vw[None], sum_w[None],
                             self.cfg.chip_margin, self.cfg.min_chip_weight)[0]

    def _decide(self, fold, sighted):
        """Locate the packet start in the fold and decide there (one CRC check).

        Returns the outcome: status, bits_known, data word and mask, chips seen, and the
        UID when the CRC confirmed it (else None).
        """
        out = {'status': None, 'bits': 0, 'word': 0, 'mask': 0, 'uid': None, 'origin': -1,
               'chips': int(np.count_nonzero((fold == ON) | (fold == OFF)))}
        uid, status, bits, origin = decide_fold(fold[None])
        out['status'], out['bits'], out['origin'] = int(status[0]), int(bits[0]), int(origin[0])
        if sighted and origin[0] >= 0 and int(origin[0]) not in sighted:
            out['status'] = STATUS_INCONSISTENT
            return out
        if origin[0] >= 0 and status[0] != STATUS_INCONSISTENT:
            word, mask = known_bits(np.roll(fold, -int(origin[0]))[None])
            out['word'], out['mask'] = int(word[0]), int(mask[0])
        if status[0] == STATUS_OK:
            out['uid'] = int(uid[0])
        return out

    def _apply(self, *outcomes):
        """Report the most complete of the fold decisions and confirm what the CRC did."""
        best = max(outcomes, key=lambda o: (o['uid'] is not None, o['bits'], o['chips']))
        self.status, self.bits_known = best['status'], best['bits']
        self.data_word, self.data_mask = best['word'], best['mask']
        self.chips_seen = best['chips']
        for outcome in outcomes:
            if outcome['uid'] is not None:
                self._confirm(outcome['uid'])

    def _confirm(self, uid):
        if self.uid is None:
            self.uid = uid
        elif uid != self.uid:
            self.contradictions += 1
            LOG.warning('lamp track decoded UID %#06x after confirming %#06x', uid, self.uid)

    # ------------------------------------------------------------------ content mode
    def _own_read(self, frag):
        """``frag``'s chips read on its own edges (rate searched when it spans enough
        chips): states, value, weight (K,) and the chip indices where it shows a
        header. Cached on the fragment.
        """
        if frag.own is None:
            cfg = self.cfg
            span = (frag.t_s[-1] - frag.t_s[0]) * cfg.chip_rate_hz
            tolerance = cfg.rate_search_tolerance if span >= cfg.rate_search_min_chips else 0
            t_b, f, _ = recover_clock(frag.edges_s[None], frag.edge_w[None], cfg.chip_rate_hz,
                                      np.array([frag.mid_s]), tolerance)
            _, states, value, weight = self._read([frag], t_b[0], f[0])
            frag.own = {'states': states[0], 'value': value[0], 'weight': weight[0],
                        'heads': np.flatnonzero(header_positions(states)[0])}
        return frag.own

    def _content_fold(self):
        """Fold of the fragments placed by overlap."""
        if not self.placed:
            return np.zeros(PACKET_CHIPS, np.int8)
        frags = list(self.placed)
        k = max(len(f.own['states']) for f in frags)
        states = np.zeros((len(frags), k), np.int8)
        value = np.full((len(frags), k), 0.5)
        weight = np.zeros((len(frags), k))
        for i, frag in enumerate(frags):
            n = len(frag.own['states'])
            states[i, :n], value[i, :n], weight[i, :n] = (
                frag.own['states'], frag.own['value'], frag.own['weight'])
        shift = np.array([self.placed[f] for f in frags])
        votes = [v.sum(axis=0) for v in fold_votes(states, value, weight, shift)]
        return packet_states(*(v[None] for v in votes), self.cfg.chip_margin,
                             self.cfg.min_chip_weight)[0]

    def _overlap_decision(self):
        """Align fragments by the overlaps of their own chips (off-spec lamp clock).

        Without a clock the frame-to-frame packet phase is unknown, but every fragment's
        chips can be read on its own edges. The fragment with the most chips anchors a
        fold; every other one is placed at the one cyclic shift where its chips agree
        with the fold (:func:`unique_shift`), which grows the fold, until no more fit.
        The packet start is then located in that fold by the protocol's structure and
        decided once, as on the clock (:meth:`_decide`).
        """
        candidates = [f for f in self.fragments[-MAX_CONTENT_FRAGMENTS:] if len(f.edges_s)]
        for frag in candidates:
            self._own_read(frag)
        sizable = {f for f in candidates if np.count_nonzero(
            (f.own['states'] == ON) | (f.own['states'] == OFF)) >= MIN_OVERLAP_CHIPS}
        # the fragment with the most chips anchors the fold (the biggest overlaps)
        candidates.sort(key=lambda f: -np.count_nonzero(
            (f.own['states'] == ON) | (f.own['states'] == OFF)))
        if not sizable:
            self.placed = {}
            return self._decide(np.zeros(PACKET_CHIPS, np.int8), frozenset())
        self.placed = {candidates[0]: 0}
        fold = self._content_fold()
        grown = True
        while grown:
            grown = False
            for frag in candidates:
                if frag in self.placed:
                    continue
                shift = unique_shift(*overlap_contradictions(frag.own['states'], fold))
                if shift is not None:
                    self.placed[frag] = shift
                    fold = self._content_fold()
                    grown = True
        self.content_fold = fold
        sighted = frozenset(int(p + shift) % PACKET_CHIPS for frag, shift in self.placed.items()
                            for p in frag.own['heads'])
        # the fold must be the lamp of every fragment: one that disagrees with it at
        # every shift (another lamp's spot taken by the track, or a misread) leaves the
        # fold undecided, else a few foreign fragments agreeing among themselves would
        # decide the foreign lamp's UID
        foreign = any(
            np.count_nonzero((f.own['states'] == ON) | (f.own['states'] == OFF))
            >= MIN_OVERLAP_CHIPS
            and overlap_contradictions(f.own['states'], fold)[0].min() >= MIN_CONTRADICTIONS
            for f in candidates if f not in self.placed)
        out = self._decide(fold, sighted)
        if out['uid'] is not None and not foreign:
            # the decided packet, now whole, must fit every fragment the track holds, and
            # every placed one where it was placed (no fragment outvoted): fragments of
            # a neighbouring lamp of the line share its header and line bits and can be
            # placed by them; the lamp's own fragments then disagree with the packet
            # where the lamp bits and the CRC differ
            packet = np.where(packet_chips(out['uid']) == 1, ON, OFF).astype(np.int8)
            in_fold = np.roll(packet, out['origin'])
            foreign = any(
                overlap_contradictions(f.own['states'], packet)[0].min() >= MIN_CONTRADICTIONS
                for f in candidates) or any(
                overlap_contradictions(f.own['states'], in_fold)[0][shift]
                >= MIN_CONTRADICTIONS for f, shift in self.placed.items())
        if len(sighted) > 1 or foreign:
            out.update(status=STATUS_INCONSISTENT, bits=0, word=0, mask=0, uid=None)
        return out

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
        lo = cfg.chip_rate_hz * (1 - cfg.rate_search_tolerance)
        hi = cfg.chip_rate_hz * (1 + cfg.rate_search_tolerance)
        # the latest pair of consecutive sightings that gives the rate: the sightings
        # are read newest first and only as far back as that pair (each one costs a
        # clock fit and a read of its fragment, and in content mode the rate, which
        # keys their cache, changes at every frame)
        starts = (t for frag in reversed(self.fragments) for t in
                  reversed(self._own_starts(frag)))
        later = next(starts, None)
        for earlier in starts:
            dt, later = later - earlier, earlier
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
