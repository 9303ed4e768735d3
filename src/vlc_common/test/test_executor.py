"""LeanExecutor: the callbacks rclpy's executor calls, called directly, one wait per batch."""
import threading
import time

import pytest

rclpy = pytest.importorskip('rclpy')

from rcl_interfaces.srv import GetParameters  # noqa: E402
from rclpy.clock import Clock, ClockType  # noqa: E402
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor  # noqa: E402
from rclpy.qos import QoSProfile, ReliabilityPolicy  # noqa: E402
from rclpy.task import Future  # noqa: E402
from std_msgs.msg import Int32  # noqa: E402

from vlc_common.executor import LeanExecutor, make_executor  # noqa: E402
from vlc_common.polled import PolledSubscription  # noqa: E402
from vlc_common.qos_events import poll_qos_events  # noqa: E402

pytestmark = pytest.mark.ros

STEADY = Clock(clock_type=ClockType.STEADY_TIME)


@pytest.fixture
def context():
    ctx = rclpy.Context()
    rclpy.init(context=ctx)
    yield ctx
    rclpy.try_shutdown(context=ctx)


def _node(ctx, name):
    return rclpy.create_node(name, context=ctx)


def _spin_until(executor, condition, timeout_s=10.0):
    deadline = time.monotonic() + timeout_s
    while not condition() and time.monotonic() < deadline:
        executor.spin_once(timeout_sec=0.05)
    return condition()


def test_timers_subscriptions_and_guards_run_without_rclpy_tasks(context, monkeypatch):
    node = _node(context, 'lean_basic')
    got, infos, ticks, guarded = [], [], [], []
    pub = node.create_publisher(Int32, 'lean_numbers', 50)
    node.create_subscription(Int32, 'lean_numbers', lambda m: got.append(m.data), 50)
    node.create_subscription(Int32, 'lean_numbers',
                             lambda m, info: infos.append(info['source_timestamp']), 50)
    polled = PolledSubscription(node, Int32, 'lean_numbers', 50)
    node.create_timer(0.01, lambda: ticks.append(1), clock=STEADY)
    gc = node.create_guard_condition(lambda: guarded.append(1))
    poll_qos_events(node, period_s=3600.0)     # as run_node does once the node is built
    executor = LeanExecutor(context=context)
    executor.add_node(node)
    # rclpy's path (its generator and tasks) is never taken
    monkeypatch.setattr(SingleThreadedExecutor, '_spin_once_impl', None)
    assert _spin_until(executor, lambda: pub.get_subscription_count() == 3)
    for i in range(20):
        pub.publish(Int32(data=i))
    gc.trigger()
    assert _spin_until(executor, lambda: len(got) == 20 and len(infos) == 20
                       and len(ticks) >= 5 and guarded)
    assert got == list(range(20)) and all(t > 0 for t in infos)
    assert guarded == [1]
    assert not executor._tasks
    # the polled subscription's messages wait for take_all()
    assert [m.data for m in polled.take_all()] == list(range(20))
    node.destroy_node()


def test_parameter_services_answer_a_client_and_futures_complete(context):
    server = _node(context, 'lean_server')
    server.declare_parameter('answer', 42)
    client_node = _node(context, 'lean_client')
    client = client_node.create_client(GetParameters, '/lean_server/get_parameters')
    executor = LeanExecutor(context=context)
    executor.add_node(server)
    executor.add_node(client_node)
    assert _spin_until(executor, client.service_is_ready)
    future = client.call_async(GetParameters.Request(names=['answer']))
    executor.spin_until_future_complete(future, timeout_sec=10.0)
    assert future.done() and future.result().values[0].integer_value == 42
    # a future completed by a callback ends spin_until_future_complete (the rig's end)
    finished = Future()
    server.create_timer(0.05, lambda: finished.done() or finished.set_result(7), clock=STEADY)
    executor.spin_until_future_complete(finished, timeout_sec=10.0)
    assert finished.result() == 7
    server.destroy_node()
    client_node.destroy_node()


def test_a_coroutine_callback_runs_as_an_rclpy_task(context):
    node = _node(context, 'lean_async')
    done = []

    async def tick():
        done.append(1)
    timer = node.create_timer(0.01, tick, clock=STEADY)
    executor = LeanExecutor(context=context)
    executor.add_node(node)
    assert _spin_until(executor, lambda: done)
    timer.cancel()
    assert _spin_until(executor, lambda: not executor._tasks)
    node.destroy_node()


def test_waitables_left_with_the_executor_run_in_the_lean_path(context, monkeypatch):
    # QoS event handlers made after poll_qos_events (a recorder subscribing as topics
    # appear) stay waitables of the executor: their events still reach their callbacks
    node = _node(context, 'lean_waitable')
    node.create_publisher(Int32, 'lean_qos', QoSProfile(depth=5,
                                                        reliability=ReliabilityPolicy.BEST_EFFORT))
    node.create_subscription(Int32, 'lean_qos', lambda m: None,
                             QoSProfile(depth=5, reliability=ReliabilityPolicy.RELIABLE))
    events = []
    for handler in node.waitables:
        handler.callback = lambda event, h=handler: events.append(h.event_type.name)
    executor = LeanExecutor(context=context)
    executor.add_node(node)
    monkeypatch.setattr(SingleThreadedExecutor, '_spin_once_impl', None)
    assert _spin_until(executor, lambda: len(events) >= 2)
    assert sorted(events) == ['RCL_PUBLISHER_OFFERED_INCOMPATIBLE_QOS',
                              'RCL_SUBSCRIPTION_REQUESTED_INCOMPATIBLE_QOS']
    node.destroy_node()


def test_shutdown_of_the_context_ends_the_spin(context):
    # a SIGINT's shutdown arrives while the executor waits (rclpy's handler, another thread)
    node = _node(context, 'lean_shutdown')
    threading.Timer(0.2, context.try_shutdown).start()
    executor = LeanExecutor(context=context)
    executor.add_node(node)
    started = time.monotonic()
    with pytest.raises(ExternalShutdownException):
        executor.spin()
    assert time.monotonic() - started < 5.0


def test_an_exception_in_a_callback_propagates_as_in_rclpy(context):
    node = _node(context, 'lean_raise')

    def boom():
        raise RuntimeError('callback failed')
    node.create_timer(0.01, boom, clock=STEADY)
    executor = LeanExecutor(context=context)
    executor.add_node(node)
    with pytest.raises(RuntimeError, match='callback failed'):
        _spin_until(executor, lambda: False, timeout_s=5.0)
    node.destroy_node()


def test_the_environment_switch_gives_rclpys_executor(context, monkeypatch):
    monkeypatch.setenv('VLC_EXECUTOR', 'rclpy')
    assert type(make_executor(context)) is SingleThreadedExecutor
    monkeypatch.delenv('VLC_EXECUTOR')
    assert type(make_executor(context)) is LeanExecutor
