"""Short history of platform attitudes with slerp interpolation at any instant.

The localizer needs the camera platform's attitude at the exposure mid-time of the rows
a lamp spot covers (paper §3.3.2), which falls between two IMU samples and is usually
older than the newest one (image processing takes longer than an IMU period). The
compensator publishes ``imu/data`` at the IMU rate; a consumer pushes every message
into an :class:`AttitudeBuffer` and asks :meth:`AttitudeBuffer.at` for the attitude at
the measurement's stamp.

Times are seconds (float, e.g. ROS stamp ``sec + nanosec·1e-9``); quaternions are
``x, y, z, w`` and rotate ``base_link`` vectors into ``map``.
"""
import logging
import math

import numpy as np

from vlc_common.core.rotations import (
    quat_conjugate,
    quat_multiply,
    quat_normalize,
    quat_slerp,
    quat_to_rotvec,
    quat_to_rpy,
)

_LOG = logging.getLogger(__name__)


class AttitudeBuffer:
    """Time-ordered attitude samples over a sliding horizon, interpolated by slerp.

    Parameters
    ----------
    horizon_s : float
        Samples older than ``newest − horizon_s`` are dropped [s].
    max_gap_s : float
        Two neighbouring samples farther apart than this are not interpolated across:
        :meth:`at` returns ``None`` inside such a gap [s].
    max_extrapolation_s : float
        How far past the newest sample :meth:`at` may extrapolate at the last
        sample pair's constant angular rate [s]; 0 disables extrapolation. Nothing is
        extrapolated before the oldest sample.
    """

    def __init__(self, horizon_s=2.0, max_gap_s=0.05, max_extrapolation_s=0.0):
        if horizon_s <= 0.0 or max_gap_s <= 0.0 or max_extrapolation_s < 0.0:
            raise ValueError('horizon_s and max_gap_s must be > 0, max_extrapolation_s ≥ 0')
        self.horizon_s = float(horizon_s)
        self.max_gap_s = float(max_gap_s)
        self.max_extrapolation_s = float(max_extrapolation_s)
        self._capacity = 1024
        self._t = np.empty(self._capacity)
        self._q = np.empty((self._capacity, 4))
        self._cov = np.empty((self._capacity, 3, 3))
        self._start = 0
        self._end = 0

    def __len__(self):
        return self._end - self._start

    @property
    def oldest_s(self):
        """Stamp of the oldest kept sample [s], or ``None`` when empty."""
        return float(self._t[self._start]) if len(self) else None

    @property
    def newest_s(self):
        """Stamp of the newest sample [s], or ``None`` when empty."""
        return float(self._t[self._end - 1]) if len(self) else None

    def clear(self):
        """Forget every sample (e.g. after the attitude filter was reset)."""
        self._start = self._end = 0

    def push(self, t_s, quat_xyzw, covariance=None):
        """Append one attitude sample.

        Parameters
        ----------
        t_s : float
            Sample time [s]; must be later than the newest kept sample.
        quat_xyzw : array_like, shape (4,)
            Attitude of ``base_link`` in ``map``; normalised here.
        covariance : array_like, shape (3, 3), optional
            Small-angle attitude error covariance about map x, y, z [rad²]; NaN when
            omitted.

        Returns
        -------
        bool
            ``False`` (sample ignored, logged) when the stamp is not strictly newer
            than the newest sample or the quaternion is not finite and non-zero.
        """
        x, y, z, w = (float(v) for v in quat_xyzw)
        norm = math.sqrt(x * x + y * y + z * z + w * w)
        if not (math.isfinite(t_s) and math.isfinite(norm) and norm > 1e-9):
            _LOG.debug('AttitudeBuffer: non-finite sample at t=%r ignored', t_s)
            return False
        newest = self._t[self._end - 1] if self._end > self._start else -math.inf
        if t_s <= newest:
            _LOG.debug('AttitudeBuffer: stamp %.9f not after %.9f, ignored', t_s, newest)
            return False
        if self._end == self._capacity:
            self._compact()
        q = [x / norm, y / norm, z / norm, w / norm]
        if newest > -math.inf:
            p = self._q[self._end - 1]
            if q[0] * p[0] + q[1] * p[1] + q[2] * p[2] + q[3] * p[3] < 0.0:
                # Keep neighbours on one hemisphere so that slerp takes the short arc.
                q = [-v for v in q]
        self._t[self._end] = t_s
        self._q[self._end] = q
        self._cov[self._end] = np.nan if covariance is None else np.asarray(covariance,
                                                                             dtype=float)
        self._end += 1
        self._drop_older_than(t_s - self.horizon_s)
        return True

    def at(self, t_s):
        """Attitude at time ``t_s`` by slerp between the two bracketing samples.

        Returns
        -------
        numpy.ndarray, shape (4,) or None
            Unit quaternion ``x, y, z, w`` (w ≥ 0), or ``None`` when ``t_s`` is outside
            the kept history (beyond the allowed extrapolation) or inside a gap longer
            than ``max_gap_s``.
        """
        # One instant, the same arithmetic as at_many's row for it without its
        # vectorised masks (np.isin over the whole history): ~10x faster, called for
        # every fix and every published pose.
        n = len(self)
        if n == 0:
            return None
        t = float(t_s)
        times = self._t[self._start:self._end]
        quats = self._q[self._start:self._end]
        k = int(np.searchsorted(times, t, side='right'))
        if k > 0 and times[k - 1] == t:
            q = quats[k - 1:k]
        elif n >= 2:
            hi = min(max(k, 1), n - 1)
            lo = hi - 1
            span = times[hi] - times[lo]
            if span > self.max_gap_s:
                return None
            newest = times[n - 1]
            if not (times[0] <= t <= newest
                    or (t > newest and t - newest <= self.max_extrapolation_s)):
                return None
            q = quat_slerp(quats[lo:lo + 1], quats[hi:hi + 1],
                           np.array([(t - times[lo]) / span]))
        else:
            return None
        return quat_normalize(q)[0]

    def at_many(self, t_s):
        """Vectorised :meth:`at`: times (N,) → quaternions (N, 4), NaN rows if unknown."""
        t = np.asarray(t_s, dtype=float).reshape(-1)
        out = np.full((t.size, 4), np.nan)
        n = len(self)
        if n == 0:
            return out
        times = self._t[self._start:self._end]
        quats = self._q[self._start:self._end]
        exact = np.isin(t, times)
        if n >= 2:
            hi = np.clip(np.searchsorted(times, t, side='right'), 1, n - 1)
            lo = hi - 1
            span = times[hi] - times[lo]
            frac = (t - times[lo]) / span
            inside = (t >= times[0]) & (t <= times[-1]) & (span <= self.max_gap_s)
            ahead = ((t > times[-1]) & (t - times[-1] <= self.max_extrapolation_s)
                     & (span <= self.max_gap_s))
            use = inside | ahead
            if np.any(use):
                # frac > 1 past the newest sample extends the last constant-rate arc.
                out[use] = quat_slerp(quats[lo[use]], quats[hi[use]], frac[use])
        if np.any(exact):
            idx = np.searchsorted(times, t[exact])
            out[exact] = quats[idx]
        ok = ~np.isnan(out[:, 0])
        out[ok] = quat_normalize(out[ok])
        return out

    def rpy_at(self, t_s):
        """Roll, pitch, yaw (3,) [rad] at ``t_s`` (R = Rz·Ry·Rx), or ``None``."""
        q = self.at(t_s)
        return None if q is None else quat_to_rpy(q)

    def covariance_at(self, t_s):
        """Attitude covariance (3, 3) [rad²] at ``t_s``, linear in time, or ``None``."""
        n = len(self)
        if n == 0:
            return None
        times = self._t[self._start:self._end]
        if t_s < times[0] or t_s > times[-1] + self.max_extrapolation_s:
            return None
        if n == 1:
            return self._cov[self._start].copy() if t_s == times[0] else None
        hi = int(np.clip(np.searchsorted(times, t_s, side='right'), 1, n - 1))
        lo = hi - 1
        if times[hi] - times[lo] > self.max_gap_s:
            return None
        w = min((t_s - times[lo]) / (times[hi] - times[lo]), 1.0)
        c0, c1 = self._cov[self._start + lo], self._cov[self._start + hi]
        return (1.0 - w) * c0 + w * c1

    def angular_velocity_at(self, t_s):
        """Mean angular rate (3,) [rad/s] in ``base_link`` over the bracketing pair."""
        n = len(self)
        if n < 2:
            return None
        times = self._t[self._start:self._end]
        hi = int(np.clip(np.searchsorted(times, t_s, side='right'), 1, n - 1))
        lo = hi - 1
        span = times[hi] - times[lo]
        if span > self.max_gap_s or t_s < times[0] or t_s > times[-1] + self.max_extrapolation_s:
            return None
        quats = self._q[self._start:self._end]
        rel = quat_multiply(quat_conjugate(quats[lo]), quats[hi])
        return quat_to_rotvec(rel) / span

    def _drop_older_than(self, t_min):
        if self._end - self._start < 2 or self._t[self._start + 1] > t_min:
            return
        times = self._t[self._start:self._end]
        # Keep one sample at or before t_min so that t_min itself stays interpolable.
        k = int(np.searchsorted(times, t_min, side='right')) - 1
        if k > 0:
            self._start += k

    def _compact(self):
        n = len(self)
        if n >= self._capacity // 2:
            self._capacity *= 2
            t = np.empty(self._capacity)
            q = np.empty((self._capacity, 4))
            c = np.empty((self._capacity, 3, 3))
        else:
            t, q, c = self._t, self._q, self._cov
        t[:n] = self._t[self._start:self._end]
        q[:n] = self._q[self._start:self._end]
        c[:n] = self._cov[self._start:self._end]
        self._t, self._q, self._cov = t, q, c
        self._start, self._end = 0, n

