"""``lamp_map_from_csv``: a surveyor's CSV → lamp map YAML → LampMap, and its errors."""
import pathlib
import subprocess

import numpy as np

from vlc_calibration.lamp_map_from_csv import main
from vlc_common.core.alignment import Alignment
from vlc_common.core.lamp_map import LampMap
from vlc_common.core.protocol import uid_of

WS = pathlib.Path(__file__).resolve().parents[3]
SURVEY = """\
# Line 3 left wall, chainages from the as-built alignment; 1 sigma per map axis
uid,chainage_m,lateral_m,height_m,sigma_x_m,sigma_y_m,sigma_z_m
0x3001,210.000,2.51,1.41,0.004,0.004,0.006
0x3002,220.000,2.49,1.39,0.004,0.004,0.006
0x3003,230.000,2.50,1.40,0.004,0.004,0.006
"""


def test_survey_to_lamp_map(tmp_path, capsys):
    (tmp_path / 'survey.csv').write_text(SURVEY)
    out = tmp_path / 'lamp_map_line3.yaml'
    code = main([str(tmp_path / 'survey.csv'), '-o', str(out), '--alignment', 'curved_demo'])
    assert code == 0
    assert (f'lamp_map_from_csv: 3 lamps of line 3, chainage 210.000 … 230.000 m on alignment '
            f'curved_demo; survey 1σ known for 3 of them; wrote {out}') in capsys.readouterr().out
    lamp_map = LampMap.load(out)
    assert lamp_map.alignment == 'curved_demo'
    lamp = lamp_map.by_uid(uid_of(3, 2))
    # chainage 220 m is on the first transition curve of curved_demo
    np.testing.assert_allclose(lamp.position_m,
                               Alignment.named('curved_demo').to_map(220.0, 2.49, 1.39)[0],
                               atol=1e-6)
    np.testing.assert_allclose(lamp.position_sigma_m, [0.004, 0.004, 0.006])
    assert out.read_text().startswith('# Lamp map from the survey survey.csv')


def test_bad_survey_exits_with_2(tmp_path, capsys):
    bad = tmp_path / 'bad.csv'
    bad.write_text(SURVEY.replace('0x3003', '0x3002'))
    code = main([str(bad), '-o', str(tmp_path / 'map.yaml')])
    assert code == 2
    assert (f'lamp_map_from_csv: error: {bad}: row 5, column uid: duplicate UID 0x3002 '
            '(line 3, lamp 2; first on row 4)') in capsys.readouterr().err
    assert not (tmp_path / 'map.yaml').exists()
    exe = WS / 'install' / 'lib' / 'vlc_calibration' / 'lamp_map_from_csv'
    assert exe.exists(), 'run make build first'
    result = subprocess.run([str(exe), str(tmp_path / 'missing.csv'), '-o',
                             str(tmp_path / 'map.yaml')], capture_output=True, text=True,
                            timeout=60)
    assert result.returncode == 2
    assert 'missing.csv: row 1: cannot be read' in result.stderr
