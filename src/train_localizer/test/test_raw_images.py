"""Raw images of a calibrated stereo pair through the spot locator and the fix geometry.

The rig renders raw images through a true lens pair (``OpticsTruth.example()``: barrel
distortion k1 ≈ −0.30, principal points off centre, the right camera turned by 0.24°,
a 15 µs trigger skew) and publishes a perfect calibration of it (K, D raw; R, P from
cv2.stereoRectify). The spot locator maps each raw spot centre through its camera's
K, D, R, P; the localizer's camera_info handling turns its camera axes by the left R
and triangulates in the rectified frame. The same scenes on the ideal pinhole rig are
the reference; the same raw images read as if they were rectified are the control that
shows the rectification is doing the work.
"""
import numpy as np
import pytest
from sensor_msgs.msg import CameraInfo

from spot_locator import conversions as spot_conversions
from spot_locator.core.locator import (
    FLAG_EDGE_DISPARITY,
    FLAG_RECTIFIED,
    LocatorConfig,
    SpotLocator,
)
from train_localizer.conversions import CameraInfoIntrinsics
from train_localizer.core.fix import RigGeometry, triangulate
from train_localizer.core.join import JoinConfig, join_frame
from vlc_common.camera_info import camera_info_msg
from vlc_common.core.camera import CameraModel
from vlc_common.core.lamp_map import LampMap, resolve_lamp_map_path
from vlc_common.core.records import LAMP_DTYPE
from vlc_stereo_camera.core.optics_truth import OpticsTruth
from vlc_stereo_camera.core.renderer import RendererConfig, StereoRenderer
from vlc_stereo_camera.core.trajectory import MotionProfile, Trajectory, Vibration, VibrationConfig

# the graph's camera timing (stereo_camera_node.yaml)
TIMING = dict(fps=30.0, row_time_s=30e-6, exposure_s=25e-6, chip_rate_hz=21150.0,
              off_level=0.05)
# train chainages: lamps 3.6–9 m ahead (both rigs) and, in the raw rig's wider field,
# 13–15 m ahead
STARTS_M = (11.0, 13.0, 15.5, 17.0)
# along-track window of the ideal pair (docs/arch/vlc_stereo_camera.md)
IDEAL_FAR_M = 9.5


@pytest.fixture(scope='module')
def lamp_map():
    return LampMap.load(resolve_lamp_map_path(''))


def _msg(info):
    return camera_info_msg(info)


def _as_if_rectified(msg):
    """The same camera_info with the lens and the rectification left out (D = 0, R = I,
    K = P[:, :3]): what a receiver that assumes rectified images uses.
    """
    p = np.reshape(msg.p, (3, 4))
    return CameraInfo(width=msg.width, height=msg.height, distortion_model='plumb_bob',
                      d=[0.0] * 5, k=[float(x) for x in p[:, :3].ravel()],
                      r=[float(x) for x in np.eye(3).ravel()], p=list(msg.p))


def _run(lamp_map, optics_truth, speed_kmh=0.0, rectify=True, starts=STARTS_M):
    """Per lamp seen in both images: (along-track m, position error m or inf if no pair,
    the pair's stamp offset − the truth's s or nan).
    """
    config = RendererConfig(optics_truth=optics_truth, **TIMING)
    rig = config.rig()
    out = []
    for start in starts:
        kind = 'constant' if speed_kmh else 'stationary'
        trajectory = Trajectory(MotionProfile(kind, start_chainage_m=start,
                                              speed_mps=speed_kmh / 3.6),
                                Vibration(VibrationConfig(enabled=False), seed=1))
        renderer = StereoRenderer(config, lamp_map, trajectory, seed=3)
        msgs = [_msg(info) for info in renderer.camera_info_dicts()]
        if not rectify:
            msgs = [_as_if_rectified(m) for m in msgs]
        geometry = spot_conversions.stereo_geometry(*msgs)
        locator = SpotLocator(LocatorConfig(
            normal_cam=tuple(rig.R_base_cam.T @ np.array([0.0, -1.0, 0.0])),
            train_velocity_cam_mps=tuple(rig.R_base_cam.T @ np.array([-1.0, 0.0, 0.0])),
            row_time_s=config.row_time_s, exposure_s=config.exposure_s), geometry)
        rig_geometry = RigGeometry(row_time_s=config.row_time_s, exposure_s=config.exposure_s)
        intrinsics = CameraInfoIntrinsics(rig_geometry)
        for index, m in enumerate(msgs):
            intrinsics.update(index, m)
        assert intrinsics.source == 'camera_info'
        frame = renderer.render(0)
        records = spot_conversions.pairs_to_records(
            locator.process(frame.left, frame.right, speed_kmh / 3.6).pairs)
        if records.size and rectify and optics_truth is not None:
            assert np.all(records['flags'] & FLAG_RECTIFIED)
        obs, _ = join_frame(0, records, None)
        for truth in frame.truth:
            if not (truth.in_left and truth.in_right):
                continue
            lamp = lamp_map.by_uid(truth.uid)
            best, error, dt = None, np.inf, np.nan
            for o in obs:
                p_cam, _ = triangulate(o, rig_geometry)
                if p_cam is None:
                    continue
                t = frame.t0_s + o.exposure_mid_offset_s
                s = trajectory.sample([t])
                p_base = rig_geometry.R_base_cam @ p_cam + rig_geometry.t_base_cam
                e = np.linalg.norm(s.position_m[0] + s.R_map_base[0] @ p_base - lamp.position_m)
                if e < error:
                    best, error = o, e
            if best is not None:
                dt = best.exposure_mid_offset_s - (truth.t_centre_s - frame.t0_s)
            out.append((truth.along_track_m, error, dt))
    return np.array(out)


