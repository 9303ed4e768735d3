"""``decoder_benchmark``: the figures of the decoder's targets, measured, printed, written.

Sections (all by default; ``--only`` picks some):

* ``fuzz``: random and corrupted stripe profiles (``core.synth.fuzz_profiles``) through
  the profile decoder: accepted, correct and wrong UIDs per corruption.
* ``speeds``: the rig (``vlc_stereo_camera`` renderer, default lamp map and scenario,
  vibration on) at 20…120 km/h: per lamp passed, the along-track distance and range at
  the first confirmation, lamps confirmed before leaving the view, wrong UIDs; per frame,
  the chips each frame's stripes read (and how many wrong, against the rig's waveform)
  and whether the lamp's record carries its UID, binned by range → table + PNG.
* ``whatif``: the high speeds at 20 000 chips/s and 25 µs exposure (rig and decoder).
* ``clocks``: confirmation against the lamps' clock error (content alignment beyond
  the protocol's ±100 ppm).
* ``timing``: CPU time per stereo pair with two lamps in view (lamps every 5 m),
  OpenCV on one thread.
* ``detection``: spot recall and spurious spots of the paper's chain (median filter +
  Otsu) and of the noise-referenced threshold, with their times.

``--write-docs`` replaces the generated section of ``docs/arch/vlc_decoder.md`` and
writes ``docs/images/decoder_success_vs_range.png`` under the workspace ($VLC_WS).
"""
import argparse
import os
import pathlib
import re
import sys
import time

import cv2
import numpy as np

from .core import chips, synth
from .core.assembly import CONFIRMED
from .core.config import DecoderConfig
from .core.spots import find_spots
from .core.tracker import LampTracker, combine_profiles

SPEEDS_KMH = (20, 40, 60, 80, 100, 120)
RANGE_BINS_M = np.arange(1.0, 12.5, 1.0)
DOC_BEGIN = '<!-- decoder_benchmark:begin -->'
DOC_END = '<!-- decoder_benchmark:end -->'


def _out(lines, text=''):
    lines.append(text)
    print(text, flush=True)


# ---------------------------------------------------------------------- fuzz
def bench_fuzz(lines, per_kind):
    cfg = DecoderConfig()

    def decode(y, w):
        t = np.broadcast_to(np.arange(y.shape[1]) * cfg.row_time_s + 0.5 * cfg.exposure_s,
                            y.shape)
        return chips.decode_profiles(np.ascontiguousarray(t), y, w, cfg)[0]

    start = time.process_time()
    stats = synth.fuzz_run(decode, per_kind)
    cpu = time.process_time() - start
    total = sum(s['profiles'] for s in stats.values())
    _out(lines, f'### Fuzz: {total} random and corrupted stripe profiles '
                f'({cpu:.1f} s CPU)')
    _out(lines)
    _out(lines, '| corruption | profiles | accepted | correct UID | wrong UID |')
    _out(lines, '|---|---|---|---|---|')
    for kind, s in stats.items():
        _out(lines, f"| {kind} | {s['profiles']} | {s['accepted']} | {s['correct']} | "
                    f"{s['wrong']} |")
    wrong = sum(s['wrong'] for s in stats.values())
    _out(lines, f'| **all** | {total} | {sum(s["accepted"] for s in stats.values())} | '
                f'{sum(s["correct"] for s in stats.values())} | **{wrong}** |')
    _out(lines)
    return wrong


# ---------------------------------------------------------------------- rig passes
def _rig():
    from vlc_stereo_camera.core.lamp_map import LampMap, resolve_lamp_map_path
    from vlc_stereo_camera.core.renderer import RendererConfig, StereoRenderer
    from vlc_stereo_camera.core.trajectory import MotionProfile, Trajectory, Vibration
    return LampMap, resolve_lamp_map_path, RendererConfig, StereoRenderer, MotionProfile, \
        Trajectory, Vibration


