"""What the laser sees of the local map from a pose, and what a scan shows is gone.

Both work by bearing bins around the sensor (one bin per beam spacing), compiled:

- :func:`render_view` is a virtual scan of the map, a ray cast of its local surfaces:
  in each bin the cells nearest the sensor (within a margin of the nearest one) are
  kept, so walls behind walls drop out (occlusion), and the bin's central ray is
  intersected with the line fitted to their surface (the pooled moments of their
  blocks). Each direction then holds one surface sample like a real beam (PL-ICP's
  ordered-scan machinery and every matcher's normal estimate apply unchanged), and
  the sample lies on the average of every observation the map kept there, which
  averages the sensor noise of many scans. Measured on fr079, the points of such a
  view scatter about their local lines by half what plain cell means do.
- :func:`seen_through` is free-space carving at the same granularity: a cell the new
  scan saw through (its beams, and both neighbours', went clearly farther) belonged to
  something that has moved (a person, a door) or was an outlier; its weight halves
  and it goes once the weight falls below one observation.
"""

from __future__ import annotations

import math

import numba
import numpy as np

from laser_odom.core.registration.local_map.cells import (
    ALIVE, BLOCK_WEIGHT, BLOCK_X, BLOCK_XX, BLOCK_XY, BLOCK_Y, BLOCK_YY, HITS, LAST_SEEN,
    line_normal, MEAN_X, MEAN_Y, S_XX, S_XY, S_YY, WEIGHT)
from laser_odom.core.scan.bearings import bearing_bin


@numba.njit(cache=True, nogil=True, inline='always')
def _wrapped(b: int, bins: int) -> int:
    """Return bin ``b`` taken around the circle, for ``-bins <= b < 2 bins``.

    ``b % bins`` for the footprints' range of offsets, without an integer division
    (the costliest step of the cell loops, which mostly visit one bin per cell).
    """
    if b < 0:
        return b + bins
    return b - bins if b >= bins else b


@numba.njit(cache=True, nogil=True, inline='always')
def _footprint(r: float, half_cell: float, bin_angle: float) -> int:
    """Return how many bins a cell ``r`` from the sensor covers on each side of its own.

    A cell is a square, not a point: near the sensor it hides (or is seen through by)
    the beams of several bins, ``asin(half_cell / r)`` to either side of its centre.
    """
    if r <= half_cell:
        return int(math.pi / bin_angle)
    return int(math.asin(half_cell / r) / bin_angle + 0.5)


