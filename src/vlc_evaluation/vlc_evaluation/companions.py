"""Issue 7 through the real graph: every positioning method side by side, a lamp outage,
a forged lamp.

Three scenario kinds of the runner (``Scenario.kind``), each scored from its bag:

* ``companions`` — the whole graph plus ``photodiode_node`` (rig) and the four companion
  nodes (``rssi_localizer_node``, ``dead_reckoning_node``, ``ins_beacon_node``,
  ``curvature_node``) on the same static and dynamic scenarios, straight and curved
  (``curved_demo``). Every method is scored alike: every pose stamped after the settle
  time against the truth interpolated at its stamp (max, mean, 95th percentile), the
  availability (share of truth instants after the settle time with a pose of the
  method within ``max_gap_s`` on both sides: 0.1 s, curvature 1.0 s — it matches once
  a second), and the CPU time per update the node reports in its diagnostics.
* ``outage`` — the camera (and the photodiode) get a lamp map with every second lamp
  removed over ``HALF_DARK_M`` and then every lamp over ``FULL_DARK_M``; the decoder and
  the localizer keep the full map. Scored: the main localizer's error and published 3σ
  before, inside and after the outage, the integrity states its diagnostics report
  there, and where it re-acquires (its chainage σ back to the tracking level). A second
  run on ``curved_demo`` (:func:`curved_outage_scenario`, re-acquisition by the curvature
  match): every lamp dark over ``CURVED_DARK_M`` from ``CURVED_DARK_FROM_M``
  (no half-dark stretch), ``curvature_node`` beside the graph; scored alike (chainage =
  the truth projected on the alignment, σ along the track tangent) plus the localizer's
  curvature-aid counters, the error at the end of the dark stretch and the curvature
  matches' own errors there.
* ``forged`` — a clean run and the same run with one lamp broadcasting another lamp's
  valid UID (camera's lamp map only). ``LampMap`` refuses two lamps with one UID, so the
  UID copied is that of a lamp beyond the run's stretch (never in view), which the
  camera's map leaves out. Scored: the main localizer's and the INS's errors, the
  decoder frames confirming the forged UID, the localizer's rejected-fix counts and the
  INS beacon checker's flags.

Curved scenarios pass ``alignment: curved_demo`` to the rig, the curved lamp map to
every receiver and the IMU compensator (whose pulls toward a constant track attitude
are wrong on curves, grades and cant: it switches them off there).
"""
import pathlib

import numpy as np

from vlc_bags.bagio import open_bag
from vlc_common.core.alignment import Alignment
from vlc_common.core.lamp_map import Lamp, LampMap, default_lamp_map_path
from vlc_common.core.protocol import uid_of
from vlc_common.stamps import stamp_to_s
from vlc_evaluation import bag_eval, metrics, report
from vlc_evaluation.scenarios import (
    DYNAMIC_START_M,
    LAMP_X_M,
    STATIC_OBSERVE_S,
    Scenario,
    dynamic_settle_s,
    lead_in_m,
)

CURVED = 'curved_demo'
#: (key, label, pose topic, diagnostics status prefix, max_gap_s)
METHODS = (
    ('vlc_stereo', 'VLC stereo (train_localizer, this project)', '/train/pose',
     'train_localizer', 0.1),
    ('rssi', 'VLC + RSSI trilateration', '/companion/rssi/pose', 'rssi_localizer_node', 0.1),
    ('dead_reckoning', 'landmark + IMU dead reckoning', '/companion/dead_reckoning/pose',
     'dead_reckoning_node', 0.1),
    ('ins_beacon', 'INS + ZUPT + stereo beacon ranging', '/companion/ins_beacon/pose',
     'ins_beacon_node', 0.1),
    ('curvature', 'curvature-array correlation', '/companion/curvature/pose',
     'curvature_node', 1.0),
)
#: node-reported CPU per update (median key, tail key) per method
PROCESSING_KEYS = {'vlc_stereo': ('processing_ms_per_fix_median', 'processing_ms_per_fix_p99'),
                   'rssi': ('processing_ms_median', 'processing_ms_p95'),
                   'dead_reckoning': ('processing_ms_median', 'processing_ms_p95'),
                   'ins_beacon': ('processing_ms_median', 'processing_ms_p95')}
# (package, executable, parameter files) and the subscriptions each node creates
PHOTODIODE = ('vlc_stereo_camera', 'photodiode_node', ['rig.yaml', 'photodiode_node.yaml'])
COMPANION_NODES = {
    'rssi': [('companion_localizers', 'rssi_localizer_node', ['rssi_localizer_node.yaml'])],
    'dead_reckoning': [('companion_localizers', 'dead_reckoning_node',
                        ['dead_reckoning_node.yaml'])],
    'ins_beacon': [('companion_localizers', 'ins_beacon_node', ['ins_beacon_node.yaml'])],
    'curvature': [('companion_localizers', 'curvature_node', ['curvature_node.yaml'])],
}
_FRAME_NODE_SUBS = {'/imu/data': 1, '/spots/pairs': 1, '/vlc/lamps': 1,
                    '/stereo/left/camera_info': 1, '/stereo/right/camera_info': 1}
SUBSCRIPTIONS = {'photodiode_node': {'/clock': 1},
                 'rssi_localizer_node': {'/photodiode/rssi': 1, '/imu/data': 1},
                 'dead_reckoning_node': _FRAME_NODE_SUBS, 'ins_beacon_node': _FRAME_NODE_SUBS,
                 'curvature_node': {'/imu/data_raw': 1, '/train/odometry': 1}}
POSE_TOPICS = [m[2] for m in METHODS[1:]]

