"""Per-frame pipeline: spots in both images → stereo pairs → lamp tracks → UIDs.

Left and right rows are exposed at the same instants (rectified stereo, one stamp), so a
lamp's two spots carry the same chips: the pair's row profiles are averaged, and when
one spot is cut by the image border (its row sums then miss part of the disc) the other
image's profile is used alone (paper: the right image stands in for the left one).
Tracks follow spots from frame to frame by a constant-acceleration prediction in the
left image (new tracks: moved as earlier lamps moved from the same spot height,
:func:`path_prediction`) and own one :class:`~vlc_decoder.core.assembly.PacketAssembler`
each.
"""
import dataclasses
from dataclasses import dataclass, field
import itertools
import logging
import math

import numpy as np

from vlc_decoder.core.assembly import CONFIRMED, PARTIAL, PacketAssembler
from vlc_decoder.core.frame_grid import FrameGrid
from vlc_decoder.core.spots import detect

LOG = logging.getLogger(__name__)

ANOMALY = 3   # decode state of a CRC-valid UID that the lamp map does not know

# how far (px) the left and right spots of one lamp may sit apart in rows
PAIR_ROW_TOLERANCE_PX = 3.0
# frames unseen after which a track's association gate stops growing
MAX_GATE_GROWTH = 3
# path prior: a track seen fewer than this many times (no acceleration yet) is moved as
# earlier lamps moved from the same spot height
PATH_PRIOR_MAX_SEEN = 3
# the prediction is the median of the latest this many earlier paths
PATH_PRIOR_PATHS = 3
# paths of tracks seen at least this many times are kept, for this long after their
# last observation (s)
PATH_MIN_OBSERVATIONS = 3
PATH_MEMORY_S = 5.0
# observations kept per track for its path (a lamp at standstill stays in view for ever)
PATH_MAX_POINTS = 40


@dataclass
class LampRecord:
    """What the decoder reports about one tracked lamp in one stereo frame."""

    track_id: int
    state: int                      # SEARCHING/PARTIAL/CONFIRMED (assembly) or ANOMALY
    uid: int = -1                   # once confirmed (or the anomalous UID)
    position_m: np.ndarray = None   # lamp position in map once confirmed, else None
    left: object = None             # Spot in the left image or None
    right: object = None            # Spot in the right image or None
    chips_seen: int = 0
    bits_known: int = 0
    data_word: int = 0              # data bits read (UID << 8 | CRC), see data_mask
    data_mask: int = 0              # which of the 24 data bits are known
    mid_row: float = 0.0            # mean row of the spot (exposure mid-time reference)
    source: str = ''                # which image(s) the stripes were read from
    content_aligned: bool = False   # the lamp's clock is off: aligned by content


@dataclass
class _Track:
    track_id: int
    assembler: PacketAssembler
    u: float
    v: float
    disparity: float
    stamp_ns: int
    velocity: np.ndarray = field(default_factory=lambda: np.zeros(2))
    acceleration: np.ndarray = field(default_factory=lambda: np.zeros(2))
    missed: int = 0
    seen: int = 0
    anomaly_reported: bool = False
    # the track's timeline on the frame grid (FrameGrid.anchor), None: the stamps
    timeline: tuple = None
    # (stamp_ns, u, v, spot height px) of the latest observations: the lamp's path
    history: list = field(default_factory=list)

    def predict(self, stamp_ns):
        """Predicted left-image position (px) and the part of it that the acceleration
        contributes (px): a lamp's image speeds up as the train closes in on it (by
        half its speed per frame at 120 km/h in the last frames), so the next position
        is extrapolated at constant acceleration, but only from an unbroken run of
        frames; after a gap the velocity alone is used.
        """
        dt = (stamp_ns - self.stamp_ns) * 1e-9
        step = 0.5 * self.acceleration * dt * dt if self.missed == 0 else np.zeros(2)
        return np.array([self.u, self.v]) + self.velocity * dt + step, float(np.hypot(*step))

    def update(self, stamp_ns, u, v):
        """Move the track to a new observation at ``stamp_ns``."""
        dt = (stamp_ns - self.stamp_ns) * 1e-9
        if dt > 0:
            velocity = (np.array([u, v]) - [self.u, self.v]) / dt
            # the acceleration needs two velocities from consecutive observations
            self.acceleration = ((velocity - self.velocity) / dt
                                 if self.seen >= 2 and self.missed == 0 else np.zeros(2))
            self.velocity = velocity
        self.u, self.v, self.stamp_ns = u, v, stamp_ns

    def path(self):
        """(times s, positions (n, 2) px, spot heights px) of the latest observations."""
        h = np.asarray(self.history, dtype=float).reshape(-1, 4)
        return h[:, 0] * 1e-9, h[:, 1:3], h[:, 3]


