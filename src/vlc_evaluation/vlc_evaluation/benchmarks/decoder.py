"""``decoder_benchmark``: the figures of the decoder's targets, measured, printed, written.

Sections (all by default; ``--only`` picks some):

* ``fuzz``: random and corrupted stripe profiles (``core.synth.fuzz_profiles``) through
  the profile decoder, at the protocol's default timing and at the graph's: accepted,
  correct and wrong UIDs per corruption.
* ``speeds``: the rig (``vlc_stereo_camera`` renderer, default lamp map and scenario,
  vibration on) at 20…120 km/h: per lamp passed, the along-track distance and range at
  the first confirmation, lamps confirmed before leaving the view, wrong UIDs, and the
  ideal reader's bound; every lamp missed, with the chips its frames showed (why); per
  frame, the chips each frame's stripes read (and how many wrong, against the rig's
  waveform) and whether the lamp's record carries its UID, binned by range → table + PNG.
* ``chipscreen``: the lamps' chip rate screened on the rig's geometry (disc rows per
  frame, recorded once) with an ideal reader over every packet phase, 19 000–21 500
  chips/s: cheap, a proxy for choosing candidates.
* ``chiprates``: candidate chip rates (``--chip-rates``) through the decoder on the rig
  at every speed and at standstill (frames to confirm a lamp standing ahead).
* ``rig``: 120 km/h with rig changes (frame rate; chip rates ``--rig-chip-rates``; rig
  and decoder alike).
* ``whatif``: the high speeds at the protocol's 10 000 chips/s and 50 µs exposure.
* ``clocks``: confirmation against the lamps' clock error (beyond the protocol's
  ±100 ppm: alignment by content), with and without alignment by overlaps.
* ``timing``: CPU time per stereo pair with two lamps in view (lamps every 5 m),
  OpenCV on one thread.
* ``detection``: spot recall and spurious spots of the paper's chain (median filter +
  Otsu) and of the noise-referenced threshold, with their times.

The graph's chip rate and exposure are read from ``config/vlc_decoder_node.yaml``.
``--write-docs`` replaces the generated sections of ``docs/arch/vlc_decoder.md`` (only
those run) and writes ``docs/images/decoder_success_vs_range.png`` under the workspace
($VLC_WS).
"""
import argparse
import os
import pathlib
import sys
import time

import cv2
import numpy as np

from vlc_common.core.config_files import config_path
from vlc_decoder.core import assembly, chips, synth
from vlc_decoder.core.assembly import CONFIRMED
from vlc_decoder.core.config import DecoderConfig, signal_timing_from_params_file
from vlc_decoder.core.spots import find_spots
from vlc_decoder.core.tracker import LampTracker, combine_profiles

SPEEDS_KMH = (20, 40, 60, 80, 100, 120)
RANGE_BINS_M = np.arange(1.0, 12.5, 1.0)
SECTIONS = ('fuzz', 'speeds', 'chipscreen', 'chiprates', 'rig', 'whatif', 'clocks', 'timing',
            'detection')
DOC_BEGIN = '<!-- decoder_benchmark:begin -->'
DOC_END = '<!-- decoder_benchmark:end -->'
# chip rates compared with the graph's (sections chiprates and rig): the previous graph
# rate, rates near it with distinct per-frame packet advances, and the screened ones
CANDIDATE_CHIP_RATES_HZ = (20_000.0, 19_845.0, 20_058.0, 20_250.0, 20_442.0, 20_620.0,
                           20_900.0, 21_020.0, 21_040.0, 21_150.0, 21_200.0)
# along-track positions of the lamp in the standstill runs, m
STANDSTILL_ALONG_M = (3.0, 5.0, 7.0, 9.0)


def node_params_path():
    """The decoder node's config/vlc_decoder_node.yaml."""
    return config_path('vlc_decoder', 'vlc_decoder_node.yaml')


# the graph's lamp chip rate and camera exposure, from the node's parameter file (the one
# place they are written for the decoder; the rig is configured alike in every run)
GRAPH_TIMING = {k: v for k, v in signal_timing_from_params_file(node_params_path()).items()
                if k in ('chip_rate_hz', 'exposure_s')}


def _timing_label(timing):
    return f"{timing['chip_rate_hz']:.0f} chips/s, exposure {timing['exposure_s'] * 1e6:.0f} us"


def packet_advance_chips(chip_rate_hz, fps=30.0):
    """Packet phase advance from one frame to the next, chips in (−27, 27]."""
    a = (chip_rate_hz / fps) % 54.0
    return a - 54.0 if a > 27.0 else a


def _out(lines, text=''):
    lines.append(text)
    print(text, flush=True)


# ---------------------------------------------------------------------- fuzz
def bench_fuzz(lines, per_kind):
    """The profile fuzz at the protocol's default timing and at the graph's."""
    wrong = 0
    for label, cfg in (('protocol default: 10000 chips/s, exposure 50 us', DecoderConfig()),
                       (f'graph: {_timing_label(GRAPH_TIMING)}', DecoderConfig(**GRAPH_TIMING))):
        def decode(y, w, cfg=cfg):
            t = np.broadcast_to(np.arange(y.shape[1]) * cfg.row_time_s
                                + 0.5 * cfg.exposure_s, y.shape)
            return chips.decode_profiles(np.ascontiguousarray(t), y, w, cfg)[0]

        start = time.process_time()
        stats = synth.fuzz_run(decode, per_kind, cfg=cfg)
        cpu = time.process_time() - start
        total = sum(s['profiles'] for s in stats.values())
        _out(lines, f'### Fuzz, {label}: {total} random and corrupted stripe profiles '
                    f'({cpu:.1f} s CPU)')
        _out(lines)
        _out(lines, '| corruption | profiles | accepted | correct UID | wrong UID |')
        _out(lines, '|---|---|---|---|---|')
        for kind, s in stats.items():
            _out(lines, f"| {kind} | {s['profiles']} | {s['accepted']} | {s['correct']} | "
                        f"{s['wrong']} |")
        bad = sum(s['wrong'] for s in stats.values())
        _out(lines, f'| **all** | {total} | {sum(s["accepted"] for s in stats.values())} | '
                    f'{sum(s["correct"] for s in stats.values())} | **{bad}** |')
        _out(lines)
        wrong += bad
    return wrong


