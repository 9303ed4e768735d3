"""Lamp-map refinement on recorded learning passes, against the truth.

Replays one train's learning-pass bags (``run_evaluation --passes N``:
``<out>/passes/train<i>/pass*/pass*``) in order through the localizer core
(``localizer_replay``, the bag's belief files), each pass reading and then writing one
refinement file as the node does, and prints a Markdown table per pass: the triplets it
measured and their error against the truth (the q the drawn lamp positions give), the
surveyed map's along-track error and the refined map's over the lamps the passes
refined, the stated 1σ, the lamps found off their survey and the flagged ones.

    python scripts/lamp_refinement_replay.py OUT/passes/train7 [--file /tmp/ref.yaml]
"""
import argparse
import pathlib
import tempfile

import numpy as np

from train_localizer.core.lamp_refinement_file import save_refinement
from vlc_common.core.lamp_map import LampMap
from vlc_evaluation import localizer_replay as lr


def along_track_errors(bag):
    """{uid: surveyed − true along-track position, m} (straight line along x)."""
    inst = bag.parent / (bag.name + '.installation')
    truth = {x.uid: x for x in LampMap.load(str(inst / 'truth/lamp_map.yaml')).lamps}
    belief = LampMap.load(str(inst / 'belief/lamp_map.yaml'))
    return ({x.uid: float(x.position_m[0] - truth[x.uid].position_m[0]) for x in belief.lamps},
            {x.uid: float(x.position_sigma_m[0]) for x in belief.lamps})


def cm(values, how):
    return '–' if len(values) == 0 else f'{100 * how(np.abs(values)):.2f}'


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    parser.add_argument('train', type=pathlib.Path)
    parser.add_argument('--file', type=pathlib.Path, default=None,
                        help='refinement file (default: a temporary one, started empty)')
    args = parser.parse_args(argv)
    path = args.file or pathlib.Path(tempfile.mkdtemp()) / 'lamp_refinement.yaml'
    path.unlink(missing_ok=True)
    bags = sorted(p for p in args.train.glob('pass*/pass*') if (p / 'metadata.yaml').exists())
    print('| pass | triplets | triplet error rms / max (cm) | stated σ median (cm) | lamps '
          '| survey rms / max (cm) | refined rms / max (cm) | lamp σ median (cm) '
          '| off survey | flagged |')
    print('|---|---|---|---|---|---|---|---|---|---|')
    for k, bag in enumerate(bags, 1):
        loc = lr.replay_with_belief(bag, {'lamp_refinement_path': str(path)}).localizer
        kept = loc.config.refinement_kept
        measurements = loc.pass_recorder.finish()
        merged = kept.base.merged(measurements)
        save_refinement(path, merged, kept.survey_map, 'replay')
        true_e, sigma = along_track_errors(bag)
        q_err = np.array([m.q_m - (true_e[m.uids[1]] - m.lam * true_e[m.uids[0]]
                                   - (1.0 - m.lam) * true_e[m.uids[2]])
                          for m in measurements])
        corrections, off = merged.corrections(sigma)
        uids = sorted(corrections)
        survey = np.array([true_e[u] for u in uids])
        refined = np.array([true_e[u] - corrections[u][0] for u in uids])
        stated = [corrections[u][1] for u in uids]
        print(f'| {k} | {len(measurements)} | {cm(q_err, lambda a: np.sqrt(np.mean(a * a)))} / '
              f'{cm(q_err, np.max)} | '
              f'{cm([m.sigma_m for m in measurements], np.median)} | {len(uids)} | '
              f'{cm(survey, lambda a: np.sqrt(np.mean(a * a)))} / {cm(survey, np.max)} | '
              f'{cm(refined, lambda a: np.sqrt(np.mean(a * a)))} / {cm(refined, np.max)} | '
              f'{cm(stated, np.median)} | '
              f'{", ".join(f"{u:#06x}" for u in off) or "none"} | '
              f'{", ".join(f"{f.uid:#06x}" for f in merged.flags) or "none"} |')


if __name__ == '__main__':
    main()
