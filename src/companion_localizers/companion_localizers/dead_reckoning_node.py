"""``dead_reckoning_node``: landmark + IMU dead reckoning (companion method 2).

The emergency-positioning scheme (:mod:`companion_localizers.core.dead_reckoning`):
20-sample sliding-window average of the gravity-free along-track acceleration from
``imu/data``, zero-velocity correction when the IMU or the lamp spots show a standing
train, integration reset at each confirmed lamp (``vlc/lamps`` state confirmed, ranged
from ``spots/pairs``). Topics, QoS and the common parameters: :mod:`.frame_node`.

Publishes ``companion/dead_reckoning/pose`` (geometry_msgs/PoseStamped; reliable,
depth 10) on the ``publish_rate_hz`` grid of IMU time while the chainage 1σ is below
``max_sigma_m``, and ``diagnostics`` (landmarks used, last landmark's reset, CPU time).
Parameters: ``config/dead_reckoning_node.yaml``.
"""
import sys

from companion_localizers.core.dead_reckoning import (
    DeadReckoning,
    DeadReckoningConfig,
    ImageStillConfig,
)
from companion_localizers.frame_node import ImuFrameNode, common_config_kwargs
from vlc_common.parameters import descriptor as _desc
from vlc_common.process import run_node


class DeadReckoningNode(ImuFrameNode):
    """ROS wrapper of :class:`DeadReckoning`."""

    METHOD = 'dead_reckoning'
    EXTRA_PARAMETERS = (
        ('window_samples', 20, _desc('Sliding-window average of the along-track '
                                     'acceleration, samples.', 1, 10000, integer=True)),
        ('landmark_max_ahead_m', 10.0, _desc('A lamp becomes a landmark at its first ranged, '
                                            'confirmed sighting nearer than this, m.',
                                            0.1, 100.0)),
        ('landmark_stride', 1, _desc('Only every n-th lamp of the map is a landmark.', 1, 10000,
                                     integer=True)),
        ('image_still_enabled', True, _desc('Still lamp spots also count as a standstill.')),
        ('image_still_window_s', 0.3, _desc('Spots must stay put this long, s.', 0.01, 10.0)),
        ('image_still_max_motion_px', 0.5, _desc('Largest spot motion of a standing train, px.',
                                                 0.0, 100.0)),
        ('image_still_min_frames', 5, _desc('Frames needed to judge image stillness.', 2, 1000,
                                            integer=True)),
    )

    def __init__(self, **kwargs):
        super().__init__('dead_reckoning_node', **kwargs)

    def make_core(self, p, lamp_map):
        config = DeadReckoningConfig(
            window_samples=p['window_samples'], landmark_max_ahead_m=p['landmark_max_ahead_m'],
            landmark_stride=p['landmark_stride'],
            image_still=ImageStillConfig(enabled=p['image_still_enabled'],
                                         window_s=p['image_still_window_s'],
                                         max_motion_px=p['image_still_max_motion_px'],
                                         min_frames=p['image_still_min_frames']),
            **common_config_kwargs(p))
        return DeadReckoning(config, lamp_map)

    def extra_diagnostics(self):
        core = self.core
        values = {'landmarks_used': len(core.landmarks), 'unknown_uid': core.unknown_uids,
                  'image_still': core.image_still.still}
        if core.landmarks:
            last = core.landmarks[-1]
            values['last_landmark_uid'] = f'{last.uid:#06x}'
            values['last_landmark_chainage_m'] = f'{last.chainage_m:.3f}'
            values['last_reset_m'] = f'{last.chainage_m - last.before_m:+.3f}'
        return None, '', values


def main(args=None):
    return run_node(DeadReckoningNode, 'dead_reckoning_node', args)


if __name__ == '__main__':
    sys.exit(main())
