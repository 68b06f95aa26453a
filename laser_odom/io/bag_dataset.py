"""A recorded bag as a benchmark dataset: its scans, wheel odometry and reference.

``laser_odom_bench --bag`` reads a bag through
:class:`laser_odom.io.bag_reader.BagReader`: the scans of its only ``LaserScan``
topic, the ``/odom`` wheel odometry if present, and a reference - a TUM file given
with it, or else the bag's ``/ground_truth`` Odometry topic.
"""

from __future__ import annotations

from pathlib import Path
from typing import Callable, Collection, Sequence

import numpy as np

from laser_odom.core.metrics import associate
from laser_odom.core.trajectory import Dataset, Trajectory
from laser_odom.io.bag_reader import BagReader, LASER_SCAN, ODOMETRY
from laser_odom.io.tum import read_tum

BAG_ODOMETRY = '/odom'
"""The wheel odometry topic of a ``--bag``."""

BAG_GROUND_TRUTH = '/ground_truth'
"""The reference topic of a ``--bag`` given no ``--reference``."""

NO_REFERENCE = '-'
"""A ``--reference`` that gives its bag none (the bag's ``/ground_truth``, if any)."""


def bag_name(path: str, taken: Collection[str]) -> str:
    """Return a dataset name for a bag: its directory or file name, made unique."""
    bag = Path(path)
    base = (bag.name if bag.is_dir() else bag.stem) or str(bag)
    name, number = base, 1
    while name in taken:
        number += 1
        name = f'{base}-{number}'
    return name


def bag_reference(reference: str | None) -> Trajectory | None:
    """Read a ``--reference`` TUM file (None for none); ValueError in one line."""
    if reference is None or reference == NO_REFERENCE:
        return None
    if not Path(reference).is_file():
        raise ValueError(f'reference file not found: {reference}')
    return read_tum(reference)


def check_overlap(dataset: Dataset, source: str) -> None:
    """Raise ValueError when the reference pairs with fewer than two scans in time."""
    stamps = np.array([scan.stamp_ns for scan in dataset.scans], dtype=np.int64)
    paired = len(associate(Trajectory(stamps, np.zeros((len(stamps), 3))),
                           dataset.reference)[0])
    if paired < 2:
        raise ValueError(f'reference {source} does not overlap bag {dataset.name} in time: '
                         f'it pairs with {paired} of {len(stamps)} scans (stamps within '
                         '10 ms)')


def load_bag_dataset(path: str, name: str, reference: str | None = None) -> Dataset:
    """Read a bag's scans, ``/odom`` and reference (``--reference``, else ``/ground_truth``).

    Raises ValueError or :class:`BagError` (one line) for a missing bag, a bag without
    scans and a reference that does not overlap the scans in time.
    """
    truth = bag_reference(reference)
    with BagReader(path) as bag:
        scans = list(bag.scans(bag.select_topic(LASER_SCAN)))
        if len(scans) < 2:
            raise ValueError(f'{path}: {len(scans)} scans; a benchmark needs a bag with scans')
        odometry = (bag.odometry(BAG_ODOMETRY) if bag.topics.get(BAG_ODOMETRY) == ODOMETRY
                    else Trajectory())
        if truth is None and bag.topics.get(BAG_GROUND_TRUTH) == ODOMETRY:
            truth, reference = bag.odometry(BAG_GROUND_TRUTH), f'{path}:{BAG_GROUND_TRUTH}'
    dataset = Dataset(name, scans, odometry, truth if truth is not None else Trajectory())
    if truth is not None:
        check_overlap(dataset, str(reference))
    return dataset


def bag_loaders(bags: Sequence[str], references: Sequence[str],
                taken: Collection[str]) -> dict[str, Callable[[], Dataset]]:
    """Read every ``--bag`` now (bad input fails before the runs); name -> loader.

    The i-th reference belongs to the i-th bag; names avoid those in ``taken``.
    """
    if len(references) > len(bags):
        raise ValueError(f'{len(references)} --reference for {len(bags)} --bag: the i-th '
                         '--reference belongs to the i-th --bag')
    loaders: dict[str, Callable[[], Dataset]] = {}
    for index, path in enumerate(bags):
        name = bag_name(path, [*taken, *loaders])
        reference = references[index] if index < len(references) else None
        dataset = load_bag_dataset(path, name, reference)
        loaders[name] = lambda dataset=dataset: dataset
    return loaders