def test_raw_images_triangulate_like_the_ideal_pinhole_pair(lamp_map):
    """Standing: the raw rig's lamps are found to the centimetre, as the ideal pinhole
    rig's; read as if rectified, the same raw images give no such fixes.
    """
    ideal = _run(lamp_map, None)
    raw = _run(lamp_map, OpticsTruth.example())
    control = _run(lamp_map, OpticsTruth.example(), rectify=False, starts=(11.0, 15.5))
    near = raw[:, 0] < IDEAL_FAR_M
    assert len(ideal) == 4 and near.sum() == 4 and len(raw) >= 6
    # every lamp found, within 5 mm where the ideal pair sees it, as the ideal pair
    # (measured 0.2–2.1 mm, ideal 0.1–2.7 mm; without the localizer's turn by the left
    # R: 10–31 mm), within 6 cm 13–15 m ahead, beyond the ideal pair's field (~4 cm:
    # a disparity of 8 px there)
    assert np.all(ideal[:, 1] < 0.005), ideal
    assert np.all(raw[near, 1] < 0.005), raw
    assert np.all(raw[~near, 1] < 0.06), raw
    # stamped at the left spot's raw row: within 10 µs of the truth's instant
    assert np.all(np.abs(raw[near, 2]) < 10e-6), raw
    # the control: no pair at all, or wrong pairs metres off
    assert len(control) >= 3 and np.all(control[:, 1] > 0.1), control


def test_raw_images_in_motion(lamp_map):
    """At 100 km/h the right spot is exposed on other rows and 15 µs late: it is moved
    back to the left centre's instant before the common row and the disparity.
    """
    raw = _run(lamp_map, OpticsTruth.example(), speed_kmh=100.0, starts=(11.0, 15.5))
    near = raw[:, 0] < IDEAL_FAR_M
    assert near.sum() == 2, raw
    # measured 2.4 and 6.8 mm; without moving the right spot to the left instant 52 and
    # 80 mm
    assert np.all(raw[near, 1] < 0.015), raw


def test_decoder_positions_are_rectified_for_the_join():
    """The decoder reports raw left-image positions; the spot pairs are rectified."""
    spots = np.zeros(1, dtype=[('u_left', 'f8'), ('v_left', 'f8'), ('u_right', 'f8'),
                               ('v_right', 'f8')])
    spots[0] = (300.0, 200.0, 280.0, 200.0)
    lamps = np.zeros(1, dtype=LAMP_DTYPE)
    lamps['uid'], lamps['state'] = 77, 2
    lamps['left_u'], lamps['left_v'] = 270.0, 190.0          # 32 px off in the raw image
    obs, unmatched = join_frame(0, spots, lamps, JoinConfig())
    assert unmatched == 1 and obs[0].uid is None
    config = JoinConfig(rectify_left=lambda uv: np.asarray(uv) + [30.0, 10.0])
    obs, unmatched = join_frame(0, spots, lamps, config)
    assert unmatched == 0 and obs[0].uid == 77


def test_camera_info_of_raw_images_turns_the_camera_axes(lamp_map):
    """The localizer's camera axes become R_base_cam·Rᵀ (the rectified frame) and the
    join gets the left camera's raw → rectified map; ideal camera_info changes nothing.
    """
    config = RendererConfig(optics_truth=OpticsTruth.example())
    renderer = StereoRenderer(config, lamp_map, Trajectory(MotionProfile('stationary')),
                              seed=1)
    geometry = RigGeometry()
    mount = geometry.R_base_cam.copy()
    join = JoinConfig()
    intrinsics = CameraInfoIntrinsics(geometry, join_config=join)
    infos = renderer.camera_info_dicts()
    for index, info in enumerate(infos):
        intrinsics.update(index, _msg(info))
    R = np.asarray(infos[0]['R'], float).reshape(3, 3)
    np.testing.assert_allclose(geometry.R_base_cam, mount @ R.T, atol=1e-15)
    model = CameraModel.from_camera_info(infos[0])
    uv = np.array([[100.0, 80.0], [640.0, 360.0]])
    np.testing.assert_array_equal(join.rectify_left(uv), model.rectify_points(uv))
    # back to an ideal pair: the mount's axes bit for bit, no map
    ideal = StereoRenderer(RendererConfig(), lamp_map, Trajectory(MotionProfile('stationary')),
                           seed=1).camera_info_dicts()
    for _ in range(3):          # a different valid camera_info is taken after three
        for index, info in enumerate(ideal):
            intrinsics.update(index, _msg(info))
    assert np.array_equal(geometry.R_base_cam, mount) and join.rectify_left is None


