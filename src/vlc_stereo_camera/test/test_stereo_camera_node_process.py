"""The installed stereo_camera_node as a process: bad parameters and duration_s exit codes."""
import time

import pytest

pytestmark = pytest.mark.graph


@pytest.mark.parametrize('name, value, words', [
    ('fps', 0.0, ['fps']),
    ('chip_rate_hz', 50000.0, ['chip_rate_hz']),
    ('motion_profile', 'bogus', ['motion profile', 'bogus']),
    ('rig_profile', 'fancy', ['rig_profiles.yaml: rig_profile: unknown profile', "'fancy'"]),
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


def test_a_drawn_profile_writes_the_installation_the_command_writes(launch, tmp_path):
    from vlc_common.core.lamp_map import LampMap, resolve_lamp_map_path
    from vlc_common.core.vehicle import load_vehicle
    from vlc_stereo_camera.core.installation import draw_installation
    proc = launch('vlc_stereo_camera', 'stereo_camera_node',
                  params={'rig_profile': 'realistic', 'seed': 4, 'duration_s': 0.1,
                          'realtime_factor': 0.0, 'noise_bank_size': 1,
                          'installation_dir': str(tmp_path / 'node')})
    code = proc.wait(timeout=90)
    log = launch.output(proc)
    assert code == 0, log
    assert 'rig_profile realistic, seed 4' in log and 'camera_info = its calibration' in log
    inst = draw_installation('realistic', 4, load_vehicle(''),
                             LampMap.load(resolve_lamp_map_path('')))
    inst.write(tmp_path / 'core')
    for name in ('belief/left.yaml', 'belief/right.yaml', 'belief/vehicle.yaml',
                 'belief/lamp_map.yaml', 'truth/vehicle.yaml', 'truth/lamp_map.yaml'):
        assert ((tmp_path / 'node' / name).read_text()
                == (tmp_path / 'core' / name).read_text()), name


def test_a_calibration_for_another_image_size_stops_the_node(launch, tmp_path):
    from vlc_common.core.calibration import StereoCalibration, save_ros_stereo
    from vlc_common.core.camera import CameraIntrinsics, StereoCameraModel, StereoRig
    pair = StereoCameraModel.from_rig(StereoRig(intrinsics=CameraIntrinsics(
        640, 480, 520.0, 520.0, 319.5, 239.5)))
    left, right = tmp_path / 'left.yaml', tmp_path / 'right.yaml'
    save_ros_stereo(StereoCalibration(pair.left, pair.right), left, right)
    proc = launch('vlc_stereo_camera', 'stereo_camera_node',
                  params={'calibration_paths': [str(left), str(right)]})
    code = proc.wait(timeout=60)
    log = launch.output(proc)
    assert code == 2, log
    assert (f'{left}, {right}: image size: calibrated for 640x480 px, the images are '
            '1280x720 px') in log
    right.write_text('image_width: 1280\nimage_height: [\n')
    proc = launch('vlc_stereo_camera', 'stereo_camera_node',
                  params={'calibration_paths': [str(left), str(right)]})
    assert proc.wait(timeout=60) == 2
    log = launch.output(proc)
    assert 'invalid configuration' in log and f'{right}' in log, log
