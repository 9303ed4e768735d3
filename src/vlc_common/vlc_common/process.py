"""Process conventions shared by every node of the graph: start-up, ``main()``, clean stop."""
import contextlib
import ctypes
import faulthandler
import gc
import os
import signal
import subprocess

# glibc mallopt() parameters (malloc.h)
_M_TRIM_THRESHOLD = -1
_M_MMAP_THRESHOLD = -3
# Large enough for a 1280x720 rgb8 frame (2.8 MB) and the middleware's copies of it.
LARGE_BUFFER_MMAP_THRESHOLD = 16 << 20
# Free heap kept before it is returned to the kernel: a few frames' worth.
LARGE_BUFFER_TRIM_THRESHOLD = 64 << 20


def keep_large_buffers():
    """Make glibc reuse freed frame-sized buffers instead of unmapping them.

    Every received or published image passes through several buffers of its size (the
    middleware's sample, the deserialised C message, the Python ``array``). glibc serves
    a request above its mmap threshold with a fresh ``mmap`` and unmaps it on free, so
    each buffer costs a page fault per 4 KiB page on first touch; with the thresholds
    below the buffers come from (and return to) the heap, on the critical path to the
    pose (measured: docs/ARCHITECTURE.md, process conventions). The process's heap keeps
    up to ``LARGE_BUFFER_TRIM_THRESHOLD`` of freed memory. Returns True when
    the allocator took both settings (False off glibc, or with the environment variable
    ``VLC_KEEP_LARGE_BUFFERS=0``, which keeps glibc's defaults).
    """
    if os.environ.get('VLC_KEEP_LARGE_BUFFERS', '1') == '0':
        return False
    try:
        # the symbols the process already has: the allocator it actually runs on (no
        # ctypes.util.find_library, which runs ldconfig in a subprocess at every start)
        mallopt = ctypes.CDLL(None).mallopt
    except (OSError, AttributeError):
        return False
    mallopt.argtypes = (ctypes.c_int, ctypes.c_int)
    mallopt.restype = ctypes.c_int
    return bool(mallopt(_M_MMAP_THRESHOLD, LARGE_BUFFER_MMAP_THRESHOLD)
                and mallopt(_M_TRIM_THRESHOLD, LARGE_BUFFER_TRIM_THRESHOLD))


def freeze_start_up_objects():
    """Move everything allocated so far out of the garbage collector's reach.

    Called by each processing node once it is built, before it spins. After the imports
    (rclpy, numpy, scipy, OpenCV, scikit-image), the lamp map and any warm-up the process
    holds ~90k GC-tracked objects that live until exit, and every full (generation-2)
    collection traverses them all, landing on whichever frame or IMU sample happens to
    allocate at that moment (docs/arch/spot_locator.md "Per-frame tail"). Frozen, a full
    collection only sees what was allocated since. Per-frame garbage is still collected
    as before.

    Only the young generations are collected first: a full collection of those ~90k
    objects took 0.04 s on an idle machine and 0.15-0.27 s beside the running graph, all
    of it in the way of a respawned node's first message; what cyclic garbage the start
    left in the old generation is frozen with the rest (a few kB, never a growth).
    """
    gc.collect(1)
    gc.freeze()


def spin_until_shutdown(spin, context=None):
    """Run ``spin()`` (``rclpy.spin(node)`` and the like) until SIGINT or an external
    shutdown, and return normally then.

    SIGINT arrives while the executor may be inside rclpy's C++ code: rclpy's signal
    handler shuts the context down, and the KeyboardInterrupt that follows can surface
    as a ``RuntimeError`` from pybind11 ("Unable to convert call argument '0' to Python
    object", raised by ``take_message`` while it built the message) or an ``RCLError``
    from a wait set whose context is gone. With the context shut down these are part of
    the stop, not a failure (seen in the evaluation: decoder, compensator and localizer
    exiting 1 or 255 at a SIGINT on a loaded machine); while it is still up they are
    real errors and propagate.
    """
    import rclpy
    from rclpy.executors import ExternalShutdownException
    try:
        spin()
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except RuntimeError:
        if rclpy.ok(context=context):
            raise


#: Exit code of a node that cannot start: invalid parameters, an unreadable file.
EXIT_INVALID_CONFIG = 2

