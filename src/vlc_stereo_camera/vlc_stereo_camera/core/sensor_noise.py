"""Photometric chain and image-sensor model of the synthetic rolling-shutter camera.

Chain, from the lamp to a digital number (DN), per pixel and per row exposure:

1. Lamp. A disc of area A emitting ``luminous_flux_lm`` when "on" with a generalized
   Lambertian pattern I(φ) = I0·cos^m φ, m = −ln 2 / ln cos θ½ (θ½ = half-power
   semi-angle, the lamp's "60° field angle" → m = 1). Total flux Φ = 2π·I0/(m + 1), so
   I0 = Φ(m + 1)/(2π). Its luminance seen at angle φ from the disc normal is
   L(φ) = I(φ)/(A cos φ) = (I0/A)·cos^(m−1) φ. An extended source's luminance does not
   fall with distance: the inverse-square law appears only through the spot's pixel
   footprint (a far lamp covers fewer pixels, each as bright as for a near lamp).
2. Lens (thin lens, object far compared with f). Sensor illuminance behind a pixel that
   sees the lamp, at field angle θ from the optical axis:
   E = π·τ·L·cos⁴θ / (4 N²)  (lux; τ lens transmission, N f-number, cos⁴θ natural
   vignetting).
3. Photons → electrons. E (lux) → W/m² through the luminous efficacy of the white-LED
   spectrum K (lm/W), → photons/s/m² through the mean photon energy h·c/λ̄, times the
   pixel area p², the quantum efficiency η and the exposure time:
   e⁻ = η · E/K · λ̄/(h c) · p² · t_exp.
   With the defaults (21 W × 100 lm/W = 2100 lm, 0.2 m disc, f/2.0, τ 0.9, K 300 lm/W,
   λ̄ 555 nm, p 3.75 µm, η 0.5, 50 µs) a fully covered on-axis pixel collects about
   12 400 e⁻ while the lamp is "on": 1.24 × the 10 000 e⁻ full well, so the core of
   a near spot saturates lightly and an "off" chip (5 %) stays at ~16 DN, readable.
4. Sensor. Signal + dark current (``dark_current_e_per_s`` × exposure) with Poisson shot
   noise (Gaussian approximation, exact enough above ~20 e⁻: every lit pixel and the
   ~150 e⁻ background), clipped at the full well (saturation), plus Gaussian read noise;
   then conversion gain ``adc_max_dn / full_well_e`` DN/e⁻ (the ADC saturates with the
   pixel), black level, rounding to 8 bits and clipping to 0…255.

Background: a dim tunnel, ``background_dn`` on average with a smooth gradient (brighter
toward the bottom-left of the image, where the camera sees the lit wall). A full-frame
fresh noise draw per frame would cost more than rendering the lamps, so background noise comes
from a seeded bank of pre-rendered noisy background frames (one picked per frame and
camera); the regions around lamps get fresh noise every frame.

Optional, off by default (``SensorConfig`` alone reproduces the model above bit for bit):

5. Fixed pattern and row noise (:class:`FixedPatternConfig`, :class:`FixedPattern`), in
   the terms of the EMVA 1288 standard (Release 3.1, 2016, §4 "Spatial nonuniformity and
   defect pixels"), drawn once per camera from the seed:
   * PRNU: a per-pixel gain 1 + N(0, ``prnu_rms``) on the photo-signal; industrial CMOS
     cameras' EMVA 1288 datasheets give PRNU of a few tenths of a percent to ~1 % (the
     default 1 % is the pessimistic end, an uncorrected low-cost sensor).
   * DSNU: a per-pixel dark offset N(0, ``dsnu_rms_e``) e⁻ (datasheets: ~1–10 e⁻ at short
     exposures, dominated by the readout's offset spread rather than dark current).
   * Hot pixels: a Poisson number of pixels (``hot_pixel_fraction``, a few per million)
     with a dark current log-uniform in ``hot_pixel_dark_current_e_per_s`` (default
     2·10⁵–4·10⁶ e⁻/s, 4·10³–8·10⁴ × the 50 e⁻/s median: an assumption for a warm sensor,
     whose dark current doubles every ~6–8 °C; set it from a dark frame of the real
     camera), integrated over the exposure: 10–200 e⁻ (0.3–5 DN) at 50 µs. Dark-frame
     studies also find hot pixels whose excess does not grow with the exposure; those
     would be DSNU outliers, not modelled.
   * Row noise: one temporal offset N(0, ``row_noise_e``) e⁻ per row and frame, common to
     the whole row (the row's shared readout circuitry); typically a fraction of the
     read noise (1 e⁻ against 3 e⁻ by default). At this gain (39 e⁻/DN) it is far below
     one DN and shows only as a row-wise bias of the rounding.
   With fixed pattern on, the signal of a pixel is S·gain + dark + offset and the
   shot and read noise are drawn as one Gaussian of variance e + read²: identical to
   drawing them apart except for pixels within a few e⁻ of the full well, which the
   8-bit ADC clips to 255 either way. The background bank is drawn per camera with the
   camera's pattern, and each bank frame carries its own row offsets, which the regions
   around lamps of a frame take over, so a row's offset is the same across the whole row
   (it cycles with the bank's ``noise_bank_size`` frames, as the background noise does).
6. Noise table (:class:`NoiseTable`): the Gaussian noise of the regions around lamps
   taken from a window at a random offset in a table of pre-drawn standard normal
   samples instead of drawing it each frame (a draw costs ~20–40 ns per sample; a
   near lamp's regions are ~10⁵ pixels). For speed; the table is far larger than any
   region, so no receiver can see the repetition.
"""
from dataclasses import dataclass

