"""Companion method 1: VLC + RSSI trilateration from per-lamp received optical power.

Each lamp's received power ``P_i`` (the photodiode separates the lamps by their codes)
is turned into a distance by inverting the Lambertian line-of-sight channel
(:mod:`vlc_common.core.optical_channel`, Komine & Nakagawa 2004)::

    P = P_t·(m + 1)·A·Ts·g / (2π) · cos^m φ · cos ψ / d²
    cos φ = α/d,  α = n_l·(p − l)        (lamp disc normal n_l, lamp l, PD p)
    cos ψ = β/d,  β = n_r·(l − p)        (PD normal n_r)
    ⇒  d = (P_t·(m + 1)·A·Ts·g/(2π) · α^m·β / P)^(1/(m+3))

``α`` and ``β`` are projections that depend on the PD position only through the lamp's
direction; for a wall lamp facing the track and a PD facing the wall they do not depend
on the chainage at all, otherwise (a yawed platform) the inversion and the position
are iterated to a fixed point. The PD pose is ``base_link``'s pose composed with the
PD mount; the attitude comes from ``imu/data`` (a 7.5° yaw turns the PD normal enough
to change ``cos ψ`` of a lamp 5 m ahead by 40 %, i.e. its distance by 10 %).

Position by generalised least squares over the lamps received: Gauss–Newton on the
residuals ``|p − l_i| − d_i(p)`` (the distance inverted at the current estimate; its
dependence on the estimate is part of the Jacobian) with their covariance: each
distance's own error (σ_d/d = σ_P/P/(m+3), independent per lamp: receiver noise and the
lamp-power tolerance) plus the errors common to every lamp of a sample, hence
correlated — the attitude error (it moves the PD on its 2.9 m lever and turns its
normal) and the platform's lateral/vertical offset from the track.

**Integration window.** A sample is the mean power over its window (20 ms: 0.67 m at
120 km/h), not the power at its centre; P ∝ d^−(m+3) is strongly convex near a lamp,
so the mean exceeds the centre value by up to a few per cent — a bias the χ² test
sees. With the train speed known (the node differentiates its own fixes), each
iteration divides the measured power by the model's window-mean/centre ratio at the
current estimate (``window_s``; 0 = point samples).

**Geometry (rank) check — why the track constraint.** All lamps of this tunnel lie on
one line (the left wall at a fixed height): collinear anchors fix only the distance to
that line and the position along it; the PD may sit anywhere on a circle around the
line, and the 3×3 normal matrix of a free 3-D solve is singular (rank 2). A free solve
is therefore refused for collinear lamps (``reason = 'collinear'``). The train runs on
the track, so ``base_link``'s lateral and vertical offsets are known (to vibration
level, mm) and the chainage is the only unknown: ``solve_mode = 'auto'`` uses the
free 3-D solve only when the lamps received are not collinear (≥ 3 lamps spanning a
plane, e.g. lamps on both walls), and the track-constrained 1-D solve otherwise. The
1-D solve needs ≥ ``min_lamps`` lamps (one lamp leaves the sign of the along-track
offset open) and enough information: a lamp abeam of the PD constrains nothing
(∂|p − l|/∂x = 0), so the solution's 1σ must be below ``max_sigma_m``; and the lamps
other than the nearest must tell the solution from its mirror image about the nearest
lamp (a far lamp at grazing incidence, whose power depends on the heading, may not:
the solution is then ``ambiguous``, not guessed).

No ROS here.
"""
from dataclasses import dataclass, field
import math

import numpy as np
from scipy.stats import chi2 as chi2_dist

from vlc_common.core.optical_channel import PhotodiodeConfig

SOLVE_MODES = ('auto', 'track', 'free')
#: Starts of the track-constrained solve tried at most.
MAX_STARTS = 2
#: Step of the numerical derivative of the inverted distances, m.
JACOBIAN_STEP_M = 1e-4


