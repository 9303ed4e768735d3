"""The rig-profile summary: the profile's figures beside the reference's and the paper's,
written between its markers.
"""
from vlc_evaluation import report


def _figures(static_max, dynamic_max, inside):
    fig = {'count': 5, 'misses': 0, 'max_m': static_max, 'mean_m': static_max / 2}
    dyn = {'count': 9, 'misses': 0, 'max_m': dynamic_max, 'mean_m': dynamic_max / 2}
    return {'static': {'ours': fig}, 'dynamic': {'60': {'test_points': dyn}},
            'dynamic_detail': {'60': {'covariance_3sigma_fraction': inside}}}


def test_profile_beside_ideal_and_paper():
    text = report.profile_summary('realistic', _figures(0.05, 0.08, 0.997),
                                  _figures(0.003, 0.008, 0.998))
    lines = text.splitlines()
    assert lines[0].startswith('| protocol | realistic: max / mean (cm) | ideal:')
    assert '| 5.00 / 2.50 | 0.30 / 0.15 | 29.73 / 10.48 |' in lines[2]
    assert '| 8.00 / 4.00 | 0.80 / 0.40 | 34.25 / 15.33 |' in lines[3]
    assert lines[4].endswith('| 99.7 % | 99.8 % | – |')
    # a reference without the row: a dash, not a crash
    assert '| – |' in report.profile_summary('harsh', _figures(0.1, 0.2, 0.9)).splitlines()[2]


def test_profile_block_is_written_between_its_markers(tmp_path):
    out = tmp_path / 'out'
    out.mkdir()
    (out / 'report.json').write_text(
        '{"figures": ' + __import__('json').dumps(_figures(0.05, 0.08, 0.997)) + '}')
    doc = tmp_path / 'README.md'
    doc.write_text(f'# x\n{report.PROFILE_BEGIN}\nold\n{report.PROFILE_END}\ntail\n')
    report.update_profile_docs(doc, out, 'realistic', 'run_evaluation --rig-profile realistic')
    text = doc.read_text()
    assert 'old' not in text and text.endswith('tail\n') and '| 5.00 / 2.50 | – |' in text
