"""``rig_benchmark``: frames per second of the stereo renderer on one CPU core.

Renders 2 × 1280×720 mono8 frames (the full ``StereoRenderer.render`` path plus the
conversion of both images to sensor_msgs/Image) pinned to one core
(``os.sched_setaffinity``) with OpenCV single-threaded (``cv2.setNumThreads(1)``), and
prints frames per second and milliseconds per stereo pair (median, p99, max), both in
wall time and in this thread's CPU time: on a machine shared with other work the wall
figures include time the core spent on other processes, the CPU figures are what one
core dedicated to the renderer delivers.

Scenarios:

* ``two_lamps``: both lamp centres in both images in every frame. With the default
  10 m lamp spacing the lamp-centre window (0.55–9.65 m along track) is shorter than
  the spacing, so two whole lamps are never in view together; this scenario uses a map
  with lamps every 5 m and a train standing with lamps 2.2 m and 7.2 m ahead, platform
  vibration on.
* ``cruise_120``: the default map at 120 km/h with vibration (motion-blur sub-steps,
  spots entering and leaving), for the per-frame cost along a whole lamp cell.

Usage: ``rig_benchmark [--frames N] [--scenario two_lamps|cruise_120|all]``.
"""
import argparse
import os
import time

import cv2
import numpy as np

from vlc_common.core.lamp_map import LampMap, resolve_lamp_map_path, straight_tunnel_map
from vlc_stereo_camera.conversions import header, image_msg
from vlc_stereo_camera.core.renderer import RendererConfig, StereoRenderer
from vlc_stereo_camera.core.trajectory import MotionProfile, Trajectory, Vibration


def _scenarios():
    return {
        'two_lamps': ('lamps every 5 m, train standing 2.2 m / 7.2 m before two lamps, '
                      'vibration on',
                      straight_tunnel_map(spacing_m=5.0),
                      Trajectory(MotionProfile('stationary', start_chainage_m=7.8),
                                 Vibration(seed=1))),
        'cruise_120': ('default lamp map (10 m), 120 km/h from chainage 0, vibration on',
                       LampMap.load(resolve_lamp_map_path('')),
                       Trajectory(MotionProfile('constant', start_chainage_m=0.0,
                                                speed_mps=120 / 3.6), Vibration(seed=1))),
    }


def run(name, description, lamp_map, trajectory, frames):
    renderer = StereoRenderer(RendererConfig(), lamp_map, trajectory, seed=1)
    renderer.render(0)                        # first-call allocations out of the timing
    render_ms, total_ms, cpu_ms, lamps = [], [], [], []
    cpu0, wall0 = time.process_time(), time.perf_counter()
    for k in range(1, frames + 1):
        c0, t0 = time.thread_time(), time.perf_counter()
        frame = renderer.render(k)
        t1 = time.perf_counter()
        hdr = header(0, 'camera')
        image_msg(frame.left, hdr)
        image_msg(frame.right, hdr)
        t2, c2 = time.perf_counter(), time.thread_time()
        render_ms.append(1e3 * (t1 - t0))
        total_ms.append(1e3 * (t2 - t0))
        cpu_ms.append(1e3 * (c2 - c0))
        lamps.append(sum(t.in_left and t.in_right for t in frame.truth))
    cpu, wall = time.process_time() - cpu0, time.perf_counter() - wall0
    lamps = np.array(lamps)
    print(f'[{name}] {description}')
    print(f'  lamp centres in both images per frame: mean {lamps.mean():.2f}, '
          f'min {lamps.min()}, max {lamps.max()}; {frames} stereo frames')
    for label, ms in (('render (wall)', render_ms), ('render + 2 msgs (wall)', total_ms),
                      ('render + 2 msgs (CPU)', cpu_ms)):
        ms = np.array(ms)
        print(f'  {label:22s} median {np.median(ms):6.2f} ms  p99 {np.percentile(ms, 99):6.2f} '
              f'ms  max {ms.max():6.2f} ms  -> {1e3 / ms.mean():6.1f} fps (mean), '
              f'{1e3 / np.percentile(ms, 99):6.1f} fps (p99)')
    print(f'  CPU time / wall time {cpu / wall:.2f} (share of the one core this process got)')
    return 1e3 / np.mean(total_ms), 1e3 / np.mean(cpu_ms)


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--frames', type=int, default=300)
    parser.add_argument('--scenario', default='all', choices=['all', 'two_lamps', 'cruise_120'])
    args = parser.parse_args(argv)
    cpu = min(os.sched_getaffinity(0))
    os.sched_setaffinity(0, {cpu})
    cv2.setNumThreads(1)
    print(f'rig_benchmark: 2 x 1280x720 mono8 per frame, pinned to CPU {cpu}, '
          f'cv2.setNumThreads(1), target 30 fps')
    scenarios = _scenarios()
    names = list(scenarios) if args.scenario == 'all' else [args.scenario]
    for name in names:
        fps_wall, fps_cpu = run(name, *scenarios[name], frames=args.frames)
        for label, fps in (('wall time', fps_wall), ('one dedicated core (CPU time)', fps_cpu)):
            print(f'  => {label}: {"sustains" if fps >= 30.0 else "DOES NOT sustain"} '
                  f'30 fps ({fps:.1f} fps)')


if __name__ == '__main__':
    main()
