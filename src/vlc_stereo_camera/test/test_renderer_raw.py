"""Raw images through the true lens (``RendererConfig.optics_truth``).

References are computed here independently of the renderer's conic, remap and
rolling-shutter code: the trajectory, the rig's mount, OpenCV's extrinsics convention
and the foundation's ``CameraModel`` (forward distortion ``project`` and the iterative
``undistort_normalized``), plus brute-force sampling of sensor pixels.
"""
import dataclasses

import numpy as np
import pytest

from vlc_common.core.camera import StereoRig
from vlc_common.core.lamp_map import Lamp, LampMap, resolve_lamp_map_path
from vlc_stereo_camera.core.optics_truth import LensMap, OpticsTruth, TrueCamera
from vlc_stereo_camera.core.renderer import RendererConfig, StereoRenderer
from vlc_stereo_camera.core.sensor_noise import SensorConfig
from vlc_stereo_camera.core.trajectory import MotionProfile, Trajectory, Vibration, VibrationConfig

TRUTH = OpticsTruth.example()
W, H = 1280, 720


@pytest.fixture(scope='module')
def lamp_map():
    return LampMap.load(resolve_lamp_map_path(''))


def still(chainage_m, vibration=False):
    return Trajectory(MotionProfile('stationary', start_chainage_m=chainage_m),
                      Vibration(VibrationConfig(enabled=vibration), seed=2))


def moving(speed_kmh, chainage_m=0.0, vibration=False):
    return Trajectory(MotionProfile('constant', start_chainage_m=chainage_m,
                                    speed_mps=speed_kmh / 3.6),
                      Vibration(VibrationConfig(enabled=vibration), seed=2))


def geometry_only(truth=TRUTH, **kw):
    """Steady lamps; no PSF, noise, vignetting, background or saturation."""
    return RendererConfig(optics_truth=truth, lamp_modulation=False, sensor_noise=False,
                          optics_psf=False, vignetting=False,
                          sensor=SensorConfig(background_dn=0.0, dark_current_e_per_s=0.0,
                                              full_well_e=1e12, noise_bank_size=1), **kw)


def camera_pose(renderer_config, camera, position_m, R_map_base):
    """Optical centre (3,) and R_map_cam (3, 3) of the true camera (or (N, 3), (N, 3, 3)
    for base poses (N, 3), (N, 3, 3)), from the rig's mount and the truth's right-camera
    pose (OpenCV convention x_r = R·x_l + T).
    """
    rig = StereoRig(baseline_m=renderer_config.baseline_m)
    R_base_left = rig.R_base_cam
    left = position_m + R_map_base @ np.asarray(renderer_config.mount_xyz_m)
    if camera == 0:
        return left, R_map_base @ R_base_left
    R, T = renderer_config.optics_truth.extrinsics()
    # x_r = R·x_l + T: the right centre is x_l = −Rᵀ·T, its axes the rows of R.
    return (left + R_map_base @ R_base_left @ (-R.T @ T)), R_map_base @ R_base_left @ R.T


def to_camera(config, camera, points_map, trajectory, t_s):
    s = trajectory.sample([t_s])
    centre, R_mc = camera_pose(config, camera, s.position_m[0], s.R_map_base[0])
    return (np.atleast_2d(points_map) - centre) @ R_mc


def field_lamps(config, chainage_m, ranges_m, margin_px=40.0):
    """Lamps facing the left camera, one per (raw image point, range), for a train
    standing at ``chainage_m`` without vibration: the raw points are the corners, edge
    middles and centre of the sensor, ``margin_px`` in from the border.
    """
    model = config.optics_truth.left.camera_model(W, H)
    raw = np.array([[u, v] for u in (margin_px, 640.0, W - margin_px)
                    for v in (margin_px, 360.0, H - margin_px)])
    rays = np.column_stack([model.undistort_normalized(raw), np.ones(len(raw))])
    rig = StereoRig()
    centre = np.array([chainage_m, 0.0, 0.0]) + np.asarray(config.mount_xyz_m)
    lamps = []
    for i, (ray, r) in enumerate([(ray, r) for r in ranges_m for ray in rays]):
        d = rig.R_base_cam @ (ray / np.linalg.norm(ray))
        lamps.append(Lamp(uid=(3 << 12) | (i + 1), line_id=3, lamp_id=i + 1,
                          position_m=centre + r * d, normal=-d, diameter_m=0.2))
    return LampMap(lamps)


