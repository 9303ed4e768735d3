#!/usr/bin/env bash
# Every benchmark command; each prints its own figures.
set -eo pipefail
cd "$VLC_WS"
ros2run vlc_stereo_camera rig_benchmark
python -m train_localizer.bagtools.bench_recorder --seconds 10
