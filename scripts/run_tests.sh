#!/usr/bin/env bash
# Lints the code (ruff) and runs every test tier: pure-core pytest, in-process rclpy tests, graph tests of the
# installed executables. Called by `make test` (which sources scripts/env.sh first).
#
# The tests that start no process (not marked `graph`: pure core and in-process rclpy) run
# on VLC_TEST_WORKERS pytest-xdist workers (default 2, one per core; each worker draws DDS
# domains from a range of its own, conftest.py); then the graph tests, which start the
# installed executables and time them, run one at a time. VLC_TEST_WORKERS=1 runs
# everything in one serial pytest. Arguments go to pytest (both passes); a pass that
# selects no test is not a failure.
set -eo pipefail
cd "$VLC_WS"
rm -f /dev/shm/fastrtps_* /dev/shm/sem.fastrtps_* 2>/dev/null || true
# lint first (config: ruff.toml), then every test tier
ruff check src tests scripts conftest.py
workers="${VLC_TEST_WORKERS:-2}"
if [[ "$workers" -le 1 ]] || ! python -c 'import xdist' 2>/dev/null; then
    exec python -m pytest "$@"
fi
run() {
    local code=0
    python -m pytest "$@" || code=$?
    # 5: no test selected (e.g. a path holding only graph tests)
    if [[ $code -ne 0 && $code -ne 5 ]]; then return $code; fi
}
status=0
run -m "not graph" -n "$workers" "$@" || status=$?
rm -f /dev/shm/fastrtps_* /dev/shm/sem.fastrtps_* 2>/dev/null || true
run -m graph "$@" || status=$?
exit $status
