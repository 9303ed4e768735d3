"""``two_host_benchmark``: sensors on one host, processing on another, over Fast DDS UDP.

Two Linux network namespaces stand for the two computers of a train: the **sensor
host** runs ``stereo_camera_node`` and ``adis16488_node`` (the shipped ``rig.yaml`` and
node parameter files), the **processing host** runs two probes (one takes both image
topics, one the IMU, each counting every message and measuring its latency) and, with
``--processing``, ``spot_locator_node`` and ``vlc_decoder_node``. The namespaces are
joined by a veth pair on a private /24 (``10.77.0.1`` sensor, ``10.77.0.2``
processing); ``--link 1gbit`` puts a ``tc tbf`` qdisc on both ends that sends at
1 Gbit/s (bursts of at most 10 frames) behind a queue of 1000 full frames (1.5 MB), as
a train Ethernet port with its default txqueuelen would (``netem`` is not in every
kernel, ``tbf`` is). Every process runs with ``ip netns exec`` on a DDS domain of its
own, ``ROS_AUTOMATIC_DISCOVERY_RANGE=SUBNET`` and the Fast DDS profile under test; the
profiles tried carry a UDPv4 transport only, so nothing can travel through shared
memory (``/dev/shm`` is common to both namespaces): the harness records every Fast DDS
shared-memory file a process of the run maps (none may).

Figures per run: images sent (``ceil(duration · fps)`` per camera: the camera publishes
every frame with ``t < duration_s`` and exits 0; a run whose camera has not finished is
flagged), the rate the camera achieved, received (distinct frame indices), lost;
latency = the probe's callback time − the DDS source timestamp (the publisher's
``write`` on the sensor host; both namespaces share one kernel clock), median / p99 /
max, and the DDS reception timestamp − source timestamp (transport only, without the
probe's executor); IMU samples received (best effort, sensor-data QoS); the drop
counters of both namespaces and the machine's load average.

Usage (as root, after ``source scripts/env.sh``)::

    two_host_benchmark [--profiles udp_defaults,udp_buffers,...|all] [--runs 3]
                       [--duration 10] [--link none|1gbit] [--processing]
                       [--queue-frames 1000] [--kernel-defaults]
                       [--profile-file NAME=path.xml ...] [--keep-logs]

A profile name is one of :data:`PROFILES` (generated into a temporary directory),
``shipped`` (``config/fastdds_two_hosts.xml`` of the workspace, ``$VLC_WS``),
``shipped_unicast`` (the same without the image readers' multicast locators),
``shipped_sndbuf4m`` (with the 4 MB send buffer it had before 2026-12-06) or
``shipped_hb20`` (with the image writers' 20 ms heartbeat it had before then).
``--queue-frames N`` shortens or lengthens the shaped link's send queue (a stress
test), ``--kernel-defaults`` leaves out the IP-reassembly settings
(:data:`HOST_SYSCTLS`) the harness otherwise applies in both namespaces.
Needs root (CAP_SYS_ADMIN, CAP_NET_ADMIN) for ``ip netns``; prints why and exits 2
without it. Results and why the shipped profile is what it is: docs/arch/deployment.md.

The harness (:class:`TwoHosts`, :func:`run_stream`) is also what
``tests/test_two_hosts.py`` uses.
"""
import argparse
import contextlib
import itertools
import json
import math
import os
import pathlib
import re
import shutil
import signal
import struct
import subprocess
import sys
import tempfile
import time

import numpy as np

from vlc_common.process import logged_output, start_logged

SENSOR, PROCESSING = 'sensor', 'processing'
SUBNET = '10.77.0'
ADDRESSES = {SENSOR: f'{SUBNET}.1', PROCESSING: f'{SUBNET}.2'}
IMAGE_TOPICS = ('/stereo/left/image_raw', '/stereo/right/image_raw')
IMU_TOPIC = '/imu/data_raw'
OUTPUT_TOPICS = ('/spots/pairs', '/vlc/lamps')
IMAGE_BYTES = 1280 * 720     # one mono8 frame's payload
EPOCH_S = 1704067200.0        # rig.yaml epoch_s: stamps are epoch + k / rate
FPS = 30.0
IMU_RATE_HZ = 400.0
FRAME_B = 1514               # a full Ethernet frame
TBF_BURST_B = 10 * FRAME_B
QUEUE_FRAMES = 1000          # a NIC's default txqueuelen
TBF_LIMIT_B = QUEUE_FRAMES * FRAME_B
#: kernel settings of both train computers (docs/arch/deployment.md), applied in each
#: namespace (they are per network namespace). IP reassembly: a 64 kB datagram whose
#: fragment was lost holds its reassembly memory until ``ipfrag_time``; with the defaults
#: (30 s, 4 MB) about 64 such datagrams fill it and every later fragmented datagram (every
#: image) is dropped for up to 30 s, while the writer's repairs keep the link saturated.
HOST_SYSCTLS = {'net.ipv4.ipfrag_time': '3', 'net.ipv4.ipfrag_high_thresh': '134217728'}
SHIPPED_PROFILE = pathlib.Path('config') / 'fastdds_two_hosts.xml'

# ----------------------------------------------------------------------------- profiles
_HEAD = ('<?xml version="1.0" encoding="UTF-8" ?>\n'
         '<profiles xmlns="http://www.eprosima.com/XMLSchemas/fastRTPS_Profiles">\n')


def _udp_profile(transport='', writer='', reader='', participant_extra=''):
    """A participant with one UDPv4 transport (no SHM) and optional endpoint defaults."""
    xml = (_HEAD + '  <transport_descriptors>\n    <transport_descriptor>\n'
           '      <transport_id>udp</transport_id>\n      <type>UDPv4</type>\n'
           f'{transport}    </transport_descriptor>\n  </transport_descriptors>\n'
           '  <participant profile_name="two_hosts" is_default_profile="true">\n'
           f'    <rtps>\n{participant_extra}'
           '      <userTransports><transport_id>udp</transport_id></userTransports>\n'
           '      <useBuiltinTransports>false</useBuiltinTransports>\n'
           '    </rtps>\n  </participant>\n')
    if writer:
        xml += ('  <data_writer profile_name="two_hosts_writer" is_default_profile="true">\n'
                f'{writer}  </data_writer>\n')
    if reader:
        xml += ('  <data_reader profile_name="two_hosts_reader" is_default_profile="true">\n'
                f'{reader}  </data_reader>\n')
    return xml + '</profiles>\n'


