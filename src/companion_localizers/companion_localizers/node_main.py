"""The one ``main()`` of the companion nodes: start, spin, stop cleanly.

Invalid parameters end the process with exit code 2 and a fatal log line (as the rig's
nodes); SIGINT or an external shutdown ends it with 0.
"""
import rclpy
from rclpy.exceptions import ParameterException
from rclpy.executors import ExternalShutdownException

from vlc_common.process import spin_until_shutdown

#: Exit code of an invalid configuration.
EXIT_INVALID_CONFIG = 2


def run_node(node_class, logger_name, args=None):
    """Create ``node_class()`` and spin it; returns the process exit code."""
    rclpy.init(args=args)
    try:
        node = node_class()
    except (ValueError, OSError, ParameterException) as exc:
        rclpy.logging.get_logger(logger_name).fatal(f'invalid parameter: {exc}')
        rclpy.try_shutdown()
        return EXIT_INVALID_CONFIG
    try:
        spin_until_shutdown(lambda: rclpy.spin(node))
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        node.destroy_node()
        rclpy.try_shutdown()
    return 0
