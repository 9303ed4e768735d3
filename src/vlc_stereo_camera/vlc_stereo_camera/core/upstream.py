"""Synthetic lamp observations and IMU samples from the rig's own truth models.

Feeds the localizer core exactly what the upstream nodes would, without images: the
rig's :class:`~vlc_stereo_camera.core.trajectory.Trajectory` gives the pose of
``base_link`` at any instant, its :class:`~vlc_common.core.camera.StereoRig`
projects each lamp into both cameras at the exposure mid-time of the row the spot
falls on (rolling shutter), and an error model adds what the spot locator, the decoder
and the IMU compensator leave behind:

* spot centres: independent Gaussian noise of ``pixel_sigma_px`` per coordinate;
* UIDs: confirmed only after a lamp has been seen in ``confirm_after_frames`` frames
  (the decoder assembles a packet from several frames), ``None`` before;
* attitude (``imu/data`` orientation): the truth times a small rotation whose angles
  are first-order Gauss–Markov processes (σ, correlation time) — slowly varying,
  like a compensator's residual;
* specific force: the truth plus a constant turn-on bias and white noise (ADIS16488).

Used by the tests (against analytic truth) and by the benchmarks: :func:`feed_localizer`
drives the localizer, :func:`run_core` an IMU-and-frames companion core.
"""
from dataclasses import dataclass, replace
import math

import numpy as np

from vlc_common.core.camera import StereoRig
from vlc_common.core.lamp_map import straight_tunnel_map
from vlc_common.core.observation import NS_PER_S, ImuSample, LampObservation
from vlc_common.core.rotations import quat_from_rpy, quat_multiply
from vlc_stereo_camera.core.trajectory import MotionProfile, Trajectory, Vibration

_DEG = math.pi / 180.0
EPOCH_NS = 1_704_067_200 * NS_PER_S


@dataclass
class SensorErrors:
    """Error model of the simulated upstream nodes (SI units, radians).

    Attributes
    ----------
    pixel_sigma_px : float
        1σ of every spot-centre coordinate, px.
    confirm_after_frames : int
        Frames a lamp must have been seen before its UID is reported.
    attitude_sigma_rad : tuple of 3 floats
        Stationary 1σ of the roll, pitch and yaw error of ``imu/data``, rad.
    attitude_corr_time_s : float
        Correlation time of those errors, s.
    attitude_cov_reported : bool
        Whether ``imu/data`` carries the attitude covariance (σ² on the diagonal).
    accel_bias_sigma_mps2 : float
        1σ of the constant specific-force bias per axis, m/s² (ADIS16488: 16 mg).
    accel_noise_density_mps2_rthz : float
        Specific-force white noise density, m/s²/√Hz (ADIS16488: ≈ 5e-4).
    """

    pixel_sigma_px: float = 0.05
    confirm_after_frames: int = 5
    attitude_sigma_rad: tuple = (0.03 * _DEG, 0.03 * _DEG, 0.1 * _DEG)
    attitude_corr_time_s: float = 5.0
    attitude_cov_reported: bool = True
    accel_bias_sigma_mps2: float = 0.16
    accel_noise_density_mps2_rthz: float = 5e-4


@dataclass
class SimTiming:
    """Sensor rates and the delays with which their data reach the localizer.

    Attributes
    ----------
    imu_rate_hz, frame_rate_hz : float
    frame_delay_s : float
        From a frame's stamp (row 0) to its lamp records reaching the localizer, s
        (readout of 720 rows is 21.6 ms, plus decoding and spot location).
    imu_delay_s : float
        From an IMU sample's stamp to ``imu/data`` reaching the localizer, s.
    """

    imu_rate_hz: float = 400.0
    frame_rate_hz: float = 30.0
    frame_delay_s: float = 0.040
    imu_delay_s: float = 0.002


