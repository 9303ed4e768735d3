"""Tables (Markdown), figures (PNG) and the JSON of every figure, from scored runs.

The paper's figures (``shared/EVALUATION.md``) are printed beside ours; nothing here is
typed in from a measurement: every number of ours comes from the results passed in.
"""
import json
import math
import os
import pathlib
import time

import numpy as np

from vlc_evaluation import html_report, identification, latency, metrics, scenarios

PAPER_STATIC = {'max_cm': 29.73, 'min_cm': 2.68, 'mean_cm': 10.48, 'p90_cm': 20.0}
PAPER_DYNAMIC = {20: {'max_cm': 32.09, 'mean_cm': 11.07, 'p75_cm': 18.0},
                 40: {'max_cm': 33.05, 'mean_cm': 14.21, 'p75_cm': 19.0},
                 60: {'max_cm': 34.25, 'mean_cm': 15.33, 'p75_cm': 22.0},
                 80: {'max_cm': 34.75, 'mean_cm': 16.52, 'p75_cm': 23.0},
                 100: {'max_cm': 36.11, 'mean_cm': 17.68, 'p75_cm': 23.5}}


_cm = metrics.cm_text


def _paper(value):
    return '–' if value is None else f'{value:.2f}'


def _static_rows(label, errors, misses):
    s = metrics.summarize(errors, misses=misses)
    return s, (f'| {label} | {_cm(s.max_m)} | {_cm(s.mean_m)} | {_cm(s.min_m)} | '
               f'{_cm(s.p90_m)} | {s.count} | {s.misses} |')


def static_table(results):
    """Markdown table of the static protocol, ours beside the paper's.

    Rows: the published pose (the product), then the raw single-frame fixes of the same
    trials (no filtering, :mod:`.raw_fix`): the paper's eq. 12–14 chain and this
    project's track-constrained fix.
    """
    rows = ['| static protocol | max (cm) | mean (cm) | min (cm) | 90th pct (cm) | results | '
            'misses |', '|---|---|---|---|---|---|---|']
    figures = {}

    def add(key, label, errors, misses):
        summary, row = _static_rows(label, errors, misses)
        figures[key] = summary.as_dict()
        rows.append(row)

    add('ours', 'this project, published pose, Euclidean',
        [r['error_m'] for r in results if r.get('error_m') is not None],
        sum(1 for r in results if r.get('error_m') is None))
    add('ours_along_track', 'this project, published pose, along track',
        [abs(r['along_m']) for r in results if r.get('along_m') is not None],
        sum(1 for r in results if r.get('along_m') is None))
    for method, label in (('paper', 'raw single frame, paper eq. 12–14 + IMU attitude'),
                          ('constrained', 'raw single frame, track-constrained fix')):
        raw = [r['raw'][method] for r in results if r.get('raw')]
        if not raw:
            continue
        add(f'raw_{method}', f'{label}, Euclidean',
            [x['error_m'] for x in raw if x['error_m'] is not None],
            sum(1 for x in raw if x['error_m'] is None))
        add(f'raw_{method}_along_track', f'{label}, along track',
            [abs(x['along_m']) for x in raw if x['along_m'] is not None],
            sum(1 for x in raw if x['along_m'] is None))
    rows.append(f'| paper (Acta Optica Sinica 2023) | {_paper(PAPER_STATIC["max_cm"])} | '
                f'{_paper(PAPER_STATIC["mean_cm"])} | {_paper(PAPER_STATIC["min_cm"])} | '
                f'< {_paper(PAPER_STATIC["p90_cm"])} | 200 | – |')
    return '\n'.join(rows), figures


def dynamic_table(results):
    """Markdown table of the dynamic protocol per speed, ours beside the paper's."""
    by_speed = {}
    for r in results:
        by_speed.setdefault(int(round(r['speed_kmh'])), []).append(r)
    rows = ['| speed (km/h) | max (cm) | mean (cm) | 75th pct (cm) | 95th pct (cm) | '
            'availability | paper max | paper mean | paper 75th |',
            '|---|---|---|---|---|---|---|---|---|']
    figures = {}
    for v in sorted(by_speed):
        pts = [p for r in by_speed[v] for p in r['points']]
        errs = [p['error_m'] for p in pts if p['error_m'] is not None]
        misses = sum(1 for p in pts if p['error_m'] is None)
        s = metrics.summarize(errs, misses=misses)
        avail = s.count / max(1, s.count + s.misses)
        paper = PAPER_DYNAMIC.get(v, {})
        rows.append(f'| {v} | {_cm(s.max_m)} | {_cm(s.mean_m)} | {_cm(s.p75_m)} | '
                    f'{_cm(s.p95_m)} | {100 * avail:.1f} % | {_paper(paper.get("max_cm"))} | '
                    f'{_paper(paper.get("mean_cm"))} | {_paper(paper.get("p75_cm"))} |')
        figures[v] = {'test_points': s.as_dict(), 'availability': avail}
    return '\n'.join(rows), figures


