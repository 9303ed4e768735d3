"""Stereo ranging to a lamp: the along-track distance from ``base_link`` to the lamp.

The stereo pair measures the range ``r`` from the left optical centre to the lamp
(triangulation, paper eq. 12: ``Z = fx·b/d``; the range is the norm of the
triangulated point and, unlike its direction, does not depend on the platform
attitude). The lamp sits on the wall at a known lateral and vertical offset from the
track, so the along-track distance from the camera to the lamp follows from the range
alone (the patent's "stereo ranging to a beacon")::

    a = √(r² − Δy² − Δz²),   Δy, Δz = lamp − camera across the track
    q = a + c_x               (c = R·t_base_cam: camera offset from base_link in map)

``q = x_lamp − s``: lamp chainage minus ``base_link`` chainage. For a known lamp, ``q``
gives the chainage; for any fixed lamp, the change of ``q`` between two frames gives
the distance travelled. The attitude enters only through the small lever ``c``
(0.8 m lateral, 2.9 m up: 0.1° of heading moves ``c_x`` by 1.4 mm).

Variance: the range's (triangulation covariance along the line of sight) scaled by
``(r/a)²``, the track offsets' (``base_link`` lateral/vertical, mm) by ``(Δ/a)²`` —
the root is ill-conditioned for a lamp nearly abeam, so ranges with ``a`` below
``min_along_m`` are not used — and the attitude error through the lever.

No ROS here.
"""
from dataclasses import dataclass
import math

import numpy as np

from train_localizer.core.fix import measurement_time_ns, triangulate


@dataclass
class RangingConfig:
    """Attributes
    ----------
    track_offset_yz_m : tuple of 2 floats
        Nominal lateral and vertical position of ``base_link`` in ``map``, m.
    track_sigma_yz_m : tuple of 2 floats
        1σ of ``base_link``'s lateral and vertical offset from it, m.
    min_along_m : float
        Lamps closer than this along the track (nearly abeam) are not ranged, m.
    min_disparity_px : float
        Pairs with a smaller disparity are not used, px.
    attitude_sigma_rad : tuple of 3 floats
        Attitude 1σ about map x, y, z used when ``imu/data`` carries no covariance, rad.
    """

    track_offset_yz_m: tuple = (0.0, 0.0)
    track_sigma_yz_m: tuple = (0.004, 0.004)
    min_along_m: float = 0.3
    min_disparity_px: float = 4.0
    attitude_sigma_rad: tuple = (1e-3, 1e-3, 2e-3)


@dataclass
class BeaconRange:
    """One lamp ranged in one frame.

    Attributes
    ----------
    t_ns : int
        Measurement instant (exposure mid-time of the spot's rows), ns.
    range_m : float
        Left optical centre → lamp, m.
    ahead_m : float
        ``q = x_lamp − s``: lamp chainage minus ``base_link`` chainage, m.
    ahead_var_m2 : float
        Variance of ``ahead_m``, m².
    camera_x_m : float
        ``c_x``: the left camera's along-track offset from ``base_link`` in map, m.
    """

    t_ns: int
    range_m: float
    ahead_m: float
    ahead_var_m2: float
    camera_x_m: float


def range_to_lamp(obs, geometry, R_map_base, lamp_yz_m, config, attitude_cov_rad2=None):
    """Along-track distance from ``base_link`` to the lamp of a spot pair.

    Parameters
    ----------
    obs : vlc_common.core.observation.LampObservation
    geometry : train_localizer.core.fix.RigGeometry
    R_map_base : ndarray (3, 3)
        Platform attitude at the measurement instant.
    lamp_yz_m : tuple of 2 floats
        The lamp's lateral and vertical position in ``map`` (from the lamp map; the
        wall line's for a lamp not yet identified), m.
    config : RangingConfig
    attitude_cov_rad2 : ndarray (3, 3), optional
        Attitude error covariance about map x, y, z; ``config.attitude_sigma_rad`` if None.

    Returns
    -------
    BeaconRange or None
        None for a pair that cannot be ranged (disparity too small, lamp nearly abeam
        or nearer than the track geometry allows, non-finite input).
    """
    if not obs.is_finite():
        return None
    p_cam, cov_cam = triangulate(obs, geometry, config.min_disparity_px)
    if p_cam is None:
        return None
    r = float(np.linalg.norm(p_cam))
    u = p_cam / r
    var_r = float(u @ cov_cam @ u)
    R = np.asarray(R_map_base, dtype=float)
    c = R @ geometry.t_base_cam
    y0, z0 = config.track_offset_yz_m
    dy = float(lamp_yz_m[0]) - (y0 + c[1])
    dz = float(lamp_yz_m[1]) - (z0 + c[2])
    a2 = r * r - dy * dy - dz * dz
    if not a2 >= config.min_along_m ** 2:
        return None
    a = math.sqrt(a2)
    sy, sz = config.track_sigma_yz_m
    if attitude_cov_rad2 is None:
        attitude_cov_rad2 = np.diag(np.square(config.attitude_sigma_rad))
    # c' = Exp(δθ)·c ≈ c + δθ × c  ⇒  δc_x = δθ_y·c_z − δθ_z·c_y
    j_att = np.array([0.0, c[2], -c[1]])
    var = ((r / a) ** 2 * var_r + (dy / a * sy) ** 2 + (dz / a * sz) ** 2
           + float(j_att @ np.asarray(attitude_cov_rad2, float) @ j_att))
    return BeaconRange(t_ns=measurement_time_ns(obs, geometry), range_m=r, ahead_m=a + c[0],
                       ahead_var_m2=var, camera_x_m=float(c[0]))
