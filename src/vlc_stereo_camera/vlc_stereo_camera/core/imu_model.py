"""Error model of the ADIS16488 IMU (gyroscopes and accelerometers), vectorised.

Per axis, sample n (Analog Devices ADIS16488A datasheet figures, Table 1)::

    ω_meas = sat(M_g · ω_true + b_g,0 + b_g(n) + w_g(n))
    f_meas = sat(M_a · f_true + b_a,0 + b_a(n) + w_a(n))

* ``w``: white noise, σ per sample = density · √rate, from the angle random walk
  0.26 °/√h → 0.26·π/180/60 rad/s/√Hz and the velocity random walk 0.029 m/s/√h →
  0.029/60 m/s²/√Hz (densities do not depend on the output rate).
* ``b(n)``: in-run bias, a bank of K independent first-order Gauss–Markov processes
  with log-spaced correlation times and equal σ (one per decade, from about where the
  white-noise line meets the floor — gyro 10 s, accelerometer 1 s — to 10⁴ s). One
  Gauss–Markov process alone has a hump-shaped Allan curve (peak ≈ 0.617·σ at
  τ ≈ 1.89·T_c) that falls again beyond it; one per decade sums to the flat floor of
  flicker (bias-instability) noise, which is what the datasheet's "in-run bias
  stability" — the lowest point of the Allan deviation — measures. σ is chosen so
  that the bank's analytic Allan deviation has a geometric mean over
  [1.89·T_min, 1.89·T_max] equal to the datasheet figure (5.1 °/h, 0.1 mg); with a
  single correlation time this reduces to σ = B / 0.617. Each process is discretised
  exactly: b(n) = φ·b(n−1) + σ·√(1−φ²)·ξ(n), φ = exp(−dt/T_c), started from its
  stationary distribution.
* ``b_0``: turn-on bias, a seeded random constant (datasheet initial bias error, 1σ).
* ``M = I + S + A``: seeded scale-factor errors S (diagonal, datasheet sensitivity
  repeatability) and axis-to-axis misalignment A (off-diagonal, small angles).
* ``sat``: clipping at the dynamic range (±450 °/s, ±18 g).

Random numbers are drawn sample-major (one row of all noise inputs per sample), so the
output does not depend on how the samples are split into ``step`` calls. Not modelled:
the sensor's internal filtering and decimation, g-sensitivity of the gyroscopes,
temperature effects, quantisation (32-bit outputs make it negligible).
"""
import argparse
from dataclasses import dataclass

import numpy as np
from scipy.signal import lfilter

from vlc_stereo_camera.core.allan import (
    GM_PEAK_TAU_RATIO,
    allan_floor,
    cluster_sizes,
    fit_white_density,
    gauss_markov_adev,
    overlapping_adev,
)

GRAVITY_MPS2 = 9.80665
DEG = np.pi / 180.0
#: Highest output data rate of the ADIS16488 (its internal sample clock), Hz.
MAX_RATE_HZ = 2460.0
#: Mixed into the scenario seed so the IMU noise is independent of the other processes
#: driven by the same seed.
_SEED_STREAM = 16488
#: Up to this many samples per step, the Gauss–Markov recursion runs as a numpy loop
#: over samples (cheaper than K lfilter calls for the node's small batches).
_SHORT_BATCH = 64


