"""How far ``base_link`` moves across and above its nominal place on the track, from the IMU.

The published pose puts ``base_link`` on the track's nominal line (the fix's track
constraint); the car body moves about it on its suspension, driven by the track's
irregularity: a few millimetres on a good track, centimetres on a poor one at speed
(the ``harsh`` rig profile at 100 km/h: 15–18 mm RMS and up to 40 mm vertically). How much
depends on the line and the speed, neither of which a fixed parameter knows; the IMU
measures it.

Estimate: the body's lateral and vertical acceleration (the specific force rotated into
``map`` by the compensated attitude, gravity removed; lateral = horizontal and square to
the body's heading, so it holds on a curve) through two leaky integrators, transfer
``1/(s + ω_c)²`` with ``ω_c = 2π·highpass_hz``: displacement above the corner, a bounded
response to an accelerometer bias or a gravity leak below it (0.01 m/s² → 1 mm at
0.5 Hz). Their running variance over ``window_s`` is the motion's; the published 1σ is
``factor`` times its square root, never below the configured floor. The band below the
corner (the slow track geometry the body follows) is not seen, so the estimate is low by
up to half on a poor track at speed and high on a good one (the IMU's noise and the
residual of the attitude): ``factor`` 2 covers the first.

Measured by replaying recorded bags through the localizer core (docs/arch/
train_localizer.md, "Across and above the track"): on ``harsh`` at 100 km/h the vertical
error reached 36–40 mm, 77–87 % of the poses inside a fixed 1 cm 3σ, and all of them
inside the grown one; on ``realistic`` the 1σ stays 10–13 mm.
"""
import math


class CrossTrackMotion:
    """Running lateral and vertical motion of ``base_link`` from its acceleration.

    Parameters
    ----------
    highpass_hz : float
        Corner of the two leaky integrators, Hz (> 0).
    window_s : float
        Time constant of the running mean and variance, s (> 0).
    max_gap_s : float
        A longer step between two samples restarts the integrators (the motion before
        the gap says nothing of the displacement after it), s.
    """

    def __init__(self, highpass_hz=0.5, window_s=2.0, max_gap_s=0.05):
        if not (highpass_hz > 0.0 and window_s > 0.0 and max_gap_s > 0.0):
            raise ValueError('highpass_hz, window_s and max_gap_s must be > 0')
        self._w = 2.0 * math.pi * float(highpass_hz)
        self._window_s = float(window_s)
        self._max_gap_s = float(max_gap_s)
        self.reset()

    def reset(self):
        self._t = None
        self._axes = [[0.0, 0.0, 0.0, 0.0] for _ in range(2)]   # v, d, mean, variance

    def add(self, t_s, a_lateral, a_vertical):
        """One sample: lateral and vertical acceleration (gravity removed), m/s²."""
        dt = None if self._t is None else t_s - self._t
        if dt is not None and dt <= 0.0:
            return
        self._t = t_s
        if dt is None or dt > self._max_gap_s:
            for axis in self._axes:
                axis[0] = axis[1] = 0.0
            return
        w = self._w
        k = min(1.0, dt / self._window_s)
        for axis, a in zip(self._axes, (a_lateral, a_vertical)):
            v, d, mean, var = axis
            v += dt * (a - w * v)
            d += dt * (v - w * d)
            mean += k * (d - mean)
            var += k * ((d - mean) ** 2 - var)
            axis[:] = (v, d, mean, var)

    def sigma_m(self):
        """(lateral, vertical) RMS of the motion, m."""
        return tuple(math.sqrt(max(axis[3], 0.0)) for axis in self._axes)


def lateral_vertical(quat_xyzw, f):
    """Lateral and vertical acceleration (m/s², gravity removed) of the specific force
    ``f`` (3, body axes) under the attitude ``quat_xyzw`` (body → map, unit): vertical =
    map z; lateral = horizontal, square to the body's heading (left positive).
    """
    x, y, z, w = quat_xyzw
    # rows of the rotation matrix applied to f, and the body x axis' horizontal part
    fx, fy, fz = f
    r00, r01, r02 = 1.0 - 2.0 * (y * y + z * z), 2.0 * (x * y - z * w), 2.0 * (x * z + y * w)
    r10, r11, r12 = 2.0 * (x * y + z * w), 1.0 - 2.0 * (x * x + z * z), 2.0 * (y * z - x * w)
    r20, r21, r22 = 2.0 * (x * z - y * w), 2.0 * (y * z + x * w), 1.0 - 2.0 * (x * x + y * y)
    ax = r00 * fx + r01 * fy + r02 * fz
    ay = r10 * fx + r11 * fy + r12 * fz
    az = r20 * fx + r21 * fy + r22 * fz - GRAVITY_MPS2
    norm = math.hypot(r00, r10)
    if norm < 1e-9:
        return 0.0, az
    return (-r10 * ax + r00 * ay) / norm, az


#: Standard gravity, m/s² (what the specific force of a body at rest reads upward).
GRAVITY_MPS2 = 9.80665
