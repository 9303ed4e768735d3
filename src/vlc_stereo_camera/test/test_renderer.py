"""Geometry, photometry and determinism of the stereo rolling-shutter renderer.

Reference values are computed here independently of the renderer's conic/coverage code:
projections of the disc centre and of a densely sampled rim polygon through the
foundation's StereoRig and Trajectory.
"""
import cv2
import numpy as np
import pytest

from vlc_common.core.lamp_map import LampMap, resolve_lamp_map_path, straight_tunnel_map
from vlc_common.core.optical_channel import lambertian_order
from vlc_stereo_camera.core.renderer import RendererConfig, StereoRenderer
from vlc_stereo_camera.core.sensor_noise import OpticsConfig, SensorConfig
from vlc_stereo_camera.core.trajectory import MotionProfile, Trajectory, Vibration, VibrationConfig

LAMP_X_M = 10.0          # first lamp of the shipped map (UID 4097)


@pytest.fixture(scope='module')
def lamp_map():
    return LampMap.load(resolve_lamp_map_path(''))


def still(chainage_m, vibration=False, seed=1):
    return Trajectory(MotionProfile('stationary', start_chainage_m=chainage_m),
                      Vibration(VibrationConfig(enabled=vibration), seed=seed))


def geometry_only(**kw):
    """Steady lamps, no PSF, noise, vignetting, background or saturation: pure coverage."""
    return RendererConfig(lamp_modulation=False, sensor_noise=False, optics_psf=False,
                          vignetting=False,
                          sensor=SensorConfig(background_dn=0.0, dark_current_e_per_s=0.0,
                                              full_well_e=1e12, noise_bank_size=1), **kw)


def rim_polygon(lamp, n=4000):
    n_hat = lamp.normal
    e1 = np.array([1.0, 0.0, 0.0]) - n_hat[0] * n_hat
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(n_hat, e1)
    a = np.linspace(0.0, 2.0 * np.pi, n, endpoint=False)
    r = lamp.diameter_m / 2
    return lamp.position_m + r * (np.outer(np.cos(a), e1) + np.outer(np.sin(a), e2))


def moments_of(weights):
    m = cv2.moments(weights.astype(np.float64))
    return m['m10'] / m['m00'], m['m01'] / m['m00'], m


def axis_ratio(m, sheppard=0.0):
    """Minor/major axis ratio from central moments (optionally minus the binning term)."""
    mu20 = m['mu20'] / m['m00'] - sheppard
    mu02 = m['mu02'] / m['m00'] - sheppard
    mu11 = m['mu11'] / m['m00']
    lo, hi = np.linalg.eigvalsh([[mu20, mu11], [mu11, mu02]])
    return np.sqrt(lo / hi)


def test_visibility_window_of_the_lamp_centre(lamp_map):
    """Lamp centre in both images for 0.44–9.55 m along track at rest (pitch 27°).

    "In an image" = inside the sensor area u ∈ [−0.5, W − 0.5], v ∈ [−0.5, H − 0.5]
    (pixel centres at integers).
    """
    lamp = lamp_map.by_uid(4097)
    renderer = StereoRenderer(RendererConfig(sensor_noise=False), lamp_map, still(0.0))
    rig = renderer.rig
    assert renderer.config.pitch_deg == 27.0
    for d in np.linspace(0.44, 9.549, 92):
        renderer.trajectory = still(LAMP_X_M - d)
        truth = {t.uid: t for t in renderer.render_at(0.0).truth}
        assert lamp.uid in truth, f'lamp not rendered at {d:.2f} m'
        t = truth[lamp.uid]
        assert t.in_left and t.in_right, f'centre not in both images at {d:.2f} m'
        uv_l, uv_r, depth = rig.project(lamp.position_m[None], np.array([LAMP_X_M - d, 0, 0]),
                                        np.eye(3))
        np.testing.assert_allclose(t.uv_left, uv_l[0], atol=1e-6)
        np.testing.assert_allclose(t.uv_right, uv_r[0], atol=1e-6)
        assert t.depth_m == pytest.approx(depth[0], abs=1e-9)
        assert t.along_track_m == pytest.approx(d, abs=1e-9)
    for d in (0.43, 9.56):
        uv_l, uv_r, _ = rig.project(lamp.position_m[None], np.array([LAMP_X_M - d, 0, 0]),
                                    np.eye(3))
        inside = [(-0.5 <= uv[0, 0] <= 1279.5 and -0.5 <= uv[0, 1] <= 719.5)
                  for uv in (uv_l, uv_r)]
        assert not all(inside), f'centre still in both images at {d} m'
    # The limits: near by the bottom image edge (vertical FOV), far by the right edge of
    # the left image (horizontal FOV).
    uv_near, _, _ = rig.project(lamp.position_m[None], np.array([LAMP_X_M - 0.43, 0, 0]),
                                np.eye(3))
    uv_far, _, _ = rig.project(lamp.position_m[None], np.array([LAMP_X_M - 9.56, 0, 0]),
                               np.eye(3))
    assert uv_near[0, 1] > 719.5 and 0 < uv_near[0, 0] < 1279
    assert uv_far[0, 0] > 1279.5 and 0 < uv_far[0, 1] < 719