@dataclass(frozen=True)
class Adis16488Params:
    """Error parameters in SI units (defaults: ADIS16488A datasheet, 1σ values).

    Attributes
    ----------
    gyro_arw_rad_s_rthz : float
        Gyro white-noise density (angle random walk), rad/s/√Hz.
    gyro_bias_instability_rad_s : float
        Gyro in-run bias stability = Allan deviation floor, rad/s.
    accel_vrw_mps2_rthz : float
        Accelerometer white-noise density (velocity random walk), m/s²/√Hz.
    accel_bias_instability_mps2 : float
        Accelerometer in-run bias stability = Allan deviation floor, m/s².
    gyro_bias_corr_times_s, accel_bias_corr_times_s : tuple of float
        Correlation times of the Gauss–Markov banks, seconds.
    gyro_turn_on_bias_sigma_rad_s, accel_turn_on_bias_sigma_mps2 : float
        1σ of the constant turn-on bias per axis.
    gyro_scale_factor_sigma, accel_scale_factor_sigma : float
        1σ of the relative scale-factor error per axis (0.01 = 1 %).
    gyro_misalignment_sigma_rad, accel_misalignment_sigma_rad : float
        1σ of each off-diagonal axis-to-axis misalignment, rad.
    gyro_range_rad_s, accel_range_mps2 : float
        Dynamic range; outputs are clipped to ±range.
    """

    gyro_arw_rad_s_rthz: float = 0.26 * DEG / 60.0
    gyro_bias_instability_rad_s: float = 5.1 * DEG / 3600.0
    accel_vrw_mps2_rthz: float = 0.029 / 60.0
    accel_bias_instability_mps2: float = 0.1e-3 * GRAVITY_MPS2
    gyro_bias_corr_times_s: tuple = (10.0, 100.0, 1000.0, 10000.0)
    accel_bias_corr_times_s: tuple = (1.0, 10.0, 100.0, 1000.0, 10000.0)
    gyro_turn_on_bias_sigma_rad_s: float = 0.2 * DEG
    accel_turn_on_bias_sigma_mps2: float = 16e-3 * GRAVITY_MPS2
    gyro_scale_factor_sigma: float = 0.01
    accel_scale_factor_sigma: float = 0.005
    gyro_misalignment_sigma_rad: float = 0.05 * DEG
    accel_misalignment_sigma_rad: float = 0.035 * DEG
    gyro_range_rad_s: float = 450.0 * DEG
    accel_range_mps2: float = 18.0 * GRAVITY_MPS2

    def __post_init__(self):
        for name, value in vars(self).items():
            if name.endswith('corr_times_s'):
                continue
            if not np.isfinite(value) or value < 0.0:
                raise ValueError(f'{name} must be finite and >= 0, got {value}')
        if self.gyro_range_rad_s <= 0.0 or self.accel_range_mps2 <= 0.0:
            raise ValueError('gyro_range_rad_s and accel_range_mps2 must be > 0')
        for name in ('gyro_bias_corr_times_s', 'accel_bias_corr_times_s'):
            taus = np.asarray(getattr(self, name), dtype=float)
            if taus.ndim != 1 or taus.size == 0 or not np.all(np.isfinite(taus)) \
                    or np.any(taus <= 0.0):
                raise ValueError(f'{name} must be a non-empty list of positive seconds, '
                                 f'got {getattr(self, name)}')

    @classmethod
    def from_datasheet_units(cls, gyro_arw_deg_rthr, gyro_bias_instability_deg_hr,
                             accel_vrw_mps_rthr, accel_bias_instability_mg,
                             gyro_bias_corr_times_s, accel_bias_corr_times_s,
                             gyro_turn_on_bias_sigma_dps,
                             accel_turn_on_bias_sigma_mg, gyro_scale_factor_sigma,
                             accel_scale_factor_sigma, gyro_misalignment_sigma_deg,
                             accel_misalignment_sigma_deg, gyro_range_dps, accel_range_g):
        """Build from datasheet units (argument order): °/√h, °/h, m/s/√h, mg, s, s, °/s,
        mg, –, –, °, °, °/s, g.
        """
        return cls(
            gyro_arw_rad_s_rthz=gyro_arw_deg_rthr * DEG / 60.0,
            gyro_bias_instability_rad_s=gyro_bias_instability_deg_hr * DEG / 3600.0,
            accel_vrw_mps2_rthz=accel_vrw_mps_rthr / 60.0,
            accel_bias_instability_mps2=accel_bias_instability_mg * 1e-3 * GRAVITY_MPS2,
            gyro_bias_corr_times_s=tuple(float(t) for t in gyro_bias_corr_times_s),
            accel_bias_corr_times_s=tuple(float(t) for t in accel_bias_corr_times_s),
            gyro_turn_on_bias_sigma_rad_s=gyro_turn_on_bias_sigma_dps * DEG,
            accel_turn_on_bias_sigma_mps2=accel_turn_on_bias_sigma_mg * 1e-3 * GRAVITY_MPS2,
            gyro_scale_factor_sigma=gyro_scale_factor_sigma,
            accel_scale_factor_sigma=accel_scale_factor_sigma,
            gyro_misalignment_sigma_rad=gyro_misalignment_sigma_deg * DEG,
            accel_misalignment_sigma_rad=accel_misalignment_sigma_deg * DEG,
            gyro_range_rad_s=gyro_range_dps * DEG,
            accel_range_mps2=accel_range_g * GRAVITY_MPS2)

    def ideal(self):
        """The same sensor with every error term set to zero (ranges kept)."""
        return Adis16488Params(
            gyro_arw_rad_s_rthz=0.0, gyro_bias_instability_rad_s=0.0,
            accel_vrw_mps2_rthz=0.0, accel_bias_instability_mps2=0.0,
            gyro_bias_corr_times_s=self.gyro_bias_corr_times_s,
            accel_bias_corr_times_s=self.accel_bias_corr_times_s,
            gyro_turn_on_bias_sigma_rad_s=0.0,
            accel_turn_on_bias_sigma_mps2=0.0, gyro_scale_factor_sigma=0.0,
            accel_scale_factor_sigma=0.0, gyro_misalignment_sigma_rad=0.0,
            accel_misalignment_sigma_rad=0.0, gyro_range_rad_s=self.gyro_range_rad_s,
            accel_range_mps2=self.accel_range_mps2)


