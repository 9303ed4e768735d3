"""Runs scenarios through the whole graph, in parallel lanes, and records each in a bag.

One scenario = one fresh set of node processes (rig, decoder, spot locator, IMU
compensator, localizer, bag recorder) and a fresh :class:`GraphProbe` on its lane's DDS
domain; nothing carries over from one scenario to the next but the domain id.
A scenario's data are fixed by its seed, and the graph is paced by simulated time, so
a scenario gives the same result whichever lane or order runs it, as long as no node
falls so far behind that a queue overflows (the nodes' diagnostics count it; the run is
then marked degraded and run again, slower: :mod:`.scenarios`).

Phases of one scenario (each timed, ``result['timing']``):

1. *start*: every node is started at once (``fork`` spawner: no per-node imports);
2. *ready*: the probe sees every subscription the run needs (processing nodes and
   recorder), then opens its gate, the camera's last awaited image subscriber;
3. *sim*: simulated time runs ``duration_s`` (the camera exits at the end; the IMU runs
   ``IMU_TAIL_S`` beyond so the localizer can publish past the last frame); a replay
   scenario starts ``bag_player`` instead;
4. *drain*: until ``train/pose`` has covered the last frame (or, for a localizer that
   publishes only at fixes, none came for ``POSE_QUIET_S`` after the IMU finished) and
   the IMU has finished its tail, plus ``DRAIN_GRACE_S`` for the recorder;
5. *stop*: SIGINT to every node at once, the recorder last (it closes the bag).
"""
from dataclasses import dataclass, field
import functools
import json
import logging
import os
import pathlib
import queue
import threading
import time

import yaml

from vlc_bags.bagio import iter_raw, open_bag
from vlc_bags.typesupport import header_stamp_ns
from vlc_common.stamps import stamp_to_ns
from vlc_evaluation.graph_runner import (
    ForkSpawner,
    GraphRun,
    read_cpu_seconds,
    read_peak_rss_mib,
    ros_argv,
    workspace_install,
)
from vlc_evaluation.latency import READOUT_S

LOG = logging.getLogger(__name__)

PROCESSING_NODES = [('imu_compensator', 'imu_compensator_node'),
                    ('vlc_decoder', 'vlc_decoder_node'),
                    ('spot_locator', 'spot_locator_node'),
                    ('train_localizer', 'train_localizer_node')]
RIG_NODES = [('vlc_stereo_camera', 'adis16488_node'),
             ('vlc_stereo_camera', 'stereo_camera_node')]
RECORDER = ('vlc_bags', 'bag_recorder')
PLAYER = ('vlc_bags', 'bag_player')
LOCKSTEP = ('vlc_evaluation', 'lockstep_graph')
EXECUTABLES = [exe for _, exe in PROCESSING_NODES + RIG_NODES + [RECORDER, PLAYER,
                                                                      LOCKSTEP]]
# Extra processing nodes a scenario may add (Scenario.extra_nodes: the companion methods
# and the rig's photodiode), preloaded in the fork server too.
EXTRA_EXECUTABLES = ['photodiode_node', 'rssi_localizer_node', 'dead_reckoning_node',
                     'ins_beacon_node', 'curvature_node', 'sbs_splitter_node',
                     'fault_injector_node']
# What a replay plays from a sensor bag (the processing nodes' inputs and the truth; an
# SBS camera's frames instead of the stereo topics: vlc_evaluation.sbs_bag)
SBS_TOPICS = ('/image_raw', '/image_raw/compressed')
REPLAYED_TOPICS = ('/stereo/left/image_raw', '/stereo/right/image_raw',
                   '/stereo/left/camera_info', '/stereo/right/camera_info', '/imu/data_raw',
                   '/ground_truth/pose', '/ground_truth/spots') + SBS_TOPICS

