"""Lamp-map refinement (core/lamp_refinement.py) and the file a line keeps it in
(core/lamp_refinement_file.py).
"""
import dataclasses
import functools
import re

import numpy as np
import pytest

from train_localizer.core.fix import RigGeometry
from train_localizer.core.lamp_refinement import (
    Refinement,
    RefinementConfig,
    TripletMeasurement,
)
from train_localizer.core.lamp_refinement_file import (
    RefinementFileError,
    load_refinement,
    read_kept,
    refined_map,
    save_refinement,
    survey_digest,
)
from train_localizer.core.localizer import Localizer, LocalizerConfig
from vlc_common.core.camera import StereoRig
from vlc_common.core.lamp_map import LampMap, straight_tunnel_map
from vlc_stereo_camera.core.trajectory import MotionProfile, Trajectory, Vibration
from vlc_stereo_camera.core.upstream import (
    SensorErrors,
    SensorSimulator,
    SimTiming,
    event_stream,
    feed_localizer,
)

X_AXIS = np.array([1.0, 0.0, 0.0])


# ------------------------------------------------------------ synthetic passes
def synthetic_pass(truth_e, rng, sigma=0.008, lam_sd=0.03, bias=None):
    """One pass's triplet measurements of a chain of lamps whose fixes read ``truth_e``
    (m, by uid order) too far, each measured with 1σ ``sigma`` plus the triplet's own
    repeatable error ``bias`` ({(a, b, c): m}; the same every pass, as on the graph).
    """
    uids = sorted(truth_e)
    out = []
    for a, b, c in zip(uids, uids[1:], uids[2:]):
        lam = float(np.clip(0.5 + rng.normal(0.0, lam_sd), 0.3, 0.7))
        q = truth_e[b] - lam * truth_e[a] - (1 - lam) * truth_e[c]
        q += (bias or {}).get((a, b, c), 0.0)
        out.append(TripletMeasurement((a, b, c), lam, q + rng.normal(0.0, sigma), sigma))
    return out


def chain(seed, n=30, gross=None):
    rng = np.random.default_rng(seed)
    uids = [0x1000 + k for k in range(1, n + 1)]
    e = dict(zip(uids, rng.normal(0.0, 0.003, n)))
    for k, v in (gross or {}).items():
        e[uids[k]] += v
    return uids, e, rng


def repeatable(uids, rng, sd=0.008):
    return {key: float(rng.normal(0.0, sd)) for key in zip(uids, uids[1:], uids[2:])}


@pytest.mark.parametrize('seed', [1, 2, 3])
def test_passes_find_a_lamp_off_its_survey_and_never_spoil_the_survey(seed):
    uids, truth, rng = chain(seed, gross={12: 0.05})
    bias = repeatable(uids, rng)
    sigma = dict.fromkeys(uids, 0.003)
    ref = Refinement()
    errors = {}
    for n in range(1, 11):
        ref = ref.merged(synthetic_pass(truth, rng, bias=bias))
        corr, off = ref.corrections(sigma)
        if n in (1, 10):
            errors[n] = np.array([truth[u] - corr[u][0] for u in uids[1:-1]])
            # honest: the stated 1σ covers the remaining error
            z = errors[n] / np.array([corr[u][1] for u in uids[1:-1]])
            assert np.mean(np.abs(z) < 3.0) >= 0.95
    assert set(off) == {uids[12]} and ref.passes == 10
    assert abs(errors[10][11]) < 0.025               # the gross lamp placed to 2.5 cm
    # a 3 mm survey is better than what a pass measures of a lamp (1 cm, much of it the
    # same every pass): the ordinary lamps keep their survey, no worse than it was
    raw = np.array([truth[u] for u in uids[1:-1] if u != uids[12]])
    left = np.delete(errors[10], 11)
    assert np.sqrt(np.mean(left ** 2)) < 1.1 * np.sqrt(np.mean(raw ** 2))
    assert not ref.flags                              # nothing moved