def bias_bank_sigma(floor, corr_times_s):
    """Per-process σ of the Gauss–Markov bank whose Allan floor equals ``floor``.

    The bank's analytic Allan deviation (root sum of squares of the processes) is
    scaled so that its geometric mean over [1.89·T_min, 1.89·T_max] equals ``floor``;
    for one process this is σ = floor / 0.617, the peak relation.

    Parameters
    ----------
    floor : float
        Target Allan deviation floor (in-run bias stability), signal units.
    corr_times_s : array_like (K,)
        Correlation times, seconds.

    Returns
    -------
    float
        σ of each process, signal units.
    """
    taus = np.asarray(corr_times_s, dtype=float)
    grid = np.geomspace(GM_PEAK_TAU_RATIO * taus.min(), GM_PEAK_TAU_RATIO * taus.max(), 400)
    unit = np.sqrt(sum(gauss_markov_adev(grid, 1.0, t) ** 2 for t in taus))
    return floor / np.exp(np.mean(np.log(unit)))


def _axis_matrix(rng, scale_sigma, misalignment_sigma):
    m = np.eye(3) + np.diag(rng.normal(0.0, 1.0, 3) * scale_sigma)
    off = ~np.eye(3, dtype=bool)
    m[off] += rng.normal(0.0, 1.0, 6) * misalignment_sigma
    return m


def _apply_matrix(m, v):
    """Rows of ``v`` (N, 3) multiplied by ``m`` (3, 3), summed in a fixed order.

    A BLAS product may round differently for different N, which would make a sample
    depend on how the samples were batched.
    """
    return v[:, 0:1] * m[:, 0] + v[:, 1:2] * m[:, 1] + v[:, 2:3] * m[:, 2]


