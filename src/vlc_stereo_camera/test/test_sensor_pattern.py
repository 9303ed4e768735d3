"""Fixed-pattern noise, row noise and the noise table of the sensor model, alone and as
the renderer applies them (background bank and lamp regions alike).
"""
import numpy as np
import pytest

from vlc_common.core.lamp_map import LampMap, resolve_lamp_map_path
from vlc_stereo_camera.core.renderer import RendererConfig, StereoRenderer
from vlc_stereo_camera.core.sensor_noise import (
    FixedPattern,
    FixedPatternConfig,
    NoiseTable,
    SensorConfig,
    SensorModel,
)
from vlc_stereo_camera.core.trajectory import MotionProfile, Trajectory, Vibration, VibrationConfig

H, W = 720, 1280


def test_pattern_statistics_follow_the_configuration():
    config = FixedPatternConfig(prnu_rms=0.01, dsnu_rms_e=2.0, hot_pixel_fraction=20e-6,
                                hot_pixel_dark_current_e_per_s=(2e5, 4e6))
    pattern = FixedPattern(config, H, W, 50e-6, np.random.default_rng(1))
    assert pattern.gain.mean() == pytest.approx(1.0, abs=1e-4)
    assert pattern.gain.std() == pytest.approx(0.01, rel=0.01)
    rows, cols, signal = pattern.hot_pixels
    n_expected = 20e-6 * H * W                           # 18.4
    assert abs(len(rows) - n_expected) < 4 * np.sqrt(n_expected)
    assert np.all((signal >= 2e5 * 50e-6) & (signal <= 4e6 * 50e-6))
    cold = np.ones((H, W), bool)
    cold[rows, cols] = False
    assert pattern.offset_e[cold].std() == pytest.approx(2.0, rel=0.01)
    assert np.all(pattern.offset_e[rows, cols] > 8.0)     # 10–200 e⁻ on top of DSNU
    again = FixedPattern(config, H, W, 50e-6, np.random.default_rng(1))
    np.testing.assert_array_equal(again.gain, pattern.gain)     # drawn once, from the seed
    offsets = pattern.row_offsets_e(np.random.default_rng(2))
    assert offsets.shape == (H,) and offsets.std() == pytest.approx(1.0, rel=0.1)


def test_expose_applies_gain_and_offset_per_pixel():
    """Noise-free: DN = round((S·gain + dark + offset + row)·g) in the window given."""
    config = SensorConfig(full_well_e=2550.0)              # 0.1 DN/e⁻
    pattern = FixedPattern(FixedPatternConfig(prnu_rms=0.05, dsnu_rms_e=20.0), H, W, 50e-6,
                           np.random.default_rng(3))
    sensor = SensorModel(config, 50e-6, noise=False)
    window = (100, 140, 200, 230)                          # u0, u1, v0, v1
    signal = np.full((30, 40), 1000.0, np.float32)
    rows = np.linspace(-5.0, 5.0, 30).astype(np.float32)
    dn = sensor.expose(signal, None, pattern=pattern, window=window)
    e = 1000.0 * pattern.gain[200:230, 100:140] + sensor.dark_e + pattern.offset_e[200:230,
                                                                                  100:140]
    np.testing.assert_array_equal(dn, np.clip(np.floor(e * 0.1 + 0.5), 0, 255))
    # row noise is temporal: without sensor noise it is not applied
    assert np.array_equal(sensor.expose(signal, None, pattern=pattern, window=window,
                                        row_offset_e=rows), dn)


def test_one_draw_noise_has_the_shot_and_read_variance():
    config = SensorConfig(full_well_e=2550.0, read_noise_e=10.0)
    sensor = SensorModel(config, 50e-6)
    signal = np.full((400, 400), 900.0, np.float32)
    table = NoiseTable(1 << 20, np.random.default_rng(4))
    for normal in (None, table.take(signal.shape, np.random.default_rng(5))):
        dn = sensor.expose(signal, np.random.default_rng(6), row_offset_e=np.zeros(400),
                           normal=normal).astype(float)
        # σ² = (900 + 10²) e⁻² → 3.16 DN, plus 1/12 DN² of rounding
        assert dn.var() == pytest.approx(1000.0 * 0.01 + 1 / 12, rel=0.03)
        assert dn.mean() == pytest.approx(90.0, abs=0.05)


def test_noise_table_windows():
    table = NoiseTable(1 << 16, np.random.default_rng(7))
    a = table.take((10, 20), np.random.default_rng(8))
    b = table.take((10, 20), np.random.default_rng(9))
    assert a.shape == (10, 20) and not np.array_equal(a, b)
    assert not a.flags.writeable
    big = table.take((300, 300), np.random.default_rng(8))     # larger than the table
    assert big.shape == (300, 300)
    assert abs(table.z.mean()) < 0.02 and table.z.std() == pytest.approx(1.0, abs=0.01)


def test_rows_share_one_offset_across_background_and_lamp_regions():
    """Row noise made visible (1 DN rms at 0.1 DN/e⁻): in a frame with a lamp, each row's
    mean residual over the lamp region's background pixels equals the row's residual over
    the pre-rendered background, and the offsets change from frame to frame.
    """
    sensor = SensorConfig(full_well_e=2550.0, read_noise_e=3.0, background_dn=20.0,
                          noise_bank_size=8)
    config = RendererConfig(sensor=sensor, lamp_modulation=False, optics_psf=False,
                            fixed_pattern=FixedPatternConfig(prnu_rms=0.0, dsnu_rms_e=0.0,
                                                             row_noise_e=10.0,
                                                             hot_pixel_fraction=0.0),
                            noise_table_size=1 << 20)
    lamps = LampMap.load(resolve_lamp_map_path(''))
    trajectory = Trajectory(MotionProfile('stationary', start_chainage_m=7.0),
                            Vibration(VibrationConfig(enabled=False)))
    renderer = StereoRenderer(config, lamps, trajectory, seed=2)
    expected = renderer.render(0, electrons=True)
    gain = sensor.gain_dn_per_e
    lit = np.argwhere(expected.left - renderer._background_e > 1.0)   # the disc (no PSF)
    (v0, u0), (v1, _) = lit.min(axis=0), lit.max(axis=0)
    rows = np.arange(v0, v1 + 1)
    lamp_region = slice(u0 - 18, u0 - 3)       # the ROI's pad: background, fresh noise
    background = slice(20, 300)                # the pre-rendered bank frame
    residual_rows = []
    for k in (0, 1):
        frame = renderer.render(k)
        e = expected.left
        in_roi = (frame.left[rows, lamp_region] - e[rows, lamp_region] * gain).mean(axis=1)
        outside = (frame.left[rows, background] - e[rows, background] * gain).mean(axis=1)
        assert len(rows) > 40 and outside.std() > 0.7          # 1 DN rms row offsets
        assert np.corrcoef(in_roi, outside)[0, 1] > 0.8
        assert np.std(in_roi - outside) < 0.6                  # ~0.4 from pixel noise
        residual_rows.append(outside)
    assert abs(np.corrcoef(*residual_rows)[0, 1]) < 0.5
