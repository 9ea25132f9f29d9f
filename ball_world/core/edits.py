"""Edits of a running world: which balls exist under which names, and which edits are valid.

Why a module of its own: an edit (spawn, delete, set state) reaches the world from the
standard simulation_interfaces services of the node and, identically, from a recording
being re-simulated; the rules must be one piece of code. No ROS here: the node turns
requests into these calls and EditRefused kinds into the standard's result codes.

Names. Every ball has an entity name for its life: `ball_<i>` for the balls a world starts
with, the requested name (or a generated `ball_<k>`) for spawned ones. Names are never
reused within a segment (from a start or reset to the next), so an impulse or a state
request for a deleted ball can never reach another ball that took its name.
"""
from dataclasses import dataclass
import math
import re

import numpy as np
import yaml

from ball_world.core import limits
from ball_world.core.parameters import number_text
from ball_world.core.stepping import reachable_speed, speed_limit, travel_per_substep

#: A name: a letter, then letters, digits or underscores (usable as a frame id and in YAML).
NAME_PATTERN = re.compile(r'[A-Za-z][A-Za-z0-9_]*')
#: Longest resource_string accepted, characters.
MAX_RESOURCE_LENGTH = 4096
#: Most balls one SpawnEntities request may ask for.
MAX_SPAWN_BATCH = 1_000
#: A spawned ball's radius and mass when its resource_string does not give them.
DEFAULT_RADIUS = 0.2
DEFAULT_DENSITY = 1.0
#: The one kind of entity the world spawns (GetSpawnables lists it).
BALL_URI = 'ball'
RESOURCE_FORMAT = ('YAML or JSON mapping, all keys optional: radius (m, default '
                   f'{DEFAULT_RADIUS}), mass (kg, default {DEFAULT_DENSITY:g} kg/m^2 x area), '
                   'velocity ([vx, vy] in m/s, default [0, 0]), agent (true: a robot driven '
                   'by <name>/cmd_vel, default false)')

# What an edit can be refused for (the node maps each to the standard's result code).
NAME_NOT_UNIQUE = 'name_not_unique'
NAME_INVALID = 'name_invalid'
NO_RESOURCE = 'no_resource'
UNSUPPORTED_FORMAT = 'unsupported_format'
NAMESPACE_INVALID = 'namespace_invalid'
RESOURCE_PARSE_ERROR = 'resource_parse_error'
INVALID_POSE = 'invalid_pose'
NOT_FOUND = 'not_found'
TOO_MANY = 'too_many'


class EditRefused(ValueError):
    """An edit that must not touch the world; `kind` says why, the message how to fix it."""

    def __init__(self, kind, message):
        super().__init__(message)
        self.kind = kind


@dataclass(frozen=True)
class Ball:
    """A ball to spawn: where, how fast, how large and heavy."""

    x: float
    y: float
    vx: float
    vy: float
    radius: float
    mass: float


#: The YAML loader: libyaml's when PyYAML has it (about 100 times faster than pure Python).
_LOADER = getattr(yaml, 'CSafeLoader', yaml.SafeLoader)
#: Most YAML events (nodes, starts and ends) a resource_string may hold: the format needs
#: about 15, and counting stops here, so no input costs more than this to look at.
MAX_RESOURCE_EVENTS = 64
#: Deepest nesting of mappings and sequences in a resource_string (the format needs 2).
MAX_RESOURCE_DEPTH = 4
_OPENS = (yaml.MappingStartEvent, yaml.SequenceStartEvent)
_CLOSES = (yaml.MappingEndEvent, yaml.SequenceEndEvent)


def brief(value, limit=64):
    """A bounded rendering of any value from a request, safe to put in a message.

    Why: repr() of an integer read from 4 KB of YAML can fail (Python's digit limit) or run
    to kilobytes, and a list can hold either; a refusal must never fail or flood.
    """
    if isinstance(value, bool) or value is None or isinstance(value, float):
        return repr(value)
    if isinstance(value, int):
        bits = value.bit_length()
        return repr(value) if bits <= 64 else f'an integer of {bits:,} bits'
    if isinstance(value, str):
        return repr(value[:limit]) + ('...' if len(value) > limit else '')
    if isinstance(value, (list, tuple, dict)):
        count = len(value)
        return f'a {type(value).__name__} of {count:,} item' + ('' if count == 1 else 's')
    return f'a {type(value).__name__}'