def pinhole(camera, p_cam):
    return np.array([camera.fx * p_cam[0] / p_cam[2] + camera.cx,
                     camera.fy * p_cam[1] / p_cam[2] + camera.cy])


def spot_centroid(image, uv, half_px):
    u, v = int(round(uv[0])), int(round(uv[1]))
    u0, v0 = max(u - half_px, 0), max(v - half_px, 0)
    win = image[v0:v + half_px + 1, u0:u + half_px + 1].astype(np.float64)
    vv, uu = np.mgrid[v0:v0 + win.shape[0], u0:u0 + win.shape[1]]
    return np.array([(uu * win).sum(), (vv * win).sum()]) / win.sum(), win


def disc_axes(lamp):
    nh = lamp.normal
    e1 = np.array([1.0, 0.0, 0.0]) - nh[0] * nh
    e1 /= np.linalg.norm(e1)
    return e1, np.cross(nh, e1)


def disc_samples(lamp, n=700):
    """Points uniform in area on the disc (n² of them)."""
    e1, e2 = disc_axes(lamp)
    a = (np.arange(n) + 0.5) / n
    r = np.sqrt(a)[:, None] * lamp.diameter_m / 2
    th = 2 * np.pi * a[None, :]
    return (lamp.position_m + (r * np.cos(th))[..., None] * e1
            + (r * np.sin(th))[..., None] * e2).reshape(-1, 3)


def rim_points(lamp, n=4000):
    e1, e2 = disc_axes(lamp)
    th = np.linspace(0.0, 2 * np.pi, n, endpoint=False)[:, None]
    return lamp.position_m + lamp.diameter_m / 2 * (np.cos(th) * e1 + np.sin(th) * e2)


def flux_centroid(model, lamp, p_cam_of):
    """Where the disc's light lands on the raw sensor, on average: the forward lens model
    over the disc, each disc point weighted by its ideal-image area element
    |n_c · p| / z³ (the light per ideal pixel is uniform; ``model.project`` carries it to
    the sensor, and an ideal area keeps its light wherever the lens puts it).
    """
    p = p_cam_of(disc_samples(lamp))
    n_c = p_cam_of(lamp.position_m + lamp.normal)[0] - p_cam_of(lamp.position_m)[0]
    weight = np.abs(p @ n_c) / p[:, 2] ** 3
    uv, _ = model.project(p)
    return (uv * weight[:, None]).sum(axis=0) / weight.sum()


def test_lens_map_is_the_camera_model_undistortion():
    """The renderer's static maps agree with CameraModel.undistort_normalized, corners
    included, and its forward projection with CameraModel.project inside the field.
    """
    cam = TRUTH.left
    lens = LensMap(cam, W, H)
    model = cam.camera_model(W, H)
    rng = np.random.default_rng(4)
    idx = np.vstack([rng.integers(0, [H + 16, W + 16], size=(400, 2)),
                     [[0, 0], [0, W + 15], [H + 15, 0], [H + 15, W + 15]]])
    raw = np.column_stack([idx[:, 1] - 8.0, idx[:, 0] - 8.0])
    ideal = model.undistort_normalized(raw) * [cam.fx, cam.fy] + [cam.cx, cam.cy]
    got = np.column_stack([lens.map_x[idx[:, 0], idx[:, 1]], lens.map_y[idx[:, 0], idx[:, 1]]])
    np.testing.assert_allclose(got, ideal, atol=2e-4)            # float32 storage
    xy = rng.uniform(-0.8, 0.8, size=(500, 2))
    p = np.column_stack([xy, np.ones(len(xy))]) * 3.0
    np.testing.assert_allclose(np.column_stack(lens.project_normalized(xy[:, 0], xy[:, 1])),
                               model.project(p)[0], atol=1e-9)
    # Guard: far outside the field the polynomial folds back into the image; the
    # renderer's projection keeps growing instead.
    far = np.array([[2.2, 0.9], [3.0, 1.0]])
    u_model = model.project(np.column_stack([far, np.ones(2)]))[0][:, 0]
    u_guard = lens.project_normalized(far[:, 0], far[:, 1])[0]
    assert 0 < u_model[0] < W and np.all(u_guard > W) and u_guard[1] > u_guard[0]
    # Flux: the illumination map is the ideal area per sensor pixel (cos⁴θ aside).
    assert lens.illumination[8 + 360, 8 + 640] == pytest.approx(
        1.0 / (1.0 + ((640 - cam.cx) ** 2 + (360 - cam.cy) ** 2) / cam.fx ** 2) ** 2, rel=2e-3)
    assert 0.6 < lens.illumination.min() < 0.75        # corners: cos⁴θ / det J