# ---------------------------------------------------------------------- rig passes
def _rig():
    from vlc_common.core.lamp_map import LampMap, resolve_lamp_map_path
    from vlc_stereo_camera.core.renderer import RendererConfig, StereoRenderer
    from vlc_stereo_camera.core.trajectory import MotionProfile, Trajectory, Vibration
    return LampMap, resolve_lamp_map_path, RendererConfig, StereoRenderer, MotionProfile, \
        Trajectory, Vibration


def _renderer_class(clock_error):
    """The rig's renderer, or one whose lamp clocks are all off by ``clock_error``
    (fraction; sign drawn per lamp from the seed) instead of uniformly within ±ppm.
    """
    StereoRenderer = _rig()[3]
    if clock_error is None:
        return StereoRenderer
    from vlc_stereo_camera.core.transmitter import LampWaveform

    class FixedClockRenderer(StereoRenderer):
        def lamp_waveform(self, uid):
            wf = self._waveforms.get(uid)
            if wf is None:
                rng = np.random.default_rng([self.seed, 0x1A4F, int(uid)])
                rate = self.config.chip_rate_hz * (1.0 + rng.choice([-1.0, 1.0]) * clock_error)
                wf = LampWaveform(uid=int(uid), chip_rate_hz=rate,
                                  phase_s=rng.uniform(0.0, 54 / rate),
                                  off_level=self.config.off_level)
                self._waveforms[uid] = wf
            return wf
    return FixedClockRenderer


def run_pass(speed_kmh, n_lamps, seed, lamp_clock_ppm=100.0, lamp_map=None,
             collect_frames=True, first_lamp_m=10.0, chip_rate_hz=None,
             exposure_s=None, clock_error=None, rig_options=None):
    """Drive the rig past ``n_lamps`` lamps and decode every frame.

    ``clock_error``: every lamp's clock off by this fraction (else uniform within
    ±``lamp_clock_ppm``); ``rig_options``: more RendererConfig fields (fps, pitch_deg…),
    the decoder configured alike; chip rate and exposure default to the graph's. Returns
    (per-lamp dict uid → info, per-frame list of dicts, CPU ms per frame).
    """
    chip_rate_hz = GRAPH_TIMING['chip_rate_hz'] if chip_rate_hz is None else chip_rate_hz
    exposure_s = GRAPH_TIMING['exposure_s'] if exposure_s is None else exposure_s
    LampMap, resolve, RendererConfig, _, MotionProfile, Trajectory, Vibration = _rig()
    lamps = lamp_map if lamp_map is not None else LampMap.load(resolve(''))
    speed = speed_kmh / 3.6
    start = first_lamp_m - 12.0
    trajectory = Trajectory(MotionProfile('constant', start_chainage_m=start,
                                          speed_mps=speed), Vibration(seed=seed))
    config = RendererConfig(lamp_clock_ppm=lamp_clock_ppm, chip_rate_hz=chip_rate_hz,
                            exposure_s=exposure_s, **(rig_options or {}))
    renderer = _renderer_class(clock_error)(config, lamps, trajectory, seed=seed)
    cfg = DecoderConfig(row_time_s=config.row_time_s, exposure_s=config.exposure_s,
                        chip_rate_hz=config.chip_rate_hz, off_level=config.off_level)
    tracker = LampTracker(cfg, lamps)
    # until the last lamp is 1 m behind base_link: by then it has left the view
    n_frames = int(np.ceil((13.0 + 10.0 * (n_lamps - 1)) / speed * config.fps))
    wanted = {lamp.uid for lamp in lamps.near(first_lamp_m, 10.0 * (n_lamps - 1) + 0.1, 0.1)}
    info, frames, cpu_ms = {}, [], []
    for k in range(n_frames):
        frame = renderer.render(k)
        stamp_ns = int(round(frame.t0_s * 1e9))
        t0 = time.thread_time()
        records = tracker.process(stamp_ns, frame.left, frame.right)
        cpu_ms.append((time.thread_time() - t0) * 1e3)
        for truth in frame.truth:
            if truth.uid not in wanted:
                continue
            lamp = info.setdefault(truth.uid, {'first_seen': k, 'confirmed': None,
                                               'wrong': 0, 'ideal': None, 'frames': 0,
                                               'chips_shown': 0, 'bits_read': 0,
                                               'seen_chips': np.zeros(54, bool)})
            lamp['last_seen'] = k
            lamp['frames'] += 1
            complete = _ideal_reader(lamp, truth, renderer, frame, cfg)
            if lamp['ideal'] is None and complete:
                lamp['ideal'] = k
                lamp['ideal_along_m'] = truth.along_track_m
            rec = _match(records, truth)
            ok = rec is not None and rec.state == CONFIRMED and rec.uid == truth.uid
            if rec is not None and rec.state >= CONFIRMED and rec.uid != truth.uid:
                lamp['wrong'] += 1
            if rec is not None:
                lamp['bits_read'] = max(lamp['bits_read'], rec.bits_known)
            if ok and lamp['confirmed'] is None:
                lamp['confirmed'] = k
                lamp['along_m'] = truth.along_track_m
                lamp['range_m'] = truth.range_m
            if collect_frames:
                read, bad = (_frame_chips(rec, renderer, frame, cfg, truth.uid) if rec
                             else (0, 0))
                frames.append({'range_m': truth.range_m, 'speed': speed_kmh,
                               'found': rec is not None, 'identified': ok,
                               'chips': read, 'chip_errors': bad})
    return info, frames, cpu_ms


