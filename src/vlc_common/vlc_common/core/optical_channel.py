"""The line-of-sight optical channel from a lamp to a photodiode, and the photodiode's noise.

Shared by the rig's photodiode (which draws samples through it) and the RSSI receiver
(which inverts it): one model, with the parameters each side is given.

A photodiode (PD) rides the vibrating platform beside the stereo camera and receives the
wall lamps through the line-of-sight Lambertian channel (Komine & Nakagawa 2004; the
RSSI trilateration paper of Zhang, Xu, Ma, Zhu uses the same model)::

    H(0) = (m + 1)·A / (2π·d²) · cos^m φ · Ts · g(ψ) · cos ψ     for 0 ≤ ψ ≤ Ψc
    H(0) = 0                                                      for ψ > Ψc
    g(ψ) = n² / sin² Ψc                                          (optical concentrator)

``d`` lamp–PD distance, ``φ`` irradiance angle (lamp disc normal to the PD), ``ψ``
incidence angle (PD normal to the lamp), ``A`` PD area, ``Ts`` optical filter gain,
``n`` concentrator refractive index, ``Ψc`` field of view (half angle). The lamp order
is the generalized Lambertian ``m = −ln 2 / ln cos Φ½`` with Φ½ the semi-angle at half
power; the lamps' 60° semi-angle gives m = 1 — the same reading of "60°" as the
camera's photometric chain (``sensor_noise.lambertian_order``). A lamp is a point
source at its disc centre: the PD is ≥ 2.2 m from a 0.1 m-radius disc.

Received power ``P_r = P_t·H(0)`` with ``P_t`` the lamp's optical power when "on"
(2100 lm at 300 lm/W, the camera chain's lamp: 7 W), times a per-lamp factor
``1 + ε``, ε ~ N(0, ``lamp_power_sigma_rel``) fixed per lamp (flux tolerance and ageing:
the receiver does not know it). Lamps are separable by their codes: the PD correlates
its photocurrent with each lamp's known chip sequence over one sample window and
estimates each lamp's received "on" power (ideal orthogonal codes: no cross-talk).

Noise of one per-lamp estimate (Komine & Nakagawa eq. 5–7), photocurrent variance in
the estimator's noise bandwidth ``B`` (half the sample rate: one window averages
``2·B_front·T`` front-end samples, which leaves white noise of bandwidth 1/(2T))::

    σ²_shot    = 2q·R·P_total·B + 2q·I_bg·I2·B
    σ²_thermal = 8π·k·T_K/G · η·A·I2·B² + 16π²·k·T_K·Γ/g_m · η²·A²·I3·B³

``P_total`` is the power of every lamp received (shot noise of the whole photocurrent),
``I_bg`` the background (tunnel lighting) current. The published estimate is
``P̂ = P_r + n/R``, n ~ N(0, σ²_shot + σ²_thermal), with its σ and SNR.

No ROS here. Frames: REP-103 ``map`` and ``base_link``; the PD mount and normal are
given in ``base_link``.
"""

from dataclasses import dataclass
import math

import numpy as np


def lambertian_order(half_power_angle_deg):
    """Generalized Lambertian order m = −ln 2 / ln cos θ½ (60° → 1)."""
    c = np.cos(np.radians(half_power_angle_deg))
    if not 0.0 < c < 1.0:
        raise ValueError(f'half-power angle {half_power_angle_deg} deg must be in (0, 90)')
    return -np.log(2.0) / np.log(c)



