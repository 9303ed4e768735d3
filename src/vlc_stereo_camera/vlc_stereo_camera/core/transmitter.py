"""What the synthetic lamps broadcast: the light output of the VLC protocol
(:mod:`vlc_common.core.protocol`) over time, with each lamp's own clock.
"""
from dataclasses import dataclass

import numpy as np

from vlc_common.core.protocol import PACKET_CHIPS, packet_chips


@dataclass
class LampWaveform:
    """On-off keyed light output of one lamp: packets repeated back to back.

    ``level(t)`` is 1 while a chip is "on" and ``off_level`` while it is "off". The chip
    with index k (counting from the packet start at ``phase_s``) lasts
    ``[phase_s + k/chip_rate_hz, phase_s + (k+1)/chip_rate_hz)``. ``chip_rate_hz``
    includes the lamp's clock error.
    """

    uid: int
    chip_rate_hz: float = 10_000.0
    phase_s: float = 0.0
    off_level: float = 0.05

    def __post_init__(self):
        self.chips = packet_chips(self.uid).astype(float)
        levels = self.off_level + (1.0 - self.off_level) * self.chips
        # cumulative integral of the level over whole chips, in chip units
        self._levels = levels
        self._cum = np.concatenate([[0.0], np.cumsum(levels)])

    def level(self, t_s):
        """Instantaneous output (relative to "on") at times ``t_s`` (s), any shape."""
        k = np.floor((np.asarray(t_s) - self.phase_s) * self.chip_rate_hz).astype(np.int64)
        return self._levels[k % PACKET_CHIPS]

    def _integral_chips(self, t_s):
        """∫ level dt from phase_s to t, in chip-durations (vectorised)."""
        x = (np.asarray(t_s, dtype=float) - self.phase_s) * self.chip_rate_hz
        n_packets = np.floor(x / PACKET_CHIPS)
        rem = x - n_packets * PACKET_CHIPS
        k = np.minimum(np.floor(rem).astype(np.int64), PACKET_CHIPS - 1)
        return n_packets * self._cum[-1] + self._cum[k] + (rem - k) * self._levels[k]

    def mean_over(self, t_start_s, t_end_s):
        """Exact mean output over the windows ``[t_start_s, t_end_s]`` (arrays, s)."""
        t_start_s = np.asarray(t_start_s, dtype=float)
        t_end_s = np.asarray(t_end_s, dtype=float)
        span = (t_end_s - t_start_s) * self.chip_rate_hz
        return (self._integral_chips(t_end_s) - self._integral_chips(t_start_s)) / span
