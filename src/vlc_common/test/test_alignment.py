"""Track alignment geometry, its inverse projection, and the alignment lamp maps.

References are independent of the closed forms in core/alignment.py: numerical
integration of the heading, numerical derivatives, and the circle through three points.
"""
import pathlib

import numpy as np
import pytest
from scipy.integrate import cumulative_trapezoid

from vlc_common.core.alignment import (
    DEMO_DESIGN_SPEED_MPS,
    NAMED_ALIGNMENTS,
    NAMED_TRACK_PROFILES,
    Alignment,
    design_cant_m,
)
from vlc_common.core.lamp_map import (
    LampMap,
    alignment_lamp_map,
    default_lamp_map_path,
    lamp_map_file_name,
    resolve_lamp_map_path,
    straight_tunnel_map,
)

CONFIG = pathlib.Path(__file__).resolve().parents[1] / 'config'


@pytest.fixture(scope='module')
def demo():
    return Alignment.named('curved_demo')


def test_default_straight_is_map_x():
    a = Alignment.straight()
    s = np.array([-1234.5, -0.25, 0.0, 10.0, 1999.75, 1.0e5])
    p = a.evaluate(s)
    np.testing.assert_array_equal(p.x_m, s)
    np.testing.assert_array_equal(p.y_m, 0.0)
    np.testing.assert_array_equal(p.heading_rad, 0.0)
    np.testing.assert_array_equal(p.curvature_1pm, 0.0)
    chainage, lateral = a.project(s, np.full_like(s, 0.3))
    np.testing.assert_array_equal(chainage, s)
    np.testing.assert_array_equal(lateral, 0.3)
    assert a.is_straight and Alignment.named('straight').is_straight


def test_curved_demo_elements_radii_and_heading(demo):
    assert demo.length_m == pytest.approx(2310.0)
    radii = sorted(abs(e[2]) for e in NAMED_ALIGNMENTS['curved_demo'] if e[0] == 'arc')
    assert radii == [300.0, 400.0, 600.0, 800.0]
    s = np.arange(-50.0, 2420.0, 0.5)
    p = demo.evaluate(s)
    # Curvature: 0 on the straights, ±1/R on the arcs, linear on the clothoids.
    assert p.curvature_1pm[s < 200].max() == 0.0
    assert demo.evaluate(380.0).curvature_1pm[0] == pytest.approx(1 / 400)
    assert demo.evaluate(1070.0).curvature_1pm[0] == pytest.approx(-1 / 600)
    assert demo.evaluate(240.0).curvature_1pm[0] == pytest.approx(0.5 / 400)
    assert np.all(np.abs(np.diff(p.curvature_1pm)) <= 0.5 / 60 / 300 * 1.0001)   # continuous
    # Heading = ∫κ ds (trapezoid of the exact curvature) and map x monotonic.
    psi = cumulative_trapezoid(p.curvature_1pm, s, initial=0.0)
    np.testing.assert_allclose(p.heading_rad, psi, atol=1e-7)
    assert np.degrees(p.heading_rad).max() == pytest.approx(40.1, abs=0.1)
    assert np.all(np.diff(p.x_m) > 0.0)


def test_position_is_the_integral_of_the_tangent(demo):
    s = np.linspace(-20.0, 2400.0, 242001)            # 1 cm steps
    p = demo.evaluate(s)
    x = cumulative_trapezoid(np.cos(p.heading_rad), s, initial=0.0) + p.x_m[0]
    y = cumulative_trapezoid(np.sin(p.heading_rad), s, initial=0.0) + p.y_m[0]
    np.testing.assert_allclose(p.x_m, x, atol=1e-6)
    np.testing.assert_allclose(p.y_m, y, atol=1e-6)
    # Continuous across every element joint.
    for s0 in np.cumsum([0.0] + [e[1] for e in NAMED_ALIGNMENTS['curved_demo']]):
        a, b = demo.evaluate([s0 - 1e-7, s0 + 1e-7]).x_m, demo.evaluate([s0 - 1e-7, s0 + 1e-7]).y_m
        assert np.hypot(a[1] - a[0], b[1] - b[0]) == pytest.approx(2e-7, abs=1e-9)


def test_arc_points_lie_on_the_circle(demo):
    """Three points of the R = 400 m arc define a circle of radius 400 m through the rest."""
    p = demo.evaluate(np.linspace(290.0, 470.0, 7))
    (x1, x2, x3), (y1, y2, y3) = p.x_m[[0, 3, 6]], p.y_m[[0, 3, 6]]
    a = np.array([[x2 - x1, y2 - y1], [x3 - x1, y3 - y1]])
    b = 0.5 * np.array([x2 ** 2 - x1 ** 2 + y2 ** 2 - y1 ** 2,
                        x3 ** 2 - x1 ** 2 + y3 ** 2 - y1 ** 2])
    centre = np.linalg.solve(a, b)
    np.testing.assert_allclose(np.hypot(p.x_m - centre[0], p.y_m - centre[1]), 400.0, atol=1e-7)
    # Curving left: the centre is on the left of the running direction.
    left = p.left_normal[3]
    assert (centre - [p.x_m[3], p.y_m[3]]) @ left == pytest.approx(400.0, abs=1e-6)