class SensorSimulator:
    """Generates :class:`ImuSample` and :class:`LampObservation` records of one run.

    Parameters
    ----------
    trajectory : vlc_stereo_camera.core.trajectory.Trajectory
    rig : vlc_common.core.camera.StereoRig
    lamp_map : vlc_common.core.lamp_map.LampMap
    errors : SensorErrors
    rng : numpy.random.Generator
    row_time_s, exposure_s : float
        Rolling-shutter timing of the rig.
    """

    def __init__(self, trajectory, rig, lamp_map, errors=None, rng=None, row_time_s=30e-6,
                 exposure_s=50e-6):
        self.trajectory = trajectory
        self.rig = rig
        self.lamp_map = lamp_map
        self.errors = errors or SensorErrors()
        self.rng = rng or np.random.default_rng(0)
        self.row_time_s = row_time_s
        self.exposure_s = exposure_s
        self.accel_bias = self.rng.normal(0.0, self.errors.accel_bias_sigma_mps2, 3)
        self._att_err = self.rng.normal(0.0, 1.0, 3) * np.asarray(self.errors.attitude_sigma_rad)
        self._att_t = None
        self._seen = {}

    # ------------------------------------------------------------------ IMU
    def imu_samples(self, t_s):
        """``imu/data`` samples at increasing times ``t_s`` (N,), seconds since epoch."""
        t_s = np.atleast_1d(np.asarray(t_s, dtype=float))
        truth = self.trajectory.sample(t_s)
        e = self.errors
        sigma = np.asarray(e.attitude_sigma_rad)
        rate = 1.0 / np.median(np.diff(t_s)) if t_s.size > 1 else 400.0
        noise = self.rng.normal(0.0, e.accel_noise_density_mps2_rthz * math.sqrt(rate),
                                (t_s.size, 3))
        err = np.empty((t_s.size, 3))
        for k, t in enumerate(t_s):
            if self._att_t is not None:
                phi = math.exp(-(t - self._att_t) / e.attitude_corr_time_s)
                self._att_err = (phi * self._att_err + math.sqrt(1.0 - phi * phi) * sigma
                                 * self.rng.normal(0.0, 1.0, 3))
            self._att_t = t
            err[k] = self._att_err
        # The estimate is the truth turned by a small rotation about the map axes.
        q_est = quat_multiply(quat_from_rpy(err[:, 0], err[:, 1], err[:, 2]),
                              quat_from_rpy(*truth.rpy_rad.T))
        accel = truth.specific_force_body_mps2 + self.accel_bias + noise
        cov = np.diag(sigma ** 2) if e.attitude_cov_reported else None
        out = [ImuSample(stamp_ns=to_stamp_ns(t), accel_mps2=accel[k],
                         gyro_rps=truth.angular_velocity_body_rps[k], quat_xyzw=q_est[k],
                         attitude_cov_rad2=cov)
               for k, t in enumerate(t_s)]
        return out

    # ------------------------------------------------------------------ camera
    def frame(self, t0_s, noise=True):
        """Lamp observations of the frame whose row 0 starts exposing at ``t0_s``.

        Returns
        -------
        stamp_ns : int
        observations : list of LampObservation
        truth : list of dict
            Per observation: ``uid`` (true lamp), ``t_s`` (exposure mid-time of its
            row), ``uv_left``, ``uv_right`` (noise-free), ``p_cam`` (true, left optical
            frame), ``base_position_m``, ``R_map_base``.
        """
        k = self.rig.intrinsics
        s_now = float(self.trajectory.sample(t0_s).chainage_m[0])
        cam_x = s_now + self.rig.cam_positions_base()[0][0]
        lamps = self.lamp_map.near_chainage(cam_x, 15.0, 2.0)
        observations, truth = [], []
        if not lamps:
            return to_stamp_ns(t0_s), observations, truth
        points = np.array([lamp.position_m for lamp in lamps])
        t = np.full(len(lamps), t0_s + 0.5 * self.exposure_s + k.cy * self.row_time_s)
        for iteration in range(4):
            # The row the spot falls on sets its exposure time, which moves the spot:
            # a fixed point, converged to well under a microsecond in three rounds.
            sample = self.trajectory.sample(t)
            uv_l, uv_r, z = self.rig.project(points, sample.position_m, sample.R_map_base)
            if iteration < 3:
                t = t0_s + 0.5 * self.exposure_s + np.clip(
                    np.nan_to_num(uv_l[:, 1]), 0.0, k.height) * self.row_time_s
        p_cam = self.rig.to_camera(points, sample.position_m, sample.R_map_base, 0)
        sig = self.errors.pixel_sigma_px
        for i, lamp in enumerate(lamps):
            if not z[i] > 0.1:
                continue
            radius_px = k.fx * 0.5 * lamp.diameter_m / z[i]
            if not (_inside(uv_l[i], radius_px, k) and _inside(uv_r[i], radius_px, k)):
                continue
            self._seen[lamp.uid] = self._seen.get(lamp.uid, 0) + 1
            uid = lamp.uid if self._seen[lamp.uid] > self.errors.confirm_after_frames else None
            n = self.rng.normal(0.0, sig, 4) if noise else np.zeros(4)
            observations.append(LampObservation(
                stamp_ns=to_stamp_ns(t0_s), uid=uid, uv_left=uv_l[i] + n[:2],
                uv_right=uv_r[i] + n[2:], sigma_u_px=sig, sigma_v_px=sig))
            truth.append({'uid': lamp.uid, 't_s': float(t[i]), 'uv_left': uv_l[i],
                          'uv_right': uv_r[i], 'p_cam': p_cam[i],
                          'base_position_m': sample.position_m[i],
                          'R_map_base': sample.R_map_base[i]})
        return to_stamp_ns(t0_s), observations, truth


def _inside(uv, radius_px, k):
    return (radius_px <= uv[0] <= k.width - 1 - radius_px
            and radius_px <= uv[1] <= k.height - 1 - radius_px)


def to_stamp_ns(t_s):
    """Simulation seconds since the epoch → ROS stamp, ns (exact on a µs grid)."""
    return EPOCH_NS + int(round(float(t_s) * 1e6)) * 1000


def from_stamp_ns(stamp_ns):
    """ROS stamp (ns) → simulation seconds since the epoch."""
    return (int(stamp_ns) - EPOCH_NS) * 1e-9


