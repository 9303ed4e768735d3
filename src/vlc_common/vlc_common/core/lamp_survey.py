"""Surveyed lamp lists (CSV, as a spreadsheet exports them) → :class:`LampMap`.

One header row, then one lamp per row; column names are matched without regard to case
and surrounding spaces, in any order. Separator ``,``, ``;`` or tab (taken from the
header row); decimal point ``.``; lines starting with ``#`` and blank lines are skipped.
Row numbers in messages are the file's line numbers, as a spreadsheet shows them (the
header is row 1).

Columns (:data:`COLUMNS`):

* identity: ``uid`` (decimal or ``0x`` hex) or ``line_id`` + ``lamp_id``; with all
  three, the uid must be ``line_id << 12 | lamp_id`` (protocol: line 0…15, lamp 0…4095).
* position, either on the alignment — ``chainage_m`` with ``lateral_m`` (left of the
  centreline, m) and ``height_m`` (above rail level, m), each defaulting to the value
  given to :func:`read_lamp_csv` (2.5 m and 1.4 m: the shipped maps' wall) — or in the
  map frame — ``x_m``, ``y_m``, ``z_m`` (then an optional ``chainage_m`` is checked
  against the chainage of (x, y) on the alignment, and without it the chainage is
  computed).
* optional: ``normal_x``, ``normal_y``, ``normal_z`` (disc normal, into the tunnel;
  default: horizontal, facing the track centreline; straight down for a lamp on the
  centreline); ``diameter_m`` (default 0.2 m); the survey 1σ, ``sigma_m`` (each map
  axis) or ``sigma_x_m``, ``sigma_y_m``, ``sigma_z_m``, kept in
  :attr:`Lamp.position_sigma_m` (unknown: NaN). An empty cell in an optional column
  takes the default.

Checks, each raising :class:`LampSurveyError` naming the row and column: unknown or
repeated columns, missing or half-given column groups, cells that are not numbers,
non-finite values, ids out of range, a uid that disagrees with line and lamp id,
duplicate UIDs, lamps of a line not listed in increasing chainage (and, unless
switched off, lamp id), a chainage beyond the ends of the alignment, a non-positive
diameter, a negative 1σ, a zero normal.
"""
import csv
from dataclasses import dataclass
import io
import math
import pathlib

import numpy as np

from vlc_common.core.alignment import Alignment
from vlc_common.core.lamp_map import Lamp, LampMap
from vlc_common.core.protocol import uid_of

#: Accepted columns and what they hold.
COLUMNS = {
    'uid': 'lamp UID, line_id << 12 | lamp_id (decimal or 0x hex)',
    'line_id': 'line id, 0..15',
    'lamp_id': 'lamp id on the line, 0..4095',
    'chainage_m': 'chainage along the alignment, m',
    'lateral_m': 'offset left of the track centreline, m (with chainage_m)',
    'height_m': 'height above rail level, m (with chainage_m)',
    'x_m': 'map x, m', 'y_m': 'map y, m', 'z_m': 'map z, m',
    'normal_x': 'disc normal, map x', 'normal_y': 'disc normal, map y',
    'normal_z': 'disc normal, map z',
    'diameter_m': 'disc diameter, m',
    'sigma_m': 'survey 1σ, each map axis, m',
    'sigma_x_m': 'survey 1σ along map x, m', 'sigma_y_m': 'survey 1σ along map y, m',
    'sigma_z_m': 'survey 1σ along map z, m',
}
_GROUPS = (('x_m', 'y_m', 'z_m'), ('normal_x', 'normal_y', 'normal_z'),
           ('sigma_x_m', 'sigma_y_m', 'sigma_z_m'))
#: A lamp closer than this to the centreline has no wall side: its default normal is down.
_CENTRELINE_M = 1e-6


