"""``stereo_camera_node``: the synthetic rolling-shutter stereo VLC camera of the rig.

Renders the lit tunnel seen by the train-head stereo camera (``core.renderer``) on a
simulated clock and publishes (relative names unless stated):

* ``stereo/left/image_raw``, ``stereo/right/image_raw`` (sensor_msgs/Image, mono8;
  reliable, keep last 5): identical stamps = epoch + t0, the start of row-0 exposure.
* ``stereo/left/camera_info``, ``stereo/right/camera_info`` (sensor_msgs/CameraInfo;
  reliable, transient local, depth 1): with every frame, same stamp; right
  ``P[0,3] = −fx·baseline``.
* ``ground_truth/pose`` (geometry_msgs/PoseStamped; reliable, depth 10): base_link in
  map at the frame stamp.
* ``ground_truth/odometry`` (nav_msgs/Odometry; reliable, depth 10): the same pose with
  ``child_frame_id`` = base_link and the true twist in base_link axes.
* ``ground_truth/spots`` (sensor_msgs/PointCloud2; reliable, depth 10): per-lamp truth,
  fields in ``conversions.py`` / docs/arch/vlc_stereo_camera.md.
* ``/clock`` (rosgraph_msgs/Clock; reliable, depth 10; absolute, as ROS time sources
  expect) at ``clock_rate_hz`` when ``publish_clock``: exact ticks epoch + j/rate; with
  ``duration_s`` and ``clock_tail_s`` > 0 a last tick at epoch + duration_s + clock_tail_s.
* ``diagnostics`` (diagnostic_msgs/DiagnosticArray; reliable, depth 10) at 1 Hz wall
  time: frames rendered, render time, lamps in view, lag behind real time.

Threads: rendering runs on a worker thread that fills a small queue; a pacing thread
publishes frames and clock ticks in simulated-time order, at ``realtime_factor`` ×
real time (0 = as fast as possible). Paced, with the frames ahead in hand, the renderer
starts each frame ``render_gap_s`` after a frame is published: a real camera takes no
CPU from the receivers while they work on the frame it just sent, and the renderer
should not either. A frame is published when its last row has been
read out (t0 + (H−1)·row_time + exposure). The executor thread only serves the
diagnostics timer and the shutdown guard condition, so it stays responsive.
With ``duration_s`` > 0 the node publishes every frame and tick with t < duration_s and
exits 0. With ``wait_for_subscribers`` N > 0, simulated time starts only when both image
topics have N subscribers (recordings and tests that need frame 0), and with
``wait_for_clock_subscribers`` M > 0 until ``/clock`` has M matched subscribers (an IMU
following it would otherwise miss the start). Invalid parameters
fail at start-up with a message and exit code 2. OpenCV runs single-threaded
(``cv2.setNumThreads(1)``): the renderer is sized for one core, and the other nodes of
the graph need the rest.

Sensor faults (shared rig parameters, :mod:`.core.sensor_faults`; every default off, and
off the node publishes exactly as without them). They act on publication only: every
frame is rendered and the pacing and ``/clock`` run on unchanged.

* ``camera_dropouts_s`` [start_s, duration_s, ...]: a frame whose t0 (start of row-0
  exposure, simulated seconds since the start) lies in a window [start_s,
  start_s + duration_s) publishes no image and no camera_info on either side;
  ``ground_truth/pose``, ``ground_truth/odometry``, ``ground_truth/spots`` and
  ``/clock`` go on (the truth stays continuous).
* ``sensor_clock_jumps_s`` [at_s, jump_s, ...]: the images, camera_info and the
  ground truth of frames with t0 ≥ at_s are stamped Σ jump_s later (the sensor host's
  clock stepped; cumulative, negative = back, when stamps repeat). ``/clock`` is not
  stepped: the truth is stamped in the (stepped) sensor time, so "truth at a pose's
  stamp" stays meaningful within a segment; a consumer separates the segments of a
  backward jump by the recording (receive) time.

Published frame stamp = epoch + t0 + Σ_{at_s ≤ t0} jump_s. Diagnostics then also report
``frames_dropped``.

Rig profile (shared ``rig_profile``; :mod:`.core.installation`): ``ideal`` (default) is
the rig above. ``realistic`` / ``harsh`` draw an installation from the profile and
``seed``: the images are rendered RAW through the true lenses, from the true mount, of
the true lamps (positions as built, tilted normals, diameters, brightness, dead lamps),
with the row time, fixed pattern, corner PSF and wall reflections of the profile; but
``camera_info`` carries the BELIEF (the drawn calibration: K, D, R, P per camera), and
``ground_truth/spots`` the raw truth. With ``installation_dir`` the node writes
``belief/{left,right,vehicle,lamp_map}.yaml`` (for the receivers: ``vehicle_path``,
``lamp_map_path``) and ``truth/`` (the evaluation's only) there at start-up.

``calibration_paths`` [left.yaml, right.yaml] (camera_info_manager files, or one OpenCV
FileStorage file): publish that calibration as camera_info instead, as a camera driver
publishes its camera_info_url (e.g. a checkerboard calibration of the drawn lenses made by
``calibrate_installation``). A file that does not parse or was calibrated for another
image size stops the node with the file and field named, exit code 2.
"""
import dataclasses
from dataclasses import dataclass
import queue
import sys
import threading
import time