ELECTRON_CHARGE_C = 1.602176634e-19
BOLTZMANN_J_PER_K = 1.380649e-23
@dataclass
class PhotodiodeConfig:
    """Photodiode geometry, optics, lamps and noise (SI units unless named).

    Attributes
    ----------
    mount_xyz_m : tuple of 3 floats
        PD position in ``base_link``, m (default: beside the left camera).
    azimuth_deg : float
        PD normal turned from ``base_link`` +y (toward the left wall) to +x (forward), deg.
    elevation_deg : float
        PD normal above the horizontal, deg (−41.4°: aimed at the nearest point of the
        lamp line, 1.7 m left and 1.5 m below the default mount).
    fov_half_angle_deg : float
        Receiver field of view Ψc (half angle), deg.
    area_m2 : float
        Detector area A, m².
    filter_transmission : float
        Optical filter gain Ts.
    refractive_index : float
        Concentrator refractive index n; gain g = n² / sin² Ψc.
    responsivity_a_per_w : float
        Photodiode responsivity R, A/W.
    lamp_optical_power_w : float
        Optical power P_t of a lamp when "on", W.
    lamp_half_power_angle_deg : float
        Lamp semi-angle at half power Φ½, deg (m = −ln 2 / ln cos Φ½).
    lamp_power_sigma_rel : float
        1σ relative deviation of each lamp's actual power from ``lamp_optical_power_w``
        (fixed per lamp, unknown to the receiver).
    noise_bandwidth_hz : float
        Noise bandwidth B of one per-lamp power estimate, Hz.
    background_current_a : float
        Background photocurrent I_bg (tunnel lighting), A.
    temperature_k : float
        Absolute temperature T_K, K.
    open_loop_gain : float
        Pre-amplifier open-loop voltage gain G.
    fet_transconductance_s : float
        FET transconductance g_m, S.
    fet_noise_factor : float
        FET channel noise factor Γ.
    capacitance_per_area_f_m2 : float
        Fixed capacitance of the PD per unit area η, F/m² (112 pF/cm²).
    noise_factor_i2, noise_factor_i3 : float
        Noise bandwidth factors I2, I3 (Komine & Nakagawa).
    min_snr_db : float
        Lamps whose estimate has a lower SNR are not reported, dB.
    """

    mount_xyz_m: tuple = (0.0, 0.8, 2.9)
    azimuth_deg: float = 0.0
    elevation_deg: float = -41.4
    fov_half_angle_deg: float = 80.0
    area_m2: float = 1.0e-4
    filter_transmission: float = 1.0
    refractive_index: float = 1.5
    responsivity_a_per_w: float = 0.54
    lamp_optical_power_w: float = 7.0
    lamp_half_power_angle_deg: float = 60.0
    lamp_power_sigma_rel: float = 0.02
    noise_bandwidth_hz: float = 25.0
    background_current_a: float = 10.0e-6
    temperature_k: float = 295.0
    open_loop_gain: float = 10.0
    fet_transconductance_s: float = 0.030
    fet_noise_factor: float = 1.5
    capacitance_per_area_f_m2: float = 1.12e-6
    noise_factor_i2: float = 0.562
    noise_factor_i3: float = 0.0868
    min_snr_db: float = 10.0

    def __post_init__(self):
        self.mount_xyz_m = tuple(float(v) for v in self.mount_xyz_m)
        if len(self.mount_xyz_m) != 3 or not all(map(math.isfinite, self.mount_xyz_m)):
            raise ValueError('mount_xyz_m must be 3 finite numbers')
        if not 0.0 < self.fov_half_angle_deg < 90.0:
            raise ValueError('fov_half_angle_deg must be in (0, 90)')
        for name in ('area_m2', 'filter_transmission', 'refractive_index',
                     'responsivity_a_per_w', 'lamp_optical_power_w', 'noise_bandwidth_hz',
                     'temperature_k', 'open_loop_gain', 'fet_transconductance_s',
                     'capacitance_per_area_f_m2'):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0.0):
                raise ValueError(f'{name} must be finite and > 0, got {value}')
        for name in ('lamp_power_sigma_rel', 'background_current_a', 'fet_noise_factor',
                     'noise_factor_i2', 'noise_factor_i3'):
            value = getattr(self, name)
            if not (math.isfinite(value) and value >= 0.0):
                raise ValueError(f'{name} must be finite and >= 0, got {value}')
        self.order_m = float(lambertian_order(self.lamp_half_power_angle_deg))

    @property
    def concentrator_gain(self):
        """G = n² / sin² Ψc (ideal non-imaging concentrator)."""
        return self.refractive_index ** 2 / math.sin(math.radians(self.fov_half_angle_deg)) ** 2

    @property
    def normal_base(self):
        """Unit PD normal in ``base_link`` (3,)."""
        az, el = math.radians(self.azimuth_deg), math.radians(self.elevation_deg)
        return np.array([math.cos(el) * math.sin(az), math.cos(el) * math.cos(az),
                         math.sin(el)])


