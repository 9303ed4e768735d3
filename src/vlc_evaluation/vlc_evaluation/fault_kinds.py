"""The malformed messages of ``fault_injector_node``, one builder per kind (no ROS node).

Each kind names one defect and builds the messages that carry it, as
``[(topic_key, message), ...]``: image kinds a stereo pair (left and right with one
stamp, so the pair reaches the receivers' processing instead of waiting for a partner),
camera_info kinds a left and a right message, IMU kinds one ``imu/data_raw`` and one
``imu/data`` sample, point-cloud kinds one ``spots/pairs`` and one ``vlc/lamps`` cloud.
Apart from its defect a message is as valid as the graph's own: built from the newest
real message of its topic when the injector has one (:class:`Templates`), else from the
project's layouts and defaults.

Stamps: a kind about content is stamped just after the newest real frame (or IMU
sample), so it is newer than what the receivers processed and collides with no real
stamp; the stamp kinds use 1970 (``sec`` 0 or 1), ``future_offset_s`` after the node
clock, or, for ``imu_duplicate_stamp``, the stamp of the newest real sample itself.
"""
import copy
from dataclasses import dataclass, field
import math

import numpy as np
from sensor_msgs.msg import CameraInfo, Image, Imu, PointField

from vlc_common.core.records import LAMP_DTYPE, PAIR_DTYPE
from vlc_common.pointcloud import records_to_cloud
from vlc_common.stamps import NS_PER_S, header, ns_to_stamp, stamp_to_ns

#: topic key → relative topic name the injector publishes on
TOPICS = {
    'left_image': 'stereo/left/image_raw', 'right_image': 'stereo/right/image_raw',
    'left_info': 'stereo/left/camera_info', 'right_info': 'stereo/right/camera_info',
    'imu_raw': 'imu/data_raw', 'imu': 'imu/data',
    'pairs': 'spots/pairs', 'lamps': 'vlc/lamps',
}
FRAME_IDS = {'left': 'camera_left_optical_frame', 'right': 'camera_right_optical_frame',
             'imu_raw': 'imu_link', 'imu': 'base_link'}
#: A content kind is stamped this long after the newest real frame or IMU sample, ns.
AFTER_NEWEST_NS = 1_000_000
AFTER_NEWEST_IMU_NS = 1_000


@dataclass
class Templates:
    """What the injector knows of the graph when it builds a kind.

    Attributes
    ----------
    now_ns : int
        Node clock (simulated time when the graph has a /clock), ns.
    future_offset_ns : int
        How far after ``now_ns`` a future stamp lies, ns.
    infos : list
        Newest real CameraInfo of the left and right camera (None until one came).
    imu : dict
        Newest real Imu of ``imu_raw`` and ``imu`` (absent until one came).
    width, height : int
        Image size used until a camera_info told the real one, px.
    """

    now_ns: int
    future_offset_ns: int = 365 * 86400 * NS_PER_S
    infos: list = field(default_factory=lambda: [None, None])
    imu: dict = field(default_factory=dict)
    width: int = 1280
    height: int = 720

    def size(self):
        info = self.infos[0]
        if info is not None and info.width > 0 and info.height > 0:
            return int(info.width), int(info.height)
        return self.width, self.height

    def frame_stamp_ns(self):
        """A stamp just after the newest real frame (camera_info carries the frame's
        stamp), or the node clock before any.
        """
        stamps = [stamp_to_ns(i.header.stamp) for i in self.infos if i is not None]
        return max(stamps) + AFTER_NEWEST_NS if stamps else self.now_ns

    def future_ns(self):
        return self.now_ns + self.future_offset_ns


# ------------------------------------------------------------------ images
def _image(stamp_ns, side, width, height, *, encoding='mono8', step=None, nbytes=None):
    step = width if step is None else step
    nbytes = step * height if nbytes is None else nbytes
    return Image(header=header(stamp_ns, FRAME_IDS[side]), width=width, height=height,
                 encoding=encoding, is_bigendian=False, step=step, data=bytes(nbytes))


def _pair(build):
    return [(f'{side}_image', build(side)) for side in ('left', 'right')]


def _image_kind(**change):
    """A stereo pair of mono8 images of the camera's size (black) with ``change``:
    ``stamp`` (callable of the Templates), ``size`` (callable (w, h) → (w, h)), the rest
    (encoding, step, nbytes as callables of (w, h)) passed to :func:`_image`.
    """
    def build(t):
        w, h = t.size()
        stamp = change.get('stamp', Templates.frame_stamp_ns)(t)
        ww, hh = change.get('size', lambda w, h: (w, h))(w, h)
        extra = {k: (v(w, h) if callable(v) else v) for k, v in change.items()
                 if k in ('encoding', 'step', 'nbytes')}
        return _pair(lambda side: _image(stamp, side, ww, hh, **extra))
    return build


