"""Multi-pass evaluation: one train on one line, run again and again (issue 17).

A train in service passes the same lamps every day; what its localizer learns on one
run (the files it keeps: the disparity map, ``disparity_map_path``, the optional
self-survey's calibration, ``self_calibration_path``, and the lamp-map refinement,
``lamp_refinement_path``) is read at the next start. This protocol
measures what that is worth on a drawn rig profile:

* a *train* is one drawn installation (``installation_seed``: vehicle, optics,
  calibration, mount, the line's lamps and survey);
* its *learning passes* are dynamic runs over the line at ``learn_speed_kmh``, one after
  the other, each a fresh graph with new sensor noise, platform motion and IMU biases
  (``seed``), reading and writing the train's kept files;
* at each *checkpoint* n (0 = the first pass: nothing kept yet; 1, 3, 10 …) the scored
  runs — static trials and dynamic runs at each speed — start from a copy of the files
  as n learning passes left them. Their seeds are the same at every checkpoint (a
  dynamic run's follows its speed), so two checkpoints differ only in what was learnt.
  The first pass and the last checkpoint (issue 17's two columns) score every speed of
  ``end_speeds_kmh`` (20–120 km/h) besides ``speeds_kmh`` (40, 100); the checkpoints
  between, and the ablations, ``speeds_kmh`` only.

Rounds: round k runs learning pass k + 1 of every train and the scored runs of
checkpoint k, on the evaluation's lanes. Bags, logs and results in
``<out>/passes/train<i>/{pass<k>,after<n>/static,after<n>/dynamic}/``; the kept files in
``<out>/passes/train<i>/kept/`` (replaced by what each learning pass wrote in
``pass<k>/files/``, which every attempt of the pass starts as a fresh copy of them), as
checkpoint n found them in ``after<n>/kept/``, and each scored run's own copy in
``after<n>/files/<run>/``.

*Ablations* (``ablations``): at the last checkpoint the scored runs are run again once
per variant, each with one switch turned (:data:`ABLATIONS`: undistortion and
rectification off, the refinement off, the self-calibration — the disparity map — off),
reading the same kept files, in
``after<n>/<variant>/``.
"""
import json
import pathlib
import shutil

import yaml

from train_localizer.core.disparity_map import DisparityMap, DisparityMapConfig
from train_localizer.core.disparity_map_file import DisparityMapFileError, load_disparity_map
from train_localizer.core.kept_file import read_mapping
from vlc_evaluation import ablations, budget, scenarios

CHECKPOINTS = (0, 1, 3, 10)
STATIC_POINTS_M = (9.0, 5.0, 2.0)
SPEEDS_KMH = (40, 100)
#: the speeds also scored at the first pass and the last checkpoint
END_SPEEDS_KMH = (20, 40, 60, 80, 100, 120)
LEARN_SPEED_KMH = 60
LEARN_CELLS = 6
GROUP_PREFIX = 'passes/'
SELF_CALIBRATION_FILE = 'self_calibration.yaml'
LAMP_REFINEMENT_FILE = 'lamp_refinement.yaml'
DISPARITY_MAP_FILE = 'disparity_map.yaml'
BEGIN_MARK, END_MARK = '<!-- passes:begin -->', '<!-- passes:end -->'
LOCALIZER = 'train_localizer_node'
#: name -> (what it turns, localizer parameters on top of the run's given the run's,
#: Scenario fields)
ABLATIONS = {
    'no_undistortion': ('undistortion and rectification off (the receivers take the raw '
                        'images as rectified)', lambda given: {},
                        {'calibration': 'uncorrected'}),
    'no_refinement': ('lamp-map refinement off',
                      lambda given: {'lamp_refinement_path': ''}, {}),
    'no_disparity_map': ('self-calibration (the learnt disparity map) off',
                         lambda given: {'use_disparity_map': False}, {}),
}


def run_seed(train, role, index):
    """Seed of a run of ``train``: ``role`` 0 = learning pass ``index``, 1 = the
    ``index``-th scored run (the same at every checkpoint).
    """
    return 100000 * int(train) + 1000 * int(role) + int(index)


def _localizer_params(base, files_dir):
    """The kept files' paths, unless ``base`` sets them (``lamp_refinement_path: ''``:
    the refinement off, an ablation).
    """
    files_dir = pathlib.Path(files_dir)
    return dict({'self_calibration_path': str(files_dir / SELF_CALIBRATION_FILE),
                 'lamp_refinement_path': str(files_dir / LAMP_REFINEMENT_FILE),
                 'disparity_map_path': str(files_dir / DISPARITY_MAP_FILE)}, **base)


