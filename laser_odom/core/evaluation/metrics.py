"""Trajectory error metrics: ATE after SE(2) alignment and RPE between reference poses.

Odometry drifts, so its error is scored two ways (Sturm et al., "A benchmark for the
evaluation of RGB-D SLAM systems", IROS 2012, Sec. V):

- the absolute trajectory error (ATE) is the RMS position error after the estimate
  has been rigidly aligned to the reference. The alignment is the least-squares
  rotation and translation without scale (Umeyama, "Least-squares estimation of
  transformation parameters between two point patterns", PAMI 1991, eqs. 40-42;
  Arun et al. 1987), solved in closed form in 2D;
- the relative pose error (RPE) compares the motion between consecutive reference
  poses with the estimate's motion over the same interval,
  ``E_i = (Q_a^-1 Q_b)^-1 (P_a^-1 P_b)`` (Sturm et al., eq. 1). The estimate has a
  pose at every processed scan, so ``P_a^-1 P_b`` is the odometry chained over every
  scan between the two reference stamps; the reference may hold keyframes only.

Estimate and reference poses are paired by stamp: an exact match when there is one,
otherwise the nearest estimate within a tolerance, against the reference
interpolated to that estimate's stamp (so a small stamp offset is not scored as
position error).
"""

from __future__ import annotations

from dataclasses import dataclass, field
import math

import numpy as np

from laser_odom.core import se2
from laser_odom.core.trajectory import Trajectory

DEFAULT_MAX_OFFSET_NS = 10_000_000
"""Largest stamp difference [ns] at which an estimate and a reference pose are paired."""

FAILED_TRANSLATION = 0.5
"""A relative-pose step with a translational error above this [m] counts as failed."""

FAILED_ROTATION_DEG = 10.0
"""A relative-pose step with a rotational error above this [deg] counts as failed."""


@dataclass
class TrajectoryErrors:
    """Errors of an estimated trajectory against a reference.

    Translational errors are metres, rotational errors degrees. ``alignment`` is the
    SE(2) pose that maps estimate positions onto the reference (applied before ATE).
    Per-step arrays hold the RPE of each scored step, in reference order.
    """

    steps: int
    rpe_trans_mean: float
    rpe_trans_rms: float
    rpe_rot_mean: float
    rpe_rot_rms: float
    ate_rms: float
    failed_steps: int
    pairs: int
    alignment: np.ndarray = field(default_factory=se2.pose)
    rpe_trans: np.ndarray = field(default_factory=lambda: np.zeros(0))
    rpe_rot: np.ndarray = field(default_factory=lambda: np.zeros(0))

    def summary(self) -> str:
        """Return a one-paragraph human-readable summary."""
        return (f'ATE {self.ate_rms:.4f} m (RMS over {self.pairs} poses, SE(2)-aligned); '
                f'RPE over {self.steps} steps: translation mean {self.rpe_trans_mean:.4f} m '
                f'RMS {self.rpe_trans_rms:.4f} m, rotation mean {self.rpe_rot_mean:.3f} deg '
                f'RMS {self.rpe_rot_rms:.3f} deg; failed steps {self.failed_steps}')


def distance_travelled(trajectory: Trajectory) -> float:
    """Return the path length [m]: the sum of distances between consecutive positions."""
    if len(trajectory) < 2:
        return 0.0
    steps = np.diff(trajectory.poses[:, :2], axis=0)
    return float(np.sum(np.hypot(steps[:, 0], steps[:, 1])))


def distance_between(trajectory: Trajectory, start_ns: int, end_ns: int) -> float:
    """Return the path length [m] of ``trajectory`` from ``start_ns`` to ``end_ns``.

    The ends are interpolated (clipped to the trajectory's span): the distance a
    reference covers over the scans of a run that processed only part of a bag
    (stopped with Ctrl-C, ``--max-scans``), not the whole bag's.
    """
    if len(trajectory) < 2 or end_ns <= start_ns:
        return 0.0
    stamps = trajectory.stamps_ns
    start_ns, end_ns = max(int(start_ns), int(stamps[0])), min(int(end_ns), int(stamps[-1]))
    inside = (stamps > start_ns) & (stamps < end_ns)
    ends = [trajectory.interpolate(start_ns), trajectory.interpolate(end_ns)]
    if end_ns <= start_ns or ends[0] is None or ends[1] is None:
        return 0.0
    poses = np.vstack([ends[0], trajectory.poses[inside], ends[1]])
    return distance_travelled(Trajectory(np.arange(len(poses)), poses))


