"""sensor_msgs/CameraInfo checked before use; the last good one kept per camera.

``camera_info`` is latched (reliable, transient local, depth 1) and published with every
frame: a subscriber holds one message per camera and each new one replaces it. A bad one
(all-zero K/P, NaN, a size that is not the images') must not replace a good one, and a
single odd one must not change the geometry a node works with. :class:`CameraInfoKeeper`
keeps, per camera, the last good message: one that fails :func:`camera_info_problem` is
refused; a valid one that differs from the kept one (size, K or P) becomes the kept one
only after ``confirm_count`` consecutive identical messages (a camera that was really
re-calibrated or re-configured keeps sending its new one; a lone stray message is
forgotten at the next regular one). The first valid message is kept at once.
"""
import math

import numpy as np


def camera_info_problem(msg):
    """None when ``msg`` (a CameraInfo or anything with its fields) describes a usable
    rectified camera, else a short reason: zero size, K, R, P or D not finite, no
    positive focal length in K or P, P[2,2] not 1 (not a projection of a rectified
    image), K or P the wrong length.
    """
    if not (int(msg.width) > 0 and int(msg.height) > 0):
        return f'zero size ({msg.width}x{msg.height})'
    k, p, r = (np.asarray(v, dtype=float) for v in (msg.k, msg.p, msg.r))
    if k.size != 9 or p.size != 12 or r.size != 9:
        return f'K, R, P of {k.size}, {r.size}, {p.size} values (9, 9, 12 expected)'
    d = np.asarray(msg.d, dtype=float)
    for name, values in (('K', k), ('R', r), ('P', p), ('D', d)):
        if not np.all(np.isfinite(values)):
            return f'{name} not finite'
    if not (k[0] > 0.0 and k[4] > 0.0):
        return 'K has no positive focal length (uncalibrated)'
    if not (p[0] > 0.0 and p[5] > 0.0):
        return 'P has no positive focal length'
    if not math.isclose(p[10], 1.0, rel_tol=1e-9, abs_tol=1e-9):
        return f'P[2,2] is {p[10]}, not 1'
    return None


def raw_camera_model(msg):
    """The :class:`~vlc_common.core.camera.CameraModel` of a camera whose images are raw
    (D ≠ 0, R ≠ I or P[:, :3] ≠ K: pixels must be mapped through K, D, R, P to the
    rectified image), None when its images are rectified already (D = 0 or empty,
    R = I or all zero — an uncalibrated driver's — and P[:, :3] = K, or no K at all:
    only P given). Raises ValueError (``CameraModelError``) when K, D, R, P are not a
    valid camera model.
    """
    K = np.asarray(msg.k, dtype=float).reshape(3, 3)
    D = np.asarray(msg.d, dtype=float).ravel()
    R = np.asarray(msg.r, dtype=float).reshape(3, 3)
    P = np.asarray(msg.p, dtype=float).reshape(3, 4)
    if not np.any(R):
        R = np.eye(3)
    if not np.any(K) or (not np.any(D) and np.array_equal(R, np.eye(3))
                         and np.array_equal(P[:, :3], K)):
        return None
    from vlc_common.core.camera import CameraModel
    return CameraModel(int(msg.width), int(msg.height), K, D, R, P,
                       msg.distortion_model or 'plumb_bob')


def _key(msg):
    # D, R and the model too: a new calibration may change the lens alone
    return (int(msg.width), int(msg.height), tuple(float(v) for v in msg.k),
            tuple(float(v) for v in msg.p), tuple(float(v) for v in msg.d),
            tuple(float(v) for v in msg.r), str(msg.distortion_model))


class CameraInfoKeeper:
    """The last good camera_info of each camera (0 left, 1 right); see the module
    docstring.

    Parameters
    ----------
    confirm_count : int
        Consecutive identical valid messages that replace a different kept one (>= 1).
    """

    #: ``update`` outcomes
    KEPT, SAME, REFUSED, PENDING = 'kept', 'same', 'refused', 'pending'

    def __init__(self, confirm_count=3):
        if confirm_count < 1:
            raise ValueError('confirm_count must be >= 1')
        self.confirm_count = int(confirm_count)
        self.current = [None, None]
        self.refused = 0
        self.ignored = 0               # valid, different, never confirmed
        self._candidate = [None, None]  # (key, count)

    def update(self, side, msg):
        """Offer one message of camera ``side``; returns ``(outcome, reason)``:
        :attr:`KEPT` (it is the kept one now: a change), :attr:`SAME` (equal to the kept
        one), :attr:`REFUSED` (invalid: ``reason`` says why), :attr:`PENDING` (valid,
        different, not confirmed yet).
        """
        problem = camera_info_problem(msg)
        if problem is not None:
            self.refused += 1
            return self.REFUSED, problem
        key = _key(msg)
        kept = self.current[side]
        if kept is None:
            self.current[side] = msg
            self._candidate[side] = None
            return self.KEPT, None
        if key == _key(kept):
            self.current[side] = msg           # the newest header
            if self._candidate[side] is not None:
                self.ignored += 1
            self._candidate[side] = None
            return self.SAME, None
        cand = self._candidate[side]
        if cand is not None and cand[0] == key:
            count = cand[1] + 1
        else:
            if cand is not None:
                self.ignored += 1
            count = 1
        if count >= self.confirm_count:
            self.current[side] = msg
            self._candidate[side] = None
            return self.KEPT, None
        self._candidate[side] = (key, count)
        return self.PENDING, (f'differs from the kept one ({kept.width}x{kept.height}): '
                              f'{count} of {self.confirm_count} needed to change')

    def both(self):
        """(left, right) kept messages, or None until both cameras sent a good one."""
        if self.current[0] is None or self.current[1] is None:
            return None
        return tuple(self.current)


def stereo_camera_publishers(node):
    """The publishers of a stereo camera, as the receivers subscribe to them:
    ``stereo/{left,right}/image_raw`` (reliable, keep last 5) and
    ``stereo/{left,right}/camera_info`` (reliable, transient local, depth 1: latched).
    Returns ``(image publishers, camera_info publishers)``, left first.
    """
    from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
    from sensor_msgs.msg import CameraInfo, Image
    image_qos = QoSProfile(depth=5, reliability=ReliabilityPolicy.RELIABLE)
    latched = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                         durability=DurabilityPolicy.TRANSIENT_LOCAL)
    sides = ('left', 'right')
    return ([node.create_publisher(Image, f'stereo/{side}/image_raw', image_qos)
             for side in sides],
            [node.create_publisher(CameraInfo, f'stereo/{side}/camera_info', latched)
             for side in sides])


def camera_info_msg(info, header=None):
    """sensor_msgs/CameraInfo from a camera_info dict (``width``, ``height``,
    ``distortion_model``, ``K``, ``D``, ``R``, ``P``, as ``camera_info_dicts()`` of the
    rig and of a loaded calibration give them), with ``header``.
    """
    from sensor_msgs.msg import CameraInfo
    from std_msgs.msg import Header
    return CameraInfo(header=header if header is not None else Header(),
                      height=int(info['height']), width=int(info['width']),
                      distortion_model=str(info.get('distortion_model') or 'plumb_bob'),
                      d=[float(v) for v in np.ravel(info['D'])],
                      k=[float(v) for v in np.ravel(info['K'])],
                      r=[float(v) for v in np.ravel(info['R'])],
                      p=[float(v) for v in np.ravel(info['P'])])

