"""The player's spin loop ends cleanly when a stop signal shuts the context down under it."""
import threading
import types

import pytest

rclpy = pytest.importorskip('rclpy')

pytestmark = pytest.mark.ros


def _spin_with(monkeypatch, spin_once):
    """The player's ``_play`` over an executor whose ``spin_once`` is the given one."""
    from vlc_bags import player_node

    class Executor:
        def add_node(self, node):
            pass

        def spin_once(self, timeout_sec=None):
            spin_once()

    monkeypatch.setattr(player_node, 'SingleThreadedExecutor', Executor)
    node = types.SimpleNamespace(done=threading.Event(), failure=None,
                                 config=types.SimpleNamespace(exit_when_done=True))
    rclpy.init()
    try:
        return player_node._play(node)
    finally:
        rclpy.try_shutdown()


def test_a_context_shut_down_under_spin_once_ends_playback_with_exit_0(monkeypatch):
    # CI 2026-12-06: a SIGINT between rclpy.ok() and spin_once's wait set made the
    # player exit 1 with "failed to initialize wait set: the given context is not valid"
    def shut_down_under_spin():
        rclpy.shutdown()
        raise RuntimeError('failed to initialize wait set: the given context is not '
                           'valid, either rcl_init() was not called or rcl_shutdown() '
                           'was called.')
    assert _spin_with(monkeypatch, shut_down_under_spin) == 0


def test_an_error_while_the_context_is_up_is_not_swallowed(monkeypatch):
    def broken():
        raise RuntimeError('a real error')
    with pytest.raises(RuntimeError, match='a real error'):
        _spin_with(monkeypatch, broken)


def _player(play_once, context_ok):
    from vlc_bags import player_node
    logged = []
    fake = types.SimpleNamespace(
        config=types.SimpleNamespace(wait_for_subscriptions=False, start_delay_s=0.0,
                                     rate=1.0, loop=False),
        _stop=threading.Event(), published=0, failure=None, done=threading.Event(),
        context=types.SimpleNamespace(ok=lambda: context_ok),
        get_logger=lambda: types.SimpleNamespace(info=logged.append, warning=logged.append,
                                                 error=logged.append))
    fake._play_once = lambda schedule: play_once()
    player_node.BagPlayerNode._play(fake)
    return fake, logged


def test_a_publish_failing_because_a_signal_shut_the_context_is_the_stop_not_a_failure():
    # CI 2026-12-06: the player thread's publish raised "publisher's context is invalid"
    # after a SIGTERM, and the player exited 1
    def publish_after_shutdown():
        raise RuntimeError("Failed to publish: publisher's context is invalid")
    fake, _ = _player(publish_after_shutdown, context_ok=False)
    assert fake.failure is None and fake.done.is_set()


def test_a_bag_that_fails_while_the_context_is_up_is_a_failure():
    def unreadable():
        raise OSError('bag unreadable')
    fake, logged = _player(unreadable, context_ok=True)
    assert isinstance(fake.failure, OSError) and fake.done.is_set()
    assert any('playback failed' in str(line) for line in logged)
