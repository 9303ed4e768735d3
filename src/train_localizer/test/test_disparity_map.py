"""The learnt disparity map (core/disparity_map.py), the file a train keeps it in
(core/disparity_map_file.py) and its use by the localizer.
"""
import dataclasses
import functools
import math

import numpy as np
import pytest

from train_localizer.core.disparity_map import DisparityMap, DisparityMapConfig
from train_localizer.core.disparity_map_file import (
    DisparityMapFileError,
    load_disparity_map,
    save_disparity_map,
)
from train_localizer.core.fix import RigGeometry
from train_localizer.core.localizer import Localizer, LocalizerConfig
from vlc_common.core.camera import StereoRig
from vlc_common.core.lamp_map import straight_tunnel_map
from vlc_stereo_camera.core.trajectory import MotionProfile, Trajectory, Vibration
from vlc_stereo_camera.core.upstream import (
    SensorErrors,
    SensorSimulator,
    SimTiming,
    along_track_errors,
    disparity_error_hook,
    event_stream,
    feed_localizer,
)

GEOMETRY = RigGeometry(fx=1040.0, fy=1040.0, cx=640.0, cy=360.0, baseline_m=0.12)
FB = GEOMETRY.fx * GEOMETRY.baseline_m
#: What the map learns of itself, with no cell borrowed from a neighbour.
OWN = DisparityMapConfig(extrapolate_cells=0)


def field(u):
    """A disparity error that is not one offset: larger toward the image edge, px."""
    x = (u - GEOMETRY.cx) / GEOMETRY.fx
    return 0.3 + 0.8 * x * x


def spot_u(along):
    """Column of a lamp ``along`` m ahead, 2.5 m to the side, in a camera turned 15°
    toward the wall: far lamps left of the centre, near ones toward the right edge.
    """
    return GEOMETRY.cx + GEOMETRY.fx * math.tan(math.atan2(2.5, along) - math.radians(15.0))


RANGES_M = np.linspace(16.0, 3.0, 60)


def lamp_pass(dm, uid, rng, ranges=RANGES_M, state_sigma_m=0.01, state_error_m=0.0):
    """Feed ``dm`` one lamp seen from ``ranges`` (m): the camera at the origin, the lamp
    2.5 m to the side (:func:`spot_u`), the measured disparity carrying :func:`field` and
    0.02 px of noise; the filter's chainage off by ``state_error_m`` and stating
    ``state_sigma_m``.
    """
    for r in ranges:
        along = math.sqrt(r * r - 2.5 ** 2)
        lamp = np.array([along, 2.5, 0.0])
        u, v = spot_u(along), GEOMETRY.cy - 40.0
        k = math.hypot(1.0, math.hypot((u - GEOMETRY.cx) / GEOMETRY.fx,
                                       (v - GEOMETRY.cy) / GEOMETRY.fy))
        d = FB * k / r + field(u) + rng.normal(0.0, 0.02)
        camera = np.array([state_error_m, 0.0, 0.0])     # where the filter puts it
        res = dm.residual((u, v), v, d, lamp, camera, along - state_error_m, state_sigma_m,
                          GEOMETRY)
        if res is not None:
            dm.add(u, v, res[0], res[1], uid)


def test_the_field_is_learnt_where_the_reference_allows_and_nowhere_else():
    dm = DisparityMap(OWN)
    rng = np.random.default_rng(1)
    lamp_pass(dm, 0x1001, rng)
    # one lamp pass: nothing is used yet (a single lamp could be off its survey)
    assert all(dm.correction(u, 320.0) is None for u in range(0, 1400, 16))
    lamp_pass(dm, 0x1002, rng)
    known = [u for u in range(0, 1400, 8) if dm.correction(u, 320.0) is not None]
    assert known, 'cells learnt after two passes'
    for u in known:
        delta, sigma = dm.correction(u, 320.0)
        assert sigma >= dm.config.sigma_floor_px
        assert abs(delta - field(u)) <= sigma                   # what it states holds
        if u < spot_u(8.0):                                      # lamps 8-16 m ahead
            assert delta == pytest.approx(field(u), abs=0.03)
    assert dm.correction(known[-1], 700.0) is None          # another row: unknown
    cells, residuals, mean_abs = dm.summary()
    assert cells >= 1 and residuals > 0 and 0.3 < mean_abs < 1.2
    # against a 3 cm reference the near lamps say little about the disparity (0.3 px at
    # 3 m): their cells stay unknown, the far ones are learnt
    dm = DisparityMap(OWN)
    for uid in (1, 2):
        lamp_pass(dm, uid, rng, state_sigma_m=0.03)
    assert dm.correction(spot_u(12.0), 320.0) is not None
    assert dm.correction(spot_u(3.0), 320.0) is None


