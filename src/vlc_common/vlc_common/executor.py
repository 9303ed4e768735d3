"""The nodes' executor: rclpy's single-threaded executor without its per-callback tax.

rclpy 7.1's ``SingleThreadedExecutor`` rebuilds its wait set in Python at every wake-up,
wraps every callback in a :class:`rclpy.task.Task` around a coroutine, and that task
triggers the executor's own guard condition twice, so every callback is followed by a
second, empty wake-up that rebuilds the wait set again. A node with only a 10 ms timer
and an empty callback spends 0.46 ms of CPU per period that way (46 ms per second;
measured on this machine class, docs/ARCHITECTURE.md "The nodes' executor"), and the
graph's nodes wake several hundred times a second.

:class:`LeanExecutor` waits on the same entities through the same rcl wait set and calls
the same callbacks in the same order (timers, subscriptions, guard conditions, clients,
services, as rclpy does), but calls them directly: one wait per batch of ready work, no
task, no guard trigger; a waitable (a QoS event handler created after
``vlc_common.qos_events`` moved the others) is waited on and executed as rclpy does. A
task — made with ``create_task``, a coroutine callback, a waitable's unfinished work —
goes through rclpy's own implementation until none is left (the class is rclpy's
``SingleThreadedExecutor``; ``spin``, ``spin_until_future_complete``, ``add_node``,
``shutdown`` are rclpy's). Callbacks in a group that cannot execute (``vlc_common.polled``) are not
waited on, as in rclpy. ``VLC_EXECUTOR=rclpy`` makes :func:`make_executor` return rclpy's
``SingleThreadedExecutor`` instead (A/B).
"""
from contextlib import ExitStack
import inspect
import os

from rclpy.exceptions import InvalidHandle
from rclpy.executors import (
    ExternalShutdownException,
    SingleThreadedExecutor,
    TimeoutObject,
)
from rclpy.impl.implementation_singleton import rclpy_implementation as _rclpy
from rclpy.subscription import Subscription
from rclpy.utilities import timeout_sec_to_nsec
from rclpy.waitable import NumberOfEntities

#: Environment variable: ``rclpy`` gives rclpy's SingleThreadedExecutor (A/B).
EXECUTOR_ENV = 'VLC_EXECUTOR'


