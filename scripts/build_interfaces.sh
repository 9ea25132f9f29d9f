#!/usr/bin/env bash
# Builds the simulation_interfaces types (interfaces/simulation_interfaces) into a virtual
# environment of the wheels set-up: no ros-jazzy-simulation-interfaces wheel exists.
#
#   scripts/build_interfaces.sh VENV
#
# ROS 2's CMake tools (ament_cmake, the rosidl generators and typesupports) come from the
# ros-jazzy-* wheels of requirements/ros-build-wheels.txt, already in VENV; cmake, make and a
# C/C++ compiler from the system. The package is installed with VENV as its prefix: the Python
# package lands in VENV's site-packages, the libraries in VENV/lib, which the wheels' start-up
# hook (ros_wheels_bootstrapper) puts on LD_LIBRARY_PATH of every VENV/bin/python process.
#
# Built once and reused: a stamp in VENV holds a hash of everything the build reads (definition
# files, this script, the CMake helper, the requirements), and nothing is done while it matches.
# Any change rebuilds from scratch (rosidl regenerates every file when one definition changes, so
# an old build tree saves nothing); the tree is deleted after a successful install, the log kept
# in VENV/build. A failure prints one line naming what is missing and exits 1.
set -euo pipefail
cd "$(dirname "$0")/.."

fail() {
  echo "setup: cannot build simulation_interfaces: $*" >&2
  exit 1
}

[ $# -eq 1 ] || { echo 'usage: scripts/build_interfaces.sh VENV' >&2; exit 2; }
[ -x "$1/bin/python" ] || fail "$1/bin/python does not exist (run scripts/setup.sh)"
venv=$(realpath "$1")
python=$venv/bin/python
package=interfaces/simulation_interfaces
stamp=$venv/.ball_world-simulation-interfaces
build=$venv/build/simulation_interfaces
log=$venv/build/simulation_interfaces.log

inputs=$( (find "$package" -type f; echo scripts/build_interfaces.sh;
           echo scripts/wheels_python_paths.cmake; echo requirements/ros-build-wheels.txt;
           echo requirements/ros-wheels.txt) | LC_ALL=C sort)
# shellcheck disable=SC2086  # the paths hold no spaces
wanted=$(sha256sum $inputs | sha256sum | cut -d' ' -f1)
[ "$(cat "$stamp" 2>/dev/null)" = "$wanted" ] && exit 0

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

echo "setup: building simulation_interfaces into $venv (about 4 minutes on 2 cores, once)"
rm -rf "$build"
mkdir -p "$build"
: > "$log"
# rosidl looks up the available typesupports in the ament index of these prefixes.
export AMENT_PREFIX_PATH="$venv${AMENT_PREFIX_PATH:+:$AMENT_PREFIX_PATH}"
cmake -S "$package" -B "$build" -DCMAKE_BUILD_TYPE=Release -DBUILD_TESTING=OFF \
  -DCMAKE_INSTALL_PREFIX="$venv" -DCMAKE_PREFIX_PATH="$venv" -DPython3_EXECUTABLE="$python" \
  -DCMAKE_PROJECT_INCLUDE="$PWD/scripts/wheels_python_paths.cmake" >> "$log" 2>&1 ||
  explain_failure configure
cmake --build "$build" --parallel "$(nproc)" >> "$log" 2>&1 || explain_failure build
cmake --install "$build" >> "$log" 2>&1 || explain_failure install

"$python" -c '
from rclpy.type_support import check_for_type_support
from simulation_interfaces.action import SimulateSteps
from simulation_interfaces.srv import GetSimulatorFeatures
check_for_type_support(GetSimulatorFeatures)
check_for_type_support(SimulateSteps)' >> "$log" 2>&1 ||
  fail "the installed types do not load in $python; log: $log"
rm -rf "$build"
echo "$wanted" > "$stamp"
