"""Planar line-segment geometry for the simulated worlds, vectorised with numpy.

A world is a set of segments stored as rows ``[x0, y0, x1, y1]`` of an (M, 4) array.
These helpers build such rows from boxes and polygons and answer the two questions
the path checks need: how far points are from the walls, and whether a polyline
crosses any wall.
"""

from __future__ import annotations

import math

import numpy as np

from laser_odom.core import se2


def polygon(vertices: np.ndarray | list, closed: bool = True) -> np.ndarray:
    """Return the segments joining consecutive ``vertices`` (K, 2), closing the loop if asked."""
    v = np.asarray(vertices, dtype=float).reshape(-1, 2)
    end = np.roll(v, -1, axis=0) if closed else v[1:]
    start = v if closed else v[:-1]
    return np.hstack((start, end))


def box(cx: float, cy: float, width: float, height: float, angle: float = 0.0) -> np.ndarray:
    """Return the four sides of a ``width`` x ``height`` box centred at (cx, cy), rotated."""
    hw, hh = 0.5 * width, 0.5 * height
    corners = np.array([[-hw, -hh], [hw, -hh], [hw, hh], [-hw, hh]])
    return polygon(se2.transform_points(se2.pose(cx, cy, angle), corners))


def rectangle(x0: float, y0: float, x1: float, y1: float) -> np.ndarray:
    """Return the four sides of the axis-aligned rectangle with corners (x0, y0), (x1, y1)."""
    return polygon([[x0, y0], [x1, y0], [x1, y1], [x0, y1]])


def pillar(cx: float, cy: float, radius: float, sides: int = 8) -> np.ndarray:
    """Return a regular polygon approximating a round pillar of ``radius``."""
    a = np.arange(sides) * (2.0 * math.pi / sides)
    return polygon(np.column_stack((cx + radius * np.cos(a), cy + radius * np.sin(a))))


def wall(start: tuple[float, float], end: tuple[float, float],
         gaps: list[tuple[float, float]] = ()) -> np.ndarray:
    """Return a straight wall from ``start`` to ``end`` with door openings.

    ``gaps`` are ``(from, to)`` distances along the wall [m] that are left open.
    """
    p0, p1 = np.asarray(start, dtype=float), np.asarray(end, dtype=float)
    length = float(np.hypot(*(p1 - p0)))
    direction = (p1 - p0) / length
    cuts = [0.0]
    for g0, g1 in sorted(gaps):
        cuts.extend((g0, g1))
    cuts.append(length)
    pieces = [(a, b) for a, b in zip(cuts[0::2], cuts[1::2]) if b - a > 1e-9]
    return np.array([[*(p0 + a * direction), *(p0 + b * direction)] for a, b in pieces])


def stack(*parts: np.ndarray) -> np.ndarray:
    """Concatenate segment arrays into one (M, 4) array."""
    return np.vstack([np.asarray(p, dtype=float).reshape(-1, 4) for p in parts])


def distance_to_segments(points: np.ndarray, segments: np.ndarray) -> np.ndarray:
    """Return the distance of each point (N, 2) to the nearest segment (M, 4).

    Projection of the point onto each segment, clamped to the segment's ends;
    broadcast as (N, M), so callers chunk very large inputs.
    """
    p = np.asarray(points, dtype=float).reshape(-1, 2)
    a = segments[None, :, 0:2]
    e = segments[None, :, 2:4] - segments[None, :, 0:2]
    length2 = np.maximum(np.einsum('nmi,nmi->nm', e, e), 1e-300)
    u = np.clip(np.einsum('nmi,nmi->nm', p[:, None, :] - a, e) / length2, 0.0, 1.0)
    closest = a + u[..., None] * e
    return np.min(np.hypot(p[:, None, 0] - closest[..., 0], p[:, None, 1] - closest[..., 1]),
                  axis=1)


def _cross(ax: np.ndarray, ay: np.ndarray, bx: np.ndarray, by: np.ndarray) -> np.ndarray:
    """Return the z component of the 2D cross product."""
    return ax * by - ay * bx


def polyline_crosses(points: np.ndarray, segments: np.ndarray) -> np.ndarray:
    """Tell, for each step ``points[i] -> points[i+1]``, whether it crosses any segment.

    Standard orientation test: two segments intersect properly when each one's end
    points lie on opposite sides of the other (touching counts as crossing).
    """
    p = np.asarray(points, dtype=float).reshape(-1, 2)
    if len(p) < 2 or len(segments) == 0:
        return np.zeros(max(len(p) - 1, 0), dtype=bool)
    p0, p1 = p[:-1, None, :], p[1:, None, :]
    q0, q1 = segments[None, :, 0:2], segments[None, :, 2:4]
    d = p1 - p0
    e = q1 - q0
    o1 = _cross(d[..., 0], d[..., 1], q0[..., 0] - p0[..., 0], q0[..., 1] - p0[..., 1])
    o2 = _cross(d[..., 0], d[..., 1], q1[..., 0] - p0[..., 0], q1[..., 1] - p0[..., 1])
    o3 = _cross(e[..., 0], e[..., 1], p0[..., 0] - q0[..., 0], p0[..., 1] - q0[..., 1])
    o4 = _cross(e[..., 0], e[..., 1], p1[..., 0] - q0[..., 0], p1[..., 1] - q0[..., 1])
    hit = (o1 * o2 <= 0.0) & (o3 * o4 <= 0.0)
    collinear = (o1 == 0.0) & (o2 == 0.0)
    return np.any(hit & ~collinear, axis=1)
