"""Benchmark: whether ``bag_recorder`` keeps up with the train's sensor load on one core.

Publishes 2 × 30 Hz mono8 1280×720 images (0.9 MB each, reliable keep last 5) and a
400 Hz IMU (sensor data QoS) from this process for ``--seconds``, records them with the
installed ``bag_recorder`` in a temporary folder, stops it with SIGINT and prints:
messages published / recorded per topic, the recorder's CPU use (user + system time of
its process from /proc, in % of one core), write throughput, and the delay between the
middleware receiving a message and the recorder's callback (from receive_times.csv; a
delay that stays small means the recorder keeps up, one that grows means it falls behind).

Run (after ``make build``)::

    source scripts/env.sh
    python -m vlc_bags.bench_recorder --seconds 10 [--storage sqlite3]
        [--compression zstd] [--keep]
"""
from __future__ import annotations

import argparse
import os
from pathlib import Path
import shutil
import signal
import struct
import subprocess
import tempfile
import threading
import time

import numpy as np


def _cpu_s(pid: int) -> float:
    fields = Path(f'/proc/{pid}/stat').read_text().rsplit(')', 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf('SC_CLK_TCK')


def _percentiles(values_ns: list[int]) -> str:
    if not values_ns:
        return 'n/a'
    a = np.asarray(values_ns) * 1e-3
    return (f'median {np.median(a):8.0f} µs  p99 {np.percentile(a, 99):8.0f} µs  '
            f'max {a.max():8.0f} µs')


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('--seconds', type=float, default=10.0)
    parser.add_argument('--storage', default='mcap', choices=('mcap', 'sqlite3'))
    parser.add_argument('--compression', default='none', choices=('none', 'zstd'))
    parser.add_argument('--flush-interval-s', type=float, default=1.0)
    parser.add_argument('--poll-period-s', type=float, default=None,
                        help="the recorder's poll_period_s (default: its own; 0 = a "
                             'callback per message)')
    parser.add_argument('--keep', action='store_true', help='keep the bag (default: delete)')
    args = parser.parse_args()

    os.environ['ROS_DOMAIN_ID'] = str(150 + os.getpid() % 80)
    from ament_index_python.packages import get_package_prefix
    import rclpy
    from rclpy.context import Context
    from rclpy.qos import QoSProfile, ReliabilityPolicy, qos_profile_sensor_data
    from rclpy.serialization import serialize_message
    from sensor_msgs.msg import Image, Imu

    from vlc_bags.bagio import bag_summary, read_receive_times

    exe = Path(get_package_prefix('vlc_bags')) / 'lib' / 'vlc_bags' / 'bag_recorder'
    out = Path(tempfile.mkdtemp(prefix='bench_bag_')) / 'bag'
    topics = ['stereo/left/image_raw', 'stereo/right/image_raw', 'imu/data_raw']
    recorder = subprocess.Popen(
        [str(exe), '--ros-args', '-p', f'output:={out}', '-p', f'storage:={args.storage}',
         '-p', f'compression:={args.compression}', '-p',
         f'flush_interval_s:={args.flush_interval_s}', '-p', f'topics:=[{",".join(topics)}]']
        + ([] if args.poll_period_s is None else
           ['-p', f'poll_period_s:={float(args.poll_period_s)}']),
        stdout=subprocess.DEVNULL, stderr=subprocess.STDOUT, start_new_session=True)

    ctx = Context()
    rclpy.init(context=ctx)
    node = rclpy.create_node('bench_publisher', context=ctx)
    image_qos = QoSProfile(depth=5, reliability=ReliabilityPolicy.RELIABLE)
    pubs = {'left': node.create_publisher(Image, topics[0], image_qos),
            'right': node.create_publisher(Image, topics[1], image_qos),
            'imu': node.create_publisher(Imu, topics[2], qos_profile_sensor_data)}
    # distinct noise frames, so that compression cannot reuse the previous image
    rng = np.random.default_rng(1)
    image_cdrs = [bytearray(serialize_message(Image(
        height=720, width=1280, encoding='mono8', step=1280,
        data=rng.integers(0, 256, 1280 * 720, dtype=np.uint8).tobytes()))) for _ in range(5)]
    imu_cdr = bytearray(serialize_message(Imu()))
    deadline = time.monotonic() + 20.0
    while any(p.get_subscription_count() == 0 for p in pubs.values()):
        if time.monotonic() > deadline or recorder.poll() is not None:
            raise SystemExit('recorder did not subscribe')
        time.sleep(0.05)
    time.sleep(0.5)

    sent = {'left': 0, 'right': 0, 'imu': 0}

    def stamp(buf: bytearray, t_ns: int) -> bytes:
        struct.pack_into('<iI', buf, 4, t_ns // 10**9, t_ns % 10**9)
        return bytes(buf)

    cpu0, wall0 = _cpu_s(recorder.pid), time.monotonic()

    def publish_loop() -> None:
        start = time.monotonic()
        n_img = n_imu = 0
        while True:
            now = time.monotonic() - start
            if now >= args.seconds:
                return
            while n_img / 30.0 <= now:
                t_ns = time.time_ns()
                for i, side in enumerate(('left', 'right')):
                    pubs[side].publish(stamp(image_cdrs[(2 * n_img + i) % 5], t_ns))
                    sent[side] += 1
                n_img += 1
            while n_imu / 400.0 <= now:
                pubs['imu'].publish(stamp(imu_cdr, time.time_ns()))
                sent['imu'] += 1
                n_imu += 1
            time.sleep(0.001)

    thread = threading.Thread(target=publish_loop)
    thread.start()
    thread.join()
    time.sleep(0.5)
    cpu1, wall1 = _cpu_s(recorder.pid), time.monotonic()
    os.killpg(recorder.pid, signal.SIGINT)
    code = recorder.wait(30)
    node.destroy_node()
    rclpy.shutdown(context=ctx)

    counts = {s.topic: s.message_count for s in bag_summary(out)}
    size_mb = sum(f.stat().st_size for f in out.iterdir()) / 1e6
    rows = read_receive_times(out)
    print(f'recorder exit code {code}; storage {args.storage}, compression '
          f'{args.compression}, {args.seconds:.0f} s of load')
    for side, topic in zip(('left', 'right', 'imu'), topics):
        recorded = counts.get('/' + topic, 0)
        print(f'  /{topic:24s} published {sent[side]:6d}  recorded {recorded:6d}')
    print(f'  recorder CPU {100 * (cpu1 - cpu0) / (wall1 - wall0):5.1f} % of one core; '
          f'bag {size_mb:.0f} MB = {size_mb / args.seconds:.1f} MB/s')
    for kind in ('image_raw', 'imu'):
        sel = [r for r in rows if kind in r['topic']]
        queueing = [r['callback_wall_ns'] - r['received_timestamp_ns'] for r in sel]
        transport = [r['received_timestamp_ns'] - r['source_timestamp_ns'] for r in sel]
        print(f'  {kind:9s} middleware receive -> callback: {_percentiles(queueing)}')
        print(f'  {kind:9s} publish -> middleware receive:  {_percentiles(transport)}')
    if args.keep:
        print(f'  bag kept in {out}')
    else:
        shutil.rmtree(out.parent)


if __name__ == '__main__':
    main()
