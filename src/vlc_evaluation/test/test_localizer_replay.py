"""localizer_replay: the localizer core (and the attitude loop) re-run offline on a bag."""
from geometry_msgs.msg import PoseStamped
import pytest
from rclpy.serialization import serialize_message

from vlc_bags.bagio import write_bag
from vlc_common.core.rotations import quat_from_rpy
from vlc_common.stamps import header
from vlc_evaluation import localizer_replay as replay
from vlc_stereo_camera.core.upstream import constant_speed_run, from_stamp_ns
from vlc_stereo_camera.upstream_messages import imu_msg, lamps_msg, spots_msg


def test_localizer_replay_reruns_the_core_on_a_bag_offline(tmp_path):
    """localizer_replay reads the inputs a graph recorded and scores the core's poses."""
    traj, events = constant_speed_run(60.0, 1.5, seed=22)
    msgs = []
    for arrival_s, kind, payload in events:
        t_ns = int(round(arrival_s * 1e9))
        if kind == 'imu':
            # the same samples as the compensator's input (it ignores the orientation)
            for topic in ('/imu/data', '/imu/data_raw'):
                msgs.append((topic, 'sensor_msgs/msg/Imu', t_ns,
                             serialize_message(imu_msg(payload))))
            continue
        stamp, observations, _ = payload
        msgs.append(('/spots/pairs', 'sensor_msgs/msg/PointCloud2', t_ns,
                     serialize_message(spots_msg(stamp, observations))))
        msgs.append(('/vlc/lamps', 'sensor_msgs/msg/PointCloud2', t_ns + 1000,
                     serialize_message(lamps_msg(stamp, observations))))
        truth = PoseStamped(header=header(stamp, 'map'))
        state = traj.sample(from_stamp_ns(stamp))
        p = state.position_m.reshape(-1)
        truth.pose.position.x, truth.pose.position.y, truth.pose.position.z = map(float, p)
        o = truth.pose.orientation
        o.x, o.y, o.z, o.w = map(float, quat_from_rpy(*state.rpy_rad.reshape(-1)))
        msgs.append(('/ground_truth/pose', 'geometry_msgs/msg/PoseStamped', t_ns,
                     serialize_message(truth)))
    msgs.sort(key=lambda m: m[2])
    bag = tmp_path / 'run'
    write_bag(bag, msgs)
    result = replay.replay(bag, replay.load_params())
    scores = replay.score(result)
    assert scores['poses'] > 30
    assert scores['error']['max_m'] < 0.06
    assert scores['fix_status'].get('accepted', 0) > 10
    # a switch changes what runs: raw single-frame fixes only with use_kalman off
    raw = replay.replay(bag, replay.load_params(overrides={'use_kalman': False}))
    assert raw.pose_t.size and raw.pose_t.size != result.pose_t.size
    with pytest.raises(ValueError):
        replay.load_params(overrides={'no_such_parameter': 1})
    # --compensator: the attitude loop re-run on /imu/data_raw, the localizer's aids fed
    # back (an ideal gyro here: the cold start's heading comes from the lamps)
    loop = replay.CompensatorLoop()
    closed = replay.score(replay.replay(bag, replay.load_params(), loop), settle_s=0.5)
    assert loop.compensator.stats.accepted > 400 and loop.compensator.stats.aiding_used > 2
    assert closed['poses'] > 30 and closed['error']['max_m'] < 0.06
    assert closed['heading_max_abs_deg'] < 0.5
    # no aiding: the cold start keeps the heading it guessed (the track's), off by the sway
    blind = replay.score(replay.replay(bag, replay.load_params(
        overrides={'attitude_aiding_period_s': 0.0}), replay.CompensatorLoop()), settle_s=0.5)
    assert blind['heading_max_abs_deg'] > closed['heading_max_abs_deg']
    with pytest.raises(ValueError):
        replay.CompensatorLoop(overrides={'no_such_parameter': 1})


def test_the_cli_gives_a_drawn_bag_the_receivers_belief_unless_told_not(tmp_path,
                                                                        monkeypatch, capsys):
    """A drawn-profile bag replayed with the shipped files is metres off (another
    calibration, map and vehicle than the node had): the CLI takes the belief files
    beside the bag, as the evaluation gave them to the node; -p overrides them,
    --no-belief and a bag without them keep the shipped files.
    """
    bag = tmp_path / 'dynamic_120kmh_seed43'
    belief = tmp_path / 'dynamic_120kmh_seed43.installation' / 'belief'
    belief.mkdir(parents=True)
    (belief / 'left.yaml').write_text('x')
    (belief / 'train_localizer_node.yaml').write_text(
        "/**:\n  ros__parameters:\n    calibration_disparity_sigma_px: 0.7\n")
    assert replay.belief_dir(bag) == belief
    assert replay.belief_dir(tmp_path / 'ideal_bag') is None
    seen = []
    monkeypatch.setattr(replay, 'camera_info_messages', lambda paths: list(paths))
    monkeypatch.setattr(replay, 'replay', lambda b, params, loop, infos:
                        seen.append((params, infos)))
    monkeypatch.setattr(replay, 'score', lambda result, settle_s: {})
    replay.main([str(bag), '-p', 'vehicle_path:=/given.yaml'])
    params, infos = seen[-1]
    assert params['lamp_map_path'] == str(belief / 'lamp_map.yaml')
    assert params['vehicle_path'] == '/given.yaml'
    assert params['calibration_disparity_sigma_px'] == 0.7
    assert infos == [belief / 'left.yaml', belief / 'right.yaml']
    assert 'belief' in capsys.readouterr().out
    replay.main([str(bag), '--no-belief'])
    params, infos = seen[-1]
    assert params['lamp_map_path'] == replay.load_params()['lamp_map_path'] and infos is None
