"""The view's scene without ROS: lamp states from vlc/lamps, the along-track 3σ from the
pose covariance, the rays of the last fix from spots/pairs joined to the lamp records,
and the markers that draw them.
"""
from geometry_msgs.msg import Point
import numpy as np
import pytest
from std_msgs.msg import Header
from visualization_msgs.msg import Marker

from vlc_common.core.lamp_map import LampMap, default_lamp_map_path
from vlc_common.core.records import LAMP_DTYPE, PAIR_DTYPE
from vlc_common.core.rotations import quat_from_rpy, quat_to_matrix
from vlc_common.core.vehicle import CameraMount
from vlc_view.conversions import scene_markers
from vlc_view.core import style
from vlc_view.core.scene import (
    LAMP_IDENTIFIED_NOW,
    LAMP_NOT_SEEN,
    LAMP_SEEN_RECENTLY,
    TrainPose,
    ViewState,
    along_track,
)

LAMP_MAP = LampMap.load(default_lamp_map_path())
S = 10 ** 9


def lamps(*entries):
    """vlc/lamps records: (uid, state, left_u, left_v) each."""
    out = np.zeros(len(entries), dtype=LAMP_DTYPE)
    for i, (uid, state, u, v) in enumerate(entries):
        out[i]['uid'], out[i]['state'] = uid, state
        out[i]['left_u'], out[i]['left_v'] = u, v
    return out


def pairs(*uv):
    out = np.zeros(len(uv), dtype=PAIR_DTYPE)
    for i, (u, v) in enumerate(uv):
        out[i]['u_left'], out[i]['v_left'] = u, v
        out[i]['u_right'], out[i]['disparity'] = u - 30.0, 30.0
    return out


def state(recent_s=5.0):
    return ViewState(LAMP_MAP, CameraMount(position_m=[0.0, 0.8, 2.9]), recent_s=recent_s)


def index(uid):
    return [lamp.uid for lamp in LAMP_MAP.lamps].index(uid)


def test_lamp_states_identified_now_recently_not_seen():
    view = state(recent_s=2.0)
    view.add_lamps(1 * S, lamps((0x1001, 2, 100, 100)))
    view.add_lamps(2 * S, lamps((0x1002, 2, 100, 100), (0x1003, 1, 300, 300)))
    view.add_lamps(3 * S + 1, lamps((0x1003, 2, 200, 200), (0x1004, 0, 400, 400)))
    states = view.scene().lamp_states
    assert states[index(0x1003)] == LAMP_IDENTIFIED_NOW
    assert states[index(0x1002)] == LAMP_SEEN_RECENTLY       # 1 s before the newest
    assert states[index(0x1001)] == LAMP_NOT_SEEN            # 2 s + 1 ns before it
    assert states[index(0x1004)] == LAMP_NOT_SEEN            # searching: no UID
    assert (states == LAMP_NOT_SEEN).sum() == len(LAMP_MAP) - 2
    # an older frame arriving late does not change what is identified now
    view.add_lamps(2 * S + 5, lamps((0x1005, 2, 100, 100)))
    states = view.scene().lamp_states
    assert states[index(0x1003)] == LAMP_IDENTIFIED_NOW
    assert states[index(0x1005)] == LAMP_SEEN_RECENTLY


def test_along_track_sigma_is_the_covariance_along_the_horizontal_heading():
    yaw = np.radians(30.0)
    cov = np.zeros((6, 6))
    cov[:3, :3] = np.diag([0.02 ** 2, 0.01 ** 2, 0.5 ** 2])
    pose = TrainPose(0, np.zeros(3), quat_from_rpy(0.0, np.radians(10.0), yaw), cov)
    axis, sigma = along_track(pose)
    assert axis == pytest.approx([np.cos(yaw), np.sin(yaw), 0.0])
    want = np.sqrt((0.02 * np.cos(yaw)) ** 2 + (0.01 * np.sin(yaw)) ** 2)
    assert sigma == pytest.approx(want)               # the pitch and var z do not enter