import numpy as np

from vlc_common.core.optical_channel import lambertian_order

PLANCK_J_S = 6.62607015e-34
LIGHT_SPEED_MPS = 299_792_458.0


@dataclass
class OpticsConfig:
    """Lamp emission and lens parameters of steps 1–3 of the module docstring."""

    luminous_flux_lm: float = 2100.0
    half_power_angle_deg: float = 60.0
    f_number: float = 2.0
    lens_transmission: float = 0.9
    efficacy_lm_per_w: float = 300.0
    mean_wavelength_m: float = 555e-9
    pixel_pitch_m: float = 3.75e-6
    quantum_efficiency: float = 0.5

    def __post_init__(self):
        if self.luminous_flux_lm <= 0.0 or self.f_number <= 0.0:
            raise ValueError('luminous_flux_lm and f_number must be > 0')
        if not 0.0 < self.lens_transmission <= 1.0 or not 0.0 < self.quantum_efficiency <= 1.0:
            raise ValueError('lens_transmission and quantum_efficiency must be in (0, 1]')
        self.order_m = lambertian_order(self.half_power_angle_deg)

    def electrons_per_luminance(self, exposure_s):
        """Electrons of a pixel that sees a surface of 1 cd/m² on axis over ``exposure_s``
        (E = π·τ·L/(4N²), steps 2–3); multiply by the surface's luminance and cos⁴θ.
        """
        illuminance_lux = np.pi * self.lens_transmission / (4.0 * self.f_number ** 2)
        return illuminance_lux * exposure_s * self.electrons_per_lux_second()

    def electrons_per_lux_second(self):
        """Photo-electrons per pixel per lux·second of sensor illuminance."""
        watts_per_m2 = 1.0 / self.efficacy_lm_per_w
        photon_energy_j = PLANCK_J_S * LIGHT_SPEED_MPS / self.mean_wavelength_m
        return (self.quantum_efficiency * watts_per_m2 / photon_energy_j
                * self.pixel_pitch_m ** 2)

    def luminance_cd_m2(self, disc_area_m2, cos_phi):
        """Lamp luminance L(φ) = (I0/A)·cos^(m−1) φ for an "on" lamp, cd/m²."""
        m = self.order_m
        intensity0_cd = self.luminous_flux_lm * (m + 1.0) / (2.0 * np.pi)
        return intensity0_cd / disc_area_m2 * np.power(np.maximum(cos_phi, 1e-6), m - 1.0)

    def on_electrons(self, disc_area_m2, cos_phi, exposure_s):
        """Electrons of a fully covered on-axis pixel over ``exposure_s`` of "on" light."""
        illuminance_lux = (np.pi * self.lens_transmission
                           * self.luminance_cd_m2(disc_area_m2, cos_phi)
                           / (4.0 * self.f_number ** 2))
        return illuminance_lux * exposure_s * self.electrons_per_lux_second()


