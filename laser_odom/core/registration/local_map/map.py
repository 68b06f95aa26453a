"""A local map of the recent scans, the reference that scan matching drifts least against.

Scan-to-scan odometry adds every step's error to the next. Matching against a map of
the last metres instead (Cartographer's submaps, hector_mapping's grid, IMLS-SLAM's
model, KISS-ICP's voxel map) averages the sensor noise of many scans and keeps in view
walls the last scan lost. The map here is a hash of small square cells in the odom
frame, each holding the moments of the points that fell in it
(:mod:`laser_odom.core.registration.local_map.cells`), bounded in radius around the robot and in
cell count, so memory and time per scan stay flat over hours. Per match the map is
seen from the previous pose as a virtual scan with the map's own normals
(:mod:`laser_odom.core.registration.local_map.view`), which every matcher takes as it takes a
reference scan: ``icp`` pairs with its points, ``nicp`` with their normals and
curvature, ``imls`` builds its implicit surface over them, ``plicp`` joins
neighbouring bearings into Censi's segments, and the global search rasterises them.
"""

from __future__ import annotations

from dataclasses import dataclass
import math

import numpy as np

from laser_odom.core import se2
from laser_odom.core.registration.local_map.cells import (
    add_points, ALIVE, cell_key, EMPTY, find_cell, FLOAT_COLUMNS, INT_COLUMNS, LAST_SEEN, MEAN_X,
    MEAN_Y, refresh_blocks, remove_cells, stale_cells, WEIGHT)
from laser_odom.core.registration.local_map.surface_fit import fit_to_surfaces
from laser_odom.core.registration.local_map.view import ranges_by_bin, render_view, seen_through
from laser_odom.core.scan.laser_scan import ScanPoints

OCCLUSION_CELLS = 2.0
"""Cells within this many cell sizes of the nearest one in a bearing bin are averaged
into the view's point; farther ones are hidden behind it."""

CARVE_MARGIN = 0.1
"""A cell is seen through when the beams reach at least this far [m] (plus two cells)
beyond it."""


@dataclass(frozen=True)
class MapGeometry:
    """The map's fixed settings: cell size [m], radius [m], cell budget, weight cap, age.

    ``max_age`` is how many insertions a cell survives without being seen again.
    """

    resolution: float
    radius: float
    max_cells: int
    max_weight: float
    max_age: int


