"""Tables (Markdown), figures (PNG) and the JSON of every figure, from scored runs.

The paper's figures (``shared/EVALUATION.md``) are printed beside ours; nothing here is
typed in from a measurement: every number of ours comes from the results passed in.
"""
import json
import pathlib

import numpy as np

from . import metrics

PAPER_STATIC = {'max_cm': 29.73, 'min_cm': 2.68, 'mean_cm': 10.48, 'p90_cm': 20.0}
PAPER_DYNAMIC = {20: {'max_cm': 32.09, 'mean_cm': 11.07, 'p75_cm': 18.0},
                 40: {'max_cm': 33.05, 'mean_cm': 14.21, 'p75_cm': 19.0},
                 60: {'max_cm': 34.25, 'mean_cm': 15.33, 'p75_cm': 22.0},
                 80: {'max_cm': 34.75, 'mean_cm': 16.52, 'p75_cm': 23.0},
                 100: {'max_cm': 36.11, 'mean_cm': 17.68, 'p75_cm': 23.5}}


def _cm(value):
    return '–' if value is None or not np.isfinite(value) else f'{100.0 * value:.2f}'


def _paper(value):
    return '–' if value is None else f'{value:.2f}'


def static_table(results):
    """Markdown table of the static protocol, ours beside the paper's."""
    errors = [r['error_m'] for r in results if r.get('error_m') is not None]
    misses = sum(1 for r in results if r.get('error_m') is None)
    along = [abs(r['along_m']) for r in results if r.get('along_m') is not None]
    s = metrics.summarize(errors, misses=misses)
    a = metrics.summarize(along)
    rows = ['| static protocol | max (cm) | mean (cm) | min (cm) | 90th pct (cm) | results | misses |',
            '|---|---|---|---|---|---|---|',
            f'| this project, Euclidean | {_cm(s.max_m)} | {_cm(s.mean_m)} | {_cm(s.min_m)} | '
            f'{_cm(s.p90_m)} | {s.count} | {s.misses} |',
            f'| this project, along track | {_cm(a.max_m)} | {_cm(a.mean_m)} | {_cm(a.min_m)} | '
            f'{_cm(a.p90_m)} | {a.count} | – |',
            f'| paper (Acta Optica Sinica 2023) | {_paper(PAPER_STATIC["max_cm"])} | '
            f'{_paper(PAPER_STATIC["mean_cm"])} | {_paper(PAPER_STATIC["min_cm"])} | '
            f'< {_paper(PAPER_STATIC["p90_cm"])} | 200 | – |']
    return '\n'.join(rows), {'ours': s.as_dict(), 'ours_along_track': a.as_dict()}


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
    if pts:
        d, e = np.array(pts).T
        ax.plot(d, e, 'o', alpha=0.5, label='this project (each trial)')
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


def write_report(static_results, dynamic_results, out_dir, title='Accuracy'):
    """Write ``report.md``, ``report.json`` and PNGs into ``out_dir``; returns the text."""
    out_dir = pathlib.Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    parts, figures = [f'## {title}'], {}
    if static_results:
        table, figures['static'] = static_table(static_results)
        plot_static(static_results, out_dir / 'static_error_vs_distance.png')
        parts += ['', table, '', '![static](static_error_vs_distance.png)']
    if dynamic_results:
        table, figures['dynamic'] = dynamic_table(dynamic_results)
        plot_dynamic(dynamic_results, out_dir / 'dynamic_error_per_speed.png')
        parts += ['', table, '', '![dynamic](dynamic_error_per_speed.png)']
    text = '\n'.join(parts) + '\n'
    (out_dir / 'report.md').write_text(text, encoding='utf-8')
    (out_dir / 'report.json').write_text(json.dumps(
        {'figures': figures, 'static': static_results, 'dynamic': dynamic_results},
        indent=1, default=float), encoding='utf-8')
    return text


BEGIN_MARK = '<!-- evaluation:begin (generated by run_evaluation --readme; do not edit) -->'
END_MARK = '<!-- evaluation:end -->'


def update_markdown(markdown_path, report_dir, command):
    """Put ``report_dir/report.md`` between the evaluation markers of ``markdown_path``.

    The report's PNGs and JSON are copied to ``docs/evaluation/`` beside the Markdown
    file and the image links rewritten to point there; the command line that produced
    the figures is written above them.
    """
    import shutil
    markdown_path = pathlib.Path(markdown_path)
    report_dir = pathlib.Path(report_dir)
    target = markdown_path.parent / 'docs' / 'evaluation'
    target.mkdir(parents=True, exist_ok=True)
    for name in ('report.json', 'static_error_vs_distance.png', 'dynamic_error_per_speed.png'):
        if (report_dir / name).exists():
            shutil.copy(report_dir / name, target / name)
    body = (report_dir / 'report.md').read_text(encoding='utf-8')
    body = body.replace('](static_error', '](docs/evaluation/static_error')
    body = body.replace('](dynamic_error', '](docs/evaluation/dynamic_error')
    section = (f'{BEGIN_MARK}\nGenerated by `{command}` (all figures in '
               f'`docs/evaluation/report.json`).\n\n{body}{END_MARK}')
    text = markdown_path.read_text(encoding='utf-8')
    if BEGIN_MARK in text and END_MARK in text:
        head, rest = text.split(BEGIN_MARK, 1)
        _, tail = rest.split(END_MARK, 1)
        text = head + section + tail
    else:
        text = text.rstrip('\n') + '\n\n' + section + '\n'
    markdown_path.write_text(text, encoding='utf-8')
