"""Typed configuration of the decoder core (filled once from the node's parameters)."""
from dataclasses import dataclass

import yaml

from vlc_common.core.config_files import SAFE_LOADER

SIGNAL_TIMING_KEYS = ('row_time_s', 'exposure_s', 'chip_rate_hz', 'off_level')


@dataclass
class DecoderConfig:
    """Every tunable of the decoder core; units in the names.

    Signal timing
        ``row_time_s`` (row-to-row exposure start delay), ``exposure_s`` (row exposure),
        ``chip_rate_hz`` (nominal lamp chip rate), ``off_level`` (lamp "off" output
        relative to "on"): the camera's and protocol's, not in camera_info.
    Chip decisions
        ``chip_margin``: a chip is read only when its normalised level is at least this
        far from 0.5; ``min_chip_weight``: and when rows worth this many fully-inside
        exposures cover it.
    Clocks
        ``rate_search_tolerance``: the within-frame chip-rate search span (fraction),
        covering the protocol's ±2 % driver mismatch, used for profiles spanning at
        least ``rate_search_min_chips``; ``clock_tolerance_ppm``: the lamp clock accuracy
        assumed when carrying a packet phase from frame to frame.
    Optics
        ``psf_sigma_px``: the lens blur (Gaussian σ of the point spread function's core,
        px); the spot's row envelope is modelled with it.
    Detection
        threshold ``background + detect_threshold_sigma·σ`` but at least
        ``detect_min_contrast`` DN above it (or Otsu: ``use_otsu``, ``median_filter``),
        ``detect_min_area_px``, ``max_spots`` per image, ``border_margin_px``.
    Tracking
        ``track_gate_px`` association gate, ``track_max_missed_frames``,
        ``max_fragments`` frames of stripes kept per lamp; ``stamp_jump_reset_s``: a
        frame stamped more than this before the previous one (a looped bag, a restarted
        camera) resets every track, so fragments are never mixed across the jump;
        ``frame_rate_hz``: the camera's frame rate, on whose period each lamp's packet
        is assembled (:class:`~vlc_decoder.core.frame_grid.FrameGrid`: a driver's stamp
        jitter does not reach the assembly; 0 or a rate the stamps contradict: the
        stamps as they are).
    """

    row_time_s: float = 30e-6
    exposure_s: float = 50e-6
    chip_rate_hz: float = 10_000.0
    off_level: float = 0.05
    chip_margin: float = 0.2
    min_chip_weight: float = 0.2
    rate_search_tolerance: float = 0.03
    rate_search_min_chips: float = 24.0
    clock_tolerance_ppm: float = 100.0
    psf_sigma_px: float = 0.7
    # spot detection
    detect_threshold_sigma: float = 8.0
    detect_min_contrast: float = 20.0
    detect_min_area_px: int = 3
    use_otsu: bool = False
    median_filter: bool = False
    max_spots: int = 8
    # tracking and assembly
    track_gate_px: float = 60.0
    track_max_missed_frames: int = 15
    max_fragments: int = 120
    stamp_jump_reset_s: float = 0.05
    border_margin_px: int = 2
    frame_rate_hz: float = 30.0

    def __post_init__(self):
        if not (self.row_time_s > 0 and self.exposure_s > 0 and self.chip_rate_hz > 0):
            raise ValueError('row_time_s, exposure_s and chip_rate_hz must be positive')
        if not 0.0 <= self.off_level < 0.5:
            raise ValueError('off_level must be in [0, 0.5)')
        if not self.stamp_jump_reset_s >= 0.0:
            raise ValueError('stamp_jump_reset_s must be >= 0')
        if not self.frame_rate_hz >= 0.0:
            raise ValueError('frame_rate_hz must be >= 0')
        if not self.psf_sigma_px >= 0.0:
            raise ValueError('psf_sigma_px must be >= 0')
        if not 0.0 < self.chip_margin < 0.5:
            raise ValueError('chip_margin must be in (0, 0.5)')

    @property
    def rows_per_chip(self):
        return 1.0 / (self.chip_rate_hz * self.row_time_s)

    @property
    def max_dark_gap_rows(self):
        """Longest dark stretch inside one lamp spot, rows.

        The longest off run of the protocol is four chips (header ``000`` followed by a
        data bit 0, whose first chip is off); the exposure shortens it by one exposure.
        """
        return 4.0 * self.rows_per_chip + 2.0


def signal_timing_from_params_file(path):
    """The signal timing of a ROS params file (``/**: ros__parameters:``).

    Returns a dict with those of ``SIGNAL_TIMING_KEYS`` the file sets (floats), so
    benchmarks and tests take the graph's timing from ``config/vlc_decoder_node.yaml``,
    the one place it is written for the decoder, instead of repeating its numbers.
    """
    with open(path, encoding='utf-8') as stream:
        params = yaml.load(stream, Loader=SAFE_LOADER)['/**']['ros__parameters']
    return {key: float(params[key]) for key in SIGNAL_TIMING_KEYS if key in params}
