"""What the view shows, from the graph's own records: one definition for the markers and
for the pictures drawn from a bag.

* **Lamps** of the lamp map, each in one of three states from ``vlc/lamps``: identified
  now (its UID confirmed in the newest frame), seen recently (confirmed within
  ``recent_s`` of the newest frame's stamp), not seen. Searching and partial spots carry
  no UID and colour no lamp.
* **The train**: ``base_link`` of ``train/pose_with_covariance`` (the newest), and its
  along-track 3σ bar: ±3·sqrt(aᵀΣa) about the position along a, the horizontal direction
  of base_link's x axis (Σ: the position block of the covariance).
* **Rays of the last fix** (the newest frame with at least one such lamp): from the
  left camera's optical centre (base_link pose ∘ the vehicle file's camera mount, with
  the pose nearest the frame's stamp) to the map position of each lamp of that frame
  whose spot pair (``spots/pairs``) the decoder's confirmed UID was joined to (the
  localizer's join, :func:`train_localizer.core.join.join_frame`): the lamps the
  localizer fixes on. Lamps it uses unconfirmed (as the lamp the map predicts) are not
  drawn.

Times are data stamps (ns), not receive times, so a replayed bag looks as it did live.
"""
from collections import deque
from dataclasses import dataclass, field

import numpy as np

from train_localizer.core.join import JoinConfig, join_frame
from vlc_common.core.rotations import quat_to_matrix

LAMP_NOT_SEEN, LAMP_SEEN_RECENTLY, LAMP_IDENTIFIED_NOW = 0, 1, 2
LAMP_STATE_NAMES = {LAMP_NOT_SEEN: 'not seen', LAMP_SEEN_RECENTLY: 'seen recently',
                    LAMP_IDENTIFIED_NOW: 'identified now'}
#: vlc/lamps ``state`` of a confirmed UID of the lamp map.
_CONFIRMED = 2


@dataclass
class TrainPose:
    """``base_link`` in the map: stamp (ns), position (3,) m, quaternion (4,) x, y, z, w,
    covariance (6, 6) of x, y, z (m²) and the rotations (rad²).
    """

    stamp_ns: int
    position_m: np.ndarray
    quat_xyzw: np.ndarray
    covariance: np.ndarray

    @property
    def rotation(self):
        """(3, 3): base_link axes in the map."""
        return quat_to_matrix(self.quat_xyzw)


@dataclass
class Scene:
    """One picture's worth of the view (see the module docstring).

    Attributes
    ----------
    stamp_ns : int
        Newest data stamp the scene holds, ns (0: none yet).
    lamp_positions : ndarray, shape (N, 3)
        Lamp disc centres in the map, m.
    lamp_uids : ndarray, shape (N,)
    lamp_states : ndarray, shape (N,)
        ``LAMP_NOT_SEEN``, ``LAMP_SEEN_RECENTLY`` or ``LAMP_IDENTIFIED_NOW``.
    train : TrainPose or None
    along_axis : ndarray, shape (3,)
        Unit along-track direction at the train (horizontal base_link x).
    sigma_along_m : float
        Along-track 1σ of the position, m (NaN without a pose).
    bar_m : ndarray, shape (2, 3)
        Ends of the ±3σ along-track bar, m.
    camera_m : ndarray, shape (3,) or None
        Left camera optical centre of the last fix, m.
    rays_m : ndarray, shape (K, 2, 3)
        Camera → lamp segments of the last fix, m.
    ray_uids : list of int
    fix_stamp_ns : int
        Stamp of the frame the rays belong to (0: none).
    history_m : ndarray, shape (M, 3)
        The train positions received so far (oldest first), m.
    """

    stamp_ns: int
    lamp_positions: np.ndarray
    lamp_uids: np.ndarray
    lamp_states: np.ndarray
    train: TrainPose = None
    along_axis: np.ndarray = field(default_factory=lambda: np.array([1.0, 0.0, 0.0]))
    sigma_along_m: float = float('nan')
    bar_m: np.ndarray = field(default_factory=lambda: np.full((2, 3), np.nan))
    camera_m: np.ndarray = None
    rays_m: np.ndarray = field(default_factory=lambda: np.zeros((0, 2, 3)))
    ray_uids: list = field(default_factory=list)
    fix_stamp_ns: int = 0
    history_m: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))


def along_track(pose):
    """(unit along-track direction (3,), along-track 1σ in m) of a :class:`TrainPose`:
    base_link's x axis made horizontal, and sqrt(aᵀ Σ_xyz a).
    """
    x_axis = pose.rotation[:, 0]
    a = np.array([x_axis[0], x_axis[1], 0.0])
    norm = np.linalg.norm(a)
    a = a / norm if norm > 1e-9 else np.array([1.0, 0.0, 0.0])
    cov = np.asarray(pose.covariance, float).reshape(6, 6)[:3, :3]
    var = float(a @ cov @ a)
    return a, float(np.sqrt(var)) if var >= 0.0 else float('nan')


