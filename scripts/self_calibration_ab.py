"""A/B of the localizer's self-calibration on recorded realistic-profile bags.

Replays each bag's recorded perception output (``/spots/pairs``, ``/vlc/lamps``,
``/imu/data``) through the localizer core (``localizer_replay``) with the bag's belief
files (``<bag>.installation/belief``: calibration, vehicle, surveyed map), once with
``use_self_calibration`` false and once true, and prints a Markdown table: dynamic bags
score every pose after a 3 s lead-in, static bags (``static_*``) the last pose; the
estimated disparity offset and stereo scale error with their stated 1σ.

    python scripts/self_calibration_ab.py OUT/dynamic/dynamic_* OUT/static/static_*

Bags come from ``run_evaluation --rig-profile realistic`` (any protocol).
"""
import argparse
import pathlib

import numpy as np

from vlc_evaluation import localizer_replay as lr


def replay(bag, on):
    """(ReplayResult, the Localizer) of one bag, self-calibration on or off."""
    result = lr.replay_with_belief(bag, {'use_self_calibration': on})
    return result, result.localizer


def scores(result, static):
    """(absolute along-track errors m, published σ m) of the scored poses."""
    t, x, var = result.pose_t, result.pose_xyz[:, 0], result.pose_var
    if static:
        t, x, var = t[-1:], x[-1:], var[-1:]
    else:
        keep = (t >= result.truth_t[0] + 3.0) & (t <= result.truth_t[-1])
        t, x, var = t[keep], x[keep], var[keep]
    err = np.abs(x - np.interp(t, result.truth_t, result.truth_xyz[:, 0]))
    return err, np.sqrt(var)


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    parser.add_argument('bags', nargs='+', type=pathlib.Path)
    args = parser.parse_args(argv)
    bags = [b for b in args.bags if (b / 'metadata.yaml').exists()]
    print('| bag | self-calibration | poses | max (cm) | mean (cm) | within 3σ '
          '| disparity offset (px) | stereo scale error |')
    print('|---|---|---|---|---|---|---|---|')
    static_sets = {False: [], True: []}
    for bag in sorted(bags):
        static = bag.name.startswith('static_')
        for on in (False, True):
            result, loc = replay(bag, on)
            if result.pose_t.size == 0:
                print(f'| {bag.name} | {"on" if on else "off"} | 0 | – | – | – | – | – |')
                continue
            err, sigma = scores(result, static)
            if static:
                static_sets[on].append((err[0], sigma[0]))
                continue
            s = loc.survey
            theta = ('–', '–') if s is None else (
                f'{s.theta[0]:+.3f} ± {s.published_sigmas()[0]:.3f}',
                f'{s.theta[1]:+.2e} ± {s.published_sigmas()[1]:.1e}')
            print(f'| {bag.name} | {"on" if on else "off"} | {err.size} | '
                  f'{100 * err.max():.2f} | {100 * err.mean():.2f} | '
                  f'{100 * np.mean(err <= 3.0 * sigma):.1f} % | {theta[0]} | {theta[1]} |')
    for on, rows in static_sets.items():
        if rows:
            a = np.array(rows)
            print(f'| static set ({len(a)} trials) | {"on" if on else "off"} | {len(a)} | '
                  f'{100 * a[:, 0].max():.2f} | {100 * a[:, 0].mean():.2f} | '
                  f'{100 * np.mean(a[:, 0] <= 3.0 * a[:, 1]):.1f} % | – | – |')


if __name__ == '__main__':
    main()
