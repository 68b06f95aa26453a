"""Tests of the reference-free score: map entropy and odometry disagreement (synthetic)."""

import math
import time

import numpy as np
import pytest

from laser_odom.core import se2
from laser_odom.core.evaluation.map_quality import (
    map_entropy, odometry_disagreement, reference_free_score)
from laser_odom.core.scan.laser_scan import scan_to_points
from laser_odom.core.simulation import simulate
from laser_odom.core.trajectory import Trajectory


@pytest.fixture(scope='module')
def run():
    """Return (stamps, true poses, base-frame points, wheel odometry) of a simulated run."""
    dataset = simulate('office', duration=20.0, seed=4)
    points = [scan_to_points(scan).points for scan in dataset.scans]
    return (dataset.reference.stamps_ns, dataset.reference.poses, points,
            dataset.odometry)


def _noisy(poses: np.ndarray, sigma: float, seed: int = 0) -> np.ndarray:
    """Return poses with independent noise: sigma [m] in x, y and sigma / 5 [rad] in yaw."""
    rng = np.random.default_rng(seed)
    return poses + rng.normal(size=poses.shape) * np.array([sigma, sigma, sigma / 5.0])


def _drifted(poses: np.ndarray, yaw_per_scan: float) -> np.ndarray:
    """Return the trajectory re-integrated with a yaw error added to every step."""
    steps = [se2.relative(a, b) for a, b in zip(poses[:-1], poses[1:])]
    out = [poses[0].copy()]
    for step in steps:
        out.append(se2.compose(out[-1], step + np.array([0.0, 0.0, yaw_per_scan])))
    return np.array(out)


def _odometry_at(odometry: Trajectory, stamps: np.ndarray) -> np.ndarray:
    return np.array([odometry.interpolate(int(s)) for s in stamps])


@pytest.mark.parametrize('measure', ['entropy', 'line_variance'])
def test_true_poses_are_sharpest_and_score_grows_with_noise(run, measure):
    stamps, poses, points, _ = run
    scores = [map_entropy(stamps, _noisy(poses, sigma), points, measure=measure)
              for sigma in (0.0, 0.01, 0.03, 0.1)]
    assert all(math.isfinite(s) for s in scores)
    assert np.all(np.diff(scores) > 0), scores


def test_drifted_poses_score_worse_monotonic_in_drift(run):
    stamps, poses, points, _ = run
    scores = [reference_free_score(stamps, _drifted(poses, drift), points)
              for drift in (0.0, 0.002, 0.005, 0.02)]
    assert np.all(np.diff(scores) > 0), scores


def test_reference_free_score_is_the_default_map_entropy(run):
    stamps, poses, points, _ = run
    assert reference_free_score(stamps, poses, points) == map_entropy(stamps, poses, points)


def test_window_in_seconds_and_subsampling_options_rank_the_same(run):
    stamps, poses, points, _ = run
    options = [{'window_seconds': 2.0}, {'window': 10, 'stride': 5},
               {'points_per_scan': None, 'queries_per_window': None, 'max_windows': None},
               {'max_range': None, 'radius': 0.1}]
    for kwargs in options:
        clean = map_entropy(stamps, poses, points, **kwargs)
        noisy = map_entropy(stamps, _noisy(poses, 0.03), points, **kwargs)
        assert math.isfinite(clean) and clean < noisy, kwargs


def test_fewer_scans_than_a_window_give_a_finite_score(run):
    stamps, poses, points, _ = run
    for count in (2, 3):
        score = map_entropy(stamps[:count], poses[:count], points[:count], window=30)
        assert math.isfinite(score)
    assert math.isfinite(map_entropy(stamps[:1], poses[:1], points[:1], points_per_scan=None))
    assert math.isfinite(map_entropy(stamps[:3], poses[:3], points[:3],
                                     window_seconds=60.0))


def test_empty_point_sets(run):
    stamps, poses, points, _ = run
    some_empty = [np.zeros((0, 2)) if k % 2 else p for k, p in enumerate(points)]
    assert math.isfinite(map_entropy(stamps, poses, some_empty))
    with pytest.raises(ValueError, match='empty or too sparse'):
        map_entropy(stamps, poses, [np.zeros((0, 2))] * len(stamps))


