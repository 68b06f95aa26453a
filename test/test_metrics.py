"""Tests of the trajectory metrics against analytically known answers."""

import math

import numpy as np
import pytest

from laser_odom.core import se2
from laser_odom.core.evaluation.metrics import (
    align_se2, associate, distance_travelled, drift_segment_length, evaluate, relative_errors,
    segment_drift)
from laser_odom.core.trajectory import Trajectory


def _circle_trajectory(n: int = 200, radius: float = 5.0, dt_ns: int = 100_000_000,
                       start_ns: int = 1_000_000_000) -> Trajectory:
    """Return a robot driving a circle anticlockwise, heading along the tangent."""
    phi = np.linspace(0.0, 1.5 * math.pi, n)
    poses = np.column_stack((radius * np.cos(phi), radius * np.sin(phi),
                             se2.wrap_angle(phi + math.pi / 2)))
    return Trajectory(start_ns + dt_ns * np.arange(n), poses)


def _transformed(traj: Trajectory, t: se2.Pose) -> Trajectory:
    """Return the trajectory with every pose premultiplied by ``t``."""
    return Trajectory(traj.stamps_ns.copy(), np.array([se2.compose(t, p) for p in traj.poses]))


def test_distance_travelled_of_a_square():
    square = Trajectory([0, 1, 2, 3, 4], [[0, 0, 0], [2, 0, 0], [2, 2, 0], [0, 2, 0], [0, 0, 0]])
    assert distance_travelled(square) == pytest.approx(8.0)
    assert distance_travelled(Trajectory([5], [[1, 2, 3]])) == 0.0


def test_rigid_offset_gives_zero_ate_and_rpe():
    reference = _circle_trajectory()
    estimate = _transformed(reference, se2.pose(3.0, -7.0, 2.2))
    errors = evaluate(estimate, reference)
    assert errors.pairs == len(reference)
    assert errors.steps == len(reference) - 1
    assert errors.ate_rms == pytest.approx(0.0, abs=1e-9)
    assert errors.rpe_trans_rms == pytest.approx(0.0, abs=1e-9)
    assert errors.rpe_rot_rms == pytest.approx(0.0, abs=1e-9)
    assert errors.failed_steps == 0
    # The alignment maps the estimate back: it is the inverse of the offset applied.
    np.testing.assert_allclose(errors.alignment, se2.inverse(se2.pose(3.0, -7.0, 2.2)),
                               atol=1e-9)


def test_align_se2_recovers_known_transform_from_noisy_points():
    rng = np.random.default_rng(3)
    source = rng.uniform(-10, 10, size=(500, 2))
    truth = se2.pose(1.5, -2.0, 0.7)
    target = se2.transform_points(truth, source) + rng.normal(0, 0.01, size=(500, 2))
    np.testing.assert_allclose(align_se2(source, target), truth, atol=5e-3)


def test_constant_per_step_error_gives_known_rpe():
    # Reference: straight line, 1 m steps. Estimate: every step is 1.1 m and turns 2 deg.
    n = 21
    reference = Trajectory(np.arange(n) * 10**8, np.column_stack(
        (np.arange(n, dtype=float), np.zeros(n), np.zeros(n))))
    step = se2.pose(1.1, 0.0, math.radians(2.0))
    poses = [se2.pose()]
    for _ in range(n - 1):
        poses.append(se2.compose(poses[-1], step))
    estimate = Trajectory(reference.stamps_ns, np.array(poses))
    errors = evaluate(estimate, reference)
    # E = (1 m straight)^-1 * step = (0.1, 0, 2 deg) every step.
    assert errors.steps == n - 1
    assert errors.rpe_trans_mean == pytest.approx(0.1, abs=1e-12)
    assert errors.rpe_trans_rms == pytest.approx(0.1, abs=1e-12)
    assert errors.rpe_rot_mean == pytest.approx(2.0, abs=1e-9)
    assert errors.rpe_rot_rms == pytest.approx(2.0, abs=1e-9)
    assert errors.failed_steps == 0
    assert errors.ate_rms > 0.5  # the curved estimate cannot be aligned onto the line


def test_rpe_chains_the_estimate_between_keyframes():
    # Estimate at every scan, reference only at every 3rd scan: still an exact match.
    reference = _circle_trajectory(n=91)
    estimate = _transformed(reference, se2.pose(-1.0, 4.0, -0.3))
    keyframes = Trajectory(reference.stamps_ns[::3], reference.poses[::3])
    errors = evaluate(estimate, keyframes)
    assert errors.pairs == 31 and errors.steps == 30
    assert errors.rpe_trans_rms == pytest.approx(0.0, abs=1e-9)
    assert errors.ate_rms == pytest.approx(0.0, abs=1e-9)