def test_truth_undistorts_onto_the_pinhole_projection():
    """(a) Every lamp's raw truth, undistorted with the true CameraModel, lands within
    0.02 px of the pinhole projection of the same point, computed from the trajectory
    at the truth's own instant (per camera, the right one through OpenCV's extrinsics),
    over the whole sensor, corners included.
    """
    config = geometry_only()
    lamps = field_lamps(config, 0.0, (3.0, 6.0))
    trajectory = still(0.0, vibration=True)
    renderer = StereoRenderer(config, lamps, trajectory, seed=1)
    frame = renderer.render(2, electrons=True)
    assert len(frame.truth) == len(lamps)
    worst, raw_span = 0.0, []
    for truth in frame.truth:
        lamp = lamps.by_uid(truth.uid)
        for camera, uv, t_s in ((0, truth.uv_left, truth.t_centre_s),
                                (1, truth.uv_right, truth.t_centre_right_s)):
            cam = TRUTH.cameras[camera]
            # the truth instant is the exposure mid-time of the sensor row it lies on
            skew = TRUTH.trigger_skew_s if camera else 0.0
            assert t_s == pytest.approx(frame.t0_s + skew + uv[1] * config.row_time_s
                                        + config.exposure_s / 2, abs=1e-9)
            p_cam = to_camera(config, camera, lamp.position_m, trajectory, t_s)[0]
            ideal = cam.camera_model(W, H).undistort_normalized(uv[None])[0]
            residual = np.hypot(*(ideal * [cam.fx, cam.fy] + [cam.cx, cam.cy]
                                  - pinhole(cam, p_cam)))
            worst = max(worst, residual)
            raw_span.append(uv)
    assert worst < 0.02
    raw_span = np.array(raw_span)
    assert raw_span[:, 0].min() < 60 and raw_span[:, 0].max() > 1220
    assert raw_span[:, 1].min() < 60 and raw_span[:, 1].max() > 660
    # The lens matters: at the corners the raw truth is ~100 px from the pinhole's.
    corner = min(frame.truth, key=lambda t: np.hypot(*(t.uv_left - 40.0)))
    p_cam = to_camera(config, 0, lamps.by_uid(corner.uid).position_m, trajectory,
                      corner.t_centre_s)[0]
    assert np.hypot(*(corner.uv_left - pinhole(TRUTH.left, p_cam))) > 50.0


