"""Surveyed lamp lists (core/lamp_survey.py) and the survey 1σ in the lamp map.

CSV text is written as a surveyor's spreadsheet exports it: a header row, lamps in
order along the line, blank optional cells, a comment line, sometimes semicolons.
"""
import numpy as np
import pytest

from vlc_common.core.alignment import Alignment
from vlc_common.core.lamp_map import (
    Lamp,
    LampMap,
    alignment_lamp_map,
    default_lamp_map_path,
    lamp_map_file_name,
    write_shipped_maps,
)
from vlc_common.core.lamp_survey import (
    LampSurveyError,
    SurveyDefaults,
    parse_lamp_csv,
    read_lamp_csv,
)
from vlc_common.core.protocol import uid_of

BY_CHAINAGE = """\
# Line 2, left wall, survey 2026-11-30 (total station, 1 sigma 3 mm plan, 5 mm height)
line_id,lamp_id,chainage_m,lateral_m,height_m,sigma_x_m,sigma_y_m,sigma_z_m
2,1,10.000,2.512,1.398,0.003,0.003,0.005
2,2,20.004,2.497,1.402,0.003,0.003,0.005

2,3,29.998,,,0.003,0.003,0.005
2,4,40.010,2.503,1.401,,,
"""


def test_survey_by_chainage_on_a_curved_alignment():
    alignment = Alignment.named('curved_demo')
    lamp_map = parse_lamp_csv(BY_CHAINAGE, 'survey.csv', alignment)
    assert len(lamp_map) == 4 and lamp_map.alignment == 'curved_demo'
    lamp = lamp_map.by_uid(uid_of(2, 2))
    np.testing.assert_allclose(lamp.position_m, alignment.to_map(20.004, 2.497, 1.402)[0])
    np.testing.assert_allclose(lamp.position_sigma_m, [0.003, 0.003, 0.005])
    assert lamp.chainage_m == 20.004 and lamp.has_position_sigma
    # blank lateral and height take the defaults, blank sigmas are unknown
    third, fourth = lamp_map.by_uid(uid_of(2, 3)), lamp_map.by_uid(uid_of(2, 4))
    np.testing.assert_allclose(third.position_m, alignment.to_map(29.998, 2.5, 1.4)[0])
    assert np.all(np.isnan(fourth.position_sigma_m)) and not fourth.has_position_sigma
    # the disc faces the track: minus the left normal (as the shipped maps)
    shipped = alignment_lamp_map(alignment, line_id=2, last_chainage_m=40.0)
    np.testing.assert_allclose(third.normal, shipped.by_uid(uid_of(2, 3)).normal, atol=1e-4)
    np.testing.assert_allclose(lamp_map.position_sigmas[3], np.nan)
    # rows are the file's lines, comment and blank lines counted, as a spreadsheet shows
    with pytest.raises(LampSurveyError, match=r'survey.csv: row 7, column chainage_m: chainage '
                                              r'15.000 m is not beyond 29.998 m .* \(row 6\)'):
        parse_lamp_csv(BY_CHAINAGE.replace('40.010', '15.000'), 'survey.csv', alignment)


def test_survey_in_map_coordinates_semicolons_and_uids():
    text = ('UID; x_m; y_m; z_m; normal_x; normal_y; normal_z; diameter_m; sigma_m\n'
            '0x1001; 10.0; 2.5; 1.4; ; ; ; ; 0.004\n'
            '4098; 20.0; -2.6; 1.5; 0; 1; 0; 0.25; 0.004\n'
            '0x1003; 30.0; 0.0; 5.2; ; ; ; ; \n')
    lamp_map = parse_lamp_csv(text)
    first, second, third = lamp_map.lamps
    assert (first.line_id, first.lamp_id) == (1, 1) and second.uid == 0x1002
    np.testing.assert_allclose(first.normal, [0, -1, 0])           # left wall: faces −y
    np.testing.assert_allclose(second.normal, [0, 1, 0])           # right wall
    np.testing.assert_allclose(third.normal, [0, 0, -1])           # above the track
    assert second.diameter_m == 0.25 and first.diameter_m == 0.2
    np.testing.assert_allclose(first.position_sigma_m, [0.004] * 3)
    assert lamp_map.alignment == '' and first.chainage_m == 10.0