# environment variable naming the camera nodes' precompute_cache_dir (run_evaluation sets
# it to <out>/rig_cache unless given; unset: no memo)
RIG_CACHE_ENV = 'VLC_RIG_CACHE_DIR'
IMU_TAIL_S = 0.1          # IMU samples beyond the last camera frame (poses past it)
DRAIN_GRACE_S = 0.25      # after the last pose is seen: let the recorder take it too
POSE_QUIET_S = 0.3        # inputs done and no pose for this long: the localizer is done
READY_TIMEOUT_S = 60.0    # start-up (imports, construction, discovery) may not exceed this
RECORDER_SCAN_S = 0.1     # recorder graph scan period: subscribes 0.1 s after a publisher
# One split per run: closing a split every second (the crash-safety default) costs the
# recorder about a third of its CPU; a run interrupted before its bag is closed is rerun.
RECORDER_FLUSH_S = 60.0
# In lean recordings (the latency replays: no 400 Hz topics) the recorder observes at a
# lower CPU priority than the graph it records, so a frame's processing never queues
# behind it (its keep-last queues of 100 hold a second of its busiest topic, /clock).
# Latency is unaffected by the recorder's own delay: it comes from the publishers'
# source timestamps. Full recordings keep the default priority: the 400 Hz IMU topics
# would overflow a starved recorder's queues in a quarter of a second.
RECORDER_NICE_LEAN = 10

# Subscriptions the processing nodes create (topic: count); the recorder adds one per
# recorded topic, the probe its own ('/clock', '/train/pose').
PROCESSING_SUBSCRIPTIONS = {'/imu/data_raw': 1, '/imu/data': 1, '/vlc/lamps': 1,
                            '/spots/pairs': 1, '/train/odometry': 1,
                            '/stereo/left/image_raw': 2, '/stereo/right/image_raw': 2,
                            '/clock': 2, '/train/pose': 1}


def rig_epoch_s(install=None):
    """``epoch_s`` of the installed ``rig.yaml`` (simulated t = 0 in ROS time)."""
    path = pathlib.Path(install or workspace_install()) / 'share' / 'vlc_stereo_camera' \
        / 'config' / 'rig.yaml'
    params = yaml.safe_load(path.read_text())['/**']['ros__parameters']
    return float(params['epoch_s'])


class RunAborted(Exception):
    """The evaluation was interrupted (Ctrl-C); the scenario's graph has been stopped."""


def required_subscriptions(recorded_topics, processing=True):
    """Subscriber counts that mean "every node and the recorder listen"."""
    need = dict(PROCESSING_SUBSCRIPTIONS) if processing else {'/clock': 2, '/train/pose': 1}
    for topic in recorded_topics:
        need[topic] = need.get(topic, 0) + 1
    return need


@dataclass
class Lane:
    """One evaluation lane: a DDS domain, the shared spawner and the lane's pace.

    ``pace`` (0, 1] multiplies every scenario's real-time factor: it drops after a run
    in which a node fell behind (the machine was short of CPU) and recovers after clean
    runs, so a lane slows down under load instead of losing frames. ``ceiling`` is what
    the lane has learnt: just below the pace of its last degraded run. Recovery climbs
    back only to the ceiling and then probes above it slowly (+2 % per clean run at the
    ceiling), so a lane does not keep returning to a pace the machine cannot carry —
    each such return cost a rerun (92 reruns in 262 scenarios of the full protocol
    before the ceiling).
    """

    domain_id: int
    spawner: object = None
    epoch_s: float = field(default_factory=rig_epoch_s)
    abort: threading.Event = field(default_factory=threading.Event)
    pace: float = 1.0
    # Floor of the pace: on a slow machine a floor of 0.3 still left most runs with a
    # node falling behind (IMU gaps, lamp records past the localizer's history); a
    # slower clean run is worth more than a fast degraded one.
    min_pace: float = 0.15
    ceiling: float = 1.0

    def slow_down(self, severe=True):
        """After a degraded run: halve the pace if nodes fell far behind, else -20 %;
        the ceiling drops to 90 % of the pace that failed.
        """
        self.ceiling = max(self.min_pace, min(self.ceiling, 0.9 * self.pace))
        self.pace = max(self.min_pace, (0.5 if severe else 0.8) * self.pace)

    def recover(self):
        """After a clean run: +10 % up to the ceiling; at the ceiling, raise it by 2 %."""
        if self.pace >= self.ceiling:
            self.ceiling = min(1.0, 1.02 * self.ceiling)
        self.pace = min(self.ceiling, 1.1 * self.pace)

    def move_domain(self):
        """Another domain for the next run (this one is used by someone else)."""
        self.domain_id = 120 + (self.domain_id - 120 + 37) % 113


# /clock from the player as the camera's (the latency figures interpolate between ticks)
PLAYER_CLOCK_HZ = 100.0
# Images (and their camera_info) exist only once the camera has read out the last row
# (latency.READOUT_S after the first row's exposure start).
FRAME_TOPICS = ('/stereo/left/image_raw', '/stereo/right/image_raw',
                '/stereo/left/camera_info', '/stereo/right/camera_info') + SBS_TOPICS


