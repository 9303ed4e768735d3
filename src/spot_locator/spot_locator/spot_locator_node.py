"""``spot_locator_node``: sub-pixel lamp spot centres in both stereo images.

Subscribes (relative names):

* ``stereo/left/image_raw``, ``stereo/right/image_raw`` (sensor_msgs/Image: mono8,
  mono16, 8UC1, 16UC1; rgb8/bgr8 are converted to grey; reliable, keep last 5): left
  and right are paired by identical stamps.
* ``stereo/left/camera_info``, ``stereo/right/camera_info`` (sensor_msgs/CameraInfo;
  reliable, transient local, depth 1): the rectified geometry (P matrices, right
  ``P[0,3] = −fx·b``); with D ≠ 0 or R ≠ I the images are raw and each spot centre is
  mapped through its camera's K, D, R, P (``spots/pairs`` is in rectified pixels,
  stamped by the left centre's raw row). Images are skipped until both have arrived.
  The last good one of each camera is kept
  (:class:`vlc_common.camera_info.CameraInfoKeeper`): an invalid one (zero or NaN K/P)
  is refused with a throttled warning, a different valid one (another size) is taken
  only once it came three times in a row.
* ``train/odometry`` (nav_msgs/Odometry; reliable, depth 10): train speed for the
  exposure blur (|twist.linear|). Without a recent one the ``assumed_speed_mps``
  parameter is used.

Publishes:

* ``spots/pairs`` (sensor_msgs/PointCloud2; reliable, depth 10): one point per matched
  lamp spot pair, header = the images' header; fields in :mod:`.conversions` and
  docs/arch/spot_locator.md.
* ``diagnostics`` (diagnostic_msgs/DiagnosticArray; reliable, depth 10), once per
  ``diagnostics_period_s`` (steady clock): frames processed/skipped, processing time,
  spots and pairs.

One thread: the image callback that completes a stereo pair processes it at once, as
the decoder does (a worker thread fed from a queue added a hand-over delay before every
pair's processing: docs/arch/spot_locator.md "Queues"). Bad input (unknown encoding, empty,
truncated or inconsistent image, left/right size mismatch, images of another size than
camera_info's, unpaired or out-of-order stamps) gives a throttled warning and is skipped.

State: only the stereo pairing (images waiting for their partner, the newest paired
stamp) and the latest odometry speed (aged by receipt time); the locator itself keeps
nothing between frames. An image stamped more than ``backward_reset_s`` before or
``forward_jump_s`` after the newest one is held: alone (a 1970 or far-future stamp) it is
dropped as an outlier and counted; ``time_base_confirm_count`` consecutive images of a new
time base more than ``backward_reset_s`` back (a looped bag replay, a restarted camera)
clear the pairing state with a throttled warning and are processed, so the replay is not
dropped as out of order.
"""
from collections import deque
from dataclasses import dataclass
import sys
import time

import cv2
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from nav_msgs.msg import Odometry
import numpy as np
from rcl_interfaces.msg import ParameterType
from rclpy.clock import Clock, ClockType
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import CameraInfo, Image, PointCloud2

from spot_locator import conversions
from spot_locator.core.centres import ChordConfig
from spot_locator.core.detection import DetectConfig
from spot_locator.core.locator import ECCENTRICITY_MODES, METHODS, LocatorConfig, SpotLocator
from spot_locator.core.matching import MatchConfig
from vlc_common.camera_info import CameraInfoKeeper
from vlc_common.core.stereo_pairing import StereoPairing
from vlc_common.core.vehicle import load_vehicle
from vlc_common.parameters import descriptor as _desc
from vlc_common.polled import pair_images
from vlc_common.process import (
    keep_large_buffers,
    run_node,
)
from vlc_common.throttled_log import ThrottledWarnings

_WARN_PERIOD_S = 2.0
#: the stereo pairing's events (StereoPairing.add) → throttled warning (key, text)
PAIRING_WARNINGS = {
    'reset': ('stamp_reset', 'image stamps jumped back by more than backward_reset_s for '
              'time_base_confirm_count images; stereo pairing reset'),
    'out_of_order': ('out_of_order', 'an image stamp is not newer than the last paired '
                     'stamp; skipped'),
    'outlier': ('stamp_outlier', 'an image stamped far from the stream (beyond '
                'backward_reset_s before or forward_jump_s after the newest) dropped'),
}


