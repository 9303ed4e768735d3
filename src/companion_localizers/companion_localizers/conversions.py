"""Messages ↔ core records for the companion localizers (the only module that knows both).

Inputs: ``photodiode/rssi`` records (PointCloud2 → :class:`~.core.rssi.LampReading`),
``imu/data`` (→ ImuSample, train_localizer's conversion), ``spots/pairs`` and
``vlc/lamps`` (PointCloud2 → structured arrays, joined by train_localizer's
FrameJoiner). Outputs: PoseStamped, DiagnosticStatus.
"""
from collections import deque
import time

from geometry_msgs.msg import PoseStamped
import numpy as np

from companion_localizers.core.rssi import LampReading
from train_localizer.conversions import (  # noqa: F401
    CameraInfoIntrinsics,
    imu_from_msg,
    ns_to_stamp,
    stamp_to_ns,
)
from vlc_common.diagnostics import diagnostic_status  # noqa: F401 (here for the nodes)
from vlc_common.pointcloud import cloud_to_records  # noqa: F401 (re-exported)

RSSI_FIELDS = ('uid', 'power_w')
SPOT_FIELDS = ('u_left', 'v_left', 'u_right', 'v_right')


def require_fields(records, names, topic):
    """Raise ValueError naming the fields of ``names`` missing from a record array."""
    have = set(records.dtype.names or ())
    missing = [n for n in names if n not in have]
    if missing and records.size:
        raise ValueError(f'{topic}: missing fields {", ".join(missing)}')


def rssi_readings(records, lamp_map):
    """``photodiode/rssi`` records → (list of LampReading, UIDs not in the map).

    Records with a non-finite or non-positive power are left out (the caller counts
    them: ``len(records) − len(readings) − len(unknown)``).
    """
    readings, unknown = [], []
    if records.dtype.names is None or records.size == 0:
        return readings, unknown
    sigma = (records['power_sigma_w'] if 'power_sigma_w' in records.dtype.names
             else np.zeros(records.size))
    for uid, power, s in zip(records['uid'].tolist(), records['power_w'].tolist(),
                             np.asarray(sigma, dtype=float).tolist()):
        lamp = lamp_map.by_uid(uid)
        if lamp is None:
            unknown.append(int(uid))
            continue
        if not (np.isfinite(power) and power > 0.0):
            continue
        readings.append(LampReading(uid=int(uid), position_m=lamp.position_m,
                                    normal=lamp.normal, power_w=float(power),
                                    power_sigma_w=float(s) if np.isfinite(s) else 0.0))
    return readings, unknown


def pose_stamped(stamp_ns, position_m, quat_xyzw, frame_id):
    """geometry_msgs/PoseStamped of ``base_link`` in ``frame_id`` at ``stamp_ns``."""
    msg = PoseStamped()
    msg.header.stamp = ns_to_stamp(stamp_ns)
    msg.header.frame_id = frame_id
    p, q = msg.pose.position, msg.pose.orientation
    p.x, p.y, p.z = (float(v) for v in position_m)
    q.x, q.y, q.z, q.w = (float(v) for v in quat_xyzw)
    return msg


class CpuTimer:
    """CPU time of the calling thread per processed update (``time.thread_time``: not
    inflated by other processes sharing the cores), over the last ``window`` updates.

    ``with timer: ...`` measures one update.
    """

    def __init__(self, window=500):
        self._ms = deque(maxlen=window)
        self._start = None
        self.total_s = 0.0
        self.count = 0

    def __enter__(self):
        self._start = time.thread_time()
        return self

    def __exit__(self, *exc):
        elapsed = time.thread_time() - self._start
        self._ms.append(elapsed * 1e3)
        self.total_s += elapsed
        self.count += 1
        return False

    def summary(self, prefix):
        """Diagnostics values ``<prefix>_median``, ``_p95``, ``_max`` (ms)."""
        return summary_ms(self._ms, prefix)


def summary_ms(values_ms, prefix):
    """Diagnostics values ``<prefix>_median``, ``_p95``, ``_max`` of CPU times (ms)."""
    if not values_ms:
        return {}
    arr = np.asarray(values_ms)
    return {f'{prefix}_median': f'{np.median(arr):.3f}',
            f'{prefix}_p95': f'{np.percentile(arr, 95):.3f}',
            f'{prefix}_max': f'{np.max(arr):.3f}'}
