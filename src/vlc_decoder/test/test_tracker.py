"""Frame pipeline: stereo pairing, tracking, right-image fallback; fed by the rig too."""
import dataclasses
import logging
import pathlib

import numpy as np
import pytest

from vlc_decoder.core import synth
from vlc_decoder.core.assembly import CONFIRMED
from vlc_decoder.core.config import DecoderConfig, signal_timing_from_params_file
from vlc_decoder.core.spots import detect
from vlc_decoder.core.tracker import LampTracker, combine_profiles, pair_spots, path_prediction

CFG = DecoderConfig()
NODE_PARAMS = pathlib.Path(__file__).resolve().parents[1] / 'config' / 'vlc_decoder_node.yaml'


class MapStub:
    def __init__(self, uids):
        self.positions = {u: np.array([10.0 * i, 2.5, 1.4]) for i, u in enumerate(uids)}

    def by_uid(self, uid):
        pos = self.positions.get(uid)
        return None if pos is None else type('Lamp', (), {'position_m': pos})()


def test_right_image_stands_in_when_the_left_spot_is_cut():
    """A lamp at the left image's right border: its left spot is cut, the right one whole."""
    rng = np.random.default_rng(21)
    uid = 0x1005
    signal = synth.LampSignal(uid, phase_s=rng.uniform(0, 1))
    tracker = LampTracker(CFG, MapStub([uid]))
    confirmed_at = None
    for k in range(60):
        # the train creeps: the spot moves by a row per frame, so frames see new chips
        lamp = synth.SyntheticLamp(signal, 1278.0, 200.0 + k, 30.0, 14.0, 40.0)
        left, right = synth.render_stereo([lamp], k / 30.0, rng=rng)
        records = tracker.process(int(round(k / 30 * 1e9)), left, right)
        assert len(records) == 1
        rec = records[0]
        assert rec.left is not None and rec.left.cut and not rec.right.cut
        assert rec.source == 'right'
        if rec.state == CONFIRMED:
            confirmed_at = k
            assert rec.uid == uid
            np.testing.assert_allclose(rec.position_m, [0.0, 2.5, 1.4])
            break
    assert confirmed_at is not None
    assert len(tracker.tracks) == 1


def test_pairing_and_combined_profile():
    rng = np.random.default_rng(22)
    lamps = [synth.SyntheticLamp(synth.LampSignal(0x1001, phase_s=1e-3), 1100, 150, 22, 12, 36),
             synth.SyntheticLamp(synth.LampSignal(0x1002, phase_s=2e-3), 500, 500, 45, 50, 70)]
    left, right = synth.render_stereo(lamps, 0.0, rng=rng)
    pairs = pair_spots(detect(left, CFG), detect(right, CFG), 250.0)
    assert len(pairs) == 2
    for a, b in pairs:
        assert a is not None and b is not None
        assert a.u - b.u == pytest.approx(22 if a.u > 800 else 45, abs=1.0)
        rows, level, weight, source = combine_profiles(a, b)
        assert source == 'both'
        # every row that carries weight is kept (cap rows beyond the chord cut are not)
        assert set(rows) <= set(a.rows) | set(b.rows)
        assert len(rows) >= np.count_nonzero(a.weight > 0) - 2
        assert np.all(np.diff(rows) > 0) and np.all((weight > 0) & (weight <= 1))


def test_synthetic_pass_one_track_per_lamp_and_right_uids():
    uids = [0x1001, 0x1002, 0x1003]
    tracker = LampTracker(CFG, MapStub(uids))
    seen = {}
    for stamp, left, right, _ in synth.pass_frames(60.0, uids, seed=3):
        for rec in tracker.process(stamp, left, right):
            if rec.state >= CONFIRMED:
                assert rec.uid in uids
                seen.setdefault(rec.uid, set()).add(rec.track_id)
    assert set(seen) == set(uids)
    assert all(len(ids) == 1 for ids in seen.values())


def test_out_of_order_stamp_is_refused():
    tracker = LampTracker(CFG)
    blank = np.full((720, 1280), 4, np.uint8)
    tracker.process(10 ** 9, blank, blank)
    with pytest.raises(ValueError):
        tracker.process(10 ** 9, blank, blank)
    # a step back within stamp_jump_reset_s is a late frame, not a new sequence
    with pytest.raises(ValueError):
        tracker.process(10 ** 9 - int(0.5 * CFG.stamp_jump_reset_s * 1e9), blank, blank)
    assert tracker.resets == 0


