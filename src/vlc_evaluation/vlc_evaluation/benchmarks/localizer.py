"""Core benchmark: the static and dynamic protocols of EVALUATION.md on simulated spots.

Runs :class:`~train_localizer.core.localizer.Localizer` on lamp observations and IMU
samples generated from the rig's truth models (:mod:`vlc_stereo_camera.core.upstream`:
Trajectory + StereoRig projection at each spot's exposure mid-time, σ = 0.05 px centre
noise, UIDs confirmed after 5 frames, slowly varying attitude errors, ADIS16488
accelerometer bias and noise), no images and no ROS. It proves the method before the
graph exists; the evaluation of recorded bags is the final word.

Prints Markdown tables: static protocol (fused and raw single-frame fixes), dynamic
protocol per speed, ablations (one switch off at a time, and all off = the paper's
chain), 3σ-coverage of the published covariance and processing time per fix.

Usage::

    python -m vlc_evaluation.benchmarks.localizer [--runs 10] [--trials 10] [--json out.json]
"""
import argparse
import json
import sys
import time

import numpy as np

from train_localizer.core.fix import RigGeometry
from train_localizer.core.localizer import Localizer, LocalizerConfig
from vlc_common.core.camera import StereoRig
from vlc_common.core.lamp_map import straight_tunnel_map
from vlc_stereo_camera.core.trajectory import MotionProfile, Trajectory, Vibration
from vlc_stereo_camera.core.upstream import (
    SensorErrors,
    SensorSimulator,
    SimTiming,
    event_stream,
    from_stamp_ns,
)

CONFIGS = {
    'full': {},
    'no_range_constraint': {'use_range_constraint': False},
    'no_imu_attitude': {'use_imu_attitude': False},
    'no_exposure_stamping': {'use_exposure_stamping': False},
    'no_kalman': {'use_kalman': False},
    'paper_chain': {'use_range_constraint': False, 'use_imu_attitude': False,
                    'use_exposure_stamping': False, 'use_kalman': False},
}


def make_localizer(rig, lamp_map, switches):
    """A Localizer with the rig's true geometry and the given ablation switches."""
    cfg = LocalizerConfig(geometry=RigGeometry.from_stereo_rig(rig))
    for key, value in switches.items():
        sub = next((c for c in (cfg, cfg.fix, cfg.kalman, cfg.integrity, cfg.standstill)
                    if hasattr(c, key)), None)
        if sub is None:
            raise KeyError(f'unknown localizer setting {key!r}')
        setattr(sub, key, value)
    return Localizer(lamp_map, cfg)


def run(localizer, events):
    """Feed a time-ordered event list; returns poses, fix records and per-fix seconds."""
    poses, fixes, per_fix_s = [], [], []
    for _, kind, payload in events:
        if kind == 'imu':
            report = localizer.add_imu(payload)
        else:
            stamp_ns, observations, _ = payload
            start = time.perf_counter()
            report = localizer.add_frame(stamp_ns, observations)
            elapsed = time.perf_counter() - start
            if report.fixes:
                per_fix_s.append(elapsed / len(report.fixes))
        poses.extend(report.poses)
        fixes.extend(report.fixes)
    return poses, fixes, per_fix_s


def pose_errors(poses, trajectory):
    """(N, 3) errors (m), (N, 3) published 1σ (m), (N,) times (s) of a list of poses."""
    if not poses:
        return np.zeros((0, 3)), np.zeros((0, 3)), np.zeros(0)
    t = np.array([from_stamp_ns(p.stamp_ns) for p in poses])
    truth = trajectory.sample(t)
    est = np.array([p.position_m for p in poses])
    sigma = np.sqrt(np.array([np.diag(p.position_cov_m2) for p in poses]))
    return est - truth.position_m, sigma, t


def stats_cm(values_m, percentiles=(75, 90, 95), scale=100.0):
    """max/mean/min/percentiles of |values| × scale (default m → cm)."""
    v = np.abs(np.asarray(values_m)) * scale
    if v.size == 0:
        return {'n': 0}
    out = {'n': int(v.size), 'max': float(v.max()), 'mean': float(v.mean()),
           'min': float(v.min())}
    for p in percentiles:
        out[f'p{p}'] = float(np.percentile(v, p))
    return out


def coverage(err, sigma):
    """Fraction of poses whose error is inside 3σ on every axis."""
    if err.size == 0:
        return float('nan')
    return float(np.mean(np.all(np.abs(err) <= 3.0 * sigma, axis=1)))