@pytest.mark.parametrize('range_m', [2.5, 8.0])
def test_steady_disc_centroid_is_the_lens_image_of_its_light(range_m):
    """(b) The intensity centroid of a steady disc in the raw image (no PSF, noise or
    vignetting) is the flux centroid of the disc through the true lens (the forward
    CameraModel over the disc, weighted by ideal-image area) within 0.02 px, and its total
    light is the ideal image's (the lens moves light, it does not make it) within 0.3 %.
    The truth (projected centre) differs from both by the perspective eccentricity and
    the lens's curvature over the spot, computed here too.
    """
    config = geometry_only()
    lamps = field_lamps(config, 0.0, (range_m,), margin_px=100.0)
    renderer = StereoRenderer(config, lamps, still(0.0), seed=1)
    frame = renderer.render_at(0.0, electrons=True)
    cam = TRUTH.left
    model = cam.camera_model(W, H)
    on_e = config.optics.on_electrons(np.pi * 0.1 ** 2, 1.0, config.exposure_s)
    half = int(1.3 * cam.fx * 0.1 / range_m) + 6
    checked = 0
    for truth in frame.truth:
        lamp = lamps.by_uid(truth.uid)
        centroid, window = spot_centroid(frame.left, truth.uv_left, half)
        if min(window[0].max(), window[-1].max(), window[:, 0].max(),
               window[:, -1].max()) > 0.0 or window.shape != (2 * half + 1, 2 * half + 1):
            continue                                  # cut by the image border
        def p_cam(points):
            return to_camera(config, 0, points, renderer.trajectory, 0.0)
        reference = flux_centroid(model, lamp, p_cam)
        np.testing.assert_allclose(centroid, reference, atol=0.02)
        # Ideal-image area of the disc: its projected rim polygon in the pinhole image.
        rim = p_cam(rim_points(lamp))
        xy = np.column_stack([cam.fx * rim[:, 0] / rim[:, 2], cam.fy * rim[:, 1] / rim[:, 2]])
        area = 0.5 * abs(np.dot(xy[:, 0], np.roll(xy[:, 1], 1))
                         - np.dot(xy[:, 1], np.roll(xy[:, 0], 1)))
        assert window.sum() == pytest.approx(on_e * area, rel=3e-3)
        assert np.hypot(*(centroid - truth.uv_left)) < 1.5
        checked += 1
    assert checked >= 6


def brute_force_raw(renderer, lamp, t0_s, camera, roi, row_of_pixel='sensor', n_sub=6, K=8):
    """Expected electrons of ``lamp`` in ``roi`` of a raw image, pixel by pixel: n_sub²
    points per pixel undistorted by CameraModel, each row's exposure in K steps on the
    exact trajectory, ray–disc intersection, times 1/det J of the lens (ideal area per
    pixel). ``row_of_pixel='ideal'`` times a point by its ideal (undistorted) row instead
    of its sensor row: the error a renderer that ignored the lens's row tilt would make.
    """
    config = renderer.config
    cam = TRUTH.cameras[camera]
    model = cam.camera_model(W, H)
    u0, u1, v0, v1 = roi
    off = (np.arange(n_sub) + 0.5) / n_sub - 0.5
    vv, uu = np.mgrid[v0:v1, u0:u1].astype(float)
    shape = vv.shape + (n_sub, n_sub)
    su = np.broadcast_to(uu[..., None, None] + off[None, None, None, :], shape).ravel()
    sv = np.broadcast_to(vv[..., None, None] + off[None, None, :, None], shape).ravel()
    xy = model.undistort_normalized(np.column_stack([su, sv]))
    rays = np.column_stack([xy, np.ones(len(xy))])
    # the row whose instants expose each point (rounded to 1/20 row for the ideal rows,
    # so the trajectory is sampled at few distinct instants)
    rows = (np.round(sv) if row_of_pixel == 'sensor'
            else np.round(20.0 * (xy[:, 1] * cam.fy + cam.cy)) / 20.0)
    skew = TRUTH.trigger_skew_s if camera else 0.0
    covered = np.zeros(len(rays))
    for k in range(K):
        t = t0_s + skew + rows * config.row_time_s + config.exposure_s * (k + 0.5) / K
        instants, index = np.unique(t, return_inverse=True)
        s = renderer.trajectory.sample(instants)
        centre, R_mc = camera_pose(config, camera, s.position_m, s.R_map_base)
        centre, R_mc = centre[index], R_mc[index]
        d = np.einsum('nij,nj->ni', R_mc, rays)
        lam = ((lamp.position_m - centre) @ lamp.normal) / (d @ lamp.normal)
        hit = centre + lam[:, None] * d - lamp.position_m
        covered += (np.einsum('ni,ni->n', hit, hit) <= (lamp.diameter_m / 2) ** 2) & (lam > 0)
    coverage = covered.reshape(shape).mean(axis=(2, 3)) / K
    centre_xy = model.undistort_normalized(np.column_stack([uu.ravel(), vv.ravel()]))
    h = 1e-6
    jx = (model.distort_normalized(centre_xy + [h, 0])
          - model.distort_normalized(centre_xy - [h, 0])) / (2 * h)
    jy = (model.distort_normalized(centre_xy + [0, h])
          - model.distort_normalized(centre_xy - [0, h])) / (2 * h)
    det = (jx[:, 0] * jy[:, 1] - jx[:, 1] * jy[:, 0]).reshape(uu.shape)
    return coverage / det