@numba.njit(cache=True, nogil=True)
def render_view(floats: np.ndarray, ints: np.ndarray, pose: np.ndarray, sensor: np.ndarray,
                bin_angle: float, max_range: float, margin: float, half_cell: float,
                min_hits: int, latest: int) -> np.ndarray:
    """Return the virtual scan of the map seen from ``pose``: rows x, y, range, bin.

    ``pose`` is the base pose in the map frame, ``sensor`` the laser's position on the
    base; rows are in the base frame, in bearing order. A cell counts when it was
    touched by at least ``min_hits`` insertions or by the ``latest`` one, and hides the
    bins its square (half side ``half_cell``) covers. In each bin the cells within
    ``margin`` of the nearest are pooled: their weighted mean, and the moments of their
    blocks (rotated into the base frame), whose total-least-squares line the bin's
    central ray is intersected with (:func:`_ray_on_surface`).
    """
    bins = max(int(math.ceil(2.0 * math.pi / bin_angle)), 1)
    cos_t, sin_t = math.cos(pose[2]), math.sin(pose[2])
    n = ints.shape[0]
    nearest = np.full(bins, np.inf)
    used = np.empty(n, dtype=np.int64)
    local = np.empty((n, 2))
    cell_bin = np.empty(n, dtype=np.int64)
    cell_range = np.empty(n)
    count = 0
    for c in range(n):
        if ints[c, ALIVE] == 0 or (ints[c, HITS] < min_hits and ints[c, LAST_SEEN] != latest):
            continue
        dx, dy = floats[c, MEAN_X] - pose[0], floats[c, MEAN_Y] - pose[1]
        bx, by = cos_t * dx + sin_t * dy, -sin_t * dx + cos_t * dy
        qx, qy = bx - sensor[0], by - sensor[1]
        r = math.sqrt(qx * qx + qy * qy)
        if r > max_range or r <= 1e-6:
            continue
        b = bearing_bin(qx, qy, bin_angle, bins)
        used[count], cell_bin[count], cell_range[count] = c, b, r
        local[count, 0], local[count, 1] = bx, by
        count += 1
        span = _footprint(r, half_cell, bin_angle)
        for o in range(-span, span + 1):
            k = _wrapped(b + o, bins)
            nearest[k] = min(nearest[k], r)
    # Per bin: weight, weighted x and y; block weight, weighted centroid, raw second moments.
    sums = np.zeros((bins, 9))
    for m in range(count):
        b = cell_bin[m]
        if cell_range[m] > nearest[b] + margin:
            continue
        c = used[m]
        w = floats[c, WEIGHT]
        sums[b, 0] += w
        sums[b, 1] += w * local[m, 0]
        sums[b, 2] += w * local[m, 1]
        bw = floats[c, BLOCK_WEIGHT]
        if bw <= 0.0:
            continue
        ox, oy = floats[c, BLOCK_X] - pose[0], floats[c, BLOCK_Y] - pose[1]
        mx, my = cos_t * ox + sin_t * oy, -sin_t * ox + cos_t * oy
        sxx, sxy, syy = floats[c, BLOCK_XX], floats[c, BLOCK_XY], floats[c, BLOCK_YY]
        # Scatter rotated into the base frame: R^T S R.
        sums[b, 3] += bw
        sums[b, 4] += bw * mx
        sums[b, 5] += bw * my
        sums[b, 6] += (cos_t * cos_t * sxx + 2.0 * cos_t * sin_t * sxy + sin_t * sin_t * syy
                       + bw * mx * mx)
        sums[b, 7] += ((cos_t * cos_t - sin_t * sin_t) * sxy + cos_t * sin_t * (syy - sxx)
                       + bw * mx * my)
        sums[b, 8] += (sin_t * sin_t * sxx - 2.0 * cos_t * sin_t * sxy + cos_t * cos_t * syy
                       + bw * my * my)
    filled = 0
    for b in range(bins):
        if sums[b, 0] > 0.0:
            filled += 1
    view = np.empty((filled, 4))
    k = 0
    for b in range(bins):
        w = sums[b, 0]
        if w <= 0.0:
            continue
        x, y = sums[b, 1] / w, sums[b, 2] / w
        bw = sums[b, 3]
        if bw > 0.0:
            cx, cy = sums[b, 4] / bw, sums[b, 5] / bw
            x, y = _ray_on_surface(x, y, cx, cy, max(sums[b, 6] - bw * cx * cx, 0.0),
                                   sums[b, 7] - bw * cx * cy,
                                   max(sums[b, 8] - bw * cy * cy, 0.0), sensor,
                                   -math.pi + (b + 0.5) * bin_angle, margin)
        view[k, 0], view[k, 1] = x, y
        view[k, 2] = math.hypot(x - sensor[0], y - sensor[1])
        view[k, 3] = b
        k += 1
    return view


RAYCAST_CURVATURE = 0.1
"""A bin's pooled surface this flat (curvature l1 / (l1 + l2)) is intersected with the
bin's central ray; a rounder one (a corner, clutter) keeps the mean of its cells."""

RAYCAST_MIN_COSINE = 0.15
"""Rays this close to grazing (|cos| of the angle to the normal) keep the cell mean."""