_STR = ParameterType.PARAMETER_STRING
_DARR = ParameterType.PARAMETER_DOUBLE_ARRAY
# name, default, descriptor. Documented key by key in config/spot_locator_node.yaml.
NODE_PARAMETERS = (
    ('method', 'chord', _desc('Centre estimator: ' + ' | '.join(METHODS) + '.', ptype=_STR)),
    ('eccentricity', 'conic', _desc('Perspective eccentricity correction: '
                                    + ' | '.join(ECCENTRICITY_MODES) + '.', ptype=_STR)),
    ('lamp_diameter_m', 0.2, _desc('Lamp disc diameter, m.', 0.01, 2.0)),
    ('lamp_normal_map', [0.0, -1.0, 0.0], _desc('Unit disc normal of the lamps in map '
                                                '(into the tunnel).', ptype=_DARR)),
    ('vehicle_path', '', _desc("Vehicle mount file (the camera's axis in base_link, for the "
                               "nominal lamp normal and motion direction in the image); '' = "
                               'share/vlc_common/config/vehicle.yaml.', ptype=_STR)),
    ('conic_normal_min_rows', 30, _desc('Spots at least this many rows tall give their own '
                                        'disc normal for the eccentricity correction.',
                                        3, 4096, integer=True)),
    ('conic_normal_max_angle_deg', 20.0, _desc('A measured disc normal further than this '
                                               'from the nominal one is not used, deg.',
                                               0.0, 90.0)),
    ('rolling_shutter_model', True, _desc('When the train moves, correct each centre with the '
                                          'rolling-shutter model of the moving lamp (its '
                                          'image moves and grows during the readout).')),
    ('wiener', False, _desc('Wiener-deconvolve the exposure motion blur before measuring.')),
    ('wiener_balance', 0.02, _desc('Wiener-Hunt regularisation weight (skimage balance).',
                                   1e-6, 10.0)),
    ('min_blur_px', 0.3, _desc('Blur length below which deblurring is skipped, px.',
                               0.0, 100.0)),
    ('assumed_speed_mps', 0.0, _desc('Train speed used for the blur when no recent '
                                     'train/odometry arrived, m/s.', 0.0, 100.0)),
    ('odometry_timeout_s', 1.0, _desc('train/odometry older than this (receipt time) is '
                                      'ignored, s.', 0.0, 3600.0)),
    ('row_time_s', 30e-6, _desc('Rolling-shutter line time, s.', 1e-7, 1e-3)),
    ('exposure_s', 25e-6, _desc('Exposure time of each row, s.', 1e-7, 0.1)),
    ('trigger_skew_s', 0.0, _desc('The right camera\'s row r is exposed this long after the '
                                  'left camera\'s row r (camera_info has no field for it), '
                                  's; a moving lamp\'s right centre is moved back to the '
                                  'left one\'s instant.', -0.01, 0.01)),
    ('vignetting', 'cos4', _desc("Lens fall-off removed before measuring: 'cos4' | 'none'.",
                                 ptype=_STR)),
    ('threshold_snr', 6.0, _desc('Detection threshold above background, noise sigmas.',
                                 1.0, 1000.0)),
    ('min_threshold_dn', 8.0, _desc('Lower bound of the detection threshold above '
                                    'background, DN.', 0.0, 65535.0)),
    ('closing_rows', 13, _desc('Height of the vertical closing that joins stripes, rows '
                               '(> longest dark run: 3 chips / (chip_rate * row_time)).',
                               1, 1000, integer=True)),
    ('min_area_px', 6, _desc('Smallest spot, px.', 1, 1000000, integer=True)),
    ('max_spots', 16, _desc('Largest number of spots per image.', 1, 1000, integer=True)),
    ('reject_border_spots', True, _desc('Drop spots that touch the image border.')),
    ('pair_cut_spots', True, _desc('Chord method: pair a spot cut by the image\'s side '
                                   'border with its lamp\'s whole spot in the other image, '
                                   'the disparity from the uncut chord ends (flag bit 9).')),
    ('max_row_diff_px', 3.0, _desc('Matching: allowed difference of the spots\' centre rows, '
                                   'px.', 0.0, 100.0)),
    ('min_row_overlap', 0.5, _desc('Matching: the shorter spot\'s row span must overlap the '
                                   'other by this fraction.', 0.0, 1.0)),
    ('min_disparity_px', 2.0, _desc('Matching: smallest disparity, px.', 0.0, 10000.0)),
    ('max_disparity_px', 400.0, _desc('Matching: largest disparity, px.', 0.0, 10000.0)),
    ('max_area_ratio', 2.0, _desc('Matching: largest spot area ratio.', 1.0, 100.0)),
    ('max_pending_stamps', 10, _desc('Unpaired images kept per side while waiting for the '
                                     'other side.', 1, 1000, integer=True)),
    ('catch_up_pairs', 2, _desc('Complete stereo pairs processed, oldest first, when several '
                                'waited (the node was stalled): a stall of up to this many '
                                'frames loses none; older pairs are dropped and counted '
                                '(superseded). 1 = only the newest.', 1, 10, integer=True)),
    ('backward_reset_s', 1.0, _desc('An image stamped more than this before the newest one '
                                    'is held as a possible outlier; time_base_confirm_count '
                                    'of them in a row (a looped bag replay) reset the stereo '
                                    'pairing; a smaller step back is dropped as out of '
                                    'order, s.', 1e-3, 1e6)),
    ('forward_jump_s', 1.0, _desc('An image stamped more than this after the newest one is '
                                  'held as a possible outlier, s.', 0.0, 3600.0)),
    ('time_base_confirm_count', 3, _desc('Consecutive images of a new time base that confirm '
                                         'it; fewer are outliers, dropped.', 1, 1000,
                                         integer=True)),
    ('diagnostics_period_s', 1.0, _desc('Diagnostics period (steady clock), s.',
                                        0.05, 3600.0)),
    ('warm_up', True, _desc('Run a synthetic stereo pair through the whole pipeline before '
                            'subscribing, so the first frames do not pay the libraries\' '
                            'first-call costs.')),
)


