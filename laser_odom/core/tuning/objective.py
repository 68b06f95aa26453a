"""Score one trial of ``laser_odom_tune``: run the odometry over the bags, judge the run.

A trial is a set of node parameter values. Each bag's scans go through a fresh
:class:`~laser_odom.core.pipeline.odometry.OdometryPipeline` built from those values by the
node's own rules (:func:`~laser_odom.core.configuration.node.settings_from_params`), with the
bag's wheel odometry or IMU fed as the prior exactly as the replay feeds it
(:class:`~laser_odom.core.motion.priors.PriorFeed`), so a tuned value means live what it
meant here. The run is then scored, lower being better:

- ``rpe`` (with a reference): mean translational RPE [m] + :data:`ROTATION_LENGTH` x
  mean rotational RPE [rad] + :data:`FAILED_STEP_PENALTY` per failed step (RPE above
  0.5 m or 10 deg, :mod:`laser_odom.core.evaluation.metrics`): a lost step is what a user
  notices first, so it costs more than its share of the mean;
- ``ate`` (with a reference): the RMS absolute trajectory error after SE(2) alignment;
- ``reference_free``: the sharpness of the local maps the scans make at the
  estimated poses, plus, weighted, the disagreement with wheel odometry
  (:func:`laser_odom.core.evaluation.map_quality.reference_free_score`).

Several bags score the mean of their scores. A trial whose laser matches were
mostly rejected (more than :data:`MAX_REJECTED_SHARE` of a bag's matches), or
seldom constrained every direction (:data:`MIN_MATCHED_SHARE`), has failed,
whatever its score: its trajectory is the motion prior's (``rejected_motion:
predict``) or standing still, not the laser's, and wheel odometry can score a better
RPE over a short bag while it drifts away over a long one. The counts of every bag
(matched, degenerate, rejected and why) come back with the score, as the replay
prints them. This module does not import Optuna: the tool passes a ``report``
callback that may stop a hopeless trial (pruning).
"""

from __future__ import annotations

from dataclasses import dataclass, field
import math
from pathlib import Path
from typing import Any, Callable, Mapping, Sequence

import numpy as np

from laser_odom.core.configuration.node import settings_from_params
from laser_odom.core.evaluation.metrics import evaluate
from laser_odom.core.events import EventLog
from laser_odom.core.motion.priors import PriorFeed
from laser_odom.core.pipeline.estimate import OdometryEstimate
from laser_odom.core.pipeline.odometry import OdometryPipeline
from laser_odom.core.pipeline.runner import run_pipeline
from laser_odom.core.scan.laser_scan import LaserScan
from laser_odom.core.trajectory import RecordedBag, Trajectory

OBJECTIVES = ('rpe', 'ate')
"""Scores against a reference (``--objective``)."""

REFERENCE_FREE = 'reference_free'
"""The score without a reference (``--reference-free``)."""

ROTATION_LENGTH = 1.0
"""Metres one radian of rotational RPE counts as: the error it makes at 1 m, the
typical distance at which a heading error shows in the next steps."""

FAILED_STEP_PENALTY = 0.01
"""Added to the ``rpe`` score per failed step [m]: a run with one lost step scores
like one whose mean error is 1 cm worse."""

MAX_REJECTED_SHARE = 0.5
"""A trial whose matches were rejected on more than this share of a bag's scans has
failed: the laser no longer makes its trajectory."""

MIN_MATCHED_SHARE = 0.1
"""A trial whose matches constrained every direction on fewer than this share of a
bag's scans has failed too: a degenerate match takes the prediction where the scan is
blind, so a run of degenerate and rejected matches is the prior's trajectory (a trial
with one iteration per match and the global search always on: matched 0, degenerate
60, rejected 39 of 99, and it beat the laser's RPE on a bag with good odometry)."""

FAILED_TRIAL_SCORE = 1e3
"""The score of a trial that cannot run (a refused combination, an exception, a
non-finite score): far above any real score, so the sampler avoids the region, and
the study goes on."""

Reporter = Callable[[int, float], None]
"""``report(step, score_so_far)``; it raises to stop a hopeless trial."""


@dataclass
class TrialResult:
    """A trial's score, each bag's score, and why it failed (None when it ran)."""

    score: float
    bag_scores: list[float] = field(default_factory=list)
    error: str | None = None
    trajectories: list[Trajectory] = field(default_factory=list)
    counts: list[dict[str, int]] = field(default_factory=list)
    """Per bag: scans processed, matched, degenerate, rejected and each rejection
    reason (``rejected_<reason>``), as the replay counts them."""


def match_counts(counters: Mapping[str, int]) -> dict[str, int]:
    """Return what the replay's summary counts of a run: outcomes and rejection reasons."""
    counts = {name: int(counters.get(name, 0))
              for name in ('processed', 'matched', 'degenerate', 'rejected')}
    counts.update({name: int(value) for name, value in sorted(counters.items())
                   if name.startswith('rejected_') and value})
    return counts


def describe_counts(counts: Mapping[str, int]) -> str:
    """Return the counts in the replay's words (``matched 95, ... failed (rejected) 2``)."""
    reasons = ', '.join(f'{k} {v}' for k, v in counts.items() if k.startswith('rejected_'))
    return (f'processed {counts["processed"]}, matched {counts["matched"]}, degenerate '
            f'{counts["degenerate"]}, failed (rejected) {counts["rejected"]}'
            + (f' ({reasons})' if reasons else ''))


