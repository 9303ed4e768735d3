"""Light that is not a lamp's disc: distractor lights and each lamp's wall reflection,
and the field-varying PSF.

References are computed here: projections through the foundation's StereoRig and
CameraModel, the documented photometry, and the waveforms integrated numerically.
"""
import dataclasses

import numpy as np
import pytest

from vlc_common.core.camera import StereoRig
from vlc_common.core.lamp_map import Lamp, LampMap, straight_tunnel_map
from vlc_stereo_camera.core.optics_truth import OpticsTruth
from vlc_stereo_camera.core.renderer import RendererConfig, StereoRenderer
from vlc_stereo_camera.core.sensor_noise import SensorConfig
from vlc_stereo_camera.core.stray_light import Distractor, FlickerWaveform, StrayLightConfig
from vlc_stereo_camera.core.trajectory import MotionProfile, Trajectory, Vibration, VibrationConfig

TRUTH = OpticsTruth.example()


def still(chainage_m=0.0):
    return Trajectory(MotionProfile('stationary', start_chainage_m=chainage_m),
                      Vibration(VibrationConfig(enabled=False)))


def quiet(**kw):
    """No PSF, noise, vignetting, background or saturation."""
    kw = dict(dict(lamp_modulation=False, optics_psf=False), **kw)
    return RendererConfig(sensor_noise=False, vignetting=False,
                          sensor=SensorConfig(background_dn=0.0, dark_current_e_per_s=0.0,
                                              full_well_e=1e12, noise_bank_size=1), **kw)


def in_view(pixel, range_m, chainage_m=0.0):
    """Map point seen by the default left camera at pinhole ``pixel``, ``range_m`` away,
    and the unit direction to it, for a train standing at ``chainage_m``.
    """
    rig = StereoRig()
    k = rig.intrinsics
    ray = np.array([(pixel[0] - k.cx) / k.fx, (pixel[1] - k.cy) / k.fy, 1.0])
    d = rig.R_base_cam @ (ray / np.linalg.norm(ray))
    return np.array([chainage_m, 0.0, 0.0]) + np.asarray(rig.mount_xyz_m) + range_m * d, d


def rim(position, normal, diameter, n=4000):
    e1 = np.array([1.0, 0.0, 0.0]) - normal[0] * normal
    if np.linalg.norm(e1) < 1e-6:
        e1 = np.array([0.0, 0.0, 1.0]) - normal[2] * normal
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(normal, e1)
    a = np.linspace(0.0, 2 * np.pi, n, endpoint=False)[:, None]
    return position + diameter / 2 * (np.cos(a) * e1 + np.sin(a) * e2)


def centroid(image):
    vv, uu = np.mgrid[:image.shape[0], :image.shape[1]]
    return np.array([(uu * image).sum(), (vv * image).sum()]) / image.sum()


def polygon_centroid(uv):
    x, y = uv[:, 0], uv[:, 1]
    cross = x * np.roll(y, -1) - np.roll(x, -1) * y
    area = cross.sum() / 2
    return np.array([((x + np.roll(x, -1)) * cross).sum(),
                     ((y + np.roll(y, -1)) * cross).sum()]) / (6 * area)


def test_flicker_waveform_mean_is_the_integral():
    wave = FlickerWaveform(flicker_hz=100.0, depth=0.8, phase_rad=1.1)
    t0 = 1234.5 + np.linspace(0.0, 0.01, 37)
    t1 = t0 + 50e-6
    s = np.linspace(0.0, 1.0, 4001)
    numeric = np.trapezoid(wave.level(t0[:, None] + s * 50e-6), s, axis=1)
    np.testing.assert_allclose(wave.mean_over(t0, t1), numeric, atol=1e-9)
    assert wave.level(np.linspace(0, 0.01, 1001)).min() == pytest.approx(0.2, abs=1e-4)
    np.testing.assert_array_equal(FlickerWaveform().mean_over(t0, t1), 1.0)