@dataclass
class RssiConfig:
    """Parameters of the RSSI localizer (SI units).

    Attributes
    ----------
    photodiode : PhotodiodeConfig
        The receiver's knowledge of the channel: PD mount and normal, optics, lamp power
        and order (must describe the actual photodiode). ``lamp_power_sigma_rel`` is
        used as the relative power error of every lamp.
    track_offset_yz_m : tuple of 2 floats
        Nominal lateral and vertical position of ``base_link`` in ``map`` (track
        constraint), m.
    track_sigma_yz_m : tuple of 2 floats
        1σ of ``base_link``'s lateral and vertical offset from the nominal (vibration,
        track irregularity), m; projected on each lamp's line of sight and added to
        the distance variance of the track-constrained solve.
    solve_mode : str
        ``auto`` (free 3-D solve when the lamps are not collinear, else track-
        constrained), ``track`` (always constrained), ``free`` (3-D only; collinear
        lamp sets are rejected).
    min_lamps : int
        Fewest lamps for a track-constrained solve (2: one lamp leaves the side open).
    collinear_tolerance_m : float
        Lamps whose second principal spread (RMS distance from their best-fit line) is
        below this are collinear, m.
    max_sigma_m : float
        Solutions whose along-track 1σ exceeds this are rejected (weak geometry), m.
    chi2_probability : float
        Solutions whose weighted residual exceeds this χ² quantile (n − unknowns dof)
        are rejected as inconsistent.
    distance_sigma_floor_m : float
        Smallest 1σ of an inverted distance (model error: a lamp is not exactly a
        Lambertian point source), m; keeps the residual covariance regular.
    separation_sigma : float
        A solution is ambiguous unless the lamps other than the nearest separate it
        from its mirror about the nearest lamp by this many σ.
    window_s : float
        Integration window of one power sample, s (1 / PD rate); 0 = point samples.
    attitude_sigma_rad : tuple of 3 floats
        Attitude error 1σ about map x, y, z when the caller gives no covariance, rad.
    max_iterations : int
        Gauss–Newton iterations per start.
    tolerance_m : float
        Convergence of a Gauss–Newton step, m.
    """

    photodiode: PhotodiodeConfig = field(default_factory=PhotodiodeConfig)
    track_offset_yz_m: tuple = (0.0, 0.0)
    track_sigma_yz_m: tuple = (0.004, 0.004)
    solve_mode: str = 'auto'
    min_lamps: int = 2
    collinear_tolerance_m: float = 0.05
    max_sigma_m: float = 0.5
    chi2_probability: float = 0.999
    distance_sigma_floor_m: float = 0.001
    separation_sigma: float = 5.0
    window_s: float = 0.02
    attitude_sigma_rad: tuple = (1e-3, 1e-3, 2e-3)
    max_iterations: int = 20
    tolerance_m: float = 1e-4

    def __post_init__(self):
        if self.solve_mode not in SOLVE_MODES:
            raise ValueError(f'solve_mode must be one of {SOLVE_MODES}, got {self.solve_mode!r}')
        if self.min_lamps < 2:
            raise ValueError('min_lamps must be >= 2 (one lamp leaves the side open)')
        if not (self.max_sigma_m > 0.0 and self.collinear_tolerance_m >= 0.0):
            raise ValueError('max_sigma_m must be > 0 and collinear_tolerance_m >= 0')
        if not 0.0 < self.chi2_probability < 1.0:
            raise ValueError('chi2_probability must be in (0, 1)')
        if not (self.window_s >= 0.0 and self.separation_sigma >= 0.0
                and self.distance_sigma_floor_m > 0.0):
            raise ValueError('window_s and separation_sigma must be >= 0, '
                             'distance_sigma_floor_m > 0')


@dataclass
class LampReading:
    """One lamp's received power in one photodiode sample.

    Attributes
    ----------
    uid : int
    position_m, normal : ndarray (3,)
        Lamp disc centre and unit normal in ``map`` (from the lamp map).
    power_w : float
        Received "on" power, W.
    power_sigma_w : float
        1σ of the receiver noise of ``power_w``, W.
    """

    uid: int
    position_m: np.ndarray
    normal: np.ndarray
    power_w: float
    power_sigma_w: float = 0.0


