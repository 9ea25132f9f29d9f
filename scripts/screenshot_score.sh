#!/usr/bin/env bash
# docs/scoring.png: a scored run in Rerun, rendered headless by the native viewer.
#
# Records 7 s of the default world with ball_0 driving a circle (scripts/score_run.py),
# scores it with the example tracker (ball_world_score --rerun) and takes the viewer's
# screenshot at the last scan. Needs Debian's xvfb and mesa-vulkan-drivers, as
# scripts/screenshot_hero.sh does:  apt-get install -y xvfb xauth mesa-vulkan-drivers
# Usage: scripts/screenshot_score.sh [OUT.png]
set -euo pipefail
cd "$(dirname "$0")/.."
output=${1:-docs/scoring.png}
scripts/setup.sh
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT
rerun_bin=$(.venv/bin/python -c 'import pathlib, rerun_cli; print(pathlib.Path(rerun_cli.__file__).parent / "rerun")')

.venv/bin/python scripts/score_run.py "$work/run.mcap"
.venv/bin/ball_world_score "$work/run.mcap" --rerun "$work/scored.rrd"
xvfb-run -a -s '-screen 0 1600x900x24' \
  env VK_ICD_FILENAMES=/usr/share/vulkan/icd.d/lvp_icd.x86_64.json \
  "$rerun_bin" "$work/scored.rrd" --window-size 1600x900 --screenshot-to "$work/raw.png" \
  > "$work/viewer.log" 2>&1 || { cat "$work/viewer.log" >&2; exit 1; }
# Drop the top bar (36 points = 72 pixels), then back to 1600 pixels wide.
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
