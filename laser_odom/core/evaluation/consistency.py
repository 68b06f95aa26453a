"""Is the published covariance honest? NEES of relative and integrated poses.

A covariance is only useful if the errors it describes have that size. The normalised
estimation error squared (Bar-Shalom, Li & Kirubarajan, "Estimation with Applications
to Tracking and Navigation", 2001, Sec. 5.4),

``NEES = e^T P^-1 e``  (``e = estimate - reference``, angle wrapped; 3 dof),

has mean 3 when ``e ~ N(0, P)``: well above 3 the covariance is too confident (a
filter fusing it trusts the odometry too much), well below too pessimistic (it is
ignored). A per-step check is not enough: step errors are correlated (shared scans,
bias, :mod:`laser_odom.core.uncertainty.pose_uncertainty`), so the covariance must also hold over
many steps. Three figures are scored against a reference:

- **windows of N steps**: the relative pose from a referenced scan to the first
  referenced scan at least N steps later, with its covariance propagated from the
  recorded step covariances by :class:`PoseUncertainty` and the matcher's
  :class:`StepErrorModel` (exactly as the pipeline compounds them), against the
  reference's relative pose. Windows start every ``N // 2`` steps (at the first
  referenced scan from there). With a reference on every scan a window is exactly N
  steps; with keyframe references (real logs) it reaches to the next keyframe, so a
  "1 step" window spans the 2-4 (MIT CSAIL) or ~18 (Intel) scans between keyframes;
- **the integrated pose**: the published pose and covariance at each referenced scan,
  relative to the first referenced scan, against the reference.

Runs restart (status ``initialized`` after a reset): a window never spans a restart,
and the integrated pose is scored up to the first restart only.

**Reference noise.** A real log's reference is itself an estimate (SLAM-corrected, a
few cm and about 1 deg per pose), so ``e`` holds the reference's error too and the
NEES of an honest covariance comes out above 3. Each reference pose is taken to err by
``N(0, R)``, ``R = diag(s_t^2, s_t^2, s_r^2)`` in its own frame, independently of the
estimate. A relative reference pose between two referenced scans then errs by the
error of each end, about ``2R``: since ``R`` is isotropic in x and y, rotating one
end's error into the other end's frame leaves it unchanged, so no rotation is needed.
(The lever arm of the first end's heading error over the window, ``(s_r d)^2`` across a
window of length ``d``, is left out: the headings of a SLAM-corrected trajectory err
together over nearby poses, which is why its noise is quoted per pose, not per metre.)
``2R`` is added to the estimate's covariance before the NEES: ``e^T (P + 2R)^-1 e``.

**Failed steps: announced or silent.** A failed step (an RPE step between consecutive
referenced scans off by more than 0.5 m or 10 deg, :func:`.metrics.evaluate`) is
*announced* when the covariance the odometry published for it covers it: the NEES of
its error against the step covariance (the published twist covariance times dt^2,
compounded as independent over the scans between the two references, as a fusing
filter would) is within the 99.9 % chi-square bound for 3 dof,
:data:`ANNOUNCED_NEES`. Otherwise it is *silent*: a filter fuses it as if it were
right. The reference's noise is accounted for as in the NEES figures (``2R`` added):
a failed step of a metre along a corridor whose covariance says a metre is announced,
even though the SLAM-corrected reference's heading is itself 1 deg off.
"""

from __future__ import annotations

from dataclasses import dataclass
import math
from typing import Sequence

import numpy as np

from laser_odom.core import se2
from laser_odom.core.evaluation.metrics import (
    associate, DEFAULT_MAX_OFFSET_NS, FAILED_ROTATION_DEG, FAILED_TRANSLATION,
    paired_reference_poses, relative_errors)
from laser_odom.core.trajectory import Trajectory
from laser_odom.core.uncertainty.pose_uncertainty import (
    CHI2_3DOF_999, nees, PoseUncertainty, StepErrorModel)

WINDOWS = (1, 10, 100)
"""Window lengths [steps] of the relative-pose NEES the benchmark and the tests report."""

