"""The player's spin loop ends cleanly when a stop signal shuts the context down under it."""
import threading
import types

import pytest

rclpy = pytest.importorskip('rclpy')

pytestmark = pytest.mark.ros


def test_a_context_shut_down_under_spin_once_ends_playback_with_exit_0(monkeypatch):
    # CI 2026-12-06: a SIGINT between rclpy.ok() and spin_once's wait set made the
    # player exit 1 with "failed to initialize wait set: the given context is not valid"
    from vlc_bags import player_node

    class ShutDownUnderSpin:
        def add_node(self, node):
            pass

        def spin_once(self, timeout_sec=None):
            rclpy.shutdown()
            raise RuntimeError('failed to initialize wait set: the given context is not '
                               'valid, either rcl_init() was not called or rcl_shutdown() '
                               'was called.')

    monkeypatch.setattr(player_node, 'SingleThreadedExecutor', ShutDownUnderSpin)
    node = types.SimpleNamespace(done=threading.Event(), failure=None,
                                 config=types.SimpleNamespace(exit_when_done=True))
    rclpy.init()
    try:
        assert player_node._play(node) == 0
    finally:
        rclpy.try_shutdown()


def test_an_error_while_the_context_is_up_is_not_swallowed(monkeypatch):
    from vlc_bags import player_node

    class Broken:
        def add_node(self, node):
            pass

        def spin_once(self, timeout_sec=None):
            raise RuntimeError('a real error')

    monkeypatch.setattr(player_node, 'SingleThreadedExecutor', Broken)
    node = types.SimpleNamespace(done=threading.Event(), failure=None,
                                 config=types.SimpleNamespace(exit_when_done=True))
    rclpy.init()
    try:
        with pytest.raises(RuntimeError, match='a real error'):
            player_node._play(node)
    finally:
        rclpy.try_shutdown()
