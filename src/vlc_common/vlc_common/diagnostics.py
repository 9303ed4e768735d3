"""diagnostic_msgs built the same way by every node."""
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue


def diagnostic_status(name, hardware_id, level, message, values):
    """DiagnosticStatus with ``values`` (dict) as string KeyValues; ``level`` a
    DiagnosticStatus constant (OK, WARN, ...) or its int value.
    """
    if not isinstance(level, bytes):
        level = bytes([int(level)])
    status = DiagnosticStatus(level=level, name=name, message=message,
                              hardware_id=hardware_id)
    status.values = [KeyValue(key=str(k), value=str(v)) for k, v in values.items()]
    return status


def diagnostic_array(stamp, name, hardware_id, level, message, values):
    """A DiagnosticArray stamped ``stamp`` with one :func:`diagnostic_status`."""
    msg = DiagnosticArray()
    msg.header.stamp = stamp
    msg.status = [diagnostic_status(name, hardware_id, level, message, values)]
    return msg
