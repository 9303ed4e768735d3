"""Scenario runner: the whole graph on the paper's protocols, recorded and scored.

A scenario starts the installed nodes (rig, decoder, spot locator, IMU compensator,
localizer) and the bag recorder on a DDS domain of its own, lets the rig run for the
scenario's simulated duration, stops everything (recorder last) and scores the bag
(:mod:`.bag_eval`). Protocols (``shared/EVALUATION.md``):

* static: the train stands ``d`` metres before a lamp, d = 0.5 … 10 m, one run per
  (d, seed); the result is the last pose published after ``observe_s`` of simulated time;
* dynamic: constant speed through several lamp cells; errors at the 20 test points of
  each cell and over every published pose.
"""
from dataclasses import asdict, dataclass, field
import itertools
import json
import logging
import os
import pathlib
import time

import numpy as np

from . import bag_eval, metrics
from .graph_runner import GraphRun

LOG = logging.getLogger(__name__)

RECORDED_TOPICS = ['/ground_truth/pose', '/train/pose', '/train/pose_with_covariance',
                   '/train/odometry', '/imu/data', '/vlc/lamps', '/spots/pairs',
                   '/diagnostics']
SENSOR_TOPICS = ['/stereo/left/image_raw', '/stereo/right/image_raw',
                 '/stereo/left/camera_info', '/stereo/right/camera_info', '/imu/data_raw',
                 '/clock']
PROCESSING_NODES = [('imu_compensator', 'imu_compensator_node'),
                    ('vlc_decoder', 'vlc_decoder_node'),
                    ('spot_locator', 'spot_locator_node'),
                    ('train_localizer', 'train_localizer_node')]
TEST_POINTS_M = tuple(np.round(np.arange(10.0, 0.0, -0.5), 1))
SETTLE_CELLS = 2          # dynamic: lamp cells passed before scoring starts (cold start)
IMU_TAIL_S = 0.5         # IMU samples beyond the last camera frame
LAMP_X_M = 50.0          # the static protocol stands before the lamp at 50 m (UID 0x1005)


@dataclass
class Scenario:
    """One graph run. ``localizer_params`` carries ablation switches."""

    name: str
    motion_profile: str = 'constant'
    start_chainage_m: float = 0.0
    speed_kmh: float = 0.0
    seed: int = 1
    duration_s: float = 5.0
    observe_s: float = 0.0
    realtime_factor: float = 1.0
    record_sensors: bool = False
    localizer_params: dict = field(default_factory=dict)
    static_point_m: float = float('nan')


def static_scenarios(points_m=TEST_POINTS_M, trials=10, observe_s=3.0, first_seed=1):
    return [Scenario(name=f'static_{d:04.1f}m_seed{seed}', motion_profile='stationary',
                     start_chainage_m=LAMP_X_M - d, seed=seed, duration_s=observe_s,
                     observe_s=observe_s, static_point_m=d)
            for d, seed in itertools.product(points_m, range(first_seed, first_seed + trials))]


def dynamic_scenarios(speeds_kmh=(20, 40, 60, 80, 100, 120), runs=10, cells=6, first_seed=1):
    """Constant speed from 1 m after a lamp through ``cells`` lamp cells (10 m each)."""
    out = []
    for v, seed in itertools.product(speeds_kmh, range(first_seed, first_seed + runs)):
        distance = 10.0 * cells + 1.0
        out.append(Scenario(name=f'dynamic_{v:03d}kmh_seed{seed}', motion_profile='constant',
                            start_chainage_m=LAMP_X_M - 10.0 * cells - 0.5, speed_kmh=float(v),
                            seed=seed, duration_s=distance / (v / 3.6)))
    return out


def run_scenario(scenario, out_dir, domain_id, settle_wall_s=3.0):
    """Run one scenario through the graph; returns the bag path."""
    out_dir = pathlib.Path(out_dir)
    bag = out_dir / scenario.name
    graph = GraphRun(out_dir / f'{scenario.name}.logs', domain_id)
    topics = RECORDED_TOPICS + (SENSOR_TOPICS if scenario.record_sensors else [])
    rig = {'seed': scenario.seed, 'motion_profile': scenario.motion_profile,
           'start_chainage_m': float(scenario.start_chainage_m),
           'speed_kmh': float(scenario.speed_kmh)}
    try:
        graph.start('train_localizer', 'bag_recorder', {'output': str(bag), 'topics': topics},
                    [graph.config_file('train_localizer', 'bag_recorder.yaml')])
        for package, exe in PROCESSING_NODES:
            params = scenario.localizer_params if package == 'train_localizer' else {}
            graph.start(package, exe, params, [graph.config_file(package, f'{exe}.yaml')])
        rig_files = [graph.config_file('vlc_stereo_camera', 'rig.yaml')]
        # The IMU starts with the processing nodes and holds simulated time until the
        # camera's first /clock tick (follow_clock), so it has discovered /clock by then.
        # It runs a little past the last frame, so the localizer can propagate its last
        # fixes to a published pose (it publishes on the IMU's time grid).
        graph.start('vlc_stereo_camera', 'adis16488_node',
                    dict(rig, duration_s=float(scenario.duration_s) + IMU_TAIL_S,
                         follow_clock=True,
                         realtime_factor=float(scenario.realtime_factor)),
                    rig_files + [graph.config_file('vlc_stereo_camera', 'adis16488_node.yaml')])
        # The processing nodes import numpy/OpenCV/rclpy; the camera then waits for the
        # decoder and spot locator to subscribe before simulated time starts.
        time.sleep(settle_wall_s)
        graph.start('vlc_stereo_camera', 'stereo_camera_node',
                    dict(rig, duration_s=float(scenario.duration_s), wait_for_subscribers=2,
                         realtime_factor=float(scenario.realtime_factor)),
                    rig_files + [graph.config_file('vlc_stereo_camera',
                                                   'stereo_camera_node.yaml')])
        pace = max(scenario.realtime_factor, 0.05)
        for rig_node, limit in (('stereo_camera_node', 30.0 + 3.0 * scenario.duration_s / pace),
                                ('adis16488_node', 5.0 + 3.0 * IMU_TAIL_S / pace)):
            if graph.wait(rig_node, limit) is None:
                LOG.warning('%s: %s did not finish within %.0f s', scenario.name, rig_node,
                            limit)
        time.sleep(1.0)                      # let the last fixes reach the recorder
    finally:
        graph.stop_all(last=('bag_recorder',))
    return bag