# Companion comparison set (defaults of the command)
STATIC_POINTS_M = (9.0, 5.0, 2.0)
SPEEDS_KMH = (40, 80, 120)
CELLS = 8
CURVED_LAMP_CHAINAGE_M = 400.0   # static on the curve: before this lamp, in the 400 m arc
CURVED_START_M = 150.0           # dynamic on the curve: 50 m before the first transition
CURVED_DURATION_S = 40.0         # a curvature match needs >= 300 m of array + smoothing
CURVED_SPEED_KMH = 80.0
# Lamp outage (straight track)
OUTAGE_START_M = 19.5            # the run starts here; lamps 20..40 m light the cold start
HALF_DARK_FROM_M = 50.0          # every second lamp dark from here ...
HALF_DARK_M = 200.0              # ... over this stretch,
FULL_DARK_M = 500.0              # then no lamp over this one
OUTAGE_TAIL_M = 30.0             # run on past the first lamp after the outage
OUTAGE_SPEED_KMH = 80.0
LAMP_VIEW_AHEAD_M = 10.0         # a lamp comes into the camera's view < 10 m ahead
# Lamp outage on curved_demo (curvature aid): straight to 200 m, R 400 left 200-560 m
# (clothoids 200-280, 480-560), straight 560-860, R 600 right 860-1160 (arc 920-1100),
# straight 1160-1310, R 800 left from 1310 (clothoid 1310-1410).
CURVED_OUTAGE_START_M = 419.5    # on the R 400 arc: 480 m of array before the outage
CURVED_DARK_FROM_M = 900.0       # no lamp from here (on the R 600 entry clothoid) ...
CURVED_DARK_M = 500.0            # ... to 1400 m: R 600 curve, straight, R 800 clothoid
CURVED_OUTAGE_SPEED_KMH = 80.0
# Forged lamp (straight track)
FORGED_START_M = 20.5
FORGED_END_M = 110.5
FORGED_LAMP_X_M = 70.0           # this lamp broadcasts ...
FORGED_UID_OF_X_M = 130.0        # ... the UID of this one (19.5 m past the run's end)
FORGED_SPEED_KMH = 60.0
SETTLE_CELLS = 2


def _pkg_rig(scenario):
    return {'seed': scenario.seed, 'motion_profile': scenario.motion_profile,
            'start_chainage_m': float(scenario.start_chainage_m),
            'speed_kmh': float(scenario.speed_kmh)}


def configure(scenario, methods=tuple(COMPANION_NODES), alignment='straight',
              camera_lamp_map=''):
    """Give ``scenario`` the extra nodes of ``methods`` and the parameters of its track.

    ``camera_lamp_map``: the lamp map the rig renders (and the photodiode receives) when it
    differs from the receivers' (outage, forged lamp); '' = the alignment's map.
    """
    receiver_map = default_lamp_map_path(alignment)
    rig_map = camera_lamp_map or receiver_map
    params = scenario.node_params
    params.setdefault('stereo_camera_node', {}).update(alignment=alignment,
                                                       lamp_map_path=rig_map)
    params.setdefault('adis16488_node', {}).update(alignment=alignment)
    params.setdefault('vlc_decoder_node', {}).update(lamp_map_path=receiver_map)
    params.setdefault('train_localizer_node', {}).update(lamp_map_path=receiver_map,
                                                         alignment=alignment)
    params.setdefault('imu_compensator_node', {}).update(alignment=alignment)
    nodes = []
    if 'rssi' in methods:
        nodes.append(PHOTODIODE)
        params['photodiode_node'] = dict(_pkg_rig(scenario), alignment=alignment,
                                         lamp_map_path=rig_map, follow_clock=True)
    for method in methods:
        for package, exe, files in COMPANION_NODES[method]:
            nodes.append((package, exe, files))
            if exe == 'curvature_node':
                params[exe] = dict(alignment=alignment)
            else:
                params[exe] = dict(lamp_map_path=receiver_map)
    scenario.extra_nodes = [[p, e, list(f)] for p, e, f in nodes]
    subs = {}
    for _, exe, _ in nodes:
        for topic, n in SUBSCRIPTIONS[exe].items():
            subs[topic] = subs.get(topic, 0) + n
    scenario.extra_subscriptions = subs
    topics = {'rssi': '/companion/rssi/pose', 'dead_reckoning': '/companion/dead_reckoning/pose',
              'ins_beacon': '/companion/ins_beacon/pose',
              'curvature': '/companion/curvature/pose'}
    scenario.extra_topics = [topics[m] for m in methods]
    scenario.kind_params.setdefault('alignment', alignment)
    return scenario


# --- scenario lists ---------------------------------------------------------------

def companion_scenarios(points_m=STATIC_POINTS_M, speeds_kmh=SPEEDS_KMH, cells=CELLS,
                        observe_s=STATIC_OBSERVE_S, curved_duration_s=CURVED_DURATION_S,
                        curved_speed_kmh=CURVED_SPEED_KMH, seed=1, curved=True):
    """Static and dynamic scenarios, straight and (``curved``) on ``curved_demo``, each
    with every companion method.
    """
    out = []

    def add(name, track, motion, **kw):
        s = Scenario(name=name, seed=seed, kind='companions',
                     kind_params={'track': track, 'motion': motion}, **kw)
        out.append(configure(s, alignment=CURVED if track == 'curved' else 'straight'))

    for d in points_m:
        add(f'companions_straight_static_{d:04.1f}m', 'straight', 'static',
            motion_profile='stationary', start_chainage_m=LAMP_X_M - d, duration_s=observe_s,
            observe_s=observe_s, static_point_m=d)
    for v in speeds_kmh:
        distance = lead_in_m(v) + 10.0 * (cells - SETTLE_CELLS) + 1.0
        add(f'companions_straight_dynamic_{v:03d}kmh', 'straight', 'dynamic',
            start_chainage_m=DYNAMIC_START_M, speed_kmh=float(v),
            duration_s=distance / (v / 3.6))
    if curved:
        for d in points_m[:2]:
            add(f'companions_curved_static_{d:04.1f}m', 'curved', 'static',
                motion_profile='stationary', start_chainage_m=CURVED_LAMP_CHAINAGE_M - d,
                duration_s=observe_s, observe_s=observe_s, static_point_m=d)
        add(f'companions_curved_dynamic_{int(curved_speed_kmh):03d}kmh', 'curved', 'dynamic',
            start_chainage_m=CURVED_START_M, speed_kmh=float(curved_speed_kmh),
            duration_s=float(curved_duration_s))
    return out


