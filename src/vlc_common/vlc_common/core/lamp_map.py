"""The lamp map: UID → lamp position in ``map``, shared by the rig and the receiver.

File format (YAML)::

    frame_id: map
    alignment: curved_demo            # optional: the track alignment the map belongs to
    lamps:
      - {uid: 4097, line_id: 1, lamp_id: 1, position_m: [10.0, 2.5, 1.4],
         normal: [0.0, -1.0, 0.0], diameter_m: 0.2, chainage_m: 10.0}

``normal`` is the unit normal of the lamp disc, pointing out of the wall into the
tunnel. Positions in metres in the ``map`` frame. ``chainage_m`` (optional) is the
lamp's chainage along the alignment; absent, it is the map x (straight track). The
straight map (``lamp_map.yaml``) omits both optional keys; a curved alignment's map
(``lamp_map_<alignment>.yaml``) has them. ``position_sigma_m`` (optional, m) is the 1σ
uncertainty of the surveyed position along map x, y and z (``.nan`` for an axis not
known); absent, it is unknown (NaN). Surveyed maps are made from a spreadsheet by
``vlc_common.core.lamp_survey`` (command ``lamp_map_from_csv``).
"""
from dataclasses import dataclass, field
import os
import pathlib

import numpy as np
import yaml

from vlc_common.core.alignment import NAMED_ALIGNMENTS, Alignment
from vlc_common.core.config_files import SAFE_DUMPER, SAFE_LOADER, config_path
from vlc_common.core.protocol import uid_of

PACKAGE = 'vlc_common'


@dataclass
class Lamp:
    uid: int
    line_id: int
    lamp_id: int
    position_m: np.ndarray
    normal: np.ndarray = field(default_factory=lambda: np.array([0.0, -1.0, 0.0]))
    diameter_m: float = 0.2
    chainage_m: float = float('nan')
    #: 1σ of the surveyed position along map x, y, z (m); NaN where unknown. A scalar is
    #: taken for all three axes.
    position_sigma_m: np.ndarray = field(default_factory=lambda: np.full(3, np.nan))

    @property
    def track_chainage_m(self):
        """Chainage along the alignment: ``chainage_m``, or the map x when not given."""
        return self.chainage_m if np.isfinite(self.chainage_m) else float(self.position_m[0])

    def __post_init__(self):
        self.position_m = np.asarray(self.position_m, dtype=float).reshape(3)
        self.normal = np.asarray(self.normal, dtype=float).reshape(3)
        self.normal = self.normal / np.linalg.norm(self.normal)
        if self.uid != uid_of(self.line_id, self.lamp_id):
            raise ValueError(f'lamp uid {self.uid} != line_id {self.line_id} << 12 | '
                             f'lamp_id {self.lamp_id}')
        if not self.diameter_m > 0.0:
            raise ValueError(f'lamp {self.uid}: diameter_m must be > 0')
        self.position_sigma_m = np.array(np.broadcast_to(
            np.asarray(self.position_sigma_m, dtype=float), (3,)))
        sigma = self.position_sigma_m
        if np.any(np.isinf(sigma) | (sigma < 0)):
            raise ValueError(f'lamp {self.uid}: position_sigma_m {sigma.tolist()} must be '
                             '>= 0 and finite (NaN: unknown)')

    @property
    def has_position_sigma(self):
        """True when the survey 1σ is known for all three axes."""
        return bool(np.all(np.isfinite(self.position_sigma_m)))