@dataclass
class RssiFix:
    """Result of one trilateration.

    Attributes
    ----------
    ok : bool
        A position was found and passed the geometry and consistency checks.
    reason : str
        ``ok`` or why not: ``too_few_lamps``, ``collinear``, ``weak_geometry``,
        ``inconsistent``, ``ambiguous`` (two consistent solutions), ``no_convergence``.
    mode : str
        ``track`` or ``free`` (the solve that ran).
    position_m : ndarray (3,)
        ``base_link`` in ``map``, m (NaN when not ok).
    covariance_m2 : ndarray (3, 3)
        Of ``position_m``; track mode: the chainage variance, zeros across the track.
    lamps_used : int
    chi2 : float
        Weighted residual Σ (|p − l_i| − d_i)²/σ_i².
    distances_m : ndarray (n,)
        Distances inverted from the powers at the solution, m.
    """

    ok: bool
    reason: str
    mode: str
    position_m: np.ndarray
    covariance_m2: np.ndarray
    lamps_used: int
    chi2: float = float('nan')
    distances_m: np.ndarray = field(default_factory=lambda: np.zeros(0))

    @property
    def chainage_sigma_m(self):
        return math.sqrt(max(float(self.covariance_m2[0, 0]), 0.0))


def channel_constant(config):
    """``P_t·(m + 1)·A·Ts·g/(2π)``: received power of a lamp 1 m away on both axes, W."""
    c = config
    return (c.lamp_optical_power_w * (c.order_m + 1.0) * c.area_m2 * c.filter_transmission
            * c.concentrator_gain / (2.0 * math.pi))


def _arrays(readings):
    """(lamps (n, 3), normals (n, 3), power (n,), noise (n,)) of a list of LampReading."""
    lamps = np.array([r.position_m for r in readings], dtype=float).reshape(-1, 3)
    normals = np.array([r.normal for r in readings], dtype=float).reshape(-1, 3)
    power = np.array([r.power_w for r in readings], dtype=float)
    noise = np.array([r.power_sigma_w for r in readings], dtype=float)
    return lamps, normals, power, noise


def _geometry(pd_position_m, pd_normal, lamps, normals):
    """d, α = n_l·(p − l), β = n_r·(l − p) for PD positions (K, 3) → (K, n) each."""
    v = np.asarray(pd_position_m, float).reshape(-1, 1, 3) - lamps[None]
    d = np.sqrt(np.einsum('kni,kni->kn', v, v))
    alpha = np.einsum('kni,ni->kn', v, normals)
    beta = -(v @ np.asarray(pd_normal, float))
    return d, alpha, beta


def model_power(pd_position_m, pd_normal, lamp_positions_m, lamp_normals, config,
                field_of_view=True):
    """Received "on" power of each lamp at PD positions (the channel model), W.

    ``pd_position_m`` (K, 3) or (3,); returns (K, n). Zero behind a lamp or the PD, and
    with ``field_of_view`` outside the receiver's field of view.
    """
    d, alpha, beta = _geometry(pd_position_m, pd_normal,
                               np.asarray(lamp_positions_m, float).reshape(-1, 3),
                               np.asarray(lamp_normals, float).reshape(-1, 3))
    return _power(d, alpha, beta, config, field_of_view)


def _power(d, alpha, beta, config, field_of_view):
    m = config.order_m
    power = (channel_constant(config) * np.maximum(alpha, 0.0) ** m * np.maximum(beta, 0.0)
             / d ** (m + 3.0))
    if field_of_view:
        power = np.where(beta >= d * math.cos(math.radians(config.fov_half_angle_deg)),
                         power, 0.0)
    return power


def window_factor(pd_position_m, pd_normal, readings, velocity_mps, window_s, config,
                  points=5):
    """Mean power over the integration window over the power at its centre, per lamp.

    The PD moves at ``velocity_mps`` (3,) during the window; midpoint rule over
    ``points`` instants. Returns (n,): ones for a zero window or speed; NaN for a lamp
    the estimate puts at the edge of the field of view during the window — received
    for part of the window only, its mean power changes by a whole sub-interval for a
    centimetre of position, so it is not used (the edge of a real concentrator's
    acceptance is also its least known part).
    """
    lamps, normals, _, _ = _arrays(readings)
    return _window_factor(pd_position_m, pd_normal, lamps, normals, velocity_mps, window_s,
                          config, points)


