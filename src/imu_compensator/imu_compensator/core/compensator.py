"""Per-sample driver: input checks, zero-velocity detection, the attitude filter.

:class:`AttitudeCompensator` is everything the node does between converting an
``imu/data_raw`` message and publishing ``imu/data``, so it is tested without ROS. Each
sample is classified (:class:`SampleStatus`) and bad input never raises:

* non-finite rate or specific force → skipped;
* stamp equal to the newest → skipped (duplicate); a little older → skipped (out of
  order); older by more than ``backward_reset_s`` → the filter is reset and restarted
  at this sample (a replayed bag or a restarted clock);
* stamp later by more than ``gap_s`` → propagated over the gap with the mean of the
  two bracketing rates, the attitude variance inflated by the unknown motion, per
  ``base_link`` axis (recent rate RMS × gap)², and the standstill window restarted.

After a start or reset, if the first full standstill window is still, the filter
restarts from the track attitude with the window's mean rate as gyro bias (static
alignment, as an INS does before departure).

The train's speed (:meth:`AttitudeCompensator.odometry`, the localizer's
``train/odometry``) can overrule a standstill verdict: while recent odometry shows the
train accelerating or braking (or, optionally, moving), a sample the IMU's variance test
finds still is not taken for standstill (:class:`~.zero_velocity.OdometryVeto`). Without
recent odometry the IMU alone decides, as before.

External attitude and heading aids (the lamps') are measurements of the attitude at
their own stamp, which is usually older than the newest sample and may be older than
corrections made meanwhile (the aids before it, the pulls). Each is compared with the
estimate *as it is now known* for that instant: the published attitude then, plus the
corrections made since and the drift the bias corrections since explain; its
measurement rows carry the bias and scale-factor errors' drift since then. Then:

* its squared Mahalanobis distance (innovation against the state's covariance plus the
  aid's) above the χ² quantile of ``aiding_gate_probability`` → rejected (counted,
  :attr:`AidingStatus.INCONSISTENT`), the estimate untouched;
* consistent, but the attitude correction a linear update would make above
  ``aiding_max_correction_rad`` → applied as an attitude reset: bias and scale factors
  are consider states of that update (their cross-covariances with the attitude,
  linearised for small errors, weigh it but do not move them);
* ``aiding_reinit_count`` consecutive inconsistent aids that agree with each other → the
  estimate, not the aids, is wrong (e.g. a static alignment on a curve the track
  heading does not describe): the attitude is re-initialised from the latest (reset,
  its covariance first inflated by the innovation).
"""
from collections import deque
from dataclasses import dataclass, field
import enum
import logging
import math

import numpy as np

from imu_compensator.core.attitude_filter import N_STATES, AttitudeFilter, AttitudeFilterConfig
from imu_compensator.core.zero_velocity import (
    OdometryVeto,
    OdometryVetoConfig,
    ZeroVelocityConfig,
    ZeroVelocityDetector,
)
from vlc_common.core.rotations import (
    quat_conjugate,
    quat_from_rotvec,
    quat_from_rpy,
    quat_multiply,
    quat_normalize,
    quat_slerp,
    quat_to_matrix,
    quat_to_rotvec,
    quat_to_rpy,
)

_LOG = logging.getLogger(__name__)

#: Two inconsistent aids agree (towards a re-initialisation) when their implied
#: corrections differ by no more than their covariances plus this much, rad, plus the
#: drift the gyro-bias uncertainty allows between their stamps.
REINIT_AGREEMENT_STD_RAD = 0.5 * math.pi / 180.0
#: Variance standing in for "not measured" on the axes a heading aid does not see, when
#: it is compared with other aids (re-initialisation), rad².
_UNSEEN_VAR_RAD2 = 1.0e4
#: The rate that sizes a gap's unknown motion is, per axis, the largest RMS of the
#: bias-corrected gyro over the standstill window (full or not) of the recent past,
#: forgotten with this time constant, s, or the rate at the gap's end if larger. One
#: window's spread dips where the sway's rate turns (the rig's sway at 20-80 km/h: 2 % of
#: 30-450 ms gaps beyond 3σ with the window's own std, none with this), and right after a
#: start, or between gaps closer than a window, there is no full window at all.
GAP_RATE_MEMORY_S = 2.0
#: ... sampled every this many samples (it changes slowly).
_RATE_HOLD_EVERY = 16


