#!/usr/bin/env bash
# make learn: installs stable-baselines3 and torch into the venv (requirements/learn.txt),
# then trains PPO on ball_world/Navigate-v0 and evaluates it (ball_world_learn train; ARGS are
# its options, e.g. make learn ARGS='--minutes 5').
#
# torch is tried first from the CPU-only wheel index (no CUDA libraries); where that index
# cannot be reached, PyPI's torch comes with its nvidia-* wheels (docs/learning.md).
set -euo pipefail
cd "$(dirname "$0")/.."
venv=${BALL_WORLD_VENV:-.venv}
python=$venv/bin/python
cpu_index=https://download.pytorch.org/whl/cpu
torch_pin=$(grep -E '^torch==' requirements/learn.txt)

# torch at the pinned version (a +cpu build counts): else first from the CPU-only index.
wanted=${torch_pin#torch==}
if ! "$python" -c "import sys, torch; sys.exit(torch.__version__.split('+')[0] != '$wanted')" \
     >/dev/null 2>&1; then
  echo "learn: installing $torch_pin and stable-baselines3 into $venv (requirements/learn.txt)"
  "$python" -m pip install --quiet --no-compile --timeout 15 --retries 1 \
    --index-url "$cpu_index" "$torch_pin" -c requirements/base.txt 2>/dev/null ||
    echo "learn: $cpu_index did not answer: torch from PyPI, with its CUDA wheels (about 3 GB)"
fi
# The rest (seconds when it is all there).
"$python" -m pip install --quiet --no-compile -r requirements/learn.txt -c requirements/base.txt
"$python" -c 'import torch; print("learn: torch", torch.__version__,
               "CPU-only" if torch.version.cuda is None else "(a CUDA build, run on the CPU)")'
exec "$venv/bin/ball_world_learn" train "$@"
