"""``localizer_replay``: the localizer core re-run on a recorded bag's inputs, offline.

Reads ``/imu/data``, ``/spots/pairs``, ``/vlc/lamps`` (and ``/ground_truth/pose`` when
present) from a bag in the order they were recorded, feeds them through the same
:class:`~train_localizer.core.join.FrameJoiner` and
:class:`~train_localizer.core.localizer.Localizer` the node uses, with the node's
parameter file plus ``-p name:=value`` overrides, and prints the every-pose error
against the truth. Deterministic and much faster than the graph, so it is how a
localizer change or switch is compared on exactly the same perception output
(ablations of ``use_range_constraint``, ``use_imu_attitude``, ``use_exposure_stamping``,
``use_kalman``). Upstream switches (the compensator itself, Wiener) need the graph.

Examples::

    localizer_replay out/evaluation/dynamic/dynamic_020kmh_seed1
    localizer_replay BAG -p use_range_constraint:=false --settle-s 3.6 --json
"""
import argparse
from dataclasses import dataclass
import json
import math
import pathlib
import sys
import time

import numpy as np
import yaml

from . import conversions
from .bagtools.bagio import open_bag
from .core.join import FrameJoiner
from .core.localizer import Localizer
from .evaluation import metrics

INPUT_TOPICS = ('/imu/data', '/spots/pairs', '/vlc/lamps')
TRUTH_TOPIC = '/ground_truth/pose'


def default_params_file():
    """The node's parameter file (installed share/, else beside the sources)."""
    try:
        from ament_index_python.packages import get_package_share_directory
        path = (pathlib.Path(get_package_share_directory('train_localizer')) / 'config'
                / 'train_localizer_node.yaml')
        if path.exists():
            return path
    except (ImportError, LookupError, ValueError):
        pass
    return pathlib.Path(__file__).resolve().parents[1] / 'config' / 'train_localizer_node.yaml'


def load_params(params_file=None, overrides=None):
    """Parameter dict of the node: its declared defaults, its YAML file, then overrides."""
    from .train_localizer_node import PARAMETERS
    text = pathlib.Path(params_file or default_params_file()).read_text(encoding='utf-8')
    params = {name: default for name, default, _ in PARAMETERS}
    params.update(yaml.safe_load(text)['/**']['ros__parameters'])
    for name, value in (overrides or {}).items():
        if name not in params:
            raise ValueError(f'unknown parameter {name!r}')
        params[name] = value
    return params


@dataclass
class ReplayResult:
    """Poses (stamp s, position (3,), along-track variance) and the truth of one bag."""

    pose_t: np.ndarray
    pose_xyz: np.ndarray
    pose_var: np.ndarray
    truth_t: np.ndarray
    truth_xyz: np.ndarray
    fix_status: dict
    fix_ms: list


def replay(bag, params):
    """Run the localizer core over a bag's recorded inputs; returns a ReplayResult."""
    from .train_localizer_node import TrainLocalizerNode    # the node's config builder
    lamp_map, config = TrainLocalizerNode.setup(params)
    loc = Localizer(lamp_map, config)
    joiner = FrameJoiner()
    poses, truth, status, fix_ms = [], [], {}, []

    def take(report):
        for est in report.poses:
            poses.append((est.stamp_ns * 1e-9, *est.position_m, est.position_cov_m2[0, 0]))
        for fix in report.fixes:
            status[fix.status] = status.get(fix.status, 0) + 1

    for topic, _, received_ns, msg in open_bag(bag, topics=list(INPUT_TOPICS) + [TRUTH_TOPIC]):
        if topic == '/imu/data':
            take(loc.add_imu(conversions.imu_from_msg(msg)))
        elif topic == TRUTH_TOPIC:
            p = msg.pose.position
            truth.append((conversions.stamp_to_ns(msg.header.stamp) * 1e-9, p.x, p.y, p.z))
        else:
            try:
                records = conversions.cloud_to_records(msg)
            except ValueError:
                continue
            stamp = conversions.stamp_to_ns(msg.header.stamp)
            now_s = received_ns * 1e-9
            frames = (joiner.add_spots(stamp, records, now_s) if topic == '/spots/pairs'
                      else joiner.add_lamps(stamp, records, now_s))
            for stamp_ns, observations in frames:
                start = time.process_time()
                report = loc.add_frame(stamp_ns, observations)
                if report.fixes:
                    fix_ms.append(1e3 * (time.process_time() - start) / len(report.fixes))
                take(report)
    p = np.asarray(poses, dtype=float).reshape(-1, 5)
    t = np.asarray(truth, dtype=float).reshape(-1, 4)
    order = np.argsort(t[:, 0], kind='stable')
    return ReplayResult(p[:, 0], p[:, 1:4], p[:, 4], t[order, 0], t[order, 1:4], status, fix_ms)


def score(result, settle_s=0.0):
    """Every-pose error summary (m) and 3σ along-track coverage after ``settle_s``."""
    if result.truth_t.size < 2 or result.pose_t.size == 0:
        return {'poses': 0}
    keep = ((result.pose_t >= result.truth_t[0] + settle_s)
            & (result.pose_t <= result.truth_t[-1]))
    err, along = metrics.pose_errors(result.pose_t[keep], result.pose_xyz[keep],
                                     result.truth_t, result.truth_xyz)
    sigma = np.sqrt(result.pose_var[keep])
    ok = np.isfinite(along)
    return {'poses': int(keep.sum()), 'error': metrics.summarize(err).as_dict(),
            'along_track_3sigma_fraction': (float(np.mean(np.abs(along[ok]) <= 3.0 * sigma[ok]))
                                            if ok.any() else None),
            'fix_status': result.fix_status,
            'ms_per_fix_median': float(np.median(result.fix_ms)) if result.fix_ms else None}


def _override(text):
    name, sep, value = text.partition(':=')
    if not sep:
        raise argparse.ArgumentTypeError(f'expected name:=value, got {text!r}')
    return name, yaml.safe_load(value)


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('bags', nargs='+', help='rosbag2 directories')
    parser.add_argument('-p', dest='overrides', type=_override, action='append', default=[],
                        help='parameter override name:=value (repeatable)')
    parser.add_argument('--params-file', default='', help="default: the node's own")
    parser.add_argument('--settle-s', type=float, default=0.0,
                        help='leave out poses this long after the first truth stamp')
    parser.add_argument('--json', action='store_true', help='print JSON instead of text')
    args = parser.parse_args(argv)
    try:
        params = load_params(args.params_file or None, dict(args.overrides))
    except (OSError, ValueError) as exc:
        parser.error(str(exc))
    out = {}
    for bag in args.bags:
        out[bag] = score(replay(bag, params), args.settle_s)
    if args.json:
        print(json.dumps(out, indent=1))
        return 0
    for bag, s in out.items():
        if not s.get('poses'):
            print(f'{bag}: no scored poses')
            continue
        e = s['error']
        cover = s['along_track_3sigma_fraction']
        print(f'{bag}: {s["poses"]} poses, max {100 * e["max_m"]:.2f} cm, mean '
              f'{100 * e["mean_m"]:.2f} cm, p95 {100 * e["p95_m"]:.2f} cm, 3-sigma '
              f'{"–" if cover is None else f"{cover:.4f}"}, fixes {s["fix_status"]}, '
              f'{s["ms_per_fix_median"] or math.nan:.3f} ms/fix')
    return 0


if __name__ == '__main__':
    sys.exit(main())
