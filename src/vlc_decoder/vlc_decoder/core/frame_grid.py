"""Frame times on the camera's own period, for the packet assembly across frames.

A driver that stamps a frame when its transfer ends spreads the stamps by 0.1–1 ms; the
lamp packet is assembled across frames on the frames' times, and a chip lasts 47 µs
(21 150 chips/s): 20 µs of jitter already keeps a far lamp's packet from completing. The
camera exposes on its own crystal clock, one frame per period. :class:`FrameGrid`
numbers the frames from the stamp gaps (``k``, dropped frames skipped) and gives each
lamp track a timeline of its own: the stamp of the track's first frame plus
``(k − k₀)·period``. Within a track the times are then exact multiples of the period:
the first stamp's error is a constant shift, the period's error (a crystal's ±50 ppm) a
rate, and the assembly fits both per lamp anyway (the lamp's phase and clock rate).

The period is the camera's configured frame rate (``frame_rate_hz``), checked against
the median of the first :data:`CHECK_GAPS` stamp gaps: more than
:data:`PERIOD_TOLERANCE` off (the tracker then drops its tracks, whose first fragments
were placed on the wrong period), or 0, and the stamps are used as they are. A gap off the
grid (a quarter period) restarts the numbering and every track's timeline (a camera
restart, a time jump). A timeline within ``keep_within_ns`` of the stamp gives the
stamp itself (the rig's ideal camera, stamped at exposure, is used as it always was).
"""
import numpy as np

CHECK_GAPS = 8
PERIOD_TOLERANCE = 0.01


class FrameGrid:
    """Frame numbers of a stamped frame stream and per-track timelines on them."""

    def __init__(self, frame_rate_hz=0.0, keep_within_ns=1000):
        self.period_ns = 1e9 / frame_rate_hz if frame_rate_hz > 0.0 else None
        self.keep_within_ns = int(keep_within_ns)
        self.checked = None      # None until CHECK_GAPS gaps; then whether the period fits
        self._gaps = []
        self.epoch = 0           # increases whenever the numbering restarts
        self.reset()

    def reset(self):
        """Restart the numbering (the next frame is frame 0 of a new epoch)."""
        self.k = None
        self._last_ns = None
        self.epoch += 1

    @property
    def usable(self):
        """Whether the period is known and the stamps have not contradicted it."""
        return self.period_ns is not None and self.checked is not False

    def add(self, stamp_ns):
        """Number the frame stamped ``stamp_ns``; returns its frame number."""
        stamp_ns = int(stamp_ns)
        if self._last_ns is not None and self.period_ns is not None:
            gap = stamp_ns - self._last_ns
            n = round(gap / self.period_ns)
            if n < 1 or abs(gap - n * self.period_ns) > 0.25 * self.period_ns:
                self.reset()
            else:
                if self.checked is None:
                    self._gaps.append(gap / n)
                    if len(self._gaps) >= CHECK_GAPS:
                        median = float(np.median(self._gaps))
                        self.checked = (abs(median - self.period_ns)
                                        <= PERIOD_TOLERANCE * self.period_ns)
                self.k += n
                self._last_ns = stamp_ns
                return self.k
        self.k = 0
        self._last_ns = stamp_ns
        return self.k

    def anchor(self, stamp_ns):
        """A timeline that starts at this frame: (epoch, k, stamp_ns)."""
        return (self.epoch, self.k, int(stamp_ns))

    def time_ns(self, anchor, stamp_ns):
        """(time ns, anchor) of the current frame on the timeline ``anchor``: a timeline
        of another epoch (or none) starts again at this frame.
        """
        stamp_ns = int(stamp_ns)
        if not self.usable:
            return stamp_ns, None
        if anchor is None or anchor[0] != self.epoch:
            return stamp_ns, self.anchor(stamp_ns)
        t = anchor[2] + int(round((self.k - anchor[1]) * self.period_ns))
        return (stamp_ns if abs(t - stamp_ns) <= self.keep_within_ns else t), anchor
