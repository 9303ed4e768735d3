"""A scenario on a drawn rig profile: its installation is written beside the bag."""
import yaml

from vlc_evaluation.runner import write_installation
from vlc_evaluation.scenarios import Scenario


def test_ideal_scenarios_write_nothing_and_change_no_parameter(tmp_path):
    assert write_installation(Scenario(name='s'), tmp_path) == {}
    assert list(tmp_path.iterdir()) == []


def test_a_drawn_profile_records_profile_seed_and_every_drawn_value(tmp_path):
    params = write_installation(Scenario(name='run', seed=9, rig_profile='harsh'), tmp_path)
    folder = tmp_path / 'run.installation'
    assert params == {'vehicle_path': str(folder / 'belief' / 'vehicle.yaml'),
                      'lamp_map_path': str(folder / 'belief' / 'lamp_map.yaml')}
    truth = yaml.safe_load((folder / 'truth' / 'truth.yaml').read_text())
    assert truth['profile'] == 'harsh' and truth['seed'] == 9
    assert {'optics', 'vehicle_truth', 'vehicle_belief', 'lamps', 'calibration_error',
            'imu_clock_offset_s'} <= set(truth)
    assert (folder / 'belief' / 'left.yaml').exists()
