"""``vlc_decoder_node``: lamp UIDs from the stripes of the stereo camera's lamp spots.

Subscribes (relative names):

* ``stereo/left/image_raw``, ``stereo/right/image_raw`` (sensor_msgs/Image; reliable,
  keep last 5): paired by exact stamp. mono8 is used as is; rgb8/bgr8/rgba8/bgra8 are
  converted to gray, mono16 keeps its high byte.
* ``stereo/left/camera_info``, ``stereo/right/camera_info`` (sensor_msgs/CameraInfo;
  best effort, volatile: matches any publisher): image size checks and the stereo
  disparity bound fx·baseline / ``min_depth_m``. The last good one of each camera is
  kept (:class:`vlc_common.camera_info.CameraInfoKeeper`): an invalid one (zero or NaN
  K/P) is refused with a throttled warning, a different valid one is taken only once it
  came three times in a row.

Publishes:

* ``vlc/lamps`` (sensor_msgs/PointCloud2; reliable, depth 10): one point per lamp spot
  seen in the frame, header = the left image's header; fields in ``conversions.py``
  (track id, spot boxes and centres, decode state, chips seen, UID and map position once
  confirmed, exposure mid-time offset).
* ``diagnostics`` (diagnostic_msgs/DiagnosticArray; reliable, depth 10): every
  ``diagnostics_period_s`` and at once when a CRC-valid UID absent from the lamp map
  appears (an anomaly, never published as a lamp).

Bad input (unknown encoding, empty, truncated or inconsistent image, left/right size
mismatch, images of another size than camera_info's, unpaired or out-of-order stamps)
gives a throttled warning and the frame is skipped. An image stamped more than
``stamp_jump_reset_s`` before or ``forward_jump_s`` after the newest one is held: alone
(a 1970 or far-future stamp) it is dropped as an outlier and counted; only
``time_base_confirm_count`` consecutive images of the new time base (a looped bag)
reset the lamp tracks, with a throttled warning, and decoding starts afresh with them
(:class:`vlc_common.core.stereo_pairing.StereoPairing`).
Frames are decoded on the executor thread, well inside a frame period
(``decoder_benchmark`` measures it). OpenCV runs single-threaded.
"""
import collections
import sys
import time

import cv2
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
import numpy as np
from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor, ParameterType
from rclpy.node import Node
from rclpy.qos import QoSProfile, ReliabilityPolicy, qos_profile_sensor_data
from sensor_msgs.msg import CameraInfo, Image, PointCloud2

from vlc_common.camera_info import CameraInfoKeeper, raw_camera_model
from vlc_common.core.lamp_map import LampMap, resolve_lamp_map_path
from vlc_common.core.stereo_pairing import StereoPairing
from vlc_common.diagnostics import diagnostic_array
from vlc_common.polled import pair_images
from vlc_common.process import (
    keep_large_buffers,
    run_node,
)
from vlc_common.throttled_log import ThrottledWarnings
from vlc_decoder import conversions
from vlc_decoder.core import synth
from vlc_decoder.core.config import DecoderConfig
from vlc_decoder.core.tracker import ANOMALY, CONFIRMED, LampTracker

WARN_THROTTLE_S = 2.0
#: the stereo pairing's events (StereoPairing.add) → throttled warning (key, text)
PAIRING_WARNINGS = {
    'reset': ('stamp_jump', 'image stamps jumped back by more than stamp_jump_reset_s for '
              'time_base_confirm_count images: lamp tracks reset'),
    'out_of_order': ('out_of_order', 'an image stamp is not after the last decoded frame: '
                     'skipped'),
    'outlier': ('stamp_outlier', 'an image stamped far from the stream (beyond '
                'stamp_jump_reset_s before or forward_jump_s after the newest) dropped'),
}


def _identity(uv):
    return uv


class StartupError(RuntimeError):
    """Invalid configuration: the node cannot start (exit code 2)."""


def _float(text, lo, hi):
    return ParameterDescriptor(description=text, floating_point_range=[
        FloatingPointRange(from_value=float(lo), to_value=float(hi), step=0.0)])


def _int(text, lo, hi):
    return ParameterDescriptor(description=text, integer_range=[
        IntegerRange(from_value=int(lo), to_value=int(hi), step=1)])