_BUFFERS = ('      <sendBufferSize>4194304</sendBufferSize>\n'
            '      <receiveBufferSize>4194304</receiveBufferSize>\n')
_FAST_HEARTBEAT = ('    <times>\n      <heartbeatPeriod><sec>0</sec><nanosec>20000000</nanosec>'
                   '</heartbeatPeriod>\n      <nackResponseDelay><sec>0</sec><nanosec>0'
                   '</nanosec></nackResponseDelay>\n    </times>\n')
_FAST_ACKNACK = ('    <times>\n      <heartbeatResponseDelay><sec>0</sec><nanosec>0</nanosec>'
                 '</heartbeatResponseDelay>\n    </times>\n')


def _flow_controller(max_bytes, period_ms):
    return ('      <flow_controller_descriptor_list>\n        <flow_controller_descriptor>\n'
            '          <name>link</name>\n          <scheduler>FIFO</scheduler>\n'
            f'          <max_bytes_per_period>{max_bytes}</max_bytes_per_period>\n'
            f'          <period_ms>{period_ms}</period_ms>\n'
            '        </flow_controller_descriptor>\n'
            '      </flow_controller_descriptor_list>\n')


_ASYNC = ('    <qos>\n      <publishMode>\n        <kind>ASYNCHRONOUS</kind>\n'
          '        <flow_controller_name>link</flow_controller_name>\n'
          '      </publishMode>\n    </qos>\n')


_RT_RECEPTION = ('      <default_reception_threads>\n'
                 '        <scheduling_policy>1</scheduling_policy>\n'
                 '        <priority>20</priority>\n'
                 '      </default_reception_threads>\n')

#: name -> (description, profile XML, extra environment)
PROFILES = {
    'udp_defaults': (
        'UDPv4 only, Fast DDS defaults (64 kB messages, OS-default socket buffers)',
        _udp_profile(), {}),
    'udp_buffers': (
        'UDPv4, socket send/receive buffers 4 MB',
        _udp_profile(_BUFFERS), {}),
    'udp_buffers_hb': (
        'UDPv4, 4 MB buffers, writer heartbeat 20 ms, immediate NACK response',
        _udp_profile(_BUFFERS, _FAST_HEARTBEAT, _FAST_ACKNACK), {}),
    'udp_buffers_hb_rt': (
        'UDPv4, 4 MB buffers, heartbeat 20 ms, reception threads SCHED_FIFO priority 20',
        _udp_profile(_BUFFERS + _RT_RECEPTION, _FAST_HEARTBEAT, _FAST_ACKNACK), {}),
    'udp_buffers_rt': (
        'UDPv4, 4 MB buffers, reception threads SCHED_FIFO priority 20',
        _udp_profile(_BUFFERS + _RT_RECEPTION), {}),
    'udp_mtu1472': (
        'as udp_buffers_hb_rt, RTPS messages of at most 1472 bytes (no IP fragmentation)',
        _udp_profile(_BUFFERS.replace('      <send', '      <maxMessageSize>1472'
                                      '</maxMessageSize>\n      <send', 1) + _RT_RECEPTION,
                     _FAST_HEARTBEAT, _FAST_ACKNACK), {}),
    'async_fc800': (
        'as udp_buffers_hb_rt, writers asynchronous behind a flow controller of 1 MB per '
        '10 ms (800 Mbit/s); RMW_FASTRTPS_PUBLICATION_MODE=AUTO',
        _udp_profile(_BUFFERS + _RT_RECEPTION, _ASYNC + _FAST_HEARTBEAT, _FAST_ACKNACK,
                     participant_extra=_flow_controller(1000000, 10)),
        {'RMW_FASTRTPS_PUBLICATION_MODE': 'AUTO'}),
    'async': (
        'as udp_buffers_hb_rt, writers asynchronous (no flow controller); '
        'RMW_FASTRTPS_PUBLICATION_MODE=ASYNCHRONOUS',
        _udp_profile(_BUFFERS + _RT_RECEPTION, _FAST_HEARTBEAT, _FAST_ACKNACK),
        {'RMW_FASTRTPS_PUBLICATION_MODE': 'ASYNCHRONOUS'}),
}


def _without(element):
    return lambda xml: re.sub(rf'\s*<{element}>.*?</{element}>', '', xml, flags=re.S)


def _with_send_buffer(size):
    return lambda xml: re.sub(r'<sendBufferSize>\d+</sendBufferSize>',
                              f'<sendBufferSize>{size}</sendBufferSize>', xml)


def _with_writer_times(xml):
    writers = ''.join(f'  <data_writer profile_name="{topic}">\n{_FAST_HEARTBEAT}'
                      '  </data_writer>\n' for topic in IMAGE_TOPICS)
    return xml.replace('</profiles>', writers + '</profiles>')


#: the shipped profile and variants of it: name -> (transform of its XML, text)
SHIPPED_VARIANTS = {
    'shipped': (None, 'config/fastdds_two_hosts.xml (shipped)'),
    'shipped_unicast': (_without('multicastLocatorList'), 'the shipped profile without the '
                        'image readers\' multicast locators (each reader its own unicast copy)'),
    'shipped_sndbuf4m': (_with_send_buffer(4194304), 'the shipped profile with a 4 MB send '
                         'buffer (the profile before 2026-12-06: more than the NIC queue)'),
    'shipped_hb20': (_with_writer_times, 'the shipped profile with the image writers\' '
                     'heartbeat 20 ms and NACK response 0 (the profile before 2026-12-06)'),
}
DEFAULT_PROFILES = ('udp_defaults', 'udp_buffers', 'udp_buffers_hb', 'udp_buffers_rt', 'async',
                    'shipped_unicast', 'shipped')


