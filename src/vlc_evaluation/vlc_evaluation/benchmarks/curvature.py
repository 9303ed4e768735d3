"""Score the curvature-array correlation (companion method 4) against truth.

Two sources of input, one scorer:

* ``--bag PATH``: a recorded run (rosbag2, read with rosbags through
  ``vlc_bags.bagio``): ``/imu/data_raw`` (gyro z), the speed from
  ``--speed-topic`` (nav_msgs/Odometry, |twist.linear|; default
  ``/ground_truth/odometry``; if the bag lacks it, the speed is differentiated from the
  truth poses' chainage) and ``/ground_truth/pose`` (truth, projected on the alignment);
* no bag: synthetic runs on the rig's own models — the alignment, trajectory and
  vibration of ``vlc_stereo_camera`` and its ADIS16488 error model at 400 Hz — with a
  tachometer-like speed: truth × (1 + scale error) + white noise at 50 Hz.

Both feed :class:`~companion_localizers.core.curvature.CurvatureLocalizer` in time
order, exactly as the node does, and score every match: availability (share of match
instants with a chainage), absolute error max / mean / p95 over the matches given, and
the processor time per match (``time.process_time``, so contention from other processes
does not count).

``python -m vlc_evaluation.benchmarks.curvature`` prints the synthetic table
(``--write-docs docs/arch/curvature.md`` also replaces the generated block there);
``--bag run_bag --alignment curved_demo`` scores a bag.
"""
import argparse
from dataclasses import dataclass
import pathlib
import re
import sys

import numpy as np

from companion_localizers.core.curvature import (
    STATUS_OK,
    STATUSES,
    CurvatureConfig,
    CurvatureLocalizer,
)
from vlc_common.core.alignment import Alignment
from vlc_stereo_camera.core.imu_model import Adis16488Model, ImuSampler
from vlc_stereo_camera.core.trajectory import MotionProfile, Trajectory, Vibration

NS = 1e-9
DOC_BEGIN = '<!-- curvature_benchmark:begin -->'
DOC_END = '<!-- curvature_benchmark:end -->'


@dataclass
class RunInputs:
    """Time series of one run (seconds since any common origin).

    imu_t, yaw_rate : (N,) gyro z, rad/s; speed_t, speed : (M,) m/s;
    truth_t, truth_chainage : (K,) m.
    """

    imu_t: np.ndarray
    yaw_rate: np.ndarray
    speed_t: np.ndarray
    speed: np.ndarray
    truth_t: np.ndarray
    truth_chainage: np.ndarray


@dataclass
class Score:
    """Figures of one run (errors in m over the matches with a chainage)."""

    matches: int
    available: int
    statuses: dict
    max_m: float
    mean_m: float
    p95_m: float
    cpu_median_ms: float
    cpu_max_ms: float
    ratio_median: float

    @property
    def availability(self):
        return self.available / self.matches if self.matches else 0.0


def simulate(alignment, profile, seed=1, imu_rate_hz=400.0, speed_rate_hz=50.0,
             speed_scale_error=0.0, speed_noise_mps=0.05, duration_s=None):
    """Synthetic inputs from the rig's trajectory and ADIS16488 model.

    The speed is a tachometer: true speed × (1 + ``speed_scale_error``) + white noise of
    ``speed_noise_mps`` (clipped at 0), at ``speed_rate_hz``.
    """
    traj = Trajectory(profile, Vibration(seed=seed), alignment)
    if duration_s is None:
        duration_s = _time_to_reach(profile, alignment.end_chainage_m)
    sampler = ImuSampler(traj, Adis16488Model(imu_rate_hz, seed))
    batch = sampler.next(int(duration_s * imu_rate_hz))
    rng = np.random.default_rng([seed, 4])
    speed_t = np.arange(0.0, duration_s, 1.0 / speed_rate_hz)
    truth = traj.sample(speed_t)
    speed = np.maximum(truth.speed_mps * (1.0 + speed_scale_error)
                       + rng.normal(0.0, speed_noise_mps, len(speed_t)), 0.0)
    imu_truth = traj.sample(batch.t_s)
    chainage, _ = alignment.project(imu_truth.position_m[:, 0], imu_truth.position_m[:, 1])
    return RunInputs(batch.t_s, batch.omega[:, 2], speed_t, speed, batch.t_s, chainage)