def plot_static(results, path):
    """Error against distance to the lamp (like paper Fig. 11)."""
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt
    pts = [(r['point_m'], 100 * r['error_m']) for r in results if r.get('error_m') is not None]
    miss = sorted({r['point_m'] for r in results if r.get('error_m') is None})
    fig, ax = plt.subplots(figsize=(8, 4))
    for method, marker, label in (('paper', 'x', 'raw single frame, paper eq. 12–14'),
                                  ('constrained', '+', 'raw single frame, constrained fix')):
        raw = [(r['point_m'], 100 * r['raw'][method]['error_m']) for r in results
               if r.get('raw') and r['raw'][method]['error_m'] is not None]
        if raw:
            d, e = np.array(raw).T
            ax.plot(d + (0.08 if method == 'paper' else -0.08), e, marker, color='0.55',
                    alpha=0.6, label=label)
    if pts:
        d, e = np.array(pts).T
        ax.plot(d, e, 'o', alpha=0.5, label='this project, published pose (each trial)')
        for x in np.unique(d):
            ax.plot(x, e[d == x].max(), 'k_', markersize=12)
    for x in miss:
        ax.axvline(x, color='r', alpha=0.2)
    ax.axhline(PAPER_STATIC['max_cm'], color='C3', ls='--', label='paper max 29.73 cm')
    ax.axhline(PAPER_STATIC['mean_cm'], color='C1', ls=':', label='paper mean 10.48 cm')
    ax.set_xlabel('distance to the lamp (m)')
    ax.set_ylabel('position error (cm)')
    ax.set_title('Static protocol: error against distance to the lamp (red: misses)')
    ax.legend(fontsize=8)
    ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def plot_dynamic(results, path):
    """Error distributions per speed (like paper Fig. 15)."""
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt
    by_speed = {}
    for r in results:
        by_speed.setdefault(int(round(r['speed_kmh'])), []).extend(
            100 * p['error_m'] for p in r['points'] if p['error_m'] is not None)
    speeds = sorted(by_speed)
    fig, ax = plt.subplots(figsize=(8, 4))
    if speeds:
        ax.boxplot([by_speed[v] or [np.nan] for v in speeds], whis=(0, 100))
        ax.set_xticks(range(1, len(speeds) + 1), [str(v) for v in speeds])
        paper = [PAPER_DYNAMIC.get(v, {}).get('max_cm', np.nan) for v in speeds]
        ax.plot(range(1, len(speeds) + 1), paper, 'r^--', label='paper max')
    ax.set_xlabel('speed (km/h)')
    ax.set_ylabel('position error at the test points (cm)')
    ax.set_title('Dynamic protocol: error distribution per speed')
    ax.legend(fontsize=8)
    ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def _by_speed(results):
    by_speed = {}
    for r in results:
        by_speed.setdefault(int(round(r['speed_kmh'])), []).append(r)
    return dict(sorted(by_speed.items()))


def _finite(value):
    return float(value) if np.isfinite(value) else None


def _fmt(value, digits=2, scale=1.0):
    return '–' if value is None or not np.isfinite(value) else f'{scale * value:.{digits}f}'


def dynamic_detail_table(results):
    """Per speed: every published pose, the covariance bound, heading compensation."""
    rows = ['| speed (km/h) | every pose: max (cm) | mean (cm) | poses within 3σ | heading '
            'before (deg) | heading after: max abs (deg) | rms (deg) | cold start: heading '
            f'within {scenarios.HEADING_BOUND_DEG:g}° from the first pose on, after (s): '
            'median / max |',
            '|---|---|---|---|---|---|---|---|']
    figures = {}
    for v, runs in _by_speed(results).items():
        maxes = [r['every_pose']['max_m'] for r in runs if r.get('every_pose')]
        means = [r['every_pose']['mean_m'] for r in runs if r.get('every_pose')]
        counts = [r['every_pose']['count'] for r in runs if r.get('every_pose')]
        cov = [r['covariance_3sigma_fraction'] for r in runs
               if r.get('covariance_3sigma_fraction') is not None]
        before = [r['heading_before_deg'] for r in runs if r.get('heading_before_deg')]
        after = [r['heading_after_deg'] for r in runs if r.get('heading_after_deg')]
        settling = [r.get('heading_settling_s') for r in runs if 'heading_settling_s' in r]
        never = sum(x is None for x in settling)
        settled = [x for x in settling if x is not None]
        fig = {
            'every_pose_max_m': float(np.max(maxes)) if maxes else None,
            'every_pose_mean_m': (float(np.average(means, weights=counts))
                                  if means and sum(counts) else None),
            'covariance_3sigma_fraction': float(np.mean(cov)) if cov else None,
            'heading_before_min_deg': min(b['min'] for b in before) if before else None,
            'heading_before_max_deg': max(b['max'] for b in before) if before else None,
            'heading_after_max_abs_deg': max(a['max_abs'] for a in after) if after else None,
            'heading_after_rms_deg': (float(np.sqrt(np.mean([a['rms'] ** 2 for a in after])))
                                      if after else None),
            # a run whose heading was not within the bound at its end counts as longest
            'heading_settling_median_s': (_finite(np.median(settled + [math.inf] * never))
                                          if settling else None),
            'heading_settling_max_s': float(np.max(settled)) if settled and not never else None,
            'heading_not_settled_runs': never}
        figures[v] = fig
        settling_max = (_fmt(fig['heading_settling_max_s'], 2) if not never
                        else f'{never} run(s) not within it at the end')
        before_txt = (f'{fig["heading_before_min_deg"]:+.2f} … '
                      f'{fig["heading_before_max_deg"]:+.2f}' if before else '–')
        rows.append(f'| {v} | {_cm(fig["every_pose_max_m"])} | {_cm(fig["every_pose_mean_m"])} | '
                    f'{_fmt(fig["covariance_3sigma_fraction"], 1, 100)} % | {before_txt} | '
                    f'{_fmt(fig["heading_after_max_abs_deg"], 3)} | '
                    f'{_fmt(fig["heading_after_rms_deg"], 3)} | '
                    f'{_fmt(fig["heading_settling_median_s"], 2)} / {settling_max} |')
    return '\n'.join(rows), figures


