"""The local map's storage: a 2D hash of cells holding the moments of their points.

Each cell of a square lattice (side ``resolution``) that a scan point has fallen in
keeps the running weighted mean and scatter matrix of its points (Welford's update),
with the weight capped so that a cell follows a changed scene instead of averaging it
for ever (exponential forgetting beyond the cap). The cells are found through an
open-addressing hash table (linear probing, deletion by backward shift: Knuth, TAOCP
vol. 3, 6.4, algorithm R), so memory is bounded by the number of cells, not by the
extent of the region, and a cell is found in O(1): the 2D counterpart of KISS-ICP's
voxel hash (Vizzo et al., "KISS-ICP", RA-L 2023, Sec. IV-C).

Each cell also keeps the pooled moments of its 3x3 block of neighbouring cells: the
local surface around it, from which the view derives normals and curvature (the
covariance analysis of Pauly et al. 2002, as :mod:`laser_odom.core.scan.normals` does per
scan). They are refreshed for the cells an insertion touched and their neighbours only,
so the surface is kept up to date with the map, never rebuilt from scratch.

Everything here is compiled (numba) and works on plain arrays owned by
:class:`laser_odom.core.registration.local_map.map.LocalMap`.
"""

from __future__ import annotations

import math

import numba
import numpy as np

EMPTY = -1
"""Key of an empty hash-table slot (real keys are non-negative)."""

KEY_OFFSET = 1 << 30
"""Added to cell coordinates so that keys are non-negative (cells within 5e7 m at 5 cm)."""

# Columns of the float cell table.
WEIGHT, MEAN_X, MEAN_Y, S_XX, S_XY, S_YY = 0, 1, 2, 3, 4, 5
"""The cell's own points: weight, mean, scatter (sum of w (p - m)(p - m)^T)."""
BLOCK_WEIGHT, BLOCK_X, BLOCK_Y, BLOCK_XX, BLOCK_XY, BLOCK_YY, BLOCK_CELLS = (
    6, 7, 8, 9, 10, 11, 12)
"""The pooled moments of the 3x3 block of cells around it, and how many cells it holds."""
FLOAT_COLUMNS = 13

# Columns of the integer cell table.
KEY, LAST_SEEN, ALIVE, HITS, REFRESHED = 0, 1, 2, 3, 4
"""The cell's key, the last insertion that touched it, whether it is in use, how many
insertions touched it, and the last block refresh that visited it."""
INT_COLUMNS = 5


@numba.njit(cache=True, nogil=True, inline='always')
def cell_key(x: float, y: float, inverse_resolution: float) -> int:
    """Return the key of the cell holding ``(x, y)``: both lattice indices in one integer."""
    ix = np.int64(math.floor(x * inverse_resolution)) + KEY_OFFSET
    iy = np.int64(math.floor(y * inverse_resolution)) + KEY_OFFSET
    return (ix << 32) | iy


@numba.njit(cache=True, nogil=True, inline='always')
def _home(key: int, mask: int) -> int:
    """Return the home slot of ``key`` (Fibonacci hashing of the 64-bit key)."""
    h = np.uint64(key) * np.uint64(0x9E3779B97F4A7C15)
    return np.int64(h >> np.uint64(34)) & mask


@numba.njit(cache=True, nogil=True)
def find_cell(slot_keys: np.ndarray, slot_cells: np.ndarray, key: int) -> int:
    """Return the cell stored under ``key``, -1 when there is none."""
    mask = slot_keys.shape[0] - 1
    i = _home(key, mask)
    while True:
        stored = slot_keys[i]
        if stored == key:
            return slot_cells[i]
        if stored == EMPTY:
            return -1
        i = (i + 1) & mask


@numba.njit(cache=True, nogil=True)
def _store(slot_keys: np.ndarray, slot_cells: np.ndarray, key: int, cell: int) -> None:
    """Store ``cell`` under ``key`` (known to be absent) in the first free slot."""
    mask = slot_keys.shape[0] - 1
    i = _home(key, mask)
    while slot_keys[i] != EMPTY:
        i = (i + 1) & mask
    slot_keys[i] = key
    slot_cells[i] = cell


