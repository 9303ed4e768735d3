"""Along-track Kalman filter driven by the IMU, with delayed measurements replayed.

State ``[s, v, b]`` (chainage m, speed m/s, acceleration bias m/s²) and its discrete
model are :mod:`train_localizer.core.kalman`'s (exact integrals of
``ṡ = v, v̇ = a_m − b − n_a, ḃ = n_b``); the along-track acceleration ``a_m`` is the
filter's input, not a measurement. This module adds the time bookkeeping both
companion filters need:

* the filter starts at the first IMU sample with the chainage *unknown* (variance
  ``initial_chainage_var_m2``), so zero-velocity and speed measurements work before the
  first landmark, and the first position measurement sets the chainage;
* measurements (``z = h·x + n``) carry their own sensing time. Image measurements
  arrive tens of milliseconds after IMU samples of later instants: the filter keeps the
  IMU inputs and the state after each step for ``history_s`` and, for a measurement
  older than the newest sample, re-runs the steps from its instant with every stored
  measurement applied at its own time — exactly the in-order result. A measurement
  newer than the newest sample waits for the IMU to pass it.

No ROS here.
"""
from bisect import bisect_left, insort
from dataclasses import dataclass, field
import itertools

import numpy as np

from train_localizer.core.kalman import (
    H_CHAINAGE,
    H_SPEED,
    FilterState,
    KalmanConfig,
    innovation,
    predict,
    update,
)

__all__ = ['AlongTrackFilter', 'FilterSettings', 'H_CHAINAGE', 'H_SPEED']


@dataclass
class FilterSettings:
    """Attributes
    ----------
    kalman : train_localizer.core.kalman.KalmanConfig
        Process noise and initial speed/bias uncertainty.
    initial_chainage_var_m2 : float
        Chainage variance before any position measurement, m² ("unknown").
    history_s : float
        IMU steps and measurements kept for replaying delayed measurements, s.
    """

    kalman: KalmanConfig = field(default_factory=KalmanConfig)
    initial_chainage_var_m2: float = 1.0e8
    history_s: float = 2.0

    def __post_init__(self):
        if not (self.initial_chainage_var_m2 > 0.0 and self.history_s > 0.0):
            raise ValueError('initial_chainage_var_m2 and history_s must be > 0')


@dataclass(order=True)
class _Measurement:
    t_ns: int
    seq: int
    h: np.ndarray = field(compare=False)
    z: float = field(compare=False)
    r: float = field(compare=False)