def laser_failure(counts: Mapping[str, int], bag: str) -> str | None:
    """Return why a run is not the laser's (most matches rejected or none fully), or None."""
    attempts = counts['matched'] + counts['degenerate'] + counts['rejected']
    if attempts == 0:
        return None
    if counts['rejected'] > MAX_REJECTED_SHARE * attempts:
        why = f'laser matches rejected on {counts["rejected"]} of {attempts} scans of {bag}'
    elif counts['matched'] < MIN_MATCHED_SHARE * attempts:
        why = (f'laser matches constrained every direction on only {counts["matched"]} of '
               f'{attempts} scans of {bag}')
    else:
        return None
    return (f'{why} ({describe_counts(counts)}): its trajectory is the motion prior, not '
            'the laser')


@dataclass
class _Run:
    """The estimates of one bag so far (the points only for the reference-free score)."""

    stamps: list[int] = field(default_factory=list)
    poses: list[np.ndarray] = field(default_factory=list)
    points: list[np.ndarray] | None = None

    def add(self, estimate: OdometryEstimate) -> None:
        """Keep one estimate."""
        self.stamps.append(estimate.stamp_ns)
        self.poses.append(estimate.pose)
        if self.points is not None:
            points = estimate.scan_points
            self.points.append(np.zeros((0, 2)) if points is None else points)

    def trajectory(self) -> Trajectory:
        """Return the poses so far."""
        return Trajectory(np.array(self.stamps, dtype=np.int64),
                          np.array(self.poses).reshape(-1, 3))


def score_run(run: _Run, bag: RecordedBag, objective: str, odom_weight: float = 0.0) -> float:
    """Return the score of one bag's (partial) run; ValueError when it cannot be scored."""
    trajectory = run.trajectory()
    if len(trajectory) < 2:
        raise ValueError('fewer than two scans were processed')
    if objective == REFERENCE_FREE:
        from laser_odom.core.evaluation.map_quality import (  # written alongside
            reference_free_score)
        return float(reference_free_score(
            trajectory.stamps_ns, trajectory.poses, run.points or [],
            odometry=bag.odometry if odom_weight > 0.0 else None, odom_weight=odom_weight))
    if bag.reference is None:
        raise ValueError(f'{bag.name} has no reference for --objective {objective}')
    errors = evaluate(trajectory, bag.reference)
    if objective == 'ate':
        return errors.ate_rms
    return (errors.rpe_trans_mean + ROTATION_LENGTH * math.radians(errors.rpe_rot_mean)
            + FAILED_STEP_PENALTY * errors.failed_steps)


def _pipeline(values: Mapping[str, Any], bag: RecordedBag) -> tuple[OdometryPipeline, PriorFeed]:
    """Build the pipeline and prior feed the node would run with ``values`` on ``bag``."""
    settings = settings_from_params(values)
    pipeline = OdometryPipeline(settings.pipeline, events=EventLog(lambda message: None))
    prior = settings.pipeline.motion.prior
    if prior == 'odom' and bag.odometry is None:
        raise ValueError(f'{bag.name} has no wheel odometry for prior odom')
    if prior == 'imu' and bag.imu is None:
        raise ValueError(f'{bag.name} has no IMU for prior imu')
    return pipeline, PriorFeed(prior, settings.priors, bag.odometry, bag.imu)


def _chunks(bag: RecordedBag, split: bool) -> list[list[LaserScan]]:
    """Return the bag's scans whole, or in two halves (a checkpoint for pruning)."""
    half = len(bag.scans) // 2
    return [bag.scans[:half], bag.scans[half:]] if split and half >= 2 else [bag.scans]


def run_trial(values: Mapping[str, Any], bags: Sequence[RecordedBag], objective: str,
              odom_weight: float = 0.0, report: Reporter | None = None,
              keep_trajectories: bool = False) -> TrialResult:
    """Run ``values`` over every bag and return the score (lower is better).

    ``report(step, score)`` is called after each bag but the last with the mean score
    so far, and for a single bag after its first half (step 0): a pruner stops a
    hopeless trial there by raising, which passes through (the final score is the
    return value, so a finished trial is never pruned). Any other failure -
    a refused value, an exception of the pipeline, a run that cannot be scored, a
    bag whose matches were mostly rejected (:func:`laser_failure`) - gives
    :data:`FAILED_TRIAL_SCORE` and says why in ``error``, never an exception.
    """
    result = TrialResult(FAILED_TRIAL_SCORE)
    step = 0
    for number, bag in enumerate(bags, start=1):
        run = _Run(points=[] if objective == REFERENCE_FREE else None)
        try:
            pipeline, feed = _pipeline(values, bag)
        except Exception as err:  # noqa: B902 - any refused combination fails the trial
            result.error = f'{type(err).__name__}: {err}'
            return result
        chunks = _chunks(bag, split=len(bags) == 1)
        for index, chunk in enumerate(chunks):
            try:
                run_pipeline(pipeline, chunk, priors=feed, on_estimate=run.add)
                score = score_run(run, bag, objective, odom_weight)
                if not math.isfinite(score):
                    raise ValueError(f'score {score} on {bag.name}')
            except Exception as err:  # noqa: B902 - a bad combination must not stop a study
                result.error = f'{type(err).__name__}: {err}'
                result.bag_scores = []
                return result
            last = index == len(chunks) - 1
            if last:
                counts = match_counts(pipeline.counters)
                failure = laser_failure(counts, Path(bag.name).name)
                if failure is not None:
                    result.error, result.bag_scores = failure, []
                    result.counts.append(counts)
                    return result
                result.counts.append(counts)
                result.bag_scores.append(score)
                if keep_trajectories:
                    result.trajectories.append(run.trajectory())
            if report is not None and not (last and number == len(bags)):  # not the final
                report(step, float(np.mean(result.bag_scores)) if last else score)
            step += 1
    result.score = float(np.mean(result.bag_scores))
    return result
