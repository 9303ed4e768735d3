"""Join the decoder's lamp records and the spot locator's spot pairs of one frame.

Both arrive as structured numpy arrays (one row per lamp, see
:mod:`train_localizer.conversions`) stamped with the same image stamp, at different
times and possibly out of step. :class:`FrameJoiner` buffers each side by stamp and
releases a frame as soon as both sides of that stamp are there. A frame whose lamp
records never come (the decoder skipped it) is released with its spots alone — every
lamp then unconfirmed, usable only as the lamp the map predicts — when the decoder has
moved past that stamp or after ``timeout_s`` of waiting; lamp records whose spots never
come are dropped the same way.

Inside a frame a decoder record belongs to the spot pair nearest to it in the left
image (within ``match_radius_px``, or half the larger side of the decoder's spot box
when that is more): the decoder's spot centre (``left_u``, ``left_v``) and the spot
locator's sub-pixel centre (``u_left``, ``v_left``) of one lamp differ by the decoder's
coarser centring only, while lamps are tens of pixels apart. A near spot cut by the
image border is the large case: the decoder centres the visible part, the spot locator
the whole fitted ellipse (19 px apart for the lamp 0.5 m ahead, whose 67 x 107 px box
no other lamp comes near).
"""
from dataclasses import dataclass
import math

import numpy as np

from vlc_common.core.observation import LampObservation

#: Decoder record fields, in order of preference, for the left-image position.
LAMP_POSITION_FIELDS = (('left_u', 'left_v'), ('u_left', 'v_left'))
#: vlc_decoder ``state`` values: 2 confirmed (CRC-valid UID of a map lamp), 3 anomaly
#: (CRC-valid UID absent from the map). Both carry their UID; the localizer reports an
#: anomaly's UID as unknown and never uses it.
STATE_CONFIRMED, STATE_ANOMALY = 2, 3
#: Largest |stamp_offset_s| of a spot pair taken as its exposure mid-time, s (a frame's
#: readout lasts 22 ms); a larger one is treated as unknown.
MAX_STAMP_OFFSET_S = 1.0


@dataclass
class JoinConfig:
    """Attributes
    ----------
    match_radius_px : float
        Largest left-image distance between a lamp record and its spot pair, px.
    rectify_left : callable or None
        Raw → rectified pixels (N, 2) → (N, 2) of the left camera when its images are
        raw (the decoder's positions are raw pixels, the spot pairs' rectified ones);
        None when the images are rectified.
    timeout_s : float
        Longest wait (receive clock) for the other half of a frame, s.
    max_pending : int
        Frames kept waiting at most; older ones are released or dropped first.
    """

    match_radius_px: float = 12.0
    timeout_s: float = 0.15
    max_pending: int = 10
    rectify_left: object = None


@dataclass
class JoinStats:
    joined: int = 0
    spots_without_lamps: int = 0
    lamps_without_spots: int = 0
    unmatched_lamp_records: int = 0


def _field(rec, names, default=math.nan):
    for name in names:
        if rec.dtype.names and name in rec.dtype.names:
            return np.asarray(rec[name], dtype=float)
    return np.full(rec.shape, default, dtype=float)


def observations_from_spots(stamp_ns, spots):
    """``spots/pairs`` records → list of :class:`LampObservation` without UIDs."""
    if spots.dtype.names is None or spots.size == 0:
        return []
    su = _field(spots, ('sigma_u_left',), 0.1)
    svl = _field(spots, ('sigma_v_left',), 0.1)
    svr = _field(spots, ('sigma_v_right',), 0.1)
    sd = _field(spots, ('sigma_disparity',))
    offset = _field(spots, ('stamp_offset_s',))
    # an exposure mid-time more than a second from its image stamp is not one: unknown
    offset = np.where(np.abs(offset) <= MAX_STAMP_OFFSET_S, offset, math.nan)
    out = []
    for i in range(spots.size):
        out.append(LampObservation(
            stamp_ns=int(stamp_ns), uid=None,
            uv_left=(float(spots['u_left'][i]), float(spots['v_left'][i])),
            uv_right=(float(spots['u_right'][i]), float(spots['v_right'][i])),
            sigma_u_px=float(su[i]),
            # triangulate() uses the mean row of both centres: var = (σl² + σr²)/4.
            sigma_v_px=float(math.sqrt(0.5 * (svl[i] ** 2 + svr[i] ** 2))),
            sigma_disparity_px=float(sd[i]), exposure_mid_offset_s=float(offset[i])))
    return out


def lamp_uids(lamps):
    """(uid or None per record, left-image positions (N, 2)) of ``vlc/lamps`` records.

    The UID of a record in ``state`` confirmed or anomaly is passed on; searching and
    partial records (state 0, 1) give None (an unconfirmed lamp). Records without a
    ``state`` field count as confirmed when their ``uid`` is non-zero.
    """
    if lamps.dtype.names is None or lamps.size == 0:
        return [], np.zeros((0, 2))
    names = lamps.dtype.names
    uid = np.asarray(lamps['uid'], dtype=np.int64) if 'uid' in names else np.zeros(lamps.size, int)
    if 'state' in names:
        state = np.asarray(lamps['state'])
        confirmed = (state == STATE_CONFIRMED) | (state == STATE_ANOMALY)
    else:
        confirmed = uid != 0
    pos = np.full((lamps.size, 2), np.nan)
    for fu, fv in LAMP_POSITION_FIELDS:
        if fu in names and fv in names:
            pos = np.stack([np.asarray(lamps[fu], float), np.asarray(lamps[fv], float)], axis=1)
            break
    uids = [int(u) if c else None for u, c in zip(uid, confirmed)]
    return uids, pos


