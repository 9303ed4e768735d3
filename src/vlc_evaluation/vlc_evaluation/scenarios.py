"""Scenarios of the paper's protocols, run through the whole graph, recorded and scored.

A scenario starts the installed nodes (rig, decoder, spot locator, IMU compensator,
localizer) and the bag recorder on a DDS domain of its own (:mod:`.runner`), lets the
rig run for the scenario's simulated duration, stops everything (recorder last) and
scores the bag (:mod:`.bag_eval`). Protocols (``shared/EVALUATION.md``):

* static: the train stands ``d`` metres before a lamp, d = 0.5 … 10 m, one run per
  (d, seed); the result is the last pose published after ``observe_s`` of simulated time;
* dynamic: constant speed through several lamp cells; errors at the 20 test points of
  each cell and over every published pose, after an unscored lead-in (the cold start at
  speed, :func:`lead_in_m`; its heading error is reported on its own).
"""
from dataclasses import asdict, dataclass, field, replace
import itertools
import json
import logging
import os
import pathlib
import shutil
import time

import numpy as np

from vlc_bags.bagio import bag_time_range
from vlc_evaluation import bag_eval, identification, latency, metrics, raw_fix

LOG = logging.getLogger(__name__)

# What every run records: truth, the product, the inputs of the localizer (for the raw
# single-frame triangulation and lamp identification), diagnostics, and /clock (sim
# time -> wall time of the camera's pacing, for the latency figures).
RECORDED_TOPICS = ['/ground_truth/pose', '/train/pose', '/train/pose_with_covariance',
                   '/imu/data', '/vlc/lamps', '/spots/pairs', '/diagnostics', '/clock']
# Dynamic runs add the rig's true spots (which lamp is in view, for lamp identification)
# and the raw IMU (compensator latency).
DYNAMIC_TOPICS = ['/ground_truth/spots', '/imu/data_raw']
GROUND_TRUTH_TOPICS = ['/ground_truth/pose', '/ground_truth/odometry', '/ground_truth/spots']
# Raw sensor topics, for a replayable bag (record_sensors).
SENSOR_TOPICS = ['/stereo/left/image_raw', '/stereo/right/image_raw',
                 '/stereo/left/camera_info', '/stereo/right/camera_info', '/imu/data_raw',
                 '/clock']
TEST_POINTS_M = tuple(np.round(np.arange(10.0, 0.0, -0.5), 1))
SETTLE_CELLS = 2          # dynamic: lamp cells passed before scoring starts (cold start)
LEAD_IN_S = 3.0           # ... and at least this long at speed (see lead_in_m)
START_PAST_FIRST_LAMP_M = 0.5  # dynamic runs start this far past the map's first lamp
DYNAMIC_START_M = 10.0 + START_PAST_FIRST_LAMP_M    # ... on the shipped map (10 m)
HEADING_BOUND_DEG = 0.2   # the compensated heading's bound (cold start: time to reach it)
LAMP_X_M = 50.0          # the static protocol stands before the lamp at 50 m (UID 0x1005)


