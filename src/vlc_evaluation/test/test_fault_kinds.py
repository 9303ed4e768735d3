"""The fault injector's kinds: each carries its defect, and the receivers' conversions
(or their stamp guards) refuse every one of them. Its parameter file documents every
declared parameter with its default.
"""
import math
import pathlib

import pytest
import yaml

pytest.importorskip('rclpy')

from imu_compensator.conversions import imu_sample  # noqa: E402
from train_localizer import conversions as localizer_conversions  # noqa: E402
from vlc_common.camera_info import CameraInfoKeeper  # noqa: E402
from vlc_common.core.stamp_guard import StampGuard  # noqa: E402
from vlc_common.images import ImageError, image_to_array  # noqa: E402
from vlc_common.stamps import NS_PER_S, stamp_to_ns  # noqa: E402
from vlc_evaluation import fault_kinds  # noqa: E402
from vlc_evaluation.fault_injector_node import PARAMETERS  # noqa: E402

NOW_NS = 1_704_067_210 * NS_PER_S
CONFIG = pathlib.Path(__file__).resolve().parents[1] / 'config' / 'fault_injector_node.yaml'
STAMP_KINDS = {'image_stamp_1970_sec0', 'image_stamp_1970_sec1', 'image_stamp_future',
               'imu_stamp_1970', 'imu_stamp_future', 'cloud_stamp_1970', 'cloud_stamp_future'}


def _templates():
    """Templates as the injector has them in a running graph (real messages seen)."""
    t = fault_kinds.Templates(now_ns=NOW_NS)
    t.infos = [fault_kinds.default_camera_info(side) for side in ('left', 'right')]
    for info in t.infos:
        info.header.stamp.sec = NOW_NS // NS_PER_S - 1
    t.imu = {key: fault_kinds.default_imu(key, NOW_NS - 2_500_000) for key in ('imu_raw', 'imu')}
    return t


def _stamp_outlier(stamp_ns, newest_ns):
    """What a receiver's StampGuard does with one stamp between real ones."""
    guard = StampGuard(NS_PER_S, NS_PER_S)
    guard.push(newest_ns)
    held = guard.push(stamp_ns).held
    return held and guard.push(newest_ns + 1).dropped == [(stamp_ns, None)]


def test_every_kind_builds_its_messages_with_and_without_templates():
    assert len(fault_kinds.ALL_KINDS) == len(set(fault_kinds.ALL_KINDS)) >= 30
    groups = {'image': {'left_image', 'right_image'}, 'camera_info': {'left_info', 'right_info'},
              'imu': {'imu_raw', 'imu'}, 'cloud': {'pairs', 'lamps'}}
    for kind, info in fault_kinds.KINDS.items():
        assert info['text'] and info['group'] in groups
        for templates in (_templates(), fault_kinds.Templates(now_ns=NOW_NS)):
            msgs = fault_kinds.build(kind, templates)
            assert {key for key, _ in msgs} == groups[info['group']], kind
        assert set(fault_kinds.topics_of(kind)) == groups[info['group']]


@pytest.mark.parametrize('kind', [k for k in fault_kinds.ALL_KINDS
                                  if fault_kinds.KINDS[k]['group'] == 'image'])
def test_image_kinds_are_refused_or_dropped(kind):
    t = _templates()
    for _, msg in fault_kinds.build(kind, t):
        stamp = stamp_to_ns(msg.header.stamp)
        if kind in STAMP_KINDS:
            assert image_to_array(msg).shape == (720, 1280)           # valid content
            assert _stamp_outlier(stamp, NOW_NS)
        elif kind == 'image_size_not_camera_info':
            assert image_to_array(msg).shape == (360, 640)            # not camera_info's
        else:
            with pytest.raises(ImageError):
                image_to_array(msg)
            assert stamp > stamp_to_ns(t.infos[0].header.stamp)       # after the frame


@pytest.mark.parametrize('kind', [k for k in fault_kinds.ALL_KINDS
                                  if fault_kinds.KINDS[k]['group'] == 'camera_info'])
def test_camera_info_kinds_never_replace_the_good_one(kind):
    t = _templates()
    keeper = CameraInfoKeeper()
    for side, info in enumerate(t.infos):
        keeper.update(side, info)
    for key, msg in fault_kinds.build(kind, t):
        side = 0 if key == 'left_info' else 1
        outcome, _ = keeper.update(side, msg)
        assert outcome in (keeper.REFUSED, keeper.PENDING)
        assert keeper.current[side] is t.infos[side]


@pytest.mark.parametrize('kind', [k for k in fault_kinds.ALL_KINDS
                                  if fault_kinds.KINDS[k]['group'] == 'imu'])
def test_imu_kinds_are_not_finite_dropped_or_duplicates(kind):
    t = _templates()
    for key, msg in fault_kinds.build(kind, t):
        real = t.imu[key]
        stamp = stamp_to_ns(msg.header.stamp)
        t_s, gyro, accel = imu_sample(msg)
        raw_finite = math.isfinite(float(gyro.sum() + accel.sum()))
        sample = localizer_conversions.imu_from_msg(msg)
        if kind in STAMP_KINDS:
            assert _stamp_outlier(stamp, stamp_to_ns(real.header.stamp))
        elif kind == 'imu_duplicate_stamp':
            assert stamp == stamp_to_ns(real.header.stamp)
        elif 'orientation' in kind or 'quaternion' in kind:
            # imu/data_raw carries no orientation (REP-145): the compensator ignores it
            assert raw_finite and (key == 'imu_raw' or not sample.is_finite())
        else:
            assert not sample.is_finite()
            if 'orientation' not in kind:
                assert not raw_finite


@pytest.mark.parametrize('kind', [k for k in fault_kinds.ALL_KINDS
                                  if fault_kinds.KINDS[k]['group'] == 'cloud'])
def test_cloud_kinds_are_refused_or_carry_nothing_usable(kind):
    t = _templates()
    for key, msg in fault_kinds.build(kind, t):
        topic, required = {'pairs': ('spots/pairs', ('u_left', 'v_left', 'u_right', 'v_right')),
                           'lamps': ('vlc/lamps', ('uid',))}[key]
        if kind in ('cloud_empty', 'cloud_nan_values') or kind in STAMP_KINDS:
            records = localizer_conversions.records_from_cloud(msg, topic, required)
            if kind == 'cloud_empty':
                assert records.size == 0
            elif kind == 'cloud_nan_values':
                assert math.isnan(records[required[0]][0] if key == 'pairs'
                                  else records['left_u'][0])
            else:
                assert _stamp_outlier(stamp_to_ns(msg.header.stamp), NOW_NS)
        else:
            with pytest.raises(ValueError, match=topic):
                localizer_conversions.records_from_cloud(msg, topic, required)


def test_yaml_lists_every_parameter_with_the_code_default():
    params = yaml.safe_load(CONFIG.read_text())['/**']['ros__parameters']
    declared = {name: default for name, default, _ in PARAMETERS}
    assert set(params) == set(declared)
    for name, default in declared.items():
        assert params[name] == (pytest.approx(default) if isinstance(default, float)
                                else default), name
    assert params['kinds'] == list(fault_kinds.ALL_KINDS)
    for kind in fault_kinds.ALL_KINDS:        # each kind named and explained in the file
        assert f'- {kind} ' in CONFIG.read_text()


def test_every_parameter_has_a_description_and_numbers_a_range():
    for name, default, descriptor in PARAMETERS:
        assert descriptor.description, name
        if isinstance(default, (int, float)) and not isinstance(default, bool):
            assert descriptor.floating_point_range or descriptor.integer_range, name