class LampMap:
    """An ordered collection of lamps with lookup by UID, map x and chainage.

    Lamps are kept in map-x order; on the shipped alignments map x grows with chainage
    (heading within ±90°), so this is also chainage order.
    """

    def __init__(self, lamps, frame_id='map', alignment=''):
        self.lamps = sorted(lamps, key=lambda lamp: lamp.position_m[0])
        self.frame_id = frame_id
        self.alignment = alignment
        self._by_uid = {}
        for lamp in self.lamps:
            if lamp.uid in self._by_uid:
                raise ValueError(f'duplicate lamp UID {lamp.uid:#06x} in the lamp map')
            self._by_uid[lamp.uid] = lamp
        self.positions = (np.array([lamp.position_m for lamp in self.lamps])
                          if self.lamps else np.zeros((0, 3)))
        self.chainages = np.array([lamp.track_chainage_m for lamp in self.lamps])
        #: (N, 3) survey 1σ per lamp along map x, y, z (m), NaN where unknown
        self.position_sigmas = (np.array([lamp.position_sigma_m for lamp in self.lamps])
                                if self.lamps else np.zeros((0, 3)))
        #: the file it was loaded from (:meth:`load`), None when built in code
        self.path = None

    def __len__(self):
        return len(self.lamps)

    def by_uid(self, uid):
        """The lamp with this UID, or None when the UID is not in the map."""
        return self._by_uid.get(int(uid))

    def near(self, x_m, ahead_m, behind_m=0.0):
        """Lamps with map x in ``[x_m - behind_m, x_m + ahead_m]``, in order.

        On a straight track map x is the chainage; on a curve use :meth:`near_chainage`
        for a window along the track.
        """
        xs = self.positions[:, 0] if len(self) else np.zeros(0)
        lo, hi = np.searchsorted(xs, [x_m - behind_m, x_m + ahead_m + 1e-12])
        return self.lamps[lo:hi]

    def near_chainage(self, chainage_m, ahead_m, behind_m=0.0):
        """Lamps with chainage in ``[chainage_m - behind_m, chainage_m + ahead_m]``."""
        keep = ((self.chainages >= chainage_m - behind_m)
                & (self.chainages <= chainage_m + ahead_m + 1e-12))
        return [lamp for lamp, k in zip(self.lamps, keep) if k]

    @classmethod
    def load(cls, path):
        with open(path, encoding='utf-8') as stream:
            # libyaml's safe loader where PyYAML has it: 8x faster on the 200-lamp map,
            # which every node and every evaluation scenario loads
            data = yaml.load(stream, Loader=SAFE_LOADER)
        if not isinstance(data, dict) or 'lamps' not in data:
            raise ValueError(f'{path}: not a lamp map (no "lamps" list)')
        lamps = [Lamp(uid=int(d['uid']), line_id=int(d['line_id']),
                      lamp_id=int(d['lamp_id']), position_m=d['position_m'],
                      normal=d.get('normal', [0.0, -1.0, 0.0]),
                      diameter_m=float(d.get('diameter_m', 0.2)),
                      chainage_m=float(d.get('chainage_m', float('nan'))),
                      position_sigma_m=d.get('position_sigma_m', float('nan')))
                 for d in data['lamps']]
        lamp_map = cls(lamps, frame_id=data.get('frame_id', 'map'),
                       alignment=str(data.get('alignment', '')))
        lamp_map.path = str(path)
        return lamp_map

    def save(self, path, header=None):
        """Write the map as YAML; ``header`` (optional) replaces the opening comment
        (lines without the leading ``#``).
        """
        data = {'frame_id': self.frame_id}
        if self.alignment:
            data['alignment'] = self.alignment
        data['lamps'] = []
        for lamp in self.lamps:
            entry = {'uid': lamp.uid, 'line_id': lamp.line_id, 'lamp_id': lamp.lamp_id,
                     # + 0.0 turns -0.0 into 0.0 in the file
                     'position_m': [round(float(v), 6) + 0.0 for v in lamp.position_m],
                     'normal': [round(float(v), 6) + 0.0 for v in lamp.normal],
                     'diameter_m': float(lamp.diameter_m)}
            if np.isfinite(lamp.chainage_m):
                entry['chainage_m'] = round(float(lamp.chainage_m), 6)
            if np.any(np.isfinite(lamp.position_sigma_m)):
                entry['position_sigma_m'] = [round(float(v), 6) + 0.0
                                             for v in lamp.position_sigma_m]
            data['lamps'].append(entry)
        if header is None:
            header = ('Lamp map: UID -> lamp disc centre in the map frame (m), disc normal\n'
                      '(unit, into the tunnel) and diameter. Generated by\n'
                      '`python -m vlc_common.core.lamp_map`; shared by the rig\n'
                      'and the receiver nodes.')
        with open(path, 'w', encoding='utf-8') as stream:
            stream.write(''.join(f'# {line}'.rstrip() + '\n' for line in header.splitlines()))
            yaml.dump(data, stream, Dumper=SAFE_DUMPER, default_flow_style=None,
                      sort_keys=False, width=120)


def straight_tunnel_map(line_id=1, first_lamp_id=1, count=200, spacing_m=10.0,
                        first_chainage_m=10.0, lateral_m=2.5, height_m=1.4,
                        diameter_m=0.2):
    """Lamps every ``spacing_m`` on the left wall of a straight tunnel.

    The wall is locally vertical at the lamps (the disc normal points along −y, into the
    tunnel). Defaults put the lamps 1.7 m left of and 1.5 m below the default left
    camera (mounted at y = 0.8 m, z = 2.9 m in ``base_link``), as in the paper.
    """
    return LampMap([Lamp(uid=uid_of(line_id, first_lamp_id + i), line_id=line_id,
                         lamp_id=first_lamp_id + i,
                         position_m=[first_chainage_m + i * spacing_m, lateral_m, height_m],
                         normal=[0.0, -1.0, 0.0], diameter_m=diameter_m)
                    for i in range(count)])