def learning_pass(train, k, files_dir, profile='realistic', speed_kmh=LEARN_SPEED_KMH,
                  cells=LEARN_CELLS, localizer_params=None, realtime_factor=1.0,
                  kept_dir=None):
    """Learning pass ``k`` (1, 2, …) of ``train``: a dynamic run that reads and writes
    the files in ``files_dir``, a fresh copy of ``kept_dir`` at every attempt.
    """
    scenario = scenarios.dynamic_scenarios(speeds_kmh=(speed_kmh,), runs=1, cells=cells,
                                           first_seed=run_seed(train, 0, k))[0]
    scenario.name = f'pass{k:02d}_{speed_kmh:03d}kmh'
    scenario.rig_profile, scenario.installation_seed = profile, int(train)
    scenario.realtime_factor = realtime_factor
    scenario.node_params = {LOCALIZER: _localizer_params(localizer_params or {}, files_dir)}
    scenario.files_from, scenario.files_to = str(kept_dir or ''), str(files_dir)
    return scenario


def scored_runs(train, files_dir, profile='realistic', points_m=STATIC_POINTS_M,
                speeds_kmh=SPEEDS_KMH, cells=4, observe_s=scenarios.STATIC_OBSERVE_S,
                localizer_params=None, realtime_factor=1.0, kept_dir=None):
    """(static, dynamic) Scenarios of one checkpoint of ``train``; each reads its own
    copy of the files of ``kept_dir`` in ``files_dir/<name>`` (what it writes back is
    not kept).
    """
    static = [scenarios.static_scenarios(points_m=(d,), trials=1, observe_s=observe_s,
                                         first_seed=run_seed(train, 1, i))[0]
              for i, d in enumerate(points_m)]
    # the seed follows the speed: the same run at every checkpoint that scores it
    dynamic = [scenarios.dynamic_scenarios(speeds_kmh=(v,), runs=1, cells=cells,
                                           first_seed=run_seed(train, 1, 100 + int(v)))[0]
               for v in speeds_kmh]
    for scenario in static + dynamic:
        scenario.rig_profile, scenario.installation_seed = profile, int(train)
        scenario.realtime_factor = realtime_factor
        own = pathlib.Path(files_dir) / scenario.name
        scenario.node_params = {LOCALIZER: _localizer_params(localizer_params or {}, own)}
        scenario.files_from, scenario.files_to = str(kept_dir or ''), str(own)
    return static, dynamic


def _read_yaml(path):
    """The kept file's mapping; None when it is missing or unreadable."""
    try:
        return read_mapping(path, ValueError)
    except ValueError:
        return None


def kept_state(files_dir):
    """What a train keeps: the self-calibration file's values and the lamp refinement's
    passes, triplets and flagged lamps ({} when nothing is kept yet).
    """
    state = {}
    calibration = _read_yaml(pathlib.Path(files_dir) / SELF_CALIBRATION_FILE)
    if calibration:
        state.update({k: calibration.get(k) for k in (
            'disparity_offset_px', 'disparity_offset_sigma_px', 'stereo_scale_error',
            'stereo_scale_sigma', 'runs')})
    refinement = _read_yaml(pathlib.Path(files_dir) / LAMP_REFINEMENT_FILE)
    if refinement:
        state.update(refinement_passes=refinement.get('passes'),
                     refinement_triplets=len(refinement.get('triplets') or []),
                     refinement_flags=len(refinement.get('flags') or []))
    disparity = _read_yaml(pathlib.Path(files_dir) / DISPARITY_MAP_FILE)
    if disparity:
        try:
            cells, runs, _ = load_disparity_map(
                pathlib.Path(files_dir) / DISPARITY_MAP_FILE, disparity.get('vehicle_id'),
                float(disparity.get('cell_px', DisparityMapConfig.cell_px)))
        except (DisparityMapFileError, TypeError, ValueError):
            cells = None
        if cells is not None:
            in_use, _, mean_abs = DisparityMap(kept=cells).summary()
            state.update(disparity_map_runs=runs, disparity_map_cells=in_use,
                         disparity_map_mean_abs_px=mean_abs)
    return state


