"""A split-stereo sensor bag as a side-by-side (SBS) UVC camera would have recorded it,
and the replay that shows the SBS input is as accurate as the split one.

    sbs_bag convert bags/sample_80kmh out/sbs_jpeg --encoding jpeg
    sbs_bag compare bags/sample_80kmh --encodings mono8 jpeg --out out/sbs

``convert`` writes a copy of a sensor bag (``stereo/left|right/image_raw`` +
``camera_info``, IMU, ground truth) in which every stereo pair is one SBS frame, left
camera in the left half, as usb_cam or v4l2_camera publish a stereo UVC camera:
``/image_raw`` (sensor_msgs/Image; ``--encoding`` mono8, bgr8, rgb8, yuyv
(``yuv422_yuy2``), uyvy (``yuv422``)) or ``/image_raw/compressed``
(sensor_msgs/CompressedImage, format ``jpeg``; ``--encoding jpeg``). Colour and YUV
frames carry the grey scene with neutral colour (R = G = B, U = V = 128), so their luma
is the split bag's image exactly; JPEG is lossy (``--jpeg-quality``, default 95:
image_transport's default ``jpeg_quality``). The stereo camera_info topics are left out
(a UVC driver has no stereo calibration; ``sbs_splitter_node`` publishes it from a
file): the bag's camera_info is written as calibration files in ``<out>/calibration/``,
``left.yaml`` and ``right.yaml`` (camera_info_manager) and ``stereo.yaml`` (OpenCV
FileStorage). Every other topic is copied as it is, with its timestamps.

``compare`` converts the bag to each encoding and replays the split bag and each SBS
bag through the graph (``bag_player`` → [``sbs_splitter_node``] → decoder, spot locator,
IMU compensator, localizer; :mod:`.scenarios`), and prints every pose's error against the
truth side by side.
"""
import argparse
from dataclasses import replace
import logging
import pathlib
import shutil
import sys

import cv2
import numpy as np

from vlc_bags.bagio import bag_summary, iter_raw
from vlc_bags.split_writer import SplitBagWriter
from vlc_bags.typesupport import jazzy_typestore
from vlc_common.core.calibration import StereoCalibration, save_opencv_stereo, save_ros_stereo
from vlc_common.core.camera import CameraModel

LOG = logging.getLogger(__name__)

STEREO_IMAGES = ('/stereo/left/image_raw', '/stereo/right/image_raw')
STEREO_INFOS = ('/stereo/left/camera_info', '/stereo/right/camera_info')
RAW_TOPIC = '/image_raw'
COMPRESSED_TOPIC = '/image_raw/compressed'
#: --encoding → sensor_msgs/Image encoding (None: CompressedImage JPEG).
ENCODINGS = {'mono8': 'mono8', 'bgr8': 'bgr8', 'rgb8': 'rgb8', 'yuyv': 'yuv422_yuy2',
             'uyvy': 'yuv422', 'jpeg': None}
#: image_transport's default ``jpeg_quality``: what a driver's compressed topic carries
#: unless configured otherwise.
JPEG_QUALITY = 95
CALIBRATION_DIR = 'calibration'
SPLITTER = ('vlc_camera_input', 'sbs_splitter_node')


