"""``calibrate_installation``: a real checkerboard calibration of a drawn installation.

``make_installation`` (simulator) writes the belief calibration as the truth perturbed by
the errors a calibration leaves (fast, per draw). This command replaces it by an actual
calibration, as a depot would make it: it renders checkerboard pairs through the
installation's TRUE lenses (``truth/truth.yaml``; the simulator's checkerboard renderer:
a 15×10-corner board of 25 mm squares pushed into the corners, edges and centre of each
image, 0.55–1.0 m away, 2 DN noise), runs ``stereo_calibrate`` on them and writes

* ``belief/left.yaml``, ``belief/right.yaml``: the calibration found (its own stereo and
  per-camera reprojection RMS and pair count in the ``# calibration:`` comment);
* ``truth/calibration.yaml``: the calibration's errors against the truth (focal length
  %, principal point px, undistortion displacement at the sensor's corners and edge
  middles px, stereo rotation deg, baseline mm), for the evaluation.

::

    calibrate_installation DIR [--pairs 16]

Deterministic per installation (board poses and noise from the installation's seed).
About 10 s of one core for 16 pairs. Exit status 0; 2 with ``calibrate_installation:
error: …`` when ``DIR/truth/truth.yaml`` is missing or unusable or the calibration fails.
The stereo camera node publishes the result with ``calibration_paths:=[DIR/belief/left.yaml,
DIR/belief/right.yaml]``.
"""
import argparse
import contextlib
import io
import pathlib
import sys
import tempfile

import cv2
import numpy as np
import yaml

from vlc_calibration.stereo_calibrate import main as stereo_calibrate
from vlc_common.core.calibration import load_ros_stereo
from vlc_stereo_camera.core.checkerboard import (
    Checkerboard,
    StereoBoardRenderer,
    calibration_poses,
)
from vlc_stereo_camera.core.optics_truth import OpticsTruth, TrueCamera

BOARD = Checkerboard((15, 10), 0.025)
#: Where the distortion is largest: the sensor's corners and the middles of its edges, px.
EDGE_POINTS = np.array([[-0.5, -0.5], [1279.5, -0.5], [-0.5, 719.5], [1279.5, 719.5],
                        [639.5, -0.5], [639.5, 719.5], [-0.5, 359.5], [1279.5, 359.5]])
_TAG_BOARDS = 0xB0A4D


class InstallationError(ValueError):
    """An installation folder that cannot be calibrated (message names file and field)."""


def optics_from_truth(truth, source='truth.yaml'):
    """The true :class:`OpticsTruth` recorded in a parsed ``truth.yaml``."""
    try:
        o = truth['optics']
        cams = [TrueCamera(fx=float(o[s]['fx']), fy=float(o[s]['fy']), cx=float(o[s]['cx']),
                           cy=float(o[s]['cy']), distortion=tuple(o[s]['distortion']))
                for s in ('left', 'right')]
        return OpticsTruth(left=cams[0], right=cams[1],
                           right_rotation_deg=tuple(o['right_rotation_deg']),
                           right_position_m=tuple(o['right_position_m']),
                           trigger_skew_s=float(o['trigger_skew_s']))
    except (KeyError, TypeError) as exc:
        raise InstallationError(f'{source}: optics: missing or malformed ({exc!r}); an ideal '
                                'installation has no lenses to calibrate') from None
    except ValueError as exc:
        raise InstallationError(f'{source}: optics: {exc}') from None


def _displacement(camera, uv):
    """Undistortion displacement (N, 2) of raw pixels with the camera's own K, px."""
    return camera.undistort_normalized(uv) @ camera.K[:2, :2].T + camera.K[:2, 2] - uv


