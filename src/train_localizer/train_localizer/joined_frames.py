"""What every node that positions from joined lamp frames does the same way."""


class JoinedFramesNode:
    """Mixin of a ``rclpy.node.Node`` that joins ``spots/pairs`` and ``vlc/lamps`` into
    frames (``self.joiner``, a :class:`~train_localizer.core.join.FrameJoiner`), takes
    its intrinsics from camera_info (``self._intrinsics``, a
    :class:`~train_localizer.conversions.CameraInfoIntrinsics`), hands each joined frame
    to ``self._process(frames)``, measures time on ``self._steady`` (a steady clock) and
    throttles warnings by code (``self._warnings``).
    """

    def _flush_joiner(self):
        self._process(self.joiner.flush(self._now_s()))

    def _on_camera_info(self, index, msg):
        self._intrinsics.offer(index, msg, self.get_logger().info,
                               lambda text: self._warn('camera_info', text))

    def _warn(self, code, message):
        self._warnings.warn(code, message)

    def _now_s(self):
        """Steady-clock seconds (the joiner's timeouts are wall time)."""
        return self._steady.now().nanoseconds * 1e-9