@dataclass
class SpotLocatorNodeConfig:
    """Typed node parameters (see NODE_PARAMETERS for meaning and units)."""

    method: str
    eccentricity: str
    lamp_diameter_m: float
    lamp_normal_map: list
    vehicle_path: str
    conic_normal_min_rows: int
    conic_normal_max_angle_deg: float
    rolling_shutter_model: bool
    wiener: bool
    wiener_balance: float
    min_blur_px: float
    assumed_speed_mps: float
    odometry_timeout_s: float
    row_time_s: float
    exposure_s: float
    trigger_skew_s: float
    vignetting: str
    threshold_snr: float
    min_threshold_dn: float
    closing_rows: int
    min_area_px: int
    max_spots: int
    reject_border_spots: bool
    pair_cut_spots: bool
    max_row_diff_px: float
    min_row_overlap: float
    min_disparity_px: float
    max_disparity_px: float
    max_area_ratio: float
    max_pending_stamps: int
    catch_up_pairs: int
    backward_reset_s: float
    forward_jump_s: float
    time_base_confirm_count: int
    diagnostics_period_s: float
    warm_up: bool

    def locator_config(self):
        """The core LocatorConfig (ValueError if the parameters are inconsistent)."""
        normal_map = np.asarray(self.lamp_normal_map, float)
        if normal_map.shape != (3,) or not np.linalg.norm(normal_map) > 0:
            raise ValueError('lamp_normal_map must be a non-zero 3-vector')
        if self.min_disparity_px >= self.max_disparity_px:
            raise ValueError('min_disparity_px must be < max_disparity_px')
        R_base_cam = load_vehicle(self.vehicle_path).camera.R_base_cam
        # Nominal attitude (straight track, no vibration): base_link axes = map axes.
        normal_cam = R_base_cam.T @ (normal_map / np.linalg.norm(normal_map))
        # Lamps move backwards past the train: -x of base_link, in the optical frame.
        velocity_cam = R_base_cam.T @ np.array([-1.0, 0.0, 0.0])
        return LocatorConfig(
            method=self.method, eccentricity=self.eccentricity,
            lamp_radius_m=0.5 * self.lamp_diameter_m, normal_cam=tuple(normal_cam),
            conic_normal_min_rows=self.conic_normal_min_rows,
            conic_normal_max_angle_deg=self.conic_normal_max_angle_deg,
            rolling_shutter_model=self.rolling_shutter_model,
            wiener=self.wiener, wiener_balance=self.wiener_balance,
            min_blur_px=self.min_blur_px, train_velocity_cam_mps=tuple(velocity_cam),
            row_time_s=self.row_time_s, exposure_s=self.exposure_s,
            trigger_skew_s=self.trigger_skew_s,
            reject_border_spots=self.reject_border_spots,
            pair_cut_spots=self.pair_cut_spots, vignetting=self.vignetting,
            detect=DetectConfig(threshold_snr=self.threshold_snr,
                                min_threshold_dn=self.min_threshold_dn,
                                closing_rows=self.closing_rows, min_area_px=self.min_area_px,
                                max_spots=self.max_spots),
            chord=ChordConfig(),
            match=MatchConfig(max_row_diff_px=self.max_row_diff_px,
                              min_row_overlap=self.min_row_overlap,
                              min_disparity_px=self.min_disparity_px,
                              max_disparity_px=self.max_disparity_px,
                              max_area_ratio=self.max_area_ratio))