def _window_factor(pd_position_m, pd_normal, lamps, normals, velocity_mps, window_s, config,
                   points=5):
    if lamps.shape[0] == 0:
        return np.ones(0)
    moving = window_s > 0.0 and np.any(velocity_mps)
    tau = ((np.arange(points) + 0.5) / points - 0.5) * window_s if moving else np.zeros(1)
    p = np.asarray(pd_position_m, float) + np.outer(tau, velocity_mps)
    d, alpha, beta = _geometry(np.vstack([p, pd_position_m]), pd_normal, lamps, normals)
    power = _power(d, alpha, beta, config, field_of_view=False)
    inside = beta[:-1] >= d[:-1] * math.cos(math.radians(config.fov_half_angle_deg))
    with np.errstate(invalid='ignore', divide='ignore'):
        ratio = power[:-1].mean(axis=0) / power[-1]
    usable = np.all(inside, axis=0) & np.isfinite(ratio) & (ratio > 0.0)
    return np.where(usable, ratio, np.nan)


def distances_from_power(readings, pd_position_m, pd_normal, config, factor=None):
    """Distances (and their 1σ) of each lamp from its received power (channel inversion).

    Parameters
    ----------
    readings : list of LampReading
    pd_position_m, pd_normal : ndarray (3,)
        Current estimate of the PD position and its unit normal in ``map``; they give
        the projections α = n_l·(p − l) and β = n_r·(l − p) of the inversion.
    config : PhotodiodeConfig
    factor : ndarray (n,), optional
        Measured power over the power at the estimate (:func:`window_factor`); the
        powers are divided by it before the inversion.

    Returns
    -------
    d_m, sigma_m : ndarray (n,)
        NaN for a lamp the estimate puts behind the lamp or the PD (α or β ≤ 0) or with
        a non-positive power.
    """
    return _invert(*_arrays(readings), pd_position_m, pd_normal, config, factor)


def _invert(lamps, normals, power, noise, pd_position_m, pd_normal, config, factor=None):
    m = config.order_m
    if factor is not None:
        power, noise = power / factor, noise / factor
    v = np.asarray(pd_position_m, float) - lamps
    alpha = np.einsum('ni,ni->n', v, normals)
    beta = -(v @ np.asarray(pd_normal, float))
    ok = (alpha > 0.0) & (beta > 0.0) & (power > 0.0) & np.isfinite(power)
    with np.errstate(invalid='ignore', divide='ignore'):
        d = (channel_constant(config) * alpha ** m * beta / power) ** (1.0 / (m + 3.0))
        rel = np.sqrt((noise / power) ** 2 + config.lamp_power_sigma_rel ** 2)
    return np.where(ok, d, np.nan), np.where(ok, d * rel / (m + 3.0), np.nan)


def collinear(points_m, tolerance_m):
    """True when the points lie within ``tolerance_m`` (RMS) of one straight line.

    The second singular value of the centred point matrix over √n is the RMS distance
    from the best-fit line (the first principal axis).
    """
    p = np.asarray(points_m, dtype=float).reshape(-1, 3)
    if p.shape[0] < 3:
        return True
    s = np.linalg.svd(p - p.mean(axis=0), compute_uv=False)
    return bool(s[1] / math.sqrt(p.shape[0]) <= tolerance_m)


def _failed(reason, mode, n):
    return RssiFix(ok=False, reason=reason, mode=mode, position_m=np.full(3, np.nan),
                   covariance_m2=np.full((3, 3), np.nan), lamps_used=n)


def _chi2_limit(dof, probability):
    return float(chi2_dist.ppf(probability, dof)) if dof > 0 else math.inf