@dataclass
class Scenario:
    """One graph run.

    ``node_params``: ``{executable: {parameter: value}}`` given to the nodes on top of
    their parameter files (ablation switches, e.g.
    ``{'train_localizer_node': {'use_kalman': False}}``; also ``bag_recorder``).
    ``run_processing`` False runs only the rig and the recorder (a sensor bag);
    ``replay_bag`` replaces the rig by ``bag_player`` playing that sensor bag.
    ``extra_nodes``: ``[[package, executable, [parameter files in its share/config]]]``
    started beside the processing nodes (the companion methods, :mod:`.companions`),
    with ``node_params[executable]``; ``extra_subscriptions`` (``{topic: count}``) are
    theirs, awaited before simulated time starts; ``extra_topics`` are recorded too;
    ``extra_publishers`` (``{topic: count}``) theirs on the graph's own sensor topics (the
    fault injector), not taken for another graph sharing the domain.
    ``kind`` (``companions``, ``outage``, ``forged``; '' = the paper's protocols) selects
    the scoring, ``kind_params`` its geometry (:mod:`.companions`). ``lean_recording``
    leaves the 400 Hz IMU topics out of the bag (latency replays). ``rig_profile``
    (``ideal``, ``realistic``, ``harsh``): the rig's profile; a drawn one's installation
    (belief and truth, profile, seed, every drawn value) is written beside the bag in
    ``<name>.installation/`` and the processing nodes get its belief files;
    ``calibration`` ``drawn`` (the installation's calibration: the truth perturbed by a
    calibration's errors) or ``checkerboard`` (an actual ``stereo_calibrate`` of boards
    rendered through the true lenses, ``calibrate_installation``; the camera node then
    publishes it through ``calibration_paths``) or ``uncorrected`` (the drawn one with
    its distortion and rectification dropped: the undistortion ablation, published the
    same way). ``installation_seed`` (0 = ``seed``)
    draws the installation, ``seed`` the run (sensor noise, platform motion, IMU biases):
    the multi-pass protocol runs one train on one line again and again (:mod:`.passes`).
    ``files_from`` / ``files_to``: before every attempt ``files_to`` is emptied and the
    ``*.yaml`` of ``files_from`` (if it exists) copied into it — the files a run reads and
    writes back (the localizer's kept files), so that a retried attempt starts from the
    same files as the first, not from what the failed one wrote. ``lockstep``: the nodes
    run in one process on simulated time (:mod:`.lockstep`) instead of as a graph.
    """

    name: str
    motion_profile: str = 'constant'
    start_chainage_m: float = 0.0
    speed_kmh: float = 0.0
    seed: int = 1
    duration_s: float = 5.0
    observe_s: float = 0.0
    realtime_factor: float = 1.0
    record_sensors: bool = False
    run_processing: bool = True
    replay_bag: str = ''
    node_params: dict = field(default_factory=dict)
    static_point_m: float = float('nan')
    extra_nodes: list = field(default_factory=list)
    extra_subscriptions: dict = field(default_factory=dict)
    extra_topics: list = field(default_factory=list)
    extra_publishers: dict = field(default_factory=dict)
    kind: str = ''
    kind_params: dict = field(default_factory=dict)
    lean_recording: bool = False
    rig_profile: str = 'ideal'
    calibration: str = 'drawn'
    installation_seed: int = 0
    files_from: str = ''
    files_to: str = ''
    lockstep: bool = False

    def restore_files(self):
        """``files_to`` as a fresh copy of ``files_from``'s ``*.yaml`` (see above)."""
        if not self.files_to:
            return
        dst = pathlib.Path(self.files_to)
        shutil.rmtree(dst, ignore_errors=True)
        dst.mkdir(parents=True, exist_ok=True)
        src = pathlib.Path(self.files_from) if self.files_from else None
        for path in sorted(src.glob('*.yaml')) if src is not None and src.is_dir() else ():
            shutil.copy2(path, dst / path.name)

    @property
    def drawn_seed(self):
        """The seed of the drawn installation: ``installation_seed``, else ``seed``."""
        return int(self.installation_seed) or int(self.seed)

    @property
    def is_replay(self):
        return bool(self.replay_bag)

    @property
    def is_static(self):
        return self.motion_profile == 'stationary'

    def recorded_topics(self):
        if not self.run_processing:
            return list(dict.fromkeys(SENSOR_TOPICS + GROUND_TRUTH_TOPICS))
        topics = list(RECORDED_TOPICS)
        if self.lean_recording:
            # latency runs: the recorder is measurement overhead that the train does not
            # carry; the 400 Hz IMU topics would cost it most of a core
            topics.remove('/imu/data')
        if self.is_replay:
            topics += ['/ground_truth/spots'] + ([] if self.lean_recording
                                                 else ['/imu/data_raw'])
        elif not self.is_static:
            topics += DYNAMIC_TOPICS
        if self.record_sensors:
            topics += SENSOR_TOPICS
        topics += self.extra_topics
        return list(dict.fromkeys(topics))


# Static trials stand this long before the result is taken: the first pose comes within
# 0.45 s at every point of the protocol (8 s trials, 2026-12-01), so the result is the
# filter after >= 1.5 s of fixes.
STATIC_OBSERVE_S = 2.0


def protocol_geometry(lamp_map):
    """``(lamp_x_m, start_chainage_m, cell_m)`` of the protocols on ``lamp_map``: the lamp
    the static trials stand before (the one nearest ``LAMP_X_M`` with at least 10 m of
    line before it), the dynamic runs' start (0.5 m past the first lamp) and the lamp
    spacing (the median). On the shipped map: 50, 10.5 and 10 m, the paper's.
    """
    s = np.sort(np.asarray(lamp_map.chainages, float))     # (map x where a lamp has none)
    if s.size < 2:
        raise ValueError('the protocols need a lamp map of two lamps or more')
    standing = s[s >= s[0] + max(TEST_POINTS_M)]
    if standing.size == 0:
        raise ValueError('the static protocol needs a lamp with 10 m of line before it')
    lamp_x = float(standing[np.argmin(np.abs(standing - LAMP_X_M))])
    return lamp_x, float(s[0]) + START_PAST_FIRST_LAMP_M, float(np.median(np.diff(s)))