def identification_table(results):
    """Lamp identification per speed (decoder output against the rig's true spots)."""
    rows = ['| speed (km/h) | lamps in view | identified | lamps passed (seen closer than '
            f'{identification.PASSED_WITHIN_M:g} m) | passed and identified | first '
            'confirmation: median (m before the lamp) | min (m) | identified frames | wrong '
            'UIDs accepted | anomalies |', '|---|---|---|---|---|---|---|---|---|---|']
    dist_rows = ['| speed (km/h) | ' + ' | '.join(f'{lo}–{lo + 1} m' for lo in range(10))
                 + ' |', '|---|' + '---|' * 10]
    figures = {}
    for v, runs in _by_speed(results).items():
        ids = [r['identification'] for r in runs if r.get('identification')]
        if not ids:
            continue
        first = [d for i in ids for d in i['first_confirmation_m'].values()]
        confirmed = [d for d in first if d is not None]
        frames = [f for i in ids for f in i['frames']]
        wrong = sum(i['wrong_uids'] for i in ids)
        anomalies = sum(i['anomalies'] for i in ids)
        passed = [identification.passed_lamps(i['frames'], i['first_confirmation_m'])
                  for i in ids]
        bins = identification.success_by_distance(frames)
        frame_rate = float(np.mean([f[3] for f in frames])) if frames else None
        fig = {'lamps_in_view': len(first), 'lamps_identified': len(confirmed),
               'lamps_passed': sum(p for p, _ in passed),
               'lamps_passed_identified': sum(i for _, i in passed),
               'first_confirmation_median_m': float(np.median(confirmed)) if confirmed else None,
               'first_confirmation_min_m': float(np.min(confirmed)) if confirmed else None,
               'identified_frame_rate': frame_rate, 'wrong_uids_accepted': wrong,
               'anomalies': anomalies, 'by_distance': bins}
        figures[v] = fig
        rows.append(f'| {v} | {fig["lamps_in_view"]} | {fig["lamps_identified"]} | '
                    f'{fig["lamps_passed"]} | {fig["lamps_passed_identified"]} | '
                    f'{_fmt(fig["first_confirmation_median_m"])} | '
                    f'{_fmt(fig["first_confirmation_min_m"])} | '
                    f'{_fmt(frame_rate, 1, 100)} % | {wrong} | {anomalies} |')
        dist_rows.append(f'| {v} | ' + ' | '.join(
            '–' if b['identified'] is None else f'{100 * b["identified"]:.0f} %'
            for b in bins) + ' |')
    return '\n'.join(rows), '\n'.join(dist_rows), figures


LATENCY_ROWS = (('vlc_decoder', 'decoder', 'frame complete → vlc/lamps sent'),
                ('spot_locator', 'spot_locator', 'frame complete → spots/pairs sent'),
                ('train_localizer', 'localizer', 'later input sent → train/pose sent'),
                ('imu_compensator', 'imu_compensator', 'imu/data_raw sent → imu/data sent'),
                ('end to end', 'exposure_to_pose', 'spot exposure → train/pose sent'),
                ('… of it: readout', 'readout_wait',
                 'spot exposure → frame complete (the rolling shutter: physical)'),
                ('… of it: the graph', 'frame_to_pose', 'frame complete → train/pose sent'))


def latency_table(results):
    """Per node latency (receive log) and self-reported processing time.

    Latency means wall time, so only runs at a real-time factor of 1 count when there
    are any (a slowed-down run gives each node more time per frame).
    """
    realtime = [r for r in results if r.get('scenario', {}).get('realtime_factor', 1.0) == 1.0]
    used = realtime or list(results)
    rows = ['| node | measured | median (ms) | p99 (ms) | max (ms) | samples | processing per '
            'frame, node-reported: median / p99 / max (ms) |', '|---|---|---|---|---|---|---|']
    figures = {'runs': len(used), 'realtime_only': bool(realtime)}
    for node, key, what in LATENCY_ROWS:
        samples = [x for r in used for x in r.get('latency_ms', {}).get(key, [])]
        lat = latency.summarize_ms(samples)
        med, p99, top = _processing_columns(used, node)
        figures[key] = dict(lat, processing_median_ms=float(np.median(med)) if med else None,
                            processing_p99_ms=float(np.max(p99)) if p99 else None,
                            processing_max_ms=float(np.max(top)) if top else None)
        proc_txt = (f'{np.median(med):.2f} / {_fmt(figures[key]["processing_p99_ms"])} / '
                    f'{np.max(top):.2f}' if med and top else '–')
        rows.append(f'| {node} | {what} | {_fmt(lat["median_ms"])} | {_fmt(lat["p99_ms"])} | '
                    f'{_fmt(lat["max_ms"])} | {lat["count"]} | {proc_txt} |')
    note = (f'{len(used)} runs' + (' at real-time factor 1' if realtime else
                                   ' (none at real-time factor 1: wall times of slowed runs)'))
    return '\n'.join(rows) + (f'\n\nLatency over {note}. Processing: the median of the runs\' '
                              f'medians, the largest p99 and max (each node reports them over '
                              f'its last few hundred frames).'), figures


def _processing_columns(results, node):
    """Node-reported processing per frame of ``node`` over ``results``: the runs'
    medians, p99s and maxima (lists, ms). A result of a bag recorded before the nodes
    reported their p99 holds [median, max].
    """
    med, p99, top = [], [], []
    for r in results:
        values = (r.get('processing_ms') or {}).get(node)
        if not values:
            continue
        if len(values) == 2:
            values = [values[0], None, values[1]]
        for column, value in zip((med, p99, top), values):
            if value is not None:
                column.append(value)
    return med, p99, top


LATENCY_LOG = 'latency_runs.jsonl'


def replays_by_profile(results):
    """Replay results split by the rig profile their bags were recorded on: (the
    ``ideal`` rig's, every drawn profile's).
    """
    def profile(r):
        return (r.get('scenario') or {}).get('rig_profile', 'ideal')
    return ([r for r in results if profile(r) == 'ideal'],
            [r for r in results if profile(r) != 'ideal'])


