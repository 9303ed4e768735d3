"""The localizer's track model on an alignment with a vertical profile and cant.

Reference: the rig's trajectory (ground truth of ``base_link`` for a standing train
without vibration) and the alignment's own evaluation.
"""
import numpy as np
import pytest

from train_localizer.core.track import Track
from vlc_common.core.alignment import NAMED_ALIGNMENTS, Alignment
from vlc_stereo_camera.core.trajectory import MotionProfile, Trajectory, Vibration, VibrationConfig

DEMO = Alignment.named('curved_demo')


@pytest.mark.parametrize('chainage_m', [0.0, 240.0, 380.0, 1000.0, 1890.0, 2300.0])
def test_base_link_sits_at_the_alignment_elevation(chainage_m):
    """Track.position is where the rig puts base_link (elevation included), and the
    frame's tangent and normal stay horizontal unit vectors: chainage is plan distance.
    """
    track = Track(DEMO)
    P, t, n = track.frame(chainage_m)
    truth = Trajectory(MotionProfile('stationary', start_chainage_m=chainage_m),
                       Vibration(VibrationConfig(enabled=False)), DEMO).sample([0.0])
    np.testing.assert_allclose(P, truth.position_m[0], atol=1e-12)
    assert P[2] == pytest.approx(DEMO.evaluate(chainage_m).elevation_m[0], abs=1e-15)
    assert t[2] == n[2] == 0.0
    assert np.linalg.norm(t) == pytest.approx(1.0) and t @ n == pytest.approx(0.0, abs=1e-15)
    assert track.chainage_of(P) == pytest.approx(chainage_m, abs=1e-8)
    # The plan tangent is the rig's plan velocity direction for a moving train.
    moving = Trajectory(MotionProfile('constant', start_chainage_m=chainage_m, speed_mps=20.0),
                        Vibration(VibrationConfig(enabled=False)), DEMO).sample([0.0])
    velocity = moving.velocity_mps[0]
    np.testing.assert_allclose(velocity[:2] / np.linalg.norm(velocity[:2]), t[:2], atol=1e-12)
    assert velocity[2] == pytest.approx(20.0 * DEMO.evaluate(chainage_m).grade[0], abs=1e-12)


def test_offsets_and_level_alignments_are_unchanged():
    """Offsets add along n and up; a level alignment keeps z = z0 and the straight the
    fast path.
    """
    level = Track(Alignment(NAMED_ALIGNMENTS['curved_demo']), offset_yz_m=(0.3, 1.2))
    P, _, n = level.frame(380.0)
    p = level.alignment.evaluate(380.0)
    np.testing.assert_array_equal(P, np.array([p.x_m[0], p.y_m[0], 0.0]) + 0.3 * n
                                  + 1.2 * np.array([0.0, 0.0, 1.0]))
    graded = Track(DEMO, offset_yz_m=(0.3, 1.2))
    assert graded.position(380.0)[2] == pytest.approx(1.2 + DEMO.evaluate(380.0).elevation_m[0])
    straight = Track()
    assert straight.straight_x and not Track(DEMO).straight_x
    np.testing.assert_array_equal(straight.position(12.5), [12.5, 0.0, 0.0])


@pytest.mark.parametrize('chainage_m', [0.0, 240.0, 380.0, 1000.0, 1890.0, 2300.0])
def test_attitude_is_the_rigs_track_frame(chainage_m):
    """Track.attitude is the rig's R_map_base of a standing train without vibration:
    heading, the grade's pitch and the cant's roll (before, the localizer's track
    attitude had the heading only: 4.7° of cant in curved_demo's R 400 m curve, ten
    times its stated roll 1σ without the IMU).
    """
    truth = Trajectory(MotionProfile('stationary', start_chainage_m=chainage_m),
                       Vibration(VibrationConfig(enabled=False)), DEMO).sample([0.0])
    np.testing.assert_allclose(Track(DEMO).attitude(chainage_m), truth.R_map_base[0],
                               atol=1e-12)
    np.testing.assert_array_equal(Track().attitude(chainage_m), np.eye(3))


def test_the_demo_curve_is_canted():
    """The curve the test above reads has a cant of several degrees (it tests the roll)."""
    assert abs(np.degrees(DEMO.evaluate(380.0).cant_rad[0])) > 3.0
