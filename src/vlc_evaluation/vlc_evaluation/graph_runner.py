"""Runs the installed executables of the graph as separate processes (no ``launch``).

Each node process gets its own process group (so a SIGINT reaches the node even from a
script whose background jobs ignore it), the run's DDS domain, localhost-only discovery
and the project's Fast DDS profile. On a machine with a full ROS 2 install the same
graph is started with ``ros2 launch`` or ``ros2 run``; this runner exists because neither
is installable here, and it is what the scenario runner and ``make demo`` use.

Two ways to start a node (``spawn``):

* ``exec``: ``install/lib/<package>/<executable>`` as a new interpreter, exactly as
  ``ros2 run`` does. Importing rclpy, numpy, OpenCV and scikit-image costs each node
  0.2–1.3 s of CPU (``python -c 'import <module>'``), about 4 CPU-seconds per graph.
* ``fork`` (the evaluation's default): the same console-script entry points, read from
  the installed distributions' metadata, run in processes forked from a
  :mod:`multiprocessing` fork server that imported every node module once. Each node is
  still a process of its own with its own DDS participant, argv (``--ros-args …``),
  environment, log file and process group; only the import work is shared. The fork
  server only imports (no rclpy context, no DDS participant), so no DDS thread is ever
  forked; a child closes the fork server's liveness pipe and asks for SIGINT when the
  fork server ends, so a killed evaluation leaves no node running.
"""
import contextlib
import ctypes
import functools
import importlib
from importlib import metadata
import json
import multiprocessing
import os
import pathlib
import resource
import signal
import subprocess
import sys
import threading
import time

import yaml

SPAWN_MODES = ('exec', 'fork')
#: s between the SIGUSR1 (stack dump) and the SIGKILL of a process that did not stop
STACK_DUMP_S = 0.5
# how GraphRun.start hands a forked child its niceness (not left in the node's environment)
NICE_ENV = 'VLC_GRAPH_RUNNER_NICE'


def workspace_install():
    """The colcon install prefix (``$COLCON_PREFIX_PATH`` or ``install/`` beside src/)."""
    prefix = os.environ.get('COLCON_PREFIX_PATH', '').split(os.pathsep)[0]
    if prefix:
        return pathlib.Path(prefix)
    return pathlib.Path(__file__).resolve().parents[3] / 'install'


def param_text(value):
    """A parameter value as ``-p name:=value`` text (bools lower case, lists bracketed)."""
    if isinstance(value, bool):
        return 'true' if value else 'false'
    if isinstance(value, (list, tuple)):
        # strings quoted: a ':' or ',' inside one would end it in a YAML flow sequence
        return '[' + ','.join(json.dumps(v) if isinstance(v, str) else param_text(v)
                              for v in value) + ']'
    if isinstance(value, str):
        # rcl reads the value as YAML: '' would be no value at all, 'true' or '1.5' a
        # bool or a number; such strings go quoted
        try:
            plain = value != '' and yaml.safe_load(value) == value
        except yaml.YAMLError:
            plain = False
        return value if plain else json.dumps(value)
    return str(value)


def ros_argv(params=None, params_files=()):
    """A node's ``--ros-args`` arguments: its parameter files, then ``-p`` overrides."""
    argv = ['--ros-args']
    for params_file in params_files:
        argv += ['--params-file', str(params_file)]
    for key, value in (params or {}).items():
        argv += ['-p', f'{key}:={param_text(value)}']
    return argv


def console_entry_points(executables):
    """``{executable: 'module:function'}`` of installed console scripts (missing: absent)."""
    wanted = set(executables)
    found = {}
    for ep in metadata.entry_points(group='console_scripts'):
        if ep.name in wanted and ep.name not in found:
            found[ep.name] = ep.value
    return found


_PR_SET_PDEATHSIG = 1
_PR_SET_NAME = 15


