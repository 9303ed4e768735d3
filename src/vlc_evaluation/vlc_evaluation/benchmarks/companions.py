"""``companion_benchmark``: accuracy, availability and CPU time of companion methods 1–3.

Sections (``--only``; all by default):

* ``rssi`` — the RSSI core on the rig's photodiode model (Lambertian channel, shot and
  thermal noise, lamp-power tolerance, platform vibration) at each speed, with a
  converged attitude (0.05°, 0.05°, 0.1° 1σ), and the sensitivity to the lamp-power
  tolerance and to an unconverged heading (0.8° off, 5° reported, as the compensator
  right after a start at speed);
* ``frames`` — dead reckoning and INS + beacon ranging on train_localizer's simulated
  lamp observations and IMU samples at each speed, a stop-and-go run, and a forged lamp
  (the lamp at 50 m broadcasting lamp 8's UID): flagged or not, error with and without;
* ``bags`` (``--bags DIR ...``) — recorded graph runs replayed through the cores
  (inputs as recorded: the real decoder, spot locator, compensator; photodiode when
  recorded), scored against their ground truth.

Errors are Euclidean, every pose against the truth at its stamp; availability = share
of the run's 50 Hz grid (RSSI: of the photodiode samples) with a pose; CPU time with
``time.thread_time`` (not inflated by other processes), per update (a photodiode
sample, a frame) and per IMU sample. ``--json FILE`` writes every figure;
``--write-docs`` replaces the generated section of ``docs/arch/companion_localizers.md``
under the workspace ($VLC_WS).
"""
import argparse
import json
import math
import os
import pathlib
import sys
import time

import numpy as np

from companion_localizers.core.dead_reckoning import DeadReckoning, DeadReckoningConfig
from companion_localizers.core.ins_beacon import InsBeacon, InsBeaconConfig
from companion_localizers.core.rssi import LampReading, RssiConfig, trilaterate
from vlc_common.core.lamp_map import LampMap, resolve_lamp_map_path
from vlc_common.core.optical_channel import PhotodiodeConfig
from vlc_common.core.rotations import rpy_to_matrix
from vlc_evaluation.companion_replay import replay_frames, replay_rssi, summary_ms
from vlc_evaluation.companion_scoring import load_bag, score_poses
from vlc_stereo_camera.core.photodiode import Photodiode
from vlc_stereo_camera.core.trajectory import MotionProfile, Trajectory, Vibration
from vlc_stereo_camera.core.upstream import LAMPS, run_core

DEG = math.pi / 180.0
SPEEDS_KMH = (20.0, 40.0, 60.0, 80.0, 100.0, 120.0)
PAPER_RSSI = 'paper (Zhang, Xu, Ma, Zhu): max 39.23 cm, mean 13.36 cm'
#: The package section of the architecture document, under the workspace ($VLC_WS).
DOCS_PATH = pathlib.Path('docs') / 'arch' / 'companion_localizers.md'


def _stats(errors):
    e = np.asarray(errors, dtype=float)
    if e.size == 0:
        return {'count': 0, 'max_m': math.nan, 'mean_m': math.nan, 'p95_m': math.nan}
    return {'count': int(e.size), 'max_m': float(e.max()), 'mean_m': float(e.mean()),
            'p95_m': float(np.percentile(e, 95))}


def _cm(v):
    return '–' if not math.isfinite(v) else f'{100.0 * v:.2f}'


def rssi_run(speed_kmh, seconds, seed, tolerance=0.02, heading_error_deg=0.0,
             heading_sigma_deg=0.1):
    """RSSI core over ``seconds`` of a run; returns figures (dict)."""
    rng = np.random.default_rng(seed)
    profile = (MotionProfile('stationary', start_chainage_m=45.3) if speed_kmh == 0.0 else
               MotionProfile('constant', start_chainage_m=12.0, speed_mps=speed_kmh / 3.6))
    traj = Trajectory(profile, Vibration(seed=seed))
    pd = Photodiode(PhotodiodeConfig(lamp_power_sigma_rel=tolerance), LAMPS, traj, seed=seed)
    config = RssiConfig(photodiode=PhotodiodeConfig(lamp_power_sigma_rel=max(tolerance, 1e-3)))
    sigma = np.array([0.05, 0.05, heading_sigma_deg]) * DEG
    errors, cpu_ms, reasons = [], [], {}
    last = None
    n_samples = int(seconds * 50)
    for n in range(n_samples):
        sample = pd.sample(n, 50.0)
        truth = traj.sample(sample.t_s)
        err_att = rng.normal(0.0, [0.05 * DEG, 0.05 * DEG, 0.0])
        err_att[2] = heading_error_deg * DEG
        R = rpy_to_matrix(*(truth.rpy_rad[0] + err_att))
        readings = [LampReading(int(u), LAMPS.by_uid(u).position_m, LAMPS.by_uid(u).normal, p, s)
                    for u, p, s in zip(sample.uid, sample.power_w, sample.power_sigma_w)]
        start = time.thread_time()
        fix = trilaterate(readings, R, config, speed_kmh / 3.6, np.diag(sigma ** 2),
                          None if last is None else last + speed_kmh / 3.6 * 0.02)
        cpu_ms.append(1e3 * (time.thread_time() - start))
        reasons[fix.reason] = reasons.get(fix.reason, 0) + 1
        last = float(fix.position_m[0]) if fix.ok else None
        if fix.ok:
            errors.append(float(np.linalg.norm(fix.position_m - truth.position_m[0])))
    out = _stats(errors)
    out.update(availability=len(errors) / n_samples, outcomes=reasons,
               cpu_ms_median=summary_ms(cpu_ms)[0], cpu_ms_p95=summary_ms(cpu_ms)[1])
    return out


