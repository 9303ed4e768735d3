"""Installation tools of the VLC positioning stack (no rclpy).

Commands:

* ``stereo_calibrate``: checkerboard image pairs → ``left.yaml``/``right.yaml``
  (camera_info_manager) and optionally an OpenCV FileStorage file
  (:mod:`vlc_calibration.stereo_calibrate`, core in :mod:`vlc_calibration.stereo`);
* ``lamp_map_from_csv``: a surveyed lamp list (CSV) → the lamp map YAML
  (:mod:`vlc_calibration.lamp_map_from_csv`, core in ``vlc_common.core.lamp_survey``).

See docs/arch/calibration.md.
"""
