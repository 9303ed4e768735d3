"""The disparity error of the rectified pair, learnt cell by cell of the image from the
lamps themselves (the stereo range calibration a train learns and keeps).

**Why.** A good checkerboard calibration still leaves the rectified pair a disparity
error of a few tenths of a pixel, and not one offset: the right camera's residual
rotation about the vertical axis gives ``f·δψ·(1 + x²)``, a focal-length mismatch a term
in ``x``, the principal points a constant, the distortion residuals the rest. On the
`realistic` rig it was +0.34 px at the image centre and +0.82 px at the right edge on one
installation, −0.03 … +0.20 px on another. A lamp 10 m ahead has 12 px of disparity:
0.6 px is a range error of half a metre, so the fix leans on the lamp's direction, whose
attitude and mount errors grow with the range too — a standing train 10 m before a lamp
read 10 cm off.

**Measurement, free of the attitude.** For a confirmed lamp the filter's chainage ``s``
(before this fix) puts the left camera at ``c = track(s) + R·t_cb`` and the surveyed lamp
at range ``r = |lamp − c|``; the rectified ray of the spot ``(x, y) = ((u − cx)/fx,
(v − cy)/fy)`` turns that range into the depth ``Z = r/√(1 + x² + y²)``, so the
disparity the pair should show is ``fx·b/Z`` and the residual is

    δd = d − fx·b·√(1 + x² + y²)/r.

No direction enters (a range is rotation-free; ``R`` moves only the short lever
``t_cb``), so neither the IMU attitude nor the mount angles reach ``δd``. The filter's
own error ``σ_s`` reaches it as ``fx·b·√(1 + x² + y²)·|along|/r³·σ_s``: large for a near
lamp (a 2 cm chainage error is 0.3 px at 3 m), small far away (0.03 px at 10 m), which
is exactly where the disparity error costs most. A residual is used only when that
reference term is below ``max_reference_sigma_px``; the filter, which leans on near
lamps, is then a reference the far lamps' disparity cannot pull with it.

**Model.** The image is cut into square cells (``cell_px``) of the rectified left image;
each cell keeps the sufficient statistics of a weighted straight line ``δd = a + b·(u −
u_c)`` over its residuals (slope prior ``slope_sigma``), and counts the lamp passes (one
lamp, one run) behind it. A cell is used once ``min_passes`` passes are in it. Its 1σ:
the larger of the line's statistical 1σ and the residual scatter over √passes (the
residuals of one pass share the reference's error), times ``sigma_inflation``, never
below ``sigma_floor_px``; the fix states it in place of the calibration's disparity σ.

**Cells no pass reaches.** The residuals come from lamps ≥ ``min_along_m`` ahead whose
reference is good, so the image's outer columns, where a lamp 1–5 m ahead of a standing
train stands, are rarely learnt. The error is smooth over the image (the terms above), so
such a cell borrows the offset of the nearest learnt cell at most
``extrapolate_cells`` cells away (Euclidean in cells; ties: the nearer column, then
the nearer row), with the borrowed cell's 1σ plus ``extrapolation_sigma_fraction`` of the
offset, so a fix leans on it only as far as it may be wrong (0 cells: off, such a spot
keeps the calibration's σ).

**Kept by the train.** The cells' sums are what the kept file holds
(:mod:`.disparity_map_file`): a new run adds to them, so passes accumulate; the vehicle
id and the calibration's fx·b guard against another train's or another calibration's map.
"""
from dataclasses import dataclass
import math

import numpy as np


@dataclass
class DisparityMapConfig:
    """Switches and thresholds of :class:`DisparityMap` (px, m)."""

    cell_px: float = 64.0
    max_reference_sigma_px: float = 0.12   # the filter's chainage σ mapped into d
    noise_px: float = 0.03                 # per residual: spot centres, survey
    min_passes: int = 2                    # lamp passes in a cell before it is used
    slope_sigma: float = 0.002             # prior 1σ of the in-cell slope, px per px
    sigma_inflation: float = 3.0
    sigma_floor_px: float = 0.1            # the stated σ never falls below this
    max_state_sigma_m: float = 0.10        # a less certain filter is no reference
    min_along_m: float = 1.0               # lamps nearer along the track: not used
    extrapolate_cells: int = 6             # unknown cell: nearest learnt one this near
    extrapolation_sigma_fraction: float = 0.5  # of the borrowed offset, added to its 1σ

    def __post_init__(self):
        values = (self.cell_px, self.max_reference_sigma_px, self.noise_px,
                  self.slope_sigma, self.sigma_inflation, self.sigma_floor_px,
                  self.max_state_sigma_m)
        if not all(math.isfinite(float(v)) and float(v) > 0.0 for v in values):
            raise ValueError('disparity map: cell size, sigmas and inflation must be > 0')
        if int(self.min_passes) < 1:
            raise ValueError('disparity map: min_passes must be >= 1')
        if int(self.extrapolate_cells) < 0 or not (
                math.isfinite(float(self.extrapolation_sigma_fraction))
                and float(self.extrapolation_sigma_fraction) >= 0.0):
            raise ValueError('disparity map: extrapolate_cells and '
                             'extrapolation_sigma_fraction must be >= 0')


