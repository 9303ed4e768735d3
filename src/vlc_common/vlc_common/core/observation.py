"""Plain records the localizer core consumes: one lamp seen in one stereo frame, one IMU sample.

They are what :mod:`train_localizer.conversions` makes of the ``vlc/lamps``,
``spots/pairs`` and ``imu/data`` messages, so the core never sees a ROS type. Times are
integer nanoseconds of the sensor clock (ROS stamps), so joins by stamp are exact and
published stamps land exactly on the publish grid.
"""
from dataclasses import dataclass, field
import math

import numpy as np

NS_PER_S = 1_000_000_000


@dataclass
class LampObservation:
    """One lamp spot pair of one stereo frame, with the UID the decoder assigned to it.

    Attributes
    ----------
    stamp_ns : int
        Image stamp: start of exposure of row 0 of both images, ns.
    uid : int or None
        CRC-confirmed lamp UID, or None while the decoder has not confirmed one.
    uv_left, uv_right : ndarray (2,)
        Sub-pixel spot centres (u right, v down) in the rectified left and right images, px.
    sigma_u_px, sigma_v_px : float
        1σ of each centre coordinate (same for both images), px.
    sigma_disparity_px : float
        1σ of ``d = u_left − u_right``, px; NaN means ``√2·sigma_u_px`` (independent
        left and right errors).
    exposure_mid_offset_s : float
        Exposure mid-time of the rows the spot covers, minus ``stamp_ns``, s; NaN means
        unknown (the core then uses the spot's centre row, see
        :func:`train_localizer.core.fix.measurement_time_ns`).
    """

    stamp_ns: int
    uid: object
    uv_left: np.ndarray
    uv_right: np.ndarray
    sigma_u_px: float = 0.05
    sigma_v_px: float = 0.05
    sigma_disparity_px: float = float('nan')
    exposure_mid_offset_s: float = float('nan')

    def __post_init__(self):
        self.uv_left = np.asarray(self.uv_left, dtype=float).reshape(2)
        self.uv_right = np.asarray(self.uv_right, dtype=float).reshape(2)

    @property
    def disparity_px(self):
        """``u_left − u_right`` (px), > 0 for a point in front of the rig."""
        return float(self.uv_left[0] - self.uv_right[0])

    def is_finite(self):
        """True when every centre and uncertainty needed for a fix is a finite number."""
        return bool(np.all(np.isfinite(self.uv_left)) and np.all(np.isfinite(self.uv_right))
                    and np.isfinite(self.sigma_u_px) and np.isfinite(self.sigma_v_px)
                    and self.sigma_u_px > 0.0 and self.sigma_v_px > 0.0)


@dataclass
class ImuSample:
    """One ``imu/data`` sample: compensated attitude plus raw rate and specific force.

    Attributes
    ----------
    stamp_ns : int
        Sample time, ns.
    accel_mps2 : ndarray (3,)
        Specific force in ``base_link`` axes, m/s² (not bias-corrected).
    gyro_rps : ndarray (3,)
        Angular rate in ``base_link`` axes, rad/s.
    quat_xyzw : ndarray (4,) or None
        Attitude of ``base_link`` in ``map`` (x, y, z, w), or None if the message has none.
    attitude_cov_rad2 : ndarray (3, 3) or None
        Attitude error covariance about map x, y, z, rad², or None if unknown.
    """

    stamp_ns: int
    accel_mps2: np.ndarray
    gyro_rps: np.ndarray = field(default_factory=lambda: np.zeros(3))
    quat_xyzw: np.ndarray = None
    attitude_cov_rad2: np.ndarray = None

    def __post_init__(self):
        self.accel_mps2 = np.asarray(self.accel_mps2, dtype=float).reshape(3)
        self.gyro_rps = np.asarray(self.gyro_rps, dtype=float).reshape(3)
        if self.quat_xyzw is not None:
            self.quat_xyzw = np.asarray(self.quat_xyzw, dtype=float).reshape(4)
        if self.attitude_cov_rad2 is not None:
            self.attitude_cov_rad2 = np.asarray(self.attitude_cov_rad2, dtype=float).reshape(3, 3)

    def is_finite(self):
        """True when stamp, specific force, rate and (if given) attitude are usable."""
        # (floats, not array calls: the localizer asks at every IMU sample)
        values = self.accel_mps2.tolist() + self.gyro_rps.tolist()
        if self.quat_xyzw is not None:
            q = self.quat_xyzw.tolist()
            if not math.sqrt(sum(v * v for v in q)) > 1e-6:     # (NaN fails here too)
                return False
            values += q
        return all(map(math.isfinite, values))
