"""ROS time stamps ↔ integer nanoseconds and seconds, one definition for every node.

Stamps are handled as integer nanoseconds wherever they are joined or compared (exact),
and as float seconds only for arithmetic on short intervals.
"""
from fractions import Fraction

from builtin_interfaces.msg import Time
from std_msgs.msg import Header

NS_PER_S = 1_000_000_000


def stamp_to_ns(stamp):
    """builtin_interfaces/Time → integer nanoseconds."""
    return int(stamp.sec) * NS_PER_S + int(stamp.nanosec)


def stamp_to_s(stamp):
    """builtin_interfaces/Time → float seconds (``sec + nanosec·1e-9``)."""
    return stamp.sec + stamp.nanosec * 1e-9


def ns_to_stamp(ns):
    """Integer nanoseconds → builtin_interfaces/Time."""
    sec, nanosec = divmod(int(ns), NS_PER_S)
    return Time(sec=sec, nanosec=nanosec)


def header(ns, frame_id):
    """std_msgs/Header stamped ``ns`` (integer nanoseconds) in ``frame_id``."""
    return Header(stamp=ns_to_stamp(ns), frame_id=frame_id)


def epoch_to_ns(epoch_s):
    """A clock epoch (float seconds) in integer nanoseconds, whole seconds kept exact."""
    whole = int(epoch_s // 1)
    return whole * NS_PER_S + int(round((epoch_s - whole) * NS_PER_S))


def sample_stamp_ns(epoch_ns, index, rate_hz):
    """Stamp of sample ``index`` of a sensor at ``rate_hz``: epoch + index / rate, in ns.

    Computed in exact rational arithmetic and rounded to the nanosecond once, so stamps
    never accumulate a period's rounding error (at 400 Hz they are exactly 2 500 000 ns
    apart, at 2460 Hz 406 504 or 406 505 ns).
    """
    return epoch_ns + round(int(index) * Fraction(NS_PER_S) / Fraction(rate_hz))