def _linux_prctl(option, value):
    """prctl(2) where available (Linux); a no-op elsewhere."""
    try:
        libc = ctypes.CDLL(None, use_errno=True)
        libc.prctl(option, value, 0, 0, 0)
    except (OSError, AttributeError):
        pass


def _run_entry_point(entry, argv, env, log_path):
    """Child side of ``fork``: become ``argv[0]`` and run its console-script entry point."""
    os.setsid()
    # multiprocessing hands every child the client's end of the pipe by whose EOF the fork
    # server notices that the evaluation is gone; a node holding it would keep the fork
    # server, and so itself (below), alive after a killed evaluation.
    try:
        from multiprocessing import forkserver
        fd = forkserver._forkserver._forkserver_alive_fd
        if fd is not None:
            os.close(fd)
            forkserver._forkserver._forkserver_alive_fd = None
    except (ImportError, AttributeError, OSError):
        pass
    # SIGINT when the fork server ends (it ends with the evaluation process), so a killed
    # evaluation leaves no node behind; `top` and `ps -o comm` show the node's name.
    _linux_prctl(_PR_SET_PDEATHSIG, signal.SIGINT)
    _linux_prctl(_PR_SET_NAME, ctypes.c_char_p(os.path.basename(argv[0])[:15].encode()))
    fd = os.open(log_path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o644)
    os.dup2(fd, 1)
    os.dup2(fd, 2)
    os.close(fd)
    nice = env.pop(NICE_ENV, None)
    if nice:
        os.nice(int(nice))
    # The runner stops nodes with SIGINT: give it back its KeyboardInterrupt even when the
    # evaluation was started with SIGINT ignored (a background job of a script, nohup)
    signal.signal(signal.SIGINT, signal.default_int_handler)
    os.environ.clear()
    os.environ.update(env)
    sys.argv = list(argv)
    module, _, attr = entry.partition(':')
    main = importlib.import_module(module)
    for part in attr.split('.'):
        main = getattr(main, part)
    try:
        sys.exit(main())
    finally:
        # CPU and peak resident memory of this node (the fork server's children are not
        # the runner's children, so the runner's RUSAGE_CHILDREN cannot see them)
        usage = resource.getrusage(resource.RUSAGE_SELF)
        with open(log_path + '.cpu', 'w', encoding='utf-8') as stream:
            stream.write(f'{usage.ru_utime:.3f} {usage.ru_stime:.3f} '
                         f'{peak_rss_kib(usage)}\n')


def _exec_child_setup(nice):
    """In an exec'ed node before exec: its niceness, and SIGINT back to its default (an
    ignored signal stays ignored across exec, and Python then installs no
    KeyboardInterrupt: a node started by an evaluation running as a script's background
    job would not stop on the runner's SIGINT).
    """
    signal.signal(signal.SIGINT, signal.SIG_DFL)
    if nice:
        os.nice(int(nice))


def peak_rss_kib(usage=None):
    """Peak resident set size of the calling process, KiB: ``VmHWM`` of /proc/self/status (the
    pages it shares with the fork server, the imported libraries, counted in full), else
    ``ru_maxrss`` of ``usage`` (getrusage RUSAGE_SELF).
    """
    try:
        with open('/proc/self/status', encoding='ascii') as stream:
            for line in stream:
                if line.startswith('VmHWM:'):
                    return int(line.split()[1])
    except (OSError, ValueError, IndexError):
        pass
    usage = usage or resource.getrusage(resource.RUSAGE_SELF)
    return int(usage.ru_maxrss)


def read_peak_rss_mib(log_dir):
    """``{node: peak RSS in MiB}`` written by nodes started with ``fork`` (the third
    field of ``<node>.log.cpu``; files without it are left out).
    """
    out = {}
    for path in pathlib.Path(log_dir).glob('*.log.cpu'):
        fields = path.read_text().split()
        try:
            out[path.name[:-len('.log.cpu')]] = round(int(fields[2]) / 1024.0, 1)
        except (IndexError, ValueError):
            continue
    return out


