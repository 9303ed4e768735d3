"""``lamp_map_from_csv``: a surveyed lamp list (CSV) → the lamp map YAML of the receivers.

Usage::

    lamp_map_from_csv SURVEY.csv -o lamp_map.yaml [--alignment straight|curved_demo]
                      [--lateral-m 2.5] [--height-m 1.4] [--diameter-m 0.2]
                      [--frame-id map] [--any-lamp-id-order] [--chainage-tolerance-m 0.5]

The CSV columns and checks: ``vlc_common.core.lamp_survey``. Exit status 0 on success,
2 with ``<file>: row <n>, column <c>: <problem>`` on stderr for an unusable survey.
"""
import argparse
import pathlib
import sys

import numpy as np

from vlc_common.core.alignment import NAMED_ALIGNMENTS
from vlc_common.core.lamp_survey import LampSurveyError, SurveyDefaults, read_lamp_csv

PROG = 'lamp_map_from_csv'


def build_parser():
    defaults = SurveyDefaults()
    parser = argparse.ArgumentParser(
        prog=PROG, description='Surveyed lamp list (CSV with a header row) to the lamp map '
        'YAML that the camera and the receivers load (lamp_map_path parameter).')
    parser.add_argument('csv', type=pathlib.Path, help='the survey, one lamp per row')
    parser.add_argument('-o', '--output', type=pathlib.Path, required=True,
                        help='lamp map YAML to write')
    parser.add_argument('--alignment', choices=sorted(NAMED_ALIGNMENTS), default='straight',
                        help='the line\'s track alignment, for chainage positions (default '
                        'straight: chainage = map x)')
    parser.add_argument('--lateral-m', type=float, default=defaults.lateral_m,
                        help='lateral offset left of the centreline where the survey has no '
                        f'lateral_m, m (default {defaults.lateral_m})')
    parser.add_argument('--height-m', type=float, default=defaults.height_m,
                        help='height above rail level where the survey has no height_m, m '
                        f'(default {defaults.height_m})')
    parser.add_argument('--diameter-m', type=float, default=defaults.diameter_m,
                        help=f'lamp disc diameter where the survey has none, m (default '
                        f'{defaults.diameter_m})')
    parser.add_argument('--frame-id', default='map', help='frame of the positions')
    parser.add_argument('--any-lamp-id-order', action='store_true',
                        help='allow lamp ids that do not increase along the line')
    parser.add_argument('--chainage-tolerance-m', type=float, default=0.5,
                        help='largest difference between a chainage_m column and the '
                        'chainage of x_m, y_m on the alignment, m (default 0.5)')
    return parser


def main(argv=None):
    args = build_parser().parse_args(argv)
    try:
        lamp_map = read_lamp_csv(args.csv, args.alignment,
                                 SurveyDefaults(args.lateral_m, args.height_m, args.diameter_m),
                                 args.frame_id, not args.any_lamp_id_order,
                                 args.chainage_tolerance_m)
    except LampSurveyError as exc:
        print(f'{PROG}: error: {exc}', file=sys.stderr)
        return 2
    try:
        lamp_map.save(args.output, header=(
            f'Lamp map from the survey {args.csv.name} (lamp_map_from_csv, alignment '
            f'{args.alignment}): UID -> lamp disc centre in the map frame (m),\n'
            'disc normal (unit, into the tunnel), diameter, chainage and the survey 1 sigma '
            'per map axis (m).'))
    except OSError as exc:
        print(f'{PROG}: error: {args.output}: cannot be written ({exc})', file=sys.stderr)
        return 2
    lines = sorted({lamp.line_id for lamp in lamp_map.lamps})
    known = int(sum(lamp.has_position_sigma for lamp in lamp_map.lamps))
    print(f'{PROG}: {len(lamp_map)} lamps of line{"s" if len(lines) > 1 else ""} '
          f'{", ".join(map(str, lines))}, chainage {np.min(lamp_map.chainages):.3f} … '
          f'{np.max(lamp_map.chainages):.3f} m on alignment {args.alignment}; survey 1σ known '
          f'for {known} of them; wrote {args.output}')
    return 0


if __name__ == '__main__':
    sys.exit(main())