#: the shipped map's :func:`protocol_geometry`
SHIPPED_GEOMETRY = (LAMP_X_M, DYNAMIC_START_M, 10.0)


def placement(geometry=None):
    """``(static kwargs, dynamic kwargs)`` of :func:`static_scenarios` and
    :func:`dynamic_scenarios` for a :func:`protocol_geometry` (None: the shipped map's).
    """
    lamp_x, start, cell = geometry or SHIPPED_GEOMETRY
    return {'lamp_x_m': lamp_x}, {'start_chainage_m': start, 'cell_m': cell}


def static_scenarios(points_m=TEST_POINTS_M, trials=10, observe_s=STATIC_OBSERVE_S,
                     first_seed=1, lamp_x_m=LAMP_X_M):
    return [Scenario(name=f'static_{d:04.1f}m_seed{seed}', motion_profile='stationary',
                     start_chainage_m=lamp_x_m - d, seed=seed, duration_s=observe_s,
                     observe_s=observe_s, static_point_m=d)
            for d, seed in itertools.product(points_m, range(first_seed, first_seed + trials))]


def lead_in_m(speed_kmh):
    """Unscored start of a dynamic run, m: ``SETTLE_CELLS`` lamp cells, and at least
    ``LEAD_IN_S`` at speed.

    Every run starts cold at speed: no pose until a UID is confirmed, and the
    compensator learns the turn-on gyro bias (0.2 °/s 1σ) and scale from the first lamps'
    attitude aids, which takes time, not distance — two cells are 3.6 s at 20 km/h but
    0.6 s at 120 km/h, where the heading was still 0.2–0.28° off on the seeds with the
    largest bias (2026-12-02). The protocol's figures are the train in service; the
    lead-in's heading is reported as the cold start.
    """
    return max(SETTLE_CELLS * 10.0, LEAD_IN_S * speed_kmh / 3.6)


def dynamic_settle_s(speed_kmh):
    """Time from a dynamic run's start to its first scored instant, s."""
    return max(1.0, lead_in_m(speed_kmh) / max(speed_kmh / 3.6, 0.1))


def dynamic_scenarios(speeds_kmh=(20, 40, 60, 80, 100, 120), runs=10, cells=6, first_seed=1,
                      start_chainage_m=DYNAMIC_START_M, cell_m=10.0):
    """Constant speed from 0.5 m past the first lamp (the next is in view at once): the
    lead-in (:func:`lead_in_m`, ``SETTLE_CELLS`` of the ``cells`` at 20 km/h, longer
    faster), then the scored ``cells − SETTLE_CELLS`` lamp cells (``cell_m`` each: the
    lamp spacing, :func:`protocol_geometry`).
    """
    out = []
    for v, seed in itertools.product(speeds_kmh, range(first_seed, first_seed + runs)):
        distance = lead_in_m(v) + cell_m * (cells - SETTLE_CELLS) + 1.0
        out.append(Scenario(name=f'dynamic_{v:03d}kmh_seed{seed}', motion_profile='constant',
                            start_chainage_m=start_chainage_m, speed_kmh=float(v),
                            seed=seed, duration_s=distance / (v / 3.6)))
    return out


def _latency_samples(run):
    return {k: np.round(v, 3).tolist() for k, v in latency.frame_latencies(run).items()}


def score_static(run, scenario, lamp_map, bag=None):
    """Static result: the last pose published (after ``observe_s``), or a miss; the raw
    single-frame fixes of the same trial (:mod:`.raw_fix`; a drawn rig profile's with
    the belief of ``<bag>.installation``).
    """
    belief = None
    if scenario.rig_profile != 'ideal' and bag is not None:
        folder = pathlib.Path(bag).parent / f'{scenario.name}.installation'
        if (folder / 'belief').is_dir():
            belief = raw_fix.belief_setup(folder)
    out = {'point_m': scenario.static_point_m, 'seed': scenario.seed, 'error_m': None,
           'along_m': None, 'raw': raw_fix.score_raw_static(run, lamp_map, belief),
           'health': bag_eval.graph_health(run), 'latency_ms': _latency_samples(run),
           'processing_ms': bag_eval.processing_times(run)}
    # the last pose whose instant the truth covers (the IMU runs past the last frame)
    covered = np.nonzero((run.pose_t >= run.truth_t[0]) & (run.pose_t <= run.truth_t[-1])
                         if run.truth_t.size else np.zeros(0, bool))[0]
    if covered.size == 0:
        return out
    last = covered[-1:]
    err, along = metrics.pose_errors(run.pose_t[last], run.pose_xyz[last], run.truth_t,
                                     run.truth_xyz)
    out.update({'error_m': float(err[0]), 'along_m': float(along[0]),
                'observed_s': float(run.pose_t[last[0]] - run.truth_t[0])})
    return out


