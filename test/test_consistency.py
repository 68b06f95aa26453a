"""The NEES of :mod:`laser_odom.core.evaluation.consistency` on synthetic runs of known error.

Trajectories whose step errors are drawn from the very model the covariance states
(white, shared-scan and bias shares) must score about 3; the same runs with the
covariance stated twice too large or too small must not, so the tolerance cannot pass
by accident. A reference with noise of its own scores clearly above 3 unless that noise
(``2R`` per relative pose) is accounted for. References on some scans only (keyframes)
and restarts are handled.
"""

import math

import numpy as np
import pytest

from laser_odom.core import se2
from laser_odom.core.evaluation.consistency import (
    integrated_nees, reference_at, ReferenceNoise, run_consistency, window_nees,
    window_nees_values)
from laser_odom.core.trajectory import Trajectory
from laser_odom.core.uncertainty.pose_uncertainty import nees, PoseUncertainty, StepErrorModel

S = np.diag([4e-4, 1e-4, 3e-6])
"""Step covariance: 2 cm along, 1 cm across, 0.1 deg."""

MODELS = {'white': StepErrorModel(), 'shared scan': StepErrorModel(0.6),
          'shared scan and bias': StepErrorModel(0.5, 0.3, 0.9)}
RUNS, STEPS = 40, 300
HONEST = (2.3, 3.8)
"""Mean NEES of the honest covariance: 3 within sampling error (errors drawn from the
model, fixed seeds; the integrated pose's mean over 40 runs varies most, by about
+-0.3); a covariance stated 2x too large gives 1.5, 2x too small 6."""


def synthetic_run(rng: np.random.Generator, model: StepErrorModel, steps: int = STEPS,
                  stated: float = 1.0, step: tuple = (0.1, 0.0, 0.02),
                  covariance: np.ndarray = S) -> dict:
    """Return a run whose step errors are drawn from ``model`` with covariance ``S``.

    ``e_k = (n_k - n_{k-1}) + w_k + b_k`` in the step's frame (pose_uncertainty); the
    run states ``stated * S`` for each step and the pose covariance compounded from it.
    """
    a, c, phi = model.shared_scan, model.shares()[1], model.bias_correlation
    zero = np.zeros(3)
    shared = rng.multivariate_normal(zero, a * covariance / 2, size=steps + 1)
    white = rng.multivariate_normal(zero, (1 - a - c) * covariance, size=steps)
    kicks = rng.multivariate_normal(zero, (1 - phi ** 2) * c * covariance, size=steps)
    bias = rng.multivariate_normal(zero, c * covariance)
    truth, poses = [se2.pose()], [se2.pose()]
    pose_covariances, step_covariances = [np.zeros((3, 3))], [np.zeros((3, 3))]
    state = PoseUncertainty.at()
    for k in range(steps):
        bias = phi * bias + kicks[k]
        true_step = np.array(step) * (1.0 + 0.5 * math.sin(k / 15.0))  # lever arms vary
        measured = true_step + shared[k + 1] - shared[k] + white[k] + bias
        state = state.propagate(poses[-1], measured, stated * covariance, model)
        truth.append(se2.compose(truth[-1], true_step))
        poses.append(se2.compose(poses[-1], measured))
        pose_covariances.append(state.pose_covariance)
        step_covariances.append(stated * covariance)
    return {'poses': np.array(poses), 'pose_covariances': np.array(pose_covariances),
            'step_covariances': np.array(step_covariances), 'truth': np.array(truth)}


def figures(runs: list, model: StepErrorModel, noise: ReferenceNoise = ReferenceNoise(),
            reference_key: str = 'truth', windows=(1, 10, 100)) -> dict:
    """Mean NEES over all runs per window length, and of the integrated pose."""
    out = {n: np.mean([window_nees(r['poses'], r['step_covariances'], model,
                                   r[reference_key], n, noise) for r in runs])
           for n in windows}
    out['integrated'] = np.mean([integrated_nees(r['poses'], r['pose_covariances'],
                                                 r[reference_key], noise) for r in runs])
    return out


def integrated_figure(model: StepErrorModel, stated: float = 1.0,
                      reference=lambda run: run['truth']) -> float:
    """Mean integrated NEES over 200 runs of 100 steps.

    One run's mean varies a lot (its errors are a random walk: NEES 1 to 18 over 300
    steps), so the integrated figure needs many runs; short ones keep that cheap.
    """
    runs = [synthetic_run(np.random.default_rng(1000 + seed), model, steps=100,
                          stated=stated) for seed in range(200)]
    return float(np.mean([integrated_nees(r['poses'], r['pose_covariances'], reference(r))
                          for r in runs]))


@pytest.mark.parametrize('name', sorted(MODELS))
def test_errors_drawn_from_the_stated_covariance_give_nees_three(name):
    model = MODELS[name]
    honest = figures([synthetic_run(np.random.default_rng(seed), model)
                      for seed in range(RUNS)], model, windows=(1, 10, 100))
    honest['integrated'] = integrated_figure(model)
    low, high = HONEST
    assert all(low <= value <= high for value in honest.values()), (name, honest)


def test_a_covariance_stated_too_large_or_too_small_fails_the_tolerance():
    model, (low, high) = MODELS['shared scan and bias'], HONEST
    for stated, wrong in ((2.0, lambda v: v < low), (0.5, lambda v: v > high)):
        runs = [synthetic_run(np.random.default_rng(seed), model, stated=stated)
                for seed in range(RUNS)]
        off = figures(runs, model)
        off['integrated'] = integrated_figure(model, stated)
        assert all(wrong(value) for value in off.values()), (stated, off)


