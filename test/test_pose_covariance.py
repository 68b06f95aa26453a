"""The published pose covariance is honest over whole runs, not only per step.

NEES (e^T P^-1 e, 3 dof: about 3 when honest) of relative poses over 1, 10 and 100
steps and of the integrated pose the pipeline publishes, against the simulator's
truth, in two worlds with four noise seeds each (averaged per world), keyframes off
and on, and matching against the local map. The integrated NEES of one run varies
much from seed to seed (plicp against the map in the cluttered world, seeds 1-10:
1.5-6.6, mean 3.5), so two seeds were too few to tell a calibration from a draw. Far
below 3 fails too: a covariance too pessimistic to be useful. The simulated scanner
is exact but for its noise, so the heading walk of a real one is set to 0.
"""

from dataclasses import dataclass, replace

import numpy as np
import pytest

from laser_odom.core import se2
from laser_odom.core.configuration.pipeline import KeyframeConfig, PipelineConfig
from laser_odom.core.evaluation import consistency
from laser_odom.core.evaluation.benchmark import simulated_scanner
from laser_odom.core.evaluation.consistency import Consistency, reference_at, run_consistency
from laser_odom.core.events import EventLog
from laser_odom.core.pipeline.odometry import OdometryPipeline
from laser_odom.core.pipeline.runner import run_pipeline, RunResult
from laser_odom.core.simulation import LaserModel, simulate
from laser_odom.core.trajectory import Trajectory
from laser_odom.core.uncertainty.pose_uncertainty import PoseUncertainty, StepErrorModel

LOW, HIGH = 1.5, 6.0

OVERCONFIDENT = {('icp', 'office', 'local_map')}
"""Where the published covariance is known to be too confident (strict: a fix shows).
``icp`` against the map that keeps 1000 insertions (``map_max_age``) errs alike for
many steps in the office (NEES 3.4 / 8.9 / 40 over 1 / 10 / 100 steps, 17 integrated);
no single ``map_covariance_scale`` / ``map_covariance_shared`` fits both worlds (3.0 /
0.99: office 9.3 over 100 steps, cluttered 1.0). ``icp`` is there for comparison."""
PESSIMISTIC = {('plicp', 'cluttered', 'local_map')}
"""Where the published covariance is known to be too cautious over runs (strict: a fix
shows). ``plicp`` against the map in the cluttered world, refined on the map's surfaces
(``map_surface_refine``): NEES over 1 / 10 / 100 steps and integrated 1.49 / 1.49 / 2.05 /
3.43, a hair under 1.5 per step (its ``map_covariance_scale`` 1.5 also sets when a map step
and the previous scan's agree, so it was left). Before the refinement the office was the
cautious one: 2.5 / 2.7 / 3.3 / 1.4, now 2.1 / 2.0 / 2.6 / 2.4. Scan to scan its shares were
fitted again when its segment lines took their surface's direction (office 0.39 integrated,
cluttered 1.2 over 10 steps before, :data:`.plicp.matcher.PLICP_SHARED_SCAN`); the
office's seeds 1 and 2 were the cluttered world's runs in this test until the cache
keyed them by world."""
WINDOWS = (1, 10, 100)
SEEDS = {'office': (5, 9, 1, 2), 'cluttered': (6, 10, 1, 2)}
MATCHERS = ('plicp', 'nicp', 'imls', 'icp')


@dataclass
class Recorded:
    """What one run published (poses, covariances, per-step covariances), with the truth."""

    result: RunResult
    reference: Trajectory
    model: StepErrorModel

    def figures(self) -> Consistency:
        """Mean NEES over windows of 1, 10 and 100 steps and of the integrated pose."""
        r = self.result
        return run_consistency(r.trajectory, r.pose_covariances, r.step_covariances,
                               r.statuses, self.reference, self.model, windows=WINDOWS)


@pytest.fixture(scope='module')
def runs():
    """100 s (1000 scans) per world and seed, 1 cm range noise."""
    return {(world, seed): simulate(world, duration=100.0,
                                    laser=LaserModel(noise_sigma=0.01), seed=seed)
            for world, seeds in SEEDS.items() for seed in seeds}