def _write_map(lamps, path, base):
    path = pathlib.Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    LampMap(lamps, frame_id=base.frame_id, alignment=base.alignment).save(path)
    return str(path.resolve())


def outage_geometry(half_from_m=HALF_DARK_FROM_M, half_m=HALF_DARK_M, full_m=FULL_DARK_M,
                    lamp_map=None):
    """Dark lamps (chainages) and the stretches: every second lamp dark in
    [half_from, half_from + half_m), every lamp dark in [that end, + full_m).
    """
    lamp_map = lamp_map or LampMap.load(default_lamp_map_path())
    x = np.array(sorted(lamp.track_chainage_m for lamp in lamp_map.lamps))
    full_from = half_from_m + half_m
    full_to = full_from + full_m
    half = (x >= half_from_m) & (x < full_from)
    dark = (half & (np.round((x - half_from_m) / 10.0).astype(int) % 2 == 1)) \
        | ((x >= full_from) & (x < full_to))
    lit = x[~dark]
    return {'dark_lamps_m': x[dark].tolist(), 'half_dark_from_m': half_from_m,
            'full_dark_from_m': full_from, 'full_dark_to_m': full_to,
            'last_lit_before_m': float(lit[lit < full_from].max()),
            'first_lit_after_m': float(lit[lit >= full_to].min())}


def outage_scenario(out_dir, speed_kmh=OUTAGE_SPEED_KMH, seed=1, half_m=HALF_DARK_M,
                    full_m=FULL_DARK_M):
    """The lamp-outage run; writes the camera's lamp map into ``out_dir``."""
    full = LampMap.load(default_lamp_map_path())
    geo = outage_geometry(half_m=half_m, full_m=full_m, lamp_map=full)
    dark = set(geo['dark_lamps_m'])
    path = _write_map([lamp for lamp in full.lamps if lamp.position_m[0] not in dark],
                      pathlib.Path(out_dir) / 'lamp_map_outage.yaml', full)
    end = geo['first_lit_after_m'] + OUTAGE_TAIL_M
    s = Scenario(name=f'outage_{int(speed_kmh):03d}kmh', seed=seed, kind='outage',
                 start_chainage_m=OUTAGE_START_M, speed_kmh=float(speed_kmh),
                 duration_s=(end - OUTAGE_START_M) / (speed_kmh / 3.6),
                 kind_params=dict(geo, camera_lamp_map=path),
                 # integrity state every 0.2 s of wall time, not 1 s
                 node_params={'train_localizer_node': {'diagnostics_period_s': 0.2}})
    return configure(s, methods=('ins_beacon',), camera_lamp_map=path)


def curved_outage_scenario(out_dir, speed_kmh=CURVED_OUTAGE_SPEED_KMH, seed=1,
                           start_m=CURVED_OUTAGE_START_M, dark_from_m=CURVED_DARK_FROM_M,
                           dark_m=CURVED_DARK_M):
    """The lamp-outage run on ``curved_demo`` with ``curvature_node`` beside the graph
    (its speed from ``train/odometry``, as the launch file); every lamp dark over
    [``dark_from_m``, + ``dark_m``) of chainage; writes the camera's map into ``out_dir``.
    """
    full = LampMap.load(default_lamp_map_path(CURVED))
    geo = outage_geometry(half_from_m=dark_from_m, half_m=0.0, full_m=dark_m, lamp_map=full)
    dark = set(geo['dark_lamps_m'])
    path = _write_map([lamp for lamp in full.lamps if lamp.track_chainage_m not in dark],
                      pathlib.Path(out_dir) / 'lamp_map_outage_curved.yaml', full)
    end = geo['first_lit_after_m'] + OUTAGE_TAIL_M
    s = Scenario(name=f'outage_curved_{int(speed_kmh):03d}kmh', seed=seed, kind='outage',
                 start_chainage_m=float(start_m), speed_kmh=float(speed_kmh),
                 duration_s=(end - start_m) / (speed_kmh / 3.6),
                 kind_params=dict(geo, camera_lamp_map=path, track='curved'),
                 node_params={'train_localizer_node': {'diagnostics_period_s': 0.2}})
    return configure(s, methods=('curvature',), alignment=CURVED, camera_lamp_map=path)