class AlongTrackFilter:
    """See the module docstring. Times are integer ns of the sensor clock."""

    def __init__(self, settings=None):
        self.settings = settings or FilterSettings()
        self._t = []          # step times, ns
        self._acc = []        # mean along-track acceleration input over (t[k-1], t[k]]
        self._bq = []         # extra bias random-walk intensity over the step, m²/s⁵
        self._state = []      # FilterState after step k (measurements at ≤ t[k] applied)
        self._meas = []       # sorted _Measurement
        self._seq = itertools.count()
        self._trimmed = False     # the first stored step is no longer the prior's
        self.dropped_old = 0

    @property
    def started(self):
        return bool(self._t)

    @property
    def newest_ns(self):
        return self._t[-1] if self._t else None

    @property
    def state(self):
        """State at the newest IMU sample (None before the first)."""
        return self._state[-1] if self._state else None

    def reset(self):
        self._t.clear()
        self._acc.clear()
        self._bq.clear()
        self._state.clear()
        self._meas.clear()
        self._trimmed = False

    def _prior(self):
        k = self.settings.kalman
        return FilterState(np.zeros(3), np.diag([self.settings.initial_chainage_var_m2,
                                                 k.initial_speed_sigma_mps ** 2,
                                                 k.initial_bias_sigma_mps2 ** 2]))

    def add_imu(self, t_ns, accel_mps2, bias_q_extra=0.0):
        """Step to ``t_ns`` with the mean measured along-track acceleration over the step.

        ``bias_q_extra`` (m²/s⁵) adds bias random walk over the step (the wandering
        gravity leak of an uncertain pitch). Samples not newer than the newest are
        refused (returns False).
        """
        t_ns = int(t_ns)
        if self._t and t_ns <= self._t[-1]:
            return False
        if not self._t:
            state = self._propagate(self._prior(), t_ns, t_ns, accel_mps2, bias_q_extra)
        else:
            state = self._propagate(self._state[-1], self._t[-1], t_ns, accel_mps2,
                                    bias_q_extra)
        self._t.append(t_ns)
        self._acc.append(float(accel_mps2))
        self._bq.append(float(bias_q_extra))
        self._state.append(state)
        self._trim()
        return True

    def add_measurement(self, t_ns, h, z, r):
        """Scalar measurement ``z = h·x + n``, var(n) = ``r``, sensed at ``t_ns``.

        Returns False (dropped, counted) when it is older than the history.
        """
        t_ns = int(t_ns)
        if self._t and (t_ns < self._t[0] or (self._trimmed and t_ns <= self._t[0])):
            self.dropped_old += 1
            return False
        m = _Measurement(t_ns, next(self._seq), np.asarray(h, dtype=float), float(z),
                         float(r))
        insort(self._meas, m)
        if self._t and t_ns <= self._t[-1]:
            self._replay_from(max(bisect_left(self._t, t_ns), 0))
        return True

    def state_at(self, t_ns):
        """State at ``t_ns`` (within the history; beyond the newest sample it is predicted
        with the newest acceleration input, measurements after the newest step aside).
        Returns None before the first sample or for a time older than the history.
        """
        t_ns = int(t_ns)
        if not self._t or t_ns < self._t[0]:
            return None
        k = bisect_left(self._t, t_ns)
        if k < len(self._t) and self._t[k] == t_ns:
            return self._state[k]
        if k == len(self._t):
            return self._predict(self._state[-1], t_ns - self._t[-1], self._acc[-1],
                                 self._bq[-1])
        return self._propagate(self._state[k - 1], self._t[k - 1], t_ns, self._acc[k],
                               self._bq[k])

    def innovation_at(self, t_ns, h, z, r):
        """(innovation, its variance) of a measurement at ``t_ns`` against the state
        there, without applying it; None when the state is unknown there.
        """
        state = self.state_at(t_ns)
        if state is None:
            return None
        return innovation(state, z, r, np.asarray(h, dtype=float))

    # ------------------------------------------------------------------ internals
    def _predict(self, state, dt_ns, accel, bias_q):
        return predict(state, dt_ns * 1e-9, accel, self.settings.kalman, bias_q_extra=bias_q)

    def _measurements_in(self, t_from_ns, t_to_ns):
        """Stored measurements with t_from < t ≤ t_to, in time order."""
        lo = bisect_left(self._meas, _Measurement(t_from_ns + 1, -1, None, 0.0, 0.0))
        hi = bisect_left(self._meas, _Measurement(t_to_ns + 1, -1, None, 0.0, 0.0))
        return self._meas[lo:hi]

    def _propagate(self, state, t_from_ns, t_to_ns, accel, bias_q):
        """From ``state`` at ``t_from`` to ``t_to`` with ``accel``, applying the stored
        measurements in (t_from, t_to]; a first step (t_from == t_to) applies the ones
        at that instant.
        """
        lo = t_from_ns if t_from_ns < t_to_ns else t_from_ns - 1
        cur, t_cur = state, t_from_ns
        for m in self._measurements_in(lo, t_to_ns):
            cur = self._predict(cur, m.t_ns - t_cur, accel, bias_q)
            cur = update(cur, m.z, m.r, m.h)
            t_cur = m.t_ns
        return self._predict(cur, t_to_ns - t_cur, accel, bias_q)

    def _replay_from(self, k):
        """Recompute the states from step ``k`` on."""
        if k == 0:
            self._state[0] = self._propagate(self._prior(), self._t[0], self._t[0],
                                             self._acc[0], self._bq[0])
            k = 1
        for j in range(k, len(self._t)):
            self._state[j] = self._propagate(self._state[j - 1], self._t[j - 1], self._t[j],
                                             self._acc[j], self._bq[j])

    def _trim(self):
        horizon = self._t[-1] - int(self.settings.history_s * 1e9)
        drop = bisect_left(self._t, horizon)
        drop = min(drop, len(self._t) - 2)
        if drop > 0:
            self._trimmed = True
            del self._t[:drop], self._acc[:drop], self._bq[:drop], self._state[:drop]
            cut = bisect_left(self._meas, _Measurement(self._t[0], -1, None, 0.0, 0.0))
            del self._meas[:cut]