def test_rolling_shutter_follows_the_sensor_row_at_speed(lamp_map):
    """A lamp 1.5 m ahead at 120 km/h (image speed ~12 000 px/s, the lens tilting the rows
    by ~0.07 row per column there): the rendered raw spot matches a brute-force rendering
    that exposes every sub-pixel at its *sensor* row's instants, within 0.03 px in
    centroid and 0.5 % in light, in both cameras (the right one 15 µs late). Timing the
    points by their ideal rows instead (~20 rows off here) would move the centroid by
    more than a pixel.
    """
    config = geometry_only()
    trajectory = moving(120.0)
    renderer = StereoRenderer(config, lamp_map, trajectory, seed=1)
    t0 = (10.0 - 1.5) / (120 / 3.6)
    frame = renderer.render_at(t0, electrons=True)
    truth = next(t for t in frame.truth if t.uid == 4097)
    lamp = lamp_map.by_uid(4097)
    on_e = config.optics.on_electrons(np.pi * 0.1 ** 2, 1.0, config.exposure_s)
    for camera, image, uv in ((0, frame.left, truth.uv_left), (1, frame.right, truth.uv_right)):
        half = int(1.3 * 1040 * 0.1 / truth.range_m) + 10
        u, v = int(uv[0]), int(uv[1])
        roi = (u - half, u + half, v - half, v + half)
        got = image[roi[2]:roi[3], roi[0]:roi[1]]
        assert got[0].max() == 0 and got[-1].max() == 0 and got[:, 0].max() == 0
        ref = brute_force_raw(renderer, lamp, t0, camera, roi) * on_e

        def centroid(img):
            vv, uu = np.mgrid[:img.shape[0], :img.shape[1]]
            return np.array([(uu * img).sum(), (vv * img).sum()]) / img.sum()
        np.testing.assert_allclose(centroid(got), centroid(ref), atol=0.03)
        assert got.sum() == pytest.approx(ref.sum(), rel=5e-3)
        if camera == 0:
            wrong = brute_force_raw(renderer, lamp, t0, camera, roi, row_of_pixel='ideal',
                                    n_sub=4, K=4) * on_e
            assert np.hypot(*(centroid(wrong) - centroid(ref))) > 1.0      # 5.2 px