def _bool(text):
    return ParameterDescriptor(description=text, type=ParameterType.PARAMETER_BOOL)


def _str(text):
    return ParameterDescriptor(description=text, type=ParameterType.PARAMETER_STRING)


# name, default, descriptor; the DecoderConfig fields first, then the node's own
CORE_PARAMETERS = (
    ('row_time_s', 30e-6, _float('Delay between the exposure starts of two rows, s.',
                                 1e-7, 1e-3)),
    ('exposure_s', 25e-6, _float('Row exposure time, s.', 1e-7, 0.033)),
    ('chip_rate_hz', 21_150.0, _float('Nominal lamp chip rate, chips/s.', 2000.0, 40000.0)),
    ('off_level', 0.05, _float('Lamp "off" output relative to "on".', 0.0, 0.49)),
    ('chip_margin', 0.2, _float('A chip is read only this far (normalised level) from 0.5.',
                                0.05, 0.45)),
    ('min_chip_weight', 0.2, _float('Evidence (fully-inside row exposures) a chip read '
                                    'needs.', 0.1, 10.0)),
    ('rate_search_tolerance', 0.03, _float('Within-frame chip-rate search span (fraction).',
                                           0.0, 0.1)),
    ('rate_search_min_chips', 24.0, _float('Profiles spanning fewer chips keep the prior '
                                           'rate.', 4.0, 1000.0)),
    ('clock_tolerance_ppm', 100.0, _float('Lamp clock accuracy assumed frame to frame, ppm.',
                                          1.0, 10000.0)),
    ('psf_sigma_px', 0.7, _float('Lens blur, Gaussian sigma of the PSF core, px (the '
                                 "camera's); models the spot's row envelope.", 0.0, 10.0)),
    ('detect_threshold_sigma', 8.0, _float('Spot threshold above the background, in '
                                           'background noise sigmas.', 2.0, 100.0)),
    ('detect_min_contrast', 20.0, _float('Spot threshold at least this far above the '
                                         'background, DN.', 1.0, 250.0)),
    ('detect_min_area_px', 3, _int('Smallest spot core, pixels.', 1, 10000)),
    ('use_otsu', False, _bool('Threshold with Otsu (the paper) instead of the noise-'
                              'referenced threshold.')),
    ('median_filter', False, _bool('3x3 median filter before thresholding (the paper).')),
    ('max_spots', 8, _int('Most lamp spots decoded per image.', 1, 64)),
    ('track_gate_px', 60.0, _float('Association gate around a predicted spot, px.',
                                   1.0, 2000.0)),
    ('track_max_missed_frames', 15, _int('Frames a track survives unseen.', 0, 1000)),
    ('max_fragments', 120, _int('Frames of stripes kept per lamp for assembly.', 2, 10000)),
    ('stamp_jump_reset_s', 0.05, _float('An image stamped more than this before the last '
                                        'frame (looped bag) resets the lamp tracks, s.',
                                        0.0, 3600.0)),
    ('border_margin_px', 2, _int('A spot this close to the left/right border is cut.',
                                 0, 100)),
    ('frame_rate_hz', 30.0, _float('Camera frame rate: packets are assembled on its period '
                                   '(image stamp jitter averaged out); 0 or a rate the '
                                   'stamps contradict = the stamps as they are, frames/s.',
                                   0.0, 1000.0)),
)
NODE_PARAMETERS = (
    ('lamp_map_path', '', _str("Lamp map YAML; '' = vlc_stereo_camera's installed map.")),
    ('min_depth_m', 0.5, _float('Nearest lamp depth paired in stereo, m (disparity bound).',
                                0.05, 100.0)),
    ('max_pending_stamps', 10, _int('Unpaired image stamps kept before the oldest is '
                                    'dropped.', 1, 1000)),
    ('catch_up_pairs', 2, _int('Complete stereo pairs decoded, oldest first, when several '
                               'waited (the node was stalled): a stall of up to this many '
                               'frames loses none; older pairs are dropped and counted '
                               '(skipped_superseded). 1 = only the newest.', 1, 10)),
    ('forward_jump_s', 1.0, _float('An image stamped more than this after the newest one '
                                   'is held as a possible outlier, s.', 0.0, 3600.0)),
    ('time_base_confirm_count', 3, _int('Consecutive images of a new time base (stamped '
                                        'beyond stamp_jump_reset_s before or '
                                        'forward_jump_s after the newest one) that '
                                        'confirm it; fewer are outliers, dropped.', 1, 1000)),
    ('diagnostics_period_s', 1.0, _float('Diagnostics period, s (wall time).', 0.05, 3600.0)),
    ('hardware_id', 'stereo_camera', _str('hardware_id of the diagnostics status.')),
    ('warm_up', True, _bool('Decode a few synthetic striped frames before subscribing, so '
                            'first-call costs do not fall on the first real frames.')),
)