def _ideal_reader(lamp, truth, renderer, frame, cfg):
    """Whether an ideal reader has every data bit by now.

    It reads each chip that some row of the disc (truth rows, either image) exposes at
    least 75 % inside it, without error; a bit needs one of its two chips.
    """
    spans = [r for r in (truth.rows_left, truth.rows_right) if r is not None]
    rows = np.arange(min(r[0] for r in spans), max(r[1] for r in spans) + 1)
    wave = renderer.lamp_waveform(truth.uid)
    x = (frame.t0_s + rows * cfg.row_time_s - wave.phase_s) * wave.chip_rate_hz
    half = 0.5 * cfg.exposure_s * wave.chip_rate_hz
    centre = x + half
    k = np.floor(centre)
    inside = (np.minimum(centre + half, k + 1) - np.maximum(centre - half, k)) / (2 * half)
    shown = np.unique(k[inside >= 0.75].astype(np.int64))
    lamp['chips_shown'] += len(shown)
    lamp['seen_chips'][shown % 54] = True
    return bool(lamp['seen_chips'][6:].reshape(24, 2).any(axis=1).all())


def _match(records, truth, gate_px=40.0):
    best, best_d = None, gate_px
    for rec in records:
        for spot, uv in ((rec.left, truth.uv_left), (rec.right, truth.uv_right)):
            if spot is not None:
                d = float(np.hypot(spot.u - uv[0], spot.v - uv[1]))
                if d < best_d:
                    best, best_d = rec, d
    return best


def _frame_chips(rec, renderer, frame, cfg, uid):
    """Chips this frame's own stripes read, and how many disagree with the lamp."""
    rows, level, weight, _ = combine_profiles(rec.left, rec.right)
    t = frame.t0_s + rows * cfg.row_time_s + 0.5 * cfg.exposure_s
    read = chips.read_profiles(t[None], level[None], weight[None], cfg)
    states = read['states'][0]
    k = np.flatnonzero(states != chips.UNKNOWN)
    if len(k) == 0:
        return 0, 0
    t_mid = read['t_b'][0] + (read['n0'][0] + k + 0.5) / read['f'][0]
    wave = renderer.lamp_waveform(uid)
    truth_on = wave.level(t_mid) > 0.5
    return len(k), int(np.count_nonzero(truth_on != (states[k] == chips.ON)))


def _pass_stats(lamps):
    """Per-speed summary of run_pass lamp dicts."""
    along = [v['along_m'] for v in lamps if v['confirmed'] is not None]
    return {'count': len(lamps), 'confirmed': len(along), 'along': along,
            'ranges': [v['range_m'] for v in lamps if v['confirmed'] is not None],
            'wrong': sum(v['wrong'] for v in lamps),
            'ideal': [v['ideal_along_m'] for v in lamps if v['ideal'] is not None]}


def _along_text(along):
    return (f'{np.median(along):.2f} / {np.min(along):.2f} / {np.max(along):.2f}'
            if along else '–')


def bench_speeds(lines, n_lamps, seeds, png_path, chip_rate_hz=None, exposure_s=None,
                 speeds=SPEEDS_KMH, frame_table=True, missed_table=True):
    chip_rate_hz = GRAPH_TIMING['chip_rate_hz'] if chip_rate_hz is None else chip_rate_hz
    exposure_s = GRAPH_TIMING['exposure_s'] if exposure_s is None else exposure_s
    _out(lines, f'### Confirmation per speed (rig, vibration on, {n_lamps} lamps x '
                f'{len(seeds)} runs per speed, {chip_rate_hz:.0f} chips/s, exposure '
                f'{exposure_s * 1e6:.0f} us)')
    _out(lines)
    _out(lines, 'Along-track distance: lamp chainage minus base_link chainage when the lamp\'s '
                'record first carries its confirmed UID. The ideal reader (a bound, not a '
                'decoder) reads without error every chip that some row of the disc exposes '
                '≥ 75 % inside it, and needs one chip per data bit: what the disc\'s rows can '
                'give before the lamp leaves the view.')
    _out(lines)
    _out(lines, '| speed km/h | lamps | confirmed in view | along-track at 1st confirmation '
                'm: median / min / max | range m: median | wrong UIDs | ideal reader: '
                'complete in view | ideal: along-track m median |')
    _out(lines, '|---|---|---|---|---|---|---|---|')
    all_frames, missed = [], []
    failures = 0
    wrong_total = 0
    for speed in speeds:
        lamps = []
        for seed in seeds:
            info, frames, _ = run_pass(speed, n_lamps, seed, chip_rate_hz=chip_rate_hz,
                                       exposure_s=exposure_s)
            all_frames += frames
            lamps += list(info.values())
            missed += [(speed, seed, uid, v) for uid, v in sorted(info.items())
                       if v['confirmed'] is None]
        st = _pass_stats(lamps)
        failures += st['count'] - st['confirmed']
        wrong_total += st['wrong']
        rng = f'{np.median(st["ranges"]):.2f}' if st['ranges'] else '–'
        ideal_stat = f'{np.median(st["ideal"]):.2f}' if st['ideal'] else '–'
        count = max(st['count'], 1)
        _out(lines, f'| {speed:g} | {st["count"]} | {st["confirmed"]} '
                    f'({100.0 * st["confirmed"] / count:.0f} %) | {_along_text(st["along"])} | '
                    f'{rng} | {st["wrong"]} | {len(st["ideal"])} '
                    f'({100.0 * len(st["ideal"]) / count:.0f} %) | {ideal_stat} |')
    _out(lines)
    if missed_table:
        _missed_table(lines, missed)
    if frame_table:
        _range_table(lines, all_frames)
    if png_path is not None:
        _range_png(all_frames, png_path)
        _out(lines, f'![decode success against range](../images/{png_path.name})')
        _out(lines)
    return failures, wrong_total