def profile_paths(names, tmpdir, workspace=None, extra=()):
    """``{name: (description, path, env)}`` for the requested profiles."""
    out = {}
    for name in names:
        if name in SHIPPED_VARIANTS:
            path = pathlib.Path(workspace or os.environ.get('VLC_WS', '.')) / SHIPPED_PROFILE
            if not path.exists():
                raise FileNotFoundError(f'{path} (set VLC_WS or run from the workspace)')
            if name == 'shipped':
                out[name] = ('config/fastdds_two_hosts.xml (shipped)', path, {})
                continue
            transform, description = SHIPPED_VARIANTS[name]
            variant = pathlib.Path(tmpdir) / f'{name}.xml'
            variant.write_text(transform(path.read_text()))
            out[name] = (description, variant, {})
            continue
        description, xml, env = PROFILES[name]
        path = pathlib.Path(tmpdir) / f'{name}.xml'
        path.write_text(xml)
        out[name] = (description, path, env)
    for item in extra:
        name, _, path = item.partition('=')
        out[name] = (f'{path} (given)', pathlib.Path(path), {})
    return out


# ----------------------------------------------------------------------------- namespaces
def _ip(*args, check=True):
    return subprocess.run(['ip', *args], check=check, capture_output=True, text=True,
                          timeout=20)


def netns_unavailable():
    """Why two network namespaces cannot be made here (``None`` if they can)."""
    if shutil.which('ip') is None:
        return 'iproute2 (`ip`) is not installed'
    name = f'vlc2h-check-{os.getpid()}'
    try:
        result = _ip('netns', 'add', name, check=False)
    except (OSError, subprocess.SubprocessError) as exc:
        return f'`ip netns add` failed: {exc}'
    if result.returncode != 0:
        return f'`ip netns add` refused (root/CAP_SYS_ADMIN needed): {result.stderr.strip()}'
    try:
        veth = _ip('-n', name, 'link', 'add', 'v2hchk0', 'type', 'veth', 'peer', 'name',
                   'v2hchk1', check=False)
        if veth.returncode != 0:
            return f'`ip link add ... type veth` refused: {veth.stderr.strip()}'
    finally:
        _ip('netns', 'del', name, check=False)
    return None


def remove_stale_namespaces():
    """Delete the namespaces of harness runs whose process is gone (killed mid-run)."""
    listing = _ip('netns', 'list', check=False).stdout
    for name in re.findall(r'^(vlc2h-(?:sensor|proc)-(\d+)x\d+)', listing, flags=re.M):
        ns, pid = name[0], int(name[1])
        if pathlib.Path(f'/proc/{pid}').exists():
            continue
        for orphan in _ip('netns', 'pids', ns, check=False).stdout.split():
            with contextlib.suppress(ProcessLookupError, ValueError):
                os.kill(int(orphan), signal.SIGKILL)
        _ip('netns', 'del', ns, check=False)


def shaping_unavailable(rate='1gbit'):
    """Why a veth cannot be shaped with a tbf qdisc here (``None`` if it can)."""
    name = f'vlc2h-tbf-{os.getpid()}'
    try:
        _ip('netns', 'add', name)
        _ip('-n', name, 'link', 'add', 'v2htbf0', 'type', 'veth', 'peer', 'name', 'v2htbf1')
        result = subprocess.run(['ip', 'netns', 'exec', name, 'tc', 'qdisc', 'add', 'dev',
                                 'v2htbf0', 'root', 'tbf', 'rate', rate, 'burst',
                                 str(TBF_BURST_B), 'limit', str(TBF_LIMIT_B)],
                                capture_output=True, text=True, timeout=20)
        return None if result.returncode == 0 else f'tc refused tbf: {result.stderr.strip()}'
    except (OSError, subprocess.SubprocessError) as exc:
        return f'{exc}'
    finally:
        _ip('netns', 'del', name, check=False)


def _in_namespace(ns, cmd):
    """Run ``cmd`` inside network namespace ``ns``; a refusal raises RuntimeError."""
    result = subprocess.run(['ip', 'netns', 'exec', ns, *cmd], capture_output=True,
                            text=True, timeout=20)
    if result.returncode != 0:
        raise RuntimeError(f'`{" ".join(cmd)}` refused in {ns}: {result.stderr.strip()}')