def score_dynamic(run, scenario, lamp_map, heading_plot=False):
    """Errors at the 20 test points of each passed cell and over every pose; lamp
    identification, latency, heading compensation, graph health.
    """
    lamp_chainages = lamp_map.positions[:, 0]
    out = {'speed_kmh': scenario.speed_kmh, 'seed': scenario.seed, 'points': [],
           'health': bag_eval.graph_health(run), 'latency_ms': _latency_samples(run),
           'processing_ms': bag_eval.processing_times(run),
           'identification': identification.identification(run)}
    if run.truth_t.size < 2:
        return out
    inst, dist, _ = metrics.test_point_instants(run.truth_t, run.truth_xyz[:, 0],
                                                lamp_chainages, TEST_POINTS_M)
    # Cold start: no pose until a UID is confirmed, and the compensator learns its gyro
    # bias and scale from the first lamps. Score after the lead-in (lead_in_m).
    settle = run.truth_t[0] + dynamic_settle_s(scenario.speed_kmh)
    keep = inst >= settle
    err, along = metrics.errors_at_instants(inst[keep], run.pose_t, run.pose_xyz,
                                            run.truth_t, run.truth_xyz)
    every = bag_eval.score_run(run, lamp_chainages, settle_s=settle - run.truth_t[0])
    out.update({
        'points': [{'point_m': float(d), 'error_m': None if not np.isfinite(e) else float(e),
                    'along_m': None if not np.isfinite(a) else float(a)}
                   for d, e, a in zip(dist[keep], err, along)],
        'every_pose': every['every_pose'],
        'covariance_3sigma_fraction': every.get('covariance_3sigma_fraction'),
        'heading_after_deg': every.get('heading_after_deg'),
        'heading_before_deg': every.get('heading_before_deg'),
        'heading_settling_s': bag_eval.heading_settling_s(
            run, run.pose_t[0] if run.pose_t.size else np.inf, HEADING_BOUND_DEG)})
    if heading_plot:
        out['heading_series'] = bag_eval.heading_series(run)
    return out


def recorded_installation(bag):
    """(rig profile, seed, installation seed) a sensor bag was recorded with: the
    recorder's ``custom_data`` of a drawn installation, else ('ideal', 1, 0).
    """
    import yaml
    try:
        info = yaml.safe_load((pathlib.Path(bag) / 'metadata.yaml').read_text(
            encoding='utf-8'))['rosbag2_bagfile_information']
        custom = info.get('custom_data') or {}
        return (str(custom.get('rig_profile', 'ideal')), int(custom.get('seed', 1)),
                int(custom.get('installation_seed', 0)))
    except (OSError, KeyError, TypeError, ValueError, yaml.YAMLError):
        return 'ideal', 1, 0


def replay_scenario(bag, realtime_factor=1.0, lean_recording=False):
    """A scenario that replays the sensor bag ``bag`` through the processing nodes. A bag
    recorded from a drawn installation (its ``custom_data``: :func:`recorded_installation`)
    is replayed with that installation's belief handed to the receivers, as in a live run.
    """
    start, end = bag_time_range(bag)
    profile, seed, installation_seed = recorded_installation(bag)
    bag = pathlib.Path(bag)
    return Scenario(name=f'replay_{bag.name}', replay_bag=str(bag),
                    duration_s=max(end - start, 0) * 1e-9, realtime_factor=realtime_factor,
                    lean_recording=lean_recording, rig_profile=profile, seed=seed,
                    installation_seed=installation_seed)