def header_stamped(bag, topics=('/stereo/left/image_raw',) + SBS_TOPICS):
    """True when the bag's timestamps of its first frame (``topics``) are its header
    stamps (a sensor bag of the rig recorded with ``timestamp_source: header``), False for
    receive times.
    """
    for _, _, timestamp, data in iter_raw(bag, list(topics)):
        return header_stamp_ns(data) == timestamp
    return False


def bag_end_ns(bag, topic='/ground_truth/pose'):
    """Header stamp of the last ``topic`` message of a bag, ns (0 if none)."""
    last = 0
    for _, _, _, msg in open_bag(bag, topics=[topic]):
        last = max(last, stamp_to_ns(msg.header.stamp))
    return last


def write_installation(scenario, out_dir):
    """The receivers' parameters for a drawn rig profile ({} for ``ideal``).

    Draws the scenario's installation (the draw the rig nodes make from ``rig_profile``
    and ``seed`` on the shipped vehicle and lamp map) and writes it beside the bag,
    ``<out_dir>/<name>.installation/{belief,truth}/``: ``truth/truth.yaml`` records the
    profile, the seed and every drawn value for the evaluation. Returns
    ``{'vehicle_path': belief/vehicle.yaml, 'lamp_map_path': belief/lamp_map.yaml}``, plus
    ``error_model_path`` (``belief/train_localizer_node.yaml``, :func:`write_error_model`)
    for an installation poorer than the localizer's defaults state.
    With ``scenario.calibration`` ``checkerboard`` the belief calibration is replaced by
    an actual checkerboard calibration of the true lenses (``calibrate_installation``);
    with ``uncorrected`` its distortion and rectification are dropped (D = 0, R = I,
    K = P[:, :3]: the receivers take the raw images as rectified — the ablation of
    undistortion and rectification).
    """
    if scenario.rig_profile == 'ideal':
        return {}
    from vlc_common.core.lamp_map import LampMap
    from vlc_common.core.vehicle import load_vehicle
    from vlc_stereo_camera.core.installation import draw_installation
    camera = scenario.node_params.get('stereo_camera_node', {})
    inst = draw_installation(scenario.rig_profile, scenario.drawn_seed,
                             load_vehicle(camera.get('vehicle_path', '')),
                             LampMap.load(_rig_lamp_map_path(scenario)))
    folder = pathlib.Path(out_dir) / f'{scenario.name}.installation'
    paths = inst.write(folder)
    if scenario.calibration == 'checkerboard':
        from vlc_evaluation.installation_calibration import calibrate_installation
        calibrate_installation(folder)
    elif scenario.calibration == 'uncorrected':
        for side in ('left', 'right'):
            drop_distortion(folder / 'belief' / f'{side}.yaml')
    elif scenario.calibration != 'drawn':
        raise ValueError(f'scenario {scenario.name}: calibration {scenario.calibration!r} is '
                         'not drawn, checkerboard or uncorrected')
    out = {'vehicle_path': paths['belief/vehicle.yaml'],
           'lamp_map_path': paths['belief/lamp_map.yaml']}
    error_model = write_error_model(scenario.rig_profile, folder / 'belief')
    if error_model:
        out[ERROR_MODEL_KEY] = error_model
    return out


def write_error_model(profile, belief_dir):
    """Write ``belief_dir/train_localizer_node.yaml``, the localizer's parameters file of
    :func:`stated_error_model` (what the integrator states with the calibration and the
    mount), when there is anything to state; returns its path or None.
    """
    model = stated_error_model(profile)
    if not model:
        return None
    path = pathlib.Path(belief_dir) / f'{LOCALIZER_EXE}.yaml'
    with open(path, 'w', encoding='utf-8') as stream:
        stream.write('# The calibration and mount 1-sigma this installation states (its '
                     'calibration RMS and\n# mount measurement against the reference of '
                     'the node defaults): a params file\n# for train_localizer_node after '
                     'its own.\n')
        yaml.safe_dump({'/**': {'ros__parameters': model}}, stream, sort_keys=False,
                       default_flow_style=None)
    return str(path)


