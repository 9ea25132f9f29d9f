#!/usr/bin/env bash
# docs/demo.png, the README's top picture: `make demo` (ball_world_demo) in headless Chromium,
# robots among balls with their scans as fans, the map (or walls) and the tracker's rings.
#
# Needs Debian's chromium and puppeteer-core (scripts/screenshot_web.js says how). Runs the
# demo on its own ports and DDS domain (DEMO_WEB_PORT, DEMO_GRPC_PORT, ROS_DOMAIN_ID), opens
# the page, takes shots at SHOTS seconds after it loaded (default 10,40,70) into
# runs/screenshots/, light and dark (THEMES), measures their contrast (scripts/contrast.py)
# and copies the light one at PICK seconds (default 70) to OUT (default docs/demo.png).
# OPEN_AFTER=S opens the page S seconds after the demo started (default 2): a page opened
# late, which should show the present within seconds. After the shots it prints the world's
# progress lines (step and wall time), to compare with the simulated time each shot shows.
# Usage: scripts/screenshot_demo.sh [OUT.png]
set -euo pipefail
cd "$(dirname "$0")/.."
output=${1:-docs/demo.png}
web=${DEMO_WEB_PORT:-9190}
grpc=${DEMO_GRPC_PORT:-9976}
shots=${SHOTS:-10,40,70}
pick=${PICK:-70}
export ROS_DOMAIN_ID=${ROS_DOMAIN_ID:-77} ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST
export NODE_PATH=${NODE_PATH:-$HOME/tools/puppeteer/node_modules}
mkdir -p runs/screenshots
url="http://127.0.0.1:$web/?url=rerun%2Bhttp%3A%2F%2F127.0.0.1%3A$grpc%2Fproxy"
for theme in ${THEMES:-light dark}; do
  .venv/bin/ball_world_demo --web-port "$web" --grpc-port "$grpc" \
    --log-dir runs/screenshots/demo-logs > "runs/screenshots/demo-$theme.out" 2>&1 &
  demo=$!
  trap 'kill -INT $demo 2>/dev/null; wait $demo' EXIT
  sleep "${OPEN_AFTER:-2}"
  echo "$theme: page opened $(date -u +%H:%M:%S) UTC, load $(cut -d' ' -f1-3 /proc/loadavg)"
  THEME=$theme node scripts/screenshot_web.js "$url" "runs/screenshots/demo-$theme" "$shots"
  grep -h 'step' runs/screenshots/demo-logs/world.log | tail -n 12 || true
  kill -INT "$demo"; wait "$demo" || true
  trap - EXIT
done
.venv/bin/python scripts/contrast.py runs/screenshots/demo-*-"$pick"s.png
cp "runs/screenshots/demo-light-${pick}s.png" "$output"
echo "wrote $output"
