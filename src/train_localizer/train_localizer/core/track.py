"""The track the localizer's one unknown, the chainage, lives on.

``base_link`` rides at a known lateral and vertical offset from the centreline of an
alignment (``vlc_common.core.alignment``: straights, clothoids, circular curves, and
optionally a vertical profile and cant). The filter estimates the chainage ``s``;
everything in ``map`` follows from the alignment: the nominal position ``P(s)`` at the
alignment's elevation z(s), the running direction ``t(s)`` and the left normal ``n(s)``.
On the default straight alignment ``P(s) = (s, y0, z0)`` and ``t = e_x`` exactly (a fast
path: the fix evaluates the track in its inner loop).

``t`` and ``n`` are horizontal: chainage is plan distance (railway practice), so the
along-track component of a map vector is its projection on the plan tangent, which is
what :meth:`chainage_of` inverts; the grade's vertical rate ``dz/ds`` is not part of
``t``. The cant is not needed here: it rolls ``base_link`` about the centreline at rail
level, where ``base_link`` sits with the default offsets (0, 0), so it changes the
attitude — which the IMU (``imu/data``) reports — and not the position. With non-zero
offsets the offsets stay along the horizontal normal and the vertical, as before; on a
canted curve the true ``base_link`` would then be rotated by the cant φ about the
centreline (a shift of about z0·φ across, y0·φ up).
"""
import math

import numpy as np

from vlc_common.core.alignment import Alignment
from vlc_common.core.rotations import rpy_to_matrix

_E_X = np.array([1.0, 0.0, 0.0])
_E_Y = np.array([0.0, 1.0, 0.0])
_E_Z = np.array([0.0, 0.0, 1.0])


class Track:
    """An alignment with the nominal offsets of ``base_link`` from its centreline.

    Parameters
    ----------
    alignment : Alignment or None
        None = the straight line along map x (s = x).
    offset_yz_m : (float, float)
        Nominal lateral (left, along n) and vertical offset of ``base_link``, m.
    """

    def __init__(self, alignment=None, offset_yz_m=(0.0, 0.0)):
        self.alignment = alignment if alignment is not None else Alignment.straight()
        self.offset_yz_m = (float(offset_yz_m[0]), float(offset_yz_m[1]))
        self.straight_x = self._is_map_x(self.alignment)

    @classmethod
    def for_lamp_map(cls, lamp_map, alignment_name='', offset_yz_m=(0.0, 0.0)):
        """The track of a lamp map: ``alignment_name``, else the alignment the map file
        names, else straight (ValueError for an unknown name).
        """
        name = alignment_name or getattr(lamp_map, 'alignment', '') or 'straight'
        return cls(Alignment.named(name), offset_yz_m)

    @staticmethod
    def _is_map_x(alignment):
        """True when the alignment is the level line s = x (the fast path applies)."""
        if not alignment.is_straight or not alignment.is_level:
            return False
        p = alignment.evaluate(np.array([0.0, 1.0]))
        return bool(np.allclose(p.x_m, [0.0, 1.0], atol=1e-12)
                    and np.allclose(p.y_m, 0.0, atol=1e-12))

    @property
    def name(self):
        return getattr(self.alignment, 'name', 'custom')

    def frame(self, chainage_m):
        """(P (3,), t (3,), n (3,)): nominal ``base_link`` position, tangent, left normal."""
        y0, z0 = self.offset_yz_m
        if self.straight_x:
            return np.array([chainage_m, y0, z0]), _E_X, _E_Y
        p = self.alignment.evaluate(chainage_m)
        c, s = math.cos(p.heading_rad[0]), math.sin(p.heading_rad[0])
        t = np.array([c, s, 0.0])
        n = np.array([-s, c, 0.0])
        return np.array([p.x_m[0], p.y_m[0], p.elevation_m[0]]) + y0 * n + z0 * _E_Z, t, n

    def attitude(self, chainage_m):
        """R_map_base (3, 3) of a platform riding the track at a chainage: the track frame
        Rz(ψ)·Ry(θ)·Rx(φ) of the rig (heading ψ, grade pitch θ = −atan(dz/ds), cant roll
        φ); the identity on the level straight line along map x.
        """
        if self.straight_x:
            return np.eye(3)
        p = self.alignment.evaluate(chainage_m)
        roll = 0.0 if p.cant_rad is None else float(p.cant_rad[0])
        pitch = 0.0 if p.grade is None else -math.atan(float(p.grade[0]))
        return rpy_to_matrix(roll, pitch, float(p.heading_rad[0]))

    def position(self, chainage_m):
        """Nominal ``base_link`` position (3,) in map at a chainage."""
        return self.frame(chainage_m)[0]

    def chainage_of(self, xyz_m):
        """Chainage of the foot point of a map position (3,) on the centreline, m."""
        if self.straight_x:
            return float(xyz_m[0])
        s, _ = self.alignment.project(xyz_m[0], xyz_m[1])
        return float(s[0])

    def covariance(self, chainage_m, along_var, lateral_var, vertical_var):
        """Map-frame position covariance (3, 3) from along/lateral/vertical variances.

        The along-track variance lies along dP/ds: on a grade G an error of the chainage
        moves the position G times as much vertically as it moves it along the plan.
        """
        _, t, n = self.frame(chainage_m)
        if not self.straight_x and not self.alignment.is_level:
            t = t + float(self.alignment.evaluate(chainage_m).grade[0]) * _E_Z
        return (along_var * np.outer(t, t) + lateral_var * np.outer(n, n)
                + vertical_var * np.outer(_E_Z, _E_Z))