#: The localizer's calibration error model (train_localizer_node.yaml) states a stereo
#: calibration of this reprojection RMS and a camera mount measured to this 1σ: the
#: ``realistic`` profile's. A poorer installation must be stated as such.
REFERENCE_CALIBRATION_RMS_PX = 0.15
REFERENCE_MOUNT_SIGMA_DEG = 0.05
#: The localizer parameters that scale with the calibration's reprojection RMS (the
#: parameter covariance of a least-squares calibration scales with its residual's σ²),
#: and the one that scales with the mount's measurement 1σ.
CALIBRATION_SIGMA_PARAMETERS = ('stereo_scale_sigma', 'focal_length_sigma',
                                'principal_point_sigma_px', 'calibration_sigma_px',
                                'calibration_disparity_sigma_px')
MOUNT_SIGMA_PARAMETER = 'mount_angle_sigma_deg'


def stated_error_model(profile, defaults=None):
    """The localizer parameters an integrator writes for an installation of ``profile``
    (a RigProfile or its name): the node's calibration and mount 1σ scaled by how much
    poorer the installation's stated calibration (reprojection RMS) and mount measurement
    are than the reference its defaults state; never below the defaults (a better
    installation keeps them: the ``realistic`` profile and its error-budget rows run on the
    defaults exactly). The mount takes the principal point's share when the camera-to-body
    calibration sees through the camera (``principal_point_in_mount``). {} for ``ideal``.

    ``defaults``: the node's parameters (None: its installed parameter file, read once).
    """
    from vlc_stereo_camera.core.installation import load_profile
    if isinstance(profile, str):
        profile = load_profile(profile)
    if profile.ideal:
        return {}
    if defaults is None:
        defaults = _localizer_defaults()
    cal, mount = profile.calibration, profile.mount
    k_cal = float(cal['reprojection_rms_px']) / REFERENCE_CALIBRATION_RMS_PX
    k_mount = max(float(mount['camera_angle_measurement_sigma_deg']) / REFERENCE_MOUNT_SIGMA_DEG,
                  k_cal * float(cal.get('principal_point_in_mount', 0.0)))
    out = {}
    if k_cal > 1.0:
        out.update({name: round(float(defaults[name]) * k_cal, 9)
                    for name in CALIBRATION_SIGMA_PARAMETERS})
    if k_mount > 1.0:
        out[MOUNT_SIGMA_PARAMETER] = [round(float(v) * k_mount, 9)
                                      for v in defaults[MOUNT_SIGMA_PARAMETER]]
    return out


@functools.lru_cache(maxsize=1)
def _localizer_defaults():
    from vlc_evaluation.localizer_replay import load_params
    return load_params()


def read_error_model(belief_dir):
    """The parameters of :func:`write_error_model`'s file in ``belief_dir`` ({} if none)."""
    path = pathlib.Path(belief_dir) / f'{LOCALIZER_EXE}.yaml'
    if not path.exists():
        return {}
    return yaml.safe_load(path.read_text(encoding='utf-8'))['/**']['ros__parameters']


def drop_distortion(path):
    """Rewrite a camera_info_manager YAML file as a rectified camera's: D = 0, R = I,
    K = P[:, :3] (the projection and the baseline kept).
    """
    from vlc_common.core.calibration import read_camera_info_yaml, write_camera_info_yaml
    from vlc_common.core.camera import CameraModel
    camera, name, meta = read_camera_info_yaml(path)
    write_camera_info_yaml(path, CameraModel(camera.width, camera.height, camera.P[:, :3],
                                             P=camera.P), name, meta)


def _rig_lamp_map_path(scenario):
    """The lamp map the scenario's camera node renders (resolved path)."""
    from vlc_common.core.lamp_map import resolve_lamp_map_path
    camera = scenario.node_params.get('stereo_camera_node', {})
    return resolve_lamp_map_path(camera.get('lamp_map_path', ''),
                                 camera.get('alignment', 'straight'))


#: ``write_installation``'s key of the localizer's stated error model (a params file)
ERROR_MODEL_KEY = 'error_model_path'
LOCALIZER_EXE = 'train_localizer_node'


def receiver_params_files(belief, graph, package, exe, names=None):
    """A processing node's parameter files: its installed ones (``names``; default
    ``<exe>.yaml``), then for the localizer the installation's stated error model (its -p
    parameters, the scenario's own, still win).
    """
    files = [graph.config_file(package, name)
             for name in (names if names is not None else [f'{exe}.yaml'])]
    if exe == LOCALIZER_EXE and belief.get(ERROR_MODEL_KEY):
        files.append(belief[ERROR_MODEL_KEY])
    return files