def run_pass(speed_kmh, n_lamps, seed, lamp_clock_ppm=100.0, lamp_map=None,
             collect_frames=True, first_lamp_m=10.0, chip_rate_hz=20_000.0,
             exposure_s=25e-6):
    """Drive the rig past ``n_lamps`` lamps and decode every frame.

    Returns (per-lamp dict uid → info, per-frame list of dicts, CPU ms per frame).
    """
    LampMap, resolve, RendererConfig, StereoRenderer, MotionProfile, Trajectory, \
        Vibration = _rig()
    lamps = lamp_map if lamp_map is not None else LampMap.load(resolve(''))
    speed = speed_kmh / 3.6
    start = first_lamp_m - 12.0
    trajectory = Trajectory(MotionProfile('constant', start_chainage_m=start,
                                          speed_mps=speed), Vibration(seed=seed))
    config = RendererConfig(lamp_clock_ppm=lamp_clock_ppm, chip_rate_hz=chip_rate_hz,
                            exposure_s=exposure_s)
    renderer = StereoRenderer(config, lamps, trajectory, seed=seed)
    cfg = DecoderConfig(row_time_s=config.row_time_s, exposure_s=config.exposure_s,
                        chip_rate_hz=config.chip_rate_hz, off_level=config.off_level)
    tracker = LampTracker(cfg, lamps)
    n_frames = int(np.ceil((12.0 + 10.0 * (n_lamps - 1)) / speed * config.fps))
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
                                               'wrong': 0, 'ideal': None,
                                               'seen_chips': np.zeros(54, bool)})
            lamp['last_seen'] = k
            if lamp['ideal'] is None and _ideal_reader(lamp, truth, renderer, frame, cfg):
                lamp['ideal'] = k
                lamp['ideal_along_m'] = truth.along_track_m
            rec = _match(records, truth)
            ok = rec is not None and rec.state == CONFIRMED and rec.uid == truth.uid
            if rec is not None and rec.state >= CONFIRMED and rec.uid != truth.uid:
                lamp['wrong'] += 1
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
    lamp['seen_chips'][(k[inside >= 0.75].astype(np.int64)) % 54] = True
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


