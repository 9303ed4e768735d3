"""What the markers show, drawn from a recorded bag into a PNG (top view and side view).

    view_picture BAG -o docs/images/view_sample_80kmh.png [--at-s T] [--ahead-m 14]

Reads ``/vlc/lamps``, ``/spots/pairs``, ``/train/pose_with_covariance`` (and
``/ground_truth/pose`` when the bag has it) in bag order into the same
:class:`vlc_view.core.scene.ViewState` the marker node keeps, up to ``--at-s`` seconds
after the bag's first pose (default: the whole bag), and draws the scene with matplotlib
in the marker node's colours: the lamps by state with the UIDs of those seen, the train
head (box behind base_link) and the positions so far, the along-track ±3σ bar (drawn at
least 5 cm long; its value in the legend), the rays of the last fix from the left camera,
and the true position at the pose's stamp.
"""
import argparse
import pathlib
import sys

import numpy as np

from vlc_bags.bagio import open_bag
from vlc_common.core.lamp_map import LampMap, resolve_lamp_map_path
from vlc_common.core.vehicle import load_vehicle
from vlc_common.stamps import stamp_to_ns
from vlc_view import conversions
from vlc_view.core import style
from vlc_view.core.scene import LAMP_STATE_NAMES, ViewState

TOPICS = ('/vlc/lamps', '/spots/pairs', '/train/pose_with_covariance', '/ground_truth/pose')


def scene_from_bag(bag, lamp_map, camera_mount, at_s=None, recent_s=5.0):
    """Feed a bag's records into a :class:`ViewState` (bag order) and return
    ``(scene, truth)``: the scene of the records stamped up to ``at_s`` seconds after the
    first pose's stamp (None: all), and the ground-truth position (3,) at the scene's pose
    stamp (None without ground truth in the bag).
    """
    state = ViewState(lamp_map, camera_mount, recent_s=recent_s)
    truth_t, truth_xyz = [], []
    messages = list(open_bag(bag, topics=list(TOPICS)))
    poses = [stamp_to_ns(m.header.stamp) for t, _, _, m in messages
             if t == '/train/pose_with_covariance']
    # data time, not the bag's receive times (a replay may have run slower than real time)
    until_ns = None if at_s is None or not poses else min(poses) + at_s * 1e9
    for topic, _, _, msg in messages:
        stamp_ns = stamp_to_ns(msg.header.stamp)
        if topic == '/ground_truth/pose':
            p = msg.pose.position
            truth_t.append(stamp_ns)
            truth_xyz.append((p.x, p.y, p.z))
        elif until_ns is not None and stamp_ns > until_ns:
            continue
        elif topic == '/train/pose_with_covariance':
            state.add_pose(*conversions.pose_with_covariance(msg))
        else:
            stamp_ns, records = conversions.cloud_records(msg)
            (state.add_lamps if topic == '/vlc/lamps' else state.add_pairs)(stamp_ns, records)
    scene = state.scene()
    truth = None
    if scene.train is not None and len(truth_t) >= 2:
        order = np.argsort(truth_t)
        t = np.asarray(truth_t, float)[order]
        xyz = np.asarray(truth_xyz)[order]
        stamp = float(scene.train.stamp_ns)
        if t[0] <= stamp <= t[-1]:
            truth = np.array([np.interp(stamp, t, xyz[:, k]) for k in range(3)])
    return scene, truth