def test_stamp_jump_back_resets_the_tracks(caplog):
    """A looped bag: the stamps jump back; fragments are never mixed across the jump."""
    uids = [0x1001, 0x1002]
    tracker = LampTracker(CFG)
    frames = list(synth.pass_frames(40.0, uids, n_frames=40, seed=3))
    for stamp_ns, left, right, _ in frames:
        tracker.process(stamp_ns, left, right)
    before = {t.track_id for t in tracker.tracks}
    assert before and any(t.assembler.uid is not None for t in tracker.tracks)
    with caplog.at_level('WARNING', logger='vlc_decoder.core.tracker'):
        stamp_ns, left, right, _ = frames[20]      # 0.63 s back, lamps in view
        records = tracker.process(stamp_ns, left, right)
    assert tracker.resets == 1
    assert any('jumped back' in r.getMessage() for r in caplog.records)
    assert records and all(r.track_id > max(before) for r in records)
    assert all(r.state != CONFIRMED for r in records)
    assert all(len(t.assembler.fragments) == 1 for t in tracker.tracks)
    # the replay decodes again from scratch
    for stamp_ns, left, right, _ in frames[21:]:
        records = tracker.process(stamp_ns, left, right)
    assert {r.uid for r in records if r.state == CONFIRMED} <= set(uids)


def _lamp_frame(lamps, k):
    return synth.render_stereo(lamps, k / 30.0, rng=np.random.default_rng(k))


def test_a_confirmed_track_never_carries_its_uid_to_another_lamp():
    """Lamp A is confirmed, then vanishes; its neighbour B (same line: same header and
    line bits) shows up inside A's gate but away from A's predicted position. B's
    stripes are off A's clock grid or contradict A's packet there: a new track.
    """
    wrong = 0
    for trial in range(12):
        rng = np.random.default_rng(100 + trial)
        uid_a = 0x1000 | int(rng.integers(1, 4000))
        signal_a = synth.LampSignal(uid_a, phase_s=rng.uniform(0, 0.01))
        signal_b = synth.LampSignal(uid_a + 1, phase_s=rng.uniform(0, 0.01))
        tracker = LampTracker(CFG)
        lamp_a = synth.SyntheticLamp(signal_a, 600.0, 300.0, 20.0, 16.0, 60.0)
        # A vanishes two frames after its confirmation (its clock as young as it gets)
        confirmed_at = None
        for k in range(40):
            records = tracker.process(int(k * 1e9 / 30), *_lamp_frame([lamp_a], k))
            if confirmed_at is None and records and records[0].state == CONFIRMED:
                confirmed_at = k
            if confirmed_at is not None and k >= confirmed_at + 2:
                break
        assert records[0].state == CONFIRMED and records[0].uid == uid_a
        # 80 px off: inside the gate (60 px + the spot's height), not a tight match
        lamp_b = synth.SyntheticLamp(signal_b, 680.0, 300.0, 20.0, 16.0, 60.0)
        last_a = k
        for j in range(last_a + 1, last_a + 5):
            for rec in tracker.process(int(j * 1e9 / 30), *_lamp_frame([lamp_b], j)):
                wrong += rec.state == CONFIRMED and rec.uid != uid_a + 1
    assert wrong == 0


def _two_spots_one_uid(frames=60, seed=3):
    """A tracker fed two still spots that blink one UID (a duplicated lamp, a reflection):
    (tracker, [records per frame], uid).
    """
    rng = np.random.default_rng(seed)
    uid = 0x1000 | int(rng.integers(1, 4000))
    lamps = [synth.SyntheticLamp(synth.LampSignal(uid, phase_s=rng.uniform(0, 0.01)),
                                 u, 300.0, 20.0, 16.0, 60.0) for u in (400.0, 900.0)]
    tracker = LampTracker(CFG)
    out = [tracker.process(int(k * 1e9 / 30), *_lamp_frame(lamps, k)) for k in range(frames)]
    return tracker, out, uid, lamps


def test_one_uid_is_never_confirmed_on_two_spots_of_a_frame(caplog):
    """Both spots decode the UID on tracks followed frame by frame: neither is reported
    confirmed while the other is (without the rule both were), and the frames are counted.
    """
    with caplog.at_level(logging.WARNING, logger='vlc_decoder.core.tracker'):
        tracker, out, uid, _ = _two_spots_one_uid()
    assert all(sum(r.state == CONFIRMED for r in records) <= 1 for records in out)
    assert tracker.duplicate_uid_frames > 1
    # warned once, though every later frame has the two spots
    assert sum('confirmed on 2 spots' in m for m in caplog.messages) == 1
    # the tracks themselves decoded it (so the rule, not the decoding, withheld it)
    assert [t.assembler.uid for t in tracker.tracks] == [uid, uid]