def test_inconsistent_inputs_raise_value_error(run):
    stamps, poses, points, _ = run
    with pytest.raises(ValueError, match='no scans'):
        map_entropy(np.zeros(0), np.zeros((0, 3)), [])
    with pytest.raises(ValueError, match='point sets'):
        map_entropy(stamps, poses, points[:-1])
    with pytest.raises(ValueError, match='stamps for'):
        map_entropy(stamps[:-1], poses, points)
    with pytest.raises(ValueError, match=r'shape \(N, 3\)'):
        map_entropy(stamps, poses[:, :2], points)
    with pytest.raises(ValueError, match='unknown measure'):
        map_entropy(stamps, poses, points, measure='sharpness')
    with pytest.raises(ValueError, match='odometry'):
        reference_free_score(stamps, poses, points, odom_weight=1.0)


def test_stamps_must_increase_only_where_they_are_used_as_times(run):
    stamps, poses, points, odometry = run
    looped = stamps.copy()
    looped[len(stamps) // 2:] -= stamps[len(stamps) // 2] - stamps[0]  # a bag that loops
    assert math.isfinite(map_entropy(looped, poses, points))
    with pytest.raises(ValueError, match='must not decrease'):
        map_entropy(looped, poses, points, window_seconds=2.0)
    with pytest.raises(ValueError, match='must not decrease'):
        odometry_disagreement(looped, poses, odometry)


def test_diverged_run_scores_infinite(run):
    stamps, poses, points, odometry = run
    broken = poses.copy()
    broken[5, 0] = np.nan
    assert map_entropy(stamps, broken, points) == math.inf
    assert odometry_disagreement(stamps, broken, odometry) == math.inf


def test_odometry_disagreement_is_zero_for_the_odometry_itself(run):
    stamps, _, _, odometry = run
    odom_poses = _odometry_at(odometry, stamps)
    assert odometry_disagreement(stamps, odom_poses, odometry) == pytest.approx(0.0, abs=1e-9)
    shifted = np.array([se2.compose(se2.pose(4.0, -2.0, 1.0), p) for p in odom_poses])
    assert odometry_disagreement(stamps, shifted, odometry,
                                 window_seconds=1.5) == pytest.approx(0.0, abs=1e-9)
    assert odometry_disagreement(stamps, _noisy(odom_poses, 0.02), odometry) > 0.01


def test_odometry_weight_adds_the_disagreement(run):
    stamps, poses, points, odometry = run
    entropy = map_entropy(stamps, poses, points)
    disagreement = odometry_disagreement(stamps, poses, odometry)
    assert disagreement > 0.0  # the simulated wheel odometry drifts
    combined = reference_free_score(stamps, poses, points, odometry, odom_weight=2.0)
    assert combined == pytest.approx(entropy + 2.0 * disagreement)
    odom_poses = _odometry_at(odometry, stamps)
    assert reference_free_score(stamps, odom_poses, points, odometry, 5.0) == pytest.approx(
        map_entropy(stamps, odom_poses, points), abs=1e-6)


def test_odometry_not_covering_the_run_raises(run):
    stamps, poses, _, _ = run
    elsewhere = Trajectory(stamps[-1] + np.arange(1, 4) * 1_000_000, np.zeros((3, 3)))
    with pytest.raises(ValueError, match='does not cover'):
        odometry_disagreement(stamps, poses, elsewhere)


def test_a_thousand_scans_score_in_well_under_a_second(run):
    stamps, poses, points, _ = run
    repeat = -(-1000 // len(stamps))
    many_stamps = np.arange(len(stamps) * repeat, dtype=np.int64) * 100_000_000
    many_poses = np.tile(poses, (repeat, 1))
    many_points = list(points) * repeat
    started = time.perf_counter()
    assert math.isfinite(reference_free_score(many_stamps, many_poses, many_points))
    assert time.perf_counter() - started < 2.0  # about 0.1 s; slack for a loaded machine