def rssi_section(quick):
    seconds = 6.0 if quick else 20.0
    rows, figures = [], {}
    header = ('| case | speed km/h | solved | max (cm) | mean (cm) | 95th pct (cm) | '
              'CPU ms median / p95 |\n|---|---|---|---|---|---|---|')
    cases = [('tolerance 2 %, attitude known', dict(tolerance=0.02), SPEEDS_KMH + (0.0,))]
    cases += [(f'tolerance {t:.0%}, attitude known', dict(tolerance=t), (60.0,))
              for t in (0.0, 0.05)]
    cases += [('heading 0.8° off, 5° reported', dict(heading_error_deg=0.8,
                                                      heading_sigma_deg=5.0), (60.0,))]
    for name, kwargs, speeds in cases:
        for v in speeds:
            f = rssi_run(v, seconds, seed=11, **kwargs)
            figures[f'{name} @ {v:g}'] = f
            rows.append(f'| {name} | {v:g} | {100 * f["availability"]:.1f} % | '
                        f'{_cm(f["max_m"])} | {_cm(f["mean_m"])} | {_cm(f["p95_m"])} | '
                        f'{f["cpu_ms_median"]:.2f} / {f["cpu_ms_p95"]:.2f} |')
    text = (f'### RSSI trilateration on the rig photodiode ({seconds:g} s per row, 50 Hz; '
            f'{PAPER_RSSI})\n\n{header}\n' + '\n'.join(rows))
    return text, figures


def frame_run(cls, config_cls, speed_kmh, seconds, seed, **kwargs):
    core = cls(config_cls(), LAMPS)
    start = time.thread_time()
    err, stamps, results = run_core(core, speed_kmh, t_end_s=seconds, seed=seed, **kwargs)
    total_ms = 1e3 * (time.thread_time() - start)
    out = _stats(err)
    grid = int(seconds * 50)
    out.update(availability=min(1.0, len(err) / grid), results=len(results),
               frame_cpu_ms_median=summary_ms(list(core.frame_cpu_ms))[0],
               frame_cpu_ms_p95=summary_ms(list(core.frame_cpu_ms))[1],
               core_cpu_ms_per_pose=total_ms / max(len(err), 1))
    if isinstance(core, InsBeacon):
        out['flags'] = [(f.uid, f.verdict) for f in core.flags]
    return out


def frames_section(quick):
    seconds = 5.0 if quick else 12.0
    rows, figures = [], {}
    header = ('| method | run | published | max (cm) | mean (cm) | 95th pct (cm) | '
              'CPU ms per frame median / p95 |\n|---|---|---|---|---|---|---|')
    methods = (('dead reckoning', DeadReckoning, DeadReckoningConfig),
               ('INS + beacon ranging', InsBeacon, InsBeaconConfig))
    runs = [(f'{v:g} km/h', dict(speed_kmh=v)) for v in SPEEDS_KMH]
    runs.append(('stop and go (30 km/h, 3 m/s²)',
                 dict(speed_kmh=30.0, profile='accel_cruise_brake', dwell_s=1.0,
                      cruise_s=2.0, accel_mps2=3.0, brake_mps2=3.0)))
    for name, cls, cfg in methods:
        for run_name, kwargs in runs:
            kwargs = dict(kwargs)
            speed = kwargs.pop('speed_kmh')
            f = frame_run(cls, cfg, speed, seconds, seed=5, **kwargs)
            figures[f'{name} @ {run_name}'] = f
            rows.append(f'| {name} | {run_name} | {100 * f["availability"]:.1f} % | '
                        f'{_cm(f["max_m"])} | {_cm(f["mean_m"])} | {_cm(f["p95_m"])} | '
                        f'{f["frame_cpu_ms_median"]:.2f} / {f["frame_cpu_ms_p95"]:.2f} |')
    text = (f'### Dead reckoning and INS + beacon ranging on simulated observations '
            f'({seconds:g} s per run from 3 m, 50 Hz output)\n\n{header}\n' + '\n'.join(rows))

    def forge(stamp, observations, truth):
        for obs, tr in zip(observations, truth):
            if LAMPS.by_uid(tr['uid']).position_m[0] == 50.0 and obs.uid is not None:
                obs.uid = 0x1008

    clean = frame_run(InsBeacon, InsBeaconConfig, 60.0, 5.0, seed=4)
    forged = frame_run(InsBeacon, InsBeaconConfig, 60.0, 5.0, seed=4, observe=forge)
    figures['forged lamp'] = {'clean': clean, 'forged': forged}
    text += ('\n\n### Forged lamp (INS + beacon ranging, 60 km/h: the lamp at 50 m '
             'broadcasts lamp 8\'s UID)\n\n| run | flags | max (cm) | mean (cm) |\n'
             '|---|---|---|---|\n'
             f'| clean | {len(clean["flags"])} | {_cm(clean["max_m"])} | '
             f'{_cm(clean["mean_m"])} |\n'
             f'| forged | {len(forged["flags"])} ('
             f'{", ".join(sorted({f"{u:#06x} {v}" for u, v in forged["flags"]}))}) | '
             f'{_cm(forged["max_m"])} | {_cm(forged["mean_m"])} |')
    return text, figures


