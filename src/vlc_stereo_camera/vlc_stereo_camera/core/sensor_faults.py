"""Sensor faults of the rig: when samples are lost, held back or mis-stamped (pure Python).

The rig's physics never changes: every sample and frame is computed as without faults;
the faults act at publication time only, on the *true* simulated time ``t`` of a sample
(seconds since the start, t = 0 at ``epoch_s``; here in integer nanoseconds ``t_ns``
so that every comparison with a stamp is exact).

Faults (parameters of ``config/rig.yaml``, every default off):

``imu_dropouts_s`` = [start_s, duration_s, ...]
    IMU samples with start_s ≤ t < start_s + duration_s are not published (lost, not
    delayed). Windows may overlap.
``camera_dropouts_s`` = [start_s, duration_s, ...]
    The same for camera frames (t = the frame's start of row-0 exposure): no image and
    no camera_info; ground truth and ``/clock`` go on.
``imu_burst_s`` = B (0 = off)
    The IMU holds its samples and releases them in bursts at the boundaries k·B of
    simulated time (k = 1, 2, ...): the sample at t is released at the first boundary
    strictly after it, (⌊t/B⌋ + 1)·B, so a burst holds the samples of
    [(k−1)·B, k·B), each with its own stamp.
``imu_stamp_offset_s`` = d
    Added to every IMU stamp (the IMU clock runs offset from the camera's); release
    still by the true time. A drawn installation adds its IMU clock offset here, and
    its drift (``imu_clock_drift_ppm`` of :meth:`SensorFaults.from_parameters`: the IMU
    stamp gains drift·1e-6·t).
``sensor_clock_jumps_s`` = [at_s, jump_s, ...]
    Every sensor and truth stamp of a sample with t ≥ at_s gets jump_s more
    (cumulative over the jumps; negative = back). ``/clock`` is not stepped.

Stamps: ``stamp = epoch + t + Σ_{at ≤ t} jump`` (+ ``imu_stamp_offset_s`` + drift·t for
the IMU).
"""
from dataclasses import dataclass
import math

NS_PER_S = 1_000_000_000


def _to_ns(seconds):
    return int(round(seconds * NS_PER_S))


def _finite(value):
    return isinstance(value, (int, float)) and math.isfinite(value)


def _pairs(name, values):
    """Flat [a, b, a, b, ...] → list of (a, b) floats; ValueError unless pairs of numbers."""
    values = [] if values is None else list(values)
    if len(values) % 2:
        raise ValueError(f'{name} must hold pairs of numbers, got {len(values)} values: '
                         f'{values}')
    if not all(_finite(v) for v in values):
        raise ValueError(f'{name} must hold finite numbers, got {values}')
    return [(float(values[i]), float(values[i + 1])) for i in range(0, len(values), 2)]


def _windows(name, values):
    """[start_s, duration_s, ...] → ((start_ns, end_ns), ...), validated, sorted."""
    windows = []
    for i, (start_s, duration_s) in enumerate(_pairs(name, values)):
        start_ns, duration_ns = _to_ns(start_s), _to_ns(duration_s)
        if start_s < 0.0:
            raise ValueError(f'{name}: window {i} starts at {start_s:g} s; start_s must be '
                             '>= 0 (simulated seconds since the start)')
        if duration_ns <= 0:
            raise ValueError(f'{name}: window {i} lasts {duration_s:g} s; duration_s must be '
                             '> 0 (at least 1 ns)')
        windows.append((start_ns, start_ns + duration_ns))
    return tuple(sorted(windows))


def _in_any(windows, t_ns):
    return any(start <= t_ns < end for start, end in windows)


def _describe_windows(windows):
    return ', '.join(f'[{a / NS_PER_S:g}, {b / NS_PER_S:g}) s' for a, b in windows)