def chi2_quantile(probability, dof):
    """Quantile of the χ² distribution with 1, 2 or 3 degrees of freedom (bisection on
    the closed-form CDF); ``inf`` for ``probability ≥ 1``.
    """
    if probability >= 1.0:
        return math.inf
    if dof not in (1, 2, 3):
        raise ValueError(f'dof must be 1, 2 or 3, got {dof}')

    def cdf(x):
        if dof == 2:
            return -math.expm1(-0.5 * x)
        p = math.erf(math.sqrt(0.5 * x))
        return p if dof == 1 else p - math.sqrt(2.0 * x / math.pi) * math.exp(-0.5 * x)

    lo, hi = 0.0, 1.0
    while cdf(hi) < probability:
        hi *= 2.0
    for _ in range(200):
        mid = 0.5 * (lo + hi)
        if cdf(mid) < probability:
            lo = mid
        else:
            hi = mid
        if hi - lo < 1e-12 * hi:
            break
    return hi


def _skew(v):
    return np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])


def _left_jacobian_inverse(phi):
    """J_l(φ)⁻¹ of SO(3): log(Exp(δ)·Exp(φ)) = φ + J_l(φ)⁻¹·δ + O(δ²)."""
    angle = float(np.linalg.norm(phi))
    k = _skew(phi)
    if angle < 1e-6:
        return np.eye(3) - 0.5 * k + k @ k / 12.0
    half = 0.5 * angle
    coef = (1.0 - half / math.tan(half)) / angle ** 2
    return np.eye(3) - 0.5 * k + coef * (k @ k)


class SampleStatus(enum.Enum):
    """What :meth:`AttitudeCompensator.process` did with a sample."""

    OK = 'ok'
    INITIALIZED = 'initialized'      # first sample: filter started, estimate published
    GAP = 'gap'                      # propagated over a gap, estimate published
    RESET = 'reset'                  # time jumped backwards: restarted, estimate published
    NONFINITE = 'nonfinite'          # skipped
    DUPLICATE = 'duplicate'          # skipped
    OUT_OF_ORDER = 'out_of_order'    # skipped

    @property
    def accepted(self):
        return self in (SampleStatus.OK, SampleStatus.INITIALIZED, SampleStatus.GAP,
                        SampleStatus.RESET)


class AidingStatus(enum.Enum):
    """What :meth:`AttitudeCompensator.attitude_aiding` / ``heading_aiding`` did with an aid."""

    USED = 'used'                          # fused (linearised update)
    RESET = 'reset'                        # consistent, too large to linearise: attitude reset
    REINITIALISED = 'reinitialised'        # agreed with the inconsistent aids before it
    INVALID = 'invalid'                    # not finite / covariance not positive definite
    OUTSIDE_HISTORY = 'outside_history'    # stamp not inside the kept attitude history
    INCONSISTENT = 'inconsistent'          # failed the Mahalanobis gate

    @property
    def applied(self):
        return self in (AidingStatus.USED, AidingStatus.RESET, AidingStatus.REINITIALISED)


@dataclass
class AidingResult:
    """Outcome of one aid; true when it was applied.

    Attributes
    ----------
    status : AidingStatus
    t_s : float
        The aid's stamp, s.
    d2 : float
        Squared Mahalanobis distance of its innovation (nan when not computed).
    dof : int
        Degrees of freedom of that distance (3: attitude, 1: heading).
    gate_d2 : float
        The gate it was compared with.
    innovation_rad : float
        Norm of the innovation, rad (nan when not computed).
    correction_rad : float
        Norm of the attitude correction a linear update would make, rad (nan when not
        computed).
    """

    status: AidingStatus
    t_s: float
    d2: float = float('nan')
    dof: int = 0
    gate_d2: float = float('nan')
    innovation_rad: float = float('nan')
    correction_rad: float = float('nan')

    def __bool__(self):
        return self.status.applied


