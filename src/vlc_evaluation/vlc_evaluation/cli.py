"""``run_evaluation``: runs the graph on the evaluation protocols and writes the report.

Examples::

    run_evaluation --protocol demo                 # make demo: a short default scenario
    run_evaluation --protocol full --out out/eval  # 20 points x 10 trials, 6 speeds x 10 runs
    run_evaluation --protocol dynamic --speeds 100 120 --runs 2
    run_evaluation --protocol full --lanes 2 --rescore --out out/eval   # score again
    run_evaluation --protocol companions --lanes 1 --out out/companions   # other methods
    run_evaluation --protocol none --forged --out out/forged
    run_evaluation --protocol none --latency --out out/latency       # replay latency
    run_evaluation --protocol none --budget --out out/budget         # error budget
    run_evaluation --protocol none --passes 10 --out out/passes      # multi-pass
"""
import argparse
import itertools
import json
import logging
import os
import pathlib
import sys
import time

from vlc_common.core.lamp_map import LampMap, default_lamp_map_path
from vlc_evaluation import (
    ablations,
    budget,
    companions,
    departures,
    faults,
    passes,
    report,
    runner,
    scenarios,
)
from vlc_evaluation.graph_runner import SPAWN_MODES
from vlc_evaluation.sample_bag import record_sample_bag, sample_scenario


def _progress(done, total, name, started):
    """A one-line progress bar on stderr (``started``: time.monotonic() at the start)."""
    elapsed = time.monotonic() - started
    width = 30
    total = max(total, done, 1)
    filled = int(width * done / total)
    eta = elapsed / max(done, 1) * (total - done)
    sys.stderr.write(f'\r[{"#" * filled}{"." * (width - filled)}] {done}/{total} '
                     f'{name:<28} {elapsed:5.0f} s elapsed, ~{eta:4.0f} s left')
    if done == total:
        sys.stderr.write('\n')
    sys.stderr.flush()


# Latency bags: 8 s of sensors (240 stereo frames, 3200 IMU samples) per speed, of the
# ideal rig and of one drawn installation of the realistic profile (raw, distorted images
# of a wider field: about twice the lamp spots per frame, the receivers' case with a real
# camera); the realistic bags are named realistic_sensors_<speed>kmh.
LATENCY_SPEEDS_KMH = (60, 120)
LATENCY_PROFILES = ('ideal', 'realistic')
LATENCY_INSTALLATION_SEED = 1
LIVE_GROUP = 'latency/live'
LATENCY_BAG_S = 8.0


# The live graph alone at real time (rig, processing nodes and recorder; nothing else on
# the machine): the same speeds, two seeds each, the dynamic protocol's run length.
LIVE_LATENCY_RUNS = 2


def live_latency_scenarios():
    """Dynamic scenarios whose latency is measured with the whole live graph alone on
    the machine, at real time (a fresh lane each, never rerun slower).
    """
    return scenarios.dynamic_scenarios(speeds_kmh=LATENCY_SPEEDS_KMH, runs=LIVE_LATENCY_RUNS)


def latency_replays(out, rescore=False):
    """Replay scenarios at real-time factor 1 of the latency sensor bags (each speed, the
    ideal rig and installation LATENCY_INSTALLATION_SEED of each drawn profile of
    LATENCY_PROFILES), recording the bags first (rig and recorder only, slowed to 0.3 so
    no frame is lost) where missing, or with ``rescore`` leaving a missing one out; a lean
    recording (no 400 Hz IMU topics).
    """
    replays = []
    for profile, speed in itertools.product(LATENCY_PROFILES, LATENCY_SPEEDS_KMH):
        prefix = '' if profile == 'ideal' else f'{profile}_'
        bag = out / 'latency_bags' / f'{prefix}sensors_{speed:03d}kmh'
        if not (bag / 'metadata.yaml').exists() and rescore:
            continue            # an output folder from before this bag was recorded
        if not (bag / 'metadata.yaml').exists():
            # uncompressed: the player would otherwise decompress a zstd chunk of several
            # frames at once, a CPU burst on the cores the measured nodes share
            recording = sample_scenario(bag.name, float(speed), duration_s=LATENCY_BAG_S,
                                        realtime_factor=0.3, compression='none',
                                        seed=LATENCY_INSTALLATION_SEED)
            recording.rig_profile = profile
            for problem in record_sample_bag(bag, recording):
                logging.getLogger(__name__).warning('%s: %s', bag, problem)
        # (a drawn installation's bag says so: the receivers get its belief)
        replays.append(scenarios.replay_scenario(bag, 1.0, lean_recording=True))
    return replays


