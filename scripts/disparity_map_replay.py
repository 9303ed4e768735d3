"""The learnt disparity map (train_localizer core/disparity_map.py) on recorded bags.

Replays recorded realistic-profile bags through the localizer core (``localizer_replay``
with each bag's belief files), grouped by drawn installation (the bag's
``.installation/truth/truth.yaml``): per installation its dynamic bags one after the
other, each reading and then writing one kept disparity map as the node does, then its
static bags reading that map (a standing train learns nothing: one lamp pass). Round 0
starts from no map: the installation's first dynamic bag is a first pass (what a run
learns of itself), the next reads what it kept, the static trials what both kept; each
further round reads what the rounds before kept. A row with the map off is the baseline. Prints a
Markdown table: per round, dynamic max / mean per speed (every pose after 3 s), the
static results (the last pose of each trial), poses within 3σ, over all installations.

    python scripts/disparity_map_replay.py BAG... [--rounds 3] [--param NAME:=VALUE]...

Bags: ``run_evaluation --protocol dynamic --rig-profile realistic --speeds 40 100
--runs 3`` and ``--protocol static --trials 3 --rig-profile realistic`` (the same seeds
are the same installations).
"""
import argparse
import collections
import pathlib
import tempfile

import numpy as np
import yaml

from train_localizer.core.disparity_map_file import save_disparity_map
from train_localizer.node_parameters import load_mount
from vlc_evaluation import localizer_replay as lr


def installation(bag):
    return (bag.parent / (bag.name + '.installation') / 'truth' / 'truth.yaml').read_text()


def replay(bag, path, use, params=None):
    """(result, published σ of the last pose); writes what a dynamic run learnt."""
    res = lr.replay_with_belief(bag, {**(params or {}), 'use_disparity_map': use,
                                      'disparity_map_path': str(path) if use else ''})
    dm = res.localizer.disparity_map
    if use and 'static' not in bag.name and dm is not None and dm.run:
        g = res.localizer.config.geometry
        vehicle = load_mount(lr.load_params(None, {
            'vehicle_path': str(bag.parent / (bag.name + '.installation/belief/vehicle.yaml'))}))
        save_disparity_map(path, dm.cells(), vehicle.vehicle_id, g.fx * g.baseline_m,
                           dm.config.cell_px, res.localizer.config.disparity_map_runs + 1)
    return res


def score(bag, res, out):
    if res.pose_t.size == 0:
        out['misses'] += 1
        return
    if 'static' in bag.name:
        err = abs(res.pose_xyz[-1, 0] - float(np.median(res.truth_xyz[:, 0])))
        out['static'].append(err)
        out['inside'].append(err <= 3.0 * np.sqrt(res.pose_var[-1]))
        return
    s = lr.score(res, 3.0)
    speed = bag.name.split('_')[1]
    out[speed].append((s['error']['max_m'], s['error']['mean_m']))
    out['dyn_inside'].append(s['along_track_3sigma_fraction'])


def cells(values):
    a = np.array(values, float).reshape(len(values), -1)
    return '–' if a.size == 0 else f'{100 * a[:, 0].max():.2f} / {100 * a[:, -1].mean():.2f}'


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    parser.add_argument('bags', nargs='+', type=pathlib.Path)
    parser.add_argument('--rounds', type=int, default=3)
    parser.add_argument('--param', action='append', default=[], metavar='NAME:=VALUE',
                        help='a localizer parameter for every replay (YAML value), e.g. '
                             'systematic_weight_inflation:=1.0')
    args = parser.parse_args(argv)
    params = {}
    for item in args.param:
        name, sep, value = item.partition(':=')
        if not sep:
            parser.error(f'--param {item!r}: expected NAME:=VALUE')
        params[name] = yaml.safe_load(value)
    groups = collections.defaultdict(list)
    for bag in args.bags:
        groups[installation(bag)].append(bag)
    tmp = pathlib.Path(tempfile.mkdtemp())
    speeds = sorted({b.name.split('_')[1] for b in args.bags if 'dynamic' in b.name})
    print('| map | ' + ' | '.join(f'{v} max / mean (cm)' for v in speeds)
          + ' | static max / mean (cm) | dynamic poses within 3σ | static within 3σ | misses |')
    print('|---|' + '---|' * (len(speeds) + 4))
    for use, rounds in ((False, 1), (True, args.rounds)):
        paths = {key: tmp / f'map{i}.yaml' for i, key in enumerate(groups)}
        for r in range(rounds):
            out = collections.defaultdict(list, misses=0)
            for key, bags in groups.items():
                order = sorted(bags, key=lambda b: ('static' in b.name, b.name))
                for bag in order:
                    score(bag, replay(bag, paths[key], use, params), out)
            name = 'off' if not use else (f'learnt, round {r}'
                                          + (' (from no map)' if r == 0 else ''))
            print(f'| {name} | ' + ' | '.join(cells(out[v]) for v in speeds)
                  + f' | {cells(out["static"])} | {100 * np.mean(out["dyn_inside"]):.1f} % | '
                  f'{100 * np.mean(out["inside"]):.1f} % | {out["misses"]} |', flush=True)
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