def forged_scenarios(out_dir, speed_kmh=FORGED_SPEED_KMH, seed=1):
    """A clean run and the same run with the lamp at ``FORGED_LAMP_X_M`` broadcasting the
    UID of the lamp at ``FORGED_UID_OF_X_M`` (camera's map only).
    """
    full = LampMap.load(default_lamp_map_path())
    by_x = {lamp.position_m[0]: lamp for lamp in full.lamps}
    victim, source = by_x[FORGED_LAMP_X_M], by_x[FORGED_UID_OF_X_M]
    forged = Lamp(uid=uid_of(source.line_id, source.lamp_id), line_id=source.line_id,
                  lamp_id=source.lamp_id, position_m=victim.position_m, normal=victim.normal,
                  diameter_m=victim.diameter_m)
    lamps = [forged if lamp is victim else lamp for lamp in full.lamps if lamp is not source]
    path = _write_map(lamps, pathlib.Path(out_dir) / 'lamp_map_forged.yaml', full)
    geo = {'forged_lamp_m': FORGED_LAMP_X_M, 'forged_uid': int(forged.uid),
           'true_uid': int(victim.uid), 'uid_owner_m': FORGED_UID_OF_X_M}
    out = []
    for name, camera_map in (('clean', ''), ('forged', path)):
        s = Scenario(name=f'forged_{name}_{int(speed_kmh):03d}kmh', seed=seed, kind='forged',
                     start_chainage_m=FORGED_START_M, speed_kmh=float(speed_kmh),
                     duration_s=(FORGED_END_M - FORGED_START_M) / (speed_kmh / 3.6),
                     kind_params=dict(geo, run=name, camera_lamp_map=camera_map))
        out.append(configure(s, methods=('ins_beacon',), camera_lamp_map=camera_map))
    return out


# --- scoring -------------------------------------------------------------------------

def _load_poses(bag, topics):
    cols = {t: ([], []) for t in topics}
    for topic, _, _, msg in open_bag(bag, topics=list(topics)):
        p = msg.pose.position
        cols[topic][0].append(stamp_to_s(msg.header.stamp))
        cols[topic][1].append([p.x, p.y, p.z])
    out = {}
    for topic, (t, xyz) in cols.items():
        t = np.asarray(t, float)
        order = np.argsort(t, kind='stable')
        out[topic] = (t[order], np.asarray(xyz, float).reshape(-1, 3)[order])
    return out


def _diag(run, node):
    """Every diagnostics status of ``node`` in bag order (list of {key: str})."""
    out = []
    for name, entries in run.diagnostics.items():
        if name.split(':')[0].strip().endswith(node):
            out.extend(entries)
    return out


def _float(values, key):
    try:
        v = float(values[key])
    except (KeyError, TypeError, ValueError):
        return None
    return v if np.isfinite(v) else None


def score_method(pose_t, pose_xyz, truth_t, truth_xyz, settle_t, max_gap_s):
    """Errors of every pose after ``settle_t`` and the truth instants covered."""
    if truth_t.size < 2:
        return {'errors_m': [], 'instants': 0, 'covered': 0}
    keep = (pose_t >= settle_t) & (pose_t <= truth_t[-1])
    err, _ = metrics.pose_errors(pose_t[keep], pose_xyz[keep], truth_t, truth_xyz)
    instants = truth_t[truth_t >= settle_t]
    covered, _ = metrics.errors_at_instants(instants, pose_t, pose_xyz, truth_t, truth_xyz,
                                            max_gap_s=max_gap_s)
    return {'errors_m': np.round(err, 5).tolist(), 'instants': int(instants.size),
            'covered': int(np.isfinite(covered).sum())}


def _processing(run, method, node):
    entries = _diag(run, node)
    if method == 'curvature':
        # the CPU of each match (the status repeats the last one until the next match)
        per_match, seen = [], None
        for values in entries:
            n = values.get('matches')
            v = _float(values, 'match_cpu_ms')
            if n != seen and v is not None and (n or '0') != '0':
                per_match.append(v)
            seen = n
        return ([float(np.median(per_match)), float(np.max(per_match))]
                if per_match else [None, None])
    keys = PROCESSING_KEYS[method]
    for values in reversed(entries):
        found = [_float(values, k) for k in keys]
        if found[0] is not None:
            return found
    return [None, None]


def _curvature_statuses(run):
    counts = {}
    for values in _diag(run, 'curvature_node'):
        status = values.get('status')
        if status:
            counts[status] = counts.get(status, 0) + 1
    return counts


def _settle_t(run, scenario):
    if scenario.is_static:
        return run.truth_t[0] + 1.0
    if scenario.kind == 'companions' and scenario.kind_params.get('track') == 'straight':
        return run.truth_t[0] + dynamic_settle_s(scenario.speed_kmh)   # as the protocol's runs
    return run.truth_t[0] + max(1.0, SETTLE_CELLS * 10.0 / max(scenario.speed_kmh / 3.6, 0.1))


def score_companions(run, scenario):
    """Every method of one ``companions`` scenario."""
    out = {'kind': 'companions', 'track': scenario.kind_params.get('track'),
           'motion': scenario.kind_params.get('motion'), 'speed_kmh': scenario.speed_kmh,
           'point_m': scenario.static_point_m if scenario.is_static else None,
           'health': bag_eval.graph_health(run), 'methods': {}}
    if run.truth_t.size < 2:
        return out
    poses = _load_poses(run.bag_path, POSE_TOPICS)
    poses['/train/pose'] = (run.pose_t, run.pose_xyz)
    settle = _settle_t(run, scenario)
    for method, _, topic, node, gap in METHODS:
        t, xyz = poses[topic]
        score = score_method(t, xyz, run.truth_t, run.truth_xyz, settle, gap)
        score['processing_ms'] = _processing(run, method, node)
        out['methods'][method] = score
    out['methods']['curvature']['statuses'] = _curvature_statuses(run)
    return out


def _along_sigma(run, alignment=None):
    """(t, σ along the track (m)) of /train/pose_with_covariance: along map x, or along
    the tangent of ``alignment`` at the true chainage.
    """
    if alignment is None or alignment.is_straight or run.cov_t.size == 0:
        return run.cov_t, np.sqrt(np.maximum(run.cov_xyz[:, 0, 0], 0.0))
    # stamps outside the truth's span take its end (they are left out of the scores)
    truth = metrics.interpolate_positions(np.clip(run.cov_t, run.truth_t[0], run.truth_t[-1]),
                                          run.truth_t, run.truth_xyz)
    s, _ = alignment.project(truth[:, 0], truth[:, 1])
    tan = alignment.evaluate(s).tangent
    var = np.einsum('ni,nij,nj->n', tan, run.cov_xyz[:, :2, :2], tan)
    return run.cov_t, np.sqrt(np.maximum(var, 0.0))