def run_passes(out_dir, lamp_map, trains=(1, 2), passes=10, checkpoints=CHECKPOINTS,
               profile='realistic', points_m=STATIC_POINTS_M, speeds_kmh=SPEEDS_KMH,
               end_speeds_kmh=END_SPEEDS_KMH, learn_speed_kmh=LEARN_SPEED_KMH,
               localizer_params=None, lanes=2, spawn='fork', progress=None, retries=1,
               realtime_factor=1.0, ablations=(), lockstep=False):
    """Run the protocol (``lockstep``: as lockstep graphs, :mod:`.lockstep`); returns
    ``{train: {checkpoint: {'static': [...], 'dynamic':
    [...], 'kept': {...}(, 'ablations': {variant: {'static': …, 'dynamic': …}})}}}``
    (also written to ``<out>/passes/results.json``).
    """
    out_dir = pathlib.Path(out_dir)
    root = out_dir / GROUP_PREFIX.rstrip('/')
    checkpoints = sorted({int(n) for n in checkpoints if 0 <= int(n) <= passes})
    results = {int(t): {} for t in trains}
    for t in trains:
        shutil.rmtree(root / f'train{t}' / 'kept', ignore_errors=True)
        (root / f'train{t}' / 'kept').mkdir(parents=True, exist_ok=True)
    for k in range(0, max(passes, max(checkpoints, default=0)) + 1):
        groups = {}
        for t in trains:
            base = root / f'train{t}'
            if k < passes:
                groups[f'{GROUP_PREFIX}train{t}/pass{k + 1:02d}'] = [learning_pass(
                    t, k + 1, base / f'pass{k + 1:02d}' / 'files', profile, learn_speed_kmh,
                    localizer_params=localizer_params, realtime_factor=realtime_factor,
                    kept_dir=base / 'kept')]
            if k in checkpoints:
                # the files as k passes left them, for the record and the scored runs
                kept = base / f'after{k:02d}' / 'kept'
                shutil.rmtree(kept, ignore_errors=True)
                shutil.copytree(base / 'kept', kept)
                results[int(t)][k] = {'kept': kept_state(kept)}
                given = dict(localizer_params or {})
                variants = [('', given, {})] + [
                    (name, dict(given, **ABLATIONS[name][1](given)), ABLATIONS[name][2])
                    for name in (ablations if k == checkpoints[-1] else ())]
                for name, params, fields in variants:
                    where = base / f'after{k:02d}' / name
                    speeds = (sorted(set(speeds_kmh) | set(end_speeds_kmh))
                              if not name and k in (0, checkpoints[-1]) else speeds_kmh)
                    static, dynamic = scored_runs(t, where / 'files', profile, points_m,
                                                  speeds, localizer_params=params,
                                                  realtime_factor=realtime_factor,
                                                  kept_dir=kept)
                    for scenario in static + dynamic:
                        for field, value in fields.items():
                            setattr(scenario, field, value)
                    group = f'{GROUP_PREFIX}train{t}/after{k:02d}/' + (f'{name}/' if name else '')
                    groups[group + 'static'] = static
                    groups[group + 'dynamic'] = dynamic
        if not groups:
            continue
        done = scenarios.run_protocols(groups, out_dir, lamp_map, lanes=lanes, spawn=spawn,
                                       progress=progress, retries=retries, lockstep=lockstep)
        for t in trains:
            base = root / f'train{t}'
            if k < passes:
                # what the pass wrote is what the train keeps
                shutil.rmtree(base / 'kept')
                shutil.copytree(base / f'pass{k + 1:02d}' / 'files', base / 'kept')
            for kind in ('static', 'dynamic'):
                group = f'{GROUP_PREFIX}train{t}/after{k:02d}/{kind}'
                if group in done:
                    results[int(t)][k][kind] = done[group]
                for name in ablations:
                    group = f'{GROUP_PREFIX}train{t}/after{k:02d}/{name}/{kind}'
                    if group in done:
                        results[int(t)][k].setdefault('ablations', {}).setdefault(
                            name, {})[kind] = done[group]
    with open(root / 'results.json', 'w', encoding='utf-8') as stream:
        json.dump({str(t): {str(n): v for n, v in r.items()} for t, r in results.items()},
                  stream)
    return results