class Adis16488Model:
    """Seeded, stateful ADIS16488 error model; see the module docstring.

    Parameters
    ----------
    rate_hz : float
        Output data rate, Hz, in (0, 2460].
    seed : int
        Seed (≥ 0); the same seed, rate and parameters give identical samples.
    params : Adis16488Params, optional
        Error parameters; default the datasheet values.
    """

    def __init__(self, rate_hz, seed, params=None):
        rate_hz = float(rate_hz)
        if not (0.0 < rate_hz <= MAX_RATE_HZ):
            raise ValueError(f'rate_hz must be in (0, {MAX_RATE_HZ:g}] Hz (the ADIS16488 '
                             f'output data rate), got {rate_hz:g}')
        if int(seed) < 0:
            raise ValueError(f'seed must be >= 0, got {seed}')
        self.rate_hz = rate_hz
        self.dt_s = 1.0 / rate_hz
        self.params = p = params or Adis16488Params()
        const_seq, noise_seq = np.random.SeedSequence([int(seed), _SEED_STREAM]).spawn(2)
        const_rng = np.random.default_rng(const_seq)
        self._rng = np.random.default_rng(noise_seq)

        self.gyro_turn_on_bias_rad_s = const_rng.normal(0.0, 1.0, 3) \
            * p.gyro_turn_on_bias_sigma_rad_s
        self.accel_turn_on_bias_mps2 = const_rng.normal(0.0, 1.0, 3) \
            * p.accel_turn_on_bias_sigma_mps2
        self.gyro_matrix = _axis_matrix(const_rng, p.gyro_scale_factor_sigma,
                                        p.gyro_misalignment_sigma_rad)
        self.accel_matrix = _axis_matrix(const_rng, p.accel_scale_factor_sigma,
                                         p.accel_misalignment_sigma_rad)

        gyro_taus = np.asarray(p.gyro_bias_corr_times_s, dtype=float)
        accel_taus = np.asarray(p.accel_bias_corr_times_s, dtype=float)
        self.gyro_bank_sigma_rad_s = bias_bank_sigma(p.gyro_bias_instability_rad_s, gyro_taus)
        self.accel_bank_sigma_mps2 = bias_bank_sigma(p.accel_bias_instability_mps2, accel_taus)
        # One row per Gauss–Markov process: gyro processes act on columns 0:3, accel
        # processes on 3:6 of the (N, 6) error array.
        taus = np.concatenate([gyro_taus, accel_taus])
        self._bank_column = np.repeat([0, 3], [gyro_taus.size, accel_taus.size])
        sigma = np.repeat([self.gyro_bank_sigma_rad_s, self.accel_bank_sigma_mps2],
                          [gyro_taus.size, accel_taus.size])
        self._phi = np.exp(-self.dt_s / taus)                  # exact discretisation
        self._drive = sigma * np.sqrt(1.0 - self._phi ** 2)
        # Start each process from its stationary distribution.
        self._bank = const_rng.normal(0.0, 1.0, (taus.size, 3)) * sigma[:, None]

        self.white_sigma = np.repeat([p.gyro_arw_rad_s_rthz, p.accel_vrw_mps2_rthz], 3) \
            * np.sqrt(rate_hz)
        self._range = np.repeat([p.gyro_range_rad_s, p.accel_range_mps2], 3)
        self.samples_generated = 0
        self.last_bias = self._bias_now()

    def _gauss_markov(self, drive):
        """Run every bias process over N samples: b(n) = φ·b(n−1) + drive(n).

        The exact discrete Gauss–Markov recursion. A short batch (the node's few samples
        per tick) loops over samples with all processes at once; a long one uses
        lfilter per process. Both evaluate round(drive + round(φ·b)), so the output
        does not depend on the batching, to the bit.

        Parameters
        ----------
        drive : ndarray (N, K, 3)
            σ·√(1−φ²)·ξ per sample, process and axis.

        Returns
        -------
        ndarray (N, K, 3)
            The processes' values at each sample; the state is kept in ``self._bank``.
        """
        n = drive.shape[0]
        out = np.empty_like(drive)
        if n <= _SHORT_BATCH:
            phi = self._phi[:, None]
            state = self._bank
            for i in range(n):
                state = drive[i] + phi * state
                out[i] = state
        else:
            for j, phi in enumerate(self._phi):
                # lfilter's state before the first sample is φ·b(n−1).
                out[:, j], _ = lfilter([1.0], [1.0, -phi], drive[:, j], axis=0,
                                       zi=(phi * self._bank[j])[None, :])
        self._bank = out[-1].copy()
        return out

    def _bias_now(self):
        bias = np.concatenate([self.gyro_turn_on_bias_rad_s, self.accel_turn_on_bias_mps2])
        for col, state in zip(self._bank_column, self._bank):
            bias[col:col + 3] += state
        return bias

    @property
    def gyro_white_variance(self):
        """Variance of the gyro white noise per sample, (rad/s)² (ARW² · rate)."""
        return float(self.white_sigma[0] ** 2)

    @property
    def accel_white_variance(self):
        """Variance of the accelerometer white noise per sample, (m/s²)² (VRW² · rate)."""
        return float(self.white_sigma[3] ** 2)

    def step(self, true_omega, true_f):
        """Measure N consecutive samples; the bias state carries over between calls.

        Parameters
        ----------
        true_omega : array_like (N, 3)
            True angular rate of the sensor frame, rad/s.
        true_f : array_like (N, 3)
            True specific force at the sensor, m/s² (+9.80665 on z at rest, z up).

        Returns
        -------
        omega_meas : ndarray (N, 3)
            Measured angular rate, rad/s.
        f_meas : ndarray (N, 3)
            Measured specific force, m/s².
        """
        true_omega = np.asarray(true_omega, dtype=float).reshape(-1, 3)
        true_f = np.asarray(true_f, dtype=float).reshape(-1, 3)
        n = true_omega.shape[0]
        if true_f.shape[0] != n:
            raise ValueError(f'true_omega has {n} rows, true_f {true_f.shape[0]}')
        xi = self._rng.standard_normal((n, 6 + 3 * self._phi.size))
        error = xi[:, :6] * self.white_sigma
        error += np.concatenate([self.gyro_turn_on_bias_rad_s, self.accel_turn_on_bias_mps2])
        if n:
            drive = xi[:, 6:].reshape(n, -1, 3) * self._drive[:, None]   # (N, K, 3)
            bank = self._gauss_markov(drive)
            for j, col in enumerate(self._bank_column):
                error[:, col:col + 3] += bank[:, j]
            self.last_bias = self._bias_now()
        omega = _apply_matrix(self.gyro_matrix, true_omega) + error[:, :3]
        f = _apply_matrix(self.accel_matrix, true_f) + error[:, 3:]
        self.samples_generated += n
        return (np.clip(omega, -self._range[:3], self._range[:3]),
                np.clip(f, -self._range[3:], self._range[3:]))


