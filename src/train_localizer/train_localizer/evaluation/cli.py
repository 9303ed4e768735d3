"""``run_evaluation``: runs the graph on the evaluation protocols and writes the report.

Examples::

    run_evaluation --protocol demo                 # make demo: a short default scenario
    run_evaluation --protocol full --out out/eval  # 20 points x 10 trials, 6 speeds x 10 runs
    run_evaluation --protocol dynamic --speeds 100 120 --runs 2
"""
import argparse
import logging
import pathlib
import sys
import time

from vlc_stereo_camera.core.lamp_map import LampMap, default_lamp_map_path

from . import report, scenarios


def _progress(done, total, name, started=[None]):  # noqa: B006 - start time memo
    started[0] = started[0] or time.monotonic()
    elapsed = time.monotonic() - started[0]
    width = 30
    filled = int(width * done / total)
    eta = elapsed / done * (total - done)
    sys.stderr.write(f'\r[{"#" * filled}{"." * (width - filled)}] {done}/{total} '
                     f'{name:<28} {elapsed:5.0f} s elapsed, ~{eta:4.0f} s left')
    if done == total:
        sys.stderr.write('\n')
    sys.stderr.flush()


def build_scenarios(args):
    static, dynamic = [], []
    if args.protocol == 'demo':
        static = scenarios.static_scenarios(points_m=(9.0, 5.0, 2.0), trials=1,
                                            observe_s=args.observe_s)
        dynamic = scenarios.dynamic_scenarios(speeds_kmh=(60,), runs=1, cells=4)
    if args.protocol in ('static', 'full'):
        static = scenarios.static_scenarios(trials=args.trials, observe_s=args.observe_s)
    if args.protocol in ('dynamic', 'full'):
        dynamic = scenarios.dynamic_scenarios(speeds_kmh=tuple(args.speeds), runs=args.runs,
                                              cells=args.cells)
    return static, dynamic


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--protocol', choices=['demo', 'static', 'dynamic', 'full'],
                        default='demo')
    parser.add_argument('--out', default='out/evaluation', help='bags, logs and report')
    parser.add_argument('--trials', type=int, default=10, help='static trials per point')
    parser.add_argument('--observe-s', type=float, default=3.0,
                        help='static: simulated seconds observed before the result')
    parser.add_argument('--speeds', type=int, nargs='+', default=[20, 40, 60, 80, 100, 120])
    parser.add_argument('--runs', type=int, default=10, help='dynamic runs per speed')
    parser.add_argument('--cells', type=int, default=6, help='dynamic: lamp cells per run')
    parser.add_argument('--lamp-map', default='', help="lamp map ('' = the rig's default)")
    parser.add_argument('--rescore', action='store_true',
                        help='do not run the graph: score the bags already in --out again')
    parser.add_argument('--readme', default='',
                        help='also write the report between the evaluation markers of this '
                             'Markdown file (figures copied beside it under docs/evaluation)')
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format='%(levelname)s %(name)s: %(message)s')
    out = pathlib.Path(args.out)
    lamp_map = LampMap.load(args.lamp_map or default_lamp_map_path())
    lamps_x = lamp_map.positions[:, 0]
    static, dynamic = build_scenarios(args)
    total = static + dynamic
    done = [0]

    def progress(_, __, name):
        done[0] += 1
        _progress(done[0], len(total), name)

    static_results = scenarios.run_protocol(static, out / 'static', lamps_x, progress,
                                            rescore=args.rescore)
    dynamic_results = scenarios.run_protocol(dynamic, out / 'dynamic', lamps_x, progress,
                                             rescore=args.rescore)
    text = report.write_report(static_results, dynamic_results, out,
                               title=f'Accuracy ({args.protocol} protocol)')
    print(text)
    print(f'report: {out / "report.md"}, figures: {out / "report.json"}')
    if args.readme:
        command = 'run_evaluation ' + ' '.join(argv if argv is not None else sys.argv[1:])
        report.update_markdown(pathlib.Path(args.readme), out, command)
        print(f'{args.readme}: evaluation section rewritten')
    return 0


if __name__ == '__main__':
    sys.exit(main())
