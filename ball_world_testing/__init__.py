"""What the tests (test/) and the soak runs (benchmarks/soak.py) share: see harness.py.

A package of its own at the repository root, not installed with ball_world (setup.py takes
only ball_world), so that both import it by name: `python -m pytest`, `colcon test` and
`python -m benchmarks.soak` all run with the repository root on sys.path. The tests folder
could not serve: as a package named `test` it would shadow the standard library's.
"""