def score_replay(run, scenario, lamp_map):
    """A replayed sensor bag: every pose from the localizer's first one on (there are no
    protocol test points in a short pass), the lamps identified, graph health.
    """
    out = {'bag': scenario.replay_bag, 'poses': int(run.pose_t.size),
           'realtime_factor': scenario.realtime_factor,
           'health': bag_eval.graph_health(run), 'latency_ms': _latency_samples(run),
           'processing_ms': bag_eval.processing_times(run),
           'identification': identification.identification(run)}
    if run.pose_t.size and run.truth_t.size:
        out['first_pose_s'] = float(run.pose_t[0] - run.truth_t[0])
        scores = bag_eval.score_run(run, lamp_map.positions[:, 0],
                                    settle_s=out['first_pose_s'])
        out['every_pose'] = scores['every_pose']
        out['every_pose_along_track'] = scores['every_pose_along_track']
        out['covariance_3sigma_fraction'] = scores.get('covariance_3sigma_fraction')
    return out


def score_scenario(bag, scenario, lamp_map):
    """Score one recorded scenario bag (static or dynamic protocol, or a
    :mod:`.companions` kind).
    """
    if scenario.kind == 'fault':
        from vlc_evaluation import faults
        from vlc_evaluation.runner import rig_epoch_s
        result = faults.score_fault(bag, scenario, rig_epoch_s())
        result['scenario'] = asdict(scenario)
        return result
    run = bag_eval.load_run(bag)
    if scenario.kind == 'departure':
        from vlc_evaluation import departures
        result = departures.score_departure(run, scenario)
    elif scenario.kind:
        from vlc_evaluation import companions
        result = companions.score_kind(run, scenario)
    elif scenario.is_replay:
        result = score_replay(run, scenario, lamp_map)
    elif scenario.is_static:
        result = score_static(run, scenario, lamp_map, bag)
    else:
        # one heading time series per speed for the plot (the first seed's run)
        result = score_dynamic(run, scenario, lamp_map, heading_plot=scenario.seed == 1)
    result['scenario'] = asdict(scenario)
    return result


def _run_with_retries(scenario, bag_dir, lane, lamp_map, retries):
    """Run a scenario on ``lane``; while a node fell behind (a dropped frame or IMU
    sample, the camera lagging real time) or the graph misbehaved, run it again, slower.
    The kept result says how many attempts it took (``attempts``) and at which real-time
    factor it ran (``scenario.realtime_factor``).
    """
    from vlc_evaluation.runner import run_scenario
    for attempt in range(1, retries + 2):
        at_floor = lane.pace <= lane.min_pace
        run = replace(scenario, realtime_factor=round(scenario.realtime_factor * lane.pace, 3))
        shutil.rmtree(bag_dir / run.name, ignore_errors=True)
        logs = bag_dir / f'{run.name}.logs'
        if logs.exists():
            # the logs of a degraded attempt are kept beside the new ones
            shutil.rmtree(bag_dir / f'{run.name}.logs.attempt{attempt - 1}', ignore_errors=True)
            logs.rename(bag_dir / f'{run.name}.logs.attempt{attempt - 1}')
        run.restore_files()
        bag, timing = run_scenario(run, bag_dir, lane, run.recorded_topics())
        scored_at = time.monotonic()
        result = score_scenario(bag, run, lamp_map)
        timing['score_s'] = round(time.monotonic() - scored_at, 3)
        result['timing'] = timing
        result['attempts'] = attempt
        bad = timing['problems'] or result['health']['degraded']
        if not bad:
            lane.recover()
            return result
        if not timing['problems'] and at_floor:
            # already at the slowest pace: running it again would not be slower
            return result
        lane.slow_down(severe=bool(timing['problems']) or bag_eval.severely_degraded(
            result['health']))
        LOG.warning('%s (real-time factor %.2f): %s', run.name, run.realtime_factor,
                    '; '.join(timing['problems']) or f'degraded {result["health"]}')
    return result


#: the nodes that read ``lamp_map_path``: the rig's camera, and the receivers' decoder and
#: localizer (on a drawn installation they are given the survey of that map instead)
LAMP_MAP_NODES = ('stereo_camera_node', 'vlc_decoder_node', 'train_localizer_node')


