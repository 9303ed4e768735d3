"""Lamp identification figures of a run: which lamps in view the decoder identified, when.

Ground truth is ``ground_truth/spots`` (one point per lamp with pixels in an image, with
its UID, projected centre and along-track distance); the decoder's output is
``vlc/lamps`` (one point per spot, ``state`` 2 = CRC-confirmed UID of the lamp map).
Both carry the image stamp, so frames pair exactly. Within a frame a decoder spot is
the lamp whose true centre is nearest to its bounding box in either image (zero inside
it), within ``match_radius_px``: a spot cut by the image border has its true centre
outside the image, next to the box (up to ~70 px below it for a lamp 0.3 m ahead).
Lamps are 10 m apart, so at most two are in view, and they are then more than a
thousand pixels apart.

* **identified** (per lamp and frame): a confirmed record with the lamp's own UID;
* **first confirmation**: the along-track distance to the lamp at the first frame it is
  identified (larger = earlier);
* **wrong UID accepted**: a confirmed record whose UID is not that of the lamp it sits
  on (or that sits on no lamp); must be 0. Anomalies (``state`` 3: CRC-valid UID absent
  from the map, never used) are counted apart.
"""
import numpy as np

CONFIRMED = 2
ANOMALY = 3


def _box_distance(rec, side, truth_u, truth_v):
    """Distances (px) from the true centres to the record's spot in one image: to its
    bounding box when the record has one (a spot cut by the border keeps its true centre
    outside the image, beside the box), else to its centre; inf without that spot.
    """
    names = rec.dtype.names
    if f'{side}_u_min' in names:
        lo_u, hi_u = rec[f'{side}_u_min'], rec[f'{side}_u_max']
        lo_v, hi_v = rec[f'{side}_v_min'], rec[f'{side}_v_max']
    else:
        lo_u = hi_u = rec[f'{side}_u']
        lo_v = hi_v = rec[f'{side}_v']
    if not (np.isfinite(lo_u) and np.isfinite(lo_v) and np.isfinite(rec[f'{side}_u'])):
        return np.full(truth_u.shape, np.inf)
    du = np.maximum(np.maximum(lo_u - truth_u, truth_u - hi_u), 0.0)
    dv = np.maximum(np.maximum(lo_v - truth_v, truth_v - hi_v), 0.0)
    d = np.hypot(du, dv)
    return np.where(np.isfinite(d), d, np.inf)


def _record_truth_index(rec, truth, match_radius_px):
    """Index of the lamp a decoder record sits on (-1: none within the radius)."""
    if len(truth) == 0:
        return -1
    d = np.minimum(_box_distance(rec, 'left', truth['u_left'], truth['v_left']),
                   _box_distance(rec, 'right', truth['u_right'], truth['v_right']))
    k = int(np.argmin(d))
    return k if d[k] <= match_radius_px else -1


def identification(run, match_radius_px=100.0):
    """Per-frame and per-lamp identification of one run.

    Returns a JSON-ready dict: ``frames`` (list of [uid, along_track_m, detected,
    identified] for every lamp whose centre is in an image), ``first_confirmation_m``
    ({uid: along-track distance, or None if never identified while in view}),
    ``wrong_uids`` (count), ``wrong_uid_list``, ``anomalies`` (count).
    """
    frames, first, wrong, wrong_list, anomalies = [], {}, 0, set(), 0
    for stamp in sorted(run.truth_spots):
        truth = run.truth_spots[stamp]
        recs = run.lamps.get(stamp)
        recs = recs if recs is not None else np.zeros(0)
        owner = np.array([_record_truth_index(r, truth, match_radius_px) for r in recs],
                         dtype=int)
        for r, k in zip(recs, owner):
            if r['state'] == ANOMALY:
                anomalies += 1
            elif r['state'] == CONFIRMED and (k < 0 or int(truth['uid'][k]) != int(r['uid'])):
                wrong += 1
                wrong_list.add(int(r['uid']))
        for k, lamp in enumerate(truth):
            if not (lamp['in_left'] or lamp['in_right']):
                continue
            uid = int(lamp['uid'])
            mine = recs[owner == k] if recs.size else recs
            detected = bool(len(mine))
            identified = bool(np.any((mine['state'] == CONFIRMED) & (mine['uid'] == uid))) \
                if detected else False
            along = float(lamp['along_track_m'])
            frames.append([uid, along, detected, identified])
            if identified and first.get(uid) is None:
                first[uid] = along
            else:
                first.setdefault(uid, None)
    return {'frames': frames, 'first_confirmation_m': {str(k): v for k, v in first.items()},
            'wrong_uids': wrong, 'wrong_uid_list': sorted(wrong_list),
            'anomalies': anomalies}


# A lamp counts as passed when the run saw it closer than this: the train went by it
# while it was in view. A lamp glimpsed only farther out (the next lamp at the FOV edge,
# 9.5-13 m ahead, when a run ends) was never passed.
PASSED_WITHIN_M = 5.0


def passed_lamps(frames, first_confirmation_m, within_m=PASSED_WITHIN_M):
    """(lamps passed, of them identified) of one run.

    ``frames``: rows [uid, along_track_m, detected, identified]; ``first_confirmation_m``:
    {uid (int or str): distance or None} — the lamps in view.
    """
    nearest = {}
    for uid, along, _, _ in frames:
        nearest[int(uid)] = min(nearest.get(int(uid), np.inf), float(along))
    passed = [first for uid, first in first_confirmation_m.items()
              if nearest.get(int(uid), np.inf) < within_m]
    return len(passed), sum(first is not None for first in passed)


def success_by_distance(frames, edges_m=tuple(range(0, 11))):
    """Detection and identification rates per along-track distance bin.

    ``frames``: rows [uid, along_track_m, detected, identified] (from several runs).
    Returns a list of dicts per bin: lo_m, hi_m, frames, detected, identified (rates).
    """
    rows = np.array([[f[1], f[2], f[3]] for f in frames], dtype=float).reshape(-1, 3)
    out = []
    for lo, hi in zip(edges_m[:-1], edges_m[1:]):
        sel = (rows[:, 0] >= lo) & (rows[:, 0] < hi)
        n = int(sel.sum())
        out.append({'lo_m': float(lo), 'hi_m': float(hi), 'frames': n,
                    'detected': float(rows[sel, 1].mean()) if n else None,
                    'identified': float(rows[sel, 2].mean()) if n else None})
    return out
