"""The fault protocol: the whole graph at speed through one fault per run, scored for
integrity rather than accuracy.

Each run is a dynamic scenario (constant speed, the installed nodes, the recorder) with
one fault from :data:`FAULTS`, injected ``FAULT_AT_S`` of simulated time into the run
(after the cold start has settled) and followed by ``RECOVERY_S`` of simulated time:

* on the machine: busy-loop processes beside the graph (CPU overload), SIGSTOP/SIGCONT of
  one node (a swap storm or a long pause), SIGKILL of one node and its restart (a
  supervisor's respawn) — done by :class:`FaultDriver` while the run goes on, timed by
  the rig's ``/clock``;
* in the sensors (the rig's sensor-fault parameters, ``config/rig.yaml`` of
  vlc_stereo_camera): IMU or camera dropouts, IMU delivered in bursts, an IMU–camera
  stamp offset, the sensors' clock stepped back or forward (``/clock`` runs on);
* on the wire: ``fault_injector_node`` publishing malformed messages on the graph's own
  topics (wrong encoding, wrong size, truncated data, NaN/inf IMU, empty and mis-typed
  point clouds, stamps from 1970).

Scores per run (:func:`score_fault`): poses published, the largest error, the fraction
of poses inside their own published 3σ (every axis), *confidently wrong* poses (more
than ``WRONG_M`` off while claiming a 3σ under ``WRONG_M``: the failure a CBTC consumer
cannot detect), the time from the end of the fault until the localizer reports
``tracking`` again (its diagnostics, published at every change of state) in seconds and
lamps passed, and the exit codes of every node. Truth is taken at the instant a pose
describes: after a sensor clock step the truth is stamped in the stepped clock too, and
each pose is matched to the run segment it was made in by the recording times.
"""
from dataclasses import dataclass, field
import json
import math
import os
import pathlib
import signal
import subprocess
import sys
import threading
import time

import numpy as np

from vlc_bags.bagio import open_bag
from vlc_common.stamps import stamp_to_ns
from vlc_evaluation.report import replace_marked_block

FAULT_SPEED_KMH = 80.0
FAULT_AT_S = 6.0          # simulated time of the fault's start (cold start settled)
RECOVERY_S = 8.0          # simulated time after the fault's end
WRONG_M = 0.5             # a pose this far off while claiming a 3σ below it is confidently wrong
LAMP_SPACING_M = 10.0
BACK_TO_TRACKING_LAMPS = 3.0
MIN_INSIDE_3SIGMA = 0.997
#: Written beside each bag by the driver: what was done when (simulated seconds).
FAULT_FILE = 'fault.json'


@dataclass(frozen=True)
class Fault:
    """One row of the fault table.

    ``action``: '' (the rig does it, from ``rig``), ``busy`` (``count`` busy processes
    for ``for_s`` wall seconds), ``stall`` (SIGSTOP ``node`` for ``for_s`` wall seconds),
    ``kill`` (SIGKILL ``node``, then start it again), ``inject`` (malformed input for
    ``for_s`` simulated seconds). ``rig``: sensor-fault parameters of both rig nodes;
    ``whole_run``: the fault lasts the whole run (no recovery to time).
    """

    name: str
    label: str
    action: str = ''
    node: str = ''
    count: int = 0
    for_s: float = 0.0
    rig: tuple = ()
    whole_run: bool = False

    @property
    def rig_params(self):
        return {key: (list(value) if isinstance(value, tuple) else value)
                for key, value in self.rig}


