"""rclpy ↔ rosbags conversions for the bag nodes: QoS profiles and message classes."""
from __future__ import annotations

import importlib

from rclpy.qos import (
    DurabilityPolicy,
    HistoryPolicy,
    LivelinessPolicy,
    QoSProfile,
    ReliabilityPolicy,
)
from rosbags.interfaces import (
    Qos,
    QosDurability,
    QosHistory,
    QosLiveliness,
    QosReliability,
    QosTime,
)


def _enum(target, name: str):
    return target.__members__.get(name, target.UNKNOWN)


def _time(duration) -> QosTime:
    ns = duration.nanoseconds
    return QosTime(ns // 1_000_000_000, ns % 1_000_000_000)


def qos_from_rclpy(profile: QoSProfile) -> Qos:
    """An endpoint's rclpy QoS profile as the rosbags profile rosbag2 records."""
    return Qos(_enum(QosHistory, profile.history.name), int(profile.depth),
               _enum(QosReliability, profile.reliability.name),
               _enum(QosDurability, profile.durability.name),
               _time(profile.deadline), _time(profile.lifespan),
               _enum(QosLiveliness, profile.liveliness.name),
               _time(profile.liveliness_lease_duration),
               bool(profile.avoid_ros_namespace_conventions))


def qos_to_rclpy(qos: Qos) -> QoSProfile:
    """The history, depth, reliability and durability of a rosbags profile for rclpy.

    Deadline, lifespan and liveliness stay at ROS defaults (infinite / automatic): the
    bag nodes never need them and recorded values of remote endpoints are not reliable.
    """
    history = HistoryPolicy.KEEP_ALL if qos.history == QosHistory.KEEP_ALL \
        else HistoryPolicy.KEEP_LAST
    return QoSProfile(
        history=history, depth=max(1, qos.depth),
        reliability=ReliabilityPolicy.RELIABLE if qos.reliability == QosReliability.RELIABLE
        else ReliabilityPolicy.BEST_EFFORT,
        durability=DurabilityPolicy.TRANSIENT_LOCAL
        if qos.durability == QosDurability.TRANSIENT_LOCAL else DurabilityPolicy.VOLATILE,
        liveliness=LivelinessPolicy.AUTOMATIC)


def message_class(msgtype: str):
    """Python class of a ROS 2 message type name such as ``sensor_msgs/msg/Image``.

    Raises
    ------
    ImportError
        The interface package is not installed or the name is malformed.
    """
    parts = msgtype.split('/')
    if len(parts) != 3:
        raise ImportError(f'not a ROS 2 message type name: {msgtype!r}')
    pkg, kind, name = parts
    try:
        return getattr(importlib.import_module(f'{pkg}.{kind}'), name)
    except (ModuleNotFoundError, AttributeError) as exc:
        raise ImportError(f'message type {msgtype} is not installed: {exc}') from exc
