"""Cross-check of the rig profiles' calibration errors against real calibrations.

For a few seeds, draws the ``realistic`` vehicle's true lenses (``core/installation.py``),
renders 16 checkerboard pairs through them (the boards of ``test_stereo_calibrate.py``:
15x10 corners, 25 mm squares, pushed into the corners, edges and centre), runs
``stereo_calibrate`` on them and prints the calibration's error against the truth next to
the profile's 1-sigma, the sizes the profile's perturbation of the truth uses in place of
a calibration per draw. Slow (a calibration per seed); not a test.

    python scripts/calibration_error_check.py [--seeds 1 2 3] [--profile realistic]
"""
import argparse
import contextlib
import io
import pathlib
import tempfile

import cv2
import numpy as np

from vlc_calibration.stereo_calibrate import main as stereo_calibrate
from vlc_common.core.calibration import load_ros_stereo
from vlc_evaluation.installation_calibration import BOARD, EDGE_POINTS
from vlc_stereo_camera.core.checkerboard import (
    StereoBoardRenderer,
    calibration_poses,
)
from vlc_stereo_camera.core.installation import draw_optics, load_profile


def displacement(camera, uv):
    return camera.undistort_normalized(uv) @ camera.K[:2, :2].T + camera.K[:2, 2] - uv


def calibrate(optics, seed, folder):
    truth = optics.stereo_model(1280, 720)
    renderer = StereoBoardRenderer(truth, BOARD)
    rng = np.random.default_rng([seed, 0xB0A4D])
    for k, pose in enumerate(calibration_poses(renderer, 16, rng, distance_m=(0.55, 1.0),
                                               in_both=False)):
        left, right = renderer.render(*pose, rng)
        cv2.imwrite(str(folder / f'left_{k:02d}.png'), left)
        cv2.imwrite(str(folder / f'right_{k:02d}.png'), right)
    with contextlib.redirect_stdout(io.StringIO()):
        code = stereo_calibrate([str(folder), '--size', '15x10', '--square', '0.025',
                                 '-o', str(folder)])
    if code != 0:
        raise RuntimeError(f'stereo_calibrate exited {code}')
    return truth, load_ros_stereo(folder / 'left.yaml', folder / 'right.yaml')


def main():
    p = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    p.add_argument('--seeds', type=int, nargs='+', default=[1, 2, 3])
    p.add_argument('--profile', default='realistic')
    args = p.parse_args()
    profile = load_profile(args.profile)
    c = profile.calibration
    print(f'profile {args.profile} 1-sigma: focal {c["focal_sigma"] * 100:.2f} %, principal '
          f'point {c["principal_point_sigma_px"]} px, rotation {c["rotation_sigma_deg"]} deg, '
          f'translation {c["translation_sigma_m"] * 1e3} mm, stated RMS '
          f'{c["reprojection_rms_px"]} px')
    print('seed  focal err %      pp err px        corner err px  rot err deg  '
          'base err mm  stereo RMS px')
    for seed in args.seeds:
        optics, _ = draw_optics(profile, seed)
        with tempfile.TemporaryDirectory() as tmp:
            truth, est = calibrate(optics, seed, pathlib.Path(tmp))
        focal, pp, corner = [], [], []
        for e, t in ((est.left, truth.left), (est.right, truth.right)):
            focal += list(100 * (e.K[[0, 1], [0, 1]] / t.K[[0, 1], [0, 1]] - 1))
            pp += list(e.K[:2, 2] - t.K[:2, 2])
            corner.append(np.linalg.norm(displacement(e, EDGE_POINTS)
                                         - displacement(t, EDGE_POINTS), axis=1).max())
        R_est, T_est = est.stereo.extrinsics()
        R_true, T_true = truth.extrinsics()
        angle = np.degrees(np.arccos(np.clip((np.trace(R_est.T @ R_true) - 1) / 2, -1, 1)))
        base = 1e3 * (np.linalg.norm(T_est) - np.linalg.norm(T_true))
        print(f'{seed:4d}  {np.round(focal, 3)}  {np.round(pp, 2)}  '
              f'{max(corner):.3f}  {angle:.4f}  {base:+.3f}  {est.rms_px:.3f}')


if __name__ == '__main__':
    main()