class TwoHosts:
    """Two network namespaces joined by a veth pair; processes started in either.

    Use as a context manager: the namespaces (and with them the veth pair and its
    qdiscs) are deleted on exit, every process started with :meth:`start` is stopped
    (SIGINT, then SIGKILL), any process still inside a namespace is killed by its id,
    and the Fast DDS shared-memory files any of them mapped are removed.
    """

    _serial = itertools.count()

    def __init__(self, link='none', log_dir=None, queue_frames=QUEUE_FRAMES,
                 host_sysctls=HOST_SYSCTLS):
        tag = f'{os.getpid()}x{next(self._serial)}'
        self.ns = {SENSOR: f'vlc2h-sensor-{tag}', PROCESSING: f'vlc2h-proc-{tag}'}
        # interface names are at most 15 characters
        self.ifname = {SENSOR: f'v2hs{tag}'[:15], PROCESSING: f'v2hp{tag}'[:15]}
        self.link = link
        self.queue_frames = queue_frames
        self.host_sysctls = dict(host_sysctls or {})
        self.log_dir = pathlib.Path(log_dir or tempfile.mkdtemp(prefix='two_hosts_'))
        self.log_dir.mkdir(parents=True, exist_ok=True)
        self.procs = []
        self.shm_seen = set()
        self._created = []

    # -------------------------------------------------------------- set-up
    def __enter__(self):
        try:
            self._setup()
        except BaseException:
            self.close()
            raise
        return self

    def __exit__(self, *exc):
        self.close()

    def _setup(self):
        remove_stale_namespaces()
        for host in (SENSOR, PROCESSING):
            _ip('netns', 'add', self.ns[host])
            self._created.append(self.ns[host])
        s, p = self.ifname[SENSOR], self.ifname[PROCESSING]
        _ip('-n', self.ns[SENSOR], 'link', 'add', s, 'type', 'veth', 'peer', 'name', p,
            'netns', self.ns[PROCESSING])
        for host in (SENSOR, PROCESSING):
            ns, dev = self.ns[host], self.ifname[host]
            _ip('-n', ns, 'link', 'set', 'lo', 'up')
            _ip('-n', ns, 'addr', 'add', f'{ADDRESSES[host]}/24', 'dev', dev)
            _ip('-n', ns, 'link', 'set', dev, 'up')
            # SPDP discovery goes to 239.255.0.1: route multicast out of the veth
            _ip('-n', ns, 'route', 'add', '224.0.0.0/4', 'dev', dev)
            for key, value in self.host_sysctls.items():
                _in_namespace(ns, ['sysctl', '-w', f'{key}={value}'])
            if self.link != 'none':
                self._shape(ns, dev)

    def _shape(self, ns, dev):
        rate = self.link
        # a token bucket at the line rate: bursts of at most 10 full frames, and a queue
        # of queue_frames frames (default 1000 = 1.5 MB, a NIC's default txqueuelen)
        # before packets are dropped
        _in_namespace(ns, ['tc', 'qdisc', 'add', 'dev', dev, 'root', 'tbf', 'rate', rate,
                           'burst', str(TBF_BURST_B),
                           'limit', str(self.queue_frames * FRAME_B)])

    def sysctl(self, host, key):
        result = subprocess.run(['ip', 'netns', 'exec', self.ns[host], 'sysctl', '-n', key],
                                capture_output=True, text=True, timeout=20)
        return result.stdout.strip()

    def counters(self):
        """Drop counters of both hosts: qdisc drops, UDP buffer errors, IP reassembly."""
        out = {}
        for host in (SENSOR, PROCESSING):
            ns, dev = self.ns[host], self.ifname[host]
            qdisc = subprocess.run(['ip', 'netns', 'exec', ns, 'tc', '-s', 'qdisc', 'show',
                                    'dev', dev], capture_output=True, text=True,
                                   timeout=20).stdout
            drops = sum(int(n) for n in re.findall(r'dropped (\d+)', qdisc))
            snmp = subprocess.run(['ip', 'netns', 'exec', ns, 'cat', '/proc/net/snmp'],
                                  capture_output=True, text=True, timeout=20).stdout
            values = _snmp(snmp)
            link = subprocess.run(['ip', '-n', ns, '-s', '-j', 'link', 'show', dev],
                                  capture_output=True, text=True, timeout=20).stdout
            stats = json.loads(link)[0]['stats64'] if link.strip() else {}
            out[host] = {'rx_bytes': stats.get('rx', {}).get('bytes', 0),
                         'tx_bytes': stats.get('tx', {}).get('bytes', 0),
                         'qdisc_dropped': drops,
                         'udp_rcvbuf_errors': values.get(('Udp', 'RcvbufErrors'), 0),
                         'udp_sndbuf_errors': values.get(('Udp', 'SndbufErrors'), 0),
                         'ip_reasm_fails': values.get(('Ip', 'ReasmFails'), 0)}
        return out

    def describe_link(self):
        out = []
        for host in (SENSOR, PROCESSING):
            qdisc = subprocess.run(['ip', 'netns', 'exec', self.ns[host], 'tc', 'qdisc',
                                    'show', 'dev', self.ifname[host]],
                                   capture_output=True, text=True, timeout=20).stdout.strip()
            out.append(f'{host} {ADDRESSES[host]} {self.ifname[host]}: {qdisc}')
        return '; '.join(out)

    # -------------------------------------------------------------- processes
    def start(self, host, cmd, env, name):
        """Start ``cmd`` in ``host``'s namespace (own process group, log in log_dir)."""
        proc = start_logged(['ip', 'netns', 'exec', self.ns[host], *cmd],
                            self.log_dir / f'{name}.log', env)
        proc.name, proc.host = name, host
        self.procs.append(proc)
        return proc

    output = staticmethod(logged_output)

    def note_shared_memory(self):
        """Record the Fast DDS shared-memory files any live process of the run maps."""
        for pid in self._pids():
            with contextlib.suppress(OSError):
                maps = pathlib.Path(f'/proc/{pid}/maps').read_text()
                for line in maps.splitlines():
                    if '/dev/shm/' in line and 'fastrtps' in line:
                        self.shm_seen.add(line.split()[-1])

    def _pids(self):
        pids = {proc.pid for proc in self.procs if proc.poll() is None}
        for ns in self._created:
            result = _ip('netns', 'pids', ns, check=False)
            pids.update(int(p) for p in result.stdout.split() if p.isdigit())
        return pids

    @staticmethod
    def stop(proc, timeout=10.0):
        if proc.poll() is None:
            with contextlib.suppress(ProcessLookupError):
                os.killpg(proc.pid, signal.SIGINT)
            try:
                proc.wait(timeout)
            except subprocess.TimeoutExpired:
                with contextlib.suppress(ProcessLookupError):
                    os.killpg(proc.pid, signal.SIGKILL)
                proc.wait(5)
        return proc.returncode

    def close(self):
        """Stop every process, delete the namespaces, remove SHM files they mapped."""
        with contextlib.suppress(Exception):
            self.note_shared_memory()
        for proc in self.procs:
            with contextlib.suppress(Exception):
                self.stop(proc)
        for ns in self._created:
            # anything still inside one of our namespaces is ours: kill it by its id
            result = _ip('netns', 'pids', ns, check=False)
            for pid in (int(p) for p in result.stdout.split() if p.isdigit()):
                with contextlib.suppress(ProcessLookupError):
                    os.kill(pid, signal.SIGKILL)
        for ns in reversed(self._created):
            _ip('netns', 'del', ns, check=False)
        self._created = []
        for proc in self.procs:
            proc.log.close()
        _remove_unused_shm(self.shm_seen)


