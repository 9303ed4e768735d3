"""``localizer_replay``: the localizer core re-run on a recorded bag's inputs, offline.

Reads ``/imu/data``, ``/spots/pairs``, ``/vlc/lamps`` (and ``/ground_truth/pose`` when
present) from a bag in the order they were recorded, feeds them through the same
:class:`~train_localizer.core.join.FrameJoiner` and
:class:`~train_localizer.core.localizer.Localizer` the node uses, with the node's
parameter file plus ``-p name:=value`` overrides, and prints the every-pose error
against the truth. Deterministic and much faster than the graph, so it is how a
localizer change or switch is compared on exactly the same perception output
(ablations of ``use_range_constraint``, ``use_imu_attitude``, ``use_exposure_stamping``,
``use_kalman``).

``--compensator`` re-runs the attitude loop too: the
:class:`~imu_compensator.core.compensator.AttitudeCompensator` (the compensator node's
parameter file, ``-c name:=value`` overrides) on ``/imu/data_raw`` replaces the recorded
``/imu/data``, and every ``attitude_aiding`` message the localizer emits is fused back
through the same conversions as between the two nodes, so a compensator change is
compared on the same perception output as well; it also prints the heading error.
Upstream switches (Wiener, the decoder, the spot locator) need the graph.

Examples::

    localizer_replay out/evaluation/dynamic/dynamic_020kmh_seed1
    localizer_replay BAG -p use_range_constraint:=false --settle-s 3.6 --json
    localizer_replay BAG --compensator -c pull_window_s:=6.0 --settle-s 3.6
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

from imu_compensator.conversions import fill_imu_data, fuse_aiding, imu_sample
from train_localizer import conversions
from train_localizer.core.join import FrameJoiner
from train_localizer.core.localizer import Localizer
from vlc_bags.bagio import open_bag
from vlc_common.core.config_files import config_path
from vlc_common.core.rotations import quat_to_rpy
from vlc_evaluation import metrics

INPUT_TOPICS = ('/imu/data', '/spots/pairs', '/vlc/lamps')
RAW_IMU_TOPIC = '/imu/data_raw'
TRUTH_TOPIC = '/ground_truth/pose'


def default_params_file(package='train_localizer'):
    """A node's parameter file (installed share/, else beside the sources)."""
    return config_path(package, f'{package}_node.yaml')


def load_params(params_file=None, overrides=None):
    """Parameter dict of the node: its declared defaults, its YAML file, then overrides."""
    from train_localizer.train_localizer_node import PARAMETERS
    text = pathlib.Path(params_file or default_params_file()).read_text(encoding='utf-8')
    params = {name: default for name, default, _ in PARAMETERS}
    params.update(yaml.safe_load(text)['/**']['ros__parameters'])
    for name, value in (overrides or {}).items():
        if name not in params:
            raise ValueError(f'unknown parameter {name!r}')
        params[name] = value
    return params


class _Parameters:
    """Just enough of an rclpy node for a node's ``read_config``: the declared
    defaults, then a YAML parameter file's values, then overrides.
    """

    def __init__(self, params_file, overrides=None):
        text = pathlib.Path(params_file).read_text(encoding='utf-8')
        self._values = dict(yaml.safe_load(text)['/**']['ros__parameters'])
        self._overrides = dict(overrides or {})
        self._declared = {}

    def declare_parameter(self, name, default, descriptor=None):
        value = self._overrides.pop(name, self._values.get(name, default))
        self._declared[name] = value

    def get_parameter(self, name):
        return argparse.Namespace(value=self._declared[name])

    def check_overrides(self):
        if self._overrides:
            raise ValueError(f'unknown parameter(s) {sorted(self._overrides)!r}')