def event_stream(simulator, t_start_s, t_end_s, timing=None):
    """Time-ordered ``(arrival_s, kind, payload)`` of one run.

    ``kind`` is ``'imu'`` (payload: ImuSample) or ``'frame'`` (payload: (stamp_ns,
    observations, truth)); events are ordered by their arrival at the localizer, so
    frames arrive ``frame_delay_s`` after their stamp, behind the IMU.
    """
    timing = timing or SimTiming()
    n_imu = int(math.floor((t_end_s - t_start_s) * timing.imu_rate_hz)) + 1
    imu_t = t_start_s + np.arange(n_imu) / timing.imu_rate_hz
    events = [(t + timing.imu_delay_s, 0, s) for t, s in zip(imu_t, simulator.imu_samples(imu_t))]
    n_frames = int(math.floor((t_end_s - t_start_s) * timing.frame_rate_hz)) + 1
    for i in range(n_frames):
        t0 = t_start_s + i / timing.frame_rate_hz
        events.append((t0 + timing.frame_delay_s, 1, simulator.frame(t0)))
    events.sort(key=lambda e: (e[0], e[1]))
    return [(t, 'imu' if kind == 0 else 'frame', payload) for t, kind, payload in events]


def feed_localizer(localizer, events, frame_hook=None, on_report=None):
    """Feed ``events`` (:func:`event_stream`) to ``localizer`` in their order.

    ``frame_hook(stamp_ns, observations, truth)`` returns the observations a frame passes
    on (a lamp outage, forged lamps); ``on_report(kind, payload, report)`` runs after each
    event (an aid fed from the IMU or the poses). Returns (poses, fixes, events) of every
    step report.
    """
    poses, fixes, logs = [], [], []
    for _, kind, payload in events:
        if kind == 'imu':
            report = localizer.add_imu(payload)
        else:
            stamp, observations, truth = payload
            if frame_hook is not None:
                observations = frame_hook(stamp, observations, truth)
            report = localizer.add_frame(stamp, observations)
        if on_report is not None:
            on_report(kind, payload, report)
        poses += report.poses
        fixes += report.fixes
        logs += report.events
    return poses, fixes, logs


def along_track_errors(trajectory, poses, after_s=0.0):
    """(chainage − truth, published 1σ), m, of the poses stamped after ``after_s``."""
    poses = [p for p in poses if from_stamp_ns(p.stamp_ns) > after_s]
    truth = trajectory.sample(np.array([from_stamp_ns(p.stamp_ns) for p in poses])).position_m
    return (np.array([p.chainage_m for p in poses]) - truth[:, 0],
            np.sqrt([p.chainage_var_m2 for p in poses]))


def disparity_error_hook(error_px):
    """A ``frame_hook`` for :func:`feed_localizer` that makes every disparity ``error_px(u)``
    px too large (``u`` the left centre's column): the right centre moved left by it.
    """
    def hook(stamp, observations, truth):
        return [replace(o, uv_right=(o.uv_right[0] - error_px(o.uv_left[0]), o.uv_right[1]))
                for o in observations]
    return hook


def dark_lamps(lamp_map, dark_m):
    """A ``frame_hook`` for :func:`feed_localizer`: the lamps whose track chainage lies in
    ``dark_m`` = (from, to) are dark, their observations dropped.
    """
    lo, hi = dark_m

    def hook(stamp_ns, observations, truth):
        return [o for o, tr in zip(observations, truth)
                if not lo <= lamp_map.by_uid(tr['uid']).track_chainage_m < hi]
    return hook


LAMPS = straight_tunnel_map()


def constant_speed_run(speed_kmh, t_end_s, seed, start_chainage_m=0.0, errors=None):
    """(trajectory, events) of a run at constant speed on the straight map from
    ``start_chainage_m``, with the default error model: what :func:`event_stream` yields
    over ``[0, t_end_s]``.
    """
    traj = Trajectory(MotionProfile('constant', start_chainage_m=start_chainage_m,
                                    speed_mps=speed_kmh / 3.6), Vibration(seed=seed))
    sim = SensorSimulator(traj, StereoRig(), LAMPS, errors or SensorErrors(),
                          np.random.default_rng(seed))
    return traj, event_stream(sim, 0.0, t_end_s)


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


def yaw_rate_on_alignment(alignment, start_m, distance_m, speed_mps, rate_hz=100.0, seed=0,
                          bias_rps=0.0, noise_rps=0.0, vibration_deg=0.0, vibration_hz=0.45):
    """(t s, yaw rate rad/s, true chainage m) of a train at constant speed on
    ``alignment``: κ(s)·v plus a gyro bias, seeded white noise and a bounded heading
    oscillation ``A sin(2π f t)``.
    """
    rng = np.random.default_rng(seed)
    t = np.arange(0.0, distance_m / speed_mps, 1.0 / rate_hz)
    s = start_m + speed_mps * t
    w = alignment.evaluate(s).curvature_1pm * speed_mps + bias_rps
    w = w + rng.normal(0.0, noise_rps, t.size)
    w = w + math.radians(vibration_deg) * 2 * math.pi * vibration_hz * np.cos(
        2 * math.pi * vibration_hz * t)
    return t, w, s
