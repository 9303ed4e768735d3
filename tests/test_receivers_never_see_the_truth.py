"""The receivers know only what a real train would know.

The rig's truth (``ground_truth/*`` topics, an installation's ``truth/`` folder written by
``make_installation`` or ``stereo_camera_node``'s ``installation_dir``, the rig profiles)
is for the evaluation only. A static check over every receiver package's installed
sources (code, parameter files, launch files; tests excluded): none names a ground-truth
topic, a truth file or the simulator's installation, so none can subscribe to or open
them. The receivers get the belief (camera_info, ``belief/vehicle.yaml`` through
``vehicle_path``, ``belief/lamp_map.yaml`` through ``lamp_map_path``).
"""
import pathlib
import re

import pytest

SRC = pathlib.Path(__file__).resolve().parents[1] / 'src'
RECEIVERS = ('vlc_decoder', 'spot_locator', 'imu_compensator', 'train_localizer',
             'companion_localizers')
#: What a receiver must never name: the truth topics, the truth folder and files, the
#: simulator's installation and profiles (importing the simulator at all is refused by
#: test_package_rules.py).
FORBIDDEN = re.compile(r'ground_truth|truth/|truth\.yaml|rig_profile|installation_dir|'
                       r'make_installation|core\.installation')
SUFFIXES = {'.py', '.yaml', '.yml', '.xml', '.json', '.cfg', '.toml'}


def violations(package_dir):
    """[(file, line number, line)] of every forbidden name in a package's sources."""
    found = []
    for path in sorted(package_dir.rglob('*')):
        if (not path.is_file() or path.suffix not in SUFFIXES
                or 'test' in path.relative_to(package_dir).parts
                or path.name == 'package.xml'):
            continue
        for number, line in enumerate(path.read_text(encoding='utf-8').splitlines(), 1):
            if FORBIDDEN.search(line):
                found.append((str(path.relative_to(SRC)), number, line.strip()))
    return found


@pytest.mark.parametrize('package', RECEIVERS)
def test_no_receiver_opens_a_truth_file_or_topic(package):
    assert (SRC / package).is_dir()
    assert violations(SRC / package) == []


def test_the_check_catches_a_receiver_that_peeks(tmp_path):
    pkg = tmp_path / 'peeking_receiver'
    (pkg / 'peeking_receiver').mkdir(parents=True)
    (pkg / 'test').mkdir()
    (pkg / 'peeking_receiver' / 'node.py').write_text(
        "self.create_subscription(PoseStamped, 'ground_truth/pose', cb, 10)\n"
        "open(os.path.join(d, 'truth', 'truth.yaml'))\n")
    (pkg / 'peeking_receiver' / 'params.yaml').write_text("lamp_map_path: /x/truth/lamp_map.yaml\n")
    (pkg / 'test' / 'test_ok.py').write_text("'ground_truth/pose'\n")   # tests may
    global SRC
    saved, SRC = SRC, tmp_path
    try:
        found = violations(pkg)
    finally:
        SRC = saved
    assert [(f, n) for f, n, _ in found] == [
        ('peeking_receiver/peeking_receiver/node.py', 1),
        ('peeking_receiver/peeking_receiver/node.py', 2),
        ('peeking_receiver/peeking_receiver/params.yaml', 1)]
