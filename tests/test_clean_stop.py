"""Every node of the graph stops cleanly: one or two SIGINTs (a terminal's Ctrl-C, and
``ros2 launch`` forwarding it again to each node) or a SIGTERM end each installed
executable with exit code 0, without a traceback, and leave no Fast DDS shared-memory
segment behind.
"""
import contextlib
import os
import pathlib
import signal
import time

import pytest

pytestmark = pytest.mark.graph

ROOT = pathlib.Path(__file__).resolve().parents[1]
SAMPLE_BAG = ROOT / 'bags' / 'sample_80kmh'
RIG = {'realtime_factor': 0.5, 'speed_kmh': 60.0, 'start_chainage_m': 3.0}
SHM = pathlib.Path('/dev/shm')


def _calibration(tmp_path):
    """The rig's ideal stereo calibration as camera_info files (for the SBS splitter)."""
    from vlc_common.core.calibration import StereoCalibration, save_ros_stereo
    from vlc_common.core.camera import StereoCameraModel, StereoRig
    pair = StereoCameraModel.from_rig(StereoRig())
    files = [tmp_path / 'left.yaml', tmp_path / 'right.yaml']
    save_ros_stereo(StereoCalibration(pair.left, pair.right), *files)
    return [str(f) for f in files]


def _nodes(tmp_path):
    """(package, executable, parameters) of every long-running node of the graph."""
    return [
        ('vlc_stereo_camera', 'stereo_camera_node', RIG),
        ('vlc_stereo_camera', 'adis16488_node', RIG),
        ('vlc_stereo_camera', 'photodiode_node', {'follow_clock': False, **RIG}),
        ('vlc_decoder', 'vlc_decoder_node', {}),
        ('spot_locator', 'spot_locator_node', {}),
        ('imu_compensator', 'imu_compensator_node', {}),
        ('train_localizer', 'train_localizer_node', {}),
        ('companion_localizers', 'curvature_node', {}),
        ('companion_localizers', 'rssi_localizer_node', {}),
        ('companion_localizers', 'dead_reckoning_node', {}),
        ('companion_localizers', 'ins_beacon_node', {}),
        ('vlc_bags', 'bag_recorder', {'output': str(tmp_path / 'bag'),
                                      'topics': ['imu/data_raw']}),
        ('vlc_bags', 'bag_player', {'bag': str(SAMPLE_BAG), 'loop': True, 'rate': 0.5}),
        ('vlc_camera_input', 'sbs_splitter_node', {'calibration_files': _calibration(tmp_path)}),
        ('vlc_view', 'marker_node', {}),
        # idle here (its first injection an hour away): only its stop is tested
        ('vlc_evaluation', 'fault_injector_node', {'start_s': 3600.0}),
    ]


def _mapped_shm_files():
    """/dev/shm files some live process has mapped."""
    mapped = set()
    for maps in pathlib.Path('/proc').glob('[0-9]*/maps'):
        try:
            text = maps.read_text()
        except OSError:
            continue
        for line in text.splitlines():
            if '/dev/shm/' in line:
                mapped.add(line.split('/dev/shm/', 1)[1].split(' ')[0])
    return mapped


def _leaked_segments(before):
    """Fast DDS data segments created since ``before`` that no live process maps (a
    segment's ``<name>_el`` companion belongs to it; port segments are shared by every
    participant of a host and stay).
    """
    now = {p.name for p in SHM.glob('fastrtps_*') if not p.name.startswith('fastrtps_port')}
    mapped = {name.removesuffix('_el') for name in _mapped_shm_files()}
    return sorted(name for name in now - before if name.removesuffix('_el') not in mapped)


def _start_all(launch, tmp_path):
    procs = {exe: launch(pkg, exe, params) for pkg, exe, params in _nodes(tmp_path)}
    deadline = time.monotonic() + 25.0
    # a node is up once it logged its start line (every node logs one when built)
    while time.monotonic() < deadline:
        pending = [exe for exe, p in procs.items()
                   if p.poll() is None and '[INFO]' not in launch.output(p)]
        if not pending:
            break
        time.sleep(0.2)
    for exe, proc in procs.items():
        assert proc.poll() is None, f'{exe} died at start:\n{launch.output(proc)}'
    time.sleep(1.0)
    return procs


def _wait_all(procs, timeout_s=20.0):
    deadline = time.monotonic() + timeout_s
    for proc in procs.values():
        try:
            proc.wait(max(0.1, deadline - time.monotonic()))
        except Exception:  # noqa: BLE001 — reported by the exit-code assertion below
            pass


@pytest.mark.parametrize('signals', [(signal.SIGINT, signal.SIGINT), (signal.SIGTERM,)],
                         ids=['double_sigint', 'sigterm'])
def test_every_node_stops_with_exit_0_without_traceback_or_leftover_segment(
        launch, tmp_path, signals):
    if not SAMPLE_BAG.exists():
        pytest.fail(f'{SAMPLE_BAG} is missing')
    before = {p.name for p in SHM.glob('fastrtps_*')}
    procs = _start_all(launch, tmp_path)
    for i, signum in enumerate(signals):
        if i:
            time.sleep(0.02)     # ros2 launch forwards the terminal's SIGINT a moment later
        for proc in procs.values():
            os.killpg(proc.pid, signum)
    _wait_all(procs)
    hung = [proc for proc in procs.values() if proc.poll() is None]
    for proc in hung:
        # every node prints its threads' Python stacks on SIGUSR1 (vlc_common.process)
        with contextlib.suppress(ProcessLookupError):
            os.kill(proc.pid, signal.SIGUSR1)
    if hung:
        time.sleep(1.0)
    problems = []
    for exe, proc in procs.items():
        out = launch.output(proc)
        if proc.returncode != 0:
            # the log of every node that did not end with 0 (a watchdog's stacks, a
            # fatal line), not only of one still running
            problems.append(f'{exe}: exit code {proc.returncode}'
                            + (', still running' if proc in hung else '')
                            + f'; its log:\n{out[-6000:]}')
        if 'Traceback' in out:
            problems.append(f'{exe}: traceback\n{out[-2000:]}')
    assert not problems, '\n'.join(problems)
    assert _leaked_segments(before) == []


def test_sigusr1_prints_every_threads_stack_and_the_node_runs_on(launch):
    # what the stop test asks of a node that did not stop
    proc = launch('imu_compensator', 'imu_compensator_node', {})
    deadline = time.monotonic() + 20.0
    while '[INFO]' not in launch.output(proc) and time.monotonic() < deadline:
        assert proc.poll() is None, launch.output(proc)
        time.sleep(0.2)
    os.kill(proc.pid, signal.SIGUSR1)
    deadline = time.monotonic() + 5.0
    while 'most recent call first' not in launch.output(proc) and time.monotonic() < deadline:
        time.sleep(0.1)
    out = launch.output(proc)
    assert 'most recent call first' in out and 'File "' in out, out
    assert proc.poll() is None, out
    os.killpg(proc.pid, signal.SIGINT)
    assert proc.wait(20.0) == 0, launch.output(proc)
