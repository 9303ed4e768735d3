"""``make_installation``: draw a rig installation and write its belief and truth files.

::

    make_installation --profile realistic --seed 7 --out DIR [--alignment straight]
                      [--vehicle FILE] [--lamp-map FILE] [--profiles-file FILE]

writes ``DIR/belief/{left,right,vehicle,lamp_map}.yaml`` (what a real installation hands
the receivers: the stereo calibration in camera_info_manager YAML, the vehicle mount as
measured, the surveyed lamp map) and ``DIR/truth/{truth,vehicle,lamp_map,left,right}.yaml``
(every drawn value; for the evaluation only). The draw is the one ``stereo_camera_node``
and ``adis16488_node`` make with the same ``rig_profile``, ``seed``, vehicle file, lamp
map and the camera defaults of ``config/stereo_camera_node.yaml`` (the camera options
below, if the node's were changed). Exit status 0; 2 with ``make_installation: error:
<file>: <field>: <problem>`` for an unknown profile or a file that does not parse.
"""
import argparse
import sys

from vlc_common.core.lamp_map import LampMap, resolve_lamp_map_path
from vlc_common.core.vehicle import VehicleFileError, load_vehicle
from vlc_stereo_camera.core.installation import (
    NominalCamera,
    ProfileError,
    draw_installation,
    load_profile,
)


def parse_args(argv):
    d = NominalCamera()
    p = argparse.ArgumentParser(prog='make_installation', description=__doc__.split('\n')[0])
    p.add_argument('--profile', required=True, help='rig profile (ideal, realistic, harsh)')
    p.add_argument('--seed', type=int, default=1, help='scenario seed (default 1)')
    p.add_argument('--out', required=True, help='output folder (belief/ and truth/)')
    p.add_argument('--alignment', default='straight', help='alignment of the default lamp map')
    p.add_argument('--vehicle', default='', help="nominal vehicle file ('' = shipped)")
    p.add_argument('--lamp-map', default='', help="nominal lamp map ('' = the alignment's)")
    p.add_argument('--profiles-file', default='', help="profiles YAML ('' = shipped)")
    for name in ('width', 'height'):
        p.add_argument(f'--{name}', type=int, default=getattr(d, name), help='image size, px')
    for name in ('fx', 'fy', 'cx', 'cy'):
        p.add_argument(f'--{name}', type=float, default=getattr(d, name), help='nominal, px')
    p.add_argument('--baseline-m', type=float, default=d.baseline_m)
    p.add_argument('--row-time-s', type=float, default=d.row_time_s)
    return p.parse_args(argv)


def main(argv=None):
    args = parse_args(sys.argv[1:] if argv is None else argv)
    try:
        profile = load_profile(args.profile, args.profiles_file)
        vehicle = load_vehicle(args.vehicle)
        map_path = resolve_lamp_map_path(args.lamp_map, args.alignment)
        try:
            lamp_map = LampMap.load(map_path)
        except (OSError, ValueError, KeyError, TypeError) as exc:
            raise ValueError(f'{map_path}: (file): not a usable lamp map ({exc})') from None
        nominal = NominalCamera(width=args.width, height=args.height, fx=args.fx, fy=args.fy,
                                cx=args.cx, cy=args.cy, baseline_m=args.baseline_m,
                                row_time_s=args.row_time_s)
        inst = draw_installation(profile, args.seed, vehicle, lamp_map, nominal)
        paths = inst.write(args.out)
    except (ProfileError, VehicleFileError, ValueError) as exc:
        print(f'make_installation: error: {exc}', file=sys.stderr)
        return 2
    truth = inst.truth_dict()
    print(f'rig profile {profile.name}, seed {args.seed} ({profile.source})')
    if not profile.ideal:
        print(f'calibration: stated RMS {inst.calibration.rms_px:g} px, baseline '
              f'{inst.calibration.baseline_m * 1e3:.3f} mm (true '
              f'{inst.optics.right_position_m[0] * 1e3:.3f} mm)')
        print(f'IMU clock offset {inst.imu_clock_offset_s * 1e3:+.3f} ms, trigger skew '
              f'{inst.optics.trigger_skew_s * 1e6:.1f} us, dead lamps {truth["dead_lamps"]}, '
              f'gross survey errors {truth["gross_survey_errors"]}')
    for name, path in paths.items():
        print(f'wrote {name}: {path}')
    return 0


if __name__ == '__main__':
    sys.exit(main())
