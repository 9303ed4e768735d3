"""Companion method 3: INS with zero-velocity update and motion constraint + stereo
ranging to coded beacons, with beacon-ID plausibility (metro self-positioning system).

* **INS**: the along-track filter (:mod:`.along_track`) integrates the gravity-free
  along-track acceleration; the motion constraint (the train moves along its track,
  lateral and vertical velocity zero) makes the navigation state one-dimensional;
  zero-velocity updates at standstill (:mod:`.imu_driven`).
* **Stereo beacon ranging** (:mod:`.ranging`): every lamp spot pair gives the range to
  its lamp and so ``q = x_lamp − s``, the lamp's chainage ahead of ``base_link``.
  A lamp is followed from frame to frame (a track: ``q`` continuous, lamps 10 m apart).
  - Tracks of a beacon whose ID is confirmed and **plausible** give position updates
    ``s = x_lamp − q``.
  - All other tracks — a lamp not identified yet, or a beacon flagged as forged or
    misplaced — still are fixed lamps: the change of ``q`` between two frames
    ``velocity_baseline_s`` apart is the distance travelled, a **velocity** update
    ``v(t_mid) = −Δq/Δt`` (exact for constant acceleration). Each range is used once,
    either as a position or within a velocity.
* **Beacon plausibility** (:mod:`.beacon_sequence`): each confirmed sighting is checked
  against the last accepted beacon with the distance travelled, integrated from the
  filter's speed (an odometer that position updates do not shift). A flagged beacon's
  position is never used; it is reported (``flags``).

No ROS here.
"""
from bisect import bisect_left
from dataclasses import dataclass, field
import math

import numpy as np

from companion_localizers.core.along_track import H_CHAINAGE, H_SPEED
from companion_localizers.core.beacon_sequence import BeaconSequenceChecker, BeaconSequenceConfig
from companion_localizers.core.imu_driven import NS_PER_S, ImuDrivenConfig, ImuDrivenLocalizer
from companion_localizers.core.ranging import RangingConfig, range_to_lamp
from train_localizer.core.fix import RigGeometry, measurement_time_ns


@dataclass
class InsBeaconConfig(ImuDrivenConfig):
    """:class:`ImuDrivenConfig` plus ranging, tracking and plausibility parameters.

    Attributes
    ----------
    ranging : RangingConfig
    geometry : train_localizer.core.fix.RigGeometry
    sequence : BeaconSequenceConfig
    survey_sigma_m : float
        1σ of a lamp's surveyed chainage, m.
    velocity_baseline_s : float
        Shortest time between the two ranges of a velocity update, s.
    track_gap_s : float
        A lamp track unseen this long is closed, s.
    track_gate_m : float
        Largest jump of ``q`` between frames of one track beyond the predicted motion, m.
    max_speed_mps : float
        Motion allowed between frames while the speed is unknown, m/s.
    gate_chi2 : float
        Position updates with a larger normalised innovation² are skipped (a wrong
        stereo match); not applied while the chainage is unknown.
    """

    ranging: RangingConfig = field(default_factory=RangingConfig)
    geometry: RigGeometry = field(default_factory=RigGeometry)
    sequence: BeaconSequenceConfig = field(default_factory=BeaconSequenceConfig)
    survey_sigma_m: float = 0.005
    velocity_baseline_s: float = 0.1
    track_gap_s: float = 0.5
    track_gate_m: float = 0.5
    max_speed_mps: float = 60.0
    gate_chi2: float = 25.0

    def __post_init__(self):
        super().__post_init__()
        if not (self.velocity_baseline_s > 0.0 and self.track_gap_s > 0.0
                and self.track_gate_m > 0.0 and self.max_speed_mps > 0.0
                and self.gate_chi2 > 0.0):
            raise ValueError('velocity_baseline_s, track_gap_s, track_gate_m, max_speed_mps '
                             'and gate_chi2 must be > 0')


@dataclass
class _Track:
    last_t_ns: int
    last_q: float
    ref_t_ns: int
    ref_q: float
    ref_var: float
    uid: object = None
    plausible: bool = False


@dataclass
class BeaconFlag:
    """A beacon sighting flagged by the plausibility check."""

    t_ns: int
    uid: int
    verdict: str
    reason: str
    offset_m: float


@dataclass
class InsCounters:
    beacons_accepted: int = 0
    beacons_flagged: int = 0
    position_updates: int = 0
    velocity_updates: int = 0
    gate_rejections: int = 0
    unrangeable: int = 0


