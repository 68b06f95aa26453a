"""Vectorised ray casting: all beams of a scan against all wall segments at once.

A ray ``o + t d`` (t > 0) meets a segment ``a + u e`` (0 <= u <= 1) where
``t = ((a - o) x e) / (d x e)`` and ``u = ((a - o) x d) / (d x e)``, with ``x`` the
planar cross product (the usual parametric line-line intersection, e.g. Goldman,
"Intersection of two lines in three-space", Graphics Gems I, 1990). Broadcasting
beams x segments gives every candidate at once; the smallest positive ``t`` per
beam is the range.
"""

from __future__ import annotations

import numpy as np

PARALLEL_EPS = 1e-12
"""Rays within this of parallel to a segment (|d x e| / |e|) do not hit it."""


def cast_rays(origin: np.ndarray, angles: np.ndarray, segments: np.ndarray,
              max_range: float = np.inf) -> np.ndarray:
    """Return the distance along each ray to the nearest segment, ``inf`` when none.

    ``origin`` is the (2,) ray start, ``angles`` the (B,) world-frame ray directions and
    ``segments`` the (M, 4) walls ``[x0, y0, x1, y1]``. Segments entirely beyond
    ``max_range`` are skipped first, which keeps large worlds cheap.
    """
    o = np.asarray(origin, dtype=float).reshape(2)
    angles = np.asarray(angles, dtype=float).reshape(-1)
    seg = np.asarray(segments, dtype=float).reshape(-1, 4)
    if np.isfinite(max_range) and len(seg):
        seg = seg[_segments_within(o, seg, max_range)]
    ranges = np.full(angles.shape[0], np.inf)
    if len(seg) == 0 or angles.shape[0] == 0:
        return ranges
    dx, dy = np.cos(angles)[:, None], np.sin(angles)[:, None]
    ax, ay = (seg[:, 0] - o[0])[None, :], (seg[:, 1] - o[1])[None, :]
    ex, ey = (seg[:, 2] - seg[:, 0])[None, :], (seg[:, 3] - seg[:, 1])[None, :]
    denom = dx * ey - dy * ex
    length = np.hypot(ex, ey)
    valid = np.abs(denom) > PARALLEL_EPS * length
    safe = np.where(valid, denom, 1.0)
    t = (ax * ey - ay * ex) / safe
    u = (ax * dy - ay * dx) / safe
    hit = valid & (t > 0.0) & (u >= 0.0) & (u <= 1.0)
    t = np.where(hit, t, np.inf)
    return np.minimum(ranges, t.min(axis=1))


def _segment_distances(origin: np.ndarray, segments: np.ndarray) -> np.ndarray:
    """Return each segment's distance to ``origin`` (2,), or to its row's origin (M, 2)."""
    a = segments[:, 0:2] - origin
    e = segments[:, 2:4] - segments[:, 0:2]
    length2 = np.maximum(np.einsum('mi,mi->m', e, e), 1e-300)
    u = np.clip(-np.einsum('mi,mi->m', a, e) / length2, 0.0, 1.0)
    closest = a + u[:, None] * e
    return np.hypot(closest[:, 0], closest[:, 1])


def _segments_within(origin: np.ndarray, segments: np.ndarray, radius: float) -> np.ndarray:
    """Tell which segments come within ``radius`` of ``origin`` (point-segment distance)."""
    return _segment_distances(origin, segments) <= radius