class SpotLocatorNode(Node):
    """See the module docstring."""

    def __init__(self, **kwargs):
        super().__init__('spot_locator_node', **kwargs)
        for name, default, descriptor in NODE_PARAMETERS:
            self.declare_parameter(name, default, descriptor)
        self.config = cfg = SpotLocatorNodeConfig(
            **{name: self.get_parameter(name).value for name, _, _ in NODE_PARAMETERS})
        self.locator_config = cfg.locator_config()
        # (StereoGeometry, SpotLocator) of the latest usable camera_info pair
        self._located = None
        self._infos = CameraInfoKeeper()

        self._pairing = StereoPairing(cfg.max_pending_stamps,
                                      int(round(cfg.backward_reset_s * 1e9)),
                                      int(round(cfg.forward_jump_s * 1e9)),
                                      cfg.time_base_confirm_count)
        self._speed = (cfg.assumed_speed_mps, -np.inf)
        # the clock of the odometry's age (an in-process driver on simulated time
        # replaces it: vlc_evaluation.lockstep)
        self._monotonic = time.monotonic
        self._stats = dict(frames=0, pairs=0, bad_image=0, no_camera_info=0,
                           size_mismatch=0, failed=0, unmatched=0, border=0,
                           edge_pairs=0)
        self._proc_ms = deque(maxlen=200)
        self._warnings = ThrottledWarnings(self.get_logger(), _WARN_PERIOD_S)
        # first calls into OpenCV/LAPACK/scipy/scikit-image are slow: pay them now, not
        # on the first frames (the geometry here is the nominal one; camera_info's
        # replaces it, the library state stays warm)
        warm_start = time.perf_counter()
        if cfg.warm_up:
            SpotLocator(self.locator_config).warm_up()
        self._warm_up_ms = 1e3 * (time.perf_counter() - warm_start)

        image_qos = QoSProfile(depth=5, reliability=ReliabilityPolicy.RELIABLE)
        latched = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                             durability=DurabilityPolicy.TRANSIENT_LOCAL)
        self._image_subs = []
        for side, index in (('left', 0), ('right', 1)):
            self._image_subs.append(self.create_subscription(
                Image, f'stereo/{side}/image_raw', lambda msg, i=index: self._on_image(i, msg),
                image_qos))
            self.create_subscription(CameraInfo, f'stereo/{side}/camera_info',
                                     lambda msg, i=index: self._on_info(i, msg), latched)
        self.create_subscription(Odometry, 'train/odometry', self._on_odometry, 10)
        self.pub_pairs = self.create_publisher(PointCloud2, 'spots/pairs', 10)
        self.pub_diag = self.create_publisher(DiagnosticArray, 'diagnostics', 10)
        self.create_timer(cfg.diagnostics_period_s, self._publish_diagnostics,
                          clock=Clock(clock_type=ClockType.STEADY_TIME))
        self.get_logger().info(f'spot locator: method {cfg.method}, eccentricity '
                               f'{cfg.eccentricity}, wiener {cfg.wiener}; warmed up in '
                               f'{self._warm_up_ms:.0f} ms')

    # ------------------------------------------------------------ callbacks
    def _warn(self, kind, text):
        self._warnings.warn(kind, text)

    def _count(self, key, n=1):
        self._stats[key] += n

    def _on_info(self, index, msg):
        outcome, reason = self._infos.update(index, msg)
        side = ('left', 'right')[index]
        if outcome == CameraInfoKeeper.REFUSED:
            self._warn(f'camera_info_refused_{side}', f'{side} camera_info refused, the last '
                       f'good one kept: {reason}')
            return
        if outcome == CameraInfoKeeper.PENDING:
            self._warn(f'camera_info_pending_{side}', f'{side} camera_info {reason}')
            return
        if outcome == CameraInfoKeeper.SAME:
            return          # the geometry of the kept pair was derived when it came (KEPT)
        both = self._infos.both()
        if both is None:
            return
        try:
            geometry = conversions.stereo_geometry(*both)
        except ValueError as exc:
            self._warn('camera_info', f'camera_info unusable, keeping the previous geometry: {exc}')
            return
        if self._located is None or geometry != self._located[0]:
            self._located = (geometry, SpotLocator(self.locator_config, geometry))

    def _on_odometry(self, msg):
        v = msg.twist.twist.linear
        speed = float(np.sqrt(v.x * v.x + v.y * v.y + v.z * v.z))
        if np.isfinite(speed):
            self._speed = (speed, self._monotonic())
        else:
            self._warn('odometry', 'train/odometry speed is not finite; ignored')

    def _on_image(self, index, msg):
        """Pair by stamp and process the complete pairs: the images that arrived since
        (both subscriptions' queues) count, so a node that fell behind processes the
        newest ``catch_up_pairs`` pairs, oldest first, instead of working through the
        whole backlog (vlc_common.core.stereo_pairing).
        """
        _, pairs = pair_images(self._pairing, index, msg, self._image_subs, self._warn,
                               PAIRING_WARNINGS, self.config.catch_up_pairs)
        for _, left_msg, right_msg in pairs:
            try:
                self._process(left_msg, right_msg)
            except Exception as exc:  # noqa: BLE001 — one bad frame must not stop the node
                self._count('failed')
                self._warn('failed', f'frame processing failed, skipped: {exc!r}')

    # ------------------------------------------------------------ processing
    def _process(self, left_msg, right_msg):
        located = self._located
        if located is None:
            self._count('no_camera_info')
            self._warn('no_camera_info', 'no camera_info for both cameras yet; stereo pair skipped')
            return
        try:
            left = conversions.image_to_array(left_msg)
            right = conversions.image_to_array(right_msg)
        except ValueError as exc:
            self._count('bad_image')
            self._warn('bad_image', f'bad image, stereo pair skipped: {exc}')
            return
        if left.shape != right.shape:
            self._count('size_mismatch')
            self._warn('size_mismatch', f'left {left.shape} and right {right.shape} image '
                       'sizes differ; stereo pair skipped')
            return
        g, locator = located
        if left.shape != (g.height, g.width):
            self._count('size_mismatch')
            self._warn('size_mismatch', f'image size {left.shape[::-1]} differs from camera_info '
                       f'{(g.width, g.height)}; stereo pair skipped')
            return
        speed, received = self._speed
        if self._monotonic() - received > self.config.odometry_timeout_s:
            speed = self.config.assumed_speed_mps
        result = locator.process(left, right, speed)
        records = conversions.pairs_to_records(result.pairs)
        self.pub_pairs.publish(conversions.records_to_cloud(records, left_msg.header))
        stats = self._stats
        stats['frames'] += 1
        stats['pairs'] += len(result.pairs)
        stats['unmatched'] += result.unmatched_left + result.unmatched_right
        stats['border'] += result.rejected_border
        stats['edge_pairs'] += result.edge_pairs
        stats['failed'] += result.failed
        self._proc_ms.append(1e3 * result.processing_s)

    # ------------------------------------------------------------ diagnostics
    def _publish_diagnostics(self):
        stats = dict(self._stats, **vars(self._pairing.stats))
        proc = np.array(self._proc_ms)
        skipped = (stats['bad_image'] + stats['size_mismatch'] + stats['out_of_order']
                   + stats['no_camera_info'] + stats['superseded'] + stats['stamp_outliers'])
        status = DiagnosticStatus(name=f'{self.get_name()}: spots', hardware_id='stereo_camera',
                                  level=DiagnosticStatus.OK, message='locating spots')
        if self._located is None:
            status.level, status.message = DiagnosticStatus.WARN, 'waiting for camera_info'
        elif skipped or stats['unpaired']:
            status.level = DiagnosticStatus.WARN
            status.message = 'some images skipped or unpaired'
        values = dict(stats)
        values['camera_info_refused'] = self._infos.refused
        values['camera_info_ignored'] = self._infos.ignored
        values['processing_ms_median'] = f'{np.median(proc):.2f}' if proc.size else 'nan'
        values['processing_ms_p99'] = f'{np.percentile(proc, 99):.2f}' if proc.size else 'nan'
        values['processing_ms_max'] = f'{proc.max():.2f}' if proc.size else 'nan'
        values['speed_mps'] = f'{self._speed[0]:.3f}'
        status.values = [KeyValue(key=k, value=str(v)) for k, v in values.items()]
        msg = DiagnosticArray(status=[status])
        msg.header.stamp = self.get_clock().now().to_msg()
        self.pub_diag.publish(msg)


def main(args=None):
    # one core: the stereo pair is processed in a single thread by design
    cv2.setNumThreads(1)
    keep_large_buffers()
    return run_node(SpotLocatorNode, 'spot_locator_node', args)


if __name__ == '__main__':
    sys.exit(main())
