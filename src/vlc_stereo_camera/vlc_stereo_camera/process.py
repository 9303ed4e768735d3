"""Process-level start-up shared by every node of the graph."""
import gc


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