def test_truth_is_the_rolling_shutter_fixed_point_at_speed(lamp_map):
    """Moving at 100 km/h with vibration: truth = projection at its own row's mid-time."""
    cfg = RendererConfig(sensor_noise=False)
    traj = Trajectory(MotionProfile('constant', start_chainage_m=5.0, speed_mps=100 / 3.6),
                      Vibration(seed=3))
    renderer = StereoRenderer(cfg, lamp_map, traj, seed=3)
    checked = 0
    for k in range(0, 9, 2):
        frame = renderer.render(k)
        for t in frame.truth:
            lamp = lamp_map.by_uid(t.uid)
            expected_t = frame.t0_s + t.uv_left[1] * cfg.row_time_s + cfg.exposure_s / 2
            assert t.t_centre_s == pytest.approx(expected_t, abs=3e-9)   # 1e-4 row
            s = traj.sample([t.t_centre_s])
            uv_l, uv_r, depth = renderer.rig.project(lamp.position_m[None], s.position_m[0],
                                                     s.R_map_base[0])
            np.testing.assert_allclose(t.uv_left, uv_l[0], atol=1e-3)
            np.testing.assert_allclose(t.uv_right, uv_r[0], atol=1e-3)
            assert t.uv_left[1] == pytest.approx(t.uv_right[1], abs=1e-6)   # rectified
            disparity = t.uv_left[0] - t.uv_right[0]
            assert disparity == pytest.approx(cfg.intrinsics.fx * cfg.baseline_m / depth[0],
                                              rel=1e-9)
            assert t.along_track_m == pytest.approx(lamp.position_m[0] - s.position_m[0, 0],
                                                    abs=1e-9)
            checked += 1
    assert checked >= 3


@pytest.mark.parametrize('distance_m', [1.0, 2.0, 5.0, 9.0])
def test_spot_centroid_and_area_against_projected_rim(lamp_map, distance_m):
    """Rendered disc coverage = the perspective image of the disc.

    Area and centroid agree with the projected rim polygon; the centroid's offset from
    the truth (the projected disc centre) is the perspective eccentricity, reproduced.
    """
    lamp = lamp_map.by_uid(4097)
    renderer = StereoRenderer(geometry_only(), lamp_map, still(LAMP_X_M - distance_m))
    frame = renderer.render_at(0.0, electrons=True)
    truth = frame.truth[0]
    cfg = renderer.config
    on_e = cfg.optics.on_electrons(np.pi * 0.1 ** 2, 1.0, cfg.exposure_s)  # m = 1: any φ
    cu, cv, m = moments_of(frame.left / on_e)
    uv, _, _ = renderer.rig.project(rim_polygon(lamp), np.array([LAMP_X_M - distance_m, 0, 0]),
                                    np.eye(3))
    poly = cv2.moments(uv.astype(np.float32).reshape(-1, 1, 2))
    pu, pv = poly['m10'] / poly['m00'], poly['m01'] / poly['m00']
    assert m['m00'] == pytest.approx(poly['m00'], rel=2e-3)
    assert cu == pytest.approx(pu, abs=0.01)
    assert cv == pytest.approx(pv, abs=0.01)
    eccentricity = np.array([pu, pv]) - truth.uv_left
    np.testing.assert_allclose(np.array([cu, cv]) - truth.uv_left, eccentricity, atol=0.01)
    if distance_m <= 2.0:
        assert np.hypot(*eccentricity) > 0.1     # near lamps: clearly not the centroid