def _check_shape(text):
    """Refuse aliases, deep nesting and long documents from the parser's events alone.

    Why: PyYAML composes and constructs recursively (400 brackets raise RecursionError) and
    expands aliases (a 4 KB alias bomb); the event stream shows all three at a bounded cost.
    """
    loader = _LOADER(text)
    try:
        depth = 0
        for count in range(MAX_RESOURCE_EVENTS + 1):
            if not loader.check_event():
                return
            event = loader.get_event()
            if isinstance(event, yaml.AliasEvent):
                raise EditRefused(RESOURCE_PARSE_ERROR, 'resource_string: aliases are not '
                                                        'accepted')
            if isinstance(event, _OPENS):
                depth += 1
                if depth > MAX_RESOURCE_DEPTH:
                    raise EditRefused(RESOURCE_PARSE_ERROR, 'resource_string nests deeper '
                                                            f'than {MAX_RESOURCE_DEPTH} levels')
            elif isinstance(event, _CLOSES):
                depth -= 1
        raise EditRefused(RESOURCE_PARSE_ERROR, 'resource_string holds more than '
                                                f'{MAX_RESOURCE_EVENTS} YAML nodes; expected '
                                                'radius, mass, velocity')
    finally:
        loader.dispose()


def _load(text):
    """The YAML (or JSON) value of a resource_string, or EditRefused saying why not."""
    try:
        _check_shape(text)
        return yaml.load(text, Loader=_LOADER)
    except EditRefused:
        raise
    except yaml.YAMLError as error:
        reason = (str(error).splitlines() or [''])[0][:160]
        raise EditRefused(RESOURCE_PARSE_ERROR, f'resource_string is not YAML: {reason}')
    except Exception as error:  # noqa: B902 - a value YAML reads but Python cannot build
        raise EditRefused(RESOURCE_PARSE_ERROR, 'resource_string cannot be read: '
                                                f'{type(error).__name__}') from None


def _number(value, what):
    if isinstance(value, str):  # YAML 1.1 reads 1.0e6 (no sign) as text
        try:
            value = float(value)
        except ValueError:
            pass
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise EditRefused(RESOURCE_PARSE_ERROR, f'{what} must be a number, got {brief(value)}')
    try:
        value = float(value)
    except OverflowError:
        raise EditRefused(RESOURCE_PARSE_ERROR, f'{what} must be finite, got '
                                                f'{brief(value)}') from None
    if not math.isfinite(value):
        raise EditRefused(RESOURCE_PARSE_ERROR, f'{what} must be finite, got {value}')
    return value


def parse_resource(text):
    """(radius, mass, (vx, vy)) from a spawn request's resource_string (see RESOURCE_FORMAT)."""
    return parse_spawn(text)[:3]


def parse_spawn(text):
    """(radius, mass, (vx, vy), agent) from a resource_string (see RESOURCE_FORMAT).

    Any text gets a result or EditRefused, at a cost bounded by MAX_RESOURCE_LENGTH and
    MAX_RESOURCE_EVENTS.
    """
    if len(text) > MAX_RESOURCE_LENGTH:
        raise EditRefused(RESOURCE_PARSE_ERROR, f'resource_string is {len(text):,} characters; '
                                                f'at most {MAX_RESOURCE_LENGTH} are accepted')
    fields = {}
    if text.strip():
        fields = _load(text)
        if not isinstance(fields, dict):
            raise EditRefused(RESOURCE_PARSE_ERROR, 'resource_string must be a mapping such '
                                                    "as '{radius: 0.2, mass: 1.0}'")
    unknown = [key for key in fields if key not in ('radius', 'mass', 'velocity', 'agent')]
    if unknown:
        raise EditRefused(RESOURCE_PARSE_ERROR, f'unknown key {brief(unknown[0])} in '
                                                'resource_string; expected radius, mass, '
                                                'velocity, agent')
    agent = fields.get('agent', False)
    if not isinstance(agent, bool):
        raise EditRefused(RESOURCE_PARSE_ERROR, f'agent must be true or false, got '
                                                f'{agent!r:.64}')
    radius = _number(fields.get('radius', DEFAULT_RADIUS), 'radius')
    mass = _number(fields['mass'], 'mass') if 'mass' in fields else \
        DEFAULT_DENSITY * math.pi * radius * radius
    velocity = fields.get('velocity', [0.0, 0.0])
    if not isinstance(velocity, (list, tuple)) or len(velocity) != 2:
        raise EditRefused(RESOURCE_PARSE_ERROR, f'velocity must be [vx, vy], got '
                                                f'{brief(velocity)}')
    vx, vy = (_number(v, 'velocity') for v in velocity)
    for what, value, low, high, unit in (
            ('radius', radius, limits.MIN_RADIUS, limits.MAX_RADIUS, 'm'),
            ('mass', mass, limits.MIN_MASS, limits.MAX_MASS, 'kg')):
        if not low <= value <= high:
            raise EditRefused(RESOURCE_PARSE_ERROR, f'{what} {number_text(value)} {unit} is '
                                                    f'outside {number_text(low)} to '
                                                    f'{number_text(high)} {unit}')
    return radius, mass, (vx, vy), agent