class ViewState:
    """The records received so far, reduced to what :meth:`scene` draws.

    Parameters
    ----------
    lamp_map : vlc_common.core.lamp_map.LampMap
    camera_mount : vlc_common.core.vehicle.CameraMount
        The left camera's optical centre on base_link (``position_m``).
    recent_s : float
        A lamp identified within this long before the newest frame is "seen recently", s.
    history : int
        Train positions kept for the track drawn behind the train.
    join_config : train_localizer.core.join.JoinConfig, optional
        How spot pairs and lamp records are joined (the localizer's defaults).
    """

    def __init__(self, lamp_map, camera_mount, recent_s=5.0, history=2000, join_config=None):
        self.lamp_map = lamp_map
        self.camera_offset_m = np.asarray(camera_mount.position_m, float)
        self.recent_ns = int(round(recent_s * 1e9))
        self.join_config = join_config or JoinConfig()
        self._index = {lamp.uid: i for i, lamp in enumerate(lamp_map.lamps)}
        self._last_identified_ns = np.full(len(lamp_map), -1, dtype=np.int64)
        self._newest_lamps_ns = None
        self._identified_now = set()
        self._frames = {}                  # stamp → {'lamps': records, 'pairs': records}
        self._fix = (0, [])                # (stamp_ns, uids of the lamps fixed on)
        self._poses = deque(maxlen=max(int(history), 2))

    # ------------------------------------------------------------------ input
    def add_lamps(self, stamp_ns, records):
        """One ``vlc/lamps`` frame (``LAMP_DTYPE`` records) stamped ``stamp_ns``."""
        stamp_ns = int(stamp_ns)
        confirmed = set()
        if records is not None and records.size:
            for uid, state in zip(records['uid'], records['state']):
                if int(state) == _CONFIRMED and int(uid) in self._index:
                    confirmed.add(int(uid))
        for uid in confirmed:
            i = self._index[uid]
            self._last_identified_ns[i] = max(self._last_identified_ns[i], stamp_ns)
        if self._newest_lamps_ns is None or stamp_ns >= self._newest_lamps_ns:
            self._newest_lamps_ns = stamp_ns
            self._identified_now = confirmed
        self._add_frame(stamp_ns, 'lamps', records)

    def add_pairs(self, stamp_ns, records):
        """One ``spots/pairs`` frame (``PAIR_DTYPE`` records) stamped ``stamp_ns``."""
        self._add_frame(int(stamp_ns), 'pairs', records)

    def add_pose(self, stamp_ns, position_m, quat_xyzw, covariance):
        """One ``train/pose_with_covariance``: position (3,) m, quaternion x, y, z, w,
        covariance (36,) or (6, 6).
        """
        self._poses.append(TrainPose(int(stamp_ns), np.asarray(position_m, float),
                                     np.asarray(quat_xyzw, float),
                                     np.asarray(covariance, float).reshape(6, 6)))

    def _add_frame(self, stamp_ns, kind, records):
        frame = self._frames.setdefault(stamp_ns, {})
        frame[kind] = records
        if 'lamps' in frame and 'pairs' in frame:
            del self._frames[stamp_ns]
            if stamp_ns >= self._fix[0]:
                observations, _ = join_frame(stamp_ns, frame['pairs'], frame['lamps'],
                                             self.join_config)
                uids = [o.uid for o in observations
                        if o.uid is not None and o.uid in self._index]
                if uids:
                    self._fix = (stamp_ns, uids)
        # a frame whose other half never comes is forgotten after a few newer ones
        while len(self._frames) > 8:
            del self._frames[min(self._frames)]

    # ------------------------------------------------------------------ output
    def pose_at(self, stamp_ns):
        """The received pose nearest ``stamp_ns`` (None without poses)."""
        if not self._poses:
            return None
        return min(self._poses, key=lambda p: abs(p.stamp_ns - stamp_ns))

    def scene(self):
        """The :class:`Scene` of everything received so far."""
        lm = self.lamp_map
        states = np.full(len(lm), LAMP_NOT_SEEN, dtype=np.int8)
        newest = self._newest_lamps_ns
        if newest is not None:
            recent = self._last_identified_ns >= newest - self.recent_ns
            states[recent & (self._last_identified_ns >= 0)] = LAMP_SEEN_RECENTLY
            for uid in self._identified_now:
                states[self._index[uid]] = LAMP_IDENTIFIED_NOW
        stamps = [newest or 0] + ([self._poses[-1].stamp_ns] if self._poses else [])
        scene = Scene(stamp_ns=max(stamps), lamp_positions=lm.positions.copy(),
                      lamp_uids=np.array([lamp.uid for lamp in lm.lamps], dtype=np.int64),
                      lamp_states=states,
                      history_m=np.array([p.position_m for p in self._poses]).reshape(-1, 3))
        if not self._poses:
            return scene
        train = self._poses[-1]
        axis, sigma = along_track(train)
        scene.train, scene.along_axis, scene.sigma_along_m = train, axis, sigma
        scene.bar_m = np.stack([train.position_m - 3.0 * sigma * axis,
                                train.position_m + 3.0 * sigma * axis])
        fix_ns, uids = self._fix
        if fix_ns:
            pose = self.pose_at(fix_ns)
            camera = pose.position_m + pose.rotation @ self.camera_offset_m
            scene.camera_m, scene.fix_stamp_ns, scene.ray_uids = camera, fix_ns, list(uids)
            scene.rays_m = np.array([[camera, lm.positions[self._index[uid]]]
                                     for uid in uids]).reshape(-1, 2, 3)
        return scene
