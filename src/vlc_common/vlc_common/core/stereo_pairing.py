"""Left and right images paired by their identical stamps, the newest complete pairs first.

Both image nodes (decoder, spot locator) take a stereo pair only once both halves have
arrived. When they fall behind (a busy machine, a stall) they work on the newest
``catch_up_pairs`` complete pairs, oldest first, and drop every older image instead of
working through the whole backlog: a short stall (up to ``catch_up_pairs`` frame periods)
costs no frame, and the lag behind the camera stays bounded by that many pairs'
processing. Every image that is not processed is counted by why.

Stamps pass a :class:`~vlc_common.core.stamp_guard.StampGuard` (one for both sides)
first: an image stamped far from the stream (1970, the far future) is held, and dropped
as an outlier when the stream goes on; only ``confirm_count`` consecutive images of a new
time base (a looped bag, a restarted camera) are handed on, and a jump back then restarts
the pairing. One bad stamp costs its own image, never the pairing.
"""
from collections import OrderedDict
from dataclasses import dataclass

from vlc_common.core.stamp_guard import NS_PER_S, StampGuard


@dataclass
class PairingStats:
    """Images left unprocessed since start, by cause."""

    unpaired: int = 0         # its partner never came (dropped when newer pairs completed)
    superseded: int = 0       # complete pairs dropped for a newer complete pair (lag)
    out_of_order: int = 0     # not newer than the last pair handed over
    stamp_resets: int = 0     # a confirmed new time base jumped back: pairing restarted
    stamp_outliers: int = 0   # stamped far from the stream (held, then dropped)


class StereoPairing:
    """Pairs images of two sides (0 left, 1 right) by exact stamp (integer ns).

    Parameters
    ----------
    max_pending : int
        Unpaired stamps kept while waiting for their other half; the oldest beyond this
        are dropped as unpaired.
    backward_reset_ns : int
        An image stamped more than this before the last pair handed over (or the newest
        image, if that is older) is held as a possible outlier (see the module
        docstring); once a new time base this far back is
        confirmed (a looped bag, a restarted camera) the pairing is cleared and starts
        afresh. A smaller step back is out of order and dropped.
    forward_jump_ns : int
        An image stamped more than this after the newest one is held the same way.
    confirm_count : int
        Consecutive images of a new time base that confirm it.
    """

    def __init__(self, max_pending=10, backward_reset_ns=NS_PER_S, forward_jump_ns=NS_PER_S,
                 confirm_count=3):
        self.max_pending = int(max_pending)
        self.backward_reset_ns = int(backward_reset_ns)
        self.guard = StampGuard(backward_reset_ns, forward_jump_ns, confirm_count)
        self.stats = PairingStats()
        self._pending = OrderedDict()      # stamp → [left, right], in arrival order
        self.last_stamp_ns = None          # the last pair handed over

    def add(self, side, stamp_ns, item):
        """Offer one image; returns the list of what happened, in order (usually empty):
        ``'outlier'`` for each held image dropped as an outlier, ``'reset'`` when a
        confirmed new time base jumped back and the pairing restarted (the caller resets
        what depends on the timeline), ``'out_of_order'`` for each image not newer than
        the last pair handed over (dropped).
        """
        result = self.guard.push(stamp_ns, (side, item), self.last_stamp_ns)
        events = ['outlier'] * len(result.dropped)
        self.stats.stamp_outliers += len(result.dropped)
        if result.rebased < 0:
            self.stats.unpaired += sum(1 for halves in self._pending.values()
                                       for h in halves if h is not None)
            self._pending.clear()
            self.last_stamp_ns = None
            self.stats.stamp_resets += 1
            events.append('reset')
        for stamp, (image_side, image) in result.released:
            if self.last_stamp_ns is not None and stamp <= self.last_stamp_ns:
                self.stats.out_of_order += 1
                events.append('out_of_order')
                continue
            halves = self._pending.setdefault(stamp, [None, None])
            halves[image_side] = image
            while len(self._pending) > self.max_pending:
                _, old = self._pending.popitem(last=False)
                self.stats.unpaired += sum(h is not None for h in old)
        return events

    def add_many(self, images):
        """Offer images taken together, ``(side, stamp_ns, item)`` each (what arrived on
        both sides while the node was busy), in stamp order rather than as given: every
        left before every right would put a backlog's older rights behind the newest left
        by more than a small ``backward_reset_ns`` and hold them as outliers. Returns the
        events of :meth:`add`, in order.
        """
        events = []
        for side, stamp_ns, item in sorted(images, key=lambda image: image[1]):
            events += self.add(side, stamp_ns, item)
        return events

    def newest_pair(self):
        """(stamp_ns, left, right) of the newest complete pair, or None. Every image older
        than it is dropped (a complete pair as superseded, a lone half as unpaired).
        """
        pairs = self.complete_pairs(1)
        return pairs[0] if pairs else None

    def complete_pairs(self, max_pairs=1):
        """The newest ``max_pairs`` complete pairs ``[(stamp_ns, left, right), ...]``,
        oldest first (empty when none is complete). Every image older than the newest of
        them that is not among them is dropped: a complete pair as superseded, a lone half
        as unpaired (its partner would have come before the newer pair's, each side's
        images arrive in order).
        """
        if max_pairs < 1:
            raise ValueError(f'max_pairs must be >= 1, not {max_pairs}')
        complete = sorted(s for s, (left, right) in self._pending.items()
                          if left is not None and right is not None)
        if not complete:
            return []
        keep = complete[-max_pairs:]
        kept = set(keep)
        newest = keep[-1]
        for old in [s for s in self._pending if s < newest and s not in kept]:
            halves = self._pending.pop(old)
            if halves[0] is not None and halves[1] is not None:
                self.stats.superseded += 2
            else:
                self.stats.unpaired += 1
        self.last_stamp_ns = newest
        return [(stamp, *self._pending.pop(stamp)) for stamp in keep]
