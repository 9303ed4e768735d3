"""Print the car body's platform motion at 20, 60 and 120 km/h (RMS and peak).

``python -m vlc_stereo_camera.car_body_report``: for the German low-disturbance track
(``CarBodyConfig()``), the same ×3 ('harsh') and FRA class 6, the heading (yaw), pitch
and roll of ``base_link`` — RMS, peak and rate RMS — and the lateral and vertical
displacement, over 2 km of track per speed (:func:`.core.car_body.motion_statistics`).
Figures include the static track geometry under the car (what a standing train shows).
"""
import math

from vlc_stereo_camera.core.car_body import CarBodyConfig, motion_statistics

_DEG = 180.0 / math.pi


def main():
    cases = (('german_low', CarBodyConfig()),
             ('german_low x3', CarBodyConfig(scale=3.0)),
             ('fra_6', CarBodyConfig(spectrum='fra_6')))
    print('track            km/h | yaw rms/peak deg  rate deg/s | pitch rms/peak deg  '
          'rate deg/s | roll rms/peak deg | y rms mm | z rms mm')
    for label, config in cases:
        stats = motion_statistics(config)
        for speed, axes in stats.items():
            yaw, pitch, roll = axes['yaw'], axes['pitch'], axes['roll']
            print(f'{label:15s} {speed:5.0f} | {yaw["rms"] * _DEG:7.4f} / {yaw["peak"] * _DEG:7.4f}'
                  f'  {yaw["rate_rms"] * _DEG:7.4f} | {pitch["rms"] * _DEG:7.4f} / '
                  f'{pitch["peak"] * _DEG:7.4f}  {pitch["rate_rms"] * _DEG:7.4f} | '
                  f'{roll["rms"] * _DEG:6.3f} / {roll["peak"] * _DEG:6.3f} | '
                  f'{axes["y"]["rms"] * 1e3:8.2f} | {axes["z"]["rms"] * 1e3:8.2f}')


if __name__ == '__main__':
    main()
