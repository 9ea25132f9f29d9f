"""How Rerun draws a map (core.occupancy_map): its cells as one image, at the map's place.

A module of its own so rerun_log.py only calls it. The grid is logged once as a
SegmentationImage (one byte per cell: a 2-million-cell map is 2 MB, whatever its walls), under
a transform that puts cell (column i, row j) on the square of side `resolution` at
(origin_x + i resolution, origin_y + j resolution), below the arena's +y-up flip, so the map
lies exactly where the physics has it. Its classes are coloured by an AnnotationContext:
free cells transparent, occupied ones the walls' colour, unknown ones a dim grey, and scale
mode's 1-99 shades in between. Static: the map is read once per run (`map` is read-only), and
a late page of a live view gets it.
"""
import numpy as np
import rerun as rr

from ball_world.core.occupancy_map import OCCUPIED, UNKNOWN

#: Entity paths, under the arena's +y-up transform.
MAP = 'arena/map'
MAP_CELLS = 'arena/map/cells'
#: Class ids of the image: a map value v in 0..100 is class v + 1; unknown (-1) is class 0.
UNKNOWN_CLASS = 0
#: Colours (RGBA): unknown cells dim, occupied ones as the walls, free ones not drawn.
UNKNOWN_COLOR = (110, 110, 120, 110)
DRAW_ORDER = -20.0


def map_classes(data):
    """uint8 class of each cell of an int8 grid (see UNKNOWN_CLASS)."""
    return (np.asarray(data, dtype=np.int16) + 1).clip(0, OCCUPIED + 1).astype(np.uint8)


def annotation_context(wall_color):
    """The classes' colours: 0 unknown, 1 free (transparent), 101 occupied, the shades of a
    scale-mode map between (their alpha grows with the occupancy)."""
    red, green, blue = wall_color[:3]
    infos = [rr.AnnotationInfo(id=UNKNOWN_CLASS, label='unknown', color=UNKNOWN_COLOR)]
    for value in range(0, OCCUPIED + 1):
        alpha = round(255 * value / OCCUPIED)
        label = 'free' if value == 0 else 'occupied' if value == OCCUPIED else f'{value}%'
        infos.append(rr.AnnotationInfo(id=value + 1, label=label,
                                       color=(red, green, blue, alpha)))
    return rr.AnnotationContext(infos)


def map_entities(occupancy_map, wall_color):
    """[(entity path, archetype)] that draw the map: its transform and colours, its cells."""
    x, y = occupancy_map.origin
    resolution = occupancy_map.resolution
    return [
        (MAP, rr.Transform3D(translation=(x, y, 0.0), scale=(resolution, resolution, 1.0))),
        (MAP, annotation_context(wall_color)),
        (MAP_CELLS, rr.SegmentationImage(map_classes(occupancy_map.data), opacity=1.0,
                                         draw_order=DRAW_ORDER)),
    ]


def map_bounds(occupancy_map):
    """(xmin, ymin, xmax, ymax) of the map's known cells (free or occupied), m: what a view
    fits. A SLAM map is mostly unknown around the building (the sandbox is 19.2 m square
    for a room of 5 m); the whole grid when no cell is known."""
    known = occupancy_map.data != UNKNOWN
    rows = np.flatnonzero(known.any(axis=1))
    columns = np.flatnonzero(known.any(axis=0))
    if not len(rows):
        rows = np.array([0, occupancy_map.height - 1])
        columns = np.array([0, occupancy_map.width - 1])
    x, y = occupancy_map.origin
    resolution = occupancy_map.resolution
    return (float(x + columns[0] * resolution), float(y + rows[0] * resolution),
            float(x + (columns[-1] + 1) * resolution), float(y + (rows[-1] + 1) * resolution))
