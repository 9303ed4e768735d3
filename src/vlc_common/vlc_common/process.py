"""Process-level start-up shared by every node of the graph."""
import ctypes
import gc
import os

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
    each buffer costs a page fault per 4 KiB page on first touch: 710 minor faults and
    2.6 ms CPU per 0.9 MB mono8 image taken by a subscriber, measured with two processes
    at 30 Hz on the project's Fast DDS profile; with the thresholds below the buffers come
    from (and return to) the heap: 68 faults, 1.2 ms. A node taking both images of every
    frame saves about 2.8 ms per frame, on the critical path to the pose. The process's
    heap keeps up to ``LARGE_BUFFER_TRIM_THRESHOLD`` of freed memory. Returns True when
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
    collection traverses them all: 45–55 ms on this machine, landing on whichever frame
    or IMU sample happens to allocate at that moment (measured in spot_locator,
    docs/arch/spot_locator.md "Per-frame tail"). Frozen, a full collection only sees what
    was allocated since (well under a millisecond). Per-frame garbage is still collected
    as before.
    """
    gc.collect()
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