FAULTS = (
    Fault('none', 'no fault (reference)'),
    Fault('cpu_1', 'CPU overload: 1 busy process for 20 s', 'busy', count=1, for_s=20.0),
    Fault('cpu_2', 'CPU overload: 2 busy processes for 20 s', 'busy', count=2, for_s=20.0),
    Fault('cpu_4', 'CPU overload: 4 busy processes for 20 s', 'busy', count=4, for_s=20.0),
    Fault('imu_dropout_1s', 'IMU dropout 1 s', for_s=1.0,
          rig=(('imu_dropouts_s', (FAULT_AT_S, 1.0)),)),
    Fault('imu_dropout_5s', 'IMU dropout 5 s', for_s=5.0,
          rig=(('imu_dropouts_s', (FAULT_AT_S, 5.0)),)),
    Fault('camera_dropout_2s', 'camera dropout 2 s', for_s=2.0,
          rig=(('camera_dropouts_s', (FAULT_AT_S, 2.0)),)),
    Fault('imu_bursts', 'IMU delivered in 0.5 s bursts', whole_run=True,
          rig=(('imu_burst_s', 0.5),)),
    Fault('stall_camera', 'camera process stalled 1.5 s (SIGSTOP)', 'stall',
          'stereo_camera_node', for_s=1.5),
    Fault('stall_imu', 'IMU process stalled 1.5 s (SIGSTOP)', 'stall', 'adis16488_node',
          for_s=1.5),
    Fault('stall_localizer', 'localizer stalled 1.5 s (SIGSTOP)', 'stall',
          'train_localizer_node', for_s=1.5),
    Fault('offset_20ms', 'IMU–camera stamp offset 20 ms', whole_run=True,
          rig=(('imu_stamp_offset_s', 0.02),)),
    Fault('offset_200ms', 'IMU–camera stamp offset 200 ms', whole_run=True,
          rig=(('imu_stamp_offset_s', 0.2),)),
    Fault('kill_localizer', 'localizer killed (SIGKILL) and restarted', 'kill',
          'train_localizer_node'),
    Fault('kill_decoder', 'decoder killed (SIGKILL) and restarted', 'kill',
          'vlc_decoder_node'),
    Fault('clock_back', 'sensor clock stepped back 2 s', for_s=0.0,
          rig=(('sensor_clock_jumps_s', (FAULT_AT_S, -2.0)),)),
    Fault('clock_forward', 'sensor clock stepped forward 2 s', for_s=0.0,
          rig=(('sensor_clock_jumps_s', (FAULT_AT_S, 2.0)),)),
    Fault('malformed', 'malformed input for 5 s (every kind)', 'inject', for_s=5.0),
)
BY_NAME = {f.name: f for f in FAULTS}


def fault_of(scenario):
    return BY_NAME[scenario.kind_params['fault']]


def stamp_shift_s(fault):
    """Total step of the sensor clock over the run, s (poses end that far off /clock)."""
    jumps = dict(fault.rig).get('sensor_clock_jumps_s', ())
    return float(sum(jumps[1::2]))


def fault_scenarios(speed_kmh=FAULT_SPEED_KMH, seed=1, names=None):
    """One :class:`~vlc_evaluation.scenarios.Scenario` per fault (all, or ``names``)."""
    from vlc_evaluation.scenarios import DYNAMIC_START_M, Scenario
    out = []
    for fault in FAULTS:
        if names and fault.name not in names:
            continue
        length = 0.0 if fault.action in ('busy', 'stall', 'kill') else fault.for_s
        if fault.action == 'busy':
            length = fault.for_s           # wall seconds: at least as long in sim time
        node_params, extra_nodes, extra_publishers = {}, [], {}
        if fault.rig:
            node_params = {'adis16488_node': fault.rig_params,
                           'stereo_camera_node': fault.rig_params}
        if fault.action == 'inject':
            extra_nodes = [['vlc_evaluation', 'fault_injector_node',
                            ['fault_injector_node.yaml']]]
            node_params['fault_injector_node'] = {'start_s': FAULT_AT_S,
                                                  'duration_s': fault.for_s}
            extra_publishers = {'/imu/data_raw': 1, '/stereo/left/image_raw': 1}
        out.append(Scenario(
            name=f'fault_{fault.name}', motion_profile='constant',
            start_chainage_m=DYNAMIC_START_M, speed_kmh=float(speed_kmh), seed=seed,
            duration_s=FAULT_AT_S + length + RECOVERY_S, node_params=node_params,
            extra_nodes=extra_nodes, extra_publishers=extra_publishers, kind='fault',
            kind_params={'fault': fault.name}))
    return out


