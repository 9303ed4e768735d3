"""A simulated run of an IMU-and-frames companion core (tests and benchmark).

Feeds a core the records train_localizer's SensorSimulator makes from the rig's
trajectory — ADIS16488-like accelerometer bias and noise, a slowly wandering attitude
error, pixel noise, UIDs only after a few frames, frames 40 ms late — and scores its
poses against the trajectory. No ROS here.
"""
import numpy as np

from train_localizer.core.simulation import (SensorErrors, SensorSimulator, event_stream,
                                             from_stamp_ns)
from vlc_stereo_camera.core.camera import StereoRig
from vlc_stereo_camera.core.lamp_map import straight_tunnel_map
from vlc_stereo_camera.core.trajectory import MotionProfile, Trajectory, Vibration

LAMPS = straight_tunnel_map()


def run_core(core, speed_kmh=60.0, t_end_s=8.0, seed=1, profile='constant',
             errors=None, observe=None, **motion):
    """Feed a simulated run to ``core``; returns (errors m (N,), stamps s (N,), results).

    The run starts at ``start_m`` (3 m) and follows ``profile`` at ``speed_kmh``;
    further keywords go to MotionProfile (``dwell_s``, ``cruise_s``, ...).

    ``observe(stamp_ns, observations, truth)`` may edit a frame's observations (forged
    lamps, dropped UIDs) before the core sees them.
    """
    traj = Trajectory(MotionProfile(profile, start_chainage_m=motion.pop('start_m', 3.0),
                                    speed_mps=speed_kmh / 3.6, **motion), Vibration(seed=seed))
    sim = SensorSimulator(traj, StereoRig(), LAMPS, errors or SensorErrors(),
                          np.random.default_rng(seed))
    errs, stamps, results = [], [], []
    for _, kind, payload in event_stream(sim, 0.0, t_end_s):
        if kind == 'imu':
            for est in core.add_imu(payload):
                t = from_stamp_ns(est.stamp_ns)
                errs.append(np.linalg.norm(est.position_m - traj.sample(t).position_m[0]))
                stamps.append(t)
            results += core.take_results()
        else:
            stamp, observations, truth = payload
            if observe is not None:
                observe(stamp, observations, truth)
            results += core.add_frame(stamp, observations)
    return np.asarray(errs), np.asarray(stamps), results
