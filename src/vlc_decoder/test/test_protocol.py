"""Decoder against vectors built from the text of shared/VLC_PROTOCOL.md.

Nothing here uses the shared protocol module's encoder as the reference: the
expected chips are typed from the protocol's worked example or built in this file by a
bit-by-bit reading of the protocol text.
"""
import numpy as np
import pytest

from vlc_common.core import protocol
from vlc_decoder.core import chips, synth
from vlc_decoder.core.config import DecoderConfig

# VLC_PROTOCOL.md, "Worked example": line_id 1, lamp_id 42 → UID 0x102A → CRC-8 0x81;
# data bits 0001 0000 0010 1010 1000 0001; chips = header 111000 + Manchester (0→01, 1→10)
WORKED_UID = 0x102A
WORKED_CRC = 0x81
WORKED_BITS = '0001' '0000' '0010' '1010' '1000' '0001'
WORKED_CHIPS = '111000' + ''.join('01' if b == '0' else '10' for b in WORKED_BITS)


def text_crc8(data):
    """CRC-8/SMBUS as the protocol states it: poly 0x07, init 0, MSB first, no XOR out."""
    crc = 0
    for byte in data:
        for i in range(7, -1, -1):
            bit = ((crc >> 7) ^ (byte >> i)) & 1
            crc = ((crc << 1) & 0xFF) ^ (0x07 if bit else 0)
    return crc


def text_packet(line_id, lamp_id):
    """54 chips of one packet, built from the protocol text alone."""
    uid = (line_id << 12) | lamp_id
    crc = text_crc8(bytes([uid >> 8, uid & 0xFF]))
    bits = format(line_id, '04b') + format(lamp_id, '012b') + format(crc, '08b')
    return '111000' + ''.join('10' if b == '1' else '01' for b in bits)


def states_of(chip_text):
    return np.array([chips.ON if c == '1' else chips.OFF for c in chip_text], dtype=np.int8)


def test_crc_check_value_and_worked_example():
    assert protocol.crc8(b'123456789') == 0xF4
    assert text_crc8(b'123456789') == 0xF4
    assert protocol.crc8(bytes([0x10, 0x2A])) == WORKED_CRC
    assert int(protocol.crc8_uid(WORKED_UID)) == WORKED_CRC
    assert protocol.split_uid(WORKED_UID) == (1, 42)


def test_worked_example_chips():
    assert len(WORKED_CHIPS) == protocol.PACKET_CHIPS == 54
    assert text_packet(1, 42) == WORKED_CHIPS
    assert ''.join(map(str, protocol.packet_chips(WORKED_UID))) == WORKED_CHIPS


def test_decode_worked_example_from_chips():
    uid, status, bits = chips.decide_packets(states_of(WORKED_CHIPS)[None])
    assert status[0] == chips.STATUS_OK and bits[0] == 24 and uid[0] == WORKED_UID
    # the same chips at an arbitrary fold origin: the header is found by its structure
    rolled = np.roll(states_of(WORKED_CHIPS), 17)[None]
    uid, status, _, origin = chips.decide_fold(rolled)
    assert uid[0] == WORKED_UID and origin[0] == 17


def test_decode_worked_example_from_rendered_row_profile():
    cfg = DecoderConfig()
    chip_values = np.array([int(c) for c in WORKED_CHIPS])
    signal = synth.LampSignal(WORKED_UID, phase_s=0.37e-3, chips=chip_values)
    rows = np.arange(240)    # 7.2 ms of rows: more than one 5.4 ms packet
    level = synth.row_levels(signal, 0.0, len(rows))
    y = (level - signal.off_level) / (1 - signal.off_level)
    t = rows * cfg.row_time_s + 0.5 * cfg.exposure_s
    uid, status = chips.decode_profiles(t[None], y[None], np.ones((1, len(rows))), cfg)
    assert status[0] == chips.STATUS_OK and uid[0] == WORKED_UID


@pytest.mark.parametrize('line_id, lamp_id', [(0, 0), (1, 1), (1, 42), (7, 2048), (15, 4095),
                                              (9, 1234)])
def test_vectors_from_protocol_text_decode(line_id, lamp_id):
    cfg = DecoderConfig()
    text = text_packet(line_id, lamp_id)
    uid, status, _, _ = chips.decide_fold(np.roll(states_of(text), 5)[None])
    assert status[0] == chips.STATUS_OK and uid[0] == (line_id << 12) | lamp_id
    signal = synth.LampSignal(0, phase_s=1.1e-3, chips=np.array([int(c) for c in text]))
    rows = np.arange(230)
    y = (synth.row_levels(signal, 0.0, len(rows)) - 0.05) / 0.95
    t = rows * cfg.row_time_s + 0.5 * cfg.exposure_s
    uid, status = chips.decode_profiles(t[None], y[None], np.ones((1, len(rows))), cfg)
    assert uid[0] == (line_id << 12) | lamp_id


def test_header_run_cannot_occur_in_manchester_data():
    rng = np.random.default_rng(3)
    for uid in rng.integers(0, 1 << 16, 200):
        text = text_packet(int(uid) >> 12, int(uid) & 0xFFF)
        data = text[6:]
        assert '111' not in data and '000' not in data


def test_wrong_crc_is_rejected_and_missing_chips_are_not_guessed():
    text = list(WORKED_CHIPS)
    # invert the last data bit (both its chips): Manchester still valid, CRC not
    text[-2:] = ['1', '0'] if text[-2:] == ['0', '1'] else ['0', '1']
    _, status, _ = chips.decide_packets(states_of(''.join(text))[None])
    assert status[0] == chips.STATUS_CRC
    # one data bit unread (both chips unknown): no decision, whatever the CRC would say
    states = states_of(WORKED_CHIPS)
    states[20:22] = chips.UNKNOWN
    uid, status, bits = chips.decide_packets(states[None])
    assert status[0] == chips.STATUS_INCOMPLETE and bits[0] == 23 and uid[0] == -1
    # a Manchester violation is inconsistent, not a bit error to correct
    states = states_of(WORKED_CHIPS)
    states[7] = states[6]
    _, status, _ = chips.decide_packets(states[None])
    assert status[0] == chips.STATUS_INCONSISTENT