class LampSurveyError(ValueError):
    """A survey row or column that cannot be used: ``<file>: row <n>, column <c>: …``."""

    def __init__(self, source, row, column, problem):
        self.source, self.row, self.column, self.problem = str(source), row, column, problem
        where = f'row {row}' + (f', column {column}' if column else '')
        super().__init__(f'{self.source}: {where}: {problem}')


@dataclass
class SurveyDefaults:
    """Values for columns a survey leaves out (m)."""

    lateral_m: float = 2.5
    height_m: float = 1.4
    diameter_m: float = 0.2


def read_lamp_csv(path, alignment=None, defaults=None, frame_id='map',
                  increasing_lamp_ids=True, chainage_tolerance_m=0.5):
    """A surveyed lamp list (CSV file) → :class:`LampMap`; see the module docstring.

    Parameters
    ----------
    path : str or Path
    alignment : Alignment or str, optional
        The line's alignment (or a name of :data:`NAMED_ALIGNMENTS`); default straight.
    defaults : SurveyDefaults, optional
    frame_id : str
    increasing_lamp_ids : bool
        Require lamp ids to increase along each line (catches swapped ids).
    chainage_tolerance_m : float
        Largest difference allowed between a ``chainage_m`` column and the chainage of
        the lamp's (x, y) on the alignment, m.
    """
    path = pathlib.Path(path)
    try:
        text = path.read_text(encoding='utf-8-sig')
    except (OSError, UnicodeDecodeError) as exc:
        raise LampSurveyError(path, 1, '', f'cannot be read ({exc})') from None
    return parse_lamp_csv(text, str(path), alignment, defaults, frame_id,
                          increasing_lamp_ids, chainage_tolerance_m)


def _rows(text):
    """(line number, cells) of the non-blank, non-comment lines; the separator is taken
    from the first of them (the header).
    """
    lines = [(n, line) for n, line in enumerate(text.splitlines(), start=1)
             if line.strip() and not line.lstrip().startswith('#')]
    if not lines:
        return []
    header = lines[0][1]
    delimiter = max((';', '\t', ','), key=header.count)
    reader = csv.reader(io.StringIO('\n'.join(line for _, line in lines)),
                        delimiter=delimiter)
    return [(n, [cell.strip() for cell in cells]) for (n, _), cells in zip(lines, reader)]


def parse_lamp_csv(text, source='<csv>', alignment=None, defaults=None, frame_id='map',
                   increasing_lamp_ids=True, chainage_tolerance_m=0.5):
    """:func:`read_lamp_csv` of CSV ``text``; ``source`` names it in messages."""
    if alignment is None:
        alignment = Alignment.straight()
    elif isinstance(alignment, str):
        alignment = Alignment.named(alignment)
    defaults = defaults or SurveyDefaults()
    rows = _rows(text)
    if not rows:
        raise LampSurveyError(source, 1, '', 'no header row (an empty file)')
    header_row, header = rows[0]
    columns = _columns(source, header_row, header)
    if len(rows) == 1:
        raise LampSurveyError(source, header_row, '', 'no lamps below the header')
    lamps, first_row_of_uid, last_of_line = [], {}, {}
    bounded = alignment.length_m > 0.0
    for row, cells in rows[1:]:
        cell = _Cells(source, row, cells, columns, len(header))
        lamp = _lamp(cell, alignment, defaults, chainage_tolerance_m)
        if lamp.uid in first_row_of_uid:
            raise LampSurveyError(source, row, cell.id_column,
                                  f'duplicate UID {lamp.uid:#06x} (line {lamp.line_id}, '
                                  f'lamp {lamp.lamp_id}; first on row '
                                  f'{first_row_of_uid[lamp.uid]})')
        first_row_of_uid[lamp.uid] = row
        if bounded and not (alignment.start_chainage_m <= lamp.chainage_m
                            <= alignment.end_chainage_m):
            raise LampSurveyError(source, row, cell.position_column,
                                  f'chainage {lamp.chainage_m:.3f} m is beyond the '
                                  f'alignment {alignment.name} ({alignment.start_chainage_m:g}'
                                  f' … {alignment.end_chainage_m:g} m)')
        previous = last_of_line.get(lamp.line_id)
        if previous is not None:
            prev_row, prev = previous
            if not lamp.chainage_m > prev.chainage_m:
                raise LampSurveyError(source, row, cell.position_column,
                                      f'chainage {lamp.chainage_m:.3f} m is not beyond '
                                      f'{prev.chainage_m:.3f} m of the previous lamp of line '
                                      f'{lamp.line_id} (row {prev_row}): list the lamps of '
                                      'a line in order along the track')
            if increasing_lamp_ids and not lamp.lamp_id > prev.lamp_id:
                raise LampSurveyError(source, row, cell.id_column,
                                      f'lamp id {lamp.lamp_id} follows lamp id '
                                      f'{prev.lamp_id} of line {lamp.line_id} (row '
                                      f'{prev_row}): lamp ids must increase along the line')
        last_of_line[lamp.line_id] = (row, lamp)
        lamps.append(lamp)
    name = '' if alignment.name == 'straight' else alignment.name
    return LampMap(lamps, frame_id=frame_id, alignment=name)