def receiver_params(belief, scenario, exe):
    """A processing node's parameters: the belief files under the scenario's own; a
    ``lamp_map_path`` that names the rig's own (true) map is replaced by the survey (a
    deliberately different receiver map, as in the forged-lamp and outage scenarios, is
    kept as it is).
    """
    own = scenario.node_params.get(exe, {})
    belief = {k: v for k, v in belief.items() if k != ERROR_MODEL_KEY}
    params = dict(belief, **own)
    if belief and own.get('lamp_map_path') and (
            os.path.realpath(os.path.expanduser(own['lamp_map_path']))
            == os.path.realpath(_rig_lamp_map_path(scenario))):
        params['lamp_map_path'] = belief['lamp_map_path']
    return params


def _start_rig(graph, scenario, camera_subscribers, camera_params=None):
    rig = {'seed': scenario.seed, 'motion_profile': scenario.motion_profile,
           'start_chainage_m': float(scenario.start_chainage_m),
           'speed_kmh': float(scenario.speed_kmh),
           'realtime_factor': float(scenario.realtime_factor)}
    if scenario.rig_profile != 'ideal':
        rig['rig_profile'] = scenario.rig_profile
        if scenario.installation_seed:
            rig['installation_seed'] = int(scenario.installation_seed)
    rig_files = [graph.config_file('vlc_stereo_camera', 'rig.yaml')]
    # The IMU follows the camera's /clock (its default), which runs IMU_TAIL_S past the
    # last frame.
    graph.start('vlc_stereo_camera', 'adis16488_node',
                dict(rig, duration_s=float(scenario.duration_s) + IMU_TAIL_S,
                     **scenario.node_params.get('adis16488_node', {})),
                rig_files + [graph.config_file('vlc_stereo_camera', 'adis16488_node.yaml')])
    # The camera constructs its renderer meanwhile and then holds simulated time
    # until the decoder, the spot locator (, the recorder) and the probe's gate
    # subscribe to its images.
    graph.start('vlc_stereo_camera', 'stereo_camera_node',
                dict(rig, duration_s=float(scenario.duration_s), clock_tail_s=IMU_TAIL_S,
                     wait_for_subscribers=camera_subscribers,
                     precompute_cache_dir=os.environ.get(RIG_CACHE_ENV, ''),
                     **{**(camera_params or {}),
                        **scenario.node_params.get('stereo_camera_node', {})}),
                rig_files + [graph.config_file('vlc_stereo_camera', 'stereo_camera_node.yaml')])


def _start_nodes(graph, scenario, out_dir, recorded_topics):
    """Start the scenario's nodes on ``graph``: the rig (unless it replays a bag), the
    recorder of ``recorded_topics`` into ``out_dir/<name>``, the processing nodes and
    the scenario's extra nodes.
    """
    # (a replayed bag of a drawn installation: the receivers get its belief too)
    belief = write_installation(scenario, out_dir)
    recorder = {'output': str(pathlib.Path(out_dir) / scenario.name),
                'topics': list(recorded_topics),
                'discovery_interval_s': RECORDER_SCAN_S,
                'flush_interval_s': RECORDER_FLUSH_S}
    if belief:
        recorder['metadata'] = [f'rig_profile={scenario.rig_profile}',
                                f'seed={scenario.seed}',
                                f'installation_seed={scenario.drawn_seed}',
                                f'installation={out_dir / f"{scenario.name}.installation"}']
    if not scenario.replay_bag:
        # The rig first: the camera builds its renderer (the longest construction)
        # while the other nodes start, and holds simulated time until the decoder,
        # the spot locator, the probe's gate (, the recorder) subscribe to its images.
        camera = {}
        if belief and scenario.calibration in ('checkerboard', 'uncorrected'):
            belief_dir = pathlib.Path(belief['vehicle_path']).parent
            camera['calibration_paths'] = [str(belief_dir / 'left.yaml'),
                                           str(belief_dir / 'right.yaml')]
        _start_rig(graph, scenario, 1 + 2 * scenario.run_processing
                   + int('/stereo/left/image_raw' in recorded_topics), camera)
    graph.start(*RECORDER, dict(recorder, **scenario.node_params.get('bag_recorder', {})),
                [graph.config_file(*RECORDER[:1], 'bag_recorder.yaml')],
                nice=RECORDER_NICE_LEAN if scenario.lean_recording else 0)
    for package, exe in (PROCESSING_NODES if scenario.run_processing else []):
        graph.start(package, exe, receiver_params(belief, scenario, exe),
                    receiver_params_files(belief, graph, package, exe))
    for package, exe, files in scenario.extra_nodes:
        graph.start(package, exe, receiver_params(belief, scenario, exe),
                    receiver_params_files(belief, graph, package, exe, files))