class AidingHistory:
    """Per accepted sample: the published attitude, the composed correction the filter's
    updates had made by then and its lag integrals (see
    :meth:`~imu_compensator.core.attitude_filter.AttitudeFilter.lag_integrals`) — what
    a delayed aid is compared with. Interpolated at any instant inside the history
    (slerp for the rotations, linear for the integrals).

    Parameters
    ----------
    horizon_s : float
        Samples older than ``newest − horizon_s`` are dropped, s.
    max_gap_s : float
        No interpolation across a larger step between neighbouring samples, s.
    """

    _WIDTH = 4 + 4 + 9 + 3

    def __init__(self, horizon_s, max_gap_s):
        if not (horizon_s > 0.0 and max_gap_s > 0.0):
            raise ValueError('horizon_s and max_gap_s must be > 0')
        self.horizon_s = float(horizon_s)
        self.max_gap_s = float(max_gap_s)
        self._capacity = 1024
        self._t = np.empty(self._capacity)
        self._v = np.empty((self._capacity, self._WIDTH))
        self._start = self._end = 0

    def __len__(self):
        return self._end - self._start

    def clear(self):
        """Forget every sample (the filter restarted)."""
        self._start = self._end = 0

    def push(self, t_s, quat_xyzw, correction_xyzw, int_a, int_rb):
        """Append one sample; its stamp must be later than the newest."""
        if self._end == self._capacity:
            n = len(self)
            if n >= self._capacity // 2:
                self._capacity *= 2
                t, v = np.empty(self._capacity), np.empty((self._capacity, self._WIDTH))
            else:
                t, v = self._t, self._v
            t[:n] = self._t[self._start:self._end]
            v[:n] = self._v[self._start:self._end]
            self._t, self._v, self._start, self._end = t, v, 0, n
        self._t[self._end] = t_s
        self._v[self._end] = [*quat_xyzw, *correction_xyzw, *int_a, *int_rb]
        self._end += 1
        if self._end - self._start > 1 and self._t[self._start + 1] <= t_s - self.horizon_s:
            times = self._t[self._start:self._end]
            k = int(np.searchsorted(times, t_s - self.horizon_s, side='right')) - 1
            self._start += max(k, 0)

    def lookup(self, t_s):
        """(attitude (4,), correction (4,), ∫R dt (9,), ∫R·b dt (3,)) at ``t_s``, or None
        outside the history or inside a gap longer than ``max_gap_s``.
        """
        n = len(self)
        if n == 0 or not math.isfinite(t_s):
            return None
        times = self._t[self._start:self._end]
        vals = self._v[self._start:self._end]
        if not times[0] <= t_s <= times[-1]:
            return None
        k = int(np.searchsorted(times, t_s, side='right'))
        if times[k - 1] == t_s:
            row = vals[k - 1].copy()
        else:
            lo, hi = k - 1, k
            span = times[hi] - times[lo]
            if span > self.max_gap_s:
                return None
            f = (t_s - times[lo]) / span
            row = (1.0 - f) * vals[lo] + f * vals[hi]
            # slerp takes the short arc whatever the signs of the two quaternions
            row[:4] = quat_slerp(vals[lo, :4], vals[hi, :4], f)
            row[4:8] = quat_slerp(vals[lo, 4:8], vals[hi, 4:8], f)
        return (quat_normalize(row[:4]), quat_normalize(row[4:8]), row[8:17], row[17:20])

    def at(self, t_s):
        """The published attitude (4,) at ``t_s``, or None (see :meth:`lookup`)."""
        got = self.lookup(t_s)
        return None if got is None else got[0]


