"""What a photodiode receiver and the rig's photodiode share: the channel parameters
(the rig draws samples with them, the RSSI localizer inverts the channel with them),
declared from one table so both read one parameter file's values.
"""
from vlc_common.core.optical_channel import PhotodiodeConfig
from vlc_common.parameters import descriptor as _desc

_PD = PhotodiodeConfig()

#: Channel parameters: what a receiver must know to invert the channel. The RSSI
#: localizer declares the same table (companion_localizers), so both sides read one
#: parameter file's values. (name, default, descriptor); see config/photodiode_node.yaml.
CHANNEL_PARAMETERS = (
    ('pd_fov_half_angle_deg', _PD.fov_half_angle_deg, _desc('Receiver field of view '
                                                            '(half angle), deg.', 1.0, 89.0)),
    ('pd_area_m2', _PD.area_m2, _desc('Detector area, m^2.', 1e-8, 1e-2)),
    ('pd_filter_transmission', _PD.filter_transmission, _desc('Optical filter gain Ts.',
                                                              1e-3, 1.0)),
    ('pd_refractive_index', _PD.refractive_index, _desc('Concentrator refractive index n '
                                                        '(gain n^2 / sin^2 FOV).', 1.0, 3.0)),
    ('pd_responsivity_a_per_w', _PD.responsivity_a_per_w, _desc('Photodiode responsivity, '
                                                                'A/W.', 1e-3, 2.0)),
    ('lamp_optical_power_w', _PD.lamp_optical_power_w, _desc('Optical power of a lamp when '
                                                             '"on", W.', 1e-3, 1e3)),
    ('lamp_half_power_angle_deg', _PD.lamp_half_power_angle_deg,
     _desc('Lamp semi-angle at half power, deg (Lambertian order m = -ln2/ln cos).',
           1.0, 89.0)),
    ('lamp_power_sigma_rel', _PD.lamp_power_sigma_rel,
     _desc('1-sigma relative deviation of each lamp\'s actual power from the nominal (fixed '
           'per lamp, unknown to the receiver).', 0.0, 0.5)),
)



def declare_channel_parameters(node):
    """Declare :data:`CHANNEL_PARAMETERS` on ``node``; returns their values (dict)."""
    for name, default, descriptor in CHANNEL_PARAMETERS:
        node.declare_parameter(name, default, descriptor)
    return {name: node.get_parameter(name).value for name, _, _ in CHANNEL_PARAMETERS}


def photodiode_config(channel, mount, **noise):
    """PhotodiodeConfig from channel parameter values, the photodiode's mount (a
    :class:`~vlc_common.core.vehicle.PhotodiodeMount` of the vehicle file) and optional
    noise keywords (ValueError for an invalid combination).
    """
    return PhotodiodeConfig(
        mount_xyz_m=tuple(float(v) for v in mount.position_m), azimuth_deg=mount.azimuth_deg,
        elevation_deg=mount.elevation_deg,
        fov_half_angle_deg=channel['pd_fov_half_angle_deg'], area_m2=channel['pd_area_m2'],
        filter_transmission=channel['pd_filter_transmission'],
        refractive_index=channel['pd_refractive_index'],
        responsivity_a_per_w=channel['pd_responsivity_a_per_w'],
        lamp_optical_power_w=channel['lamp_optical_power_w'],
        lamp_half_power_angle_deg=channel['lamp_half_power_angle_deg'],
        lamp_power_sigma_rel=channel['lamp_power_sigma_rel'], **noise)
