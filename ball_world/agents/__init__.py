"""The agents as one part: balls that are robots, over arrays, beside the World.

`part.AgentPart` holds them (core.agents' headings and commands, core.odometry's drifting
odometry, the scanners of ball_world.scans) and is what the Simulation calls: once before a
step (commands -> the drive's impulses), around it (the headings turned, the contact and the
odometry measured) and once after it (odometry, ground truth, bumpers, scans and /tf ->
the StepRecord's AgentFrame, `frames`). Its parameters are read once, when it is made from
them; nothing of it climbs back up through the Simulation.
"""
