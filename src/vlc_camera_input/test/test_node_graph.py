"""The installed sbs_splitter_node refuses to start without a usable calibration: exit
code 2 and a message naming the file and the field.
"""
import pytest

from vlc_common.core.calibration import StereoCalibration, save_ros_stereo
from vlc_common.core.camera import StereoCameraModel, StereoRig

pytestmark = [pytest.mark.graph, pytest.mark.ros]


def _exit(launch, params):
    proc = launch('vlc_camera_input', 'sbs_splitter_node', params)
    code = proc.wait(30)
    return code, launch.output(proc)


def test_unusable_calibration_at_start_exits_2_naming_file_and_field(launch, tmp_path):
    pair = StereoCameraModel.from_rig(StereoRig())
    left, right = tmp_path / 'left.yaml', tmp_path / 'right.yaml'
    save_ros_stereo(StereoCalibration(pair.left, pair.right), left, right)
    text = left.read_text()
    bad = tmp_path / 'bad_left.yaml'
    bad.write_text(text.replace('  rows: 3\n  cols: 4\n', '  rows: 4\n  cols: 3\n'))
    cases = [
        ({}, 'calibration_files: (parameter): no calibration file given'),
        ({'calibration_files': [str(tmp_path / 'nope.yaml'), str(right)]},
         f'{tmp_path / "nope.yaml"}: (file): no such file'),
        ({'calibration_files': [str(bad), str(right)]},
         f'{bad}: projection_matrix: expected 3x4, got 4x3'),
        ({'calibration_files': [str(left), str(right)], 'input': 'mjpeg'},
         "input: 'mjpeg' is not one of raw, compressed"),
    ]
    for params, message in cases:
        code, out = _exit(launch, params)
        assert code == 2, out
        assert 'invalid configuration, not starting' in out and message in out, out
        assert 'Traceback' not in out
