"""``receivers_benchmark``: the decoder's and the spot locator's per-frame path on rig frames.

Renders fixed sequences of stereo frames with the rig (graph timing, default lamp map,
vibration on): standing 6 m before a lamp, and passing lamps at 60 and 120 km/h; each
with the ideal rig's camera_info and with raw images through ``OpticsTruth.example()``
and their calibration. Every frame goes through each node's own per-frame path
(``VlcDecoderNode._process``, ``SpotLocatorNode._process``: Image messages → arrays →
core → PointCloud2 → publish), in this process, one thread (``cv2.setNumThreads(1)``),
the node's warm-up done, frame after frame as the nodes see them, with their installed
parameter files.

Prints, per node and sequence, the processing time per stereo pair: the core's CPU time,
the core's wall time as the node reports it in its diagnostics, and the CPU time of the
whole ``_process`` (median, p99, max; CPU = this thread's); and a SHA-256 of every
published cloud's bytes per node and sequence (``--hash-only``: one pass, no timing): a
change to the cores that must not change their output keeps every hash.

``--pace``: one frame every camera frame period (``fps`` of the installed
stereo_camera_node.yaml), the thread asleep in between, as in the graph. Back to back, a
frame finds the CPU's caches and branch predictors warm from the one before; after the
graph's ~30 ms idle between frames it does not (on the 2-core machines of this project,
measured 2026-12-07 on the latency bags' frames: 1.6-1.8x the back-to-back CPU per
frame). The paced figures are those the nodes report in the replay; the back-to-back
ones are the code's own cost, for A/B.

``--bag PATH``: the frames of a recorded sensor bag (its stereo images and camera_info,
every frame in stamp order, at most ``--frames``) instead of the rendered sequences,
e.g. the latency replay's ``OUT/latency_bags/sensors_120kmh`` or a real camera's bag;
the spot locator is given ``--bag-speed`` (m/s) as the odometry speed.

Usage::

    receivers_benchmark [--frames 60] [--repeats 3] [--only decoder,spot] [--min-of K]
                        [--hash-only] [--profile N] [--pace] [--bag PATH --bag-speed V]
"""
import argparse
import collections
import copy
import cProfile
import hashlib
import pathlib
import pstats
import time

import cv2
import numpy as np

SEQUENCES = (('standing', 0.0), ('60kmh', 60.0), ('120kmh', 120.0))
NODES = ('decoder', 'spot')


def _camera_info(info):
    from vlc_common.camera_info import camera_info_msg
    return camera_info_msg(info)


def _image(array, stamp_ns, frame_id):
    from sensor_msgs.msg import Image
    msg = Image(height=array.shape[0], width=array.shape[1], encoding='mono8',
                step=array.shape[1], data=array.tobytes())
    msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(stamp_ns, 10**9)
    msg.header.frame_id = frame_id
    return msg


def render_sequence(speed_kmh, frames, raw, seed=7):
    """(camera_info messages, [(stamp_ns, left Image, right Image)], speed m/s)."""
    from vlc_common.core.lamp_map import LampMap, resolve_lamp_map_path
    from vlc_evaluation.benchmarks.spot_locator import graph_timing
    from vlc_stereo_camera.core.optics_truth import OpticsTruth
    from vlc_stereo_camera.core.renderer import RendererConfig, StereoRenderer
    from vlc_stereo_camera.core.trajectory import MotionProfile, Trajectory, Vibration
    lamps = LampMap.load(resolve_lamp_map_path(''))
    config = RendererConfig(optics_truth=OpticsTruth.example() if raw else None,
                            **graph_timing())
    kind = 'constant' if speed_kmh > 0 else 'stationary'
    # standing: the lamp at 50 m 6 m ahead; moving: from 12 m before the lamp at 20 m
    start = 44.0 if speed_kmh <= 0 else 8.0
    trajectory = Trajectory(MotionProfile(kind, start_chainage_m=start,
                                          speed_mps=speed_kmh / 3.6), Vibration(seed=seed))
    renderer = StereoRenderer(config, lamps, trajectory, seed=seed)
    infos = [_camera_info(i) for i in renderer.camera_info_dicts()]
    out = []
    for k in range(frames):
        f = renderer.render(k)
        stamp = int(round(f.t0_s * 1e9))
        out.append((stamp, _image(f.left, stamp, 'camera_left_optical_frame'),
                    _image(f.right, stamp, 'camera_right_optical_frame')))
    return infos, out, speed_kmh / 3.6


