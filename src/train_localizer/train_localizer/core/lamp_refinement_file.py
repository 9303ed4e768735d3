"""The lamp-map refinement a line keeps between runs: one YAML file per surveyed line.

Written by the localizer when it stops (and every ``lamp_refinement_save_s``): what the
file held plus this run's triplet measurements (:mod:`.lamp_refinement`); read at the
next start, its corrections are applied to the surveyed map::

    line_ids: [1]                   # the line(s) of the lamp map it refines
    survey_digest: 3f0c9a1b2d4e5f60 # the survey it is relative to (positions, 0.1 mm)
    vehicle_id: demo_train          # the last writer (for the record; any train may add)
    passes: 3
    triplets:                       # [uid a, uid b, uid c, λ, q m, 1σ m, passes(,
    - [4097, 4098, 4099, 0.5, 0.0012, 0.004, 3]   #  [[λ, q, 1σ] held apart, …])]
    flags:                          # lamps set apart (moved between passes)
    - {uid: 4101, kind: moved, reason: '...', at_pass: 3, previous: [[...], ...]}
    written: '2026-12-04T10:31:02Z'

A file that does not parse, lacks a field, holds a non-finite value or a σ ≤ 0, names a
lamp the map does not have, or belongs to another line or another survey of it is
refused with :class:`RefinementFileError` (its message names the file and the field); the
node then runs on the survey.
"""
import dataclasses
from dataclasses import dataclass, field
import hashlib
import math
import pathlib

import numpy as np

from train_localizer.core.kept_file import read_mapping, write_atomically
from train_localizer.core.lamp_refinement import Flag, KeptTriplet, Refinement
from vlc_common.core.lamp_map import LampMap


class RefinementFileError(ValueError):
    """An unusable refinement file: ``<file>: <field>: <problem>``."""


def line_ids(lamp_map):
    return sorted({int(lamp.line_id) for lamp in lamp_map.lamps})


def survey_digest(lamp_map):
    """16 hex digits identifying the surveyed positions (rounded to 0.1 mm)."""
    text = ';'.join(f'{lamp.uid}:' + ','.join(f'{v:.4f}' for v in lamp.position_m)
                    for lamp in sorted(lamp_map.lamps, key=lambda x: x.uid))
    return hashlib.sha256(text.encode()).hexdigest()[:16]


def _held(path, field, items):
    out = []
    for item in items if isinstance(items, list) else [None]:
        try:
            lam, q, sigma = (float(v) for v in item)
        except (TypeError, ValueError):
            raise RefinementFileError(f'{path}: {field}: held measurement {item!r} is not '
                                      '[lambda, q, sigma]') from None
        if not (math.isfinite(q) and sigma > 0.0 and 0.0 <= lam <= 1.0):
            raise RefinementFileError(f'{path}: {field}: held measurement {item!r} out of '
                                      'range')
        out.append((lam, q, sigma))
    return out


def _triplet(path, field, row, uids):
    if not isinstance(row, (list, tuple)) or len(row) not in (7, 8):
        raise RefinementFileError(f'{path}: {field}: expected [uid a, uid b, uid c, lambda, '
                                  f'q, sigma, passes(, held)], got {row!r}')
    try:
        key = tuple(int(u) for u in row[:3])
        lam, q, sigma = (float(v) for v in row[3:6])
        passes = int(row[6])
    except (TypeError, ValueError):
        raise RefinementFileError(f'{path}: {field}: {row!r} is not numbers') from None
    if not all(math.isfinite(v) for v in (lam, q, sigma)):
        raise RefinementFileError(f'{path}: {field}: not finite')
    if not sigma > 0.0 or not 0.0 <= lam <= 1.0 or passes < 1:
        raise RefinementFileError(f'{path}: {field}: sigma must be > 0, lambda in [0, 1], '
                                  f'passes >= 1 ({row!r})')
    unknown = [u for u in key if u not in uids]
    if unknown:
        raise RefinementFileError(f'{path}: {field}: lamp {unknown[0]:#06x} is not in the '
                                  'lamp map')
    held = _held(path, field, row[7]) if len(row) == 8 else []
    return key, KeptTriplet(lam, q, sigma, passes, held)


def load_refinement(path, lamp_map, config=None):
    """The Refinement of ``path`` for ``lamp_map``; None if the file does not exist (a
    first run); RefinementFileError if it is unusable.
    """
    path = pathlib.Path(path)
    data = read_mapping(path, RefinementFileError)
    if data is None:
        return None
    for name in ('line_ids', 'survey_digest', 'passes', 'triplets'):
        if name not in data:
            raise RefinementFileError(f'{path}: {name}: missing')
    if sorted(int(v) for v in data['line_ids'] or []) != line_ids(lamp_map):
        raise RefinementFileError(f'{path}: line_ids: {data["line_ids"]!r} is another line '
                                  f'than the lamp map\'s ({line_ids(lamp_map)})')
    if str(data['survey_digest']) != survey_digest(lamp_map):
        raise RefinementFileError(f'{path}: survey_digest: learnt on another survey of the '
                                  f'line ({data["survey_digest"]}, this map '
                                  f'{survey_digest(lamp_map)})')
    passes = data['passes']
    if not isinstance(passes, int) or passes < 0:
        raise RefinementFileError(f'{path}: passes: {passes!r} is not a count >= 0')
    uids = {lamp.uid for lamp in lamp_map.lamps}
    triplets = dict(_triplet(path, f'triplets[{i}]', row, uids)
                    for i, row in enumerate(data['triplets'] or []))
    flags = []
    for i, f in enumerate(data.get('flags') or []):
        field = f'flags[{i}]'
        if not isinstance(f, dict) or not {'uid', 'kind', 'reason', 'at_pass'} <= set(f):
            raise RefinementFileError(f'{path}: {field}: expected uid, kind, reason, at_pass')
        previous = dict(_triplet(path, f'{field}.previous[{j}]', row, uids)
                        for j, row in enumerate(f.get('previous') or []))
        flags.append(Flag(int(f['uid']), str(f['kind']), str(f['reason']), int(f['at_pass']),
                          previous))
    return Refinement(config, triplets, flags, passes)