@dataclass
class SensorConfig:
    """Pixel, noise and ADC parameters of step 4 of the module docstring."""

    full_well_e: float = 10_000.0
    read_noise_e: float = 3.0
    dark_current_e_per_s: float = 50.0
    adc_max_dn: int = 255
    black_level_dn: float = 0.0
    background_dn: float = 4.0
    noise_bank_size: int = 16

    def __post_init__(self):
        if self.full_well_e <= 0.0 or self.read_noise_e < 0.0 or self.dark_current_e_per_s < 0.0:
            raise ValueError('full_well_e must be > 0, read_noise_e and dark current >= 0')
        if self.background_dn < 0.0 or self.noise_bank_size < 1:
            raise ValueError('background_dn must be >= 0 and noise_bank_size >= 1')

    @property
    def gain_dn_per_e(self):
        return self.adc_max_dn / self.full_well_e


@dataclass
class FixedPatternConfig:
    """Fixed-pattern and row noise of step 5 of the module docstring (e⁻, e⁻/s)."""

    prnu_rms: float = 0.01
    dsnu_rms_e: float = 2.0
    row_noise_e: float = 1.0
    hot_pixel_fraction: float = 4e-6
    hot_pixel_dark_current_e_per_s: tuple = (2e5, 4e6)

    def __post_init__(self):
        lo, hi = self.hot_pixel_dark_current_e_per_s
        if not (0.0 <= self.prnu_rms < 0.5 and self.dsnu_rms_e >= 0.0
                and self.row_noise_e >= 0.0 and 0.0 <= self.hot_pixel_fraction < 0.01
                and 0.0 < lo <= hi):
            raise ValueError('FixedPatternConfig: prnu_rms in [0, 0.5), dsnu_rms_e and '
                             'row_noise_e >= 0, hot_pixel_fraction in [0, 0.01), '
                             '0 < hot dark current low <= high')


class FixedPattern:
    """One camera's fixed pattern, drawn once (step 5 of the module docstring).

    Attributes
    ----------
    gain : (H, W) float32
        Per-pixel photo-response gain (PRNU), mean 1.
    offset_e : (H, W) float32
        Per-pixel dark offset over one exposure, e⁻ (DSNU, plus hot pixels' dark signal).
    hot_pixels : (rows (n,), cols (n,), dark signal (n,) e⁻)
    """

    def __init__(self, config, height, width, exposure_s, rng):
        self.config = config
        shape = (height, width)
        self.gain = (1.0 + config.prnu_rms * rng.standard_normal(shape)).astype(np.float32)
        np.maximum(self.gain, 0.0, out=self.gain)
        self.offset_e = (config.dsnu_rms_e * rng.standard_normal(shape)).astype(np.float32)
        n_hot = int(rng.poisson(config.hot_pixel_fraction * height * width))
        flat = rng.choice(height * width, size=n_hot, replace=False)
        lo, hi = config.hot_pixel_dark_current_e_per_s
        signal_e = np.exp(rng.uniform(np.log(lo), np.log(hi), n_hot)) * exposure_s
        rows, cols = np.unravel_index(flat, shape)
        self.offset_e[rows, cols] += signal_e.astype(np.float32)
        self.hot_pixels = (rows, cols, signal_e)

    def row_offsets_e(self, rng):
        """(H,) float32 row noise of one frame, e⁻."""
        return (self.config.row_noise_e
                * rng.standard_normal(self.gain.shape[0])).astype(np.float32)


class NoiseTable:
    """Standard normal samples drawn once; windows at random offsets serve as noise.

    ``take(shape, rng)`` returns a (read-only) view of ``prod(shape)`` consecutive
    samples starting at an offset drawn from ``rng`` (a fresh draw if the table is too
    small).
    """

    def __init__(self, size, rng):
        self.z = rng.standard_normal(int(size), dtype=np.float32)
        self.z.flags.writeable = False

    def take(self, shape, rng):
        n = int(np.prod(shape))
        if n > self.z.size:
            return rng.standard_normal(shape, dtype=np.float32)
        offset = int(rng.integers(0, self.z.size - n + 1))
        return self.z[offset:offset + n].reshape(shape)


