"""How Rerun draws an agent's lidar scan: a fan of rays from the robot, and the points they hit.

What RViz's LaserScan display shows as points alone is here also the beams themselves, thin
and translucent, from the scanner (the agent's centre) to each return: at a glance the fan
says which robot sees what, and where it sees nothing (a beam with no return, +inf, draws
no ray). The hit points are drawn over the balls, the rays under them.
"""
import numpy as np
import rerun as rr

from ball_world.scans import hit_points

#: Entity path of the scans: a file's each at arena/scans/<name>; a live view's all at
#: arena/scans itself, one entity (one message per flush, whatever the number of robots).
SCANS = 'arena/scans'
#: Cyan: no ball has it; the hit points keep 3:1 on both viewer themes, the rays are faint.
SCAN_COLOR = (0, 160, 220)
RAY_ALPHA = 90
#: At most this many rays per scan (every k-th beam; every hit point is drawn): 360 rays of
#: two robots filled the arena, and cost a software-rendered web viewer its frame rate.
MAX_RAYS = 72
#: A live view's hit points per scan at most: a view is sent what it can show (two robots'
#: full scans were 80% of what a view got, ten times a second).
VIEW_MAX_POINTS = 180
#: A live view's rays per frame, all robots together: each robot gets its share (at most
#: MAX_RAYS), and none below MIN_RAYS. Twenty robots' 72 rays each were a blue mesh over the
#: whole depot in which robots, balls and racks could not be told apart; its hit points
#: alone outline what each robot sees.
VIEW_RAY_BUDGET = 144
MIN_RAYS = 12


def view_rays(robots):
    """Rays a live view draws per scan with this many robots (VIEW_RAY_BUDGET): 72 for one
    or two, 48 for three, none from thirteen on (hit points only)."""
    share = VIEW_RAY_BUDGET // max(robots, 1)
    return min(MAX_RAYS, share) if share >= MIN_RAYS else 0


#: Under the balls (30) and the trails (10); the hit points over the balls.
RAY_ORDER = 5.0
HIT_ORDER = 35.0


def scan_geometry(scan, x, y, yaw, max_points=None, max_rays=MAX_RAYS):
    """(rays (n, 2, 2), hits (m, 2)) float32 of one scan taken at (x, y) facing yaw: a ray
    from the scanner along every k-th beam to its return (at most max_rays), and the hit
    points (every return, or of every k-th beam so that at most max_points are drawn)."""
    every = 1 if max_points is None else max(1, -(-len(scan.ranges) // max_points))
    hits = hit_points(_every(scan, every), x, y, yaw).astype(np.float32)
    if max_rays <= 0:
        return np.zeros((0, 2, 2), dtype=np.float32), hits
    every = max(1, -(-len(scan.ranges) // max_rays))
    ends = hit_points(_every(scan, every), x, y, yaw).astype(np.float32)
    rays = np.empty((len(ends), 2, 2), dtype=np.float32)
    rays[:, 0] = (x, y)
    rays[:, 1] = ends
    return rays, hits


def layers(rays, hits):
    """rr archetypes of rays and hit points (of one scan or of several)."""
    return [rr.LineStrips2D(rays, radii=rr.Radius.ui_points(0.75),
                            colors=(*SCAN_COLOR, RAY_ALPHA), draw_order=RAY_ORDER),
            rr.Points2D(hits, radii=rr.Radius.ui_points(2.0), colors=SCAN_COLOR,
                        draw_order=HIT_ORDER)]


def scan_layers(scan, x, y, yaw, max_points=None):
    """rr archetypes of one scan (scan_geometry): the rays and the hit points."""
    return layers(*scan_geometry(scan, x, y, yaw, max_points))


def view_layers(geometries):
    """rr archetypes of several scans' (rays, hits) drawn together (a live view's)."""
    geometries = list(geometries)
    rays = (np.concatenate([rays for rays, _ in geometries]) if geometries
            else np.zeros((0, 2, 2), dtype=np.float32))
    hits = (np.concatenate([hits for _, hits in geometries]) if geometries
            else np.zeros((0, 2), dtype=np.float32))
    return layers(rays, hits)


def _every(scan, every):
    """The scan with only every `every`-th beam (from the first): same fan, coarser."""
    if every == 1:
        return scan
    fan = scan.fan._replace(angle_increment=scan.fan.angle_increment * every,
                            samples=len(scan.ranges[::every]))
    return scan._replace(ranges=scan.ranges[::every], fan=fan)