#: s the node's teardown (``destroy_node``: rcl's node and Fast DDS's participant, then
#: ``rclpy.try_shutdown``) may take before the process dumps its stacks and exits 1
#: (:func:`run_node`). Rarely, with every node of a graph stopping at once, Fast DDS's
#: participant deletion never returned (CI: a spot locator still there 20 s after two
#: SIGINTs, its stack in ``destroy_node``; the evaluation: a localizer SIGKILLed).
TEARDOWN_WATCHDOG_S = 5.0


class _StopSignals:
    """SIGINT / SIGTERM handler under rclpy's own.

    rclpy's handler (installed by ``rclpy.init`` on top of this one) shuts the context
    down, which ends the spin in order (ExternalShutdownException); then it calls this
    handler. While the node spins this only counts: a KeyboardInterrupt raised at an
    arbitrary point of the executor's Python can leave a half-built task behind and turn
    a stop into a crash. Before the node spins (while it is built) the first signal
    raises KeyboardInterrupt, there is nothing to tear down in order yet. ``ros2 launch``
    forwards Ctrl-C to every node after the terminal already sent it to the whole process
    group, so the second signal of a stop arrives during the clean-up: it is ignored.
    """

    def __init__(self):
        self.spinning = False
        self.received = 0

    def __call__(self, signum, frame):
        self.received += 1
        if self.received == 1 and not self.spinning:
            raise KeyboardInterrupt


#: Environment variable: a directory where every node writes a cProfile of its spin
#: (``<name>.<pid>.prof``, read with ``pstats``), for finding where a live graph's CPU
#: goes (docs/ARCHITECTURE.md, process conventions). Unset: no profiling.
PROFILE_DIR_ENV = 'VLC_PROFILE_DIR'
#: Environment variable: ``cpu`` times the profile of :data:`PROFILE_DIR_ENV` in the
#: process's CPU time (``time.process_time``) instead of the wall clock, so a node that
#: is descheduled inside a call (a loaded machine: seven nodes on two cores) is not
#: charged for the time it waited; unset or ``wall``: the wall clock (cProfile's default).
PROFILE_CLOCK_ENV = 'VLC_PROFILE_CLOCK'


def _profiled(spin, name):
    """``spin`` under cProfile when :data:`PROFILE_DIR_ENV` names a directory."""
    directory = os.environ.get(PROFILE_DIR_ENV)
    if not directory:
        return spin

    clock = os.environ.get(PROFILE_CLOCK_ENV, 'wall')
    if clock not in ('wall', 'cpu'):
        raise ValueError(f'{PROFILE_CLOCK_ENV}={clock!r}: expected wall or cpu')

    def run(node):
        import cProfile
        import time
        profile = cProfile.Profile(time.process_time) if clock == 'cpu' else cProfile.Profile()
        profile.enable()
        try:
            return spin(node)
        finally:
            profile.disable()
            os.makedirs(directory, exist_ok=True)
            profile.dump_stats(os.path.join(directory, f'{name}.{os.getpid()}.prof'))
    return run


def _spin(node):
    with _executor_for(node) as executor:
        spin_until_shutdown(executor.spin)


@contextlib.contextmanager
def _executor_for(node):
    """The graph's executor (:mod:`vlc_common.executor`) with ``node`` added, as
    ``rclpy.spin`` adds it to its global one (and removes it afterwards).
    """
    from vlc_common.executor import make_executor
    executor = make_executor(node.context)
    executor.add_node(node)
    try:
        yield executor
    finally:
        executor.remove_node(node)


