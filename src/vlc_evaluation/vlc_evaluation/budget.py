"""Error budget: each error source of a drawn rig profile switched on alone.

A reader deciding what to calibrate or survey better needs to know what each error
costs. For a profile (``realistic`` by default) the same reduced static + dynamic set
runs once per row, on the same points, speeds and seeds:

* ``none``: every source off (``<profile>/none``): raw images through the lens design's
  distortion, calibration, mount and map exact, the eq. 21 vibration — what is left is
  the method's own error;
* one row per source of :data:`~vlc_stereo_camera.core.installation.BUDGET_SOURCES`
  (``<profile>/only-<source>``): that source's draws, exactly those it has in the whole
  profile for the seed, and nothing else;
* ``all``: the whole profile.

The rows do not add up: errors partly cancel, and the receivers' stated uncertainty is
the same in every row (they do not know which source is on).
"""
from vlc_evaluation import ablations, metrics, scenarios

STATIC_POINTS_M = (9.0, 5.0, 2.0)
SPEEDS_KMH = (40, 100)
GROUP_PREFIX = 'budget/'
BEGIN_MARK, END_MARK = '<!-- budget:begin -->', '<!-- budget:end -->'


def budget_rows(profile='realistic'):
    """[(row name, rig profile name, label)] of the budget of ``profile``."""
    from vlc_stereo_camera.core.installation import BUDGET_SOURCES
    rows = [('none', f'{profile}/none', 'none (raw images through the lens design; '
             'everything else exact)')]
    rows += [(name, f'{profile}/only-{name}', label)
             for name, (label, _) in BUDGET_SOURCES.items()]
    rows.append(('all', profile, f'all of `{profile}`'))
    return rows


def budget_groups(profile='realistic', points_m=STATIC_POINTS_M, trials=2,
                  speeds_kmh=SPEEDS_KMH, runs=2, cells=4,
                  observe_s=scenarios.STATIC_OBSERVE_S, realtime_factor=1.0, first_seed=1,
                  geometry=None):
    """``{'budget/<row>/static': [Scenario], 'budget/<row>/dynamic': […]}``, every row on
    the same points, speeds and seeds (placed on the lamps of ``geometry``,
    :func:`.scenarios.protocol_geometry`).
    """
    groups = {}
    at_static, at_dynamic = scenarios.placement(geometry)
    for name, rig_profile, _ in budget_rows(profile):
        static = scenarios.static_scenarios(points_m=points_m, trials=trials,
                                            observe_s=observe_s, first_seed=first_seed,
                                            **at_static)
        dynamic = scenarios.dynamic_scenarios(speeds_kmh=speeds_kmh, runs=runs, cells=cells,
                                              first_seed=first_seed, **at_dynamic)
        for scenario in static + dynamic:
            scenario.rig_profile = rig_profile
            scenario.realtime_factor = realtime_factor
        groups[f'{GROUP_PREFIX}{name}/static'] = static
        groups[f'{GROUP_PREFIX}{name}/dynamic'] = dynamic
    return groups


def within_3sigma(dynamic):
    """Share of every published pose within its 3σ over the dynamic runs (pose-count
    weighted), or None.
    """
    pairs = [(r['covariance_3sigma_fraction'], (r.get('every_pose') or {}).get('count', 0))
             for r in dynamic if r.get('covariance_3sigma_fraction') is not None]
    total = sum(n for _, n in pairs)
    return sum(f * n for f, n in pairs) / total if total else None


def summary_cells(fig, speeds):
    """Table cells of one row of figures (``protocol_summary`` plus ``within_3sigma``):
    static max / mean, max / mean per speed, the dynamic poses within 3σ, misses.
    """
    cm = metrics.cm_text
    s = fig['static']
    cells = [f'{cm(s["max_m"])} / {cm(s["mean_m"])}']
    cells += [f'{cm(fig["dynamic"][v]["max_m"])} / {cm(fig["dynamic"][v]["mean_m"])}'
              if v in fig['dynamic'] else '–' for v in speeds]
    within = fig['within_3sigma']
    cells.append('–' if within is None else f'{100 * within:.1f} %')
    cells.append(str(s['misses'] + sum(d['misses'] for d in fig['dynamic'].values())))
    return cells


def budget_table(results, profile='realistic'):
    """(Markdown table, figures) of the budget rows found in ``results`` (``{group:
    [result]}`` as :func:`scenarios.run_protocols` returns them).
    """
    figures = {}
    for name, rig_profile, label in budget_rows(profile):
        static = results.get(f'{GROUP_PREFIX}{name}/static', [])
        dynamic = results.get(f'{GROUP_PREFIX}{name}/dynamic', [])
        if static or dynamic:
            figures[name] = dict(ablations.protocol_summary(static, dynamic), label=label,
                                 rig_profile=rig_profile,
                                 within_3sigma=within_3sigma(dynamic),
                                 seeds=sorted({r['seed'] for r in static + dynamic
                                               if r.get('seed') is not None}))
    speeds = sorted({v for f in figures.values() for v in f['dynamic']})
    head = ('| error source (alone) | static max / mean (cm) | '
            + ' | '.join(f'{v} km/h max / mean (cm)' for v in speeds)
            + ' | dynamic poses within 3σ | misses |')
    rows = [head, '|' + '---|' * (4 + len(speeds))]
    for name, fig in figures.items():
        rows.append(f'| `{name}`: {fig["label"]} | ' + ' | '.join(summary_cells(fig, speeds))
                    + ' |')
    return '\n'.join(rows), figures


def describe(figures, points_m=None):
    """One paragraph saying what the table was run on."""
    seeds = sorted({s for f in figures.values() for s in f['seeds']})
    n_static = max((f['static']['count'] + f['static']['misses'] for f in figures.values()),
                   default=0)
    return (f'Each row: {n_static} static results (points '
            f'{", ".join(f"{p:g}" for p in points_m or STATIC_POINTS_M)} m before a lamp) and '
            f'the dynamic test points, on seeds {", ".join(map(str, seeds))}; the same '
            'seeds draw the same values of a source in its row and in `all`. Misses: '
            'static results and test points without a pose.')


def update_docs(path, table, figures, command, points_m=None):
    """Write the budget ``table`` and ``figures`` (:func:`budget_table`) between the
    budget markers of the Markdown file ``path``.
    """
    from vlc_evaluation.report import replace_marked_block
    section = (f'{BEGIN_MARK}\nGenerated by `{command}`.\n\n{describe(figures, points_m)}\n\n'
               f'{table}\n{END_MARK}')
    replace_marked_block(path, section, begin=BEGIN_MARK, end=END_MARK)


def plot_budget(figures, path):
    """Bar chart of every row's static and per-speed mean and max error."""
    return ablations.plot_ablations(figures, path, title='Error budget')
