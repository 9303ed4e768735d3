"""``sbs_splitter_node``: a side-by-side stereo UVC camera as the graph's stereo input.

A stereo UVC camera delivers both cameras of one exposure in one frame, left camera in
the left half (2560×720 for two 1280×720 sensors). Its ROS driver (usb_cam,
v4l2_camera) publishes that frame; this node splits it into the two images the receivers
take, with the stereo calibration's camera_info.

Subscribes (relative names), one of them by ``input``:

* ``image_raw`` (sensor_msgs/Image; mono8, mono16, bgr8/rgb8, bgra8/rgba8, yuv422/uyvy,
  yuv422_yuy2/yuyv), ``input: raw``;
* ``image_raw/compressed`` (sensor_msgs/CompressedImage, JPEG as usb_cam and
  image_transport publish it, or PNG; decoded with ``cv2.imdecode``), ``input:
  compressed``.

QoS reliable, keep last 5 (``input_reliability: best_effort`` for a driver publishing
with the sensor-data profile).

Publishes:

* ``stereo/left/image_raw``, ``stereo/right/image_raw`` (sensor_msgs/Image, mono8;
  reliable, keep last 5 as every image of the graph): the two halves, as grey (the
  luma; the receivers read brightness only), header stamp the input frame's, frame ids
  ``left_frame_id`` / ``right_frame_id``; rectified with the calibration when
  ``rectify`` is on.
* ``stereo/left/camera_info``, ``stereo/right/camera_info`` (sensor_msgs/CameraInfo;
  reliable, transient local, depth 1): from the calibration file(s), with every frame,
  same header as its image (with ``rectify``: the rectified camera's, D = 0, R = I).
* ``diagnostics`` (diagnostic_msgs/DiagnosticArray; reliable, depth 10), every
  ``diagnostics_period_s``: frames split, frames skipped by cause, split time, the
  calibration in use and the camera timing.

The calibration (``calibration_files``: the left and right camera_info_manager YAML of
``camera_calibration``, or OpenCV FileStorage file(s)) is read at start with
:func:`vlc_common.core.calibration.load_stereo_calibration`; a file that cannot be used
stops the node with exit code 2 and a message naming the file and field. Set at run
time, a new calibration that cannot be used is refused (the old one stays). Bad frames
(not two calibrated cameras side by side, odd width, unsupported encoding, corrupt or
truncated JPEG) give a throttled warning and are skipped.

``row_time_s`` and ``exposure_s`` are the camera's rolling-shutter timing, which a UVC
camera does not report per frame: they must equal the decoder's, spot locator's and
localizer's (``tests/test_config_consistency.py`` checks the shipped files). Here they
only check the stamps (a frame interval shorter than the readout means a wrong
``row_time_s``) and are reported in the diagnostics.
"""
from collections import Counter, deque
import sys
import time

import cv2
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
import numpy as np
from rcl_interfaces.msg import ParameterType, SetParametersResult
from rclpy.clock import Clock, ClockType
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.qos import QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import CompressedImage, Image
from std_msgs.msg import Header

from vlc_camera_input import conversions
from vlc_camera_input.core import sbs
from vlc_camera_input.core.rectify import Rectifier, rectified_camera_info
from vlc_common.camera_info import stereo_camera_publishers
from vlc_common.core.calibration import CalibrationError, load_stereo_calibration
from vlc_common.diagnostics import diagnostic_array
from vlc_common.parameters import descriptor
from vlc_common.process import keep_large_buffers, run_node
from vlc_common.stamps import stamp_to_ns
from vlc_common.throttled_log import ThrottledWarnings

WARN_PERIOD_S = 2.0
INPUTS = {'raw': (Image, 'image_raw'), 'compressed': (CompressedImage, 'image_raw/compressed')}
RELIABILITIES = {'reliable': ReliabilityPolicy.RELIABLE,
                 'best_effort': ReliabilityPolicy.BEST_EFFORT}
#: Parameters that select the calibration (re-read when one of them is set at run time).
CALIBRATION_PARAMETERS = ('calibration_files', 'calibration_length_unit_m',
                          'calibration_alpha')


def _str(text):
    return descriptor(text, ptype=ParameterType.PARAMETER_STRING)


def _bool(text):
    return descriptor(text, ptype=ParameterType.PARAMETER_BOOL)