#: The sums a cell keeps (weighted: w = 1/σ², x = u − u_c, y = δd).
CELL_SUMS = ('sw', 'swx', 'swxx', 'swy', 'swxy', 'swyy')


@dataclass
class Cell:
    sw: float = 0.0
    swx: float = 0.0
    swxx: float = 0.0
    swy: float = 0.0
    swxy: float = 0.0
    swyy: float = 0.0
    residuals: int = 0
    passes: int = 0

    def add(self, x, y, w):
        self.sw += w
        self.swx += w * x
        self.swxx += w * x * x
        self.swy += w * y
        self.swxy += w * x * y
        self.swyy += w * y * y
        self.residuals += 1

    def merged(self, other):
        out = Cell(**{k: getattr(self, k) + getattr(other, k) for k in CELL_SUMS})
        out.residuals = self.residuals + other.residuals
        out.passes = self.passes + other.passes
        return out

    def line(self, slope_sigma):
        """(a, b, cov (2, 2), scatter² px²) of the weighted line y = a + b·x."""
        H = np.array([[self.sw, self.swx], [self.swx, self.swxx + slope_sigma ** -2]])
        g = np.array([self.swy, self.swxy])
        cov = np.linalg.inv(H)
        a, b = cov @ g
        # weighted mean square residual about the line
        ss = (self.swyy - 2 * a * self.swy - 2 * b * self.swxy + a * a * self.sw
              + 2 * a * b * self.swx + b * b * self.swxx)
        return float(a), float(b), cov, max(float(ss) / self.sw, 0.0)


