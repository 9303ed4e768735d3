"""Left/right spot matching on the rectified epipolar constraint.

In a rectified pair a lamp covers the same rows in both images (they are also exposed
at the same instants, so rolling-shutter skew and stripes coincide), its disparity
``u_left − u_right`` is positive and bounded by the working range, and its two spots have
about the same size. The first and last lit rows themselves are not compared: a dim
stripe at a spot's tip may pass the detection threshold in one image and not in the
other; the centre rows and the overlap of the row spans are robust to that. Candidate
pairs passing these gates are assigned one-to-one with the Hungarian method; a spot
without an admissible partner is left unmatched.
"""
from dataclasses import dataclass

import numpy as np
from scipy.optimize import linear_sum_assignment


@dataclass
class MatchConfig:
    """Gates of the stereo matcher.

    max_row_diff_px: allowed difference of the two spots' centre rows (px).
    min_row_overlap: the shorter row span must overlap the other by this fraction.
    min_disparity_px, max_disparity_px: admissible disparity (px); with fx = 1040 px and
        b = 0.12 m, 2 px ≈ 62 m and 400 px ≈ 0.31 m.
    max_area_ratio: larger/smaller pixel area.
    """

    max_row_diff_px: float = 3.0
    min_row_overlap: float = 0.5
    min_disparity_px: float = 2.0
    max_disparity_px: float = 400.0
    max_area_ratio: float = 2.0


@dataclass
class SpotSummary:
    """What the matcher needs to know of one spot (image pixels)."""

    u: float
    v: float
    row_min: int
    row_max: int
    area_px: float


def match_spots(left, right, config=None):
    """Match left and right spots.

    Parameters
    ----------
    left, right : sequences of :class:`SpotSummary`.
    config : :class:`MatchConfig`.

    Returns
    -------
    pairs : list of (i_left, i_right).
    unmatched_left, unmatched_right : lists of indices.
    """
    cfg = config or MatchConfig()
    nl, nr = len(left), len(right)
    if nl == 0 or nr == 0:
        return [], list(range(nl)), list(range(nr))
    big = 1e9
    cost = np.full((nl, nr), big)
    for i, a in enumerate(left):
        for j, b in enumerate(right):
            drow = abs(a.v - b.v)
            overlap = (min(a.row_max, b.row_max) - max(a.row_min, b.row_min) + 1) / max(
                min(a.row_max - a.row_min, b.row_max - b.row_min) + 1, 1)
            d = a.u - b.u
            ratio = max(a.area_px, b.area_px) / max(min(a.area_px, b.area_px), 1e-9)
            if (drow > cfg.max_row_diff_px or overlap < cfg.min_row_overlap
                    or not cfg.min_disparity_px <= d <= cfg.max_disparity_px
                    or ratio > cfg.max_area_ratio):
                continue
            cost[i, j] = drow / cfg.max_row_diff_px + (1.0 - overlap) + np.log(ratio)
    rows, cols = linear_sum_assignment(cost)
    pairs = [(int(i), int(j)) for i, j in zip(rows, cols) if cost[i, j] < big]
    ml = {i for i, _ in pairs}
    mr = {j for _, j in pairs}
    return pairs, [i for i in range(nl) if i not in ml], [j for j in range(nr) if j not in mr]
