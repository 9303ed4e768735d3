"""config/imu_compensator_node.yaml documents every declared parameter with its default."""
import pathlib

import pytest
import yaml

from imu_compensator.imu_compensator_node import NODE_PARAMETERS

CONFIG = pathlib.Path(__file__).resolve().parents[1] / 'config' / 'imu_compensator_node.yaml'


def test_yaml_lists_every_parameter_with_the_code_default():
    params = yaml.safe_load(CONFIG.read_text())['/**']['ros__parameters']
    declared = {name: default for name, default, _ in NODE_PARAMETERS}
    assert set(params) == set(declared)
    for name, default in declared.items():
        value = params[name]
        if isinstance(default, (list, tuple)):
            assert value == pytest.approx(list(default), rel=1e-4), name
        elif isinstance(default, float):
            assert value == pytest.approx(default, rel=1e-4), name
        else:
            assert value == default, name


def test_every_parameter_has_a_description_and_numbers_a_range():
    for name, default, descriptor in NODE_PARAMETERS:
        assert descriptor.description, name
        if isinstance(default, (int, float)) and not isinstance(default, bool):
            assert descriptor.floating_point_range or descriptor.integer_range, name
