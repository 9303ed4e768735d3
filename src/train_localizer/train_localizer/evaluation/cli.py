"""``run_evaluation``: runs the graph on the evaluation protocols and writes the report.

Examples::

    run_evaluation --protocol demo                 # make demo: a short default scenario
    run_evaluation --protocol full --out out/eval  # 20 points x 10 trials, 6 speeds x 10 runs
    run_evaluation --protocol dynamic --speeds 100 120 --runs 2
    run_evaluation --protocol full --lanes 2 --rescore --out out/eval   # score again
    run_evaluation --protocol companions --lanes 1 --out out/companions   # issue 7
    run_evaluation --protocol none --forged --out out/forged
"""
import argparse
import logging
import os
import pathlib
import sys
import time

from vlc_stereo_camera.core.lamp_map import LampMap, default_lamp_map_path

from . import ablations, companions, report, scenarios
from .graph_runner import SPAWN_MODES


def _progress(done, total, name, started):
    """A one-line progress bar on stderr (``started``: time.monotonic() at the start)."""
    elapsed = time.monotonic() - started
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
    for scenario in static + dynamic:
        scenario.realtime_factor = args.realtime_factor
    return static, dynamic


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--protocol',
                        choices=['demo', 'static', 'dynamic', 'full', 'companions', 'none'],
                        default='demo', help='none: only what the options below add; '
                        'companions: --companions --outage --forged')
    parser.add_argument('--out', default='out/evaluation', help='bags, logs and report')
    parser.add_argument('--trials', type=int, default=10, help='static trials per point')
    parser.add_argument('--observe-s', type=float, default=3.0,
                        help='static: simulated seconds observed before the result')
    parser.add_argument('--speeds', type=int, nargs='+', default=[20, 40, 60, 80, 100, 120])
    parser.add_argument('--runs', type=int, default=10, help='dynamic runs per speed')
    parser.add_argument('--cells', type=int, default=6, help='dynamic: lamp cells per run')
    parser.add_argument('--lamp-map', default='', help="lamp map ('' = the rig's default)")
    parser.add_argument('--lanes', type=int, default=2,
                        help='scenarios run in parallel, each on a DDS domain of its own')
    parser.add_argument('--spawn', choices=SPAWN_MODES, default='fork',
                        help='fork: nodes forked from a preloaded fork server; exec: each '
                             'node a new interpreter (as ros2 run)')
    parser.add_argument('--realtime-factor', type=float, default=1.0,
                        help='simulated seconds per wall second of every scenario (the '
                             'highest: a lane slows down while nodes fall behind)')
    parser.add_argument('--retries', type=int, default=1,
                        help='runs again, slower, a scenario in which a node fell behind')
    parser.add_argument('--replay-bag', action='append', default=[],
                        help='also replay this sensor bag (e.g. bags/sample_80kmh) through the '
                             'processing nodes with bag_player and score it (repeatable)')
    parser.add_argument('--ablations', action='store_true',
                        help='also run the reduced static + dynamic set once per ablation '
                             'variant (evaluation/ablations.py) and add their table')
    parser.add_argument('--ablation-trials', type=int, default=2,
                        help='ablations: static trials per point')
    parser.add_argument('--ablation-runs', type=int, default=2,
                        help='ablations: dynamic runs per speed')
    parser.add_argument('--companions', action='store_true',
                        help='also run every positioning method (companion nodes and the '
                             'photodiode beside the graph) on static and dynamic scenarios, '
                             'straight and curved, and add their table (evaluation/companions.py)')
    parser.add_argument('--companion-speeds', type=int, nargs='+',
                        default=list(companions.SPEEDS_KMH), help='companions: straight speeds')
    parser.add_argument('--companion-points', type=float, nargs='+',
                        default=list(companions.STATIC_POINTS_M),
                        help='companions: static points (m before the lamp; the first two '
                             'also on the curve)')
    parser.add_argument('--companion-curved-s', type=float, default=companions.CURVED_DURATION_S,
                        help='companions: simulated seconds of the curved dynamic run (0: no '
                             'curved scenarios)')
    parser.add_argument('--outage', action='store_true',
                        help='also run the lamp-outage scenario (every second lamp dark for '
                             '200 m, then none for 500 m) and add its table')
    parser.add_argument('--outage-speed', type=float, default=companions.OUTAGE_SPEED_KMH)
    parser.add_argument('--forged', action='store_true',
                        help='also run the forged-lamp pair (clean, forged) and add its table')
    parser.add_argument('--forged-speed', type=float, default=companions.FORGED_SPEED_KMH)
    parser.add_argument('--companions-docs', nargs='+', default=[],
                        help='also write the companion, outage and forged-lamp tables between '
                             'the companions markers of these Markdown files')
    parser.add_argument('--rescore', action='store_true',
                        help='do not run the graph: score the bags already in --out again')
    parser.add_argument('--readme', default='',
                        help='also write the report between the evaluation markers of this '
                             'Markdown file (figures copied beside it under docs/evaluation)')
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format='%(levelname)s %(name)s: %(message)s')
    out = pathlib.Path(args.out)
    lamp_map = LampMap.load(args.lamp_map or default_lamp_map_path())
    static, dynamic = build_scenarios(args)
    groups = {'static': static, 'dynamic': dynamic}
    if args.replay_bag:
        groups['replay'] = [scenarios.replay_scenario(bag, args.realtime_factor)
                            for bag in args.replay_bag]
    if args.protocol == 'companions':
        args.companions = args.outage = args.forged = True
    kinds = {}
    if args.companions:
        kinds['companions'] = companions.companion_scenarios(
            points_m=tuple(args.companion_points), speeds_kmh=tuple(args.companion_speeds),
            observe_s=args.observe_s, curved_duration_s=args.companion_curved_s,
            curved=args.companion_curved_s > 0)
    if args.outage:
        kinds['outage'] = [companions.outage_scenario(out / 'outage', args.outage_speed)]
    if args.forged:
        kinds['forged'] = companions.forged_scenarios(out / 'forged', args.forged_speed)
    for group in kinds.values():
        for scenario in group:
            scenario.realtime_factor = args.realtime_factor
    groups.update(kinds)
    if args.ablations:
        groups.update(ablations.ablation_groups(
            trials=args.ablation_trials, runs=args.ablation_runs, observe_s=args.observe_s,
            realtime_factor=args.realtime_factor))
    total = sum(len(g) for g in groups.values())
    started = time.monotonic()

    def progress(done, _, name):
        _progress(done, total, name, started)

    try:
        results = scenarios.run_protocols(groups, out, lamp_map, lanes=args.lanes,
                                          spawn=args.spawn, progress=progress,
                                          rescore=args.rescore, retries=args.retries)
    except KeyboardInterrupt:
        print('\ninterrupted: the running scenarios were stopped', file=sys.stderr)
        sys.stderr.flush()
        sys.stdout.flush()
        # Every node is stopped; skip the interpreter's teardown, in which rclpy's
        # C++ signal-handler thread aborts after an interrupt.
        os._exit(130)
    static_results, dynamic_results = results['static'], results['dynamic']
    ablation = None
    if args.ablations:
        table, figures = ablations.ablation_table(results)
        ablations.plot_ablations(figures, out / 'ablations.png')
        ablation = (table, figures)
    text = report.write_report(static_results, dynamic_results, out,
                               title=(f'Accuracy ({args.protocol} protocol)'
                                      if args.protocol not in ('none', 'companions')
                                      else 'Evaluation'),
                               ablations=ablation, replays=results.get('replay'))
    if kinds:
        added = companions.append_to_report(out, results.get('companions', ()),
                                            results.get('outage', ()), results.get('forged', ()))
        text += added
        command = 'run_evaluation ' + ' '.join(argv if argv is not None else sys.argv[1:])
        for path in args.companions_docs:
            companions.update_docs(path, added, command)
            print(f'{path}: companions section rewritten')
    print(text)
    print(f'report: {out / "report.md"}, figures: {out / "report.json"}')
    if args.readme:
        command = 'run_evaluation ' + ' '.join(argv if argv is not None else sys.argv[1:])
        report.update_markdown(pathlib.Path(args.readme), out, command)
        print(f'{args.readme}: evaluation section rewritten')
    wall = time.monotonic() - started
    how = 'rescored' if args.rescore else f'on {args.lanes} lane(s)'
    print(f'{total} scenarios {how}: total wall time {wall:.0f} s ({wall / 60:.1f} min)')
    return 0


if __name__ == '__main__':
    sys.exit(main())
