"""The lockstep graph's local topics, timers and simulated time (vlc_evaluation.lockstep),
with small nodes in this process; and which scenarios may run as a lockstep graph.
"""
from dataclasses import replace

import pytest
from rclpy.node import Node
from rclpy.qos import HistoryPolicy, QoSProfile
from sensor_msgs.msg import Imu
from std_msgs.msg import String

from vlc_common.polled import PolledSubscription, take_pending
from vlc_evaluation import lockstep, runner, scenarios

pytestmark = pytest.mark.ros


@pytest.fixture
def bus(ros_env):
    import rclpy
    rclpy.init(args=[])
    bus = lockstep.Bus()
    nodes = []
    with lockstep.local_entities(bus):
        yield bus, nodes
    for node in nodes:
        node.destroy_node()
    rclpy.try_shutdown()


def _node(nodes, name):
    node = Node(name)
    nodes.append(node)
    return node


def test_a_message_reaches_each_subscription_as_its_own_copy_in_publication_order(bus):
    bus, nodes = bus
    a, b = _node(nodes, 'a'), _node(nodes, 'b')
    pub = a.create_publisher(Imu, 'imu/data_raw', 10)
    got, infos = [], []
    b.create_subscription(Imu, '/imu/data_raw', got.append, 10)
    b.create_subscription(Imu, 'imu/data_raw', lambda m, info: infos.append(info), 10)
    raw = PolledSubscription(b, Imu, 'imu/data_raw', QoSProfile(depth=3), raw=True)
    every = PolledSubscription(b, Imu, 'imu/data_raw',
                               QoSProfile(depth=1, history=HistoryPolicy.KEEP_ALL))
    msg = Imu()
    for k in range(5):
        # the ADIS node refills one message per sample: each delivery must be a copy
        msg.header.stamp.sec = k
        bus.now_ns = k
        pub.publish(msg)
    assert got == [] and not infos          # callbacks run when the bus drains
    bus.drain()
    assert [m.header.stamp.sec for m in got] == [0, 1, 2, 3, 4]
    assert len({id(m) for m in got}) == 5
    assert [i['source_timestamp'] for i in infos] == [0, 1, 2, 3, 4]
    # a polled subscription keeps the last `depth` messages, as CDR bytes when raw
    taken = raw.take_all()
    assert len(taken) == 3 and all(isinstance(t, bytes) for t in taken)
    assert raw.take_all() == []
    assert [m.header.stamp.sec for m in every.take_all()] == [0, 1, 2, 3, 4]   # keep-all
    assert pub.get_subscription_count() == 4
    assert ('/imu/data_raw', ['sensor_msgs/msg/Imu']) in bus.topic_names_and_types()
    assert [p.qos_profile.depth for p in bus.publishers_info('/imu/data_raw')] == [10]
    with pytest.raises(TypeError):
        pub.publish(String(data='not an Imu'))


def test_a_callback_taking_its_queue_finds_what_was_published_since(bus):
    bus, nodes = bus
    node = _node(nodes, 'n')
    pub = node.create_publisher(String, 'chatter', 10)
    seen = []

    def on_msg(msg):
        # what a spot locator does: skip to the newest of the queued messages
        seen.append([msg.data] + [m.data for m in take_pending(sub)])

    sub = node.create_subscription(String, 'chatter', on_msg, 10)
    for text in 'abc':
        pub.publish(String(data=text))
    bus.drain()
    assert seen == [['a', 'b', 'c']]        # the executor found the other queue turns empty


def test_timers_fire_on_simulated_time_in_order_and_cancel(bus):
    bus, nodes = bus
    node = _node(nodes, 'n')
    fired = []
    fast = node.create_timer(0.01, lambda: fired.append(('fast', bus.now_ns)))
    node.create_timer(0.025, lambda: fired.append(('slow', bus.now_ns)))
    idle = node.create_timer(0.001, lambda: fired.append(('idle', bus.now_ns)),
                             autostart=False)
    assert idle.is_canceled()
    bus.run_timers(30_000_000)
    assert fired == [('fast', 10_000_000), ('fast', 20_000_000), ('slow', 25_000_000),
                     ('fast', 30_000_000)]
    assert bus.now_ns == 30_000_000
    fast.cancel()
    fired.clear()
    bus.run_timers(60_000_000)
    assert fired == [('slow', 50_000_000)]
    # a reset restarts the period from now and drops the due time scheduled before
    fast.reset()
    fired.clear()
    bus.run_timers(75_000_000)
    assert fired == [('fast', 70_000_000), ('slow', 75_000_000)]


def test_a_callback_publishing_runs_its_subscribers_before_the_next_event(bus):
    bus, nodes = bus
    a, b = _node(nodes, 'a'), _node(nodes, 'b')
    out = a.create_publisher(String, 'out', 10)
    chain = []
    a.create_subscription(String, 'in', lambda m: out.publish(String(data=m.data + '!')), 10)
    b.create_subscription(String, 'out', lambda m: chain.append(m.data), 10)
    first = b.create_publisher(String, 'in', 10)
    first.publish(String(data='x'))
    bus.drain()
    assert chain == ['x!']


def test_a_node_the_lockstep_graph_does_not_know_is_refused(bus):
    bus, _ = bus
    with pytest.raises(ValueError, match='cannot run in a lockstep graph'):
        lockstep.build_node({'executable': 'sbs_splitter_node', 'argv': ['--ros-args']}, bus)


def test_which_scenarios_may_run_in_lockstep():
    static = scenarios.static_scenarios(points_m=(4.0,), trials=1, observe_s=1.5)[0]
    assert runner.lockstep_capable(static)
    assert not runner.lockstep_capable(replace(static, replay_bag='bags/sample_80kmh'))
    assert not runner.lockstep_capable(replace(static, kind='fault'))
    assert runner.lockstep_capable(replace(
        static, extra_nodes=[['companion_localizers', 'curvature_node', []]]))
    assert not runner.lockstep_capable(replace(
        static, extra_nodes=[['vlc_camera_input', 'sbs_splitter_node', []]]))
    assert not runner.lockstep_capable(replace(
        static, extra_publishers={'/imu/data_raw': 1}))


def test_the_spec_path_is_read_from_the_ros_args():
    assert lockstep._spec_path(['--ros-args', '-p', 'spec:=/tmp/x.json']) == '/tmp/x.json'
    with pytest.raises(SystemExit):
        lockstep._spec_path(['--ros-args'])