def test_a_poor_survey_is_improved_lamp_to_lamp():
    rng = np.random.default_rng(9)
    uids = [0x1000 + k for k in range(1, 41)]
    truth = dict(zip(uids, rng.normal(0.0, 0.03, len(uids))))     # a 3 cm survey
    sigma = dict.fromkeys(uids, 0.03)
    ref = Refinement()
    for _ in range(10):
        ref = ref.merged(synthetic_pass(truth, rng, sigma=0.004))
    corr, _ = ref.corrections(sigma)
    err = np.array([truth[u] - corr[u][0] for u in uids[1:-1]])
    raw = np.array([truth[u] for u in uids[1:-1]])
    # second differences say nothing of the survey's level and slope: of its errors
    # they remove the part that varies from lamp to lamp
    assert np.sqrt(np.mean(err ** 2)) < 0.7 * np.sqrt(np.mean(raw ** 2))
    assert np.mean(np.abs(err) < 3.0 * np.array([corr[u][1] for u in uids[1:-1]])) >= 0.9


@pytest.mark.parametrize('seed', [4, 5, 6, 7])
def test_a_lamp_moved_between_passes_is_flagged_within_three_passes(seed, tmp_path):
    uids, truth, rng = chain(seed)
    line = straight_tunnel_map(count=30)
    path = tmp_path / 'refinement.yaml'
    ref = Refinement()
    for _ in range(4):
        ref = ref.merged(synthetic_pass(truth, rng))
    before = dict(ref.triplets)
    moved = {**truth, uids[15]: truth[uids[15]] + 0.05}
    for _ in range(3):
        # each pass a run of its own: what it keeps goes through the file
        save_refinement(path, ref.merged(synthetic_pass(moved, rng)), line)
        ref = load_refinement(path, line)
        if ref.flags:
            break
    assert [f.uid for f in ref.flags] == [uids[15]] and ref.flags[0].kind == 'moved'
    # its fixes read 5 cm further: the lamp stands 5 cm back along the track
    assert ref.flags[0].reason.startswith(('moved -5', 'moved -4', 'moved -6'))
    # its earlier triplets are kept apart, not averaged with the new place
    assert set(ref.flags[0].previous) == {key for key in before if uids[15] in key}
    corr, _ = ref.corrections(dict.fromkeys(uids, 0.003))
    for _ in range(3):
        ref = ref.merged(synthetic_pass(moved, rng))
    corr, _ = ref.corrections(dict.fromkeys(uids, 0.003))
    assert corr[uids[15]][0] == pytest.approx(moved[uids[15]], abs=0.01)
    assert len(ref.flags) == 1


def test_no_lamp_is_flagged_on_an_ordinary_survey():
    for seed in range(10, 20):
        uids, truth, rng = chain(seed)
        ref = Refinement()
        for _ in range(10):
            ref = ref.merged(synthetic_pass(truth, rng))
        assert not ref.flags
        assert ref.corrections(dict.fromkeys(uids, 0.003))[1] == {}


def test_blocks_give_the_whole_solution():
    uids, truth, rng = chain(8, n=60, gross={30: 0.05})
    ref = Refinement()
    for _ in range(3):
        ref = ref.merged(synthetic_pass(truth, rng))
    sigma = dict.fromkeys(uids, 0.003)
    whole, _ = Refinement(RefinementConfig(block=1000), ref.triplets).corrections(sigma)
    blocks, _ = Refinement(RefinementConfig(block=7, overlap=12), ref.triplets).corrections(sigma)
    for u in uids:
        assert blocks[u][0] == pytest.approx(whole[u][0], abs=1e-5)
        assert blocks[u][1] == pytest.approx(whole[u][1], rel=1e-3)


# ------------------------------------------------------------ the localizer's passes
RIG = StereoRig()
SPEED_MPS = 60.0 / 3.6


