"""Train motion along the track alignment and camera-platform vibration (paper eq. 21).

Times ``t_s`` are seconds since the simulation epoch. Everything is analytic in t (sums
of sinusoids, piecewise-constant acceleration, the alignment's closed-form geometry), so
the IMU model gets exact angular rate and specific force, and the renderer gets the pose
at any row's exposure instant.

Track geometry (:mod:`.alignment`; default the straight line along map x): at chainage
s(t) the centreline point P(s), heading ψ(s) and curvature κ(s). ``base_link`` is

    p = P(s) + Rz(ψ)·w,     R_map_base = Rz(ψ)·Rz(yaw_v)·Ry(pitch_v)·Rx(roll_v)

with w = (x_v, y_v, z_v) the vibration displacement in the track frame (along, left,
up). Differentiating with Ω = ψ̇·ẑ, ψ̇ = κ·v, Ω̇ = (κ'·v² + κ·a)·ẑ:

    ṗ = v·t + Ω × Rw + R·ẇ
    p̈ = a·t + κ·v²·n + Ω̇ × Rw + Ω × (Ω × Rw) + 2·Ω × Rẇ + R·ẅ

(t, n: track tangent and left normal), so the IMU sees the track's yaw rate κ·v and the
centripetal acceleration κ·v² toward the curve's centre. On a level alignment without
cant the centripetal acceleration appears in full on the platform's y axis, and the roll
is the vibration roll only. On the default straight every added term is an exact zero,
so the samples equal the straight-track model's to the bit.

Vertical profile and cant (alignments that are not :attr:`Alignment.is_level`): the
track frame is R_T(s) = Rz(ψ)·Ry(θ)·Rx(φ) with the grade pitch θ = −atan(dz/ds) and the
cant roll φ(s), and the centreline point P(s) = (x, y, z(s)) rises with the elevation::

    p = P(s) + R_T·w,          R_map_base = R_T·Rz(yaw_v)·Ry(pitch_v)·Rx(roll_v)
    ṗ = v·P' + R_T·(ẇ + ω×w)
    p̈ = a·P' + v²·P'' + R_T·(ẅ + 2ω×ẇ + ω̇×w + ω×(ω×w))

with ω, ω̇ the track frame's angular rate and acceleration in its own axes, from the
Euler rates ψ̇ = κ·v, θ̇ = θ'·v, φ̇ = φ'·v (second derivatives ·v² + ·a). The body rate is
R_vᵀ·ω + ω_v (ω_v: the vibration's own Euler-rate formula below). So ``base_link``'s
height follows z(s), its pitch includes the grade, its roll includes the cant, and the
specific force f = Rᵀ·(p̈ − g) carries gravity's components along the grade and across
the cant (on a canted curve the lateral force is κ·v²·cos φ + g·sin φ, i.e. the cant
deficiency only).

Vibration model (paper eq. 21: low-frequency sinusoids plus Gaussian track
irregularity), per axis k of (x, y, z, roll, pitch, yaw)::

    q_k(t) = g(v) · [c_k + Σ_i A_ki sin(2π f_ki t + φ_ki)]  +  I_k(s(t))
    I_k(s) = Σ_j B_kj sin(2π s / λ_j + ψ_kj)

The bracket is the car-body response, whose amplitude grows with speed up to
``full_amplitude_speed_mps`` (g(v) = min(1, v / v_full)) and vanishes at standstill; the
track irregularity I_k is a random-phase spectral sum over wavelengths λ_j — Gaussian by
the central limit theorem, smooth, and a function of chainage, so a standing train sees
a constant offset. Phases come from the seed. With the defaults the heading (yaw)
disturbance stays within −5.0…+7.5° (paper §4.2.2).

Any object with the same ``evaluate(t_s, s_m, v_mps, a_mps2) -> (q, q̇, q̈)`` can take
the vibration's place: :class:`~vlc_stereo_camera.core.car_body.CarBody` is the car body
of a metro car on its suspension, driven by a standard track irregularity.
"""
from dataclasses import dataclass, field

import numpy as np

from vlc_common.core.alignment import Alignment
from vlc_common.core.rotations import matrix_to_quat_xyzw, matrix_to_rpy, rpy_to_matrix

GRAVITY_MPS2 = 9.80665
AXES = ('x', 'y', 'z', 'roll', 'pitch', 'yaw')