# --- while the run goes on ---------------------------------------------------------

class FaultDriver(threading.Thread):
    """Does a fault's machine action at ``FAULT_AT_S`` of simulated time (the probe's
    ``/clock``) and writes what it did, when, into ``FAULT_FILE`` beside the bag.
    """

    def __init__(self, fault, graph, probe, epoch_s, out_path, abort):
        super().__init__(name=f'fault-{fault.name}', daemon=True)
        self.fault = fault
        self.graph = graph
        self.probe = probe
        self.epoch_ns = int(round(epoch_s * 1e9))
        self.out_path = pathlib.Path(out_path)
        self.abort = abort
        self.record = {'fault': fault.name, 'window_s': None, 'killed_exit_code': None,
                       'problems': []}
        self._busy = []

    def _sim_s(self):
        clock = self.probe.clock_ns
        return None if clock is None else (clock - self.epoch_ns) * 1e-9

    def _wait_until(self, t_s, timeout_s=120.0):
        deadline = time.monotonic() + timeout_s
        while not self.abort():
            now = self._sim_s()
            if now is not None and now >= t_s:
                return True
            if time.monotonic() > deadline:
                return False
            time.sleep(0.01)
        return False

    def run(self):
        fault = self.fault
        try:
            if not fault.action or fault.action == 'inject':
                return
            if not self._wait_until(FAULT_AT_S):
                self.record['problems'].append('simulated time did not reach the fault')
                return
            start = self._sim_s()
            if fault.action == 'busy':
                self._busy = [subprocess.Popen([sys.executable, '-c', 'while True: pass'])
                              for _ in range(fault.count)]
                self._sleep(fault.for_s)
                self.stop_busy()
            elif fault.action == 'stall':
                self.graph.signal(fault.node, signal.SIGSTOP)
                try:
                    self._sleep(fault.for_s)
                finally:
                    self.graph.signal(fault.node, signal.SIGCONT)
            elif fault.action == 'kill':
                self.record['killed_exit_code'] = self.graph.kill(fault.node)
                self.graph.restart(fault.node)
                self.record['restarted_wall_s'] = time.time()
            self.record['window_s'] = [start, self._sim_s()]
        except Exception as exc:  # noqa: BLE001 — reported in the run's problems
            self.record['problems'].append(f'fault driver: {exc!r}')
        finally:
            self.stop_busy()

    def _sleep(self, wall_s):
        deadline = time.monotonic() + wall_s
        while time.monotonic() < deadline and not self.abort():
            time.sleep(0.02)

    def stop_busy(self):
        for proc in self._busy:
            proc.kill()
            proc.wait()
        self._busy = []

    def finish(self, timeout_s=60.0):
        """Wait for the action to end; write and return the record."""
        self.join(timeout_s)
        self.stop_busy()
        self.out_path.write_text(json.dumps(self.record), encoding='utf-8')
        return self.record


# --- scoring -----------------------------------------------------------------------

@dataclass
class FaultRun:
    """What scoring needs from a fault run's bag (ns; ``log`` = recording time)."""

    truth_stamp: np.ndarray
    truth_log: np.ndarray
    truth_xyz: np.ndarray
    pose_stamp: np.ndarray
    pose_log: np.ndarray
    pose_xyz: np.ndarray
    pose_cov: np.ndarray
    clock_log: np.ndarray
    clock_ns: np.ndarray
    states: list = field(default_factory=list)   # [(log ns, integrity state)]


def _state_age_ns(values):
    """How long before its publication the reported integrity state began (the
    localizer's ``integrity_state_age_s``; 0 when absent or unreadable): the recorder
    matches a respawned localizer's diagnostics only after discovery and may miss the
    message of the transition itself, not the time it happened.
    """
    try:
        age = float(values.get('integrity_state_age_s', 0.0))
    except ValueError:
        return 0
    return int(round(age * 1e9)) if math.isfinite(age) and age > 0.0 else 0