class LocalMap:
    """Cells of recent scan points in the odom frame, with their local surfaces."""

    def __init__(self, geometry: MapGeometry) -> None:
        """Allocate the tables for ``geometry.max_cells`` cells (an empty map)."""
        self.geometry = geometry
        capacity = int(geometry.max_cells)
        self._floats = np.zeros((capacity, FLOAT_COLUMNS))
        self._ints = np.zeros((capacity, INT_COLUMNS), dtype=np.int64)
        slots = 1 << max(int(math.ceil(math.log2(2 * capacity))), 4)
        self._slot_keys = np.full(slots, EMPTY, dtype=np.int64)
        self._slot_cells = np.zeros(slots, dtype=np.int64)
        self._free = np.arange(capacity - 1, -1, -1, dtype=np.int64)
        self._free_count = np.array([capacity], dtype=np.int64)
        self._touched = np.zeros(0, dtype=np.int64)
        self._used_rows = 0
        self.insertions = 0
        self._refreshes = 0

    def clear(self) -> None:
        """Forget every cell (in place: the tables are kept, so memory stays flat)."""
        self._floats.fill(0.0)
        self._ints.fill(0)
        self._slot_keys.fill(EMPTY)
        self._slot_cells.fill(0)
        self._free[:] = np.arange(len(self._free) - 1, -1, -1, dtype=np.int64)
        self._free_count[0] = len(self._free)
        self._used_rows = 0
        self.insertions = 0
        self._refreshes = 0

    def __len__(self) -> int:
        """Return the number of cells in use."""
        return int(self._ints.shape[0] - self._free_count[0])

    def cell_means(self) -> tuple[np.ndarray, np.ndarray]:
        """Return the mean point (N, 2, odom frame) and weight (N,) of every cell in use."""
        alive = np.flatnonzero(self._ints[:, ALIVE])
        return (self._floats[alive][:, [MEAN_X, MEAN_Y]].copy(),
                self._floats[alive, WEIGHT].copy())

    def find(self, point: np.ndarray) -> int:
        """Return the cell (row of the tables) holding odom-frame ``point``, -1 if none."""
        key = cell_key(float(point[0]), float(point[1]), 1.0 / self.geometry.resolution)
        return int(find_cell(self._slot_keys, self._slot_cells, key))

    def _used(self) -> tuple[np.ndarray, np.ndarray]:
        """Return the rows of the tables that ever held a cell (views, not copies).

        The free list hands out rows from the lowest up and takes freed ones back on
        top, so rows past the most ever in use at once were never touched: the loops
        over every cell (view, carving, staleness) stop there instead of at the
        budget (``max_cells``), which is mostly headroom.
        """
        return self._floats[:self._used_rows], self._ints[:self._used_rows]

    @property
    def nbytes(self) -> int:
        """Bytes the map's tables hold (fixed by ``max_cells``)."""
        return int(self._floats.nbytes + self._ints.nbytes + self._slot_keys.nbytes
                   + self._slot_cells.nbytes + self._free.nbytes)

    def insert(self, points: np.ndarray, pose: se2.Pose, sensor: np.ndarray,
               bin_angle: float) -> None:
        """Add a scan's base-frame ``points`` seen from base ``pose`` (odom frame).

        First the cells the scan saw through lose weight (and go when below one
        observation), then the points join their cells, the blocks around every
        changed cell are pooled again, and cells beyond the radius or over the budget
        (the longest unseen first) are dropped.
        """
        self.insertions += 1
        pose = np.asarray(pose, dtype=float)
        sensor = np.asarray(sensor, dtype=float)
        geometry = self.geometry
        bins = max(int(math.ceil(2.0 * math.pi / bin_angle)), 1)
        measured = ranges_by_bin(np.ascontiguousarray(points, dtype=float), sensor,
                                 bin_angle, bins)
        gone = seen_through(*self._used(), pose, sensor, measured, bin_angle,
                            CARVE_MARGIN + 2.0 * geometry.resolution,
                            0.5 * geometry.resolution)
        self._remove(gone, refresh=True)
        self._make_room(len(points))
        world = np.ascontiguousarray(se2.transform_points(pose, points), dtype=float)
        if self._touched.shape[0] < len(world):
            self._touched = np.zeros(len(world), dtype=np.int64)
        touched = add_points(world, 1.0 / geometry.resolution, geometry.max_weight,
                             self.insertions, self._floats, self._ints, self._slot_keys,
                             self._slot_cells, self._free, self._free_count, self._touched)
        self._used_rows = max(self._used_rows, len(self._free) - int(self._free_count[0]))
        self._refresh(self._touched[:touched])
        self._remove(stale_cells(pose[0], pose[1], geometry.radius,
                                 self.insertions - geometry.max_age, *self._used()),
                     refresh=True)

    def view(self, pose: se2.Pose, sensor: np.ndarray, bin_angle: float,
             max_range: float, min_hits: int = 1, stamp_ns: int = 0) -> ScanPoints:
        """Return the map as a virtual scan seen from base ``pose``, in its base frame.

        One point per bearing bin of ``bin_angle`` around the ``sensor`` (its position
        on the base), out to ``max_range``, where the bin's central ray meets the map's
        local surface (:func:`.local_map.view.render_view`). Cells need ``min_hits``
        insertions, unless the latest made them.
        """
        geometry = self.geometry
        sensor = np.asarray(sensor, dtype=float)
        rows = render_view(*self._used(), np.asarray(pose, dtype=float), sensor,
                           float(bin_angle), float(max_range),
                           OCCLUSION_CELLS * geometry.resolution, 0.5 * geometry.resolution,
                           int(min_hits), self.insertions)
        return ScanPoints(points=np.ascontiguousarray(rows[:, :2]),
                          beam_index=rows[:, 3].astype(np.int64), ranges=rows[:, 2].copy(),
                          stamp_ns=stamp_ns, virtual=True)

    def fit_to_surfaces(self, points: np.ndarray, pose: se2.Pose, weak_share: float = 0.0
                        ) -> tuple[np.ndarray, int]:
        """Refine ``pose`` of base-frame ``points`` on the cells' surfaces; pose and pairs.

        :func:`.local_map.surface_fit.fit_to_surfaces`.
        """
        return fit_to_surfaces(points, np.asarray(pose, dtype=float), self._floats,
                               self._ints, self._slot_keys, self._slot_cells,
                               1.0 / self.geometry.resolution, weak_share)

    def _refresh(self, changed: np.ndarray) -> None:
        """Pool the block moments around the changed cells again."""
        if len(changed):
            self._refreshes += 1
            refresh_blocks(changed, 1.0 / self.geometry.resolution, self._refreshes,
                           self._floats, self._ints, self._slot_keys, self._slot_cells)

    def _remove(self, cells: np.ndarray, refresh: bool) -> None:
        """Drop cells; with ``refresh`` the blocks of their neighbours are pooled again."""
        if len(cells) == 0:
            return
        remove_cells(cells, self._floats, self._ints, self._slot_keys, self._slot_cells,
                     self._free, self._free_count)
        if refresh:
            self._refresh(cells)

    def _make_room(self, needed: int) -> None:
        """Free cells for ``needed`` new ones, dropping the longest unseen first."""
        short = int(needed - self._free_count[0])
        if short <= 0:
            return
        alive = np.flatnonzero(self._ints[:, ALIVE])
        short = min(short, len(alive))
        oldest = alive[np.argpartition(self._ints[alive, LAST_SEEN], short - 1)[:short]]
        self._remove(oldest, refresh=True)