def path_prediction(paths, height_px, dt_s):
    """How far a lamp whose spot is ``height_px`` tall moves in ``dt_s``, from earlier
    lamps' paths through the image.

    Every lamp of the line crosses the image on a similar path; its image speeds up
    along it as the train closes in (by half per frame at 120 km/h in its last frames),
    so one observation gives no velocity and a constant-velocity guess from two is far
    off. The spot's height gives the range, and so the point of an earlier lamp's path
    (``paths``: list of (times s (n,), positions (n, 2) px, heights (n,) px), oldest
    first) where that lamp was as far: the displacement is that path's ``dt_s`` on from
    there (linear between its observations, extrapolated on its last segment). Vibration
    moves the paths some tens of pixels apart, so they are matched by height, not
    position. The median over the latest ``PATH_PRIOR_PATHS`` paths whose heights
    cover ``height_px`` within ±10 %. Returns the displacement (2,) px or None.
    """
    moves = []
    for times, pos, heights in reversed(paths):       # the latest first
        if len(times) < 2 or not (0.9 * heights.min() <= height_px <= 1.1 * heights.max()):
            continue
        # the first segment reaching the height (heights grow along the path, not
        # strictly: the envelope fit is noisy)
        i = min(max(int(np.searchsorted(np.maximum.accumulate(heights), height_px)) - 1, 0),
                len(times) - 2)
        dh = heights[i + 1] - heights[i]
        lam = float(min(max((height_px - heights[i]) / dh, 0.0), 1.0)) if dh > 0 else 0.0
        tau = times[i] + lam * (times[i + 1] - times[i])
        here = pos[i] + lam * (pos[i + 1] - pos[i])
        target = tau + dt_s
        j = min(max(int(np.searchsorted(times, target)) - 1, 0), len(times) - 2)
        frac = (target - times[j]) / max(times[j + 1] - times[j], 1e-9)
        moves.append(pos[j] + frac * (pos[j + 1] - pos[j]) - here)
        if len(moves) == PATH_PRIOR_PATHS:
            break
    if not moves:
        return None
    return np.median(np.array(moves), axis=0)


def _row_overlap(a, b):
    return min(a.row1, b.row1) - max(a.row0, b.row0)


def _rectified(spots, rectify):
    """(u, v, row shift) per spot in the rectified image, or the raw ones."""
    if rectify is None or not spots:
        return [(s.u, s.v, 0.0) for s in spots]
    uv = np.asarray(rectify(np.array([[s.u, s.v] for s in spots], float)), float)
    return [(u, v, v - s.v) for s, (u, v) in zip(spots, uv.reshape(-1, 2))]


def pair_spots(left, right, max_disparity_px, rectify=None):
    """Greedy stereo pairing: same rows, right spot left of the left one.

    ``rectify``: None for rectified images, else (left, right) raw → rectified pixel
    maps ((N, 2) → (N, 2)) of raw images: the rows and the disparity are compared in
    the rectified images (a lamp's two raw rows differ with a rotated right camera or
    other principal points), the row spans moved with the centres.

    Returns a list of (left_spot or None, right_spot or None).
    """
    rl = _rectified(left, None if rectify is None else rectify[0])
    rr = _rectified(right, None if rectify is None else rectify[1])
    candidates = []
    for i, a in enumerate(left):
        ua, va, sa = rl[i]
        for j, b in enumerate(right):
            ub, vb, sb = rr[j]
            overlap = (min(a.row1 + sa, b.row1 + sb) - max(a.row0 + sa, b.row0 + sb)
                       if rectify is not None else _row_overlap(a, b))
            if overlap < 0.5 * min(a.row1 - a.row0, b.row1 - b.row0):
                continue
            cut = a.cut or b.cut
            # a spot cut by the border has a biased centre: only its rows pair it
            if not cut and abs(va - vb) > PAIR_ROW_TOLERANCE_PX + 0.1 * (a.row1 - a.row0):
                continue
            disparity = ua - ub
            if not -2.0 - (a.width_px + b.width_px if cut else 0.0) <= disparity \
                    <= max_disparity_px:
                continue
            candidates.append((abs(va - vb) + 0.01 * disparity, i, j))
    candidates.sort()
    used_l, used_r, pairs = set(), set(), []
    for _, i, j in candidates:
        if i in used_l or j in used_r:
            continue
        used_l.add(i)
        used_r.add(j)
        pairs.append((left[i], right[j]))
    pairs += [(a, None) for i, a in enumerate(left) if i not in used_l]
    pairs += [(None, b) for j, b in enumerate(right) if j not in used_r]
    return pairs