@dataclass
class MotionProfile:
    """Chainage s(t), speed v(t), acceleration a(t) along the track.

    kind: ``stationary`` (at ``start_chainage_m``), ``constant`` (``speed_mps`` from
    ``start_chainage_m`` at t = 0), or ``accel_cruise_brake`` (stand for ``dwell_s``,
    accelerate at ``accel_mps2`` to ``speed_mps``, cruise ``cruise_s``, brake at
    ``brake_mps2`` to a stop, then stand).
    """

    kind: str = 'constant'
    start_chainage_m: float = 0.0
    speed_mps: float = 20.0 / 3.6
    accel_mps2: float = 1.0
    brake_mps2: float = 1.0
    dwell_s: float = 5.0
    cruise_s: float = 20.0

    def __post_init__(self):
        if self.kind not in ('stationary', 'constant', 'accel_cruise_brake'):
            raise ValueError(f'unknown motion profile {self.kind!r}: expected stationary, '
                             'constant or accel_cruise_brake')
        if self.speed_mps < 0.0 or self.accel_mps2 <= 0.0 or self.brake_mps2 <= 0.0:
            raise ValueError('speed_mps must be >= 0, accel_mps2 and brake_mps2 > 0')
        if self.dwell_s < 0.0 or self.cruise_s < 0.0:
            raise ValueError('dwell_s and cruise_s must be >= 0')

    def _segments(self):
        """(t_start, s_start, v_start, a) of each constant-acceleration segment."""
        s0, v = self.start_chainage_m, self.speed_mps
        if self.kind == 'stationary':
            return [(0.0, s0, 0.0, 0.0)]
        if self.kind == 'constant':
            return [(0.0, s0, v, 0.0)]
        t_acc, t_brk = v / self.accel_mps2, v / self.brake_mps2
        t1 = self.dwell_s
        t2 = t1 + t_acc
        t3 = t2 + self.cruise_s
        t4 = t3 + t_brk
        s2 = s0 + 0.5 * v * t_acc
        s3 = s2 + v * self.cruise_s
        s4 = s3 + 0.5 * v * t_brk
        return [(0.0, s0, 0.0, 0.0), (t1, s0, 0.0, self.accel_mps2), (t2, s2, v, 0.0),
                (t3, s3, v, -self.brake_mps2), (t4, s4, 0.0, 0.0)]

    def evaluate(self, t_s):
        """Chainage (m), speed (m/s) and acceleration (m/s²) at times ``t_s`` (N,)."""
        t = np.atleast_1d(np.asarray(t_s, dtype=float))
        seg = self._segments()
        starts = np.array([s[0] for s in seg])
        i = np.clip(np.searchsorted(starts, t, side='right') - 1, 0, len(seg) - 1)
        t0, s0, v0, a = (np.array([s[k] for s in seg])[i] for k in range(4))
        dt = t - t0
        return s0 + v0 * dt + 0.5 * a * dt * dt, v0 + a * dt, a

    def duration_s(self):
        """End of the last motion segment (0 for stationary and constant profiles)."""
        return self._segments()[-1][0]


def _default_sinusoids():
    # (amplitude, frequency Hz) per axis; translations in m, angles in degrees.
    return {
        'x': [(0.001, 0.5)],
        'y': [(0.003, 0.8), (0.0015, 1.7)],
        'z': [(0.002, 1.2), (0.001, 2.5)],
        'roll': [(0.3, 0.8), (0.15, 1.7)],
        'pitch': [(0.2, 0.6), (0.1, 1.9)],
        'yaw': [(3.9, 0.45), (1.7, 1.1), (0.45, 2.3)],
    }


@dataclass
class VibrationConfig:
    """Amplitudes of eq. 21. Translations in metres, angles in degrees.

    ``offsets`` c_k are added to the sinusoid sums (yaw centre 1.25° makes the default
    heading disturbance span −5.0…+7.5°); ``irregularity_max`` bounds each axis's track
    irregularity (the sum of its spectral amplitudes), spread over
    ``irregularity_wavelengths_m``.
    """

    enabled: bool = True
    scale: float = 1.0
    full_amplitude_speed_mps: float = 20.0 / 3.6
    sinusoids: dict = field(default_factory=_default_sinusoids)
    offsets: dict = field(default_factory=lambda: {'yaw': 1.25})
    irregularity_max: dict = field(default_factory=lambda: {
        'y': 0.002, 'z': 0.002, 'roll': 0.05, 'pitch': 0.05, 'yaw': 0.2})
    irregularity_wavelengths_m: tuple = tuple(np.geomspace(2.0, 40.0, 24))

    def __post_init__(self):
        if self.scale < 0.0 or self.full_amplitude_speed_mps <= 0.0:
            raise ValueError('vibration scale must be >= 0 and full_amplitude_speed_mps > 0')


