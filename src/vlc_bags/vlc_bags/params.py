"""Parameter declaration helpers shared by the bag nodes (rclpy)."""
from __future__ import annotations

from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor
from rclpy.node import Node
from rclpy.parameter import Parameter


def declare(node: Node, name: str, default, description: str, *,
            float_range: tuple[float, float] | None = None,
            int_range: tuple[int, int] | None = None):
    """Declare a parameter with a descriptor and return its value.

    ``default`` may be ``Parameter.Type.STRING_ARRAY`` for a string list that defaults to
    empty (rclpy cannot infer a type from ``[]``); its value is then a tuple.
    """
    descriptor = ParameterDescriptor(description=description)
    if float_range is not None:
        descriptor.floating_point_range = [FloatingPointRange(
            from_value=float(float_range[0]), to_value=float(float_range[1]))]
    if int_range is not None:
        descriptor.integer_range = [IntegerRange(from_value=int(int_range[0]),
                                                 to_value=int(int_range[1]))]
    value = node.declare_parameter(name, default, descriptor).value
    if default is Parameter.Type.STRING_ARRAY:
        return tuple(value or ())
    return value
