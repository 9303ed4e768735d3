"""What the localizer reports after each IMU sample or frame: poses, the fate of each lamp
observation, events to log and the attitude the lamps show.
"""
from dataclasses import dataclass, field
import math

import numpy as np

from train_localizer.core.integrity import Level


@dataclass
class PoseEstimate:
    """The pose of ``base_link`` in ``map`` at ``stamp_ns``.

    Attributes
    ----------
    stamp_ns : int
        Time the pose describes, ns.
    position_m : ndarray (3,)
        Chainage and the nominal track offsets, m.
    position_cov_m2 : ndarray (3, 3)
        Covariance of ``position_m`` (along-track: filter variance plus the systematic
        floor of the last fix), m².
    speed_mps, speed_var : float
        Along-track speed and its variance (m/s, m²/s²); NaN for raw fixes.
    quat_xyzw : ndarray (4,)
        Attitude of ``base_link`` in ``map``; identity when unknown.
    attitude_cov_rad2 : ndarray (3, 3)
        Attitude covariance about map x, y, z, rad² (large when unknown).
    angular_velocity_rps : ndarray (3,)
        Angular rate in ``base_link`` (from the newest IMU sample before the stamp).
    kind : str
        ``grid`` (publish grid), ``fix`` (right after a fix) or ``raw`` (use_kalman off).
    chainage_along_m, chainage_var_m2 : float
        The chainage (m) and its variance (m²): ``position_m`` is the track's point there.
    """

    stamp_ns: int
    position_m: np.ndarray
    position_cov_m2: np.ndarray
    speed_mps: float
    speed_var: float
    quat_xyzw: np.ndarray
    attitude_cov_rad2: np.ndarray
    angular_velocity_rps: np.ndarray
    kind: str
    chainage_along_m: float = float('nan')
    chainage_var_m2: float = float('nan')

    @property
    def chainage_m(self):
        if math.isfinite(self.chainage_along_m):
            return float(self.chainage_along_m)
        return float(self.position_m[0])

    @property
    def chainage_sigma_m(self):
        if math.isfinite(self.chainage_var_m2):
            return math.sqrt(self.chainage_var_m2)
        return math.sqrt(self.position_cov_m2[0, 0])


@dataclass
class FixRecord:
    """What happened to one lamp observation (for diagnostics and the benchmark).

    ``status`` is one of ``accepted``, ``initialised``, ``reinitialised``,
    ``rejected_gate``, ``rejected_geometry``, ``unknown_uid``, ``unconfirmed_skipped``,
    ``too_old``, ``bad_observation``, ``waiting_for_uid``.
    """

    measurement_ns: int
    uid: object
    lamp_uid: object
    status: str
    chainage_m: float = float('nan')
    var_m2: float = float('nan')
    d2: float = float('nan')
    detail: str = ''


@dataclass
class Event:
    """A condition the node should log (throttled per ``code``)."""

    level: Level
    code: str
    message: str


@dataclass
class StepReport:
    """Outputs of one ``add_imu`` / ``add_frame`` call."""

    poses: list = field(default_factory=list)
    fixes: list = field(default_factory=list)
    events: list = field(default_factory=list)
    attitude_aids: list = field(default_factory=list)


@dataclass
class AttitudeAid:
    """The platform attitude one lamp shows (for ``attitude_aiding``).

    ``quat_xyzw`` is the attitude the fix used at ``stamp_ns`` (imu/data's; the track's
    when imu/data's is not usable, so that a compensator whose attitude is wrong gets it
    back) corrected by the attitude error the lamp's range and direction show
    (:func:`~train_localizer.core.fix.vision_attitude`);
    ``cov_rad2`` its covariance about the map axes from the lamp alone (the IMU's own
    attitude was not used: large about the line of sight, which one lamp cannot see),
    rad². ``chainage_m`` is the fix's.
    """

    stamp_ns: int
    quat_xyzw: np.ndarray
    cov_rad2: np.ndarray
    chainage_m: float
