"""Spot detection and envelope-normalised row profiles on synthetic spots."""
import numpy as np
import pytest

from vlc_decoder.core import chips, spots, synth
from vlc_decoder.core.config import DecoderConfig

CFG = DecoderConfig()


def render_one(rng, uid, height, width, v=300.0, u=600.0, gain=200.0, phase=None):
    signal = synth.LampSignal(uid, phase_s=rng.uniform(0, 0.01) if phase is None else phase)
    lamp = synth.SyntheticLamp(signal, u, v, 20.0, width, height)
    left, right = synth.render_stereo([lamp], 0.0, gain_dn=gain, rng=rng)
    return signal, left, right


def true_levels(signal, rows):
    level = signal.mean_over(rows * CFG.row_time_s, rows * CFG.row_time_s + CFG.exposure_s)
    return (level - signal.off_level) / (1 - signal.off_level)


@pytest.mark.parametrize('height, width', [(20, 3.5), (25, 7), (40, 16), (70, 45)])
def test_one_striped_spot_is_one_spot_with_the_true_row_levels(height, width):
    rng = np.random.default_rng(int(height))
    for _ in range(10):
        signal, left, _ = render_one(rng, int(rng.integers(0, 1 << 16)), height, width)
        found = spots.detect(left, CFG)
        assert len(found) == 1, 'the dark stripes split the spot'
        spot = found[0]
        # coarse centre (the spot locator refines it): the extent of a far spot whose
        # cap is dark ("off") is short by up to a couple of rows
        assert abs(spot.v - 300.0) < 1.0 + 0.1 * height and abs(spot.u - 600.0) < 1.5
        truth = true_levels(signal, spot.rows)
        used = spot.weight > 0.5
        # well-weighted rows read their level closely and never on the wrong side of 0.5
        assert np.median(np.abs(spot.level[used] - truth[used])) < 0.1
        clear = used & (np.abs(truth - 0.5) > 0.4)
        assert np.all((spot.level[clear] > 0.5) == (truth[clear] > 0.5))
        # rows outside the disc are never part of the profile
        assert spot.rows[0] >= 300 - height / 2 - 2 and spot.rows[-1] <= 300 + height / 2 + 2


def test_dim_cap_rows_do_not_read_as_off():
    """An "on" row at the top of a spot is short, not dark: the envelope says so."""
    rng = np.random.default_rng(5)
    wrong_naive = wrong_envelope = 0
    for _ in range(40):
        signal, left, _ = render_one(rng, int(rng.integers(0, 1 << 16)), 40, 16)
        spot = spots.detect(left, CFG)[0]
        truth = true_levels(signal, spot.rows)
        # lit rows in the caps that carry evidence (the outermost rows, weighted < 0.3,
        # barely count in a chip's vote)
        on_caps = (truth > 0.9) & (spot.weight >= 0.3) & (spot.weight < 1)
        patch = left[spot.rows, spot.col0:spot.col1].astype(float) - 4.0
        naive = patch.sum(axis=1) / patch.sum(axis=1).max()
        wrong_naive += int(np.count_nonzero(naive[on_caps] < 0.5))
        wrong_envelope += int(np.count_nonzero(spot.level[on_caps] < 0.5))
    assert wrong_naive > 20            # dividing by the brightest row fails at the caps
    assert wrong_envelope == 0


def test_two_lamps_two_spots_and_background_threshold():
    rng = np.random.default_rng(2)
    lamps = [synth.SyntheticLamp(synth.LampSignal(0x1001, phase_s=1e-3), 1200, 80, 15, 7, 25),
             synth.SyntheticLamp(synth.LampSignal(0x1002, phase_s=3e-3), 700, 420, 40, 45, 60)]
    left, _ = synth.render_stereo(lamps, 0.0, rng=rng)
    found = sorted(spots.detect(left, CFG), key=lambda s: s.u)
    assert [round(s.u) for s in found] == [700, 1200]
    background, sigma = spots.background_level(left)
    assert background == pytest.approx(4.0, abs=1.0) and 0.5 <= sigma < 3
    assert not spots.detect(np.full((720, 1280), 4, np.uint8), CFG)


def test_paper_chain_is_available():
    rng = np.random.default_rng(3)
    _, left, _ = render_one(rng, 0x102A, 40, 16)
    otsu = DecoderConfig(use_otsu=True, median_filter=True)
    found = spots.detect(left, otsu)
    assert any(abs(s.u - 600) < 3 and abs(s.v - 300) < 3 for s in found)


def test_spot_cut_by_border_is_flagged_and_measured_row_by_row():
    rng = np.random.default_rng(4)
    signal, left, right = render_one(rng, 0x1003, 40, 16, u=1279.0)
    spot = [s for s in spots.detect(left, CFG) if s.v > 250][0]
    assert spot.cut
    truth = true_levels(signal, spot.rows)
    used = spot.weight > 0.5
    assert np.median(np.abs(spot.level[used] - truth[used])) < 0.15
    whole = [s for s in spots.detect(right, CFG) if s.v > 250][0]
    assert not whole.cut


def test_row_profile_reads_chips_of_a_frame():
    """Chips read from one frame's spot agree with the lamp."""
    rng = np.random.default_rng(6)
    errors = read = 0
    for _ in range(30):
        signal, left, _ = render_one(rng, int(rng.integers(0, 1 << 16)), 55, 28)
        spot = spots.detect(left, CFG)[0]
        t = spot.rows * CFG.row_time_s + 0.5 * CFG.exposure_s
        res = chips.read_profiles(t[None], spot.level[None], spot.weight[None], CFG)
        k = np.flatnonzero(res['states'][0] != chips.UNKNOWN)
        t_mid = res['t_b'][0] + (res['n0'][0] + k + 0.5) / res['f'][0]
        on = signal.chips[np.floor((t_mid - signal.phase_s) * signal.chip_rate_hz)
                          .astype(int) % 54] == 1
        errors += int(np.count_nonzero(on != (res['states'][0][k] == chips.ON)))
        read += len(k)
    assert read > 30 * 12 and errors == 0


@pytest.mark.parametrize('height, width', [(40, 16), (70, 45)])
def test_envelope_fitted_on_the_on_rows_reads_the_cap_rows(height, width):
    """The lit extent ends early when a cap chip is off and late when the optics spill an
    "on" cap; the parabola through the squared sums of the rows read "on" (an ellipse's
    squared chord) recovers the disc, so the partly weighted cap rows read true too.
    """
    rng = np.random.default_rng(21)
    errors = []
    for _ in range(30):
        signal, left, _ = render_one(rng, int(rng.integers(0, 1 << 16)), height, width)
        spot = spots.detect(left, CFG)[0]
        truth = true_levels(signal, spot.rows)
        caps = (spot.weight > 0) & (spot.weight < spots.CAP_HI)
        errors += list(np.abs(spot.level[caps] - truth[caps]))
        assert abs(spot.v - 300.0) < 1.0
    assert len(errors) > 100
    assert np.median(errors) < 0.05 and np.percentile(errors, 95) < 0.25


def test_tiny_spots_are_profiled_or_dropped_never_crash():
    image = np.full((720, 1280), 4, np.uint8)
    image[100, 200:204] = 200            # one row
    image[300:302, 500] = 180            # one column
    image[500, 700] = 255                # one pixel
    for spot in spots.detect(image, CFG):
        assert len(spot.rows) == len(spot.level) == len(spot.weight) > 0