def test_a_track_reaching_a_spot_after_a_gap_is_split_off_when_its_uid_is_taken():
    """The stale track of the realistic rig's wrong UIDs: a confirmed track misses its
    spot for two frames and then takes a spot 80 px off (inside its grown gate, not a
    tight match) while another track holds a spot confirming the same UID: that spot
    starts a new track (not confirmed), the other keeps its confirmed UID.
    """
    tracker, out, uid, lamps = _two_spots_one_uid()
    k = len(out)
    ids = {round(t.u): t.track_id for t in tracker.tracks}
    for j in (k, k + 1):     # the spot at 900 px is not seen for two frames
        tracker.process(int(j * 1e9 / 30), *_lamp_frame(lamps[:1], j))
    moved = [lamps[0], dataclasses.replace(lamps[1], u_left=980.0)]
    records = tracker.process(int((k + 2) * 1e9 / 30), *_lamp_frame(moved, k + 2))
    by_u = {round(r.left.u / 100.0): r for r in records}
    assert by_u[4].state == CONFIRMED and by_u[4].uid == uid
    assert by_u[4].track_id == ids[400]
    assert by_u[10].state != CONFIRMED
    assert by_u[10].track_id not in ids.values()
    assert ids[900] not in {t.track_id for t in tracker.tracks}


# ---------------------------------------------------------------------- the rig
rig = pytest.importorskip('vlc_stereo_camera.core.renderer')


def rig_pass(speed_kmh, n_lamps, seed, cfg=CFG, **renderer_kw):
    from vlc_common.core.lamp_map import LampMap, resolve_lamp_map_path
    from vlc_stereo_camera.core.trajectory import MotionProfile, Trajectory, Vibration
    lamps = LampMap.load(resolve_lamp_map_path(''))
    trajectory = Trajectory(MotionProfile('constant', start_chainage_m=-2.0,
                                          speed_mps=speed_kmh / 3.6), Vibration(seed=seed))
    renderer = rig.StereoRenderer(rig.RendererConfig(**renderer_kw), lamps, trajectory,
                                  seed=seed)
    tracker = LampTracker(cfg, lamps)
    n = int((12 + 10 * (n_lamps - 1)) / (speed_kmh / 3.6) * 30)
    for k in range(n):
        frame = renderer.render(k)
        records = tracker.process(int(round(frame.t0_s * 1e9)), frame.left, frame.right)
        yield frame, records


def _truth_uid(frame, rec):
    spot = rec.left if rec.left is not None else rec.right
    uvs = [(t.uid, t.uv_left if rec.left is not None else t.uv_right) for t in frame.truth]
    uid, uv = min(uvs, key=lambda x: np.hypot(x[1][0] - spot.u, x[1][1] - spot.v))
    return uid


def test_rig_pass_confirms_every_lamp_with_its_uid():
    confirmed, sources = {}, set()
    for frame, records in rig_pass(40.0, 3, seed=7):
        for rec in records:
            sources.add(rec.source)
            if rec.state >= CONFIRMED:
                truth = _truth_uid(frame, rec)
                assert rec.uid == truth, 'wrong UID'
                assert rec.state == CONFIRMED
                confirmed.setdefault(truth, frame.index)
    assert {0x1001, 0x1002, 0x1003} <= set(confirmed)
    # entering at the right border, the lamp is read from the right image first
    assert 'right' in sources or 'right_cut' in sources


def test_rig_high_speed_never_a_wrong_uid():
    for frame, records in rig_pass(120.0, 4, seed=8):
        for rec in records:
            if rec.state >= CONFIRMED:
                assert rec.uid == _truth_uid(frame, rec)