@functools.cache
def pass_events(seed, moved=None):
    """One pass at 60 km/h; ``moved`` (index, m): that lamp really stands so much further
    along the track than anyone surveyed it.
    """
    truth = straight_tunnel_map(count=12)
    if moved is not None:
        lamps = list(truth.lamps)
        lamps[moved[0]] = dataclasses.replace(
            lamps[moved[0]], position_m=lamps[moved[0]].position_m + [moved[1], 0.0, 0.0])
        truth = LampMap(lamps)
    traj = Trajectory(MotionProfile('constant', start_chainage_m=8.0, speed_mps=SPEED_MPS),
                      Vibration(seed=seed))
    sim = SensorSimulator(traj, RIG, truth, SensorErrors(), np.random.default_rng(seed))
    return event_stream(sim, 0.0, 85.0 / SPEED_MPS, SimTiming(imu_rate_hz=100.0))


def surveyed(offsets):
    """The map the receivers get: lamps ``offsets`` {index: m} further along x."""
    lamps = straight_tunnel_map(count=12).lamps
    return LampMap([dataclasses.replace(lamp, position_m=lamp.position_m
                                        + [offsets.get(i, 0.0), 0.0, 0.0],
                                        position_sigma_m=[0.003, 0.003, 0.005])
                    for i, lamp in enumerate(lamps)])


def run_pass(belief, seed, applied=None, moved=None):
    k = RIG.intrinsics
    geometry = RigGeometry(fx=k.fx, fy=k.fy, cx=k.cx, cy=k.cy, baseline_m=RIG.baseline_m,
                           t_base_cam=RIG.cam_positions_base()[0], R_base_cam=RIG.R_base_cam)
    loc = Localizer(belief, LocalizerConfig(geometry=geometry, refinement=RefinementConfig(),
                                            refinement_applied=applied or {}))
    feed_localizer(loc, pass_events(seed, moved))
    return loc.pass_recorder.finish()


def test_a_pass_measures_each_lamp_against_its_neighbours_not_the_filter():
    """A lamp surveyed 5 cm too far shows in its own triplet (+5 cm) and half as much,
    negatively, in its neighbours' — the filter, which follows each lamp, would have
    blamed the next lamp alone.
    """
    offsets = {5: 0.05}
    ms = run_pass(surveyed(offsets), seed=3)
    assert len(ms) >= 4        # lamps 0x1002-0x1007; those still in view at stop are left out
    uids = [lamp.uid for lamp in straight_tunnel_map(count=12).lamps]
    for m in ms:
        e = [offsets.get(uids.index(u), 0.0) for u in m.uids]
        truth = e[1] - m.lam * e[0] - (1 - m.lam) * e[2]
        assert abs(m.q_m - truth) < max(3.0 * m.sigma_m, 0.01), m
    middle = {m.uids[1]: m.q_m for m in ms}
    assert middle[uids[5]] == pytest.approx(0.05, abs=0.02)


def test_a_refined_map_is_measured_in_survey_terms():
    """On a map already corrected by c, the pass's measurements add c back: the same
    numbers as on the survey, give or take the noise.
    """
    uids = [lamp.uid for lamp in straight_tunnel_map(count=12).lamps]
    raw = {m.uids: m.q_m for m in run_pass(surveyed({5: 0.05}), seed=4)}
    fixed = {m.uids: m.q_m for m in run_pass(surveyed({}), seed=4, applied={uids[5]: 0.05})}
    for key in set(raw) & set(fixed):
        assert fixed[key] == pytest.approx(raw[key], abs=0.012)


def test_a_lamp_moved_in_the_tunnel_is_flagged_within_three_passes(tmp_path):
    """Passes through the localizer: three on the line as surveyed, then lamp 5 is
    re-fitted 5 cm further along; what each pass keeps goes through the file.
    """
    line = surveyed({})
    path = tmp_path / 'refinement.yaml'
    flagged_at = None
    for k in range(6):
        moved = (5, 0.05) if k >= 3 else None
        ref = load_refinement(path, line) or Refinement()
        ref = ref.merged(run_pass(line, seed=30 + k, moved=moved))
        save_refinement(path, ref, line)
        if k < 3:
            assert not ref.flags                       # nothing moved yet
        elif ref.flags and flagged_at is None:
            flagged_at = k
    assert flagged_at is not None and flagged_at <= 5
    uid = straight_tunnel_map(count=12).lamps[5].uid
    flag = load_refinement(path, line).flags
    assert [f.uid for f in flag] == [uid] and flag[0].kind == 'moved'
    assert flag[0].reason.startswith(('moved +4', 'moved +5', 'moved +6'))
    assert flag[0].previous                            # its old triplets kept apart