def test_an_unknown_cell_borrows_the_nearest_learnt_one_with_a_wider_sigma():
    """Against a 3 cm reference the near lamps' cells are not learnt (above); a cell
    within ``extrapolate_cells`` of a learnt one borrows its offset, and the σ it states
    covers the true field there; farther cells stay unknown; a borrowed estimate follows
    its source as it learns.
    """
    rng = np.random.default_rng(5)
    own, dm = DisparityMap(OWN), DisparityMap(DisparityMapConfig(extrapolate_cells=3))
    wide = DisparityMap()                           # the default reach: 6 cells
    assert wide.config.extrapolate_cells == 6
    for uid in (1, 2):
        lamp_pass(own, uid, rng, state_sigma_m=0.03)
    dm.run = {k: dataclasses.replace(c) for k, c in own.run.items()}
    wide.run = {k: dataclasses.replace(c) for k, c in own.run.items()}
    learnt = sorted(k[0] for k in own.cells() if own._estimate(k) is not False)
    row_v = 320.0
    edge = learnt[-1]                              # the learnt cell nearest the near lamps
    c = dm.config.cell_px
    for di in (1, 2, 3):
        u = (edge + di + 0.5) * c
        assert own.correction(u, row_v) is None
        delta, sigma = dm.correction(u, row_v)
        source, source_sigma = own.correction((edge + 0.5) * c, row_v)
        assert delta == pytest.approx(own._estimate((edge, int(row_v // c)))[0])
        assert sigma == pytest.approx(source_sigma + 0.5 * abs(delta))
        assert abs(delta - field(u)) <= sigma      # what it states holds
    assert dm.correction((edge + 4 + 0.5) * c, row_v) is None     # beyond the reach
    for di in range(1, 7):                          # what the default reach states holds
        u = (edge + di + 0.5) * c
        delta, sigma = wide.correction(u, row_v)
        assert abs(delta - field(u)) <= sigma, di
    assert wide.correction((edge + 7 + 0.5) * c, row_v) is None
    assert dm.correction((edge + 0.5) * c, 700.0) is None        # six rows away
    before = dm.correction((edge + 1.5) * c, row_v)
    for _ in range(40):                             # the source cell learns more
        dm.add((edge + 0.5) * c, row_v, 1.0, 0.03, 0x1009)
    after = dm.correction((edge + 1.5) * c, row_v)
    assert after[0] > before[0] + 0.1
    with pytest.raises(ValueError, match='extrapolat'):
        DisparityMapConfig(extrapolate_cells=-1)


def test_a_filter_too_uncertain_is_no_reference():
    dm = DisparityMap()
    lamp_pass(dm, 0x1001, np.random.default_rng(2), state_sigma_m=0.2)
    assert not dm.run
    dm = DisparityMap(DisparityMapConfig(max_state_sigma_m=0.3))
    lamp_pass(dm, 0x1001, np.random.default_rng(2), state_sigma_m=0.2)
    # only lamps far enough that 20 cm of chainage is below 0.12 px were used
    used = list(dm.run.values())
    assert used and sum(c.residuals for c in used) < 30


def test_a_biased_reference_moves_the_map_by_what_it_maps_to():
    """A filter 2 cm off moves the learnt far cells by ≈ fx·b·along/r³·2 cm (≤ 0.03 px
    beyond 8 m, plus noise), not by the decimetres of range error a far lamp's disparity has.
    """
    dm = DisparityMap(OWN)
    rng = np.random.default_rng(3)
    for uid in (1, 2, 3):
        lamp_pass(dm, uid, rng, state_error_m=0.02)
    far = [u for u in range(0, int(spot_u(8.0)), 8) if dm.correction(u, 320.0) is not None]
    assert far
    for u in far:
        assert abs(dm.correction(u, 320.0)[0] - field(u)) < 0.05


def test_kept_cells_add_to_this_run_and_round_trip(tmp_path):
    rng = np.random.default_rng(4)
    first = DisparityMap(OWN)
    lamp_pass(first, 1, rng)
    lamp_pass(first, 2, rng)
    path = tmp_path / 'disparity_map.yaml'
    save_disparity_map(path, first.cells(), 'train_7', FB, 64.0, runs=1)
    cells, runs, fx_b = load_disparity_map(path, 'train_7', 64.0)
    assert runs == 1 and fx_b == pytest.approx(FB)
    assert cells == first.cells()                  # YAML keeps every float exactly
    second = DisparityMap(OWN, kept=cells, kept_fx_b=fx_b)
    assert second.check_calibration(FB) == ''
    u = next(u for u in range(0, 1400, 8) if first.correction(u, 320.0) is not None)
    assert second.correction(u, 320.0) == pytest.approx(first.correction(u, 320.0))
    lamp_pass(second, 1, rng)
    key = second._key(u, 320.0)
    assert second.cell(key).passes == first.cell(key).passes + 1
    # learnt on another calibration: the kept cells are dropped, learning starts afresh
    other = DisparityMap(OWN, kept=cells, kept_fx_b=fx_b)
    assert 'this calibration has' in other.check_calibration(FB * 1.01)
    assert other.correction(u, 320.0) is None and not other.kept


@pytest.mark.parametrize('text,field_name', [
    (': not yaml [', 'does not parse'),
    ('- a list\n', 'not a mapping'),
    ('vehicle_id: train_7\ncell_px: 64\ncells: []\n', 'camera_fx_b_px_m: missing'),
    ('vehicle_id: train_9\ncamera_fx_b_px_m: 124.8\ncell_px: 64\ncells: []\n',
     'vehicle_id'),
    ('vehicle_id: train_7\ncamera_fx_b_px_m: 124.8\ncell_px: 32\ncells: []\n', 'cell_px'),
    ('vehicle_id: train_7\ncamera_fx_b_px_m: .nan\ncell_px: 64\ncells: []\n',
     'camera_fx_b_px_m'),
    ('vehicle_id: train_7\ncamera_fx_b_px_m: 124.8\ncell_px: 64\ncells: [[1, 2, 3]]\n',
     'cells[0]'),
    ('vehicle_id: train_7\ncamera_fx_b_px_m: 124.8\ncell_px: 64\n'
     'cells: [[1, 2, 3, 4, -1.0, 0, 0, 0, 0, 0]]\n', 'cells[0]'),
    ('vehicle_id: train_7\ncamera_fx_b_px_m: 124.8\ncell_px: 64\n'
     'cells: [[1, 2, 3, 4, 1.0, 0, 0, .inf, 0, 0]]\n', 'cells[0]'),
    ('vehicle_id: train_7\ncamera_fx_b_px_m: 124.8\ncell_px: 64\nruns: 0\ncells: []\n',
     'runs'),
])
def test_bad_files_are_refused_naming_file_and_field(tmp_path, text, field_name):
    path = tmp_path / 'disparity_map.yaml'
    path.write_text(text)
    with pytest.raises(DisparityMapFileError) as err:
        load_disparity_map(path, 'train_7', 64.0)
    assert str(path) in str(err.value) and field_name in str(err.value)


def test_no_file_is_a_first_run(tmp_path):
    assert load_disparity_map(tmp_path / 'none.yaml', 'train_7', 64.0) is None


# --------------------------------------------------------------- the localizer
RIG = StereoRig()
LAMPS = straight_tunnel_map(count=10)
SPEED_MPS = 20.0 / 3.6


@functools.cache
def truth_pass(seed):
    """(trajectory, events): 60 m at 20 km/h past six lamps (IMU at 100 Hz); a lamp's UID
    is confirmed some 9 m ahead.
    """
    traj = Trajectory(MotionProfile('constant', start_chainage_m=8.0, speed_mps=SPEED_MPS),
                      Vibration(seed=seed))
    sim = SensorSimulator(traj, RIG, LAMPS, SensorErrors(), np.random.default_rng(seed))
    return traj, event_stream(sim, 0.0, 60.0 / SPEED_MPS, SimTiming(imu_rate_hz=100.0))


def run_pass(seed, dm_config, kept=None, error=None):
    """(along-track errors, published σ, localizer) of a pass whose disparities carry
    ``error(u)`` px (default :func:`field`), the receiver stating a 0.8 px calibration
    disparity σ (raw images); ``kept``: a DisparityMap's cells from an earlier pass.
    """
    error = error or field
    traj, events = truth_pass(seed)
    geometry = dataclasses.replace(RigGeometry.from_stereo_rig(RIG),
                                   calibration_sigma_px=(0.2, 0.8), raw_images=True)
    config = LocalizerConfig(geometry=geometry, disparity_map=dm_config,
                             disparity_map_kept=kept or {},
                             disparity_map_kept_fx_b=geometry.fx * geometry.baseline_m)
    loc = Localizer(LAMPS, config)
    poses, _, _ = feed_localizer(loc, events, frame_hook=disparity_error_hook(error))
    return (*along_track_errors(traj, poses, 1.0), loc)


def test_a_learnt_map_corrects_the_far_lamps_of_the_next_pass():
    """Pass 1 learns the field; pass 2 (other noise and vibration) reads it: its far
    fixes are corrected and stated with the map's σ, its error falls, and every pose
    stays within its 3σ.
    """
    err_off, _, _ = run_pass(5, None)
    _, _, first = run_pass(4, DisparityMapConfig())
    cells = first.disparity_map.cells()
    assert cells and first.disparity_map.summary()[0] >= 1
    err_on, sigma_on, second = run_pass(5, DisparityMapConfig(), kept=cells)
    corrected = [key for key in second.disparity_map.cells()
                 if second.disparity_map._estimate(key) is not False]
    for key in corrected:
        a, _, sigma, centre = second.disparity_map._estimate(key)
        assert abs(a - field(centre)) < max(2.0 * sigma, 0.1)
    assert np.mean(np.abs(err_on)) < np.mean(np.abs(err_off))
    assert np.mean(np.abs(err_on) <= 3.0 * sigma_on) >= 0.997


def test_the_map_is_off_for_an_exact_rectified_pair_and_when_switched_off():
    traj, events = truth_pass(5)
    loc = Localizer(LAMPS, LocalizerConfig(disparity_map=DisparityMapConfig()))
    ref = Localizer(LAMPS, LocalizerConfig())
    a = [p.chainage_m for p in feed_localizer(loc, events)[0]]
    b = [p.chainage_m for p in feed_localizer(ref, events)[0]]
    assert a == b and not loc.disparity_map.run
    err_a, _, off = run_pass(5, None)
    assert off.disparity_map is None