def record(run, matcher: str, keyframes: KeyframeConfig | None = None,
           reference: str = 'scan') -> Recorded:
    """Run the pipeline over the simulated scans; the simulator's truth is the reference."""
    config = simulated_scanner(PipelineConfig(matcher=matcher))
    if keyframes is not None:
        config = replace(config, keyframes=keyframes)
    config.local_map.reference = reference
    pipeline = OdometryPipeline(config, events=EventLog(lambda message: None))
    result = run_pipeline(pipeline, run.scans)
    assert len(result.trajectory) == len(run.scans)
    return Recorded(result, run.reference, StepErrorModel.of_map(config.matcher_config)
                    if reference == 'local_map' else StepErrorModel.of(config.matcher_config))


def integrated_nees(rec: Recorded) -> float:
    """Mean NEES of the published pose against the truth (after the first 10 scans)."""
    r = rec.result
    return consistency.integrated_nees(r.trajectory.poses, r.pose_covariances,
                                       reference_at(r.trajectory, rec.reference))


@pytest.fixture(scope='module')
def recordings(runs):
    """Each matcher over every run, keyframes off (the default), against either reference."""
    cache = {}

    def get(matcher: str, world: str, reference: str = 'scan') -> list[Recorded]:
        for seed in SEEDS[world]:  # both worlds run seeds 1 and 2: the world is in the key
            if (matcher, world, seed, reference) not in cache:
                cache[matcher, world, seed, reference] = record(runs[world, seed], matcher,
                                                                reference=reference)
        return [cache[matcher, world, seed, reference] for seed in SEEDS[world]]
    return get


@pytest.mark.parametrize('reference', ['scan', 'local_map'])
@pytest.mark.parametrize('world', sorted(SEEDS))
@pytest.mark.parametrize('matcher', MATCHERS)
def test_relative_and_integrated_pose_nees_are_about_three(
        recordings, matcher, world, reference):
    each = [r.figures() for r in recordings(matcher, world, reference)]
    figures = {f'{n} steps': np.mean([f.windows[n] for f in each]) for n in WINDOWS}
    figures['integrated'] = np.mean([f.integrated for f in each])
    honest = all(LOW <= value <= HIGH for value in figures.values())
    assert honest != ((matcher, world, reference) in OVERCONFIDENT | PESSIMISTIC), (
        matcher, world, reference, figures)


@pytest.mark.parametrize('matcher', MATCHERS)
def test_integrated_pose_nees_with_keyframes(runs, matcher):
    keyframes = KeyframeConfig(keyframe_distance=0.3, keyframe_angle=0.3)
    values = [integrated_nees(record(runs[world, seed], matcher, keyframes))
              for world, seeds in SEEDS.items() for seed in seeds]
    assert LOW <= np.mean(values) <= HIGH, (matcher, values)


# --- the model on its own ---------------------------------------------------------

STEP = se2.pose(0.1, 0.0, 0.0)
S = np.diag([1e-4, 4e-4, 1e-5])
S_PLANAR = np.diag([1e-4, 4e-4, 0.0])
"""Without heading noise no lever arm couples the axes: sums of S stay sums of S."""


def straight_run(model: StepErrorModel, steps: int, covariance: np.ndarray,
                 scans_apart: int = 1) -> np.ndarray:
    """Pose covariance after ``steps`` equal straight steps of the given covariance."""
    pose, state = se2.pose(), PoseUncertainty.at()
    for _ in range(steps):
        state = state.propagate(pose, STEP, covariance, model, scans_apart)
        pose = se2.compose(pose, STEP)
    return state.pose_covariance


def test_white_errors_compound_as_smith_self_and_cheeseman():
    pose, expected = se2.pose(0.3, -0.2, 0.4), np.diag([1e-3, 2e-3, 3e-4])
    state = PoseUncertainty.at(expected)
    for step in (se2.pose(0.2, 0.05, 0.1), se2.pose(0.1, -0.1, -0.3)):
        ja, jb = se2.compose_jacobians(pose, step)
        expected = ja @ expected @ ja.T + jb @ S @ jb.T
        state = state.propagate(pose, step, S, StepErrorModel())
        pose = se2.compose(pose, step)
    assert np.allclose(state.pose_covariance, expected, rtol=1e-12, atol=1e-15)