def test_projection_inverts_to_map(demo):
    rng = np.random.default_rng(4)
    s = rng.uniform(-300.0, 2700.0, 2000)
    lateral = rng.uniform(-5.0, 5.0, 2000)
    points = demo.to_map(s, lateral, 1.4)
    chainage, offset = demo.project(points[:, 0], points[:, 1])
    np.testing.assert_allclose(chainage, s, atol=1e-8)
    np.testing.assert_allclose(offset, lateral, atol=1e-8)


def test_rotated_straight_projection():
    a = Alignment([('straight', 100.0)], start_chainage_m=50.0, start_xy_m=(3.0, -2.0),
                  start_heading_rad=0.5)
    p = a.to_map([80.0], 1.5)[0]
    s, lat = a.project([p[0]], [p[1]])
    assert (s[0], lat[0]) == (pytest.approx(80.0), pytest.approx(1.5))


@pytest.mark.parametrize('elements, words', [
    ([('arc', 10.0, 300.0)], 'start and end with a straight'),
    ([('straight', 10.0), ('arc', 10.0, 300.0), ('straight', 1.0)], 'clothoid must lead'),
    ([('straight', 10.0), ('clothoid', 10.0, 300.0), ('straight', 1.0)], 'zero-curvature'),
    ([('straight', 10.0), ('spiral', 10.0, 3.0), ('straight', 1.0)], 'unknown alignment element'),
    ([('straight', -1.0)], 'length'),
])
def test_invalid_alignments_are_rejected(elements, words):
    with pytest.raises(ValueError, match=words):
        Alignment(elements)


def test_unknown_named_alignment():
    with pytest.raises(ValueError, match='unknown alignment'):
        Alignment.named('loop')


def test_curvature_template_is_one_metre_samples(demo):
    s, kappa = demo.curvature_template(1.0)
    assert s[0] == 0.0 and s[-1] == 2310.0 and np.all(np.diff(s) == 1.0)
    np.testing.assert_array_equal(kappa, demo.evaluate(s).curvature_1pm)


# --- lamp maps ------------------------------------------------------------------------

def test_alignment_lamp_map_of_the_straight_is_the_straight_map():
    a = alignment_lamp_map(Alignment.straight(), last_chainage_m=2000.0)
    b = straight_tunnel_map()
    assert len(a) == len(b) == 200
    for la, lb in zip(a.lamps, b.lamps):
        assert la.uid == lb.uid
        np.testing.assert_array_equal(la.position_m, lb.position_m)
        np.testing.assert_allclose(la.normal, lb.normal, atol=1e-15)
        assert la.track_chainage_m == lb.track_chainage_m


def test_curved_lamps_follow_the_wall(demo):
    lamps = alignment_lamp_map(demo, line_id=2)
    assert len(lamps) == 231 and lamps.alignment == 'curved_demo'
    for lamp in lamps.lamps:
        s, lateral = demo.project([lamp.position_m[0]], [lamp.position_m[1]])
        assert s[0] == pytest.approx(lamp.chainage_m, abs=1e-8)
        assert lateral[0] == pytest.approx(2.5, abs=1e-8)
        # 1.4 m above the rail level of its chainage: the wall follows the grade.
        assert lamp.position_m[2] == pytest.approx(
            1.4 + demo.evaluate(lamp.chainage_m).elevation_m[0], abs=1e-12)
        # Disc normal horizontal, facing the track: opposite the left normal there.
        n = demo.evaluate(lamp.chainage_m).left_normal[0]
        np.testing.assert_allclose(lamp.normal, [-n[0], -n[1], 0.0], atol=1e-12)
    assert [lamp.lamp_id for lamp in lamps.near_chainage(395.0, 20.0, 10.0)] == [39, 40, 41]
    assert np.all(np.diff(lamps.chainages) == 10.0)