AID_KEYS = ('curvature_aids_received', 'curvature_aids_applied', 'curvature_aids_rejected',
            'curvature_aids_ignored', 'curvature_aid_resets')


def _aid_counters(run):
    """The localizer's curvature-aid counters from its last diagnostics."""
    loc = _diag(run, 'train_localizer')
    last = loc[-1] if loc else {}
    out = {k: _float(last, k) for k in AID_KEYS}
    out['last_curvature_aid'] = last.get('last_curvature_aid')
    return out


def _curvature_matches(run, alignment, lo, hi):
    """Accepted curvature matches (companion/curvature/pose) stamped while the true
    chainage is in [lo, hi): count, max and mean |match chainage − true chainage|.
    """
    t, xyz = _load_poses(run.bag_path, ['/companion/curvature/pose'])[
        '/companion/curvature/pose']
    inside = (t >= run.truth_t[0]) & (t <= run.truth_t[-1])
    t, xyz = t[inside], xyz[inside]
    if not t.size:
        return {'matches': 0, 'max_m': None, 'mean_m': None}
    truth = metrics.interpolate_positions(t, run.truth_t, run.truth_xyz)
    s_true, _ = alignment.project(truth[:, 0], truth[:, 1])
    s_match, _ = alignment.project(xyz[:, 0], xyz[:, 1])
    m = (s_true >= lo) & (s_true < hi)
    err = np.abs(s_match - s_true)[m]
    return {'matches': int(m.sum()), 'matches_in_run': int(t.size),
            'max_m': float(err.max()) if err.size else None,
            'mean_m': float(err.mean()) if err.size else None}


def score_outage(run, scenario):
    """The main localizer through the outage (see the module docstring)."""
    g = scenario.kind_params
    out = {'kind': 'outage', 'speed_kmh': scenario.speed_kmh, 'geometry': {
        k: v for k, v in g.items() if k != 'dark_lamps_m'}, 'dark_lamps': len(g['dark_lamps_m']),
        'health': bag_eval.graph_health(run), 'stretches': {}}
    track = g.get('track', 'straight')
    alignment = Alignment.named(g.get('alignment', 'straight'))
    if track != 'straight':
        out['track'] = track
    if run.truth_t.size < 2 or run.pose_t.size == 0:
        return out
    # chainage of the truth: map x on straight track, its projection on a curve
    truth_s = run.truth_xyz[:, 0] if alignment.is_straight else \
        alignment.project(run.truth_xyz[:, 0], run.truth_xyz[:, 1])[0]
    stretches = (('before', -np.inf, g['half_dark_from_m']),
                 ('every second lamp dark', g['half_dark_from_m'], g['full_dark_from_m']),
                 ('no lamp', g['full_dark_from_m'], g['full_dark_to_m']),
                 ('after', g['full_dark_to_m'], np.inf))
    stretches = [st for st in stretches if st[2] > st[1]]   # no half-dark stretch: left out
    settle = _settle_t(run, scenario)
    keep = (run.pose_t >= settle) & (run.pose_t <= run.truth_t[-1])
    t = run.pose_t[keep]
    err, _ = metrics.pose_errors(t, run.pose_xyz[keep], run.truth_t, run.truth_xyz)
    s_at = np.interp(t, run.truth_t, truth_s)
    ct, sigma = _along_sigma(run, alignment)
    ck = (ct >= settle) & (ct <= run.truth_t[-1])
    cs = np.interp(ct[ck], run.truth_t, truth_s)
    diff = run.cov_mean[ck] - metrics.interpolate_positions(ct[ck], run.truth_t, run.truth_xyz)
    inside = np.all(np.abs(diff) <= 3.0 * np.sqrt(np.maximum(
        np.diagonal(run.cov_xyz[ck], axis1=1, axis2=2), 0.0)), axis=1)
    states = [(v.get('integrity_state'), _float(v, 'last_pose_chainage_m'))
              for v in _diag(run, 'train_localizer')]
    for name, lo, hi in stretches:
        m = (s_at >= lo) & (s_at < hi)
        c = (cs >= lo) & (cs < hi)
        seen = {}
        for state, chainage in states:
            if state and chainage is not None and lo <= chainage < hi:
                seen[state] = seen.get(state, 0) + 1
        out['stretches'][name] = {
            'poses': int(m.sum()),
            'max_m': float(err[m].max()) if m.any() else None,
            'mean_m': float(err[m].mean()) if m.any() else None,
            'max_3sigma_along_m': float(3.0 * sigma[ck][c].max()) if c.any() else None,
            'within_3sigma': float(inside[c].mean()) if c.any() else None,
            'integrity_states': seen}
    # re-acquisition: the along-track σ back at the tracking level after the outage
    before = sigma[ck][cs < g['half_dark_from_m']]
    level = max(0.05, 3.0 * float(np.median(before))) if before.size else 0.05
    after = np.nonzero((cs >= g['full_dark_to_m'] - 10.0) & (sigma[ck] <= level))[0]
    peak = sigma[ck][(cs >= g['full_dark_from_m']) & (cs < g['full_dark_to_m'])]
    out['sigma_peak_m'] = float(peak.max()) if peak.size else None
    out['reacquire_sigma_level_m'] = level
    if after.size:
        t_re = ct[ck][after[0]]
        s_re = float(cs[after[0]])
        post = t >= t_re
        out.update({'reacquired_at_m': s_re,
                    'reacquired_before_first_lit_lamp_m': g['first_lit_after_m'] - s_re,
                    'reacquired_within_one_lamp': bool(s_re <= g['first_lit_after_m']),
                    'max_after_reacquisition_m': float(err[post].max()) if post.any() else None})
    else:
        out['reacquired_within_one_lamp'] = False
    # the end of the dark stretch: the last pose before the first lamp after it can be
    # in view
    end_s = g['first_lit_after_m'] - LAMP_VIEW_AHEAD_M
    dark = np.nonzero((s_at >= g['full_dark_from_m']) & (s_at < end_s))[0]
    if dark.size:
        i = dark[-1]
        j = np.nonzero(ck)[0]
        k = j[np.argmin(np.abs(ct[j] - t[i]))] if j.size else None
        out['end_of_dark'] = {'chainage_m': float(s_at[i]), 'error_m': float(err[i]),
                              'sigma_along_m': float(sigma[k]) if k is not None else None}
    if track != 'straight':
        out['aid'] = _aid_counters(run)
        out['curvature_statuses'] = _curvature_statuses(run)
        out['curvature_matches_dark'] = _curvature_matches(
            run, alignment, g['full_dark_from_m'], g['full_dark_to_m'])
    return out