def alignment_lamp_map(alignment, line_id=1, first_lamp_id=1, spacing_m=10.0,
                       first_chainage_m=10.0, last_chainage_m=None, lateral_m=2.5,
                       height_m=1.4, diameter_m=0.2):
    """Lamps every ``spacing_m`` of chainage on the left wall of ``alignment``.

    Each lamp sits ``lateral_m`` left of the centreline (along the track's left normal
    n(s)) at ``height_m`` above rail level, its disc in the wall plane with the normal
    −n(s), facing the track. ``last_chainage_m`` defaults to the alignment's end. On
    the default straight this is :func:`straight_tunnel_map` (same positions and
    normals), with each lamp's chainage recorded.

    Parameters
    ----------
    alignment : Alignment
    line_id, first_lamp_id : int
        UID = line_id << 12 | lamp_id, lamp ids counting up from ``first_lamp_id``.
    spacing_m, first_chainage_m, last_chainage_m, lateral_m, height_m, diameter_m : float
        Metres.
    """
    last = alignment.end_chainage_m if last_chainage_m is None else float(last_chainage_m)
    count = int(np.floor((last - first_chainage_m) / spacing_m + 1e-9)) + 1
    s = first_chainage_m + spacing_m * np.arange(count)
    points = alignment.to_map(s, lateral_m, height_m)
    normals = -alignment.evaluate(s).left_normal
    return LampMap([Lamp(uid=uid_of(line_id, first_lamp_id + i), line_id=line_id,
                         lamp_id=first_lamp_id + i, position_m=points[i],
                         normal=[normals[i, 0], normals[i, 1], 0.0], diameter_m=diameter_m,
                         chainage_m=float(s[i]))
                    for i in range(count)], alignment=alignment.name)


def lamp_map_file_name(alignment='straight'):
    """``lamp_map.yaml`` for the straight alignment, else ``lamp_map_<alignment>.yaml``."""
    return 'lamp_map.yaml' if alignment in ('', 'straight') else f'lamp_map_{alignment}.yaml'


def default_lamp_map_path(alignment='straight'):
    """``share/vlc_common/config/<lamp map of the alignment>`` (installed, else source)."""
    return str(config_path(PACKAGE, lamp_map_file_name(alignment)))


def resolve_lamp_map_path(path, alignment='straight'):
    """An explicit path as given; '' means the default map of ``alignment``."""
    return os.path.expanduser(path) if path else default_lamp_map_path(alignment)


def write_shipped_maps(config_dir):
    """Write the straight map and one map per named curved alignment into ``config_dir``.

    The straight map is line 1; the curved alignments are lines 2, 3, … in the order of
    ``NAMED_ALIGNMENTS``, so a receiver given the wrong map sees unknown UIDs (a reported
    anomaly) instead of silently using another line's lamp positions.
    """
    config_dir = pathlib.Path(config_dir)
    straight_tunnel_map().save(config_dir / lamp_map_file_name('straight'))
    curved = [name for name, spec in NAMED_ALIGNMENTS.items() if spec is not None]
    for line_id, name in enumerate(curved, start=2):
        alignment_lamp_map(Alignment.named(name), line_id=line_id).save(
            config_dir / lamp_map_file_name(name))


def main(argv=None):
    """``python -m vlc_common.core.lamp_map [DIR]``: write the shipped maps into DIR
    (default: the package's ``config`` folder in the source tree, which only a source
    checkout has; an installed package's is a copy that the next build replaces).
    """
    import argparse
    parser = argparse.ArgumentParser(description=main.__doc__.split('\n')[0])
    source = pathlib.Path(__file__).resolve().parents[2] / 'config'
    parser.add_argument('out_dir', nargs='?', default=str(source),
                        help='directory to write lamp_map*.yaml into (default: %(default)s)')
    args = parser.parse_args(argv)
    if not pathlib.Path(args.out_dir).is_dir():
        parser.error(f'{args.out_dir} is not a directory (run from a source checkout, or '
                     'name the directory to write the maps into)')
    write_shipped_maps(args.out_dir)
    print(f'lamp maps written into {args.out_dir}')
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