def trilaterate(readings, R_map_base, config, speed_mps=0.0, attitude_cov_rad2=None,
                predicted_chainage_m=None):
    """Position of ``base_link`` from one sample's lamp readings.

    Parameters
    ----------
    readings : list of LampReading
    R_map_base : ndarray (3, 3)
        Platform attitude (``imu/data``), or identity when unknown.
    config : RssiConfig
    speed_mps : float
        Along-track speed during the sample, m/s (integration-window correction).
    attitude_cov_rad2 : ndarray (3, 3), optional
        Covariance of the attitude error about map x, y, z, rad²;
        ``config.attitude_sigma_rad`` when None.
    predicted_chainage_m : float, optional
        A prediction of the chainage (e.g. the last fix moved on by the speed): one more
        start of the track-constrained solve (it never chooses between solutions).

    Returns
    -------
    RssiFix
    """
    readings = [r for r in readings if math.isfinite(r.power_w) and r.power_w > 0.0]
    n = len(readings)
    lamps = np.array([r.position_m for r in readings], dtype=float).reshape(-1, 3)
    is_collinear = collinear(lamps, config.collinear_tolerance_m)
    if attitude_cov_rad2 is None or not np.all(np.isfinite(attitude_cov_rad2)):
        attitude_cov_rad2 = np.diag(np.square(config.attitude_sigma_rad))
    problem = _Problem(readings, np.asarray(R_map_base, dtype=float), config, speed_mps,
                       np.asarray(attitude_cov_rad2, dtype=float))
    problem.warm_start = predicted_chainage_m
    if config.solve_mode == 'free' or (config.solve_mode == 'auto' and not is_collinear
                                       and n >= 3):
        if n < 3:
            return _failed('too_few_lamps', 'free', n)
        if is_collinear:
            return _failed('collinear', 'free', n)
        return _solve_free(problem)
    if n < config.min_lamps:
        return _failed('too_few_lamps', 'track', n)
    return _solve_track(problem)


class _Problem:
    """One sample's readings with the PD mount and normal turned by the attitude."""

    def __init__(self, readings, R, config, speed_mps, attitude_cov):
        pdc = config.photodiode
        self.readings = readings
        self.config = config
        self.attitude_cov = attitude_cov
        self.warm_start = None
        self.mount = R @ np.asarray(pdc.mount_xyz_m)      # PD offset from base_link in map
        self.n_r = R @ pdc.normal_base
        self.lamps, self.normals, self.power, self.noise = _arrays(readings)
        self.velocity = np.array([float(speed_mps) if math.isfinite(speed_mps) else 0.0,
                                  0.0, 0.0])

    def distances(self, p):
        """Distances and 1σ inverted at PD position ``p``, window-corrected."""
        pdc = self.config.photodiode
        factor = _window_factor(p, self.n_r, self.lamps, self.normals, self.velocity,
                                self.config.window_s, pdc)
        return _invert(self.lamps, self.normals, self.power, self.noise, p, self.n_r, pdc,
                       factor)

    def residual_covariance(self, p, d, sd, track):
        """Covariance (n, n) of the residuals ``|p − l_i| − d_i`` at PD position ``p``.

        The distances' own errors (power noise, lamp tolerance: independent per lamp),
        plus two errors common to every lamp of the sample, hence correlated: the
        attitude error δθ (it moves the PD by δθ × c and turns its normal, changing
        every cos ψ: δr_i = δθ·[c × v̂_i − d_i/((m+3)·β_i)·(n_r × (l_i − p))]) and,
        with ``track``, the platform's lateral and vertical offset (δr_i = v̂_i·δp).
        """
        m = self.config.photodiode.order_m
        v = p - self.lamps
        rng = np.linalg.norm(v, axis=1)
        unit = v / rng[:, None]
        beta = -v @ self.n_r
        ok = np.isfinite(d)
        cov = np.diag(np.where(ok, sd, 0.0) ** 2 + self.config.distance_sigma_floor_m ** 2)
        dd = np.where(ok, d, 0.0)
        A = (_cross(self.mount, unit)
             + (dd / ((m + 3.0) * beta))[:, None] * _cross(self.n_r, -v))
        cov += A @ self.attitude_cov @ A.T
        if track:
            B = unit[:, 1:]
            cov += B @ np.diag(np.square(self.config.track_sigma_yz_m)) @ B.T
        return cov


def _cross(a, b):
    """A × b for a (3,) and rows b (n, 3) (numpy.cross is slow on small arrays)."""
    return np.stack([a[1] * b[:, 2] - a[2] * b[:, 1], a[2] * b[:, 0] - a[0] * b[:, 2],
                     a[0] * b[:, 1] - a[1] * b[:, 0]], axis=1)


