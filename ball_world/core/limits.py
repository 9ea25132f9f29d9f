"""The largest and smallest worlds ball_world promises to step, in one place.

Why limits at all: every number a user can type (a parameter, a spawn request, an impulse, a
value in a recording) reaches the core, and a value that is merely valid can still make a
step take hours (a radius of 1e-300 m needs 1e8 substeps), overflow (two masses of 1e308 kg
add to infinity) or exhaust memory (10 million balls). Inside these limits every world
steps in bounded time and memory; outside them it is refused with one line naming the value.
The node, the scenario builder, the services and the offline tools all check against this
module, so a recording can never hold a world the node would refuse.
"""

#: Balls in one world (explicit, random and spawned together).
MAX_BALLS = 100_000
#: Wall segments in one world, the arena's four included.
MAX_WALLS = 1_000
#: Largest |x| or |y| of a ball centre, a wall end point or an arena edge, m. At 1e6 m a
#: float64 still resolves 1.2e-10 m.
COORDINATE_LIMIT = 1e6
#: Radius of a ball, m.
MIN_RADIUS = 1e-3
MAX_RADIUS = 1e3
#: Largest radius over smallest radius within one world. The broadphase's hierarchical grid
#: keeps candidates O(N) at any ratio; the substeps are planned on the smallest radius, so
#: the ratio bounds how much finer than its size a large ball's motion is cut.
MAX_RADIUS_RATIO = 100.0
#: Mass of a ball, kg.
MIN_MASS = 1e-6
MAX_MASS = 1e6
#: Shortest wall segment, m.
MIN_WALL_LENGTH = 1e-6
#: Substeps one seed-mode step may need: no ball may be fast enough to need more (initial
#: velocities, impulses, set states; collisions cannot exceed it because the bound is taken
#: on the energy, see core.world.World.reachable_speed).
MAX_SUBSTEPS = 1_000
#: Simulated seconds per step, s (dt is kept in whole nanoseconds, at least 1 ns).
MAX_DT = 3600.0
#: Simulation time fits builtin_interfaces/Time (int32 seconds): a run stops before it.
MAX_SIM_TIME_NS = (2**31 - 1) * 10**9
#: Length of a frame id or an entity name, characters.
MAX_NAME_LENGTH = 256
#: Cells of a map (core.occupancy_map): 4096 x 4096, eight times a 2-million-cell warehouse
#: at 3 cm. Its grid, solid cells and /map message take about 16 MB each at this size, and
#: decoding it about 200 MB for a moment; every cell is encoded and recorded with numpy.
MAX_MAP_CELLS = 16_777_216
#: Boundary runs of a map (core.static_geometry.boundary_runs: edges between a solid and a
#: free cell, merged along each grid line), counted from the grid before anything is built
#: from them: every run is a segment the physics indexes. A checkerboard of the largest map
#: would make 33 million (several GB of index); a 4096 x 4096 SLAM map with 2% speckle makes
#: 1.3 million. At this limit the worst case builds within the figures of
#: docs/performance.md (Loading a map: the worst maps inside the limits).
MAX_MAP_RUNS = 2_097_152
#: Bytes of a map's image file: the largest map as a 16-bit ASCII PGM (up to 6 bytes a cell,
#: 100 MB) or an uncompressed colour PNG fits.
MAX_MAP_IMAGE_BYTES = 128 << 20
#: Bytes of a map's YAML file (nav2's are about 150).
MAX_MAP_YAML_BYTES = 64 << 10
#: Smallest map resolution, m per cell (SLAM maps use 1 to 10 cm; a ball is at least
#: MIN_RADIUS).
MIN_MAP_RESOLUTION = 1e-3
