"""Transmitter side of the VLC lamp protocol, version 1 (``shared/VLC_PROTOCOL.md``).

The receiver (``vlc_decoder``) is written independently from the protocol text; this
module is what the synthetic lamps broadcast.
"""
from dataclasses import dataclass

import numpy as np

HEADER_CHIPS = np.array([1, 1, 1, 0, 0, 0], dtype=np.uint8)
PACKET_CHIPS = 54


def crc8(data: bytes) -> int:
    """CRC-8/SMBUS: polynomial 0x07, init 0x00, no reflection, no final XOR."""
    crc = 0
    for byte in data:
        crc ^= byte
        for _ in range(8):
            crc = ((crc << 1) ^ 0x07) & 0xFF if crc & 0x80 else (crc << 1) & 0xFF
    return crc


def uid_of(line_id: int, lamp_id: int) -> int:
    """UID = line_id << 12 | lamp_id (4 + 12 bits)."""
    if not 0 <= line_id <= 15 or not 0 <= lamp_id <= 4095:
        raise ValueError(f'line_id {line_id} must be 0..15 and lamp_id {lamp_id} 0..4095')
    return (line_id << 12) | lamp_id


def packet_chips(uid: int) -> np.ndarray:
    """The 54 chips of one packet: header 111000, then 24 data bits Manchester coded.

    Data bits (MSB first) are the 16-bit UID and its CRC-8; bit 1 → chips 1 0, bit 0 →
    chips 0 1. Returns a (54,) uint8 array of 0/1.
    """
    if not 0 <= uid <= 0xFFFF:
        raise ValueError(f'UID {uid} does not fit 16 bits')
    payload = uid.to_bytes(2, 'big')
    word = (uid << 8) | crc8(payload)
    bits = [(word >> (23 - i)) & 1 for i in range(24)]
    chips = [c for b in bits for c in ((1, 0) if b else (0, 1))]
    return np.concatenate([HEADER_CHIPS, np.array(chips, dtype=np.uint8)])


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