def load_fault_run(bag):
    rows = {k: [] for k in ('t', 'p', 'c', 'd')}
    for topic, _, log_ns, msg in open_bag(bag, topics=['/ground_truth/pose', '/clock',
                                                       '/train/pose_with_covariance',
                                                       '/diagnostics']):
        if topic == '/ground_truth/pose':
            p = msg.pose.position
            rows['t'].append((stamp_to_ns(msg.header.stamp), log_ns, p.x, p.y, p.z))
        elif topic == '/train/pose_with_covariance':
            p = msg.pose.pose.position
            cov = np.asarray(msg.pose.covariance, dtype=float).reshape(6, 6)[:3, :3]
            rows['p'].append((stamp_to_ns(msg.header.stamp), log_ns, p.x, p.y, p.z, cov))
        elif topic == '/clock':
            rows['c'].append((log_ns, stamp_to_ns(msg.clock)))
        else:
            for status in msg.status:
                if status.name.split(':')[0].strip().endswith('train_localizer'):
                    values = {kv.key: kv.value for kv in status.values}
                    if 'integrity_state' in values:
                        rows['d'].append((log_ns - _state_age_ns(values),
                                          values['integrity_state']))
    truth = np.array([r[:5] for r in rows['t']], dtype=float).reshape(-1, 5)
    poses = rows['p']
    clock = np.array(rows['c'], dtype=float).reshape(-1, 2)
    order = np.argsort(clock[:, 0], kind='stable')
    return FaultRun(
        truth_stamp=truth[:, 0].astype(np.int64), truth_log=truth[:, 1].astype(np.int64),
        truth_xyz=truth[:, 2:5],
        pose_stamp=np.array([r[0] for r in poses], dtype=np.int64),
        pose_log=np.array([r[1] for r in poses], dtype=np.int64),
        pose_xyz=np.array([r[2:5] for r in poses], dtype=float).reshape(-1, 3),
        pose_cov=np.array([r[5] for r in poses], dtype=float).reshape(-1, 3, 3),
        clock_log=clock[order, 0], clock_ns=clock[order, 1], states=sorted(rows['d']))


def truth_segments(stamp_ns, log_ns, max_lead_s=0.5):
    """Split the truth (in recording order) where its stamps step: back at all, or ahead
    of the recording clock by more than ``max_lead_s``. Returns index arrays.
    """
    order = np.argsort(log_ns, kind='stable')
    stamp, log = stamp_ns[order], log_ns[order]
    if stamp.size == 0:
        return []
    d_stamp = np.diff(stamp)
    d_log = np.diff(log)
    cut = np.flatnonzero((d_stamp < 0) | (d_stamp - d_log > max_lead_s * 1e9)) + 1
    return [order[part] for part in np.split(np.arange(stamp.size), cut)]


#: A pose may be stamped this long past its time base's last truth sample (the truth
#: comes with each frame, poses also between frames from the IMU): the truth is
#: extrapolated over it at the segment's last velocity (≤ 1.3 mm at 1 m/s²), s.
TRUTH_EXTRAPOLATION_S = 0.05


def _extrapolated(x, xp, fp):
    """np.interp with linear extrapolation from the end segments."""
    y = np.interp(x, xp, fp)
    if xp.size >= 2:
        if x > xp[-1]:
            y = fp[-1] + (fp[-1] - fp[-2]) / (xp[-1] - xp[-2]) * (x - xp[-1])
        elif x < xp[0]:
            y = fp[0] + (fp[1] - fp[0]) / (xp[1] - xp[0]) * (x - xp[0])
    return y