def test_foreshortened_aspect_ratio_follows_viewing_angle(lamp_map):
    """Minor/major axis ratio of the spot ≈ cos(viewing angle), exactly the rim's."""
    lamp = lamp_map.by_uid(4097)
    renderer = StereoRenderer(geometry_only(), lamp_map, still(0.0))
    angles, ratios = [], []
    for d in (1.0, 2.0, 3.0, 5.0, 7.0, 9.0):
        renderer.trajectory = still(LAMP_X_M - d)
        frame = renderer.render_at(0.0, electrons=True)
        truth = frame.truth[0]
        _, _, m = moments_of(frame.left)
        ratio = axis_ratio(m, sheppard=1.0 / 12.0)     # pixel binning adds 1/12 px²
        uv, _, _ = renderer.rig.project(rim_polygon(lamp), np.array([LAMP_X_M - d, 0, 0]),
                                        np.eye(3))
        poly_ratio = axis_ratio(cv2.moments(uv.astype(np.float32).reshape(-1, 1, 2)))
        assert ratio == pytest.approx(poly_ratio, rel=0.01), d
        cos_phi = np.cos(np.radians(truth.viewing_angle_deg))
        # Weak perspective gives cos φ; the off-axis image plane stretches it a little.
        assert ratio == pytest.approx(cos_phi, rel=0.08), d
        angles.append(truth.viewing_angle_deg)
        ratios.append(ratio)
    assert np.all(np.diff(angles) > 0) and np.all(np.diff(ratios) < 0)


def test_extended_source_radiance_does_not_fall_with_distance(lamp_map):
    """A fully covered pixel is as bright at 9 m as at 2 m (1/r² only via the footprint)."""
    renderer = StereoRenderer(geometry_only(), lamp_map, still(0.0))
    peaks = []
    for d in (2.0, 9.0):
        renderer.trajectory = still(LAMP_X_M - d)
        peaks.append(renderer.render_at(0.0, electrons=True).left.max())
    cfg = renderer.config
    # m = 1 (60° field angle): luminance independent of the viewing angle too.
    expected = cfg.optics.on_electrons(np.pi * 0.1 ** 2, 1.0, cfg.exposure_s)
    np.testing.assert_allclose(peaks, expected, rtol=1e-5)


def test_photometric_chain_numbers():
    """Hand calculation of the documented chain: ~12 300 e⁻ on axis, 1.24 full wells."""
    optics = OpticsConfig()
    assert lambertian_order(60.0) == pytest.approx(1.0)
    luminance = 2100.0 / np.pi / (np.pi * 0.1 ** 2)           # I0 = Φ/π for m = 1
    illuminance = np.pi * 0.9 * luminance / (4 * 2.0 ** 2)
    photons_per_lux_s_m2 = (1 / 300.0) / (6.62607015e-34 * 299792458.0 / 555e-9)
    electrons = 0.5 * illuminance * 50e-6 * photons_per_lux_s_m2 * (3.75e-6) ** 2
    got = optics.on_electrons(np.pi * 0.1 ** 2, 1.0, 50e-6)
    assert got == pytest.approx(electrons, rel=1e-12)
    assert 1.1 < got / SensorConfig().full_well_e < 1.4


def test_near_spot_saturates_lightly_and_off_chips_stay_readable(lamp_map):
    renderer = StereoRenderer(RendererConfig(), lamp_map, still(LAMP_X_M - 2.0), seed=4)
    frame = renderer.render(0)
    t = frame.truth[0]
    r0, r1 = t.rows_left
    u = int(round(t.uv_left[0]))
    core = frame.left[r0 + 5:r1 - 4, u - 3:u + 4].astype(float)
    row_means = core.mean(axis=1)
    assert (core == 255).mean() > 0.2                          # "on" rows saturate
    off_rows = row_means[row_means < 100]
    assert off_rows.size >= 3
    background = np.median(frame.left[:, :200])
    assert 2.0 <= background <= 8.0                            # dim tunnel: a few DN
    assert off_rows.min() > background + 6.0                   # off_level 0.05 visible
    far = StereoRenderer(RendererConfig(), lamp_map, still(LAMP_X_M - 9.0), seed=4).render(0)
    assert far.left.max() > 150                                # a far lamp stays bright


