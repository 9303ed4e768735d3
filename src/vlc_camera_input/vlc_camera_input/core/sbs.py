"""Side-by-side (SBS) stereo frames: one image holding both cameras of one exposure.

A stereo UVC camera (two sensors behind one USB bridge, e.g. 2 × 1280×720 as one
2560×720 stream) delivers the left camera in the left half and the right camera in the
right half of every frame; both halves carry the frame's one stamp. usb_cam and
v4l2_camera publish it as ``image_raw`` (mono8, bgr8/rgb8, yuv422/yuyv) and, through
image_transport, as ``image_raw/compressed`` (JPEG). This module splits a frame already
converted to grey and decodes compressed frames; every problem raises :class:`SbsError`
whose ``kind`` names it for the node's counters.
"""
import cv2
import numpy as np

#: JPEG start- and end-of-image markers.
JPEG_SOI = b'\xff\xd8'
JPEG_EOI = b'\xff\xd9'
PNG_SIGNATURE = b'\x89PNG\r\n\x1a\n'
#: ``CompressedImage.format`` words that name a format cv2.imdecode reads (usb_cam writes
#: ``jpeg``, image_transport ``bgr8; jpeg compressed bgr8`` or ``png``).
DECODABLE_FORMATS = ('jpeg', 'jpg', 'png')


class SbsError(ValueError):
    """A frame that cannot be split: ``kind`` is one of ``odd_width``, ``size``,
    ``format``, ``corrupt`` (a compressed frame that does not decode, or truncated).
    """

    def __init__(self, kind, text):
        super().__init__(text)
        self.kind = kind


def split(image, camera_size=None, swap=False):
    """Split an SBS grey frame into the left and right camera images.

    Parameters
    ----------
    image : ndarray, shape (H, 2·W)
        The whole frame, one camera per half.
    camera_size : (int, int), optional
        (W, H) of one camera, px (the calibration's): the frame must be (2·W) × H.
    swap : bool
        The camera puts the left camera in the right half.

    Returns
    -------
    left, right : ndarray, shape (H, W)
        C-contiguous copies (each is published on its own).
    """
    height, width = image.shape[:2]
    if width % 2:
        raise SbsError('odd_width', f'an SBS frame of odd width {width} px cannot be split '
                                    'into two cameras')
    half = width // 2
    if camera_size is not None and (half, height) != (int(camera_size[0]),
                                                      int(camera_size[1])):
        cw, ch = int(camera_size[0]), int(camera_size[1])
        raise SbsError('size', f'SBS frame {width}x{height} px is not two {cw}x{ch} px '
                               f'cameras side by side (expected {2 * cw}x{ch}): the '
                               'calibration belongs to another resolution')
    first = np.ascontiguousarray(image[:, :half])
    second = np.ascontiguousarray(image[:, half:])
    return (second, first) if swap else (first, second)


def decode_compressed(data, fmt=''):
    """A ``CompressedImage``'s bytes → (H, W) uint8 grey (the luma: JPEG's Y channel as
    stored, no colour conversion).

    Parameters
    ----------
    data : bytes-like
        The compressed frame.
    fmt : str
        ``CompressedImage.format``; '' is taken for JPEG (some drivers leave it empty).

    Raises :class:`SbsError` ``format`` for a format other than JPEG or PNG (e.g.
    ``compressedDepth``, ``h264``), ``corrupt`` for data that is not a whole image (no
    JPEG start marker, no end marker: a frame cut short on the USB link) or that OpenCV
    cannot decode.
    """
    words = fmt.lower().replace(';', ' ').split()
    if words and not any(w in DECODABLE_FORMATS for w in words):
        raise SbsError('format', f'compressed format {fmt!r} is not JPEG or PNG')
    buf = np.frombuffer(data, dtype=np.uint8)
    if buf.size == 0:
        raise SbsError('corrupt', 'empty compressed frame')
    head = bytes(buf[:2])
    if head == JPEG_SOI:
        # UVC bridges pad MJPEG frames with zeros after the end marker
        tail = bytes(buf[-4096:]).rstrip(b'\x00')
        if not tail.endswith(JPEG_EOI):
            raise SbsError('corrupt', f'JPEG frame of {buf.size} B has no end-of-image '
                                      'marker (cut short)')
    elif head != PNG_SIGNATURE[:2]:
        raise SbsError('corrupt', f'compressed frame of {buf.size} B does not start with a '
                                  'JPEG or PNG signature')
    image = cv2.imdecode(buf, cv2.IMREAD_GRAYSCALE)
    if image is None or image.size == 0:
        raise SbsError('corrupt', f'compressed frame of {buf.size} B does not decode')
    return image


def readout_s(height, row_time_s, exposure_s):
    """Rolling-shutter readout of one frame, s: the last row starts exposing
    ``(height − 1)·row_time_s`` after the first and is read ``exposure_s`` later.
    """
    return (int(height) - 1) * float(row_time_s) + float(exposure_s)