def _rows(triplets):
    return [[*map(int, key), round(t.lam, 4), round(t.q_m, 6), round(t.sigma_m, 6),
             int(t.passes)] + ([[[round(v, 6) for v in held] for held in t.pending]]
                               if t.pending else [])
            for key, t in sorted(triplets.items())]


def save_refinement(path, refinement, lamp_map, vehicle_id=''):
    """Write atomically (a temporary file renamed over the old one)."""
    data = {'line_ids': line_ids(lamp_map), 'survey_digest': survey_digest(lamp_map),
            'vehicle_id': str(vehicle_id), 'passes': int(refinement.passes),
            'triplets': _rows(refinement.triplets),
            'flags': [{'uid': f.uid, 'kind': f.kind, 'reason': f.reason, 'at_pass': f.at_pass,
                       'previous': _rows(f.previous)} for f in refinement.flags]}
    write_atomically(path, data, '# Lamp-map refinement (train_localizer '
                     'core/lamp_refinement.py): triplets [uid a, uid b, uid c, lambda, q m, '
                     'sigma m, passes]\n', default_flow_style=None)


@dataclass
class KeptRefinement:
    """What a localizer read at start: the file, the survey it refines, the kept
    Refinement (None: first run or refused), the corrections applied ({uid: m}), the
    lamps off their survey ({uid: reason}) and a state text for diagnostics.
    """

    path: str
    survey_map: object
    base: object
    applied: dict = field(default_factory=dict)
    off_survey: dict = field(default_factory=dict)
    state: str = ''
    refused: bool = False


def _axis_sigma(lamp, default_sigma_m):
    """The survey's per-axis 1σ of ``lamp`` (its own, else the default on every axis)."""
    sigma = np.asarray(lamp.position_sigma_m, float)
    return sigma if np.all(np.isfinite(sigma)) else np.full(3, float(default_sigma_m))


def along_track_sigma(lamp, tangent, default_sigma_m):
    """The survey's along-track 1σ of ``lamp`` (its own per-axis σ, else the default)."""
    return float(np.sqrt(np.sum((np.asarray(tangent) * _axis_sigma(lamp, default_sigma_m))
                                ** 2)))


def refined_map(lamp_map, corrections, tangent_of, default_sigma_m):
    """A copy of ``lamp_map`` with each corrected lamp moved back by its correction
    along the track and its along-track σ replaced by the refined one.

    ``corrections``: {uid: (e m, 1σ m)}; ``tangent_of(lamp)``: the track's unit tangent
    at the lamp. The per-axis σ stays diagonal: along an axis-aligned track exact, on a
    curve the along-track share of each axis is replaced.
    """
    lamps = []
    for lamp in lamp_map.lamps:
        if lamp.uid not in corrections:
            lamps.append(lamp)
            continue
        e, s = corrections[lamp.uid]
        t = np.asarray(tangent_of(lamp), float)
        var = _axis_sigma(lamp, default_sigma_m) ** 2 * (1.0 - t * t) + (t * t) * s * s
        lamps.append(dataclasses.replace(lamp, position_m=lamp.position_m - e * t,
                                         position_sigma_m=np.sqrt(var)))
    return LampMap(lamps, frame_id=lamp_map.frame_id, alignment=lamp_map.alignment)


def read_kept(path, lamp_map, tangent_of, default_sigma_m, config=None):
    """(the map to localize on, KeptRefinement) of the refinement file ``path`` for the
    surveyed ``lamp_map``; a refused file leaves the survey (state 'refused: …').
    """
    try:
        base = load_refinement(path, lamp_map, config)
    except RefinementFileError as exc:
        return lamp_map, KeptRefinement(path, lamp_map, None, state=f'refused: {exc}',
                                        refused=True)
    if base is None:
        return lamp_map, KeptRefinement(path, lamp_map, Refinement(config),
                                        state='learning (first pass on this survey)')
    sigma = {lamp.uid: along_track_sigma(lamp, tangent_of(lamp), default_sigma_m)
             for lamp in lamp_map.lamps}
    corrections, off = base.corrections(sigma)
    kept = KeptRefinement(path, lamp_map, base, {u: e for u, (e, _) in corrections.items()},
                          off, state=f'from file ({base.passes} pass(es)): '
                          f'{len(corrections)} lamps refined')
    return refined_map(lamp_map, corrections, tangent_of, default_sigma_m), kept
