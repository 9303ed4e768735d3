"""A node's QoS event handlers taken off the executor's wait set and polled once a second.

rclpy gives every publisher and subscription two default event handlers (a warning when
a peer with incompatible QoS or an incompatible type appears), each a waitable that
rclpy's executor adds to its wait set, asks whether it is ready and walks through its
Python bookkeeping at every wake-up: 18 of the 32 entities of the localizer's wait set,
at some 400 wake-ups per simulated second in the IMU-rate nodes. The events they report
happen at discovery, a few times in a node's life, and their warnings lose nothing by
coming up to a second late.

:func:`poll_qos_events` moves every event handler the node has into a callback group the
executor never waits on (the same mechanism as :mod:`.polled`) and checks them from one
steady-clock timer with a wait set of their own, calling each handler's callback exactly
as the executor would (the warnings read the same). Measured on a 60 km/h run at real-time
factor 0.5, two interleaved runs each: CPU per run 14.8 → 13.0 s (localizer −16 %,
compensator −16 %, spot locator −14 %; docs/ARCHITECTURE.md, process conventions).
Handlers created after the call (a publisher made later) stay with the executor.
"""
from contextlib import ExitStack
import os

from rclpy.clock import Clock, ClockType
from rclpy.event_handler import EventHandler
from rclpy.impl.implementation_singleton import rclpy_implementation as _rclpy

from vlc_common.executor import entered
from vlc_common.polled import NeverWaited

#: Period of the check, s (the delay of a QoS warning at most).
POLL_PERIOD_S = 1.0


class PolledQosEvents:
    """The event handlers of ``node`` checked every ``period_s`` (see the module)."""

    def __init__(self, node, period_s=POLL_PERIOD_S):
        self._context = node.context
        self._logger = node.get_logger()
        self.handlers = [w for w in node.waitables if isinstance(w, EventHandler)]
        group = NeverWaited()
        for handler in self.handlers:
            # the executor asks the entity's own group whether to wait on it
            handler.callback_group = group
        self.timer = (node.create_timer(period_s, self.poll,
                                        clock=Clock(clock_type=ClockType.STEADY_TIME))
                      if self.handlers else None)

    def poll(self):
        """Take every pending event and call its handler's callback; returns how many."""
        handled = 0
        with ExitStack() as stack:
            # a handler whose publisher or subscription is gone is left out
            live = [h for h in self.handlers if entered(stack, h)]
            if not live:
                return 0
            stack.enter_context(self._context.handle)
            wait_set = _rclpy.WaitSet(0, 0, 0, 0, 0, len(live), self._context.handle)
            wait_set.clear_entities()
            for handler in live:
                handler.add_to_wait_set(wait_set)
            wait_set.wait(0)
            ready = [(h, h.take_data()) for h in live if h.is_ready(wait_set)]
        for handler, data in ready:
            if data:
                try:
                    handler.callback(data)
                except Exception as exc:  # noqa: BLE001 - a warning must not stop the node
                    self._logger.error(f'QoS event callback failed: {exc!r}')
                handled += 1
        return handled


#: Environment variable: ``0`` leaves the handlers with rclpy's executor (A/B).
ENABLE_ENV = 'VLC_POLL_QOS_EVENTS'


def poll_qos_events(node, period_s=POLL_PERIOD_S):
    """Move ``node``'s event handlers off the executor (:class:`PolledQosEvents`);
    None, leaving them where rclpy put them, with ``VLC_POLL_QOS_EVENTS=0``.
    """
    if os.environ.get(ENABLE_ENV, '1') == '0':
        return None
    return PolledQosEvents(node, period_s)