def _missed_table(lines, missed):
    """Why each lamp missed was missed: what its frames showed, from the rig's truth."""
    if not missed:
        return
    _out(lines, 'Lamps not confirmed in view, with what the rig\'s ground truth says their '
                'frames showed (chips a disc row exposes ≥ 75 % inside): chips shown summed '
                'over the frames, distinct packet chips among them (of 54), data bits with '
                'at least one chip shown (of 24), and the decoder\'s data bits at the end.')
    _out(lines)
    _out(lines, '| speed km/h | run | UID | frames in view | chips shown | distinct chips | '
                'data bits shown | never shown | decoder bits | verdict |')
    _out(lines, '|---|---|---|---|---|---|---|---|---|---|')
    for speed, seed, uid, v in missed:
        shown = v['seen_chips'][6:].reshape(24, 2).any(axis=1)
        never = [int(b) for b in np.flatnonzero(~shown)]
        gone = ', '.join(f'bit {b} (chips {6 + 2 * b}, {7 + 2 * b})' for b in never) or '–'
        verdict = ('not decodable: a data bit never shown' if never else
                   f'decodable by the ideal reader at {v["ideal_along_m"]:.2f} m' if
                   v['ideal'] is not None else 'decodable')
        _out(lines, f'| {speed:g} | {seed} | {uid:#06x} | {v["frames"]} | {v["chips_shown"]} | '
                    f'{int(v["seen_chips"].sum())} | {int(shown.sum())} | {gone} | '
                    f'{v["bits_read"]} | {verdict} |')
    _out(lines)


def bench_rig(lines, n_lamps, seeds, chip_rates=(), speed_kmh=120.0):
    """The highest speed with rig changes that the decoder cannot make itself: frame
    rates, and the lamps' chip rate (``chip_rates``, besides the graph's).
    """
    graph_rate = GRAPH_TIMING['chip_rate_hz']
    options = [(f'as configured (30 fps, {graph_rate:.0f} chips/s)', {}, graph_rate),
               ('40 fps', {'fps': 40.0}, graph_rate),
               ('45 fps (readout 21.6 ms of 22.2)', {'fps': 45.0}, graph_rate)]
    options += [(f'{rate:.0f} chips/s (packet advance {packet_advance_chips(rate):+.2f} '
                 f'chips/frame)', {}, rate) for rate in chip_rates if rate != graph_rate]
    _out(lines, f'### Rig changes at {speed_kmh:g} km/h ({n_lamps} lamps x {len(seeds)} runs, '
                'rig and decoder configured alike, exposure '
                f'{GRAPH_TIMING["exposure_s"] * 1e6:.0f} us)')
    _out(lines)
    _out(lines, '| rig | lamps | frames in view per lamp | ideal reader: complete in view | '
                'decoder: confirmed in view | along-track m at 1st confirmation: median / '
                'min / max | wrong UIDs |')
    _out(lines, '|---|---|---|---|---|---|---|')
    for label, rig_options, rate in options:
        lamps = []
        for seed in seeds:
            info, _, _ = run_pass(speed_kmh, n_lamps, seed, collect_frames=False,
                                  chip_rate_hz=rate, rig_options=rig_options)
            lamps += list(info.values())
        st = _pass_stats(lamps)
        _out(lines, f'| {label} | {st["count"]} | '
                    f'{np.mean([v["frames"] for v in lamps]):.1f} | {len(st["ideal"])} | '
                    f'{st["confirmed"]} | {_along_text(st["along"])} | {st["wrong"]} |')
    _out(lines)


def run_standstill(along_m, seed, chip_rate_hz, max_frames, lamp_map=None):
    """A train standing with a lamp ``along_m`` ahead: the frame (0-based) whose record
    first carries the lamp's confirmed UID, None if none within ``max_frames``; and the
    wrong UIDs published for it.

    At standstill the spot does not move across the rows, so only the packet's phase
    advance from frame to frame (the chip rate) brings new chips into view.
    """
    LampMap, resolve, RendererConfig, _, MotionProfile, Trajectory, Vibration = _rig()
    lamps = lamp_map if lamp_map is not None else LampMap.load(resolve(''))
    lamp_chainage_m = 10.0
    trajectory = Trajectory(MotionProfile('stationary', start_chainage_m=lamp_chainage_m
                                          - along_m), Vibration(seed=seed))
    config = RendererConfig(chip_rate_hz=chip_rate_hz, exposure_s=GRAPH_TIMING['exposure_s'])
    renderer = _rig()[3](config, lamps, trajectory, seed=seed)
    tracker = LampTracker(DecoderConfig(row_time_s=config.row_time_s,
                                        exposure_s=config.exposure_s,
                                        chip_rate_hz=config.chip_rate_hz,
                                        off_level=config.off_level), lamps)
    uid = min(lamps.near(lamp_chainage_m, 0.1, 0.1), key=lambda lamp: abs(
        lamp.track_chainage_m - lamp_chainage_m)).uid
    wrong = 0
    for k in range(max_frames):
        frame = renderer.render(k)
        records = tracker.process(int(round(frame.t0_s * 1e9)), frame.left, frame.right)
        for truth in frame.truth:
            if truth.uid != uid:
                continue
            rec = _match(records, truth)
            if rec is not None and rec.state >= CONFIRMED and rec.uid != uid:
                wrong += 1
            if rec is not None and rec.state == CONFIRMED and rec.uid == uid:
                return k, wrong
    return None, wrong


def _shown_masks(t0_s, rows, chip_rate_hz, phases_chips, row_time_s, exposure_s):
    """Packet chips (bit masks, (P,) uint64) that ``rows`` expose ≥ 75 % inside a chip,
    for lamp packet phases ``phases_chips`` (P,): the ideal reader's rule.
    """
    half = 0.5 * exposure_s * chip_rate_hz
    centre = (t0_s + rows * row_time_s) * chip_rate_hz + half - phases_chips[:, None]
    k = np.floor(centre)
    frac = centre - k
    inside = (np.minimum(frac + half, 1.0) - np.maximum(frac - half, 0.0)) / (2 * half)
    bits = np.where(inside >= 0.75,
                    np.left_shift(np.uint64(1), (k.astype(np.int64) % 54).astype(np.uint64)),
                    np.uint64(0))
    return np.bitwise_or.reduce(bits, axis=1)


