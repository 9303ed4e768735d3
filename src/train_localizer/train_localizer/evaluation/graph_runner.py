"""Runs the installed executables of the graph as separate processes (no ``launch``).

Each process gets its own process group (so a SIGINT reaches the node even from a
script whose background jobs ignore it), the run's DDS domain, localhost-only discovery
and the project's Fast DDS profile. On a machine with a full ROS 2 install the same
graph is started with ``ros2 launch`` or ``ros2 run``; this runner exists because neither
is installable here, and it is what the scenario runner and ``make demo`` use.
"""
import os
import pathlib
import signal
import subprocess
import time


def workspace_install():
    """The colcon install prefix (``$COLCON_PREFIX_PATH`` or ``install/`` beside src/)."""
    prefix = os.environ.get('COLCON_PREFIX_PATH', '').split(os.pathsep)[0]
    if prefix:
        return pathlib.Path(prefix)
    return pathlib.Path(__file__).resolve().parents[4] / 'install'


def param_text(value):
    """A parameter value as ``-p name:=value`` text (bools lower case, lists bracketed)."""
    if isinstance(value, bool):
        return 'true' if value else 'false'
    if isinstance(value, (list, tuple)):
        return '[' + ','.join(param_text(v) for v in value) + ']'
    return str(value)


class GraphRun:
    """A set of node processes on one DDS domain, logging into ``log_dir``."""

    def __init__(self, log_dir, domain_id, install=None, extra_env=None):
        self.log_dir = pathlib.Path(log_dir)
        self.log_dir.mkdir(parents=True, exist_ok=True)
        self.install = pathlib.Path(install) if install else workspace_install()
        self.env = dict(os.environ)
        self.env.update({'ROS_DOMAIN_ID': str(domain_id),
                         'ROS_AUTOMATIC_DISCOVERY_RANGE': 'LOCALHOST',
                         'PYTHONUNBUFFERED': '1'})
        profile = self.install.parent / 'config' / 'fastdds_localhost_bigshm.xml'
        if 'FASTRTPS_DEFAULT_PROFILES_FILE' not in self.env and profile.exists():
            self.env['FASTRTPS_DEFAULT_PROFILES_FILE'] = str(profile)
        self.env.update(extra_env or {})
        self.procs = {}

    def config_file(self, package, name):
        return self.install / 'share' / package / 'config' / name

    def start(self, package, executable, params=None, params_files=(), name=None):
        """Start ``install/lib/<package>/<executable>``; returns the Popen."""
        exe = self.install / 'lib' / package / executable
        if not exe.exists():
            raise FileNotFoundError(f'{exe} is not installed (run `make setup`)')
        cmd = [str(exe), '--ros-args']
        for params_file in params_files:
            cmd += ['--params-file', str(params_file)]
        for key, value in (params or {}).items():
            cmd += ['-p', f'{key}:={param_text(value)}']
        name = name or executable
        log = open(self.log_dir / f'{name}.log', 'w')
        proc = subprocess.Popen(cmd, env=self.env, stdout=log, stderr=subprocess.STDOUT,
                                start_new_session=True)
        proc.log_file = log
        self.procs[name] = proc
        return proc

    def stop(self, name, timeout_s=10.0):
        """SIGINT the process group, SIGKILL after ``timeout_s``; returns the exit code."""
        proc = self.procs[name]
        if proc.poll() is None:
            try:
                os.killpg(proc.pid, signal.SIGINT)
                proc.wait(timeout_s)
            except ProcessLookupError:
                pass
            except subprocess.TimeoutExpired:
                os.killpg(proc.pid, signal.SIGKILL)
                proc.wait(5.0)
        proc.log_file.close()
        return proc.returncode

    def wait(self, name, timeout_s):
        """Wait for a process to exit by itself; returns its exit code or None."""
        try:
            return self.procs[name].wait(timeout_s)
        except subprocess.TimeoutExpired:
            return None

    def stop_all(self, last=()):
        """Stop every process, the ones named in ``last`` after all others."""
        codes = {}
        for name in [n for n in self.procs if n not in last] + list(last):
            if name in self.procs:
                codes[name] = self.stop(name)
        time.sleep(0.2)
        return codes

    def log(self, name):
        return (self.log_dir / f'{name}.log').read_text(errors='replace')
