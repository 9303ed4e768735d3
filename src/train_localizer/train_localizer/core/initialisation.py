"""Starting the filter: from a configured prior, from the first confirmed lamp and the
frames of it seen before its UID was confirmed, and restarting the chainage when
confirmed lamps contradict the state.

Cold start without a prior: nothing is published until a confirmed UID. The confirming
frame usually comes after several frames in which the decoder tracked the same lamp
without a UID yet; those observations are kept for ``init_lookback_s`` and, once lamp L
is confirmed, chained backwards frame by frame (each within ``max_speed_mps`` of the
next and farther from every other map lamp), so the filter starts from a short track of
L and knows the speed at once.
"""
import math

import numpy as np

from train_localizer.core.kalman import FilterState, initial_state
from vlc_common.core.observation import NS_PER_S

#: Other lamps within this chainage distance are candidates a frame could also show, m.
_OTHER_LAMPS_M = 60.0


def prior_state(config):
    """The FilterState of a configured prior (``initial_chainage_m``, its σ and, if known,
    ``initial_speed_mps``) of a :class:`~train_localizer.core.localizer.LocalizerConfig`.
    """
    speed = config.initial_speed_mps
    return initial_state(config.initial_chainage_m, config.initial_chainage_sigma_m ** 2,
                         config.kalman, speed_mps=speed if math.isfinite(speed) else 0.0,
                         speed_var_m2s2=0.01 if math.isfinite(speed) else None)


def restarted_chainage(old, chainage_m, var_m2, keep_speed, speed_sigma_mps, bias_sigma_mps2):
    """``old`` (FilterState) with its chainage restarted at ``chainage_m`` (variance
    ``var_m2``), uncorrelated with the rest. ``keep_speed`` keeps the speed and bias
    covariance; else their variances are raised to at least ``speed_sigma_mps²`` and
    ``bias_sigma_mps2²`` (a state that far off had its speed wrong too).
    """
    P = np.zeros((3, 3))
    P[0, 0] = var_m2
    if keep_speed:
        P[1:, 1:] = old.P[1:, 1:]
    else:
        P[1, 1] = max(old.P[1, 1], speed_sigma_mps ** 2)
        P[2, 2] = max(old.P[2, 2], bias_sigma_mps2 ** 2)
    x = old.x.copy()
    x[0] = chainage_m
    return FilterState(x, P)


class ColdStart:
    """Unconfirmed observations kept while waiting for the first confirmed UID.

    Parameters
    ----------
    lookback_s : float
        How far back unconfirmed observations are kept, s.
    max_speed_mps : float
        Highest speed the train can have, m/s (bounds the lamp's track between frames).
    """

    def __init__(self, lookback_s, max_speed_mps):
        self.lookback_ns = int(lookback_s * NS_PER_S)
        self.max_speed_mps = max_speed_mps
        self.waiting = []

    def clear(self):
        self.waiting = []

    def forget_before(self, t_ns):
        """Drop what is older than the lookback from ``t_ns``."""
        horizon = t_ns - self.lookback_ns
        self.waiting = [p for p in self.waiting if p.t_ns >= horizon]

    def chain(self, prep, lamp, fix, fix_for, lamp_map):
        """[(t_ns, FixResult)] of lamp ``lamp``'s recent unconfirmed frames, oldest first,
        ending with the confirmed frame ``prep`` and its ``fix``.

        Walking back from the confirmed frame, an unconfirmed observation joins the track
        when, explained as ``lamp`` (``fix_for(prep, lamp)`` → (fix, geometry_ok)), it lies
        within ``max_speed_mps`` of the newer track point, and explained as any other map
        lamp it would not.
        """
        chain = [(prep.t_ns, fix)]
        anchor_t, anchor = prep.t_ns, fix
        others = [other.track_chainage_m - lamp.track_chainage_m
                  for other in lamp_map.near_chainage(lamp.track_chainage_m, _OTHER_LAMPS_M,
                                                      _OTHER_LAMPS_M)
                  if other.uid != lamp.uid]
        for old in sorted(self.waiting, key=lambda p: -p.t_ns):
            if old.t_ns >= anchor_t:
                continue
            f, geometry_ok = fix_for(old, lamp)
            if not geometry_ok:
                continue
            reach = (self.max_speed_mps * (anchor_t - old.t_ns) * 1e-9
                     + 4.0 * math.sqrt(f.var_m2 + anchor.var_m2))
            if abs(f.chainage_m - anchor.chainage_m) > reach:
                continue
            # Explained as another lamp (dx further along), the fix would move by dx.
            if any(abs(f.chainage_m + dx - anchor.chainage_m) <= reach for dx in others):
                continue
            chain.append((old.t_ns, f))
            anchor_t, anchor = old.t_ns, f
        return chain[::-1]