def lever_arm_specific_force(f_base, omega, alpha, lever_arm_m):
    """Specific force at a point ``r`` of the rigid platform from the one at its origin.

    f_r = f_0 + ω × (ω × r) + α × r, all in the platform (base_link) frame.

    Parameters
    ----------
    f_base : ndarray (N, 3)
        Specific force at the base_link origin, m/s².
    omega : ndarray (N, 3)
        Angular rate of base_link in its own frame, rad/s.
    alpha : ndarray (N, 3)
        Angular acceleration (time derivative of ``omega``), rad/s².
    lever_arm_m : array_like (3,)
        Position of the sensor in base_link, m.
    """
    r = np.broadcast_to(np.asarray(lever_arm_m, dtype=float), np.shape(f_base))
    return f_base + np.cross(omega, np.cross(omega, r)) + np.cross(alpha, r)


def true_imu_signals(trajectory, t_s, lever_arm_m=(0.0, 0.0, 0.0), diff_step_s=1e-4):
    """True angular rate and specific force of an IMU mounted on base_link.

    Parameters
    ----------
    trajectory : vlc_stereo_camera.core.trajectory.Trajectory
        The motion (anything with ``sample(t_s)`` returning ``angular_velocity_body_rps``
        and ``specific_force_body_mps2``).
    t_s : ndarray (N,)
        Times since the epoch, seconds.
    lever_arm_m : array_like (3,)
        IMU position in base_link, m; its axes are base_link's.
    diff_step_s : float
        Step of the central difference that gives the angular acceleration (the
        trajectory is analytic and smooth between motion-segment boundaries).

    Returns
    -------
    omega : ndarray (N, 3)
        rad/s, base_link (= imu_link) axes.
    f : ndarray (N, 3)
        m/s² at the IMU.
    """
    t = np.atleast_1d(np.asarray(t_s, dtype=float))
    truth = trajectory.sample(t)
    omega = truth.angular_velocity_body_rps
    f = truth.specific_force_body_mps2
    r = np.asarray(lever_arm_m, dtype=float)
    if np.any(r != 0.0):
        ahead = trajectory.sample(t + diff_step_s).angular_velocity_body_rps
        behind = trajectory.sample(t - diff_step_s).angular_velocity_body_rps
        alpha = (ahead - behind) / (2.0 * diff_step_s)
        f = lever_arm_specific_force(f, omega, alpha, r)
    return omega, f


