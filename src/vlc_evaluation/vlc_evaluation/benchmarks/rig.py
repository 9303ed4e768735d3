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

Cameras (``--camera``):

* ``ideal`` (default): today's renderer, the ideal rectified pinhole pair.
* ``truthful``: every opt-in model of a truthful camera and sensor on
  (:func:`truthful_config`): raw images through the 3.9 mm M12 lens pair of
  ``OpticsTruth.example()`` (distortion, off-centre principal points, the right camera
  turned 0.24° and triggered 15 µs late), the PSF widening to 1.4 px σ at the corners,
  fixed-pattern and row noise, each lamp's wall reflection, distractor lights (a signal
  every 100 m, platform lights flickering at 100 Hz) and the noise table.
* ``realistic``: what the camera node renders on the ``realistic`` rig profile
  (:func:`realistic_config`): the drawn installation of seed 1 on the scenario's lamp
  map — its true lenses, mount, row time, lamps (tilted, resized, dimmed), PSF, fixed
  pattern and wall reflections (no distractors: they are not part of a profile).
* ``both``: ideal and truthful, scenario by scenario, frames interleaved (the same load
  on a shared machine), then the ratio.

Usage: ``rig_benchmark [--frames N] [--scenario two_lamps|cruise_120|all]
[--camera ideal|truthful|realistic|both]``.
"""
import argparse
import os
import time

import cv2
import numpy as np

from vlc_common.core.alignment import Alignment
from vlc_common.core.lamp_map import LampMap, resolve_lamp_map_path, straight_tunnel_map
from vlc_stereo_camera.conversions import header, image_msg
from vlc_stereo_camera.core.optics_truth import OpticsTruth
from vlc_stereo_camera.core.renderer import RendererConfig, StereoRenderer
from vlc_stereo_camera.core.sensor_noise import FixedPatternConfig
from vlc_stereo_camera.core.stray_light import Distractor, StrayLightConfig
from vlc_stereo_camera.core.trajectory import MotionProfile, Trajectory, Vibration


def truthful_config():
    """RendererConfig with every opt-in model of a truthful camera and sensor on."""
    straight = Alignment.straight()
    distractors = []
    # On the left wall, below 2.2 m: the part of the tunnel the cameras see.
    for chainage in np.arange(55.0, 1000.0, 100.0):
        distractors.append(Distractor.on_alignment(
            straight, chainage, 2.4, 2.0, facing='oncoming', diameter_m=0.15,
            luminance_cd_m2=30_000.0, name=f'signal {chainage:.0f} m'))
    for chainage in np.arange(120.0, 1000.0, 200.0):
        for offset in (0.0, 6.0, 12.0):
            distractors.append(Distractor.on_alignment(
                straight, chainage + offset, 2.4, 2.1, facing='track', diameter_m=0.3,
                luminance_cd_m2=5_000.0, flicker_hz=100.0, flicker_depth=0.3,
                name=f'platform light {chainage + offset:.0f} m'))
    return RendererConfig(optics_truth=OpticsTruth.example(), psf_sigma_corner_px=1.4,
                          fixed_pattern=FixedPatternConfig(), stray_light=StrayLightConfig(),
                          distractors=tuple(distractors), noise_table_size=1 << 22)


def realistic_config(lamp_map, seed=1):
    """RendererConfig of the ``realistic`` profile's installation ``seed`` on ``lamp_map``
    (the truth the camera node renders: lenses, mount, row time, lamps, sensor).
    """
    from vlc_common.core.vehicle import VehicleMount
    from vlc_stereo_camera.core.installation import draw_installation
    inst = draw_installation('realistic', seed, VehicleMount(), lamp_map)
    mount = inst.vehicle_truth.camera
    return RendererConfig(mount_xyz_m=tuple(float(v) for v in mount.position_m),
                          placement_angle_deg=mount.placement_angle_deg,
                          pitch_deg=mount.pitch_deg, roll_deg=mount.roll_deg,
                          **inst.renderer_fields())


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


def _measure(renderers, frames):
    """Render ``frames`` frames with each renderer, interleaved frame by frame; per
    renderer: render ms (wall), render + 2 msgs ms (wall, CPU), lamps in both images.
    """
    for renderer in renderers:
        renderer.render(0)                    # first-call allocations out of the timing
    results = [dict(render=[], total=[], cpu=[], lamps=[]) for _ in renderers]
    for k in range(1, frames + 1):
        for renderer, out in zip(renderers, results):
            c0, t0 = time.thread_time(), time.perf_counter()
            frame = renderer.render(k)
            t1 = time.perf_counter()
            hdr = header(0, 'camera')
            image_msg(frame.left, hdr)
            image_msg(frame.right, hdr)
            t2, c2 = time.perf_counter(), time.thread_time()
            out['render'].append(1e3 * (t1 - t0))
            out['total'].append(1e3 * (t2 - t0))
            out['cpu'].append(1e3 * (c2 - c0))
            out['lamps'].append(sum(t.in_left and t.in_right for t in frame.truth))
    return results


def run(name, description, lamp_map, trajectory, frames, cameras=('ideal',)):
    """Print the figures of one scenario per camera; returns {camera: (fps wall, fps CPU)}."""
    configs = {'ideal': RendererConfig, 'truthful': truthful_config,
               'realistic': lambda: realistic_config(lamp_map)}
    renderers = [StereoRenderer(configs[camera](), lamp_map, trajectory, seed=1)
                 for camera in cameras]
    cpu0, wall0 = time.process_time(), time.perf_counter()
    results = _measure(renderers, frames)
    cpu, wall = time.process_time() - cpu0, time.perf_counter() - wall0
    print(f'[{name}] {description}')
    fps = {}
    for camera, out in zip(cameras, results):
        lamps = np.array(out['lamps'])
        print(f'  camera {camera}: lamp centres in both images per frame: mean '
              f'{lamps.mean():.2f}, min {lamps.min()}, max {lamps.max()}; {frames} stereo frames')
        for label, key in (('render (wall)', 'render'), ('render + 2 msgs (wall)', 'total'),
                           ('render + 2 msgs (CPU)', 'cpu')):
            ms = np.array(out[key])
            print(f'    {label:22s} median {np.median(ms):6.2f} ms  p99 '
                  f'{np.percentile(ms, 99):6.2f} ms  max {ms.max():6.2f} ms  -> '
                  f'{1e3 / ms.mean():6.1f} fps (mean), {1e3 / np.percentile(ms, 99):6.1f} fps '
                  '(p99)')
        fps[camera] = (1e3 / np.mean(out['total']), 1e3 / np.mean(out['cpu']))
    print(f'  CPU time / wall time {cpu / wall:.2f} (share of the one core this process got)')
    if len(cameras) == 2:
        print(f'  {cameras[1]} / {cameras[0]} CPU time per frame: '
              f'{np.mean(results[1]["cpu"]) / np.mean(results[0]["cpu"]):.2f}')
    return fps


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--frames', type=int, default=300)
    parser.add_argument('--scenario', default='all', choices=['all', 'two_lamps', 'cruise_120'])
    parser.add_argument('--camera', default='ideal',
                        choices=['ideal', 'truthful', 'realistic', 'both'],
                        help='ideal: the rectified pinhole pair (default); truthful: lens, '
                             'skew, PSF, fixed pattern, stray light, distractors; realistic: '
                             'the realistic profile\'s drawn installation (seed 1); both: '
                             'ideal and truthful')
    args = parser.parse_args(argv)
    cpu = min(os.sched_getaffinity(0))
    os.sched_setaffinity(0, {cpu})
    cv2.setNumThreads(1)
    print(f'rig_benchmark: 2 x 1280x720 mono8 per frame, pinned to CPU {cpu}, '
          f'cv2.setNumThreads(1), target 30 fps')
    scenarios = _scenarios()
    names = list(scenarios) if args.scenario == 'all' else [args.scenario]
    cameras = ('ideal', 'truthful') if args.camera == 'both' else (args.camera,)
    for name in names:
        fps = run(name, *scenarios[name], frames=args.frames, cameras=cameras)
        for camera in cameras:
            fps_wall, fps_cpu = fps[camera]
            for label, value in (('wall time', fps_wall),
                                 ('one dedicated core (CPU time)', fps_cpu)):
                print(f'  => {camera}, {label}: '
                      f'{"sustains" if value >= 30.0 else "DOES NOT sustain"} 30 fps '
                      f'({value:.1f} fps)')


if __name__ == '__main__':
    main()