def _time_to_reach(profile, chainage_m):
    """First time the profile reaches ``chainage_m`` (or its end + 10 s), s."""
    t = np.arange(0.0, 3600.0, 0.1)
    s, _, _ = profile.evaluate(t)
    reached = np.flatnonzero(s >= chainage_m)
    if reached.size:
        return float(t[reached[0]])
    return float(profile.duration_s() + 10.0)


def load_bag(bag_path, alignment, imu_topic='/imu/data_raw',
             speed_topic='/ground_truth/odometry', truth_topic='/ground_truth/pose'):
    """Read a run bag into :class:`RunInputs` (header stamps, seconds)."""
    from vlc_bags.bagio import open_bag

    cols = {'imu': [], 'speed': [], 'truth': []}
    for topic, _, _, msg in open_bag(bag_path, topics=[imu_topic, speed_topic, truth_topic]):
        stamp = msg.header.stamp.sec + NS * msg.header.stamp.nanosec
        if topic == imu_topic:
            cols['imu'].append((stamp, msg.angular_velocity.z))
        elif topic == speed_topic:
            v = msg.twist.twist.linear
            cols['speed'].append((stamp, float(np.sqrt(v.x ** 2 + v.y ** 2 + v.z ** 2))))
        elif topic == truth_topic:
            p = msg.pose.position
            cols['truth'].append((stamp, p.x, p.y))
    if not cols['imu'] or not cols['truth']:
        raise ValueError(f'{bag_path}: needs {imu_topic} and {truth_topic}')
    imu = np.array(sorted(cols['imu']))
    truth = np.array(sorted(cols['truth']))
    chainage, _ = alignment.project(truth[:, 1], truth[:, 2])
    if cols['speed']:
        speed = np.array(sorted(cols['speed']))
        speed_t, speed_v = speed[:, 0], speed[:, 1]
    else:
        # No odometry: the truth's chainage rate (for re-scoring evaluation bags).
        speed_t = 0.5 * (truth[1:, 0] + truth[:-1, 0])
        speed_v = np.abs(np.diff(chainage) / np.diff(truth[:, 0]))
    return RunInputs(imu[:, 0], imu[:, 1], speed_t, speed_v, truth[:, 0], chainage)


def run(inputs, alignment, config=None, match_period_s=1.0, speed_timeout_s=0.5):
    """Feed the inputs in time order; returns the list of TimedMatch."""
    loc = CurvatureLocalizer(alignment, config or CurvatureConfig(), match_period_s,
                             speed_timeout_s)
    events = sorted([(t, 1, w) for t, w in zip(inputs.imu_t.tolist(),
                                               inputs.yaw_rate.tolist())]
                    + [(t, 0, v) for t, v in zip(inputs.speed_t.tolist(),
                                                 inputs.speed.tolist())])
    out = []
    for t, kind, value in events:
        out += loc.add_imu(t, value) if kind else loc.add_speed(t, value)
    return out


def score(matches, inputs):
    """Score matches against the truth chainage (interpolated at each match time)."""
    statuses = dict.fromkeys(STATUSES, 0)
    errors, cpu, ratios = [], [], []
    for m in matches:
        statuses[m.match.status] += 1
        cpu.append(m.match.cpu_s * 1e3)
        if m.match.status == STATUS_OK:
            truth = np.interp(m.t_s, inputs.truth_t, inputs.truth_chainage)
            errors.append(abs(m.match.chainage_m - truth))
            ratios.append(m.match.ratio)
    e = np.asarray(errors)
    nan = float('nan')
    return Score(matches=len(matches), available=len(errors),
                 statuses={k: v for k, v in statuses.items() if v},
                 max_m=float(e.max()) if e.size else nan,
                 mean_m=float(e.mean()) if e.size else nan,
                 p95_m=float(np.percentile(e, 95)) if e.size else nan,
                 cpu_median_ms=float(np.median(cpu)) if cpu else nan,
                 cpu_max_ms=float(np.max(cpu)) if cpu else nan,
                 ratio_median=float(np.median(ratios)) if ratios else nan)


