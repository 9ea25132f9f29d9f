# The two commands of the README. Both set everything up first (scripts/setup.sh is fast
# when nothing changed), so they work on a fresh clone.
.PHONY: run test setup
VENV := .venv

setup:
	@scripts/setup.sh

run: setup
	$(VENV)/bin/ball_world_sim

test: setup
	$(VENV)/bin/python -m pytest -q test