# name, default, descriptor
NODE_PARAMETERS = (
    ('input', 'raw', _str("'raw': sensor_msgs/Image on image_raw; 'compressed': "
                          'sensor_msgs/CompressedImage (JPEG, PNG) on image_raw/compressed.')),
    ('input_reliability', 'reliable', _str("QoS reliability of the input subscription: "
                                           "'reliable' or 'best_effort' (matches a driver "
                                           'publishing with the sensor-data profile).')),
    ('calibration_files', Parameter.Type.STRING_ARRAY,
     descriptor('Stereo calibration: [left.yaml, right.yaml] (camera_info_manager) or '
                'OpenCV FileStorage file(s).', ptype=ParameterType.PARAMETER_STRING_ARRAY)),
    ('calibration_length_unit_m', 1.0, descriptor('Metres per length unit of an OpenCV '
                                                  'file (0.001: millimetres).', 1e-6, 1.0)),
    ('calibration_alpha', 0.0, descriptor('cv2.stereoRectify free scaling for an OpenCV file '
                                          'without R1, R2, P1, P2 (0: valid pixels only, 1: '
                                          'all pixels; -1: OpenCV default).', -1.0, 1.0)),
    ('swap_halves', False, _bool('The camera puts the left camera in the right half.')),
    ('rectify', False, _bool('Remap each half to its rectified image with the calibration '
                             '(and publish the rectified camera_info).')),
    ('left_frame_id', 'camera_left_optical_frame', _str('Frame of the left image and '
                                                        'camera_info.')),
    ('right_frame_id', 'camera_right_optical_frame', _str('Frame of the right image and '
                                                          'camera_info.')),
    ('row_time_s', 3.0e-5, descriptor('Rolling shutter: delay between the exposure starts '
                                      'of two rows, s (the decoder\'s).', 1e-7, 1e-3)),
    ('exposure_s', 2.5e-5, descriptor('Row exposure, s (the decoder\'s).', 1e-7, 0.033)),
    ('warm_up', True, _bool('Convert and split one synthetic frame of the calibrated size '
                            'before subscribing, so first-call costs do not fall on the '
                            'first real frames.')),
    ('diagnostics_period_s', 1.0, descriptor('Diagnostics period, s (steady clock).',
                                             0.05, 3600.0)),
    ('hardware_id', 'sbs_stereo_camera', _str('hardware_id of the diagnostics status.')),
)


class StereoInput:
    """What one calibration gives the node: camera size, CameraInfo contents, rectifiers.

    Raises ValueError (:class:`CalibrationError`) for files that cannot be used.
    """

    def __init__(self, files, length_unit_m, alpha, rectify):
        files = [f for f in (files or ()) if f]
        if not files:
            raise CalibrationError('calibration_files', '(parameter)',
                                   'no calibration file given: the left and right '
                                   'camera_info YAML of camera_calibration, or an OpenCV '
                                   'FileStorage file')
        self.calibration = load_stereo_calibration(files, alpha=alpha,
                                                   length_unit_m=length_unit_m)
        self.camera_size = self.calibration.image_size
        infos = self.calibration.camera_info_dicts()
        self.rectifiers = None
        if rectify:
            self.rectifiers = [Rectifier(self.calibration.left),
                               Rectifier(self.calibration.right)]
            infos = [rectified_camera_info(info) for info in infos]
        self.infos = infos

    def describe(self):
        cal = self.calibration
        return (f'{cal.source}: {cal.image_size[0]}x{cal.image_size[1]} px per camera, '
                f'baseline {cal.baseline_m:.4f} m, fx {cal.left.fx:.1f} px, '
                f'{cal.left.distortion_model}')