def test_nees_is_the_normalised_squared_error_with_the_angle_wrapped():
    covariance = np.diag([4.0, 1.0, 0.25])
    assert nees([2.0, 1.0, 0.5], covariance) == pytest.approx(3.0)
    assert nees([0.0, 0.0, 2 * math.pi + 0.5], covariance) == pytest.approx(1.0)


def test_reference_noise_is_accounted_for_as_two_r():
    # Small, precise steps against a reference of 5 cm and 1 deg per pose: the reference
    # noise dominates. Over 1 and 10 steps (0.02-0.2 m) and a 4 m run the lever arm of a
    # heading error (left out of 2R) stays small beside 2R.
    model, small = StepErrorModel(), np.diag([2.5e-5, 2.5e-5, 3e-7])
    noise = ReferenceNoise.degrees(0.05, 1.0)
    rng = np.random.default_rng(7)
    runs = []
    for seed in range(RUNS):
        run = synthetic_run(np.random.default_rng(seed), model, steps=200,
                            step=(0.02, 0.0, 0.002), covariance=small)
        errors = rng.multivariate_normal(np.zeros(3), noise.covariance, size=201)
        run['noisy'] = np.array([se2.compose(pose, error)
                                 for pose, error in zip(run['truth'], errors)])
        runs.append(run)
    ignored = figures(runs, model, reference_key='noisy', windows=(1, 10))
    assert all(value > 10.0 for value in ignored.values()), ignored
    counted = figures(runs, model, noise, reference_key='noisy', windows=(1, 10))
    low, high = HONEST
    assert all(low <= value <= high for value in counted.values()), counted
    truth = figures(runs, model, noise, windows=(1, 10))  # noise counted but absent
    assert all(value < 1.5 for value in truth.values()), truth


def test_windows_run_between_referenced_scans_only():
    model = MODELS['shared scan']
    run = synthetic_run(np.random.default_rng(3), model, steps=200)
    sparse = run['truth'].copy()
    kept = np.zeros(len(sparse), dtype=bool)
    kept[[4, 5, 9, 12, 20, 23, 31, 60, 62, 120, 199]] = True
    sparse[~kept] = np.nan
    args = (run['poses'], run['step_covariances'], model, sparse)
    # From 4: 4-5, 5-9, 9-12, 12-20, ... each to the next referenced scan >= 1 step on.
    assert len(window_nees_values(*args, 1)) == 10
    # >= 10 steps, starting every 5: 4-20, 9-20, 20-31, 31-60, 60-120, 120-199.
    assert len(window_nees_values(*args, 10)) == 6
    assert len(window_nees_values(*args, 100)) == 2  # 4-120, 60-199
    # A restart at 50 (a time jump back): no window spans it (31-60, 4-120 are gone).
    restarts = np.zeros(len(sparse), dtype=bool)
    restarts[50] = True
    assert len(window_nees_values(*args, 10, restarts=restarts)) == 5
    assert len(window_nees_values(*args, 100, restarts=restarts)) == 1


def test_sparse_references_and_a_late_first_reference_still_give_three():
    model = MODELS['white']

    def sparse(run: dict) -> np.ndarray:
        """Return the reference from scan 20 on (a late start: anchored there), every 3rd scan."""
        reference = run['truth'].copy()
        reference[:20] = np.nan
        reference[20:][np.arange(len(reference) - 20) % 3 != 0] = np.nan
        return reference

    runs = [synthetic_run(np.random.default_rng(seed), model) for seed in range(RUNS)]
    for run in runs:
        run['sparse'] = sparse(run)
    figure = figures(runs, model, reference_key='sparse')
    figure['integrated'] = integrated_figure(model, reference=sparse)
    low, high = HONEST
    assert all(low <= value <= high for value in figure.values()), figure


def test_a_run_result_is_scored_against_a_reference_trajectory_by_stamp():
    model = MODELS['white']
    run = synthetic_run(np.random.default_rng(11), model, steps=120)
    stamps = np.arange(121, dtype=np.int64) * 100_000_000
    trajectory = Trajectory(stamps, run['poses'])
    reference = Trajectory(stamps[::2] + 2_000_000, run['truth'][::2])  # 2 ms late
    at = reference_at(trajectory, reference)
    assert np.isnan(at[1::2]).all() and np.isfinite(at[::2]).all()
    statuses = ['initialized'] + ['matched'] * 120
    result = run_consistency(trajectory, run['pose_covariances'], run['step_covariances'],
                             statuses, reference, model)
    assert set(result.windows) == {1, 10, 100}
    assert all(math.isfinite(v) for v in [*result.windows.values(), result.integrated])
    # A degenerate or rejected step compounds white, as the pipeline does.
    unmatched = ['initialized'] + ['degenerate', 'rejected'] * 60
    assert run_consistency(trajectory, run['pose_covariances'], run['step_covariances'],
                           unmatched, reference, MODELS['shared scan']) == result
    empty = run_consistency(trajectory, run['pose_covariances'], run['step_covariances'],
                            statuses, Trajectory(), model)
    assert all(math.isnan(v) for v in [*empty.windows.values(), empty.integrated])