def run_node(make_node, name, args=None, *, spin=_spin, stop=None, startup_errors=()):
    """The ``main()`` of a node: init, build, spin, stop cleanly; returns the exit code.

    Parameters
    ----------
    make_node : callable
        Builds the node (after ``rclpy.init``).
    name : str
        Logger name of the fatal message when the node cannot start.
    args : list of str, optional
        Command-line arguments for ``rclpy.init``.
    spin : callable(node) -> int or None
        Runs the node until it is done or stopped; its return value is the exit code
        (default: the graph's executor, ``vlc_common.executor``, until SIGINT, SIGTERM
        or an external shutdown).
    stop : callable(node), optional
        Called before ``destroy_node`` (flush files, stop threads); default: the node
        class's ``on_stop`` method where it has one (the convention every driver of the
        node classes follows: also ``vlc_evaluation.lockstep``).
    startup_errors : tuple of exception types
        Raised while building the node: a fatal log line and exit code
        :data:`EXIT_INVALID_CONFIG` (besides ParameterException, ValueError, OSError).

    One or two SIGINTs (a terminal's Ctrl-C, ``ros2 launch``) or a SIGTERM end the node
    with exit code 0 and no traceback; the node and its DDS participant are destroyed,
    so no shared-memory segment is left behind. A teardown that has not returned after
    :data:`TEARDOWN_WATCHDOG_S` writes every thread's stack to stderr and exits 1.
    """
    import rclpy
    from rclpy.exceptions import ParameterException
    from rclpy.executors import ExternalShutdownException

    stopper = _StopSignals()
    for signum in (signal.SIGINT, signal.SIGTERM):
        signal.signal(signum, stopper)
    # SIGUSR1 prints every thread's Python stack to stderr (the node's log) and the node
    # runs on: what a node that does not stop is doing (tests/test_clean_stop.py asks)
    with contextlib.suppress(AttributeError, ValueError, OSError):
        faulthandler.register(signal.SIGUSR1, all_threads=True, chain=False)
    rclpy.init(args=args)
    node, code = None, 0
    try:
        node = make_node()
        # the QoS warnings' handlers off the executor's wait set (vlc_common.qos_events)
        from vlc_common.qos_events import poll_qos_events
        poll_qos_events(node)
        freeze_start_up_objects()
        stopper.spinning = True
        if stopper.received:
            return 0
        code = _profiled(spin, name)(node) or 0
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except (ParameterException, ValueError, OSError, *startup_errors) as exc:
        if node is not None:
            raise
        rclpy.logging.get_logger(name).fatal(f'invalid configuration, not starting: {exc}')
        code = EXIT_INVALID_CONFIG
    finally:
        stopper.spinning = True
        # From here a signal only counts (_StopSignals): rclpy's handler, which runs on
        # its own thread and shuts the contexts down, stays out of the teardown (the
        # second SIGINT of a ros2 launch stop arrives during it; CI: a marker node that
        # exited 1 after two SIGINTs, a spot locator whose destroy_node never returned).
        with contextlib.suppress(Exception):
            from rclpy.signals import uninstall_signal_handlers
            uninstall_signal_handlers()
        if node is not None:
            stop = stop if stop is not None else getattr(type(node), 'on_stop', None)
            if stop is not None:
                stop(node)
            # A C-level timer (no GIL needed: the hang is inside rcl): stacks to the log,
            # then _exit(1), so the process ends with its reason instead of a SIGKILL.
            faulthandler.dump_traceback_later(TEARDOWN_WATCHDOG_S, exit=True)
            node.destroy_node()
        rclpy.try_shutdown()
        faulthandler.cancel_dump_traceback_later()
        # Python's finalisation resets a signal with a Python handler to the default
        # action: a second SIGINT arriving then would kill the process (exit -2). An
        # ignored signal is left ignored.
        for signum in (signal.SIGINT, signal.SIGTERM):
            signal.signal(signum, signal.SIG_IGN)
    return code


def spin_until_finished(node):
    """Spin a node that ends by itself (a rig node with a duration) until its ``finished``
    future is done or it is stopped; returns the future's exit code (0 when stopped).
    """
    with _executor_for(node) as executor:
        spin_until_shutdown(lambda: executor.spin_until_future_complete(node.finished))
    return node.finished.result() if node.finished.done() else 0


def start_logged(cmd, log_path, env=None):
    """``subprocess.Popen(cmd)`` in a session (process group) of its own, stdout and
    stderr into the file ``log_path``, kept open as ``proc.log`` (:func:`logged_output`).
    """
    log = open(log_path, 'w+')
    proc = subprocess.Popen([str(c) for c in cmd], env=env, stdout=log,
                            stderr=subprocess.STDOUT, start_new_session=True)
    proc.log = log
    return proc


def logged_output(proc):
    """Everything a process started by :func:`start_logged` has written so far."""
    proc.log.flush()
    proc.log.seek(0)
    return proc.log.read()