def test_failed_steps_are_counted_by_both_thresholds():
    n = 11
    reference = Trajectory(np.arange(n) * 10**8, np.column_stack(
        (np.arange(n, dtype=float), np.zeros(n), np.zeros(n))))
    est_steps = [se2.pose(1.0, 0.0, 0.0)] * (n - 1)
    est_steps[2] = se2.pose(1.6, 0.0, 0.0)                 # 0.6 m error: failed
    est_steps[5] = se2.pose(1.0, 0.0, math.radians(12.0))  # 12 deg error: failed
    est_steps[7] = se2.pose(1.4, 0.0, math.radians(9.0))   # below both: not failed
    poses = [se2.pose()]
    for s in est_steps:
        poses.append(se2.compose(poses[-1], s))
    errors = evaluate(Trajectory(reference.stamps_ns, np.array(poses)), reference)
    assert errors.failed_steps == 2
    np.testing.assert_allclose(errors.rpe_trans[[2, 5, 7]], [0.6, 0.0, 0.4], atol=1e-12)
    np.testing.assert_allclose(errors.rpe_rot[[2, 5, 7]], [0.0, 12.0, 9.0], atol=1e-9)
    assert errors.rpe_trans_mean == pytest.approx(1.0 / 10, abs=1e-12)


def test_association_by_nearest_stamp_within_tolerance():
    estimate = Trajectory([100, 200, 300, 400], np.zeros((4, 3)))
    reference = Trajectory([99, 205, 260, 300, 301, 1000], np.zeros((6, 3)))
    ref_index, est_index = associate(estimate, reference, max_offset_ns=10)
    # 99->100, 205->200, 260 is 40 ns from anything, 300 exact wins over 301.
    assert ref_index.tolist() == [0, 1, 3]
    assert est_index.tolist() == [0, 1, 2]


def test_offset_stamps_use_the_interpolated_reference():
    reference = _circle_trajectory(n=100)
    shifted = Trajectory(reference.stamps_ns[:-1] + 5_000_000, np.array(
        [reference.interpolate(int(t) + 5_000_000) for t in reference.stamps_ns[:-1]]))
    errors = evaluate(shifted, reference, max_offset_ns=6_000_000)
    assert errors.pairs == 99
    assert errors.ate_rms < 1e-3  # chord-vs-arc interpolation error only


def test_relative_errors_wraps_angles():
    ref = np.array([[0.0, 0.0, math.pi - 0.01], [0.0, 0.0, -math.pi + 0.01]])
    est = np.array([[0.0, 0.0, 0.0], [0.0, 0.0, 0.02]])
    trans, rot = relative_errors(est, ref)
    assert trans[0] == pytest.approx(0.0) and rot[0] == pytest.approx(0.0, abs=1e-9)


def test_no_overlap_raises():
    with pytest.raises(ValueError):
        evaluate(Trajectory([0], [[0, 0, 0]]), Trajectory([10**9], [[0, 0, 0]]))


# --- drift over segments of path (KITTI style) -------------------------------------

def _straight(n: int, spacing: float, scale: float = 1.0, yaw_per_metre: float = 0.0
              ) -> Trajectory:
    """Return n poses ``spacing`` apart along x, the distances scaled and heading turned."""
    s = np.arange(n) * spacing
    return Trajectory(1_000_000_000 + 100_000_000 * np.arange(n),
                      np.column_stack((scale * s, np.zeros(n), yaw_per_metre * s)))


def test_segment_drift_of_a_scale_error_is_that_error_per_path_length():
    reference = _straight(2001, 0.1)  # 200 m
    drift = segment_drift(_straight(2001, 0.1, scale=1.01), reference)
    assert drift.length == 50.0
    assert drift.translation == pytest.approx(1.0, rel=1e-6)
    assert drift.rotation == pytest.approx(0.0, abs=1e-12)
    assert drift.segments == 2001 - 500


def test_segment_drift_of_a_heading_drift_is_its_rate():
    reference = _straight(2001, 0.1)
    rate = math.radians(0.05)  # deg per metre
    drift = segment_drift(_straight(2001, 0.1, yaw_per_metre=rate), reference)
    assert drift.rotation == pytest.approx(0.05, rel=1e-6)


def test_short_runs_use_shorter_segments_and_too_short_ones_have_none():
    assert drift_segment_length(120.0) == 50.0
    assert drift_segment_length(60.0) == 20.0
    assert drift_segment_length(15.0) == 5.0
    assert drift_segment_length(1.0) == 2.0
    reference = _straight(601, 0.1)  # 60 m
    drift = segment_drift(_straight(601, 0.1, scale=0.98), reference)
    assert drift.length == 20.0 and drift.translation == pytest.approx(2.0, rel=1e-6)
    none = segment_drift(_straight(11, 0.1), _straight(11, 0.1), length=5.0)
    assert none.segments == 0 and math.isnan(none.translation)
