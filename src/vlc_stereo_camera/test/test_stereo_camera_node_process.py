"""The installed stereo_camera_node as a process: bad parameters and duration_s exit codes."""
import time

import pytest

pytestmark = pytest.mark.graph


@pytest.mark.parametrize('name, value, words', [
    ('fps', 0.0, ['fps']),
    ('chip_rate_hz', 50000.0, ['chip_rate_hz']),
    ('motion_profile', 'bogus', ['motion profile', 'bogus']),
])
def test_invalid_parameter_fails_at_startup(launch, name, value, words):
    proc = launch('vlc_stereo_camera', 'stereo_camera_node', params={name: value})
    code = proc.wait(timeout=60)
    log = launch.output(proc)
    assert code == 2, log
    assert 'invalid configuration' in log
    for word in words:
        assert word in log, log


def test_duration_run_exits_zero(launch):
    proc = launch('vlc_stereo_camera', 'stereo_camera_node',
                  params={'duration_s': 0.5, 'realtime_factor': 0.0, 'noise_bank_size': 1})
    code = proc.wait(timeout=60)
    assert code == 0, launch.output(proc)


def test_sigint_exits_zero(launch):
    proc = launch('vlc_stereo_camera', 'stereo_camera_node', params={'noise_bank_size': 1})
    deadline = time.monotonic() + 60.0
    while 'rendering' not in launch.output(proc) and time.monotonic() < deadline:
        assert proc.poll() is None, launch.output(proc)
        time.sleep(0.2)
    time.sleep(1.0)                         # running: frames being rendered and published
    assert proc.poll() is None
    assert launch.stop(proc) == 0, launch.output(proc)