def photodiode_pose(base_position_m, R_map_base, config):
    """PD position and unit normal in ``map`` for ``base_link`` poses.

    Parameters
    ----------
    base_position_m : ndarray (3,) or (N, 3)
    R_map_base : ndarray (3, 3) or (N, 3, 3)
    config : PhotodiodeConfig

    Returns
    -------
    position_m, normal : ndarray (N, 3)
    """
    base = np.asarray(base_position_m, dtype=float).reshape(-1, 3)
    R = np.asarray(R_map_base, dtype=float).reshape(-1, 3, 3)
    mount = np.asarray(config.mount_xyz_m)
    return base + R @ mount, R @ config.normal_base


def channel_gain(pd_position_m, pd_normal, lamp_positions_m, lamp_normals, config):
    """LOS DC gain H(0) of every lamp at every PD pose.

    Parameters
    ----------
    pd_position_m, pd_normal : ndarray (N, 3)
        PD centres and unit normals in ``map``.
    lamp_positions_m, lamp_normals : ndarray (L, 3)
        Lamp disc centres and unit disc normals (into the tunnel) in ``map``.
    config : PhotodiodeConfig

    Returns
    -------
    gain : ndarray (N, L)
        H(0), dimensionless (0 outside the field of view or behind a lamp).
    distance_m, cos_phi, cos_psi : ndarray (N, L)
    """
    p = np.asarray(pd_position_m, dtype=float).reshape(-1, 1, 3)
    n_r = np.asarray(pd_normal, dtype=float).reshape(-1, 1, 3)
    lamps = np.asarray(lamp_positions_m, dtype=float).reshape(1, -1, 3)
    n_l = np.asarray(lamp_normals, dtype=float).reshape(1, -1, 3)
    v = p - lamps                                         # lamp → PD
    d = np.linalg.norm(v, axis=2)
    cos_phi = np.sum(v * n_l, axis=2) / d
    cos_psi = -np.sum(v * n_r, axis=2) / d
    cos_fov = math.cos(math.radians(config.fov_half_angle_deg))
    seen = (cos_phi > 0.0) & (cos_psi >= cos_fov)
    m = config.order_m
    gain = ((m + 1.0) * config.area_m2 / (2.0 * math.pi * d * d)
            * np.power(np.clip(cos_phi, 0.0, None), m) * config.filter_transmission
            * config.concentrator_gain * cos_psi)
    return np.where(seen, gain, 0.0), d, cos_phi, cos_psi


def noise_variance_a2(total_power_w, config):
    """Photocurrent noise variance σ²_shot + σ²_thermal of one estimate, A².

    ``total_power_w`` is the optical power of every lamp received (scalar or array).
    """
    q, k = ELECTRON_CHARGE_C, BOLTZMANN_J_PER_K
    c = config
    B = c.noise_bandwidth_hz
    shot = (2.0 * q * c.responsivity_a_per_w * np.asarray(total_power_w, dtype=float) * B
            + 2.0 * q * c.background_current_a * c.noise_factor_i2 * B)
    eta_a = c.capacitance_per_area_f_m2 * c.area_m2
    thermal = (8.0 * math.pi * k * c.temperature_k / c.open_loop_gain * eta_a
               * c.noise_factor_i2 * B ** 2
               + 16.0 * math.pi ** 2 * k * c.temperature_k * c.fet_noise_factor
               / c.fet_transconductance_s * eta_a ** 2 * c.noise_factor_i3 * B ** 3)
    return shot + thermal