# ------------------------------------------------------------ the file
LAMPS = straight_tunnel_map(count=12)


def kept_after(passes=2):
    uids, truth, rng = chain(1, n=12, gross={6: 0.05})
    ref = Refinement()
    for _ in range(passes):
        ref = ref.merged(synthetic_pass(dict(zip([lamp.uid for lamp in LAMPS.lamps],
                                                  truth.values())), rng))
    return ref


def test_file_round_trip_and_the_map_it_gives(tmp_path):
    path = tmp_path / 'refinement.yaml'
    ref = kept_after()
    save_refinement(path, ref, LAMPS, 'train_7')
    back = load_refinement(path, LAMPS)
    assert back.passes == 2 and set(back.triplets) == set(ref.triplets)
    for key, t in ref.triplets.items():
        assert back.triplets[key].q_m == pytest.approx(t.q_m, abs=1e-6)
    refined, kept = read_kept(path, LAMPS, lambda lamp: X_AXIS, 0.005)
    assert kept.state.startswith('from file (2 pass(es))') and not kept.refused
    gross = LAMPS.lamps[6].uid
    assert gross in kept.off_survey and kept.applied[gross] == pytest.approx(0.05, abs=0.015)
    lamp = refined.by_uid(gross)
    assert lamp.position_m[0] == pytest.approx(LAMPS.by_uid(gross).position_m[0]
                                               - kept.applied[gross])
    assert lamp.position_m[1:] == pytest.approx(LAMPS.by_uid(gross).position_m[1:])
    # no file yet: a first pass on the survey
    first, kept = read_kept(tmp_path / 'none.yaml', LAMPS, lambda lamp: X_AXIS, 0.005)
    assert first is LAMPS and kept.state.startswith('learning') and kept.base.passes == 0


def test_refined_map_replaces_the_along_track_sigma_only():
    lamp = LAMPS.lamps[0]
    out = refined_map(LAMPS, {lamp.uid: (0.01, 0.001)}, lambda lamp: X_AXIS, 0.005)
    assert out.lamps[0].position_sigma_m == pytest.approx([0.001, 0.005, 0.005])
    assert out.lamps[1] is LAMPS.lamps[1]


@pytest.mark.parametrize('edit,field', [
    (lambda d: 'line_ids: [unclosed', 'does not parse'),
    (lambda d: d.replace('line_ids:', 'lines:'), 'line_ids: missing'),
    (lambda d: d.replace('line_ids: [1]', 'line_ids: [2]'), 'another line'),
    (lambda d: d.replace('survey_digest: ', 'survey_digest: 0'), 'another survey'),
    (lambda d: d.replace('- [4097,', '- [9999,', 1), 'not in the lamp map'),
    (lambda d: re.sub(r'- \[4097, 4098, 4099, [0-9.]+,', '- [4097, 4098, 4099, 2.0,', d,
                      count=1),
     r'triplets\[0\]'),
])
def test_bad_files_are_refused_naming_file_and_field(tmp_path, edit, field):
    path = tmp_path / 'refinement.yaml'
    save_refinement(path, kept_after(), LAMPS)
    path.write_text(edit(path.read_text()))
    with pytest.raises(RefinementFileError, match=field) as exc:
        load_refinement(path, LAMPS)
    assert str(path) in str(exc.value)
    refined, kept = read_kept(path, LAMPS, lambda lamp: X_AXIS, 0.005)
    assert refined is LAMPS and kept.refused and kept.state.startswith('refused')


def test_digest_follows_the_survey():
    moved = surveyed({3: 0.001})
    assert survey_digest(moved) != survey_digest(surveyed({}))
    assert survey_digest(surveyed({})) == survey_digest(surveyed({}))