@numba.njit(cache=True, nogil=True)
def _ray_on_surface(x: float, y: float, cx: float, cy: float, a: float, h: float,
                    c: float, sensor: np.ndarray, angle: float, margin: float
                    ) -> tuple[float, float]:
    """Return where the bin's central ray meets the line fitted to its cells' surface.

    A real beam samples the surface along its own direction; the virtual scan does
    the same (a ray cast of the map's local line, the total-least-squares line
    through the pooled moments ``[[a, h], [h, c]]`` about ``(cx, cy)``), so its points
    lie on the averaged surface rather than on a zigzag of cell means. The cell mean
    ``(x, y)`` stays where the surface is not flat, the ray grazes it, or the
    intersection lies more than ``margin`` from the mean.
    """
    nx, ny = line_normal(a, h, c, RAYCAST_CURVATURE)
    if nx == 0.0 and ny == 0.0:
        return x, y
    ux, uy = math.cos(angle), math.sin(angle)
    along = nx * ux + ny * uy
    if abs(along) < RAYCAST_MIN_COSINE:
        return x, y
    t = (nx * (cx - sensor[0]) + ny * (cy - sensor[1])) / along
    px, py = sensor[0] + t * ux, sensor[1] + t * uy
    if t <= 0.0 or math.hypot(px - x, py - y) > margin:
        return x, y
    return px, py


@numba.njit(cache=True, nogil=True, inline='always')
def _not_past(reading: float, reach: float) -> bool:
    """Tell whether a bin's ``reading`` fails to show the beams passing ``reach``.

    No reading (-1: no return, outside the field of view) says nothing; one at or
    short of ``reach`` stopped at the cell or before it.
    """
    return reading < 0.0 or reading <= reach


@numba.njit(cache=True, nogil=True)
def seen_through(floats: np.ndarray, ints: np.ndarray, pose: np.ndarray,
                 sensor: np.ndarray, measured: np.ndarray, bin_angle: float,
                 margin: float, half_cell: float) -> np.ndarray:
    """Halve the weight of cells the scan saw through; return those now below one.

    ``measured`` holds the scan's range per bearing bin from the sensor at ``pose``
    (-1 where the bin holds no reading). A cell is seen through when every bin its
    square covers (half side ``half_cell``), and at least its two neighbours, has
    readings that all lie more than ``margin`` beyond it: the beams passed where the
    cell claims a surface. Bins without a reading (no return,
    outside the field of view) say nothing. The weight and scatter halve, which
    leaves the mean in place.
    """
    bins = measured.shape[0]
    cos_t, sin_t = math.cos(pose[2]), math.sin(pose[2])
    out = np.empty(ints.shape[0], dtype=np.int64)
    count = 0
    for c in range(ints.shape[0]):
        if ints[c, ALIVE] == 0:
            continue
        dx, dy = floats[c, MEAN_X] - pose[0], floats[c, MEAN_Y] - pose[1]
        qx = cos_t * dx + sin_t * dy - sensor[0]
        qy = -sin_t * dx + cos_t * dy - sensor[1]
        r = math.sqrt(qx * qx + qy * qy)
        b = bearing_bin(qx, qy, bin_angle, bins)
        if _not_past(measured[b], r + margin):
            continue  # its own bin decides most cells: no footprint to walk
        span = max(_footprint(r, half_cell, bin_angle), 1)
        through = True
        for o in range(-span, span + 1):
            if _not_past(measured[_wrapped(b + o, bins)], r + margin):
                through = False
                break
        if not through:
            continue
        floats[c, WEIGHT] *= 0.5
        floats[c, S_XX] *= 0.5
        floats[c, S_XY] *= 0.5
        floats[c, S_YY] *= 0.5
        if floats[c, WEIGHT] < 1.0:
            out[count] = c
            count += 1
    return out[:count]


@numba.njit(cache=True, nogil=True)
def ranges_by_bin(points: np.ndarray, sensor: np.ndarray, bin_angle: float,
                  bins: int) -> np.ndarray:
    """Return the farthest reading per bearing bin of base-frame points (-1: none)."""
    out = np.full(bins, -1.0)
    for k in range(points.shape[0]):
        qx, qy = points[k, 0] - sensor[0], points[k, 1] - sensor[1]
        b = bearing_bin(qx, qy, bin_angle, bins)
        out[b] = max(out[b], math.sqrt(qx * qx + qy * qy))
    return out