def append_latency_run(out_dir, command, figures, after_s, live=None, realistic=None):
    """Append one latency-replay run's end-to-end and processing figures (the
    ``figures`` of :func:`latency_table`) to ``out_dir/latency_runs.jsonl``; ``after_s``:
    wall seconds the same command had run the graph before the replays (the protocols);
    ``live``: the same figures of the live graph alone, when it ran; ``realistic``: those
    of the realistic profile's bags replayed.
    """
    e2e = figures.get('exposure_to_pose', {})
    entry = {'finished': time.strftime('%Y-%m-%d %H:%M'), 'command': command,
             'after_min': round(after_s / 60.0, 1), 'samples': e2e.get('count', 0),
             'median_ms': e2e.get('median_ms'), 'p99_ms': e2e.get('p99_ms'),
             'max_ms': e2e.get('max_ms')}
    for key in ('decoder', 'spot_locator', 'localizer'):
        entry[f'{key}_processing_ms'] = figures.get(key, {}).get('processing_median_ms')
        entry[f'{key}_processing_p99_ms'] = figures.get(key, {}).get('processing_p99_ms')
    if live:
        live_e2e = live.get('exposure_to_pose', {})
        entry.update(live_median_ms=live_e2e.get('median_ms'), live_p99_ms=live_e2e.get('p99_ms'),
                     live_samples=live_e2e.get('count', 0))
    if realistic:
        real_e2e = realistic.get('exposure_to_pose', {})
        entry.update(realistic_median_ms=real_e2e.get('median_ms'),
                     realistic_p99_ms=real_e2e.get('p99_ms'),
                     realistic_samples=real_e2e.get('count', 0))
        for key in ('decoder', 'spot_locator'):
            entry[f'realistic_{key}_processing_ms'] = realistic.get(key, {}).get(
                'processing_median_ms')
    with open(pathlib.Path(out_dir) / LATENCY_LOG, 'a', encoding='utf-8') as log:
        log.write(json.dumps(entry) + '\n')


def latency_runs_table(out_dir):
    """Every latency-replay run logged in ``out_dir`` (Markdown, '' if none), oldest
    first, and their entries: the spread of one machine's moments on the same code.
    """
    path = pathlib.Path(out_dir) / LATENCY_LOG
    if not path.exists():
        return '', []
    runs = [json.loads(line) for line in path.read_text(encoding='utf-8').splitlines()
            if line.strip()]
    rows = ['| finished | command | after the protocols (min) | samples | end to end median '
            '/ p99 / max (ms) | processing median (p99): decoder / spot locator / localizer '
            '(ms) | live graph alone: end to end median / p99 (ms) | realistic bags: end to '
            'end median / p99, processing median decoder / spot locator (ms) |',
            '|---|---|---|---|---|---|---|---|']

    def proc(r, key):
        p99 = r.get(f'{key}_processing_p99_ms')
        return _fmt(r[f'{key}_processing_ms']) + (f' ({p99:.2f})' if p99 is not None else '')
    for r in runs:
        live = (f'{_fmt(r["live_median_ms"])} / {_fmt(r["live_p99_ms"])}'
                if r.get('live_samples') else '–')
        real = (f'{_fmt(r["realistic_median_ms"])} / {_fmt(r["realistic_p99_ms"])}, '
                f'{_fmt(r.get("realistic_decoder_processing_ms"))} / '
                f'{_fmt(r.get("realistic_spot_locator_processing_ms"))}'
                if r.get('realistic_samples') else '–')
        rows.append(f'| {r["finished"]} | `{r["command"]}` | {r["after_min"]:.1f} | '
                    f'{r["samples"]} | {_fmt(r["median_ms"])} / {_fmt(r["p99_ms"])} / '
                    f'{_fmt(r["max_ms"])} | {proc(r, "decoder")} / {proc(r, "spot_locator")} / '
                    f'{proc(r, "localizer")} | {live} | {real} |')
    return '\n'.join(rows), runs


def _lockstep(result):
    """Whether ``result`` is of a lockstep graph (:mod:`.lockstep`), not the graph's."""
    return bool(result.get('scenario', {}).get('lockstep'))


def health_summary(results):
    """How the runs went: reruns, real-time factors, runs still degraded."""
    flagged = [r for r in results if r.get('health', {}).get('degraded')]
    lag = max([r['health']['camera_lag_max_s'] for r in results if r.get('health')],
              default=0.0)
    rtf = [r['scenario']['realtime_factor'] for r in results if 'scenario' in r]
    reruns = sum(r.get('attempts', 1) - 1 for r in results)
    lockstep = sum(_lockstep(r) for r in results)
    text = (f'Graph health: {len(results)} runs, {reruns} rerun(s) because a node fell '
            f'behind; real-time factor {min(rtf, default=1):.2f}–{max(rtf, default=1):.2f}; '
            f'{len(flagged)} kept run(s) still had a node falling behind (camera lag > 0.1 s, '
            f'dropped frames or IMU samples; largest camera lag {lag:.2f} s).')
    if lockstep:
        text += (f' {lockstep} of the {len(results)} runs were lockstep graphs (the nodes in '
                 'one process on simulated time, vlc_evaluation.lockstep: nothing there can '
                 'fall behind; the real-time factor is not theirs).')
    return text, {'runs': len(results), 'reruns': reruns, 'degraded_runs': len(flagged),
                  'lockstep_runs': lockstep,
                  'camera_lag_max_s': lag,
                  'realtime_factor_min': min(rtf, default=None),
                  'realtime_factor_max': max(rtf, default=None),
                  'degraded': [r['scenario']['name'] for r in flagged if 'scenario' in r]}


PHASES = (('start', None, 'started'), ('ready', 'started', 'ready'),
          ('gate', 'ready', 'sim_started'), ('simulated run', 'sim_started', 'camera_done'),
          ('drain', 'camera_done', 'drained'), ('stop', 'drained', 'stopped'))
