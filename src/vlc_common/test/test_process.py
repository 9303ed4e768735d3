"""spin_until_shutdown: a stop by SIGINT is a clean return, whatever rclpy raised."""
import pytest

rclpy = pytest.importorskip('rclpy')

from rclpy.executors import ExternalShutdownException  # noqa: E402

from vlc_common.process import spin_until_shutdown  # noqa: E402

pytestmark = pytest.mark.ros


def _raise(exc):
    def spin():
        raise exc
    return spin


def test_sigint_and_external_shutdown_return_normally():
    ctx = rclpy.Context()
    rclpy.init(context=ctx)
    try:
        spin_until_shutdown(_raise(KeyboardInterrupt()), context=ctx)
        spin_until_shutdown(_raise(ExternalShutdownException()), context=ctx)
    finally:
        rclpy.shutdown(context=ctx)


def test_runtime_error_is_a_stop_only_once_the_context_is_shut_down():
    ctx = rclpy.Context()
    rclpy.init(context=ctx)
    convert = RuntimeError("Unable to convert call argument '0' to Python object")
    try:
        with pytest.raises(RuntimeError):
            spin_until_shutdown(_raise(convert), context=ctx)     # a real error
    finally:
        rclpy.shutdown(context=ctx)
    # SIGINT shut the context down first: the same error is the stop
    spin_until_shutdown(_raise(convert), context=ctx)
    with pytest.raises(ValueError):
        spin_until_shutdown(_raise(ValueError('bug')), context=ctx)


def test_profile_dir_writes_a_profile_of_the_spin(tmp_path, monkeypatch):
    import os
    import pstats

    from vlc_common.process import PROFILE_DIR_ENV, _profiled

    def spin(node):
        return sum(range(1000)) and 7

    monkeypatch.delenv(PROFILE_DIR_ENV, raising=False)
    assert _profiled(spin, 'n') is spin                  # unset: nothing wraps the spin
    monkeypatch.setenv(PROFILE_DIR_ENV, str(tmp_path / 'prof'))
    assert _profiled(spin, 'some_node')(None) == 7       # the spin's exit code
    written = list((tmp_path / 'prof').iterdir())
    assert [p.name for p in written] == [f'some_node.{os.getpid()}.prof']
    assert any(key[2] == 'spin' for key in pstats.Stats(str(written[0])).stats)


@pytest.mark.parametrize('clock', ['wall', 'cpu'])
def test_profile_clock_charges_a_sleeping_spin_by_the_chosen_clock(tmp_path, monkeypatch,
                                                                   clock):
    import pstats
    import time

    from vlc_common.process import PROFILE_CLOCK_ENV, PROFILE_DIR_ENV, _profiled

    def spin(node):
        time.sleep(0.3)                                  # descheduled, no CPU
        return 0

    monkeypatch.setenv(PROFILE_DIR_ENV, str(tmp_path / clock))
    monkeypatch.setenv(PROFILE_CLOCK_ENV, clock)
    assert _profiled(spin, 'n')(None) == 0
    stats = pstats.Stats(str(next((tmp_path / clock).iterdir())))
    spin_total = next(v[3] for k, v in stats.stats.items() if k[2] == 'spin')
    if clock == 'wall':
        assert spin_total >= 0.29
    else:
        assert spin_total < 0.1


def test_an_unknown_profile_clock_is_refused(tmp_path, monkeypatch):
    from vlc_common.process import PROFILE_CLOCK_ENV, PROFILE_DIR_ENV, _profiled
    monkeypatch.setenv(PROFILE_DIR_ENV, str(tmp_path))
    monkeypatch.setenv(PROFILE_CLOCK_ENV, 'sundial')
    with pytest.raises(ValueError, match='VLC_PROFILE_CLOCK'):
        _profiled(lambda node: 0, 'n')


_HANGING_TEARDOWN = '''
import time
import rclpy.node
from vlc_common import process

process.TEARDOWN_WATCHDOG_S = 1.0


class Node(rclpy.node.Node):
    def destroy_node(self):
        time.sleep(60.0)          # as rcl's participant deletion did, now and then


raise SystemExit(process.run_node(lambda: Node('hanging_teardown'), 'hanging_teardown',
                                  spin=lambda node: 0))
'''


def test_a_teardown_that_hangs_ends_the_process_with_its_stacks(tmp_path, ros_env):
    """destroy_node that does not return (seen: Fast DDS's participant deletion, with a
    whole graph stopping at once) no longer leaves the process hanging until a SIGKILL:
    after TEARDOWN_WATCHDOG_S its stacks are in its log and it exits 1.
    """
    import subprocess
    import sys
    import time
    script = tmp_path / 'hang.py'
    script.write_text(_HANGING_TEARDOWN)
    start = time.monotonic()
    proc = subprocess.run([sys.executable, str(script)], capture_output=True, text=True,
                          timeout=30.0, env=ros_env)
    assert proc.returncode == 1, proc.stderr
    assert time.monotonic() - start < 20.0
    assert 'Timeout' in proc.stderr and 'destroy_node' in proc.stderr


_ON_STOP = '''
import pathlib
import sys
import rclpy.node
from vlc_common import process

out = pathlib.Path(sys.argv[1])


class Node(rclpy.node.Node):
    def on_stop(self):
        out.write_text(out.read_text() + 'class ')


out.write_text('')
code = process.run_node(lambda: Node('on_stop'), 'on_stop', spin=lambda node: 0)
process.run_node(lambda: Node('on_stop'), 'on_stop', spin=lambda node: 0,
                 stop=lambda node: out.write_text(out.read_text() + 'given'))
raise SystemExit(code)
'''


def test_run_node_calls_the_node_class_on_stop_unless_given_another(tmp_path, ros_env):
    """The stop a node class names (on_stop: the localizer's kept files, the recorder's
    bag) runs before destroy_node, as the lockstep graph's driver also calls it; a
    ``stop`` given to run_node replaces it.
    """
    import subprocess
    import sys
    script, out = tmp_path / 'on_stop.py', tmp_path / 'calls.txt'
    script.write_text(_ON_STOP)
    proc = subprocess.run([sys.executable, str(script), str(out)], capture_output=True,
                          text=True, timeout=60.0, env=ros_env)
    assert proc.returncode == 0, proc.stderr
    assert out.read_text() == 'class given'
