"""Beacon-sequence plausibility: is a lamp's ID where the distance travelled says it is.

A train passes the coded beacons (lamps) of its line in map order. Each sighting of a
beacon, with the train's odometer reading (a distance along the track from any
independent source — inertial dead reckoning, wheel odometry, the along-track filter's
own prediction) and, optionally, the measured distance from the train to the beacon,
predicts where the beacon must be on the map: at the last accepted beacon's map
chainage plus the distance travelled since. A beacon is plausible when

1. its ID is in the lamp map (else ``UNKNOWN_UID``);
2. the map distance from the last accepted beacon equals the distance travelled
   within the tolerance ``max(gate_sigma·σ, tolerance_floor_m)``.

A beacon failing 2 is flagged as forged (broadcasting another lamp's valid ID) or
misplaced (moved from its surveyed place), with the ID sequence named in the verdict:
``OUT_OF_SEQUENCE`` when its ID belongs at or behind the last accepted beacon in the
running direction (the sequence of IDs along the line must be monotonic: a repeat of a
passed beacon, an ID from behind), ``DISTANCE_MISMATCH`` when the ID is ahead but not
as far as travelled (an ID that jumps lamps, or a lamp off its place). Skipped (dark,
unread) lamps are allowed: only the distance counts. A passing beacon that is still
where the map has it is accepted; a new one ahead (``CONSISTENT``) becomes the anchor,
a passed one seen again (``REPEAT``: the anchor while in view, or a lamp behind seen
by a receiver that looks backwards) does not, except that the anchor's own newest
sighting replaces it (the odometer is then only trusted from there to the next beacon).

σ² = the odometer's variance since the last accepted beacon (given by the caller) +
(``odometer_drift_rel`` × distance travelled)² + the two beacon-range variances + the
survey tolerance. The first beacon has nothing to be checked against: it is accepted
as ``FIRST``. If the anchor was itself wrong (a forged first beacon), every genuine
beacon after it would be flagged; so when ``reanchor_count`` successive flagged
beacons agree with each other (their own offsets within the tolerance), the checker
re-anchors on them and reports the old anchor as the suspect (``REANCHORED``).

Pure Python/numpy, no ROS; reusable by any localizer's integrity checks:

    checker = BeaconSequenceChecker(lamp_map)
    result = checker.check(uid, odometer_m, odometer_var_m2, range_along_m)
    if result.flagged: ...   # forged or misplaced: do not use its position
"""
from dataclasses import dataclass
import enum
import math


class Verdict(enum.Enum):
    FIRST = 'first'                       # accepted, nothing to check against yet
    CONSISTENT = 'consistent'             # accepted (a new beacon in sequence)
    REPEAT = 'repeat'                     # the anchor beacon again, still in place
    REANCHORED = 'reanchored'             # accepted; the previous anchor was the outlier
    UNKNOWN_UID = 'unknown_uid'           # not in the lamp map
    OUT_OF_SEQUENCE = 'out_of_sequence'   # behind the anchor in the running direction
    DISTANCE_MISMATCH = 'distance_mismatch'  # in sequence, but not where travel puts it


ACCEPTED = (Verdict.FIRST, Verdict.CONSISTENT, Verdict.REPEAT, Verdict.REANCHORED)


@dataclass
class BeaconSequenceConfig:
    """Tolerances of the check (metres).

    Attributes
    ----------
    gate_sigma : float
        Offsets beyond this many σ are flagged.
    tolerance_floor_m : float
        Smallest tolerance, m (lamp survey, spot and range errors not in σ).
    odometer_drift_rel : float
        Relative error of the distance travelled (scale factor), added to σ.
    survey_sigma_m : float
        1σ of a lamp's surveyed chainage, m.
    reanchor_count : int
        Successive flagged beacons that agree with each other and re-anchor the check.
    """

    gate_sigma: float = 4.0
    tolerance_floor_m: float = 1.0
    odometer_drift_rel: float = 0.02
    survey_sigma_m: float = 0.05
    reanchor_count: int = 2

    def __post_init__(self):
        if not (self.gate_sigma > 0.0 and self.tolerance_floor_m >= 0.0
                and self.odometer_drift_rel >= 0.0 and self.survey_sigma_m >= 0.0):
            raise ValueError('beacon sequence tolerances must be >= 0 (gate_sigma > 0)')
        if self.reanchor_count < 1:
            raise ValueError('reanchor_count must be >= 1')


