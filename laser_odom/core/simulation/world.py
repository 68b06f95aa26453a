"""Simulated 2D worlds: walls as line segments, a robot path, and a registry by name.

Every world is laid out so that its robot path starts at the origin heading along
+x; the world frame is therefore also the odometry frame of the simulated robot.

- ``office`` (default): two rooms, a corridor, a hall with pillars and an open area
  with clutter; rich structure, the demo world. The loop starts in the hall.
- ``corridor``: a ring of 2 m corridors with side doors, niches, side rooms and a
  T-junction, so that motion along the corridors stays observable.
- ``cluttered``: a hall with many boxes and pillars placed by a seeded generator.
- ``featureless_corridor``: a 200 m straight corridor with smooth parallel walls and
  nothing else within 60 m of the path: translation along it is unobservable.
- ``campus``: an outdoor campus of 150 x 100 m, six buildings 25-37 m long (recessed
  entrances with canopy columns, a courtyard) 20-30 m apart, trees in clusters and an
  avenue, and open ground around: in the open directions a beam returns nothing. A
  220 m loop of paths between the buildings.
- ``hall``: a 60 x 30 m convention hall, 0.5 m pillars on a 10 m grid and booths with
  open sides; a 120 m loop whose long middle aisle is 15 m or more from every wall,
  beyond the range of a 12 m lidar.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property, lru_cache
from typing import Callable

import numpy as np

from laser_odom.core.simulation import geometry as geo
from laser_odom.core.simulation.trajectory import SmoothPath, SpeedProfile


class UnknownWorldError(ValueError):
    """Raised for a world name that is not registered."""


@dataclass(frozen=True, eq=False)
class World:
    """Walls (M, 4) ``[x0, y0, x1, y1]`` and the closed waypoint loop the robot drives."""

    name: str
    description: str
    segments: np.ndarray
    waypoints: np.ndarray
    corner_radius: float = 1.0
    min_clearance: float = 0.4
    """Designed lower bound on the path's distance to any wall [m]."""

    @cached_property
    def path(self) -> SmoothPath:
        """Return the smooth loop the robot drives, built on first use."""
        return SmoothPath(self.waypoints, self.corner_radius, speed=SpeedProfile())

    @property
    def bounds(self) -> tuple[float, float, float, float]:
        """Return ``(xmin, ymin, xmax, ymax)`` of all walls."""
        xs = self.segments[:, [0, 2]]
        ys = self.segments[:, [1, 3]]
        return float(xs.min()), float(ys.min()), float(xs.max()), float(ys.max())


def _freeze(segments: np.ndarray) -> np.ndarray:
    """Return a read-only float copy, so the cached worlds cannot be altered."""
    out = np.array(segments, dtype=float).reshape(-1, 4)
    out.setflags(write=False)
    return out