class Vibration:
    """Seeded realisation of the eq. 21 vibration; see the module docstring."""

    def __init__(self, config=None, seed=0):
        self.config = config or VibrationConfig()
        rng = np.random.default_rng(seed)
        cfg = self.config
        lam = np.asarray(cfg.irregularity_wavelengths_m, dtype=float)
        self._terms = {}
        for k in AXES:
            unit = 1.0 if k in ('x', 'y', 'z') else np.pi / 180.0
            sin = np.array(cfg.sinusoids.get(k, []), dtype=float).reshape(-1, 2)
            amp = sin[:, 0] * unit * cfg.scale
            omega = 2.0 * np.pi * sin[:, 1]
            phase = rng.uniform(0.0, 2.0 * np.pi, len(sin))
            # Track irregularity: amplitude ∝ wavelength (long waves dominate, as in
            # measured track spectra), normalised so the axis never exceeds its bound.
            b = lam / lam.sum() * cfg.irregularity_max.get(k, 0.0) * unit * cfg.scale
            psi = rng.uniform(0.0, 2.0 * np.pi, len(lam))
            self._terms[k] = (amp, omega, phase, cfg.offsets.get(k, 0.0) * unit * cfg.scale,
                              b, 2.0 * np.pi / lam, psi)

    def evaluate(self, t_s, s_m, v_mps, a_mps2):
        """Vibration of all six axes with first and second time derivatives.

        Returns three (N, 6) arrays q, q̇, q̈ in axis order x, y, z (m), roll, pitch, yaw
        (rad).
        """
        t = np.atleast_1d(np.asarray(t_s, dtype=float))
        n = t.shape[0]
        q, qd, qdd = (np.zeros((n, 6)) for _ in range(3))
        if not self.config.enabled:
            return q, qd, qdd
        v_full = self.config.full_amplitude_speed_mps
        g = np.minimum(1.0, np.abs(v_mps) / v_full)
        gd = np.where(np.abs(v_mps) < v_full, np.sign(v_mps) * a_mps2 / v_full, 0.0)
        for j, k in enumerate(AXES):
            amp, omega, phase, offset, b, kappa, psi = self._terms[k]
            arg = np.outer(t, omega) + phase
            body = offset + np.sin(arg) @ amp
            body_d = np.cos(arg) @ (amp * omega)
            body_dd = -np.sin(arg) @ (amp * omega ** 2)
            sarg = np.outer(s_m, kappa) + psi
            irr = np.sin(sarg) @ b
            irr_s = np.cos(sarg) @ (b * kappa)
            irr_ss = -np.sin(sarg) @ (b * kappa ** 2)
            q[:, j] = g * body + irr
            # d/dt[g·body] = ġ·body + g·ḃody with ġ = g'(v)·a; g'' = 0 and ȧ = 0 inside
            # the piecewise-constant-acceleration segments.
            qd[:, j] = gd * body + g * body_d + irr_s * v_mps
            qdd[:, j] = 2.0 * gd * body_d + g * body_dd + irr_ss * v_mps ** 2 + irr_s * a_mps2
        return q, qd, qdd


@dataclass
class TrajectorySample:
    """Ground truth of ``base_link`` at N instants (map frame unless stated).

    ``chainage_m`` is the train's chainage s (without the along-track vibration),
    ``rpy_rad`` the attitude in map (yaw = track heading + vibration yaw),
    ``track_heading_rad`` ψ(s) and ``track_curvature_1pm`` κ(s) of the alignment there;
    ``track_elevation_m`` z(s) (m), ``track_grade`` dz/ds and ``track_cant_rad`` φ(s)
    (rad, REP-103 roll of the track plane), all zero on a level alignment.
    """

    t_s: np.ndarray
    chainage_m: np.ndarray
    speed_mps: np.ndarray
    position_m: np.ndarray
    velocity_mps: np.ndarray
    acceleration_mps2: np.ndarray
    rpy_rad: np.ndarray
    R_map_base: np.ndarray
    angular_velocity_body_rps: np.ndarray
    specific_force_body_mps2: np.ndarray
    track_heading_rad: np.ndarray = None
    track_curvature_1pm: np.ndarray = None
    track_elevation_m: np.ndarray = None
    track_grade: np.ndarray = None
    track_cant_rad: np.ndarray = None

    @property
    def quat_xyzw(self):
        return matrix_to_quat_xyzw(self.R_map_base)