@pytest.mark.parametrize('raw', [False, True])
def test_a_distractor_shows_where_it_is_projected(raw):
    """A steady signal aspect (0.15 m, facing oncoming trains) in an otherwise empty tunnel:
    its truth is its projection (the rig's pinhole, or the true lens), its rendered spot
    is its disc's image (the projected rim's centroid, 0.02 px, on the ideal pair; within
    its eccentricity of the truth through the lens), no lamp truth is reported, and a
    fully covered pixel holds its luminance's electrons.
    """
    position, _ = in_view((900.0, 250.0), 6.0)
    normal = np.array([-1.0, 0.0, 0.0])
    signal = Distractor(position_m=tuple(position), normal=tuple(normal), diameter_m=0.15,
                        luminance_cd_m2=30_000.0, name='signal')
    config = quiet(distractors=(signal,), optics_truth=TRUTH if raw else None)
    renderer = StereoRenderer(config, LampMap([]), still(), seed=1)
    frame = renderer.render_at(0.0, electrons=True)
    assert frame.truth == [] and len(frame.distractors) == 1
    shown = frame.distractors[0]
    assert (shown.name, shown.index, shown.in_left, shown.in_right) == ('signal', 0, True, True)
    rig = StereoRig()
    p_cam = rig.to_camera(position[None], np.zeros(3), np.eye(3))
    if raw:
        expected = TRUTH.left.camera_model(1280, 720).project(p_cam)[0][0]
    else:
        expected = rig.project_camera(p_cam)[0][0]
    np.testing.assert_allclose(shown.uv_left, expected, atol=1e-6)
    u, v = np.round(shown.uv_left).astype(int)
    window = frame.left[v - 40:v + 41, u - 40:u + 41].astype(np.float64)
    spot = centroid(window) + [u - 40, v - 40]
    if raw:
        assert np.hypot(*(spot - shown.uv_left)) < 1.0
    else:
        uv_rim = rig.project_camera(rig.to_camera(rim(position, normal, 0.15), np.zeros(3),
                                                  np.eye(3)))[0]
        np.testing.assert_allclose(spot, polygon_centroid(uv_rim), atol=0.02)
        expected_e = config.optics.electrons_per_luminance(config.exposure_s) * 30_000.0
        assert window.max() == pytest.approx(expected_e, rel=1e-6)


def test_a_mains_light_flickers_row_by_row_and_a_steady_one_does_not():
    """A 100 Hz platform light 0.3 m wide, 3 m away: its rows follow the mean of the
    flicker waveform over each row's exposure; the same light steady has flat rows.
    """
    position, d = in_view((640.0, 360.0), 3.0)
    lights = {hz: Distractor(position_m=tuple(position), normal=tuple(-d), diameter_m=0.3,
                             luminance_cd_m2=5_000.0, flicker_hz=hz, flicker_depth=0.9)
              for hz in (0.0, 100.0)}
    frames = {hz: StereoRenderer(quiet(lamp_modulation=True, distractors=(light,)),
                                 LampMap([]), still(), seed=4).render_at(0.02, electrons=True)
              for hz, light in lights.items()}
    steady, flicker = frames[0.0].left, frames[100.0].left
    rows = np.flatnonzero(steady.max(axis=1) > 0.9 * steady.max())
    assert len(rows) > 80                                # ~3 ms of rows: a third of a period
    ratio = flicker[rows].sum(axis=1) / steady[rows].sum(axis=1)
    renderer = StereoRenderer(quiet(lamp_modulation=True, distractors=(lights[100.0],)),
                              LampMap([]), still(), seed=4)
    wave = renderer._distractors[0].waveform          # its seeded phase
    t = 0.02 + rows * renderer.config.row_time_s
    np.testing.assert_allclose(ratio, wave.mean_over(t, t + renderer.config.exposure_s),
                               atol=1e-4)
    assert np.ptp(ratio) > 0.5
    assert np.ptp(steady[rows].max(axis=1)) < 1e-3 * steady.max()