def static_protocol(args, rig, lamp_map, configs):
    """Paper §4.2.1: standing 10.0 … 0.5 m before a lamp, independent trials."""
    lamp_x = 100.0
    distances = np.round(np.arange(10.0, 0.49, -0.5), 2)
    results = {name: {'err': [], 'sigma': [], 'misses': 0} for name in configs}
    for d in distances:
        for trial in range(args.trials):
            seed = 1000 * trial + int(d * 10)
            traj = Trajectory(MotionProfile('stationary', start_chainage_m=lamp_x - d),
                              Vibration(seed=seed))
            sim = SensorSimulator(traj, rig, lamp_map,
                                  SensorErrors(pixel_sigma_px=args.pixel_sigma),
                                  np.random.default_rng(seed))
            events = event_stream(sim, 0.0, args.observe_s)
            for name, switches in configs.items():
                poses, _, _ = run(make_localizer(rig, lamp_map, switches), events)
                if not poses:
                    results[name]['misses'] += 1
                    continue
                err, sigma, _ = pose_errors(poses[-1:], traj)
                results[name]['err'].append(err[0])
                results[name]['sigma'].append(sigma[0])
    out = {}
    for name, r in results.items():
        err = np.array(r['err']).reshape(-1, 3)
        sigma = np.array(r['sigma']).reshape(-1, 3)
        out[name] = {'error_3d_cm': stats_cm(np.linalg.norm(err, axis=1)),
                     'error_along_cm': stats_cm(err[:, 0]),
                     'misses': r['misses'], 'results': int(len(err)),
                     'coverage_3sigma': coverage(err, sigma)}
    return out