def _lamp_records_with_uid(run, uid, state=2):
    n = 0
    for records in run.lamps.values():
        if records.size and 'uid' in records.dtype.names:
            n += int(np.sum((records['uid'] == uid) & (records['state'] == state)))
    return n


def score_forged(run, scenario):
    """Clean or forged run: errors of the main localizer and the INS, rejections, flags."""
    g = scenario.kind_params
    out = {'kind': 'forged', 'run': g['run'], 'speed_kmh': scenario.speed_kmh,
           'forged_uid': g['forged_uid'], 'health': bag_eval.graph_health(run), 'methods': {}}
    if run.truth_t.size < 2:
        return out
    settle = _settle_t(run, scenario)
    poses = _load_poses(run.bag_path, ['/companion/ins_beacon/pose'])
    poses['/train/pose'] = (run.pose_t, run.pose_xyz)
    for method, topic in (('vlc_stereo', '/train/pose'),
                          ('ins_beacon', '/companion/ins_beacon/pose')):
        t, xyz = poses[topic]
        out['methods'][method] = score_method(t, xyz, run.truth_t, run.truth_xyz, settle, 0.1)
    loc = _diag(run, 'train_localizer')
    last = loc[-1] if loc else {}
    out['localizer'] = {k: _float(last, k) for k in (
        'fixes_accepted', 'rejected_contradiction', 'rejected_geometry', 'unknown_uid')}
    out['localizer']['integrity_states'] = sorted({v.get('integrity_state') for v in loc
                                                   if v.get('integrity_state')})
    ins = _diag(run, 'ins_beacon_node')
    last = ins[-1] if ins else {}
    out['ins_beacon'] = {'beacons_flagged': _float(last, 'beacons_flagged'),
                         'beacons_accepted': _float(last, 'beacons_accepted'),
                         'flags': sorted({(v.get('last_flagged_uid'), v.get('last_flag_reason'))
                                          for v in ins if v.get('last_flag_reason')})}
    out['decoder_frames_forged_uid'] = _lamp_records_with_uid(run, g['forged_uid'])
    return out


def score_kind(run, scenario):
    """Scores of a scenario of one of this module's kinds. A bag whose truth stops more
    than a second before the run's end (seen once: the recorder stopped receiving 10 s
    after closing its first split) is marked degraded, so the runner runs it again.
    """
    result = {'companions': score_companions, 'outage': score_outage,
              'forged': score_forged}[scenario.kind](run, scenario)
    span = float(run.truth_t[-1] - run.truth_t[0]) if run.truth_t.size else 0.0
    if span < scenario.duration_s - 1.0:
        result['health'] = dict(result['health'], bag_truncated_at_s=round(span, 3),
                                degraded=True)
    return result


# --- tables ------------------------------------------------------------------------

_cm = metrics.cm_text


def _m(value):
    return '–' if value is None or not np.isfinite(value) else f'{value:.2f}'


def _ms(values):
    return ' / '.join('–' if v is None else f'{v:.2f}' for v in values)


CASES = (('straight', 'static'), ('straight', 'dynamic'), ('curved', 'static'),
         ('curved', 'dynamic'))


def companion_table(results):
    """One Markdown table of every method per case (track × motion), pooled over the
    case's scenarios; returns (markdown, figures).
    """
    figures = {}
    rows = ['| case | method | poses | max (cm) | mean (cm) | 95th pct (cm) | availability '
            '| CPU ms per update (median / tail) | note |',
            '|---|---|---|---|---|---|---|---|---|']
    for track, motion in CASES:
        runs = [r for r in results if r.get('track') == track and r.get('motion') == motion
                and r.get('methods')]
        if not runs:
            continue
        speeds = sorted({int(round(r['speed_kmh'])) for r in runs})
        case = (f'{track}, {motion} ({len(runs)} run{"s" * (len(runs) > 1)}'
                + (f', {"/".join(map(str, speeds))} km/h' if motion == 'dynamic' else '') + ')')
        for method, label, *_ in METHODS:
            scores = [r['methods'][method] for r in runs if method in r['methods']]
            errors = np.concatenate([np.asarray(s['errors_m'], float) for s in scores]) \
                if scores else np.zeros(0)
            summary = metrics.summarize(errors)
            instants = sum(s['instants'] for s in scores)
            avail = sum(s['covered'] for s in scores) / instants if instants else 0.0
            proc = [p for s in scores for p in [s.get('processing_ms')] if p and p[0] is not None]
            cpu = [float(np.median([p[0] for p in proc])),
                   float(np.max([p[1] for p in proc if p[1] is not None] or [np.nan]))] \
                if proc else [None, None]
            note = ''
            if method == 'curvature':
                statuses = {}
                for s in scores:
                    for k, n in s.get('statuses', {}).items():
                        statuses[k] = statuses.get(k, 0) + n
                note = ', '.join(f'{k} {n}' for k, n in sorted(statuses.items(),
                                                               key=lambda kv: -kv[1]))
            fig = {'poses': int(errors.size), 'max_m': summary.max_m, 'mean_m': summary.mean_m,
                   'p95_m': summary.p95_m, 'availability': avail, 'cpu_ms': cpu, 'note': note}
            figures.setdefault(f'{track}_{motion}', {})[method] = fig
            rows.append(f'| {case} | {label} | {fig["poses"]} | {_cm(summary.max_m)} | '
                        f'{_cm(summary.mean_m)} | {_cm(summary.p95_m)} | {100 * avail:.1f} % | '
                        f'{_ms(cpu)} | {note} |')
    return '\n'.join(rows), figures