def encode_frame(grey, encoding, jpeg_quality=JPEG_QUALITY):
    """An SBS grey frame (H, 2·W) uint8 → (data bytes, step, ROS encoding or 'jpeg').

    Colour: R = G = B = grey (BT.601 luma = grey exactly); YUV 4:2:2: Y = grey,
    U = V = 128; JPEG: a colour JPEG of that image (as a colour UVC camera's MJPEG).
    """
    grey = np.ascontiguousarray(grey, dtype=np.uint8)
    if encoding == 'jpeg':
        ok, data = cv2.imencode('.jpg', cv2.cvtColor(grey, cv2.COLOR_GRAY2BGR),
                                [cv2.IMWRITE_JPEG_QUALITY, int(jpeg_quality)])
        if not ok:
            raise ValueError('JPEG encoding failed')
        return data.tobytes(), 0, 'jpeg'
    ros = ENCODINGS[encoding]
    if encoding == 'mono8':
        pixels = grey
    elif encoding in ('bgr8', 'rgb8'):
        pixels = np.repeat(grey[:, :, None], 3, axis=2)
    else:
        chroma = np.full_like(grey, 128)
        pixels = np.stack([grey, chroma] if encoding == 'yuyv' else [chroma, grey], axis=2)
    pixels = np.ascontiguousarray(pixels)
    return pixels.tobytes(), pixels[0].nbytes, ros


def _image_array(msg):
    if msg.encoding != 'mono8':
        raise ValueError(f'split bag images must be mono8, got {msg.encoding!r}')
    return np.asarray(msg.data, dtype=np.uint8)[:msg.step * msg.height].reshape(
        msg.height, msg.step)[:, :msg.width]


def _calibration(infos):
    cams = [CameraModel.from_camera_info({'width': m.width, 'height': m.height,
                                          'distortion_model': m.distortion_model,
                                          'K': m.k, 'D': m.d, 'R': m.r, 'P': m.p})
            for m in infos]
    return StereoCalibration(cams[0], cams[1], camera_name='sbs')


def convert(bag, out, encoding='mono8', jpeg_quality=JPEG_QUALITY, compression='zstd',
            frame_id='camera'):
    """Write the SBS copy of the split sensor bag ``bag`` into ``out`` (must not exist).

    Returns
    -------
    dict
        ``frames`` (SBS frames written), ``topic``, ``encoding``, ``calibration``
        (``{'ros': [left, right], 'opencv': [stereo]}``, paths as str), ``copied``
        (passed-through topics).
    """
    if encoding not in ENCODINGS:
        raise ValueError(f'encoding must be one of {", ".join(ENCODINGS)}, not {encoding!r}')
    bag, out = pathlib.Path(bag), pathlib.Path(out)
    typestore = jazzy_typestore()
    summary = {t.topic: t for t in bag_summary(bag)}
    missing = [t for t in STEREO_IMAGES + STEREO_INFOS if t not in summary]
    if missing:
        raise ValueError(f'{bag}: not a split stereo sensor bag: no {", ".join(missing)}')
    topic = COMPRESSED_TOPIC if encoding == 'jpeg' else RAW_TOPIC
    msgtype = ('sensor_msgs/msg/CompressedImage' if encoding == 'jpeg'
               else 'sensor_msgs/msg/Image')
    types = typestore.types
    copied = [t for t in summary if t not in STEREO_IMAGES + STEREO_INFOS]
    pending = {}            # header stamp → {side: (bag timestamp, image)}
    infos = [None, None]
    frames = 0
    writer = SplitBagWriter(out, compression=compression,
                            custom_data={'timestamp_source': 'header',
                                         'converted_by': 'vlc_evaluation.sbs_bag',
                                         'sbs_encoding': encoding})
    with writer:
        writer.add_topic(topic, msgtype, summary[STEREO_IMAGES[0]].offered_qos)
        for name in copied:
            writer.add_topic(name, summary[name].msgtype, summary[name].offered_qos)
        for name, mtype, timestamp, data in iter_raw(bag):
            if name in STEREO_INFOS:
                side = STEREO_INFOS.index(name)
                if infos[side] is None:
                    infos[side] = typestore.deserialize_cdr(data, mtype)
                continue
            if name not in STEREO_IMAGES:
                writer.write(name, timestamp, data)
                continue
            msg = typestore.deserialize_cdr(data, mtype)
            stamp = (msg.header.stamp.sec, msg.header.stamp.nanosec)
            halves = pending.setdefault(stamp, {})
            halves[STEREO_IMAGES.index(name)] = (timestamp, _image_array(msg))
            if len(halves) < 2:
                continue
            del pending[stamp]
            left, right = halves[0][1], halves[1][1]
            if left.shape != right.shape:
                raise ValueError(f'{bag}: left {left.shape} and right {right.shape} images '
                                 f'of stamp {stamp} differ in size')
            payload, step, ros_encoding = encode_frame(np.hstack([left, right]), encoding,
                                                       jpeg_quality)
            header = types['std_msgs/msg/Header'](
                stamp=types['builtin_interfaces/msg/Time'](sec=stamp[0], nanosec=stamp[1]),
                frame_id=frame_id)
            array = np.frombuffer(payload, dtype=np.uint8)
            if encoding == 'jpeg':
                sbs = types[msgtype](header=header, format='jpeg', data=array)
            else:
                sbs = types[msgtype](header=header, height=left.shape[0],
                                     width=2 * left.shape[1], encoding=ros_encoding,
                                     is_bigendian=0, step=step, data=array)
            writer.write(topic, max(halves[0][0], halves[1][0]),
                         typestore.serialize_cdr(sbs, msgtype))
            frames += 1
    if pending:
        LOG.warning('%s: %d image(s) without their stereo partner left out', bag,
                    sum(len(h) for h in pending.values()))
    if None in infos:
        raise ValueError(f'{bag}: no camera_info message on {STEREO_INFOS[infos.index(None)]}')
    calibration = _calibration(infos)
    folder = out / CALIBRATION_DIR
    folder.mkdir()
    ros = [folder / 'left.yaml', folder / 'right.yaml']
    save_ros_stereo(calibration, *ros)
    opencv = folder / 'stereo.yaml'
    save_opencv_stereo(calibration, opencv)
    return {'frames': frames, 'topic': topic, 'encoding': encoding,
            'calibration': {'ros': [str(p) for p in ros], 'opencv': [str(opencv)]},
            'copied': copied}


