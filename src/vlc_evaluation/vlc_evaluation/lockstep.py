"""``lockstep_graph``: the graph's nodes in one process, driven by simulated time.

The evaluation's accuracy protocols ask what the receivers make of a scenario; the
graph at real time also asks whether the machine keeps up. Run through DDS in separate
processes, a scenario costs about 2.5 CPU-seconds per simulated second (README, CPU
per run), half of it the middleware, the executors and the pacing, and a node that
falls behind makes the run be repeated slower. Here the same node classes, built
with the same parameter files and overrides as :mod:`.runner` starts them, run in one
process with one thread, on simulated time:

* every publisher and subscription of the nodes is a local one (``Node.create_*``
  replaced while the nodes are built): a published message is serialised once (CDR, as
  DDS does) and deserialised for each subscription, into a keep-last queue of the
  subscription's depth. A subscription with a callback has it called in publication
  order, as an executor would (a callback that takes its own or another queue with
  :func:`vlc_common.polled.take_pending` finds there what was published meanwhile); a
  :class:`~vlc_common.polled.PolledSubscription` is only taken by its node;
* every timer fires on simulated time at its period (poll timers, diagnostics), steady
  or ROS clock alike; every node gets ``use_sim_time`` and the camera's ``/clock``,
  and the localizer's steady clock and the spot locator's odometry age read
  simulated time;
* the camera's frames and ``/clock`` ticks come from its own
  :meth:`~vlc_stereo_camera.stereo_camera_node.StereoCameraNode.sim_events` (what its
  pacing thread publishes), each published at its simulated time after the timers due
  before it, and everything it causes runs before the next event: the receivers take
  no simulated time, the IMU path keeps its poll periods;
* ``bag_recorder`` is the real node, subscribed through the local topics; its bag is
  what the protocols score, as from the graph.

No node falls behind and nothing depends on the machine's load, so a scenario gives
the same bag on every run. What it does not show (latency, a node falling behind,
message loss, DDS) is what the latency protocol and ``make bench`` measure on the
graph itself.

Usage (started by :func:`.runner.run_scenario_lockstep`)::

    lockstep_graph --ros-args -p spec:=<lockstep.json>

``lockstep.json``: ``{"nodes": [{"name", "package", "executable", "argv"}], "drain_s"}``,
``argv`` a node's ``--ros-args`` arguments (:func:`.graph_runner.ros_argv`).
"""
import collections
import contextlib
import functools
import heapq
import importlib
import inspect
import itertools
import json
import pathlib
import sys
from types import SimpleNamespace

import cv2

#: The node classes a lockstep graph can hold: executable → class name; the class's module
#: is the one the executable's installed entry point names (:func:`node_module`).
NODE_CLASSES = {
    'adis16488_node': 'Adis16488Node',
    'stereo_camera_node': 'StereoCameraNode',
    'imu_compensator_node': 'ImuCompensatorNode',
    'vlc_decoder_node': 'VlcDecoderNode',
    'spot_locator_node': 'SpotLocatorNode',
    'train_localizer_node': 'TrainLocalizerNode',
    'bag_recorder': 'BagRecorderNode',
    # the companion methods and the rig's photodiode (which follows /clock)
    'photodiode_node': 'PhotodiodeNode',
    'rssi_localizer_node': 'RssiLocalizerNode',
    'dead_reckoning_node': 'DeadReckoningNode',
    'ins_beacon_node': 'InsBeaconNode',
    'curvature_node': 'CurvatureNode',
}
#: Parameters a node gets only in a lockstep graph, besides ``use_sim_time``: the image
#: nodes' warm-up moves first-call costs off the first real frames, which in a lockstep
#: graph take no simulated time anyway (it decodes synthetic frames on a tracker of its
#: own, so what the nodes publish is the same).
LOCKSTEP_PARAMETERS = {'vlc_decoder_node': ('warm_up:=false',),
                       'spot_locator_node': ('warm_up:=false',)}
#: Simulated seconds the timers run on after the camera's last event (the IMU path's
#: polls hand on the last samples; the localizer publishes past the last frame).
DRAIN_S = 0.5
NS = 1_000_000_000
MIN_TIMER_PERIOD_NS = 100_000


def _qos_profile(qos):
    from rclpy.qos import QoSProfile
    return QoSProfile(depth=qos) if isinstance(qos, int) else qos