def warm_up(cfg, lamp_map):
    """Run the tracker's per-frame code paths on synthetic striped stereo frames.

    The first calls of OpenCV's contour and morphology kernels and of numpy's ufunc loops
    for each dtype, the first header search, assembly and CRC, are slow: without this
    they fell on the first real frames and delayed them. A throwaway tracker decodes
    three frames of a near lamp (160 px, confirmed from the second frame on; a UID of the
    map, so the lookup runs too) and a far one (24 px, partial); the node's own tracker
    starts empty. Returns the
    number of confirmed records in the last frame.
    """
    tracker = LampTracker(cfg, lamp_map)
    uids = ([lamp.uid for lamp in lamp_map.lamps[:2]] if lamp_map is not None else [])
    uids += [synth.worked_example_uid()] * (2 - len(uids))
    signals = [synth.LampSignal(uid, chip_rate_hz=cfg.chip_rate_hz, off_level=cfg.off_level)
               for uid in uids]
    rng = np.random.default_rng(0)
    records = []
    for k in range(3):
        t0_s = k / 30.0
        lamps = [synth.SyntheticLamp(signals[0], u_left=400.0 + 20.0 * k, v=180.0,
                                     disparity_px=60.0, width_px=160.0, height_px=160.0),
                 synth.SyntheticLamp(signals[1], u_left=150.0 + 2.0 * k, v=60.0,
                                     disparity_px=10.0, width_px=24.0, height_px=24.0)]
        # a 640x360 frame: the same code paths as a full one at a quarter of the rendering
        left, right = synth.render_stereo(lamps, t0_s, width=640, height=360,
                                          row_time_s=cfg.row_time_s,
                                          exposure_s=cfg.exposure_s, rng=rng)
        records = tracker.process(round(t0_s * 1e9), left, right)
    return sum(r.state == CONFIRMED for r in records)


