"""Records the committed sample bag: raw sensors and ground truth of a short pass.

    python -m vlc_evaluation.sample_bag --out bags/sample_80kmh --force

runs the rig (stereo camera and ADIS16488) and the bag recorder only, on a fork of the
evaluation runner (:mod:`.runner`), and keeps in ``--out``:

* raw sensors: ``/stereo/{left,right}/image_raw``, ``/stereo/{left,right}/camera_info``,
  ``/imu/data_raw``, ``/clock``;
* ground truth: ``/ground_truth/pose``, ``/ground_truth/odometry``, ``/ground_truth/spots``.

rosbag2 MCAP with zstd chunk compression (``compression: zstd`` of the recorder: the
storage-side compression ``ros2 bag record --storage-preset-profile zstd_fast`` writes,
which ``ros2 bag play``, rosbags and the ``mcap`` reader decompress transparently), bag
timestamps = header stamps (simulated time), so ``bag_player`` replays the simulated
clock. The default pass — 80 km/h from 20.5 m for 1.5 s (45 stereo frames, 600 IMU
samples + the IMU tail) — passes the lamps at 30, 40 and 50 m and sees the one at
60 m; a dark tunnel frame pair compresses to about 0.37 MB, so the bag stays under
``--max-mb`` (20 MB).
"""
import argparse
import logging
import pathlib
import shutil
import sys
import tempfile

from vlc_bags.bagio import bag_summary
from vlc_evaluation.runner import run_jobs, run_scenario
from vlc_evaluation.scenarios import Scenario

LOG = logging.getLogger(__name__)


def sample_scenario(name, speed_kmh=80.0, start_chainage_m=20.5, duration_s=1.5, seed=1,
                    realtime_factor=0.5, compression='zstd'):
    """The sensor-only scenario of the sample bag (rig + recorder, no processing);
    ``compression`` of the recorder ('zstd' or 'none').
    """
    return Scenario(name=name, motion_profile='constant', start_chainage_m=start_chainage_m,
                    speed_kmh=speed_kmh, seed=seed, duration_s=duration_s,
                    realtime_factor=realtime_factor, record_sensors=True,
                    run_processing=False,
                    node_params={'bag_recorder': {'compression': compression,
                                                  'timestamp_source': 'header',
                                                  'flush_interval_s': 30.0,
                                                  'record_receive_times': False}})


def bag_size_mb(path):
    return sum(f.stat().st_size for f in pathlib.Path(path).rglob('*') if f.is_file()) / 1e6


def record_sample_bag(out, scenario, spawn='fork'):
    """Record ``scenario`` into the bag folder ``out`` (must not exist); returns problems."""
    out = pathlib.Path(out)
    if out.exists():
        raise FileExistsError(f'{out} exists: remove it first')
    with tempfile.TemporaryDirectory(prefix='sample_bag_') as tmp:
        [(bag, timing)] = run_jobs(
            [lambda lane: run_scenario(scenario, tmp, lane, scenario.recorded_topics())],
            lanes=1, spawn=spawn)
        out.parent.mkdir(parents=True, exist_ok=True)
        shutil.move(str(bag), str(out))
    return timing['problems']


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--out', default='bags/sample_80kmh', help='bag folder to create')
    parser.add_argument('--speed-kmh', type=float, default=80.0)
    parser.add_argument('--start-chainage-m', type=float, default=20.5)
    parser.add_argument('--duration-s', type=float, default=1.5)
    parser.add_argument('--seed', type=int, default=1)
    parser.add_argument('--realtime-factor', type=float, default=0.5,
                        help='pace of the recording (the bag holds simulated time)')
    parser.add_argument('--max-mb', type=float, default=20.0)
    parser.add_argument('--force', action='store_true', help='replace an existing --out')
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format='%(levelname)s %(name)s: %(message)s')
    out = pathlib.Path(args.out)
    if args.force and out.exists():
        shutil.rmtree(out)
    scenario = sample_scenario(out.name, args.speed_kmh, args.start_chainage_m,
                               args.duration_s, args.seed, args.realtime_factor)
    problems = record_sample_bag(out, scenario)
    for problem in problems:
        LOG.warning('%s', problem)
    size = bag_size_mb(out)
    for topic in bag_summary(out):
        print(f'{topic.topic:32s} {topic.msgtype:36s} {topic.message_count:5d}')
    print(f'{out}: {size:.1f} MB')
    if size > args.max_mb:
        print(f'larger than {args.max_mb} MB: shorten --duration-s', file=sys.stderr)
        return 1
    return 1 if problems else 0


if __name__ == '__main__':
    sys.exit(main())
