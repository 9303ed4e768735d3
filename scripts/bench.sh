#!/usr/bin/env bash
# Every benchmark command; each prints its own figures.
set -eo pipefail
cd "$VLC_WS"
ros2run vlc_evaluation rig_benchmark
python -m vlc_bags.bench_recorder --seconds 10
# decoder and spot locator per stereo pair on rendered frames (and their output hashes)
ros2run vlc_evaluation receivers_benchmark --frames 60 --repeats 2 --min-of 3