@pytest.mark.parametrize('raw', [False, True])
def test_a_lamp_reflection_returns_the_configured_fraction(raw):
    """The wall patch of a lamp 5 m ahead collects reflection_fraction of the lamp's light
    (both Lambertian, m = 1: they send the same share of their flux to the lens) within
    2 %, with a peak far dimmer than the lamp's, and carries the lamp's modulation row by
    row.
    """
    lamps = straight_tunnel_map(count=1, first_chainage_m=10.0)
    fraction = 0.05
    stray = StrayLightConfig(reflection_fraction=fraction, reflection_sigma_m=0.15)
    truth = TRUTH if raw else None
    trajectory = still(5.0)

    def render(**kw):
        renderer = StereoRenderer(quiet(optics_truth=truth, **kw), lamps, trajectory, seed=2)
        return renderer, renderer.render_at(0.0, electrons=True)
    _, lamp_only = render()
    _, with_patch = render(stray_light=stray)
    patch = with_patch.left - lamp_only.left
    assert patch.min() >= 0.0
    # the patch (±3σ) is inside the image
    nz = np.argwhere(patch > 0)
    assert nz.min() > 0 and nz[:, 0].max() < 719 and nz[:, 1].max() < 1279
    # within the ROI box, which holds at least the 3σ disc of the patch (98.9 % of it)
    assert 0.985 * fraction < patch.sum() / lamp_only.left.sum() < 1.005 * fraction
    assert patch.max() < 0.03 * lamp_only.left.max()
    # modulation: the modulated patch over the steady one is the lamp's row mean
    renderer, live = render(stray_light=stray, lamp_modulation=True)
    _, live_lamp = render(lamp_modulation=True)
    live_patch = live.left - live_lamp.left
    rows = np.flatnonzero(patch.sum(axis=1) > 0.05 * patch.sum(axis=1).max())
    ratio = live_patch[rows].sum(axis=1) / patch[rows].sum(axis=1)
    wave = renderer.lamp_waveform(lamps.lamps[0].uid)
    t = rows * renderer.config.row_time_s
    np.testing.assert_allclose(ratio, wave.mean_over(t, t + renderer.config.exposure_s),
                               atol=2e-3)


def test_psf_widens_toward_the_corners():
    """psf_sigma_corner_px: a spot near the sensor corner is blurred by σ(r) = σ0 + (σc −
    σ0)·(r/r_corner)² (its variance grows by σ(r)² − σ0² along each axis), a spot at the
    principal point by σ0 (unchanged).
    """
    lamps = []
    for i, pixel in enumerate([(640.0, 360.0), (1240.0, 40.0)]):
        position, d = in_view(pixel, 8.0)
        lamps.append(Lamp(uid=(4 << 12) | (i + 1), line_id=4, lamp_id=i + 1,
                          position_m=position, normal=-d, diameter_m=0.1))
    lamps = LampMap(lamps)
    base = dict(optics_psf=True, halo_fraction=0.0, psf_sigma_px=0.7)
    frames = {}
    for corner in (0.0, 1.6):
        config = dataclasses.replace(quiet(**base), psf_sigma_corner_px=corner)
        frames[corner] = StereoRenderer(config, lamps, still(), seed=1).render_at(
            0.0, electrons=True)
    k = StereoRig().intrinsics
    r_corner = np.hypot(639.5 + 0.5, 359.5 + 0.5)
    sigmas = []
    for truth in frames[0.0].truth:
        u, v = np.round(truth.uv_left).astype(int)
        var = []
        for corner in (0.0, 1.6):
            w = frames[corner].left[v - 20:v + 21, u - 20:u + 21].astype(np.float64)
            c = centroid(w)
            vv, uu = np.mgrid[:w.shape[0], :w.shape[1]]
            var.append(np.array([((uu - c[0]) ** 2 * w).sum(), ((vv - c[1]) ** 2 * w).sum()])
                       / w.sum())
        r = np.hypot(truth.uv_left[0] - k.cx, truth.uv_left[1] - k.cy) / r_corner
        sigma = 0.7 + (1.6 - 0.7) * r * r
        np.testing.assert_allclose(var[1] - var[0], sigma ** 2 - 0.7 ** 2, atol=0.03)
        sigmas.append(sigma)
    assert min(sigmas) == pytest.approx(0.7, abs=1e-3) and max(sigmas) > 1.4