# ------------------------------------------------------------------ camera_info
def default_camera_info(side, width=1280, height=720):
    """A plausible rectified camera_info (fx 900 px, baseline 0.12 m) for a side."""
    fx, cx, cy = 900.0, 0.5 * (width - 1), 0.5 * (height - 1)
    tx = 0.0 if side == 'left' else -fx * 0.12
    return CameraInfo(width=width, height=height, distortion_model='plumb_bob',
                      d=[0.0] * 5, k=[fx, 0.0, cx, 0.0, fx, cy, 0.0, 0.0, 1.0],
                      r=[1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0],
                      p=[fx, 0.0, cx, tx, 0.0, fx, cy, 0.0, 0.0, 0.0, 1.0, 0.0])


def _info_kind(change):
    def build(t):
        out = []
        for i, side in enumerate(('left', 'right')):
            real = t.infos[i]
            w, h = t.size()
            msg = copy.deepcopy(real) if real is not None else default_camera_info(side, w, h)
            msg.header = header(t.now_ns, FRAME_IDS[side])
            change(msg)
            out.append((f'{side}_info', msg))
        return out
    return build


def _zero_k_p(msg):
    msg.k = [0.0] * 9
    msg.p = [0.0] * 12


def _nan_p(msg):
    p = list(msg.p)
    p[2] = math.nan           # cx: the focal lengths stay positive
    msg.p = p


