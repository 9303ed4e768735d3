"""Track alignment geometry, its inverse projection, and the alignment lamp maps.

References are independent of the closed forms in core/alignment.py: numerical
integration of the heading, numerical derivatives, and the circle through three points.
"""
import pathlib

import numpy as np
import pytest
from scipy.integrate import cumulative_trapezoid

from vlc_common.core.alignment import NAMED_ALIGNMENTS, Alignment
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
        assert lamp.position_m[2] == 1.4
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