def test_shared_scan_noise_telescopes():
    # e_k = n_k - n_{k-1} only: without turning, k steps err by n_k - n_0, whatever k.
    model = StepErrorModel(shared_scan=1.0)
    assert np.allclose(straight_run(model, 1, S_PLANAR), S_PLANAR, rtol=1e-9, atol=1e-15)
    assert np.allclose(straight_run(model, 20, S_PLANAR), S_PLANAR, rtol=1e-9, atol=1e-15)
    white = straight_run(StepErrorModel(), 20, S_PLANAR)
    assert np.allclose(white, 20 * S_PLANAR, rtol=1e-9, atol=1e-15)  # white: linear growth


def test_a_persistent_bias_adds_up_linearly():
    phi = 0.999
    grown = straight_run(StepErrorModel(bias_share=1.0, bias_correlation=phi), 20, S_PLANAR)
    # Nearly the same error in every step: variance ~ k^2 S (exactly sum_ij phi^|i-j| S).
    expected = sum(phi ** abs(i - j) for i in range(20) for j in range(20))
    assert np.allclose(grown, expected * S_PLANAR, rtol=1e-9, atol=1e-15)
    assert expected > 0.98 * 400


def test_one_step_keeps_the_matchers_covariance_whatever_the_shares():
    for model in (StepErrorModel(0.6, 0.125, 0.98), StepErrorModel(0.95, 0.4, 0.95),
                  StepErrorModel(0.0, 1.0, 0.5), StepErrorModel(0.5, 0.2, 0.98, 1.3)):
        assert np.allclose(straight_run(model, 1, S), S, rtol=1e-9, atol=1e-15)


def test_what_is_not_the_scans_own_noise_falls_off_with_the_baseline():
    # Transitions n scans apart: white and bias shrink to r = (1 - a) / n^gamma, the
    # scans' own noise (which telescopes to one share over the run) takes the rest.
    a, c, phi, steps = 0.5, 0.4, 0.99, 12
    lags = sum(phi ** abs(i - j) for i in range(steps) for j in range(steps))
    for gamma, n in ((0.0, 7), (1.0, 4), (1.3, 7), (2.0, 1)):
        model = StepErrorModel(a, c, phi, baseline_falloff=gamma)
        rest = (1.0 - a) / n ** gamma
        expected = ((1.0 - rest) + (1.0 - c) * rest * steps + c * rest * lags) * S_PLANAR
        assert np.allclose(straight_run(model, steps, S_PLANAR, n), expected,
                           rtol=1e-9, atol=1e-15), (gamma, n)
        assert np.allclose(straight_run(model, 1, S, n), S, rtol=1e-9, atol=1e-15)
    # Scan to scan (the default) is one scan apart; the white model stays white.
    model = StepErrorModel(a, c, phi, baseline_falloff=1.0)
    assert model.shares() == model.shares(1) == (a, c * (1.0 - a))
    state = PoseUncertainty.at().propagate(se2.pose(), STEP, S, model)
    assert np.array_equal(PoseUncertainty.at().propagate(se2.pose(), STEP, S, model, 1).joint,
                          state.joint)
    assert np.array_equal(state.propagate(STEP, STEP, S, model).joint,
                          state.propagate(STEP, STEP, S, model, 1).joint)
    assert all(StepErrorModel().shares(n) == (0.0, 0.0) for n in (1, 2, 7))


def test_a_state_whose_scan_is_not_known_starts_its_noise_and_bias_from_their_prior():
    # After a reset only the pose covariance is known: whatever a state holds for the
    # scan's noise and the bias (and their correlation with the pose) is replaced by the
    # priors, as if the state had been made by PoseUncertainty.at.
    rng = np.random.default_rng(3)
    root = rng.normal(size=(9, 9))
    stale = root @ root.T
    model = StepErrorModel(0.5, 0.4, 0.9)
    pose_covariance = stale[0:3, 0:3]
    fresh = PoseUncertainty.at(pose_covariance).propagate(STEP, STEP, S, model)
    reset = PoseUncertainty(stale, scan_known=False).propagate(STEP, STEP, S, model)
    np.testing.assert_allclose(reset.joint, fresh.joint, rtol=1e-12, atol=1e-15)
    kept = PoseUncertainty(stale, scan_known=True).propagate(STEP, STEP, S, model)
    assert not np.allclose(kept.joint, fresh.joint)
