#!/usr/bin/env bash
# One command to set up and use tdslip_ros on a fresh machine.
#
#   ./run.sh demo [args]    set up, then run a recorded closed-loop hop and analyse it (args go to tdslip run)
#   ./run.sh test [args]    set up, then run the test suite (extra args go to pytest)
#   ./run.sh test -m "not nodes" -n 2   the fast tier on both cores: no node process, no ROS context (test/conftest.py)
#   ./run.sh setup          set up only
#
# Set-up is idempotent: each step runs again only when its inputs changed (a hash of them is kept in
# .venv/.tdslip-stamps), so a second run takes seconds. Everything lands in .venv (Python 3.11 venv
# with the pinned ROS 2 Kilted wheels, tdslip_msgs and tdslip_ros), build/ (the msg_defs build) and
# the compiled kernels' cache (~/.cache/tdslip_ros, or $NUMBA_CACHE_DIR; tdslip_ros/model/compiled.py).
set -euo pipefail

REPO="$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)"
VENV="$REPO/.venv"
STAMPS="$VENV/.tdslip-stamps"
MSG_BUILD="$REPO/build/msg_defs"
ROS2_TOOLS="$REPO/../shared/ros2-tools"
SETUP_LOG="$REPO/build/setup.log"
PIP_VERSION="26.3"

say() { echo "[run.sh] $*" >&2; }
die() { say "error: $*"; exit 1; }

# Run a set-up command with its output in build/setup.log, shown only if it fails.
logged() {
    echo "### $*" >> "$SETUP_LOG"
    if ! "$@" >> "$SETUP_LOG" 2>&1; then
        tail -n 40 "$SETUP_LOG" >&2
        die "'$1 ${2:-}' failed; the full output is in ${SETUP_LOG#"$REPO"/}"
    fi
}