INTEGRATED_SKIP = 10
"""Steps after the first referenced scan left out of the integrated NEES (its covariance
is still close to zero there, so the reference noise alone would dominate)."""

DOF = 3
"""Degrees of freedom of a planar pose: the mean NEES of an honest covariance."""

ANNOUNCED_NEES = CHI2_3DOF_999
"""A failed step whose NEES against its published covariance is within the 99.9 %
chi-square bound was announced (the covariance covers it)."""


@dataclass(frozen=True)
class ReferenceNoise:
    """Noise of each reference pose: ``s_t`` [m] in x and in y, ``s_r`` [rad] in heading."""

    translation: float = 0.0
    rotation: float = 0.0

    @classmethod
    def degrees(cls, translation: float, rotation_deg: float) -> ReferenceNoise:
        """Return the noise with the heading part given in degrees."""
        return cls(translation, math.radians(rotation_deg))

    @property
    def covariance(self) -> np.ndarray:
        """``R = diag(s_t^2, s_t^2, s_r^2)`` of one reference pose."""
        return np.diag([self.translation ** 2, self.translation ** 2, self.rotation ** 2])

    @property
    def relative_covariance(self) -> np.ndarray:
        """``2R``, the noise of a relative pose between two referenced scans.

        No rotation is needed: ``R`` is isotropic in x, y (see the module).
        """
        return 2.0 * self.covariance


NO_REFERENCE_NOISE = ReferenceNoise()
"""A reference that is the truth (simulated data)."""


def reference_at(estimate: Trajectory, reference: Trajectory,
                 max_offset_ns: int = DEFAULT_MAX_OFFSET_NS) -> np.ndarray:
    """Return the reference pose at each estimate (N, 3); NaN rows where there is none.

    Pairs by stamp as the metrics do
    (:func:`laser_odom.core.evaluation.metrics.associate`: the same stamp, else the
    nearest within ``max_offset_ns``, interpolated to the estimate's stamp), so the NEES
    and the RPE score the same scans.
    """
    at = np.full((len(estimate), 3), np.nan)
    ref_index, est_index = associate(estimate, reference, max_offset_ns)
    at[est_index] = paired_reference_poses(estimate, reference, ref_index, est_index)
    return at


def _models(model: StepErrorModel | Sequence[StepErrorModel], n: int) -> list[StepErrorModel]:
    """Return one error model per estimate (row k: the step from k - 1 to k)."""
    if isinstance(model, StepErrorModel):
        return [model] * n
    if len(model) != n:
        raise ValueError(f'{len(model)} error models for {n} estimates')
    return list(model)


def _restart_after(restarts: np.ndarray | None, n: int) -> np.ndarray:
    """Return, per estimate k, the index of the first restart after k (n if none)."""
    following = np.full(n + 1, n)
    if restarts is not None:
        for k in range(n - 1, -1, -1):
            following[k] = k + 1 if k + 1 < n and restarts[k + 1] else following[k + 1]
    return following[:n]