import cv2
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from geometry_msgs.msg import PoseStamped
from nav_msgs.msg import Odometry
import numpy as np
from rcl_interfaces.msg import ParameterType
from rclpy.clock import Clock, ClockType
from rclpy.duration import Duration
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.task import Future
from rosgraph_msgs.msg import Clock as ClockMsg
from sensor_msgs.msg import PointCloud2

from vlc_common.camera_info import stereo_camera_publishers
from vlc_common.core.calibration import load_stereo_calibration
from vlc_common.core.camera import CameraIntrinsics, StereoRig
from vlc_common.core.lamp_map import LampMap, resolve_lamp_map_path
from vlc_common.parameters import descriptor as _desc
from vlc_common.process import keep_large_buffers, run_node, spin_until_finished
from vlc_stereo_camera import conversions
from vlc_stereo_camera.core import precompute_cache
from vlc_stereo_camera.core.installation import NominalCamera, draw_installation
from vlc_stereo_camera.core.renderer import RendererConfig, StereoRenderer
from vlc_stereo_camera.core.sensor_noise import OpticsConfig, SensorConfig
from vlc_stereo_camera.rig_params import declare_scenario_parameters

_STR = ParameterType.PARAMETER_STRING
# name, default, descriptor. Documented key by key in config/stereo_camera_node.yaml.
NODE_PARAMETERS = (
    ('map_frame_id', 'map', _desc('Frame of ground_truth/pose.', ptype=_STR)),
    ('base_frame_id', 'base_link', _desc('Train-head platform frame: child_frame_id of '
                                         'ground_truth/odometry.', ptype=_STR)),
    ('left_frame_id', 'camera_left_optical_frame', _desc('Left image and camera_info frame.',
                                                         ptype=_STR)),
    ('right_frame_id', 'camera_right_optical_frame', _desc('Right image and camera_info '
                                                           'frame.', ptype=_STR)),
    ('lamp_map_path', '', _desc("Lamp map YAML; '' = the installed map of the alignment "
                                '(share/vlc_common/config/lamp_map.yaml for straight, '
                                'lamp_map_<alignment>.yaml otherwise).', ptype=_STR)),
    ('calibration_paths', [], _desc('camera_info published: [] = the rig\'s own (the ideal '
                                    'pair, or a drawn profile\'s belief calibration); '
                                    '[left.yaml, right.yaml] camera_info_manager files or one '
                                    'OpenCV FileStorage file.',
                                    ptype=ParameterType.PARAMETER_STRING_ARRAY)),
    ('image_width', 1280, _desc('Image width, px.', 64, 4096, integer=True)),
    ('image_height', 720, _desc('Image height (rows), px.', 48, 4096, integer=True)),
    ('fx', 1040.0, _desc('Focal length, px (3.9 mm / 3.75 um).', 50.0, 10000.0)),
    ('fy', 1040.0, _desc('Focal length, px.', 50.0, 10000.0)),
    ('cx', 639.5, _desc('Principal point u, px (pixel centres at integers).', 0.0, 4096.0)),
    ('cy', 359.5, _desc('Principal point v, px.', 0.0, 4096.0)),
    ('baseline_m', StereoRig.baseline_m, _desc('Stereo baseline along the left optical x axis, m.',
                               0.01, 2.0)),
    ('fps', 30.0, _desc('Frame rate, frames/s.', 1.0, 240.0)),
    ('row_time_s', 30e-6, _desc('Rolling-shutter line time: row r starts exposing at '
                                't0 + r*row_time_s, s.', 1e-6, 1e-3)),
    ('exposure_s', 25e-6, _desc('Exposure time of each row, s.', 1e-6, 0.1)),
    ('chip_rate_hz', 21150.0, _desc('Nominal VLC chip rate, chips/s (VLC_PROTOCOL.md).',
                                    2000.0, 40000.0)),
    ('off_level', 0.05, _desc('Lamp output in an "off" chip, fraction of "on".', 0.0, 0.99)),
    ('lamp_clock_ppm', 100.0, _desc('Each lamp chip-rate error is uniform in +-this, ppm.',
                                    0.0, 20000.0)),
    ('lamp_diameter_m', 0.0, _desc('Lamp disc diameter, m; 0 = each lamp\'s diameter_m '
                                   'from the lamp map (0.2 m).', 0.0, 2.0)),
    ('lamp_half_power_angle_deg', 60.0, _desc('Lamp field angle (half-power semi-angle) '
                                              'of the generalized Lambertian, deg.',
                                              1.0, 89.0)),
    ('lamp_luminous_flux_lm', 2100.0, _desc('Lamp luminous flux when "on" (21 W x '
                                            '100 lm/W), lm.', 1.0, 1.0e6)),
    ('f_number', 2.0, _desc('Lens f-number.', 0.5, 32.0)),
    ('lens_transmission', 0.9, _desc('Lens transmission.', 0.01, 1.0)),
    ('quantum_efficiency', 0.5, _desc('Sensor quantum efficiency over the white-LED '
                                      'spectrum.', 0.01, 1.0)),
    ('full_well_e', 10000.0, _desc('Pixel full-well capacity, electrons (= 255 DN).',
                                   100.0, 1.0e6)),
    ('read_noise_e', 3.0, _desc('Read noise, electrons rms.', 0.0, 1000.0)),
    ('dark_current_e_per_s', 50.0, _desc('Dark current, electrons/s per pixel.',
                                         0.0, 1.0e6)),
    ('background_dn', 4.0, _desc('Mean dim-tunnel background, DN.', 0.0, 100.0)),
    ('psf_sigma_px', 0.7, _desc('Optics + pixel PSF core Gaussian sigma, px.', 0.0, 10.0)),
    ('halo_sigma_px', 6.0, _desc('Halo (glare/blooming) Gaussian sigma, px.', 0.0, 50.0)),
    ('halo_fraction', 0.02, _desc('Fraction of the light in the halo.', 0.0, 0.5)),
    ('noise_bank_size', 16, _desc('Pre-rendered noisy background frames to pick from.',
                                  1, 256, integer=True)),
    ('realtime_factor', 1.0, _desc('Simulated seconds per wall second; 0 = as fast as '
                                   'possible.', 0.0, 100.0)),
    ('duration_s', 0.0, _desc('Simulated duration, s; 0 = forever. The node exits 0 after '
                              'it.', 0.0, 1.0e7)),
    ('publish_clock', True, _desc('Publish /clock (simulated time).')),
    ('clock_rate_hz', 100.0, _desc('/clock publication rate, Hz (simulated).', 1.0, 10000.0)),
    ('clock_tail_s', 0.0, _desc('With duration_s: /clock runs this much simulated time past '
                                'duration_s, a last tick at duration_s + clock_tail_s '
                                '(the IMU, which follows /clock, with it), s.',
                                0.0, 60.0)),
    ('wait_for_subscribers', 0, _desc('Hold simulated time at 0 until both image topics '
                                      'have this many subscribers (0 = start at once).',
                                      0, 100, integer=True)),
    ('wait_for_clock_subscribers', 0, _desc('Also hold it until /clock has this many '
                                            'matched subscribers (the IMU following it).',
                                            0, 100, integer=True)),
    ('render_gap_s', 0.015, _desc('Paced, with the frames ahead in hand: the renderer waits '
                                  'this long (simulated s) after a frame is published '
                                  'before it renders the next, so its CPU falls between '
                                  'the frames, not on the receivers\' work on the frame '
                                  'just sent; 0 = at once.', 0.0, 1.0)),
    ('precompute_cache_dir', '', _desc("Directory of the disk memo of the renderer's "
                                       'start-up arrays (lens maps, noise banks; the same '
                                       'arrays, computed once per installation and seed); '
                                       "'' = off.", ptype=_STR)),
)