class LockstepSpec:
    """Takes :func:`_start_nodes`'s start calls in place of ``graph`` (a
    :class:`GraphRun`) and starts nothing: it keeps each node's start arguments as the
    node list of a lockstep graph (:mod:`.lockstep`); ``graph`` resolves the config files
    and later starts the ``lockstep_graph`` process itself.
    """

    def __init__(self, graph):
        self.graph = graph
        self.nodes = []

    def config_file(self, package, name):
        return self.graph.config_file(package, name)

    def start(self, package, executable, params=None, params_files=(), name=None, nice=0,
              log_name=None):
        if (package, executable) == RECORDER:
            # its receive times would be simulated time too: no latency to read there
            params = dict(params or {}, record_receive_times=False)
        self.nodes.append({'name': name or executable, 'package': package,
                           'executable': executable,
                           'argv': ros_argv(params, params_files)})


def lockstep_capable(scenario):
    """Whether ``scenario`` can run as a lockstep graph: the rig (no replayed bag), no
    fault or injected topic, and only nodes :data:`.lockstep.NODE_CLASSES` can build.
    """
    from vlc_evaluation.lockstep import NODE_CLASSES
    return (not scenario.replay_bag and scenario.kind != 'fault'
            and not scenario.extra_publishers
            and all(exe in NODE_CLASSES for _, exe, _ in scenario.extra_nodes))


def run_scenario_lockstep(scenario, out_dir, lane, recorded_topics):
    """:func:`run_scenario` with the nodes in one process on simulated time
    (``lockstep_graph``, :mod:`.lockstep`): the same nodes, parameters and recorded
    bag, no DDS between them, no pacing. Returns (bag path, timing dict) as
    :func:`run_scenario`, with the phases a lockstep run has (:data:`LOCKSTEP_PHASES`):
    ``started`` (the process forked), ``ran`` (it exited: its nodes built, the scenario
    simulated and the bag closed), ``stopped``; ``cpu_s`` and ``rss_mib`` of
    ``lockstep_graph``.
    """
    if not lockstep_capable(scenario):
        raise ValueError(f'{scenario.name}: cannot run as a lockstep graph (a replay, a '
                         'fault, an injected topic or a node it cannot build)')
    out_dir = pathlib.Path(out_dir)
    bag = out_dir / scenario.name
    log_dir = out_dir / f'{scenario.name}.logs'
    t0 = time.monotonic()
    timing = {'problems': []}
    graph = GraphRun(log_dir, lane.domain_id, spawner=lane.spawner)
    spec = LockstepSpec(graph)
    _start_nodes(spec, scenario, out_dir, recorded_topics)
    spec_path = log_dir / 'lockstep.json'
    spec_path.write_text(json.dumps({'nodes': spec.nodes}, indent=1), encoding='utf-8')
    graph.start(*LOCKSTEP, {'spec': str(spec_path)})
    timing['started'] = round(time.monotonic() - t0, 3)
    # simulated time at any pace: a limit as generous as the graph's at real time
    limit = 60.0 + 3.0 * scenario.duration_s
    code = graph.wait(LOCKSTEP[1], limit, abort=lane.abort.is_set)
    timing['ran'] = round(time.monotonic() - t0, 3)
    codes = graph.stop_all() if code is None else {LOCKSTEP[1]: code}
    timing['stopped'] = round(time.monotonic() - t0, 3)
    if lane.abort.is_set():
        raise RunAborted(scenario.name)
    timing['cpu_s'] = read_cpu_seconds(log_dir)
    timing['rss_mib'] = read_peak_rss_mib(log_dir)
    timing['exit_codes'] = codes
    bad = {n: c for n, c in codes.items() if c not in (0, None)}
    if code is None:
        timing['problems'].append(f'lockstep_graph still running after {limit:.0f} s')
    if bad:
        timing['problems'].append(f'exit codes {bad}')
    return bag, timing


