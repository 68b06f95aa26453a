"""A reference covers a run by time span, not by the share of poses it pairs with (issue 30.15)."""

import numpy as np
import pytest

from laser_odom.core.evaluation.coverage import max_hole, reference_coverage
from laser_odom.core.trajectory import Trajectory

PERIOD = 100_000_000
"""10 Hz scans [ns]."""

STAMPS = np.arange(100, dtype=np.int64) * PERIOD + 10 ** 18
"""A 9.9 s run of 100 scans."""


def _reference(index: np.ndarray, offset_ns: int = 0) -> Trajectory:
    """Return reference poses at the scans ``index``, shifted by ``offset_ns``."""
    return Trajectory(STAMPS[index] + offset_ns, np.zeros((len(index), 3)))


def test_keyframes_every_third_scan_cover_the_whole_run():
    """MIT CSAIL's official reference pairs with 35 % of the scans and spans the run."""
    coverage = reference_coverage(STAMPS, _reference(np.arange(0, 100, 3)))
    assert coverage.paired == 34 and coverage.share == pytest.approx(0.34)
    assert coverage.span == pytest.approx(1.0)
    assert coverage.describe() == (
        '34 of 100 poses paired (34 %), covering 100 % of the run in time')


def test_a_reference_that_stops_early_covers_only_its_part():
    coverage = reference_coverage(STAMPS, _reference(np.arange(40)))
    assert coverage.span == pytest.approx(39 / 99)


def test_another_clock_pairs_too_few_of_its_own_poses():
    """Shifted by half a period, 2 of its 99 poses within the run pair: not a comparison."""
    shifted = _reference(np.arange(100), offset_ns=PERIOD // 2)
    shifted.stamps_ns[[10, 60]] -= PERIOD // 2
    coverage = reference_coverage(STAMPS, shifted)
    assert coverage.paired == 2 and coverage.poses == pytest.approx(2 / 99)
    assert coverage.fraction == coverage.poses
    assert coverage.shortfall() == ('only 2 % of its poses within the run pair with a scan '
                                    '(2 of 100 scans paired): another clock or another run?')


def test_keyframes_seconds_apart_and_a_dense_ground_truth_cover_the_run():
    """Intel's 345 keyframes lie one in 16 scans of a 5 Hz run; a 100 Hz truth pairs 1:1."""
    slow = np.arange(1600, dtype=np.int64) * 200_000_000 + 10 ** 18
    keyframes = Trajectory(slow[::16], np.zeros((100, 3)))
    coverage = reference_coverage(slow, keyframes)
    assert coverage.hole == pytest.approx(9.6) and coverage.span == pytest.approx(1584 / 1599)
    assert coverage.poses == 1.0 and coverage.fraction == coverage.span
    dense = Trajectory(np.arange(1000, dtype=np.int64) * 10_000_000 + 10 ** 18,
                       np.zeros((1000, 3)))
    truth = reference_coverage(STAMPS, dense)
    assert (truth.paired, truth.poses, truth.span) == (100, 1.0, pytest.approx(1.0))


def test_holes_longer_than_the_limit_are_not_covered():
    """A 3 s hole in a 10 Hz run is not covered (2 s limit); 20 periods of a slow scanner are."""
    kept = np.r_[np.arange(0, 50), np.arange(80, 100)]
    coverage = reference_coverage(STAMPS, _reference(kept))
    assert coverage.hole == 2.0 and coverage.poses == 1.0
    assert coverage.span == pytest.approx((49 + 19) / 99)
    assert coverage.shortfall().startswith('it covers only 69 % of the run in time (70 of '
                                           '100 poses paired; poses more than 2 s apart')
    slow = STAMPS[::5]  # 2 Hz: the limit is 20 periods, 10 s
    assert max_hole(slow) == pytest.approx(10.0)
    assert reference_coverage(slow, _reference(np.array([0, 50, 95]))).span == pytest.approx(1.0)


def test_an_empty_run_or_reference_covers_nothing():
    assert reference_coverage(STAMPS, Trajectory()).fraction == 0.0
    assert reference_coverage(STAMPS[:0], _reference(np.arange(3))).total == 0
    one = reference_coverage(STAMPS[:1], _reference(np.arange(1)))
    assert one.paired == 1 and one.span == 1.0