class LeanExecutor(SingleThreadedExecutor):
    """A single-threaded executor that calls ready callbacks directly (see the module)."""

    def _spin_once_impl(self, timeout_sec=None, wait_condition=lambda: False):
        nodes = self.get_nodes()
        if self._tasks:
            with self._tasks_lock:
                # rclpy's path drops finished tasks only when its generator resumes
                self._tasks = [t for t in self._tasks if not (t[0].done() or t[0].cancelled())]
        if self._tasks:
            # a task (create_task, a coroutine callback, a waitable's unfinished work):
            # rclpy's own path, until none is left
            return super()._spin_once_impl(timeout_sec, wait_condition)
        # a generator of rclpy's path left from an earlier spin must not hand out what an
        # old wait found ready
        self._cb_iter = None
        if self._is_shutdown or wait_condition():
            return None
        subs, timers, guards, clients, services, waitables = [], [], [], [], [], []
        for node in nodes:
            subs += [e for e in node.subscriptions if self.can_execute(e)]
            timers += [e for e in node.timers if self.can_execute(e)]
            guards += [e for e in node.guards if self.can_execute(e)]
            clients += [e for e in node.clients if self.can_execute(e)]
            services += [e for e in node.services if self.can_execute(e)]
            waitables += [e for e in node.waitables if self.can_execute(e)]
        timeout_ns = timeout_sec_to_nsec(
            timeout_sec.timeout if isinstance(timeout_sec, TimeoutObject) else timeout_sec)
        with ExitStack() as stack:
            subs, timers, guards, clients, services = (
                [e for e in group if entered(stack, e.handle)]
                for group in (subs, timers, guards, clients, services))
            own = [gc for gc in (self._guard, self._sigint_gc)
                   if gc is not None and entered(stack, gc.handle)]
            waitables = [w for w in waitables if entered(stack, w)]
            extra = NumberOfEntities()
            for waitable in waitables:
                extra += waitable.get_num_entities()
            stack.enter_context(self._context.handle)
            wait_set = self._wait_set_for((
                len(subs) + extra.num_subscriptions,
                len(guards) + len(own) + extra.num_guard_conditions,
                len(timers) + extra.num_timers, len(clients) + extra.num_clients,
                len(services) + extra.num_services, extra.num_events))
            wait_set.clear_entities()
            for e in subs:
                wait_set.add_subscription(e.handle)
            for e in guards + own:
                wait_set.add_guard_condition(e.handle)
            for e in timers:
                wait_set.add_timer(e.handle)
            for e in clients:
                wait_set.add_client(e.handle)
            for e in services:
                wait_set.add_service(e.handle)
            for waitable in waitables:
                waitable.add_to_wait_set(wait_set)
            wait_set.wait(timeout_ns)
            if self._is_shutdown:
                return None
            if not self._context.ok():
                raise ExternalShutdownException()
            ready = {kind: set(wait_set.get_ready_entities(kind))
                     for kind in ('subscription', 'guard_condition', 'timer', 'client',
                                  'service')}
            # a waitable reads its readiness off the wait set (rclpy: before it is gone)
            waitables = [(w, w.take_data()) for w in waitables if w.is_ready(wait_set)]
        with self._work_tracker:
            for tmr in timers:
                if tmr.handle.pointer in ready['timer']:
                    self._run_timer(tmr)
            for sub in subs:
                if sub.handle.pointer in ready['subscription']:
                    self._run_subscription(sub)
            for gc in guards:
                if gc.handle.pointer in ready['guard_condition'] and gc.callback is not None:
                    self._call(gc.callback)
            for client in clients:
                if client.handle.pointer in ready['client']:
                    self._run_client(client)
            for srv in services:
                if srv.handle.pointer in ready['service']:
                    self._run_service(srv)
            for waitable, data in waitables:
                self._run_waitable(waitable, data)
        return None

    def _wait_set_for(self, counts):
        """An rcl wait set of these sizes, kept from one spin to the next while the
        sizes stay the same (cleared and filled again before each wait).
        """
        if getattr(self, '_wait_set_counts', None) != counts:
            self._wait_set = _rclpy.WaitSet(*counts, self._context.handle)
            self._wait_set_counts = counts
        return self._wait_set

    def _call(self, callback, *args):
        """Call a callback; a coroutine it returns becomes an rclpy task (run next spin)."""
        result = callback(*args)
        if inspect.iscoroutine(result):
            self.create_task(result)
        return result

    def _run_waitable(self, waitable, data):
        """``waitable.execute(data)`` as rclpy runs it (a coroutine): to its end here when
        it does not wait for anything (a QoS event handler), else on as an rclpy task.
        """
        for future in waitable._futures:
            future._set_executor(self)
        coroutine = waitable.execute(data)
        try:
            coroutine.send(None)
        except StopIteration:
            return
        self.create_task(coroutine)

    def _run_timer(self, tmr):
        try:
            with tmr.handle:
                # rclpy's workaround for cancelled timers reported ready by rcl
                if not tmr.handle.is_timer_ready():
                    return
                tmr.handle.call_timer()
        except InvalidHandle:
            return
        self._call(tmr.callback)

    def _run_subscription(self, sub):
        taken = _take(sub, lambda h: h.take_message(sub.msg_type, sub.raw))
        if taken is None:
            return
        if sub._callback_type is Subscription.CallbackType.MessageOnly:
            self._call(sub.callback, taken[0])
        else:
            self._call(sub.callback, *taken)

    def _run_client(self, client):
        header, response = _take(client, lambda h: h.take_response(client.srv_type.Response),
                                 (None, None))
        if header is None:
            return
        try:
            future = client.get_pending_request(header.request_id.sequence_number)
        except KeyError:
            return      # the request was cancelled
        future._set_executor(self)
        future.set_result(response)

    def _run_service(self, srv):
        request, header = _take(srv, lambda h: h.service_take_request(srv.srv_type.Request),
                                (None, None))
        if header is None:
            return
        response = srv.callback(request, srv.srv_type.Response())
        srv.send_response(response, header)


def _take(entity, take, gone=None):
    """``take(entity.handle)`` with the handle held; ``gone`` when it was destroyed."""
    try:
        with entity.handle:
            return take(entity.handle)
    except InvalidHandle:
        return gone


def entered(stack, handle):
    """Enter ``handle`` into ``stack`` (kept alive while waited on); False when it was
    destroyed. Also :mod:`vlc_common.qos_events`'s wait.
    """
    try:
        stack.enter_context(handle)
    except InvalidHandle:
        return False
    return True


def make_executor(context=None):
    """The executor a node of the graph spins in: :class:`LeanExecutor`, or rclpy's
    ``SingleThreadedExecutor`` with ``VLC_EXECUTOR=rclpy``.
    """
    if os.environ.get(EXECUTOR_ENV, '') == 'rclpy':
        return SingleThreadedExecutor(context=context)
    return LeanExecutor(context=context)