def outage_table(results):
    """The main localizer through each outage run, per stretch."""
    rows = ['| run | stretch | poses | max error (cm) | mean error (cm) | largest published '
            '3σ along track (cm) | poses within 3σ | integrity states reported |',
            '|---|---|---|---|---|---|---|---|']
    lines, figures = [], {}
    for r in results:
        name = f'{r["speed_kmh"]:g} km/h, {r["dark_lamps"]} lamps dark'
        if r.get('track', 'straight') != 'straight':
            name = f'{CURVED}, {name}'
        figures[name] = {k: v for k, v in r.items() if k != 'health'}
        for stretch, s in r.get('stretches', {}).items():
            states = ', '.join(f'{k} {n}' for k, n in s['integrity_states'].items()) or '–'
            within = '–' if s['within_3sigma'] is None else f'{100 * s["within_3sigma"]:.1f} %'
            rows.append(f'| {name} | {stretch} | {s["poses"]} | {_cm(s["max_m"])} | '
                        f'{_cm(s["mean_m"])} | {_cm(s["max_3sigma_along_m"])} | {within} | '
                        f'{states} |')
        g = r['geometry']
        half = (f'outage from {g["half_dark_from_m"]:g} m (every second lamp), '
                if g.get('full_dark_from_m', np.inf) > g['half_dark_from_m'] else '')
        if 'reacquired_at_m' in r:
            lines.append(
                f'- {name}: {half}no lamp '
                f'from {g["last_lit_before_m"]:g} m to {g["first_lit_after_m"]:g} m; along-track '
                f'σ peaked at {_m(r["sigma_peak_m"])} m; re-acquired (σ ≤ '
                f'{_cm(r["reacquire_sigma_level_m"])} cm) at {r["reacquired_at_m"]:.1f} m, '
                f'{r["reacquired_before_first_lit_lamp_m"]:.1f} m before the first lamp after '
                f'the outage: within one lamp: '
                f'**{"yes" if r["reacquired_within_one_lamp"] else "no"}**'
                f'; max error after re-acquisition {_cm(r["max_after_reacquisition_m"])} cm.')
        else:
            lines.append(f'- {name}: **not re-acquired** before the end of the run.')
        if 'aid' in r:
            lines.append(f'- {name}: ' + _aid_line(r))
        cut = r.get('health', {}).get('bag_truncated_at_s')
        if cut is not None:
            lines.append(f'- {name}: **bag incomplete** — its truth stops {cut:.1f} s into the '
                         'run (the recorder stopped receiving); the stretches after that are '
                         'not measured.')
    return '\n'.join(rows + [''] + lines), figures


def _aid_line(r):
    """The curvature aid through a curved outage, one sentence."""
    a, e = r['aid'], r.get('end_of_dark')
    cm = r.get('curvature_matches_dark') or {}

    def n(v):
        return '–' if v is None else f'{v:.0f}'
    end = (f'at {e["chainage_m"]:.1f} m (the last pose before the first lamp after the '
           f'outage can be in view) error {_m(e["error_m"])} m, published 3σ along track '
           f'{_m(None if e["sigma_along_m"] is None else 3.0 * e["sigma_along_m"])} m'
           if e else 'no pose at the end of the dark stretch')
    statuses = ', '.join(f'{k} {v}' for k, v in sorted(
        r.get('curvature_statuses', {}).items(), key=lambda kv: -kv[1])) or '–'
    return (f'curvature aid (localizer diagnostics at the end of the run): received '
            f'{n(a.get("curvature_aids_received"))}, **applied '
            f'{n(a.get("curvature_aids_applied"))}**, rejected '
            f'{n(a.get("curvature_aids_rejected"))}, ignored '
            f'{n(a.get("curvature_aids_ignored"))}, resets {n(a.get("curvature_aid_resets"))}'
            f' (last: {a.get("last_curvature_aid") or "–"}); curvature matches while dark: '
            f'{cm.get("matches", 0)}, chainage error max {_m(cm.get("max_m"))} m, mean '
            f'{_m(cm.get("mean_m"))} m (curvature_node statuses: {statuses}); {end}.')


