"""``ins_beacon_node``: INS + zero-velocity update + stereo beacon ranging (companion
method 3), with beacon-ID plausibility.

Core: :mod:`companion_localizers.core.ins_beacon`. Inputs ``imu/data``, ``spots/pairs``,
``vlc/lamps`` and camera_info; topics, QoS and the common parameters: :mod:`.frame_node`.

Publishes ``companion/ins_beacon/pose`` (geometry_msgs/PoseStamped; reliable, depth 10)
on the ``publish_rate_hz`` grid of IMU time while the chainage 1σ is below
``max_sigma_m``, and ``diagnostics``: WARN for ``report_hold_s`` after a beacon is
flagged as forged or misplaced (its UID, verdict and reason in the message and in
``last_flagged_uid`` / ``last_flag_verdict`` / ``last_flag_reason``), counters of
accepted and flagged beacons, position and velocity updates, CPU time. A flag is also
logged (throttled). Parameters: ``config/ins_beacon_node.yaml``.
"""
import sys

from companion_localizers.core.beacon_sequence import BeaconSequenceConfig
from companion_localizers.core.ins_beacon import InsBeacon, InsBeaconConfig
from companion_localizers.frame_node import WARN, ImuFrameNode, common_config_kwargs
from vlc_common.parameters import descriptor as _desc
from vlc_common.process import run_node


class InsBeaconNode(ImuFrameNode):
    """ROS wrapper of :class:`InsBeacon`."""

    METHOD = 'ins_beacon'
    EXTRA_PARAMETERS = (
        ('velocity_baseline_s', 0.1, _desc('Shortest time between the two ranges of a '
                                           'velocity update, s.', 0.005, 10.0)),
        ('track_gap_s', 0.5, _desc('A lamp track unseen this long is closed, s.', 0.01, 60.0)),
        ('track_gate_m', 0.5, _desc('Largest unexplained jump of a track between frames, m.',
                                    0.01, 10.0)),
        ('max_speed_mps', 60.0, _desc('Motion allowed between frames while the speed is '
                                      'unknown, m/s.', 0.1, 200.0)),
        ('gate_chi2', 25.0, _desc('Position updates with a larger normalised innovation^2 '
                                  'are skipped.', 1.0, 1e6)),
        ('sequence_gate_sigma', 4.0, _desc('Beacon check: offsets beyond this many sigma are '
                                           'flagged.', 0.1, 100.0)),
        ('sequence_tolerance_floor_m', 1.0, _desc('Beacon check: smallest tolerance, m.',
                                                  0.0, 100.0)),
        ('sequence_odometer_drift_rel', 0.02, _desc('Beacon check: relative error of the '
                                                    'distance travelled.', 0.0, 1.0)),
        ('sequence_reanchor_count', 2, _desc('Beacon check: agreeing flagged beacons that '
                                             're-anchor it.', 1, 100, integer=True)),
        ('report_hold_s', 5.0, _desc('A flagged beacon keeps the diagnostics at WARN this '
                                     'long (steady clock), s.', 0.0, 3600.0)),
    )

    def __init__(self, **kwargs):
        self._last_flag = None
        self._last_flag_time = None
        super().__init__('ins_beacon_node', **kwargs)

    def make_core(self, p, lamp_map):
        config = InsBeaconConfig(
            velocity_baseline_s=p['velocity_baseline_s'], track_gap_s=p['track_gap_s'],
            track_gate_m=p['track_gate_m'], max_speed_mps=p['max_speed_mps'],
            gate_chi2=p['gate_chi2'],
            sequence=BeaconSequenceConfig(
                gate_sigma=p['sequence_gate_sigma'],
                tolerance_floor_m=p['sequence_tolerance_floor_m'],
                odometer_drift_rel=p['sequence_odometer_drift_rel'],
                survey_sigma_m=p['survey_sigma_m'],
                reanchor_count=p['sequence_reanchor_count']),
            **common_config_kwargs(p))
        return InsBeacon(config, lamp_map)

    def handle_frame_result(self, flags):
        for flag in flags:
            self._last_flag, self._last_flag_time = flag, self._now_s()
            self._warn(f'flag_{flag.uid}', f'beacon {flag.uid:#06x} flagged '
                       f'({flag.verdict}): {flag.reason}')

    def extra_diagnostics(self):
        c = self.core.ins_counters
        values = {'beacons_accepted': c.beacons_accepted, 'beacons_flagged': c.beacons_flagged,
                  'position_updates': c.position_updates,
                  'velocity_updates': c.velocity_updates, 'gate_rejections': c.gate_rejections,
                  'unrangeable': c.unrangeable}
        anchor = self.core.checker.anchor_uid
        if anchor is not None:
            values['last_accepted_beacon'] = f'{anchor:#06x}'
        flag = self._last_flag
        if flag is None:
            return None, '', values
        values['last_flagged_uid'] = f'{flag.uid:#06x}'
        values['last_flag_verdict'] = flag.verdict
        values['last_flag_reason'] = flag.reason
        if self._now_s() - self._last_flag_time <= self.params['report_hold_s']:
            return WARN, (f'beacon {flag.uid:#06x} flagged as forged or misplaced '
                          f'({flag.verdict})'), values
        return None, '', values


def main(args=None):
    return run_node(InsBeaconNode, 'ins_beacon_node', args)


if __name__ == '__main__':
    sys.exit(main())
