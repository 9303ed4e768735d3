"""IMU samples handed to the filter no further ahead of the frames than they need to be.

The node takes IMU samples in batches (a polled subscription) and frames one by one
(executor callbacks). After an IMU stall the IMU catches up with seconds of samples at
once; handed on in one go, they carry the filter's time seconds past the frames still
queued behind them: it coasts ("no lamp fix for 1 s") on frames it has not yet looked
at, then finds them older than its history window and drops them (fault table, 'IMU
process stalled'). :class:`ImuPacer` keeps the samples that are more than ``lead_s``
ahead of the newest frame taken and releases them as frames come, so IMU and frames
reach the filter in nearly the order of their stamps. When no frame has been taken for
``silence_s`` (steady clock, not counting the time the node spent on released samples:
a camera dropout, a stalled perception node) or the backlog
exceeds ``max_backlog`` samples (an IMU clock far ahead of the camera's), samples go on
regardless: the filter coasts on the IMU, as it must.

Stamps in integer ns, times in seconds of a steady clock; no ROS here.
"""
from collections import deque
from dataclasses import dataclass

NS_PER_S = 1_000_000_000


@dataclass(frozen=True)
class ImuPacingConfig:
    """Attributes
    ----------
    lead_s : float
        IMU samples up to this far past the newest frame are released at once, s.
    silence_s : float
        With no frame taken for this long (steady clock), every sample is released, s.
    max_backlog : int
        Samples held at most; the oldest go on beyond it.
    """

    lead_s: float = 0.5
    silence_s: float = 0.5
    max_backlog: int = 2000

    def __post_init__(self):
        if not (self.lead_s > 0.0 and self.silence_s > 0.0 and self.max_backlog >= 1):
            raise ValueError('lead_s and silence_s must be > 0 and max_backlog >= 1')


class ImuPacer:
    """Holds IMU samples that are too far ahead of the frames; see the module docstring."""

    def __init__(self, config=None):
        self.config = config or ImuPacingConfig()
        self._backlog = deque()           # (stamp_ns, item), in arrival order
        self._frame_ns = None              # stamp of the newest frame taken
        self._frame_at_s = None            # steady time it was taken
        self.held_max = 0                  # the largest backlog so far (diagnostics)

    def __len__(self):
        return len(self._backlog)

    def reset(self):
        """Forget the frame time base (a new one began); held samples stay in order."""
        self._frame_ns = None
        self._frame_at_s = None

    def on_frame(self, stamp_ns, now_s):
        """A frame stamped ``stamp_ns`` was taken at steady time ``now_s``."""
        self._frame_ns = int(stamp_ns)
        self._frame_at_s = float(now_s)

    def credit(self, busy_s):
        """The node spent ``busy_s`` handing on released samples: no frame could be
        taken meanwhile, so that time is not silence of the frames.
        """
        if self._frame_at_s is not None and busy_s > 0.0:
            self._frame_at_s += float(busy_s)

    def push(self, stamp_ns, item):
        self._backlog.append((int(stamp_ns), item))
        self.held_max = max(self.held_max, len(self._backlog))

    def release(self, now_s):
        """The held items to hand on now, in arrival order."""
        cfg = self.config
        out = []
        while len(self._backlog) > cfg.max_backlog:
            out.append(self._backlog.popleft()[1])
        if (self._frame_ns is None or self._frame_at_s is None
                or now_s - self._frame_at_s > cfg.silence_s):
            limit = None
        else:
            limit = self._frame_ns + int(round(cfg.lead_s * NS_PER_S))
        while self._backlog and (limit is None or self._backlog[0][0] <= limit):
            out.append(self._backlog.popleft()[1])
        return out