def _solve_track(problem):
    """1-D solve along the track: ``base_link`` at (s, y0, z0); see the module docstring."""
    config = problem.config
    y0, z0 = config.track_offset_yz_m
    lamps, mount = problem.lamps, problem.mount

    def pd_at(s):
        return np.array([s, y0, z0]) + mount

    # Starts: each lamp's distance, inverted with the PD abeam of it, on either side
    # (those within a metre merged, the cheapest MAX_STARTS by residual), and the
    # caller's prediction. All are solved: a second consistent solution far from the
    # best is an ambiguity (a lamp nearly abeam fixes |s − x_lamp| but not its sign,
    # and the far lamps that would tell may carry little weight), reported, not guessed.
    starts = []
    for i in range(len(problem.readings)):
        abeam = lamps[i, 0] - mount[0]
        d, _ = problem.distances(pd_at(abeam))
        rho = np.linalg.norm(pd_at(abeam)[1:] - lamps[i, 1:])
        along = math.sqrt(max(float(d[i]) ** 2 - rho ** 2, 0.0)) if np.isfinite(d[i]) else 0.0
        starts += [abeam - along, abeam + along]
    starts = sorted(_merge(starts, 1.0),
                    key=lambda s0: _start_cost(s0, problem, pd_at))[:MAX_STARTS]
    warm = problem.warm_start
    if warm is not None and math.isfinite(warm) and all(abs(warm - s0) > 0.5 for s0 in starts):
        starts.append(warm)
    results = [r for r in (_gauss_newton_track(s0, problem, pd_at) for s0 in starts)
               if r is not None]
    if not results:
        return _failed('no_convergence', 'track', len(problem.readings))
    # The solutions explaining the most lamps, the smallest residual first.
    most = max(int(np.count_nonzero(np.isfinite(r[3]))) for r in results)
    best = min((r for r in results if np.count_nonzero(np.isfinite(r[3])) == most),
               key=lambda r: r[1])
    sigma = 1.0 / math.sqrt(best[2]) if best[2] > 0.0 else math.inf
    ambiguous = any(
        r[1] <= _chi2_limit(int(np.count_nonzero(np.isfinite(r[3]))) - 1,
                            config.chi2_probability)
        and abs(r[0] - best[0]) > max(3.0 * sigma, 0.1) for r in results if r is not best)
    ambiguous = ambiguous or _mirror_ambiguous(best, problem, pd_at)
    s, cost, info, d = best
    n = int(np.count_nonzero(np.isfinite(d)))
    cov = np.zeros((3, 3))
    cov[0, 0] = 1.0 / info if info > 0.0 else math.inf
    fix = RssiFix(ok=True, reason='ok', mode='track', position_m=np.array([s, y0, z0]),
                  covariance_m2=cov, lamps_used=n, chi2=cost, distances_m=d)
    if not math.sqrt(cov[0, 0]) <= config.max_sigma_m:
        fix.ok, fix.reason = False, 'weak_geometry'
    elif cost > _chi2_limit(n - 1, config.chi2_probability):
        fix.ok, fix.reason = False, 'inconsistent'
    elif ambiguous:
        fix.ok, fix.reason = False, 'ambiguous'
    return fix


def _mirror_ambiguous(solution, problem, pd_at):
    """Whether the other lamps can tell the solution from its mirror about the nearest lamp.

    The nearest lamp fixes |s − x_lamp| (its abeam point) but not the side; the mirror
    position lies ``Δ = 2·|s − x_abeam|`` away. The other lamps' information about
    ``s`` (their block of the generalised least squares) must separate the two by
    ``separation_sigma`` standard deviations.
    """
    config = problem.config
    s, _, _, d = solution
    p = pd_at(s)
    used = np.flatnonzero(np.isfinite(d))
    dx = p[0] - problem.lamps[used, 0]
    k = int(np.argmin(np.abs(dx)))
    others = np.delete(np.arange(used.size), k)
    if others.size == 0:
        return True
    _, sd = problem.distances(p)
    C = problem.residual_covariance(p, d, sd, track=True)[np.ix_(used, used)]
    v = p - problem.lamps[used]
    J = v[:, 0] / np.linalg.norm(v, axis=1)
    Co = C[np.ix_(others, others)]
    info = float(J[others] @ np.linalg.solve(Co, J[others]))
    return not 2.0 * abs(dx[k]) * math.sqrt(max(info, 0.0)) >= config.separation_sigma


def _merge(values, tolerance):
    """Sorted values with runs closer than ``tolerance`` replaced by their mean."""
    out, group = [], []
    for v in sorted(values):
        if group and v - group[-1] > tolerance:
            out.append(sum(group) / len(group))
            group = []
        group.append(v)
    if group:
        out.append(sum(group) / len(group))
    return out


