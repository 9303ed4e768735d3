"""The disk memo of the renderer's start-up arrays gives the frames it gives without it.

A realistic installation (raw images through its drawn lenses, fixed pattern, two
noise banks) and the ideal rig (one bank) are rendered with the memo off, with it
filled by the first renderer and read by a second one, and after an entry was
corrupted: every frame bit for bit the same.
"""
import dataclasses

import numpy as np
import pytest

from vlc_common.core.lamp_map import LampMap, resolve_lamp_map_path
from vlc_common.core.vehicle import load_vehicle
from vlc_stereo_camera.core import optics_truth, precompute_cache, sensor_noise
from vlc_stereo_camera.core.installation import NominalCamera, draw_installation
from vlc_stereo_camera.core.renderer import RendererConfig, StereoRenderer
from vlc_stereo_camera.core.trajectory import MotionProfile, Trajectory, Vibration


@pytest.fixture(scope='module')
def nominal_map():
    return LampMap.load(resolve_lamp_map_path(''))


@pytest.fixture(autouse=True)
def memo_off_after():
    yield
    precompute_cache.set_directory(None)
    optics_truth.lens_map.cache_clear()


def _realistic(nominal_map, seed=3):
    inst = draw_installation('realistic', seed, load_vehicle(''), nominal_map,
                             NominalCamera())
    config = dataclasses.replace(RendererConfig(
        mount_xyz_m=tuple(inst.vehicle_truth.camera.position_m),
        placement_angle_deg=inst.vehicle_truth.camera.placement_angle_deg,
        pitch_deg=inst.vehicle_truth.camera.pitch_deg), **inst.renderer_fields())
    return config, inst.lamp_map_truth


def _frames(config, lamp_map, seed, memo):
    """Frames 0 and 5 of a train standing 4 m before a lamp, rendered by a new renderer
    (the process's own lens-map cache emptied first, so the memo is what is tested).
    """
    precompute_cache.set_directory(memo)
    optics_truth.lens_map.cache_clear()
    renderer = StereoRenderer(config, lamp_map,
                              Trajectory(MotionProfile('stationary', start_chainage_m=46.0),
                                         Vibration(seed=1)), seed=seed)
    return [np.concatenate([f.left, f.right]) for f in (renderer.render(0),
                                                        renderer.render(5))]


def _assert_same(a, b):
    for x, y in zip(a, b):
        np.testing.assert_array_equal(x, y)


def test_realistic_frames_are_the_same_with_the_memo_cold_warm_and_corrupted(
        nominal_map, tmp_path, monkeypatch):
    config, lamp_map = _realistic(nominal_map)
    reference = _frames(config, lamp_map, 3, None)
    assert reference[0].max() > 100          # a lamp is in the image
    _assert_same(_frames(config, lamp_map, 3, tmp_path), reference)
    entries = sorted(p.name.split('-')[0] for p in tmp_path.glob('*.npz'))
    assert entries == ['lens_map', 'lens_map', 'pattern_banks']
    # warm: read, not computed (the computations would fail)
    with monkeypatch.context() as m:
        def computed(*_args, **_kw):
            raise AssertionError('computed although in the memo')
        m.setattr(optics_truth, '_lens_map_arrays', computed)
        m.setattr(sensor_noise.SensorModel, 'pattern_bank', computed)
        _assert_same(_frames(config, lamp_map, 3, tmp_path), reference)
    for path in tmp_path.glob('*.npz'):
        path.write_bytes(b'not an npz')
    _assert_same(_frames(config, lamp_map, 3, tmp_path), reference)
    # replaced by whole entries again
    for path in tmp_path.glob('*.npz'):
        with np.load(path) as entry:
            assert entry.files
    # another seed draws other banks: a new entry, not the old one
    other = _frames(config, lamp_map, 4, tmp_path)
    assert not np.array_equal(other[0], reference[0])
    assert len(list(tmp_path.glob('pattern_banks-*.npz'))) == 2


def test_ideal_frames_are_the_same_with_the_memo_and_an_unwritable_directory(
        nominal_map, tmp_path):
    config = RendererConfig()
    reference = _frames(config, nominal_map, 7, None)
    _assert_same(_frames(config, nominal_map, 7, tmp_path), reference)
    assert [p.name.split('-')[0] for p in tmp_path.glob('*.npz')] == ['noise_bank']
    _assert_same(_frames(config, nominal_map, 7, tmp_path), reference)
    blocked = tmp_path / 'file'
    blocked.write_text('')
    _assert_same(_frames(config, nominal_map, 7, blocked / 'memo'), reference)
