"""Shared pytest set-up for every test tier.

* Puts each package's source on ``sys.path`` ahead of the colcon install, so pure-core
  tests exercise the working tree.
* ``ros_env``: an environment for ROS processes isolated on a DDS domain of its own,
  localhost-only discovery and the project's Fast DDS profile (32 MB shared memory).
* ``launch``: starts an installed executable (``install/lib/<pkg>/<exe>``) in its own
  process group and stops the group at the end of the test (SIGINT, then SIGKILL); its
  ``probe``, ``spin``, ``rig_listened`` and ``open_image_gate`` drive a graph test.
* ``node_factory``: nodes of a class in-process, in one rclpy context of their own,
  destroyed at the end of the test.
"""
import contextlib
import os
import pathlib
import signal
import subprocess
import sys
import time

import pytest

WS = pathlib.Path(__file__).resolve().parent
_SRC = WS / 'src'
for _pkg in sorted(_SRC.iterdir()):
    if (_pkg / 'package.xml').exists() and str(_pkg) not in sys.path:
        sys.path.insert(0, str(_pkg))

from vlc_common.process import logged_output, start_logged  # noqa: E402

INSTALL_LIB = WS / 'install' / 'lib'
FASTDDS_PROFILE = WS / 'config' / 'fastdds_localhost_bigshm.xml'


def _pick_domain_id():
    # Unique per test process and per call, within 1..119: the evaluation's lanes use
    # 120..232 (vlc_evaluation.runner), so a test run never shares a domain
    # with an evaluation running beside it. Under pytest-xdist (scripts/run_tests.sh
    # runs the tests that start no process on two workers) each worker draws from a
    # range of its own, so two tests running side by side never share a domain.
    _pick_domain_id.n = getattr(_pick_domain_id, 'n', 0) + 1
    worker = os.environ.get('PYTEST_XDIST_WORKER', '')
    workers = int(os.environ.get('PYTEST_XDIST_WORKER_COUNT', '1') or 1)
    if worker.startswith('gw') and worker[2:].isdigit() and workers > 1:
        size = 119 // workers
        start = int(worker[2:]) % workers * size
        return 1 + start + (os.getpid() * 7 + _pick_domain_id.n * 13) % size
    return 1 + (os.getpid() * 7 + _pick_domain_id.n * 13) % 119


@pytest.fixture
def ros_env(monkeypatch):
    """Environment dict for a test that talks DDS, also applied to this process."""
    domain = str(_pick_domain_id())
    settings = {
        'ROS_DOMAIN_ID': domain,
        'ROS_AUTOMATIC_DISCOVERY_RANGE': 'LOCALHOST',
        'FASTRTPS_DEFAULT_PROFILES_FILE': str(FASTDDS_PROFILE),
        'PYTHONUNBUFFERED': '1',
    }
    for key, value in settings.items():
        monkeypatch.setenv(key, value)
    return dict(os.environ)


class _Launcher:
    def __init__(self, env, tmp_path):
        self.env = env
        self.tmp_path = tmp_path
        self.procs = []

    def __call__(self, package, executable, params=None, args=(), ros_args=()):
        """Start ``install/lib/<package>/<executable>`` with ``-p name:=value`` params."""
        exe = INSTALL_LIB / package / executable
        if not exe.exists():
            pytest.fail(f'{exe} is not installed: run `make setup` first')
        cmd = [str(exe), *args, '--ros-args']
        for name, value in (params or {}).items():
            cmd += ['-p', f'{name}:={_param_text(value)}']
        cmd += list(ros_args)
        proc = start_logged(cmd, self.tmp_path / f'{package}.{executable}.{len(self.procs)}.log',
                            self.env)
        self.procs.append(proc)
        return proc

    output = staticmethod(logged_output)

    def stop(self, proc, timeout=10.0):
        """SIGINT the process group; SIGKILL if it does not exit. Returns the exit code."""
        if proc.poll() is None:
            try:
                os.killpg(proc.pid, signal.SIGINT)
            except ProcessLookupError:
                pass
            try:
                proc.wait(timeout)
            except subprocess.TimeoutExpired:
                os.killpg(proc.pid, signal.SIGKILL)
                proc.wait(5)
        return proc.returncode

    def stop_all(self):
        for proc in self.procs:
            self.stop(proc)
            proc.log.close()

    @staticmethod
    @contextlib.contextmanager
    def probe(name):
        """A node of this test process (its own rclpy context) and an executor spinning
        it: ``with launch.probe('graph_test') as (node, executor): ...``.
        """
        import rclpy
        from rclpy.executors import SingleThreadedExecutor
        ctx = rclpy.Context()
        rclpy.init(context=ctx)
        node = rclpy.create_node(name, context=ctx)
        executor = SingleThreadedExecutor(context=ctx)
        executor.add_node(node)
        try:
            yield node, executor
        finally:
            executor.shutdown()
            node.destroy_node()
            rclpy.try_shutdown(context=ctx)

    @staticmethod
    def spin(executor, seconds, until=None):
        """Spin ``executor`` for ``seconds`` of wall time, or until ``until()`` is true."""
        deadline = time.monotonic() + seconds
        while time.monotonic() < deadline and not (until is not None and until()):
            executor.spin_once(timeout_sec=0.05)

    @staticmethod
    def rig_listened(node, clock_subscribers=1):
        """True once the rig's truth is seen, ``clock_subscribers`` nodes (the IMU, ...)
        listen to ``/clock`` and a node (the localizer) listens to ``imu/data``: the rig's
        image gate may open.
        """
        return (node.count_subscribers('/clock') >= clock_subscribers
                and node.count_publishers('ground_truth/pose') >= 1
                and node.count_subscribers('imu/data') >= 1)

    @staticmethod
    def open_image_gate(node):
        """Subscribe ``node`` to both images: the rig (``wait_for_subscribers``) starts
        its simulated time once this third subscriber per image topic is there.
        """
        from sensor_msgs.msg import Image
        for side in ('left', 'right'):
            node.create_subscription(Image, f'stereo/{side}/image_raw', lambda _: None, 1)


def _param_text(value):
    if isinstance(value, bool):
        return 'true' if value else 'false'
    if isinstance(value, (list, tuple)):
        return '[' + ','.join(_param_text(v) for v in value) + ']'
    return str(value)


@pytest.fixture
def launch(ros_env, tmp_path):
    launcher = _Launcher(ros_env, tmp_path)
    yield launcher
    launcher.stop_all()
    for leftover in pathlib.Path('/dev/shm').glob('fastrtps_*'):
        # segments of processes that are gone; Fast DDS cleans live ones itself
        if time.time() - leftover.stat().st_mtime > 60:
            leftover.unlink(missing_ok=True)


@pytest.fixture
def node_factory(ros_env):
    """``make(NodeClass, **params)``: a node of that class in this process, with those
    parameter overrides, in one rclpy context shared by the test's nodes; all destroyed
    and the context shut down at the end of the test.
    """
    import rclpy
    from rclpy.parameter import Parameter
    ctx = rclpy.Context()
    rclpy.init(context=ctx)
    nodes = []

    def make(node_class, **params):
        node = node_class(context=ctx, parameter_overrides=[
            Parameter(k, value=v) for k, v in params.items()])
        nodes.append(node)
        return node

    yield make
    for node in nodes:
        node.destroy_node()
    rclpy.shutdown(context=ctx)

