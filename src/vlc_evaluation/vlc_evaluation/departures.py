"""Departures and stops (``--departures N``): the station cycle a metro train runs all day.

The dynamic protocols run at constant speed; a train in service stands at a platform,
pulls away, cruises, brakes and stands again. Each scenario: ``DWELL_S`` standing 0.5 m
past the first lamp, ``ACCEL_MPS2`` to ``SPEED_KMH``, ``CRUISE_S`` cruising, braking at
the same rate to a stop, ``STAND_S`` standing (rig motion profile
``accel_cruise_brake``). Every published pose is scored from the first one on, per
phase: the largest along-track error, the largest error in published σ, and the share
of poses within their 3σ — a departure must neither leave the train behind nor be
confident about it (docs/arch/train_localizer.md, "Zero-velocity updates").

Variants, on the same seeds: the defaults, and ``no_gate`` (the localizer's zero-velocity
χ² gate off: ``zero_velocity_gate_chi2`` 1e9), the departure as it was before the gate.
"""
import numpy as np

from vlc_evaluation import bag_eval, metrics
from vlc_evaluation.scenarios import DYNAMIC_START_M, Scenario

SPEED_KMH = 20.0
ACCEL_MPS2 = 1.0
DWELL_S = 5.0
CRUISE_S = 5.0
STAND_S = 3.0
GROUP_PREFIX = 'departures/'
PHASES = ('standing', 'accelerating', 'cruising', 'braking', 'stopped')
BEGIN_MARK, END_MARK = '<!-- departures:begin -->', '<!-- departures:end -->'
VARIANTS = (
    ('defaults', 'the defaults', {}),
    ('no_gate', 'zero-velocity gate off (`zero_velocity_gate_chi2: 1e9`)',
     {'train_localizer_node': {'zero_velocity_gate_chi2': 1.0e9}}),
)


def phase_bounds(speed_kmh=SPEED_KMH, accel_mps2=ACCEL_MPS2, dwell_s=DWELL_S,
                 cruise_s=CRUISE_S):
    """Start of each of :data:`PHASES` since the run's start, s."""
    ramp = speed_kmh / 3.6 / accel_mps2
    return (0.0, dwell_s, dwell_s + ramp, dwell_s + ramp + cruise_s,
            dwell_s + 2.0 * ramp + cruise_s)


def departure_groups(seeds, profile='realistic', speed_kmh=SPEED_KMH, variants=VARIANTS,
                     realtime_factor=1.0):
    """``{'departures/<variant>': [Scenario per seed]}``."""
    motion = {'accel_mps2': ACCEL_MPS2, 'brake_mps2': ACCEL_MPS2, 'dwell_s': DWELL_S,
              'cruise_s': CRUISE_S}
    duration = phase_bounds(speed_kmh)[-1] + STAND_S
    groups = {}
    for name, _, params in variants:
        groups[f'{GROUP_PREFIX}{name}'] = [Scenario(
            name=f'departure_{int(speed_kmh):03d}kmh_seed{seed}', kind='departure',
            motion_profile='accel_cruise_brake', start_chainage_m=DYNAMIC_START_M,
            speed_kmh=float(speed_kmh), seed=int(seed), duration_s=duration,
            realtime_factor=realtime_factor, rig_profile=profile,
            node_params=dict({'adis16488_node': dict(motion),
                              'stereo_camera_node': dict(motion)},
                             **{exe: dict(p) for exe, p in params.items()}))
            for seed in seeds]
    return groups


def score_departure(run, scenario):
    """Per phase: poses, the largest along-track error (m), the largest error in
    published σ, the share within 3σ; and the same over the whole run.
    """
    out = {'speed_kmh': scenario.speed_kmh, 'seed': scenario.seed,
           'health': bag_eval.graph_health(run), 'phases': {}}
    if run.truth_t.size < 2 or run.cov_t.size == 0:
        return out
    truth = metrics.interpolate_positions(run.cov_t, run.truth_t, run.truth_xyz)
    ok = np.all(np.isfinite(truth), axis=1)
    t = run.cov_t[ok] - run.truth_t[0]
    diff, cov = run.cov_mean[ok] - truth[ok], run.cov_xyz[ok]
    along = np.abs(diff[:, 0])
    along_sigma = np.maximum(np.sqrt(np.clip(cov[:, 0, 0], 0.0, None)), 1e-12)
    bounds = list(phase_bounds(scenario.speed_kmh)) + [np.inf]

    def figures(mask):
        if not mask.any():
            return {'poses': 0}
        return {'poses': int(mask.sum()), 'max_along_m': float(along[mask].max()),
                'max_sigmas': float((along[mask] / along_sigma[mask]).max()),
                'within_3sigma': metrics.covariance_consistency(diff[mask], cov[mask])}
    for name, lo, hi in zip(PHASES, bounds, bounds[1:]):
        out['phases'][name] = figures((t >= lo) & (t < hi))
    out['all'] = figures(np.ones(t.size, bool))
    return out


def departures_table(results):
    """(Markdown table, figures): per variant, over the seeds, per phase the largest
    along-track error and the largest error in σ, and the share of poses within 3σ.
    """
    cells = ' | '.join(f'{p}: max (cm) / in σ' for p in PHASES)
    rows = [f'| variant | runs | {cells} | poses within 3σ |',
            '|' + '---|' * (3 + len(PHASES))]
    figures = {}
    for name, label, _ in VARIANTS:
        runs = results.get(f'{GROUP_PREFIX}{name}') or []
        if not runs:
            continue
        fig = {}
        for phase in PHASES:
            got = [r['phases'][phase] for r in runs if r.get('phases', {}).get(phase, {})
                   .get('poses')]
            fig[phase] = ((max(g['max_along_m'] for g in got), max(g['max_sigmas'] for g in got))
                          if got else None)
        alls = [r['all'] for r in runs if r.get('all', {}).get('poses')]
        n = sum(a['poses'] for a in alls)
        fig['within_3sigma'] = (sum(a['within_3sigma'] * a['poses'] for a in alls) / n
                                if n else None)
        figures[name] = fig
        phase_cells = ' | '.join('–' if fig[p] is None else
                                 f'{100 * fig[p][0]:.1f} / {fig[p][1]:.1f}' for p in PHASES)
        within = '–' if fig['within_3sigma'] is None else f'{100 * fig["within_3sigma"]:.1f} %'
        rows.append(f'| {label} | {len(runs)} | {phase_cells} | {within} |')
    return '\n'.join(rows), figures


def describe(results, profile):
    seeds = sorted({r['seed'] for runs in results.values() for r in runs})
    return (f'Rig profile `{profile}`, seeds {", ".join(map(str, seeds))}: {DWELL_S:g} s '
            f'standing 0.5 m past a lamp, {ACCEL_MPS2:g} m/s² to {SPEED_KMH:g} km/h, '
            f'{CRUISE_S:g} s cruising, braking at {ACCEL_MPS2:g} m/s² to a stop, '
            f'{STAND_S:g} s standing; every published pose from the first, along the track.')


def update_docs(path, text, command):
    from vlc_evaluation.report import replace_marked_block
    replace_marked_block(path, f'{BEGIN_MARK}\nGenerated by `{command}`.\n\n{text}\n{END_MARK}',
                         begin=BEGIN_MARK, end=END_MARK)