def _columns(source, row, header):
    """{column name: index}; checks the set of columns."""
    columns = {}
    for index, raw in enumerate(header):
        name = raw.strip().lower()
        if not name:
            columns.setdefault('', []).append(index)        # checked empty on every row
            continue
        if name not in COLUMNS:
            raise LampSurveyError(source, row, raw, f'unknown column {raw!r} (known: '
                                  f'{", ".join(COLUMNS)})')
        if name in columns:
            raise LampSurveyError(source, row, raw, 'column given twice')
        columns[name] = index
    has = set(columns)
    if 'uid' not in has and not {'line_id', 'lamp_id'} <= has:
        missing = 'lamp_id' if 'line_id' in has else 'line_id' if 'lamp_id' in has else \
            'uid (or line_id and lamp_id)'
        raise LampSurveyError(source, row, missing, 'missing: a lamp needs uid or line_id '
                                                    'and lamp_id')
    for group in _GROUPS:
        given = [c for c in group if c in has]
        if given and len(given) < len(group):
            missing = ', '.join(c for c in group if c not in has)
            raise LampSurveyError(source, row, missing, f'missing: {", ".join(group)} go '
                                                        'together')
    if 'x_m' not in has and 'chainage_m' not in has:
        raise LampSurveyError(source, row, 'chainage_m', 'missing: a lamp needs chainage_m '
                                                         'or x_m, y_m, z_m')
    if 'x_m' in has:
        for name in ('lateral_m', 'height_m'):
            if name in has:
                raise LampSurveyError(source, row, name, 'places a lamp by chainage; with '
                                                         'x_m, y_m, z_m it would be ignored')
    if 'sigma_m' in has and 'sigma_x_m' in has:
        raise LampSurveyError(source, row, 'sigma_m', 'give sigma_m or sigma_x_m, sigma_y_m, '
                                                      'sigma_z_m, not both')
    return columns


class _Cells:
    """The cells of one row, read by column name with the row's checks."""

    def __init__(self, source, row, cells, columns, width):
        if len(cells) != width:
            raise LampSurveyError(source, row, '', f'{len(cells)} cells, the header has '
                                                   f'{width}')
        for index in columns.get('', []):
            if cells[index]:
                raise LampSurveyError(source, row, f'#{index + 1}',
                                      f'value {cells[index]!r} in a column without a name')
        self.source, self.row, self.cells, self.columns = source, row, cells, columns
        self.id_column = 'uid' if 'uid' in columns else 'lamp_id'
        self.position_column = 'chainage_m' if 'x_m' not in columns else 'x_m'

    def has(self, name):
        return name in self.columns and self.cells[self.columns[name]] != ''

    def error(self, name, problem):
        return LampSurveyError(self.source, self.row, name, problem)

    def number(self, name, default=None):
        if not self.has(name):
            if default is None:
                raise self.error(name, 'empty cell')
            return default
        text = self.cells[self.columns[name]]
        try:
            value = float(text)
        except ValueError:
            hint = ' (a decimal comma? use a point)' if ',' in text else ''
            raise self.error(name, f'{text!r} is not a number{hint}') from None
        if not math.isfinite(value):
            raise self.error(name, f'non-finite value {text!r}')
        return value

    def integer(self, name, low, high):
        text = self.cells[self.columns[name]] if name in self.columns else ''
        if not text:
            raise self.error(name, 'empty cell')
        try:
            value = int(text, 16) if text.lower().startswith('0x') else int(text)
        except ValueError:
            raise self.error(name, f'{text!r} is not an integer') from None
        if not low <= value <= high:
            raise self.error(name, f'{value} is out of range {low}..{high}')
        return value