def _queue_length(qos):
    """A subscription queue's length: its keep-last depth (None, unbounded: keep-all)."""
    from rclpy.qos import HistoryPolicy
    profile = _qos_profile(qos)
    if profile.history == HistoryPolicy.KEEP_ALL:
        return None
    return max(int(profile.depth), 1)


def _type_name(msg_type):
    """``sensor_msgs/msg/Image`` of a generated message class."""
    return f'{msg_type.__module__.split(".")[0]}/msg/{msg_type.__name__}'


def _takes_info(callback):
    """Whether rclpy would call it with (message, info): it cannot take the message alone."""
    try:
        inspect.signature(callback).bind(object())
        return False
    except TypeError:
        return True


class _Handle:
    """The part of a subscription handle :func:`vlc_common.polled.take_pending` uses."""

    def __init__(self, sub):
        self._sub = sub

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        return False

    def take_message(self, msg_type, raw):
        queue = self._sub.queue
        if not queue:
            return None
        msg, stamp_ns = queue.popleft()
        return msg, {'source_timestamp': stamp_ns, 'received_timestamp': stamp_ns}


class LocalSubscription:
    """A subscription of the local bus: a keep-last queue of its QoS depth."""

    def __init__(self, bus, node, msg_type, topic, callback, qos, raw, polled):
        self.bus = bus
        self.msg_type = msg_type
        self.topic_name = node.resolve_topic_name(topic)
        self.raw = raw
        self.polled = polled
        self.callback = callback
        self.with_info = not polled and _takes_info(callback)
        self.queue = collections.deque(maxlen=_queue_length(qos))
        self.handle = _Handle(self)

    def deliver(self, data, stamp_ns):
        from rclpy.serialization import deserialize_message
        msg = data if self.raw else deserialize_message(data, self.msg_type)
        self.queue.append((msg, stamp_ns))
        if not self.polled:
            self.bus.pending.append(self)

    def run_callback(self):
        """The executor's turn for this subscription: its oldest message, if any left."""
        taken = self.handle.take_message(self.msg_type, self.raw)
        if taken is None:
            return
        if self.with_info:
            self.callback(*taken)
        else:
            self.callback(taken[0])

    def destroy(self):
        self.bus.unsubscribe(self)


class LocalPublisher:
    """A publisher of the local bus."""

    def __init__(self, bus, node, msg_type, topic, qos):
        self.bus = bus
        self.msg_type = msg_type
        self.topic_name = node.resolve_topic_name(topic)
        self.qos_profile = _qos_profile(qos)
        bus.offer(self)

    def publish(self, msg):
        if isinstance(msg, bytes):
            self.bus.publish(self.topic_name, msg)
        elif not isinstance(msg, self.msg_type):
            raise TypeError(f'Expected {self.msg_type}, got {type(msg)}')
        elif self.bus.wanted(self.topic_name):
            from rclpy.serialization import serialize_message
            self.bus.publish(self.topic_name, serialize_message(msg))

    def get_subscription_count(self):
        return len(self.bus.subs[self.topic_name])

    def wait_for_all_acked(self, timeout=None):
        return True

    def destroy(self):
        pass


class LocalTimer:
    """A timer of simulated time: due every ``period_ns`` from its creation."""

    def __init__(self, bus, period_s, callback, autostart=True):
        self.bus = bus
        # (a zero period would fire forever at one instant)
        self.timer_period_ns = max(int(round(period_s * NS)), MIN_TIMER_PERIOD_NS)
        self.callback = callback
        self._canceled = True
        self.generation = 0
        if autostart:
            self.reset()

    def reset(self):
        """(Re)start the period from now; a due time scheduled before is dropped."""
        self._canceled = False
        self.generation += 1
        self.bus.schedule(self, self.bus.now_ns + self.timer_period_ns)

    def cancel(self):
        self._canceled = True

    def is_canceled(self):
        return self._canceled

    def destroy(self):
        self._canceled = True


class LocalGuard:
    """A guard condition whose trigger queues its callback."""

    def __init__(self, bus, callback):
        self.bus = bus
        self.callback = callback

    def trigger(self):
        self.bus.pending.append(self)

    def run_callback(self):
        self.callback()

    def destroy(self):
        pass