def _remove_unused_shm(paths):
    """Unlink Fast DDS shared-memory files (and their lock/semaphore companions) that
    our processes mapped and no live process maps any more.
    """
    if not paths:
        return
    in_use = set()
    for maps in pathlib.Path('/proc').glob('[0-9]*/maps'):
        with contextlib.suppress(OSError):
            in_use.update(line.split()[-1] for line in maps.read_text().splitlines()
                          if '/dev/shm/fastrtps' in line)
    for path in set(paths) - in_use:
        name = pathlib.Path(path).name
        for victim in (path, f'{path}_el', f'/dev/shm/sem.{name}_mutex'):
            pathlib.Path(victim).unlink(missing_ok=True)


def _snmp(text):
    """``{(protocol, counter): value}`` of a /proc/net/snmp text."""
    lines = text.splitlines()
    out = {}
    for names, values in zip(lines[::2], lines[1::2]):
        proto, names = names.split(':', 1)
        for name, value in zip(names.split(), values.split(':', 1)[1].split()):
            with contextlib.suppress(ValueError):
                out[(proto, name)] = int(value)
    return out


# ----------------------------------------------------------------------------- the run
def ros_environment(profile_path, domain_id, extra=None):
    """The environment of every process of a run (keeps PATH, venv, LD_LIBRARY_PATH)."""
    env = dict(os.environ)
    for key in ('ROS_LOCALHOST_ONLY', 'FASTDDS_BUILTIN_TRANSPORTS', 'ROS_STATIC_PEERS',
                'RMW_FASTRTPS_PUBLICATION_MODE', 'RMW_FASTRTPS_USE_QOS_FROM_XML'):
        env.pop(key, None)
    env.update({'ROS_DOMAIN_ID': str(domain_id), 'ROS_AUTOMATIC_DISCOVERY_RANGE': 'SUBNET',
                'FASTRTPS_DEFAULT_PROFILES_FILE': str(profile_path),
                'PYTHONUNBUFFERED': '1'})
    # the probe runs this very module: put its package first on the path
    package_root = str(pathlib.Path(__file__).resolve().parents[2])
    env['PYTHONPATH'] = os.pathsep.join(
        [package_root] + [p for p in env.get('PYTHONPATH', '').split(os.pathsep) if p])
    env.update(extra or {})
    return env


def _executable(package, name):
    from ament_index_python.packages import get_package_prefix
    path = pathlib.Path(get_package_prefix(package)) / 'lib' / package / name
    if not path.exists():
        raise FileNotFoundError(f'{path} is not installed: run `make build`')
    return path


def _config(package, name):
    from ament_index_python.packages import get_package_share_directory
    return pathlib.Path(get_package_share_directory(package)) / 'config' / name


def sensor_commands(duration_s, image_subscribers, speed_kmh=60.0):
    """stereo_camera_node and adis16488_node with the shipped parameter files."""
    rig = _config('vlc_stereo_camera', 'rig.yaml')
    scenario = ['-p', f'speed_kmh:={speed_kmh}']
    camera = [_executable('vlc_stereo_camera', 'stereo_camera_node'), '--ros-args',
              '--params-file', rig, '--params-file',
              _config('vlc_stereo_camera', 'stereo_camera_node.yaml'), *scenario,
              '-p', f'duration_s:={duration_s}',
              '-p', f'wait_for_subscribers:={image_subscribers}']
    # The IMU paces itself (follow_clock false) from its first subscriber on: following
    # the camera's /clock, which ends with the last frame, it would stop a few samples
    # short of duration_s and never exit (the count of samples sent is its exit log).
    imu = [_executable('vlc_stereo_camera', 'adis16488_node'), '--ros-args',
           '--params-file', rig, '--params-file',
           _config('vlc_stereo_camera', 'adis16488_node.yaml'), *scenario,
           '-p', f'duration_s:={duration_s}', '-p', 'wait_for_subscribers:=1',
           '-p', 'follow_clock:=false']
    return {'stereo_camera_node': camera, 'adis16488_node': imu}


def processing_commands():
    """spot_locator_node and vlc_decoder_node with their shipped parameter files."""
    return {
        'spot_locator_node': [_executable('spot_locator', 'spot_locator_node'), '--ros-args',
                              '--params-file', _config('spot_locator', 'spot_locator_node.yaml')],
        'vlc_decoder_node': [_executable('vlc_decoder', 'vlc_decoder_node'), '--ros-args',
                             '--params-file', _config('vlc_decoder', 'vlc_decoder_node.yaml')],
    }


def _domain_id():
    # The namespaces keep a run's UDP traffic to itself whatever the domain; the domain
    # still names the ports and, were shared memory on, the /dev/shm port files, so take
    # one from the pid as conftest does (tests pass their ros_env domain).
    return 1 + os.getpid() % 119