#: A lockstep graph's phases (runner.run_scenario_lockstep): one process builds its nodes
#: and simulates the scenario at once.
LOCKSTEP_PHASES = (('start', None, 'started'), ('build and simulate', 'started', 'ran'),
                   ('stop', 'ran', 'stopped'))


def timing_summary(results, phase_names=PHASES):
    """Where the wall time of a run goes (median per phase of ``phase_names``, s), each node's CPU
    (median, s) and peak RSS (median and largest, MiB) and the whole graph's (the sum of
    a run's nodes: median and largest run), over the kept attempts of ``results``.
    """
    timings = [r['timing'] for r in results if r.get('timing', {}).get('stopped')]
    if not timings:
        return '', {}
    phases = {}
    for name, start, end in phase_names:
        d = [t[end] - (t[start] if start else 0.0) for t in timings if end in t
             and (start is None or start in t)]
        phases[name] = float(np.median(d)) if d else None
    phases['score'] = float(np.median([t.get('score_s', 0.0) for t in timings]))
    cpu = {}
    for t in timings:
        for node, seconds in t.get('cpu_s', {}).items():
            cpu.setdefault(node, []).append(seconds)
    cpu = {node: float(np.median(v)) for node, v in sorted(cpu.items())}
    rss, graph_rss = {}, []
    for t in timings:
        peaks = t.get('rss_mib', {})
        for node, mib in peaks.items():
            rss.setdefault(node, []).append(mib)
        if peaks:
            graph_rss.append(sum(peaks.values()))
    rss_max = {node: float(np.max(v)) for node, v in sorted(rss.items())}
    rss = {node: float(np.median(v)) for node, v in sorted(rss.items())}
    text = ('Wall time per run (median, s): ' + ', '.join(
        f'{k} {v:.2f}' for k, v in phases.items() if v is not None)
        + (f'. CPU per run (median, s): {sum(cpu.values()):.2f} = ' + ', '.join(
            f'{k} {v:.2f}' for k, v in cpu.items()) if cpu else '')
        + (f'. Peak RSS per node (median of the runs, MiB; pages shared with the fork '
           f'server counted in each node, so the sum is an upper bound): whole graph '
           f'{np.median(graph_rss):.0f} (largest run {max(graph_rss):.0f}) = ' + ', '.join(
               f'{k} {v:.0f}' for k, v in rss.items()) if rss else '') + '.')
    ready = {}
    for t in timings:
        for topic, at in t.get('ready_topics', {}).items():
            ready.setdefault(topic, []).append(at)
    ready = dict(sorted(((topic, float(np.median(v))) for topic, v in ready.items()),
                        key=lambda item: item[1]))
    if ready:
        text += (' Ready phase, the last awaited subscriptions (median s since the start): '
                 + ', '.join(f'{k} {v:.2f}' for k, v in list(ready.items())[-3:]) + '.')
    summary = {'phases_s': phases, 'cpu_s': cpu, 'runs': len(timings)}
    cost = cpu_per_simulated_second(results)
    if cost:
        summary['cpu_per_simulated_s'] = cost
        text += (f" CPU over the {cost['runs']} kept runs: {cost['cpu_s']:.0f} CPU-s for "
                 f"{cost['simulated_s']:.0f} s simulated, {cost['ratio']:.2f} CPU-s per "
                 f"simulated second; on {cost['cores']} cores that alone is at least "
                 f"{cost['cpu_s'] / cost['cores']:.0f} s of wall time at any pace (reruns "
                 'not counted).')
    if ready:
        summary['ready_topics_s'] = ready
    if rss:
        summary.update(rss_mib=rss, rss_max_mib=rss_max,
                       graph_rss_mib={'median': float(np.median(graph_rss)),
                                      'max': float(max(graph_rss))})
    return text, summary


def cpu_per_simulated_second(results, cores=None):
    """The graph's CPU cost per simulated second over the kept runs of ``results`` that
    carry both their nodes' CPU (``timing.cpu_s``) and their simulated length
    (``scenario.duration_s``): ``{'runs', 'cpu_s', 'simulated_s', 'ratio', 'cores'}``,
    or None. ``cpu_s / cores`` is a lower bound on the wall time of those runs on this
    machine whatever the pace or the number of lanes: #21's arithmetic.
    """
    cpu = simulated = 0.0
    runs = 0
    for r in results:
        seconds = r.get('timing', {}).get('cpu_s')
        duration = r.get('scenario', {}).get('duration_s')
        if seconds and duration:
            cpu += sum(seconds.values())
            simulated += float(duration)
            runs += 1
    if not runs or simulated <= 0.0:
        return None
    cores = int(cores or os.cpu_count() or 1)
    return {'runs': runs, 'cpu_s': cpu, 'simulated_s': simulated, 'ratio': cpu / simulated,
            'cores': cores}


def plot_heading(results, path):
    """Heading error before and after IMU compensation over one run (like paper Fig. 13a)."""
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt
    series = [r for r in results if r.get('heading_series', {}).get('t_s')]
    if not series:
        return False
    run = min(series, key=lambda r: r['speed_kmh'])
    h = run['heading_series']
    fig, ax = plt.subplots(figsize=(8, 4))
    ax.plot(h['t_s'], h['before_deg'], color='C3', lw=1,
            label='before: platform heading vs track (uncompensated)')
    ax.plot(h['t_s'], h['after_deg'], color='C0', lw=1.2,
            label='after: compensated heading − true heading')
    ax.axhline(0.5, color='k', ls=':', lw=0.8, label='paper after: < 0.5°')
    ax.axhline(-0.5, color='k', ls=':', lw=0.8)
    ax.set_xlabel('time (s)')
    ax.set_ylabel('heading error (deg)')
    ax.set_title(f'Heading before and after IMU compensation, {run["speed_kmh"]:.0f} km/h '
                 f'(seed {run["seed"]})')
    ax.legend(fontsize=8)
    ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return True