def run_scenario(scenario, out_dir, lane, recorded_topics):
    """Run one scenario through the graph on ``lane``; returns (bag path, timing dict).

    With ``scenario.replay_bag`` the rig is replaced by ``bag_player`` replaying that
    bag's sensor topics at ``realtime_factor``. ``timing``: wall seconds from the start
    to each phase's end, ``cpu_s`` and ``rss_mib`` (peak resident memory) per node
    (``fork`` only), and ``problems`` (a list of strings: readiness timeout, a node's
    non-zero exit, simulated time not starting).
    """
    if scenario.lockstep:
        return run_scenario_lockstep(scenario, out_dir, lane, recorded_topics)
    from vlc_evaluation.probe import GraphProbe
    out_dir = pathlib.Path(out_dir)
    bag = out_dir / scenario.name
    graph = GraphRun(out_dir / f'{scenario.name}.logs', lane.domain_id,
                     spawner=lane.spawner)
    t0 = time.monotonic()
    # A fresh probe per scenario: a long-lived participant on a domain where six
    # processes come and go every few seconds was seen to stop receiving from new
    # participants after some ten scenarios (Fast DDS, shared-memory transport).
    probe = GraphProbe(lane.domain_id)
    timing = {'problems': []}
    def mark(phase):
        timing[phase] = round(time.monotonic() - t0, 3)

    pace = max(scenario.realtime_factor, 0.05)
    replay = bool(scenario.replay_bag)

    def died():
        return lane.abort.is_set() or any(p.poll() not in (None, 0)
                                          for p in graph.procs.values())

    try:
        _start_nodes(graph, scenario, out_dir, recorded_topics)
        required = required_subscriptions(recorded_topics, scenario.run_processing)
        for topic, count in scenario.extra_subscriptions.items():
            required[topic] = required.get(topic, 0) + count
        if replay:
            # the player's /clock and ground truth come from the bag, not from a rig; the
            # recorder subscribes to a played topic only once the player offers it (during
            # the player's start delay), so it is not awaited there
            required = {t: n - (t in recorded_topics and t in REPLAYED_TOPICS)
                        for t, n in required.items()
                        if t not in ('/clock', '/ground_truth/pose', '/ground_truth/spots')}
        mark('started')
        missing = probe.wait_for_subscribers(required, READY_TIMEOUT_S, abort=died)
        mark('ready')
        # when each awaited topic had its subscribers (s since the start): the last ones
        # are what the ready phase waited for
        timing['ready_topics'] = {topic: round(at - t0, 3)
                                  for topic, at in sorted(probe.satisfied_at.items(),
                                                          key=lambda item: item[1])}
        if missing:
            timing['problems'].append(f'not ready: {missing}')
        # another graph on this domain (another evaluation, a test) would mix with ours
        sources = {t: probe.node.count_publishers(t) for t in
                   ('/imu/data_raw', '/stereo/left/image_raw', '/train/pose')}
        if any(n > 1 + scenario.extra_publishers.get(t, 0) for t, n in sources.items()):
            timing['problems'].append(f'domain {lane.domain_id} shared with another graph: '
                                      f'publishers {sources}')
            lane.move_domain()
        if replay:
            end_ns = bag_end_ns(scenario.replay_bag)
            # A header-stamped bag would hand each frame over a readout before the
            # camera could have sent it: the player delays the frames by the readout.
            delay = READOUT_S if header_stamped(scenario.replay_bag) else 0.0
            graph.start(*PLAYER, {'bag': str(scenario.replay_bag),
                                  'rate': float(scenario.realtime_factor),
                                  'topics': list(REPLAYED_TOPICS),
                                  'delay_topics': list(FRAME_TOPICS),
                                  'topic_delay_s': delay,
                                  'clock_rate_hz': PLAYER_CLOCK_HZ,
                                  'wait_for_subscriptions': True},
                        [graph.config_file(PLAYER[0], 'bag_player.yaml')])
            mark('sim_started')
            limit = 30.0 + 3.0 * scenario.duration_s / pace
            code = graph.wait(PLAYER[1], limit, abort=lane.abort.is_set)
            if code != 0:
                timing['problems'].append(f'bag_player exit {code} (limit {limit:.0f} s)')
            mark('camera_done')
            def inputs_done():
                return True
        else:
            probe.open_gate()
            if not probe.wait_for_clock(READY_TIMEOUT_S, abort=died):
                timing['problems'].append(
                    f'simulated time did not start ({probe.describe()}; camera alive: '
                    f'{graph.running("stereo_camera_node")})')
            probe.close_gate()
            mark('sim_started')
            driver = None
            if scenario.kind == 'fault':
                from vlc_evaluation import faults
                fault = faults.fault_of(scenario)
                driver = faults.FaultDriver(fault, graph, probe, lane.epoch_s,
                                            out_dir / f'{scenario.name}.{faults.FAULT_FILE}',
                                            lane.abort.is_set)
                driver.start()
            limit = 30.0 + 3.0 * scenario.duration_s / pace
            if driver is not None:
                limit += 60.0      # the overloaded runs are slower than real time
            code = graph.wait('stereo_camera_node', limit, abort=lane.abort.is_set)
            if code != 0:
                timing['problems'].append(f'stereo_camera_node exit {code} '
                                          f'(limit {limit:.0f} s)')
            mark('camera_done')
            end_ns = round((lane.epoch_s + scenario.duration_s) * 1e9)
            if driver is not None:
                timing['problems'] += driver.finish()['problems']
                end_ns += round(faults.stamp_shift_s(fault) * 1e9)
            def inputs_done():
                return not graph.running('adis16488_node')

        drain_s = 1.5 + 2.0 * IMU_TAIL_S / pace
        if not probe.wait_for_pose_stamp(end_ns, drain_s, abort=died, quiet_s=POSE_QUIET_S,
                                         inputs_done=inputs_done):
            timing['last_pose_before_end'] = True
        if not replay:
            # The IMU exits by itself after its tail (a SIGINT during its own shutdown
            # would interrupt it).
            graph.wait('adis16488_node', drain_s, abort=lane.abort.is_set)
        time.sleep(DRAIN_GRACE_S)
        mark('drained')
    finally:
        codes = graph.stop_all(last=('bag_recorder',))
        probe.close()
        mark('stopped')
    if lane.abort.is_set():
        raise RunAborted(scenario.name)
    timing['cpu_s'] = read_cpu_seconds(graph.log_dir)
    timing['rss_mib'] = read_peak_rss_mib(graph.log_dir)
    timing['exit_codes'] = codes
    bad = {n: c for n, c in codes.items() if c not in (0, None)}
    if bad:
        timing['problems'].append(f'exit codes {bad}')
    return bag, timing


