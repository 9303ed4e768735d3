"""Readiness and progress of a running graph, seen from a small rclpy node of the runner.

A :class:`GraphProbe` lives on one evaluation lane's DDS domain for one scenario. It
replaces fixed sleeps by checks:

* **ready**: every processing node and the recorder have created their subscriptions
  (counted in the probe's view of the ROS graph, :meth:`wait_for_subscribers`);
* **gate**: the camera holds simulated time until its image topics have
  ``wait_for_subscribers`` subscribers (its documented start condition). The probe
  subscribes to both image topics only once the graph is ready, so it is the last of
  those subscribers: the camera may be started together with everything else (its
  construction overlaps theirs) and simulated time still starts only when all are
  listening. The gate's subscriptions are dropped at the first ``/clock`` tick, so the
  probe does not take frames during the run;
* **done**: ``train/pose`` has been published for every instant the scenario scores
  (:meth:`wait_for_pose_stamp`).
"""
import logging
import queue
import threading
import time

from geometry_msgs.msg import PoseStamped
import rclpy
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from rclpy.node import Node
from rclpy.qos import QoSProfile, ReliabilityPolicy
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import Image

from vlc_common.stamps import stamp_to_ns

IMAGE_TOPICS = ('/stereo/left/image_raw', '/stereo/right/image_raw')
LOG = logging.getLogger(__name__)