def compact(result):
    """A scenario result without its per-frame arrays (for report.json)."""
    out = {k: v for k, v in result.items()
           if k not in ('latency_ms', 'heading_series', 'identification')}
    if result.get('latency_ms'):
        out['latency_ms'] = {k: latency.summarize_ms(v) for k, v in result['latency_ms'].items()}
    if result.get('identification'):
        ident = result['identification']
        out['identification'] = {k: v for k, v in ident.items() if k != 'frames'}
    return out


# One line per graph run into a report folder (command, scenarios, wall time): run_evaluation
RUN_LOG = 'runs.jsonl'
FIGURES = ('static_error_vs_distance.png', 'dynamic_error_per_speed.png',
           'heading_compensation.png', 'ablations.png')


def replay_table(results):
    """Sensor bags replayed through the processing nodes (bag_player instead of the rig)."""
    rows = ['| replayed bag | poses | first pose after (s) | every pose after it: max (cm) | '
            'mean (cm) | 95th pct (cm) | lamps identified / in view | wrong UIDs accepted |',
            '|---|---|---|---|---|---|---|---|']
    figures = {}
    for r in results:
        every = r.get('every_pose') or {}
        ident = r.get('identification') or {}
        first = ident.get('first_confirmation_m', {})
        fig = {'poses': r['poses'], 'first_pose_s': r.get('first_pose_s'),
               'every_pose': every or None,
               'lamps_identified': sum(v is not None for v in first.values()),
               'lamps_in_view': len(first), 'wrong_uids': ident.get('wrong_uids')}
        figures[r['bag']] = fig
        rows.append(f'| `{r["bag"]}` | {r["poses"]} | {_fmt(r.get("first_pose_s"))} | '
                    f'{_cm(every.get("max_m"))} | {_cm(every.get("mean_m"))} | '
                    f'{_cm(every.get("p95_m"))} | {fig["lamps_identified"]} / '
                    f'{fig["lamps_in_view"]} | {fig["wrong_uids"]} |')
    return '\n'.join(rows), figures


def write_report(static_results, dynamic_results, out_dir, title='Accuracy', ablations=None,
                 replays=None, live_alone=None):
    """Write ``report.md``, ``report.json`` and PNGs into ``out_dir``; returns the text.

    ``ablations``: optional ``(markdown, figures)`` of :mod:`.ablations`; ``replays``:
    results of replayed sensor bags; ``live_alone``: results of the whole live graph run
    alone at real time (its latency).
    """
    out_dir = pathlib.Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    parts, figures = [f'## {title}'], {}
    everything = list(static_results) + list(dynamic_results) + list(replays or [])
    if static_results:
        table, figures['static'] = static_table(static_results)
        plot_static(static_results, out_dir / 'static_error_vs_distance.png')
        observe = sorted({r['scenario']['observe_s'] for r in static_results
                          if 'scenario' in r})
        parts += ['', '### Static protocol', '',
                  f'The train stands 10.0, 9.5, … 0.5 m before a lamp; the result of a trial '
                  f'is the last pose published after {", ".join(f"{o:g}" for o in observe)} s '
                  f'of simulated time (none: a miss). Raw rows: the same trials without any '
                  f'filtering — each recorded `spots/pairs` pair whose spot the decoder '
                  f'confirmed in that frame, triangulated (eq. 12) and placed in the map by the '
                  f'localizer core with the `imu/data` attitude; the trial\'s last frame.',
                  '', table, '', '![static](static_error_vs_distance.png)']
    if dynamic_results:
        table, figures['dynamic'] = dynamic_table(dynamic_results)
        plot_dynamic(dynamic_results, out_dir / 'dynamic_error_per_speed.png')
        parts += ['', '### Dynamic protocol (errors at the test points)', '', table, '',
                  '![dynamic](dynamic_error_per_speed.png)']
        table, figures['dynamic_detail'] = dynamic_detail_table(dynamic_results)
        parts += ['', '### Every published pose, covariance bound, heading compensation', '',
                  table]
        if plot_heading(dynamic_results, out_dir / 'heading_compensation.png'):
            parts += ['', '![heading](heading_compensation.png)']
        table, by_dist, figures['identification'] = identification_table(dynamic_results)
        parts += ['', '### Lamp identification', '', table, '',
                  'Frames with the lamp identified (its own confirmed UID) by along-track '
                  'distance to the lamp:', '', by_dist]
    # a lockstep run has no latency (its nodes take no simulated time)
    live = [r for r in list(static_results) + list(dynamic_results) if not _lockstep(r)]
    if live:
        table, figures['latency'] = latency_table(live)
        parts += ['', '### Latency', '', 'Over the protocol runs above, on their parallel lanes '
                  '(several graphs at once on the machine: not the train\'s case, which the '
                  'replay and the live graph alone below measure).', '', table]
    ideal_replays, drawn_replays = replays_by_profile(replays or [])
    if ideal_replays:
        # The on-train case: sensors arrive from a player (frames a readout after their
        # stamp, as from the camera), the cores run only the processing nodes and the
        # recorder, not the rig's renderer.
        table, figures['latency_replay'] = latency_table(ideal_replays)
        parts += ['', '### Latency, sensor bags replayed through the processing nodes', '',
                  table]
    if drawn_replays:
        profiles = sorted({r['scenario']['rig_profile'] for r in drawn_replays})
        table, figures['latency_replay_realistic'] = latency_table(drawn_replays)
        parts += ['', '### Latency, sensor bags of a drawn installation replayed', '',
                  f'Rig profile {", ".join(f"`{p}`" for p in profiles)}: the raw, distorted '
                  'images of a real lens and its wider field (about twice the lamp spots per '
                  'frame of the ideal rig), the receivers given the installation\'s belief.',
                  '', table]
    if live_alone:
        table, figures['latency_live'] = latency_table(live_alone)
        behind = [r for r in live_alone if r.get('health', {}).get('degraded')]
        figures['latency_live']['behind'] = len(behind)
        parts += ['', '### Latency, the whole live graph alone at real time', '',
                  'The rig (renderer and IMU), the processing nodes and the recorder, nothing '
                  'else on the machine; a run in which a node fell behind is kept and counted, '
                  f'not rerun: {len(behind)} of {len(live_alone)} runs had a node behind.', '',
                  table]
    if replays:
        runs, figures['latency_runs'] = latency_runs_table(out_dir)
        if runs:
            parts += ['', 'Every latency replay run into this output folder (the table above '
                      'is the last one; the same code and bags, the machine at different '
                      'moments):', '', runs]
    if everything:
        text, figures['health'] = health_summary(everything)
        parts += ['', text]
        # the graph's runs and the lockstep graphs' apart: one process on simulated time
        # costs and takes its time otherwise than a process per node paced by the clock
        lockstep = [r for r in everything if _lockstep(r)]
        graph = [r for r in everything if not _lockstep(r)]
        for key, runs, label, phase_names in (
                ('timing', graph, 'Graph runs', PHASES),
                ('timing_lockstep', lockstep, 'Lockstep graphs', LOCKSTEP_PHASES)):
            text, summary = timing_summary(runs, phase_names)
            if text:
                figures[key] = summary
                parts += ['', (f'{label} ({len(runs)}): ' if lockstep else '') + text]
    if replays:
        table, figures['replay'] = replay_table(replays)
        parts += ['', '### Replayed sensor bag', '', table]
    if ablations is not None:
        table, figures['ablations'] = ablations
        parts += ['', '### Ablations', '', table]
        if (out_dir / 'ablations.png').exists():
            parts += ['', '![ablations](ablations.png)']
    text = '\n'.join(parts) + '\n'
    (out_dir / 'report.md').write_text(text, encoding='utf-8')
    (out_dir / 'report.json').write_text(json.dumps(
        {'figures': figures, 'static': [compact(r) for r in static_results],
         'dynamic': [compact(r) for r in dynamic_results],
         'replay': [compact(r) for r in replays or []],
         'latency_live': [compact(r) for r in live_alone or []]},
        indent=1, default=float), encoding='utf-8')
    return text


