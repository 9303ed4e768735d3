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
                      'lamp_map_path': str(folder / 'belief' / 'lamp_map.yaml'),
                      'error_model_path': str(folder / 'belief' / 'train_localizer_node.yaml')}
    truth = yaml.safe_load((folder / 'truth' / 'truth.yaml').read_text())
    assert truth['profile'] == 'harsh' and truth['seed'] == 9
    assert {'optics', 'vehicle_truth', 'vehicle_belief', 'lamps', 'calibration_error',
            'imu_clock_offset_s'} <= set(truth)
    assert (folder / 'belief' / 'left.yaml').exists()


def test_calibrate_installation_replaces_the_belief_by_a_checkerboard_calibration(
        tmp_path, capsys):
    from vlc_common.core.calibration import load_ros_stereo
    from vlc_evaluation.installation_calibration import main
    from vlc_stereo_camera import make_installation
    assert make_installation.main(['--profile', 'realistic', '--seed', '7',
                                   '--out', str(tmp_path)]) == 0
    drawn = load_ros_stereo(tmp_path / 'belief' / 'left.yaml', tmp_path / 'belief' / 'right.yaml')
    assert drawn.rms_px == 0.15
    assert main([str(tmp_path), '--pairs', '10']) == 0      # 16 by default; 10 for speed
    assert 'profile realistic, seed 7' in capsys.readouterr().out
    found = load_ros_stereo(tmp_path / 'belief' / 'left.yaml', tmp_path / 'belief' / 'right.yaml')
    report = yaml.safe_load((tmp_path / 'truth' / 'calibration.yaml').read_text())
    assert found.pairs == report['pairs_used'] >= 5
    assert found.rms_px == report['stereo_rms_px'] < 0.1
    # the calibration's errors against the truth are those of a good calibration
    assert max(abs(v) for cam in report['focal_error_percent'] for v in cam) < 0.1
    assert max(abs(v) for cam in report['principal_point_error_px'] for v in cam) < 1.0
    assert max(report['max_edge_displacement_error_px']) < 1.0
    assert report['rotation_error_deg'] < 0.05 and abs(report['baseline_error_mm']) < 0.5
    assert not (found.left.K == drawn.left.K).all()


def test_calibrate_installation_exits_2_on_an_ideal_or_missing_installation(tmp_path, capsys):
    from vlc_evaluation.installation_calibration import main
    from vlc_stereo_camera import make_installation
    assert main([str(tmp_path / 'none')]) == 2
    assert 'truth.yaml: (file): cannot read' in capsys.readouterr().err
    assert make_installation.main(['--profile', 'ideal', '--out', str(tmp_path)]) == 0
    capsys.readouterr()
    assert main([str(tmp_path)]) == 2
    assert 'truth.yaml: optics: missing or malformed' in capsys.readouterr().err


def test_receivers_get_the_survey_instead_of_the_rigs_map_but_keep_a_deliberate_one(tmp_path):
    from vlc_common.core.lamp_map import default_lamp_map_path
    from vlc_evaluation.runner import receiver_params
    curved = default_lamp_map_path('curved_demo')
    scenario = Scenario(name='c', seed=2, rig_profile='realistic', node_params={
        'stereo_camera_node': {'alignment': 'curved_demo', 'lamp_map_path': curved},
        'train_localizer_node': {'lamp_map_path': curved, 'alignment': 'curved_demo'},
        'vlc_decoder_node': {'lamp_map_path': str(tmp_path / 'forged.yaml')}})
    belief = write_installation(scenario, tmp_path)
    truth = yaml.safe_load((tmp_path / 'c.installation' / 'truth' / 'truth.yaml').read_text())
    assert truth['lamps'][0]['uid'] >> 12 == 2               # drawn on the curved line
    localizer = receiver_params(belief, scenario, 'train_localizer_node')
    assert localizer['lamp_map_path'] == belief['lamp_map_path']
    assert localizer['alignment'] == 'curved_demo'
    assert receiver_params(belief, scenario, 'vlc_decoder_node')['lamp_map_path'] == str(
        tmp_path / 'forged.yaml')
    assert receiver_params(belief, scenario, 'spot_locator_node') == belief
    assert receiver_params({}, scenario, 'spot_locator_node') == {}


def test_a_poorer_installation_states_its_error_model_to_the_localizer(tmp_path):
    """Harsh states a calibration of 0.45 px RMS and a mount measured to 0.15 deg, three
    times the reference the localizer's defaults state: its calibration and mount 1-sigma
    are written three times larger into belief/train_localizer_node.yaml, which only the
    localizer gets, after its own file (a scenario's -p parameters still win). realistic
    and its error-budget rows state nothing: the defaults, exactly.
    """
    from vlc_evaluation.runner import (
        read_error_model,
        receiver_params,
        receiver_params_files,
        stated_error_model,
    )
    defaults = {'stereo_scale_sigma': 0.001, 'focal_length_sigma': 0.001,
                'principal_point_sigma_px': 0.5, 'calibration_sigma_px': 0.5,
                'calibration_disparity_sigma_px': 0.8, 'mount_angle_sigma_deg': [0.05, 0.1, 0.1]}
    harsh = stated_error_model('harsh', defaults)
    assert harsh == {'stereo_scale_sigma': 0.003, 'focal_length_sigma': 0.003,
                     'principal_point_sigma_px': 1.5, 'calibration_sigma_px': 1.5,
                     'calibration_disparity_sigma_px': 2.4,
                     'mount_angle_sigma_deg': [0.15, 0.3, 0.3]}
    assert stated_error_model('harsh') == harsh          # the installed parameter file's
    for name in ('ideal', 'realistic', 'realistic/none', 'realistic/only-calibration',
                 'realistic/only-camera_mount'):
        assert stated_error_model(name) == {}, name
    assert write_installation(Scenario(name='r', seed=3, rig_profile='realistic'),
                              tmp_path).keys() == {'vehicle_path', 'lamp_map_path'}
    scenario = Scenario(name='h', seed=3, rig_profile='harsh', node_params={
        'train_localizer_node': {'calibration_sigma_px': 9.0}})
    belief = write_installation(scenario, tmp_path)
    written = yaml.safe_load(open(belief['error_model_path']))['/**']['ros__parameters']
    assert written == harsh
    assert read_error_model(tmp_path / 'h.installation' / 'belief') == harsh
    assert read_error_model(tmp_path / 'r.installation' / 'belief') == {}

    class Graph:
        def config_file(self, package, name):
            return f'{package}/{name}'
    files = receiver_params_files(belief, Graph(), 'train_localizer', 'train_localizer_node')
    assert files == ['train_localizer/train_localizer_node.yaml', belief['error_model_path']]
    assert receiver_params_files(belief, Graph(), 'spot_locator', 'spot_locator_node') == [
        'spot_locator/spot_locator_node.yaml']
    for exe in ('train_localizer_node', 'spot_locator_node'):
        assert 'error_model_path' not in receiver_params(belief, scenario, exe)
    assert receiver_params(belief, scenario, 'train_localizer_node')['calibration_sigma_px'] == 9.0
