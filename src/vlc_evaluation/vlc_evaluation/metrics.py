"""Error metrics of the evaluation protocols (``shared/EVALUATION.md``).

Everything takes plain arrays: stamps in seconds (float64), positions (N, 3) in metres in
``map``. Errors are Euclidean distances between the estimated and the true position of
``base_link``; the along-track component is the x difference (straight track).
"""
from dataclasses import asdict, dataclass

import numpy as np


def interpolate_positions(t_query, t_ref, xyz_ref):
    """Linear interpolation of ``xyz_ref`` (N, 3) at ``t_query``; NaN outside [t0, tN]."""
    t_query = np.asarray(t_query, dtype=float)
    t_ref = np.asarray(t_ref, dtype=float)
    xyz_ref = np.asarray(xyz_ref, dtype=float).reshape(-1, 3)
    order = np.argsort(t_ref, kind='stable')
    t_ref, xyz_ref = t_ref[order], xyz_ref[order]
    out = np.full((t_query.shape[0], 3), np.nan)
    if t_ref.shape[0] < 2:
        return out
    inside = (t_query >= t_ref[0]) & (t_query <= t_ref[-1])
    for axis in range(3):
        out[inside, axis] = np.interp(t_query[inside], t_ref, xyz_ref[:, axis])
    return out


def pose_errors(t_est, xyz_est, t_true, xyz_true):
    """Errors of estimates against interpolated truth.

    Returns (euclidean (N,), along_track (N,), signed, estimate − truth), NaN where the
    truth does not cover the estimate's stamp.
    """
    truth = interpolate_positions(t_est, t_true, xyz_true)
    diff = np.asarray(xyz_est, dtype=float).reshape(-1, 3) - truth
    return np.linalg.norm(diff, axis=1), diff[:, 0]


@dataclass
class ErrorSummary:
    """Error statistics in metres; ``misses`` counts test points with no estimate."""

    count: int
    misses: int
    max_m: float
    mean_m: float
    min_m: float
    p50_m: float
    p75_m: float
    p90_m: float
    p95_m: float
    rms_m: float

    def as_dict(self):
        return asdict(self)


def cm_text(value):
    """A length in metres as centimetres with two decimals for a table; '–' for none."""
    return '–' if value is None or not np.isfinite(value) else f'{100.0 * value:.2f}'


def summarize(errors_m, misses=0):
    """Summary statistics of absolute errors (NaNs are counted as misses)."""
    e = np.abs(np.asarray(errors_m, dtype=float).ravel())
    misses = int(misses) + int(np.count_nonzero(~np.isfinite(e)))
    e = e[np.isfinite(e)]
    if e.size == 0:
        nan = float('nan')
        return ErrorSummary(0, misses, nan, nan, nan, nan, nan, nan, nan, nan)
    p50, p75, p90, p95 = np.percentile(e, [50, 75, 90, 95])
    return ErrorSummary(count=int(e.size), misses=misses, max_m=float(e.max()),
                        mean_m=float(e.mean()), min_m=float(e.min()), p50_m=float(p50),
                        p75_m=float(p75), p90_m=float(p90), p95_m=float(p95),
                        rms_m=float(np.sqrt(np.mean(e * e))))


def test_point_instants(t_true, chainage_true, lamp_chainages, distances_m):
    """Instants at which the train passes ``distances_m`` before each lamp.

    ``chainage_true`` must be non-decreasing over ``t_true`` where the train moves (the
    dynamic protocol runs at constant speed). Returns (instants (M,), distance (M,),
    lamp chainage (M,)) for every crossing inside the run.
    """
    t_true = np.asarray(t_true, dtype=float)
    s = np.asarray(chainage_true, dtype=float)
    instants, dists, lamps = [], [], []
    for lamp_x in np.asarray(lamp_chainages, dtype=float):
        for d in np.asarray(distances_m, dtype=float):
            target = lamp_x - d
            if target < s[0] or target > s[-1]:
                continue
            k = int(np.searchsorted(s, target))
            if k == 0 or s[k] == s[k - 1]:
                continue
            frac = (target - s[k - 1]) / (s[k] - s[k - 1])
            instants.append(t_true[k - 1] + frac * (t_true[k] - t_true[k - 1]))
            dists.append(d)
            lamps.append(lamp_x)
    return np.array(instants), np.array(dists), np.array(lamps)


def errors_at_instants(instants, t_est, xyz_est, t_true, xyz_true, max_gap_s=0.1):
    """Estimate interpolated at ``instants`` minus truth there; NaN (a miss) where no
    estimate lies within ``max_gap_s`` on both sides of the instant.
    """
    instants = np.asarray(instants, dtype=float)
    t_est = np.asarray(t_est, dtype=float)
    est = interpolate_positions(instants, t_est, xyz_est)
    n = t_est.size
    k = np.searchsorted(t_est, instants)
    before = t_est[np.clip(k - 1, 0, max(n - 1, 0))] if n else np.zeros_like(instants)
    after = t_est[np.clip(k, 0, max(n - 1, 0))] if n else np.zeros_like(instants)
    covered = ((k > 0) & (k < n) & (instants - before <= max_gap_s)
               & (after - instants <= max_gap_s))
    exact = np.isin(instants, t_est)
    est[~(covered | exact)] = np.nan
    truth = interpolate_positions(instants, t_true, xyz_true)
    diff = est - truth
    return np.linalg.norm(diff, axis=1), diff[:, 0]


def covariance_consistency(diff_xyz, cov_xyz, n_sigma=3.0):
    """Fraction of errors inside the n-σ bound of the published covariance.

    Per axis: |e_i| ≤ n·sqrt(C_ii) on all three axes. ``diff_xyz`` (N, 3), ``cov_xyz``
    (N, 3, 3).
    """
    diff = np.asarray(diff_xyz, dtype=float).reshape(-1, 3)
    sig = np.sqrt(np.clip(np.diagonal(np.asarray(cov_xyz, dtype=float), axis1=1, axis2=2),
                          0.0, None))
    inside = np.all(np.abs(diff) <= n_sigma * sig + 1e-12, axis=1)
    return float(np.mean(inside)) if inside.size else float('nan')
