#!/usr/bin/env bash
# make view: a world live in a browser (ball_world_view, ball_world/tools/view.py, does it all).
#
# Environment: WORLD (a parameters file), ARGS (ROS arguments, e.g. '-p agents:=[ball_0]'),
# STEPS (stop after this many steps; 0: until Ctrl-C), VIEW_GRPC_PORT / VIEW_WEB_PORT (the
# stream's and the page's ports), VIEW_SERVER_MEMORY (what the server keeps for late pages).
set -euo pipefail
cd "$(dirname "$0")/.."
set -f  # ARGS is split into words as a shell would, but '[ball_0]' is no file pattern
world=()
if [ -n "${WORLD:-}" ]; then world=(--world "$WORLD"); fi
# shellcheck disable=SC2086  # ARGS is meant to be split
exec .venv/bin/ball_world_view "${world[@]}" --steps "${STEPS:-0}" \
  --grpc-port "${VIEW_GRPC_PORT:-9876}" --web-port "${VIEW_WEB_PORT:-9090}" \
  --server-memory "${VIEW_SERVER_MEMORY:-256KiB}" --ros-args ${ARGS:-}