BEGIN_MARK = '<!-- evaluation:begin (generated by run_evaluation --readme; do not edit) -->'
END_MARK = '<!-- evaluation:end -->'
#: Where the full tables go, relative to the README's folder.
RESULTS_FILE = pathlib.Path('docs') / 'RESULTS.md'
RESULTS_TITLE = ('# Results\n\nEvery table and figure below is written by the evaluation '
                 'command named under the heading, from the bags it recorded; the README '
                 'shows a summary of it.\n\n')


def replace_marked_block(path, section, title='', begin=BEGIN_MARK, end=END_MARK):
    """Replace the block of ``path`` from marker ``begin`` to marker ``end`` by
    ``section`` (which carries the markers; appended when absent; the file is created
    with ``title`` when missing).
    """
    path = pathlib.Path(path)
    text = path.read_text(encoding='utf-8') if path.exists() else title
    if begin in text and end in text:
        head, rest = text.split(begin, 1)
        _, tail = rest.split(end, 1)
        text = head + section + tail
    else:
        text = text.rstrip('\n') + '\n\n' + section + '\n'
    path.write_text(text, encoding='utf-8')


def _max_mean(fig):
    return f'{_cm(fig["max_m"])} / {_cm(fig["mean_m"])}' if fig and fig.get('count') else '–'


def _protocol_rows(names, figure_sets):
    """Markdown table lines (header first) of the paper's protocols: one column of max /
    mean per ``names``/``figure_sets`` pair (report.json figures; the first set decides
    the rows), then the paper's.
    """
    lines = ['| protocol | ' + ' | '.join(f'{n}: max / mean (cm)' for n in names)
             + ' | paper: max / mean (cm) |', '|---' * (len(names) + 2) + '|']
    first = figure_sets[0]
    static = first.get('static', {}).get('ours')
    if static:
        cells = ' | '.join(_max_mean(f.get('static', {}).get('ours')) for f in figure_sets)
        lines.append(f'| static, 0.5–10 m before a lamp ({static["count"]} results, '
                     f'{static["misses"]} misses) | {cells} | '
                     f'{PAPER_STATIC["max_cm"]:.2f} / {PAPER_STATIC["mean_cm"]:.2f} |')
    for speed, fig in sorted(first.get('dynamic', {}).items(), key=lambda kv: float(kv[0])):
        if not fig.get('test_points', {}).get('count'):
            continue
        paper = PAPER_DYNAMIC.get(int(float(speed)), {})
        cells = ' | '.join(_max_mean(f.get('dynamic', {}).get(speed, {}).get('test_points'))
                           for f in figure_sets)
        lines.append(f'| dynamic, {float(speed):.0f} km/h (test points) | {cells} | '
                     + (f'{paper["max_cm"]:.2f} / {paper["mean_cm"]:.2f}' if paper else '–')
                     + ' |')
    return lines


