"""Derived datasets: as a bag holds them, copies with range noise, fast-robot re-stamping."""

import json
import math

import numpy as np
import pytest

from laser_odom.core.datasets import as_received, restamped, with_range_noise
from laser_odom.core.evaluation.benchmark import BenchRow
from laser_odom.core.evaluation.spread import spread_rows
from laser_odom.core.simulation import LaserModel, simulate
from laser_odom.io.bag_reader import open_bag
from laser_odom.io.bag_writer import write_bag
from laser_odom.tools.bench import dataset_copies, main as bench_main


@pytest.fixture(scope='module')
def dataset():
    """Return 4 s of the office with dropouts (NaN) and beams beyond range (inf)."""
    return simulate('office', 4.0, LaserModel(dropout=0.05, max_range=6.0), seed=5,
                    odometry_rate=20.0)


def test_as_received_is_what_a_bag_gives_back_bit_for_bit(tmp_path, dataset):
    path = tmp_path / 'bag'
    write_bag(path, dataset.scans)
    with open_bag(path) as bag:
        from_bag = list(bag.scans())
    received = as_received(dataset).scans
    assert len(from_bag) == len(received) == len(dataset.scans)
    changed = 0
    for ours, theirs, original in zip(received, from_bag, dataset.scans):
        np.testing.assert_array_equal(ours.ranges, theirs.ranges)
        for name in ('angle_min', 'angle_max', 'angle_increment', 'range_min', 'range_max',
                     'time_increment', 'scan_time'):
            assert getattr(ours, name) == getattr(theirs, name), name
        assert ours.stamp_ns == theirs.stamp_ns
        finite = np.isfinite(original.ranges)
        changed += int(np.count_nonzero(ours.ranges[finite] != original.ranges[finite]))
    assert changed > 0  # the simulator's float64 ranges do lose bits in a message


def test_range_noise_is_a_millimetre_reproducible_and_keeps_no_returns(dataset):
    first, again = with_range_noise(dataset, 3), with_range_noise(dataset, 3)
    other = with_range_noise(dataset, 4)
    before = np.concatenate([scan.ranges for scan in dataset.scans])
    after = np.concatenate([scan.ranges for scan in first.scans])
    np.testing.assert_array_equal(after, np.concatenate([s.ranges for s in again.scans]))
    assert not np.array_equal(after, np.concatenate([s.ranges for s in other.scans]))
    valid = np.isfinite(before) & (before <= 6.0)
    difference = after[valid] - before[valid]
    assert 0.0009 < np.std(difference) < 0.0011 and abs(np.mean(difference)) < 1e-4
    # A dropout stays a dropout, a beam beyond range stays one.
    np.testing.assert_array_equal(np.isnan(after), np.isnan(before))
    np.testing.assert_array_equal(np.isinf(after), np.isinf(before))
    assert dataset.scans[0].ranges is not first.scans[0].ranges


def test_restamped_keeps_every_pose_and_runs_the_clock_faster(dataset):
    subsampled = dataset.every(5)
    fast = restamped(subsampled, 0.1, 'fast')
    stamps = np.array([scan.stamp_ns for scan in fast.scans])
    assert fast.name == 'fast' and len(fast.scans) == len(subsampled.scans)
    np.testing.assert_array_equal(np.diff(stamps), 100_000_000)
    assert stamps[0] == subsampled.scans[0].stamp_ns
    for scan, old in zip(fast.scans, subsampled.scans):
        np.testing.assert_allclose(fast.reference.interpolate(scan.stamp_ns),
                                   subsampled.reference.interpolate(old.stamp_ns))
        np.testing.assert_allclose(fast.odometry.interpolate(scan.stamp_ns),
                                   dataset.odometry.interpolate(old.stamp_ns), atol=1e-12)
        np.testing.assert_array_equal(scan.ranges, old.ranges)
    with pytest.raises(ValueError, match='period'):
        restamped(dataset, 0.0)


def test_a_keyframe_reference_stays_on_its_keyframes(dataset):
    keyframes = dataset.reference
    keyframes = type(keyframes)(keyframes.stamps_ns[::7], keyframes.poses[::7])
    fast = restamped(type(dataset)('kf', dataset.scans, dataset.odometry, keyframes), 0.1)
    assert len(fast.reference) == len(keyframes)
    kept = {scan.stamp_ns for scan in fast.scans[::7]}
    assert set(fast.reference.stamps_ns.tolist()) == kept


def _row(copy: int, ate: float, failed: int, silent: int) -> BenchRow:
    """Return a bench row of one copy with the given figures."""
    nan = math.nan
    row = BenchRow('log', 'nicp', 'constant_velocity', 'auto', 360, 10, 9, nan, nan, nan,
                   nan, ate, failed, 0, 1.0, 2.0, silent=silent, reference='local_map')
    row.copy = copy
    return row


def test_spread_is_the_median_and_the_worst_copy():
    rows = [_row(1, 0.3, 0, 0), _row(2, 0.9, 2, 1), _row(3, 0.4, 1, 0)]
    spread, = spread_rows(rows)
    assert spread.copies == 3
    assert spread.median['ate'] == pytest.approx(0.4) and spread.worst['ate'] == 0.9
    assert spread.median['failed'] == 1 and spread.worst['silent'] == 1
    assert spread.cell('ate', 2) == '0.40 [0.90]'
    assert spread.cell('drift_trans', 2) == 'n/a'


def test_bench_perturb_prints_the_spread_over_noisy_copies(tmp_path, capsys):
    out = tmp_path / 'rows.json'
    assert bench_main(['--matchers', 'plicp', '--datasets', 'sim-gentle-drop20', '--priors',
                       'constant_velocity', '--perturb', '2', '--no-search-table',
                       '--no-progress', '--json', str(out)]) == 0
    printed = capsys.readouterr().out
    assert 'median [worst] over 2 copies' in printed
    payload = json.loads(out.read_text())
    assert [row['copy'] for row in payload['rows']] == [1, 2]
    assert payload['rows'][0]['ate'] != payload['rows'][1]['ate']
    spread, = payload['spread']
    assert spread['worst']['ate'] == max(row['ate'] for row in payload['rows'])
    assert spread['worst']['ate'] < 0.1 and spread['worst']['failed'] == 0
    # Side by side in two processes: the same figures, row for row.
    side = tmp_path / 'side.json'
    assert bench_main(['--matchers', 'plicp', '--datasets', 'sim-gentle-drop20', '--priors',
                       'constant_velocity', '--perturb', '2', '--no-search-table',
                       '--no-progress', '--jobs', '2', '--json', str(side)]) == 0
    assert [(row['copy'], row['ate'], row['failed']) for row in
            json.loads(side.read_text())['rows']] == [
        (row['copy'], row['ate'], row['failed']) for row in payload['rows']]
    assert bench_main(['--datasets', 'sim-gentle-drop20', '--jobs', '0']) == 2
    assert bench_main(['--datasets', 'sim-gentle-drop20', '--perturb', '-1']) == 2
    assert '--perturb must be >= 0' in capsys.readouterr().err


def test_copy_zero_is_the_dataset_as_received(dataset):
    (copy, received), = dataset_copies(dataset, 0, 0.001)
    assert copy == 0
    np.testing.assert_array_equal(received.scans[0].ranges, as_received(dataset).scans[0].ranges)