def lamp_box_half_sides(lamps):
    """Half the larger side of each record's left-image spot box (px; 0 without a box)."""
    names = lamps.dtype.names or ()
    box = ('left_u_min', 'left_u_max', 'left_v_min', 'left_v_max')
    if lamps.size == 0 or not all(n in names for n in box):
        return np.zeros(lamps.size)
    width = np.asarray(lamps['left_u_max'], float) - np.asarray(lamps['left_u_min'], float)
    height = np.asarray(lamps['left_v_max'], float) - np.asarray(lamps['left_v_min'], float)
    half = 0.5 * np.maximum(width, height)
    return np.where(np.isfinite(half) & (half > 0.0), half, 0.0)


def join_frame(stamp_ns, spots, lamps, config=None):
    """Observations of one frame: spot pairs with the UIDs of the matching lamp records.

    Returns
    -------
    observations : list of LampObservation
    unmatched : int
        Decoder records that matched no spot pair.
    """
    config = config or JoinConfig()
    obs = observations_from_spots(stamp_ns, spots)
    if lamps is None or not obs:
        return obs, 0 if lamps is None else int(lamps.size)
    uids, pos = lamp_uids(lamps)
    if config.rectify_left is not None and len(pos):
        pos = np.asarray(config.rectify_left(pos), float).reshape(-1, 2)
    radius = np.maximum(config.match_radius_px, lamp_box_half_sides(lamps))
    spot_uv = np.array([o.uv_left for o in obs])
    unmatched = 0
    taken = set()
    for k, uid in enumerate(uids):
        d = np.linalg.norm(spot_uv - pos[k], axis=1)
        j = int(np.nanargmin(d)) if np.any(np.isfinite(d)) else -1
        if j < 0 or not d[j] <= radius[k] or j in taken:
            unmatched += 1
            continue
        taken.add(j)
        obs[j].uid = uid
    return obs, unmatched


class FrameJoiner:
    """Buffers both record streams by stamp; see the module docstring.

    ``now_s`` arguments are the receive clock (any monotonic seconds), used only for
    the timeout.
    """

    def __init__(self, config=None):
        self.config = config or JoinConfig()
        self.stats = JoinStats()
        self._spots = {}   # stamp_ns → (records, received_s)
        self._lamps = {}
        self._newest_lamps_ns = None
        self._newest_spots_ns = None

    def clear(self):
        self._spots.clear()
        self._lamps.clear()
        self._newest_lamps_ns = self._newest_spots_ns = None

    def add_spots(self, stamp_ns, records, now_s):
        """Add one ``spots/pairs`` message; returns frames ready [(stamp_ns, observations)]."""
        stamp_ns = int(stamp_ns)
        self._newest_spots_ns = max(stamp_ns, self._newest_spots_ns or stamp_ns)
        if stamp_ns in self._lamps:
            lamps, _ = self._lamps.pop(stamp_ns)
            return self._release(now_s) + [self._join(stamp_ns, records, lamps)]
        self._spots[stamp_ns] = (records, now_s)
        return self._release(now_s)

    def add_lamps(self, stamp_ns, records, now_s):
        """Add one ``vlc/lamps`` message; returns frames ready [(stamp_ns, observations)]."""
        stamp_ns = int(stamp_ns)
        self._newest_lamps_ns = max(stamp_ns, self._newest_lamps_ns or stamp_ns)
        if stamp_ns in self._spots:
            spots, _ = self._spots.pop(stamp_ns)
            return self._release(now_s) + [self._join(stamp_ns, spots, records)]
        self._lamps[stamp_ns] = (records, now_s)
        return self._release(now_s)

    def flush(self, now_s):
        """Frames released by the timeout alone (call periodically)."""
        return self._release(now_s)

    def _join(self, stamp_ns, spots, lamps):
        obs, unmatched = join_frame(stamp_ns, spots, lamps, self.config)
        self.stats.joined += 1
        self.stats.unmatched_lamp_records += unmatched
        return stamp_ns, obs

    def _release(self, now_s):
        cfg = self.config
        ready = []
        for stamp in sorted(self._spots):
            records, received = self._spots[stamp]
            decoder_passed = self._newest_lamps_ns is not None and self._newest_lamps_ns > stamp
            too_many = len(self._spots) > cfg.max_pending
            if decoder_passed or now_s - received > cfg.timeout_s or too_many:
                del self._spots[stamp]
                self.stats.spots_without_lamps += 1
                ready.append((stamp, observations_from_spots(stamp, records)))
        for stamp in sorted(self._lamps):
            _, received = self._lamps[stamp]
            spots_passed = self._newest_spots_ns is not None and self._newest_spots_ns > stamp
            too_many = len(self._lamps) > cfg.max_pending
            if spots_passed or now_s - received > cfg.timeout_s or too_many:
                del self._lamps[stamp]
                self.stats.lamps_without_spots += 1
        return ready