class Bus:
    """Topics, timers and simulated time of one lockstep graph."""

    def __init__(self):
        self.subs = collections.defaultdict(list)
        self.publishers = collections.defaultdict(list)
        self.pending = collections.deque()
        self.now_ns = 0             # simulated time since the start (t = 0)
        self._timers = []           # heap of (due_ns, sequence, timer, generation)
        self._sequence = 0

    # topics
    def offer(self, publisher):
        self.publishers[publisher.topic_name].append(publisher)

    def subscribe(self, sub):
        self.subs[sub.topic_name].append(sub)

    def unsubscribe(self, sub):
        with contextlib.suppress(ValueError):
            self.subs[sub.topic_name].remove(sub)

    def wanted(self, topic):
        return bool(self.subs.get(topic))

    def publish(self, topic, data):
        for sub in self.subs.get(topic, ()):
            sub.deliver(data, self.now_ns)

    def drain(self):
        """Run every queued callback, and those they cause, in order."""
        while self.pending:
            self.pending.popleft().run_callback()

    # timers
    def schedule(self, timer, due_ns):
        self._sequence += 1
        heapq.heappush(self._timers, (due_ns, self._sequence, timer, timer.generation))

    def run_timers(self, until_ns):
        """Fire every timer due at or before ``until_ns``, in time (then creation) order."""
        while self._timers and self._timers[0][0] <= until_ns:
            due, _, timer, generation = heapq.heappop(self._timers)
            if timer.is_canceled() or generation != timer.generation:
                continue
            self.now_ns = max(self.now_ns, due)
            self.schedule(timer, due + timer.timer_period_ns)
            timer.callback()
            self.drain()
        self.now_ns = max(self.now_ns, until_ns)

    # the graph API the recorder's discovery uses
    def topic_names_and_types(self):
        return [(topic, [_type_name(pubs[0].msg_type)])
                for topic, pubs in sorted(self.publishers.items()) if pubs]

    def publishers_info(self, topic):
        return [SimpleNamespace(qos_profile=p.qos_profile)
                for p in self.publishers.get(topic, ())]


@contextlib.contextmanager
def local_entities(bus):
    """Within: ``rclpy.node.Node``'s publishers, subscriptions, timers, guard conditions
    and topic discovery are the bus's.
    """
    from rclpy.node import Node

    from vlc_common.polled import NeverWaited

    def create_publisher(node, msg_type, topic, qos_profile, **kwargs):
        return LocalPublisher(bus, node, msg_type, topic, qos_profile)

    def create_subscription(node, msg_type, topic, callback, qos_profile, *,
                            callback_group=None, raw=False, **kwargs):
        sub = LocalSubscription(bus, node, msg_type, topic, callback, qos_profile, raw,
                                isinstance(callback_group, NeverWaited))
        bus.subscribe(sub)
        return sub

    def create_timer(node, timer_period_sec, callback, callback_group=None, clock=None,
                     autostart=True):
        return LocalTimer(bus, timer_period_sec, callback, autostart)

    def create_guard_condition(node, callback, callback_group=None):
        return LocalGuard(bus, callback)

    patched = {
        'create_publisher': create_publisher,
        'create_subscription': create_subscription,
        'create_timer': create_timer,
        'create_guard_condition': create_guard_condition,
        'get_topic_names_and_types': lambda node, no_demangle=False:
            bus.topic_names_and_types(),
        'get_publishers_info_by_topic': lambda node, topic, no_mangle=False:
            bus.publishers_info(topic),
        'count_subscribers': lambda node, topic:
            len(bus.subs.get(node.resolve_topic_name(topic), ())),
        'count_publishers': lambda node, topic:
            len(bus.publishers.get(node.resolve_topic_name(topic), ())),
    }
    saved = {name: Node.__dict__[name] for name in patched}
    for name, function in patched.items():
        setattr(Node, name, function)
    try:
        yield bus
    finally:
        for name, function in saved.items():
            setattr(Node, name, function)


class _SimSteadyClock:
    """``.now().nanoseconds`` of simulated time (a node's steady clock in lockstep)."""

    def __init__(self, bus):
        self._bus = bus

    def now(self):
        return SimpleNamespace(nanoseconds=self._bus.now_ns)