class Trajectory:
    """Motion profile plus vibration along an alignment: ``base_link`` in ``map`` over time.

    ``alignment`` defaults to the straight line along map x (chainage = map x).
    """

    def __init__(self, profile=None, vibration=None, alignment=None):
        self.profile = profile or MotionProfile()
        self.vibration = vibration or Vibration()
        self.alignment = alignment or Alignment.straight()

    def sample(self, t_s):
        """Evaluate the ground truth at times ``t_s`` (scalar or (N,)); see TrajectorySample."""
        t = np.atleast_1d(np.asarray(t_s, dtype=float))
        s, v, a = self.profile.evaluate(t)
        q, qd, qdd = self.vibration.evaluate(t, s, v, a)
        zeros = np.zeros_like(t)
        track = self.alignment.evaluate(s + zeros)
        if not self.alignment.is_level:
            return _sample_3d(t, s + zeros, v + zeros, a + zeros, q, qd, qdd, track)
        c, sn = np.cos(track.heading_rad), np.sin(track.heading_rad)
        kappa = track.curvature_1pm
        yaw_rate = kappa * v                                     # ψ̇
        yaw_accel = track.curvature_rate_1pm2 * v * v + kappa * a   # ψ̈

        def to_map(w):
            """Track-frame (along, left) components → map x, y."""
            return c * w[:, 0] - sn * w[:, 1], sn * w[:, 0] + c * w[:, 1]

        def cross_z(rate, wx, wy):
            """(rate·ẑ) × (wx, wy, ·): the in-plane components."""
            return -rate * wy, rate * wx

        rw_x, rw_y = to_map(q)              # R·w
        rwd_x, rwd_y = to_map(qd)           # R·ẇ
        rwdd_x, rwdd_y = to_map(qdd)        # R·ẅ
        om_x, om_y = cross_z(yaw_rate, rw_x, rw_y)                  # Ω × Rw
        al_x, al_y = cross_z(yaw_accel, rw_x, rw_y)                 # Ω̇ × Rw
        cen_x, cen_y = cross_z(yaw_rate, om_x, om_y)                # Ω × (Ω × Rw)
        cor_x, cor_y = cross_z(2.0 * yaw_rate, rwd_x, rwd_y)        # 2Ω × Rẇ
        v_curve = kappa * v * v                                     # κv² along n
        position = np.stack([track.x_m + rw_x, track.y_m + rw_y, q[:, 2]], axis=1)
        velocity = np.stack([v * c + om_x + rwd_x, v * sn + om_y + rwd_y, qd[:, 2]], axis=1)
        accel = np.stack([a * c - v_curve * sn + al_x + cen_x + cor_x + rwdd_x,
                          a * sn + v_curve * c + al_y + cen_y + cor_y + rwdd_y,
                          qdd[:, 2]], axis=1)
        roll, pitch, yaw = q[:, 3], q[:, 4], track.heading_rad + q[:, 5]
        droll, dpitch, dyaw = qd[:, 3], qd[:, 4], qd[:, 5] + yaw_rate
        R = rpy_to_matrix(roll, pitch, yaw)
        # Body angular rate from ZYX Euler rates (the track heading adds to the yaw).
        omega = np.stack([
            droll - dyaw * np.sin(pitch),
            dpitch * np.cos(roll) + dyaw * np.sin(roll) * np.cos(pitch),
            -dpitch * np.sin(roll) + dyaw * np.cos(roll) * np.cos(pitch)], axis=1)
        gravity = np.array([0.0, 0.0, -GRAVITY_MPS2])
        f_body = np.einsum('nji,nj->ni', R, accel - gravity)
        return TrajectorySample(t_s=t, chainage_m=s + zeros, speed_mps=v + zeros,
                                position_m=position, velocity_mps=velocity,
                                acceleration_mps2=accel,
                                rpy_rad=np.stack([roll, pitch, yaw], axis=1), R_map_base=R,
                                angular_velocity_body_rps=omega,
                                specific_force_body_mps2=f_body,
                                track_heading_rad=track.heading_rad,
                                track_curvature_1pm=kappa,
                                track_elevation_m=track.elevation_m,
                                track_grade=track.grade, track_cant_rad=track.cant_rad)


def _euler_body_rate(roll, pitch, droll, dpitch, dyaw):
    """Body angular rate (N, 3) of ZYX Euler angles from their rates."""
    return np.stack([
        droll - dyaw * np.sin(pitch),
        dpitch * np.cos(roll) + dyaw * np.sin(roll) * np.cos(pitch),
        -dpitch * np.sin(roll) + dyaw * np.cos(roll) * np.cos(pitch)], axis=1)