def test_csv_to_yaml_to_lamp_map_round_trip(tmp_path):
    csv_path = tmp_path / 'survey.csv'
    csv_path.write_text(BY_CHAINAGE, encoding='utf-8-sig')     # with a BOM, as Excel
    lamp_map = read_lamp_csv(csv_path, 'curved_demo',
                             SurveyDefaults(lateral_m=2.5, height_m=1.4))
    lamp_map.save(tmp_path / 'map.yaml', header='Surveyed lamp map')
    text = (tmp_path / 'map.yaml').read_text()
    assert text.startswith('# Surveyed lamp map\n') and 'position_sigma_m' in text
    loaded = LampMap.load(tmp_path / 'map.yaml')
    assert [lamp.uid for lamp in loaded.lamps] == [lamp.uid for lamp in lamp_map.lamps]
    np.testing.assert_allclose(loaded.positions, lamp_map.positions, atol=1e-6)
    np.testing.assert_allclose(loaded.chainages, lamp_map.chainages, atol=1e-6)
    np.testing.assert_allclose(loaded.position_sigmas, lamp_map.position_sigmas)
    assert loaded.alignment == 'curved_demo'


def test_existing_maps_load_unchanged(tmp_path):
    for alignment in ('straight', 'curved_demo'):
        lamp_map = LampMap.load(default_lamp_map_path(alignment))
        assert np.all(np.isnan(lamp_map.position_sigmas))
    # maps without a survey 1σ are written exactly as before
    write_shipped_maps(tmp_path)
    for alignment in ('straight', 'curved_demo'):
        name = lamp_map_file_name(alignment)
        with open(default_lamp_map_path(alignment), encoding='utf-8') as stream:
            assert (tmp_path / name).read_text() == stream.read()
    with pytest.raises(ValueError, match='position_sigma_m'):
        Lamp(uid=uid_of(1, 1), line_id=1, lamp_id=1, position_m=[0, 0, 0],
             position_sigma_m=[0.01, -0.01, 0.01])


def test_the_module_writes_the_shipped_maps_where_told_and_refuses_a_missing_folder(
        tmp_path, capsys):
    """``python -m vlc_common.core.lamp_map DIR``; run from an installed package without
    DIR it used to fail with a traceback (its default is the source tree's config).
    """
    from vlc_common.core.lamp_map import main
    assert main([str(tmp_path)]) == 0
    name = lamp_map_file_name('straight')
    with open(default_lamp_map_path('straight'), encoding='utf-8') as stream:
        assert (tmp_path / name).read_text() == stream.read()
    with pytest.raises(SystemExit) as exc:
        main([str(tmp_path / 'missing')])
    assert exc.value.code == 2 and 'is not a directory' in capsys.readouterr().err


HEADER = 'line_id,lamp_id,chainage_m,lateral_m,height_m,sigma_m\n'