def screen_chip_rates(rates_hz, speeds, seeds, n_lamps=6, inner=0.9, n_phases=27):
    """Chip-rate screen on the rig's geometry, every lamp phase: an ideal reader.

    The rig is run once per speed and seed with the lamps unmodulated, to record each
    lamp's disc rows per frame (they do not depend on the chip rate); then, for every
    rate and ``n_phases`` packet phases, a reader that reads without error every chip
    exposed ≥ 75 % inside it by a row within ``inner`` of the disc's half-height (the
    decoder gives cap rows no weight) accumulates the packet chips over the frames.
    Returns {rate: {speed: (fraction of lamp×phase that saw all 54 chips in view,
    mean along-track m at completion, 0 when never)}}.
    """
    LampMap, resolve, RendererConfig, StereoRenderer, MotionProfile, Trajectory, \
        Vibration = _rig()
    lamps = LampMap.load(resolve(''))
    config = RendererConfig(lamp_modulation=False, exposure_s=GRAPH_TIMING['exposure_s'])
    tracks = {speed: [] for speed in speeds}
    for speed in speeds:
        for seed in seeds:
            trajectory = Trajectory(MotionProfile('constant', start_chainage_m=-2.0,
                                                  speed_mps=speed / 3.6), Vibration(seed=seed))
            renderer = StereoRenderer(config, lamps, trajectory, seed=seed)
            n_frames = int(np.ceil((13.0 + 10.0 * (n_lamps - 1)) / (speed / 3.6) * config.fps))
            wanted = {lamp.uid for lamp in lamps.near(10.0, 10.0 * (n_lamps - 1) + 0.1, 0.1)}
            per_uid = {}
            for k in range(n_frames):
                frame = renderer.render(k)
                for truth in frame.truth:
                    spans = [r for r in (truth.rows_left, truth.rows_right) if r is not None]
                    if truth.uid in wanted and spans:
                        r0, r1 = min(r[0] for r in spans), max(r[1] for r in spans)
                        c, a = 0.5 * (r0 + r1), 0.5 * (r1 - r0)
                        rows = np.arange(r0, r1 + 1)
                        per_uid.setdefault(truth.uid, []).append(
                            (frame.t0_s, rows[np.abs(rows - c) <= inner * a + 1e-9],
                             truth.along_track_m))
            tracks[speed] += list(per_uid.values())
    phases = np.arange(n_phases) * 54.0 / n_phases
    full = np.uint64((1 << 54) - 1)
    out = {}
    for rate in rates_hz:
        out[rate] = {}
        for speed in speeds:
            done = []
            for frames in tracks[speed]:
                seen = np.zeros(n_phases, np.uint64)
                at = np.zeros(n_phases)
                for t0_s, rows, along_m in frames:
                    if len(rows):
                        seen |= _shown_masks(t0_s, rows, rate, phases, config.row_time_s,
                                             config.exposure_s)
                    at = np.where((at == 0) & (seen == full), along_m, at)
                    if np.all(at > 0):
                        break
                done.append(at)
            done = np.array(done)
            out[rate][speed] = (float(np.mean(done > 0)), float(np.mean(done)))
    return out


def bench_chipscreen(lines, seeds, speeds=(10, 20, 40, 60, 80, 100, 110, 120),
                     lo_hz=19_000.0, hi_hz=21_500.0, step_hz=10.0, top=12):
    """The screen of :func:`screen_chip_rates` over a range of rates: the best by the
    worst speed, and the candidates.
    """
    rates = list(np.arange(lo_hz, hi_hz + 0.5 * step_hz, step_hz))
    rates += [r for r in CANDIDATE_CHIP_RATES_HZ if r not in rates]
    start = time.process_time()
    res = screen_chip_rates(rates, speeds, seeds)
    cpu = time.process_time() - start
    _out(lines, f'### Chip-rate screen: every 54th of a packet phase, rig geometry at '
                f'{", ".join(f"{s:g}" for s in speeds)} km/h x {len(seeds)} runs, '
                f'{lo_hz:.0f}–{hi_hz:.0f} chips/s in steps of {step_hz:g} ({cpu:.0f} s CPU)')
    _out(lines)
    _out(lines, 'A reader that reads every chip a row inside 90 % of the disc\'s half-height '
                'exposes ≥ 75 % inside it, for every lamp and 27 packet phases: the share of '
                'lamp × phase that saw all 54 packet chips before leaving the view, and the '
                'mean along-track distance (m) where it did (0 counted when never). Ranked '
                'by the worst speed, among rates complete at every speed; then the candidates.')
    _out(lines)
    _out(lines, '| chip rate chips/s | packet advance chips/frame | complete, worst speed | '
                + ' | '.join(f'{s:g} km/h m' for s in speeds) + ' |')
    _out(lines, '|---|---|---|' + '---|' * len(speeds))

    def row(rate):
        r = res[rate]
        worst = min(r[s][0] for s in speeds)
        _out(lines, f'| {rate:.0f} | {packet_advance_chips(rate):+.2f} | {100 * worst:.0f} % | '
                    + ' | '.join(f'{r[s][1]:.2f}' for s in speeds) + ' |')

    complete = [r for r in rates if min(res[r][s][0] for s in speeds) >= 0.999]
    for rate in sorted(complete, key=lambda r: -min(res[r][s][1] for s in speeds))[:top]:
        row(rate)
    _out(lines, '| *candidates* | | | ' + ' | '.join('' for _ in speeds) + ' |')
    for rate in CANDIDATE_CHIP_RATES_HZ:
        row(rate)
    _out(lines)
    return res


