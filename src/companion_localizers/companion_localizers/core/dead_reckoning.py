"""Companion method 2: landmark + IMU dead reckoning (the emergency-positioning scheme).

The scheme of the emergency-positioning patent: the IMU's along-track acceleration,
smoothed by a sliding-window average of the last ``window_samples`` (20) samples, is
integrated to speed and position; when the train stands still the speed is corrected
to zero (zero-velocity correction: the IMU shows a standing platform, or the lamp
spots stand still in the images); at each landmark — a lamp whose UID the decoder has
confirmed, ranged by the stereo camera (:mod:`.ranging`) — the integration is reset to
the landmark's position.

The reset is a Kalman update of the along-track filter (:mod:`.along_track`) with the
landmark's variance: the position collapses to the landmark's, and the same update
corrects the speed and the accelerometer bias through the filter's correlations. A
reset of the position alone would leave the ADIS16488's turn-on bias (16 mg, 1σ)
integrating into the speed at 0.16 m/s per second — kilometres per hour of speed error
within a minute. One landmark per lamp (the first ranged sighting of its confirmed UID
within ``landmark_max_ahead_m``; every ``landmark_stride``-th lamp of the map, to
emulate sparser markers); between landmarks the position is the IMU's alone. The
landmark is authoritative, as in the patent: no plausibility check (method 3 has one).

The 20-sample window is a causal moving average: it removes sample noise and
vibration above ~20 Hz (at 400 Hz) and delays the acceleration by 9.5 samples
(24 ms): a 1 m/s² braking onset leaves a 2.4 cm/s speed lag until the braking ends.

No ROS here.
"""
from collections import deque
from dataclasses import dataclass, field
import math

import numpy as np

from companion_localizers.core.along_track import H_CHAINAGE
from companion_localizers.core.imu_driven import NS_PER_S, ImuDrivenConfig, ImuDrivenLocalizer
from companion_localizers.core.ranging import RangingConfig, range_to_lamp
from train_localizer.core.fix import RigGeometry, measurement_time_ns


@dataclass
class ImageStillConfig:
    """Attributes
    ----------
    enabled : bool
        Use still images as standstill evidence.
    window_s : float
        Every spot must stay put over this long, s.
    max_motion_px : float
        Largest spot displacement over the window, px.
    min_frames : int
        Frames within the window needed to judge.
    max_age_s : float
        The judgement applies at most this long after the newest frame's stamp, s.
    """

    enabled: bool = True
    window_s: float = 0.3
    max_motion_px: float = 0.5
    min_frames: int = 5
    max_age_s: float = 0.2


class ImageStillness:
    """The train stands when every lamp spot stays within ``max_motion_px`` over the
    window (the standing platform does not vibrate; at walking pace a lamp 5 m ahead
    moves several pixels in 0.3 s).
    """

    def __init__(self, config=None):
        self.config = config or ImageStillConfig()
        self._frames = deque()
        self.still = False
        self.newest_ns = None

    def push(self, stamp_ns, uv_left):
        """One frame's left spot centres (K, 2); returns the current judgement."""
        cfg = self.config
        uv = np.asarray(uv_left, dtype=float).reshape(-1, 2)
        uv = uv[np.all(np.isfinite(uv), axis=1)]
        self._frames.append((int(stamp_ns), uv))
        self.newest_ns = int(stamp_ns)
        horizon = int(stamp_ns) - int(cfg.window_s * NS_PER_S)
        while len(self._frames) > 1 and self._frames[1][0] <= horizon:
            self._frames.popleft()
        self.still = self._judge()
        return self.still

    def _judge(self):
        cfg = self.config
        frames = list(self._frames)
        span = frames[-1][0] - frames[0][0]
        if len(frames) < cfg.min_frames or span < 0.8 * cfg.window_s * NS_PER_S:
            return False
        newest = frames[-1][1]
        if newest.shape[0] == 0:
            return False
        for _, uv in frames[:-1]:
            if uv.shape[0] != newest.shape[0]:
                return False
            d = np.linalg.norm(newest[:, None, :] - uv[None, :, :], axis=2)
            if not np.all(d.min(axis=1) <= cfg.max_motion_px):
                return False
        return True

    def still_at(self, t_ns):
        cfg = self.config
        return bool(cfg.enabled and self.still and self.newest_ns is not None
                    and 0 <= t_ns - self.newest_ns <= cfg.max_age_s * NS_PER_S)