class _Capture:
    """Stands in for a node's publisher: keeps the bytes of every published cloud."""

    def __init__(self):
        self.clouds = []

    def publish(self, msg):
        self.clouds.append(bytes(msg.data))


def bag_sequence(path, frames):
    """(camera_info messages, [(stamp_ns, left Image, right Image)]) of a sensor bag: the
    first ``frames`` stereo pairs (both images with one stamp) in stamp order.
    """
    from rclpy.serialization import deserialize_message
    from sensor_msgs.msg import CameraInfo, Image

    from vlc_bags.bagio import iter_raw
    sides = ('/stereo/left/', '/stereo/right/')
    infos, images = [None, None], ({}, {})
    for m in iter_raw(path, [side + t for side in sides for t in ('image_raw', 'camera_info')]):
        side = 0 if m.topic.startswith(sides[0]) else 1
        if m.topic.endswith('camera_info'):
            infos[side] = deserialize_message(bytes(m.data), CameraInfo)
            continue
        msg = deserialize_message(bytes(m.data), Image)
        images[side][msg.header.stamp.sec * 10**9 + msg.header.stamp.nanosec] = msg
    if None in infos:
        raise ValueError(f'{path}: no camera_info on {sides[infos.index(None)]}camera_info')
    stamps = sorted(set(images[0]) & set(images[1]))[:frames]
    if not stamps:
        raise ValueError(f'{path}: no stereo pair (left and right image with one stamp)')
    return infos, [(t, images[0][t], images[1][t]) for t in stamps]


def _decoder_node():
    from vlc_decoder.vlc_decoder_node import VlcDecoderNode
    node = VlcDecoderNode()
    node.pub_lamps = _Capture()
    return node


def _spot_node():
    from spot_locator.spot_locator_node import SpotLocatorNode
    node = SpotLocatorNode()
    node.pub_pairs = _Capture()
    return node


def _timed(core_ms, function):
    """``function`` that appends its thread CPU time (ms) to ``core_ms``."""
    def timed(*args):
        start = time.thread_time()
        try:
            return function(*args)
        finally:
            core_ms.append(1e3 * (time.thread_time() - start))
    return timed


def _fastest(function, min_of):
    """The least CPU time (ms) of ``min_of`` calls of ``function()``: what the code costs
    with the load of a shared machine taken out (its caches warm after the first call).
    """
    best = np.inf
    for _ in range(min_of):
        start = time.thread_time()
        function()
        best = min(best, time.thread_time() - start)
    return 1e3 * best


def _run(frames, process, reported, profile, fastest=None, pace_s=0.0):
    """``process(frame)`` for every frame: (core CPU ms, reported ms, _process CPU ms).
    ``fastest(frame)``, if given, is called before each frame (the min-of-k timing).
    With ``pace_s`` > 0 (``--pace``), frame k is due ``(k + 1)·pace_s`` after the call and
    starts then, or as soon after as the machine allows (a camera's fixed period: a
    frame started late does not delay the next); 0: back to back.
    """
    whole = []
    due = time.monotonic()
    for frame in frames:
        if fastest is not None:
            fastest(frame)
        if pace_s:
            due += pace_s
            time.sleep(max(due - time.monotonic(), 0.0))
        start = time.thread_time()
        if profile is not None:
            profile.enable()
        process(frame)
        if profile is not None:
            profile.disable()
        whole.append(1e3 * (time.thread_time() - start))
    return list(reported)[-len(frames):], whole