def match_truth(run):
    """Truth position (N, 3) at every pose's stamp, in the segment the pose was made in
    (NaN where no segment covers the stamp within ``TRUTH_EXTRAPOLATION_S``).

    After a clock step the same stamp occurs in two time bases: of the segments that
    cover it, the one whose truth of that instant was recorded just before the pose is
    taken (a pose is not recorded long before the truth of its instant).
    """
    out = np.full((run.pose_stamp.size, 3), np.nan)
    segments = []
    for idx in truth_segments(run.truth_stamp, run.truth_log):
        order = idx[np.argsort(run.truth_stamp[idx], kind='stable')]
        segments.append((run.truth_stamp[order].astype(float), run.truth_log[order].astype(float),
                         run.truth_xyz[order]))
    for i, (stamp, log) in enumerate(zip(run.pose_stamp.astype(float), run.pose_log)):
        best = None
        margin = TRUTH_EXTRAPOLATION_S * 1e9
        for seg_stamp, seg_log, xyz in segments:
            if not seg_stamp[0] - margin <= stamp <= seg_stamp[-1] + margin:
                continue
            # how long after the truth of that instant was recorded the pose was
            latency = log - _extrapolated(stamp, seg_stamp, seg_log)
            key = (latency < -5e7, abs(latency))
            if best is None or key < best[0]:
                best = (key, [_extrapolated(stamp, seg_stamp, xyz[:, k]) for k in range(3)])
        if best is not None:
            out[i] = best[1]
    return out


def sim_s_of_log(run, log_ns, epoch_ns):
    """Simulated seconds (the rig's /clock) at recording times ``log_ns``."""
    if run.clock_log.size < 2:
        return np.full(np.shape(log_ns), np.nan)
    return (np.interp(log_ns, run.clock_log, run.clock_ns) - epoch_ns) * 1e-9


def back_to_tracking_s(run, window_s, epoch_ns, grace_s=2.0):
    """Simulated seconds from the end of the fault until the localizer reports
    ``tracking`` again, None when it never does.

    The localizer's state timeline (its diagnostics at every change, at the simulated
    time they were recorded) is split into spells; every spell not ``tracking`` that
    overlaps the fault or begins within ``grace_s`` after it (a stalled process works
    off its backlog after the fault) is the fault's doing. The answer is how long after
    the fault's end the last of them ended (0: tracking throughout or at once).
    """
    start_s, end_s = window_s
    if not run.states:
        return None
    log = np.array([s[0] for s in run.states], dtype=float)
    t = sim_s_of_log(run, log, epoch_ns)
    names = [s[1] for s in run.states]
    spells, k = [], 0          # (begin, end or None) of consecutive states not tracking
    while k < len(names):
        if names[k] == 'tracking':
            k += 1
            continue
        begin = t[k]
        while k < len(names) and names[k] != 'tracking':
            k += 1
        spells.append((begin, t[k] if k < len(names) else None))
    back = 0.0
    for begin, stop in spells:
        if begin > end_s + grace_s or (stop is not None and stop < start_s):
            continue
        if stop is None:
            return None
        back = max(back, stop - end_s)
    return float(back)


def state_shares(run):
    """Share of the recorded state changes' time spent in each state, after the first
    ``tracking`` (the cold start excluded).
    """
    if not run.states:
        return {}
    log = np.array([s[0] for s in run.states], dtype=float)
    names = [s[1] for s in run.states]
    first = next((k for k, n in enumerate(names) if n == 'tracking'), None)
    if first is None:
        return {}
    end = float(run.pose_log.max()) if run.pose_log.size else log[-1]
    shares = {}
    for k in range(first, len(names)):
        stop = log[k + 1] if k + 1 < len(names) else max(end, log[k])
        shares[names[k]] = shares.get(names[k], 0.0) + max(0.0, stop - log[k])
    total = sum(shares.values()) or 1.0
    return {name: value / total for name, value in shares.items()}


def fault_window_s(fault, record):
    """(start, end) of the fault in simulated seconds, or None (whole run, no fault)."""
    if fault.whole_run or fault.name == 'none':
        return None
    if fault.action in ('busy', 'stall', 'kill'):
        window = (record or {}).get('window_s')
        return tuple(window) if window else None
    return (FAULT_AT_S, FAULT_AT_S + fault.for_s)


