#!/usr/bin/env bash
# Builds the interface packages of interfaces/ (simulation_interfaces, tf2_msgs) into a virtual
# environment of the wheels set-up: no ros-jazzy-* wheel of either exists.
#
#   scripts/build_interfaces.sh VENV [PACKAGE...]     (default: every package in interfaces/)
#
# ROS 2's CMake tools (ament_cmake, the rosidl generators and typesupports) come from the
# ros-jazzy-* wheels of requirements/ros-build-wheels.txt, already in VENV; cmake, make and a
# C/C++ compiler from the system. A package is installed with VENV as its prefix: the Python
# package lands in VENV's site-packages, the libraries in VENV/lib, which the wheels' start-up
# hook (ros_wheels_bootstrapper) puts on LD_LIBRARY_PATH of every VENV/bin/python process.
#
# Only what rclpy loads is generated (scripts/rclpy_typesupports_only.cmake: C and Python, no
# C++), without optimisation (the generated code converts and copies a few service messages; -O3
# cost compile time that no run gets back), the typesupports as unity builds (each target's
# generated files compiled as one: their shared headers parsed once). The packages are built at
# the same time, beside whatever the caller does meanwhile (scripts/setup.sh installs the rest
# of the dependencies, then ball_world, and compiles numba's kernels): on 2 cores the build of
# simulation_interfaces alone is about 35 s of wall time, 45 s of CPU.
#
# Each package is built once and reused: its own stamp in VENV (.ball_world-<package, with
# dashes>) holds a hash of everything its build reads (its definition files, this script, the
# CMake helpers, the requirements), and nothing is done while it matches, so changing one
# package's files rebuilds that package only. A change rebuilds the package from scratch (rosidl
# regenerates every file when one definition changes, so an old build tree saves nothing); the
# tree is deleted after a successful install, the log kept in VENV/build. A failure prints one
# line naming what is missing and exits 1.
set -euo pipefail
cd "$(dirname "$0")/.."

# Earlier versions of this script, by sha256: bc60fd1's built simulation_interfaces alone (before
# the stamps became per package), 1d7d111's built C++ as well (a superset of today's build), and
# neither read scripts/rclpy_typesupports_only.cmake. What they installed serves rclpy as
# today's build does, so a stamp one of them wrote for otherwise unchanged inputs is taken as
# valid (and rewritten in the current form) instead of rebuilding.
previous_script_sha256s=(bf048eacb53e2c5db0a9429a8095d4f18723f7b023d0c1da566e25bdd08ff371
                         18eb1bee2a91f413ebcc9ad4cc38d0c31db04903195f2e8b0867e59beaaab100)

