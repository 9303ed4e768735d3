"""A lone stamp from another time base is an outlier; only a sustained change is a new base.

A sensor stream's stamps advance in small steps. A stamp far before the newest one (a
message stamped 1970, a sender with an unset clock) or far after it (a clock set to the
future) is either one bad message or the start of a new time base: a looped bag, a
restarted sensor, a clock corrected by seconds. Acting on the first such stamp — a node
resetting its pairing, filter or history — lets one bad message destroy good state.
:class:`StampGuard` tells the two apart: a stamp outside the window around the newest
accepted one is *held*; ``confirm_count`` consecutive held stamps that agree with each
other (each within the window of the one before) confirm a new time base and are all
released, in order, for the node to act on (a jump back then restarts what depends on the
timeline, as before); a stamp inside the window in the meantime means the held ones were
outliers: they are dropped and counted. Nothing of a real change is lost, and a lone
outlier never reaches the node's state.
"""
from dataclasses import dataclass

NS_PER_S = 1_000_000_000


@dataclass
class GuardStats:
    """Stamps by fate since start."""

    accepted: int = 0          # inside the window, handed on at once
    outliers: int = 0          # held and then dropped (a stamp inside the window came)
    rebases: int = 0           # confirmed new time bases
    rebases_back: int = 0      # ... of which jumped back


@dataclass
class GuardResult:
    """What to do after one stamp.

    Attributes
    ----------
    released : list of (stamp_ns, item)
        Hand these on now, in order (the stamp itself, or a confirmed run of held ones).
    dropped : list of (stamp_ns, item)
        Held stamps found to be outliers: drop them (count, warn).
    rebased : int
        0, or the jump of a confirmed new time base (first released stamp minus the
        newest stamp before it), ns: negative when time jumped back.
    """

    released: list
    dropped: list
    rebased: int = 0

    @property
    def held(self):
        """True when the stamp was held (neither released nor dropped yet)."""
        return not self.released


class StampGuard:
    """Lone outliers dropped, sustained time-base changes confirmed; see the module
    docstring.

    Parameters
    ----------
    max_backward_ns : int
        A stamp this much or less before the newest accepted one is inside the window
        (the node decides about a small step back: out of order, duplicate).
    max_forward_ns : int
        A stamp this much or less after the newest accepted one is inside the window.
    confirm_count : int
        Consecutive stamps outside the window, each inside the window of the one before,
        that confirm a new time base (>= 1; 1 acts on every stamp as it comes).
    """

    def __init__(self, max_backward_ns, max_forward_ns, confirm_count=3):
        if confirm_count < 1 or max_backward_ns < 0 or max_forward_ns < 0:
            raise ValueError('confirm_count must be >= 1 and the window non-negative')
        self.max_backward_ns = int(max_backward_ns)
        self.max_forward_ns = int(max_forward_ns)
        self.confirm_count = int(confirm_count)
        self.stats = GuardStats()
        self.newest_ns = None
        self._held = []

    @classmethod
    def from_seconds(cls, max_backward_s, max_forward_s, confirm_count=3):
        return cls(round(max_backward_s * NS_PER_S), round(max_forward_s * NS_PER_S),
                   confirm_count)

    def reset(self):
        """Forget the time base (the next stamp starts one)."""
        self.newest_ns = None
        self._held = []

    @property
    def held_count(self):
        return len(self._held)

    def _inside(self, stamp_ns, reference_ns, floor_ns=None):
        low = reference_ns if floor_ns is None else min(reference_ns, int(floor_ns))
        return low - self.max_backward_ns <= stamp_ns <= reference_ns + self.max_forward_ns

    def push(self, stamp_ns, item=None, floor_ns=None):
        """Judge one stamp; returns a :class:`GuardResult`.

        ``floor_ns``: measure the window's lower edge from this stamp instead of the
        newest one when it is older (the stereo pairing passes its last pair handed
        over: one camera's images may lag the other's by a few frames).
        """
        stamp_ns = int(stamp_ns)
        if self.newest_ns is None or self._inside(stamp_ns, self.newest_ns, floor_ns):
            dropped, self._held = self._held, []
            self.stats.outliers += len(dropped)
            self.stats.accepted += 1
            self.newest_ns = stamp_ns if self.newest_ns is None else max(self.newest_ns,
                                                                         stamp_ns)
            return GuardResult([(stamp_ns, item)], dropped)
        dropped = []
        if self._held and not self._inside(stamp_ns, self._held[-1][0]):
            dropped, self._held = self._held, []
            self.stats.outliers += len(dropped)
        self._held.append((stamp_ns, item))
        if len(self._held) < self.confirm_count:
            return GuardResult([], dropped)
        released, self._held = self._held, []
        jump = released[0][0] - self.newest_ns
        self.newest_ns = max(s for s, _ in released)
        self.stats.rebases += 1
        self.stats.rebases_back += jump < 0
        self.stats.accepted += len(released)
        return GuardResult(released, dropped, jump)