def draw(scene, truth=None, title='', ahead_m=14.0, behind_m=12.0):
    """A matplotlib Figure with the top view (x, y) and the side view (x, z) of ``scene``."""
    import matplotlib
    matplotlib.use('Agg')
    from matplotlib import pyplot as plt
    from matplotlib.patches import Polygon

    fig, (top, side) = plt.subplots(2, 1, figsize=(11, 7.5), sharex=True,
                                    gridspec_kw={'height_ratios': [1.1, 1.0]})
    train = scene.train
    centre_x = train.position_m[0] if train is not None else float(
        np.nanmean(scene.lamp_positions[:, 0]))
    lo, hi = centre_x - behind_m, centre_x + ahead_m
    shown = (scene.lamp_positions[:, 0] >= lo) & (scene.lamp_positions[:, 0] <= hi)
    for ax, (i, j), label in ((top, (0, 1), 'map y (m)'), (side, (0, 2), 'map z (m)')):
        ax.axhline(0.0, color=style.TRACK_COLOUR[:3], lw=0.8, ls=':')
        for state, name in LAMP_STATE_NAMES.items():
            sel = shown & (scene.lamp_states == state)
            ax.scatter(scene.lamp_positions[sel, i], scene.lamp_positions[sel, j], s=70,
                       color=style.LAMP_COLOURS[state], edgecolor='k', lw=0.5, zorder=3,
                       label=f'lamp {name}')
        for k in np.flatnonzero(shown & (scene.lamp_states > 0)):
            ax.annotate(f'{int(scene.lamp_uids[k]):#06x}',
                        scene.lamp_positions[k, [i, j]], xytext=(0, 8),
                        textcoords='offset points', ha='center', fontsize=8)
        if len(scene.history_m) >= 2:
            ax.plot(scene.history_m[:, i], scene.history_m[:, j], color='k', lw=1.0,
                    label='train/pose so far')
        if train is not None:
            rot = train.rotation
            box = np.array(style.TRAIN_BOX_M)
            if j == 1:
                corners = [(0, -1, 0), (0, 1, 0), (-1, 1, 0), (-1, -1, 0)]
            else:
                corners = [(0, 0, 0), (0, 0, 1), (-1, 0, 1), (-1, 0, 0)]
            pts = [train.position_m + rot @ (np.array(c) * np.array(
                [box[0], box[1] / 2, box[2]])) for c in corners]
            ax.add_patch(Polygon([(p[i], p[j]) for p in pts], closed=True,
                                 color=style.TRAIN_COLOUR, label='train head'))
            half = max(3.0 * scene.sigma_along_m, style.BAR_MIN_HALF_LENGTH_M)
            ends = train.position_m + np.outer([-half, half], scene.along_axis)
            ax.plot(ends[:, i], ends[:, j], color=style.BAR_COLOUR, lw=4, solid_capstyle='butt',
                    label=f'along-track ±3σ = ±{300 * scene.sigma_along_m:.1f} cm', zorder=4)
            ax.plot(train.position_m[i], train.position_m[j], 'o', color=style.HEADING_COLOUR,
                    ms=4, zorder=5, label='base_link (train/pose)')
        if truth is not None:
            ax.plot(truth[i], truth[j], 'x', color='k', ms=8, mew=1.5, zorder=6,
                    label='ground truth')
        if scene.camera_m is not None and len(scene.rays_m):
            for n, seg in enumerate(scene.rays_m):
                ax.plot(seg[:, i], seg[:, j], color=style.RAY_COLOUR, lw=1.2, zorder=2,
                        label='rays of the last fix' if n == 0 else None)
            ax.plot(scene.camera_m[i], scene.camera_m[j], 's', color=style.CAMERA_COLOUR,
                    ms=5, zorder=5, label='left camera')
        ax.set_ylabel(label)
        ax.grid(alpha=0.3)
    if train is not None:
        _zoom(top, scene, truth)
    top.set_title('top view', fontsize=10, loc='left')
    side.set_title('side view', fontsize=10, loc='left')
    top.set_xlim(lo, hi)
    top.set_ylim(-2.0, 3.5)
    side.set_ylim(-0.5, 4.5)
    top.set_aspect('equal')
    side.set_aspect('equal')
    side.set_xlabel('map x (m)')
    handles, labels = top.get_legend_handles_labels()
    fig.legend(handles, labels, loc='lower center', ncol=4, fontsize=8, frameon=False)
    fig.suptitle(title, fontsize=11)
    fig.tight_layout(rect=(0, 0.1, 1, 0.97))
    return fig


