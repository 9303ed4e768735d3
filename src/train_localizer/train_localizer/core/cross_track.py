"""How far ``base_link`` moves across and above its nominal place on the track, from the IMU.

The published pose puts ``base_link`` on the track's nominal line (the fix's track
constraint); the car body moves about it on its suspension, driven by the track's
irregularity: a few millimetres on a good track, centimetres on a poor one at speed
(the ``harsh`` rig profile at 100 km/h: 15–18 mm RMS and up to 40 mm vertically). How much
depends on the line and the speed, neither of which a fixed parameter knows; the IMU
measures it.

Estimate: the specific force across the body's heading and vertically in ``map`` (the
compensated attitude; the body's own axes without one) through a first-order high-pass
and two leaky integrators, transfer ``s/(s + ω_c)³`` with ``ω_c = 2π·highpass_hz``:
displacement well above the corner; gravity, a bias, a standing tilt, a cold
compensator's slowly converging attitude, the steady centripetal acceleration of a curve
and its linear ramp through a transition are no motion. Their running variance
over ``window_s`` is the motion's; the published 1σ is ``factor`` times its square root,
never below the configured floor. It is a rough measure: the slow track geometry the
body follows lies below and near the corner (the estimate reads low), the body's roll and
pitch modes add acceleration that is no displacement (it reads high); ``factor`` 3 keeps
every probed run inside 3σ and overstates the motion up to several times
(docs/arch/train_localizer.md, "Across and above the track", has the figures).
"""
import math

import numpy as np


class CrossTrackMotion:
    """Running lateral and vertical motion of ``base_link`` from its specific force.

    Parameters
    ----------
    highpass_hz : float
        Corner of the high-pass and the two leaky integrators, Hz (> 0).
    window_s : float
        Time constant of the running mean and variance, s (> 0).
    max_gap_s : float
        A longer step between two samples restarts the filter (the motion before the gap
        says nothing of the displacement after it), s.

    The filter starts from rest while the body is already moving: for ``5/ω_c`` (2.0 s at
    0.4 Hz) after a start or a restart its output is that start's transient, not the
    motion, and the variance is not taken (the estimate reads 0 meanwhile; taken from the
    start, a harsh car body at 100 km/h, 0.4 g of lateral acceleration at the first
    sample, read 44 mm lateral RMS a second after the start and still 15 mm six seconds
    later, for a true lateral motion of 18 mm at most).
    """

    def __init__(self, highpass_hz=0.4, window_s=2.0, max_gap_s=0.05):
        if not (highpass_hz > 0.0 and window_s > 0.0 and max_gap_s > 0.0):
            raise ValueError('highpass_hz, window_s and max_gap_s must be > 0')
        self._w = 2.0 * math.pi * float(highpass_hz)
        self._settle_s = 5.0 / self._w
        self._window_s = float(window_s)
        self._max_gap_s = float(max_gap_s)
        self.reset()

    def reset(self):
        self._t = None
        self._since_start_s = 0.0
        self._weight = 0.0          # of the running variance since it started (bias correction)
        # per axis: last input, high-pass, velocity, displacement, its mean and variance
        self._axes = [[0.0] * 6 for _ in range(2)]

    def add(self, t_s, f_lateral, f_vertical):
        """One sample: lateral and vertical specific force (:func:`lateral_vertical`, or
        the body's y and z axes without an attitude), m/s².
        """
        dt = None if self._t is None else t_s - self._t
        if dt is not None and dt <= 0.0:
            return
        self._t = t_s
        if dt is None or dt > self._max_gap_s:
            # (re)start in the steady state of a constant input: no motion
            for axis, f in zip(self._axes, (f_lateral, f_vertical)):
                axis[:] = (f, 0.0, 0.0, 0.0, 0.0, 0.0)
            self._since_start_s = 0.0
            self._weight = 0.0
            return
        w = self._w
        self._since_start_s += dt
        settled = self._since_start_s > self._settle_s
        k = min(1.0, dt / self._window_s)
        if settled:
            self._weight += k * (1.0 - self._weight)
        for axis, f in zip(self._axes, (f_lateral, f_vertical)):
            last, hp, v, d, mean, var = axis
            hp = (hp + f - last) / (1.0 + w * dt)
            v += dt * (hp - w * v)
            d += dt * (v - w * d)
            if settled:
                mean += k * (d - mean)
                var += k * ((d - mean) ** 2 - var)
            else:
                mean = d
            axis[:] = (f, hp, v, d, mean, var)

    def sigma_m(self):
        """(lateral, vertical) RMS of the motion, m (0 until the filter has settled)."""
        if self._weight <= 0.0:
            return (0.0, 0.0)
        # the running variance started at 0: divided by its weight, it is the variance of
        # what it has seen, not that shrunk toward 0 (the first seconds after a start)
        return tuple(math.sqrt(max(axis[5], 0.0) / self._weight) for axis in self._axes)


def lateral_vertical(R_map_base, f):
    """Lateral and vertical specific force (m/s²) of ``f`` (3, body axes) under the
    attitude ``R_map_base`` (body → map): vertical = map z; lateral = horizontal and square
    to the body's heading (left positive), so the body's roll is not read as lateral
    acceleration (g·sin φ: 0.17 m/s² at 1°).
    """
    ax, ay, az = (R_map_base @ np.asarray(f, dtype=float)).tolist()
    hx, hy = float(R_map_base[0, 0]), float(R_map_base[1, 0])    # body x, horizontal part
    norm = math.hypot(hx, hy)
    if norm < 1e-9:
        return float(f[1]), az
    return (-hy * ax + hx * ay) / norm, az
