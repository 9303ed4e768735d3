"""Left and right images paired by their identical stamps, the newest complete pair first.

Both image nodes (decoder, spot locator) take a stereo pair only once both halves have
arrived, and when they fall behind (a busy machine, a stall) they work on the newest
complete pair and drop every older image instead of working through a backlog: the lag
behind the camera stays bounded by one pair's processing. Every image that is not
processed is counted by why.
"""
from collections import OrderedDict
from dataclasses import dataclass


@dataclass
class PairingStats:
    """Images left unprocessed since start, by cause."""

    unpaired: int = 0         # its partner never came (dropped when newer pairs completed)
    superseded: int = 0       # complete pairs dropped for a newer complete pair (lag)
    out_of_order: int = 0     # not newer than the last pair handed over
    stamp_resets: int = 0     # stamps jumped back by more than the reset threshold


class StereoPairing:
    """Pairs images of two sides (0 left, 1 right) by exact stamp (integer ns).

    Parameters
    ----------
    max_pending : int
        Unpaired stamps kept while waiting for their other half; the oldest beyond this
        are dropped as unpaired.
    backward_reset_ns : int
        A stamp this much older than the last pair handed over (a looped bag, a
        restarted camera) clears the pairing and starts afresh; a smaller step back is
        out of order and dropped.
    """

    def __init__(self, max_pending=10, backward_reset_ns=1_000_000_000):
        self.max_pending = int(max_pending)
        self.backward_reset_ns = int(backward_reset_ns)
        self.stats = PairingStats()
        self._pending = OrderedDict()      # stamp → [left, right], in arrival order
        self.last_stamp_ns = None          # the last pair handed over

    def add(self, side, stamp_ns, item):
        """Keep one image; returns ``'reset'`` when its stamp jumped back far enough to
        restart the pairing (the caller resets what depends on the timeline),
        ``'out_of_order'`` when it is not newer than the last pair handed over (dropped),
        else None.
        """
        stamp_ns = int(stamp_ns)
        event = None
        if (self.last_stamp_ns is not None
                and self.last_stamp_ns - stamp_ns > self.backward_reset_ns):
            self.stats.unpaired += sum(1 for halves in self._pending.values()
                                       for h in halves if h is not None)
            self._pending.clear()
            self.last_stamp_ns = None
            self.stats.stamp_resets += 1
            event = 'reset'
        if self.last_stamp_ns is not None and stamp_ns <= self.last_stamp_ns:
            self.stats.out_of_order += 1
            return 'out_of_order'
        halves = self._pending.setdefault(stamp_ns, [None, None])
        halves[side] = item
        while len(self._pending) > self.max_pending:
            _, old = self._pending.popitem(last=False)
            self.stats.unpaired += sum(h is not None for h in old)
        return event

    def newest_pair(self):
        """(stamp_ns, left, right) of the newest complete pair, or None. Every image older
        than it is dropped (a complete pair as superseded, a lone half as unpaired).
        """
        complete = [s for s, (left, right) in self._pending.items()
                    if left is not None and right is not None]
        if not complete:
            return None
        stamp = max(complete)
        for old in [s for s in self._pending if s < stamp]:
            halves = self._pending.pop(old)
            if halves[0] is not None and halves[1] is not None:
                self.stats.superseded += 2
            else:
                self.stats.unpaired += 1
        left, right = self._pending.pop(stamp)
        self.last_stamp_ns = stamp
        return stamp, left, right
