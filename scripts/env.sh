# Sourced by the Makefile and scripts: the venv, the ament index, the colcon install,
# the Fast DDS profile with a 32 MB shared-memory segment and localhost-only discovery.
_ws="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
# shellcheck disable=SC1091
source "$_ws/.venv/bin/activate"
export AMENT_PREFIX_PATH="$VIRTUAL_ENV${AMENT_PREFIX_PATH:+:$AMENT_PREFIX_PATH}"
if [ -f "$_ws/install/setup.bash" ]; then
    # colcon's setup scripts reference unset variables
    set +u
    # shellcheck disable=SC1091
    source "$_ws/install/setup.bash"
fi
export FASTRTPS_DEFAULT_PROFILES_FILE="$_ws/config/fastdds_localhost_bigshm.xml"
export ROS_AUTOMATIC_DISCOVERY_RANGE="${ROS_AUTOMATIC_DISCOVERY_RANGE:-LOCALHOST}"
export VLC_WS="$_ws"
# One BLAS/OpenMP thread per process: every node is single-threaded by design, and numpy's
# threaded BLAS gave the spot locator 15 ms extra CPU and stalls on a shared 2-core
# machine (docs/arch/spot_locator.md, "Per-frame tail"). Set before numpy is imported.
export OPENBLAS_NUM_THREADS="${OPENBLAS_NUM_THREADS:-1}"
export OMP_NUM_THREADS="${OMP_NUM_THREADS:-1}"
export MKL_NUM_THREADS="${MKL_NUM_THREADS:-1}"
unset _ws
# `ros2 run` stand-in for machines without the ros2 CLI: ros2run <pkg> <exe> [args...]
ros2run() { "$VLC_WS/install/lib/$1/$2" "${@:3}"; }
export -f ros2run