@dataclass
class BeaconCheck:
    """Result of one sighting.

    Attributes
    ----------
    verdict : Verdict
    uid : int
    map_chainage_m : float
        The beacon's chainage in the lamp map (NaN for an unknown UID), m.
    expected_chainage_m : float
        Where the distance travelled puts the beacon seen (NaN without an anchor), m.
    offset_m : float
        ``map_chainage_m − expected_chainage_m``, m.
    tolerance_m : float
        The gate applied, m.
    index_step : int
        Map lamps from the anchor to this beacon in the running direction (1 = the next
        lamp; 0 the anchor itself; negative = behind).
    reason : str
        Human-readable explanation (diagnostics).
    suspect_uid : int or None
        REANCHORED: the former anchor now suspected of being forged or misplaced.
    """

    verdict: Verdict
    uid: int
    map_chainage_m: float = math.nan
    expected_chainage_m: float = math.nan
    offset_m: float = math.nan
    tolerance_m: float = math.nan
    index_step: int = 0
    reason: str = ''
    suspect_uid: object = None

    @property
    def accepted(self):
        return self.verdict in ACCEPTED

    @property
    def flagged(self):
        """Forged or misplaced (or unknown): the beacon's map position must not be used."""
        return not self.accepted


@dataclass
class _Anchor:
    uid: int
    index: int
    chainage_m: float
    odometer_at_beacon_m: float   # odometer reading + range: the beacon in odometer terms
    range_var_m2: float
    odometer_var_m2: float


