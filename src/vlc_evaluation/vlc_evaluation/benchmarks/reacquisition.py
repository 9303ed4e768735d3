"""A long lamp outage on the curved line, with and without the curvature re-acquisition aid.

The main localizer's core (``train_localizer.core.localizer.Localizer``) runs on the
simulated lamp observations and IMU of ``vlc_stereo_camera.core.upstream`` along
``curved_demo``; every lamp between ``--dark-from`` and ``--dark-to`` (default 900 …
1400 m: 500 m) is dark. The curvature core (:class:`CurvatureLocalizer`, what
``curvature_node`` runs) takes the gyro z of the same IMU samples (plus a constant bias
and white noise) and, as in the default graph, the localizer's own published speed
(``train/odometry``; ``--speed tacho``: the truth × (1 + 3 %) + 0.05 m/s noise, a wheel
tachometer). Each accepted match goes to
:class:`train_localizer.core.reacquisition.ChainageAid` with the match's variance
(``chainage_sigma_m``²), exactly as the node does with
``companion/curvature/pose_with_covariance``.

Two error settings of the simulated compensator: ``rig`` (the localizer benchmark's:
attitude errors of 0.03° / 0.03° / 0.1°, 5 s correlation) and ``cold`` (pitch error
0.5° with a 10 s correlation, reported in the covariance: a compensator that has not
converged, the case where the IMU-only coast drifts by tens of metres — in the graph a
520 m outage at 80 km/h ended 76 m off).

Figures per run: along-track error |ŝ − s| and 3σ (published σ) at the end of the
outage and their maximum inside it, the share of poses with |error| ≤ 3σ, the aid's
statuses, the error after the first lamp past the outage, and the processor time
(``time.process_time``) of the run.

``python -m vlc_evaluation.benchmarks.reacquisition`` prints the table
(``--write-docs docs/arch/train_localizer.md`` also replaces its generated block).
"""
import argparse
from dataclasses import dataclass
import math
import pathlib
import re
import sys
import time

import numpy as np

from companion_localizers.core.curvature import CurvatureConfig, CurvatureLocalizer
from train_localizer.core.fix import RigGeometry
from train_localizer.core.localizer import Localizer, LocalizerConfig
from train_localizer.core.reacquisition import STATUSES, ChainageAid, ReacquisitionConfig
from train_localizer.core.track import Track
from vlc_common.core.alignment import Alignment
from vlc_common.core.camera import StereoRig
from vlc_common.core.lamp_map import alignment_lamp_map
from vlc_stereo_camera.core.trajectory import MotionProfile, Trajectory, Vibration
from vlc_stereo_camera.core.upstream import (
    SensorErrors,
    SensorSimulator,
    dark_lamps,
    event_stream,
    feed_localizer,
    from_stamp_ns,
    to_stamp_ns,
)

_DEG = math.pi / 180.0
DOC_BEGIN = '<!-- reacquisition_benchmark:begin -->'
DOC_END = '<!-- reacquisition_benchmark:end -->'
ERRORS = {
    'rig': SensorErrors(),
    'cold': SensorErrors(attitude_sigma_rad=(0.03 * _DEG, 0.5 * _DEG, 0.1 * _DEG),
                         attitude_corr_time_s=10.0),
}


@dataclass
class OutageRun:
    """Result of one run. Arrays per published pose: ``t_s``, ``truth_m``, ``chainage_m``,
    ``sigma_m`` (published along-track 1σ); ``aids`` the AidRecords (empty without the
    aid), ``matches`` the accepted curvature matches (t_s, chainage, σ).
    """

    t_s: np.ndarray
    truth_m: np.ndarray
    chainage_m: np.ndarray
    sigma_m: np.ndarray
    aids: list
    matches: list
    fixes: list
    cpu_s: float
    dark: tuple

    @property
    def error_m(self):
        return self.chainage_m - self.truth_m

    def in_outage(self, margin_m=0.0):
        return (self.truth_m >= self.dark[0] + margin_m) & (self.truth_m < self.dark[1])

    def end_of_outage(self):
        """Index of the last pose before the first lamp past the outage is used."""
        after = [f.measurement_ns for f in self.fixes
                 if f.status in ('accepted', 'reinitialised')
                 and from_stamp_ns(f.measurement_ns) > self._time_at(self.dark[0] + 20.0)]
        t_first = from_stamp_ns(min(after)) if after else self.t_s[-1]
        return int(np.searchsorted(self.t_s, t_first) - 1)

    def _time_at(self, chainage):
        return float(np.interp(chainage, self.truth_m, self.t_s))