def run_decoder(infos, frames, speed_mps, profile=None, min_of=0, fastest_ms=None,
                pace_s=0.0):
    """One fresh decoder node over the frames: (cloud bytes list, core CPU ms, node-reported
    wall ms, _process CPU ms), per frame. ``min_of`` > 0: also the core's least CPU time
    of that many runs on copies of the tracker as the frame found it, into ``fastest_ms``.
    """
    node = _decoder_node()
    for side, info in enumerate(infos):
        for _ in range(3):
            node._on_info(side, info)
    core = []
    tracker_process = node.tracker.process
    node.tracker.process = _timed(core, tracker_process)
    node.proc_ms = collections.deque()

    def fastest(frame):
        from vlc_decoder.conversions import image_to_mono8
        from vlc_decoder.core.tracker import LampTracker
        stamp, left, right = frame
        left, right = image_to_mono8(left), image_to_mono8(right)
        node.tracker.max_disparity_px = node._max_disparity()
        copies = [copy.deepcopy(node.tracker) for _ in range(min_of)]
        # the class's method: a copy's own ``process`` attribute is the timed original's
        fastest_ms.append(_fastest(lambda: LampTracker.process(copies.pop(), stamp, left, right),
                                   min_of))

    reported, whole = _run(frames, lambda f: node._process(*f), node.proc_ms, profile,
                           fastest if min_of else None, pace_s)
    clouds = node.pub_lamps.clouds
    node.destroy_node()
    return clouds, core, reported, whole


def run_spot(infos, frames, speed_mps, profile=None, min_of=0, fastest_ms=None,
             pace_s=0.0):
    """One fresh spot locator node over the frames: as :func:`run_decoder`."""
    node = _spot_node()
    for side, info in enumerate(infos):
        for _ in range(3):
            node._on_info(side, info)
    node._speed = (speed_mps, float('inf'))
    core = []
    locator = node._located[1]
    locator_process = locator.process
    locator.process = _timed(core, locator_process)
    node._proc_ms = collections.deque()

    def fastest(frame):
        from spot_locator.conversions import image_to_array
        left, right = image_to_array(frame[1]), image_to_array(frame[2])
        fastest_ms.append(_fastest(lambda: locator_process(left, right, speed_mps), min_of))

    reported, whole = _run(frames, lambda f: node._process(f[1], f[2]), node._proc_ms,
                           profile, fastest if min_of else None, pace_s)
    clouds = node.pub_pairs.clouds
    node.destroy_node()
    return clouds, core, reported, whole


RUNNERS = {'decoder': run_decoder, 'spot': run_spot}


def _digest(clouds):
    h = hashlib.sha256()
    for c in clouds:
        h.update(len(c).to_bytes(8, 'little'))
        h.update(c)
    return h.hexdigest()[:16]


