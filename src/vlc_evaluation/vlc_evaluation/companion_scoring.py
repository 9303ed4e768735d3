"""Score the companion localizers' poses in a recorded bag against ground truth.

A bag recorded from a graph that ran the companion nodes holds ``/ground_truth/pose``
and some of ``/companion/rssi/pose``, ``/companion/dead_reckoning/pose``,
``/companion/ins_beacon/pose``; with ``/diagnostics`` the nodes' own CPU time per
update is read too. Stamps are header stamps (the instant a pose describes).

Per method: errors of every pose against the truth interpolated at its stamp (max,
mean, 95th percentile, RMS; Euclidean and along-track), availability (the fraction of
truth instants, after ``settle_s``, with a pose of the method within ``max_gap_s``
on both sides), and the processing time the node reported (median, 95th percentile
and maximum CPU ms per update — a photodiode sample for RSSI, a stereo frame for the
others — and the total CPU ms per published pose, IMU callbacks included).

Command: ``companion_score BAG [BAG ...] [--methods rssi ...] [--settle-s S] [--json F]``.
"""
import argparse
import json
import math
import sys

import numpy as np

from vlc_bags.bagio import open_bag
from vlc_common.stamps import stamp_to_s
from vlc_evaluation import metrics

GROUND_TRUTH = '/ground_truth/pose'
DIAGNOSTICS = '/diagnostics'
#: method → (pose topic, diagnostics status name)
METHODS = {
    'rssi': ('/companion/rssi/pose', 'rssi_localizer_node: rssi'),
    'dead_reckoning': ('/companion/dead_reckoning/pose', 'dead_reckoning_node: dead_reckoning'),
    'ins_beacon': ('/companion/ins_beacon/pose', 'ins_beacon_node: ins_beacon'),
}
PROCESSING_KEYS = ('processing_ms_median', 'processing_ms_p95', 'processing_ms_max',
                   'cpu_ms_per_pose')


def load_bag(bag_path, methods=tuple(METHODS)):
    """Truth, each method's poses and the last diagnostics values of each method's node.

    Returns
    -------
    truth : (t (N,), xyz (N, 3))
    poses : dict method → (t (M,), xyz (M, 3))
    diagnostics : dict method → dict of the node's last status values (strings)
    """
    topics = {METHODS[m][0]: m for m in methods}
    names = {METHODS[m][1]: m for m in methods}
    cols = {m: ([], []) for m in methods}
    truth = ([], [])
    diag = {}
    for topic, _, _, msg in open_bag(bag_path, topics=[GROUND_TRUTH, DIAGNOSTICS, *topics]):
        if topic == GROUND_TRUTH:
            store = truth
        elif topic == DIAGNOSTICS:
            for status in msg.status:
                if status.name in names:
                    diag[names[status.name]] = {kv.key: kv.value for kv in status.values}
            continue
        else:
            store = cols[topics[topic]]
        p = msg.pose.position
        store[0].append(stamp_to_s(msg.header.stamp))
        store[1].append([p.x, p.y, p.z])

    def arrays(t, xyz):
        t = np.asarray(t, dtype=float)
        xyz = np.asarray(xyz, dtype=float).reshape(-1, 3)
        order = np.argsort(t, kind='stable')
        return t[order], xyz[order]

    return arrays(*truth), {m: arrays(*cols[m]) for m in methods}, diag


def score_poses(pose_t, pose_xyz, truth_t, truth_xyz, settle_s=0.0, max_gap_s=0.1):
    """Scores of one method's poses (dict of plain floats, JSON-ready); see the module
    docstring. Poses stamped before ``truth_t[0] + settle_s`` are left out.
    """
    out = {'poses': 0, 'availability': 0.0}
    if truth_t.size < 2:
        return out
    start = truth_t[0] + settle_s
    keep = (pose_t >= start) & (pose_t <= truth_t[-1])
    err, along = metrics.pose_errors(pose_t[keep], pose_xyz[keep], truth_t, truth_xyz)
    summary = metrics.summarize(err)
    along_summary = metrics.summarize(along)
    instants = truth_t[truth_t >= start]
    covered, _ = metrics.errors_at_instants(instants, pose_t, pose_xyz, truth_t, truth_xyz,
                                            max_gap_s=max_gap_s)
    out.update({
        'poses': int(keep.sum()),
        'max_m': summary.max_m, 'mean_m': summary.mean_m, 'p95_m': summary.p95_m,
        'rms_m': summary.rms_m,
        'along_track_max_m': along_summary.max_m, 'along_track_mean_m': along_summary.mean_m,
        'availability': float(np.mean(np.isfinite(covered))) if instants.size else 0.0,
    })
    return out


