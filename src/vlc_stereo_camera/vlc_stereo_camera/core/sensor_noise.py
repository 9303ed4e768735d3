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

    def expose(self, signal_e, rng):
        """Mean electrons (float array) → uint8 image of the same shape.

        Adds dark signal, shot noise (Gaussian approximation of Poisson), saturation at the
        full well, read noise, gain, black level and 8-bit quantization.
        """
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