def _has_control(text):
    return any(ord(c) < 32 or 127 <= ord(c) < 160 for c in text)


class Entities:
    """The entity names of a world's balls, in the order of its arrays."""

    def __init__(self, count):
        self.names = [f'ball_{i}' for i in range(count)]
        self.index_of = {name: i for i, name in enumerate(self.names)}
        self._retired = set()
        self._next_number = count

    @classmethod
    def restored(cls, names, retired, first_count):
        """The names part-way through a segment: live `names`, deleted `retired`.

        first_count: the balls the segment started with. Generated names count up from
        there past every name used, so the next one is the name the original run gave.
        """
        entities = cls(0)
        entities.append(names)
        entities._retired = set(retired)
        entities._next_number = first_count
        return entities

    def __len__(self):
        return len(self.names)

    def index(self, name):
        """Array index of the ball named `name` (EditRefused NOT_FOUND otherwise)."""
        index = self.index_of.get(name) if isinstance(name, str) else None
        if index is None:
            shown = name[:64] if isinstance(name, str) else repr(name)
            raise EditRefused(NOT_FOUND, f"no entity named '{shown}'")
        return index

    def new_name(self, requested, allow_renaming, taken=()):
        """The name a new ball gets: the requested one if valid and unused, else generated.

        taken: names already given to other balls of the same request.
        """
        if _has_control(requested):
            # Refused even with allow_renaming: a client that sends control characters has
            # a bug to hear about (a NUL cuts the name short on its way into rclpy).
            raise EditRefused(NAME_INVALID, f'name {brief(requested)} holds control '
                                            'characters')
        if requested and NAME_PATTERN.fullmatch(requested) \
                and len(requested) <= limits.MAX_NAME_LENGTH:
            if not self._used(requested, taken):
                return requested
            if not allow_renaming:
                reason = ('was deleted; names are not reused' if requested in self._retired
                          else 'is taken')
                raise EditRefused(NAME_NOT_UNIQUE, f"name '{requested}' {reason}; choose "
                                                   'another or set allow_renaming')
        elif not allow_renaming:
            if not requested:
                raise EditRefused(NAME_INVALID, 'name is empty; give one or set '
                                                'allow_renaming to get a generated name')
            raise EditRefused(NAME_INVALID, f"name '{requested[:64]}' is not a letter followed "
                                            'by letters, digits or underscores (at most '
                                            f'{limits.MAX_NAME_LENGTH} characters)')
        while self._used(f'ball_{self._next_number}', taken):
            self._next_number += 1
        return f'ball_{self._next_number}'

    def _used(self, name, taken):
        return name in self.index_of or name in self._retired or name in taken

    def append(self, names):
        for name in names:
            self.index_of[name] = len(self.names)
            self.names.append(name)

    def remove(self, index):
        """Drop the name at `index`; later balls move down one place, as in the World."""
        name = self.names.pop(index)
        self._retired.add(name)
        del self.index_of[name]
        for i in range(index, len(self.names)):
            self.index_of[self.names[i]] = i
        return name