def _office() -> World:
    """Build rooms, a corridor, a hall with pillars and a cluttered open area (25 x 14.5 m)."""
    walls = geo.stack(
        geo.rectangle(-4.0, -1.5, 21.0, 13.0),
        geo.wall((-4.0, 1.5), (12.0, 1.5), [(0.8, 2.2), (10.5, 11.7)]),
        geo.wall((4.0, 1.5), (4.0, 7.0), [(2.5, 3.5)]),
        geo.wall((-4.0, 7.0), (12.0, 7.0), [(0.8, 2.2), (13.0, 14.2)]),
        geo.wall((12.0, 1.5), (12.0, 13.0), [(1.5, 2.7), (7.7, 9.3)]),
    )
    clutter = geo.stack(
        geo.box(1.0, 4.5, 1.6, 0.8), geo.box(2.8, 3.0, 0.8, 0.8, 0.3),
        geo.box(3.5, 6.5, 0.8, 0.5), geo.pillar(-0.5, 2.8, 0.2),
        geo.box(6.0, 5.0, 2.0, 1.0), geo.box(9.5, 3.0, 1.2, 0.6, 0.4),
        geo.pillar(10.8, 5.8, 0.25), geo.box(5.0, 2.3, 0.6, 0.6),
        geo.pillar(0.0, 8.2, 0.3), geo.pillar(4.0, 11.8, 0.3), geo.pillar(8.0, 8.2, 0.3),
        geo.box(-1.0, 12.6, 2.0, 0.6), geo.box(6.5, 7.5, 1.0, 0.6),
        geo.box(3.0, -1.25, 0.8, 0.5), geo.pillar(9.0, -1.1, 0.2),
        geo.pillar(18.0, 2.5, 0.35), geo.pillar(18.0, 7.0, 0.35), geo.pillar(13.5, 5.0, 0.3),
        geo.box(19.5, 11.5, 1.5, 1.0, 0.2), geo.box(20.0, 0.0, 1.0, 2.0),
        geo.box(17.0, 12.2, 1.2, 0.6, -0.3), geo.box(13.3, 12.0, 1.0, 1.0),
    )
    # Drawn with the corridor along y = 0; the loop runs clockwise from the hall, so
    # the first minute sees the hall, the open area and the rooms' doors before the
    # corridor. Shifted so that the start (2, 10) becomes the origin.
    start = np.array([2.0, 10.0])
    waypoints = np.array([[2.0, 10.0], [15.0, 10.0], [15.0, 0.0], [-2.5, 0.0], [-2.5, 10.0]])
    segments = geo.stack(walls, clutter) - np.tile(start, 2)
    return World('office', 'rooms, corridor, hall with pillars, open area with clutter',
                 _freeze(segments), waypoints - start, corner_radius=0.8)


def _side_room(x0: float, x1: float, y: float, depth: float) -> np.ndarray:
    """Return the three walls of a room opening onto the wall ``y`` (depth < 0: below)."""
    return geo.polygon([[x0, y], [x0, y + depth], [x1, y + depth], [x1, y]], closed=False)


def _corridor() -> World:
    """Build a ring of 2 m wide corridors around a block of rooms, with doors and a junction."""
    walls = geo.stack(
        geo.wall((-6.0, -1.0), (36.0, -1.0), [(12.0, 13.0), (18.5, 20.5), (25.5, 26.5)]),
        geo.wall((36.0, -1.0), (36.0, 21.0), [(10.0, 12.0)]),
        geo.wall((36.0, 21.0), (-6.0, 21.0), [(11.0, 12.0), (19.0, 24.0), (33.0, 34.0)]),
        geo.wall((-6.0, 21.0), (-6.0, -1.0), [(12.0, 13.0)]),
        geo.wall((-4.0, 1.0), (34.0, 1.0), [(15.0, 16.0), (31.0, 32.0)]),
        geo.wall((34.0, 1.0), (34.0, 19.0), [(13.0, 14.0)]),
        geo.wall((34.0, 19.0), (-4.0, 19.0), [(17.0, 18.0)]),
        geo.wall((-4.0, 19.0), (-4.0, 1.0)),
        geo.wall((10.0, 1.0), (10.0, 19.0), [(8.0, 9.5)]),
        geo.wall((22.0, 1.0), (22.0, 19.0), [(4.0, 5.5)]),
        _side_room(4.0, 9.0, -1.0, -3.5), _side_room(12.5, 14.5, -1.0, -0.3),
        _side_room(18.0, 23.0, -1.0, -3.0),
        geo.polygon([[36.0, 9.0], [44.0, 9.0], [44.0, 11.0], [36.0, 11.0]], closed=False),
        _side_room(23.0, 26.0, 21.0, 3.0), _side_room(12.0, 17.0, 21.0, 0.4),
        _side_room(1.0, 5.0, 21.0, 3.5),
        geo.polygon([[-6.0, 5.0], [-9.0, 5.0], [-9.0, 9.0], [-6.0, 9.0]], closed=False),
    )
    clutter = geo.stack(geo.box(6.5, -3.5, 1.2, 0.6), geo.pillar(20.5, -3.0, 0.2),
                        geo.box(3.0, 17.5, 2.0, 1.0), geo.box(28.0, 4.0, 1.5, 1.5, 0.5))
    waypoints = np.array([[0.0, 0.0], [35.0, 0.0], [35.0, 20.0], [-5.0, 20.0], [-5.0, 0.0]])
    return World('corridor', 'ring of 2 m corridors with doors, niches and a T-junction',
                 _freeze(geo.stack(walls, clutter)), waypoints, corner_radius=1.0)


