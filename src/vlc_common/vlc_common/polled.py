"""Subscriptions whose messages the node takes itself, in batches, off the executor.

rclpy's executor pays a fixed cost per message — rebuilding the wait set over every
subscription, timer, service and event handler of the node, waking up, creating a task,
taking the message — that dwarfs the work of a small message: in a profile of the
localizer most of its time went to the executor, for the 400 Hz ``imu/data``. A
:class:`PolledSubscription` is a normal subscription in the ROS graph (same topic
resolution, remapping, QoS, visible to ``ros2 topic info``), but in a callback group the
executor never waits on; the node calls :meth:`PolledSubscription.take_all` from a timer
and wherever it needs everything received so far (before a fix), so a batch of messages
costs one wake-up.

The messages are taken with the subscription handle's ``take_message``, the call rclpy's
own executor and ``rclpy.wait_for_message`` make.
"""
from rclpy.callback_groups import CallbackGroup
from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy

from vlc_common.stamps import stamp_to_ns

#: QoS of a 400 Hz IMU subscription: sensor data (best effort) with a deep queue. At
#: 400 Hz a 5-sample queue loses samples whenever the process stalls for 12 ms (measured
#: under load), and 100 (0.25 s) lost 0.75 s of the burst in which a stalled IMU caught
#: up, and 0.29 s while the localizer worked off a stall's backlog of frames: 1000 holds
#: 2.5 s (about 0.4 MB).
IMU_QOS = QoSProfile(depth=1000, reliability=ReliabilityPolicy.BEST_EFFORT,
                     history=HistoryPolicy.KEEP_LAST)

#: QoS of a per-frame record subscription (``spots/pairs``, ``vlc/lamps``: a few hundred
#: bytes each): reliable, 100 deep (3.3 s at 30 fps). With 10, a localizer that spent
#: 1.3 s working off the IMU's catch-up burst after an IMU stall lost the frames of that
#: time, saw their stamps jump and coasted (fault table, 'IMU process stalled'); queued,
#: they are fused late but in order, and the lag is gone within a few frames.
RECORDS_QOS = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE,
                         history=HistoryPolicy.KEEP_LAST)


class NeverWaited(CallbackGroup):
    """A callback group whose entities the executor never adds to its wait set."""

    def can_execute(self, entity):
        return False

    def beginning_execution(self, entity):
        return False

    def ending_execution(self, entity):
        pass


class PolledSubscription:
    """``node.create_subscription`` without a callback: messages wait in the
    subscription's queue (its QoS depth, keep-last) until :meth:`take_all`.
    """

    def __init__(self, node, msg_type, topic, qos, raw=False):
        self._sub = node.create_subscription(msg_type, topic, _never_called, qos,
                                             callback_group=NeverWaited(), raw=raw)

    @property
    def subscription(self):
        return self._sub

    @property
    def topic_name(self):
        return self._sub.topic_name

    def take_all(self, limit=None, with_info=False):
        """The messages received since the last call, oldest first (at most ``limit``);
        CDR ``bytes`` for a ``raw`` subscription. ``with_info``: ``(message, info)`` pairs,
        ``info`` the middleware's message info (``source_timestamp``,
        ``received_timestamp``, ns), as a subscription callback taking two arguments gets.
        """
        return take_pending(self._sub, limit, with_info)


def take_pending(sub, limit=None, with_info=False):
    """The messages waiting in subscription ``sub``'s queue, oldest first (at most
    ``limit``): what its callback would get next. A callback may call it on its own
    subscription and the other side's to see everything received so far (the executor
    skips a subscription whose queue it finds empty).
    """
    out = []
    with sub.handle:
        while limit is None or len(out) < limit:
            taken = sub.handle.take_message(sub.msg_type, sub.raw)
            if taken is None:
                break
            out.append(taken if with_info else taken[0])
    return out


def image_arrivals(side, msg, subscriptions):
    """``(side, stamp_ns, image)`` of image ``msg`` (from camera ``side``) and of every
    image waiting in the queues of ``subscriptions`` (one per side, in side order): what
    a stereo node's image callback offers its pairing
    (``vlc_common.core.stereo_pairing.StereoPairing.add_many``), so that a node that fell
    behind sees everything received so far.
    """
    arrivals = [(side, msg)] + [(s, m) for s, sub in enumerate(subscriptions)
                                for m in take_pending(sub)]
    return [(s, stamp_to_ns(m.header.stamp), m) for s, m in arrivals]


def pair_images(pairing, side, msg, subscriptions, warn, warnings, max_pairs):
    """A stereo node's image callback: offer image ``msg`` (camera ``side``) and every
    image waiting in ``subscriptions`` to ``pairing`` (:func:`image_arrivals`), warn
    through ``warn(key, text)`` for each of the pairing's events (``warnings``: event →
    (key, text)) and for images dropped with no stereo partner, and return ``(events,
    pairs)``: the events in order and the newest ``max_pairs`` complete pairs, oldest
    first (``StereoPairing.complete_pairs``).
    """
    unpaired = pairing.stats.unpaired
    events = pairing.add_many(image_arrivals(side, msg, subscriptions))
    for event in events:
        warn(*warnings[event])
    pairs = pairing.complete_pairs(max_pairs)
    dropped = pairing.stats.unpaired - unpaired
    if dropped > 0:
        warn('unpaired', f'{dropped} image(s) with no stereo partner dropped')
    return events, pairs


def _never_called(msg):    # pragma: no cover - the executor never waits on the group
    raise AssertionError('a PolledSubscription is taken with take_all()')
