#!/usr/bin/env bash
# Lints the code (ruff) and runs every test tier: pure-core pytest, in-process rclpy tests, graph tests of the
# installed executables. Called by `make test` (which sources scripts/env.sh first).
set -eo pipefail
cd "$VLC_WS"
rm -f /dev/shm/fastrtps_* /dev/shm/sem.fastrtps_* 2>/dev/null || true
# lint first (config: ruff.toml), then every test tier
ruff check src tests scripts conftest.py
python -m pytest "$@"