class DisparityMap:
    """Learnt disparity error per image cell; see the module docstring.

    ``kept``: {(i, j): Cell} of earlier runs (the kept file), added to this run's;
    ``kept_fx_b``: the fx·b (px·m) they were learnt on (checked against the calibration
    in use by :meth:`check_calibration`).
    """

    def __init__(self, config=None, kept=None, kept_fx_b=None):
        self.config = config or DisparityMapConfig()
        self.kept = dict(kept or {})
        self.kept_fx_b = kept_fx_b
        self.refused = ''             # why the kept cells were dropped ('' = they were not)
        self.run = {}                 # (i, j) -> Cell of this run
        self._passes = set()          # (cell, lamp uid) counted this run
        self._cache = {}              # key -> estimate in use (own or borrowed)
        self._own_cache = {}          # key -> the cell's own estimate

    def _key(self, u, v):
        c = self.config.cell_px
        return int(math.floor(u / c)), int(math.floor(v / c))

    def cell(self, key):
        """Kept + this run's sums of a cell (None when it has none)."""
        kept, run = self.kept.get(key), self.run.get(key)
        if kept is None:
            return run
        return kept if run is None else kept.merged(run)

    def cells(self):
        """Every cell with data: {(i, j): Cell} (kept + this run)."""
        return {k: self.cell(k) for k in set(self.kept) | set(self.run)}

    # ------------------------------------------------------------------ use
    def check_calibration(self, fx_b_px_m):
        """Drop the kept cells if they were learnt on another calibration (fx·b differs
        by more than 1e-6 of it): they describe another rectified pair. Returns
        ``refused``.
        """
        if self.kept and self.kept_fx_b is not None and not self.refused and abs(
                self.kept_fx_b - fx_b_px_m) > 1e-6 * abs(fx_b_px_m):
            self.refused = (f'learnt on fx*b {self.kept_fx_b:.6g} px m, this calibration has '
                            f'{fx_b_px_m:.6g}: learning afresh')
            self.kept = {}
            self._cache.clear()
            self._own_cache.clear()
        return self.refused

    def correction(self, u, v):
        """(δd px, 1σ px) for a spot at rectified (u, v), or None where the map neither
        knows the cell (fewer than ``min_passes`` passes) nor a learnt cell within
        ``extrapolate_cells``: no correction, the calibration's σ stands.
        """
        key = self._key(u, v)
        est = self._cache.get(key)
        if est is None:
            est = self._own(key)
            if est is False and self.config.extrapolate_cells > 0:
                est = self._borrowed(key)
            self._cache[key] = est
        if est is False:
            return None
        a, b, sigma, centre = est
        return a + b * (u - centre), sigma

    def _own(self, key):
        """:meth:`_estimate` of a cell, memoised until the cell gets a residual."""
        est = self._own_cache.get(key)
        if est is None:
            est = self._own_cache[key] = self._estimate(key)
        return est

    def _estimate(self, key):
        c = self.config
        cell = self.cell(key)
        if cell is None or cell.passes < c.min_passes or cell.sw <= 0.0:
            return False
        a, b, cov, scatter2 = cell.line(c.slope_sigma)
        sigma = max(math.sqrt(max(cov[0, 0], 0.0)),
                    math.sqrt(scatter2 / cell.passes)) * c.sigma_inflation
        return a, b, max(sigma, c.sigma_floor_px), (key[0] + 0.5) * c.cell_px

    def _borrowed(self, key):
        """The nearest learnt cell's offset for an unknown cell (module docstring), as
        a flat line with a widened 1σ; False when none is near enough.
        """
        c = self.config
        reach = int(c.extrapolate_cells)
        best = None
        for other in set(self.kept) | set(self.run):
            di, dj = other[0] - key[0], other[1] - key[1]
            dist2 = di * di + dj * dj
            if dist2 == 0 or dist2 > reach * reach:
                continue
            rank = (dist2, abs(di), abs(dj), other)
            if best is not None and rank >= best[0]:
                continue
            est = self._own(other)
            if est is not False:
                best = (rank, est)
        if best is None:
            return False
        a, _, sigma, _ = best[1]
        return a, 0.0, sigma + c.extrapolation_sigma_fraction * abs(a), 0.0

    # ------------------------------------------------------------------ data
    def residual(self, uv_left, v_mean, disparity_px, lamp_position_m, camera_position_m,
                 along_m, chainage_sigma_m, geometry):
        """``(δd, 1σ)`` of one confirmed lamp against the filter, or None when the
        reference is too uncertain for this lamp (module docstring). ``camera_position_m``:
        the left optical centre the filter's chainage puts in ``map``; ``along_m``: the lamp's
        along-track distance from it.
        """
        c, g = self.config, geometry
        if not (chainage_sigma_m <= c.max_state_sigma_m and abs(along_m) >= c.min_along_m):
            return None
        r = float(np.linalg.norm(np.asarray(lamp_position_m, float)
                                 - np.asarray(camera_position_m, float)))
        x = (float(uv_left[0]) - g.cx) / g.fx
        y = (float(v_mean) - g.cy) / g.fy
        k = math.sqrt(1.0 + x * x + y * y)
        fb = g.fx * g.baseline_m
        sigma_ref = fb * k * abs(along_m) / r ** 3 * chainage_sigma_m
        if not (r > 0.0 and sigma_ref <= c.max_reference_sigma_px):
            return None
        delta = float(disparity_px) - fb * k / r
        return delta, math.sqrt(c.noise_px ** 2 + sigma_ref ** 2)

    def add(self, u, v, delta_px, sigma_px, lamp_uid):
        """One residual of lamp ``lamp_uid`` at rectified (u, v)."""
        if not (math.isfinite(delta_px) and math.isfinite(sigma_px) and sigma_px > 0.0):
            return
        key = self._key(u, v)
        cell = self.run.setdefault(key, Cell())
        cell.add(float(u) - (key[0] + 0.5) * self.config.cell_px, float(delta_px),
                 1.0 / (sigma_px * sigma_px))
        if (key, int(lamp_uid)) not in self._passes:
            self._passes.add((key, int(lamp_uid)))
            cell.passes += 1
        self._own_cache.pop(key, None)
        self._cache.clear()           # a borrowed estimate may now come from this cell

    def summary(self):
        """(cells in use, residuals this run, mean |δd| of the cells in use, px)."""
        used = []
        for key in self.cells():
            est = self._estimate(key)
            if est is not False:
                used.append(abs(est[0]))
        return (len(used), sum(cell.residuals for cell in self.run.values()),
                float(np.mean(used)) if used else float('nan'))
