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


WORLDS: dict[str, Callable[[], World]] = {
    'office': _office,
    'corridor': _corridor,
    'cluttered': _cluttered,
    'featureless_corridor': _featureless_corridor,
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
