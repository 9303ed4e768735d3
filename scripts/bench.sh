#!/usr/bin/env bash
# Every benchmark command; each prints its own figures.
set -eo pipefail
cd "$VLC_WS"
ros2run vlc_evaluation rig_benchmark
python -m vlc_bags.bench_recorder --seconds 10
# decoder and spot locator per stereo pair on rendered frames (and their output hashes)
ros2run vlc_evaluation receivers_benchmark --frames 60 --repeats 2 --min-of 3
# ... and paced at the camera's frame rate, as the nodes see the frames in the graph
ros2run vlc_evaluation receivers_benchmark --frames 60 --repeats 1 --pace
# the live graph (rig, processing nodes, recorder) at real time, 120 km/h, one graph on the
# machine, every run at real-time factor 1: runs with a node behind, end-to-end latency
ros2run vlc_evaluation run_evaluation --protocol dynamic --speeds 120 --runs 20 --lanes 1 \
    --realtime-factor 1.0 --retries 0 --fixed-pace --out out/realtime_120kmh