def run_outage(aid=True, errors='rig', speed='localizer', speed_kmh=80.0, start_m=100.0,
               dark=(900.0, 1400.0), end_m=1500.0, seed=1, aid_config=None,
               curvature_config=None, gyro_bias_rps=0.1 * _DEG, gyro_noise_rps=0.005,
               alignment='curved_demo'):
    """One run (see the module docstring); returns an :class:`OutageRun`."""
    start_cpu = time.process_time()
    alignment = Alignment.named(alignment)
    lamps = alignment_lamp_map(alignment, last_chainage_m=max(alignment.end_chainage_m,
                                                              end_m + 50.0))
    rig = StereoRig()
    v = speed_kmh / 3.6
    traj = Trajectory(MotionProfile('constant', start_chainage_m=start_m, speed_mps=v),
                      Vibration(seed=seed), alignment=alignment)
    sim = SensorSimulator(traj, rig, lamps, ERRORS[errors], np.random.default_rng(seed))
    events = event_stream(sim, 0.0, (end_m - start_m) / v)
    cfg = LocalizerConfig(geometry=RigGeometry.from_stereo_rig(rig))
    cfg.fix.track = Track(alignment)
    loc = Localizer(lamps, cfg)
    chainage_aid = ChainageAid(loc, aid_config or ReacquisitionConfig(enabled=aid))
    curvature = CurvatureLocalizer(alignment, curvature_config or CurvatureConfig())
    rng = np.random.default_rng([seed, 7])
    aids, matches = [], []

    def use(new_matches):
        for timed in new_matches:
            if not timed.match.ok:
                continue
            matches.append((timed.t_s, timed.match.chainage_m, timed.match.chainage_sigma_m))
            aids.append(chainage_aid.add(to_stamp_ns(timed.t_s), timed.match.chainage_m,
                                         timed.match.chainage_sigma_m ** 2))

    def feed_curvature(kind, payload, report):
        # the curvature core sees the gyro (with its own bias and noise) and a speed
        if kind == 'imu':
            t = from_stamp_ns(payload.stamp_ns)
            if speed == 'tacho' and round(t * 400) % 8 == 0:
                truth_v = float(traj.sample(t).speed_mps[0])
                use(curvature.add_speed(t, max(truth_v * 1.03 + rng.normal(0.0, 0.05), 0.0)))
            w = float(payload.gyro_rps[2]) + gyro_bias_rps + rng.normal(0.0, gyro_noise_rps)
            use(curvature.add_imu(t, w))
        if speed == 'localizer':
            for p in report.poses:
                if p.kind == 'grid':
                    use(curvature.add_speed(from_stamp_ns(p.stamp_ns), abs(p.speed_mps)))

    poses, fixes, _ = feed_localizer(loc, events, dark_lamps(lamps, dark), feed_curvature)
    t = np.array([from_stamp_ns(p.stamp_ns) for p in poses])
    return OutageRun(t, traj.sample(t).chainage_m, np.array([p.chainage_m for p in poses]),
                     np.array([p.chainage_sigma_m for p in poses]), aids, matches, fixes,
                     time.process_time() - start_cpu, tuple(dark))


