"""One reader of a recorded bag for the tools: its scans, wheel odometry, IMU, reference.

``laser_odom_bench --bag`` and ``laser_odom_tune`` read a bag through
:class:`laser_odom.io.bag_reader.BagReader` with :func:`read_bag`: the scans of one
``LaserScan`` topic (``--scan-topic``, default the only one), the wheel odometry of
``/odom`` if present, the IMU if the bag has exactly one, and a reference - a TUM file
given with it, or else the bag's ``/ground_truth`` Odometry topic. Every problem is a
one-line ``ValueError`` or :class:`BagError`.
"""

from __future__ import annotations

from pathlib import Path
from typing import Callable, Collection, Sequence

import numpy as np

from laser_odom.core.evaluation.coverage import reference_coverage
from laser_odom.core.trajectory import Dataset, RecordedBag, Trajectory
from laser_odom.io.bag_reader import BagReader, IMU, LASER_SCAN, ODOMETRY
from laser_odom.io.tum import read_tum, TumFormatError

BAG_ODOMETRY = '/odom'
"""The wheel odometry topic of a bag, unless a tool is told another."""

BAG_GROUND_TRUTH = '/ground_truth'
"""The reference topic of a bag given no reference file."""

NO_REFERENCE = '-'
"""A ``--reference`` that gives its bag no file (the bag's ``/ground_truth``, if any)."""


def _name_parts(path: str) -> list[str]:
    """Return a bag path's components, the bag's own name (a file without suffix) last."""
    bag = Path(path)
    parts = [part for part in bag.resolve().parts if part not in ('/', '')] or [str(bag)]
    if not bag.is_dir():
        parts[-1] = bag.stem or parts[-1]
    return parts


def bag_names(paths: Sequence[str], taken: Collection[str] = ()) -> list[str]:
    """Return a dataset name for each bag: its directory or file name, told apart.

    Bags of the same name (``A/bag``, ``B/bag``) are named by as many of their parent
    folders as it takes to tell them apart (``A/bag``, ``B/bag``); a name in ``taken``
    (a simulated or real dataset) or the same bag given twice gets ``-2``, ``-3``.
    """
    parts = [_name_parts(path) for path in paths]
    depth = [1] * len(paths)

    def name(i: int) -> str:
        return '/'.join(parts[i][-depth[i]:])

    while True:
        names = [name(i) for i in range(len(paths))]
        clashing = [i for i, n in enumerate(names) if depth[i] < len(parts[i]) and any(
            names[j] == n and parts[j] != parts[i] for j in range(len(paths)))]
        if not clashing:
            break
        for i in clashing:
            depth[i] += 1
    unique: list[str] = []
    for base in names:
        candidate, number = base, 1
        while candidate in taken or candidate in unique:
            number += 1
            candidate = f'{base}-{number}'
        unique.append(candidate)
    return unique


def bag_reference(reference: str | None) -> Trajectory | None:
    """Read a reference TUM file (None for none); ValueError in one line."""
    if reference is None or reference == NO_REFERENCE:
        return None
    if not Path(reference).is_file():
        raise ValueError(f'reference file not found: {reference}')
    try:
        return read_tum(reference)
    except (OSError, TumFormatError) as err:
        raise ValueError(f'cannot read reference {reference}: {err}') from None


def read_bag(path: str, reference: str | None = None, scan_topic: str | None = None,
             odom_topic: str | None = None, purpose: str = 'a benchmark') -> RecordedBag:
    """Read a bag's scans, odometry, IMU and reference (``reference``, else ``/ground_truth``).

    The wheel odometry is ``odom_topic`` - which the bag must then have - or else
    ``/odom`` if present. Raises ValueError or :class:`BagError` (one line) for a
    missing bag, an unknown or ambiguous scan topic, fewer than two scans (``purpose``
    says what needed them), a missing ``odom_topic`` and an unreadable reference file.
    """
    truth = bag_reference(reference)
    with BagReader(path) as bag:
        scans = list(bag.scans(bag.select_topic(LASER_SCAN, scan_topic)))
        if len(scans) < 2:
            raise ValueError(f'{path}: {len(scans)} scans; {purpose} needs a bag with scans')
        if odom_topic is not None:
            odom_topic = bag.select_topic(ODOMETRY, odom_topic, '--odom-topic')
        elif bag.topics.get(BAG_ODOMETRY) == ODOMETRY:
            odom_topic = BAG_ODOMETRY
        odometry = bag.odometry(odom_topic) if odom_topic is not None else None
        imu_topics = bag.topics_of_type(IMU)
        imu = bag.imu(imu_topics[0]) if len(imu_topics) == 1 else None
        source = reference if truth is not None else None
        if truth is None and bag.topics.get(BAG_GROUND_TRUTH) == ODOMETRY:
            truth, source = bag.odometry(BAG_GROUND_TRUTH), f'{path}:{BAG_GROUND_TRUTH}'
    return RecordedBag(str(path), scans, odometry, imu, truth, source)


def check_overlap(bag: RecordedBag, name: str, min_coverage: float = 0.0) -> None:
    """Raise ValueError when the reference covers too little of the bag's scans in time.

    Too little is fewer than two paired scans, or less than ``min_coverage`` of the
    run's duration (the replay's ``--min-coverage`` rule, by time span: a keyframe
    reference spanning the whole run covers it, :mod:`laser_odom.core.evaluation.coverage`).
    """
    stamps = np.array([scan.stamp_ns for scan in bag.scans], dtype=np.int64)
    reference = bag.reference if bag.reference is not None else Trajectory()
    coverage = reference_coverage(stamps, reference)
    if coverage.paired < 2:
        raise ValueError(f'reference {bag.reference_source} does not overlap {name} in time: '
                         f'it pairs with {coverage.paired} of {len(stamps)} scans (stamps '
                         'within 10 ms)')
    if coverage.fraction < min_coverage:
        raise ValueError(f'reference {bag.reference_source} of {name}: '
                         f'{coverage.shortfall()}, less than --min-coverage {min_coverage:g}')


def load_bag_dataset(path: str, name: str, reference: str | None = None,
                     scan_topic: str | None = None) -> Dataset:
    """Read a bag as a benchmark dataset; one-line errors as :func:`read_bag`, overlap too."""
    bag = read_bag(path, reference, scan_topic)
    if bag.reference is not None:
        check_overlap(bag, f'bag {name}')
    return Dataset(name, bag.scans, bag.odometry if bag.odometry is not None else Trajectory(),
                   bag.reference if bag.reference is not None else Trajectory())


def bag_loaders(bags: Sequence[str], references: Sequence[str], taken: Collection[str],
                scan_topic: str | None = None) -> dict[str, Callable[[], Dataset]]:
    """Read every ``--bag`` now (bad input fails before the runs); name -> loader.

    The i-th reference belongs to the i-th bag; names avoid those in ``taken``.
    """
    if len(references) > len(bags):
        raise ValueError(f'{len(references)} --reference for {len(bags)} --bag: the i-th '
                         '--reference belongs to the i-th --bag')
    loaders: dict[str, Callable[[], Dataset]] = {}
    for index, (path, name) in enumerate(zip(bags, bag_names(bags, taken))):
        reference = references[index] if index < len(references) else None
        dataset = load_bag_dataset(path, name, reference, scan_topic)
        loaders[name] = lambda dataset=dataset: dataset
    return loaders