@dataclass
class ImuBatch:
    """Consecutive IMU samples (see :class:`ImuSampler`).

    Attributes
    ----------
    index : ndarray (N,) int64
        Sample numbers n; sample n is taken at t = n / rate after the epoch.
    t_s : ndarray (N,)
        Sample times since the epoch, seconds.
    omega_true, f_true : ndarray (N, 3)
        Truth: angular rate (rad/s) and specific force at the IMU (m/s²).
    omega, f : ndarray (N, 3)
        Measurements (rad/s, m/s²).
    valid : ndarray (N,) bool
        False where the trajectory gave non-finite truth; those rows must be skipped.
    """

    index: np.ndarray
    t_s: np.ndarray
    omega_true: np.ndarray
    f_true: np.ndarray
    omega: np.ndarray
    f: np.ndarray
    valid: np.ndarray


class ImuSampler:
    """The IMU riding on a trajectory: sample n at t = n / rate, in order.

    Parameters
    ----------
    trajectory : Trajectory
        The platform motion (``sample(t_s)``).
    model : Adis16488Model
        The error model; its rate sets the sample times.
    lever_arm_m : array_like (3,)
        IMU position in base_link, m.
    R_base_imu : array_like (3, 3), optional
        Boresight: the IMU's axes in base_link; the sensed rate and specific force are
        these axes' components (None: the IMU is aligned with base_link).
    """

    def __init__(self, trajectory, model, lever_arm_m=(0.0, 0.0, 0.0), R_base_imu=None):
        self.trajectory = trajectory
        self.model = model
        self.lever_arm_m = np.asarray(lever_arm_m, dtype=float).reshape(3)
        if not np.all(np.isfinite(self.lever_arm_m)):
            raise ValueError(f'lever_arm_m must be finite, got {lever_arm_m}')
        self.R_base_imu = None if R_base_imu is None else np.asarray(R_base_imu, float)
        self.next_index = 0

    def next(self, count):
        """The next ``count`` samples as an :class:`ImuBatch`."""
        index = self.next_index + np.arange(int(count), dtype=np.int64)
        t = index / self.model.rate_hz
        omega_true, f_true = true_imu_signals(self.trajectory, t, self.lever_arm_m)
        if self.R_base_imu is not None:
            omega_true, f_true = omega_true @ self.R_base_imu, f_true @ self.R_base_imu
        valid = np.all(np.isfinite(omega_true), axis=1) & np.all(np.isfinite(f_true), axis=1)
        # Invalid rows still consume their noise draws, so later samples do not depend on
        # whether earlier ones were valid.
        omega, f = self.model.step(np.where(valid[:, None], omega_true, 0.0),
                                   np.where(valid[:, None], f_true, 0.0))
        self.next_index += int(count)
        return ImuBatch(index=index, t_s=t, omega_true=omega_true, f_true=f_true,
                        omega=omega, f=f, valid=valid)


def characterise(hours=6.0, rate_hz=100.0, seed=1, params=None, chunk_s=600.0):
    """Simulate the IMU at rest and read its Allan figures back.

    Parameters
    ----------
    hours : float
        Length of the simulated record.
    rate_hz : float
        Output rate; the noise densities do not depend on it, so a low rate keeps the
        run cheap.
    seed : int
    params : Adis16488Params, optional
    chunk_s : float
        Samples are generated in chunks of this length (bounds the memory).

    Returns
    -------
    dict
        ``allan``: AllanResult over the six channels (gyro x, y, z in rad/s, accel x,
        y, z in m/s²); ``arw_1s``/``vrw_1s``: Allan deviation at τ = 1 s per axis;
        ``arw_fit``/``vrw_fit``: density of the −1/2 line fitted where white noise
        dominates (gyro 0.05–2 s, accel 0.01–0.05 s); ``gyro_floor``/``accel_floor``
        and their τ: the minimum over 1 s … record/20 (longer clusters are too few
        for the minimum not to be dragged down by estimation noise).
    """
    model = Adis16488Model(rate_hz, seed, params)
    n = int(round(hours * 3600.0 * rate_hz))
    chunk = int(chunk_s * rate_hz)
    rest_f = np.array([0.0, 0.0, GRAVITY_MPS2])
    out = np.empty((n, 6))
    for start in range(0, n, chunk):
        m = min(chunk, n - start)
        omega, f = model.step(np.zeros((m, 3)), np.broadcast_to(rest_f, (m, 3)))
        out[start:start + m, :3] = omega
        out[start:start + m, 3:] = f
    one_second = int(round(rate_hz))
    res = overlapping_adev(out, rate_hz, np.union1d(cluster_sizes(n), [one_second]))
    i1 = np.flatnonzero(np.isclose(res.tau_s * rate_hz, one_second))[0]
    floor, tau_floor = allan_floor(res.tau_s, res.adev, 1.0, n / rate_hz / 20.0)
    return {
        'model': model,
        'allan': res,
        'arw_1s': res.adev[i1, :3],
        'vrw_1s': res.adev[i1, 3:],
        'arw_fit': fit_white_density(res.tau_s, res.adev[:, :3], 0.05, 2.0),
        'vrw_fit': fit_white_density(res.tau_s, res.adev[:, 3:], 0.01, 0.05),
        'gyro_floor': floor[:3], 'gyro_floor_tau_s': tau_floor[:3],
        'accel_floor': floor[3:], 'accel_floor_tau_s': tau_floor[3:],
        'mean': out.mean(axis=0),
    }