#: Raw images: the right camera's rows run up to this many rows late or early (its trigger
#: skew, 2-40 us on the realistic rig, unknown to the receivers: 1.3 rows of 30 us); the
#: lag is measured between the two profiles within it (:func:`profile_lag_rows`).
MAX_PROFILE_LAG_ROWS = 3
#: Fewest overlapping rows on which a lag is measured; else the running estimate.
MIN_LAG_OVERLAP_ROWS = 12
#: Measured lags kept for the running estimate (the median of these).
PROFILE_LAG_MEMORY = 64


def lag_overlap(a, b, k):
    """The levels of profiles ``a`` and ``b`` on the rows where b's row r meets a's row
    r + ``k``: (a's levels, b's levels), in b's row order, of one common float type.
    """
    # the rows of a profile are sorted and distinct: a's row r + k is found by bisection
    a_rows, b_rows = np.asarray(a.rows), np.asarray(b.rows)
    dtype = np.result_type(a.level, b.level)
    shifted = b_rows + k
    at = np.minimum(np.searchsorted(a_rows, shifted), len(a_rows) - 1)
    hit = a_rows[at] == shifted
    return np.asarray(a.level[at[hit]], dtype), np.asarray(b.level[hit], dtype)


def profile_lag_rows(a, b, max_rows=MAX_PROFILE_LAG_ROWS):
    """Lag ``s`` (rows, fractional) with ``b.level(r) ≈ a.level(r + s)``: the normalised
    cross-correlation of the two profiles (0 off … 1 on, the chips, no envelope) at
    integer lags within ±``max_rows``, refined by a parabola through the peak. None when
    the profiles overlap on fewer than :data:`MIN_LAG_OVERLAP_ROWS` rows at some lag or
    show no chips.
    """
    scores = []
    for k in range(-max_rows, max_rows + 1):
        x, y = lag_overlap(a, b, k)
        if len(x) < MIN_LAG_OVERLAP_ROWS:
            return None
        x, y = x - x.mean(), y - y.mean()
        norm = math.sqrt(float(x @ x) * float(y @ y))
        if not norm > 0.0:
            return None
        scores.append(float(x @ y) / norm)
    i = int(np.argmax(scores))
    shift = float(i - max_rows)
    if 0 < i < len(scores) - 1:
        c0, c1, c2 = scores[i - 1], scores[i], scores[i + 1]
        den = c0 - 2.0 * c1 + c2
        if den < 0.0:
            shift += 0.5 * (c0 - c2) / den
    return shift


def _on_left_rows(spot, lag):
    """``spot`` (right image) resampled onto the left image's rows: its row r shows the
    left row r + ``lag``.
    """
    rows = np.arange(math.ceil(spot.rows[0] + lag), math.floor(spot.rows[-1] + lag) + 1)
    if rows.size == 0:
        return spot
    return dataclasses.replace(spot, rows=rows, level=np.interp(rows - lag, spot.rows,
                                                                spot.level),
                               weight=np.interp(rows - lag, spot.rows, spot.weight))


def _measured_lag(a, b, lags):
    """:func:`profile_lag_rows` of ``a`` and ``b``, measured once per frame: ``lags`` is
    the frame's memo (keyed by the spots' identities, which it keeps alive), or None.
    """
    if lags is None:
        return profile_lag_rows(a, b)
    key = (id(a), id(b))
    if key not in lags:
        lags[key] = (a, b, profile_lag_rows(a, b))
    return lags[key][2]