def score_fault(bag, scenario, epoch_s):
    """Scores of one fault run (JSON-ready dict); see the module docstring."""
    fault = fault_of(scenario)
    bag = pathlib.Path(bag)
    record_path = bag.parent / f'{bag.name}.{FAULT_FILE}'
    record = (json.loads(record_path.read_text(encoding='utf-8'))
              if record_path.exists() else {})
    run = load_fault_run(bag)
    epoch_ns = int(round(epoch_s * 1e9))
    truth = match_truth(run)
    scored = np.all(np.isfinite(truth), axis=1)
    diff = run.pose_xyz[scored] - truth[scored]
    cov = run.pose_cov[scored]
    err = np.linalg.norm(diff, axis=1)
    sigma_axes = np.sqrt(np.clip(np.diagonal(cov, axis1=1, axis2=2), 0.0, None))
    inside = np.all(np.abs(diff) <= 3.0 * sigma_axes + 1e-12, axis=1)
    sigma_max = np.sqrt(np.clip(np.linalg.eigvalsh(cov)[:, -1], 0.0, None)) if cov.size else \
        np.zeros(0)
    wrong = (err > WRONG_M) & (3.0 * sigma_max < WRONG_M)
    window = fault_window_s(fault, record)
    if fault.action == 'kill' and fault.node == 'train_localizer_node' and window:
        # from the kill until the restarted localizer's first report it reports nothing:
        # not tracking
        kill_log = np.interp((window[0] * 1e9 + epoch_ns), run.clock_ns, run.clock_log)
        run.states = sorted(run.states + [(int(kill_log), 'not running')])
    back_s = lamps = None
    if window is not None:
        back_s = back_to_tracking_s(run, window, epoch_ns)
        if back_s is not None:
            lamps = back_s * scenario.speed_kmh / 3.6 / LAMP_SPACING_M
    result = {
        'fault': fault.name, 'label': fault.label,
        'poses': int(run.pose_stamp.size), 'poses_scored': int(scored.sum()),
        'max_error_m': float(err.max()) if err.size else None,
        'inside_3sigma': float(inside.mean()) if inside.size else None,
        'confidently_wrong': int(wrong.sum()),
        'fault_window_s': list(window) if window else None,
        'back_to_tracking_s': back_s, 'back_to_tracking_lamps': lamps,
        'state_shares': state_shares(run),
        'killed_exit_code': record.get('killed_exit_code'),
        'driver_problems': record.get('problems', []),
    }
    result['passed'] = bool(
        result['confidently_wrong'] == 0 and (result['inside_3sigma'] or 0.0) >= MIN_INSIDE_3SIGMA
        and result['poses_scored'] > 0
        and (window is None or (lamps is not None and lamps <= BACK_TO_TRACKING_LAMPS)))
    # a fault run is never run again because a node fell behind: that is the fault
    result['health'] = {'degraded': False}
    return result


def exit_codes_text(result):
    """The nodes' exit codes of a run: 'all 0', or the others by node."""
    codes = (result.get('timing') or {}).get('exit_codes') or {}
    bad = {name: code for name, code in codes.items() if code != 0}
    killed = result.get('killed_exit_code')
    text = 'all 0' if codes and not bad else (
        ', '.join(f'{n} {c}' for n, c in sorted(bad.items())) if bad else '–')
    if killed is not None:
        text += f' (killed: {killed})'
    return text