def _zoom(ax, scene, truth):
    """Inset of the top view around base_link: the ±3σ bar, the estimate and the truth at
    centimetre scale (the main view spans tens of metres).
    """
    train = scene.train
    half = max(4.0 * scene.sigma_along_m, 0.05)
    if truth is not None:
        half = max(half, 1.3 * float(np.max(np.abs(truth[:2] - train.position_m[:2]))))
    inset = ax.inset_axes((0.77, 0.05, 0.21, 0.42))
    x0, y0 = train.position_m[:2]
    bar = train.position_m + np.outer([-3.0, 3.0], scene.sigma_along_m * scene.along_axis)
    inset.plot(100 * (bar[:, 0] - x0), 100 * (bar[:, 1] - y0), color=style.BAR_COLOUR, lw=3,
               solid_capstyle='butt')
    for end in bar:
        inset.plot(100 * (end[0] - x0), 100 * (end[1] - y0), '|', color=style.BAR_COLOUR,
                   ms=12, mew=2)
    inset.plot(0.0, 0.0, 'o', color=style.HEADING_COLOUR, ms=5)
    if truth is not None:
        inset.plot(100 * (truth[0] - x0), 100 * (truth[1] - y0), 'x', color='k', ms=8, mew=1.5)
    inset.set_xlim(-100 * half, 100 * half)
    inset.set_ylim(-100 * half, 100 * half)
    inset.set_aspect('equal')
    inset.tick_params(labelsize=7)
    inset.set_title('at base_link (cm)', fontsize=8)
    inset.grid(alpha=0.3)


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('bag', help='a recording with /vlc/lamps, /spots/pairs and '
                                    '/train/pose_with_covariance')
    parser.add_argument('-o', '--output', required=True, help='PNG to write')
    parser.add_argument('--at-s', type=float, default=None,
                        help='draw the scene this long after the first pose, s (default: '
                             'the end of the bag)')
    parser.add_argument('--ahead-m', type=float, default=14.0)
    parser.add_argument('--behind-m', type=float, default=12.0)
    parser.add_argument('--recent-s', type=float, default=5.0)
    parser.add_argument('--lamp-map', default='', help="lamp map YAML ('' = the installed)")
    parser.add_argument('--vehicle', default='', help="vehicle file ('' = the installed)")
    parser.add_argument('--dpi', type=int, default=110)
    args = parser.parse_args(argv)
    try:
        lamp_map = LampMap.load(resolve_lamp_map_path(args.lamp_map))
        camera = load_vehicle(args.vehicle).camera
        scene, truth = scene_from_bag(args.bag, lamp_map, camera, args.at_s, args.recent_s)
    except (OSError, ValueError, KeyError) as exc:
        print(f'view_picture: error: {exc}', file=sys.stderr)
        return 2
    if scene.train is None:
        print(f'view_picture: error: {args.bag} has no /train/pose_with_covariance',
              file=sys.stderr)
        return 2
    title = f'{pathlib.Path(args.bag).name}: train at x = {scene.train.position_m[0]:.2f} m'
    if scene.fix_stamp_ns:
        title += (f', rays of the frame {(scene.train.stamp_ns - scene.fix_stamp_ns) / 1e6:.0f}'
                  ' ms before the pose')
    if truth is not None:
        title += f'; error {100 * np.linalg.norm(scene.train.position_m - truth):.1f} cm'
    fig = draw(scene, truth, title, args.ahead_m, args.behind_m)
    out = pathlib.Path(args.output)
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=args.dpi)
    print(f'{out}: {len(scene.ray_uids)} ray(s) to '
          f'{", ".join(f"{u:#06x}" for u in scene.ray_uids) or "no lamp"}; lamps identified '
          f'now {int((scene.lamp_states == 2).sum())}, seen recently '
          f'{int((scene.lamp_states == 1).sum())}')
    return 0


if __name__ == '__main__':
    sys.exit(main())