def combine_profiles(left, right, align=False, lag_rows=None, lags=None):
    """One row profile from a stereo pair of spots (either may be None).

    ``align`` (raw images, whose right camera is triggered a few microseconds off the
    left one): the right profile is moved onto the left one's rows by the lag the two
    show (:func:`profile_lag_rows`; where they cannot show it, ``lag_rows``, the
    tracker's running estimate) before they are averaged, and a right profile used alone
    by ``lag_rows``, so that every profile of a track runs on one clock; averaged row by
    row, a lag of 40 us (0.8 chip) smeared the chips of every lamp and no UID was
    decoded. ``lags``: the frame's memo of measured lags (see :func:`_measured_lag`).

    Returns rows (R,), level (R,), weight (R,) and a label of the source used.
    """
    sides = [s for s in (left, right) if s is not None]
    whole = [s for s in sides if not s.cut]
    use = whole if whole else sides
    if len(use) == 1:
        s = use[0]
        label = 'left' if s is left else 'right'
        if align and s is right and lag_rows:
            s = _on_left_rows(s, lag_rows)
        return s.rows, s.level, s.weight, label + ('_cut' if s.cut else '')
    a, b = use
    if align:
        lag = _measured_lag(a, b, lags)
        if lag is None:
            lag = lag_rows
        if lag is None:
            label = 'left' if a is left else 'right'
            return a.rows, a.level, a.weight, label + ('_cut' if a.cut else '')
        if lag != 0.0:
            # b's row r shows a's row r + lag: b resampled on a's rows
            on = (a.rows - lag >= b.rows[0]) & (a.rows - lag <= b.rows[-1])
            if not np.any(on):
                label = 'left' if a is left else 'right'
                return a.rows, a.level, a.weight, label + ('_cut' if a.cut else '')
            b = dataclasses.replace(
                b, rows=a.rows[on], level=np.interp(a.rows[on] - lag, b.rows, b.level),
                weight=np.interp(a.rows[on] - lag, b.rows, b.weight))
    lo, hi = min(a.rows[0], b.rows[0]), max(a.rows[-1], b.rows[-1])
    rows = np.arange(lo, hi + 1)
    total_w = np.zeros(len(rows))
    total_y = np.zeros(len(rows))
    best_w = np.zeros(len(rows))
    for s in (a, b):
        idx = s.rows - lo
        total_w[idx] += s.weight
        total_y[idx] += s.weight * s.level
        best_w[idx] = np.maximum(best_w[idx], s.weight)
    keep = total_w > 0
    level = total_y[keep] / total_w[keep]
    return rows[keep], level, best_w[keep], 'both' if not a.cut else 'both_cut'


