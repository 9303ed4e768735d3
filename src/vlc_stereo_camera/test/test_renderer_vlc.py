"""The stripes of a rendered lamp carry the VLC protocol, chip for chip.

The reference encoder, CRC and decoder below are written from shared/VLC_PROTOCOL.md
only (not from core.vlc_protocol, the renderer's transmitter): bit-serial CRC-8 long
division, Manchester 1 → on,off / 0 → off,on, header 111000, MSB first.
"""
import numpy as np
import pytest

from vlc_common.core.lamp_map import LampMap, resolve_lamp_map_path
from vlc_stereo_camera.core.renderer import RendererConfig, StereoRenderer
from vlc_stereo_camera.core.sensor_noise import OpticsConfig
from vlc_stereo_camera.core.trajectory import MotionProfile, Trajectory, Vibration, VibrationConfig

HEADER = [1, 1, 1, 0, 0, 0]


def ref_crc8(message: bytes) -> int:
    """CRC-8 by polynomial long division: x^8 + x^2 + x + 1, init 0, MSB first."""
    bits = int.from_bytes(message, 'big') << 8
    n = 8 * len(message) + 8
    for i in range(n - 1, 7, -1):
        if bits >> i & 1:
            bits ^= 0x107 << (i - 8)
    return bits & 0xFF


def ref_packet(uid: int):
    word = uid << 8 | ref_crc8(bytes([uid >> 8, uid & 0xFF]))
    chips = list(HEADER)
    for i in range(23, -1, -1):
        chips += [1, 0] if word >> i & 1 else [0, 1]
    return np.array(chips)


def ref_decode(chips):
    """54 cyclic chips → UID if a rotation gives header + Manchester data + valid CRC."""
    chips = list(chips)
    for r in range(54):
        seq = chips[r:] + chips[:r]
        if seq[:6] != HEADER:
            continue
        pairs = [tuple(seq[6 + 2 * i:8 + 2 * i]) for i in range(24)]
        if any(p not in ((1, 0), (0, 1)) for p in pairs):
            continue
        word = 0
        for p in pairs:
            word = word << 1 | (p == (1, 0))
        uid, crc = word >> 8, word & 0xFF
        if ref_crc8(bytes([uid >> 8, uid & 0xFF])) == crc:
            return uid
    return None


def test_reference_crc_matches_the_protocol_text():
    assert ref_crc8(b'123456789') == 0xF4
    assert ref_crc8(bytes([0x10, 0x2A])) == 0x81
    assert ''.join(map(str, ref_packet(0x102A)[6:])) == ''.join(
        '10' if b == '1' else '01' for b in '000100000010101010000001')


@pytest.fixture(scope='module')
def lamp_map():
    return LampMap.load(resolve_lamp_map_path(''))


def near_lamp_renderer(lamp_map, distance_m, **cfg):
    traj = Trajectory(MotionProfile('stationary', start_chainage_m=10.0 - distance_m),
                      Vibration(VibrationConfig(enabled=False)))
    return StereoRenderer(RendererConfig(**cfg), lamp_map, traj, seed=5)


def row_profile(image, truth, half_width_px=3, centres=None):
    """Mean DN per row of a narrow band following the spot's centre line.

    The centre of each row is the middle of its lit run (pixels 8 DN above the image
    median), unless ``centres`` (from another image of the same spot) are given.
    Returns rows, values (NaN where a row has no lit pixel), centres, background DN.
    """
    r0, r1 = truth.rows_left
    rows = np.arange(r0, r1 + 1)
    background = np.median(image)
    values, found = [], []
    for i, r in enumerate(rows):
        line = image[r].astype(float)
        if centres is None:
            lo = int(truth.uv_left[0]) - 60
            lit = np.flatnonzero(line[lo:lo + 121] > background + 8)
            c = lo + int(round(0.5 * (lit[0] + lit[-1]))) if lit.size else -1
        else:
            c = centres[i]
        found.append(c)
        values.append(line[c - half_width_px:c + half_width_px + 1].mean() if c >= 0
                      else np.nan)
    return rows, np.array(values), np.array(found), background