def checkerboard_calibration(optics, seed, pairs=16, width=1280, height=720,
                             camera_name='stereo'):
    """(StereoCalibration, report dict): ``stereo_calibrate`` on ``pairs`` board pairs
    rendered through ``optics``; the report holds the errors against the truth.
    """
    truth = optics.stereo_model(width, height)
    renderer = StereoBoardRenderer(truth, BOARD)
    rng = np.random.default_rng([int(seed), _TAG_BOARDS])
    with tempfile.TemporaryDirectory() as tmp:
        folder = pathlib.Path(tmp)
        for k, pose in enumerate(calibration_poses(renderer, pairs, rng,
                                                   distance_m=(0.55, 1.0), in_both=False)):
            left, right = renderer.render(*pose, rng)
            cv2.imwrite(str(folder / f'left_{k:02d}.png'), left)
            cv2.imwrite(str(folder / f'right_{k:02d}.png'), right)
        out, err = io.StringIO(), io.StringIO()
        with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
            code = stereo_calibrate([str(folder), '--size', '15x10', '--square', '0.025',
                                     '-o', str(folder), '--camera-name', camera_name])
        if code != 0:
            raise InstallationError(f'stereo_calibrate failed ({code}): '
                                    f'{err.getvalue().strip()}')
        calibration = load_ros_stereo(folder / 'left.yaml', folder / 'right.yaml')
    focal, principal, corner = [], [], []
    for est, true in ((calibration.left, truth.left), (calibration.right, truth.right)):
        focal.append((100.0 * (est.K[[0, 1], [0, 1]] / true.K[[0, 1], [0, 1]] - 1.0)).tolist())
        principal.append((est.K[:2, 2] - true.K[:2, 2]).tolist())
        corner.append(float(np.linalg.norm(_displacement(est, EDGE_POINTS)
                                           - _displacement(true, EDGE_POINTS), axis=1).max()))
    R_est, T_est = calibration.stereo.extrinsics()
    R_true, T_true = truth.extrinsics()
    cos = np.clip((np.trace(R_est.T @ R_true) - 1.0) / 2.0, -1.0, 1.0)
    report = {'method': 'checkerboard', 'pairs_rendered': int(pairs),
              'pairs_used': int(calibration.pairs),
              'stereo_rms_px': float(calibration.rms_px),
              'camera_rms_px': [float(calibration.left_rms_px),
                                float(calibration.right_rms_px)],
              'focal_error_percent': focal, 'principal_point_error_px': principal,
              'max_edge_displacement_error_px': corner,
              'rotation_error_deg': float(np.degrees(np.arccos(cos))),
              'baseline_error_mm': float(1e3 * (np.linalg.norm(T_est) - np.linalg.norm(T_true)))}
    return calibration, report


def calibrate_installation(folder, pairs=16):
    """Calibrate the installation in ``folder`` (written by ``make_installation``): the
    belief calibration files are replaced, ``truth/calibration.yaml`` written. Returns
    the report.
    """
    from vlc_common.core.calibration import save_ros_stereo
    folder = pathlib.Path(folder)
    truth_path = folder / 'truth' / 'truth.yaml'
    try:
        truth = yaml.safe_load(truth_path.read_text(encoding='utf-8'))
    except OSError as exc:
        raise InstallationError(f'{truth_path}: (file): cannot read: {exc.strerror}') from None
    except yaml.YAMLError as exc:
        raise InstallationError(f'{truth_path}: (file): not valid YAML ({exc})') from None
    if not isinstance(truth, dict):
        raise InstallationError(f'{truth_path}: (file): not an installation record')
    optics = optics_from_truth(truth, truth_path)
    camera = truth.get('nominal_camera') or {}
    name = (truth.get('vehicle_belief') or {}).get('vehicle_id') or 'stereo'
    calibration, report = checkerboard_calibration(
        optics, truth.get('seed', 0), pairs, int(camera.get('width', 1280)),
        int(camera.get('height', 720)), camera_name=name)
    save_ros_stereo(calibration, folder / 'belief' / 'left.yaml',
                    folder / 'belief' / 'right.yaml')
    report.update(profile=truth.get('profile'), seed=truth.get('seed'))
    with open(folder / 'truth' / 'calibration.yaml', 'w', encoding='utf-8') as stream:
        stream.write('# The belief calibration (belief/left.yaml, right.yaml) against the '
                     'truth; for the evaluation only.\n')
        yaml.safe_dump(report, stream, sort_keys=False, default_flow_style=None)
    return report


def main(argv=None):
    p = argparse.ArgumentParser(prog='calibrate_installation',
                                description=__doc__.split('\n')[0])
    p.add_argument('folder', help='installation folder (make_installation --out)')
    p.add_argument('--pairs', type=int, default=16, help='board pairs rendered (default 16)')
    args = p.parse_args(sys.argv[1:] if argv is None else argv)
    try:
        report = calibrate_installation(args.folder, args.pairs)
    except InstallationError as exc:
        print(f'calibrate_installation: error: {exc}', file=sys.stderr)
        return 2
    print(f'profile {report["profile"]}, seed {report["seed"]}: {report["pairs_used"]} pairs, '
          f'stereo RMS {report["stereo_rms_px"]:.3f} px; errors vs truth: focal '
          f'{report["focal_error_percent"]} %, principal point '
          f'{report["principal_point_error_px"]} px, edge displacement '
          f'{report["max_edge_displacement_error_px"]} px, rotation '
          f'{report["rotation_error_deg"]:.4f} deg, baseline {report["baseline_error_mm"]:+.3f} mm')
    print(f'wrote {pathlib.Path(args.folder) / "belief"}/left.yaml, right.yaml and '
          f'{pathlib.Path(args.folder) / "truth" / "calibration.yaml"}')
    return 0


if __name__ == '__main__':
    sys.exit(main())