def build_scenarios(args, geometry=None):
    """The static and dynamic scenarios of ``args.protocol``, placed on the lamps of
    ``geometry`` (:func:`.scenarios.protocol_geometry`; None: the shipped map's).
    """
    static, dynamic = [], []
    at_static, at_dynamic = scenarios.placement(geometry)
    if args.protocol == 'demo':
        static = scenarios.static_scenarios(points_m=(9.0, 5.0, 2.0), trials=1,
                                            observe_s=args.observe_s,
                                            first_seed=args.first_seed, **at_static)
        dynamic = scenarios.dynamic_scenarios(speeds_kmh=(60,), runs=1, cells=4,
                                              first_seed=args.first_seed, **at_dynamic)
    if args.protocol in ('static', 'full'):
        static = scenarios.static_scenarios(trials=args.trials, observe_s=args.observe_s,
                                            first_seed=args.first_seed, **at_static)
    if args.protocol in ('dynamic', 'full'):
        dynamic = scenarios.dynamic_scenarios(speeds_kmh=tuple(args.speeds), runs=args.runs,
                                              cells=args.cells, first_seed=args.first_seed,
                                              **at_dynamic)
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
    parser.add_argument('--observe-s', type=float, default=scenarios.STATIC_OBSERVE_S,
                        help='static: simulated seconds observed before the result')
    parser.add_argument('--speeds', type=int, nargs='+', default=[20, 40, 60, 80, 100, 120])
    parser.add_argument('--runs', type=int, default=10, help='dynamic runs per speed')
    parser.add_argument('--cells', type=int, default=6, help='dynamic: lamp cells per run')
    parser.add_argument('--first-seed', type=int, default=1,
                        help='seed of the first static trial and dynamic run (the others '
                             'follow: first, first + 1, ...); e.g. --protocol demo '
                             '--first-seed 2 runs the demo on seed 2')
    parser.add_argument('--lamp-map', default='',
                        help="lamp map ('' = the rig's default): the rig renders it, the "
                             'receivers are given it (or its survey, on a drawn rig profile), '
                             'the protocols stand and start at its lamps and score against it')
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
    parser.add_argument('--fixed-pace', action='store_true',
                        help='no lane ever slows down: every run at --realtime-factor (one '
                             'lane) or half of it (several), degraded or not; with --lanes 1 '
                             '--retries 0 the live graph\'s real-time benchmark')
    parser.add_argument('--lockstep', action='store_true',
                        help='run the scenarios that allow it (no replay, fault or '
                             'injected topic) in one process each on simulated time '
                             '(vlc_evaluation.lockstep): the same nodes and bags, no DDS, '
                             'no pacing')
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
    parser.add_argument('--outage-speed', type=float, default=companions.OUTAGE_SPEED_KMH,
                        help='outage: speed of the straight-track outage run, km/h; 0: no '
                             'straight run')
    parser.add_argument('--outage-curved-speed', type=float,
                        default=companions.CURVED_OUTAGE_SPEED_KMH,
                        help='outage: speed of the curved_demo outage run with curvature_node '
                             '(the re-acquisition aid), km/h; 0: no curved run')
    parser.add_argument('--forged', action='store_true',
                        help='also run the forged-lamp pair (clean, forged) and add its table')
    parser.add_argument('--forged-speed', type=float, default=companions.FORGED_SPEED_KMH)
    parser.add_argument('--companions-docs', nargs='+', default=[],
                        help='also write the companion, outage and forged-lamp tables between '
                             'the companions markers of these Markdown files')
    parser.add_argument('--latency', action='store_true',
                        help='also measure latency as on the train: record sensor bags at '
                             f'{"/".join(map(str, LATENCY_SPEEDS_KMH))} km/h (kept in '
                             'OUT/latency_bags), then replay each at real-time factor 1 '
                             'through the processing nodes, one at a time, after everything '
                             'else (the rig\'s renderer is not on the cores); and run the '
                             f'whole live graph alone at real time, {LIVE_LATENCY_RUNS} runs '
                             'per speed (OUT/latency/live/<run>)')
    parser.add_argument('--faults', action='store_true',
                        help='also run the fault protocol (evaluation/faults.py: CPU overload, '
                             'dropouts, stalls, killed nodes, clock steps, malformed input), '
                             'one fault per run, alone on the machine, after everything else')
    parser.add_argument('--fault-names', nargs='+', default=[],
                        help='faults: only these rows (names in faults.FAULTS)')
    parser.add_argument('--fault-speed', type=float, default=faults.FAULT_SPEED_KMH,
                        help='faults: train speed, km/h')
    parser.add_argument('--faults-docs', nargs='+', default=[],
                        help='faults: also write the fault table between the faults markers '
                             'of these Markdown files')
    parser.add_argument('--rig-profile', default='ideal',
                        help='rig profile of every rig scenario (ideal, realistic, harsh; '
                             'config/rig_profiles.yaml): a drawn installation per seed, '
                             'written beside each bag')
    parser.add_argument('--calibration', choices=('drawn', 'checkerboard', 'uncorrected'),
                        default='drawn',
                        help="a drawn profile's belief calibration: drawn (the truth "
                             'perturbed by a calibration\'s errors), checkerboard (an '
                             'actual calibration of the true lenses, ~10 s per scenario) or '
                             'uncorrected (drawn, distortion and rectification dropped: the '
                             'receivers take the raw images as rectified)')
    parser.add_argument('--profile-docs', nargs='+', default=[],
                        help='a drawn --rig-profile: also write its summary beside the main '
                             "evaluation's (docs/evaluation/report.json) and the paper's "
                             'between the profiles markers of these Markdown files')
    parser.add_argument('--budget', action='store_true',
                        help='also run the error budget (evaluation/budget.py): the reduced '
                             'static + dynamic set once with every error source of '
                             '--budget-profile off, once per source alone, once with all')
    parser.add_argument('--budget-profile', default='realistic',
                        help='budget: the drawn rig profile whose sources are isolated')
    parser.add_argument('--budget-trials', type=int, default=2,
                        help='budget: static trials per point (seeds first-seed, ...)')
    parser.add_argument('--budget-runs', type=int, default=2, help='budget: dynamic runs per '
                        'speed')
    parser.add_argument('--budget-docs', nargs='+', default=[],
                        help='budget: also write its table between the budget markers of '
                             'these Markdown files')
    parser.add_argument('--departures', type=int, default=0, metavar='N',
                        help='also run the departure protocol (evaluation/departures.py): '
                             'stand, pull away, cruise, brake, stand, on N seeds from '
                             '--first-seed, with the defaults and with the zero-velocity gate '
                             'off')
    parser.add_argument('--departures-profile', default='realistic',
                        help='departures: the rig profile')
    parser.add_argument('--departures-docs', nargs='+', default=[],
                        help='departures: also write its table between the departures '
                             'markers of these Markdown files')
    parser.add_argument('--passes', type=int, default=0,
                        help='also run the multi-pass protocol (evaluation/passes.py): this '
                             'many learning passes per train, scored runs at the checkpoints')
    parser.add_argument('--passes-profile', default='realistic',
                        help='multi-pass: the drawn rig profile')
    parser.add_argument('--passes-trains', type=int, nargs='+', default=[1, 2],
                        help='multi-pass: installation seeds, one train each')
    parser.add_argument('--passes-checkpoints', type=int, nargs='+',
                        default=list(passes.CHECKPOINTS),
                        help='multi-pass: passes learnt before the scored runs (0 = first pass)')
    parser.add_argument('--passes-speeds', type=int, nargs='+',
                        default=list(passes.SPEEDS_KMH),
                        help='multi-pass: the speeds of the scored dynamic runs at every '
                             'checkpoint, km/h (one run per speed)')
    parser.add_argument('--passes-end-speeds', type=int, nargs='*',
                        default=list(passes.END_SPEEDS_KMH),
                        help='multi-pass: the speeds also scored at the first pass and the '
                             'last checkpoint, km/h (none: only --passes-speeds)')
    parser.add_argument('--passes-param', action='append', default=[], metavar='NAME:=VALUE',
                        help='multi-pass: a localizer parameter for every run (YAML value), '
                             'e.g. use_self_calibration:=true')
    parser.add_argument('--passes-ablations', action='store_true',
                        help='multi-pass: at the last checkpoint also score with each of '
                             + ', '.join(d for d, *_ in passes.ABLATIONS.values()))
    parser.add_argument('--passes-docs', nargs='+', default=[],
                        help='multi-pass: also write its table between the passes markers of '
                             'these Markdown files')
    parser.add_argument('--rescore', action='store_true',
                        help='do not run the graph: score the bags already in --out again')
    parser.add_argument('--readme', default='',
                        help='also write the report between the evaluation markers of this '
                             'Markdown file (figures copied beside it under docs/evaluation)')
    args = parser.parse_args(argv)
    command = 'run_evaluation ' + ' '.join(argv if argv is not None else sys.argv[1:])
    logging.basicConfig(level=logging.INFO, format='%(levelname)s %(name)s: %(message)s')
    out = pathlib.Path(args.out)
    lamp_map = LampMap.load(args.lamp_map or default_lamp_map_path())
    if lamp_map.alignment not in ('', 'straight'):
        # the rig and the receivers would put its lamps beside the straight line
        parser.exit(2, f'run_evaluation: error: --lamp-map {args.lamp_map}: a map of the '
                       f'{lamp_map.alignment!r} alignment; the protocols run on the straight '
                       'line (the curved runs are the companions\' and the outage\'s)\n')
    try:
        geometry = scenarios.protocol_geometry(lamp_map)
    except ValueError as exc:
        parser.exit(2, f'run_evaluation: error: --lamp-map {args.lamp_map}: {exc}\n')
    static, dynamic = build_scenarios(args, geometry)
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
        kinds['outage'] = ([companions.outage_scenario(out / 'outage', args.outage_speed)]
                           if args.outage_speed > 0 else [])
        if args.outage_curved_speed > 0:
            kinds['outage'].append(companions.curved_outage_scenario(
                out / 'outage', args.outage_curved_speed))
    if args.forged:
        kinds['forged'] = companions.forged_scenarios(out / 'forged', args.forged_speed)
    for group in kinds.values():
        for scenario in group:
            scenario.realtime_factor = args.realtime_factor
    groups.update(kinds)
    if args.ablations:
        groups.update(ablations.ablation_groups(
            trials=args.ablation_trials, runs=args.ablation_runs, observe_s=args.observe_s,
            realtime_factor=args.realtime_factor, geometry=geometry))

    def check_profile(name):
        """Exit 2 naming the file and field unless ``name`` is a usable rig profile."""
        from vlc_stereo_camera.core.installation import ProfileError, load_profile
        try:
            load_profile(name)
        except ProfileError as exc:
            parser.exit(2, f'run_evaluation: error: {exc}\n')

    if args.budget:
        check_profile(f'{args.budget_profile}/none')
    if args.passes:
        check_profile(args.passes_profile)
        if args.rescore:
            parser.exit(2, 'run_evaluation: error: --passes cannot be rescored (each pass '
                           'learns from the one before)\n')
        try:
            passes_params = passes.parse_params(args.passes_param)
        except ValueError as exc:
            parser.exit(2, f'run_evaluation: error: --passes-param: {exc}\n')
    fault_scenarios = (faults.fault_scenarios(args.fault_speed, names=args.fault_names)
                       if args.faults else [])
    if args.rig_profile != 'ideal':
        check_profile(args.rig_profile)
        for name, group in list(groups.items()) + [('faults', fault_scenarios)]:
            for scenario in group if name != 'replay' else ():
                scenario.rig_profile, scenario.calibration = args.rig_profile, args.calibration
    if args.budget:
        # after --rig-profile: the budget rows keep their own profiles
        groups.update(budget.budget_groups(
            args.budget_profile, trials=args.budget_trials, runs=args.budget_runs,
            observe_s=args.observe_s, realtime_factor=args.realtime_factor,
            first_seed=args.first_seed, geometry=geometry))
    if args.departures:
        if args.departures_profile != 'ideal':
            check_profile(args.departures_profile)
        groups.update(departures.departure_groups(
            range(args.first_seed, args.first_seed + args.departures),
            args.departures_profile, realtime_factor=args.realtime_factor))
    total = sum(len(g) for g in groups.values()) + len(fault_scenarios)
    started = time.monotonic()
    # the camera nodes memoise their start-up arrays (lens maps, noise banks) here: the
    # scenarios draw the same few installations and seeds again and again (set once the
    # arguments are valid: run_evaluation is the process's main)
    os.environ.setdefault(runner.RIG_CACHE_ENV, str((out / 'rig_cache').resolve()))

    def progress(done, _, name):
        _progress(done, total, name, started)

    try:
        results = scenarios.run_protocols(groups, out, lamp_map, lanes=args.lanes,
                                          spawn=args.spawn, progress=progress,
                                          rescore=args.rescore, retries=args.retries,
                                          fixed_pace=args.fixed_pace, lockstep=args.lockstep)
        latency_results, live_alone = [], []
        protocols_s = time.monotonic() - started
        if args.latency:
            # alone on the machine, at real time: no parallel lane, no slower rerun, a
            # fresh lane each (a lane slows down after a run in which a node fell behind)
            for scenario in latency_replays(out, args.rescore):
                group = f'latency/{scenario.name}'
                latency_results += scenarios.run_protocols(
                    {group: [scenario]}, out, lamp_map, lanes=1, spawn=args.spawn,
                    rescore=args.rescore, retries=0)[group]
            # the whole live graph (rig included), alone and at real time: a run in which
            # a node fell behind is kept as it is and counted, not rerun
            for scenario in live_latency_scenarios():
                group = f'{LIVE_GROUP}/{scenario.name}'
                live_alone += scenarios.run_protocols(
                    {group: [scenario]}, out, lamp_map, lanes=1, spawn=args.spawn,
                    rescore=args.rescore, retries=0)[group]
            total += len(latency_results) + len(live_alone)
            ideal, realistic = report.replays_by_profile(latency_results)
            if ideal and not args.rescore:
                report.append_latency_run(out, command, report.latency_table(ideal)[1],
                                          protocols_s if results else 0.0,
                                          live=report.latency_table(live_alone)[1]
                                          if live_alone else None,
                                          realistic=report.latency_table(realistic)[1]
                                          if realistic else None)
        passes_results = None
        if args.passes:
            passes_results = passes.run_passes(
                out, lamp_map, trains=args.passes_trains, passes=args.passes,
                checkpoints=args.passes_checkpoints, profile=args.passes_profile,
                speeds_kmh=args.passes_speeds, end_speeds_kmh=args.passes_end_speeds,
                localizer_params=passes_params,
                lanes=args.lanes, spawn=args.spawn, retries=args.retries,
                realtime_factor=args.realtime_factor,
                ablations=tuple(passes.ABLATIONS) if args.passes_ablations else (),
                lockstep=args.lockstep)
            total += sum(len(r.get(k, ())) for t in passes_results.values()
                         for r in t.values() for k in ('static', 'dynamic')) + len(
                             passes_results) * args.passes
        fault_results = []
        if args.faults:
            # alone on the machine too: the faults bring their own load
            fault_results = scenarios.run_protocols(
                {'faults': fault_scenarios}, out, lamp_map, lanes=1, spawn=args.spawn,
                progress=progress, rescore=args.rescore, retries=0)['faults']
    except KeyboardInterrupt:
        print('\ninterrupted: the running scenarios were stopped', file=sys.stderr)
        sys.stderr.flush()
        sys.stdout.flush()
        # Every node is stopped; skip the interpreter's teardown, in which rclpy's
        # C++ signal-handler thread aborts after an interrupt.
        os._exit(130)
    replayed = list(results.get('replay') or []) + latency_results
    static_results, dynamic_results = results.get('static', []), results.get('dynamic', [])
    ablation = None
    if args.ablations:
        table, figures = ablations.ablation_table(results)
        ablations.plot_ablations(figures, out / 'ablations.png')
        ablation = (table, figures)
    text = report.write_report(static_results, dynamic_results, out,
                               title=(f'Accuracy ({args.protocol} protocol)'
                                      if args.protocol not in ('none', 'companions')
                                      else 'Evaluation'),
                               ablations=ablation, replays=replayed, live_alone=live_alone)
    if args.budget:
        table, figures = budget.budget_table(results, args.budget_profile)
        budget.plot_budget(figures, out / 'budget.png')
        added = (f'\n## Error budget (`{args.budget_profile}`, each source alone)\n\n'
                 f'{budget.describe(figures)}\n\n{table}\n\n![budget](budget.png)\n')
        with open(out / 'report.md', 'a', encoding='utf-8') as stream:
            stream.write(added)
        text += added
        for path in args.budget_docs:
            budget.update_docs(path, table, figures, command)
            print(f'{path}: budget section rewritten')
    if args.departures:
        found = {k: v for k, v in results.items() if k.startswith(departures.GROUP_PREFIX)}
        table, _ = departures.departures_table(found)
        text_d = f'{departures.describe(found, args.departures_profile)}\n\n{table}'
        added = f'\n## Departures and stops\n\n{text_d}\n'
        with open(out / 'report.md', 'a', encoding='utf-8') as stream:
            stream.write(added)
        text += added
        for path in args.departures_docs:
            departures.update_docs(path, text_d, command)
            print(f'{path}: departures section rewritten')
    if kinds:
        added = companions.append_to_report(out, results.get('companions', ()),
                                            results.get('outage', ()), results.get('forged', ()))
        text += added
        for path in args.companions_docs:
            companions.update_docs(path, added, command)
            print(f'{path}: companions section rewritten')
    if passes_results:
        table, _ = passes.passes_table(passes_results)
        described = passes.describe(passes_results, args.passes, args.passes_profile,
                                    params=passes_params)
        added = f'\n## Multi-pass (`{args.passes_profile}`)\n\n{described}\n\n{table}\n'
        with open(out / 'report.md', 'a', encoding='utf-8') as stream:
            stream.write(added)
        text += added
        for path in args.passes_docs:
            passes.update_docs(path, f'{described}\n\n{table}', command)
            print(f'{path}: passes section rewritten')
    if fault_results:
        text += faults.append_to_report(out, fault_results, args.fault_speed)
        for path in args.faults_docs:
            faults.update_docs(path, fault_results, command, args.fault_speed)
            print(f'{path}: faults section rewritten')
    print(text)
    print(f'report: {out / "report.md"}, figures: {out / "report.json"}')
    wall = time.monotonic() - started
    if not args.rescore:
        # which runs made the bags, and how long each took (the README quotes it)
        with open(out / report.RUN_LOG, 'a', encoding='utf-8') as log:
            log.write(json.dumps({'command': command, 'scenarios': total,
                                  'lanes': args.lanes, 'wall_s': round(wall, 1),
                                  'cpus': os.cpu_count(),
                                  'finished': time.strftime('%Y-%m-%d %H:%M')}) + '\n')
    for path in args.profile_docs:
        report.update_profile_docs(path, out, args.rig_profile, command)
        print(f'{path}: rig profile section rewritten')
    if args.readme:
        report.update_markdown(pathlib.Path(args.readme), out, command)
        print(f'{args.readme}: evaluation section rewritten')
    how = 'rescored' if args.rescore else f'on {args.lanes} lane(s)'
    print(f'{total} scenarios {how}: total wall time {wall:.0f} s ({wall / 60:.1f} min)')
    return 0


if __name__ == '__main__':
    sys.exit(main())