def bench_chiprates(lines, chip_rates, n_lamps, seeds, speeds=SPEEDS_KMH,
                    standstill_max_frames=60):
    """Candidate lamp chip rates at every speed and at standstill (rig and decoder
    configured alike, the graph's exposure).
    """
    fps = 30.0
    _out(lines, f'### Lamp chip rate: confirmation at every speed and at standstill '
                f'({n_lamps} lamps x {len(seeds)} runs per speed, exposure '
                f'{GRAPH_TIMING["exposure_s"] * 1e6:.0f} us, {fps:g} fps)')
    _out(lines)
    _out(lines, 'Per speed: lamps confirmed in view / lamps, and the median along-track '
                'distance at the first confirmation (m). "ideal": lamps the ideal reader '
                'completes in view, all speeds. Packet advance: (chip rate / fps) modulo 54, '
                'the chips the packet phase moves from one frame to the next. Standstill: '
                'frames until the decoder confirms a lamp standing '
                f'{", ".join(f"{a:g}" for a in STANDSTILL_ALONG_M)} m ahead (worst of '
                f'these x {len(seeds)} runs; "–" not within {standstill_max_frames} frames).')
    _out(lines)
    _out(lines, '| chip rate chips/s | packet advance chips/frame | '
                + ' | '.join(f'{s:g} km/h' for s in speeds)
                + ' | wrong UIDs | ideal: complete | standstill: frames to confirm, worst |')
    _out(lines, '|---|---|' + '---|' * len(speeds) + '---|---|---|')
    results = {}
    for rate in chip_rates:
        cells, wrong, ideal, total = [], 0, 0, 0
        per_speed = {}
        for speed in speeds:
            lamps = []
            for seed in seeds:
                info, _, _ = run_pass(speed, n_lamps, seed, collect_frames=False,
                                      chip_rate_hz=rate)
                lamps += list(info.values())
            st = _pass_stats(lamps)
            per_speed[speed] = st
            wrong += st['wrong']
            ideal += len(st['ideal'])
            total += st['count']
            med = f'{np.median(st["along"]):.2f}' if st['along'] else '–'
            cells.append(f'{st["confirmed"]}/{st["count"]}, {med}')
        still = []
        for along in STANDSTILL_ALONG_M:
            for seed in seeds:
                k, bad = run_standstill(along, seed, rate, standstill_max_frames)
                still.append(k)
                wrong += bad
        worst = '–' if any(k is None for k in still) else f'{max(still) + 1}'
        results[rate] = {'speeds': per_speed, 'wrong': wrong, 'standstill': still}
        _out(lines, f'| {rate:.0f} | {packet_advance_chips(rate, fps):+.2f} | '
                    + ' | '.join(cells) + f' | {wrong} | {ideal}/{total} | {worst} |')
    _out(lines)
    return results


def _range_table(lines, frames):
    _out(lines, '### Per-frame decoding against range (all speeds)')
    _out(lines)
    _out(lines, '"chips read" counts the chips one frame\'s stripes read on their own '
                '(edges → clock → chips), "chip errors" those disagreeing with the rig\'s '
                'lamp waveform; "identified" is the share of frames whose record for the '
                'lamp carries its confirmed UID (history included).')
    _out(lines)
    _out(lines, '| range m | frames | spot found | chips read / frame | chip errors | '
                'identified |')
    _out(lines, '|---|---|---|---|---|---|')
    r = np.array([f['range_m'] for f in frames])
    for lo, hi in zip(RANGE_BINS_M[:-1], RANGE_BINS_M[1:]):
        sel = [f for f, x in zip(frames, r) if lo <= x < hi]
        if not sel:
            continue
        n = len(sel)
        read = sum(f['chips'] for f in sel)
        bad = sum(f['chip_errors'] for f in sel)
        _out(lines, f'| {lo:.0f}–{hi:.0f} | {n} | {100.0 * sum(f["found"] for f in sel) / n:.0f} %'
                    f' | {read / n:.1f} | {bad} ({100.0 * bad / max(read, 1):.2f} %) | '
                    f'{100.0 * sum(f["identified"] for f in sel) / n:.0f} % |')
    _out(lines)


def _range_png(frames, path):
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt
    fig, axes = plt.subplots(1, 2, figsize=(11, 4))
    centres = 0.5 * (RANGE_BINS_M[:-1] + RANGE_BINS_M[1:])
    for speed in sorted({f['speed'] for f in frames}):
        sel = [f for f in frames if f['speed'] == speed]
        r = np.array([f['range_m'] for f in sel])
        ident = np.array([f['identified'] for f in sel], float)
        ys = [ident[(r >= lo) & (r < hi)].mean() * 100 if np.any((r >= lo) & (r < hi))
              else np.nan for lo, hi in zip(RANGE_BINS_M[:-1], RANGE_BINS_M[1:])]
        axes[1].plot(centres, ys, marker='o', label=f'{speed} km/h')
    r = np.array([f['range_m'] for f in frames])
    read = np.array([f['chips'] for f in frames], float)
    bad = np.array([f['chip_errors'] for f in frames], float)
    per_bin = [read[(r >= lo) & (r < hi)].mean() if np.any((r >= lo) & (r < hi)) else np.nan
               for lo, hi in zip(RANGE_BINS_M[:-1], RANGE_BINS_M[1:])]
    err = [100 * bad[(r >= lo) & (r < hi)].sum() / max(read[(r >= lo) & (r < hi)].sum(), 1)
           for lo, hi in zip(RANGE_BINS_M[:-1], RANGE_BINS_M[1:])]
    axes[0].bar(centres, per_bin, width=0.8, color='tab:blue', label='chips read per frame')
    axes[0].axhline(54, color='gray', ls=':', label='one packet (54 chips)')
    ax2 = axes[0].twinx()
    ax2.plot(centres, err, color='tab:red', marker='x', label='chip errors %')
    ax2.set_ylabel('chip errors (%)', color='tab:red')
    axes[0].set_xlabel('range to lamp (m)')
    axes[0].set_ylabel('chips read from one frame')
    axes[0].set_title('One frame\'s stripes')
    axes[0].legend(loc='upper right')
    axes[1].set_xlabel('range to lamp (m)')
    axes[1].set_ylabel('frames with the lamp identified (%)')
    axes[1].set_ylim(-2, 102)
    axes[1].set_title('UID confirmed (assembled over frames)')
    axes[1].legend(fontsize=8)
    for ax in axes:
        ax.invert_xaxis()
        ax.grid(alpha=0.3)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)