def window_nees_values(poses: np.ndarray, step_covariances: np.ndarray,
                       model: StepErrorModel | Sequence[StepErrorModel],
                       reference: np.ndarray, steps: int,
                       noise: ReferenceNoise = NO_REFERENCE_NOISE,
                       restarts: np.ndarray | None = None) -> np.ndarray:
    """Return the NEES of every window of (at least) ``steps`` steps.

    ``poses`` (N, 3) are the estimates, ``step_covariances`` (N, 3, 3) the covariance of
    each one's step from the previous estimate (row 0 unused), ``model`` the step error
    model (one for all, or one per estimate: the pipeline compounds a degenerate or
    rejected step as white), ``reference`` (N, 3) the reference pose at each estimate
    (NaN rows: none), ``restarts`` (N,) True where integration restarted. A window runs
    from a referenced scan to the first referenced scan ``steps`` or more steps later;
    the next one starts at the first referenced scan ``max(1, steps // 2)`` steps on.
    """
    poses = np.asarray(poses, dtype=float).reshape(-1, 3)
    n = len(poses)
    models = _models(model, n)
    referenced = np.flatnonzero(np.all(np.isfinite(reference), axis=1))
    restart = _restart_after(restarts, n)
    extra = noise.relative_covariance
    values = []

    def first_referenced(at: int) -> int | None:
        i = int(np.searchsorted(referenced, at))
        return int(referenced[i]) if i < len(referenced) else None

    start = first_referenced(0)
    while start is not None:
        end = first_referenced(start + steps)
        if end is None:
            break
        if end >= restart[start]:  # the window would span a restart: start after it
            start = first_referenced(int(restart[start]))
            continue
        estimate, state = se2.pose(), PoseUncertainty.at()
        for k in range(start + 1, end + 1):
            step = se2.relative(poses[k - 1], poses[k])
            state = state.propagate(estimate, step, step_covariances[k], models[k])
            estimate = se2.compose(estimate, step)
        truth = se2.relative(reference[start], reference[end])
        values.append(nees(estimate - truth, state.pose_covariance + extra))
        start = first_referenced(start + max(1, steps // 2))
    return np.array(values)


def window_nees(poses: np.ndarray, step_covariances: np.ndarray,
                model: StepErrorModel | Sequence[StepErrorModel], reference: np.ndarray,
                steps: int, noise: ReferenceNoise = NO_REFERENCE_NOISE,
                restarts: np.ndarray | None = None) -> float:
    """Return the mean NEES over windows of ``steps`` steps (:func:`window_nees_values`).

    NaN when the run has no such window.
    """
    values = window_nees_values(poses, step_covariances, model, reference, steps, noise,
                                restarts)
    return float(np.mean(values)) if values.size else float('nan')


def integrated_nees_values(poses: np.ndarray, pose_covariances: np.ndarray,
                           reference: np.ndarray,
                           noise: ReferenceNoise = NO_REFERENCE_NOISE,
                           restarts: np.ndarray | None = None,
                           skip: int = INTEGRATED_SKIP) -> np.ndarray:
    """Return the NEES of the published pose at every referenced scan (see the module).

    Relative to the first referenced scan ``r``: ``e = relative(P_r, P_k) -
    relative(Q_r, Q_k)`` with the published covariance less what ``P_r`` already had,
    ``Jb^-1 (C_k - Ja C_r Ja^T) Jb^-T`` (``Ja``, ``Jb``: :func:`se2.compose_jacobians` of
    ``P_r`` and the relative pose). That is exact for white step errors and first order
    otherwise; when ``r`` is the first estimate (``C_r = 0``, ``P_r`` the origin) it is
    the published covariance itself. A scan where the difference is not positive
    definite is left out. Scans fewer than ``skip`` steps after ``r`` are left out too,
    and so is everything from the first restart on.
    """
    poses = np.asarray(poses, dtype=float).reshape(-1, 3)
    referenced = np.flatnonzero(np.all(np.isfinite(reference), axis=1))
    if referenced.size == 0:
        return np.zeros(0)
    first = int(referenced[0])
    end = int(_restart_after(restarts, len(poses))[first])
    anchored = bool(np.any(pose_covariances[first]))
    extra = noise.relative_covariance
    values = []
    for k in referenced[(referenced >= first + skip) & (referenced < end)]:
        moved = se2.relative(poses[first], poses[k])
        covariance = pose_covariances[k]
        if anchored:
            ja, jb = se2.compose_jacobians(poses[first], moved)
            grown = covariance - ja @ pose_covariances[first] @ ja.T
            covariance = jb.T @ grown @ jb  # Jb is a rotation: Jb^-1 = Jb^T
            covariance = 0.5 * (covariance + covariance.T)
            if np.any(np.linalg.eigvalsh(covariance) <= 0.0):
                continue
        truth = se2.relative(reference[first], reference[k])
        values.append(nees(moved - truth, covariance + extra))
    return np.array(values)


def integrated_nees(poses: np.ndarray, pose_covariances: np.ndarray, reference: np.ndarray,
                    noise: ReferenceNoise = NO_REFERENCE_NOISE,
                    restarts: np.ndarray | None = None, skip: int = INTEGRATED_SKIP) -> float:
    """Return the mean NEES of the integrated pose (:func:`integrated_nees_values`).

    NaN when no referenced scan is scored.
    """
    values = integrated_nees_values(poses, pose_covariances, reference, noise, restarts, skip)
    return float(np.mean(values)) if values.size else float('nan')


@dataclass(frozen=True)
class Consistency:
    """Mean NEES of a run: per window length (steps -> NEES) and of the integrated pose."""

    windows: dict[int, float]
    integrated: float


def run_consistency(trajectory: Trajectory, pose_covariances: np.ndarray,
                    step_covariances: np.ndarray, statuses: Sequence[str],
                    reference: Trajectory, model: StepErrorModel,
                    noise: ReferenceNoise = NO_REFERENCE_NOISE,
                    windows: Sequence[int] = WINDOWS) -> Consistency:
    """Score a pipeline run (a :class:`.RunResult`: its fields) against a reference.

    ``model`` is the matcher's step error model; steps whose status is not ``matched``
    compound white, as the pipeline does. Status ``initialized`` marks a restart.
    """
    at = reference_at(trajectory, reference)
    statuses = list(statuses)
    models = [model if status == 'matched' else StepErrorModel() for status in statuses]
    restarts = np.array([status == 'initialized' for status in statuses], dtype=bool)
    return Consistency(
        {n: window_nees(trajectory.poses, step_covariances, models, at, n, noise, restarts)
         for n in windows},
        integrated_nees(trajectory.poses, pose_covariances, at, noise, restarts))


@dataclass(frozen=True)
class FailedSteps:
    """Failed steps of a run and how many of them the published covariance covered."""

    failed: int
    announced: int

    @property
    def silent(self) -> int:
        """Failed steps the covariance did not cover (a filter fuses them as truth)."""
        return self.failed - self.announced


def failed_step_nees(trajectory: Trajectory, step_covariances: np.ndarray,
                     reference: Trajectory, noise: ReferenceNoise = NO_REFERENCE_NOISE,
                     max_offset_ns: int = DEFAULT_MAX_OFFSET_NS) -> np.ndarray:
    """Return the NEES of every failed RPE step against its published step covariance.

    Steps run between consecutive scans paired with a reference pose, as in
    :func:`.metrics.evaluate`; a step fails above ``FAILED_TRANSLATION`` m or
    ``FAILED_ROTATION_DEG`` deg. Its covariance is the recorded step covariances of the
    scans it spans compounded as independent (a single scan: the step covariance
    itself), plus the reference's ``2R``; a singular one gives ``inf``.
    """
    ref_index, est_index = associate(trajectory, reference, max_offset_ns)
    if len(est_index) < 2:
        return np.zeros(0)
    poses = trajectory.poses
    references = paired_reference_poses(trajectory, reference, ref_index, est_index)
    translation, rotation = relative_errors(poses[est_index], references)
    failed = np.flatnonzero((translation > FAILED_TRANSLATION)
                            | (rotation > FAILED_ROTATION_DEG))
    white = StepErrorModel()
    values = []
    for j in failed:
        start, end = int(est_index[j]), int(est_index[j + 1])
        estimate, state = se2.pose(), PoseUncertainty.at()
        for k in range(start + 1, end + 1):
            step = se2.relative(poses[k - 1], poses[k])
            state = state.propagate(estimate, step, step_covariances[k], white)
            estimate = se2.compose(estimate, step)
        truth = se2.relative(references[j], references[j + 1])
        try:
            values.append(nees(estimate - truth,
                               state.pose_covariance + noise.relative_covariance))
        except np.linalg.LinAlgError:
            values.append(math.inf)
    return np.array(values)


def failed_steps(trajectory: Trajectory, step_covariances: np.ndarray,
                 reference: Trajectory, noise: ReferenceNoise = NO_REFERENCE_NOISE
                 ) -> FailedSteps:
    """Count a run's failed steps and those announced (:func:`failed_step_nees`)."""
    values = failed_step_nees(trajectory, step_covariances, reference, noise)
    return FailedSteps(len(values), int(np.count_nonzero(values <= ANNOUNCED_NEES)))