def calibration_files(sbs_bag, form='ros'):
    """The calibration files :func:`convert` wrote beside ``sbs_bag`` (``ros``: left and
    right camera_info YAML, ``opencv``: the FileStorage file).
    """
    folder = pathlib.Path(sbs_bag) / CALIBRATION_DIR
    names = ['left.yaml', 'right.yaml'] if form == 'ros' else ['stereo.yaml']
    return [str(folder / name) for name in names]


def sbs_replay_scenario(sbs_bag, realtime_factor=1.0, calibration_form='ros',
                        lean_recording=False):
    """A replay scenario of an SBS bag: ``bag_player`` plays its ``/image_raw`` (or
    ``/image_raw/compressed``), ``sbs_splitter_node`` splits it with the bag's
    calibration files, and the processing nodes run as for a split bag.
    """
    from vlc_evaluation.scenarios import replay_scenario
    sbs_bag = pathlib.Path(sbs_bag)
    topics = {t.topic for t in bag_summary(sbs_bag)}
    compressed = COMPRESSED_TOPIC in topics
    scenario = replay_scenario(sbs_bag, realtime_factor, lean_recording=lean_recording)
    return replace(scenario, extra_nodes=[[*SPLITTER, ['sbs_splitter_node.yaml']]],
                   node_params={SPLITTER[1]: {
                       'input': 'compressed' if compressed else 'raw',
                       'calibration_files': calibration_files(sbs_bag, calibration_form)}},
                   extra_subscriptions={COMPRESSED_TOPIC if compressed else RAW_TOPIC: 1})