def bench_whatif(lines, n_lamps, seeds, chip_rate_hz=10_000.0, exposure_s=50e-6):
    """The high speeds again at the protocol's default 10 kchip/s and the paper's 50 us
    exposure (rig and decoder alike): why the project runs 20 kchip/s and 25 us.
    """
    _out(lines, '### What if: the protocol default 10 kchip/s with 50 us exposure (rig and '
                'decoder configured alike)')
    _out(lines)
    bench_speeds(lines, n_lamps, seeds, None, chip_rate_hz, exposure_s, (80, 100, 120),
                 frame_table=False, missed_table=False)


def bench_clocks(lines, n_lamps, seeds, errors=(0.0, 1e-4, 1e-3, 5e-3, 1e-2, 2e-2),
                 speeds=(20, 60, 100)):
    """Confirmation against a lamp clock error of fixed size (random sign per lamp)."""
    _out(lines, f'### Lamp clock error ({n_lamps} lamps x {len(seeds)} runs per cell, every '
                f'lamp\'s chip rate off by the error, sign drawn per lamp; '
                f'{GRAPH_TIMING["chip_rate_hz"]:.0f} chips/s)')
    _out(lines)
    _out(lines, 'Beyond the protocol\'s ±100 ppm the chip count between frames is unknown: '
                'fragments are aligned by content (header sightings give the rate; '
                'overlaps of the fragments\' own chips place them). "without overlaps": the '
                'same runs with alignment by overlaps switched off.')
    _out(lines)
    _out(lines, '| clock error | speed km/h | lamps | confirmed | along-track m median | '
                'wrong UIDs | confirmed without overlaps |')
    _out(lines, '|---|---|---|---|---|---|---|')
    saved = assembly.MIN_OVERLAP_CHIPS
    for error in errors:
        for speed in speeds:
            counts = []
            # within the protocol's tolerance the clock places every fragment
            for overlap in (True, False) if error > 1e-4 else (True,):
                assembly.MIN_OVERLAP_CHIPS = saved if overlap else 10 ** 6
                lamps = []
                try:
                    for seed in seeds:
                        info, _, _ = run_pass(speed, n_lamps, seed, collect_frames=False,
                                              clock_error=error)
                        lamps += list(info.values())
                finally:
                    assembly.MIN_OVERLAP_CHIPS = saved
                counts.append(_pass_stats(lamps))
            st = counts[0]
            without = counts[1]['confirmed'] if len(counts) > 1 else '–'
            label = f'{error * 1e6:.0f} ppm' if error < 1e-3 else f'{error * 100:g} %'
            _out(lines, f'| {label} | {speed} | {st["count"]} | {st["confirmed"]} | '
                        f'{np.median(st["along"]) if st["along"] else float("nan"):.2f} | '
                        f'{st["wrong"]} | {without} |')
    _out(lines)


def bench_timing(lines, n_frames):
    LampMap, _, RendererConfig, StereoRenderer, MotionProfile, Trajectory, Vibration = _rig()
    from vlc_common.core.lamp_map import straight_tunnel_map
    lamps = straight_tunnel_map(spacing_m=5.0, count=60)
    _out(lines, f'### Processing time per stereo pair, two lamps in view ({n_frames} pairs, '
                f'60 km/h, OpenCV 1 thread)')
    _out(lines)
    _out(lines, '| timing | | median ms | p90 ms | max ms |')
    _out(lines, '|---|---|---|---|---|')
    medians = []
    for label, timing in ((f'graph: {_timing_label(GRAPH_TIMING)}', GRAPH_TIMING),
                          ('protocol default: 10000 chips/s, exposure 50 us', {})):
        trajectory = Trajectory(MotionProfile('constant', start_chainage_m=0.0,
                                              speed_mps=60 / 3.6), Vibration(seed=3))
        renderer = StereoRenderer(RendererConfig(**timing), lamps, trajectory, seed=3)
        tracker = LampTracker(DecoderConfig(**timing), lamps)
        cpu, wall = [], []
        k = 0
        while len(cpu) < n_frames and k < 20 * n_frames:
            frame = renderer.render(k)
            k += 1
            t_wall, t_cpu = time.perf_counter(), time.thread_time()
            tracker.process(int(round(frame.t0_s * 1e9)), frame.left, frame.right)
            t_cpu, t_wall = time.thread_time() - t_cpu, time.perf_counter() - t_wall
            both = [t for t in frame.truth if t.in_left and t.in_right]
            if len(both) == 2:
                cpu.append(t_cpu * 1e3)
                wall.append(t_wall * 1e3)
        cpu, wall = np.array(cpu), np.array(wall)
        _out(lines, f'| {label} | CPU (thread time) | {np.median(cpu):.2f} | '
                    f'{np.percentile(cpu, 90):.2f} | {cpu.max():.2f} |')
        _out(lines, f'| | wall (shared machine) | {np.median(wall):.2f} | '
                    f'{np.percentile(wall, 90):.2f} | {wall.max():.2f} |')
        medians.append(float(np.median(cpu)))
    _out(lines)
    return medians[0]