def bench_speeds(lines, n_lamps, seeds, png_path, chip_rate_hz=20_000.0, exposure_s=25e-6,
                 speeds=SPEEDS_KMH, frame_table=True):
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
    all_frames = []
    failures = 0
    wrong_total = 0
    for speed in speeds:
        along, ranges, confirmed, count, wrong, ideal = [], [], 0, 0, 0, []
        for seed in seeds:
            info, frames, _ = run_pass(speed, n_lamps, seed, chip_rate_hz=chip_rate_hz,
                                       exposure_s=exposure_s)
            all_frames += frames
            for lamp in info.values():
                count += 1
                wrong += lamp['wrong']
                if lamp['confirmed'] is not None:
                    confirmed += 1
                    along.append(lamp['along_m'])
                    ranges.append(lamp['range_m'])
                if lamp['ideal'] is not None:
                    ideal.append(lamp['ideal_along_m'])
        failures += count - confirmed
        wrong_total += wrong
        stat = (f'{np.median(along):.2f} / {np.min(along):.2f} / {np.max(along):.2f}'
                if along else '–')
        rng = f'{np.median(ranges):.2f}' if ranges else '–'
        ideal_stat = f'{np.median(ideal):.2f}' if ideal else '–'
        _out(lines, f'| {speed:g} | {count} | {confirmed} ({100.0 * confirmed / max(count, 1):.0f} %)'
                    f' | {stat} | {rng} | {wrong} | {len(ideal)} '
                    f'({100.0 * len(ideal) / max(count, 1):.0f} %) | {ideal_stat} |')
    _out(lines)
    if frame_table:
        _range_table(lines, all_frames)
    if png_path is not None:
        _range_png(all_frames, png_path)
        _out(lines, f'![decode success against range](../images/{png_path.name})')
        _out(lines)
    return failures, wrong_total


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
    exposure (rig and decoder alike): why the project runs 20 kchip/s and 25 us."""
    _out(lines, '### What if: the protocol default 10 kchip/s with 50 us exposure (rig and '
                'decoder configured alike)')
    _out(lines)
    bench_speeds(lines, n_lamps, seeds, None, chip_rate_hz, exposure_s, (80, 100, 120),
                 frame_table=False)


def bench_clocks(lines, n_lamps, seed):
    _out(lines, '### Lamp clock error (content alignment beyond ±100 ppm)')
    _out(lines)
    _out(lines, '| clock error (uniform ±) | speed km/h | lamps | confirmed | along-track m '
                'median | wrong UIDs |')
    _out(lines, '|---|---|---|---|---|---|')
    for ppm in (100.0, 1000.0, 5000.0, 20000.0):
        for speed in (20, 60):
            info, _, _ = run_pass(speed, n_lamps, seed, lamp_clock_ppm=ppm,
                                  collect_frames=False)
            along = [v['along_m'] for v in info.values() if v['confirmed'] is not None]
            wrong = sum(v['wrong'] for v in info.values())
            _out(lines, f'| {ppm:.0f} ppm | {speed} | {len(info)} | {len(along)} | '
                        f'{np.median(along) if along else float("nan"):.2f} | {wrong} |')
    _out(lines)


def bench_timing(lines, n_frames):
    LampMap, _, RendererConfig, StereoRenderer, MotionProfile, Trajectory, Vibration = _rig()
    from vlc_stereo_camera.core.lamp_map import straight_tunnel_map
    lamps = straight_tunnel_map(spacing_m=5.0, count=60)
    trajectory = Trajectory(MotionProfile('constant', start_chainage_m=0.0,
                                          speed_mps=60 / 3.6), Vibration(seed=3))
    renderer = StereoRenderer(RendererConfig(), lamps, trajectory, seed=3)
    tracker = LampTracker(DecoderConfig(), lamps)
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
    _out(lines, f'### Processing time per stereo pair, two lamps in view ({len(cpu)} pairs, '
                f'60 km/h, OpenCV 1 thread)')
    _out(lines)
    _out(lines, '| | median ms | p90 ms | max ms |')
    _out(lines, '|---|---|---|---|')
    _out(lines, f'| CPU (thread time) | {np.median(cpu):.2f} | {np.percentile(cpu, 90):.2f} | '
                f'{cpu.max():.2f} |')
    _out(lines, f'| wall (shared machine) | {np.median(wall):.2f} | '
                f'{np.percentile(wall, 90):.2f} | {wall.max():.2f} |')
    _out(lines)
    return float(np.median(cpu))


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
def write_docs(lines, workspace):
    doc = workspace / 'docs' / 'arch' / 'vlc_decoder.md'
    text = doc.read_text(encoding='utf-8') if doc.exists() else ''
    block = '\n'.join([DOC_BEGIN, '<!-- generated by `decoder_benchmark --write-docs`; do '
                                  'not edit by hand -->', ''] + lines + [DOC_END])
    if DOC_BEGIN in text and DOC_END in text:
        text = re.sub(re.escape(DOC_BEGIN) + '.*?' + re.escape(DOC_END),
                      lambda _: block, text, flags=re.S)
    else:
        text = text.rstrip() + '\n\n## Measured figures\n\n' + block + '\n'
    doc.parent.mkdir(parents=True, exist_ok=True)
    doc.write_text(text, encoding='utf-8')
    print(f'wrote {doc}')


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    parser.add_argument('--only', nargs='*', default=None,
                        choices=['fuzz', 'speeds', 'whatif', 'clocks', 'timing',
                                 'detection'])
    parser.add_argument('--fuzz-per-kind', type=int, default=15_000)
    parser.add_argument('--lamps', type=int, default=6, help='lamps passed per run')
    parser.add_argument('--seeds', type=int, nargs='*', default=[1, 2])
    parser.add_argument('--timing-frames', type=int, default=120)
    parser.add_argument('--detection-frames', type=int, default=120)
    parser.add_argument('--chip-rate-hz', type=float, default=20_000.0,
                        help='lamp chip rate of the speed runs (rig and decoder)')
    parser.add_argument('--exposure-s', type=float, default=25e-6,
                        help='row exposure of the speed runs (rig and decoder)')
    parser.add_argument('--speeds', type=float, nargs='*', default=list(SPEEDS_KMH))
    parser.add_argument('--write-docs', action='store_true',
                        help='update docs/arch/vlc_decoder.md and the PNG under $VLC_WS')
    args = parser.parse_args(argv)
    cv2.setNumThreads(1)
    only = set(args.only) if args.only else {'fuzz', 'speeds', 'whatif', 'clocks',
                                             'timing', 'detection'}
    workspace = pathlib.Path(os.environ.get('VLC_WS', '.')).resolve()
    png = workspace / 'docs' / 'images' / 'decoder_success_vs_range.png'
    lines = []
    status = 0
    if 'fuzz' in only and bench_fuzz(lines, args.fuzz_per_kind):
        status = 1
    if 'speeds' in only:
        failures, wrong = bench_speeds(lines, args.lamps, args.seeds,
                                       png if args.write_docs else None,
                                       args.chip_rate_hz, args.exposure_s, args.speeds)
        status |= int(wrong > 0)
    if 'whatif' in only:
        bench_whatif(lines, args.lamps, args.seeds)
    if 'clocks' in only:
        bench_clocks(lines, max(3, args.lamps // 2), args.seeds[0])
    if 'timing' in only:
        bench_timing(lines, args.timing_frames)
    if 'detection' in only:
        bench_detection(lines, args.detection_frames)
    if args.write_docs:
        write_docs(lines, workspace)
    return status


if __name__ == '__main__':
    sys.exit(main())
