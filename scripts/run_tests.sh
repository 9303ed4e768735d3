#!/usr/bin/env bash
# Runs every test tier: pure-core pytest, in-process rclpy tests, graph tests of the
# installed executables. Called by `make test` (which sources scripts/env.sh first).
set -eo pipefail
cd "$VLC_WS"
rm -f /dev/shm/fastrtps_* /dev/shm/sem.fastrtps_* 2>/dev/null || true
python -m pytest "$@"