def summary(run):
    """Dict of the figures of one run (see the module docstring)."""
    err, sig = np.abs(run.error_m), run.sigma_m
    inside = run.in_outage(20.0)
    end = run.end_of_outage()
    after = run.truth_m > run.dark[1] + 5.0
    counts = dict.fromkeys(STATUSES, 0)
    for a in run.aids:
        counts[a.status] += 1
    return {
        'end_error_m': float(err[end]), 'end_3sigma_m': float(3.0 * sig[end]),
        'max_error_m': float(err[inside].max()), 'max_3sigma_m': float(3.0 * sig[inside].max()),
        'covered': float(np.mean(err <= 3.0 * sig)),
        'after_max_error_m': float(err[after].max()) if after.any() else float('nan'),
        'rejected_lamps': sum(f.status.startswith('rejected') for f in run.fixes),
        'aids': {k: v for k, v in counts.items() if v}, 'matches': len(run.matches),
        'cpu_s': run.cpu_s,
    }


HEADER = ('| run | aid | error at outage end m | 3σ there m | max error in outage m | '
          'max 3σ m | within 3σ | error after first lamp m | lamps rejected | aid statuses '
          '| CPU s |\n|---|---|---|---|---|---|---|---|---|---|---|')


def _row(name, aid, s):
    st = ', '.join(f'{k} {v}' for k, v in s['aids'].items()) or '—'
    return (f"| {name} | {'on' if aid else 'off'} | {s['end_error_m']:.2f} | "
            f"{s['end_3sigma_m']:.2f} | {s['max_error_m']:.2f} | {s['max_3sigma_m']:.2f} | "
            f"{100 * s['covered']:.1f} % | {s['after_max_error_m']:.3f} | "
            f"{s['rejected_lamps']} | {st} | {s['cpu_s']:.0f} |")


def main(argv=None):
    """Print the outage table: aid off and on, per error setting and speed source."""
    parser = argparse.ArgumentParser(description=main.__doc__)
    parser.add_argument('--seed', type=int, default=1)
    parser.add_argument('--speed-kmh', type=float, default=80.0)
    parser.add_argument('--dark-from', type=float, default=900.0)
    parser.add_argument('--dark-to', type=float, default=1400.0)
    parser.add_argument('--errors', nargs='+', default=['rig', 'cold'], choices=sorted(ERRORS))
    parser.add_argument('--speed', nargs='+', default=['localizer'],
                        choices=['localizer', 'tacho'])
    parser.add_argument('--write-docs', metavar='MD')
    args = parser.parse_args(argv)
    dark = (args.dark_from, args.dark_to)
    rows = [HEADER]
    print(HEADER, flush=True)
    for errors in args.errors:
        for speed in args.speed:
            for aid in (False, True):
                if not aid and speed != args.speed[0]:
                    continue        # without the aid the speed source plays no part
                s = summary(run_outage(aid, errors, speed, args.speed_kmh, dark=dark,
                                       end_m=dark[1] + 100.0, seed=args.seed))
                name = (f'{errors} attitude, {args.speed_kmh:g} km/h, dark '
                        f'{dark[0]:g}-{dark[1]:g} m' + (f', speed {speed}' if aid else ''))
                rows.append(_row(name, aid, s))
                print(rows[-1], flush=True)
    if args.write_docs:
        command = ('python -m vlc_evaluation.benchmarks.reacquisition '
                   + ' '.join(a for a in (argv if argv is not None else sys.argv[1:])))
        block = '\n'.join([DOC_BEGIN, f'<!-- generated by `{command.strip()}`; do not edit '
                           'by hand -->', ''] + rows + ['', DOC_END])
        path = pathlib.Path(args.write_docs)
        text = path.read_text(encoding='utf-8')
        if DOC_BEGIN in text and DOC_END in text:
            text = re.sub(re.escape(DOC_BEGIN) + '.*?' + re.escape(DOC_END), lambda _: block,
                          text, flags=re.S)
        else:
            text = text.rstrip() + '\n\n' + block + '\n'
        path.write_text(text, encoding='utf-8')
        print(f'wrote {path}')
    return 0


if __name__ == '__main__':
    sys.exit(main())