CLUTTER_SEED = 20240611
"""Seed of the generator that places the ``cluttered`` world's obstacles (fixed)."""


def _cluttered() -> World:
    """Build a 20 x 14 m hall with about 45 boxes and pillars kept clear of the robot path."""
    hall = geo.rectangle(-4.0, -3.0, 16.0, 11.0)
    waypoints = np.array([[0.0, 0.0], [12.0, 0.0], [12.0, 8.0], [-2.5, 8.0], [-2.5, 0.0]])
    path_points = SmoothPath(waypoints, 1.0).points[::10]
    rng = np.random.default_rng(CLUTTER_SEED)
    placed: list[tuple[float, float, float]] = []
    pieces = [hall]
    for _ in range(2000):
        if len(placed) >= 45:
            break
        cx, cy = rng.uniform(-3.3, 15.3), rng.uniform(-2.3, 10.3)
        if rng.random() < 0.4:
            radius = float(rng.uniform(0.1, 0.3))
            shape = geo.pillar(cx, cy, radius)
        else:
            w, h = rng.uniform(0.3, 0.9, size=2)
            radius = 0.5 * float(np.hypot(w, h))
            shape = geo.box(cx, cy, w, h, rng.uniform(-np.pi, np.pi))
        if any(np.hypot(cx - px, cy - py) < radius + pr + 0.3 for px, py, pr in placed):
            continue
        if geo.distance_to_segments(path_points, shape).min() < 0.8:
            continue
        placed.append((cx, cy, radius))
        pieces.append(shape)
    return World('cluttered', 'hall with many boxes and pillars',
                 _freeze(geo.stack(*pieces)), waypoints, corner_radius=1.0)


FEATURELESS_HALF_LENGTH = 100.0
"""Half length [m] of the featureless corridor; the path stays within +-31 m of 0."""


def _featureless_corridor() -> World:
    """Build a long, straight 3 m corridor with smooth walls; the ends are out of range."""
    h = FEATURELESS_HALF_LENGTH
    walls = geo.rectangle(-h, -1.5, h, 1.5)
    waypoints = np.array([[0.0, 0.0], [30.5, 0.0], [30.5, 0.9], [-30.5, 0.9], [-30.5, 0.0]])
    return World('featureless_corridor', 'straight corridor, smooth parallel walls only',
                 _freeze(walls), waypoints, corner_radius=0.45)


SIDES = ('south', 'east', 'north', 'west')
"""The sides of an axis-aligned building, in the counter-clockwise order its outline runs."""


def building(x0: float, y0: float, x1: float, y1: float,
             recesses: tuple[tuple[str, float, float, float], ...] = ()) -> np.ndarray:
    """Return the outline of an axis-aligned building with recesses in its facades.

    Each recess ``(side, start, end, depth)`` cuts ``depth`` metres into ``side``
    between ``start`` and ``end`` metres along it; a side runs counter-clockwise (the
    south side from west to east, the north side from east to west). Deep recesses make
    L shapes and courtyards, shallow ones entrances.
    """
    corners = np.array([[x0, y0], [x1, y0], [x1, y1], [x0, y1]], dtype=float)
    vertices = []
    for index, side in enumerate(SIDES):
        a, b = corners[index], corners[(index + 1) % 4]
        along = (b - a) / np.hypot(*(b - a))
        inward = np.array([-along[1], along[0]])
        vertices.append(a)
        for name, start, end, depth in sorted(r for r in recesses if r[0] == side):
            p, q = a + start * along, a + end * along
            vertices.extend((p, p + depth * inward, q + depth * inward, q))
    return geo.polygon(np.array(vertices))


def _entrance(x: float, y: float, width: float, normal: tuple[float, float]) -> np.ndarray:
    """Return the two canopy columns 1.5 m out from an entrance of ``width`` at (x, y)."""
    n = np.asarray(normal, dtype=float)
    t = np.array([-n[1], n[0]])
    return geo.stack(*(geo.pillar(*(np.array([x, y]) + 1.5 * n + s * 0.5 * width * t), 0.2)
                       for s in (-1.0, 1.0)))