def cast_fan(origin: np.ndarray, start: float, increment: float, count: int,
             segments: np.ndarray, max_range: float = np.inf) -> np.ndarray:
    """Return the ranges of ``count`` rays at world angles ``start + i * increment``.

    Equal to :func:`cast_rays` on those angles, computed only for the (beam, segment)
    pairs whose angles overlap (with one beam of margin on each side).
    """
    if increment == 0.0:
        return cast_rays(origin, np.full(count, start), segments, max_range)
    if increment < 0.0:
        last = start + (count - 1) * increment
        return cast_fan(origin, last, -increment, count, segments, max_range)[::-1]
    o = np.asarray(origin, dtype=float).reshape(2)
    seg = np.asarray(segments, dtype=float).reshape(-1, 4)
    if np.isfinite(max_range) and len(seg):
        seg = seg[_segments_within(o, seg, max_range)]
    ranges = np.full(count, np.inf)
    if len(seg) == 0 or count == 0:
        return ranges
    ax, ay = seg[:, 0] - o[0], seg[:, 1] - o[1]
    bx, by = seg[:, 2] - o[0], seg[:, 3] - o[1]
    phi_a, phi_b = np.arctan2(ay, ax), np.arctan2(by, bx)
    sweep = (phi_b - phi_a + np.pi) % (2.0 * np.pi) - np.pi
    low = np.where(sweep >= 0.0, phi_a, phi_b)
    span = np.abs(sweep)
    # A segment through the origin's line subtends ~pi either way: try every beam.
    span = np.where(span > np.pi - 1e-9, 2.0 * np.pi, span)
    rel = np.mod(low - start, 2.0 * np.pi)
    turn = 2.0 * np.pi / increment
    first = np.concatenate((np.floor(rel / increment), np.floor(rel / increment - turn)))
    last = np.concatenate((np.ceil((rel + span) / increment),
                           np.ceil((rel + span) / increment - turn)))
    first = np.clip(first, 0, count - 1).astype(np.int64)
    last = np.clip(last, -1, count - 1).astype(np.int64)
    owner = np.concatenate((np.arange(len(seg)), np.arange(len(seg))))
    keep = last >= first
    first, last, owner = first[keep], last[keep], owner[keep]
    sizes = last - first + 1
    total = int(sizes.sum())
    if total == 0:
        return ranges
    offsets = np.cumsum(sizes) - sizes
    pair_seg = np.repeat(owner, sizes)
    beam = np.repeat(first - offsets, sizes) + np.arange(total)
    angles = start + beam * increment
    _nearest_hits(ranges, beam, ax[pair_seg], ay[pair_seg], (bx - ax)[pair_seg],
                  (by - ay)[pair_seg], np.cos(angles), np.sin(angles))
    return ranges


def _nearest_hits(ranges: np.ndarray, beam: np.ndarray, ax: np.ndarray, ay: np.ndarray,
                  ex: np.ndarray, ey: np.ndarray, dx: np.ndarray, dy: np.ndarray) -> None:
    """Lower ``ranges[beam]`` to where each ray meets its paired segment, if it does.

    Ray ``r(t) = t d`` from its origin, segment ``a + u e`` relative to that origin;
    solving ``t d = a + u e`` (2x2, Cramer's rule) gives ``t`` along the ray and ``u``
    along the segment; a hit has ``t > 0`` and ``0 <= u <= 1``. Near-parallel pairs
    are skipped.
    """
    denom = dx * ey - dy * ex
    valid = np.abs(denom) > PARALLEL_EPS * np.hypot(ex, ey)
    safe = np.where(valid, denom, 1.0)
    t = (ax * ey - ay * ex) / safe
    u = (ax * dy - ay * dx) / safe
    hit = valid & (t > 0.0) & (u >= 0.0) & (u <= 1.0)
    np.minimum.at(ranges, beam[hit], t[hit])


ANGLE_MARGIN = 1e-9
"""Slack [rad] on the angular interval of a segment, against rounding in the culling."""


