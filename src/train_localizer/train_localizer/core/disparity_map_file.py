"""The disparity map a train keeps between runs (:mod:`.disparity_map`).

One YAML file per vehicle and calibration, the cells' sums, to which every run adds its
own::

    vehicle_id: demo_train         # must be the vehicle file's
    camera_fx_b_px_m: 124.8        # fx·b of the calibration it was learnt on
    cell_px: 64.0                  # the cell size it was learnt with
    runs: 3
    # i, j (cell column, row), lamp passes, residuals, then the weighted sums
    # sw, swx, swxx, swy, swxy, swyy (w = 1/σ² px⁻², x = u − cell centre px, y = δd px)
    cells:
    - [18, 4, 5, 212, 41000.0, 1.2e5, 3.0e7, 21500.0, 4.1e4, 1.2e4]
    written: '2026-12-05T10:31:02Z'

A file that does not parse, lacks a field, holds a malformed cell, belongs to another
vehicle or was learnt on another calibration (fx·b) or cell size is refused with
:class:`DisparityMapFileError` (its message names the file and the field); the node then
learns afresh and never writes over the refused file.
"""
import math
import pathlib

from train_localizer.core.disparity_map import CELL_SUMS, Cell
from train_localizer.core.kept_file import read_mapping, write_atomically


class DisparityMapFileError(ValueError):
    """An unusable disparity map file: ``<file>: <field>: <problem>``."""


HEADER = ('# Disparity map of the rectified pair learnt by train_localizer '
          '(core/disparity_map.py).\n# cells: i, j, lamp passes, residuals, '
          + ', '.join(CELL_SUMS) + '\n')


def load_disparity_map(path, vehicle_id, cell_px):
    """({(i, j): Cell}, runs, fx·b px·m) kept in ``path`` for this vehicle; None if the
    file does not exist (a first run); DisparityMapFileError if it is unusable. The
    calibration's fx·b is known only once camera_info has come: the localizer compares
    it then (:meth:`.disparity_map.DisparityMap.check_calibration`).
    """
    path = pathlib.Path(path)
    data = read_mapping(path, DisparityMapFileError)
    if data is None:
        return None
    for name in ('vehicle_id', 'camera_fx_b_px_m', 'cell_px', 'cells'):
        if name not in data:
            raise DisparityMapFileError(f'{path}: {name}: missing')
    if str(data['vehicle_id']) != str(vehicle_id):
        raise DisparityMapFileError(f'{path}: vehicle_id: {data["vehicle_id"]!r} is another '
                                    f'vehicle than this one ({vehicle_id!r})')
    values = {}
    for name in ('camera_fx_b_px_m', 'cell_px'):
        try:
            values[name] = float(data[name])
        except (TypeError, ValueError):
            raise DisparityMapFileError(f'{path}: {name}: {data[name]!r} is not a number') \
                from None
        if not (math.isfinite(values[name]) and values[name] > 0.0):
            raise DisparityMapFileError(f'{path}: {name}: must be finite and > 0')
    if abs(values['cell_px'] - cell_px) > 1e-9 * cell_px:
        raise DisparityMapFileError(f'{path}: cell_px: learnt with {values["cell_px"]:g} px '
                                    f'cells, this node uses {cell_px:g}')
    runs = data.get('runs', 1)
    if not isinstance(runs, int) or runs < 1:
        raise DisparityMapFileError(f'{path}: runs: {runs!r} is not a count >= 1')
    if not isinstance(data['cells'], list):
        raise DisparityMapFileError(f'{path}: cells: not a list')
    cells = {}
    for n, row in enumerate(data['cells']):
        cells.update([_cell(path, n, row)])
    return cells, runs, values['camera_fx_b_px_m']


def _cell(path, n, row):
    where = f'{path}: cells[{n}]'
    if not isinstance(row, list) or len(row) != 4 + len(CELL_SUMS):
        raise DisparityMapFileError(f'{where}: not a list of {4 + len(CELL_SUMS)} numbers')
    ints = row[:4]
    if not all(isinstance(v, int) and not isinstance(v, bool) for v in ints) or min(
            ints[2:]) < 0:
        raise DisparityMapFileError(f'{where}: i, j, passes, residuals must be integers '
                                    '(counts >= 0)')
    try:
        sums = [float(v) for v in row[4:]]
    except (TypeError, ValueError):
        raise DisparityMapFileError(f'{where}: a sum is not a number') from None
    if not all(math.isfinite(v) for v in sums) or sums[0] < 0.0 or sums[2] < 0.0 \
            or sums[5] < 0.0:
        raise DisparityMapFileError(f'{where}: sums must be finite, sw, swxx, swyy >= 0')
    cell = Cell(**dict(zip(CELL_SUMS, sums)))
    cell.passes, cell.residuals = ints[2], ints[3]
    return (ints[0], ints[1]), cell


def save_disparity_map(path, cells, vehicle_id, fx_b_px_m, cell_px, runs):
    """Write ``cells`` ({(i, j): Cell}) atomically (a temporary file renamed over the old
    one).
    """
    rows = [[int(i), int(j), int(c.passes), int(c.residuals)]
            + [float(getattr(c, k)) for k in CELL_SUMS]
            for (i, j), c in sorted(cells.items())]
    write_atomically(path, {'vehicle_id': str(vehicle_id),
                            'camera_fx_b_px_m': float(fx_b_px_m), 'cell_px': float(cell_px),
                            'runs': int(runs), 'cells': rows},
                     header=HEADER, default_flow_style=None)