class CompensatorLoop:
    """The imu_compensator node's work, offline: ``/imu/data_raw`` in, ``imu/data``
    samples out, ``attitude_aiding`` messages fused back (same conversions as the nodes).

    Parameters
    ----------
    params_file : path, optional
        The compensator node's parameter file (default: its own).
    overrides : dict, optional
        Parameter overrides.
    """

    def __init__(self, params_file=None, overrides=None):
        from sensor_msgs.msg import Imu

        from imu_compensator.core.compensator import AttitudeCompensator
        from imu_compensator.imu_compensator_node import read_config
        source = _Parameters(params_file or default_params_file('imu_compensator'), overrides)
        self.config = cfg = read_config(source)
        source.check_overrides()
        self.compensator = AttitudeCompensator(cfg.compensator)
        fc = cfg.compensator.filter
        self._floor_var = np.square(cfg.orientation_std_floor_rad)
        self._white_var = fc.gyro_noise_density_rps_rthz ** 2 * cfg.compensator.nominal_rate_hz
        self._out = Imu()
        self.heading = []      # (t_s, yaw rad) of every published sample

    def add_raw(self, msg):
        """One ``imu/data_raw`` message; the ``ImuSample`` the localizer gets, or None."""
        t_s, gyro, accel = imu_sample(msg)
        result = self.compensator.process(t_s, gyro, accel)
        if not result.status.accepted:
            return None
        fill_imu_data(self._out, msg.header, result, self._floor_var, self._white_var,
                      np.square(self.compensator.gyro_bias_std_rps),
                      msg.angular_velocity_covariance, msg.linear_acceleration_covariance)
        self.heading.append((t_s, float(quat_to_rpy(result.quat_xyzw)[2])))
        return conversions.imu_from_msg(self._out)

    def add_aids(self, report, map_frame='map'):
        """Fuse the report's attitude aids as the compensator node receives them."""
        for aid in report.attitude_aids:
            fuse_aiding(self.compensator, conversions.attitude_aid_message(aid, map_frame),
                        self.config.heading_aiding_std_rad)


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
    truth_yaw: np.ndarray = None          # (N,) rad, beside truth_t
    heading: np.ndarray = None            # (M, 2) t_s, compensator yaw rad (--compensator)
    localizer: object = None              # the Localizer core as the bag left it
    pose_cov: np.ndarray = None           # (N, 3, 3) map covariance of each pose, m²


def belief_dir(bag):
    """``<bag>.installation/belief`` of a drawn-profile bag (what the receivers were given:
    calibration, vehicle, surveyed map, the stated error model), or None when the bag has
    none (the ideal rig's bags: the shipped files are the belief).
    """
    bag = pathlib.Path(bag)
    belief = bag.parent / (bag.name + '.installation') / 'belief'
    return belief if belief_camera_files(belief)[0].exists() else None


def belief_camera_files(belief):
    """The (left, right) camera_info_manager files of ``belief`` (:func:`belief_dir`)."""
    return [belief / 'left.yaml', belief / 'right.yaml']


def belief_parameters(belief):
    """The localizer parameters the evaluation gave the node with the belief files of
    ``belief`` (:func:`belief_dir`): its lamp map, vehicle and stated error model.
    """
    from vlc_evaluation.runner import read_error_model
    return dict({'lamp_map_path': str(belief / 'lamp_map.yaml'),
                 'vehicle_path': str(belief / 'vehicle.yaml')}, **read_error_model(belief))


def replay_with_belief(bag, overrides=None):
    """:func:`replay` of a drawn-profile bag with the belief files written beside it
    (:func:`belief_dir`) and the node's parameter defaults, ``overrides`` on top.
    """
    belief = belief_dir(bag)
    if belief is None:
        raise FileNotFoundError(f'{bag}: no belief files beside it (<bag>.installation/belief)')
    params = load_params(None, dict(belief_parameters(belief), **(overrides or {})))
    return replay(str(bag), params, camera_info=camera_info_messages(belief_camera_files(belief)))


def camera_info_messages(paths):
    """The two CameraInfo-like objects (fields ``width``, ``height``, ``k``, ``d``, ``r``,
    ``p``, ``distortion_model``) of a stereo calibration file pair (camera_info_manager
    YAML, e.g. an installation's ``belief/left.yaml``, ``belief/right.yaml``), as the
    node receives them on ``stereo/*/camera_info``.
    """
    from types import SimpleNamespace

    from vlc_common.core.calibration import load_stereo_calibration
    calibration = load_stereo_calibration([str(p) for p in paths])
    return [SimpleNamespace(width=int(i['width']), height=int(i['height']),
                            k=np.ravel(i['K']).tolist(), d=np.ravel(i['D']).tolist(),
                            r=np.ravel(i['R']).tolist(), p=np.ravel(i['P']).tolist(),
                            distortion_model=i['distortion_model'])
            for i in calibration.camera_info_dicts()]