def read_cpu_seconds(log_dir):
    """``{node: CPU seconds}`` written by nodes started with ``fork`` (user + system)."""
    out = {}
    for path in pathlib.Path(log_dir).glob('*.log.cpu'):
        try:
            user, system = (float(v) for v in path.read_text().split()[:2])
        except ValueError:
            continue
        out[path.name[:-len('.log.cpu')]] = round(user + system, 3)
    return out


class ForkedProcess:
    """A fork-server child with the part of the :class:`subprocess.Popen` API used here."""

    def __init__(self, process):
        self._process = process
        self.pid = process.pid

    @property
    def returncode(self):
        return self._process.exitcode

    def poll(self):
        return self._process.exitcode

    def wait(self, timeout=None):
        self._process.join(timeout)
        if self._process.exitcode is None:
            raise subprocess.TimeoutExpired(str(self.pid), timeout)
        return self._process.exitcode


class ForkSpawner:
    """Starts console-script entry points in children of one preloaded fork server.

    One per evaluation process (the :mod:`multiprocessing` fork server is a
    per-process singleton); thread-safe. Executables without an installed entry point
    fall back to ``exec``.
    """

    _lock = threading.Lock()
    _context = None
    _preloaded = frozenset()

    def __init__(self, executables):
        self.entry_points = console_entry_points(executables)
        modules = sorted({v.partition(':')[0] for v in self.entry_points.values()})
        with ForkSpawner._lock:
            if ForkSpawner._context is None:
                ctx = multiprocessing.get_context('forkserver')
                # warm_inspect last: it indexes every module imported before it
                ctx.set_forkserver_preload(modules + [__name__ + '_warm'])
                ForkSpawner._context = ctx
                ForkSpawner._preloaded = frozenset(modules)
        self._ctx = ForkSpawner._context

    def can_fork(self, executable):
        return executable in self.entry_points

    def start(self, exe_path, executable, argv, env, log_path):
        process = self._ctx.Process(
            target=_run_entry_point, name=executable, daemon=False,
            args=(self.entry_points[executable], [str(exe_path)] + list(argv), dict(env),
                  str(log_path)))
        process.start()
        return ForkedProcess(process)