def fault_table(results):
    """Markdown table of the fault runs and its figures (dict)."""
    lines = ['| fault | poses | max error (m) | within 3σ | confidently wrong | back to '
             'tracking | node exit codes | meets acceptance |',
             '|---|---|---|---|---|---|---|---|']
    figures = {}
    order = {f.name: k for k, f in enumerate(FAULTS)}
    for r in sorted(results, key=lambda r: order.get(r.get('fault'), 99)):
        if r.get('back_to_tracking_s') is not None:
            back = f'{r["back_to_tracking_s"]:.2f} s ({r["back_to_tracking_lamps"]:.1f} lamps)'
        elif r.get('fault_window_s'):
            back = 'never'
        else:
            share = r.get('state_shares', {}).get('tracking')
            back = ('– (whole run' + (f'; tracking {100 * share:.1f} %' if share is not None
                                      else '') + ')')
        inside, worst = r.get('inside_3sigma'), r.get('max_error_m')
        worst = '–' if worst is None else f'{worst:.3f}'
        inside = '–' if inside is None else f'{100 * inside:.2f} %'
        lines.append(f'| {r["label"]} | {r["poses"]} | {worst} | {inside} | '
                     f'{r["confidently_wrong"]} | {back} | {exit_codes_text(r)} | '
                     f'{"yes" if r.get("passed") else "**no**"} |')
        figures[r['fault']] = {k: r.get(k) for k in (
            'poses', 'max_error_m', 'inside_3sigma', 'confidently_wrong',
            'back_to_tracking_s', 'back_to_tracking_lamps', 'passed')}
        figures[r['fault']]['exit_codes'] = exit_codes_text(r)
    return '\n'.join(lines) + '\n', figures


def fault_section(results, speed_kmh=FAULT_SPEED_KMH):
    """The report's fault section (Markdown) and its figures."""
    table, figures = fault_table(results)
    passed = sum(1 for r in results if r.get('passed'))
    text = (f'### Faults\n\nThe whole graph at {speed_kmh:.0f} km/h, one fault per run, '
            f'{FAULT_AT_S:.0f} s of simulated time into it, then {RECOVERY_S:.0f} s more. A '
            f'pose is confidently wrong when it is more than {WRONG_M} m off while its '
            f'published 3σ is below {WRONG_M} m; "back to tracking" is the simulated time '
            f'from the end of the fault until the localizer reports `tracking` (its '
            f'diagnostics). Acceptance per row: no confidently wrong pose, ≥ '
            f'{100 * MIN_INSIDE_3SIGMA:.1f} % within 3σ, back to tracking within '
            f'{BACK_TO_TRACKING_LAMPS:.0f} lamps, every node exit 0. Rows passing: '
            f'{passed} of {len(results)}.\n\n{table}')
    return text, figures


def append_to_report(out_dir, results, speed_kmh=FAULT_SPEED_KMH):
    """Append the fault section to ``out_dir/report.md`` and its table and figures to
    ``report.json`` (``figures.faults``: the README summary shows the table); returns the
    text appended.
    """
    out_dir = pathlib.Path(out_dir)
    text, figures = fault_section(results, speed_kmh)
    text = '\n' + text
    md = out_dir / 'report.md'
    md.write_text((md.read_text(encoding='utf-8') if md.exists() else '') + text,
                  encoding='utf-8')
    path = out_dir / 'report.json'
    data = json.loads(path.read_text(encoding='utf-8')) if path.exists() else {'figures': {}}
    data['figures']['faults'] = {'rows': figures, 'table': fault_table(results)[0],
                                 'speed_kmh': speed_kmh}
    data['faults'] = [{k: v for k, v in r.items() if k != 'scenario'} for r in results]
    path.write_text(json.dumps(data, indent=1, default=float), encoding='utf-8')
    return text


DOCS_BEGIN = '<!-- faults:begin -->'
DOCS_END = '<!-- faults:end -->'


def update_docs(markdown_path, results, command, speed_kmh=FAULT_SPEED_KMH):
    """Put the fault section of ``results`` between the fault markers of
    ``markdown_path`` (appended with them when absent), under the command line that
    produced it.
    """
    text, _ = fault_section(results, speed_kmh)
    text = text.split('\n', 1)[1].lstrip('\n')            # the file has its own heading
    markdown_path = pathlib.Path(markdown_path)
    section = (f'{DOCS_BEGIN}\nGenerated by `{command}` '
               f'({time.strftime("%Y-%m-%d %H:%M")}, {os.cpu_count()} cores, load average '
               f'{os.getloadavg()[1]:.1f} over the last 5 min at the end).\n\n'
               f'{text.rstrip()}\n{DOCS_END}')
    replace_marked_block(markdown_path, section, begin=DOCS_BEGIN, end=DOCS_END)
