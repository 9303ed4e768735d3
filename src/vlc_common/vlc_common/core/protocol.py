"""The VLC lamp protocol, version 1 (``shared/VLC_PROTOCOL.md``): one definition for the
transmitter model (the rig's lamps) and the receiver (the decoder).

On-off keying, Manchester data (bit 1 → chips ``on, off``; bit 0 → ``off, on``), a 6-chip
header ``111000``, 24 data bits sent MSB first (4-bit line_id, 12-bit lamp_id, CRC-8/SMBUS
over the 16-bit UID), packets repeated back to back: 54 chips. The worked example and the
CRC check value of the protocol text are this module's tests.
"""
import numpy as np

HEADER_CHIPS = np.array([1, 1, 1, 0, 0, 0], dtype=np.int8)
HEADER_LEN = 6
DATA_BITS = 24
PACKET_CHIPS = HEADER_LEN + 2 * DATA_BITS  # 54
# packet chip index of the header's on→off edge: the one boundary that a run of three
# equal chips (possible only in the header) pins down unambiguously
HEADER_EDGE_CHIP = 3


def _crc8_table():
    table = np.zeros(256, dtype=np.uint8)
    for byte in range(256):
        crc = byte
        for _ in range(8):
            crc = ((crc << 1) ^ 0x07) & 0xFF if crc & 0x80 else (crc << 1) & 0xFF
        table[byte] = crc
    return table


CRC8_TABLE = _crc8_table()


def crc8(data: bytes) -> int:
    """CRC-8/SMBUS of ``data``: polynomial 0x07, init 0x00, no reflection, no final XOR."""
    crc = 0
    for byte in data:
        crc = int(CRC8_TABLE[crc ^ byte])
    return crc


def crc8_uid(uid):
    """CRC-8/SMBUS over the two big-endian bytes of each 16-bit UID (vectorised).

    Parameters
    ----------
    uid : int or ndarray of int, any shape, values 0..65535

    Returns
    -------
    ndarray of uint8, the shape of ``uid``
    """
    uid = np.asarray(uid, dtype=np.int64)
    high = CRC8_TABLE[(uid >> 8) & 0xFF]
    return CRC8_TABLE[high ^ (uid & 0xFF)]


def uid_of(line_id, lamp_id):
    """UID = line_id << 12 | lamp_id (4 + 12 bits); ValueError outside 0..15 / 0..4095."""
    if not 0 <= line_id <= 15 or not 0 <= lamp_id <= 4095:
        raise ValueError(f'line_id {line_id} must be 0..15 and lamp_id {lamp_id} 0..4095')
    return (line_id << 12) | lamp_id


def split_uid(uid):
    """(line_id, lamp_id) of a UID = line_id << 12 | lamp_id."""
    return int(uid) >> 12, int(uid) & 0xFFF


def packet_chips(uid):
    """The 54 chips of one packet of ``uid``, (54,) int8 of 0/1: header ``111000``, then
    the 16-bit UID and its CRC-8 (24 bits, MSB first) Manchester coded.
    """
    if not 0 <= int(uid) <= 0xFFFF:
        raise ValueError(f'UID {uid} does not fit 16 bits')
    word = (int(uid) << 8) | int(crc8_uid(uid))
    bits = (word >> np.arange(DATA_BITS - 1, -1, -1)) & 1
    chips = np.stack([bits, 1 - bits], axis=1).reshape(-1)
    return np.concatenate([HEADER_CHIPS, chips.astype(np.int8)])


def bits_to_word(bits):
    """Data bits (..., 24) of 0/1, MSB first → (uid (...), crc (...)) as int64."""
    bits = np.asarray(bits, dtype=np.int64)
    weights = np.int64(1) << np.arange(DATA_BITS - 1, -1, -1, dtype=np.int64)
    word = (bits * weights).sum(axis=-1)
    return word >> 8, word & 0xFF
