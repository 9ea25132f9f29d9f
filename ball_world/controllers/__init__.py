"""Controllers that ship with ball_world: examples to run and to copy.

A controller is a class made with no arguments whose `act(obs)` gets every agent it drives
at once (agents.control.Observation) and returns an (N, 3) array of body-frame commands
(vx, vy, wz). Run one in the node (`-p controller:=ball_world.controllers.wander:Wander`) or
headless (`ball_world_sim --params-file FILE.yaml --controller ...`); docs/agents.md.

- `wander.Wander`: Stage's wander for a swarm: cruise, turn away from what the scan sees
  ahead, back off after a bump, and now and then a random turn.
- `flocking.Flocking`: Reynolds' boids: separation, alignment and cohesion among the robots
  within a radius, and the scan's obstacles kept away; a reason to drive many robots from
  one place (each robot needs its neighbours' poses).
"""
