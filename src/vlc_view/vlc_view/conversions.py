"""Scene → visualization_msgs/MarkerArray, and the graph's messages → the scene's inputs.

Markers (namespace, id; all in the ``frame_id`` of the node, ``map``), after a
DELETEALL so that nothing of an older scene stays:

* ``lamps`` 0: SPHERE_LIST, one sphere per lamp of the map coloured by state
  (:data:`vlc_view.core.style.LAMP_COLOURS`);
* ``lamp_labels`` i: TEXT_VIEW_FACING, the UID of each lamp identified now or recently;
* ``train`` 0: CUBE, the train head behind base_link; 1: ARROW, base_link's x axis;
* ``along_track_3sigma`` 0: LINE_LIST, the ±3σ bar with end ticks; 1: TEXT, its value;
* ``rays`` 0: LINE_LIST, camera → lamp of the last fix; 1: SPHERE, the left camera;
* ``track`` 0: LINE_STRIP, the positions received so far.
"""
from geometry_msgs.msg import Point, Pose, Quaternion, Vector3
import numpy as np
from std_msgs.msg import ColorRGBA
from visualization_msgs.msg import Marker, MarkerArray

from vlc_common.pointcloud import cloud_to_records
from vlc_common.stamps import stamp_to_ns
from vlc_view.core import style
from vlc_view.core.scene import LAMP_NOT_SEEN


def _colour(rgba):
    return ColorRGBA(r=float(rgba[0]), g=float(rgba[1]), b=float(rgba[2]), a=float(rgba[3]))


def _point(xyz):
    return Point(x=float(xyz[0]), y=float(xyz[1]), z=float(xyz[2]))


def _yaw_quaternion(axis):
    yaw = float(np.arctan2(axis[1], axis[0]))
    return Quaternion(x=0.0, y=0.0, z=float(np.sin(yaw / 2)), w=float(np.cos(yaw / 2)))


def _marker(header, ns, mid, kind, rgba=(1.0, 1.0, 1.0, 1.0), scale=(1.0, 1.0, 1.0)):
    m = Marker(header=header, ns=ns, id=mid, type=kind, action=Marker.ADD)
    m.pose.orientation.w = 1.0
    m.scale = Vector3(x=float(scale[0]), y=float(scale[1]), z=float(scale[2]))
    m.color = _colour(rgba)
    return m


def scene_markers(scene, header, lamp_diameter_m=0.3, ray_max_age_s=1.0):
    """The MarkerArray of a :class:`vlc_view.core.scene.Scene` (see the module docstring).

    ``ray_max_age_s``: rays of a fix older than this (data time, before the scene's newest
    stamp) are left out, s.
    """
    out = [Marker(header=header, action=Marker.DELETEALL)]
    lamps = _marker(header, 'lamps', 0, Marker.SPHERE_LIST, scale=(lamp_diameter_m,) * 3)
    lamps.points = [_point(p) for p in scene.lamp_positions]
    lamps.colors = [_colour(style.LAMP_COLOURS[int(s)]) for s in scene.lamp_states]
    out.append(lamps)
    for i in np.flatnonzero(scene.lamp_states != LAMP_NOT_SEEN):
        label = _marker(header, 'lamp_labels', int(i), Marker.TEXT_VIEW_FACING,
                        style.LAMP_COLOURS[int(scene.lamp_states[i])], (0, 0, 0.25))
        label.pose.position = _point(scene.lamp_positions[i] + [0.0, 0.0, 0.35])
        label.text = f'{int(scene.lamp_uids[i]):#06x}'
        out.append(label)
    if len(scene.history_m) >= 2:
        track = _marker(header, 'track', 0, Marker.LINE_STRIP, style.TRACK_COLOUR,
                        (0.03, 0, 0))
        track.points = [_point(p) for p in scene.history_m]
        out.append(track)
    train = scene.train
    if train is None:
        return MarkerArray(markers=out)
    rot = train.rotation
    body = _marker(header, 'train', 0, Marker.CUBE, style.TRAIN_COLOUR, style.TRAIN_BOX_M)
    centre = train.position_m + rot @ np.array([-style.TRAIN_BOX_M[0] / 2, 0.0,
                                                 style.TRAIN_BOX_M[2] / 2])
    q = train.quat_xyzw
    body.pose = Pose(position=_point(centre), orientation=Quaternion(
        x=float(q[0]), y=float(q[1]), z=float(q[2]), w=float(q[3])))
    arrow = _marker(header, 'train', 1, Marker.ARROW, style.HEADING_COLOUR, (0.08, 0.16, 0.2))
    arrow.points = [_point(train.position_m),
                    _point(train.position_m + style.HEADING_ARROW_M * rot[:, 0])]
    out += [body, arrow]
    if np.isfinite(scene.sigma_along_m):
        half = max(3.0 * scene.sigma_along_m, style.BAR_MIN_HALF_LENGTH_M)
        a = scene.along_axis
        side = np.array([-a[1], a[0], 0.0]) * 0.15
        ends = [train.position_m - half * a, train.position_m + half * a]
        bar = _marker(header, 'along_track_3sigma', 0, Marker.LINE_LIST, style.BAR_COLOUR,
                      (style.BAR_WIDTH_M, 0, 0))
        bar.points = [_point(ends[0]), _point(ends[1])] + [
            _point(e + s) for e in ends for s in (side, -side)]
        text = _marker(header, 'along_track_3sigma', 1, Marker.TEXT_VIEW_FACING,
                       style.BAR_COLOUR, (0, 0, 0.3))
        text.pose.position = _point(train.position_m + [0.0, 0.0, style.TRAIN_BOX_M[2] + 0.4])
        text.text = f'along-track 3σ {300.0 * scene.sigma_along_m:.1f} cm'
        out += [bar, text]
    fresh = scene.stamp_ns - scene.fix_stamp_ns <= ray_max_age_s * 1e9
    if scene.camera_m is not None and len(scene.rays_m) and fresh:
        rays = _marker(header, 'rays', 0, Marker.LINE_LIST, style.RAY_COLOUR,
                       (style.RAY_WIDTH_M, 0, 0))
        rays.points = [_point(p) for seg in scene.rays_m for p in seg]
        camera = _marker(header, 'rays', 1, Marker.SPHERE, style.CAMERA_COLOUR, (0.15,) * 3)
        camera.pose.position = _point(scene.camera_m)
        out += [rays, camera]
    return MarkerArray(markers=out)


def cloud_records(msg):
    """(stamp ns, structured records) of a PointCloud2 of the graph (vlc/lamps,
    spots/pairs).
    """
    return stamp_to_ns(msg.header.stamp), cloud_to_records(msg)


def pose_with_covariance(msg):
    """geometry_msgs/PoseWithCovarianceStamped → (stamp ns, position (3,), quaternion
    (4,) x, y, z, w, covariance (36,)).
    """
    p, q = msg.pose.pose.position, msg.pose.pose.orientation
    return (stamp_to_ns(msg.header.stamp), np.array([p.x, p.y, p.z]),
            np.array([q.x, q.y, q.z, q.w]), np.asarray(msg.pose.covariance, float))