def _stats(ms):
    a = np.asarray(ms)
    return f'{np.median(a):6.2f} {np.percentile(a, 99):6.2f} {a.max():6.2f}'


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    parser.add_argument('--frames', type=int, default=60, help='frames per sequence')
    parser.add_argument('--repeats', type=int, default=3,
                        help='passes over each sequence (a fresh node each); the timing '
                        'keeps every pass')
    parser.add_argument('--only', default=','.join(NODES), help='decoder, spot or both')
    parser.add_argument('--hash-only', action='store_true', help='one pass, hashes only')
    parser.add_argument('--min-of', type=int, default=0, metavar='K',
                        help='also time each frame\'s core K times (the decoder on copies '
                        'of its tracker) and keep the least CPU time: "fastest", the cost '
                        'of the code itself on a shared machine, for A/B comparisons')
    parser.add_argument('--profile', type=int, default=0,
                        help='print the N most expensive functions (cProfile, cumulative)')
    parser.add_argument('--pace', action='store_true',
                        help='one frame per camera frame period, asleep in between, as '
                        'in the graph (the figures the nodes report in the replay)')
    parser.add_argument('--bag', default='', help='frames of this sensor bag instead of '
                        'the rendered sequences')
    parser.add_argument('--bag-speed', type=float, default=0.0,
                        help='with --bag: the speed (m/s) the spot locator is given')
    args = parser.parse_args(argv)
    if args.pace and args.min_of:
        parser.error('--pace times each frame as the graph does; --min-of would run the '
                     'frame K times back to back before it')
    import rclpy

    from vlc_common.process import keep_large_buffers
    cv2.setNumThreads(1)
    keep_large_buffers()
    from vlc_common.core.config_files import config_path
    # the nodes' installed parameter files, as the graph starts them
    rclpy.init(args=['--ros-args',
                     '--params-file', str(config_path('vlc_decoder', 'vlc_decoder_node.yaml')),
                     '--params-file', str(config_path('spot_locator', 'spot_locator_node.yaml'))])
    nodes = [n.strip() for n in args.only.split(',') if n.strip()]
    repeats = 1 if args.hash_only else args.repeats
    totals = {n: ([], [], [], []) for n in nodes}
    profiles = {n: cProfile.Profile() for n in nodes} if args.profile else {}
    pace_s = 0.0
    if args.pace:
        from vlc_evaluation.benchmarks.spot_locator import graph_timing
        pace_s = 1.0 / graph_timing()['fps']
    sequences = ([(pathlib.Path(args.bag).name, None)] if args.bag
                 else [(f'{name}{" raw" if raw else ""}', (speed_kmh, raw))
                       for raw in (False, True) for name, speed_kmh in SEQUENCES])
    print(f'{args.frames} frames per sequence, {repeats} pass(es), '
          + (f'one frame every {1e3 * pace_s:.1f} ms' if pace_s else 'back to back')
          + '; ms per stereo pair as '
          'median p99 max: core = CPU time of the core (tracker.process, locator.process), '
          'reported = what the node reports in its diagnostics (wall time of the same '
          'call), _process = CPU time of the node\'s whole per-frame path', flush=True)
    for label, rendered in sequences:
        if rendered is None:
            infos, frames = bag_sequence(args.bag, args.frames)
            speed = args.bag_speed
        else:
            infos, frames, speed = render_sequence(rendered[0], args.frames, rendered[1])
        for node in nodes:
            core, reported, whole, fastest, digests = [], [], [], [], set()
            for _ in range(repeats):
                clouds, c, r, w = RUNNERS[node](
                    infos, frames, speed, profiles.get(node),
                    0 if args.hash_only else args.min_of, fastest, pace_s)
                digests.add(_digest(clouds))
                core += c
                reported += r
                whole += w
            for total, part in zip(totals[node], (core, reported, whole, fastest)):
                total.extend(part)
            size = sum(len(c) for c in clouds)
            line = (f'{node:8s} {label:14s} hash {",".join(sorted(digests))} '
                    f'bytes {size:7d}')
            if not args.hash_only:
                line += (f' | core {_stats(core)} | reported {_stats(reported)} | '
                         f'_process {_stats(whole)}')
                if fastest:
                    line += f' | fastest {_stats(fastest)}'
            print(line, flush=True)
    if not args.hash_only:
        for node, (core, reported, whole, fastest) in totals.items():
            print(f'{node:8s} {"all":14s} core {_stats(core)} | reported {_stats(reported)} '
                  f'| _process {_stats(whole)}'
                  + (f' | fastest {_stats(fastest)}' if fastest else ''), flush=True)
    for node, prof in profiles.items():
        print(f'\n### cProfile {node}')
        pstats.Stats(prof).sort_stats('cumulative').print_stats(args.profile)
        pstats.Stats(prof).sort_stats('tottime').print_stats(args.profile)
    rclpy.try_shutdown()


if __name__ == '__main__':
    main()
