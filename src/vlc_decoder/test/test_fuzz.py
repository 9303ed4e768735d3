"""Fuzz: no random or corrupted stripe profile may be accepted with a wrong UID.

Profiles are synthesised here, vectorised, from chip streams built from the protocol
text (header 111000, Manchester, CRC-8/SMBUS); corruptions: chip flips, truncation,
wrong chip rate, noise and level errors, random chips, pure noise. The decoder under
test is the batch profile decoder (``chips.decode_profiles``), whose packet decision
(``decide_fold``) the per-lamp assembler uses as well; a second, smaller fuzz drives
the assembler with corrupted fragment sequences.
"""
import numpy as np

from vlc_decoder.core import chips, synth
from vlc_decoder.core.assembly import PacketAssembler
from vlc_decoder.core.config import DecoderConfig

CFG = DecoderConfig()


def decode(y, w):
    t = np.broadcast_to(np.arange(y.shape[1]) * CFG.row_time_s + 0.5 * CFG.exposure_s,
                        y.shape)
    uid, _ = chips.decode_profiles(np.ascontiguousarray(t), y, w, CFG)
    return uid


def test_fuzz_no_wrong_uid_in_100k_profiles():
    per_kind = 15_000
    stats = synth.fuzz_run(decode, per_kind)
    total = sum(s['profiles'] for s in stats.values())
    wrong = {kind: s['wrong'] for kind, s in stats.items() if s['wrong']}
    assert total == per_kind * len(synth.FUZZ_KINDS) >= 100_000
    assert not wrong, f'wrong UIDs accepted: {wrong}'
    # not vacuous: the decoder does accept what the corrupted profiles still carry
    assert stats['noise']['correct'] > 1000 and stats['chip_flips']['correct'] > 100
    assert stats['wrong_rate']['correct'] > 100       # the ±2 % .. ±3 % part of the span


def test_fuzz_assembler_with_corrupted_fragment_sequences():
    """Short fragments with misreads, foreign lamps mixed in and off-spec clocks."""
    rng = np.random.default_rng(7)
    wrong = confirmed = 0
    for trial in range(300):
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