def passes_table(results):
    """(Markdown table, figures): per checkpoint, over the trains, the static and
    per-speed max / mean, the dynamic poses within 3σ, misses, and what was kept.
    """
    checkpoints = sorted({n for r in results.values() for n in r})
    figures = {}
    for n in checkpoints:
        cells = [r[n] for r in results.values() if n in r]
        kept = {t: r[n].get('kept', {}) for t, r in results.items() if n in r}
        # the checkpoint's row, then one per ablation run at it
        variants = {n: cells}
        variants.update({(n, name): [c['ablations'][name] for c in cells
                                     if name in c.get('ablations', {})]
                         for name in ABLATIONS
                         if any(name in c.get('ablations', {}) for c in cells)})
        for key, runs in variants.items():
            static = [x for c in runs for x in c.get('static', [])]
            dynamic = [x for c in runs for x in c.get('dynamic', [])]
            figures[key] = dict(ablations.protocol_summary(static, dynamic),
                                within_3sigma=budget.within_3sigma(dynamic), kept=kept)
    speeds = sorted({v for f in figures.values() for v in f['dynamic']})
    head = ('| passes learnt | static max / mean (cm) | '
            + ' | '.join(f'{v} km/h max / mean (cm)' for v in speeds)
            + ' | dynamic poses within 3σ | misses | kept, per train: disparity map, '
            'self-calibration δ, lamp refinement |')
    rows = [head, '|' + '---|' * (5 + len(speeds))]
    for n, fig in figures.items():
        kept = '; '.join(_kept_text(t, k) for t, k in sorted(fig['kept'].items()))
        label = (f'{n[0]}, {ABLATIONS[n[1]][0]}' if isinstance(n, tuple)
                 else 'first pass' if n == 0 else n)
        rows.append(f'| {label} | ' + ' | '.join(budget.summary_cells(fig, speeds))
                    + f' | {kept} |')
    return '\n'.join(rows), figures


def _kept_text(train, kept):
    parts = []
    if kept.get('disparity_map_cells'):
        parts.append(f'disparity map {kept["disparity_map_cells"]} cells, mean abs δd '
                     f'{kept["disparity_map_mean_abs_px"]:.2f} px')
    elif kept.get('disparity_map_cells') == 0:
        parts.append('disparity map: no cell in use yet')
    if kept.get('disparity_offset_px') is not None:
        parts.append(f'δ {kept["disparity_offset_px"]:+.3f} ± '
                     f'{kept["disparity_offset_sigma_px"]:.3f} px')
    if kept.get('refinement_passes') is not None:
        parts.append(f'{kept["refinement_triplets"]} triplets, '
                     f'{kept["refinement_flags"]} flagged')
    return f'{train}: ' + (', '.join(parts) or 'nothing')


def parse_params(items):
    """``['name:=value', …]`` as a dict (values as YAML); ValueError naming a bad item."""
    params = {}
    for item in items:
        name, sep, value = item.partition(':=')
        if not sep or not name.strip():
            raise ValueError(f'{item!r} is not NAME:=VALUE')
        try:
            params[name.strip()] = yaml.safe_load(value)
        except yaml.YAMLError as exc:
            raise ValueError(f'{item!r}: {exc}') from None
    return params


def describe(results, passes, profile, learn_speed_kmh=LEARN_SPEED_KMH,
             points_m=STATIC_POINTS_M, params=None):
    """One paragraph saying what the table was run on."""
    trains = sorted(results)
    given = ', '.join(f'`{k}: {v}`' for k, v in (params or {}).items())
    return (f'Rig profile `{profile}`, trains (drawn installations) '
            f'{", ".join(map(str, trains))}; {passes} learning passes at {learn_speed_kmh} '
            f'km/h each; at each checkpoint static points '
            f'{", ".join(f"{p:g}" for p in points_m)} m and one dynamic run per speed '
            '(the first pass and the last checkpoint at every speed of the table, the '
            'others and the ablations at the speeds they show), with the same seeds at '
            'every checkpoint. Localizer parameters: '
            + (given or 'the defaults') + ' (and the kept files: `disparity_map_path`, '
            '`self_calibration_path`, `lamp_refinement_path`).')


def update_docs(path, text, command):
    from vlc_evaluation.report import replace_marked_block
    replace_marked_block(path, f'{BEGIN_MARK}\nGenerated by `{command}`.\n\n{text}\n{END_MARK}',
                         begin=BEGIN_MARK, end=END_MARK)