def _lamp(cell, alignment, defaults, chainage_tolerance_m):
    """The :class:`Lamp` of one row."""
    if cell.has('line_id') or cell.has('lamp_id') or 'uid' not in cell.columns:
        line_id = cell.integer('line_id', 0, 15)
        lamp_id = cell.integer('lamp_id', 0, 4095)
        uid = uid_of(line_id, lamp_id)
        if 'uid' in cell.columns and cell.has('uid'):
            given = cell.integer('uid', 0, 0xFFFF)
            if given != uid:
                raise cell.error('uid', f'{given:#06x} is not line_id {line_id} << 12 | '
                                        f'lamp_id {lamp_id} = {uid:#06x}')
    else:
        uid = cell.integer('uid', 0, 0xFFFF)
        line_id, lamp_id = uid >> 12, uid & 0xFFF
    if 'x_m' in cell.columns:
        position = np.array([cell.number(c) for c in ('x_m', 'y_m', 'z_m')])
        chainage, lateral = (float(v[0]) for v in alignment.project(position[0], position[1]))
        if cell.has('chainage_m'):
            given = cell.number('chainage_m')
            if abs(given - chainage) > chainage_tolerance_m:
                raise cell.error('chainage_m', f'{given:.3f} m differs by '
                                 f'{abs(given - chainage):.3f} m from the chainage '
                                 f'{chainage:.3f} m of (x_m, y_m) on the alignment (tolerance '
                                 f'{chainage_tolerance_m:g} m)')
            chainage = given
    else:
        chainage = cell.number('chainage_m')
        lateral = cell.number('lateral_m', defaults.lateral_m)
        height = cell.number('height_m', defaults.height_m)
        position = alignment.to_map(chainage, lateral, height)[0]
    if cell.has('normal_x') or cell.has('normal_y') or cell.has('normal_z'):
        normal = np.array([cell.number(c) for c in ('normal_x', 'normal_y', 'normal_z')])
        if not np.linalg.norm(normal) > 0.0:
            raise cell.error('normal_x', 'the normal (0, 0, 0) has no direction')
    elif abs(lateral) < _CENTRELINE_M:
        normal = np.array([0.0, 0.0, -1.0])
    else:                            # horizontal, from the wall toward the centreline
        n = alignment.evaluate(chainage).left_normal[0]
        normal = -np.sign(lateral) * np.array([n[0], n[1], 0.0])
    diameter = cell.number('diameter_m', defaults.diameter_m)
    if not diameter > 0.0:
        raise cell.error('diameter_m', f'{diameter:g} m must be > 0')
    names = ('sigma_m',) * 3 if cell.has('sigma_m') else ('sigma_x_m', 'sigma_y_m',
                                                           'sigma_z_m')
    sigma = np.array([cell.number(name, float('nan')) for name in names])
    for name, value in zip(names, sigma):
        if value < 0:
            raise cell.error(name, f'a 1σ of {value:g} m must be >= 0')
    return Lamp(uid=uid, line_id=line_id, lamp_id=lamp_id, position_m=position, normal=normal,
                diameter_m=diameter, chainage_m=chainage, position_sigma_m=sigma)