def render_gap_wall_s(cfg, frames_in_hand):
    """Wall seconds the renderer waits after a frame was published before it renders the
    next: ``render_gap_s`` of simulated time when paced and the frames ahead are in hand
    (``frames_in_hand``: the queue is full); 0 unpaced or when the renderer is behind.
    """
    if cfg.realtime_factor > 0.0 and cfg.render_gap_s > 0.0 and frames_in_hand:
        return cfg.render_gap_s / cfg.realtime_factor
    return 0.0


@dataclass
class StereoCameraNodeConfig:
    """Typed node parameters (see NODE_PARAMETERS for meaning and units)."""

    map_frame_id: str
    base_frame_id: str
    left_frame_id: str
    right_frame_id: str
    lamp_map_path: str
    calibration_paths: tuple
    image_width: int
    image_height: int
    fx: float
    fy: float
    cx: float
    cy: float
    baseline_m: float
    fps: float
    row_time_s: float
    exposure_s: float
    chip_rate_hz: float
    off_level: float
    lamp_clock_ppm: float
    lamp_diameter_m: float
    lamp_half_power_angle_deg: float
    lamp_luminous_flux_lm: float
    f_number: float
    lens_transmission: float
    quantum_efficiency: float
    full_well_e: float
    read_noise_e: float
    dark_current_e_per_s: float
    background_dn: float
    psf_sigma_px: float
    halo_sigma_px: float
    halo_fraction: float
    noise_bank_size: int
    realtime_factor: float
    duration_s: float
    publish_clock: bool
    clock_rate_hz: float
    clock_tail_s: float
    wait_for_subscribers: int
    wait_for_clock_subscribers: int
    render_gap_s: float
    precompute_cache_dir: str

    def nominal_camera(self):
        """The stereo camera as designed (an installation's nominal)."""
        return NominalCamera(width=self.image_width, height=self.image_height, fx=self.fx,
                             fy=self.fy, cx=self.cx, cy=self.cy, baseline_m=self.baseline_m,
                             row_time_s=self.row_time_s)

    def renderer_config(self, epoch_s, vehicle):
        """The RendererConfig these parameters describe on ``vehicle`` (a VehicleMount;
        ValueError if inconsistent).
        """
        mount = vehicle.camera
        return RendererConfig(
            intrinsics=CameraIntrinsics(width=self.image_width, height=self.image_height,
                                        fx=self.fx, fy=self.fy, cx=self.cx, cy=self.cy),
            baseline_m=self.baseline_m,
            mount_xyz_m=tuple(float(v) for v in mount.position_m),
            placement_angle_deg=mount.placement_angle_deg, pitch_deg=mount.pitch_deg,
            roll_deg=mount.roll_deg, fps=self.fps, row_time_s=self.row_time_s,
            exposure_s=self.exposure_s,
            epoch_s=epoch_s, chip_rate_hz=self.chip_rate_hz, off_level=self.off_level,
            lamp_clock_ppm=self.lamp_clock_ppm, lamp_diameter_m=self.lamp_diameter_m,
            optics=OpticsConfig(luminous_flux_lm=self.lamp_luminous_flux_lm,
                                half_power_angle_deg=self.lamp_half_power_angle_deg,
                                f_number=self.f_number,
                                lens_transmission=self.lens_transmission,
                                quantum_efficiency=self.quantum_efficiency),
            sensor=SensorConfig(full_well_e=self.full_well_e, read_noise_e=self.read_noise_e,
                                dark_current_e_per_s=self.dark_current_e_per_s,
                                background_dn=self.background_dn,
                                noise_bank_size=self.noise_bank_size),
            psf_sigma_px=self.psf_sigma_px, halo_sigma_px=self.halo_sigma_px,
            halo_fraction=self.halo_fraction)