def bench_detection(lines, n_frames):
    LampMap, resolve, RendererConfig, StereoRenderer, MotionProfile, Trajectory, \
        Vibration = _rig()
    lamps = LampMap.load(resolve(''))
    trajectory = Trajectory(MotionProfile('constant', start_chainage_m=0.0,
                                          speed_mps=40 / 3.6), Vibration(seed=5))
    renderer = StereoRenderer(RendererConfig(), lamps, trajectory, seed=5)
    chains = {'paper: median 3x3 + Otsu': DecoderConfig(use_otsu=True, median_filter=True),
              'paper without median': DecoderConfig(use_otsu=True),
              'noise-referenced threshold (default)': DecoderConfig()}
    stats = {name: {'lamps': 0, 'found': 0, 'spurious': 0, 'ms': []} for name in chains}
    for k in range(n_frames):
        frame = renderer.render(k)
        for name, cfg in chains.items():
            t0 = time.thread_time()
            boxes, _, _, _ = find_spots(frame.left, cfg)
            stats[name]['ms'].append((time.thread_time() - t0) * 1e3)
            hit = set()
            for truth in frame.truth:
                if not truth.in_left:
                    continue
                stats[name]['lamps'] += 1
                u, v = truth.uv_left
                for i, (r0, r1, c0, c1) in enumerate(boxes):
                    if r0 - 3 <= v <= r1 + 3 and c0 - 3 <= u <= c1 + 3:
                        hit.add(i)
                        stats[name]['found'] += 1
                        break
            stats[name]['spurious'] += len(boxes) - len(hit)
    _out(lines, f'### Spot detection chains (left images, {n_frames} frames at 40 km/h)')
    _out(lines)
    _out(lines, '| chain | lamps in view | found | spurious spots | CPU ms / image (median) |')
    _out(lines, '|---|---|---|---|---|')
    for name, s in stats.items():
        _out(lines, f"| {name} | {s['lamps']} | {s['found']} | {s['spurious']} | "
                    f"{np.median(s['ms']):.2f} |")
    _out(lines)


# ---------------------------------------------------------------------- docs
def _section_marks(name):
    return f'<!-- decoder_benchmark:{name}:begin -->', f'<!-- decoder_benchmark:{name}:end -->'


def write_docs(sections, workspace):
    """Replace the generated sections (name → lines) in docs/arch/vlc_decoder.md.

    Each section sits between its own markers inside the generated block; sections not
    run keep their text, so ``--only`` refreshes just what it measured.
    """
    doc = workspace / 'docs' / 'arch' / 'vlc_decoder.md'
    text = doc.read_text(encoding='utf-8') if doc.exists() else ''
    if DOC_BEGIN not in text or DOC_END not in text:
        text = text.rstrip() + f'\n\n## Measured figures\n\n{DOC_BEGIN}\n{DOC_END}\n'
    head, rest = text.split(DOC_BEGIN, 1)
    block, tail = rest.split(DOC_END, 1)
    old = {}
    for name in SECTIONS:
        begin, end = _section_marks(name)
        if begin in block and end in block:
            old[name] = block.split(begin, 1)[1].split(end, 1)[0].strip('\n').split('\n')
    old.update(sections)
    parts = ['', '<!-- generated by `decoder_benchmark --write-docs`; do not edit by hand -->',
             '']
    for name in SECTIONS:
        if name in old:
            begin, end = _section_marks(name)
            parts += [begin, *old[name], end, '']
    doc.parent.mkdir(parents=True, exist_ok=True)
    doc.write_text(head + DOC_BEGIN + '\n'.join(parts) + DOC_END + tail, encoding='utf-8')
    print(f'wrote {doc}')


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    parser.add_argument('--only', nargs='*', default=None, choices=list(SECTIONS))
    parser.add_argument('--fuzz-per-kind', type=int, default=15_000)
    parser.add_argument('--lamps', type=int, default=6, help='lamps passed per run')
    parser.add_argument('--seeds', type=int, nargs='*', default=[1, 2])
    parser.add_argument('--rig-seeds', type=int, nargs='*', default=[1, 2, 3, 4],
                        help='runs of the rig-change section')
    parser.add_argument('--timing-frames', type=int, default=120)
    parser.add_argument('--detection-frames', type=int, default=120)
    parser.add_argument('--chip-rate-hz', type=float, default=GRAPH_TIMING['chip_rate_hz'],
                        help='lamp chip rate of the speed runs (rig and decoder)')
    parser.add_argument('--exposure-s', type=float, default=GRAPH_TIMING['exposure_s'],
                        help='row exposure of the speed runs (rig and decoder)')
    parser.add_argument('--speeds', type=float, nargs='*', default=list(SPEEDS_KMH))
    parser.add_argument('--chip-rates', type=float, nargs='*',
                        default=list(CANDIDATE_CHIP_RATES_HZ),
                        help='lamp chip rates compared in the chiprates section')
    parser.add_argument('--rig-chip-rates', type=float, nargs='*',
                        default=list(CANDIDATE_CHIP_RATES_HZ),
                        help='lamp chip rates of the rig-change section (besides the '
                             'graph\'s)')
    parser.add_argument('--write-docs', action='store_true',
                        help='update docs/arch/vlc_decoder.md and the PNG under $VLC_WS')
    args = parser.parse_args(argv)
    cv2.setNumThreads(1)
    only = set(args.only) if args.only else set(SECTIONS)
    workspace = pathlib.Path(os.environ.get('VLC_WS', '.')).resolve()
    png = workspace / 'docs' / 'images' / 'decoder_success_vs_range.png'
    sections = {}
    status = 0
    for name in SECTIONS:
        if name not in only:
            continue
        lines = sections[name] = []
        if name == 'fuzz' and bench_fuzz(lines, args.fuzz_per_kind):
            status = 1
        elif name == 'speeds':
            _, wrong = bench_speeds(lines, args.lamps, args.seeds,
                                    png if args.write_docs else None,
                                    args.chip_rate_hz, args.exposure_s, args.speeds)
            status |= int(wrong > 0)
        elif name == 'chipscreen':
            bench_chipscreen(lines, args.rig_seeds)
        elif name == 'chiprates':
            results = bench_chiprates(lines, args.chip_rates, args.lamps, args.seeds,
                                      args.speeds)
            status |= int(any(r['wrong'] for r in results.values()))
        elif name == 'rig':
            bench_rig(lines, args.lamps, args.rig_seeds, args.rig_chip_rates)
        elif name == 'whatif':
            bench_whatif(lines, args.lamps, args.seeds)
        elif name == 'clocks':
            bench_clocks(lines, max(3, args.lamps // 2), args.seeds)
        elif name == 'timing':
            bench_timing(lines, args.timing_frames)
        elif name == 'detection':
            bench_detection(lines, args.detection_frames)
    if args.write_docs:
        write_docs(sections, workspace)
    return status


if __name__ == '__main__':
    sys.exit(main())
