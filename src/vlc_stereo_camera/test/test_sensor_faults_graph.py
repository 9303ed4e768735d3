"""Sensor faults of the installed rig nodes (rig parameters, core/sensor_faults.py).

The IMU tests drive ``adis16488_node`` with a ``/clock`` of their own (the node follows any
``/clock``): after each tick they wait until what that tick released has arrived, so
every received sample is attributed to the tick that released it without relying on
timing. The camera tests run ``stereo_camera_node`` on small images (the faults do not
depend on the picture).
"""
import time

from geometry_msgs.msg import PoseStamped
from nav_msgs.msg import Odometry
import numpy as np
import pytest
import rclpy
from rclpy.context import Context
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.qos import QoSProfile, ReliabilityPolicy
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import CameraInfo, Image, Imu

from vlc_common.stamps import ns_to_stamp, stamp_to_ns

pytestmark = pytest.mark.graph

EPOCH_NS = 1704067200 * 10 ** 9
MS = 1_000_000
IMU_NS = 2_500_000                      # 400 Hz
FRAME_NS = 1e9 / 30.0
#: A small picture: the faults act on publication, not on what the frames show.
SMALL_CAMERA = {'image_width': 320, 'image_height': 240, 'cx': 159.5, 'cy': 119.5,
                'noise_bank_size': 1, 'start_chainage_m': 6.0}
RELIABLE = QoSProfile(depth=200, reliability=ReliabilityPolicy.RELIABLE)
#: Best effort like the IMU's publisher, with a queue deeper than anything it bursts.
IMU_QOS = QoSProfile(depth=2000, reliability=ReliabilityPolicy.BEST_EFFORT)


class Probe:
    """One node that subscribes, records (stamp, tick current at arrival, wall time) per
    topic and may publish ``/clock`` itself.
    """

    def __init__(self):
        self.ctx = Context()
        rclpy.init(context=self.ctx)
        self.node = Node('fault_probe', context=self.ctx)
        self.executor = SingleThreadedExecutor(context=self.ctx)
        self.executor.add_node(self.node)
        self.got = {}
        self.tick_ns = None             # the newest /clock this probe published
        self.clock_pub = None

    def subscribe(self, key, mtype, topic, qos, stamp=lambda m: m.header.stamp):
        self.got[key] = []

        def on_msg(msg):
            self.got[key].append((stamp_to_ns(stamp(msg)), self.tick_ns, time.monotonic()))

        self.node.create_subscription(mtype, topic, on_msg, qos)

    def stamps(self, key):
        return [s for s, _, _ in self.got[key]]

    def spin_until(self, done, timeout_s, procs=()):
        deadline = time.monotonic() + timeout_s
        while not done() and time.monotonic() < deadline:
            self.executor.spin_once(timeout_sec=0.01)
            for proc in procs:
                assert proc.poll() is None, 'a node exited early'
        return done()

    def spin_for(self, seconds):
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            self.executor.spin_once(timeout_sec=0.01)

    def tick(self, t_ns):
        """Publish /clock = epoch + t_ns."""
        if self.clock_pub is None:
            self.clock_pub = self.node.create_publisher(Clock, '/clock', RELIABLE)
        self.tick_ns = t_ns
        self.clock_pub.publish(Clock(clock=ns_to_stamp(EPOCH_NS + t_ns)))

    def close(self):
        self.executor.shutdown()
        self.node.destroy_node()
        rclpy.try_shutdown(context=self.ctx)


@pytest.fixture
def probe(ros_env):
    p = Probe()
    yield p
    p.close()


def _start_following_imu(launch, probe, params):
    """adis16488_node following the probe's /clock, matched both ways; returns the process."""
    imu = launch('vlc_stereo_camera', 'adis16488_node', params={'rate_hz': 400.0, **params})
    probe.subscribe('imu', Imu, 'imu/data_raw', IMU_QOS)
    probe.tick(0)
    assert probe.spin_until(lambda: probe.clock_pub.get_subscription_count() >= 1
                            and probe.node.count_publishers('imu/data_raw') >= 1, 30.0,
                            [imu]), launch.output(imu)
    probe.spin_for(0.5)                 # data readers and writers match after discovery
    return imu