def synthetic_cases():
    """(name, alignment name, MotionProfile, speed scale error) of the default table."""
    kmh = 1.0 / 3.6
    return [
        ('curved 40 km/h, tacho +0 %', 'curved_demo',
         MotionProfile('constant', start_chainage_m=-100.0, speed_mps=40 * kmh), 0.0),
        ('curved 80 km/h, tacho +3 %', 'curved_demo',
         MotionProfile('constant', start_chainage_m=-100.0, speed_mps=80 * kmh), 0.03),
        ('curved 120 km/h, tacho -5 %', 'curved_demo',
         MotionProfile('constant', start_chainage_m=-100.0, speed_mps=120 * kmh), -0.05),
        ('curved 80 km/h, tacho +15 %', 'curved_demo',
         MotionProfile('constant', start_chainage_m=-100.0, speed_mps=80 * kmh), 0.15),
        ('curved stop-go 0-80-0 km/h, +3 %', 'curved_demo',
         MotionProfile('accel_cruise_brake', start_chainage_m=-100.0, speed_mps=80 * kmh,
                       dwell_s=10.0, cruise_s=90.0), 0.03),
        ('straight 80 km/h, tacho +3 %', 'straight',
         MotionProfile('constant', start_chainage_m=0.0, speed_mps=80 * kmh), 0.03),
    ]


def _row(name, s):
    st = ', '.join(f'{k} {v}' for k, v in s.statuses.items())
    return (f'| {name} | {s.matches} | {100 * s.availability:.0f} % | {s.max_m:.2f} | '
            f'{s.mean_m:.2f} | {s.p95_m:.2f} | {s.ratio_median:.3f} | {s.cpu_median_ms:.1f} / '
            f'{s.cpu_max_ms:.1f} | {st} |')


HEADER = ('| run | matches | available | max m | mean m | p95 m | ratio | CPU ms/match '
          'median / max | statuses |\n|---|---|---|---|---|---|---|---|---|')


def main(argv=None):
    """Print the score table of the synthetic runs, or of one bag (``--bag``)."""
    parser = argparse.ArgumentParser(description=main.__doc__)
    parser.add_argument('--bag', help='rosbag2 directory of a run to score')
    parser.add_argument('--alignment', default='curved_demo',
                        help='alignment of the bag (vlc_common.core.alignment name)')
    parser.add_argument('--speed-topic', default='/ground_truth/odometry')
    parser.add_argument('--speed-scale-error', type=float, default=0.0,
                        help='bag runs: multiply the bag speed by 1 + this (tachometer error)')
    parser.add_argument('--seed', type=int, default=1)
    parser.add_argument('--match-period-s', type=float, default=1.0)
    parser.add_argument('--write-docs', metavar='MD',
                        help='synthetic table: also replace the generated block of this file')
    args = parser.parse_args(argv)
    print(HEADER)
    if args.bag:
        alignment = Alignment.named(args.alignment)
        inputs = load_bag(args.bag, alignment, speed_topic=args.speed_topic)
        inputs.speed = inputs.speed * (1.0 + args.speed_scale_error)
        s = score(run(inputs, alignment, match_period_s=args.match_period_s), inputs)
        print(_row(f'bag {args.bag} ({args.alignment})', s))
        return 0
    rows = []
    for name, alignment_name, profile, error in synthetic_cases():
        alignment = Alignment.named(alignment_name)
        duration = 2400.0 / profile.speed_mps if alignment.is_straight else None
        inputs = simulate(alignment, profile, seed=args.seed, speed_scale_error=error,
                          duration_s=duration)
        s = score(run(inputs, alignment, match_period_s=args.match_period_s), inputs)
        rows.append(_row(name, s))
        print(rows[-1], flush=True)
    if args.write_docs:
        write_docs(pathlib.Path(args.write_docs), [HEADER] + rows, args)
    return 0


def write_docs(path, lines, args):
    """Replace the block between DOC_BEGIN and DOC_END of ``path`` (append if absent)."""
    text = path.read_text(encoding='utf-8') if path.exists() else ''
    command = (f'python -m vlc_evaluation.benchmarks.curvature --seed {args.seed} '
               f'--match-period-s {args.match_period_s:g} --write-docs {path}')
    block = '\n'.join([DOC_BEGIN, f'<!-- generated by `{command}`; do not edit by hand -->',
                       ''] + lines + ['', DOC_END])
    if DOC_BEGIN in text and DOC_END in text:
        text = re.sub(re.escape(DOC_BEGIN) + '.*?' + re.escape(DOC_END), lambda _: block, text,
                      flags=re.S)
    else:
        text = text.rstrip() + '\n\n' + block + '\n'
    path.write_text(text, encoding='utf-8')
    print(f'wrote {path}')


if __name__ == '__main__':
    sys.exit(main())