def test_repeated_camera_info_is_not_derived_again(lamp_map, monkeypatch):
    """camera_info comes with every frame (30 Hz per camera): the models are derived when
    a pair is kept, not again for each identical message.
    """
    from train_localizer import conversions
    calls = []
    derive = conversions.raw_camera_model
    monkeypatch.setattr(conversions, 'raw_camera_model',
                        lambda msg: calls.append(msg) or derive(msg))
    infos = StereoRenderer(RendererConfig(optics_truth=OpticsTruth.example()), lamp_map,
                           Trajectory(MotionProfile('stationary')), seed=1).camera_info_dicts()
    geometry = RigGeometry()
    intrinsics = CameraInfoIntrinsics(geometry, join_config=JoinConfig())
    for _ in range(5):
        for index, info in enumerate(infos):
            intrinsics.update(index, _msg(info))
    assert len(calls) == 2 and intrinsics.source == 'camera_info'   # left and right, once
    turned = geometry.R_base_cam.copy()
    ideal = StereoRenderer(RendererConfig(), lamp_map, Trajectory(MotionProfile('stationary')),
                           seed=1).camera_info_dicts()
    for _ in range(3):          # a different pair, confirmed: derived again
        for index, info in enumerate(ideal):
            intrinsics.update(index, _msg(info))
    assert len(calls) > 2 and not np.array_equal(geometry.R_base_cam, turned)


def test_a_raw_spot_cut_by_the_side_border_is_paired_with_its_whole_spot(lamp_map):
    """Raw images cropped on the right (camera_info keeps K, D, R, P, width smaller) so
    that a lamp's left spot loses its right part: the pair from its chord ends (mapped
    through each camera's lens) agrees with the whole pair of the uncropped frame, the
    whole spot's centre to 0.2 px and the disparity within 3σ of that pair's.
    """
    config = RendererConfig(optics_truth=OpticsTruth.example(), **TIMING)
    rig = config.rig()

    def locate(infos, left, right):
        locator = SpotLocator(LocatorConfig(
            normal_cam=tuple(rig.R_base_cam.T @ np.array([0.0, -1.0, 0.0])),
            train_velocity_cam_mps=tuple(rig.R_base_cam.T @ np.array([-1.0, 0.0, 0.0])),
            row_time_s=config.row_time_s, exposure_s=config.exposure_s),
            spot_conversions.stereo_geometry(*infos))
        return locator.process(left, right)

    checked = 0
    for start in STARTS_M:
        trajectory = Trajectory(MotionProfile('stationary', start_chainage_m=start),
                                Vibration(VibrationConfig(enabled=False), seed=1))
        renderer = StereoRenderer(config, lamp_map, trajectory, seed=3)
        msgs = [_msg(info) for info in renderer.camera_info_dicts()]
        frame = renderer.render(0)
        full = locate(msgs, frame.left, frame.right).pairs
        for truth in frame.truth:
            width = int(truth.uv_left[0]) + 2
            if not (truth.in_left and truth.in_right) or truth.uv_right[0] > width - 15:
                continue                     # the right spot would be cut as well
            cropped = []
            for m in msgs:
                c = CameraInfo(width=width, height=m.height,
                               distortion_model=m.distortion_model)
                c.d, c.k, c.r, c.p = list(m.d), list(m.k), list(m.r), list(m.p)
                cropped.append(c)
            result = locate(cropped, frame.left[:, :width].copy(),
                            frame.right[:, :width].copy())
            edge = [p for p in result.pairs if p.flags & FLAG_EDGE_DISPARITY]
            assert len(edge) == 1 and result.edge_pairs == 1
            p = edge[0]
            q = min(full, key=lambda q: np.hypot(*(q.uv_right - p.uv_right)))
            assert np.hypot(*(p.uv_right - q.uv_right)) < 0.2
            assert abs(p.disparity - q.disparity) < 3.0 * p.sigma_disparity
            assert p.flags & FLAG_RECTIFIED
            checked += 1
    assert checked >= 3