def dynamic_protocol(args, rig, lamp_map, speed_kmh, configs, ablation_runs, errors=None):
    """Paper §4.2.2 at one constant speed: errors at the 20 test points of each cell."""
    errors = errors or SensorErrors(pixel_sigma_px=args.pixel_sigma)
    v = speed_kmh / 3.6
    lead_in_m = 20.0
    t_end = (lead_in_m + args.length_m) / v
    # Test points: 10.0 … 0.5 m before each lamp of the evaluated section.
    lamps = [x for x in lamp_map.positions[:, 0] if lead_in_m < x <= lead_in_m + args.length_m]
    points = np.array([x - d for x in lamps for d in np.arange(10.0, 0.49, -0.5)])
    t_points = points / v
    results = {name: {'pt': [], 'all': [], 'sigma': [], 'fix_frames': 0, 'frames': 0,
                      'per_fix_s': []} for name in configs}
    for r in range(args.runs):
        seed = 7919 * r + int(speed_kmh)
        traj = Trajectory(MotionProfile('constant', start_chainage_m=0.0, speed_mps=v),
                          Vibration(seed=seed))
        sim = SensorSimulator(traj, rig, lamp_map, errors, np.random.default_rng(seed))
        events = event_stream(sim, 0.0, t_end, SimTiming())
        n_frames = sum(1 for e in events if e[1] == 'frame' and e[2][1])
        for name, switches in configs.items():
            if name != 'full' and r >= ablation_runs:
                continue
            poses, fixes, per_fix = run(make_localizer(rig, lamp_map, switches), events)
            err, sigma, t = pose_errors(poses, traj)
            section = t >= lead_in_m / v
            res = results[name]
            res['all'].append(err[section])
            res['sigma'].append(sigma[section])
            if t.size:
                idx = np.clip(np.searchsorted(t, t_points), 0, t.size - 1)
                res['pt'].append(err[idx])
            res['per_fix_s'].extend(per_fix)
            accepted = {f.measurement_ns for f in fixes if f.status in ('accepted', 'initialised')}
            frames_ok = {from_stamp_ns(ns) // (1.0 / 30.0) for ns in accepted}
            res['fix_frames'] += len(frames_ok)
            res['frames'] += n_frames
    out = {}
    for name, res in results.items():
        if not res['all']:
            continue
        pt = np.concatenate(res['pt']) if res['pt'] else np.zeros((0, 3))
        allp = np.concatenate(res['all'])
        sig = np.concatenate(res['sigma'])
        out[name] = {'error_3d_cm': stats_cm(np.linalg.norm(pt, axis=1)),
                     'error_along_cm': stats_cm(pt[:, 0]),
                     'all_poses_3d_cm': stats_cm(np.linalg.norm(allp, axis=1)),
                     'coverage_3sigma': coverage(allp, sig),
                     'fix_availability': res['fix_frames'] / max(res['frames'], 1),
                     'per_fix_ms': stats_cm(res['per_fix_s'], (50, 99), scale=1000.0)}
    return out


def _row(name, s, extra=''):
    return (f"| {name} | {s.get('max', float('nan')):.2f} | {s.get('mean', float('nan')):.2f} | "
            f"{s.get('p75', float('nan')):.2f} | {s.get('p90', float('nan')):.2f} | "
            f"{s.get('p95', float('nan')):.2f} |{extra}")


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    parser.add_argument('--trials', type=int, default=10, help='static trials per point')
    parser.add_argument('--runs', type=int, default=10, help='dynamic runs per speed')
    parser.add_argument('--ablation-runs', type=int, default=3,
                        help='dynamic runs per speed for each ablation')
    parser.add_argument('--speeds', type=float, nargs='+', default=[20, 40, 60, 80, 100, 120])
    parser.add_argument('--length-m', type=float, default=100.0,
                        help='evaluated track length per dynamic run (after a 20 m lead-in)')
    parser.add_argument('--observe-s', type=float, default=1.0,
                        help='static: observation time from start (no prior) to the result')
    parser.add_argument('--pixel-sigma', type=float, default=0.05, help='spot centre 1σ, px')
    parser.add_argument('--no-ablations', action='store_true')
    parser.add_argument('--stress-attitude-deg', type=float, nargs=3, default=[0.2, 0.2, 0.5],
                        metavar=('ROLL', 'PITCH', 'YAW'),
                        help='attitude error 1σ of the stress section (paper: heading < 0.5°)')
    parser.add_argument('--json', help='write every figure to this JSON file')
    args = parser.parse_args(argv)
    rig, lamp_map = StereoRig(), straight_tunnel_map()
    configs = {'full': {}} if args.no_ablations else CONFIGS
    figures = {'args': vars(args)}
    t_start = time.time()

    print(f'# train_localizer core benchmark (simulated spots, sigma {args.pixel_sigma} px)\n')
    print(f'## Static protocol: 20 points x {args.trials} trials, result = last pose after '
          f'{args.observe_s:.1f} s from a cold start (no prior; UID confirmed after 5 frames)\n')
    static = static_protocol(args, rig, lamp_map, configs)
    figures['static'] = static
    print('| configuration | max cm | mean cm | p75 cm | p90 cm | p95 cm | misses | '
          '3-sigma coverage |')
    print('|---|---|---|---|---|---|---|---|')
    for name, r in static.items():
        print(_row(name, r['error_3d_cm'], f" {r['misses']} | {r['coverage_3sigma']:.4f} |"))
    print('\n(no_kalman = raw single-frame constrained fix; paper_chain = raw eq. 12-14 fix, '
          'no IMU attitude, image-stamped)\n')

    figures['dynamic'] = {}
    print(f'## Dynamic protocol: {args.runs} runs per speed (ablations {args.ablation_runs}), '
          f'{args.length_m:.0f} m each, errors at the 20 test points per 10 m cell\n')
    print('| speed km/h | configuration | max cm | mean cm | p75 cm | p90 cm | p95 cm | '
          'all-poses max cm | 3-sigma coverage | fix availability | per-fix ms median/p99 |')
    print('|---|---|---|---|---|---|---|---|---|---|---|')
    for speed in args.speeds:
        res = dynamic_protocol(args, rig, lamp_map, speed, configs, args.ablation_runs)
        figures['dynamic'][str(int(speed))] = res
        for name, r in res.items():
            s = r['error_3d_cm']
            print(f"| {speed:.0f} | {name} | {s['max']:.2f} | {s['mean']:.2f} | {s['p75']:.2f} | "
                  f"{s['p90']:.2f} | {s['p95']:.2f} | {r['all_poses_3d_cm']['max']:.2f} | "
                  f"{r['coverage_3sigma']:.4f} | {r['fix_availability']:.3f} | "
                  f"{r['per_fix_ms'].get('p50', float('nan')):.3f} / "
                  f"{r['per_fix_ms'].get('p99', float('nan')):.3f} |")
        sys.stdout.flush()
    if not args.no_ablations:
        stress = [float(np.radians(a)) for a in args.stress_attitude_deg]
        print(f'\n## Attitude stress: imu/data attitude error 1σ {args.stress_attitude_deg} deg '
              f'(reported to the localizer), {args.ablation_runs} runs per speed\n')
        print('| speed km/h | configuration | max cm | mean cm | p95 cm | 3-sigma coverage |')
        print('|---|---|---|---|---|---|')
        figures['attitude_stress'] = {}
        for speed in (args.speeds[0], args.speeds[-1]):
            stress_args = argparse.Namespace(**dict(vars(args), runs=args.ablation_runs))
            res = dynamic_protocol(stress_args, rig, lamp_map, speed,
                                   {k: CONFIGS[k] for k in ('full', 'no_range_constraint')},
                                   args.ablation_runs,
                                   SensorErrors(pixel_sigma_px=args.pixel_sigma,
                                                attitude_sigma_rad=tuple(stress)))
            figures['attitude_stress'][str(int(speed))] = res
            for name, r in res.items():
                s = r['error_3d_cm']
                print(f"| {speed:.0f} | {name} | {s['max']:.2f} | {s['mean']:.2f} | "
                      f"{s['p95']:.2f} | {r['coverage_3sigma']:.4f} |")
    print(f'\n(benchmark wall time {time.time() - t_start:.0f} s)')
    if args.json:
        with open(args.json, 'w', encoding='utf-8') as stream:
            json.dump(figures, stream, indent=1)
    return 0


if __name__ == '__main__':
    sys.exit(main())