def _check_pose(x, y, radius, arena, what):
    """The centre is finite and the whole ball lies inside the arena (if there is one)."""
    if not (math.isfinite(x) and math.isfinite(y)):
        raise EditRefused(INVALID_POSE, f'{what} ({x}, {y}) is not finite')
    if max(abs(x), abs(y)) > limits.COORDINATE_LIMIT:
        raise EditRefused(INVALID_POSE, f'{what} ({number_text(x)}, {number_text(y)}) is beyond '
                                        f'{number_text(limits.COORDINATE_LIMIT)} m')
    if arena and not (arena[0] + radius <= x <= arena[2] - radius
                      and arena[1] + radius <= y <= arena[3] - radius):
        raise EditRefused(INVALID_POSE, f'{what} ({number_text(x)}, {number_text(y)}) with '
                                        f'radius {number_text(radius)} m is not inside the '
                                        f'arena [{", ".join(number_text(v) for v in arena)}]')


class Neighbours:
    """A world's balls sorted by x: the balls a new ball could touch, found by bisection.

    Why: a SpawnEntities of 1,000 balls into a world of 99,000 checked each against all N
    balls, 2 s between two steps; a ball can only touch balls whose x is within its radius
    plus the largest radius, a strip of a few balls' width.
    """

    def __init__(self, positions, radii):
        self._order = np.argsort(positions[:, 0], kind='stable')
        self._xs = positions[self._order, 0]
        self._largest = float(radii.max()) if len(radii) else 0.0

    def near(self, x, radius):
        """Indices, ascending, of every ball that might overlap a ball at x (and more)."""
        margin = (radius + self._largest) * (1.0 + 1e-9) + 1e-12  # rounding cannot hide one
        low, high = np.searchsorted(self._xs, (x - margin, x + margin), side='left')
        return np.sort(self._order[low:high + 1])


def first_overlap(x, y, radius, positions, radii, walls, skip=None, near=None):
    """What a ball at (x, y) would overlap: ('ball', index), ('wall', index) or None.

    O(N + M) numpy, or with `near` (Neighbours of these positions) O(log N + strip + M): the
    request path of one spawn or set-state, not the step.
    """
    if len(positions):
        candidates = np.arange(len(positions)) if near is None else near.near(x, radius)
        dx = positions[candidates, 0] - x
        dy = positions[candidates, 1] - y
        reach = radii[candidates] + radius
        overlapping = dx * dx + dy * dy < reach * reach
        if skip is not None:
            overlapping[candidates == skip] = False
        hits = np.flatnonzero(overlapping)
        if len(hits):
            return 'ball', int(candidates[hits[0]])
    if len(walls.starts):
        rx = x - walls.starts[:, 0]
        ry = y - walls.starts[:, 1]
        along = np.clip(rx * walls.directions[:, 0] + ry * walls.directions[:, 1], 0.0,
                        walls.lengths)
        sx = rx - along * walls.directions[:, 0]
        sy = ry - along * walls.directions[:, 1]
        hits = np.flatnonzero(sx * sx + sy * sy < radius * radius)
        if len(hits):
            return 'wall', int(hits[0])
    return None


def check_speeds(energy, min_mass, min_radius, dt_ns, what):
    """Refuse an edit after which some ball could go faster than the world can step."""
    limit = speed_limit(travel_per_substep(min_radius), dt_ns * 1e-9)
    reachable = reachable_speed(energy, min_mass)
    if not reachable <= limit:
        raise EditRefused(INVALID_POSE, f'{what} would give the world enough energy for a ball '
                                        f'to reach {reachable:.3g} m/s, faster than the '
                                        f'{limit:.3g} m/s it can step')


def check_placement(world, entities, arena, x, y, radius, what, skip=None, near=None,
                    cells=None):
    """A ball of `radius` at (x, y) fits: inside, overlapping no other ball, no wall and no
    solid cell of the map.

    near: Neighbours of the world's balls, when many balls are placed in one go. cells: the
    map's core.solid_cells.CellQueries, or None without a map.
    """
    _check_pose(x, y, radius, arena, what)
    if cells is not None:
        hit = cells.first_overlap(x, y, radius)
        if hit is not None:
            raise EditRefused(INVALID_POSE, f'{what} ({number_text(x)}, {number_text(y)}) with '
                                            f'radius {number_text(radius)} m overlaps '
                                            f'{cells.describe(hit)}')
    hit = first_overlap(x, y, radius, world.positions, world.radii, world.walls, skip, near)
    if hit is not None:
        kind, index = hit
        other = f"ball '{entities.names[index]}'" if kind == 'ball' else f'wall {index}'
        raise EditRefused(INVALID_POSE, f'{what} ({number_text(x)}, {number_text(y)}) overlaps '
                                        f'{other}')