[ $# -ge 1 ] || { echo 'usage: scripts/build_interfaces.sh VENV [PACKAGE...]' >&2; exit 2; }
if [ ! -x "$1/bin/python" ]; then
  echo "setup: cannot build the interface packages: $1/bin/python does not exist" \
       '(run scripts/setup.sh)' >&2
  exit 1
fi
venv=$(realpath "$1")
python=$venv/bin/python
shift
if [ $# -eq 0 ]; then
  set -- $(for manifest in interfaces/*/package.xml; do basename "$(dirname "$manifest")"; done)
fi

# The python statements that load a package's types with their C typesupports, run after the
# install: a package that builds but does not load is a failure.
load_check() {
  case $1 in
    simulation_interfaces) echo '
from rclpy.type_support import check_for_type_support
from simulation_interfaces.action import SimulateSteps
from simulation_interfaces.srv import GetSimulatorFeatures
check_for_type_support(GetSimulatorFeatures)
check_for_type_support(SimulateSteps)' ;;
    tf2_msgs) echo '
from rclpy.type_support import check_for_type_support
from tf2_msgs.action import LookupTransform
from tf2_msgs.msg import TFMessage
from tf2_msgs.srv import FrameGraph
for interface in (TFMessage, FrameGraph, LookupTransform):
    check_for_type_support(interface)' ;;
    *) echo "import $1.msg" ;;
  esac
}

build_package() {
  local name=$1
  local package=interfaces/$name
  local stamp=$venv/.ball_world-${name//_/-}
  local build=$venv/build/$name
  local log=$venv/build/$name.log

  fail() {
    echo "setup: cannot build $name: $*" >&2
    exit 1
  }

  [ -f "$package/package.xml" ] || fail "$package/package.xml does not exist"
  local inputs sums wanted previous previous_sha256
  inputs=$( (find "$package" -type f; echo scripts/build_interfaces.sh;
             echo scripts/wheels_python_paths.cmake; echo scripts/rclpy_typesupports_only.cmake;
             echo requirements/ros-build-wheels.txt; echo requirements/ros-wheels.txt) |
           LC_ALL=C sort)
  # shellcheck disable=SC2086  # the paths hold no spaces
  sums=$(sha256sum $inputs)
  wanted=$(sha256sum <<< "$sums" | cut -d' ' -f1)
  [ "$(cat "$stamp" 2>/dev/null)" = "$wanted" ] && return 0
  for previous_sha256 in "${previous_script_sha256s[@]}"; do
    previous=$(grep -v '  scripts/rclpy_typesupports_only.cmake$' <<< "$sums" |
               sed "s|^[0-9a-f]*\(  scripts/build_interfaces.sh\)\$|$previous_sha256\1|" |
               sha256sum | cut -d' ' -f1)
    if [ "$(cat "$stamp" 2>/dev/null)" = "$previous" ]; then
      echo "$wanted" > "$stamp"
      return 0
    fi
  done

  for tool in cmake make cc c++; do
    command -v "$tool" >/dev/null 2>&1 || fail "'$tool' not found (install cmake, make, gcc and g++)"
  done
  "$python" -c 'import os, sys, sysconfig
sys.exit(not os.path.exists(os.path.join(sysconfig.get_path("include"), "Python.h")))' ||
    fail "the Python headers (Python.h) of $python are missing (install Python 3.12's headers)"

  # Says what is missing, read from the log of the failed step; else the first error line.
  explain_failure() {
    local flat missing
    flat=$(tr -s ' \n' ' ' < "$log")
    if missing=$(grep -o 'configuration file provided by "[^"]*"' <<< "$flat" | head -1) &&
       [ -n "$missing" ]; then
      missing=${missing#*\"}
      fail "CMake package ${missing%\"} is missing (add its ros-jazzy-* wheel to" \
           "requirements/ros-build-wheels.txt); log: $log"
    fi
    if missing=$(grep -o "No module named '[^']*'" "$log" | head -1) && [ -n "$missing" ]; then
      fail "Python module ${missing#No module named } is missing from $venv; log: $log"
    fi
    if grep -q 'No CMAKE_C\(XX\)\?_COMPILER could be found' "$log"; then
      fail "no C/C++ compiler found (install gcc and g++); log: $log"
    fi
    if missing=$(grep -o 'fatal error: [^ ]*: No such file' "$log" | head -1) && [ -n "$missing" ]
    then
      missing=${missing#fatal error: }
      fail "header ${missing%: No such file} is missing; log: $log"
    fi
    fail "$1 failed: $(grep -m1 -E 'CMake Error|[Ee]rror[: ]' "$log" || echo 'see the log'); log: $log"
  }

  local began=$SECONDS
  echo "setup: building $name into $venv (once; simulation_interfaces is the longest step of" \
       "set-up, about 45 s of CPU; log: $log)"
  rm -rf "$build"
  mkdir -p "$build"
  : > "$log"
  cmake -S "$package" -B "$build" -DCMAKE_BUILD_TYPE=None -DBUILD_TESTING=OFF \
    -DCMAKE_INSTALL_PREFIX="$venv" -DCMAKE_PREFIX_PATH="$venv" -DPython3_EXECUTABLE="$python" \
    -DCMAKE_PROJECT_INCLUDE_BEFORE="$PWD/scripts/rclpy_typesupports_only.cmake" \
    -DCMAKE_PROJECT_INCLUDE="$PWD/scripts/wheels_python_paths.cmake" >> "$log" 2>&1 ||
    explain_failure configure
  cmake --build "$build" --parallel "$(nproc)" >> "$log" 2>&1 || explain_failure build
  cmake --install "$build" >> "$log" 2>&1 || explain_failure install

  "$python" -c "$(load_check "$name")" >> "$log" 2>&1 ||
    fail "the installed types do not load in $python; log: $log"
  rm -rf "$build"
  echo "$wanted" > "$stamp"
  echo "setup: built $name in $((SECONDS - began)) s"
}

# rosidl looks up the available typesupports in the ament index of these prefixes.
export AMENT_PREFIX_PATH="$venv${AMENT_PREFIX_PATH:+:$AMENT_PREFIX_PATH}"
# Every package at once (each is its own subshell, so a failure's exit ends only that one); the
# script fails when any of them did, after all have finished.
builds=()
for name in "$@"; do
  build_package "$name" &
  builds+=($!)
done
status=0
for build in "${builds[@]}"; do
  wait "$build" || status=1
done
exit $status