def test_determinism_per_seed(lamp_map):
    traj = Trajectory(MotionProfile('constant', start_chainage_m=6.0, speed_mps=15.0),
                      Vibration(seed=7))
    cfg = RendererConfig(sensor=SensorConfig(noise_bank_size=4))
    a = StereoRenderer(cfg, lamp_map, traj, seed=7).render(3)
    b = StereoRenderer(cfg, lamp_map, traj, seed=7).render(3)
    c = StereoRenderer(cfg, lamp_map, traj, seed=8).render(3)
    assert a.truth and np.array_equal(a.left, b.left) and np.array_equal(a.right, b.right)
    assert [t.uv_left.tolist() for t in a.truth] == [t.uv_left.tolist() for t in b.truth]
    assert not np.array_equal(a.left, c.left)
    wa = StereoRenderer(cfg, lamp_map, traj, seed=7).lamp_waveform(4097)
    wc = StereoRenderer(cfg, lamp_map, traj, seed=8).lamp_waveform(4097)
    assert wa.phase_s != wc.phase_s


def test_lamp_clocks_within_ppm_and_independent(lamp_map):
    cfg = RendererConfig(lamp_clock_ppm=100.0, sensor_noise=False)
    renderer = StereoRenderer(cfg, lamp_map, still(0.0), seed=11)
    waves = [renderer.lamp_waveform(uid) for uid in range(4097, 4137)]
    errors_ppm = np.array([(w.chip_rate_hz / 10000.0 - 1.0) * 1e6 for w in waves])
    phases = np.array([w.phase_s for w in waves])
    assert np.all(np.abs(errors_ppm) <= 100.0) and errors_ppm.std() > 20.0
    assert np.all((phases >= 0) & (phases < 54 / 9999.0)) and len(set(phases)) == len(phases)


def test_left_and_right_share_row_instants_and_stamp(lamp_map):
    renderer = StereoRenderer(RendererConfig(), lamp_map, still(LAMP_X_M - 3.0), seed=2)
    frame = renderer.render(5)
    assert frame.t0_s == pytest.approx(5 / 30.0)
    assert frame.stamp_s == pytest.approx(1704067200.0 + 5 / 30.0)
    t = frame.truth[0]
    # Same rows at the same instants: the stripes are identical row for row.
    rows = slice(t.rows_left[0] + 3, t.rows_left[1] - 2)
    left = frame.left[rows, int(t.uv_left[0]) - 2:int(t.uv_left[0]) + 3].mean(axis=1)
    right = frame.right[rows, int(t.uv_right[0]) - 2:int(t.uv_right[0]) + 3].mean(axis=1)
    assert np.corrcoef(left, right)[0, 1] > 0.98


def test_two_lamps_in_view_are_both_rendered():
    lamps = straight_tunnel_map(spacing_m=5.0)
    renderer = StereoRenderer(RendererConfig(sensor_noise=False), lamps, still(8.0))
    frame = renderer.render(0)
    assert sorted(t.uid for t in frame.truth) == [4097, 4098]
    for t in frame.truth:
        u, v = np.round(t.uv_left).astype(int)
        assert frame.left[v - 2:v + 3, u - 2:u + 3].max() > 100


def test_motion_blur_widens_the_spot_at_speed(lamp_map):
    """At 120 km/h the exposure smears the near spot along its image motion."""
    def width(speed_mps):
        start = LAMP_X_M - 1.5 - speed_mps * 0.0102   # lamp ~1.5 m ahead mid-frame
        traj = Trajectory(MotionProfile('constant', start_chainage_m=start,
                                        speed_mps=speed_mps),
                          Vibration(VibrationConfig(enabled=False)))
        cfg = geometry_only(exposure_s=2e-3)
        f = StereoRenderer(cfg, lamp_map, traj).render_at(0.0, electrons=True)
        t = f.truth[0]
        row = f.left[int(round(t.uv_left[1]))]
        on_e = row.max()
        return np.count_nonzero((row > 0.02 * on_e) & (row < 0.98 * on_e))
    # Edge pixels (partial coverage) multiply when the spot moves several px per exposure.
    assert width(120 / 3.6) > width(0.0) + 10


def test_invalid_configuration_is_rejected():
    with pytest.raises(ValueError, match='fps'):
        RendererConfig(fps=0.0)
    with pytest.raises(ValueError, match='chip_rate_hz'):
        RendererConfig(chip_rate_hz=50000.0)
    with pytest.raises(ValueError, match='readout'):
        RendererConfig(fps=60.0)            # 720 rows x 30 µs = 21.6 ms > 16.7 ms
