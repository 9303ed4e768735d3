"""Latency of the running graph from the recorder's receive log (``receive_times.csv``).

Every recorded message has its header stamp (simulated time) and the wall time its
publisher sent it (``source_timestamp_ns``, from the middleware). The camera paces
simulated time against the wall clock and publishes ``/clock`` on the same pacing, so
the recorded ``/clock`` ticks map simulated instants to the wall time at which the
camera lived them. A frame (stamp t0 = start of exposure of row 0) is complete, and
published, at t0 + readout (``readout_s`` = 719 rows × 30 µs + 25 µs).

Per frame that carries a confirmed lamp spot pair:

* decoder: ``vlc/lamps`` sent − frame complete; spot locator: ``spots/pairs`` sent −
  frame complete (each node's processing plus queueing and transport);
* localizer: the first ``train/pose`` sent after both inputs were sent − the later input;
* exposure → pose: that pose's send time − the exposure mid-time of the spot's rows,
  i.e. (pose sent − frame complete) + (t0 + readout − t_exposure). The second term is
  physical camera time; at a real-time factor of 1 the sum is exactly the wall time
  from exposure to pose. Both terms are kept per sample: ``readout_wait`` (the spot's
  rows to the frame's last row: up to a whole readout, 21.6 ms, for a spot in the top
  rows; no software can shorten it) and ``frame_to_pose`` (what the graph adds).
* IMU compensator: ``imu/data`` sent − ``imu/data_raw`` sent, same stamp.

Only frames after the localizer's first pose count (before it, a cold start waits for
a UID). "The first pose after the inputs" is the pose the localizer publishes right
after the fix (``publish_on_fix``), unless an IMU callback's grid pose slipped in
between (it would then be earlier by at most one callback, < 1 ms).
"""
import numpy as np

from vlc_bags.bagio import RECEIVE_TIMES_FILE, read_receive_times

READOUT_S = 719 * 30e-6 + 25e-6
CONFIRMED = 2


def _by_stamp(rows, topic):
    return {r['header_stamp_ns']: r['source_timestamp_ns'] for r in rows
            if r['topic'] == topic and r['header_stamp_ns'] is not None}


def frame_latencies(run, readout_s=READOUT_S):
    """Latency samples of one run, in ms: dict of arrays ``decoder``, ``spot_locator``,
    ``localizer``, ``exposure_to_pose``, ``imu_compensator`` (empty without a receive log).
    """
    empty = {k: [] for k in ('decoder', 'spot_locator', 'localizer', 'exposure_to_pose',
                             'readout_wait', 'frame_to_pose', 'imu_compensator')}
    if run.bag_path is None or not (run.bag_path / RECEIVE_TIMES_FILE).exists():
        return empty
    rows = read_receive_times(run.bag_path)
    clock = sorted((r['header_stamp_ns'], r['source_timestamp_ns']) for r in rows
                   if r['topic'] == '/clock' and r['header_stamp_ns'] is not None)
    if len(clock) < 2:
        return empty
    clock_sim = np.array([c[0] for c in clock], dtype=float)
    clock_wall = np.array([c[1] for c in clock], dtype=float)
    lamps_sent = _by_stamp(rows, '/vlc/lamps')
    pairs_sent = _by_stamp(rows, '/spots/pairs')
    poses_sent = np.sort(np.array([r['source_timestamp_ns'] for r in rows
                                   if r['topic'] == '/train/pose'], dtype=float))
    out = {k: [] for k in empty}
    readout_ns = readout_s * 1e9
    for stamp, pairs in sorted(run.pairs.items()):
        lamps = run.lamps.get(stamp)
        if (len(pairs) == 0 or lamps is None or not np.any(lamps['state'] == CONFIRMED)
                or stamp not in lamps_sent or stamp not in pairs_sent):
            continue
        ready_sim = stamp + readout_ns
        if not clock_sim[0] <= ready_sim <= clock_sim[-1]:
            continue
        ready_wall = float(np.interp(ready_sim, clock_sim, clock_wall))
        t_lamps, t_pairs = lamps_sent[stamp], pairs_sent[stamp]
        out['decoder'].append((t_lamps - ready_wall) * 1e-6)
        out['spot_locator'].append((t_pairs - ready_wall) * 1e-6)
        inputs = max(t_lamps, t_pairs)
        if poses_sent.size == 0 or inputs < poses_sent[0]:
            continue
        k = int(np.searchsorted(poses_sent, inputs))
        if k >= poses_sent.size:
            continue
        offset_ns = float(pairs['stamp_offset_s'][0]) * 1e9
        out['localizer'].append((poses_sent[k] - inputs) * 1e-6)
        out['exposure_to_pose'].append(
            (poses_sent[k] - ready_wall + (readout_ns - offset_ns)) * 1e-6)
        out['readout_wait'].append((readout_ns - offset_ns) * 1e-6)
        out['frame_to_pose'].append((poses_sent[k] - ready_wall) * 1e-6)
    raw = _by_stamp(rows, '/imu/data_raw')
    for stamp, sent in _by_stamp(rows, '/imu/data').items():
        if stamp in raw:
            out['imu_compensator'].append((sent - raw[stamp]) * 1e-6)
    return out


def summarize_ms(samples):
    """median, p99, max (ms) and count of latency samples."""
    a = np.asarray(samples, dtype=float)
    a = a[np.isfinite(a)]
    if a.size == 0:
        return {'count': 0, 'median_ms': None, 'p99_ms': None, 'max_ms': None}
    return {'count': int(a.size), 'median_ms': float(np.median(a)),
            'p99_ms': float(np.percentile(a, 99)), 'max_ms': float(a.max())}
