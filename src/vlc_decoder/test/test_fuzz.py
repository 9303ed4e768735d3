"""Fuzz: no random or corrupted stripe profile or fragment sequence gives a wrong UID.

Profiles are synthesised here, vectorised, from chip streams built from the protocol
text (header 111000, Manchester, CRC-8/SMBUS); corruptions: chip flips, truncation,
wrong chip rate, noise and level errors, random chips, pure noise. The decoder under
test is the batch profile decoder (``chips.decode_profiles``), at the graph's timing
(105 000 profiles) and the protocol's (35 000), whose packet decision (``decide_fold``)
the per-lamp assembler uses as well; smaller fuzzes drive the assembler with corrupted
fragment sequences, foreign lamps mixed in and off-spec clocks.
"""
import pathlib

import numpy as np
import pytest

from vlc_decoder.core import chips, synth
from vlc_decoder.core.assembly import PacketAssembler
from vlc_decoder.core.config import DecoderConfig, signal_timing_from_params_file

CFG = DecoderConfig()
# the graph's timing, from the node's parameter file (the one place it is written)
NODE_PARAMS = pathlib.Path(__file__).resolve().parents[1] / 'config' / 'vlc_decoder_node.yaml'
GRAPH_CFG = DecoderConfig(**signal_timing_from_params_file(NODE_PARAMS))


def decoder(cfg):
    def decode(y, w):
        t = np.broadcast_to(np.arange(y.shape[1]) * cfg.row_time_s + 0.5 * cfg.exposure_s,
                            y.shape)
        uid, _ = chips.decode_profiles(np.ascontiguousarray(t), y, w, cfg)
        return uid
    return decode


@pytest.mark.parametrize('cfg, per_kind', [(GRAPH_CFG, 15_000), (CFG, 5_000)],
                         ids=['graph_timing_105k', 'protocol_timing_35k'])
def test_fuzz_no_wrong_uid_in_100k_profiles(cfg, per_kind):
    stats = synth.fuzz_run(decoder(cfg), per_kind, cfg=cfg)
    total = sum(s['profiles'] for s in stats.values())
    wrong = {kind: s['wrong'] for kind, s in stats.items() if s['wrong']}
    assert total == per_kind * len(synth.FUZZ_KINDS)
    assert not wrong, f'wrong UIDs accepted: {wrong}'
    # not vacuous: the decoder does accept what the corrupted profiles still carry
    scale = per_kind / 15_000
    assert stats['noise']['correct'] > 1000 * scale
    assert stats['chip_flips']['correct'] > 100 * scale
    assert stats['wrong_rate']['correct'] > 100 * scale   # the ±2 % .. ±3 % of the span


def test_fuzz_assembler_with_corrupted_fragment_sequences():
    """Short fragments with misreads, foreign lamps mixed in and off-spec clocks."""
    rng = np.random.default_rng(7)
    wrong = confirmed = 0
    for _ in range(300):
        uid, other = (int(u) for u in rng.integers(0, 1 << 16, 2))
        chips_true = np.tile(synth.text_packets([uid])[0], 400).astype(float)
        chips_other = np.tile(synth.text_packets([other])[0], 400).astype(float)
        rate = CFG.chip_rate_hz * (1 + rng.choice([0.0, 0.0, 0.003, 0.01, 0.02])
                                   * rng.choice([-1, 1]))
        phase = rng.uniform(0, 54)
        asm = PacketAssembler(CFG, 0)
        for k in range(25):
            t0 = k / 30.0
            n_rows = int(rng.integers(15, 70))
            first_row = int(rng.integers(0, 600))
            source = chips_other if rng.uniform() < 0.15 else chips_true
            stream = source.copy()
            if rng.uniform() < 0.3:
                stream[rng.integers(0, len(stream), 400)] = rng.integers(0, 2, 400)
            x0 = t0 * rate + phase + first_row * CFG.row_time_s * rate
            offset = int(x0) - 2
            local = stream[offset:offset + 40]
            y = synth.render_streams(local[None, :], np.array([x0 - offset]),
                                     np.array([rate / CFG.chip_rate_hz]))[0, :n_rows]
            y = y + rng.normal(size=n_rows) * rng.choice([0.03, 0.1, 0.3])
            stamp = int(round(t0 * 1e9))
            asm.add(stamp, first_row + np.arange(n_rows), y, np.ones(n_rows))
        if asm.uid is not None:
            confirmed += 1
            wrong += asm.uid != uid
    assert wrong == 0
    assert confirmed > 30


def test_fuzz_assembler_at_graph_timing_with_neighbouring_lamps():
    """The graph's timing, clocks up to 2 % off, and from the fourth frame on a spot of
    a neighbouring lamp of the same line (same header and line bits) in 15 % of the
    frames: the track is the lamp it started on, never the neighbour.
    """
    rng = np.random.default_rng(31)
    cfg = GRAPH_CFG
    wrong = confirmed = 0
    for _ in range(150):
        uid = int(rng.integers(0, 1 << 16))
        other = (uid & 0xF000) | ((uid + int(rng.integers(1, 4))) & 0xFFF)
        chips_true = np.tile(synth.text_packets([uid])[0], 800).astype(float)
        chips_other = np.tile(synth.text_packets([other])[0], 800).astype(float)
        rate = cfg.chip_rate_hz * (1 + rng.choice([0.0, 0.0, 0.001, 0.003, 0.01, 0.02])
                                   * rng.choice([-1, 1]))
        phase = rng.uniform(0, 54)
        asm = PacketAssembler(cfg, 0)
        for k in range(25):
            n_rows = int(rng.integers(15, 70))
            first_row = int(rng.integers(0, 600))
            source = chips_other if k >= 3 and rng.uniform() < 0.15 else chips_true
            stream = source.copy()
            if rng.uniform() < 0.3:
                stream[rng.integers(0, len(stream), 800)] = rng.integers(0, 2, 800)
            x0 = k / 30.0 * rate + phase + first_row * cfg.row_time_s * rate
            offset = max(int(x0) - 2, 0)
            y = synth.render_streams(stream[None, offset:offset + 80], np.array([x0 - offset]),
                                     np.array([rate / cfg.chip_rate_hz]),
                                     row_time_s=cfg.row_time_s, exposure_s=cfg.exposure_s,
                                     chip_rate_hz=cfg.chip_rate_hz)[0, :n_rows]
            y = y + rng.normal(size=n_rows) * rng.choice([0.03, 0.1, 0.3])
            asm.add(int(round(k / 30.0 * 1e9)), first_row + np.arange(n_rows), y,
                    np.ones(n_rows))
            wrong += asm.uid not in (None, uid)
        confirmed += asm.uid == uid
    assert wrong == 0
    assert confirmed > 80
