"""ParameterDescriptor construction shared by every node of the graph.

Each node declares its parameters from a table of (name, default, descriptor); this
builds the descriptor: a description and, for numbers, the allowed range.
"""
from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor


def descriptor(text, lo=None, hi=None, *, integer=False, ptype=None):
    """ParameterDescriptor with ``text``, an optional type, and the range [lo, hi].

    The range is an IntegerRange (step 1) when ``integer``, else a FloatingPointRange
    (step 0: any value); none when ``lo`` is None.
    """
    d = ParameterDescriptor(description=text)
    if ptype is not None:
        d.type = ptype
    if lo is not None:
        if integer:
            d.integer_range = [IntegerRange(from_value=int(lo), to_value=int(hi), step=1)]
        else:
            d.floating_point_range = [FloatingPointRange(from_value=float(lo),
                                                         to_value=float(hi), step=0.0)]
    return d