def run_stream(profile_path, duration_s=5.0, link='none', processing=False, log_dir=None,
               profile_env=None, domain_id=None, startup_timeout_s=60.0,
               queue_frames=QUEUE_FRAMES, host_sysctls=HOST_SYSCTLS):
    """One run: the sensors stream ``duration_s`` to the probes on the other host.

    ``queue_frames``: the sensor end's send queue (frames) behind the link;
    ``host_sysctls``: kernel settings applied in both namespaces (``{}``: the kernel's).

    Two probe processes on the processing host, as the graph has them: one takes both
    image topics (and the processing outputs), one the IMU (the compensator's topic, in
    a process of its own there too), so each has its own sockets. Returns a dict:
    ``images`` and ``imu`` summaries (:func:`summarise`), ``outputs`` (messages per
    processing output topic), ``exit_codes``, ``shm`` (Fast DDS shared-memory files
    mapped by any process of the run), ``counters`` (:meth:`TwoHosts.counters`),
    ``link``, ``sysctl``, ``logs`` and ``log_dir``.
    """
    domain_id = _domain_id() if domain_id is None else domain_id
    env = ros_environment(profile_path, domain_id, profile_env)
    expect = math.ceil(duration_s * FPS - 1e-9)
    expect_imu = math.ceil(duration_s * IMU_RATE_HZ - 1e-9)
    timeout = startup_timeout_s + 3 * duration_s + 20
    with TwoHosts(link=link, log_dir=log_dir, queue_frames=queue_frames,
                  host_sysctls=host_sysctls) as hosts:
        out = {role: hosts.log_dir / f'probe_{role}.json' for role in ('images', 'imu')}
        module = [sys.executable, '-m', 'vlc_evaluation.benchmarks.two_hosts', 'probe']
        probes = [
            hosts.start(PROCESSING, [*module, '--role', 'images', '--out', out['images'],
                                     '--expect', expect, '--timeout', timeout,
                                     *(['--outputs'] if processing else [])],
                        env, 'probe_images'),
            hosts.start(PROCESSING, [*module, '--role', 'imu', '--out', out['imu'],
                                     '--expect', expect_imu, '--timeout', timeout,
                                     '--idle', 3.0],
                        env, 'probe_imu')]
        image_subscribers = 1
        if processing:
            for name, cmd in processing_commands().items():
                hosts.start(PROCESSING, cmd, env, name)
            image_subscribers += 2
        sensors = {name: hosts.start(SENSOR, cmd, env, name) for name, cmd in
                   sensor_commands(duration_s, image_subscribers).items()}
        camera = sensors['stereo_camera_node']
        deadline = time.monotonic() + timeout
        next_shm_check = 0.0
        while (camera.poll() is None and any(p.poll() is None for p in probes)
               and time.monotonic() < deadline):
            if time.monotonic() > next_shm_check:
                hosts.note_shared_memory()
                next_shm_check = time.monotonic() + 1.0
            time.sleep(0.1)
        hosts.note_shared_memory()
        # The camera exits once every frame is published and acknowledged (or 2 s
        # passed); the probes end a moment after their last message.
        for probe in probes:
            with contextlib.suppress(subprocess.TimeoutExpired):
                probe.wait(10.0)
        exit_codes = {proc.name: proc.poll() for proc in hosts.procs}
        for proc in hosts.procs:
            hosts.stop(proc)
        logs = {proc.name: hosts.output(proc) for proc in hosts.procs}
        link_text = hosts.describe_link()
        counters = hosts.counters()
        buffers = {key: hosts.sysctl(PROCESSING, key)
                   for key in ('net.core.rmem_max', 'net.core.wmem_max', *HOST_SYSCTLS)}
        shm = sorted(hosts.shm_seen)
    data = {role: json.loads(path.read_text()) if path.exists() else None
            for role, path in out.items()}
    imu_sent = _imu_published(logs.get('adis16488_node', '')) or expect_imu
    images = data['images']
    probe_end = {role: d.get('end') if d else None for role, d in data.items()}
    return {
        'images': summarise(images, IMAGE_TOPICS, expect) if images else None,
        'imu': summarise(data['imu'], (IMU_TOPIC,), imu_sent) if data['imu'] else None,
        'outputs': {t: len(images['topics'].get(t, {}).get('index', []))
                    for t in OUTPUT_TOPICS} if images else {},
        'exit_codes': exit_codes, 'shm': shm, 'counters': counters, 'link': link_text,
        'sysctl': buffers, 'log_dir': str(hosts.log_dir), 'logs': logs,
        'domain_id': domain_id, 'load': os.getloadavg()[0], 'probe_end': probe_end,
    }


def _imu_published(log):
    for line in log.splitlines():
        if 'duration_s reached:' in line:
            with contextlib.suppress(ValueError, IndexError):
                return int(line.split('duration_s reached:')[1].split()[0])
    return None


def summarise(data, topics, sent_per_topic):
    """Sent, received, lost and latency (ms) over ``topics`` of a probe's record."""
    sent = received = duplicates = 0
    delivery, transport, missing, rates = [], [], {}, []
    for topic in topics:
        rec = data['topics'].get(topic, {'index': [], 'source_ns': [], 'received_ns': [],
                                         'callback_ns': []})
        index = np.asarray(rec['index'], dtype=np.int64)
        unique = set(index.tolist())
        sent += sent_per_topic
        got = len(unique & set(range(sent_per_topic)))
        received += got
        duplicates += len(index) - len(unique)
        missing[topic] = sorted(set(range(sent_per_topic)) - unique)[:20]
        source = np.asarray(rec['source_ns'], dtype=np.float64)
        if len(index) > 1 and source.max() > source.min():
            # messages per second the writer achieved (source stamps of its writes)
            first, last = np.argmin(index), np.argmax(index)
            rates.append((index[last] - index[first]) * 1e9 / (source[last] - source[first]))
        delivery += list((np.asarray(rec['callback_ns'], dtype=np.float64) - source) / 1e6)
        transport += list((np.asarray(rec['received_ns'], dtype=np.float64) - source) / 1e6)

    def stats(values):
        if not values:
            return {'median': float('nan'), 'p99': float('nan'), 'max': float('nan')}
        v = np.asarray(values)
        return {'median': float(np.median(v)), 'p99': float(np.percentile(v, 99)),
                'max': float(v.max())}
    return {'sent': sent, 'received': received, 'lost': sent - received,
            'duplicates': duplicates, 'missing_first': missing,
            'latency_ms': stats(delivery), 'transport_ms': stats(transport),
            'publish_rate_hz': float(min(rates)) if rates else float('nan')}


# ----------------------------------------------------------------------------- the probe
def _stamp_index(raw, rate_hz):
    """Sample index of a serialized message whose first field is a std_msgs/Header."""
    sec, nanosec = struct.unpack_from('<iI', raw, 4)   # after the 4-byte CDR header
    return round((sec - EPOCH_S + nanosec * 1e-9) * rate_hz)


