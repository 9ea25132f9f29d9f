# The commands of the README. Each sets everything up first (scripts/setup.sh is fast when
# nothing changed), so they work on a fresh clone.
.PHONY: run view demo test setup setup-run bench soak learn
VENV := .venv
# Steps of the main job (60 Hz): 1800 is 30 s; 0 runs until Ctrl-C.
STEPS ?= 1800
# Steps of make view: 0 runs until Ctrl-C.
VIEW_STEPS ?= 0
# Arguments of the benchmark and of the soak runs, e.g. make soak ARGS='kill --times 10', and
# the world's ROS arguments in make view / make demo, e.g. make view ARGS='-p agents:=[ball_0]'.
ARGS ?=
# A world's parameters file for make view / make demo, e.g. make view WORLD=worlds/sandbox.yaml.
WORLD ?=

setup:
	@scripts/setup.sh

# What run, view and demo wait for: the numba kernels they do not use (exact mode) and the
# tests' copy are compiled in the background (scripts/setup.sh).
setup-run:
	@scripts/setup.sh --for-run

run: setup-run
	mkdir -p runs
	$(VENV)/bin/ball_world --ros-args --params-file config/ball_world.yaml -p max_steps:=$(STEPS) \
	  -p record.overwrite:=true -p record.mcap:=runs/ball_world.mcap -p record.rerun:=runs/ball_world.rrd
	$(VENV)/bin/ball_world_info runs/ball_world.mcap
	@echo 'Look at the run: $(VENV)/bin/rerun runs/ball_world.rrd  (Rerun viewer)'
	@echo '  or open runs/ball_world.mcap in Foxglove with foxglove/ball_world.json (layout),'
	@echo '  or play it: $(VENV)/bin/ball_world_replay runs/ball_world.mcap  (ros2 bag play with ROS 2 Jazzy)'

# A world live in a browser (WORLD=, ARGS=): prints the address; Ctrl-C stops the node and the
# server.
view: setup-run
	@STEPS=$(VIEW_STEPS) WORLD='$(WORLD)' ARGS='$(ARGS)' scripts/view.sh

# Robots among balls live in a browser: one wandering (or driven by POLICY=runs/navigate_ppo.zip
# after make learn), one tracking, yours to drive.
demo: setup-run
	@set -f; $(VENV)/bin/ball_world_demo $(if $(WORLD),--world '$(WORLD)') $(if $(POLICY),--policy '$(POLICY)') --ros-args $(ARGS)

# Two pytest workers: three were faster (453 s against 563 s) but, with DDS discovery slower
# under the load, one run of three had two tests wait out their deadline (docs/performance.md).
test: setup
	$(VENV)/bin/python -m pytest -q -n 2 test

bench: setup
	$(VENV)/bin/python -m benchmarks.bench $(ARGS)

soak: setup
	$(VENV)/bin/python -m benchmarks.soak $(ARGS)

# PPO (stable-baselines3) on ball_world/Navigate-v0 in the sandbox, then its success rate over
# 100 seeded episodes (docs/learning.md). Installs stable-baselines3 and torch first
# (requirements/learn.txt; never part of make setup or make test). ARGS: ball_world_learn
# train's options, e.g. make learn ARGS='--minutes 5 --out runs/mine.zip'.
learn: setup
	@scripts/learn.sh $(ARGS)