@dataclass
class CompensatorConfig:
    """Everything :class:`AttitudeCompensator` needs (SI units, radians).

    Attributes
    ----------
    filter : AttitudeFilterConfig
    zero_velocity : ZeroVelocityConfig
    odometry : OdometryVetoConfig
        When recent odometry (:meth:`AttitudeCompensator.odometry`) overrules the
        IMU's standstill verdict.
    nominal_rate_hz : float
        Expected IMU rate, Hz (sizes the standstill window and the zero-rate noise).
    gap_s : float
        A step longer than this is a gap (warned, propagated), s.
    backward_reset_s : float
        A stamp older than the newest by more than this resets the filter; a smaller
        step back is an out-of-order sample and is dropped, s.
    imu_mount_rpy_rad : tuple of 3 floats
        Rotation of ``imu_link`` in ``base_link`` (roll, pitch, yaw); the filter works in
        ``base_link``.
    history_s : float
        Length of the attitude history kept for delayed (attitude or heading) aiding, s.
    aiding_gate_probability : float
        An aid is fused only when the squared Mahalanobis distance of its innovation is
        within this quantile of the χ² distribution (3 degrees of freedom for an
        attitude, 1 for a heading); 1 = no gate.
    aiding_max_correction_rad : float
        A consistent aid whose linear update would turn the attitude by more than this
        is applied as an attitude reset instead (bias and scale not corrected by it),
        rad.
    aiding_reinit_count : int
        This many consecutive inconsistent aids that agree with each other re-initialise
        the attitude from the latest; 0 = never.
    """

    filter: AttitudeFilterConfig = field(default_factory=AttitudeFilterConfig)
    zero_velocity: ZeroVelocityConfig = field(default_factory=ZeroVelocityConfig)
    odometry: OdometryVetoConfig = field(default_factory=OdometryVetoConfig)
    nominal_rate_hz: float = 400.0
    gap_s: float = 0.02
    backward_reset_s: float = 1.0
    imu_mount_rpy_rad: tuple = (0.0, 0.0, 0.0)
    history_s: float = 2.0
    aiding_gate_probability: float = 0.9999
    aiding_max_correction_rad: float = 0.1
    aiding_reinit_count: int = 5

    def __post_init__(self):
        for name in ('nominal_rate_hz', 'gap_s', 'backward_reset_s', 'history_s',
                     'aiding_max_correction_rad'):
            value = getattr(self, name)
            if not (np.isfinite(value) and value > 0.0):
                raise ValueError(f'{name} must be finite and > 0, got {value}')
        if len(self.imu_mount_rpy_rad) != 3:
            raise ValueError('imu_mount_rpy_rad needs 3 values')
        if not 0.0 < self.aiding_gate_probability <= 1.0:
            raise ValueError('aiding_gate_probability must be in (0, 1], got '
                             f'{self.aiding_gate_probability}')
        if int(self.aiding_reinit_count) != self.aiding_reinit_count \
                or self.aiding_reinit_count < 0:
            raise ValueError('aiding_reinit_count must be an integer >= 0, got '
                             f'{self.aiding_reinit_count}')


@dataclass
class SampleResult:
    """Outcome of one sample; the estimate fields are None when it was skipped.

    Attributes
    ----------
    status : SampleStatus
    t_s : float
        The sample's stamp, s.
    dt_s : float
        Step from the previous accepted sample, s (nan for the first and after a reset).
    quat_xyzw : ndarray (4,) or None
        Attitude of ``base_link`` in ``map``.
    covariance : ndarray (3, 3) or None
        Attitude error covariance about map x, y, z, rad².
    gyro_rps : ndarray (3,) or None
        Bias-corrected angular rate in ``base_link``, rad/s.
    accel_mps2 : ndarray (3,) or None
        Specific force in ``base_link`` (not bias-corrected), m/s².
    stationary : bool
    """

    status: SampleStatus
    t_s: float
    dt_s: float = float('nan')
    quat_xyzw: np.ndarray = None
    covariance: np.ndarray = None
    gyro_rps: np.ndarray = None
    accel_mps2: np.ndarray = None
    stationary: bool = False


@dataclass
class CompensatorStats:
    """Counters for diagnostics (since start)."""

    accepted: int = 0
    nonfinite: int = 0
    duplicate: int = 0
    out_of_order: int = 0
    gaps: int = 0
    resets: int = 0
    stationary_samples: int = 0
    standstill_vetoed: int = 0       # still to the IMU, moving to the odometry
    odometry_used: int = 0
    odometry_rejected: int = 0       # not finite, or out of order
    aiding_used: int = 0             # applied: linear update, reset or re-initialisation
    aiding_rejected: int = 0         # not applied, for any reason
    aiding_inconsistent: int = 0     # of those: failed the gate
    aiding_resets: int = 0           # of the used: applied as an attitude reset
    aiding_reinitialisations: int = 0

    @property
    def dropped(self):
        return self.nonfinite + self.duplicate + self.out_of_order