def test_path_prediction_moves_a_new_track_as_earlier_lamps_moved_from_its_spot_height():
    """A lamp's image speeds up along its path (x1.5 per frame): one observation gives
    no velocity, but an earlier lamp's path, matched by spot height (vibration offsets
    the paths by tens of pixels), gives the next step.
    """
    t = np.arange(6) / 30.0
    steps = 50.0 * 1.5 ** np.arange(5)
    pos = np.zeros((6, 2))
    pos[1:, 0] = -np.cumsum(steps)
    pos[1:, 1] = 0.5 * np.cumsum(steps)
    pos += [1270.0, 60.0]
    heights = 30.0 * 1.2 ** np.arange(6)
    paths = [(t, pos, heights)]
    # a lamp as tall as the earlier lamp in its third frame, wherever it is
    move = path_prediction(paths, heights[2], 1 / 30.0)
    np.testing.assert_allclose(move, pos[3] - pos[2], atol=1e-6)
    # half-way in height between two observations: half-way along that step's timing
    move = path_prediction(paths, 0.5 * (heights[1] + heights[2]), 1 / 30.0)
    assert steps[1] < np.hypot(*move) < steps[2]
    # two frames on, from the first frame's height
    np.testing.assert_allclose(path_prediction(paths, heights[0], 2 / 30.0),
                               pos[2] - pos[0], atol=1e-6)
    # no earlier lamp was this small or this big: no prior
    assert path_prediction(paths, 0.5 * heights[0], 1 / 30.0) is None
    assert path_prediction(paths, 2.0 * heights[-1], 1 / 30.0) is None


def test_rig_at_120_kmh_every_lamp_is_one_track_and_confirmed_in_view():
    """Graph timing, 120 km/h, run 8: lamp 0x1005 is in view only 5 frames, its spot
    moving 100-300 px per frame. Without a motion prior for new tracks each of its
    frames started a track (none confirmed), and stale one-frame tracks near the image
    entry took the next lamp's first spots.
    """
    timing = {k: v for k, v in signal_timing_from_params_file(
        NODE_PARAMS).items() if k in ('chip_rate_hz', 'exposure_s')}
    cfg = DecoderConfig(**timing)
    tracks, confirmed = {}, {}
    for frame, records in rig_pass(120.0, 6, seed=8, cfg=cfg, **timing):
        for truth in frame.truth:
            near = [r for r in records if r.left is not None and truth.in_left and np.hypot(
                r.left.u - truth.uv_left[0], r.left.v - truth.uv_left[1]) < 40]
            for rec in near:
                tracks.setdefault(truth.uid, set()).add(rec.track_id)
                if rec.state >= CONFIRMED:
                    assert rec.uid == truth.uid, 'wrong UID'
                    confirmed.setdefault(truth.uid, frame.index)
    assert set(tracks) == set(range(0x1001, 0x1007))
    assert all(len(ids) == 1 for ids in tracks.values()), tracks
    assert set(confirmed) == set(tracks)


def test_pair_spots_of_raw_images_compares_rectified_rows():
    """Raw images: a lamp's two raw rows differ (a rotated right camera, other principal
    points); with the cameras' raw → rectified maps the pair is found on one rectified
    row, and without them (rows read as rectified) it is not.
    """
    from vlc_decoder.core.spots import Spot
    left = [Spot(row0=100, row1=120, col0=600, col1=620, u=610.0, v=110.0, width_px=20.0)]
    right = [Spot(row0=108, row1=128, col0=570, col1=590, u=580.0, v=118.0, width_px=20.0)]
    pairs = pair_spots(left, right, 250.0)
    assert all(a is None or b is None for a, b in pairs)
    rectify = (lambda uv: np.asarray(uv) + [1.0, 0.5], lambda uv: np.asarray(uv) - [2.0, 7.5])
    pairs = pair_spots(left, right, 250.0, rectify)
    assert pairs == [(left[0], right[0])]