class GraphRun:
    """A set of node processes on one DDS domain, logging into ``log_dir``.

    ``spawner``: None (``exec``) or a :class:`ForkSpawner`.
    """

    def __init__(self, log_dir, domain_id, install=None, extra_env=None, spawner=None):
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
        self.spawner = spawner
        self.procs = {}
        self._logs = {}
        self._started = {}      # name: the arguments it was started with (restart)
        self.restarts = {}      # name: how often it was started again

    def config_file(self, package, name):
        return self.install / 'share' / package / 'config' / name

    def start(self, package, executable, params=None, params_files=(), name=None, nice=0,
              log_name=None):
        """Start ``install/lib/<package>/<executable>``; returns its process handle.

        ``nice`` > 0 lowers the process's CPU priority (set in the child before it
        starts a thread, so its DDS threads inherit it); ``log_name``: its log file's
        name (default ``name``).
        """
        name = name or executable
        self._started[name] = (package, executable, params, tuple(params_files), nice)
        exe = self.install / 'lib' / package / executable
        if not exe.exists():
            raise FileNotFoundError(f'{exe} is not installed (run `make setup`)')
        argv = ros_argv(params, params_files)
        log_path = self.log_dir / f'{log_name or name}.log'
        if self.spawner is not None and self.spawner.can_fork(executable):
            env = dict(self.env, **({NICE_ENV: str(int(nice))} if nice else {}))
            proc = self.spawner.start(exe, executable, argv, env, log_path)
        else:
            log = open(log_path, 'w')
            proc = subprocess.Popen([str(exe)] + argv, env=self.env, stdout=log,
                                    stderr=subprocess.STDOUT, start_new_session=True,
                                    preexec_fn=functools.partial(_exec_child_setup, nice))
            self._logs[name] = log
        self.procs[name] = proc
        return proc

    def signal(self, name, sig):
        """Send ``sig`` to a node's process group (SIGSTOP/SIGCONT: a stall)."""
        self._signal(name, sig)

    def kill(self, name, timeout_s=10.0):
        """SIGKILL a node (no clean stop: a crash); returns its exit code."""
        self._signal(name, signal.SIGKILL)
        try:
            self.procs[name].wait(timeout_s)
        except subprocess.TimeoutExpired:
            return None
        log = self._logs.pop(name, None)
        if log is not None:
            log.close()
        return self.procs[name].returncode

    def restart(self, name):
        """Start a node again with the arguments it was first started with (its log:
        ``<name>.restart<k>.log``); returns the new process handle.
        """
        package, executable, params, files, nice = self._started[name]
        self.restarts[name] = self.restarts.get(name, 0) + 1
        return self.start(package, executable, params, files, name=name, nice=nice,
                          log_name=f'{name}.restart{self.restarts[name]}')

    def _signal(self, name, sig):
        pid = self.procs[name].pid
        try:
            os.killpg(pid, sig)
        except ProcessLookupError:
            # a forked child not yet in its own group (killed before setsid)
            try:
                os.kill(pid, sig)
            except ProcessLookupError:
                pass

    def stop(self, name, timeout_s=10.0):
        """SIGINT the process group, SIGKILL after ``timeout_s``; returns the exit code."""
        return self.stop_many([name], timeout_s)[name]

    def stop_many(self, names, timeout_s=10.0):
        """SIGINT several processes at once, wait for all, SIGKILL the ones still running
        after ``timeout_s``; returns ``{name: exit code}``.

        Before the SIGKILL a process still running gets SIGUSR1, on which every node
        writes the Python stack of each of its threads into its log
        (``vlc_common.process.run_node``): what a node that did not stop was doing (a
        localizer SIGKILLed at the end of one static run in a few hundred, its log silent
        on why). The dump gets :data:`STACK_DUMP_S` before the SIGKILL.
        """
        names = [n for n in names if n in self.procs]
        for name in names:
            if self.procs[name].poll() is None:
                self._signal(name, signal.SIGINT)
        deadline = time.monotonic() + timeout_s
        for name in names:
            proc = self.procs[name]
            try:
                proc.wait(max(0.0, deadline - time.monotonic()))
            except subprocess.TimeoutExpired:
                self._signal(name, signal.SIGUSR1)
                with contextlib.suppress(subprocess.TimeoutExpired):
                    proc.wait(STACK_DUMP_S)
                self._signal(name, signal.SIGKILL)
                try:
                    proc.wait(5.0)
                except subprocess.TimeoutExpired:
                    pass
        for name in names:
            log = self._logs.pop(name, None)
            if log is not None:
                log.close()
        return {name: self.procs[name].returncode for name in names}

    def wait(self, name, timeout_s, abort=None):
        """Wait for a process to exit by itself; returns its exit code or None (timeout,
        or ``abort()`` became true).
        """
        deadline = time.monotonic() + timeout_s
        while True:
            try:
                return self.procs[name].wait(min(0.1, max(0.0, deadline - time.monotonic())))
            except subprocess.TimeoutExpired:
                if time.monotonic() >= deadline or (abort is not None and abort()):
                    return None

    def running(self, name):
        return name in self.procs and self.procs[name].poll() is None

    def stop_all(self, last=()):
        """Stop every process (all at once), the ones named in ``last`` afterwards."""
        codes = self.stop_many([n for n in self.procs if n not in last])
        codes.update(self.stop_many([n for n in last if n in self.procs]))
        return codes

    def log(self, name):
        return (self.log_dir / f'{name}.log').read_text(errors='replace')