class GraphProbe:
    """An rclpy context, node and executor thread on ``domain_id``."""

    def __init__(self, domain_id, name='evaluation_probe'):
        self.domain_id = domain_id
        self.context = rclpy.Context()
        rclpy.init(args=[], context=self.context, domain_id=domain_id)
        self.node = Node(name, context=self.context, start_parameter_services=False,
                         enable_rosout=False)
        self._lock = threading.Lock()
        self._gate = []
        self.satisfied_at = {}
        # Subscriptions are created and destroyed by the executor thread only (between
        # two waits), never while it waits on them.
        self._requests = queue.Queue()
        self._clock_seen = threading.Event()
        self._pose_stamp_ns = None
        self._pose_count = 0
        self._pose_wall = None
        self._clock_ns = None
        reliable = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)
        self.node.create_subscription(PoseStamped, '/train/pose', self._on_pose, reliable)
        self.node.create_subscription(Clock, '/clock', self._on_clock, reliable)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        self._wake = self.node.create_guard_condition(lambda: None)
        self._thread = threading.Thread(target=self._spin, name=f'probe{domain_id}',
                                        daemon=True)
        self._thread.start()

    def _spin(self):
        while self.context.ok():
            try:
                while not self._requests.empty():
                    request, done = self._requests.get_nowait()
                    request()
                    done.set()
                self.executor.spin_once(timeout_sec=0.05)
            except (ExternalShutdownException, rclpy.executors.ShutdownException):
                return
            except Exception as exc:  # noqa: BLE001 — a probe must outlive one bad callback
                if not self.context.ok():
                    return
                LOG.warning('probe on domain %d: %r', self.domain_id, exc)

    def _in_executor(self, request, timeout_s=5.0):
        """Run ``request()`` in the executor thread and wait for it."""
        done = threading.Event()
        self._requests.put((request, done))
        self._wake.trigger()
        if not done.wait(timeout_s):
            raise RuntimeError(f'probe on domain {self.domain_id}: executor thread stuck')

    # ------------------------------------------------------------- callbacks
    def _on_pose(self, msg):
        stamp = stamp_to_ns(msg.header.stamp)
        with self._lock:
            self._pose_count += 1
            self._pose_wall = time.monotonic()
            if self._pose_stamp_ns is None or stamp > self._pose_stamp_ns:
                self._pose_stamp_ns = stamp

    def _on_clock(self, msg):
        stamp = stamp_to_ns(msg.clock)
        with self._lock:
            if self._clock_ns is None or stamp > self._clock_ns:
                self._clock_ns = stamp
        if not self._clock_seen.is_set():
            self._clock_seen.set()

    @property
    def clock_ns(self):
        """The newest ``/clock`` received (ns), or None."""
        with self._lock:
            return self._clock_ns

    # ------------------------------------------------------------- checks
    def missing_subscribers(self, required):
        """Topics whose subscriber count is below the required one: ``{topic: (n, need)}``."""
        missing = {}
        for topic, need in required.items():
            n = self.node.count_subscribers(topic)
            if n < need:
                missing[topic] = (n, need)
        return missing

    def wait_for_subscribers(self, required, timeout_s, abort=None):
        """Wait until every topic in ``required`` ({topic: count}) has that many
        subscribers; returns the still-missing ones ({} = ready). ``abort()`` → stop early.
        ``satisfied_at`` then holds the monotonic time at which each topic was first seen
        with all its subscribers (where the wait went).
        """
        deadline = time.monotonic() + timeout_s
        self.satisfied_at = {}
        while True:
            missing = self.missing_subscribers(required)
            now = time.monotonic()
            for topic in required:
                if topic not in missing:
                    self.satisfied_at.setdefault(topic, now)
            if not missing or now > deadline or (abort and abort()):
                return missing
            time.sleep(0.02)

    def open_gate(self):
        """Subscribe to the image topics (the camera's last awaited subscriber)."""
        qos = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE)

        def create():
            if not self._gate:
                self._gate = [self.node.create_subscription(Image, topic, self._drop, qos,
                                                            raw=True)
                              for topic in IMAGE_TOPICS]
        self._in_executor(create)

    @staticmethod
    def _drop(_msg):
        pass

    def close_gate(self):
        def destroy():
            gate, self._gate = self._gate, []
            for sub in gate:
                self.node.destroy_subscription(sub)
        self._in_executor(destroy)

    def wait_for_clock(self, timeout_s, abort=None):
        """Wait for the first ``/clock`` tick of the run (simulated time started)."""
        deadline = time.monotonic() + timeout_s
        while not self._clock_seen.wait(0.02):
            if time.monotonic() > deadline or (abort and abort()):
                return False
        return True

    @property
    def pose_stamp_ns(self):
        with self._lock:
            return self._pose_stamp_ns

    @property
    def pose_count(self):
        with self._lock:
            return self._pose_count

    def wait_for_pose_stamp(self, stamp_ns, timeout_s, abort=None, quiet_s=None,
                            inputs_done=None):
        """Wait until a ``train/pose`` stamped at or after ``stamp_ns`` was received.

        With ``quiet_s`` and ``inputs_done()`` true, also stop once no pose has come for
        ``quiet_s`` (a localizer that publishes only at fixes ends before ``stamp_ns``).
        Returns True when the stamp was reached.
        """
        deadline = time.monotonic() + timeout_s
        while True:
            with self._lock:
                stamp, last = self._pose_stamp_ns, self._pose_wall
            if stamp is not None and stamp >= stamp_ns:
                return True
            now = time.monotonic()
            if now > deadline or (abort and abort()):
                return False
            if (quiet_s is not None and inputs_done is not None and inputs_done()
                    and (last is None or now - last > quiet_s)):
                return False
            time.sleep(0.02)

    def describe(self):
        """The probe's view of the run (for error messages)."""
        n = self.node
        return (f'probe domain {self.domain_id}: /clock publishers '
                f'{n.count_publishers("/clock")}, image subscribers '
                f'{n.count_subscribers(IMAGE_TOPICS[0])}, poses {self.pose_count}, '
                f'executor thread alive {self._thread.is_alive()}')

    def close(self):
        try:
            self.close_gate()
        except RuntimeError as exc:
            LOG.warning('%s', exc)
        try:
            self.node.destroy_node()
        finally:
            rclpy.try_shutdown(context=self.context)
            self._thread.join(timeout=2.0)
