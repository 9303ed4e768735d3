"""The per-lamp records the nodes exchange as sensor_msgs/PointCloud2: one definition of
each field layout (the project's message definitions; standard message types only, see
ARCHITECTURE.md), read and written field by field with :mod:`vlc_common.pointcloud`.

``spots/pairs`` layout (sensor_msgs/PointCloud2, one point per matched lamp spot pair,
header = the stereo images' header, little endian, ``height`` 1, ``point_step`` 112):

=====================================  =======  ======  =====================================
field                                  type     offset  meaning
=====================================  =======  ======  =====================================
``u_left``, ``v_left``                 float64  0, 8    projected lamp-disc centre, left, px
``u_right``, ``v_right``               float64  16, 24  same in the right image, px
``disparity``                          float64  32      u_left − u_right, px (> 0)
``stamp_offset_s``                     float64  40      measurement instant − header stamp, s:
                                                        exposure mid-time of the spot's
                                                        centre row
``sigma_u_left``, ``sigma_v_left``     float32  48, 52  1σ of u_left, v_left, px
``sigma_u_right``, ``sigma_v_right``   float32  56, 60  1σ of u_right, v_right, px
``sigma_disparity``                    float32  64      1σ of the disparity, px
``circularity_left``,                  float32  68, 72  α = 4πS/L² (paper eq. 10) of each spot
``circularity_right``                                   (NaN: the cut spot of a bit-9 pair)
``ecc_du_left``, ``ecc_dv_left``       float32  76, 80  eccentricity offset removed, left, px
``ecc_du_right``, ``ecc_dv_right``     float32  84, 88  same, right, px
``blur_px``                            float32  92      predicted exposure blur length, px
``row_min``, ``row_max``               uint32   96, 100 first/last image row the left spot
                                                        covers (lit rows after closing)
``flags``                              uint32   104     bits 0–1 method (0 centroid,
                                                        1 ellipse, 2 fused, 3 chord); 2 Wiener
                                                        applied; 3 eccentricity removed with
                                                        the nominal normal; 4 … with the
                                                        measured normal; 5 centre row from
                                                        the chord widths; 6 rolling-shutter
                                                        model applied; 7 a spot cut by an
                                                        image edge; 8 raw centres mapped
                                                        through camera_info; 9 one spot cut
                                                        by the side edge, the disparity from
                                                        the chord ends (its sigma 0.05-0.3 px)
=====================================  =======  ======  =====================================

``vlc/lamps`` (sensor_msgs/PointCloud2, one point per lamp seen in the frame, header =
the left image's header, little endian, ``point_step`` 112):

==============================================  =======  ======  ============================
field                                           type     offset  unit / meaning
==============================================  =======  ======  ============================
``map_x``, ``map_y``, ``map_z``                 float64  0–16    m, lamp disc centre in the
                                                                 lamp map's frame once
                                                                 confirmed, NaN otherwise
                                                                 (not x/y/z: the header frame
                                                                 is the camera's)
``track_id``                                    uint32   24      decoder track (stable while
                                                                 the lamp is followed)
``uid``                                         uint32   28      lamp UID when state is 2 or
                                                                 3; 0 otherwise
``state``                                       uint32   32      0 searching, 1 partial,
                                                                 2 confirmed, 3 anomaly
                                                                 (CRC-valid UID absent from
                                                                 the lamp map: not a lamp)
``chips_seen``                                  uint32   36      packet chips (of 54) read
``bits_known``                                  uint32   40      data bits (of 24) read, once
                                                                 the packet start is located
``flags``                                       uint32   44      bit 0 left spot, 1 right
                                                                 spot, 2 left cut by the
                                                                 border, 3 right cut,
                                                                 4 stripes read from the left
                                                                 image, 5 from the right,
                                                                 6 lamp clock off-spec
                                                                 (aligned by content)
``t_offset_s``                                  float64  48      s, exposure mid-time of the
                                                                 spot's rows − header stamp
``left_u``, ``left_v``                          float32  56, 60  px, spot centre, left image
                                                                 (NaN if not seen)
``left_u_min``, ``left_v_min``, ``left_u_max``, float32  64–76   px, spot bounding box
``left_v_max``                                                   (inclusive)
``right_u``, ``right_v``                        float32  80, 84  px, right image
``right_u_min``, ``right_v_min``,               float32  88–100  px
``right_u_max``, ``right_v_max``
``data_bits``                                   uint32   104     the 24 data bits (UID << 8 |
                                                                 CRC-8, MSB first) read so
                                                                 far; unknown bits 0
``data_mask``                                   uint32   108     1 for each data bit known: a
                                                                 partial packet, matched
                                                                 against the lamp the map
                                                                 predicts there, never a UID
==============================================  =======  ======  ============================
"""
import numpy as np

PAIR_DTYPE = np.dtype({
    'names': ['u_left', 'v_left', 'u_right', 'v_right', 'disparity', 'stamp_offset_s',
              'sigma_u_left', 'sigma_v_left', 'sigma_u_right', 'sigma_v_right',
              'sigma_disparity', 'circularity_left', 'circularity_right', 'ecc_du_left',
              'ecc_dv_left', 'ecc_du_right', 'ecc_dv_right', 'blur_px', 'row_min',
              'row_max', 'flags'],
    'formats': ['<f8'] * 6 + ['<f4'] * 12 + ['<u4'] * 3,
    'offsets': [0, 8, 16, 24, 32, 40] + [48 + 4 * i for i in range(12)] + [96, 100, 104],
    'itemsize': 112,
})

FLAG_LEFT, FLAG_RIGHT, FLAG_LEFT_CUT, FLAG_RIGHT_CUT = 1, 2, 4, 8
FLAG_READ_LEFT, FLAG_READ_RIGHT, FLAG_CONTENT_ALIGNED = 16, 32, 64

LAMP_DTYPE = np.dtype([
    ('map_x', '<f8'), ('map_y', '<f8'), ('map_z', '<f8'),
    ('track_id', '<u4'), ('uid', '<u4'), ('state', '<u4'), ('chips_seen', '<u4'),
    ('bits_known', '<u4'), ('flags', '<u4'),
    ('t_offset_s', '<f8'),
    ('left_u', '<f4'), ('left_v', '<f4'),
    ('left_u_min', '<f4'), ('left_v_min', '<f4'), ('left_u_max', '<f4'), ('left_v_max', '<f4'),
    ('right_u', '<f4'), ('right_v', '<f4'),
    ('right_u_min', '<f4'), ('right_v_min', '<f4'), ('right_u_max', '<f4'),
    ('right_v_max', '<f4'),
    ('data_bits', '<u4'), ('data_mask', '<u4'),
])

#: ``photodiode/rssi``: one point per lamp received in one photodiode sample (uid, snr_db
#: dB, power_w W estimated received "on" power, power_sigma_w W 1σ of the estimate).
RSSI_DTYPE = np.dtype({'names': ['uid', 'snr_db', 'power_w', 'power_sigma_w'],
                       'formats': ['<u4', '<f4', '<f8', '<f8'],
                       'offsets': [0, 4, 8, 16], 'itemsize': 24})