def associate(estimate: Trajectory, reference: Trajectory,
              max_offset_ns: int = DEFAULT_MAX_OFFSET_NS) -> tuple[np.ndarray, np.ndarray]:
    """Pair reference and estimate poses by stamp; return index arrays (reference, estimate).

    Each reference stamp takes the estimate with the same stamp, otherwise the nearest
    one within ``max_offset_ns``. An estimate pose is used at most once (by the
    closest reference stamp), and the pairs come out in reference order.
    """
    if len(estimate) == 0 or len(reference) == 0:
        empty = np.zeros(0, dtype=int)
        return empty, empty
    est_order = np.argsort(estimate.stamps_ns, kind='stable')
    est_stamps = estimate.stamps_ns[est_order]
    ref_stamps = reference.stamps_ns
    right = np.clip(np.searchsorted(est_stamps, ref_stamps), 0, len(est_stamps) - 1)
    left = np.clip(right - 1, 0, len(est_stamps) - 1)
    offset_right = np.abs(est_stamps[right] - ref_stamps)
    offset_left = np.abs(est_stamps[left] - ref_stamps)
    nearest = np.where(offset_left <= offset_right, left, right)
    offset = np.minimum(offset_left, offset_right)
    ref_index = np.flatnonzero(offset <= max_offset_ns)
    est_index = est_order[nearest[ref_index]]
    offset = offset[ref_index]
    # Keep, for each estimate pose, only the reference stamp closest to it.
    order = np.lexsort((offset, est_index))
    first = np.ones(len(order), dtype=bool)
    first[1:] = est_index[order][1:] != est_index[order][:-1]
    keep = np.sort(order[first])
    return ref_index[keep], est_index[keep]


def paired_reference_poses(estimate: Trajectory, reference: Trajectory,
                           ref_index: np.ndarray, est_index: np.ndarray) -> np.ndarray:
    """Return the reference pose of each pair from :func:`associate`.

    A pair whose stamps differ takes the reference interpolated to the estimate's stamp
    (where it lies within the reference's span), so a small stamp offset is not scored
    as an error.
    """
    est_stamps = estimate.stamps_ns[est_index]
    ref_poses = reference.poses[ref_index].copy()
    inexact = np.flatnonzero(reference.stamps_ns[ref_index] != est_stamps)
    for i in inexact:  # only pairs off by a stamp offset; usually none
        interpolated = reference.interpolate(int(est_stamps[i]))
        if interpolated is not None:
            ref_poses[i] = interpolated
    return ref_poses


def align_se2(source: np.ndarray, target: np.ndarray) -> se2.Pose:
    """Return the rigid SE(2) pose ``T`` minimising ``sum ||T(source_i) - target_i||^2``.

    Closed form of Umeyama (1991) eqs. 40-42 without scale: with centred point sets
    the optimal angle is ``atan2(sum cross(s_i, t_i), sum dot(s_i, t_i))`` and the
    translation maps the source centroid onto the target centroid.
    """
    source = np.asarray(source, dtype=float).reshape(-1, 2)
    target = np.asarray(target, dtype=float).reshape(-1, 2)
    if len(source) == 0:
        return se2.pose()
    mu_s, mu_t = source.mean(axis=0), target.mean(axis=0)
    s, t = source - mu_s, target - mu_t
    cross = float(np.sum(s[:, 0] * t[:, 1] - s[:, 1] * t[:, 0]))
    dot = float(np.sum(s[:, 0] * t[:, 0] + s[:, 1] * t[:, 1]))
    theta = math.atan2(cross, dot) if len(source) > 1 else 0.0
    translation = mu_t - se2.rotation(theta) @ mu_s
    return se2.pose(translation[0], translation[1], theta)