LOOP_CORNER_RADIUS = 0.6
"""Corner radius [m] of the campus and hall loops: tight enough that the ``fast``
profile turns at its 1.5 rad/s limit."""


CAMPUS_SEED = 20250301
"""Seed of the generator that places the ``campus`` world's trees (fixed)."""


def _tree_clusters(centres: list[tuple[float, float, float, int]], avoid: np.ndarray,
                   path_points: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Return trunks (0.15-0.35 m) in clusters ``(x, y, radius, count)``.

    A trunk is kept 2 m from the path, 1 m from ``avoid`` (the buildings) and 1 m
    from the other trunks.
    """
    placed: list[tuple[float, float, float]] = []
    pieces = []
    for cx, cy, spread, count in centres:
        for _ in range(50 * count):
            if sum(np.hypot(cx - x, cy - y) <= spread + 0.5 for x, y, _ in placed) >= count:
                break
            x, y = cx + rng.uniform(-spread, spread), cy + rng.uniform(-spread, spread)
            r = float(rng.uniform(0.15, 0.35))
            if any(np.hypot(x - px, y - py) < r + pr + 1.0 for px, py, pr in placed):
                continue
            if geo.distance_to_segments(path_points, np.array([[x, y, x, y]])).min() < r + 2.0:
                continue
            if geo.distance_to_segments(np.array([[x, y]]), avoid).min() < r + 1.0:
                continue
            placed.append((x, y, r))
            pieces.append(geo.pillar(x, y, r, sides=6))
    return geo.stack(*pieces)


def _campus() -> World:
    """Build a 150 x 100 m campus: six buildings, trees, open ground, a 220 m path loop.

    Drawn with the campus in [0, 150] x [0, 100] m; the loop runs counter-clockwise
    along paths 7-13 m from the facades, with two chicanes round tree clusters, and is
    shifted so that its start (75, 45) becomes the origin.
    """
    buildings = geo.stack(
        building(10.0, 58.0, 40.0, 88.0, (('south', 8.0, 11.0, 2.0), ('east', 10.0, 22.0, 4.0))),
        building(60.0, 62.0, 95.0, 85.0, (('south', 5.0, 8.0, 1.5), ('south', 25.0, 28.0, 1.5),
                                          ('north', 12.0, 24.0, 8.0))),
        building(115.0, 55.0, 140.0, 90.0, (('west', 10.0, 14.0, 2.0), ('west', 20.0, 28.0, 3.0))),
        building(10.0, 8.0, 35.0, 33.0, (('north', 8.0, 12.0, 2.0),)),
        building(55.0, 12.0, 92.0, 32.0, (('north', 5.0, 9.0, 2.0), ('north', 20.0, 30.0, 5.0))),
        building(112.0, 10.0, 145.0, 35.0, (('north', 10.0, 14.0, 2.0), ('west', 5.0, 15.0, 3.0))),
    )
    details = geo.stack(
        _entrance(19.5, 58.0, 3.0, (0.0, -1.0)), _entrance(66.5, 62.0, 3.0, (0.0, -1.0)),
        _entrance(115.0, 78.0, 4.0, (-1.0, 0.0)), _entrance(85.0, 32.0, 4.0, (0.0, 1.0)),
        _entrance(133.0, 35.0, 4.0, (0.0, 1.0)),
        geo.box(75.0, 53.0, 4.0, 3.0), geo.box(58.0, 40.0, 2.0, 0.6, 0.2),
        *(geo.pillar(x, 49.0, 0.25, sides=6) for x in range(54, 99, 8)),
    )
    waypoints = np.array([[75.0, 45.0], [102.0, 45.0], [102.0, 70.0], [106.0, 74.0],
                          [106.0, 97.0], [88.0, 97.0], [84.0, 100.0], [72.0, 100.0],
                          [68.0, 97.0], [48.0, 97.0], [48.0, 75.0], [51.0, 70.0],
                          [48.0, 65.0], [48.0, 45.0]])
    path_points = SmoothPath(waypoints, LOOP_CORNER_RADIUS).points[::50]
    trees = _tree_clusters(
        [(25.0, 45.0, 5.0, 8), (130.0, 45.0, 5.0, 7), (78.0, 93.0, 3.0, 5),
         (56.0, 73.0, 3.0, 5), (109.0, 62.0, 2.0, 3), (75.0, 38.0, 3.0, 4),
         (30.0, 97.0, 6.0, 6), (125.0, 98.0, 5.0, 5)],
        buildings, path_points, np.random.default_rng(CAMPUS_SEED))
    start = waypoints[0]
    segments = geo.stack(buildings, details, trees) - np.tile(start, 2)
    return World('campus', 'outdoor campus: buildings tens of metres apart, trees, open '
                 'ground', _freeze(segments), waypoints - start,
                 corner_radius=LOOP_CORNER_RADIUS, min_clearance=2.0)


def _booth(cx: float, cy: float, width: float, depth: float, opening: str) -> np.ndarray:
    """Return a booth's walls: a U open to ``opening`` (a side), or an L (``'corner'``).

    The U has its back wall opposite the opening; the L keeps the back and one side.
    """
    x0, y0, x1, y1 = cx - width / 2, cy - depth / 2, cx + width / 2, cy + depth / 2
    sides = dict(zip(SIDES, geo.rectangle(x0, y0, x1, y1)))
    if opening == 'corner':
        return geo.stack(sides['north'], sides['east'])
    return geo.stack(*(segment for side, segment in sides.items() if side != opening))


def _hall() -> World:
    """Build a 60 x 30 m hall with a 10 m grid of 0.5 m pillars and eight booths.

    Drawn in [0, 60] x [0, 30] m: pillars in rows y = 10 and y = 20, booths along the
    north wall and between the pillars. The loop runs the middle aisle (y = 15) east,
    the south aisle (y = 5) west, and is shifted so that its start (30, 15) becomes the
    origin.
    """
    pillars = geo.stack(*(geo.pillar(float(x), float(y), 0.25)
                          for x in range(10, 51, 10) for y in (10, 20)))
    booths = geo.stack(
        *(_booth(x, 26.0, 3.0, 2.5, 'south') for x in (15.0, 25.0, 35.0, 45.0)),
        _booth(25.0, 10.0, 3.0, 2.0, 'north'), _booth(45.0, 10.0, 3.0, 2.0, 'corner'),
        _booth(35.0, 20.0, 3.0, 2.0, 'south'), _booth(15.0, 20.0, 2.0, 2.0, 'corner'),
        geo.box(25.0, 26.0, 1.2, 0.6), geo.box(45.0, 10.0, 0.8, 0.8),
    )
    waypoints = np.array([[30.0, 15.0], [55.0, 15.0], [55.0, 5.0], [5.0, 5.0], [5.0, 15.0]])
    start = waypoints[0]
    segments = geo.stack(geo.rectangle(0.0, 0.0, 60.0, 30.0), pillars, booths)
    return World('hall', 'convention hall: sparse pillars and booths, distant walls',
                 _freeze(segments - np.tile(start, 2)), waypoints - start,
                 corner_radius=LOOP_CORNER_RADIUS, min_clearance=2.0)


WORLDS: dict[str, Callable[[], World]] = {
    'office': _office,
    'corridor': _corridor,
    'cluttered': _cluttered,
    'featureless_corridor': _featureless_corridor,
    'campus': _campus,
    'hall': _hall,
}
"""World builders by name; ``office`` is the default demo world."""

DEFAULT_WORLD = 'office'


def world_names() -> list[str]:
    """Return the registered world names."""
    return list(WORLDS)


@lru_cache(maxsize=None)
def get_world(name: str = DEFAULT_WORLD) -> World:
    """Return the named world (built once, then shared read-only)."""
    try:
        builder = WORLDS[name]
    except KeyError:
        raise UnknownWorldError(
            f'unknown world {name!r}; valid names: {", ".join(WORLDS)}') from None
    return builder()