def test_shipped_curved_map_is_the_generator_output(demo, tmp_path):
    """config/lamp_map_curved_demo.yaml = `python -m vlc_common.core.lamp_map`."""
    shipped = CONFIG / 'lamp_map_curved_demo.yaml'
    expected = alignment_lamp_map(demo, line_id=2)
    expected.save(tmp_path / 'x.yaml')
    assert shipped.read_text() == (tmp_path / 'x.yaml').read_text()
    loaded = LampMap.load(shipped)
    assert loaded.alignment == 'curved_demo'
    assert {lamp.line_id for lamp in loaded.lamps} == {2}
    assert loaded.by_uid((2 << 12) | 40).chainage_m == 400.0
    # The straight map is unchanged: no alignment, no chainage keys.
    straight = (CONFIG / 'lamp_map.yaml').read_text()
    assert 'chainage_m' not in straight and 'alignment' not in straight
    assert LampMap.load(CONFIG / 'lamp_map.yaml').alignment == ''


def test_lamp_map_paths_per_alignment():
    assert lamp_map_file_name('straight') == 'lamp_map.yaml'
    assert lamp_map_file_name('curved_demo') == 'lamp_map_curved_demo.yaml'
    assert default_lamp_map_path('curved_demo').endswith('lamp_map_curved_demo.yaml')
    assert resolve_lamp_map_path('') == default_lamp_map_path()
    assert resolve_lamp_map_path('', 'curved_demo') == default_lamp_map_path('curved_demo')


# --- vertical profile and cant ----------------------------------------------------------

def test_named_curved_demo_keeps_its_horizontal_geometry_to_the_bit(demo):
    """Adding cant and grade leaves x, y, ψ, κ of curved_demo exactly as they were."""
    level = Alignment(NAMED_ALIGNMENTS['curved_demo'], name='curved_demo')
    s = np.linspace(-100.0, 2400.0, 25001)
    a, b = demo.evaluate(s), level.evaluate(s)
    for name in ('x_m', 'y_m', 'heading_rad', 'curvature_1pm', 'curvature_rate_1pm2'):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name), err_msg=name)
    assert level.is_level and not demo.is_level and Alignment.straight().is_level
    for name in ('elevation_m', 'grade', 'grade_rate_1pm', 'cant_m', 'cant_rad'):
        np.testing.assert_array_equal(getattr(b, name), 0.0)
    np.testing.assert_array_equal(level.to_map(s, 2.5, 1.4)[:, 2], 1.4)


def test_vertical_profile_grades_and_vertical_curves(demo):
    """Grades between the PVIs; parabolic vertical curves of length R·|Δg| centred on the
    PVIs with z'' = Δg/L; z, G, G' continuous and each the derivative of the previous
    (numerical differentiation); straight grade lines beyond the ends.
    """
    s = np.arange(-200.0, 2600.0, 0.01)
    p = demo.evaluate(s)
    pvis = NAMED_TRACK_PROFILES['curved_demo']['vertical_profile']
    grades = [(b[1] - a[1]) / (b[0] - a[0]) for a, b in zip(pvis, pvis[1:])]
    np.testing.assert_allclose(grades, [-0.003, -0.028, 0.004, 0.025, 0.003], atol=1e-12)
    np.testing.assert_allclose(np.gradient(p.elevation_m, s)[1:-1], p.grade[1:-1], atol=1e-6)
    np.testing.assert_allclose(np.gradient(p.grade, s)[1:-1], p.grade_rate_1pm[1:-1],
                               atol=2e-4 / 2)                 # steps at the curve ends
    assert np.max(np.abs(np.diff(p.elevation_m))) < 0.03 * 0.01 * 1.001
    assert np.max(np.abs(np.diff(p.grade))) < 0.01 / 5000.0 * 1.001   # no grade jumps
    for (s_pvi, _, radius), g0, g1 in zip(pvis[1:-1], grades, grades[1:]):
        half = 0.5 * radius * abs(g1 - g0)
        inside = (s > s_pvi - half + 0.01) & (s < s_pvi + half - 0.01)
        np.testing.assert_allclose(p.grade_rate_1pm[inside], (g1 - g0) / (2 * half),
                                   rtol=1e-12)
        assert np.all(p.grade_rate_1pm[(s > s_pvi + half + 0.01) & (s < s_pvi + half + 20)]
                      == 0.0)
        # Tangent points on the grade lines through the PVI.
        z_pvi = demo.evaluate(s_pvi).elevation_m[0] - (g1 - g0) * half / 4.0
        assert z_pvi == pytest.approx([z for c, z, _ in pvis if c == s_pvi][0], abs=1e-9)
    beyond = demo.evaluate([-100.0, 2500.0])
    assert beyond.elevation_m == pytest.approx([0.3, -4.12 + 0.003 * 190.0])
    assert 20.0 < -p.elevation_m.min() < 22.0