def _start_cost(s, problem, pd_at):
    """Unweighted residual sum of squares at a start (a cheap ranking), m²."""
    p = pd_at(s)
    d, _ = problem.distances(p)
    r = np.linalg.norm(p - problem.lamps, axis=1) - d
    return float(np.sum(np.where(np.isfinite(r), r * r, 100.0)))


def _gauss_newton_track(s, problem, pd_at):
    """(s, cost, information, distances) from one start, or None (no valid distances).

    Generalised least squares: the residual covariance is not diagonal (common
    attitude and track errors, :meth:`_Problem.residual_covariance`).
    """
    config = problem.config
    for iteration in range(config.max_iterations + 1):
        p = pd_at(s)
        d, sd = problem.distances(p)
        # A lamp the estimate cannot invert (NaN) carries no weight in this iteration.
        ok = np.isfinite(d)
        if np.count_nonzero(ok) < config.min_lamps:
            return None
        v = p - problem.lamps[ok]
        rng = np.linalg.norm(v, axis=1)
        r = rng - d[ok]
        # ∂r/∂s: the range's, minus the inverted distance's (α, β depend on the PD
        # position: a yawed PD normal has an along-track part), the latter numerically.
        d_step, _ = problem.distances(pd_at(s + JACOBIAN_STEP_M))
        J = v[:, 0] / rng - np.nan_to_num((d_step[ok] - d[ok]) / JACOBIAN_STEP_M)
        C = problem.residual_covariance(p, d, sd, track=True)[np.ix_(ok, ok)]
        W = np.linalg.inv(C)
        info = float(J @ W @ J)
        if not info > 0.0:
            return None
        step = -float(J @ W @ r) / info
        if abs(step) < config.tolerance_m or iteration == config.max_iterations:
            return s, float(r @ W @ r), info, d
        s += float(np.clip(step, -5.0, 5.0))
    return None


def _solve_free(problem):
    """3-D Gauss–Newton on the PD position (non-collinear lamps); see the module docstring."""
    config = problem.config
    lamps, n = problem.lamps, len(problem.readings)
    normals = np.array([r.normal for r in problem.readings])
    # Start in front of the lamps (the side their normals face) at the track height.
    p = lamps.mean(axis=0) + 2.0 * normals.mean(axis=0)
    p[1:] = np.array(config.track_offset_yz_m) + problem.mount[1:]
    for iteration in range(config.max_iterations + 1):
        d, sd = problem.distances(p)
        if not np.all(np.isfinite(d)):
            return _failed('no_convergence', 'free', n)
        v = p - lamps
        rng = np.linalg.norm(v, axis=1)
        # ∂r/∂p: the ranges', minus the inverted distances' (numerically: α and β, and
        # so every distance, move with the PD).
        J = v / rng[:, None]
        for axis in range(3):
            dp = np.zeros(3)
            dp[axis] = JACOBIAN_STEP_M
            d_step, _ = problem.distances(p + dp)
            J[:, axis] -= np.nan_to_num((d_step - d) / JACOBIAN_STEP_M)
        W = np.linalg.inv(problem.residual_covariance(p, d, sd, track=False))
        info = J.T @ W @ J
        if np.linalg.cond(info) > 1e10:                    # rank check of the normal matrix
            return _failed('weak_geometry', 'free', n)
        step = -np.linalg.solve(info, J.T @ W @ (rng - d))
        norm = float(np.linalg.norm(step))
        if norm < config.tolerance_m or iteration == config.max_iterations:
            break
        p = p + (step if norm <= 5.0 else step * 5.0 / norm)
    cost = float((rng - d) @ W @ (rng - d))
    cov = np.linalg.inv(info)
    fix = RssiFix(ok=True, reason='ok', mode='free', position_m=p - problem.mount,
                  covariance_m2=cov, lamps_used=n, chi2=cost, distances_m=d)
    if not math.sqrt(max(cov[0, 0], 0.0)) <= config.max_sigma_m:
        fix.ok, fix.reason = False, 'weak_geometry'
    elif cost > _chi2_limit(n - 3, config.chi2_probability):
        fix.ok, fix.reason = False, 'inconsistent'
    return fix
