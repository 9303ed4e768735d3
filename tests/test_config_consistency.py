"""The camera timing every node assumes must be the camera's: one value per key across
the shipped parameter files (a mismatch mis-stamps spots or misreads chips).
"""
import pathlib

import pytest
import yaml

SRC = pathlib.Path(__file__).resolve().parents[1] / 'src'
FILES = {
    'stereo_camera_node': SRC / 'vlc_stereo_camera/config/stereo_camera_node.yaml',
    'vlc_decoder_node': SRC / 'vlc_decoder/config/vlc_decoder_node.yaml',
    'spot_locator_node': SRC / 'spot_locator/config/spot_locator_node.yaml',
    'train_localizer_node': SRC / 'train_localizer/config/train_localizer_node.yaml',
    'dead_reckoning_node': SRC / 'companion_localizers/config/dead_reckoning_node.yaml',
    'ins_beacon_node': SRC / 'companion_localizers/config/ins_beacon_node.yaml',
    'sbs_splitter_node': SRC / 'vlc_camera_input/config/sbs_splitter_node.yaml',
}


def _params(path):
    data = yaml.safe_load(path.read_text())
    return data['/**']['ros__parameters']


@pytest.mark.parametrize('key', ['row_time_s', 'exposure_s', 'chip_rate_hz', 'fps',
                                 'off_level'])
def test_camera_timing_agrees_across_nodes(key):
    values = {node: _params(path)[key] for node, path in FILES.items()
              if key in _params(path)}
    assert 'stereo_camera_node' in values or key == 'fps', values
    assert len(set(values.values())) == 1, f'{key} differs between nodes: {values}'


def test_system_runs_21_15_kchips_with_25_us_exposure():
    cam = _params(FILES['stereo_camera_node'])
    assert cam['chip_rate_hz'] == 21150.0 and cam['exposure_s'] == 2.5e-05


def test_demo_pictures_show_the_graphs_camera_timing():
    from vlc_evaluation.demo_images import DEMO_CONFIG
    cam = _params(FILES['stereo_camera_node'])
    assert DEMO_CONFIG.chip_rate_hz == cam['chip_rate_hz']
    assert DEMO_CONFIG.exposure_s == cam['exposure_s']
    assert DEMO_CONFIG.row_time_s == cam['row_time_s']
