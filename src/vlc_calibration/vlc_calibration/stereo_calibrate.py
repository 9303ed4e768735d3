"""``stereo_calibrate``: checkerboard image pairs → camera_info YAML files.

Usage::

    stereo_calibrate IMAGES --size 9x6 --square 0.04 [-o OUTPUT_DIR]
                     [--layout auto|pairs|side-by-side] [--camera-name NAME]
                     [--opencv-file stereo.yaml] [--radial-coefficients 2|3|6]
                     [--zero-tangential] [--alpha 0.0] [--min-pairs 5]

Writes ``OUTPUT_DIR/left.yaml`` and ``right.yaml`` (camera_info_manager format, as ROS
``camera_calibration`` writes them) and, with ``--opencv-file``, the same calibration
as an OpenCV FileStorage file. Prints the per-camera and stereo reprojection RMS and the
number of pairs used. Exit status 0 on success, 2 on unusable input (no board found in
any pair, size mismatch, unreadable images, bad arguments) with a message on stderr.
"""
import argparse
import logging
import pathlib
import sys

import numpy as np

from vlc_calibration.image_pairs import LAYOUTS, InputError, find_image_pairs
from vlc_calibration.stereo import CalibrationOptions, calibrate, detect_boards
from vlc_common.core.calibration import save_opencv_stereo, save_ros_stereo

PROG = 'stereo_calibrate'


def _board_size(text):
    try:
        cols, rows = (int(n) for n in text.lower().split('x'))
    except ValueError:
        raise argparse.ArgumentTypeError(f'{text!r}: expected inner corners as COLSxROWS, '
                                         'e.g. 9x6') from None
    return cols, rows


def build_parser():
    parser = argparse.ArgumentParser(
        prog=PROG, description='Stereo calibration from checkerboard image pairs: writes '
        'left.yaml and right.yaml (camera_info_manager) and optionally an OpenCV file.')
    parser.add_argument('images', type=pathlib.Path,
                        help='folder of left_*/right_* image pairs or of side-by-side images')
    parser.add_argument('--size', type=_board_size, required=True,
                        help='inner corners of the board per row and per column, e.g. 9x6 '
                        '(a board of 10x7 squares)')
    parser.add_argument('--square', type=float, required=True,
                        help='side of a square, m (sets the unit of the baseline)')
    parser.add_argument('-o', '--output-dir', type=pathlib.Path, default=pathlib.Path('.'),
                        help='folder for left.yaml and right.yaml (default: .)')
    parser.add_argument('--layout', choices=LAYOUTS, default='auto',
                        help='pairs: left*/right* files; side-by-side: one image per pair, '
                        'left camera in the left half; auto (default): pairs if any '
                        'left*/right* image exists')
    parser.add_argument('--camera-name', default='stereo',
                        help='name of the pair or vehicle id; the files get NAME/left and '
                        'NAME/right (default: stereo)')
    parser.add_argument('--opencv-file', type=pathlib.Path,
                        help='also write an OpenCV FileStorage file (.yaml, .yml, .xml, '
                        '.json): K1, D1, K2, D2, R, T, R1, R2, P1, P2')
    parser.add_argument('--radial-coefficients', type=int, choices=(2, 3, 6), default=3,
                        help='3: k1, k2, k3 (default); 2: k3 = 0 (ROS camera_calibration '
                        'default); 6: rational k1..k6')
    parser.add_argument('--zero-tangential', action='store_true',
                        help='hold the tangential distortion p1, p2 at 0')
    parser.add_argument('--alpha', type=float, default=0.0,
                        help='stereoRectify free scaling: 0 valid pixels only (default, as '
                        'ROS), 1 all source pixels')
    parser.add_argument('--min-pairs', type=int, default=5,
                        help='fewest pairs with the board in both images (default 5)')
    parser.add_argument('-v', '--verbose', action='store_true',
                        help='report the board detection of every pair')
    return parser


def _camera_line(label, camera, rms, views):
    K, D = camera.K, camera.D
    return (f'{label}: fx {K[0, 0]:.2f} fy {K[1, 1]:.2f} cx {K[0, 2]:.2f} cy {K[1, 2]:.2f} '
            f'px, D [{", ".join(f"{v:.5f}" for v in D)}], RMS {rms:.3f} px over {views} '
            'images')


def run(args, out=None):
    """Calibrate as the parsed ``args`` say, report to ``out`` (default stdout); raises
    InputError on unusable input.
    """
    options = CalibrationOptions(args.size, args.square, args.radial_coefficients,
                                 args.zero_tangential, args.alpha, args.min_pairs,
                                 args.camera_name)
    pairs = find_image_pairs(args.images, args.layout)
    detections, size = detect_boards(pairs, options.pattern_size)
    result = calibrate(detections, size, options)
    calibration = result.calibration
    args.output_dir.mkdir(parents=True, exist_ok=True)
    left_path, right_path = args.output_dir / 'left.yaml', args.output_dir / 'right.yaml'
    save_ros_stereo(calibration, left_path, right_path)
    written = [left_path, right_path]
    if args.opencv_file is not None:
        save_opencv_stereo(calibration, args.opencv_file)
        written.append(args.opencv_file)
    skipped = [d.name + (' (no board in either image)' if d.left is None and d.right is None
                         else ' (no board in the left image)' if d.left is None
                         else ' (no board in the right image)')
               for d in detections if d.left is None or d.right is None]
    cols, rows = options.pattern_size
    angle = np.degrees(np.arccos(np.clip((np.trace(result.R) - 1.0) / 2.0, -1.0, 1.0)))
    lines = [f'{PROG}: {len(pairs)} image pairs in {args.images}, {size[0]}x{size[1]} px per '
             f'camera, board {cols}x{rows} inner corners of {options.square_m:g} m',
             f'board found: left {result.left_views}, right {result.right_views}, both '
             f'{result.pairs} (the pairs used for the stereo calibration)']
    lines += [f'  skipped for the stereo calibration: {name}' for name in skipped]
    lines += [_camera_line('left camera ', calibration.left, calibration.left_rms_px,
                           result.left_views),
              _camera_line('right camera', calibration.right, calibration.right_rms_px,
                           result.right_views),
              f'stereo: baseline {calibration.baseline_m:.4f} m, right camera turned '
              f'{angle:.3f} deg, RMS {calibration.rms_px:.3f} px over {result.pairs} pairs',
              f'rectified: fx\' {calibration.left.fx:.2f} px (alpha {options.alpha:g})',
              'wrote ' + ', '.join(map(str, written))]
    worst = max(calibration.rms_px, calibration.left_rms_px, calibration.right_rms_px)
    if worst > 1.0:
        lines.append(f'warning: a reprojection RMS of {worst:.2f} px is large for a '
                     'checkerboard (typically < 0.5 px): check --size, --square, focus and '
                     'motion blur')
    print('\n'.join(lines), file=out or sys.stdout)
    return result


def main(argv=None):
    parser = build_parser()
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.INFO if args.verbose else logging.WARNING,
                        format='%(message)s')
    try:
        run(args)
    except InputError as exc:
        print(f'{PROG}: error: {exc}', file=sys.stderr)
        return 2
    return 0


if __name__ == '__main__':
    sys.exit(main())
