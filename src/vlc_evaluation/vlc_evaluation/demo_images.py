"""``render_demo_images``: PNGs of the synthetic stereo camera for the README.

Writes into ``--out-dir`` (default ``docs/images``, relative to the working directory):

* ``stereo_pair_near_far.png``: full left/right frames side by side, once with a lamp
  about 2 m ahead and once about 9 m ahead (the default lamp spacing of 10 m never shows
  both at once), train at 20 km/h with platform vibration;
* ``lamp_crops.png``: zoomed crops of the same spots showing the rolling-shutter stripes,
  labelled with UID, range, viewing angle and the rows the spot covers.
"""
import argparse
import pathlib

import matplotlib
import numpy as np

from vlc_common.core.lamp_map import LampMap, resolve_lamp_map_path
from vlc_stereo_camera.core.renderer import RendererConfig, StereoRenderer
from vlc_stereo_camera.core.trajectory import MotionProfile, Trajectory, Vibration

# The graph's camera timing (config/stereo_camera_node.yaml, ARCHITECTURE.md): 21.15 kchip/s
# lamps seen with a 25 µs row exposure, not the core's paper/protocol defaults.
DEMO_CONFIG = RendererConfig(chip_rate_hz=21_150.0, exposure_s=25e-6)

matplotlib.use('Agg')
import matplotlib.pyplot as plt  # noqa: E402  (backend first)

SPEED_MPS = 20 / 3.6
LAMP_X_M = 30.0        # lamp UID 4099


def _frame_with_lamp_at(distance_m, seed=1):
    """A frame whose row 0 starts when the lamp is ``distance_m`` ahead of base_link.

    The vibration's heading swings by −5…+7.5° and moves the far end of the view; the
    frame is taken at an instant where the heading disturbance is below 0.5°.
    """
    vibration = Vibration(seed=seed)
    candidates = np.arange(1.0, 20.0, 1.0 / 30.0)
    yaw = Trajectory(MotionProfile('constant', speed_mps=SPEED_MPS),
                     vibration).sample(candidates).rpy_rad[:, 2]
    t0 = float(candidates[np.argmax(np.abs(yaw) < np.radians(0.5))])
    traj = Trajectory(MotionProfile('constant', start_chainage_m=LAMP_X_M - distance_m
                                    - SPEED_MPS * t0, speed_mps=SPEED_MPS), vibration)
    renderer = StereoRenderer(DEMO_CONFIG, LampMap.load(resolve_lamp_map_path('')),
                              traj, seed=seed)
    frame = renderer.render_at(t0, noise_key=1)
    lamp = next(t for t in frame.truth if abs(t.along_track_m - distance_m) < 0.5)
    return frame, lamp


def _crop(image, uv, half_w, half_h):
    u, v = int(round(uv[0])), int(round(uv[1]))
    u0, v0 = max(0, u - half_w), max(0, v - half_h)
    return image[v0:v + half_h + 1, u0:u + half_w + 1], (u0, v0)


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--out-dir', default='docs/images')
    args = parser.parse_args(argv)
    out = pathlib.Path(args.out_dir)
    out.mkdir(parents=True, exist_ok=True)
    cases = [('near', *_frame_with_lamp_at(2.0)), ('far', *_frame_with_lamp_at(9.0))]

    fig, axes = plt.subplots(2, 1, figsize=(16, 9.6))
    for ax, (name, frame, lamp) in zip(axes, cases):
        ax.imshow(np.hstack([frame.left, frame.right]), cmap='gray', vmin=0, vmax=255,
                  interpolation='antialiased')
        for uv, dx in ((lamp.uv_left, 0), (lamp.uv_right, frame.left.shape[1])):
            ax.add_patch(plt.Circle((uv[0] + dx, uv[1]), 40, fill=False, color='orange'))
        ax.axvline(frame.left.shape[1] - 0.5, color='w', lw=0.8)
        ax.set_title(f'{name}: lamp UID {lamp.uid:#06x} {lamp.along_track_m:.1f} m ahead '
                     f'(range {lamp.range_m:.2f} m) — left | right, mono8, 20 km/h',
                     fontsize=11)
        ax.set_xticks([])
        ax.set_yticks([])
    fig.tight_layout()
    fig.savefig(out / 'stereo_pair_near_far.png', dpi=80)
    plt.close(fig)

    fig, axes = plt.subplots(1, 4, figsize=(16, 6.5))
    c = DEMO_CONFIG
    for i, (name, frame, lamp) in enumerate(cases):
        half_w, half_h = (40, 50) if name == 'near' else (12, 18)
        for j, (side, image, uv) in enumerate((('left', frame.left, lamp.uv_left),
                                               ('right', frame.right, lamp.uv_right))):
            ax = axes[2 * i + j]
            crop, (u0, v0) = _crop(image, uv, half_w, half_h)
            ax.imshow(crop, cmap='gray', vmin=0, vmax=255, interpolation='nearest',
                      extent=(u0 - 0.5, u0 + crop.shape[1] - 0.5, v0 + crop.shape[0] - 0.5,
                              v0 - 0.5))
            ax.plot(uv[0], uv[1], '+', color='red', ms=10, mew=1.5)
            rows = lamp.rows_left if side == 'left' else lamp.rows_right
            ax.set_title(f'{name}, {side}: UID {lamp.uid:#06x}\n'
                         f'{lamp.along_track_m:.1f} m ahead, viewing angle '
                         f'{lamp.viewing_angle_deg:.0f}°\nrows {rows[0]}–{rows[1]} '
                         f'({rows[1] - rows[0] + 1} rows ≈ '
                         f'{(rows[1] - rows[0] + 1) * c.row_time_s * c.chip_rate_hz:.0f} '
                         'chips)', fontsize=10)
            ax.set_xlabel('u (px)')
            ax.set_ylabel('v (row)')
    fig.suptitle(f'Rolling-shutter stripes of the lamp UID ({c.chip_rate_hz / 1e3:g} kchip/s, '
                 f'{c.row_time_s * 1e6:g} µs/row, {c.exposure_s * 1e6:g} µs exposure); '
                 'red +: true projected disc centre', fontsize=12)
    fig.tight_layout()
    fig.savefig(out / 'lamp_crops.png', dpi=90)
    plt.close(fig)
    for name in ('stereo_pair_near_far.png', 'lamp_crops.png'):
        print(out / name)


if __name__ == '__main__':
    main()
