"""Continuity of the sensor clock: which stamps the localizer may use, and when time restarted.

The localizer's history, gaps and replays assume one continuous sensor clock. Each of
its two input streams (``imu/data`` samples and lamp frames) is checked here before it is
used. A stamp is a *time-base candidate* instead of a usable one when it is

* older than the stream's newest stamp by more than ``imu_backward_s`` (IMU: one
  publisher's samples never come out of order, so anything but a duplicate is a clock
  that went back) or ``backward_reset_s`` (frames: two perception nodes finish frames
  out of order, and a late frame is applied where it belongs; a frame that much older
  than the newest IMU sample too, unless it continues the frame stream: frames queued
  behind an IMU backlog the node worked off first are late, not from another clock): a
  restarted or stepped sensor clock, a looped bag, a stamp from 1970;
* newer than the newest stamp of *both* streams by more than ``blind_gap_s``: nothing
  was received for that long (a stalled process whose queues overflowed, a clock stepped
  forward, a corrupt stamp from the future). What happened meanwhile cannot be vouched
  for. Shorter gaps of both streams are bridged by the localizer, which cannot tell a
  stall from a clock stepped forward either and widens the chainage accordingly.

A lone candidate (one corrupt stamp) is dropped and counted: it moves nothing. When
``confirm_count`` consecutive candidates of a stream agree with each other (each newer
than the previous by at most ``blind_gap_s``), the time base has changed: the localizer
resets (its state is *lost*: nothing is published until a confirmed lamp initialises it
again) and the held candidates are used on the new time base. Smaller steps back are
out of order (IMU samples skipped; frames applied as late measurements where the history
allows) and smaller gaps forward are gaps (the acceleration over them is unknown).

Stamps and reception times are integer ns; no ROS here.
"""
from dataclasses import dataclass, field

from vlc_common.core.observation import NS_PER_S

IMU, FRAME = 'imu', 'frame'

OK = 'ok'                    # use it
OUT_OF_ORDER = 'out_of_order'  # a little older than the stream's newest
HELD = 'held'                # a time-base candidate, held until confirmed or dropped
RESET = 'reset'              # candidates confirmed a new time base: reset, then use them


@dataclass
class TimeBaseConfig:
    """Attributes
    ----------
    backward_reset_s : float
        A frame older than the newest frame by more than this is a candidate, s.
    imu_backward_s : float
        An IMU sample older than the newest sample by more than this is a candidate, s.
    blind_gap_s : float
        A stamp newer than the newest of both streams by more than this is a
        candidate, s.
    confirm_imu : int
        Consecutive agreeing IMU candidates that confirm a new time base.
    confirm_frames : int
        Consecutive agreeing frame candidates that confirm a new time base.
    """

    backward_reset_s: float = 1.0
    imu_backward_s: float = 0.05
    blind_gap_s: float = 3.0
    confirm_imu: int = 10
    confirm_frames: int = 3

    def __post_init__(self):
        for name in ('backward_reset_s', 'imu_backward_s', 'blind_gap_s'):
            value = getattr(self, name)
            if not value > 0.0:
                raise ValueError(f'{name} must be > 0, got {value}')
        for name in ('confirm_imu', 'confirm_frames'):
            if int(getattr(self, name)) < 1:
                raise ValueError(f'{name} must be >= 1, got {getattr(self, name)}')


@dataclass
class _Stream:
    newest_ns: int = None            # newest usable stamp
    held: list = field(default_factory=list)   # [(stamp_ns, item)]


@dataclass
class TimeBaseCounters:
    dropped: int = 0     # lone candidates dropped
    resets: int = 0      # confirmed new time bases


class TimeBaseMonitor:
    """Per-stream continuity check; see the module docstring.

    :meth:`check` classifies a stamp; the caller acts on the verdict (and on ``RESET``
    calls :meth:`reset_streams`, then feeds :meth:`take_held` again).
    """

    def __init__(self, config=None):
        self.config = config or TimeBaseConfig()
        self.counters = TimeBaseCounters()
        self.last_reason = ''
        self._streams = {IMU: _Stream(), FRAME: _Stream()}

    def newest_ns(self, stream):
        return self._streams[stream].newest_ns

    def reset_streams(self):
        """Forget the newest stamps (held candidates are kept for :meth:`take_held`)."""
        for s in self._streams.values():
            s.newest_ns = None

    def take_held(self, stream):
        """The held candidates ``[(stamp_ns, item)]`` of a stream, cleared."""
        held, self._streams[stream].held = self._streams[stream].held, []
        return held

    def _newest_any(self):
        stamps = [s.newest_ns for s in self._streams.values() if s.newest_ns is not None]
        return max(stamps) if stamps else None

    def _why_candidate(self, stream, t):
        cfg = self.config
        s = self._streams[stream]
        back_s = cfg.imu_backward_s if stream == IMU else cfg.backward_reset_s
        if s.newest_ns is not None and s.newest_ns - t > back_s * NS_PER_S:
            return f'{stream} stamp {(s.newest_ns - t) * 1e-9:.3f} s older than the newest'
        imu = self._streams[IMU].newest_ns
        # A frame that continues the frame stream (within backward_reset_s of its newest)
        # is on the frame stream's time base however far the IMU is ahead: the node worked
        # off an IMU backlog (a stalled IMU catching up) before the frames queued behind it.
        continues = s.newest_ns is not None and t - s.newest_ns <= back_s * NS_PER_S
        if (stream == FRAME and not continues and imu is not None
                and imu - t > cfg.backward_reset_s * NS_PER_S):
            return f'frame stamp {(imu - t) * 1e-9:.3f} s older than the newest IMU sample'
        newest = self._newest_any()
        if newest is not None and t - newest > cfg.blind_gap_s * NS_PER_S:
            return f'{stream} stamp {(t - newest) * 1e-9:.3f} s after the newest input'
        return None

    def check(self, stream, t, item=None):
        """Verdict on stamp ``t`` (ns) of ``stream``: ``OK`` (it becomes the stream's
        newest), ``OUT_OF_ORDER`` (not newer than the newest), ``HELD`` (``item`` is kept
        with it) or ``RESET`` (then :meth:`reset_streams` and feed :meth:`take_held`).
        """
        s = self._streams[stream]
        t = int(t)
        why = self._why_candidate(stream, t)
        if why is None:
            if s.held:
                self.counters.dropped += len(s.held)
                s.held.clear()
            if s.newest_ns is not None and t <= s.newest_ns:
                return OUT_OF_ORDER
            s.newest_ns = t
            return OK
        cfg = self.config
        if s.held and not (s.held[-1][0] < t <= s.held[-1][0] + cfg.blind_gap_s * NS_PER_S):
            self.counters.dropped += len(s.held)
            s.held.clear()
        s.held.append((t, item))
        need = cfg.confirm_imu if stream == IMU else cfg.confirm_frames
        if len(s.held) < need:
            self.last_reason = why
            return HELD
        self.counters.resets += 1
        self.last_reason = why
        return RESET