def probe_main(args):
    """Run inside the processing namespace: record every image or IMU sample (+ outputs)."""
    import rclpy
    from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
    from rclpy.qos import QoSProfile, ReliabilityPolicy, qos_profile_sensor_data
    from sensor_msgs.msg import Image, Imu, PointCloud2

    rclpy.init(args=[])
    node = rclpy.create_node(f'two_host_probe_{args.role}', start_parameter_services=False,
                             enable_rosout=False)
    records, seen = {}, {}
    last_ns = [None]

    def recorder(topic, rate_hz):
        rec = records[topic] = {'index': [], 'source_ns': [], 'received_ns': [],
                                'callback_ns': []}
        distinct = seen[topic] = set()

        def callback(raw, info):
            now = last_ns[0] = time.time_ns()
            index = _stamp_index(raw, rate_hz) if rate_hz else len(rec['index'])
            distinct.add(index)
            rec['index'].append(index)
            rec['source_ns'].append(info['source_timestamp'])
            rec['received_ns'].append(info['received_timestamp'])
            rec['callback_ns'].append(now)
        return callback

    # Deep reader histories, so that a probe late by a few messages does not drop what
    # the network delivered: the count measures the link, not the probe.
    if args.role == 'images':
        counted = IMAGE_TOPICS
        qos, msg_type, rate = (QoSProfile(depth=60, reliability=ReliabilityPolicy.RELIABLE),
                               Image, FPS)
    else:
        counted = (IMU_TOPIC,)
        qos = QoSProfile(depth=400, reliability=qos_profile_sensor_data.reliability)
        msg_type, rate = Imu, IMU_RATE_HZ
    # Subscribe only once the sensors' writers are known here (discovered through the
    # veth): the camera starts at its first matched subscriber, and a frame it sent
    # before this reader had matched its writer would be dropped as the discovery race,
    # not lost by the link.
    start = time.monotonic()
    while rclpy.ok() and time.monotonic() - start < args.timeout and not all(
            node.count_publishers(t) for t in counted):
        time.sleep(0.05)
    discovered_s = time.monotonic() - start
    for topic in counted:
        node.create_subscription(msg_type, topic, recorder(topic, rate), qos, raw=True)
    if args.outputs:
        for topic in OUTPUT_TOPICS:
            node.create_subscription(
                PointCloud2, topic, recorder(topic, None),
                QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE), raw=True)
    executor = SingleThreadedExecutor()
    executor.add_node(node)
    complete_at = None
    end = 'timeout'
    try:
        while rclpy.ok() and time.monotonic() - start < args.timeout:
            executor.spin_once(timeout_sec=0.1)
            if complete_at is None and all(len(seen[t]) >= args.expect for t in counted):
                complete_at = time.monotonic()
            if complete_at is not None and time.monotonic() - complete_at > args.linger:
                end = 'complete'
                break
            if last_ns[0] is not None and time.time_ns() - last_ns[0] > args.idle * 1e9:
                end = 'idle'
                break
        else:
            end = 'shutdown' if not rclpy.ok() else end
    except (KeyboardInterrupt, ExternalShutdownException):
        end = 'interrupted'
    finally:
        result = {'topics': records, 'wall_s': time.monotonic() - start,
                  'discovered_s': discovered_s, 'end': end}
        pathlib.Path(args.out).write_text(json.dumps(result))
        with contextlib.suppress(Exception):
            node.destroy_node()
        rclpy.try_shutdown()


# ----------------------------------------------------------------------------- benchmark
def _format_row(name, run, res):
    img, imu = res['images'], res['imu']
    if img is None:
        return f'| {name} | {run} | probe gave no result | | | | | | | | | | | | |'
    lat, tr = img['latency_ms'], img['transport_ms']
    outputs = ' / '.join(str(res['outputs'].get(t, 0)) for t in OUTPUT_TOPICS)
    return (f'| {name} | {run} | {img["sent"]} | {img["publish_rate_hz"]:.1f} | '
            f'{img["received"]} | {img["lost"]} | '
            f'{lat["median"]:.1f} | {lat["p99"]:.1f} | {lat["max"]:.1f} | '
            f'{tr["median"]:.1f} / {tr["p99"]:.1f} | '
            f'{_imu_cell(imu)} | '
            f'{_drops(res["counters"])} | {_wire(res["counters"], img["sent"])} | '
            f'{res["load"]:.1f} | {outputs} |')


def _imu_cell(imu):
    if imu is None:
        return 'no IMU probe result'
    return f'{imu["received"]}/{imu["sent"]} ({imu["latency_ms"]["p99"]:.1f})'


def _wire(counters, images):
    """Bytes the sensor host sent on the link per byte of image payload sent."""
    return f'{counters[SENSOR]["tx_bytes"] / max(images * IMAGE_BYTES, 1):.2f}'


def _drops(counters):
    s, p = counters[SENSOR], counters[PROCESSING]
    return (f'{s["qdisc_dropped"]} / {p["udp_rcvbuf_errors"]} / {p["ip_reasm_fails"]}')