def test_raw_images_align_the_right_profile_by_the_trigger_skew():
    # The realistic rig triggers the right camera 2-40 us after the left one (unknown to
    # the receivers): its row r shows the chips of the left row r + skew/row_time. Row by
    # row, a 40 us skew (1.3 rows, 0.8 chip at 21150 chips/s and 30 us rows) averaged
    # the chips into grey; measured from the two profiles, the lag puts them back.
    from vlc_decoder.core.spots import Spot
    from vlc_decoder.core.tracker import profile_lag_rows
    rng = np.random.default_rng(5)
    chips = rng.integers(0, 2, 80).astype(float)
    row_time, chip_time = 30e-6, 1.0 / 21150.0

    def profile(rows, skew_s):
        t = rows * row_time + skew_s
        return chips[(t / chip_time).astype(int)]

    lag = 38.5e-6 / row_time
    rows_l, rows_r = np.arange(200, 260), np.arange(194, 252)   # other raw rows too
    left = Spot(200, 260, 0, 10, rows=rows_l, level=profile(rows_l - 200, 0.0),
                weight=np.ones(len(rows_l)))
    right = Spot(194, 252, 0, 10, rows=rows_r, level=profile(rows_r - 200, 38.5e-6),
                 weight=np.ones(len(rows_r)))
    assert profile_lag_rows(left, right) == pytest.approx(lag, abs=0.35)
    truth = dict(zip(rows_l.tolist(), left.level))

    def agreement(rows, level):
        return np.corrcoef(level, [truth[r] for r in rows])[0, 1]

    rows, level, _, source = combine_profiles(left, right)           # row by row
    inside = np.isin(rows, rows_l)
    unaligned = agreement(rows[inside], level[inside])
    rows, level, _, source = combine_profiles(left, right, align=True)
    assert source == 'both'
    inside = np.isin(rows, rows_l)
    assert agreement(rows[inside], level[inside]) > 0.9 > unaligned + 0.1
    # the right spot alone (the left one missing or cut) runs on the left clock too, by
    # the tracker's running estimate: a track's chip grid stays put from frame to frame
    inside = np.isin(rows_r, rows_l)
    as_is = agreement(rows_r[inside], right.level[inside])
    rows, level, _, source = combine_profiles(None, right, align=True, lag_rows=lag)
    assert source == 'right'
    inside = np.isin(rows, rows_l)
    assert agreement(rows[inside], level[inside]) > 0.8 > as_is + 0.2


def test_the_lag_overlap_is_the_row_by_row_lookup_bit_for_bit():
    """Profiles with gaps in their rows (rows left out by the cap weights), offset spans,
    no overlap and float32 levels: the same levels, in b's order and type, as looking
    a's row r + k up row by row (the way the lag was measured before, kept as the
    reference).
    """
    from vlc_decoder.core.spots import Spot
    from vlc_decoder.core.tracker import lag_overlap
    rng = np.random.default_rng(11)
    for trial in range(200):
        n_a, n_b = rng.integers(1, 60, 2)
        rows_a = np.sort(rng.choice(np.arange(100, 100 + 2 * n_a), n_a, replace=False))
        start = 100 + int(rng.integers(-10, 130))
        rows_b = np.sort(rng.choice(np.arange(start, start + 2 * n_b), n_b, replace=False))
        dtype = np.float32 if trial % 3 == 0 else float
        a = Spot(0, 1, 0, 1, rows=rows_a, level=rng.random(n_a).astype(dtype),
                 weight=np.ones(n_a))
        b = Spot(0, 1, 0, 1, rows=rows_b, level=rng.random(n_b), weight=np.ones(n_b))
        looked_up = dict(zip(a.rows.tolist(), a.level))
        for k in range(-3, 4):
            pairs = [(looked_up[r + k], lv) for r, lv in zip(b.rows.tolist(), b.level)
                     if r + k in looked_up]
            want = np.array(pairs).T if pairs else np.zeros((2, 0))
            x, y = lag_overlap(a, b, k)
            assert x.dtype == y.dtype == (want.dtype if pairs else x.dtype)
            assert np.array_equal(x, want[0]) and np.array_equal(y, want[1])


def test_a_raw_pair_s_lag_is_measured_once_a_frame(monkeypatch):
    """The association, the recorded lag and the stripes of an observation share one
    measurement of its lag in a frame.
    """
    from vlc_decoder.core import tracker as tracker_module
    tracker = LampTracker(CFG)
    tracker.rectify = (lambda uv: uv, lambda uv: uv)      # a raw pair, already rectified
    measure = tracker_module.profile_lag_rows
    frames = []
    monkeypatch.setattr(tracker_module, 'profile_lag_rows',
                        lambda a, b: frames[-1].append((id(a), id(b))) or measure(a, b))
    lamps = [synth.SyntheticLamp(synth.LampSignal(0x1234, phase_s=0.002), 600.0, 300.0,
                                 20.0, 16.0, 60.0),
             synth.SyntheticLamp(synth.LampSignal(0x1235, phase_s=0.004), 900.0, 420.0,
                                 24.0, 12.0, 60.0)]
    for k in range(12):
        frames.append([])
        tracker.process(int(k * 1e9 / 30), *_lamp_frame(lamps, k))
    # from the second frame on each observation is a candidate of a track too
    assert all(len(calls) == 2 and len(set(calls)) == 2 for calls in frames[1:])