class LampTracker:
    """Decodes lamps from stereo frames.

    Parameters
    ----------
    cfg : DecoderConfig
    lamp_map : object with ``by_uid(uid)`` returning a lamp (with ``position_m``) or
        None, e.g. ``vlc_common.core.lamp_map.LampMap``; None: no lookup
    max_disparity_px : largest stereo disparity to pair (fx·baseline / nearest depth)
    """

    def __init__(self, cfg, lamp_map=None, max_disparity_px=250.0):
        self.cfg = cfg
        self.lamp_map = lamp_map
        self.max_disparity_px = max_disparity_px
        # raw images: (left, right) raw → rectified pixel maps for the stereo pairing
        self.rectify = None
        # raw images: the lags (rows) measured between whole left and right profiles;
        # their median moves the profiles that cannot show one (the trigger skew is the
        # camera's, the same for every lamp)
        self.profile_lags = []
        self._lag_median = ((), None)     # (the lags it was taken of, their median)
        self.tracks = []
        self._ids = itertools.count(1)
        self.anomalies = {}          # uid -> count of tracks that decoded it
        self.confirmations = []      # (track_id, uid, stamp_ns) at first confirmation
        self.last_stamp_ns = None
        self.resets = 0              # times the tracks were dropped for a stamp jump
        # frames in which two tracks confirmed one UID (_one_track_per_uid); the UIDs
        # warned about (once each)
        self.duplicate_uid_frames = 0
        self._duplicate_uids_warned = set()
        # frame numbers on the camera's period: each track's packet on its own timeline
        self.frames = FrameGrid(cfg.frame_rate_hz)
        self._grid_warned = False
        # (last stamp ns, (times, positions, heights)) of dropped tracks: their paths
        self._paths = []

    def reset(self):
        """Forget every track (and its fragments); track ids keep counting up."""
        self.tracks = []
        self.last_stamp_ns = None
        self._paths = []
        self.frames.reset()
        self.resets += 1

    def stamp_jumped_back(self, stamp_ns):
        """Whether ``stamp_ns`` lies more than ``stamp_jump_reset_s`` before the last
        frame: the input restarted (a looped bag) rather than delivered a frame late.
        """
        return (self.last_stamp_ns is not None and self.last_stamp_ns - int(stamp_ns)
                > self.cfg.stamp_jump_reset_s * 1e9)

    def _lag_estimate(self):
        """Median of the measured profile lags (rows), None before any (computed again
        only when the lags changed: it is asked for several times a frame).
        """
        key = tuple(self.profile_lags)
        if key != self._lag_median[0]:
            self._lag_median = (key, float(np.median(key)) if key else None)
        return self._lag_median[1]

    def _profile_lag(self, spot_l, spot_r, lags=None):
        """Raw images: record the lag of a pair of whole spots; the running estimate.
        ``lags``: the frame's memo (:func:`_measured_lag`).
        """
        if (self.rectify is not None and spot_l is not None and spot_r is not None
                and not spot_l.cut and not spot_r.cut):
            lag = _measured_lag(spot_l, spot_r, lags)
            if lag is not None:
                self.profile_lags.append(lag)
                del self.profile_lags[:-PROFILE_LAG_MEMORY]
        return self._lag_estimate()

    def process(self, stamp_ns, left_image, right_image):
        """Decode one stereo frame (mono8 arrays of equal shape). Returns LampRecords."""
        left = detect(left_image, self.cfg)
        right = detect(right_image, self.cfg) if right_image is not None else []
        return self.process_spots(stamp_ns, left, right)

    def process_spots(self, stamp_ns, left, right):
        """Track and decode already-detected spots of one frame.

        A stamp more than ``stamp_jump_reset_s`` before the last frame resets the tracks
        (with a warning) and is decoded as the first frame of a new sequence; a stamp
        not after the last one otherwise raises ValueError (callers skip such frames).
        """
        stamp_ns = int(stamp_ns)
        if self.stamp_jumped_back(stamp_ns):
            LOG.warning('image stamp jumped back %.3f s: lamp tracks reset',
                        (self.last_stamp_ns - stamp_ns) * 1e-9)
            self.reset()
        if self.last_stamp_ns is not None and stamp_ns <= self.last_stamp_ns:
            raise ValueError(f'stamp {stamp_ns} ns is not after {self.last_stamp_ns} ns')
        self.last_stamp_ns = stamp_ns
        self.frames.add(stamp_ns)
        if self.frames.checked is False and not self._grid_warned:
            # the tracks so far placed their fragments on the wrong period: start again
            self._grid_warned = True
            self.tracks = []
            LOG.warning('frame_rate_hz %g does not match the image stamps: lamp packets are '
                        'assembled on the stamps as they are', self.cfg.frame_rate_hz)
        observations = pair_spots(left, right, self.max_disparity_px, self.rectify)
        # raw images: each pair's lag is measured once in this frame, for the association
        # and the stripes alike
        lags = {}
        matches, tight = self._associate(stamp_ns, observations, lags)
        # each observation's stripes, read once (a raw pair's lag is recorded once)
        profiles = [combine_profiles(spot_l, spot_r, self.rectify is not None,
                                     self._profile_lag(spot_l, spot_r, lags), lags)
                    for spot_l, spot_r in observations]
        records = [self._observe(stamp_ns, *observations[i], profiles[i], matches.get(i))
                   for i in range(len(observations))]
        records = self._one_track_per_uid(stamp_ns, observations, profiles, records, tight)
        seen = {id(t) for t in matches.values()}
        for track in self.tracks:
            if id(track) not in seen and track.stamp_ns != stamp_ns:
                track.missed += 1
        kept = []
        for track in self.tracks:
            if track.missed <= self.cfg.track_max_missed_frames:
                kept.append(track)
            elif track.seen >= PATH_MIN_OBSERVATIONS:
                self._paths.append((track.stamp_ns, track.path()))
        self.tracks = kept
        self._paths = [p for p in self._paths if stamp_ns - p[0] <= PATH_MEMORY_S * 1e9]
        return records

    def _observe(self, stamp_ns, spot_l, spot_r, profile, track):
        """Move ``track`` (None: a new track) to one observation and assemble its
        stripes (``profile``: :func:`combine_profiles` of the observation); returns the
        observation's LampRecord.
        """
        u, v, disparity = self._left_position(spot_l, spot_r, track)
        if track is None:
            track = _Track(next(self._ids), PacketAssembler(self.cfg, stamp_ns), u, v,
                           disparity, stamp_ns)
            self.tracks.append(track)
        else:
            track.update(stamp_ns, u, v)
            if disparity is not None:
                track.disparity = disparity
        frame_ns, track.timeline = self.frames.time_ns(track.timeline, stamp_ns)
        track.missed = 0
        track.seen += 1
        spot = spot_l if spot_l is not None else spot_r
        track.history.append((stamp_ns, u, v, spot.height_px))
        del track.history[:-PATH_MAX_POINTS]
        rows, level, weight, source = profile
        was_confirmed = track.assembler.state == CONFIRMED
        track.assembler.add(frame_ns, rows, level, weight)
        return self._record(track, spot_l, spot_r, rows, source, stamp_ns, was_confirmed)

    def _one_track_per_uid(self, stamp_ns, observations, profiles, records, tight):
        """One UID, one lamp: a frame's records never confirm one UID on two spots.

        Two tracks confirming one UID in a frame cannot both sit on its lamp (lamps are
        10 m apart, their UIDs unique on the map). Seen on the realistic rig (2026-12-07,
        2 of 60 runs, 3 and 7 frames): a confirmed track lost its lamp for a few frames
        (a new track took the lamp over and confirmed the UID again), and, its gate
        grown by the gap, then took the next lamp entering the image at the border where
        its own had entered 0.6 s before; that spot showed only the chips every lamp of
        the line shares, so nothing in its stripes contradicted the old packet.

        A track that reached its spot of this frame only after a gap or outside the
        tight gate (``tight``: the observation indices matched tightly) is split off:
        the spot starts a new track (decoding afresh) and the old track is dropped, its
        lamp being followed by the other. If two or more tightly followed tracks still
        confirm the UID (two spots showing one UID: a duplicated lamp, a reflection),
        none of them is reported confirmed in this frame. Counted in
        ``duplicate_uid_frames``, warned once per UID.
        """
        confirmed = {}
        for index, rec in enumerate(records):
            if rec.state == CONFIRMED:
                confirmed.setdefault(rec.uid, []).append(index)
        duplicates = {uid: idx for uid, idx in confirmed.items() if len(idx) > 1}
        if not duplicates:
            return records
        self.duplicate_uid_frames += 1
        for uid, idx in duplicates.items():
            loose = [i for i in idx if i not in tight]
            for i in loose:
                split = records[i].track_id
                self.tracks = [t for t in self.tracks if t.track_id != split]
                records[i] = self._observe(stamp_ns, *observations[i], profiles[i], None)
            held = [i for i in idx if i in tight]
            if len(held) > 1:
                for i in held:
                    records[i] = dataclasses.replace(records[i], state=PARTIAL, uid=-1,
                                                     position_m=None)
            if uid not in self._duplicate_uids_warned:
                self._duplicate_uids_warned.add(uid)
                LOG.warning('UID %#06x confirmed on %d spots in one frame: %d track(s) split '
                            'off, %d not reported confirmed (warned once per UID; counted in '
                            'duplicate_uid_frames)', uid, len(idx), len(loose),
                            len(held) if len(held) > 1 else 0)
        return records

    def _predict(self, track, stamp_ns):
        """A track's predicted left-image position (px) and its expected step (px).

        A track seen fewer than PATH_PRIOR_MAX_SEEN times has no acceleration yet (and
        after one frame no velocity): it is moved as earlier lamps moved from the same
        spot height (:func:`path_prediction`), when there are such lamps.
        """
        dt = (stamp_ns - track.stamp_ns) * 1e-9
        if track.seen < PATH_PRIOR_MAX_SEEN:
            recent = self._paths + [(t.stamp_ns, t.path()) for t in self.tracks
                                    if t is not track and t.seen >= PATH_MIN_OBSERVATIONS]
            paths = [p for _, p in sorted(recent, key=lambda item: item[0])]
            move = (path_prediction(paths, track.history[-1][3], dt)
                    if paths and track.history else None)
            if move is not None:
                return np.array([track.u, track.v]) + move, float(np.hypot(*move))
        pred, accel_step = track.predict(stamp_ns)
        return pred, float(np.linalg.norm(track.velocity)) * dt + accel_step

    def _left_position(self, spot_l, spot_r, track):
        if spot_l is not None and spot_r is not None:
            return spot_l.u, spot_l.v, spot_l.u - spot_r.u
        if spot_l is not None:
            return spot_l.u, spot_l.v, None
        disparity = track.disparity if track is not None and track.disparity else 0.0
        return spot_r.u + disparity, spot_r.v, None

    def _associate(self, stamp_ns, observations, lags=None):
        """Greedy nearest-neighbour association of observations to tracks: ({observation
        index: track}, the indices matched tightly: the track seen in the last frame and
        the spot close to its prediction). ``lags``: the frame's memo of measured lags.
        """
        pairs = []
        for t_index, track in enumerate(self.tracks):
            pred, step = self._predict(track, stamp_ns)
            for o_index, (spot_l, spot_r) in enumerate(observations):
                u, v, _ = self._left_position(spot_l, spot_r, track)
                spot = spot_l if spot_l is not None else spot_r
                # a lamp unseen for a while (vibration swings it out of view at the
                # border) may come back some way off its predicted position; the growth
                # stops after a few frames, or a stale track would reach across the image
                # for the next lamp
                gate = (self.cfg.track_gate_px * (1 + min(track.missed, MAX_GATE_GROWTH))
                        + 0.5 * step + spot.height_px)
                dist = float(np.hypot(u - pred[0], v - pred[1]))
                if dist <= gate:
                    tight = track.missed == 0 and dist <= self.cfg.track_gate_px + 0.25 * step
                    pairs.append((dist, t_index, o_index, tight))
        # check the nearest candidates against the tracks' lamps: a spot whose stripes
        # are off a track's chip grid, or read chips its packet does not have, belongs
        # to another lamp
        checked = []
        # an observation's profile, once for all the tracks it is a candidate of (the lag
        # estimate is the same for all of them: this frame's lags are recorded later)
        candidate_profiles = {}
        for dist, t_index, o_index, tight in sorted(pairs):
            if o_index not in candidate_profiles:
                candidate_profiles[o_index] = combine_profiles(
                    *observations[o_index], self.rectify is not None, self._lag_estimate(),
                    lags)
            rows, level, weight, _ = candidate_profiles[o_index]
            if self.tracks[t_index].assembler.accepts(stamp_ns, rows, level, weight, tight):
                checked.append((dist, t_index, o_index, tight))
        pairs = checked
        pairs.sort()
        used_t, used_o, matches, tight_obs = set(), set(), {}, set()
        for _, t_index, o_index, tight in pairs:
            if t_index in used_t or o_index in used_o:
                continue
            used_t.add(t_index)
            used_o.add(o_index)
            matches[o_index] = self.tracks[t_index]
            if tight:
                tight_obs.add(o_index)
        return matches, tight_obs

    def _record(self, track, spot_l, spot_r, rows, source, stamp_ns, was_confirmed):
        asm = track.assembler
        state = asm.state
        uid = asm.uid if asm.uid is not None else -1
        position = None
        if state == CONFIRMED:
            lamp = self.lamp_map.by_uid(uid) if self.lamp_map is not None else None
            if lamp is None and self.lamp_map is not None:
                state = ANOMALY
                if not track.anomaly_reported:
                    track.anomaly_reported = True
                    self.anomalies[uid] = self.anomalies.get(uid, 0) + 1
                    LOG.warning('CRC-valid UID %#06x is not in the lamp map', uid)
            elif lamp is not None:
                position = np.asarray(lamp.position_m, dtype=float)
            if not was_confirmed:
                self.confirmations.append((track.track_id, uid, stamp_ns))
        return LampRecord(track_id=track.track_id, state=state, uid=uid,
                          position_m=position, left=spot_l, right=spot_r,
                          chips_seen=asm.chips_seen, bits_known=asm.bits_known,
                          data_word=asm.data_word, data_mask=asm.data_mask,
                          mid_row=0.5 * (float(rows[0]) + float(rows[-1])),
                          source=source, content_aligned=asm.content_mode)