def benchmark_main(args):
    reason = netns_unavailable()
    if reason:
        print(f'two_host_benchmark: cannot create network namespaces here: {reason}',
              file=sys.stderr)
        return 2
    if args.link != 'none':
        reason = shaping_unavailable(args.link)
        if reason:
            print(f'two_host_benchmark: cannot shape the veth to {args.link}: {reason}',
                  file=sys.stderr)
            return 2
    names = [n for n in args.profiles.split(',') if n]
    if names == ['all']:
        names = [*PROFILES, *SHIPPED_VARIANTS]
    lines = []

    def out(text):
        print(text, flush=True)
        lines.append(text)

    with tempfile.TemporaryDirectory(prefix='two_host_profiles_') as tmp:
        profiles = profile_paths(names, tmp, extra=args.profile_file)
        kernel = ('the kernel\'s' if args.kernel_defaults else
                  ', '.join(f'{k} = {v}' for k, v in HOST_SYSCTLS.items()))
        out(f'{args.runs} run(s) of {args.duration:g} s per profile, '
            f'stereo 2 x 1280x720 mono8 at {FPS:g} fps + IMU {IMU_RATE_HZ:g} Hz, '
            f'link {args.link} behind a send queue of {args.queue_frames} frames, IP '
            f'reassembly settings: {kernel}; processing nodes '
            f'{"on" if args.processing else "off"}:')
        for name, (description, _path, _env) in profiles.items():
            out(f'- `{name}`: {description}')
        out('')
        out('| profile | run | images sent | sent per s per camera | received | lost | '
            'latency median ms | p99 ms | max ms | transport median / p99 ms | '
            'IMU received/sent (p99 ms) | packets dropped: sensor qdisc / processing UDP '
            'rcvbuf / IP reassembly fails | link bytes per image byte | load (1 min) | '
            'spots/pairs / vlc/lamps msgs |')
        out('|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|')
        totals = {}
        # interleave the profiles run by run: the machine's load drifts over minutes
        for run in range(1, args.runs + 1):
            for name, (_description, path, env) in profiles.items():
                res = run_stream(path, args.duration, args.link, args.processing,
                                 profile_env=env, log_dir=None,
                                 queue_frames=args.queue_frames,
                                 host_sysctls={} if args.kernel_defaults else HOST_SYSCTLS)
                out(_format_row(name, run, res))
                if not args.keep_logs:
                    shutil.rmtree(res['log_dir'], ignore_errors=True)
                if res['shm']:
                    print(f'  !! shared memory mapped: {res["shm"]}')
                if res['exit_codes'].get('stereo_camera_node') != 0:
                    print('  the camera had not published its whole duration when the run '
                          'ended (machine too loaded): frames it never sent count as lost '
                          'above; the run is left out of the totals')
                    continue
                if res['images'] and res['images']['lost']:
                    print(f'  lost frames (first 20 per camera): '
                          f'{res["images"]["missing_first"]}; image probe ended: '
                          f'{res["probe_end"]["images"]}; exit codes {res["exit_codes"]}')
                totals.setdefault(name, []).append(res)
        out('')
        out('per profile over all runs:')
        for name, results in totals.items():
            imgs = [r['images'] for r in results if r['images']]
            sent = sum(i['sent'] for i in imgs)
            lost = sum(i['lost'] for i in imgs)
            med = np.median([i['latency_ms']['median'] for i in imgs]) if imgs else math.nan
            p99 = max((i['latency_ms']['p99'] for i in imgs), default=math.nan)
            mx = max((i['latency_ms']['max'] for i in imgs), default=math.nan)
            fps = min((i['publish_rate_hz'] for i in imgs), default=math.nan)
            out(f'- {name} ({len(imgs)} runs): lost {lost} of {sent} images; latency '
                  f'median of run medians {med:.1f} ms, worst run p99 {p99:.1f} ms, max '
                  f'{mx:.1f} ms; camera rate down to {fps:.1f} frames/s')
        if totals:
            first = next(iter(totals.values()))[0]
            out('')
            out(f'link: {first["link"]}; sysctl in the namespaces: {first["sysctl"]}')
    if args.docs:
        from vlc_evaluation.report import replace_marked_block
        begin, end = f'<!-- {args.docs_block}:begin -->', f'<!-- {args.docs_block}:end -->'
        command = 'two_host_benchmark ' + ' '.join(args.argv)
        replace_marked_block(args.docs, '\n'.join(
            [begin, f'Generated by `{command}` (profiles interleaved run by run).', *lines,
             end]), begin=begin, end=end)
        print(f'table written to {args.docs} between the {args.docs_block} markers')
    return 0


def main(argv=None):
    argv = sys.argv[1:] if argv is None else argv
    if argv[:1] == ['probe']:
        parser = argparse.ArgumentParser(prog='two_hosts probe')
        parser.add_argument('--role', choices=('images', 'imu'), required=True)
        parser.add_argument('--out', required=True)
        parser.add_argument('--expect', type=int, required=True,
                            help='messages per counted topic; done at that many + linger')
        parser.add_argument('--outputs', action='store_true',
                            help='also count the processing nodes\' outputs')
        parser.add_argument('--timeout', type=float, default=120.0)
        parser.add_argument('--linger', type=float, default=1.5)
        parser.add_argument('--idle', type=float, default=15.0,
                            help='stop this long after the last message (the harness '
                                 'interrupts a probe 10 s after the camera has ended)')
        probe_main(parser.parse_args(argv[1:]))
        return 0
    parser = argparse.ArgumentParser(prog='two_host_benchmark', description=__doc__.split(
        '\n\n')[0], formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument('--profiles', default=','.join(DEFAULT_PROFILES),
                        help=f'comma list of {", ".join([*PROFILES, *SHIPPED_VARIANTS])}; '
                             f'or all (default: %(default)s)')
    parser.add_argument('--profile-file', action='append', default=[],
                        metavar='NAME=PATH', help='another profile XML to try')
    parser.add_argument('--runs', type=int, default=3)
    parser.add_argument('--duration', type=float, default=10.0, help='stream seconds')
    parser.add_argument('--link', default='none',
                        help="line rate of a tbf qdisc on both veth ends (e.g. 1gbit), "
                             "or 'none' (the veth's memory speed)")
    parser.add_argument('--processing', action='store_true',
                        help='also run spot_locator_node and vlc_decoder_node')
    parser.add_argument('--queue-frames', type=int, default=QUEUE_FRAMES,
                        help=f'send queue of the shaped link in {FRAME_B}-byte frames '
                             '(default %(default)s, a NIC\'s txqueuelen)')
    parser.add_argument('--kernel-defaults', action='store_true',
                        help='leave the kernel\'s IP-reassembly settings as they are '
                             f'(default: set {HOST_SYSCTLS} in both namespaces)')
    parser.add_argument('--keep-logs', action='store_true')
    parser.add_argument('--docs', metavar='FILE',
                        help='also write the table between the markers '
                             '<!-- NAME:begin/end --> of FILE (NAME: --docs-block)')
    parser.add_argument('--docs-block', default='two-hosts', metavar='NAME')
    args = parser.parse_args(argv)
    args.argv = [a for a in argv if a not in ('--docs', args.docs)
                 and not a.startswith('--docs=')]
    return benchmark_main(args)


if __name__ == '__main__':
    sys.exit(main())