def compare(bag, out_dir, encodings=('mono8', 'jpeg'), realtime_factor=0.25, lanes=2,
            jpeg_quality=JPEG_QUALITY, retries=1):
    """Replay the split ``bag`` and its SBS copies through the graph and score them.

    Returns ``{group: result}`` for group ``split`` and ``sbs_<encoding>``: the
    :func:`.scenarios.score_replay` result (every pose from the run's own first pose) plus
    ``frames`` (:func:`frames_processed`) and ``common`` (:func:`score_common_window`). The
    SBS bags and the recordings are kept in ``out_dir``.
    """
    from vlc_common.core.lamp_map import LampMap, default_lamp_map_path
    from vlc_evaluation import scenarios
    out_dir = pathlib.Path(out_dir)
    groups = {'split': [scenarios.replay_scenario(bag, realtime_factor)]}
    for encoding in encodings:
        sbs_bag = out_dir / 'sbs_bags' / f'{pathlib.Path(bag).name}_sbs_{encoding}'
        shutil.rmtree(sbs_bag, ignore_errors=True)
        sbs_bag.parent.mkdir(parents=True, exist_ok=True)
        convert(bag, sbs_bag, encoding, jpeg_quality)
        groups[f'sbs_{encoding}'] = [sbs_replay_scenario(sbs_bag, realtime_factor)]
    lamp_map = LampMap.load(default_lamp_map_path())
    results = scenarios.run_protocols(groups, out_dir, lamp_map, lanes=lanes,
                                      retries=retries)
    out = {group: found[0] for group, found in results.items()}
    recordings = {group: out_dir / group / r['scenario']['name'] for group, r in out.items()}
    common = score_common_window(recordings, lamp_map)
    for group, result in out.items():
        result['frames'] = frames_processed(recordings[group])
        result['common'] = common[group]
    return out


def score_common_window(recordings, lamp_map):
    """Every pose of each recorded replay from the latest first pose of them all on.

    The graph's cold start (first fix, attitude from the IMU) depends on when each IMU
    sample reaches the localizer relative to the frames, which varies from run to run by
    a few frames; scoring every run over the same stretch of the bag compares the inputs,
    not the start-ups. Returns ``{group: {'from_s', 'poses', 'max_m', 'mean_m',
    'along_max_m'}}`` (from_s: after the bag's first truth).
    """
    from vlc_evaluation.bag_eval import load_run, score_run
    runs = {group: load_run(path) for group, path in recordings.items()}
    starts = [run.pose_t[0] - run.truth_t[0] for run in runs.values()
              if run.pose_t.size and run.truth_t.size]
    settle = max(starts) if starts else 0.0
    out = {}
    for group, run in runs.items():
        if not (run.pose_t.size and run.truth_t.size):
            out[group] = {'from_s': settle, 'poses': 0}
            continue
        scores = score_run(run, lamp_map.positions[:, 0], settle_s=settle)
        out[group] = {'from_s': float(settle), 'poses': scores['poses'],
                      'max_m': scores['every_pose']['max_m'],
                      'mean_m': scores['every_pose']['mean_m'],
                      'along_max_m': scores['every_pose_along_track']['max_m']}
    return out


def frames_processed(recording):
    """Frames each image node reported at its last diagnostics in a recorded replay:
    ``split`` (sbs_splitter_node; None without it), ``decoded`` (decoder), ``located``
    (spot locator). The last report may precede the last frames by up to a diagnostics
    period.
    """
    from vlc_evaluation.bag_eval import _diag_values, load_run
    run = load_run(recording)
    out = {}
    for key, node, field in (('split', 'sbs_splitter_node', 'frames_split'),
                             ('decoded', 'vlc_decoder', 'frames_decoded'),
                             ('located', 'spot_locator_node', 'frames')):
        values = _diag_values(run, node, field)
        out[key] = int(values[-1]) if values else None
    return out