def summary_markdown(figures, results_link):
    """The README's summary of the evaluation: the paper's protocols, ours beside the
    paper's, and where the full tables are.
    """
    lines = _protocol_rows(['ours'], [figures])
    replay = figures.get('latency_replay', {}).get('exposure_to_pose', {})
    text = '\n'.join(lines) + '\n'
    live = figures.get('latency_live', {}).get('exposure_to_pose', {})
    real = figures.get('latency_replay_realistic', {}).get('exposure_to_pose', {})
    if replay.get('count'):
        text += (f'\nEnd-to-end latency, spot exposure to `train/pose`, sensor bags replayed '
                 f'at real time: median {replay["median_ms"]:.1f} ms, p99 '
                 f'{replay["p99_ms"]:.1f} ms'
                 + (f' (`realistic` rig profile: median {real["median_ms"]:.1f} ms, p99 '
                    f'{real["p99_ms"]:.1f} ms)' if real.get('count') else '')
                 + (f'; the whole live graph alone at real time: median '
                    f'{live["median_ms"]:.1f} ms, p99 {live["p99_ms"]:.1f} ms'
                    if live.get('count') else '') + ' (paper: 48–51 ms per fix).\n')
    return text + (f'\nEvery table (per speed and test point, covariance bound, heading, lamp '
                   f'identification, latency, ablations, the other methods, lamp outage, '
                   f'forged lamp, faults) and figure: [{results_link}]({results_link}).\n')


PROFILE_BEGIN = '<!-- profiles:begin -->'
PROFILE_END = '<!-- profiles:end -->'


def _inside_3sigma(figures):
    """Share of every published pose inside its 3σ, over all dynamic speeds (count
    weighted equally per speed), or None.
    """
    shares = [d.get('covariance_3sigma_fraction') for d in
              figures.get('dynamic_detail', {}).values()]
    shares = [v for v in shares if v is not None]
    return sum(shares) / len(shares) if shares else None


def profile_summary(profile, figures, reference=None, reference_name='ideal'):
    """Markdown: the paper's protocols on rig profile ``profile`` (``figures`` of its
    report.json), beside ``reference`` figures (the main evaluation, another profile)
    and the paper's.
    """
    ref = reference or {}
    lines = _protocol_rows([profile, reference_name], [figures, ref])
    ours, theirs = _inside_3sigma(figures), _inside_3sigma(ref)
    lines.append('| every published pose within its 3σ (dynamic) | '
                 + ('–' if ours is None else f'{100 * ours:.1f} %') + ' | '
                 + ('–' if theirs is None else f'{100 * theirs:.1f} %') + ' | – |')
    return '\n'.join(lines) + '\n'


def update_profile_docs(markdown_path, report_dir, profile, command, reference_json=None):
    """Write :func:`profile_summary` of ``report_dir/report.json`` between the profile
    markers of ``markdown_path``, beside the figures of ``reference_json`` (default: the
    main evaluation's ``docs/evaluation/report.json`` beside ``markdown_path``).
    """
    markdown_path = pathlib.Path(markdown_path)
    figures = json.loads((pathlib.Path(report_dir) / 'report.json')
                         .read_text(encoding='utf-8'))['figures']
    ref_path = pathlib.Path(reference_json) if reference_json else (
        markdown_path.parent / 'docs' / 'evaluation' / 'report.json')
    reference = (json.loads(ref_path.read_text(encoding='utf-8'))['figures']
                 if ref_path.exists() else {})
    text = profile_summary(profile, figures, reference)
    section = (f'{PROFILE_BEGIN}\nGenerated by `{command}` (rig profile `{profile}`, a drawn '
               f'installation per scenario seed; `ideal` from `{ref_path.name}` of the main '
               f'evaluation below).\n\n{text}{PROFILE_END}')
    replace_marked_block(markdown_path, section, begin=PROFILE_BEGIN, end=PROFILE_END)


def update_markdown(markdown_path, report_dir, command):
    """Write the evaluation into ``docs/RESULTS.md`` beside ``markdown_path`` (the full
    ``report_dir/report.md``) and its summary between the README's evaluation markers.

    The report's PNGs and JSON are copied to ``docs/evaluation/`` and the image links
    rewritten to point there; the command line that produced the figures is written
    above both. ``docs/RESULTS.html`` is written from ``docs/RESULTS.md`` too, one page
    with the figures embedded (:mod:`.html_report`).
    """
    import shutil
    markdown_path = pathlib.Path(markdown_path)
    report_dir = pathlib.Path(report_dir)
    docs = markdown_path.parent / 'docs'
    target = docs / 'evaluation'
    target.mkdir(parents=True, exist_ok=True)
    body = (report_dir / 'report.md').read_text(encoding='utf-8')
    for name in ('report.json',) + FIGURES:
        if (report_dir / name).exists():
            shutil.copy(report_dir / name, target / name)
            body = body.replace(f']({name})', f'](evaluation/{name})')
    runs = ''
    if (report_dir / RUN_LOG).exists():
        lines = [json.loads(line) for line in
                 (report_dir / RUN_LOG).read_text(encoding='utf-8').splitlines() if line]
        runs = 'The bags were recorded by:\n\n' + ''.join(
            f'- `{r["command"]}`: {r["scenarios"]} scenarios on {r["lanes"]} lane(s), '
            f'{r["wall_s"] / 60:.1f} min wall time ({r["cpus"]} cores, {r["finished"]})\n'
            for r in lines) + '\n'
    generated = f'Generated by `{command}` (all figures in `docs/evaluation/report.json`).'
    replace_marked_block(markdown_path.parent / RESULTS_FILE,
                   f'{BEGIN_MARK}\n{generated}\n\n{runs}{body}{END_MARK}', RESULTS_TITLE)
    html_report.write_html(markdown_path.parent / RESULTS_FILE)
    figures = json.loads((report_dir / 'report.json').read_text(encoding='utf-8'))['figures']
    replace_marked_block(markdown_path, f'{BEGIN_MARK}\n{generated}\n\n'
                   f'{summary_markdown(figures, RESULTS_FILE.as_posix())}{END_MARK}')
