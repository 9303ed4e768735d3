"""Sensors on one host, processing on another, with the shipped two-host Fast DDS profile.

Two network namespaces joined by a veth pair stand for the train's sensor computer and
processing computer (``vlc_evaluation.benchmarks.two_hosts``, the harness
``two_host_benchmark`` measures with). The sensor host runs ``stereo_camera_node`` and
``adis16488_node`` with the shipped parameter files; the processing host runs
``spot_locator_node``, ``vlc_decoder_node`` and two probes (images; IMU). Everything
talks over UDP through ``config/fastdds_two_hosts.xml`` with
``ROS_AUTOMATIC_DISCOVERY_RANGE=SUBNET`` on the test's own DDS domain; where ``tc``
accepts a token bucket, the veth is shaped to 1 Gbit/s (a train Ethernet port) behind
a NIC's default send queue, and both namespaces get the IP-reassembly settings the
deployment page prescribes for the train computers (``two_hosts.HOST_SYSCTLS``).

Skipped, saying why, where the kernel or the user may not create network namespaces
or veth pairs (unprivileged CI). Every namespace, the veth and every process are
removed by the harness, also when an assertion fails.
"""
import pathlib

import pytest

from vlc_evaluation.benchmarks import two_hosts

pytestmark = pytest.mark.graph

WS = pathlib.Path(__file__).resolve().parents[1]
PROFILE = WS / 'config' / 'fastdds_two_hosts.xml'
DURATION_S = 5.0


@pytest.fixture(scope='module')
def two_host_link():
    """The link to emulate ('1gbit' when tc takes a tbf qdisc), or skip without netns."""
    reason = two_hosts.netns_unavailable()
    if reason:
        pytest.skip(f'two-host test needs network namespaces and veth pairs: {reason}')
    return 'none' if two_hosts.shaping_unavailable('1gbit') else '1gbit'


def test_processing_host_receives_every_image_and_the_imu(ros_env, tmp_path, two_host_link):
    result = two_hosts.run_stream(PROFILE, duration_s=DURATION_S, link=two_host_link,
                                  processing=True, log_dir=tmp_path,
                                  domain_id=int(ros_env['ROS_DOMAIN_ID']), startup_timeout_s=30.0)
    print(f'two hosts, link {two_host_link}: images {result["images"]}, IMU '
          f'{result["imu"]}, outputs {result["outputs"]}, counters {result["counters"]}')
    logs = '\n'.join(f'--- {name}\n{text[-1500:]}' for name, text in result['logs'].items())
    context = (f'link {result["link"]}; counters {result["counters"]}; '
               f'exit codes {result["exit_codes"]}\n{logs}')
    # every process ran to its end: the sensors published their whole duration
    assert result['exit_codes']['stereo_camera_node'] == 0, context
    assert result['exit_codes']['adis16488_node'] == 0, context
    assert result['exit_codes']['probe_images'] == 0, context
    assert result['exit_codes']['probe_imu'] == 0, context
    # honest transport: no process mapped a Fast DDS shared-memory segment, and the
    # images went through the processing host's interface
    assert result['shm'] == [], context
    # the train computers' kernel settings (docs/arch/deployment.md) were in force
    for key, value in two_hosts.HOST_SYSCTLS.items():
        assert result['sysctl'][key] == value, context
    images = result['images']
    assert images is not None, context
    assert images['sent'] == 2 * round(DURATION_S * two_hosts.FPS)
    received_bytes = result['counters']['processing']['rx_bytes']
    assert received_bytes > images['sent'] * two_hosts.IMAGE_BYTES, context
    # every image of the stereo stream arrived on the processing host, once
    assert images['lost'] == 0, f'missing frames {images["missing_first"]}; {context}'
    assert images['received'] == images['sent']
    assert images['duplicates'] == 0
    # the IMU stream (best effort, sensor-data QoS, as the node publishes it) arrived:
    # a few samples may go (docs/arch/deployment.md), not the stream
    imu = result['imu']
    assert imu is not None, context
    assert imu['sent'] == round(DURATION_S * two_hosts.IMU_RATE_HZ)
    assert imu['received'] >= 0.95 * imu['sent'], f'IMU {imu}; {context}'
    # the processing nodes on the other host took the images and published their outputs
    assert result['outputs']['/spots/pairs'] > 0, context
    assert result['outputs']['/vlc/lamps'] > 0, context