def _track_frame_rates(track, v, a):
    """Track-frame attitude (φ, θ), its body rate ω and rate derivative ω̇, (N, 3) each.

    ZYX Euler angles of R_T = Rz(ψ)·Ry(θ)·Rx(φ) with θ = −atan(G), φ = cant roll; their
    time derivatives from the chainage derivatives by the chain rule (ṡ = v, s̈ = a).
    """
    grade, grade_s = track.grade, track.grade_rate_1pm
    one_g2 = 1.0 + grade * grade
    theta = -np.arctan(grade)
    theta_s = -grade_s / one_g2
    theta_ss = 2.0 * grade * grade_s * grade_s / (one_g2 * one_g2)   # G'' = 0 piecewise
    phi, phi_s, phi_ss = track.cant_rad, track.cant_rate_radpm, track.cant_rate2_radpm2
    psi_s, psi_ss = track.curvature_1pm, track.curvature_rate_1pm2
    v2 = v * v
    dphi, dtheta, dpsi = phi_s * v, theta_s * v, psi_s * v
    ddphi = phi_ss * v2 + phi_s * a
    ddtheta = theta_ss * v2 + theta_s * a
    ddpsi = psi_ss * v2 + psi_s * a
    sp, cp, st, ct = np.sin(phi), np.cos(phi), np.sin(theta), np.cos(theta)
    omega = _euler_body_rate(phi, theta, dphi, dtheta, dpsi)
    omega_dot = np.stack([
        ddphi - ddpsi * st - dpsi * dtheta * ct,
        ddtheta * cp - dtheta * dphi * sp + ddpsi * sp * ct + dpsi * dphi * cp * ct
        - dpsi * dtheta * sp * st,
        -ddtheta * sp - dtheta * dphi * cp + ddpsi * cp * ct - dpsi * dphi * sp * ct
        - dpsi * dtheta * cp * st], axis=1)
    return phi, theta, omega, omega_dot


def _sample_3d(t, s, v, a, q, qd, qdd, track):
    """Trajectory sample on an alignment with grade and cant (module docstring)."""
    phi, theta, omega, omega_dot = _track_frame_rates(track, v, a)
    psi = track.heading_rad
    R_T = rpy_to_matrix(phi, theta, psi)
    c, sn = np.cos(psi), np.sin(psi)
    kappa = track.curvature_1pm
    d1 = np.stack([c, sn, track.grade], axis=1)                         # dP/ds
    d2 = np.stack([-kappa * sn, kappa * c, track.grade_rate_1pm], axis=1)  # d²P/ds²
    w, wd, wdd = q[:, 0:3], qd[:, 0:3], qdd[:, 0:3]
    om_w = np.cross(omega, w)
    rel_v = wd + om_w
    rel_a = wdd + 2.0 * np.cross(omega, wd) + np.cross(omega_dot, w) + np.cross(omega, om_w)
    position = np.stack([track.x_m, track.y_m, track.elevation_m], axis=1) \
        + np.einsum('nij,nj->ni', R_T, w)
    velocity = v[:, None] * d1 + np.einsum('nij,nj->ni', R_T, rel_v)
    accel = a[:, None] * d1 + (v * v)[:, None] * d2 + np.einsum('nij,nj->ni', R_T, rel_a)
    roll_v, pitch_v, yaw_v = q[:, 3], q[:, 4], q[:, 5]
    R_v = rpy_to_matrix(roll_v, pitch_v, yaw_v)
    R = R_T @ R_v
    omega_body = np.einsum('nji,nj->ni', R_v, omega) \
        + _euler_body_rate(roll_v, pitch_v, qd[:, 3], qd[:, 4], qd[:, 5])
    gravity = np.array([0.0, 0.0, -GRAVITY_MPS2])
    f_body = np.einsum('nji,nj->ni', R, accel - gravity)
    rpy = matrix_to_rpy(R)
    # Keep the yaw continuous with the track heading (no wrap at ±π).
    rpy[:, 2] = psi + np.angle(np.exp(1j * (rpy[:, 2] - psi)))
    return TrajectorySample(t_s=t, chainage_m=s, speed_mps=v, position_m=position,
                            velocity_mps=velocity, acceleration_mps2=accel, rpy_rad=rpy,
                            R_map_base=R, angular_velocity_body_rps=omega_body,
                            specific_force_body_mps2=f_body, track_heading_rad=psi,
                            track_curvature_1pm=kappa, track_elevation_m=track.elevation_m,
                            track_grade=track.grade, track_cant_rad=phi)