def test_trigger_skew_moves_the_right_image_by_speed_times_skew(lamp_map):
    """(c) The right camera exposed 40 µs late: its truth moves along the image motion by
    w·skew/(1 − w_v·row_time) (the rolling shutter's own stretch of a late row), the left
    truth stays; the rendered right spot moves by the same to 0.02 px.
    """
    renders = {}
    for skew in (0.0, 40e-6):
        config = geometry_only(dataclasses.replace(TRUTH, trigger_skew_s=skew))
        renderer = StereoRenderer(config, lamp_map, moving(120.0), seed=1)
        renders[skew] = renderer.render_at((10.0 - 2.0) / (120 / 3.6), electrons=True)
    t0, t1 = (next(t for t in renders[s].truth if t.uid == 4097) for s in (0.0, 40e-6))
    np.testing.assert_allclose(t1.uv_left, t0.uv_left, atol=1e-9)
    assert t1.t_centre_s == t0.t_centre_s
    # image velocity of the raw right centre, from the lens model at the no-skew instant
    config = geometry_only()
    model = TRUTH.right.camera_model(W, H)
    lamp = LampMap.load(resolve_lamp_map_path('')).by_uid(4097)
    dt = 1e-6
    uv = [model.project(to_camera(config, 1, lamp.position_m, moving(120.0),
                                  t0.t_centre_right_s + s))[0][0] for s in (-dt, dt)]
    w = (uv[1] - uv[0]) / (2 * dt)
    expected = w * 40e-6 / (1.0 - w[1] * config.row_time_s)
    assert np.hypot(*w) * 40e-6 > 0.3                   # a visible shift, > 0.3 px
    np.testing.assert_allclose(t1.uv_right - t0.uv_right, expected, atol=0.005)
    assert t1.t_centre_right_s - t0.t_centre_right_s == pytest.approx(
        40e-6 + (t1.uv_right[1] - t0.uv_right[1]) * config.row_time_s, abs=1e-9)
    c0, _ = spot_centroid(renders[0.0].right, t0.uv_right, 60)
    c1, _ = spot_centroid(renders[40e-6].right, t1.uv_right, 60)
    np.testing.assert_allclose(c1 - c0, expected, atol=0.02)


def test_an_ideal_truth_renders_the_default_pair(lamp_map):
    """optics_truth with the rig's own pinhole pair (no distortion, rotation or skew):
    the same truth as the default renderer and the same electrons to 1e-4 of a lamp's.
    """
    ideal = OpticsTruth(left=TrueCamera(), right=TrueCamera(),
                        right_position_m=(RendererConfig().baseline_m, 0.0, 0.0))
    trajectory = moving(60.0, 3.0, vibration=True)
    default = StereoRenderer(RendererConfig(), lamp_map, trajectory, seed=3)
    raw = StereoRenderer(RendererConfig(optics_truth=ideal), lamp_map, trajectory, seed=3)
    on_e = default.config.optics.on_electrons(np.pi * 0.1 ** 2, 1.0, default.config.exposure_s)
    for k in (2, 6):
        a, b = default.render(k, electrons=True), raw.render(k, electrons=True)
        assert [t.uid for t in a.truth] == [t.uid for t in b.truth] and a.truth
        for ta, tb in zip(a.truth, b.truth):
            np.testing.assert_allclose(tb.uv_left, ta.uv_left, atol=1e-5)
            np.testing.assert_allclose(tb.uv_right, ta.uv_right, atol=1e-5)
            assert tb.t_centre_right_s == pytest.approx(ta.t_centre_s, abs=1e-10)
            assert tb.depth_m == pytest.approx(ta.depth_m, abs=1e-9)
            # rows: the raw path counts a row above 1e-3 of a pixel's coverage
            np.testing.assert_allclose(tb.rows_left, ta.rows_left, atol=1)
        np.testing.assert_allclose(b.left, a.left, atol=1e-4 * on_e)
        np.testing.assert_allclose(b.right, a.right, atol=1e-4 * on_e)


def test_camera_info_is_a_perfect_calibration_of_the_truth(lamp_map):
    """The renderer's camera_info is the truth's rectified calibration: rectifying the raw
    truth of a standing lamp (no skew) puts it on one row in both images, and triangulation
    returns its depth.
    """
    config = geometry_only(dataclasses.replace(TRUTH, trigger_skew_s=0.0))
    renderer = StereoRenderer(config, lamp_map, still(5.5), seed=1)
    frame = renderer.render_at(0.0, electrons=True)
    pair = renderer.true_calibration()
    infos = renderer.camera_info_dicts()
    np.testing.assert_allclose(infos[1]['P'], pair.right.P)
    np.testing.assert_allclose(infos[0]['D'], TRUTH.left.distortion)
    for truth in frame.truth:
        if not (truth.in_left and truth.in_right):
            continue
        left, right = pair.rectify_points(truth.uv_left[None], truth.uv_right[None])
        assert left[0, 1] == pytest.approx(right[0, 1], abs=0.01)
        xyz = pair.triangulate(left, right)[0]
        assert np.linalg.norm(xyz) == pytest.approx(truth.range_m, rel=1e-4)
