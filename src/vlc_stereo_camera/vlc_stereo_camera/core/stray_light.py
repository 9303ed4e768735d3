"""Light in the tunnel that is not a lamp's disc (ROS-free): wall reflections and
distractor lights, for ``RendererConfig.stray_light`` and ``RendererConfig.distractors``.

* Wall reflection (:class:`StrayLightConfig`): each lamp lights the wall around it (its
  housing and diffuser send some light sideways, the lining returns it). The wall is a
  Lambertian reflector, so the patch's luminance does not depend on the viewing
  direction: L = M/π for the exitance M (lm/m²). The patch is modelled as a Gaussian
  exitance in the wall (disc) plane, M(a, b) = f·Φ·exp(−(a² + b²)/(2σ²))/(2πσ²), centred
  ``reflection_offset_m`` (along track, up) from the lamp centre, where Φ is the lamp's
  "on" flux and f = ``reflection_fraction`` the part of it the patch returns. It
  carries the lamp's modulation (light-path delays are nanoseconds). Seen from the
  camera a Lambertian lamp of order m = 1 (the default 60° half-power angle) and its
  patch send the same fraction of their flux toward the lens, so the patch collects f
  times the lamp's electrons (tested); its peak is far dimmer, the light being spread
  over ~2πσ² instead of the disc's area A (f·A/(2πσ²) ≈ 0.7 % of the lamp's luminance
  with the defaults: ~80 e⁻, 2 DN, at 50 µs on axis). The lamp disc does not occlude the
  patch behind it: the spot gains the patch's light there (~20 % of the patch, 0.6 % of
  the lamp's light with the defaults), with the lamp's own modulation.
* Distractors (:class:`Distractor`): lights that are not lamps — a signal aspect, a
  platform or emergency light — at fixed map positions: a luminous disc of
  ``diameter_m`` facing ``normal``, Lambertian with peak luminance ``luminance_cd_m2``,
  steady or flickering (:class:`FlickerWaveform`: a lamp on a rectified 50 Hz supply
  flickers at 100 Hz). Rendered like a lamp (exact perspective coverage, PSF, rolling
  shutter, lens), without a VLC packet: the decoder must not take it for a lamp.
  Typical luminances: a colour-light signal lens (100–200 mm, 300–1000 cd on axis for
  tunnel signals) 10⁴–10⁵ cd/m²; an opal platform or emergency luminaire 10³–10⁴ cd/m²;
  the tunnel lamps 2·10⁴ cd/m² (``OpticsConfig``). The camera is monochrome: a red or
  green aspect's luminance is taken as the white-LED-equivalent signal, i.e. the sensor's
  spectral response is not modelled.
"""
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class StrayLightConfig:
    """Each lamp's reflection on the wall (module docstring).

    ``reflection_fraction``: reflected flux / the lamp's "on" flux (dimensionless, a few
    %: a sooty concrete lining has a reflectance of 0.1–0.3, and only the lamp's
    sideways light reaches it); ``reflection_sigma_m``: the Gaussian patch's σ in the
    wall plane, m; ``reflection_offset_m``: (along track, up) of the patch centre from
    the lamp centre, m.
    """

    reflection_fraction: float = 0.03
    reflection_sigma_m: float = 0.15
    reflection_offset_m: tuple = (0.0, 0.0)

    def __post_init__(self):
        if not (0.0 <= self.reflection_fraction <= 0.5 and self.reflection_sigma_m > 0.0
                and len(self.reflection_offset_m) == 2):
            raise ValueError('StrayLightConfig: reflection_fraction in [0, 0.5], '
                             'reflection_sigma_m > 0, reflection_offset_m (along, up)')


@dataclass(frozen=True)
class Distractor:
    """A light that is not a lamp, at a fixed map position (module docstring).

    ``position_m`` (3,) disc centre in map, m; ``normal`` (3,) the direction it faces in
    map (normalized here); ``diameter_m``; ``luminance_cd_m2`` peak luminance;
    ``flicker_hz`` 0 = steady, else the flicker frequency (100 Hz: 50 Hz mains rectified);
    ``flicker_depth`` in [0, 1]: the output swings between 1 − depth and 1 of the peak;
    ``name`` for reports.
    """

    position_m: tuple
    normal: tuple = (-1.0, 0.0, 0.0)
    diameter_m: float = 0.2
    luminance_cd_m2: float = 20_000.0
    flicker_hz: float = 0.0
    flicker_depth: float = 1.0
    name: str = ''

    def __post_init__(self):
        n = np.asarray(self.normal, dtype=float)
        if (len(self.position_m) != 3 or n.shape != (3,) or not np.linalg.norm(n) > 0.0
                or not self.diameter_m > 0.0 or not self.luminance_cd_m2 > 0.0
                or self.flicker_hz < 0.0 or not 0.0 <= self.flicker_depth <= 1.0):
            raise ValueError(f'Distractor {self.name!r}: position (3,), a non-zero normal, '
                             'diameter and luminance > 0, flicker_hz >= 0, depth in [0, 1]')
        object.__setattr__(self, 'position_m', tuple(float(x) for x in self.position_m))
        object.__setattr__(self, 'normal', tuple(float(x) + 0.0 for x in n / np.linalg.norm(n)))

    @classmethod
    def on_alignment(cls, alignment, chainage_m, lateral_m, height_m, facing='oncoming',
                     **kwargs):
        """A distractor placed by chainage: ``lateral_m`` left of the centreline (negative:
        right), ``height_m`` above rail level; ``facing`` 'oncoming' (toward a train
        running up the chainage, e.g. a signal), 'track' (horizontal, toward the
        centreline) or 'down'.
        """
        p = alignment.evaluate(np.array([float(chainage_m)]))
        position = alignment.to_map(np.array([float(chainage_m)]), lateral_m, height_m)[0]
        tangent = np.append(p.tangent[0], 0.0)
        left = np.append(p.left_normal[0], 0.0)
        normal = {'oncoming': -tangent, 'track': -np.sign(lateral_m or 1.0) * left,
                  'down': np.array([0.0, 0.0, -1.0])}[facing]
        return cls(position_m=tuple(position), normal=tuple(normal), **kwargs)


@dataclass
class FlickerWaveform:
    """Output of a distractor relative to its peak: steady, or
    level(t) = 1 − depth·(1 + cos(2π f t + φ))/2, swinging between 1 − depth and 1.

    ``mean_over`` is its exact mean over windows (times since the epoch, s), the same
    interface as :class:`~vlc_stereo_camera.core.transmitter.LampWaveform`.
    """

    flicker_hz: float = 0.0
    depth: float = 1.0
    phase_rad: float = 0.0

    def level(self, t_s):
        t = np.asarray(t_s, dtype=float)
        if self.flicker_hz <= 0.0 or self.depth <= 0.0:
            return np.ones_like(t)
        return 1.0 - 0.5 * self.depth * (1.0 + np.cos(2.0 * np.pi * self.flicker_hz * t
                                                      + self.phase_rad))

    def mean_over(self, t_start_s, t_end_s):
        t0 = np.asarray(t_start_s, dtype=float)
        t1 = np.asarray(t_end_s, dtype=float)
        if self.flicker_hz <= 0.0 or self.depth <= 0.0:
            return np.ones(np.broadcast(t0, t1).shape)
        w = 2.0 * np.pi * self.flicker_hz
        mean_cos = (np.sin(w * t1 + self.phase_rad) - np.sin(w * t0 + self.phase_rad)) / (
            w * (t1 - t0))
        return 1.0 - 0.5 * self.depth * (1.0 + mean_cos)
