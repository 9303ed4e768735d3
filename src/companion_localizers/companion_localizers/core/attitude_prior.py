"""Platform tilt: the ``imu/data`` estimate fused with the track's known tilt.

Roll and pitch of ``base_link`` relative to a level track are the platform's vibration
only (paper eq. 21: a few tenths of a degree). An attitude filter that starts at speed
can be degrees off in pitch for tens of seconds (the rig's compensator drifts to 2° in
the first 5 s of a 60 km/h run, reporting a 1σ of about 1°), and the companion methods
feel its pitch twice: as a gravity leak g·δθ into the along-track acceleration
(2° = 0.34 m/s²), and through the lever arm of a sensor 2.9 m above ``base_link``
(2° = 10 cm of along-track position). Both estimates of the tilt — the filter's and the
track's (zero mean, ``tilt_sigma_rad`` of vibration) — are combined by their variances
(per axis, the minimum-variance combination of two independent estimates), so a
converged filter (σ ≪ the vibration) is taken as it is and a wandering one is pulled
to the track. Heading is left as estimated: the platform's heading offset and sway
(−5…+7.5°) are not known a priori. On a graded or canted track the track's own pitch
and roll would be the prior's mean (from the line's map); this straight tunnel is
level.

No ROS here.
"""
import math

import numpy as np

from vlc_common.core.rotations import quat_from_rpy, quat_to_rpy


def fuse_tilt(quat_xyzw, cov_rad2, tilt_sigma_rad, default_sigma_rad=(0.0087, 0.0087)):
    """Roll and pitch of an attitude pulled toward the level track.

    Parameters
    ----------
    quat_xyzw : array_like (4,)
        Attitude of ``base_link`` in ``map`` from ``imu/data``.
    cov_rad2 : ndarray (3, 3) or None
        Its error covariance about map x, y, z (≈ roll, pitch, heading), rad².
    tilt_sigma_rad : tuple of 2 floats
        1σ of the platform's roll and pitch about the track (vibration), rad. A
        non-positive value leaves that axis unchanged.
    default_sigma_rad : tuple of 2 floats
        Roll and pitch 1σ assumed when ``cov_rad2`` is missing or not finite, rad.

    Returns
    -------
    quat_xyzw : ndarray (4,)
        The fused attitude (heading unchanged).
    cov_rad2 : ndarray (3, 3)
        Its covariance: fused roll and pitch variances; heading and cross terms as given
        (zeros when not given).
    """
    rpy = quat_to_rpy(np.asarray(quat_xyzw, dtype=float))
    cov = (np.array(cov_rad2, dtype=float) if cov_rad2 is not None
           else np.diag([default_sigma_rad[0] ** 2, default_sigma_rad[1] ** 2, 0.0]))
    if not np.all(np.isfinite(cov)):
        cov = np.diag([default_sigma_rad[0] ** 2, default_sigma_rad[1] ** 2, 0.0])
    out = rpy.copy()
    for axis in (0, 1):
        prior_var = float(tilt_sigma_rad[axis]) ** 2
        var = max(float(cov[axis, axis]), 0.0)
        if prior_var <= 0.0 or not math.isfinite(var):
            continue
        gain = prior_var / (prior_var + var)
        out[axis] = gain * rpy[axis]
        cov[axis, :] *= gain
        cov[:, axis] *= gain
        cov[axis, axis] = gain * var
    return quat_from_rpy(*out), cov