def replay(bag, params, compensator=None, camera_info=None):
    """Run the localizer core over a bag's recorded inputs; returns a ReplayResult.

    ``compensator``: a :class:`CompensatorLoop` run on ``/imu/data_raw`` in place of the
    recorded ``/imu/data``, with the localizer's heading aids fed back. ``camera_info``:
    the (left, right) CameraInfo-like pair (:func:`camera_info_messages`) offered to the
    localizer before the first frame, as the node takes the latched camera_info (the
    recorded bags carry none); None = the parameters' intrinsics.
    """
    from train_localizer.train_localizer_node import TrainLocalizerNode  # the node's config builder
    lamp_map, config = TrainLocalizerNode.setup(params)
    joiner = FrameJoiner()
    if camera_info is not None:
        intrinsics = conversions.CameraInfoIntrinsics(config.geometry, True,
                                                      joiner.config)
        for index, msg in enumerate(camera_info):
            outcome = intrinsics.update(index, msg)
            if outcome is not None and outcome[0] == 'warn':
                raise ValueError(f'camera_info: {outcome[1]}')
    loc = Localizer(lamp_map, config)
    poses, covs, truth, status, fix_ms = [], [], [], {}, []
    imu_topic = RAW_IMU_TOPIC if compensator else '/imu/data'

    def take(report):
        for est in report.poses:
            poses.append((est.stamp_ns * 1e-9, *est.position_m, est.position_cov_m2[0, 0]))
            covs.append(est.position_cov_m2)
        for fix in report.fixes:
            status[fix.status] = status.get(fix.status, 0) + 1
        if compensator:
            compensator.add_aids(report, params['map_frame_id'])

    topics = [imu_topic] + list(INPUT_TOPICS[1:]) + [TRUTH_TOPIC]
    for topic, _, received_ns, msg in open_bag(bag, topics=topics):
        if topic == imu_topic:
            sample = compensator.add_raw(msg) if compensator else conversions.imu_from_msg(msg)
            if sample is not None:
                take(loc.add_imu(sample))
        elif topic == TRUTH_TOPIC:
            p, q = msg.pose.position, msg.pose.orientation
            yaw = math.atan2(2.0 * (q.w * q.z + q.x * q.y), 1.0 - 2.0 * (q.y * q.y + q.z * q.z))
            truth.append((conversions.stamp_to_ns(msg.header.stamp) * 1e-9, p.x, p.y, p.z, yaw))
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
    t = np.asarray(truth, dtype=float).reshape(-1, 5)
    order = np.argsort(t[:, 0], kind='stable')
    heading = np.asarray(compensator.heading, float).reshape(-1, 2) if compensator else None
    return ReplayResult(p[:, 0], p[:, 1:4], p[:, 4], t[order, 0], t[order, 1:4], status, fix_ms,
                        np.unwrap(t[order, 4]), heading, loc,
                        np.asarray(covs, dtype=float).reshape(-1, 3, 3))


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
    out = {'poses': int(keep.sum()), 'error': metrics.summarize(err).as_dict(),
           'along_track_3sigma_fraction': (float(np.mean(np.abs(along[ok]) <= 3.0 * sigma[ok]))
                                           if ok.any() else None),
           'fix_status': result.fix_status,
           # every axis inside its 3σ, as the graph's runs are scored
           # (bag_eval.score_run: covariance_3sigma_fraction)
           'covariance_3sigma_fraction': (metrics.covariance_consistency(
               result.pose_xyz[keep] - metrics.interpolate_positions(
                   result.pose_t[keep], result.truth_t, result.truth_xyz),
               result.pose_cov[keep]) if result.pose_cov is not None and keep.any()
               else None),
           'ms_per_fix_median': float(np.median(result.fix_ms)) if result.fix_ms else None}
    if result.heading is not None and result.heading.size:
        t, yaw = result.heading[:, 0], result.heading[:, 1]
        inside = (t >= result.truth_t[0] + settle_s) & (t <= result.truth_t[-1])
        if inside.any():
            err = np.angle(np.exp(1j * (yaw[inside]
                                        - np.interp(t[inside], result.truth_t, result.truth_yaw))))
            out['heading_max_abs_deg'] = float(np.degrees(np.abs(err).max()))
            out['heading_rms_deg'] = float(np.degrees(np.sqrt(np.mean(err ** 2))))
    return out


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
    parser.add_argument('--compensator', action='store_true',
                        help='re-run the attitude compensator on /imu/data_raw, aided by the '
                        "localizer's attitude_aiding, instead of the recorded /imu/data")
    parser.add_argument('-c', dest='compensator_overrides', type=_override, action='append',
                        default=[], help='compensator parameter override name:=value '
                        '(with --compensator; repeatable)')
    parser.add_argument('--compensator-params-file', default='',
                        help="with --compensator; default: the compensator node's own")
    parser.add_argument('--settle-s', type=float, default=0.0,
                        help='leave out poses this long after the first truth stamp')
    parser.add_argument('--camera-info', nargs=2, metavar=('LEFT', 'RIGHT'), default=None,
                        help='camera_info_manager YAML pair the live node would get on '
                        'stereo/*/camera_info (e.g. BAG.installation/belief/left.yaml '
                        'right.yaml): intrinsics, baseline and the raw images\' R from it')
    parser.add_argument('--no-belief', action='store_true',
                        help="a drawn-profile bag's belief files beside it "
                        '(BAG.installation/belief: camera_info, lamp map, vehicle, stated '
                        'error model, as the evaluation gave the node) are used unless '
                        'this is given; -p and --camera-info override them')
    parser.add_argument('--json', action='store_true', help='print JSON instead of text')
    args = parser.parse_args(argv)
    out = {}
    for bag in args.bags:
        belief = None if args.no_belief else belief_dir(bag)
        try:
            params = load_params(args.params_file or None, dict(
                belief_parameters(belief) if belief else {}, **dict(args.overrides)))
        except (OSError, ValueError) as exc:
            parser.error(str(exc))
        if belief is not None and not args.json:
            print(f'{bag}: the receivers\' belief from {belief} (--no-belief: the shipped '
                  'files)')
        loop = None
        if args.compensator:
            try:
                # the localizer's alignment, unless given (the compensator's pulls need it)
                loop = CompensatorLoop(args.compensator_params_file or None,
                                       dict({'alignment': params['alignment']}
                                            if params.get('alignment') else {},
                                            **dict(args.compensator_overrides)))
            except (OSError, ValueError) as exc:
                parser.error(str(exc))
        camera_info = args.camera_info or (belief_camera_files(belief) if belief else None)
        try:
            infos = camera_info_messages(camera_info) if camera_info else None
        except (OSError, ValueError) as exc:
            parser.error(str(exc))
        out[bag] = score(replay(bag, params, loop, infos), args.settle_s)
    if args.json:
        print(json.dumps(out, indent=1))
        return 0
    for bag, s in out.items():
        if not s.get('poses'):
            print(f'{bag}: no scored poses')
            continue
        e = s['error']
        cover, every_axis = s['along_track_3sigma_fraction'], s['covariance_3sigma_fraction']
        print(f'{bag}: {s["poses"]} poses, max {100 * e["max_m"]:.2f} cm, mean '
              f'{100 * e["mean_m"]:.2f} cm, p95 {100 * e["p95_m"]:.2f} cm, 3-sigma along '
              f'{"–" if cover is None else f"{cover:.4f}"} (every axis '
              f'{"–" if every_axis is None else f"{every_axis:.4f}"}), fixes {s["fix_status"]}, '
              f'{s["ms_per_fix_median"] or math.nan:.3f} ms/fix'
              + (f', heading max {s["heading_max_abs_deg"]:.3f} deg rms '
                 f'{s["heading_rms_deg"]:.3f} deg' if 'heading_max_abs_deg' in s else ''))
    return 0


if __name__ == '__main__':
    sys.exit(main())
