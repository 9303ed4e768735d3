"""Along-track Kalman filter: chainage, speed and accelerometer bias, driven by the IMU.

State ``x = [s, v, b]``: chainage of ``base_link`` (m), its along-track speed (m/s) and
the bias of the measured along-track acceleration (m/s²). The gravity-compensated
along-track acceleration ``a_m = a + b + n_a`` is the filter's input (not a
measurement), so between lamp fixes the position follows the IMU and stays bounded by
the growth of ``P`` rather than by a motion model's guess::

    ṡ = v,   v̇ = a_m − b − n_a,   ḃ = n_b

``n_a`` white with density ``accel_noise_density`` (m/s²/√Hz), ``n_b`` white with
density ``bias_random_walk`` (m/s³/√Hz). The discrete transition and process noise
below are the exact integrals of this linear model over a step ``dt``. Fixes are scalar
chainage measurements ``z = s + n``; zero-velocity updates measure ``v = 0``.

Pure functions on :class:`FilterState` (``predict``, ``update``), in the style of
filterpy's step functions; no time bookkeeping here (see
:mod:`train_localizer.core.localizer`).
"""
from dataclasses import dataclass
import math

import numpy as np

H_CHAINAGE = np.array([1.0, 0.0, 0.0])


@dataclass
class KalmanConfig:
    """Noise model of the along-track filter (SI units).

    Attributes
    ----------
    accel_noise_density_mps2_rthz : float
        White noise of the along-track acceleration input, m/s²/√Hz: the accelerometer
        (ADIS16488 VRW 0.029 m/s/√h ≈ 5e-4) plus what attitude jitter leaks of gravity.
    bias_random_walk_mps3_rthz : float
        Random walk of the acceleration bias, m/s³/√Hz: in-run accelerometer drift and
        the slow gravity leak of attitude (pitch) errors.
    initial_bias_sigma_mps2 : float
        1σ of the bias at initialisation, m/s² (ADIS16488 turn-on bias 16 mg ≈ 0.16).
    initial_speed_sigma_mps : float
        1σ of the speed at initialisation when nothing is known, m/s.
    unknown_accel_sigma_mps2 : float
        1σ of the acceleration over a step without IMU data (a gap, or no IMU), m/s².
    """

    accel_noise_density_mps2_rthz: float = 0.01
    bias_random_walk_mps3_rthz: float = 2e-3
    initial_bias_sigma_mps2: float = 0.2
    initial_speed_sigma_mps: float = 40.0
    unknown_accel_sigma_mps2: float = 1.5

    def __post_init__(self):
        for name in ('accel_noise_density_mps2_rthz', 'bias_random_walk_mps3_rthz',
                     'initial_bias_sigma_mps2', 'initial_speed_sigma_mps',
                     'unknown_accel_sigma_mps2'):
            value = getattr(self, name)
            if not (math.isfinite(value) and value >= 0.0):
                raise ValueError(f'{name} must be finite and >= 0, got {value}')


@dataclass
class FilterState:
    """Mean ``x`` (3,) = [s m, v m/s, b m/s²] and covariance ``P`` (3, 3)."""

    x: np.ndarray
    P: np.ndarray

    def copy(self):
        return FilterState(self.x.copy(), self.P.copy())

    @property
    def chainage_m(self):
        return float(self.x[0])

    @property
    def speed_mps(self):
        return float(self.x[1])

    @property
    def chainage_var_m2(self):
        return float(self.P[0, 0])


def initial_state(chainage_m, chainage_var_m2, config, speed_mps=0.0, speed_var_m2s2=None):
    """A state at a first fix: speed unknown unless given, bias zero with its prior."""
    speed_var = config.initial_speed_sigma_mps ** 2 if speed_var_m2s2 is None else speed_var_m2s2
    return FilterState(np.array([chainage_m, speed_mps, 0.0]),
                       np.diag([chainage_var_m2, speed_var, config.initial_bias_sigma_mps2 ** 2]))


def transition(dt):
    """State transition F (3, 3) and input vector B (3,) of a step of ``dt`` seconds."""
    F = np.array([[1.0, dt, -0.5 * dt * dt], [0.0, 1.0, -dt], [0.0, 0.0, 1.0]])
    B = np.array([0.5 * dt * dt, dt, 0.0])
    return F, B


def process_noise(dt, config, accel_var=0.0, bias_q_extra=0.0):
    """Process noise Q (3, 3) of a step of ``dt`` s.

    ``accel_var`` (m²/s⁴) adds an acceleration that is unknown but constant over the
    step (a gap without IMU data): ``accel_var·B·Bᵀ``. ``bias_q_extra`` (m²/s⁵) adds
    to the bias random-walk intensity (an input error that wanders, e.g. the gravity
    leak of an uncertain pitch).
    """
    qa = config.accel_noise_density_mps2_rthz ** 2
    qb = config.bias_random_walk_mps3_rthz ** 2 + bias_q_extra
    dt2, dt3 = dt * dt, dt * dt * dt
    Q = qa * np.array([[dt3 / 3.0, dt2 / 2.0, 0.0], [dt2 / 2.0, dt, 0.0], [0.0, 0.0, 0.0]])
    Q += qb * np.array([[dt2 * dt3 / 20.0, dt2 * dt2 / 8.0, -dt3 / 6.0],
                        [dt2 * dt2 / 8.0, dt3 / 3.0, -dt2 / 2.0],
                        [-dt3 / 6.0, -dt2 / 2.0, dt]])
    if accel_var > 0.0:
        B = np.array([0.5 * dt2, dt, 0.0])
        Q += accel_var * np.outer(B, B)
    return Q


def predict(state, dt, accel, config, accel_var=0.0, bias_q_extra=0.0):
    """Propagate the state by ``dt`` seconds with the measured along-track acceleration.

    Parameters
    ----------
    state : FilterState
    dt : float
        Step, s (≥ 0).
    accel : float
        Mean measured along-track acceleration over the step (bias included), m/s².
        For a step without IMU data pass the bias estimate ``state.x[2]`` (zero true
        acceleration) and ``accel_var``.
    config : KalmanConfig
    accel_var : float
        Extra variance of an acceleration unknown over the step, m²/s⁴.
    bias_q_extra : float
        Extra bias random-walk intensity over the step, m²/s⁵.

    Returns
    -------
    FilterState
    """
    if dt <= 0.0:
        return state.copy()
    F, B = transition(dt)
    x = F @ state.x + B * accel
    P = F @ state.P @ F.T + process_noise(dt, config, accel_var, bias_q_extra)
    return FilterState(x, 0.5 * (P + P.T))


H_SPEED = np.array([0.0, 1.0, 0.0])


def innovation(state, z, r, h=H_CHAINAGE):
    """Innovation ``z − h·x`` and its variance ``h·P·hᵀ + r`` of a scalar measurement."""
    return float(z - h @ state.x), float(h @ state.P @ h + r)


def update(state, z, r, h=H_CHAINAGE):
    """Kalman update with a scalar measurement ``z = h·x + n``, ``var(n) = r``.

    The default ``h`` measures the chainage (a lamp fix, m, m²); ``H_SPEED`` the speed
    (a zero-velocity update, m/s, m²/s²). Joseph form, so ``P`` stays symmetric
    positive definite with tiny variances.

    Returns
    -------
    FilterState
    """
    y, S = innovation(state, z, r, h)
    K = state.P @ h / S
    x = state.x + K * y
    IKH = np.eye(3) - np.outer(K, h)
    P = IKH @ state.P @ IKH.T + r * np.outer(K, K)
    return FilterState(x, 0.5 * (P + P.T))