def _info_size(msg):
    msg.width, msg.height = max(1, msg.width // 2), max(1, msg.height // 2)


# ------------------------------------------------------------------ IMU
def default_imu(key, stamp_ns):
    """An IMU sample at rest (specific force +g on z; ``imu`` with an identity attitude
    and a small covariance, ``imu_raw`` without an orientation, REP-145).
    """
    msg = Imu(header=header(stamp_ns, FRAME_IDS[key]))
    msg.linear_acceleration.z = 9.80665
    msg.orientation.w = 1.0
    if key == 'imu_raw':
        msg.orientation_covariance = [-1.0] + [0.0] * 8
    else:
        msg.orientation_covariance = [1e-6, 0.0, 0.0, 0.0, 1e-6, 0.0, 0.0, 0.0, 1e-5]
    return msg


def _imu_kind(change, stamp='after'):
    """One sample on each IMU topic: the newest real one (or one at rest) with
    ``change(msg)`` applied; ``stamp`` 'after' (just after the newest real sample),
    'same' (its stamp: a duplicate), '1970' or 'future'.
    """
    def build(t):
        out = []
        for key in ('imu_raw', 'imu'):
            real = t.imu.get(key)
            msg = copy.deepcopy(real) if real is not None else default_imu(key, t.now_ns)
            base = stamp_to_ns(msg.header.stamp)
            if stamp == 'after':
                msg.header.stamp = ns_to_stamp(base + AFTER_NEWEST_IMU_NS)
            elif stamp == '1970':
                msg.header.stamp = ns_to_stamp(0)
            elif stamp == 'future':
                msg.header.stamp = ns_to_stamp(t.future_ns())
            change(msg)
            out.append((key, msg))
            if stamp == 'same' and real is None:
                out.append((key, copy.deepcopy(msg)))     # no real one: send it twice
        return out
    return build


def _set(path, value):
    def change(msg):
        obj = msg
        *parents, last = path.split('.')
        for p in parents:
            obj = getattr(obj, p)
        setattr(obj, last, value)
    return change


def _zero_quaternion(msg):
    o = msg.orientation
    o.x = o.y = o.z = o.w = 0.0


def _nothing(msg):
    pass


# ------------------------------------------------------------------ point clouds
def plausible_pair():
    """One ``spots/pairs`` record of a lamp about 5 m ahead (values of the rig's)."""
    rec = np.zeros(1, dtype=PAIR_DTYPE)
    rec['u_left'], rec['v_left'], rec['u_right'], rec['v_right'] = 700.0, 520.0, 680.0, 520.0
    rec['disparity'], rec['stamp_offset_s'] = 20.0, 0.0156
    for name in ('sigma_u_left', 'sigma_v_left', 'sigma_u_right', 'sigma_v_right'):
        rec[name] = 0.05
    rec['sigma_disparity'] = 0.07
    rec['circularity_left'] = rec['circularity_right'] = 0.95
    rec['row_min'], rec['row_max'], rec['flags'] = 510, 530, 3
    return rec


def plausible_lamp():
    """One ``vlc/lamps`` record: a lamp still being read (state 1, no UID yet)."""
    rec = np.zeros(1, dtype=LAMP_DTYPE)
    rec['map_x'] = rec['map_y'] = rec['map_z'] = math.nan
    rec['track_id'], rec['state'], rec['chips_seen'], rec['flags'] = 9999, 1, 20, 3
    rec['t_offset_s'] = 0.0156
    rec['left_u'], rec['left_v'], rec['right_u'], rec['right_v'] = 700.5, 519.6, 680.0, 520.0
    rec['left_u_min'], rec['left_v_min'] = 690.0, 510.0
    rec['left_u_max'], rec['left_v_max'] = 711.0, 530.0
    rec['right_u_min'], rec['right_v_min'] = 670.0, 510.0
    rec['right_u_max'], rec['right_v_max'] = 691.0, 530.0
    return rec


_RECORDS = {'pairs': plausible_pair, 'lamps': plausible_lamp}
_MISSING = {'pairs': 'u_left', 'lamps': 'uid'}


def _cloud_kind(change, stamp='frame'):
    """One cloud on each topic: the plausible record in the documented layout, stamped
    after the newest frame ('frame'), in 1970 or in the future, then ``change(cloud,
    key)`` applied.
    """
    def build(t):
        out = []
        for key, records in _RECORDS.items():
            stamp_ns = {'frame': Templates.frame_stamp_ns, '1970': lambda _: 0,
                        'future': Templates.future_ns}[stamp](t)
            cloud = records_to_cloud(records(), header(stamp_ns, FRAME_IDS['left']))
            change(cloud, key)
            out.append((key, cloud))
        return out
    return build


def _empty(cloud, key):
    cloud.width, cloud.row_step, cloud.data = 0, 0, b''


def _float64_for_float32(cloud, key):
    for f in cloud.fields:
        if f.datatype == PointField.FLOAT32:
            f.datatype = PointField.FLOAT64


def _missing_field(cloud, key):
    cloud.fields = [f for f in cloud.fields if f.name != _MISSING[key]]


def _point_step(cloud, key):
    cloud.point_step -= 8                       # the last fields end beyond it
    cloud.row_step = cloud.point_step * cloud.width
    cloud.data = bytes(cloud.data)[:cloud.row_step]


def _data_length(cloud, key):
    cloud.width += 1                            # two points announced, one sent
    cloud.row_step = cloud.point_step * cloud.width


def _bigendian(cloud, key):
    cloud.is_bigendian = True                   # the data stay little endian


def _nan_values(cloud, key):
    dtype = {'pairs': PAIR_DTYPE, 'lamps': LAMP_DTYPE}[key]
    rec = np.frombuffer(bytes(cloud.data), dtype=dtype).copy()
    for name in dtype.names:
        if rec.dtype[name].kind == 'f':
            rec[name] = math.nan
    cloud.data = rec.tobytes()


def _unchanged(cloud, key):
    pass


# ------------------------------------------------------------------ the kinds
def _kind(group, text, build):
    return {'group': group, 'text': text, 'build': build}


_STAMP_1970_0 = lambda t: 0                       # noqa: E731
_STAMP_1970_1 = lambda t: NS_PER_S                # noqa: E731

#: kind → {'group', 'text', 'build'}; ``build(Templates)`` → [(topic_key, message)]
KINDS = {
    'image_rgb8_mono_data': _kind('image', "encoding 'rgb8' with mono8-sized data",
                                  _image_kind(encoding='rgb8')),
    'image_bayer_rggb8': _kind('image', "encoding 'bayer_rggb8' (unsupported)",
                               _image_kind(encoding='bayer_rggb8')),
    'image_encoding_nonsense': _kind('image', "encoding 'nonsense'",
                                     _image_kind(encoding='nonsense')),
    'image_width_mismatch': _kind('image', 'width and step 8 px more than the data hold',
                                  _image_kind(size=lambda w, h: (w + 8, h),
                                              step=lambda w, h: w + 8,
                                              nbytes=lambda w, h: w * h)),
    'image_height_mismatch': _kind('image', 'height one row less than the data hold',
                                   _image_kind(size=lambda w, h: (w, h - 1),
                                               nbytes=lambda w, h: w * h)),
    'image_step_too_small': _kind('image', 'step one byte less than the width',
                                  _image_kind(step=lambda w, h: w - 1,
                                              nbytes=lambda w, h: w * h)),
    'image_truncated': _kind('image', 'data cut to half the image',
                             _image_kind(nbytes=lambda w, h: w * h // 2)),
    'image_empty': _kind('image', 'empty image (0x0, no data)',
                         _image_kind(size=lambda w, h: (0, 0), step=0, nbytes=0)),
    'image_size_not_camera_info': _kind('image', 'a consistent image of half the '
                                        "camera_info's width and height",
                                        _image_kind(size=lambda w, h: (w // 2, h // 2))),
    'image_stamp_1970_sec0': _kind('image', 'valid black image stamped 1970 (sec 0)',
                                   _image_kind(stamp=_STAMP_1970_0)),
    'image_stamp_1970_sec1': _kind('image', 'valid black image stamped 1970 (sec 1)',
                                   _image_kind(stamp=_STAMP_1970_1)),
    'image_stamp_future': _kind('image', 'valid black image stamped future_offset_s ahead',
                                _image_kind(stamp=Templates.future_ns)),
    'camera_info_zero_k_p': _kind('camera_info', 'K and P all zero', _info_kind(_zero_k_p)),
    'camera_info_nan_p': _kind('camera_info', 'NaN in P (cx)', _info_kind(_nan_p)),
    'camera_info_size_mismatch': _kind('camera_info', 'half the width and height of the '
                                       'images, P unchanged', _info_kind(_info_size)),
    'imu_nan_angular_velocity': _kind('imu', 'NaN angular velocity x',
                                      _imu_kind(_set('angular_velocity.x', math.nan))),
    'imu_inf_angular_velocity': _kind('imu', '+inf angular velocity y',
                                      _imu_kind(_set('angular_velocity.y', math.inf))),
    'imu_nan_linear_acceleration': _kind('imu', 'NaN linear acceleration z',
                                         _imu_kind(_set('linear_acceleration.z', math.nan))),
    'imu_inf_linear_acceleration': _kind('imu', '-inf linear acceleration x',
                                         _imu_kind(_set('linear_acceleration.x', -math.inf))),
    'imu_nan_orientation': _kind('imu', 'NaN orientation w',
                                 _imu_kind(_set('orientation.w', math.nan))),
    'imu_inf_orientation': _kind('imu', '+inf orientation z',
                                 _imu_kind(_set('orientation.z', math.inf))),
    'imu_zero_quaternion': _kind('imu', 'orientation (0, 0, 0, 0)',
                                 _imu_kind(_zero_quaternion)),
    'imu_stamp_1970': _kind('imu', 'valid sample stamped 1970 (sec 0)',
                            _imu_kind(_nothing, stamp='1970')),
    'imu_stamp_future': _kind('imu', 'valid sample stamped future_offset_s ahead',
                              _imu_kind(_nothing, stamp='future')),
    'imu_duplicate_stamp': _kind('imu', 'the newest real sample sent again (same stamp)',
                                 _imu_kind(_nothing, stamp='same')),
    'cloud_empty': _kind('cloud', 'no points, the documented fields',
                         _cloud_kind(_empty)),
    'cloud_float64_for_float32': _kind('cloud', 'FLOAT32 fields declared FLOAT64',
                                       _cloud_kind(_float64_for_float32)),
    'cloud_missing_field': _kind('cloud', 'u_left (spots/pairs), uid (vlc/lamps) missing',
                                 _cloud_kind(_missing_field)),
    'cloud_wrong_point_step': _kind('cloud', 'point_step 8 B short of the fields',
                                    _cloud_kind(_point_step)),
    'cloud_data_length': _kind('cloud', 'width 2, data of 1 point',
                               _cloud_kind(_data_length)),
    'cloud_bigendian': _kind('cloud', 'is_bigendian true, little-endian data',
                             _cloud_kind(_bigendian)),
    'cloud_nan_values': _kind('cloud', 'every float field NaN', _cloud_kind(_nan_values)),
    'cloud_stamp_1970': _kind('cloud', 'plausible record stamped 1970 (sec 0)',
                              _cloud_kind(_unchanged, stamp='1970')),
    'cloud_stamp_future': _kind('cloud', 'plausible record stamped future_offset_s ahead',
                                _cloud_kind(_unchanged, stamp='future')),
}
ALL_KINDS = tuple(KINDS)


def build(kind, templates):
    """[(topic_key, message)] of one injection of ``kind`` (KeyError if unknown)."""
    return KINDS[kind]['build'](templates)


def topics_of(kind):
    """The topic keys a kind publishes on."""
    return sorted({key for key, _ in build(kind, Templates(now_ns=10 * NS_PER_S))})