def _processing(values):
    out = {}
    for key in PROCESSING_KEYS:
        try:
            out[key] = float(values[key])
        except (KeyError, ValueError):
            out[key] = math.nan
    return out


def score_bag(bag_path, methods=tuple(METHODS), settle_s=0.0, max_gap_s=0.1):
    """Dict method → scores (:func:`score_poses` plus ``processing`` from diagnostics)."""
    (truth_t, truth_xyz), poses, diag = load_bag(bag_path, methods)
    result = {}
    for method in methods:
        t, xyz = poses[method]
        scores = score_poses(t, xyz, truth_t, truth_xyz, settle_s, max_gap_s)
        scores['processing'] = _processing(diag.get(method, {}))
        result[method] = scores
    return result


def score_rssi(bag_path, **kwargs):
    """Scores of ``/companion/rssi/pose`` in ``bag_path`` (see :func:`score_bag`)."""
    return score_bag(bag_path, ('rssi',), **kwargs)['rssi']


def score_dead_reckoning(bag_path, **kwargs):
    """Scores of ``/companion/dead_reckoning/pose`` in ``bag_path``."""
    return score_bag(bag_path, ('dead_reckoning',), **kwargs)['dead_reckoning']


def score_ins_beacon(bag_path, **kwargs):
    """Scores of ``/companion/ins_beacon/pose`` in ``bag_path``."""
    return score_bag(bag_path, ('ins_beacon',), **kwargs)['ins_beacon']


_cm = metrics.cm_text


def _ms(value):
    return '–' if value is None or not math.isfinite(value) else f'{value:.2f}'


def markdown_table(results):
    """Markdown table of ``{bag: {method: scores}}``."""
    rows = ['| bag | method | poses | max (cm) | mean (cm) | 95th pct (cm) | availability | '
            'CPU ms per update (median / p95) | CPU ms per pose |',
            '|---|---|---|---|---|---|---|---|---|']
    for bag, by_method in results.items():
        for method, s in by_method.items():
            proc = s['processing']
            rows.append(f'| {bag} | {method} | {s["poses"]} | {_cm(s.get("max_m"))} | '
                        f'{_cm(s.get("mean_m"))} | {_cm(s.get("p95_m"))} | '
                        f'{100.0 * s["availability"]:.1f} % | '
                        f'{_ms(proc["processing_ms_median"])} / '
                        f'{_ms(proc["processing_ms_p95"])} | {_ms(proc["cpu_ms_per_pose"])} |')
    return '\n'.join(rows)


def main(argv=None):
    parser = argparse.ArgumentParser(description='Score the companion localizers in bags.')
    parser.add_argument('bags', nargs='+', help='rosbag2 folders')
    parser.add_argument('--methods', nargs='+', choices=sorted(METHODS), default=list(METHODS))
    parser.add_argument('--settle-s', type=float, default=0.0,
                        help='leave out poses in the first seconds of the truth')
    parser.add_argument('--max-gap-s', type=float, default=0.1,
                        help='availability: a pose within this of a truth instant')
    parser.add_argument('--json', help='also write the figures to this JSON file')
    args = parser.parse_args(argv)
    results = {bag: score_bag(bag, tuple(args.methods), args.settle_s, args.max_gap_s)
               for bag in args.bags}
    sys.stdout.write(markdown_table(results) + '\n')
    if args.json:
        with open(args.json, 'w', encoding='utf-8') as stream:
            json.dump(results, stream, indent=2)
    return 0


if __name__ == '__main__':
    sys.exit(main())