def test_rays_go_from_the_left_camera_to_the_lamps_of_the_last_fix():
    view = state()
    quat = quat_from_rpy(0.0, 0.0, np.radians(2.0))
    cov = np.diag([0.01 ** 2] * 3 + [1e-4] * 3)
    for k in range(5):                                   # 50 Hz poses around the frame
        view.add_pose(int(2.00 * S) + k * 20_000_000, [44.0 + 0.1 * k, 0.0, 0.0], quat, cov)
    frame = int(2.04 * S)
    view.add_pairs(frame, pairs((600.0, 300.0), (1000.0, 200.0)))
    view.add_lamps(frame, lamps((0x1005, 2, 603.0, 298.0), (0x1006, 1, 1001.0, 201.0)))
    scene = view.scene()
    R = quat_to_matrix(quat)
    camera = np.array([44.2, 0.0, 0.0]) + R @ [0.0, 0.8, 2.9]     # the pose at 2.04 s
    assert scene.fix_stamp_ns == frame and scene.ray_uids == [0x1005]
    assert scene.camera_m == pytest.approx(camera)
    assert scene.rays_m.shape == (1, 2, 3)
    assert scene.rays_m[0, 1] == pytest.approx(LAMP_MAP.by_uid(0x1005).position_m)
    assert scene.train.stamp_ns == int(2.08 * S)                   # the newest pose
    assert scene.sigma_along_m == pytest.approx(0.01)
    assert scene.bar_m[1] - scene.bar_m[0] == pytest.approx(
        6 * 0.01 * np.array([np.cos(np.radians(2)), np.sin(np.radians(2)), 0.0]))
    # a newer frame without a confirmed lamp keeps the last fix's rays
    view.add_pairs(frame + 33_333_333, pairs((700.0, 300.0)))
    view.add_lamps(frame + 33_333_333, lamps((0x1006, 1, 701.0, 300.0)))
    assert view.scene().ray_uids == [0x1005]
    # and a spot pair far from the decoder's spot is not joined to its UID
    view.add_pairs(frame + 66_666_667, pairs((100.0, 100.0)))
    view.add_lamps(frame + 66_666_667, lamps((0x1006, 2, 700.0, 300.0)))
    assert view.scene().fix_stamp_ns == frame


def test_markers_draw_the_scene_and_leave_stale_rays_out():
    view = state()
    view.add_pose(int(2.0 * S), [44.0, 0.0, 0.0], [0.0, 0.0, 0.0, 1.0],
                  np.diag([0.02 ** 2] * 3 + [1e-4] * 3))
    view.add_pairs(int(2.0 * S), pairs((600.0, 300.0)))
    view.add_lamps(int(2.0 * S), lamps((0x1005, 2, 600.0, 300.0)))
    view.add_lamps(int(1.0 * S), lamps((0x1004, 2, 600.0, 300.0)))
    markers = scene_markers(view.scene(), Header(frame_id='map'), lamp_diameter_m=0.3).markers
    assert markers[0].action == Marker.DELETEALL
    by = {(m.ns, m.id): m for m in markers[1:]}
    assert all(m.header.frame_id == 'map' for m in markers)
    spheres = by[('lamps', 0)]
    assert spheres.type == Marker.SPHERE_LIST and len(spheres.points) == len(LAMP_MAP)
    green = spheres.colors[index(0x1005)]
    assert (green.r, green.g, green.b) == pytest.approx(
        style.LAMP_COLOURS[LAMP_IDENTIFIED_NOW][:3])
    amber = spheres.colors[index(0x1004)]
    assert (amber.r, amber.g) == pytest.approx(style.LAMP_COLOURS[LAMP_SEEN_RECENTLY][:2])
    labels = sorted(m.text for (ns, _), m in by.items() if ns == 'lamp_labels')
    assert labels == ['0x1004', '0x1005']
    bar = by[('along_track_3sigma', 0)]
    assert bar.points[0].x == pytest.approx(44.0 - 0.06)
    assert bar.points[1].x == pytest.approx(44.0 + 0.06)
    assert by[('along_track_3sigma', 1)].text == 'along-track 3σ 6.0 cm'
    rays = by[('rays', 0)]
    assert rays.type == Marker.LINE_LIST and len(rays.points) == 2
    assert rays.points[1] == Point(x=50.0, y=2.5, z=1.4)
    assert by[('train', 0)].type == Marker.CUBE and by[('train', 1)].type == Marker.ARROW
    # a pose 2 s after the fix: its rays are stale
    view.add_pose(int(4.0 * S), [88.0, 0.0, 0.0], [0.0, 0.0, 0.0, 1.0], np.eye(6) * 1e-4)
    stale = scene_markers(view.scene(), Header(frame_id='map'), ray_max_age_s=1.0).markers
    assert not any(m.ns == 'rays' for m in stale)
    assert any(m.ns == 'track' and len(m.points) == 2 for m in stale)
