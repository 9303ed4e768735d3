"""Warnings throttled per kind before they reach rclpy's logger.

rclpy's ``throttle_duration_sec`` is checked in rcutils *after* the Python logger has
located its caller with ``inspect.getframeinfo`` (and after the caller has formatted the
message), paid on every call: a 400 Hz node warning about every IMU gap while the
machine is short of CPU spent a sizeable share of its time there and fell further
behind. :class:`ThrottledWarnings` decides in Python first, formats only what is logged,
throttles each kind on its own (rclpy's throttle is per call site, so one kind cannot
hide another here) and says how many were suppressed.
"""
import time


class ThrottledWarnings:
    """At most one warning per ``period_s`` (``clock`` seconds) for each kind.

    ``warn(kind, text)``: ``text`` is a string or a callable returning one (called only
    when the warning is logged). Returns True when it was logged.
    """

    def __init__(self, logger, period_s, clock=time.monotonic):
        self._logger = logger
        self._period_s = float(period_s)
        self._clock = clock
        self._last = {}
        self._suppressed = {}

    def warn(self, kind, text):
        now = self._clock()
        last = self._last.get(kind)
        if last is not None and now - last < self._period_s:
            self._suppressed[kind] = self._suppressed.get(kind, 0) + 1
            return False
        self._last[kind] = now
        n = self._suppressed.pop(kind, 0)
        message = text() if callable(text) else text
        self._logger.warning(message + (f' (+{n} more since the last one)' if n else ''))
        return True

    def suppressed(self, kind):
        """Warnings of ``kind`` suppressed since the last one logged."""
        return self._suppressed.get(kind, 0)