# sha256 over the names and contents of the given files plus any extra words (-- word...).
inputs_hash() {
    local file
    {
        while [[ $# -gt 0 && "$1" != "--" ]]; do
            file="$1"; shift
            echo "== ${file#"$REPO"/}"
            cat "$file"
        done
        [[ $# -gt 0 ]] && shift
        echo "== extra $*"
    } | sha256sum | cut -d' ' -f1
}

stamp_is_current() { [[ -f "$STAMPS/$1" && "$(cat "$STAMPS/$1")" == "$2" ]]; }
write_stamp() { mkdir -p "$STAMPS" && echo "$2" > "$STAMPS/$1"; }

# The ROS 2 Kilted wheels are built for CPython 3.11 only.
find_python311() {
    local candidate
    for candidate in "${TDSLIP_PYTHON:-}" python3.11 python3; do
        [[ -n "$candidate" ]] || continue
        if command -v "$candidate" > /dev/null \
            && "$candidate" -c 'import sys; sys.exit(sys.version_info[:2] != (3, 11))' 2> /dev/null; then
            command -v "$candidate"
            return 0
        fi
    done
    die "Python 3.11 is required (the ROS 2 Kilted wheels are cp311); set TDSLIP_PYTHON to one"
}

ensure_venv() {
    if [[ -x "$VENV/bin/python" ]] \
        && "$VENV/bin/python" -c 'import sys; sys.exit(sys.version_info[:2] != (3, 11))' 2> /dev/null; then
        return 0
    fi
    local python
    python="$(find_python311)"
    say "creating the virtual environment .venv with $python"
    rm -rf "$VENV"
    logged "$python" -m venv "$VENV"
}

# pip check, less the one known gap of the ros2 tools' wheels (ensure_ros2_tools): they name
# ament_index_python, which the Kilted wheels install as ros-ament-index-python.
pip_check() {
    local problems
    problems="$("$VENV/bin/python" -m pip check 2>&1 | grep -v ' requires ament-index-python, which is not installed' \
        | grep -v '^No broken requirements found' || true)"
    [[ -z "$problems" ]] || { echo "$problems"; return 1; }
}

ensure_requirements() {
    local key
    key="$(inputs_hash "$REPO/requirements.txt" "$REPO/requirements-dev.txt" -- "pip==$PIP_VERSION")"
    stamp_is_current requirements "$key" && return 0
    say "installing the pinned requirements into .venv (ROS 2 Kilted wheels, numpy, scipy, ...; about a minute)"
    logged "$VENV/bin/python" -m pip install --disable-pip-version-check "pip==$PIP_VERSION"
    logged "$VENV/bin/python" -m pip install --disable-pip-version-check -r "$REPO/requirements-dev.txt"
    logged pip_check
    write_stamp requirements "$key"
}

ensure_msgs() {
    local key
    local -a msg_inputs
    mapfile -t msg_inputs < <(find "$REPO/msg_defs" -type f | LC_ALL=C sort)
    key="$(inputs_hash "${msg_inputs[@]}" -- "$(cat "$STAMPS/requirements")")"
    stamp_is_current msgs "$key" && return 0
    command -v cmake > /dev/null || die "cmake is needed to build msg_defs (apt-get install cmake)"
    say "building the interface package tdslip_msgs (msg_defs) with cmake into .venv (about 30 s)"
    # The venv is the ament/CMake prefix: the wheels' packages are found there and ours goes there.
    logged env CMAKE_PREFIX_PATH="$VENV" cmake -S "$REPO/msg_defs" -B "$MSG_BUILD" \
        -DCMAKE_INSTALL_PREFIX="$VENV" -DPython3_EXECUTABLE="$VENV/bin/python" \
        -DCMAKE_BUILD_TYPE=Release -DBUILD_TESTING=OFF
    logged cmake --build "$MSG_BUILD" --parallel 2
    logged cmake --install "$MSG_BUILD"
    write_stamp msgs "$key"
}

ensure_tdslip_ros() {
    local key
    local -a package_inputs
    # Editable: code changes need no reinstall; the installed data files (ament marker, package.xml,
    # config/*.yaml, launch/*.launch.py, ros2run launchers) are copies, hence part of the key.
    mapfile -t package_inputs < <(
        find "$REPO/setup.py" "$REPO/setup.cfg" "$REPO/package.xml" "$REPO/resource" "$REPO/config" "$REPO/launch" \
            -type f | LC_ALL=C sort
    )
    key="$(inputs_hash "${package_inputs[@]}" -- "$(cat "$STAMPS/msgs")")"
    stamp_is_current tdslip_ros "$key" && return 0
    say "installing tdslip_ros into .venv (editable)"
    logged "$VENV/bin/python" -m pip install --disable-pip-version-check \
        --no-deps --no-build-isolation --editable "$REPO"
    write_stamp tdslip_ros "$key"
}

# The real `ros2` command line for the tests, only where ../shared/ros2-tools sits beside the clone
# (its README.md): the tools' PyPI requirements, their wheels (--no-deps: their metadata names
# ament_index_python, which the Kilted wheels install as ros-ament-index-python), and the two message
# packages that no registry here ships, built from the shared source like msg_defs, with the wheels'
# include paths relocated at the end of their configure step. The package itself never needs them.
ensure_ros2_tools() {
    if [[ ! -d "$ROS2_TOOLS" ]]; then
        say "no ../shared/ros2-tools beside the clone: the tests of the real ros2 command line will skip"
        return 0
    fi
    local key package
    local -a tool_inputs wheels
    mapfile -t tool_inputs < <(
        find "$REPO/requirements-ros2-tools.txt" "$REPO/msg_defs/cmake" "$ROS2_TOOLS/wheels" "$ROS2_TOOLS/src" \
            -type f | LC_ALL=C sort
    )
    key="$(inputs_hash "${tool_inputs[@]}" -- "$(cat "$STAMPS/requirements")")"
    stamp_is_current ros2_tools "$key" && return 0
    say "installing the ros2 command-line tools from ../shared/ros2-tools into .venv (1 to 4 minutes)"
    logged "$VENV/bin/python" -m pip install --disable-pip-version-check -r "$REPO/requirements-ros2-tools.txt"
    mapfile -t wheels < <(find "$ROS2_TOOLS/wheels" -name '*.whl' | LC_ALL=C sort)
    logged "$VENV/bin/python" -m pip install --disable-pip-version-check --no-index --no-deps "${wheels[@]}"
    for package in composition_interfaces tf2_msgs; do
        logged env CMAKE_PREFIX_PATH="$VENV" AMENT_PREFIX_PATH="$VENV" \
            cmake -S "$ROS2_TOOLS/src/$package" -B "$REPO/build/ros2-tools/$package" \
            -DCMAKE_PROJECT_INCLUDE="$REPO/msg_defs/cmake/relocate_at_end_of_configure.cmake" \
            -DCMAKE_INSTALL_PREFIX="$VENV" -DPython3_EXECUTABLE="$VENV/bin/python" \
            -DCMAKE_BUILD_TYPE=Release -DBUILD_TESTING=OFF
        logged cmake --build "$REPO/build/ros2-tools/$package" --parallel 2
        logged cmake --install "$REPO/build/ros2-tools/$package"
    done
    logged "$VENV/bin/python" -c 'import composition_interfaces.srv, launch_ros, ros2cli; from tf2_msgs.msg import TFMessage'
    write_stamp ros2_tools "$key"
}

# The model's compiled kernels (numba) are cached (tdslip_ros/model/compiled.py says where); compiling them here
# spares the first node, run or test the wait. Redone when a model source changes (the cache's own key).
ensure_kernels() {
    local key
    local -a model_sources
    mapfile -t model_sources < <(find "$REPO/tdslip_ros/model" -name '*.py' | LC_ALL=C sort)
    key="$(inputs_hash "${model_sources[@]}" -- "$(cat "$STAMPS/tdslip_ros")")"
    stamp_is_current kernels "$key" && return 0
    say "compiling the model's kernels (numba; about a minute the first time)"
    logged "$VENV/bin/python" -c 'from tdslip_ros.model.policies.controllers import warm_up; warm_up()'
    write_stamp kernels "$key"
}

ensure_environment() {
    mkdir -p "$REPO/build"
    touch "$REPO/build/COLCON_IGNORE"  # keep a colcon workspace scan out of our cmake build tree
    # One set-up at a time when several run.sh start together; the lock is released before running.
    local lock_fd
    exec {lock_fd}> "$REPO/build/.setup.lock"
    flock "$lock_fd"
    : > "$SETUP_LOG"
    ensure_venv
    ensure_requirements
    ensure_msgs
    ensure_ros2_tools
    ensure_tdslip_ros
    ensure_kernels
    exec {lock_fd}>&-
    say "environment ready: .venv"
}

# Set up and run with the venv as the only ROS prefix; a sourced ROS distro would mix two ROS builds.
enter_environment() {
    export AMENT_PREFIX_PATH="$VENV"
    export PATH="$VENV/bin:$PATH"
    export VIRTUAL_ENV="$VENV"
    unset PYTHONPATH CMAKE_PREFIX_PATH COLCON_PREFIX_PATH
    # The wheels' .pth re-executes Python once with their LD_LIBRARY_PATH; an outer venv's
    # completed bootstrap must not stop ours.
    unset _ROS_WHEELS_BOOTSTRAP_COMPLETE
}

# The main job: a closed-loop lockstep hop under energy regulation, recorded to MCAP, then analysed
# against the analytic return map. Each demo gets its own folder, so earlier runs are never overwritten.
run_demo() {
    local out
    out="$REPO/runs/demo-$(date +%Y%m%d-%H%M%S)"
    say "demo: tdslip run --policy energy --strides 30 --out ${out#"$REPO"/} $*"
    "$VENV/bin/tdslip" run --policy energy --strides 30 --out "$out" "$@"
    say "demo: tdslip analyze ${out#"$REPO"/} (report into ${out#"$REPO"/}/report)"
    "$VENV/bin/tdslip" analyze "$out"
    say "demo: done; the recording (rosbag2 directory) is ${out#"$REPO"/}, the report (PNG, JSON, Markdown) ${out#"$REPO"/}/report"
}

run_tests() {
    # Without arguments pytest runs its testpaths (test/, see pyproject.toml).
    say "test: pytest $*"
    local status=0
    (cd "$REPO" && "$VENV/bin/python" -m pytest "$@") || status=$?
    [[ $status -eq 5 ]] && say "error: pytest collected no tests"
    return "$status"
}

main() {
    local command="${1:-}"
    [[ $# -gt 0 ]] && shift
    case "$command" in
        demo) enter_environment; ensure_environment; run_demo "$@" ;;
        test) enter_environment; ensure_environment; run_tests "$@" ;;
        setup) enter_environment; ensure_environment ;;
        *) sed -n '2,11p' "${BASH_SOURCE[0]}" | sed 's/^# \{0,1\}//' >&2; exit 2 ;;
    esac
}

main "$@"