@dataclass(frozen=True)
class SensorFaults:
    """The fault schedule of one rig, in integer nanoseconds of simulated time.

    Build it with :meth:`from_parameters` (validated); the default instance has no fault.

    Attributes
    ----------
    imu_dropouts_ns, camera_dropouts_ns : tuple of (int, int)
        Half-open windows [start, end) of true time, ns since the start, sorted.
    imu_burst_ns : int
        Burst period of the IMU, ns; 0 = every sample released when due.
    imu_stamp_offset_ns : int
        Added to every IMU stamp, ns.
    imu_clock_drift_ppm : float
        The IMU stamp gains this many ns per ms of true time (ppm).
    clock_jumps_ns : tuple of (int, int)
        (at, jump) pairs, ns, sorted by ``at``: from true time ``at`` on the sensor
        stamps are ``jump`` later (cumulative).
    """

    imu_dropouts_ns: tuple = ()
    camera_dropouts_ns: tuple = ()
    imu_burst_ns: int = 0
    imu_stamp_offset_ns: int = 0
    clock_jumps_ns: tuple = ()
    imu_clock_drift_ppm: float = 0.0

    @classmethod
    def from_parameters(cls, imu_dropouts_s=(), camera_dropouts_s=(), imu_burst_s=0.0,
                        imu_stamp_offset_s=0.0, sensor_clock_jumps_s=(),
                        imu_clock_drift_ppm=0.0):
        """The schedule of the rig parameters of the same names (seconds).

        Parameters
        ----------
        imu_dropouts_s, camera_dropouts_s : sequence of float
            Flat pairs [start_s, duration_s, ...]; start_s ≥ 0, duration_s > 0.
        imu_burst_s : float
            Burst period, s (≥ 0; 0 = off).
        imu_stamp_offset_s : float
            IMU stamp offset, s (finite, either sign).
        sensor_clock_jumps_s : sequence of float
            Flat pairs [at_s, jump_s, ...]; at_s ≥ 0, jump_s finite (either sign).
        imu_clock_drift_ppm : float
            IMU clock drift against the camera's, ppm (finite, |drift| < 1000).

        Raises
        ------
        ValueError
            A list is not made of pairs, a value is not finite, a window does not last
            at least 1 ns or starts before 0, a jump is before 0, the burst period is
            negative or rounds to 0 ns.
        """
        jumps = []
        for i, (at_s, jump_s) in enumerate(_pairs('sensor_clock_jumps_s',
                                                  sensor_clock_jumps_s)):
            if at_s < 0.0:
                raise ValueError(f'sensor_clock_jumps_s: jump {i} at {at_s:g} s; at_s must '
                                 'be >= 0 (simulated seconds since the start)')
            jumps.append((_to_ns(at_s), _to_ns(jump_s)))
        if not _finite(imu_burst_s) or imu_burst_s < 0.0:
            raise ValueError(f'imu_burst_s must be finite and >= 0, got {imu_burst_s}')
        burst_ns = _to_ns(imu_burst_s)
        if imu_burst_s > 0.0 and burst_ns <= 0:
            raise ValueError(f'imu_burst_s {imu_burst_s:g} s is shorter than 1 ns')
        if not _finite(imu_stamp_offset_s):
            raise ValueError(f'imu_stamp_offset_s must be finite, got {imu_stamp_offset_s}')
        if not _finite(imu_clock_drift_ppm) or abs(imu_clock_drift_ppm) >= 1000.0:
            raise ValueError(f'imu_clock_drift_ppm must be finite and within +-1000, got '
                             f'{imu_clock_drift_ppm}')
        return cls(imu_dropouts_ns=_windows('imu_dropouts_s', imu_dropouts_s),
                   imu_clock_drift_ppm=float(imu_clock_drift_ppm),
                   camera_dropouts_ns=_windows('camera_dropouts_s', camera_dropouts_s),
                   imu_burst_ns=burst_ns, imu_stamp_offset_ns=_to_ns(imu_stamp_offset_s),
                   clock_jumps_ns=tuple(sorted(jumps, key=lambda j: j[0])))

    # --- what is on ---------------------------------------------------------------------
    @property
    def active(self):
        """True when any fault is configured."""
        return bool(self.imu_dropouts_ns or self.camera_dropouts_ns or self.imu_burst_ns
                    or self.imu_stamp_offset_ns or self.clock_jumps_ns
                    or self.imu_clock_drift_ppm)

    @property
    def imu_faults(self):
        """True when any fault acts on the IMU's samples or stamps."""
        return bool(self.imu_dropouts_ns or self.imu_burst_ns or self.imu_stamp_offset_ns
                    or self.clock_jumps_ns or self.imu_clock_drift_ppm)

    @property
    def camera_faults(self):
        """True when any fault acts on the camera's frames or stamps."""
        return bool(self.camera_dropouts_ns or self.clock_jumps_ns)

    def describe(self):
        """One line naming every configured fault ('' when none), for a start-up log."""
        parts = []
        if self.imu_dropouts_ns:
            parts.append(f'IMU dropouts {_describe_windows(self.imu_dropouts_ns)}')
        if self.camera_dropouts_ns:
            parts.append(f'camera dropouts {_describe_windows(self.camera_dropouts_ns)}')
        if self.imu_burst_ns:
            parts.append(f'IMU bursts every {self.imu_burst_ns / NS_PER_S:g} s')
        if self.imu_stamp_offset_ns:
            parts.append(f'IMU stamps {self.imu_stamp_offset_ns / NS_PER_S:+g} s')
        if self.imu_clock_drift_ppm:
            parts.append(f'IMU clock drift {self.imu_clock_drift_ppm:+.2f} ppm')
        if self.clock_jumps_ns:
            parts.append('sensor clock jumps ' + ', '.join(
                f'{j / NS_PER_S:+g} s at {a / NS_PER_S:g} s' for a, j in self.clock_jumps_ns))
        return '; '.join(parts)

    # --- the schedule -------------------------------------------------------------------
    def imu_dropped(self, t_ns):
        """True if the IMU sample of true time ``t_ns`` (ns since the start) is lost."""
        return _in_any(self.imu_dropouts_ns, t_ns)

    def camera_dropped(self, t_ns):
        """True if the camera frame of true time ``t_ns`` publishes no image/camera_info."""
        return _in_any(self.camera_dropouts_ns, t_ns)

    def clock_jump_ns(self, t_ns):
        """Sum of the sensor clock jumps at or before true time ``t_ns``, ns."""
        return sum(jump for at, jump in self.clock_jumps_ns if at <= t_ns)

    def sensor_stamp_ns(self, stamp_ns, t_ns):
        """Published stamp of a camera, photodiode or truth message.

        Parameters
        ----------
        stamp_ns : int
            The true stamp (epoch + t), ns.
        t_ns : int
            True time since the start, ns.
        """
        return stamp_ns + self.clock_jump_ns(t_ns) if self.clock_jumps_ns else stamp_ns

    def imu_stamp_ns(self, stamp_ns, t_ns):
        """Published stamp of an IMU sample: the sensor stamp plus the IMU's offset and
        drift.
        """
        stamp = self.sensor_stamp_ns(stamp_ns, t_ns) + self.imu_stamp_offset_ns
        if self.imu_clock_drift_ppm:
            stamp += int(round(self.imu_clock_drift_ppm * 1e-6 * t_ns))
        return stamp

    def imu_release_ns(self, t_ns):
        """Simulated time from which the IMU sample of true time ``t_ns`` may be published:
        ``t_ns`` itself, or with bursts the first burst boundary strictly after it.
        """
        if not self.imu_burst_ns:
            return t_ns
        return (t_ns // self.imu_burst_ns + 1) * self.imu_burst_ns

    def imu_burst_samples(self, rate_hz):
        """Most samples one burst holds at ``rate_hz`` (0 without bursts)."""
        if not self.imu_burst_ns:
            return 0
        return math.ceil(self.imu_burst_ns * rate_hz / NS_PER_S) + 1

    def check_epoch(self, epoch_ns):
        """Raise ValueError if a fault would make a stamp negative (before 1970)."""
        lowest = min(0, self.imu_stamp_offset_ns)
        cumulative = 0
        for at, jump in self.clock_jumps_ns:
            cumulative += jump
            lowest = min(lowest, at + cumulative + min(0, self.imu_stamp_offset_ns))
        if epoch_ns + lowest < 0:
            raise ValueError(f'sensor_clock_jumps_s / imu_stamp_offset_s step the sensor '
                             f'clock {-lowest / NS_PER_S:g} s back, before the Unix epoch '
                             f'(epoch_s = {epoch_ns / NS_PER_S:g} s)')