class StereoCameraNode(Node):
    """See the module docstring."""

    def __init__(self, start_workers=True, **kwargs):
        """``start_workers`` False: no render and pacing threads; a driver in the same
        process takes the frames and ticks from :meth:`sim_events` and hands them to
        :meth:`emit` itself (``vlc_evaluation.lockstep``).
        """
        super().__init__('stereo_camera_node', **kwargs)
        self.scenario = declare_scenario_parameters(self)
        values = {}
        for name, default, descriptor in NODE_PARAMETERS:
            # rclpy infers no type from []: unset means empty
            values[name] = self.declare_parameter(
                name, Parameter.Type.STRING_ARRAY if default == [] else default,
                descriptor).value
        values['calibration_paths'] = tuple(values['calibration_paths'] or ())
        self.config = cfg = StereoCameraNodeConfig(**values)
        precompute_cache.set_directory(cfg.precompute_cache_dir)
        trajectory = self.scenario.trajectory()
        lamp_map = LampMap.load(resolve_lamp_map_path(cfg.lamp_map_path,
                                                      self.scenario.alignment))
        profile = self.scenario.profile()
        if profile.ideal:
            renderer_config = cfg.renderer_config(self.scenario.epoch_s,
                                                  self.scenario.nominal_vehicle())
            self.installation = None
        else:
            self.installation = inst = draw_installation(
                profile, self.scenario.drawn_seed, self.scenario.nominal_vehicle(), lamp_map,
                cfg.nominal_camera())
            renderer_config = dataclasses.replace(
                cfg.renderer_config(self.scenario.epoch_s, inst.vehicle_truth),
                **inst.renderer_fields())
            lamp_map = inst.lamp_map_truth
        self.renderer = StereoRenderer(renderer_config, lamp_map, trajectory,
                                       seed=self.scenario.seed)
        if self.installation is None:
            self._infos = self.renderer.camera_info_dicts()
        else:
            self._infos = self.installation.calibration.camera_info_dicts()
            self._report_installation()
        if cfg.calibration_paths:
            paths = list(cfg.calibration_paths)
            calibration = load_stereo_calibration(paths if len(paths) > 1 else paths[0])
            calibration.check_image_size(cfg.image_width, cfg.image_height)
            self._infos = calibration.camera_info_dicts()
            self.get_logger().info(f'camera_info from {", ".join(paths)} (stated RMS '
                                   f'{calibration.rms_px:g} px)')
        self._readout_s = ((cfg.image_height - 1) * renderer_config.row_time_s
                           + cfg.exposure_s)

        self.pub_images, self.pub_infos = stereo_camera_publishers(self)
        self.pub_pose = self.create_publisher(PoseStamped, 'ground_truth/pose', 10)
        self.pub_odom = self.create_publisher(Odometry, 'ground_truth/odometry', 10)
        self.pub_spots = self.create_publisher(PointCloud2, 'ground_truth/spots', 10)
        self.pub_diag = self.create_publisher(DiagnosticArray, 'diagnostics', 10)
        self.pub_clock = (self.create_publisher(ClockMsg, '/clock', 10)
                          if cfg.publish_clock else None)

        self.finished = Future()
        self.exit_code = 0
        self._stop = threading.Event()
        self._frames = queue.Queue(maxsize=2)
        self._stats_lock = threading.Lock()
        self._render_ms = []
        self._frames_rendered = 0
        self._lamps_in_view = 0
        self._lag_s = 0.0
        self._sim_ns = conversions.stamp_ns(self.scenario.epoch_s)
        self._epoch_ns = self._sim_ns
        self._faults = self.scenario.sensor_faults()
        self._frames_dropped = 0
        self._done_guard = self.create_guard_condition(self._on_done)
        self.create_timer(1.0, self._publish_diagnostics,
                          clock=Clock(clock_type=ClockType.STEADY_TIME))
        self._threads = []
        if start_workers:
            self._threads = [
                threading.Thread(target=self._render_loop, name='render', daemon=True),
                threading.Thread(target=self._pace_loop, name='pace', daemon=True)]
            for thread in self._threads:
                thread.start()
        self.get_logger().info(
            f'rendering {cfg.image_width}x{cfg.image_height} stereo at {cfg.fps} fps, '
            f'realtime_factor {cfg.realtime_factor}, {len(lamp_map)} lamps, '
            f'motion {self.scenario.motion_profile}, seed {self.scenario.seed}')
        if self._faults.camera_faults:
            self.get_logger().warn(f'sensor faults: {self._faults.describe()}')

    def _report_installation(self):
        """Log the drawn installation (and write it into ``installation_dir``)."""
        inst = self.installation
        truth = inst.truth_dict()
        where = ''
        if self.scenario.installation_dir:
            inst.write(self.scenario.installation_dir)
            where = f'; belief/ and truth/ written to {self.scenario.installation_dir}'
        self.get_logger().info(
            f'rig_profile {inst.profile.name}, seed {inst.seed}: raw images of the drawn '
            f'installation, camera_info = its calibration (stated RMS '
            f'{inst.calibration.rms_px:g} px), trigger skew '
            f'{inst.optics.trigger_skew_s * 1e6:.1f} us, IMU clock offset '
            f'{inst.imu_clock_offset_s * 1e3:+.3f} ms, dead lamps {truth.get("dead_lamps", [])}, '
            f'gross survey errors {truth.get("gross_survey_errors", [])}{where}')

    # ------------------------------------------------------------ worker threads
    def _render_loop(self):
        cfg = self.config
        k = 0
        try:
            while not self._stop.is_set():
                frame = self.render_frame(k)
                self._put(frame)
                if frame is None:
                    return
                k += 1
                # The put returned because the pacing took a frame, i.e. just after it
                # published one. With the queue full again (the frames ahead are in hand)
                # the next render waits, so that it does not compete with the receivers
                # for the cores while they process the frame just sent; a renderer that
                # is behind (queue not full) goes on at once.
                wait_s = render_gap_wall_s(cfg, self._frames.full())
                if wait_s > 0.0:
                    self._stop.wait(wait_s)
        except Exception as exc:  # noqa: BLE001 — report any renderer failure, then stop
            self.get_logger().error(f'rendering failed: {exc!r}')
            self.exit_code = 1
            self._put(None)

    def render_frame(self, k):
        """Frame ``k`` (its statistics counted), or None past ``duration_s``."""
        cfg = self.config
        if cfg.duration_s > 0.0 and k / cfg.fps >= cfg.duration_s:
            return None
        start = time.perf_counter()
        frame = self.renderer.render(k)
        elapsed_ms = 1e3 * (time.perf_counter() - start)
        with self._stats_lock:
            self._render_ms.append(elapsed_ms)
            self._frames_rendered += 1
            self._lamps_in_view = len(frame.truth)
        return frame

    def _put(self, item):
        while not self._stop.is_set():
            try:
                self._frames.put(item, timeout=0.1)
                return
            except queue.Full:
                continue

    def _pace_loop(self):
        try:
            self._pace()
        except Exception as exc:  # noqa: BLE001 — publishing fails once the context is down
            if self._stop.is_set() or not self.context.ok():
                return
            self.get_logger().error(f'publishing failed: {exc!r}')
            self.exit_code = 1
            self._done_guard.trigger()

    def _pace(self):
        """Publish clock ticks and frames in simulated-time order at the pacing rate."""
        cfg = self.config
        rtf = cfg.realtime_factor
        while not self._stop.is_set() and (
                min(pub.get_subscription_count() for pub in self.pub_images)
                < cfg.wait_for_subscribers
                or (self.pub_clock is not None and self.pub_clock.get_subscription_count()
                    < cfg.wait_for_clock_subscribers)):
            self._stop.wait(0.05)
        wall0 = time.monotonic()
        for t_next, frame in self.sim_events(self._next_frame):
            if rtf > 0.0:
                lag = time.monotonic() - (wall0 + t_next / rtf)
                self._lag_s = max(lag, 0.0)
                if lag < 0.0:
                    self._stop.wait(-lag)
                elif lag > 0.5:
                    # Far behind real time (slow machine): restart the pacing from here
                    # instead of bursting the backlog out.
                    self.get_logger().warn(f'simulation {lag:.2f} s behind real time',
                                           throttle_duration_sec=5.0)
                    wall0 += lag
            if self._stop.is_set():
                break
            self.emit(t_next, frame)
        if self._stop.is_set():
            return
        # duration_s reached: let reliable subscribers receive the last frames first.
        for pub in self.pub_images:
            pub.wait_for_all_acked(Duration(seconds=2.0))
        self._done_guard.trigger()

    def sim_events(self, next_frame):
        """Clock ticks and frames in simulated-time order: ``(t_s, frame)`` with ``frame``
        None for a ``/clock`` tick at ``t_s`` (simulated seconds), else a frame to publish
        at ``t_s`` (its last row read out). ``next_frame()`` gives the frames in order,
        None after the last. Ends at ``duration_s`` (and its clock tail) or on stop.
        """
        cfg = self.config
        tick = 0
        end_ticked = False
        frame = None
        frames_done = False
        while not self._stop.is_set():
            if frame is None and not frames_done:
                frame = next_frame()
                frames_done = frame is None
                if self._stop.is_set():
                    return
            t_frame = frame.t0_s + self._readout_s if frame is not None else np.inf
            t_tick = tick / cfg.clock_rate_hz if self.pub_clock is not None else np.inf
            if cfg.duration_s > 0.0:
                # ticks over [0, duration_s + clock_tail_s); with a tail, a last tick at
                # its end, also off the j/rate grid: a follower (the IMU, duration_s +
                # clock_tail_s) must see its last sample due
                t_end = cfg.duration_s + cfg.clock_tail_s
                if t_tick >= t_end:
                    t_tick = t_end if cfg.clock_tail_s > 0.0 and not end_ticked else np.inf
            t_next = min(t_frame, t_tick)
            if not np.isfinite(t_next):
                return
            if t_tick <= t_frame:
                tick += 1
                end_ticked = cfg.duration_s > 0.0 and t_tick >= t_end
                yield t_tick, None
            else:
                yield t_frame, frame
                frame = None

    def emit(self, t_s, frame):
        """Publish one event of :meth:`sim_events`: the ``/clock`` tick at ``t_s`` or
        ``frame``.
        """
        if frame is None:
            ns = conversions.stamp_ns(self.scenario.epoch_s, t_s)
            self.pub_clock.publish(ClockMsg(clock=conversions.ns_to_stamp(ns)))
            self._sim_ns = ns
        else:
            self._publish_frame(frame)

    def _next_frame(self):
        while not self._stop.is_set():
            try:
                return self._frames.get(timeout=0.1)
            except queue.Empty:
                continue
        return None

    def _publish_frame(self, frame):
        cfg = self.config
        ns = conversions.stamp_ns(self.scenario.epoch_s, frame.t0_s)
        dropped = False
        if self._faults.camera_faults:
            t_ns = ns - self._epoch_ns          # the frame's true time
            dropped = self._faults.camera_dropped(t_ns)
            ns = self._faults.sensor_stamp_ns(ns, t_ns)
        # the images carry the driver's stamp (with the installation's per-frame jitter);
        # the true pose stays on the true time
        image_ns = ns
        if self.installation is not None:
            image_ns += int(round(1e9 * self.installation.frame_stamp_jitter_s(
                round(frame.t0_s * cfg.fps))))
        left_hdr = conversions.header(image_ns, cfg.left_frame_id)
        right_hdr = conversions.header(image_ns, cfg.right_frame_id)
        if dropped:
            self._frames_dropped += 1
        else:
            self.pub_images[0].publish(conversions.image_msg(frame.left, left_hdr))
            self.pub_images[1].publish(conversions.image_msg(frame.right, right_hdr))
            self.pub_infos[0].publish(conversions.camera_info_msg(self._infos[0], left_hdr))
            self.pub_infos[1].publish(conversions.camera_info_msg(self._infos[1], right_hdr))
        map_hdr = conversions.header(ns, cfg.map_frame_id)
        self.pub_pose.publish(conversions.pose_msg(frame.base_position_m, frame.base_quat_xyzw,
                                                   map_hdr))
        self.pub_odom.publish(conversions.odometry_msg(frame, map_hdr, cfg.base_frame_id))
        # the spots' truth belongs to its image: the image's stamp (the evaluation pairs
        # them by stamp; their exposure times inside are true)
        self.pub_spots.publish(conversions.records_to_cloud(
            conversions.truth_records(frame.truth, frame.t0_s), left_hdr))

    # ------------------------------------------------------------ executor side
    def _on_done(self):
        if not self.finished.done():
            self.finished.set_result(self.exit_code)

    def _publish_diagnostics(self):
        cfg = self.config
        with self._stats_lock:
            render_ms, self._render_ms = self._render_ms, []
            frames, lamps = self._frames_rendered, self._lamps_in_view
        status = DiagnosticStatus(name=f'{self.get_name()}: renderer',
                                  hardware_id='synthetic_stereo_rig',
                                  level=DiagnosticStatus.OK, message='rendering')
        budget_ms = 1e3 / (cfg.fps * max(cfg.realtime_factor, 1e-9))
        if render_ms and cfg.realtime_factor > 0.0 and np.median(render_ms) > budget_ms:
            status.level = DiagnosticStatus.WARN
            status.message = 'rendering slower than the frame period'
        values = {'frames_rendered': str(frames),
                  'frames_last_second': str(len(render_ms)),
                  'render_ms_median': f'{np.median(render_ms):.2f}' if render_ms else 'nan',
                  'render_ms_max': f'{np.max(render_ms):.2f}' if render_ms else 'nan',
                  'lamps_in_view': str(lamps),
                  'lag_behind_realtime_s': f'{self._lag_s:.3f}'}
        if self._faults.camera_faults:
            values['frames_dropped'] = str(self._frames_dropped)
        status.values = [KeyValue(key=key, value=value) for key, value in values.items()]
        self.pub_diag.publish(DiagnosticArray(header=conversions.header(self._sim_ns, ''),
                                              status=[status]))

    def stop(self):
        """Stop and join the worker threads."""
        self._stop.set()
        for thread in self._threads:
            thread.join(timeout=5.0)


def main(args=None):
    cv2.setNumThreads(1)
    keep_large_buffers()
    return run_node(StereoCameraNode, 'stereo_camera_node', args, spin=spin_until_finished,
                    stop=StereoCameraNode.stop)


if __name__ == '__main__':
    sys.exit(main())
