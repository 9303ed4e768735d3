"""FrameGrid: each lamp track's packet on the camera's period, not on jittered stamps."""
import numpy as np
import pytest

from vlc_decoder.core.frame_grid import CHECK_GAPS, FrameGrid

EPOCH_NS = 1_700_000_000_000_000_000


def _run(grid, stamps, start_track_at=0):
    """Frame times of one track that starts at frame index ``start_track_at``."""
    timeline, times = None, []
    for i, stamp in enumerate(stamps):
        grid.add(stamp)
        if i >= start_track_at:
            t, timeline = grid.time_ns(timeline, stamp)
            times.append(t)
    return np.array(times, dtype=np.int64)


def test_exact_stamps_are_used_as_they_are():
    stamps = [EPOCH_NS + round(k * 1e9 / 30) for k in range(200)]
    assert np.array_equal(_run(FrameGrid(30.0), stamps), stamps)


def test_a_track_lies_on_the_period_whatever_the_stamp_jitter_and_dropped_frames():
    rng = np.random.default_rng(5)
    k = np.arange(300)
    k = k[(k % 23) != 7]                                        # dropped frames
    period = 1e9 / 30 * (1 + 40e-6)                             # the camera's crystal
    true = EPOCH_NS + np.round(k * period).astype(np.int64)
    stamps = true + np.round(rng.normal(0.0, 100e3, k.size)).astype(np.int64)
    grid = FrameGrid(30.0)
    times = _run(grid, stamps, start_track_at=20)
    error = (times - true[20:]).astype(float)
    # a constant (the first stamp's jitter) plus a rate (the crystal's 40 ppm): what the
    # packet assembly fits per lamp as the lamp's phase and clock rate
    fit = np.polyfit(true[20:] - true[20], error, 1)
    assert abs(fit[0]) == pytest.approx(40e-6, rel=0.05)
    residual = error - np.polyval(fit, true[20:] - true[20])
    assert np.max(np.abs(residual)) < 2.0                       # ns: rounding only
    assert np.std(stamps - true) > 80e3


def test_a_rate_the_stamps_contradict_gives_way_to_the_stamps():
    stamps = [EPOCH_NS + round(k * 1e9 / 25) + (k % 3) * 50_000 for k in range(40)]
    grid = FrameGrid(30.0)
    times = _run(grid, stamps)                                  # 25 fps, not 30
    assert np.array_equal(times[CHECK_GAPS + 1:], stamps[CHECK_GAPS + 1:])
    assert grid.checked is False and not grid.usable
    grid = FrameGrid(30.0)
    for k in range(CHECK_GAPS):
        grid.add(EPOCH_NS + round(k * 1e9 / 30))
    assert grid.checked is None and grid.usable                # on the period meanwhile
    assert FrameGrid(0.0).time_ns(None, 7) == (7, None)


def test_a_gap_off_the_grid_restarts_every_timeline():
    grid = FrameGrid(30.0)
    stamps = [EPOCH_NS + round(k * 1e9 / 30) + (k % 2) * 40_000 for k in range(20)]
    timeline = None
    for s in stamps:
        grid.add(s)
        _, timeline = grid.time_ns(timeline, s)
    late = stamps[-1] + 50_000_000                              # 1.5 periods: off the grid
    grid.add(late)
    t, new = grid.time_ns(timeline, late)
    assert t == late and new != timeline and new[1] == 0