def use_lamp_map(scenario, lamp_map):
    """Run ``scenario`` on the lamp map it is scored against (``run_evaluation
    --lamp-map``): a map loaded from a file other than the shipped default becomes the
    ``lamp_map_path`` of the rig and the receivers, unless the scenario's camera names a
    map of its own (the companion, outage and forged-lamp scenarios, whose receivers are
    given a deliberately different one). Before, the graph ran on the shipped map and the
    test points came from the given one.
    """
    from vlc_common.core.lamp_map import default_lamp_map_path
    path = getattr(lamp_map, 'path', None)
    if not path or os.path.realpath(path) == os.path.realpath(default_lamp_map_path()):
        return
    if scenario.node_params.get('stereo_camera_node', {}).get('lamp_map_path'):
        return
    for exe in LAMP_MAP_NODES:
        scenario.node_params.setdefault(exe, {})['lamp_map_path'] = os.path.realpath(path)


def run_protocols(groups, out_dir, lamp_map, lanes=2, spawn='fork', progress=None,
                  rescore=False, retries=1, fixed_pace=False, lockstep=False):
    """Run and score groups of scenarios; bags in ``out_dir/<group>/``.

    ``lockstep``: every scenario that can (:func:`.runner.lockstep_capable`) runs as a
    lockstep graph (:mod:`.lockstep`), the others as the graph.

    ``groups``: ``{group: [Scenario]}``. All scenarios share the ``lanes`` parallel lanes
    (longest first, so the lanes finish together); a degraded run is repeated up to
    ``retries`` times, slower (:func:`_run_with_retries`); with ``fixed_pace`` no lane
    ever slows down (every run at its real-time factor). Returns ``{group: [result]}``
    in scenario order, also written to ``out_dir/<group>/results.jsonl``. With
    ``rescore`` the graph is not run: the bags already there are scored again.
    """
    out_dir = pathlib.Path(out_dir)
    items = [(group, scenario) for group, scenarios in groups.items()
             for scenario in scenarios]
    for _, scenario in items:
        use_lamp_map(scenario, lamp_map)
    if lockstep:
        from vlc_evaluation.runner import lockstep_capable
        for _, scenario in items:
            scenario.lockstep = lockstep_capable(scenario)
    # a group with no scenarios this time (e.g. static in `--protocol companions`) keeps
    # what an earlier run into the same folder recorded
    groups = {group: scenarios for group, scenarios in groups.items() if scenarios}
    for group in groups:
        (out_dir / group).mkdir(parents=True, exist_ok=True)
    order = sorted(range(len(items)), key=lambda i: -items[i][1].duration_s)
    previous = {}
    for group in groups if rescore else ():
        path = out_dir / group / 'results.jsonl'
        if path.exists():
            for line in path.read_text(encoding='utf-8').splitlines():
                if not line.strip():
                    continue
                prior = json.loads(line)
                previous[(group, prior['scenario']['name'])] = prior
    done = [0]

    def make_job(group, scenario):
        def job(lane):
            started = time.monotonic()
            bag_dir = out_dir / group
            if lane is None:
                bag = bag_dir / scenario.name
                if not (bag / 'metadata.yaml').exists():
                    raise FileNotFoundError(f'{bag}: no bag to rescore')
                # how the bag was made (pace, timing, attempts) comes from the last run
                prior = previous.get((group, scenario.name), {})
                made = prior.get('scenario', {})
                run = replace(scenario, realtime_factor=made.get(
                    'realtime_factor', scenario.realtime_factor),
                    lockstep=made.get('lockstep', scenario.lockstep))
                result = score_scenario(bag, run, lamp_map)
                result['timing'] = prior.get('timing', {})
                result['attempts'] = prior.get('attempts', 1)
                result['wall_s'] = prior.get('wall_s')
                return result
            result = _run_with_retries(scenario, bag_dir, lane, lamp_map, retries)
            result['wall_s'] = round(time.monotonic() - started, 3)
            return result
        return job

    def on_done(_, result):
        done[0] += 1
        if progress:
            progress(done[0], len(items), result['scenario']['name'])

    jobs = [make_job(*items[i]) for i in order]
    if rescore:
        ordered = []
        for job in jobs:
            ordered.append(job(None))
            on_done(None, ordered[-1])
    else:
        from vlc_evaluation.runner import run_jobs
        ordered = run_jobs(jobs, lanes=lanes, spawn=spawn, on_done=on_done,
                           fixed_pace=fixed_pace)
    results = [None] * len(items)
    for k, i in enumerate(order):
        results[i] = ordered[k]
    out = {group: [] for group in groups}
    for (group, _), result in zip(items, results):
        out[group].append(result)
    for group, group_results in out.items():
        with open(out_dir / group / 'results.jsonl', 'w', encoding='utf-8') as stream:
            for result in group_results:
                stream.write(json.dumps(result) + '\n')
    return out