def main(argv=None):
    """Print the Allan figures of the simulated IMU against the datasheet."""
    parser = argparse.ArgumentParser(description=main.__doc__)
    parser.add_argument('--hours', type=float, default=6.0)
    parser.add_argument('--rate-hz', type=float, default=100.0)
    parser.add_argument('--seed', type=int, default=1)
    args = parser.parse_args(argv)
    r = characterise(args.hours, args.rate_hz, args.seed)
    p = r['model'].params
    rows = [
        ('gyro ARW at tau=1 s', 'deg/sqrt(h)', r['arw_1s'] / DEG * 60.0,
         p.gyro_arw_rad_s_rthz / DEG * 60.0),
        ('gyro ARW, -1/2 fit', 'deg/sqrt(h)', r['arw_fit'] / DEG * 60.0,
         p.gyro_arw_rad_s_rthz / DEG * 60.0),
        ('gyro bias floor', 'deg/h', r['gyro_floor'] / DEG * 3600.0,
         p.gyro_bias_instability_rad_s / DEG * 3600.0),
        ('accel VRW at tau=1 s', 'm/s/sqrt(h)', r['vrw_1s'] * 60.0, p.accel_vrw_mps2_rthz * 60.0),
        ('accel VRW, -1/2 fit', 'm/s/sqrt(h)', r['vrw_fit'] * 60.0, p.accel_vrw_mps2_rthz * 60.0),
        ('accel bias floor', 'mg', r['accel_floor'] / GRAVITY_MPS2 * 1e3,
         p.accel_bias_instability_mps2 / GRAVITY_MPS2 * 1e3),
    ]
    print(f'ADIS16488 model at rest: {args.hours:g} h at {args.rate_hz:g} Hz, seed {args.seed}; '
          'floors = min of the overlapping Allan deviation over 1 s .. record/20')
    print(f'{"quantity":<22}{"unit":<13}{"x":>9}{"y":>9}{"z":>9}{"datasheet":>11}')
    for name, unit, values, datasheet in rows:
        print(f'{name:<22}{unit:<13}' + ''.join(f'{v:9.4g}' for v in values)
              + f'{datasheet:11.4g}')
    print('floor at tau (s): gyro ' + ' '.join(f'{t:.0f}' for t in r['gyro_floor_tau_s'])
          + ', accel ' + ' '.join(f'{t:.0f}' for t in r['accel_floor_tau_s']))
    m = r['model']
    for name, taus, sigma, floor, unit, scale in (
            ('gyro', p.gyro_bias_corr_times_s, m.gyro_bank_sigma_rad_s,
             p.gyro_bias_instability_rad_s, 'deg/h', 3600.0 / DEG),
            ('accel', p.accel_bias_corr_times_s, m.accel_bank_sigma_mps2,
             p.accel_bias_instability_mps2, 'mg', 1e3 / GRAVITY_MPS2)):
        print(f'{name} in-run bias: {len(taus)} Gauss-Markov processes, T_c = '
              + ', '.join(f'{t:g}' for t in taus) + f' s, sigma each {sigma * scale:.4g} {unit}'
              f' = {sigma / floor:.3f} x floor, stationary total '
              f'{sigma * np.sqrt(len(taus)) * scale:.4g} {unit}')


if __name__ == '__main__':
    main()