@pytest.mark.parametrize('text, row, column, words', [
    ('line_id,lamp_id,chainage,height_m\n1,1,10,1.4\n', 1, 'chainage',
     "unknown column 'chainage' (known: uid, line_id"),
    ('uid,chainage_m,uid\n4097,10,4097\n', 1, 'uid', 'column given twice'),
    ('line_id,chainage_m\n1,10\n', 1, 'lamp_id', 'missing: a lamp needs uid or line_id'),
    ('uid,x_m,y_m\n4097,10,2.5\n', 1, 'z_m', 'missing: x_m, y_m, z_m go together'),
    ('uid,x_m,y_m,z_m,height_m\n4097,10,2.5,1.4,1.4\n', 1, 'height_m', 'would be ignored'),
    ('uid,lateral_m\n4097,2.5\n', 1, 'chainage_m', 'needs chainage_m or x_m, y_m, z_m'),
    ('uid,chainage_m,sigma_m,sigma_x_m,sigma_y_m,sigma_z_m\n', 1, 'sigma_m', 'not both'),
    (HEADER, 1, '', 'no lamps below the header'),
    (HEADER + '1,1,10,2.5,1.4,0.01\n1,1,20,2.5,1.4,0.01\n', 3, 'lamp_id',
     'duplicate UID 0x1001 (line 1, lamp 1; first on row 2)'),
    ('uid,chainage_m\n4097,10\n0x1002,20\n4097,30\n', 4, 'uid', 'duplicate UID 0x1001'),
    (HEADER + '16,1,10,2.5,1.4,0.01\n', 2, 'line_id', '16 is out of range 0..15'),
    (HEADER + '1,4096,10,2.5,1.4,0.01\n', 2, 'lamp_id', '4096 is out of range 0..4095'),
    ('uid,chainage_m\n70000,10\n', 2, 'uid', '70000 is out of range 0..65535'),
    ('uid,line_id,lamp_id,chainage_m\n4098,1,1,10\n', 2, 'uid',
     '0x1002 is not line_id 1 << 12 | lamp_id 1 = 0x1001'),
    (HEADER + '1,1,10,2.5,1.4,0.01\n1,2,30,2.5,1.4,0.01\n1,3,20,2.5,1.4,0.01\n', 4,
     'chainage_m', 'chainage 20.000 m is not beyond 30.000 m of the previous lamp of line 1 '
     '(row 3)'),
    (HEADER + '1,2,10,2.5,1.4,0.01\n1,1,20,2.5,1.4,0.01\n', 3, 'lamp_id',
     'lamp id 1 follows lamp id 2 of line 1 (row 2)'),
    (HEADER + '1,1,nan,2.5,1.4,0.01\n', 2, 'chainage_m', "non-finite value 'nan'"),
    (HEADER + '1,1,10,2.5,inf,0.01\n', 2, 'height_m', "non-finite value 'inf'"),
    ('line_id;lamp_id;chainage_m\n1;1;10,5\n', 2, 'chainage_m',
     "'10,5' is not a number (a decimal comma? use a point)"),
    (HEADER + '1,1,10,2.5,1.4\n', 2, '', '5 cells, the header has 6'),
    (HEADER + '1,1,10,2.5,1.4,-0.01\n', 2, 'sigma_m', 'a 1σ of -0.01 m must be >= 0'),
    ('uid,chainage_m,diameter_m\n4097,10,0\n', 2, 'diameter_m', '0 m must be > 0'),
    ('uid,chainage_m,normal_x,normal_y,normal_z\n4097,10,0,0,0\n', 2, 'normal_x',
     'has no direction'),
    ('uid,chainage_m,\n4097,10,x\n', 2, '#3', "value 'x' in a column without a name"),
    ('uid,chainage_m\n,10\n', 2, 'uid', 'empty cell'),
])
def test_survey_errors_name_row_and_column(text, row, column, words):
    with pytest.raises(LampSurveyError) as info:
        parse_lamp_csv(text, 'survey.csv')
    assert (info.value.row, info.value.column) == (row, column)
    assert words in info.value.problem
    where = f'row {row}' + (f', column {column}' if column else '')
    assert str(info.value).startswith(f'survey.csv: {where}: ')


def test_alignment_checks():
    alignment = Alignment.named('curved_demo')           # chainage 0 … 2310 m
    with pytest.raises(LampSurveyError, match=r'row 3, column chainage_m: chainage 2400.000 '
                                              r'm is beyond the alignment curved_demo '
                                              r'\(0 … 2310 m\)'):
        parse_lamp_csv('uid,chainage_m\n4097,2300\n4098,2400\n', 's.csv', alignment)
    # map coordinates are projected onto the alignment for the chainage
    x, y, _ = alignment.to_map(500.0, 2.5, 1.4)[0]
    text = f'uid,x_m,y_m,z_m,chainage_m\n4097,{x},{y},1.4,500.2\n'
    (lamp,) = parse_lamp_csv(text, 's.csv', alignment).lamps
    assert lamp.chainage_m == 500.2
    with pytest.raises(LampSurveyError, match=r'row 2, column chainage_m: 501.000 m differs '
                                              r'by 1.000 m from the chainage 500.000 m'):
        parse_lamp_csv(text.replace('500.2', '501.0'), 's.csv', alignment)
    text = f'uid,x_m,y_m,z_m\n4097,{x},{y},1.4\n'
    (lamp,) = parse_lamp_csv(text, 's.csv', alignment).lamps
    assert lamp.chainage_m == pytest.approx(500.0, abs=1e-6)
    # lamp ids may be allowed in any order
    relaxed = parse_lamp_csv(HEADER + '1,2,10,2.5,1.4,0.01\n1,1,20,2.5,1.4,0.01\n',
                             increasing_lamp_ids=False)
    assert [lamp.lamp_id for lamp in relaxed.lamps] == [2, 1]
    with pytest.raises(LampSurveyError, match=r'nothere.csv: row 1: cannot be read'):
        read_lamp_csv('nothere.csv')