@numba.njit(cache=True, nogil=True)
def _erase(slot_keys: np.ndarray, slot_cells: np.ndarray, key: int) -> None:
    """Remove ``key`` and shift later entries of its probe run back (no tombstones)."""
    mask = slot_keys.shape[0] - 1
    i = _home(key, mask)
    while slot_keys[i] != key:
        if slot_keys[i] == EMPTY:
            return
        i = (i + 1) & mask
    slot_keys[i] = EMPTY
    j = i
    while True:
        j = (j + 1) & mask
        if slot_keys[j] == EMPTY:
            return
        home = _home(slot_keys[j], mask)
        # The entry at j stays when its home lies cyclically in (i, j].
        if (i < j and i < home <= j) or (i > j and (home > i or home <= j)):
            continue
        slot_keys[i], slot_cells[i] = slot_keys[j], slot_cells[j]
        slot_keys[j] = EMPTY
        i = j


@numba.njit(cache=True, nogil=True)
def remove_cells(cells: np.ndarray, floats: np.ndarray, ints: np.ndarray,
                 slot_keys: np.ndarray, slot_cells: np.ndarray, free: np.ndarray,
                 free_count: np.ndarray) -> None:
    """Remove the given cells: erase their keys and return them to the free list."""
    for c in cells:
        if ints[c, ALIVE] == 0:
            continue
        _erase(slot_keys, slot_cells, ints[c, KEY])
        ints[c, ALIVE] = 0
        floats[c, :] = 0.0
        free[free_count[0]] = c
        free_count[0] += 1


@numba.njit(cache=True, nogil=True)
def add_points(points: np.ndarray, inverse_resolution: float, max_weight: float,
               sequence: int, floats: np.ndarray, ints: np.ndarray, slot_keys: np.ndarray,
               slot_cells: np.ndarray, free: np.ndarray, free_count: np.ndarray,
               touched: np.ndarray) -> int:
    """Add points (in the map frame) to their cells; return how many cells they touched.

    A new cell takes a slot from the free list (points that find none are dropped: the
    caller frees room first). Each point updates its cell's weighted mean and scatter
    (Welford); a cell already at ``max_weight`` first scales its weight and scatter
    down so that the new point counts ``1 / max_weight`` (exponential forgetting). The
    touched cells are written to ``touched`` (once each per ``sequence``).
    """
    count = 0
    for k in range(points.shape[0]):
        x, y = points[k, 0], points[k, 1]
        if not (math.isfinite(x) and math.isfinite(y)):
            continue
        key = cell_key(x, y, inverse_resolution)
        c = find_cell(slot_keys, slot_cells, key)
        if c < 0:
            if free_count[0] == 0:
                continue
            free_count[0] -= 1
            c = free[free_count[0]]
            floats[c, :] = 0.0
            ints[c, KEY], ints[c, LAST_SEEN], ints[c, ALIVE] = key, -1, 1
            ints[c, HITS], ints[c, REFRESHED] = 0, -1
            _store(slot_keys, slot_cells, key, c)
        if ints[c, LAST_SEEN] != sequence:
            ints[c, LAST_SEEN] = sequence
            ints[c, HITS] += 1
            touched[count] = c
            count += 1
        weight = floats[c, WEIGHT]
        if weight > max_weight - 1.0:
            keep = max(max_weight - 1.0, 0.0) / weight
            floats[c, WEIGHT] *= keep
            floats[c, S_XX] *= keep
            floats[c, S_XY] *= keep
            floats[c, S_YY] *= keep
            weight = floats[c, WEIGHT]
        total = weight + 1.0
        dx, dy = x - floats[c, MEAN_X], y - floats[c, MEAN_Y]
        mx, my = floats[c, MEAN_X] + dx / total, floats[c, MEAN_Y] + dy / total
        floats[c, S_XX] += dx * (x - mx)
        floats[c, S_XY] += dx * (y - my)
        floats[c, S_YY] += dy * (y - my)
        floats[c, MEAN_X], floats[c, MEAN_Y], floats[c, WEIGHT] = mx, my, total
    return count


@numba.njit(cache=True, nogil=True)
def refresh_blocks(changed: np.ndarray, inverse_resolution: float, refresh: int,
                   floats: np.ndarray, ints: np.ndarray, slot_keys: np.ndarray,
                   slot_cells: np.ndarray) -> int:
    """Pool the 3x3 block moments of the changed cells and their neighbours.

    ``changed`` lists cells whose own moments changed (or whose neighbour was
    removed); every alive cell within one lattice step of one of them gets its block
    recomputed, once per ``refresh``. The pooled moments combine the cells' weighted
    means and scatters exactly (the parallel form of Welford's update, Chan et al.
    1979). Returns the number of blocks recomputed.
    """
    done = 0
    block = np.empty(9, dtype=np.int64)
    neighbours = np.empty(9, dtype=np.int64)
    for c0 in changed:
        for k in range(block_cells(ints[c0, KEY], slot_keys, slot_cells, block)):
            c = block[k]
            if ints[c, REFRESHED] == refresh:
                continue
            ints[c, REFRESHED] = refresh
            _pool_block(c, floats, ints, slot_keys, slot_cells, neighbours)
            done += 1
    return done


