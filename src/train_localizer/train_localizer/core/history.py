"""The localizer's short history of filter steps: propagation and delayed updates.

Every accepted IMU sample adds a *step*: its time, the along-track acceleration input
over the interval that ends there, the angular rate, and the filter state after the
step's updates. A measurement older than the newest step is applied where it belongs: a
step is inserted at its time (predicted from the step before with that interval's
input), updated, and every later step is re-propagated with its stored input and
updates, so the result is exactly what an in-order filter would have produced. Updates
are kept with their step and re-applied whenever an older measurement forces a replay.

Stamps are integer nanoseconds of the sensor clock.
"""
import bisect
import math

import numpy as np

from train_localizer.core.kalman import predict, update
from vlc_common.core.observation import NS_PER_S

#: The input of a step whose acceleration is unknown (an IMU gap, the first sample).
NO_INPUT = (float('nan'), 0.0)
#: Steps always kept behind the history window before old ones are pruned in one go.
_PRUNE_BATCH = 64


class StepHistory:
    """Steps of the along-track filter within ``history_s`` of the newest one.

    Parameters
    ----------
    kalman : KalmanConfig
        Process model of the propagation.
    history_s : float
        How far back a measurement may be applied, s.

    Each step ``i`` holds ``t[i]`` (ns), ``a[i]`` = (acceleration input m/s² over the
    interval ending there, extra bias noise intensity) or :data:`NO_INPUT`, ``x[i]`` the
    FilterState after its updates (None before initialisation), ``gyro[i]`` the angular
    rate in ``base_link`` (rad/s) and ``upd[i]`` its updates: ``('z', H, z, r)``,
    ``('set', FilterState)`` or ``('doubt', gap_s)`` (the chainage variance widened by
    the distance the train runs in ``gap_s`` at the state's speed).
    """

    def __init__(self, kalman, history_s):
        self.kalman = kalman
        self.history_ns = int(history_s * NS_PER_S)
        self.clear()

    def clear(self):
        self.t, self.a, self.x, self.gyro, self.upd = [], [], [], [], []

    def __len__(self):
        return len(self.t)

    @property
    def newest_ns(self):
        return self.t[-1] if self.t else None

    @property
    def newest_state(self):
        """The newest FilterState, or None (no step, or not initialised)."""
        return self.x[-1] if self.t else None

    def propagate(self, state, dt_ns, a_in):
        """``state`` predicted over ``dt_ns`` with the input ``a_in`` of that interval."""
        cfg = self.kalman
        dt = dt_ns * 1e-9
        accel, bias_q = a_in
        if math.isnan(accel):
            return predict(state, dt, float(state.x[2]), cfg, cfg.unknown_accel_sigma_mps2 ** 2)
        return predict(state, dt, accel, cfg, bias_q_extra=bias_q)

    def append(self, t, a_in, gyro, first_state=None):
        """Append a step at the newest end, its state propagated from the previous step
        (``first_state`` when there is none: a configured prior, or None).
        """
        x = first_state
        if self.t and self.x[-1] is not None:
            x = self.propagate(self.x[-1], t - self.t[-1], a_in)
        self.t.append(t)
        self.a.append(a_in)
        self.x.append(x)
        self.gyro.append(np.asarray(gyro, dtype=float))
        self.upd.append([])
        self._prune()

    def _prune(self):
        cutoff = self.t[-1] - self.history_ns
        k = bisect.bisect_right(self.t, cutoff) - 1
        if k > _PRUNE_BATCH:
            del self.t[:k], self.a[:k], self.x[:k], self.gyro[:k], self.upd[:k]

    def is_too_old(self, t):
        """True when ``t`` lies before the history window."""
        return bool(self.t) and t < self.t[-1] - self.history_ns

    def index_at_or_before(self, t):
        return bisect.bisect_right(self.t, t) - 1

    def state_at(self, t):
        """Filter state at ``t`` (not stored) from the step at or before it, or None."""
        i = self.index_at_or_before(t)
        if i < 0 or self.x[i] is None:
            return None
        if self.t[i] == t:
            return self.x[i]
        a_in = self.a[i + 1] if i + 1 < len(self.t) else self.a[i]
        return self.propagate(self.x[i], t - self.t[i], a_in)

    def insert(self, t):
        """Index of a step at ``t``, inserting one (state propagated) if needed."""
        i = self.index_at_or_before(t)
        if i >= 0 and self.t[i] == t:
            return i
        if i + 1 < len(self.t):
            a_in = self.a[i + 1]
        else:
            a_in = self.a[i] if i >= 0 else NO_INPUT
        state = self.state_at(t) if i >= 0 else None
        gyro = self.gyro[i] if i >= 0 else (self.gyro[0] if self.gyro else np.zeros(3))
        self.t.insert(i + 1, t)
        self.a.insert(i + 1, a_in)
        self.x.insert(i + 1, state)
        self.gyro.insert(i + 1, gyro)
        self.upd.insert(i + 1, [])
        return i + 1

    def insert_sample(self, t, a_in, gyro):
        """An IMU sample older than the newest step (steps were extrapolated past it while
        the IMU lagged): put it where it belongs with its input and replay the later
        steps.
        """
        i = self.insert(t)
        self.a[i] = a_in
        self.gyro[i] = np.asarray(gyro, dtype=float)
        if i > 0 and self.x[i - 1] is not None:
            self.x[i] = self.propagate(self.x[i - 1], t - self.t[i - 1], a_in)
            for upd in self.upd[i]:
                self.x[i] = self.apply_update(self.x[i], upd)
            self.replay_from(i)

    @staticmethod
    def apply_update(state, upd):
        if upd[0] == 'set':
            return upd[1].copy()
        if upd[0] == 'doubt':
            # the stamps advanced by gap_s with nothing to show that time did: the
            # chainage may be off by as far as the train runs in that time
            out = state.copy()
            out.P[0, 0] += (abs(float(state.x[1])) * upd[1]) ** 2
            return out
        _, h, z, r = upd
        return update(state, z, r, h)

    def add_update(self, i, upd):
        """Apply ``upd`` at step ``i``, remember it, and replay the later steps."""
        self.upd[i].append(upd)
        self.x[i] = self.apply_update(self.x[i], upd)
        self.replay_from(i)

    def replay_from(self, i):
        """Re-propagate every step after ``i`` with its stored input and updates."""
        for j in range(i + 1, len(self.t)):
            prev = self.x[j - 1]
            x = None if prev is None else self.propagate(prev, self.t[j] - self.t[j - 1],
                                                         self.a[j])
            for upd in self.upd[j]:
                x = self.apply_update(x, upd)
            self.x[j] = x

    def gyro_at(self, t):
        """Angular rate (3,) of the step at or before ``t``, rad/s (zeros before any)."""
        i = self.index_at_or_before(t)
        return self.gyro[i].copy() if i >= 0 else np.zeros(3)
