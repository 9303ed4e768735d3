"""Ablations: the same reduced static + dynamic set run once per switch turned off (or on).

Each variant changes one node parameter on top of the parameter files (names as in
``src/*/config/*.yaml``); the baseline runs the same scenarios with the defaults, so
every row compares like with like (same points, speeds and seeds):

=========================  ==================================================
variant                    parameter
=========================  ==================================================
no_imu_compensation        train_localizer ``use_imu_attitude: false`` — the fix
                           geometry takes the platform as aligned with the track
                           (identity attitude), i.e. no IMU heading/vibration
                           compensation (the compensator itself has no switch)
wiener_on                  spot_locator ``wiener: true`` (off by default)
no_fusion                  train_localizer ``use_kalman: false`` — every accepted
                           single-frame fix published raw
no_range_constraint        train_localizer ``use_range_constraint: false`` — the
                           paper's eq. 13–14 fix instead of the track-constrained one
no_exposure_stamping       train_localizer ``use_exposure_stamping: false`` — fixes
                           stamped with the image stamp (row 0) instead of the
                           exposure mid-time of the spot's rows
=========================  ==================================================
"""
import numpy as np

from vlc_evaluation import metrics, scenarios

VARIANTS = (
    ('baseline', 'all switches at their defaults', {}),
    ('no_imu_compensation', 'IMU compensation off (localizer `use_imu_attitude: false`)',
     {'train_localizer_node': {'use_imu_attitude': False}}),
    ('wiener_on', 'Wiener deblurring on (spot_locator `wiener: true`)',
     {'spot_locator_node': {'wiener': True}}),
    ('no_fusion', 'fusion off, raw single-frame fixes (localizer `use_kalman: false`)',
     {'train_localizer_node': {'use_kalman': False}}),
    ('no_range_constraint', 'paper eq. 13–14 fix (localizer `use_range_constraint: false`)',
     {'train_localizer_node': {'use_range_constraint': False}}),
    ('no_exposure_stamping', 'image stamp, not exposure mid-time (localizer '
     '`use_exposure_stamping: false`)',
     {'train_localizer_node': {'use_exposure_stamping': False}}),
)
STATIC_POINTS_M = (9.0, 6.0, 3.0, 1.0)
SPEEDS_KMH = (20, 60, 120)
GROUP_PREFIX = 'ablations/'


def ablation_groups(points_m=STATIC_POINTS_M, trials=2, speeds_kmh=SPEEDS_KMH, runs=2,
                    cells=4, observe_s=scenarios.STATIC_OBSERVE_S, realtime_factor=1.0,
                    variants=VARIANTS, geometry=None):
    """``{'ablations/<variant>/static': [Scenario], 'ablations/<variant>/dynamic': …}``
    (placed on the lamps of ``geometry``, :func:`.scenarios.protocol_geometry`).
    """
    groups = {}
    at_static, at_dynamic = scenarios.placement(geometry)
    for name, _, params in variants:
        static = scenarios.static_scenarios(points_m=points_m, trials=trials,
                                            observe_s=observe_s, **at_static)
        dynamic = scenarios.dynamic_scenarios(speeds_kmh=speeds_kmh, runs=runs, cells=cells,
                                              **at_dynamic)
        for scenario in static + dynamic:
            scenario.node_params = {exe: dict(p) for exe, p in params.items()}
            scenario.realtime_factor = realtime_factor
        groups[f'{GROUP_PREFIX}{name}/static'] = static
        groups[f'{GROUP_PREFIX}{name}/dynamic'] = dynamic
    return groups


def protocol_summary(static, dynamic):
    """Static summary, dynamic summary per speed and the largest every-pose error of one
    row's results (the ablation and the error-budget tables).
    """
    s = metrics.summarize([r['error_m'] for r in static if r.get('error_m') is not None],
                          misses=sum(1 for r in static if r.get('error_m') is None))
    by_speed = {}
    for r in dynamic:
        by_speed.setdefault(int(round(r['speed_kmh'])), []).extend(r['points'])
    dyn = {}
    for v, pts in sorted(by_speed.items()):
        d = metrics.summarize([p['error_m'] for p in pts if p['error_m'] is not None],
                              misses=sum(1 for p in pts if p['error_m'] is None))
        dyn[v] = d.as_dict()
    every = [r['every_pose'] for r in dynamic if r.get('every_pose')]
    return {'static': s.as_dict(), 'dynamic': dyn,
            'every_pose_max_m': max((e['max_m'] for e in every), default=None)}


_cm = metrics.cm_text


def ablation_table(results, variants=VARIANTS):
    """Markdown table and figures from ``results`` (``{group: [result]}`` as returned by
    :func:`scenarios.run_protocols`); rows without results are skipped.
    """
    figures = {}
    for name, label, params in variants:
        static = results.get(f'{GROUP_PREFIX}{name}/static', [])
        dynamic = results.get(f'{GROUP_PREFIX}{name}/dynamic', [])
        if static or dynamic:
            figures[name] = dict(protocol_summary(static, dynamic), label=label, params=params)
    speeds = sorted({v for f in figures.values() for v in f['dynamic']})
    head = ('| variant | static max (cm) | static mean (cm) | static misses | '
            + ' | '.join(f'{v} km/h max / mean (cm)' for v in speeds)
            + ' | dynamic misses |')
    rows = [head, '|' + '---|' * (5 + len(speeds))]
    for fig in figures.values():
        s = fig['static']
        cells = [f'{_cm(fig["dynamic"][v]["max_m"])} / {_cm(fig["dynamic"][v]["mean_m"])}'
                 if v in fig['dynamic'] else '–' for v in speeds]
        misses = sum(d['misses'] for d in fig['dynamic'].values())
        rows.append(f'| {fig["label"]} | {_cm(s["max_m"])} | {_cm(s["mean_m"])} | '
                    f'{s["misses"]} | ' + ' | '.join(cells) + f' | {misses} |')
    return '\n'.join(rows), figures


def plot_ablations(figures, path, title='Ablations'):
    """Bar chart: static and per-speed mean and max error of every variant."""
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt
    if not figures:
        return False
    names = list(figures)
    speeds = sorted({v for f in figures.values() for v in f['dynamic']})
    groups = ['static'] + [f'{v} km/h' for v in speeds]
    fig, axes = plt.subplots(1, 2, figsize=(11, 4), sharey=False)
    width = 0.8 / len(names)
    for ax, key, what in ((axes[0], 'mean_m', 'mean error'), (axes[1], 'max_m', 'max error')):
        for i, name in enumerate(names):
            f = figures[name]
            values = [f['static'][key]] + [f['dynamic'].get(v, {}).get(key, np.nan)
                                           for v in speeds]
            ax.bar(np.arange(len(groups)) + i * width, 100 * np.asarray(values, float),
                   width, label=name)
        ax.set_xticks(np.arange(len(groups)) + 0.4 - width / 2, groups)
        ax.set_ylabel('error (cm)')
        ax.set_title(f'{title}: {what}')
        ax.grid(alpha=0.3, axis='y')
    axes[0].legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return True