@numba.njit(cache=True, nogil=True, inline='always')
def block_cells(key: int, slot_keys: np.ndarray, slot_cells: np.ndarray,
                out: np.ndarray) -> int:
    """Write the cells of the 3x3 block around the cell ``key`` into ``out``; return how many."""
    ix, iy = key >> 32, key & 0xFFFFFFFF
    count = 0
    for ox in range(-1, 2):
        for oy in range(-1, 2):
            c = find_cell(slot_keys, slot_cells, ((ix + ox) << 32) | (iy + oy))
            if c >= 0:
                out[count] = c
                count += 1
    return count


@numba.njit(cache=True, nogil=True)
def _pool_block(c: int, floats: np.ndarray, ints: np.ndarray, slot_keys: np.ndarray,
                slot_cells: np.ndarray, block: np.ndarray) -> None:
    """Recompute cell ``c``'s block moments from the cells around it (``block``: scratch)."""
    cells = block_cells(ints[c, KEY], slot_keys, slot_cells, block)
    weight = sx = sy = 0.0
    for k in range(cells):
        n = block[k]
        w = floats[n, WEIGHT]
        weight += w
        sx += w * floats[n, MEAN_X]
        sy += w * floats[n, MEAN_Y]
    if weight <= 0.0:
        floats[c, BLOCK_WEIGHT:] = 0.0
        return
    mx, my = sx / weight, sy / weight
    sxx = sxy = syy = 0.0
    for k in range(cells):
        n = block[k]
        w = floats[n, WEIGHT]
        dx, dy = floats[n, MEAN_X] - mx, floats[n, MEAN_Y] - my
        sxx += floats[n, S_XX] + w * dx * dx
        sxy += floats[n, S_XY] + w * dx * dy
        syy += floats[n, S_YY] + w * dy * dy
    floats[c, BLOCK_WEIGHT], floats[c, BLOCK_X], floats[c, BLOCK_Y] = weight, mx, my
    floats[c, BLOCK_XX], floats[c, BLOCK_XY], floats[c, BLOCK_YY] = sxx, sxy, syy
    floats[c, BLOCK_CELLS] = cells


@numba.njit(cache=True, nogil=True)
def stale_cells(centre_x: float, centre_y: float, radius: float, oldest: int,
                floats: np.ndarray, ints: np.ndarray) -> np.ndarray:
    """Return the alive cells beyond ``radius`` of the centre or last seen before ``oldest``."""
    out = np.empty(ints.shape[0], dtype=np.int64)
    count = 0
    radius2 = radius * radius
    for c in range(ints.shape[0]):
        if ints[c, ALIVE] == 0:
            continue
        dx, dy = floats[c, MEAN_X] - centre_x, floats[c, MEAN_Y] - centre_y
        if dx * dx + dy * dy > radius2 or ints[c, LAST_SEEN] < oldest:
            out[count] = c
            count += 1
    return out[:count]


@numba.njit(cache=True, nogil=True, inline='always')
def line_normal(sxx: float, sxy: float, syy: float, max_curvature: float
                ) -> tuple[float, float]:
    """Return the unit normal of the total-least-squares line of the scatter ``S``.

    ``S = [[sxx, sxy], [sxy, syy]]`` are (pooled) second moments about their mean, at
    any scale. The line runs along the principal axis ``0.5 atan2(2 sxy, sxx - syy)``;
    (0, 0) when there is no line: an empty scatter, or a curvature (the smaller
    eigenvalue's share of the trace, Pauly et al. 2002) above ``max_curvature``.
    """
    total = sxx + syy
    if total <= 0.0:
        return 0.0, 0.0
    spread = math.sqrt((0.5 * (sxx - syy)) ** 2 + sxy * sxy)
    if (0.5 * total - spread) / total > max_curvature:
        return 0.0, 0.0
    principal = 0.5 * math.atan2(2.0 * sxy, sxx - syy)
    return -math.sin(principal), math.cos(principal)
