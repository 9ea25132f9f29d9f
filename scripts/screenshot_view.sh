#!/usr/bin/env bash
# Screenshots of `make view` (ball_world_view) of a world, in headless Chromium, light and
# dark: runs/screenshots/view-<name>-<theme>-<S>s.png, measured with scripts/contrast.py.
#
# Needs Debian's chromium and puppeteer-core (scripts/screenshot_web.js says how). Runs the
# view on its own ports and DDS domain (VIEW_WEB_PORT, VIEW_GRPC_PORT, ROS_DOMAIN_ID), opens
# the page OPEN_AFTER seconds after the view started (default 5) once per theme (THEMES) and
# takes shots SHOTS seconds after it loaded (default 15,40).
# Usage: scripts/screenshot_view.sh [WORLD.yaml]   (default worlds/depot.yaml)
set -euo pipefail
cd "$(dirname "$0")/.."
world=${1:-worlds/depot.yaml}
name=$(basename "$world" .yaml)
web=${VIEW_WEB_PORT:-9290}
grpc=${VIEW_GRPC_PORT:-9876}
export ROS_DOMAIN_ID=${ROS_DOMAIN_ID:-78} ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST
export NODE_PATH=${NODE_PATH:-$HOME/tools/puppeteer/node_modules}
mkdir -p runs/screenshots
url="http://127.0.0.1:$web/?url=rerun%2Bhttp%3A%2F%2F127.0.0.1%3A$grpc%2Fproxy"
for theme in ${THEMES:-light dark}; do
  .venv/bin/ball_world_view --world "$world" --web-port "$web" --grpc-port "$grpc" \
    --log-dir runs/screenshots/view-logs > "runs/screenshots/view-$name-$theme.out" 2>&1 &
  view=$!
  trap 'kill -INT $view 2>/dev/null; wait $view' EXIT
  sleep "${OPEN_AFTER:-5}"
  echo "$theme: page opened $(date -u +%H:%M:%S) UTC, load $(cut -d' ' -f1-3 /proc/loadavg)"
  THEME=$theme node scripts/screenshot_web.js "$url" "runs/screenshots/view-$name-$theme" \
    "${SHOTS:-15,40}" | grep -v 'request' || true
  kill -INT "$view"; wait "$view" || true
  trap - EXIT
done
shots=${SHOTS:-15,40}
.venv/bin/python scripts/contrast.py runs/screenshots/view-"$name"-*-"${shots##*,}"s.png