def test_row_levels_follow_the_chip_waveform(lamp_map):
    """Unsaturated near lamp: each row's level = mean of the protocol waveform over
    that row's exposure window, at the given row time.
    """
    flux = 0.5 * OpticsConfig().luminous_flux_lm            # on ≈ 0.6 full well
    steady = near_lamp_renderer(lamp_map, 2.0, optics=OpticsConfig(luminous_flux_lm=flux),
                                optics_psf=False, lamp_modulation=False, sensor_noise=False)
    live = near_lamp_renderer(lamp_map, 2.0, optics=OpticsConfig(luminous_flux_lm=flux),
                              optics_psf=False)
    cfg = live.config
    uid = 4097
    clock = live.lamp_waveform(uid)          # the lamp's seeded phase and rate error
    chips = ref_packet(uid)
    for k in (0, 1, 2):
        frame = live.render(k)
        on_frame = steady.render(k)
        truth = frame.truth[0]
        rows, on_dn, centres, _ = row_profile(on_frame.left, truth)
        _, dn, _, background = row_profile(frame.left, truth, centres=centres)
        full = on_dn > 0.9 * np.nanmax(on_dn)            # rows crossing the full disc
        measured = (dn[full] - background) / (on_dn[full] - background)
        t_start = frame.t0_s + rows[full] * cfg.row_time_s
        s = np.linspace(0.0, 1.0, 2001)
        t = t_start[:, None] + s[None, :] * cfg.exposure_s
        idx = np.floor((t - clock.phase_s) * clock.chip_rate_hz).astype(np.int64) % 54
        level = cfg.off_level + (1 - cfg.off_level) * chips[idx]
        expected = np.trapezoid(level, s, axis=1)
        assert full.sum() > 40
        np.testing.assert_allclose(measured, expected, atol=0.05)


def test_blind_multi_frame_decode_of_a_near_lamp(lamp_map):
    """Default photometry (saturating "on" chips, PSF, halo, noise): threshold the rows,
    fold their exposure mid-times over the packet period, search the unknown phase and
    chip-rate error, and decode the UID with the CRC.
    """
    renderer = near_lamp_renderer(lamp_map, 2.0)
    cfg = renderer.config
    times, bits = [], []
    for k in range(8):
        frame = renderer.render(k)
        truth = frame.truth[0]
        rows, dn, _, background = row_profile(frame.left, truth)
        ok = np.isfinite(dn)
        rows, dn = rows[ok], dn[ok]
        mid = np.abs(rows - truth.uv_left[1]) < 0.35 * (rows[-1] - rows[0])
        times.append(frame.t0_s + rows[mid] * cfg.row_time_s + cfg.exposure_s / 2)
        bits.append(dn[mid] > 0.5 * (background + 255))
    times, bits = np.concatenate(times), np.concatenate(bits)
    best = None
    for ppm in np.linspace(-300, 300, 13):
        rate = cfg.chip_rate_hz * (1 + ppm * 1e-6)
        for phase in np.arange(0.0, 1.0, 0.02):
            pos = (times - times[0]) * rate - phase
            frac = pos - np.floor(pos)
            use = np.abs(frac - 0.5) < 0.2       # window wholly inside one chip
            k = np.floor(pos[use]).astype(np.int64) % 54
            ones = np.bincount(k, bits[use], minlength=54)
            count = np.bincount(k, minlength=54)
            if np.any(count == 0):
                continue
            agree = np.maximum(ones, count - ones).sum() / count.sum()
            if best is None or agree > best[0]:
                best = (agree, (ones / count > 0.5).astype(int))
    assert best is not None and best[0] > 0.98
    assert ref_decode(best[1]) == 4097


def test_chip_rate_parameter_changes_the_stripe_pitch(lamp_map):
    """At 5 kchip/s the stripes are twice as tall as at 10 kchip/s."""
    def shortest_cycle_rows(rate):
        renderer = near_lamp_renderer(lamp_map, 1.0, chip_rate_hz=rate, lamp_clock_ppm=0.0)
        cycles = []
        for k in range(4):
            frame = renderer.render(k)
            truth = frame.truth[0]
            rows, dn, _, background = row_profile(frame.left, truth)
            # rows across the middle of the spot, where the band lies inside the disc
            mid = np.abs(rows - truth.uv_left[1]) < 0.35 * (rows[-1] - rows[0])
            b = (dn[mid] > 0.5 * (background + 255)).astype(int)
            rising = np.flatnonzero(np.diff(b) == 1)
            cycles += list(np.diff(rising))
        return np.min(cycles)
    # Shortest off→on→off→on cycle = two chips: 2 × 100 µs / 30 µs ≈ 6.7 rows at
    # 10 kchip/s, 13.3 rows at 5 kchip/s.
    assert 6 <= shortest_cycle_rows(10000.0) <= 7
    assert 13 <= shortest_cycle_rows(5000.0) <= 14