class InsBeacon(ImuDrivenLocalizer):
    """See the module docstring.

    Parameters
    ----------
    config : InsBeaconConfig
    lamp_map : vlc_common.core.lamp_map.LampMap
    """

    def __init__(self, config, lamp_map):
        super().__init__(config)
        self.lamp_map = lamp_map
        self.checker = BeaconSequenceChecker(lamp_map, config.sequence)
        self.ins_counters = InsCounters()
        self.flags = []                  # BeaconFlag, in order
        self._tracks = []
        # A lamp not identified yet is assumed on the wall line of the map's lamps.
        pos = lamp_map.positions if len(lamp_map) else np.array([[0.0, 2.5, 1.4]])
        self._wall_yz = tuple(np.median(pos[:, 1:], axis=0))
        # (t_ns, distance travelled m, speed m/s, ∫σ_v dt m, σ_v m/s) per IMU step
        self._odo = []
        self._odo_t = []
        self._anchor_bound_m = 0.0       # odometer bound at the anchor's last sighting

    # ------------------------------------------------------------------ odometer
    def add_imu(self, sample):
        out = super().add_imu(sample)
        state = self.filter.state
        if state is not None and self.filter.newest_ns == sample.stamp_ns:
            v, sv = float(state.x[1]), math.sqrt(max(float(state.P[1, 1]), 0.0))
            if self._odo:
                t0, d0, v0, c0, sv0 = self._odo[-1]
                dt = (sample.stamp_ns - t0) / NS_PER_S
                row = (sample.stamp_ns, d0 + 0.5 * (v0 + v) * dt, v,
                       c0 + 0.5 * (sv0 + sv) * dt, sv)
            else:
                row = (sample.stamp_ns, 0.0, v, 0.0, sv)
            self._odo.append(row)
            self._odo_t.append(sample.stamp_ns)
            horizon = sample.stamp_ns - int(self.config.filter.history_s * NS_PER_S)
            if len(self._odo_t) > 2 and self._odo_t[len(self._odo_t) // 2] < horizon:
                # Trim in halves: amortised O(1) per sample.
                cut = bisect_left(self._odo_t, horizon) - 1
                del self._odo[:cut], self._odo_t[:cut]
        return out

    def odometer_at(self, t_ns):
        """(distance travelled m, its error bound σ m) at ``t_ns``, or None without IMU.

        The distance is the speed integrated as it was known at each IMU step (later
        corrections from delayed measurements do not shift past readings, so readings
        taken at different times stay comparable); the bound integrates the speed's
        1σ at each step (errors taken as fully correlated: a conservative bound).
        Readings are kept for the filter's ``history_s`` and extrapolated beyond.
        """
        if not self._odo:
            return None
        k = bisect_left(self._odo_t, t_ns)
        if k in (0, len(self._odo)):
            t, d, v, c, sv = self._odo[0 if k == 0 else -1]
            dt = (t_ns - t) / NS_PER_S
            return d + v * dt, c + sv * abs(dt)
        (ta, da, _, ca, _), (tb, db, _, cb, _) = self._odo[k - 1], self._odo[k]
        w = (t_ns - ta) / (tb - ta)
        return da + (db - da) * w, ca + (cb - ca) * w

    # ------------------------------------------------------------------ frames
    def process_frame(self, stamp_ns, observations):
        """One frame's LampObservations. Returns the BeaconFlags raised by it."""
        cfg = self.config
        self.counters.frames += 1
        new_flags = []
        good = [o for o in observations if o.is_finite()]
        self.counters.bad_observations += len(observations) - len(good)
        ranges = []
        for obs in good:
            lamp = self.lamp_map.by_uid(obs.uid) if obs.uid is not None else None
            t_ns = measurement_time_ns(obs, cfg.geometry)
            R, cov = self.rotation_at(t_ns)
            yz = lamp.position_m[1:] if lamp is not None else self._wall_yz
            rng = range_to_lamp(obs, cfg.geometry, R, yz, cfg.ranging, cov)
            if rng is None:
                self.ins_counters.unrangeable += 1
                continue
            ranges.append((obs, lamp, rng))
        for obs, lamp, rng in ranges:
            track = self._associate(obs, rng)
            if lamp is not None:
                flag = self._beacon(obs, lamp, rng, track)
                if flag is not None:
                    new_flags.append(flag)
            elif track.uid is not None:
                # A frame without the decoder's record: the track still knows its beacon.
                lamp = self.lamp_map.by_uid(track.uid)
                R, cov = self.rotation_at(rng.t_ns)
                rng = range_to_lamp(obs, cfg.geometry, R, lamp.position_m[1:], cfg.ranging,
                                    cov) or rng
            if track.plausible and lamp is not None:
                self._position_update(lamp, rng, track)
            else:
                self._velocity_update(rng, track)
        horizon = stamp_ns - int(cfg.track_gap_s * NS_PER_S)
        self._tracks = [t for t in self._tracks if t.last_t_ns >= horizon]
        return new_flags

    def _associate(self, obs, rng):
        """The track of this lamp (continuity of q), or a new one."""
        cfg = self.config
        state = self.filter.state_at(rng.t_ns)
        speed_known = state is not None and state.P[1, 1] < 1.0
        best, best_err = None, math.inf
        for track in self._tracks:
            if track.uid is not None and obs.uid is not None and track.uid != obs.uid:
                continue
            dt = (rng.t_ns - track.last_t_ns) / NS_PER_S
            if dt <= 0.0:
                continue
            if speed_known:
                err = abs(rng.ahead_m - (track.last_q - state.x[1] * dt))
                gate = cfg.track_gate_m + 3.0 * math.sqrt(state.P[1, 1]) * dt
            else:
                err = abs(rng.ahead_m - track.last_q)
                gate = cfg.track_gate_m + cfg.max_speed_mps * dt
            if err <= gate and err < best_err:
                best, best_err = track, err
        if best is None:
            best = _Track(last_t_ns=rng.t_ns, last_q=rng.ahead_m, ref_t_ns=rng.t_ns,
                          ref_q=rng.ahead_m, ref_var=rng.ahead_var_m2)
            self._tracks.append(best)
            return best
        best.last_t_ns, best.last_q = rng.t_ns, rng.ahead_m
        return best

    def _beacon(self, obs, lamp, rng, track):
        """Plausibility check of a confirmed beacon sighting; returns a BeaconFlag or None."""
        odo = self.odometer_at(rng.t_ns)
        if odo is None:
            return None
        distance, bound = odo
        sigma = max(bound - self._anchor_bound_m, 0.0)
        check = self.checker.check(lamp.uid, distance, sigma * sigma, rng.ahead_m,
                                   rng.ahead_var_m2)
        if check.accepted and self.checker.anchor_uid == lamp.uid:
            self._anchor_bound_m = bound
        track.uid = lamp.uid
        if check.accepted:
            if not track.plausible:
                self.ins_counters.beacons_accepted += 1
            track.plausible = True
            return None
        track.plausible = False
        self.ins_counters.beacons_flagged += 1
        flag = BeaconFlag(t_ns=int(rng.t_ns), uid=int(lamp.uid), verdict=check.verdict.value,
                          reason=check.reason, offset_m=float(check.offset_m))
        self.flags.append(flag)
        # Its ranges restart as a speed reference from this frame.
        track.ref_t_ns, track.ref_q, track.ref_var = rng.t_ns, rng.ahead_m, rng.ahead_var_m2
        return flag

    def _position_update(self, lamp, rng, track):
        cfg = self.config
        z = float(lamp.position_m[0]) - rng.ahead_m
        r = rng.ahead_var_m2 + cfg.survey_sigma_m ** 2
        innov = self.filter.innovation_at(rng.t_ns, H_CHAINAGE, z, r)
        if innov is not None and innov[1] < 1.0 and innov[0] ** 2 / innov[1] > cfg.gate_chi2:
            self.ins_counters.gate_rejections += 1
            return
        if self.filter.add_measurement(rng.t_ns, H_CHAINAGE, z, r):
            self.ins_counters.position_updates += 1
        else:
            self.counters.measurements_dropped_old += 1
        track.ref_t_ns, track.ref_q, track.ref_var = rng.t_ns, rng.ahead_m, rng.ahead_var_m2

    def _velocity_update(self, rng, track):
        cfg = self.config
        dt = (rng.t_ns - track.ref_t_ns) / NS_PER_S
        if dt < cfg.velocity_baseline_s:
            return
        z = -(rng.ahead_m - track.ref_q) / dt
        r = (rng.ahead_var_m2 + track.ref_var) / (dt * dt)
        t_mid = (rng.t_ns + track.ref_t_ns) // 2
        if self.filter.add_measurement(t_mid, H_SPEED, z, r):
            self.ins_counters.velocity_updates += 1
        else:
            self.counters.measurements_dropped_old += 1
        track.ref_t_ns, track.ref_q, track.ref_var = rng.t_ns, rng.ahead_m, rng.ahead_var_m2