class AttitudeCompensator:
    """Attitude of the camera platform from raw IMU samples; see the module docstring.

    Parameters
    ----------
    config : CompensatorConfig
    """

    def __init__(self, config=None):
        self.config = config or CompensatorConfig()
        self.filter = AttitudeFilter(self.config.filter)
        self.filter.delayed_horizon_s = self.config.history_s
        self.zero_velocity = ZeroVelocityDetector(self.config.zero_velocity,
                                                  self.config.nominal_rate_hz)
        # Inside an IMU gap the attitude then is unknown (that is the gap's variance): an
        # aid stamped there has nothing to be compared with.
        self.history = AidingHistory(horizon_s=self.config.history_s,
                                     max_gap_s=self.config.gap_s)
        self.odometry_veto = OdometryVeto(self.config.odometry)
        self.stats = CompensatorStats()
        self.last_t_s = None
        self._rate_scale_rps = np.zeros(3)
        self._rate_scale_t_s = None
        self._since_rate_hold = _RATE_HOLD_EVERY
        self._gate_d2 = {dof: chi2_quantile(self.config.aiding_gate_probability, dof)
                         for dof in (1, 3)}
        # The inconsistent aids since the last applied one: (stamp, implied correction
        # (3,) map axes, its covariance (3, 3), the filter's correction quaternion then).
        self._inconsistent = deque(maxlen=max(1, self.config.aiding_reinit_count))
        self._aligning = True
        self._bias_known_rps = self.config.zero_velocity.max_rate_rps / 3.0
        mount = self.config.imu_mount_rpy_rad
        self._r_base_imu = quat_to_matrix(quat_from_rpy(*mount))
        self._mounted = bool(np.any(np.asarray(mount) != 0.0))

    # ------------------------------------------------------------------ samples
    def process(self, t_s, gyro_rps, accel_mps2):
        """Feed one raw IMU sample (``imu_link`` axes); see the module docstring.

        Parameters
        ----------
        t_s : float
            Sample stamp, s.
        gyro_rps : array_like (3,)
            Angular rate, rad/s.
        accel_mps2 : array_like (3,)
            Specific force, m/s² (+g on z at rest).

        Returns
        -------
        SampleResult
        """
        gyro = np.asarray(gyro_rps, dtype=float).reshape(3)
        accel = np.asarray(accel_mps2, dtype=float).reshape(3)
        # One sum catches any NaN or ±inf among the six values (and absurd ~1e308 ones).
        if not (math.isfinite(t_s) and math.isfinite(float(gyro.sum() + accel.sum()))):
            self.stats.nonfinite += 1
            return SampleResult(SampleStatus.NONFINITE, t_s)
        if self._mounted:
            gyro = self._r_base_imu @ gyro
            accel = self._r_base_imu @ accel

        if self.last_t_s is None:
            return self._start(t_s, gyro, accel, SampleStatus.INITIALIZED)
        dt = t_s - self.last_t_s
        if dt == 0.0:
            self.stats.duplicate += 1
            return SampleResult(SampleStatus.DUPLICATE, t_s, dt)
        if dt < 0.0:
            if -dt > self.config.backward_reset_s:
                self.stats.resets += 1
                return self._start(t_s, gyro, accel, SampleStatus.RESET, dt)
            self.stats.out_of_order += 1
            return SampleResult(SampleStatus.OUT_OF_ORDER, t_s, dt)

        status = SampleStatus.OK
        extra_var = 0.0
        if dt > self.config.gap_s:
            status = SampleStatus.GAP
            self.stats.gaps += 1
            # What the platform did during the gap is unknown beyond its recent rate (the
            # propagation uses the mean of the two bracketing rates), axis by axis: the
            # heading sway's rate is ten times roll's and pitch's.
            rate = np.maximum(self._rate_scale_rps,
                              np.abs(gyro - self.filter.gyro_bias_rps))
            extra_var = np.square(rate * dt)
            self.zero_velocity.reset()
        # The mean-rate test needs a bias known to well within its threshold (after the
        # static alignment or a long enough run), not the cold-start guess.
        known = self.filter.gyro_bias_std_rps.max() < self._bias_known_rps
        stationary = self.zero_velocity.push(gyro, accel,
                                             self.filter.gyro_bias_rps if known else None)
        if stationary and self.odometry_veto.vetoes(t_s):
            # Still to the IMU, but the odometry sees the train accelerating (or moving):
            # no hold, no zero-rate update, no standstill gravity, no static alignment.
            stationary = self.zero_velocity.stationary = False
            self.stats.standstill_vetoed += 1
        self._since_rate_hold += 1
        if self._since_rate_hold >= _RATE_HOLD_EVERY:
            self._hold_rate_scale(t_s)
        if stationary:
            self.stats.stationary_samples += 1
        if self._aligning and self.zero_velocity.full:
            self._aligning = False
            if stationary:
                self._align(gyro)
                return self._accept(t_s, dt, gyro, accel, status, stationary)
        self.filter.step(gyro, accel, dt, stationary, self.config.nominal_rate_hz, extra_var)
        return self._accept(t_s, dt, gyro, accel, status, stationary)

    def _hold_rate_scale(self, t_s):
        # Largest recent window RMS per axis, forgotten over GAP_RATE_MEMORY_S (see there).
        rms = self.zero_velocity.gyro_rms_rps(self.filter.gyro_bias_rps)
        if not np.all(np.isfinite(rms)):
            return
        if self._rate_scale_t_s is not None:
            decay = math.exp(-(t_s - self._rate_scale_t_s) / GAP_RATE_MEMORY_S)
            rms = np.maximum(self._rate_scale_rps * decay, rms)
        self._rate_scale_rps = rms
        self._rate_scale_t_s = t_s
        self._since_rate_hold = 0

    def _align(self, gyro):
        # Static alignment: the first window after a start was still, so the platform
        # has not turned since the start — go back to the starting (track) attitude and
        # take the window's mean rate as the bias, instead of keeping the drift the
        # unknown turn-on bias caused while the window filled.
        n = self.zero_velocity.window_samples
        noise = self.config.filter.gyro_noise_density_rps_rthz \
            * math.sqrt(self.config.nominal_rate_hz)
        self.filter.initialize(gyro, aligned_gyro_bias_rps=self.zero_velocity.window_mean[:3],
                               gyro_bias_std_rps=noise / math.sqrt(n))
        self._restart_history()
        _LOG.info('static alignment over %d still samples: gyro bias %s rad/s', n,
                  np.array2string(self.filter.gyro_bias_rps, precision=6))

    def _start(self, t_s, gyro, accel, status, dt=float('nan')):
        if status is SampleStatus.RESET:
            _LOG.info('IMU time jumped back by %.3f s: attitude filter reset', -dt)
        self.filter.initialize(gyro)
        self.zero_velocity.reset()
        self.zero_velocity.push(gyro, accel)
        self._aligning = True
        self._restart_history()
        return self._accept(t_s, dt, gyro, accel, status, False)

    def _restart_history(self):
        # The filter restarted (its corrections and lag integrals with it): the attitudes
        # before are not comparable with the new estimate.
        self.history.clear()
        self._inconsistent.clear()

    def _accept(self, t_s, dt, gyro, accel, status, stationary):
        self.last_t_s = t_s
        self.stats.accepted += 1
        f = self.filter
        quat = f.quat
        cov = f.attitude_covariance
        self.history.push(t_s, quat.tolist(), f._correction_q, *f.lag_integrals())
        return SampleResult(status, t_s, dt, quat, cov, f.corrected_rate(gyro),
                            accel, stationary)

    # ------------------------------------------------------------------ odometry
    def odometry(self, t_s, speed_mps, speed_var_m2ps2=None):
        """Feed the train's speed (the localizer's ``train/odometry``) at its stamp.

        While the newest usable speed is within ``odometry.timeout_s`` of an IMU sample
        and shows the train accelerating (or moving, when ``max_speed_mps`` is set), that
        sample is not taken for standstill, whatever the IMU's variance test says.
        Without recent odometry nothing changes.

        Returns
        -------
        str
            What :meth:`~imu_compensator.core.zero_velocity.OdometryVeto.push` did:
            ``'used'``, ``'uncertain'`` (speed σ too large: not used, not counted as
            rejected), ``'out_of_order'`` or ``'invalid'`` (non-finite; both counted in
            ``stats.odometry_rejected``).
        """
        status = self.odometry_veto.push(t_s, speed_mps, speed_var_m2ps2)
        if status == OdometryVeto.USED:
            self.stats.odometry_used += 1
        elif status != OdometryVeto.UNCERTAIN:
            self.stats.odometry_rejected += 1
        return status

    # ------------------------------------------------------------------ aiding
    def heading_aiding(self, t_s, yaw_rad, variance_rad2):
        """Fuse an external heading measurement (e.g. from vision) taken at ``t_s``.

        Compared with the estimate for ``t_s`` as now known (see the module docstring);
        the heading change since ``t_s`` comes from the gyro, far more accurate over a
        few hundred ms than any aiding measurement.

        Returns
        -------
        AidingResult
            False (counted, not raised) unless applied: ``t_s`` outside the kept
            history, values not finite or the variance not positive, or inconsistent
            with the estimate.
        """
        if not (np.isfinite(t_s) and np.isfinite(yaw_rad) and np.isfinite(variance_rad2)
                and variance_rad2 > 0.0):
            return self._rejected(AidingResult(AidingStatus.INVALID, t_s))
        ref = self._reference(t_s)
        if ref is None:
            return self._rejected(AidingResult(AidingStatus.OUTSIDE_HISTORY, t_s))
        q_then, shift, h = ref
        yaw_then = quat_to_rpy(quat_multiply(quat_from_rotvec(shift), q_then))[2]
        z = np.array([(yaw_rad - yaw_then + math.pi) % (2.0 * math.pi) - math.pi])
        implied_cov = np.diag([_UNSEEN_VAR_RAD2, _UNSEEN_VAR_RAD2, variance_rad2])
        return self._fuse(t_s, h[2:3], z, np.array([[variance_rad2]]),
                          np.array([0.0, 0.0, z[0]]), implied_cov)

    def attitude_aiding(self, t_s, quat_xyzw, covariance_rad2):
        """Fuse an external attitude measurement (e.g. the one a lamp shows) taken at
        ``t_s``: the attitude of ``base_link`` in ``map`` and its covariance about the
        map axes (3, 3), rad².

        Compared with the estimate for ``t_s`` as now known (see the module docstring).
        With the full covariance the filter sees which combination of roll, pitch and
        heading the measurement constrains, so an aid whose heading depends on the
        platform's tilt corrects the tilt as well, instead of passing the tilt error on
        to the heading as if it were noise.

        Returns
        -------
        AidingResult
            False (counted, not raised) unless applied: ``t_s`` outside the kept
            history, values not finite or the covariance not symmetric positive
            definite, or inconsistent with the estimate.
        """
        q = np.asarray(quat_xyzw, dtype=float).reshape(-1)
        cov = np.asarray(covariance_rad2, dtype=float)
        ok = (q.size == 4 and cov.shape == (3, 3) and np.isfinite(t_s)
              and np.all(np.isfinite(q)) and np.all(np.isfinite(cov))
              and np.linalg.norm(q) > 1e-6 and np.allclose(cov, cov.T, atol=1e-12)
              and np.all(np.linalg.eigvalsh(cov) > 0.0))
        if not ok:
            return self._rejected(AidingResult(AidingStatus.INVALID, t_s))
        ref = self._reference(t_s)
        if ref is None:
            return self._rejected(AidingResult(AidingStatus.OUTSIDE_HISTORY, t_s))
        q_then, shift, h = ref
        # What the aid measured against the attitude published for t_s,
        # R_meas = Exp(δ)·R_then, less what the estimate for t_s has moved since. Its
        # covariance is about its own attitude (R_true = Exp(ε)·R_meas); about R_then
        # that is δ + J_l(δ)⁻¹·ε: a lamp leaves its line of sight unseen by degrees, and
        # an aid degrees away from R_then turns that partly into what it sees.
        delta = quat_to_rotvec(quat_multiply(quat_normalize(q), quat_conjugate(q_then)))
        z = delta - shift
        j = _left_jacobian_inverse(delta)
        cov = j @ cov @ j.T
        return self._fuse(t_s, _left_jacobian_inverse(shift) @ h, z, cov, z, cov)

    def _reference(self, t_s):
        """What an aid stamped ``t_s`` is compared with, or None outside the history.

        Returns
        -------
        (ndarray (4,), ndarray (3,), ndarray (3, N_STATES))
            The attitude published for ``t_s``; the rotation (map axes, rad) the estimate
            for ``t_s`` has moved by since — the updates' corrections, and the drift the
            bias corrections since explain; and the rows that give the attitude error at
            ``t_s`` from the current error state: δθ_then = δθ_now + A·δb + W·δk, with
            A = ∫R dt and W = ∫R·diag(ω) dt since then.
        """
        got = self.history.lookup(t_s)
        if got is None:
            return None
        q_then, c_then, int_a_then, int_rb_then = got
        f = self.filter
        int_a_now, int_rb_now = f.lag_integrals()
        a = (np.asarray(int_a_now) - int_a_then).reshape(3, 3)
        drift = a @ f.gyro_bias_rps - (np.asarray(int_rb_now) - int_rb_then)
        c_now = f.correction_quat
        correction = quat_to_rotvec(quat_multiply(c_now, quat_conjugate(c_then)))
        # The gyro's own turn since then (U = C⁻¹·R), body axes, for the scale rows.
        u_then = quat_multiply(quat_conjugate(c_then), q_then)
        u_now = quat_multiply(quat_conjugate(c_now), f.quat)
        turn = quat_to_rotvec(quat_multiply(quat_conjugate(u_then), u_now))
        h = np.zeros((3, N_STATES))
        h[:, :3] = np.eye(3)
        h[:, 3:6] = a
        h[:, 6:] = quat_to_matrix(f.quat) * turn
        return q_then, correction + drift, h

    def _fuse(self, t_s, h, z, cov, implied, implied_cov):
        """Gate, then fuse as an update, a reset or a re-initialisation (module docstring)."""
        cfg = self.config
        dof = z.size
        gate = self._gate_d2[dof]
        f = self.filter
        since = f.clock_s - (self.last_t_s - t_s)
        d2, correction = f.aiding_statistics(h, z, cov, since)
        result = AidingResult(AidingStatus.USED, t_s, d2, dof, gate, float(np.linalg.norm(z)),
                              float(np.linalg.norm(correction)))
        if not d2 <= gate:
            result.status = AidingStatus.INCONSISTENT
            self.stats.aiding_inconsistent += 1
            if not self._agrees(t_s, implied, implied_cov):
                self._inconsistent.clear()
            self._inconsistent.append((t_s, implied, implied_cov, f.correction_quat))
            if cfg.aiding_reinit_count == 0 or len(self._inconsistent) < cfg.aiding_reinit_count:
                return self._rejected(result)
            # The estimate contradicted every one of the last aids and they agree: it is
            # the estimate that is wrong. Restart the attitude from the latest aid, its
            # covariance first inflated by the innovation.
            result.status = AidingStatus.REINITIALISED
            self.stats.aiding_reinitialisations += 1
            inflate = np.outer(implied, implied)
            if dof == 1:
                inflate = np.zeros((3, 3))
                inflate[2, 2] = z[0] ** 2
            f.update_aiding(h, z, cov, since, reset=True, inflate_rad2=inflate)
            _LOG.warning('%d consecutive aids agreed on a %.2f deg correction: attitude '
                         're-initialised from them', len(self._inconsistent),
                         math.degrees(float(np.linalg.norm(implied))))
        elif result.correction_rad > cfg.aiding_max_correction_rad:
            result.status = AidingStatus.RESET
            self.stats.aiding_resets += 1
            f.update_aiding(h, z, cov, since, reset=True)
        else:
            f.update_aiding(h, z, cov, since)
        self._inconsistent.clear()
        self.stats.aiding_used += 1
        return result

    def _agrees(self, t_s, implied, implied_cov):
        """Whether an inconsistent aid agrees with every one kept before it."""
        gate = self._gate_d2[3]
        c_now = self.filter.correction_quat
        bias_std = float(self.filter.gyro_bias_std_rps.max())
        for t_i, implied_i, cov_i, c_i in self._inconsistent:
            # What was a correction then is less what the estimate has moved since.
            moved = quat_to_rotvec(quat_multiply(c_now, quat_conjugate(c_i)))
            diff = implied_i - moved - implied
            tol = REINIT_AGREEMENT_STD_RAD ** 2 + (bias_std * abs(t_s - t_i)) ** 2
            if not diff @ np.linalg.solve(cov_i + implied_cov + np.eye(3) * tol, diff) <= gate:
                return False
        return True

    def _rejected(self, result):
        self.stats.aiding_rejected += 1
        return result

    # ------------------------------------------------------------------ read-outs
    @property
    def stationary(self):
        return self.zero_velocity.stationary

    @property
    def gyro_bias_rps(self):
        return self.filter.gyro_bias_rps.copy()

    @property
    def gyro_bias_std_rps(self):
        return self.filter.gyro_bias_std_rps
