"""The self-calibration a train keeps between runs: a small YAML file per vehicle.

Written by the localizer when it stops (and every ``self_calibration_save_s``) once its
self-survey (:mod:`.self_survey`) has learnt the stereo range calibration; read at the
next start as the prior, so a train starts with the calibration it learnt::

    vehicle_id: demo_train          # must be the vehicle file's
    disparity_offset_px: 0.41       # δ: measured disparity minus true, px
    disparity_offset_sigma_px: 0.04
    stereo_scale_error: -0.0012     # ε: fx·b true / believed − 1
    stereo_scale_sigma: 0.0008
    camera_fx_b_px_m: 124.8         # fx·b of the calibration it was learnt on
    runs: 3
    written: '2026-12-04T10:31:02Z'

A file that does not parse, lacks a field, holds a non-finite or negative σ, or belongs
to another vehicle is refused with :class:`SelfCalibrationFileError` (its message names
the file and the field); the node then runs on the calibration it was given.
"""
from dataclasses import asdict, dataclass
import math
import pathlib

from train_localizer.core.kept_file import read_mapping, write_atomically


class SelfCalibrationFileError(ValueError):
    """An unusable self-calibration file: ``<file>: <field>: <problem>``."""


@dataclass
class SavedCalibration:
    vehicle_id: str
    disparity_offset_px: float
    disparity_offset_sigma_px: float
    stereo_scale_error: float
    stereo_scale_sigma: float
    camera_fx_b_px_m: float
    runs: int = 1
    written: str = ''


_FLOATS = ('disparity_offset_px', 'disparity_offset_sigma_px', 'stereo_scale_error',
           'stereo_scale_sigma', 'camera_fx_b_px_m')


def load_saved_calibration(path, vehicle_id):
    """The SavedCalibration of ``path`` for ``vehicle_id``; None if the file does not
    exist (a first run); SelfCalibrationFileError if it is unusable.
    """
    path = pathlib.Path(path)
    data = read_mapping(path, SelfCalibrationFileError)
    if data is None:
        return None
    values = {}
    for name in ('vehicle_id',) + _FLOATS:
        if name not in data:
            raise SelfCalibrationFileError(f'{path}: {name}: missing')
    if str(data['vehicle_id']) != str(vehicle_id):
        raise SelfCalibrationFileError(
            f'{path}: vehicle_id: {data["vehicle_id"]!r} is another vehicle than this one '
            f'({vehicle_id!r})')
    for name in _FLOATS:
        try:
            values[name] = float(data[name])
        except (TypeError, ValueError):
            raise SelfCalibrationFileError(f'{path}: {name}: {data[name]!r} is not a number') \
                from None
        if not math.isfinite(values[name]):
            raise SelfCalibrationFileError(f'{path}: {name}: not finite')
    for name in ('disparity_offset_sigma_px', 'stereo_scale_sigma', 'camera_fx_b_px_m'):
        if not values[name] > 0.0:
            raise SelfCalibrationFileError(f'{path}: {name}: must be > 0')
    runs = data.get('runs', 1)
    if not isinstance(runs, int) or runs < 1:
        raise SelfCalibrationFileError(f'{path}: runs: {runs!r} is not a count >= 1')
    return SavedCalibration(vehicle_id=str(data['vehicle_id']), runs=runs,
                            written=str(data.get('written', '')), **values)


def save_calibration(path, saved):
    """Write atomically (a temporary file renamed over the old one)."""
    write_atomically(path, asdict(saved))