def _clock_listeners(probe):
    """How many /clock subscriptions the probe's own node holds (its ``subscribe`` or a
    direct ``create_subscription``): the camera must count them beside the IMU's, or it
    starts its clock as soon as the probe alone matched, and the IMU may miss it all.
    """
    return sum(s.topic_name == '/clock' for s in probe.node.subscriptions)


def _start_imu_then_camera(launch, probe, imu_params, camera_params):
    """adis16488_node on the camera's clock: the IMU and the probe's subscriptions matched
    first, then the camera, whose clock starts when the probe takes both image topics.
    Returns (imu, camera).
    """
    imu = launch('vlc_stereo_camera', 'adis16488_node', params=imu_params)
    assert probe.spin_until(lambda: probe.node.count_publishers('imu/data_raw') >= 1
                            and probe.node.count_subscribers('/clock')
                            >= 1 + _clock_listeners(probe), 30.0,
                            [imu]), launch.output(imu)
    probe.spin_for(0.5)                 # data readers and writers match after discovery
    for side in ('left', 'right'):
        if side not in probe.got:
            probe.subscribe(side, Image, f'stereo/{side}/image_raw', RELIABLE)
    # its clock starts once the IMU (and the probe, if it listens) matched /clock too
    camera = launch('vlc_stereo_camera', 'stereo_camera_node',
                    params={**SMALL_CAMERA, 'wait_for_subscribers': 1,
                            'wait_for_clock_subscribers': 1 + _clock_listeners(probe),
                            **camera_params})
    return imu, camera


def _drive(probe, ticks_ns, released, imu, timeout_s=5.0):
    """Publish each tick; wait until every sample it releases (``released(t_ns)``: the
    newest true time due, or None) has arrived, before the next.
    """
    for t_ns in ticks_ns:
        probe.tick(t_ns)
        newest = released(t_ns)
        if newest is not None:
            probe.spin_until(lambda n=newest: probe.got['imu'] and
                             probe.got['imu'][-1][0] >= EPOCH_NS + n, timeout_s, [imu])
        else:
            probe.executor.spin_once(timeout_sec=0.002)
    probe.spin_for(0.3)                 # anything late would show now


# --- IMU --------------------------------------------------------------------------------

def test_imu_dropout_window_loses_its_samples(launch, probe):
    imu = _start_following_imu(launch, probe, {'imu_dropouts_s': [0.5, 0.25]})
    window = (500 * MS, 750 * MS)

    def newest_kept(t_ns):
        n = t_ns // IMU_NS * IMU_NS
        return window[0] - IMU_NS if window[0] <= n < window[1] else n

    _drive(probe, range(0, 1_200 * MS + 1, 10 * MS), newest_kept, imu)
    t = np.array(probe.stamps('imu')) - EPOCH_NS
    assert np.all(t % IMU_NS == 0) and np.all(np.diff(t) > 0)
    assert not np.any((t >= window[0]) & (t < window[1])), 'a sample of the window arrived'
    # the samples up to the window and from its end on arrived (best effort: a few may not)
    before, after = t[t < window[0]], t[t >= window[1]]
    assert len(before) >= 0.95 * 200 and before[-1] >= window[0] - 4 * IMU_NS
    assert len(after) >= 0.95 * 181 and after[0] <= window[1] + 3 * IMU_NS
    assert after[-1] >= 1_200 * MS - 3 * IMU_NS
    assert launch.stop(imu) == 0, launch.output(imu)
    assert 'IMU dropouts [0.5, 0.75) s' in launch.output(imu)