def score_static(run, scenario):
    """Static result: the last pose published (after ``observe_s``), or a miss."""
    # the last pose whose instant the truth covers (the IMU runs past the last frame)
    covered = np.nonzero((run.pose_t >= run.truth_t[0]) & (run.pose_t <= run.truth_t[-1])
                         if run.truth_t.size else np.zeros(0, bool))[0]
    if covered.size == 0:
        return {'point_m': scenario.static_point_m, 'seed': scenario.seed, 'error_m': None,
                'along_m': None}
    last = covered[-1:]
    err, along = metrics.pose_errors(run.pose_t[last], run.pose_xyz[last], run.truth_t,
                                     run.truth_xyz)
    return {'point_m': scenario.static_point_m, 'seed': scenario.seed,
            'error_m': float(err[0]), 'along_m': float(along[0]),
            'observed_s': float(run.pose_t[last[0]] - run.truth_t[0])}


def score_dynamic(run, scenario, lamp_chainages):
    """Errors at the 20 test points of each passed cell, and over every pose."""
    if run.truth_t.size < 2:
        return {'speed_kmh': scenario.speed_kmh, 'seed': scenario.seed, 'points': []}
    inst, dist, _ = metrics.test_point_instants(run.truth_t, run.truth_xyz[:, 0],
                                                lamp_chainages, TEST_POINTS_M)
    # Cold start: no pose until a UID is confirmed. Score from the later of 1 s and the
    # first SETTLE_CELLS lamp cells of the run.
    speed = max(scenario.speed_kmh / 3.6, 0.1)
    settle = run.truth_t[0] + max(1.0, SETTLE_CELLS * 10.0 / speed)
    keep = inst >= settle
    err, along = metrics.errors_at_instants(inst[keep], run.pose_t, run.pose_xyz,
                                            run.truth_t, run.truth_xyz)
    every = bag_eval.score_run(run, lamp_chainages, settle_s=settle - run.truth_t[0])
    return {'speed_kmh': scenario.speed_kmh, 'seed': scenario.seed,
            'points': [{'point_m': float(d), 'error_m': None if not np.isfinite(e) else float(e),
                        'along_m': None if not np.isfinite(a) else float(a)}
                       for d, e, a in zip(dist[keep], err, along)],
            'every_pose': every['every_pose'],
            'covariance_3sigma_fraction': every.get('covariance_3sigma_fraction'),
            'heading_after_deg': every.get('heading_after_deg'),
            'heading_before_deg': every.get('heading_before_deg')}


def run_protocol(scenarios, out_dir, lamp_chainages, progress=None, rescore=False):
    """Run and score scenarios one after another (bags kept in ``out_dir``); returns
    the list of result dicts, also written to ``out_dir/results.jsonl``. With
    ``rescore`` the graph is not run: the bags already in ``out_dir`` are scored again."""
    out_dir = pathlib.Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    results = []
    base_domain = 100 + os.getpid() % 100
    (out_dir / 'results.jsonl').unlink(missing_ok=True)
    for i, scenario in enumerate(scenarios):
        started = time.monotonic()
        if rescore:
            bag = out_dir / scenario.name
            if not (bag / 'metadata.yaml').exists():
                raise FileNotFoundError(f'{bag}: no bag to rescore')
        else:
            bag = run_scenario(scenario, out_dir, domain_id=base_domain + (i % 30))
        run = bag_eval.load_run(bag)
        if scenario.motion_profile == 'stationary':
            result = score_static(run, scenario)
        else:
            result = score_dynamic(run, scenario, lamp_chainages)
        result['scenario'] = asdict(scenario)
        result['wall_s'] = time.monotonic() - started
        results.append(result)
        with open(out_dir / 'results.jsonl', 'a', encoding='utf-8') as stream:
            stream.write(json.dumps(result) + '\n')
        if progress:
            progress(i + 1, len(scenarios), scenario.name)
    return results