def relative_errors(est_poses: np.ndarray,
                    ref_poses: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Return per-step RPE (translation [m], |rotation| [deg]) of paired pose sequences.

    Step ``i`` scores the motion from pose ``i`` to pose ``i + 1``:
    ``E = relative(relative(ref_a, ref_b), relative(est_a, est_b))`` (Sturm et al.,
    eq. 1), vectorised over all steps.
    """
    if len(est_poses) < 2:
        return np.zeros(0), np.zeros(0)
    ref_step = _relative_many(ref_poses[:-1], ref_poses[1:])
    est_step = _relative_many(est_poses[:-1], est_poses[1:])
    error = _relative_many(ref_step, est_step)
    return np.hypot(error[:, 0], error[:, 1]), np.degrees(np.abs(error[:, 2]))


def _relative_many(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Return ``a_i^-1 b_i`` for (N, 3) pose arrays (row-wise :func:`se2.relative`)."""
    c, s = np.cos(a[:, 2]), np.sin(a[:, 2])
    dx, dy = b[:, 0] - a[:, 0], b[:, 1] - a[:, 1]
    return np.column_stack((c * dx + s * dy, -s * dx + c * dy,
                            se2.wrap_angle(b[:, 2] - a[:, 2])))


def evaluate(estimate: Trajectory, reference: Trajectory,
             max_offset_ns: int = DEFAULT_MAX_OFFSET_NS,
             failed_translation: float = FAILED_TRANSLATION,
             failed_rotation_deg: float = FAILED_ROTATION_DEG) -> TrajectoryErrors:
    """Score an estimated trajectory against a reference (ATE and RPE).

    Raises ``ValueError`` when no estimate pose can be paired with a reference pose.
    """
    ref_index, est_index = associate(estimate, reference, max_offset_ns)
    if len(ref_index) == 0:
        raise ValueError('no estimate pose lies within '
                         f'{max_offset_ns * 1e-9:.3f} s of a reference stamp')
    est_poses = estimate.poses[est_index]
    ref_poses = paired_reference_poses(estimate, reference, ref_index, est_index)
    alignment = align_se2(est_poses[:, :2], ref_poses[:, :2])
    aligned = se2.transform_points(alignment, est_poses[:, :2])
    position_error = np.hypot(*(aligned - ref_poses[:, :2]).T)
    trans, rot = relative_errors(est_poses, ref_poses)
    failed = (trans > failed_translation) | (rot > failed_rotation_deg)
    return TrajectoryErrors(
        steps=len(trans),
        rpe_trans_mean=_mean(trans), rpe_trans_rms=_rms(trans),
        rpe_rot_mean=_mean(rot), rpe_rot_rms=_rms(rot),
        ate_rms=_rms(position_error), failed_steps=int(np.count_nonzero(failed)),
        pairs=len(ref_index), alignment=alignment, rpe_trans=trans, rpe_rot=rot)


DRIFT_SEGMENT = 50.0
"""Path length [m] of the segments the drift is measured over (KITTI uses 100-800 m of
road; indoors 50 m spans a few corridors)."""

SHORTER_SEGMENTS = (20.0, 10.0, 5.0, 2.0)
"""Segment lengths [m] for runs too short for :data:`DRIFT_SEGMENT`: the longest that
fits twice into the reference path."""


@dataclass
class SegmentDrift:
    """Drift per path length over segments of ``length`` metres (KITTI style).

    ``translation`` is the mean translational error in percent of the segment's path
    length, ``rotation`` the mean rotational error in degrees per metre, over
    ``segments`` segments (one from every paired pose with ``length`` of path ahead).
    NaN when the run is too short for one segment.
    """

    length: float
    translation: float
    rotation: float
    segments: int


def drift_segment_length(path_length: float) -> float:
    """Return the segment length for a run whose reference path is ``path_length`` [m].

    :data:`DRIFT_SEGMENT` when the path holds two such segments, else the longest of
    :data:`SHORTER_SEGMENTS` it holds twice (the shortest when none).
    """
    for length in (DRIFT_SEGMENT,) + SHORTER_SEGMENTS:
        if path_length >= 2.0 * length:
            return length
    return SHORTER_SEGMENTS[-1]


def segment_drift(estimate: Trajectory, reference: Trajectory, length: float | None = None,
                  max_offset_ns: int = DEFAULT_MAX_OFFSET_NS) -> SegmentDrift:
    """Return the drift over segments of ``length`` metres of reference path.

    The KITTI odometry benchmark's measure (Geiger, Lenz & Urtasun, "Are we ready for
    autonomous driving?", CVPR 2012, Sec. 3.2, and its devkit): from every paired
    pose ``i`` the segment runs to the first pose ``j`` whose reference path length
    from ``i`` reaches ``length``; its error is
    ``E = (Q_i^-1 Q_j)^-1 (P_i^-1 P_j)`` and it scores ``|t(E)| / d`` and ``|theta(E)| /
    d`` with ``d`` the segment's path length. The mean over all segments is returned;
    ``length`` defaults to :func:`drift_segment_length` of the reference path.
    """
    ref_index, est_index = associate(estimate, reference, max_offset_ns)
    est_poses = estimate.poses[est_index]
    ref_poses = paired_reference_poses(estimate, reference, ref_index, est_index)
    travelled = np.concatenate(([0.0], np.cumsum(np.hypot(
        *np.diff(ref_poses[:, :2], axis=0).T)))) if len(ref_poses) else np.zeros(0)
    total = float(travelled[-1]) if len(travelled) else 0.0
    length = drift_segment_length(total) if length is None else float(length)
    ends = np.searchsorted(travelled, travelled + length)
    starts = np.flatnonzero(ends < len(travelled))
    if len(starts) == 0:
        return SegmentDrift(length, math.nan, math.nan, 0)
    ends = ends[starts]
    error = _relative_many(_relative_many(ref_poses[starts], ref_poses[ends]),
                           _relative_many(est_poses[starts], est_poses[ends]))
    path = travelled[ends] - travelled[starts]
    return SegmentDrift(length,
                        float(np.mean(np.hypot(error[:, 0], error[:, 1]) / path) * 100.0),
                        float(np.degrees(np.mean(np.abs(error[:, 2]) / path))), len(starts))


def _mean(values: np.ndarray) -> float:
    """Return the mean, 0 for no values."""
    return float(np.mean(values)) if len(values) else 0.0


def _rms(values: np.ndarray) -> float:
    """Return the root mean square, 0 for no values."""
    return float(np.sqrt(np.mean(np.square(values)))) if len(values) else 0.0