class SensorModel:
    """Turns expected electrons per pixel into a noisy 8-bit image (step 4)."""

    def __init__(self, config, exposure_s, noise=True):
        self.config = config
        self.exposure_s = exposure_s
        self.noise = noise
        self.dark_e = config.dark_current_e_per_s * exposure_s

    def background_electrons(self, height, width):
        """(H, W) float32 mean electrons of the dim tunnel: a smooth gradient, mean
        ``background_dn``.
        """
        c = self.config
        v = np.linspace(0.0, 1.0, height, dtype=np.float32)[:, None]
        u = np.linspace(0.0, 1.0, width, dtype=np.float32)[None, :]
        shape = (0.55 + 0.9 * v) * (1.2 - 0.4 * u)
        return (c.background_dn / c.gain_dn_per_e * shape / shape.mean()).astype(np.float32)

    def expose(self, signal_e, rng, pattern=None, window=None, row_offset_e=None,
               normal=None):
        """Mean electrons (float array) → uint8 image of the same shape.

        Adds dark signal, shot noise (Gaussian approximation of Poisson), saturation at the
        full well, read noise, gain, black level and 8-bit quantization.

        Optional (step 5 and 6 of the module docstring): ``pattern`` a
        :class:`FixedPattern` of the whole sensor with ``window`` = (u0, u1, v0, v1) the
        pixels ``signal_e`` covers, half-open (default: all); ``row_offset_e`` (rows,) the
        frame's row noise for those rows, e⁻; ``normal`` standard normal noise of the shape of
        ``signal_e`` (default: drawn from ``rng``). With any of them the shot and read
        noise are one Gaussian draw per pixel.
        """
        if pattern is not None or row_offset_e is not None or normal is not None:
            return self._expose_one_draw(signal_e, rng, pattern, window, row_offset_e, normal)
        c = self.config
        e = np.asarray(signal_e, dtype=np.float32) + np.float32(self.dark_e)
        if self.noise:
            e = e + np.sqrt(e) * rng.standard_normal(e.shape, dtype=np.float32)
        np.clip(e, 0.0, c.full_well_e, out=e)
        if self.noise and c.read_noise_e > 0.0:
            e += np.float32(c.read_noise_e) * rng.standard_normal(e.shape, dtype=np.float32)
        dn = e * np.float32(c.gain_dn_per_e) + np.float32(c.black_level_dn + 0.5)
        np.clip(dn, 0.0, c.adc_max_dn, out=dn)
        return dn.astype(np.uint8)

    def background_bank(self, background_e, rng):
        """(n, H, W) uint8 noisy background frames, ``n = noise_bank_size``."""
        n = self.config.noise_bank_size if self.noise else 1
        return np.stack([self.expose(background_e, rng) for _ in range(n)])

    def _expose_one_draw(self, signal_e, rng, pattern, window, row_offset_e, normal):
        c = self.config
        e = np.asarray(signal_e, dtype=np.float32)
        if pattern is not None:
            u0, u1, v0, v1 = window if window is not None else (0, e.shape[1], 0, e.shape[0])
            e = e * pattern.gain[v0:v1, u0:u1]
            e += pattern.offset_e[v0:v1, u0:u1]
            e += np.float32(self.dark_e)
        else:
            e = e + np.float32(self.dark_e)
        if self.noise:
            z = normal if normal is not None else rng.standard_normal(e.shape, dtype=np.float32)
            sigma = np.maximum(e, 0.0)
            sigma += np.float32(c.read_noise_e ** 2)
            np.sqrt(sigma, out=sigma)
            sigma *= z
            e += sigma
        np.clip(e, 0.0, c.full_well_e, out=e)
        if row_offset_e is not None and self.noise:
            e += np.asarray(row_offset_e, dtype=np.float32)[:, None]
        dn = e * np.float32(c.gain_dn_per_e) + np.float32(c.black_level_dn + 0.5)
        np.clip(dn, 0.0, c.adc_max_dn, out=dn)
        return dn.astype(np.uint8)

    def pattern_bank(self, background_e, rng, pattern):
        """Background bank of one camera with its fixed pattern (step 5).

        Returns (frames (n, H, W) uint8, row offsets (n, H) float32 e⁻): each frame drawn
        with its own row noise, which the lamp regions of a frame that shows it must use.
        """
        n = self.config.noise_bank_size if self.noise else 1
        rows = np.stack([pattern.row_offsets_e(rng) if self.noise
                         else np.zeros(background_e.shape[0], np.float32) for _ in range(n)])
        frames = np.stack([self.expose(background_e, rng, pattern=pattern, row_offset_e=r)
                           for r in rows])
        return frames, rows