@dataclass
class DeadReckoningConfig(ImuDrivenConfig):
    """:class:`ImuDrivenConfig` plus the scheme's own parameters.

    Attributes
    ----------
    window_samples : int
        Sliding-window average of the along-track acceleration, samples (patent: 20).
    image_still : ImageStillConfig
    landmark_max_ahead_m : float
        A lamp becomes a landmark at its first ranged sighting with a confirmed UID
        closer than this along the track (range error grows with the range²), m.
    landmark_stride : int
        Only lamps whose map index is a multiple of this are landmarks (1 = every lamp).
    survey_sigma_m : float
        1σ of a lamp's surveyed chainage, m.
    ranging : RangingConfig
    geometry : train_localizer.core.fix.RigGeometry
    """

    window_samples: int = 20
    image_still: ImageStillConfig = field(default_factory=ImageStillConfig)
    landmark_max_ahead_m: float = 10.0
    landmark_stride: int = 1
    survey_sigma_m: float = 0.005
    ranging: RangingConfig = field(default_factory=RangingConfig)
    geometry: RigGeometry = field(default_factory=RigGeometry)

    def __post_init__(self):
        super().__post_init__()
        if self.window_samples < 1 or self.landmark_stride < 1:
            raise ValueError('window_samples and landmark_stride must be >= 1')
        if not self.landmark_max_ahead_m > 0.0:
            raise ValueError('landmark_max_ahead_m must be > 0')


@dataclass
class LandmarkEvent:
    """A landmark reset: UID, measurement instant (ns), chainage (m), its 1σ (m), and
    the dead-reckoned chainage just before the reset (m).
    """

    uid: int
    t_ns: int
    chainage_m: float
    sigma_m: float
    before_m: float


class DeadReckoning(ImuDrivenLocalizer):
    """See the module docstring.

    Parameters
    ----------
    config : DeadReckoningConfig
    lamp_map : vlc_common.core.lamp_map.LampMap
    """

    def __init__(self, config, lamp_map):
        super().__init__(config)
        self.lamp_map = lamp_map
        self._index = {lamp.uid: i for i, lamp in enumerate(lamp_map.lamps)}
        self._window = deque(maxlen=config.window_samples)
        self._window_sum = 0.0
        self.image_still = ImageStillness(config.image_still)
        self.landmarks = []           # LandmarkEvent, in order of use
        self._used = set()
        self.unknown_uids = 0

    def accel_input(self, accel_x):
        """Mean of the last ``window_samples`` along-track accelerations (patent)."""
        if len(self._window) == self._window.maxlen:
            self._window_sum -= self._window[0]
        self._window.append(accel_x)
        self._window_sum += accel_x
        return self._window_sum / len(self._window)

    def zero_velocity_allowed(self, t_ns, state):
        """Still lamp spots prove a standstill whatever the filter's speed (a moving
        train moves every lamp by pixels in 0.3 s): the zero-velocity correction of
        the scheme, also at a cold start; the IMU's evidence as in the base class.
        """
        return (self.image_still.still_at(t_ns)
                or super().zero_velocity_allowed(t_ns, state))

    def process_frame(self, stamp_ns, observations):
        """One frame's LampObservations; applies at most one landmark per new lamp.

        Returns the LandmarkEvents applied.
        """
        cfg = self.config
        self.counters.frames += 1
        good = [o for o in observations if o.is_finite()]
        self.counters.bad_observations += len(observations) - len(good)
        self.image_still.push(stamp_ns, [o.uv_left for o in good])
        events = []
        for obs in good:
            if obs.uid is None or obs.uid in self._used:
                continue
            lamp = self.lamp_map.by_uid(obs.uid)
            if lamp is None:
                self.unknown_uids += 1
                continue
            if self._index[lamp.uid] % cfg.landmark_stride:
                continue
            t_ns = measurement_time_ns(obs, cfg.geometry)
            R, cov = self.rotation_at(t_ns)
            rng = range_to_lamp(obs, cfg.geometry, R, lamp.position_m[1:], cfg.ranging, cov)
            if rng is None or rng.ahead_m > cfg.landmark_max_ahead_m:
                continue
            chainage = float(lamp.position_m[0]) - rng.ahead_m
            var = rng.ahead_var_m2 + cfg.survey_sigma_m ** 2
            before = self.filter.state_at(t_ns)
            if not self.filter.add_measurement(t_ns, H_CHAINAGE, chainage, var):
                self.counters.measurements_dropped_old += 1
                continue
            self._used.add(obs.uid)
            event = LandmarkEvent(uid=int(obs.uid), t_ns=int(t_ns), chainage_m=chainage,
                                  sigma_m=math.sqrt(var),
                                  before_m=math.nan if before is None else float(before.x[0]))
            self.landmarks.append(event)
            events.append(event)
        return events