def forged_table(results):
    """Clean and forged runs side by side."""
    rows = ['| run | VLC stereo max / mean (cm) | INS max / mean (cm) | decoder frames confirming '
            'the forged UID | localizer fixes accepted / rejected (contradiction) | INS beacons '
            'accepted / flagged | INS flags (uid, reason) |',
            '|---|---|---|---|---|---|---|']
    figures = {}
    for r in results:
        figs = {}
        cells = []
        for method in ('vlc_stereo', 'ins_beacon'):
            s = metrics.summarize(r.get('methods', {}).get(method, {}).get('errors_m', []))
            figs[method] = {'max_m': s.max_m, 'mean_m': s.mean_m, 'poses': s.count}
            cells.append(f'{_cm(s.max_m)} / {_cm(s.mean_m)}')
        loc, ins = r.get('localizer', {}), r.get('ins_beacon', {})
        flags = '; '.join(f'{u} {why}' for u, why in ins.get('flags', [])) or '–'

        def n(v):
            return '–' if v is None else f'{v:.0f}'
        figures[r['run']] = dict(figs, localizer=loc, ins_beacon=ins,
                                 decoder_frames_forged_uid=r.get('decoder_frames_forged_uid'))
        rows.append(f'| {r["run"]} ({r["speed_kmh"]:g} km/h) | {cells[0]} | {cells[1]} | '
                    f'{r.get("decoder_frames_forged_uid", "–")} | '
                    f'{n(loc.get("fixes_accepted"))} / {n(loc.get("rejected_contradiction"))} | '
                    f'{n(ins.get("beacons_accepted"))} / {n(ins.get("beacons_flagged"))} | '
                    f'{flags} |')
    return '\n'.join(rows), figures


def compact(result):
    """A result without its per-pose error arrays (report.json)."""
    out = dict(result)
    if 'methods' in out:
        out['methods'] = {}
        for method, s in result['methods'].items():
            e = metrics.summarize(s.get('errors_m', []))
            out['methods'][method] = dict({k: v for k, v in s.items() if k != 'errors_m'},
                                          max_m=e.max_m, mean_m=e.mean_m, p95_m=e.p95_m)
    return out


def report_sections(companions=(), outage=(), forged=()):
    """Markdown sections and figures of the three kinds (empty where none ran)."""
    parts, figures = [], {}
    if companions:
        table, figures['companions'] = companion_table(companions)
        parts += ['', '### Every positioning method on the same scenarios', '',
                  'Every pose after the settle time (static 1 s; straight dynamic runs the '
                  "protocol's lead-in, two lamp cells and at least 3 s; curved the later of "
                  '1 s and two lamp cells) against the truth at its stamp; availability = '
                  'share of '
                  'truth instants with a pose within 0.1 s on both sides (curvature: 1.0 s, it '
                  'matches once a second); CPU = the node\'s own report per update (VLC stereo: '
                  'per fix, median / p99, after the decoder and spot locator; RSSI: per '
                  'photodiode sample; DR, INS: per stereo frame, median / p95; curvature: per '
                  'match, median / max). Curvature refuses straight track by design (note: its '
                  'statuses). Straight-track runs: the lamp at 50 m; curved runs on '
                  '`curved_demo`: static before the lamp at 400 m (in the R 400 m arc), dynamic '
                  f'from {CURVED_START_M:g} m; the curvature node takes its speed from '
                  '`train/odometry`.', '', table,
                  '', 'Sources: RSSI trilateration max 39.23 cm, mean 13.36 cm (Zhang, Xu, Ma, '
                  'Zhu); dead reckoning and curvature correlation: metre level.']
    if outage:
        table, figures['outage'] = outage_table(outage)
        parts += ['', '### Lamp outage (main localizer)', '',
                  'The camera renders a lamp map without the dark lamps; decoder and localizer '
                  'keep the full map. Stretches by the true chainage; integrity states from '
                  'the localizer\'s diagnostics (every 0.2 s), placed by its '
                  '`last_pose_chainage_m`.' + (
                      ' On `curved_demo` the chainage is the truth projected on the '
                      'alignment, the σ the one along the track tangent, and curvature_node '
                      'runs beside the graph (speed from `train/odometry`) for the '
                      'localizer\'s re-acquisition aid.'
                      if any(r.get('track', 'straight') != 'straight' for r in outage)
                      else ''), '', table]
    if forged:
        table, figures['forged'] = forged_table(forged)
        f = forged[0]
        parts += ['', '### Forged lamp', '',
                  f'The lamp at {FORGED_LAMP_X_M:g} m broadcasts UID {f["forged_uid"]:#06x} '
                  f'(the lamp at {FORGED_UID_OF_X_M:g} m, beyond the run) in the forged run; '
                  'decoder and localizer keep the true map. Same seed as the clean run.', '',
                  table]
    return '\n'.join(parts), figures


def append_to_report(out_dir, companions=(), outage=(), forged=()):
    """Append the sections of the three kinds to ``out_dir/report.md`` and their figures
    and compact results to ``report.json`` (written by :func:`report.write_report`);
    returns the text appended.
    """
    import json
    out_dir = pathlib.Path(out_dir)
    text, figures = report_sections(companions, outage, forged)
    if not text:
        return ''
    text += '\n'
    md = out_dir / 'report.md'
    md.write_text((md.read_text(encoding='utf-8') if md.exists() else '') + text,
                  encoding='utf-8')
    path = out_dir / 'report.json'
    data = json.loads(path.read_text(encoding='utf-8')) if path.exists() else {'figures': {}}
    data['figures'].update(figures)
    for kind, results in (('companions', companions), ('outage', outage), ('forged', forged)):
        if results:
            data[kind] = [compact(r) for r in results]
    path.write_text(json.dumps(data, indent=1, default=float), encoding='utf-8')
    return text


DOCS_BEGIN = ('<!-- companions:begin (generated by run_evaluation --companions-docs; '
              'do not edit) -->')
DOCS_END = '<!-- companions:end -->'


def update_docs(markdown_path, text, command):
    """Put ``text`` (the sections of :func:`report_sections`) between the companion markers
    of ``markdown_path`` (appended with them when absent), under the command line.
    """
    markdown_path = pathlib.Path(markdown_path)
    section = (f'{DOCS_BEGIN}\nGenerated by `{command}` (all figures in its '
               f'`report.json`).\n{text.rstrip()}\n{DOCS_END}')
    report.replace_marked_block(markdown_path, section, begin=DOCS_BEGIN, end=DOCS_END)