def lane_domains(lanes, pid=None):
    """Consecutive DDS domain ids for the lanes, spread by process id (≤ 232)."""
    pid = os.getpid() if pid is None else pid
    base = 120 + (pid % (110 // max(lanes, 1))) * lanes
    return [base + i for i in range(lanes)]


def run_jobs(jobs, lanes=2, spawn='fork', on_done=None, fixed_pace=False):
    """Run ``jobs`` (callables ``job(lane)``) on ``lanes`` parallel lanes.

    ``fixed_pace``: a lane keeps its starting pace (its floor is that pace), so a run in
    which a node fell behind does not slow the next ones: how a live graph at a given
    real-time factor fares, run after run.

    Each lane is a thread with its own DDS domain and probe; the longest jobs should
    come first (the caller orders them). ``on_done(index, result)`` is called as each
    job finishes (from the lane's thread, serialised). Returns the results in job order.
    """
    spawner = ForkSpawner(EXECUTABLES + EXTRA_EXECUTABLES) if spawn == 'fork' else None
    todo = queue.Queue()
    for i, job in enumerate(jobs):
        todo.put((i, job))
    results = [None] * len(jobs)
    errors = []
    lock = threading.Lock()

    abort = threading.Event()

    def lane_main(domain_id):
        # The graph needs about three cores per simulated second (CPU per run in the
        # README): two lanes on this 2-core class of machine start at half real time and
        # probe upwards from there (Lane.ceiling).
        start = 1.0 if lanes == 1 else 0.5
        lane = Lane(domain_id, spawner, abort=abort, pace=start, ceiling=start)
        if fixed_pace:
            lane.min_pace = start
        while not errors and not abort.is_set():
            try:
                i, job = todo.get_nowait()
            except queue.Empty:
                return
            try:
                result = job(lane)
            except BaseException as exc:  # noqa: BLE001 — re-raised in the caller
                errors.append(exc)
                return
            with lock:
                results[i] = result
                if on_done:
                    on_done(i, result)

    threads = [threading.Thread(target=lane_main, args=(d,), name=f'lane{d}')
               for d in lane_domains(lanes)]
    for thread in threads:
        thread.start()
    try:
        for thread in threads:
            while thread.is_alive():
                thread.join(0.2)
    except KeyboardInterrupt:
        # Ctrl-C reaches this thread only: stop the lanes' graphs, then give up
        LOG.warning('interrupted: stopping the running scenarios')
        abort.set()
        for thread in threads:
            thread.join()
        raise
    if errors:
        raise errors[0]
    return results