class BeaconSequenceChecker:
    """See the module docstring.

    Parameters
    ----------
    lamp_map : vlc_common.core.lamp_map.LampMap
        Lamps sorted by chainage (the map's own order defines the sequence).
    config : BeaconSequenceConfig
    direction : int
        +1 when the train runs toward increasing chainage, −1 the other way: the
        chainage travelled is ``direction`` × the odometer's change.
    """

    def __init__(self, lamp_map, config=None, direction=1):
        if direction not in (1, -1):
            raise ValueError('direction must be +1 or -1')
        self.lamp_map = lamp_map
        self.config = config or BeaconSequenceConfig()
        self.direction = direction
        self._index = {lamp.uid: i for i, lamp in enumerate(lamp_map.lamps)}
        self._anchor = None
        self._pending = []       # flagged sightings since the anchor: (_Anchor, offset)

    @property
    def anchor_uid(self):
        return None if self._anchor is None else self._anchor.uid

    def reset(self):
        """Forget the anchor (a re-initialised localizer)."""
        self._anchor = None
        self._pending.clear()

    def check(self, uid, odometer_m, odometer_var_m2=0.0, range_along_m=0.0,
              range_var_m2=0.0):
        """Check one sighting of beacon ``uid``; accepted sightings move the anchor.

        Parameters
        ----------
        uid : int
            The ID read (CRC-valid).
        odometer_m : float
            Distance travelled at the sighting, m (any origin; it grows in the running
            direction, whichever way the chainage goes).
        odometer_var_m2 : float
            Variance of the odometer's change since the anchor's sighting, m².
        range_along_m : float
            Along-track distance from the train to the beacon (ahead positive), m.
        range_var_m2 : float
            Its variance, m².

        Returns
        -------
        BeaconCheck
        """
        uid = int(uid)
        cfg = self.config
        lamp = self.lamp_map.by_uid(uid)
        if lamp is None:
            return BeaconCheck(Verdict.UNKNOWN_UID, uid, reason=f'UID {uid:#06x} is not in '
                               'the lamp map')
        here = _Anchor(uid, self._index[uid], float(lamp.position_m[0]),
                       float(odometer_m) + float(range_along_m),
                       float(range_var_m2), float(odometer_var_m2))
        if self._anchor is None:
            self._anchor = here
            return BeaconCheck(Verdict.FIRST, uid, map_chainage_m=here.chainage_m,
                               reason='first beacon: accepted without a check')
        result = self._compare(self._anchor, here)
        if result.verdict in (Verdict.CONSISTENT, Verdict.REPEAT):
            # A new beacon ahead becomes the anchor; so does the anchor's own newest
            # sighting (the shortest odometer span to the next beacon).
            if result.verdict == Verdict.CONSISTENT or uid == self._anchor.uid:
                self._anchor = here
            self._pending.clear()
            return result
        # Flagged. If the last reanchor_count flagged beacons agree among themselves,
        # the anchor is the outlier.
        self._pending = [p for p in self._pending if p.uid != uid] + [here]
        if len(self._pending) >= cfg.reanchor_count and self._pending_agree():
            suspect = self._anchor.uid
            self._anchor = here
            self._pending.clear()
            result.verdict = Verdict.REANCHORED
            result.suspect_uid = suspect
            result.reason = (f'{cfg.reanchor_count} beacons agree with each other and not '
                             f'with beacon {suspect:#06x}: re-anchored, {suspect:#06x} '
                             'suspected forged or misplaced')
        return result

    def _tolerance(self, a, b, travel_m):
        cfg = self.config
        var = (b.odometer_var_m2 + (cfg.odometer_drift_rel * travel_m) ** 2
               + a.range_var_m2 + b.range_var_m2 + 2.0 * cfg.survey_sigma_m ** 2)
        return max(cfg.gate_sigma * math.sqrt(max(var, 0.0)), cfg.tolerance_floor_m)

    def _compare(self, a, b):
        """Check sighting ``b`` against anchor ``a``."""
        # Odometer readings grow in the running direction; beacons lie range_along ahead.
        travel = b.odometer_at_beacon_m - a.odometer_at_beacon_m
        expected = a.chainage_m + self.direction * travel
        offset = b.chainage_m - expected
        tol = self._tolerance(a, b, abs(travel))
        # LampMap keeps its lamps sorted by chainage: the map index is the ID sequence.
        step = self.direction * (b.index - a.index)
        result = BeaconCheck(Verdict.CONSISTENT, b.uid, map_chainage_m=b.chainage_m,
                             expected_chainage_m=expected, offset_m=offset, tolerance_m=tol,
                             index_step=step)
        if abs(offset) <= tol:
            if step > 0:
                result.reason = f'{step} lamp(s) after {a.uid:#06x}, offset {offset:+.2f} m'
            else:
                result.verdict = Verdict.REPEAT
                result.reason = 'a beacon already passed, still where the map has it'
        elif step <= 0:
            result.verdict = Verdict.OUT_OF_SEQUENCE
            result.reason = (f'beacon {b.uid:#06x} belongs {-step} lamp(s) behind the last '
                             f'beacon {a.uid:#06x} but is seen {offset:+.1f} m off its place '
                             f'(tolerance {tol:.1f} m): ID out of sequence, forged or '
                             'misplaced')
        else:
            result.verdict = Verdict.DISTANCE_MISMATCH
            result.reason = (f'beacon {b.uid:#06x} is {b.chainage_m - a.chainage_m:+.1f} m '
                             f'from {a.uid:#06x} on the map but {self.direction * travel:+.1f}'
                             f' m of chainage were travelled (tolerance {tol:.1f} m): forged '
                             'or misplaced')
        return result

    def _pending_agree(self):
        recent = self._pending[-self.config.reanchor_count:]
        first = recent[0]
        for b in recent[1:]:
            check = self._compare(first, b)
            if check.verdict != Verdict.CONSISTENT:
                return False
        return True
