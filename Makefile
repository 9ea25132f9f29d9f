# The two commands of the README. Both set everything up first (scripts/setup.sh is fast
# when nothing changed), so they work on a fresh clone.
.PHONY: run test setup
VENV := .venv
# Steps of the main job (60 Hz): 1800 is 30 s; 0 runs until Ctrl-C.
STEPS ?= 1800

setup:
	@scripts/setup.sh

run: setup
	$(VENV)/bin/ball_world --ros-args --params-file config/ball_world.yaml -p max_steps:=$(STEPS)

test: setup
	$(VENV)/bin/python -m pytest -q test