def test_imu_bursts_release_each_group_at_its_boundary(launch, probe):
    burst_ns = 250 * MS
    imu = _start_following_imu(launch, probe, {'imu_burst_s': 0.25})

    def newest_released(t_ns):
        limit = t_ns // burst_ns * burst_ns         # samples t < limit are out
        return limit - IMU_NS if limit > 0 else None

    _drive(probe, range(0, 1_000 * MS + 1, 10 * MS), newest_released, imu)
    got = probe.got['imu']
    t = np.array([s for s, _, _ in got]) - EPOCH_NS
    arrival_tick = np.array([tick for _, tick, _ in got])
    assert np.all(t % IMU_NS == 0) and np.all(np.diff(t) > 0)
    assert len(t) >= 0.95 * 400 and t[-1] >= 1_000 * MS - 4 * IMU_NS
    # each sample arrived while the clock stood at the first boundary after it: held
    # until then, and the whole group [(k-1)B, kB) arrived at that one tick
    boundary = (t // burst_ns + 1) * burst_ns
    np.testing.assert_array_equal(arrival_tick, boundary)
    groups = {int(b): t[boundary == b] for b in np.unique(boundary)}
    assert sorted(groups) == [250 * MS, 500 * MS, 750 * MS, 1_000 * MS]
    for b, members in groups.items():
        assert members[0] >= b - burst_ns and len(members) >= 0.9 * 100
    assert launch.stop(imu) == 0, launch.output(imu)


def test_imu_stamp_offset_shifts_stamps_exactly_relative_to_clock_release(launch, probe):
    offset_ns = -37_100_000                         # off the 2.5 ms grid
    imu = _start_following_imu(launch, probe, {'imu_stamp_offset_s': -0.0371})
    ticks = [0, 13 * MS, 50 * MS, 101 * MS, 250 * MS, 252 * MS, 400 * MS, 700 * MS]
    _drive(probe, ticks, lambda c: c // IMU_NS * IMU_NS + offset_ns, imu)
    got = probe.got['imu']
    stamps = np.array([s for s, _, _ in got]) - EPOCH_NS
    true_t = stamps - offset_ns
    assert np.all(true_t % IMU_NS == 0) and np.all(np.diff(true_t) > 0)
    assert len(true_t) >= 0.95 * (700 * MS // IMU_NS + 1)
    # released when the clock reached the TRUE time, never before, with every sample
    # the tick reached: the newest sample after each tick is the tick's own
    for stamp, tick, _ in got:
        assert stamp - EPOCH_NS - offset_ns <= tick
    newest_at = {}
    for stamp, tick, _ in got:
        newest_at[tick] = max(newest_at.get(tick, stamp), stamp)
    exact = [newest - EPOCH_NS == tick // IMU_NS * IMU_NS + offset_ns
             for tick, newest in newest_at.items()]
    assert len(exact) >= len(ticks) - 1 and sum(exact) >= len(ticks) - 1, newest_at
    assert launch.stop(imu) == 0, launch.output(imu)


def test_imu_bursts_on_the_cameras_clock_leave_in_groups(launch, probe):
    """With the camera's clock: each burst is published at once, when the clock has
    reached its boundary. Publication instants are the DDS source timestamps (wall
    clock of the publishing process), mapped to simulated time through those of the
    /clock ticks, so the probe's own speed does not enter.
    """
    burst_ns = 500 * MS
    clock, samples = [], []                  # (source wall ns, simulated ns)

    def on_clock(msg, info):
        clock.append((info['source_timestamp'], stamp_to_ns(msg.clock) - EPOCH_NS))

    def on_imu(msg, info):
        samples.append((info['source_timestamp'], stamp_to_ns(msg.header.stamp) - EPOCH_NS))

    probe.node.create_subscription(Clock, '/clock', on_clock, RELIABLE)
    probe.node.create_subscription(Imu, 'imu/data_raw', on_imu, IMU_QOS)
    imu, camera = _start_imu_then_camera(launch, probe, {'imu_burst_s': 0.5},
                                         {'realtime_factor': 2.0, 'duration_s': 4.2})
    probe.spin_until(lambda: camera.poll() is not None, 90.0, [imu])
    # a loaded machine may leave the IMU behind the clock: let it publish what it holds
    probe.spin_until(lambda: len(samples) >= 1600, 3.0, [imu])
    assert camera.returncode == 0, launch.output(camera)
    assert launch.stop(imu) == 0, launch.output(imu)
    assert len(samples) >= 1000, launch.output(imu)
    clock.sort()
    wall, t = (np.array(v, dtype=np.int64) for v in zip(*samples))
    assert np.all(t % IMU_NS == 0) and np.all(np.diff(t) > 0)
    # the simulated time at which each sample was published
    published = np.interp(wall, [w for w, _ in clock], [c for _, c in clock])
    boundary = (t // burst_ns + 1) * burst_ns
    # held: none published before the clock reached its burst boundary
    assert np.all(published >= boundary - 1 * MS), (published - boundary).min() / MS
    # at once: the 200 samples of a burst leave together (within a few ticks; the median
    # over the bursts, as a loaded machine may pause the IMU in the middle of one), not
    # spread over the 0.5 s they cover
    bursts = [b for b in np.unique(boundary) if np.count_nonzero(boundary == b) == 200]
    assert len(bursts) >= 4, np.unique(boundary, return_counts=True)
    spread = [np.ptp(published[boundary == b]) for b in bursts]
    assert np.median(spread) < burst_ns / 4, spread


# --- camera -----------------------------------------------------------------------------

def test_camera_dropout_stops_images_but_not_clock_or_truth(launch, probe):
    window = (0.5e9, 1.0e9)
    camera = launch('vlc_stereo_camera', 'stereo_camera_node',
                    params={**SMALL_CAMERA, 'realtime_factor': 2.0, 'duration_s': 1.5,
                            'wait_for_subscribers': 1, 'camera_dropouts_s': [0.5, 0.5]})
    probe.subscribe('clock', Clock, '/clock', RELIABLE, stamp=lambda m: m.clock)
    probe.subscribe('pose', PoseStamped, 'ground_truth/pose', RELIABLE)
    probe.subscribe('info', CameraInfo, 'stereo/left/camera_info', RELIABLE)
    probe.subscribe('right', Image, 'stereo/right/image_raw', RELIABLE)
    probe.subscribe('left', Image, 'stereo/left/image_raw', RELIABLE)
    probe.spin_until(lambda: camera.poll() is not None, 90.0)
    probe.spin_for(0.3)
    assert camera.returncode == 0, launch.output(camera)
    frames = [EPOCH_NS + round(k * FRAME_NS) for k in range(45)]    # t0 < 1.5 s
    kept = [s for s in frames if not window[0] <= s - EPOCH_NS < window[1]]
    assert len(kept) == 45 - 15
    # every frame outside the window and none inside (reliable, from frame 0)
    assert probe.stamps('left') == kept and probe.stamps('right') == kept
    info = probe.stamps('info')
    assert info and set(info) <= set(kept) and info == kept[len(kept) - len(info):]
    # the truth goes on through the window, frame by frame
    pose = probe.stamps('pose')
    assert len(pose) >= 40 and pose == frames[len(frames) - len(pose):]
    assert sum(window[0] <= s - EPOCH_NS < window[1] for s in pose) == 15
    # and /clock: its 10 ms ticks go on through the window (reliable keep-last: a busy
    # probe may miss one)
    clock = np.array(probe.stamps('clock')) - EPOCH_NS
    inside = clock[(clock >= window[0]) & (clock < window[1])]
    assert len(inside) >= 40 and np.all(clock % (10 * MS) == 0)
    assert np.all(np.diff(clock) > 0) and np.all(np.diff(clock) <= 100 * MS)
    assert 'camera dropouts [0.5, 1) s' in launch.output(camera)


def test_clock_jumps_step_sensor_and_truth_stamps_but_not_clock(launch, probe):
    # +0.3001 s at 0.6 s, then -0.5002 s at 1.2 s: off the IMU grid, so that every stamp
    # tells which segment it is in
    jumps = [(600 * MS, 300_100_000), (1_200 * MS, -500_200_000)]
    params = {'sensor_clock_jumps_s': [0.6, 0.3001, 1.2, -0.5002]}

    def jump(t_ns):
        return sum(j for at, j in jumps if t_ns >= at)

    probe.subscribe('clock', Clock, '/clock', RELIABLE, stamp=lambda m: m.clock)
    probe.subscribe('imu', Imu, 'imu/data_raw', IMU_QOS)
    probe.subscribe('pose', PoseStamped, 'ground_truth/pose', RELIABLE)
    probe.subscribe('odom', Odometry, 'ground_truth/odometry', RELIABLE)
    imu, camera = _start_imu_then_camera(launch, probe, params,
                                         {**params, 'realtime_factor': 1.0,
                                          'duration_s': 1.8})
    probe.spin_until(lambda: camera.poll() is not None, 90.0, [imu])
    probe.spin_for(0.3)
    assert camera.returncode == 0, launch.output(camera)
    assert launch.stop(imu) == 0, launch.output(imu)
    # images and truth: frame k stamped epoch + t0 + the jumps up to t0, in frame order
    t0 = [round(k * FRAME_NS) for k in range(54)]                  # t0 < 1.8 s
    expected = [EPOCH_NS + t + jump(t) for t in t0]
    assert probe.stamps('left') == expected and probe.stamps('right') == expected
    pose = probe.stamps('pose')
    assert len(pose) >= 48 and pose == expected[len(expected) - len(pose):]
    odom = probe.stamps('odom')
    assert len(odom) >= 48 and odom == expected[len(expected) - len(odom):]
    # so the stamps step by a frame period, and by jump_s more at the first frame from at_s
    steps = np.diff(expected) - FRAME_NS
    assert np.count_nonzero(np.abs(steps) > 1) == 2
    assert abs(steps[18 - 1] - 300_100_000) <= 1 and abs(steps[36 - 1] + 500_200_000) <= 1
    # IMU: every sample stamped epoch + t + the jumps up to its true t
    imu_stamps = np.array(probe.stamps('imu')) - EPOCH_NS
    assert len(imu_stamps) >= 0.9 * 720, launch.output(imu)
    grid = {n * IMU_NS + jump(n * IMU_NS) for n in range(int(2.5e9 // IMU_NS))}
    assert set(imu_stamps.tolist()) <= grid
    segment = [np.count_nonzero((imu_stamps % IMU_NS) == r)
               for r in (0, 300_100_000 % IMU_NS, -200_100_000 % IMU_NS)]
    assert all(n >= 100 for n in segment), segment     # every segment arrived
    # the backward jump shows in arrival order: a stamp smaller than the one before
    assert np.any(np.diff(imu_stamps) < 0)
    # /clock is not stepped: on its 10 ms grid, forward only, continuous over every jump
    clock = np.array(probe.stamps('clock')) - EPOCH_NS
    assert len(clock) >= 150 and clock[0] <= 200 * MS and clock[-1] >= 1_700 * MS
    assert np.all(clock % (10 * MS) == 0)
    assert np.all(np.diff(clock) > 0) and np.all(np.diff(clock) <= 100 * MS)


# --- start-up -----------------------------------------------------------------------------

@pytest.mark.parametrize('exe, params, words', [
    ('adis16488_node', {'imu_dropouts_s': [1.0, 0.5, 2.0]}, ['imu_dropouts_s', 'pairs']),
    ('stereo_camera_node', {'camera_dropouts_s': [1.0, -0.5]},
     ['camera_dropouts_s', 'duration_s must be > 0']),
    ('photodiode_node', {'sensor_clock_jumps_s': [-1.0, 0.5]},
     ['sensor_clock_jumps_s', 'at_s must be >= 0']),
])
def test_invalid_fault_parameters_exit_2(launch, exe, params, words):
    proc = launch('vlc_stereo_camera', exe, params=params)
    code = proc.wait(timeout=60)
    out = launch.output(proc)
    assert code == 2, out
    assert 'invalid configuration' in out
    for word in words:
        assert word in out, out
