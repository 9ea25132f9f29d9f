#!/usr/bin/env bash
# The README's picture, docs/screenshot.png: records a 5 s run with one push
# (scripts/hero_run.py) and renders it in the native Rerun viewer, headless.
#
# Needs Debian's xvfb and mesa-vulkan-drivers (software Vulkan):
#   apt-get install -y xvfb xauth mesa-vulkan-drivers
# The viewer's top bar is cropped: under a software renderer (and in a container) it shows
# warning badges that a user's viewer would not. Usage: scripts/screenshot_hero.sh [OUT.png]
set -euo pipefail
cd "$(dirname "$0")/.."
output=${1:-docs/screenshot.png}
scripts/setup.sh
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT
rerun_bin=$(.venv/bin/python -c 'import pathlib, rerun_cli; print(pathlib.Path(rerun_cli.__file__).parent / "rerun")')

.venv/bin/python scripts/hero_run.py "$work/hero.rrd"
# --screenshot-to waits for the recording to load, saves the window and quits. The window
# is 1600x900 logical points, rendered at twice that.
xvfb-run -a -s '-screen 0 1600x900x24' \
  env VK_ICD_FILENAMES=/usr/share/vulkan/icd.d/lvp_icd.x86_64.json \
  "$rerun_bin" "$work/hero.rrd" --window-size 1600x900 --screenshot-to "$work/raw.png" \
  > "$work/viewer.log" 2>&1 || { cat "$work/viewer.log" >&2; exit 1; }
# Drop the top bar (36 points = 72 pixels), then back to 1600 pixels wide (with Pillow,
# which matplotlib brings into .venv).
.venv/bin/python - "$work/raw.png" "$output" <<'CROP'
import sys
from PIL import Image
raw = Image.open(sys.argv[1])
cropped = raw.crop((0, 72, raw.width, raw.height))
width = 1600
cropped.resize((width, round(cropped.height * width / cropped.width)), Image.LANCZOS).save(
    sys.argv[2])
CROP
echo "wrote $output"