def _on_sim_time(node, bus):
    """Point a node's own steady-clock readings at simulated time: its ``_steady``
    clock (the localizers' frame joiners and IMU pacer) and ``_monotonic`` (the spot
    locator's odometry age).
    """
    if hasattr(node, '_steady'):
        node._steady = _SimSteadyClock(bus)
    if hasattr(node, '_monotonic'):
        node._monotonic = lambda: bus.now_ns / NS


@functools.cache
def _entry_points():
    from vlc_evaluation.graph_runner import console_entry_points
    return console_entry_points(NODE_CLASSES)


def node_module(executable):
    """The module of ``executable``'s installed entry point (``module:main``): the one
    ``ros2 run`` starts, so a lockstep graph builds the node class the graph runs.
    """
    try:
        return _entry_points()[executable].partition(':')[0]
    except KeyError:
        raise ValueError(f'{executable}: no installed entry point (colcon build)') from None


def build_node(spec, bus):
    """One node of ``spec`` (``executable``, ``argv``) on the bus, on simulated time."""
    executable = spec['executable']
    if executable not in NODE_CLASSES:
        raise ValueError(f'{executable} cannot run in a lockstep graph (known: '
                         f'{", ".join(sorted(NODE_CLASSES))})')
    cls = getattr(importlib.import_module(node_module(executable)), NODE_CLASSES[executable])
    argv = list(spec['argv']) + ['-p', 'use_sim_time:=true']
    for parameter in LOCKSTEP_PARAMETERS.get(executable, ()):
        argv += ['-p', parameter]
    kwargs = {'cli_args': argv}
    if executable == 'stereo_camera_node':
        kwargs['start_workers'] = False
    node = cls(**kwargs)
    _on_sim_time(node, bus)
    return node


def run(spec, log=print):
    """Build the graph of ``spec``, run the camera's scenario to its end and the timers
    ``drain_s`` beyond, stop every node; returns the number of camera events.
    """
    import rclpy

    bus = Bus()
    nodes = {}
    # the recorder last: its discovery at start then finds every publisher
    order = sorted(spec['nodes'], key=lambda n: n['executable'] == 'bag_recorder')
    rclpy.init(args=[])
    try:
        with local_entities(bus):
            for node_spec in order:
                nodes[node_spec['name']] = (node_spec['executable'],
                                            build_node(node_spec, bus))
            cameras = [n for exe, n in nodes.values() if exe == 'stereo_camera_node']
            if len(cameras) != 1:
                raise ValueError(f'a lockstep graph needs one stereo_camera_node, not '
                                 f'{len(cameras)}')
            camera = cameras[0]
            frames = itertools.count()
            events = 0
            bus.drain()
            for t_s, frame in camera.sim_events(lambda: camera.render_frame(next(frames))):
                t_ns = int(round(t_s * NS))
                bus.run_timers(t_ns)
                camera.emit(t_s, frame)
                bus.drain()
                events += 1
            bus.run_timers(bus.now_ns + int(round(float(spec.get('drain_s', DRAIN_S)) * NS)))
            log(f'lockstep graph: {events} camera events, simulated time '
                f'{bus.now_ns / NS:.3f} s')
    finally:
        # what run_node does before destroy_node: the node class's on_stop (the
        # localizer saves what it keeps, the recorder closes its bag)
        for _, node in nodes.values():
            on_stop = getattr(node, 'on_stop', None)
            if on_stop is not None:
                on_stop()
        for _, node in nodes.values():
            node.destroy_node()
        rclpy.try_shutdown()
    return events


def _spec_path(argv):
    """``spec:=PATH`` of ``--ros-args -p spec:=PATH``."""
    for i, arg in enumerate(argv[:-1]):
        if arg == '-p' and argv[i + 1].startswith('spec:='):
            return argv[i + 1][len('spec:='):]
    raise SystemExit('usage: lockstep_graph --ros-args -p spec:=<lockstep.json>')


def main(argv=None):
    argv = sys.argv[1:] if argv is None else argv
    from vlc_common.process import keep_large_buffers
    cv2.setNumThreads(1)
    keep_large_buffers()
    spec = json.loads(pathlib.Path(_spec_path(argv)).read_text(encoding='utf-8'))
    run(spec)
    return 0


if __name__ == '__main__':
    sys.exit(main())