def bags_section(bags, lamp_map):
    rows, figures = [], {}
    header = ('| bag | method | poses | max (cm) | mean (cm) | 95th pct (cm) | availability | '
              'CPU ms per update median / p95 |\n|---|---|---|---|---|---|---|---|')
    for bag in bags:
        (truth_t, truth_xyz), _, _ = load_bag(bag, ())
        runs = {'dead_reckoning': replay_frames(bag, DeadReckoning(DeadReckoningConfig(),
                                                                   lamp_map)),
                'ins_beacon': replay_frames(bag, InsBeacon(InsBeaconConfig(), lamp_map))}
        rssi = replay_rssi(bag, RssiConfig(), lamp_map)
        if rssi.update_ms:
            runs['rssi'] = rssi
        for method, run in runs.items():
            s = score_poses(run.t_s, run.xyz, truth_t, truth_xyz)
            med, p95, _ = summary_ms(run.update_ms if method == 'rssi'
                                     else list(run.core.frame_cpu_ms))
            s.update(cpu_ms_median=med, cpu_ms_p95=p95)
            figures[f'{bag} {method}'] = s
            rows.append(f'| {bag} | {method} | {s["poses"]} | {_cm(s.get("max_m", math.nan))}'
                        f' | {_cm(s.get("mean_m", math.nan))} | '
                        f'{_cm(s.get("p95_m", math.nan))} | {100 * s["availability"]:.1f} % '
                        f'| {med:.2f} / {p95:.2f} |')
    return '### Recorded graph runs replayed through the cores\n\n' + header + '\n' + \
        '\n'.join(rows), figures


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    parser.add_argument('--only', nargs='+', choices=('rssi', 'frames', 'bags'),
                        default=None)
    parser.add_argument('--bags', nargs='+', default=[], help='recorded run bags to replay')
    parser.add_argument('--quick', action='store_true', help='short runs (a few s each)')
    parser.add_argument('--json', help='write every figure to this JSON file')
    parser.add_argument('--write-docs', action='store_true',
                        help='also replace the generated section of '
                             'docs/arch/companion_localizers.md')
    args = parser.parse_args(argv)
    sections = args.only or (['rssi', 'frames'] + (['bags'] if args.bags else []))
    lamp_map = LampMap.load(resolve_lamp_map_path(''))
    texts, figures = [], {}
    for section in sections:
        if section == 'rssi':
            text, fig = rssi_section(args.quick)
        elif section == 'frames':
            text, fig = frames_section(args.quick)
        else:
            text, fig = bags_section(args.bags, lamp_map)
        texts.append(text)
        figures[section] = fig
        sys.stdout.write(text + '\n\n')
        sys.stdout.flush()
    if args.json:
        with open(args.json, 'w', encoding='utf-8') as stream:
            json.dump(figures, stream, indent=2, default=str)
    if args.write_docs:
        command = ' '.join(['companion_benchmark'] + (['--quick'] if args.quick else [])
                           + (['--only'] + args.only if args.only else []))
        workspace = pathlib.Path(os.environ.get('VLC_WS', '.')).resolve()
        write_docs(workspace / DOCS_PATH, texts, command)
    return 0


def write_docs(path, texts, command):
    """Replace the text between the benchmark's markers in ``path``."""
    begin, end = '<!-- companion_benchmark:begin -->', '<!-- companion_benchmark:end -->'
    doc = path.read_text(encoding='utf-8')
    if begin not in doc or end not in doc:
        raise ValueError(f'{path}: benchmark markers not found')
    body = (f'{begin}\n<!-- generated by `{command} --write-docs`; do not edit by hand -->\n\n'
            + '\n\n'.join(texts) + f'\n{end}')
    path.write_text(doc[:doc.index(begin)] + body + doc[doc.index(end) + len(end):],
                    encoding='utf-8')


if __name__ == '__main__':
    sys.exit(main())