class VlcDecoderNode(Node):
    """Thin ROS wrapper around :class:`~vlc_decoder.core.tracker.LampTracker`."""

    def __init__(self, **kwargs):
        super().__init__('vlc_decoder_node', **kwargs)
        for name, default, descriptor in CORE_PARAMETERS + NODE_PARAMETERS:
            self.declare_parameter(name, default, descriptor)
        value = {n: self.get_parameter(n).value for n, _, _ in CORE_PARAMETERS}
        try:
            self.cfg = DecoderConfig(**value)
        except ValueError as error:
            raise StartupError(f'invalid parameters: {error}') from error
        self.lamp_map_path = self.get_parameter('lamp_map_path').value
        self.min_depth_m = self.get_parameter('min_depth_m').value
        self.max_pending = self.get_parameter('max_pending_stamps').value
        self.catch_up_pairs = self.get_parameter('catch_up_pairs').value
        self.hardware_id = self.get_parameter('hardware_id').value
        lamp_map = self._load_lamp_map(self.lamp_map_path)
        if self.get_parameter('warm_up').value:
            start = time.perf_counter()
            warm_up(self.cfg, lamp_map)
            self.get_logger().info(f'warmed up in {(time.perf_counter() - start) * 1e3:.0f} ms')
        self.tracker = LampTracker(self.cfg, lamp_map)
        self.camera_infos = CameraInfoKeeper()
        self.pairing = StereoPairing(
            self.max_pending, int(round(self.cfg.stamp_jump_reset_s * 1e9)),
            int(round(self.get_parameter('forward_jump_s').value * 1e9)),
            self.get_parameter('time_base_confirm_count').value)
        self.stats = collections.Counter()
        self.proc_ms = collections.deque(maxlen=300)
        self.reported_anomalies = set()
        self._warnings = ThrottledWarnings(self.get_logger(), WARN_THROTTLE_S)

        image_qos = QoSProfile(depth=5, reliability=ReliabilityPolicy.RELIABLE)
        self._image_subs = [
            self.create_subscription(Image, f'stereo/{name}/image_raw',
                                     lambda m, side=side: self._on_image(side, m), image_qos)
            for side, name in enumerate(('left', 'right'))]
        self.create_subscription(CameraInfo, 'stereo/left/camera_info',
                                 lambda m: self._on_info(0, m), qos_profile_sensor_data)
        self.create_subscription(CameraInfo, 'stereo/right/camera_info',
                                 lambda m: self._on_info(1, m), qos_profile_sensor_data)
        self.pub_lamps = self.create_publisher(PointCloud2, 'vlc/lamps', 10)
        self.pub_diag = self.create_publisher(DiagnosticArray, 'diagnostics', 10)
        self.create_timer(self.get_parameter('diagnostics_period_s').value,
                          self._publish_diagnostics)
        self.get_logger().info(
            f'decoding lamps at {self.cfg.chip_rate_hz:.0f} chips/s, rows '
            f'{self.cfg.row_time_s * 1e6:.1f} us, exposure {self.cfg.exposure_s * 1e6:.1f} us; '
            f'lamp map {self.lamp_map_path or "(default)"} with '
            f'{len(lamp_map.lamps) if lamp_map is not None else 0} lamps')

    def _load_lamp_map(self, path):
        resolved = resolve_lamp_map_path(path)
        try:
            return LampMap.load(resolved)
        except (OSError, ValueError, KeyError, TypeError) as error:
            raise StartupError(f'cannot load the lamp map {resolved}: {error}') from error

    # ------------------------------------------------------------------ input
    def _warn(self, kind, text):
        """Warn at most once per WARN_THROTTLE_S (wall time) for each kind of problem."""
        self._warnings.warn(kind, text)

    @property
    def infos(self):
        """The kept (last good) camera_info of the left and right camera, or None."""
        return self.camera_infos.current

    def _on_info(self, side, msg):
        outcome, reason = self.camera_infos.update(side, msg)
        if outcome == CameraInfoKeeper.REFUSED:
            self._warn(f'camera_info_refused_{side}', f'{("left", "right")[side]} camera_info '
                       f'refused, the last good one kept: {reason}')
        elif outcome == CameraInfoKeeper.PENDING:
            self._warn(f'camera_info_pending_{side}', f'{("left", "right")[side]} camera_info '
                       f'{reason}')
        elif outcome == CameraInfoKeeper.KEPT:
            self._update_rectify()

    def _update_rectify(self):
        """Raw images (camera_info with D ≠ 0 or R ≠ I): pair the spots on rectified rows."""
        both = self.camera_infos.both()
        if both is None:
            return
        try:
            models = [raw_camera_model(m) for m in both]
        except ValueError as exc:
            self._warn('camera_info_model', f'camera_info lens model unusable, spots paired '
                       f'on raw rows: {exc}')
            models = [None, None]
        if all(m is None for m in models):
            self.tracker.rectify = None
        else:
            self.tracker.rectify = tuple(_identity if m is None else m.rectify_points
                                         for m in models)

    def _on_image(self, side, msg):
        """Pair by stamp and decode the complete pairs: the images that arrived since
        (both subscriptions' queues) count, so a decoder that fell behind decodes the
        newest ``catch_up_pairs`` pairs, oldest first, instead of working through the
        whole backlog (vlc_common.core.stereo_pairing).
        """
        events, pairs = pair_images(self.pairing, side, msg, self._image_subs, self._warn,
                                    PAIRING_WARNINGS, self.catch_up_pairs)
        if 'reset' in events:
            # a looped bag or a restarted camera: start afresh rather than skip every
            # frame until the stamps catch up, and never mix fragments across the jump
            self.tracker.reset()
        for pair in pairs:
            self._process(*pair)

    # ------------------------------------------------------------------ decoding
    def _process(self, stamp_ns, left_msg, right_msg):
        try:
            left = conversions.image_to_mono8(left_msg)
            right = conversions.image_to_mono8(right_msg)
        except conversions.ImageError as error:
            self.stats['skipped_bad_image'] += 1
            self._warn(f'bad_image:{error.kind}', f'frame {stamp_ns} ns skipped: {error}')
            return
        if left.shape != right.shape:
            self.stats['skipped_size_mismatch'] += 1
            self._warn('size_mismatch', f'frame {stamp_ns} ns skipped: left '
                       f'{left.shape[::-1]} and right {right.shape[::-1]} images differ in size')
            return
        for side, info in enumerate(self.infos):
            if info is not None and (info.width, info.height) != (left.shape[1],
                                                                   left.shape[0]):
                self.stats['skipped_size_mismatch'] += 1
                self._warn(f'camera_info_{side}', f'frame {stamp_ns} ns skipped: camera_info '
                           f'{info.width}x{info.height} does not match the '
                           f'{left.shape[1]}x{left.shape[0]} images')
                return
        self.tracker.max_disparity_px = self._max_disparity()
        start = time.perf_counter()
        records = self.tracker.process(stamp_ns, left, right)
        self.proc_ms.append((time.perf_counter() - start) * 1e3)
        self.stats['frames_decoded'] += 1
        array = conversions.records_to_array(records, self.cfg.row_time_s,
                                             self.cfg.exposure_s)
        self.pub_lamps.publish(conversions.records_to_cloud(array, left_msg.header))
        anomalies = {r.uid for r in records if r.state == ANOMALY}
        if anomalies - self.reported_anomalies:
            self.reported_anomalies |= anomalies
            self._warn('anomaly', 'CRC-valid UID(s) absent from the lamp map: '
                       + ', '.join(f'{u:#06x}' for u in sorted(anomalies)))
            self._publish_diagnostics()

    def _max_disparity(self):
        info = self.infos[1]
        if info is None or len(info.p) < 12 or info.p[3] >= 0:
            return 250.0
        return -float(info.p[3]) / self.min_depth_m        # P[0,3] = -fx·baseline

    # ------------------------------------------------------------------ diagnostics
    def _pairing_counts(self):
        ps = self.pairing.stats
        return {'skipped_unpaired': ps.unpaired, 'skipped_out_of_order': ps.out_of_order,
                'skipped_superseded': ps.superseded, 'skipped_stamp_outliers': ps.stamp_outliers,
                'resets_stamp_jump': ps.stamp_resets}

    def _publish_diagnostics(self):
        tracker = self.tracker
        counts = dict(self.stats, **self._pairing_counts())
        skipped = sum(v for k, v in counts.items() if k.startswith('skipped'))
        anomalies = sorted(tracker.anomalies)
        level = DiagnosticStatus.OK
        message = 'decoding'
        if anomalies:
            level = DiagnosticStatus.WARN
            message = 'CRC-valid UIDs absent from the lamp map: ' + ', '.join(
                f'{u:#06x}' for u in anomalies)
        elif skipped:
            level = DiagnosticStatus.WARN
            message = f'{skipped} frames skipped (bad input)'
        values = dict(counts)
        values.update({
            'camera_info_refused': self.camera_infos.refused,
            'camera_info_ignored': self.camera_infos.ignored,
            'tracks_active': len(tracker.tracks),
            'lamps_confirmed': len(tracker.confirmations),
            # frames in which two spots confirmed one UID (neither reported on both)
            'duplicate_uid_frames': tracker.duplicate_uid_frames,
            'anomalous_uids': ' '.join(f'{u:#06x}' for u in anomalies),
            'decode_ms_median': f'{np.median(self.proc_ms):.2f}' if self.proc_ms else 'nan',
            'decode_ms_p99': (f'{np.percentile(self.proc_ms, 99):.2f}' if self.proc_ms
                              else 'nan'),
            'decode_ms_max': f'{np.max(self.proc_ms):.2f}' if self.proc_ms else 'nan',
        })
        self.pub_diag.publish(diagnostic_array(
            self.get_clock().now().to_msg(), 'vlc_decoder: lamp identification',
            self.hardware_id, level, message, values))


def main(args=None):
    cv2.setNumThreads(1)
    keep_large_buffers()
    return run_node(VlcDecoderNode, 'vlc_decoder_node', args, startup_errors=(StartupError,))


if __name__ == '__main__':
    sys.exit(main())
