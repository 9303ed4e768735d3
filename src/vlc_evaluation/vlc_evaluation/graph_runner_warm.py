"""Imported last by the fork server (:class:`.graph_runner.ForkSpawner`): start-up work
that every forked node would otherwise repeat, done once before the fork.

* :mod:`inspect`'s module-by-file index. rclpy's logger finds its caller with
  ``inspect.getframeinfo``, whose first call in a process maps every loaded module to
  its file (a ``realpath`` per module). In a child of the fork server that is every
  module of every node (numpy, SciPy, OpenCV, scikit-image, rclpy, …), paid at each
  node's first log line in each process of every scenario.
* The C type support of the graph's message types (rclpy imports and checks it at a
  type's first publisher or subscription). Loading it opens
  the message packages' shared libraries; no rclpy context, participant or DDS thread
  is created, so forking stays safe.
* The bag recorder's rosbags typestore of ROS 2 Jazzy: its module (which builds the
  Humble and Iron stores it derives from, some 180 dataclasses) was imported afresh by
  the recorder of every scenario, about 70 ms.
* The shipped rig profiles, parsed once (``installation._parse_profiles`` keeps them):
  the camera and IMU nodes of every scenario read them at start.
"""
import inspect
import sys

from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import PoseStamped, PoseWithCovarianceStamped
from nav_msgs.msg import Odometry
from rclpy.type_support import check_for_type_support
import rosbags.typesys.stores.ros2_jazzy  # noqa: F401 — imported for its module cache
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import CameraInfo, Image, Imu, PointCloud2

for _type in (CameraInfo, Clock, DiagnosticArray, Image, Imu, Odometry, PointCloud2,
              PoseStamped, PoseWithCovarianceStamped):
    check_for_type_support(_type)

try:
    from vlc_stereo_camera.core.installation import load_profiles
    load_profiles()
except Exception:  # noqa: BLE001 — a broken profiles file is the nodes' to report
    pass

inspect.getframeinfo(sys._getframe())