def cast_rays_from(origins: np.ndarray, angles: np.ndarray, segments: np.ndarray,
                   max_range: float = np.inf) -> np.ndarray:
    """Return the distance along each ray from its own origin to the nearest segment.

    Ray ``i`` starts at ``origins[i]`` (B, 2) and heads along the world angle
    ``angles[i]`` (B,): the beams of a scan taken while the robot moves. The result
    equals :func:`cast_rays` ``(origins[i], [angles[i]], segments, max_range)`` for
    every ``i`` (segments entirely beyond ``max_range`` of a ray's origin are skipped
    for that ray, ``inf`` when nothing is hit), computed only for the (ray, segment)
    pairs that can meet: seen from the origins' centroid ``c``, a segment at distance
    ``d`` covers an interval of directions, and a ray from an origin within ``s`` of
    ``c`` can only meet it within ``asin(s / d)`` of that interval. The per-ray
    arithmetic is that of :func:`cast_fan`, so rays sharing one origin give the same
    ranges as the fan.
    """
    o = np.asarray(origins, dtype=float).reshape(-1, 2)
    phi = np.asarray(angles, dtype=float).reshape(-1)
    if o.shape[0] != phi.shape[0]:
        raise ValueError(f'{o.shape[0]} origins for {phi.shape[0]} rays')
    seg = np.asarray(segments, dtype=float).reshape(-1, 4)
    count = phi.shape[0]
    ranges = np.full(count, np.inf)
    if count == 0 or len(seg) == 0:
        return ranges
    centre = o.mean(axis=0)
    spread = float(np.max(np.hypot(o[:, 0] - centre[0], o[:, 1] - centre[1])))
    dist = _segment_distances(centre, seg)
    border = np.zeros(len(seg), dtype=bool)
    if np.isfinite(max_range):
        slack = spread + ANGLE_MARGIN * max(1.0, max_range)
        near = dist <= max_range + slack
        seg, dist = seg[near], dist[near]
        border = dist > max_range - slack
        if len(seg) == 0:
            return ranges
    beam, owner = _candidate_pairs(centre, spread, dist, phi, seg)
    if np.any(border):
        check = border[owner]
        keep = ~check
        keep[check] = _segment_distances(o[beam[check]], seg[owner[check]]) <= max_range
        beam, owner = beam[keep], owner[keep]
    ox, oy = o[beam, 0], o[beam, 1]
    ax, ay = seg[owner, 0] - ox, seg[owner, 1] - oy
    bx, by = seg[owner, 2] - ox, seg[owner, 3] - oy
    _nearest_hits(ranges, beam, ax, ay, bx - ax, by - ay, np.cos(phi)[beam],
                  np.sin(phi)[beam])
    return ranges


def _candidate_pairs(centre: np.ndarray, spread: float, dist: np.ndarray, angles: np.ndarray,
                     segments: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Return the (ray, segment) index pairs of rays whose direction can meet the segment.

    Each segment's interval of directions seen from ``centre`` is widened by
    ``asin(spread / dist)``; segments closer than ``spread`` (or seen across about
    pi, i.e. passing next to ``centre``) are paired with every ray. The rays are sorted
    by direction so each interval is two ``searchsorted`` look-ups.
    """
    two_pi = 2.0 * np.pi
    ax, ay = segments[:, 0] - centre[0], segments[:, 1] - centre[1]
    bx, by = segments[:, 2] - centre[0], segments[:, 3] - centre[1]
    phi_a, phi_b = np.arctan2(ay, ax), np.arctan2(by, bx)
    sweep = (phi_b - phi_a + np.pi) % two_pi - np.pi
    low = np.where(sweep >= 0.0, phi_a, phi_b)
    ratio = np.divide(spread, dist, out=np.full(dist.shape, np.inf), where=dist > 0.0)
    margin = np.arcsin(np.minimum(ratio, 1.0)) + ANGLE_MARGIN
    width = np.abs(sweep) + 2.0 * margin
    every = (np.abs(sweep) > np.pi - 1e-9) | (ratio >= 1.0) | (width >= two_pi)
    wrapped = np.mod(angles, two_pi)
    order = np.argsort(wrapped, kind='stable')
    sorted_angles = wrapped[order]
    part = np.flatnonzero(~every)
    start = np.mod(low[part] - margin[part], two_pi)
    end = start + width[part]
    total = len(angles)
    first = np.concatenate((np.searchsorted(sorted_angles, start, side='left'),
                            np.zeros(len(part), dtype=np.int64),
                            np.zeros(int(every.sum()), dtype=np.int64)))
    last = np.concatenate((np.searchsorted(sorted_angles, end, side='right'),
                           np.searchsorted(sorted_angles, end - two_pi, side='right'),
                           np.full(int(every.sum()), total, dtype=np.int64)))
    owner = np.concatenate((part, part, np.flatnonzero(every)))
    sizes = np.maximum(last - first, 0)
    pairs = int(sizes.sum())
    offsets = np.cumsum(sizes) - sizes
    rank = np.repeat(first - offsets, sizes) + np.arange(pairs)
    return order[rank], np.repeat(owner, sizes)