def comparison_table(results):
    """Markdown table of :func:`compare`'s results (errors in mm)."""
    lines = ['| input | first pose (s) | poses | every pose: max (mm) | mean (mm) | '
             'common stretch: poses | max (mm) | mean (mm) | along track max (mm) | '
             'lamps confirmed | wrong UIDs | frames split / decoded / located | '
             'real-time factor |',
             '|---|---|---|---|---|---|---|---|---|---|---|---|---|']

    def mm(d, key):
        return f'{1e3 * d[key]:.2f}' if d.get(key) is not None else '–'
    for group, r in results.items():
        every = r.get('every_pose') or {}
        common = r.get('common') or {}
        ident = r.get('identification') or {}
        first = ident.get('first_confirmation_m') or {}
        frames = r.get('frames') or {}
        counts = ' / '.join('–' if frames.get(k) is None else str(frames[k])
                            for k in ('split', 'decoded', 'located'))
        first_pose = r.get('first_pose_s')
        lines.append(f'| {group} | {"–" if first_pose is None else f"{first_pose:.3f}"} | '
                     f'{r.get("poses", 0)} | {mm(every, "max_m")} | {mm(every, "mean_m")} | '
                     f'{common.get("poses", 0)} | {mm(common, "max_m")} | '
                     f'{mm(common, "mean_m")} | {mm(common, "along_max_m")} | '
                     f'{sum(v is not None for v in first.values())} | '
                     f'{ident.get("wrong_uids", "–")} | {counts} | '
                     f'{r["scenario"]["realtime_factor"]} |')
    if results:
        start = next(iter(results.values())).get('common', {}).get('from_s')
        if start is not None:
            lines.append(f'\nCommon stretch: every pose from {start:.3f} s after the first '
                         'truth (the latest first pose of the runs) to the end.')
    return '\n'.join(lines)


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    sub = parser.add_subparsers(dest='command', required=True)
    conv = sub.add_parser('convert', help='write the SBS copy of a split sensor bag')
    conv.add_argument('bag', help='split stereo sensor bag (e.g. bags/sample_80kmh)')
    conv.add_argument('out', help='SBS bag folder to create')
    conv.add_argument('--encoding', choices=list(ENCODINGS), default='mono8')
    conv.add_argument('--jpeg-quality', type=int, default=JPEG_QUALITY)
    conv.add_argument('--compression', choices=['zstd', 'none'], default='zstd',
                      help='MCAP chunk compression')
    conv.add_argument('--frame-id', default='camera', help='header.frame_id of the frames')
    conv.add_argument('--force', action='store_true', help='replace an existing OUT')
    comp = sub.add_parser('compare', help='replay the split bag and its SBS copies through '
                                          'the graph and compare the errors')
    comp.add_argument('bag', help='split stereo sensor bag')
    comp.add_argument('--encodings', nargs='+', choices=list(ENCODINGS),
                      default=['mono8', 'jpeg'])
    comp.add_argument('--jpeg-quality', type=int, default=JPEG_QUALITY)
    comp.add_argument('--out', default='out/sbs', help='folder for the bags and recordings')
    comp.add_argument('--realtime-factor', type=float, default=0.25,
                      help='requested replay pace (each of two lanes starts at half of it)')
    comp.add_argument('--lanes', type=int, default=2)
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format='%(levelname)s %(name)s: %(message)s')
    if args.command == 'convert':
        out = pathlib.Path(args.out)
        if args.force and out.exists():
            shutil.rmtree(out)
        try:
            done = convert(args.bag, out, args.encoding, args.jpeg_quality, args.compression,
                           args.frame_id)
        except (ValueError, OSError) as exc:
            print(f'sbs_bag: error: {exc}', file=sys.stderr)
            return 2
        print(f'{out}: {done["frames"]} SBS frames on {done["topic"]} ({args.encoding}); '
              f'copied {", ".join(done["copied"])}')
        print('calibration: ' + ' '.join(done['calibration']['ros'] +
                                         done['calibration']['opencv']))
        return 0
    results = compare(args.bag, args.out, args.encodings, args.realtime_factor, args.lanes,
                      args.jpeg_quality)
    print(comparison_table(results))
    return 0


if __name__ == '__main__':
    sys.exit(main())