class SbsSplitterNode(Node):
    """See the module docstring."""

    def __init__(self, **kwargs):
        super().__init__('sbs_splitter_node', **kwargs)
        p = {}
        for name, default, desc in NODE_PARAMETERS:
            p[name] = self.declare_parameter(name, default, desc).value
        if p['input'] not in INPUTS:
            raise ValueError(f"input: {p['input']!r} is not one of {', '.join(INPUTS)}")
        if p['input_reliability'] not in RELIABILITIES:
            raise ValueError(f"input_reliability: {p['input_reliability']!r} is not one of "
                             f"{', '.join(RELIABILITIES)}")
        self.params = p
        self.stereo = StereoInput(p['calibration_files'], p['calibration_length_unit_m'],
                                  p['calibration_alpha'], p['rectify'])
        self.readout_s = sbs.readout_s(self.stereo.camera_size[1], p['row_time_s'],
                                       p['exposure_s'])
        self.warm_up_ms = self._warm_up() if p['warm_up'] else 0.0
        self.stats = Counter()
        self.split_ms = deque(maxlen=300)
        self.min_interval_s = float('inf')
        self._last_stamp_ns = None
        self._warnings = ThrottledWarnings(self.get_logger(), WARN_PERIOD_S)
        self.add_on_set_parameters_callback(self._on_set_parameters)

        self.pub_images, self.pub_infos = stereo_camera_publishers(self)
        self.pub_diag = self.create_publisher(DiagnosticArray, 'diagnostics', 10)
        msg_type, topic = INPUTS[p['input']]
        input_qos = QoSProfile(depth=5, reliability=RELIABILITIES[p['input_reliability']])
        handler = self._on_image if p['input'] == 'raw' else self._on_compressed
        self.create_subscription(msg_type, topic, handler, input_qos)
        self.create_timer(p['diagnostics_period_s'], self._publish_diagnostics,
                          clock=Clock(clock_type=ClockType.STEADY_TIME))
        self.get_logger().info(
            f'splitting {self.resolve_topic_name(topic)} ({p["input"]}) into '
            f'{self.resolve_topic_name("stereo/left/image_raw")} and right; calibration '
            f'{self.stereo.describe()}{"; rectifying" if p["rectify"] else ""}; rows '
            f'{p["row_time_s"] * 1e6:.1f} us, exposure {p["exposure_s"] * 1e6:.1f} us; warmed '
            f'up in {self.warm_up_ms:.0f} ms')

    def _warm_up(self):
        """Run one synthetic frame of the calibrated size through the conversion, the split,
        the rectification and the message construction (nothing is published): the first
        calls into libjpeg, OpenCV's colour conversion and remap, and the first allocation
        of frame-sized buffers, are slow. Returns the time it took, ms.
        """
        start = time.perf_counter()
        width, height = self.stereo.camera_size
        rng = np.random.default_rng(0)
        frame = rng.integers(0, 255, size=(height, 2 * width), dtype=np.uint8)
        if self.params['input'] == 'compressed':
            data = cv2.imencode('.jpg', cv2.cvtColor(frame, cv2.COLOR_GRAY2BGR),
                                [cv2.IMWRITE_JPEG_QUALITY, 95])[1]
            frame = sbs.decode_compressed(data.tobytes(), 'jpeg')
        else:
            frame = conversions.image_to_grey(Image(height=height, width=2 * width,
                                                    encoding='mono8', step=2 * width,
                                                    data=frame.tobytes()))
        halves = sbs.split(frame, self.stereo.camera_size)
        if self.stereo.rectifiers is not None:
            halves = [rect(half) for rect, half in zip(self.stereo.rectifiers, halves)]
        for side in (0, 1):
            conversions.camera_info_msg(self.stereo.infos[side], Header())
            conversions.image_msg(halves[side], Header())
        return (time.perf_counter() - start) * 1e3

    # ------------------------------------------------------------------ parameters
    def _on_set_parameters(self, params):
        changed = {q.name: q.value for q in params}
        if 'input' in changed or 'input_reliability' in changed:
            return SetParametersResult(successful=False, reason='input and input_reliability '
                                       'are read at start only')
        if not any(name in changed for name in CALIBRATION_PARAMETERS + ('rectify',)):
            return SetParametersResult(successful=True)
        values = {name: changed.get(name, self.params[name]) for name in
                  CALIBRATION_PARAMETERS + ('rectify',)}
        try:
            stereo = StereoInput(values['calibration_files'],
                                 values['calibration_length_unit_m'],
                                 values['calibration_alpha'], values['rectify'])
        except (ValueError, OSError) as exc:
            self.stats['calibration_refused'] += 1
            self.get_logger().warning(f'new calibration refused, keeping {self.stereo.describe()}'
                                      f': {exc}')
            return SetParametersResult(successful=False, reason=str(exc))
        self.params.update(values)
        self.stereo = stereo
        self.readout_s = sbs.readout_s(stereo.camera_size[1], self.params['row_time_s'],
                                       self.params['exposure_s'])
        self.get_logger().info(f'calibration now {stereo.describe()}')
        return SetParametersResult(successful=True)

    # ------------------------------------------------------------------ input
    def _skip(self, kind, stamp_ns, text):
        self.stats[f'skipped_{kind}'] += 1
        self._warnings.warn(kind, f'SBS frame {stamp_ns} ns skipped: {text}')

    def _on_image(self, msg):
        start = time.perf_counter()
        try:
            grey = conversions.image_to_grey(msg)
        except conversions.ImageError as exc:
            kind = 'encoding' if exc.kind == 'encoding' else 'bad_image'
            self._skip(kind, stamp_to_ns(msg.header.stamp), str(exc))
            return
        self._split_and_publish(msg.header, grey, start)

    def _on_compressed(self, msg):
        start = time.perf_counter()
        try:
            grey = conversions.compressed_to_grey(msg)
        except sbs.SbsError as exc:
            kind = 'encoding' if exc.kind == 'format' else exc.kind
            self._skip(kind, stamp_to_ns(msg.header.stamp), str(exc))
            return
        self._split_and_publish(msg.header, grey, start)

    def _split_and_publish(self, header, grey, start):
        stamp_ns = stamp_to_ns(header.stamp)
        self.stats['frames_received'] += 1
        stereo = self.stereo
        try:
            halves = sbs.split(grey, stereo.camera_size, self.params['swap_halves'])
        except sbs.SbsError as exc:
            self._skip(exc.kind, stamp_ns, str(exc))
            return
        self._check_timing(stamp_ns)
        if stereo.rectifiers is not None:
            halves = [rect(half) for rect, half in zip(stereo.rectifiers, halves)]
        for side, frame_id in enumerate((self.params['left_frame_id'],
                                         self.params['right_frame_id'])):
            hdr = Header(stamp=header.stamp, frame_id=frame_id)
            self.pub_infos[side].publish(conversions.camera_info_msg(stereo.infos[side], hdr))
            self.pub_images[side].publish(conversions.image_msg(halves[side], hdr))
        self.stats['frames_split'] += 1
        self.split_ms.append((time.perf_counter() - start) * 1e3)

    def _check_timing(self, stamp_ns):
        last, self._last_stamp_ns = self._last_stamp_ns, stamp_ns
        if last is None or stamp_ns <= last:
            return
        interval_s = (stamp_ns - last) * 1e-9
        self.min_interval_s = min(self.min_interval_s, interval_s)
        if interval_s < self.readout_s:
            self.stats['timing_inconsistent'] += 1
            self._warnings.warn('timing', lambda: (
                f'frames {interval_s * 1e3:.2f} ms apart, shorter than the readout '
                f'(rows - 1) x row_time_s + exposure_s = {self.readout_s * 1e3:.2f} ms: '
                'row_time_s does not match the camera'))

    # ------------------------------------------------------------------ diagnostics
    def _publish_diagnostics(self):
        counts = dict(self.stats)
        skipped = sum(v for k, v in counts.items() if k.startswith('skipped_'))
        level, message = DiagnosticStatus.OK, 'splitting'
        if not counts.get('frames_received') and not skipped:
            level, message = DiagnosticStatus.WARN, 'no frame received yet'
        elif skipped:
            level, message = DiagnosticStatus.WARN, f'{skipped} frames skipped (bad input)'
        elif counts.get('timing_inconsistent'):
            level, message = DiagnosticStatus.WARN, 'frame interval shorter than the readout'
        proc = np.array(self.split_ms)
        values = {'frames_split': 0, 'frames_received': 0, **counts,
                  'split_ms_median': f'{np.median(proc):.2f}' if proc.size else 'nan',
                  'split_ms_max': f'{proc.max():.2f}' if proc.size else 'nan',
                  'calibration': self.stereo.describe(),
                  'rectify': self.params['rectify'],
                  'row_time_s': self.params['row_time_s'],
                  'exposure_s': self.params['exposure_s'],
                  'readout_ms': f'{self.readout_s * 1e3:.3f}',
                  'frame_interval_ms_min': (f'{self.min_interval_s * 1e3:.3f}'
                                            if np.isfinite(self.min_interval_s) else 'nan')}
        self.pub_diag.publish(diagnostic_array(
            self.get_clock().now().to_msg(), f'{self.get_name()}: stereo camera input',
            self.params['hardware_id'], level, message, values))


def main(args=None):
    cv2.setNumThreads(1)
    keep_large_buffers()
    return run_node(SbsSplitterNode, 'sbs_splitter_node', args)


if __name__ == '__main__':
    sys.exit(main())
