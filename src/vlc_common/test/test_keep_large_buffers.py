"""keep_large_buffers: frame-sized buffers are reused, not mapped afresh each time."""
import subprocess
import sys

_PROBE = r'''
import resource, sys
from vlc_common.process import keep_large_buffers
if sys.argv[1] == "tuned":
    assert keep_large_buffers()
before = None
for i in range(41):
    if i == 1:   # after the first round, which maps the buffers in any case
        before = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
    # a 1280x720 mono8 image in three copies (middleware sample, C message, Python
    # array), zero-filled: every page touched, then all freed
    copies = [bytearray(900 * 1024) for _ in range(3)]
    del copies
print(resource.getrusage(resource.RUSAGE_SELF).ru_minflt - before)
'''


def _faults(mode):
    out = subprocess.run([sys.executable, '-c', _PROBE, mode], capture_output=True, text=True,
                         check=True)
    return int(out.stdout.strip())


def test_freed_frame_buffers_are_reused():
    default, tuned = _faults('default'), _faults('tuned')
    # glibc's default returns the freed 2.7 MB to the kernel each time (its trim
    # threshold follows the mmap threshold: twice the largest buffer freed): ~225 faults
    # per buffer touched again
    assert default > 40 * 200, default
    assert tuned < 40 * 10, tuned