def test_cant_follows_the_design_rule_and_ramps_with_curvature(demo):
    """Cant = 11.8·V²/R − 61 mm at 80 km/h, capped at 120 mm, rounded up to 5 mm (GB 50157
    metro rule, written out independently here); constant on the arcs, proportional to
    curvature along the transitions, banked toward the centre, and its angle's
    derivatives match numerical differentiation.
    """
    def rule_mm(radius_m):
        cant = 11.8 * 80.0 ** 2 / radius_m - 61.0
        return min(120.0, 5.0 * np.ceil(cant / 5.0 - 1e-9))

    assert [rule_mm(r) for r in (400.0, 600.0, 800.0, 300.0)] == [120.0, 65.0, 35.0, 120.0]
    for radius in (300.0, 400.0, 600.0, 800.0, 2000.0, 5000.0):
        assert design_cant_m(radius, DEMO_DESIGN_SPEED_MPS) * 1000.0 == pytest.approx(
            max(rule_mm(radius), 0.0), abs=5.0 + 1e-9)
    assert design_cant_m(-400.0, DEMO_DESIGN_SPEED_MPS) == pytest.approx(0.12)
    assert design_cant_m(5000.0, DEMO_DESIGN_SPEED_MPS) == 0.0
    s = np.arange(-50.0, 2400.0, 0.01)
    p = demo.evaluate(s)
    for chainage, radius, cant in ((380.0, 400.0, 0.12), (1010.0, -600.0, -0.065),
                                   (1510.0, 800.0, 0.035), (1890.0, -300.0, -0.12)):
        q = demo.evaluate(chainage)
        assert q.curvature_1pm[0] == pytest.approx(1.0 / radius)
        assert q.cant_m[0] == pytest.approx(cant, abs=1e-15)
        assert q.cant_rad[0] == pytest.approx(-np.arcsin(cant / 1.5), abs=1e-15)
    # Transitions: cant/κ constant (linear ramps of both), zero on the straights.
    ramp = (s > 200.5) & (s < 279.5)
    np.testing.assert_allclose(p.cant_m[ramp] / p.curvature_1pm[ramp], 0.12 * 400.0,
                               rtol=1e-9)
    assert np.all(p.cant_m[np.abs(p.curvature_1pm) == 0.0] == 0.0)
    assert np.all(np.sign(p.cant_m) == np.sign(p.curvature_1pm))
    assert np.max(np.abs(np.diff(p.cant_m))) <= 0.12 / 70.0 * 0.01 * 1.0001   # no jumps
    np.testing.assert_allclose(np.gradient(p.cant_rad, s)[1:-1], p.cant_rate_radpm[1:-1],
                               atol=0.12 / 70 / 1.5 * 1.01 / 2)   # steps at ramp ends
    np.testing.assert_allclose(np.gradient(p.cant_rate_radpm, s)[ramp],
                               p.cant_rate2_radpm2[ramp], rtol=1e-5)
    assert np.all(p.cant_rate2_radpm2[ramp] < 0.0) and p.cant_rate2_radpm2[ramp].min() < -5e-8
    d = p.cant_m / 1.5
    ramp_rate = np.gradient(p.cant_m, s) / 1.5
    np.testing.assert_allclose(p.cant_rate2_radpm2[ramp],
                               -d[ramp] * ramp_rate[ramp] ** 2 / (1 - d[ramp] ** 2) ** 1.5,
                               rtol=1e-6)


@pytest.mark.parametrize('kwargs, words', [
    (dict(cant_m=[0.0, 0.1, 0.1, 0.0]), 'one per element'),
    (dict(cant_m=[0.0, 0.1, 0.1, 0.05, 0.0]), 'back to straight must end at cant 0'),
    (dict(cant_m=[0.1, 0.1, 0.1, 0.0, 0.0]), 'straight has no cant'),
    (dict(cant_m=[0.0, 0.1, 0.12, 0.0, 0.0]), 'cant jumps'),
    (dict(cant_m=[0.0, 1.6, 1.6, 0.0, 0.0]), 'rail centre distance'),
    (dict(vertical_profile=[(0.0, 0.0, 0.0)]), 'at least two'),
    (dict(vertical_profile=[(0.0, 0.0), (100.0, 1.0), (50.0, 0.0)]), 'increasing'),
    (dict(vertical_profile=[(0.0, 0.0), (100.0, 1.0, 0.0), (200.0, 0.0)]), 'radius > 0'),
    (dict(vertical_profile=[(0.0, 0.0), (100.0, 3.0, 20000.0), (200.0, 0.0)]), 'overlaps'),
])
def test_invalid_cant_and_vertical_profiles_are_rejected(kwargs, words):
    elements = [('straight', 100.0), ('clothoid', 50.0, 500.0), ('arc', 50.0, 500.0),
                ('clothoid', 50.0, float('inf')), ('straight', 100.0)]
    with pytest.raises(ValueError, match=words):
        Alignment(elements, **kwargs)
