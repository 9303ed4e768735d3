"""The shipped launch file names installed executables and parameter files.

``launch`` is not installable on these machines, so the file cannot be executed here;
this checks what can be checked without it: it parses, every Node it starts is an
installed executable, every parameter file it passes is installed, and it declares the
arguments its docstring promises.
"""
import ast
import pathlib

import pytest

ROOT = pathlib.Path(__file__).resolve().parents[3]
LAUNCH = ROOT / 'src' / 'vlc_bringup' / 'launch' / 'vlc_positioning.launch.py'
INSTALL = ROOT / 'install'


def _calls(tree, name):
    return [n for n in ast.walk(tree) if isinstance(n, ast.Call)
            and getattr(n.func, 'id', getattr(n.func, 'attr', None)) == name]


def _kw(call, key):
    for kw in call.keywords:
        if kw.arg == key and isinstance(kw.value, ast.Constant):
            return kw.value.value
    return None


@pytest.fixture(scope='module')
def tree():
    return ast.parse(LAUNCH.read_text(encoding='utf-8'))


def test_every_node_is_an_installed_executable(tree):
    nodes = [(_kw(c, 'package'), _kw(c, 'executable')) for c in _calls(tree, 'Node')]
    assert len(nodes) == 9
    for package, executable in nodes:
        assert (INSTALL / 'lib' / package / executable).exists(), (package, executable)


def test_every_parameter_file_is_installed(tree):
    files = [(c.args[0].value, c.args[1].value) for c in _calls(tree, '_config')]
    assert len(files) >= 6
    for package, name in files:
        assert (INSTALL / 'share' / package / 'config' / name).exists(), (package, name)
    assert (INSTALL / 'share' / 'vlc_bringup' / 'launch' / LAUNCH.name).exists()


def test_declared_arguments(tree):
    declared = {c.args[0].value for c in _calls(tree, 'DeclareLaunchArgument')}
    assert declared == {'use_rig', 'use_sim_time', 'motion_profile', 'speed_kmh',
                        'start_chainage_m', 'seed', 'alignment', 'lamp_map_path',
                        'use_curvature', 'curvature_speed_topic', 'use_sbs_camera',
                        'sbs_calibration_files', 'sbs_input', 'sbs_image_topic', 'use_view'}
