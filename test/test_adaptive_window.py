"""The search window adapts, and what the odometry cannot tell it says.

The window grows with the time since the last good match, and once more when the best
pose lies at its edge or fits poorly; a rejected or poorly fitting step gets a
covariance that covers the window.

Simulated with ``prior: none`` (no guess at all): scans dropped until 2.5 m and 60 deg
pass between them (office and cluttered) never fail; in the corridor worlds with
steps of a metre, ``nicp`` fails no more steps than ``imls`` (and in a featureless one,
where nothing tells the motion along the axis, every failed step is announced). The
counters of what the evidence did reach ``/diagnostics`` and the replay summary.
"""

from collections import Counter
import math

import numpy as np
import pytest

from laser_odom.core import se2
from laser_odom.core.configuration.node import NodeConfig
from laser_odom.core.configuration.pipeline import GlobalSearchConfig, PipelineConfig
from laser_odom.core.evaluation.benchmark import benchmark_run
from laser_odom.core.matchers import MatchResult
from laser_odom.core.motion.blind_prior import Prediction
from laser_odom.core.pipeline.announce import EVIDENCE_EVENTS
from laser_odom.core.pipeline.estimate import EVENTS
from laser_odom.core.registration.acceptance import judge_match, rejected_covariance
from laser_odom.core.registration.registrar import Registration
from laser_odom.core.search import SearchWindow
from laser_odom.core.simulation import drop_to_steps, simulate


def test_the_window_grows_with_the_time_since_the_last_good_match():
    config = GlobalSearchConfig()  # 1.5 m, 90 deg; 1 m/s, 1.5 rad/s, at most 4 m
    assert config.window(0.5) == SearchWindow(1.5, math.pi / 2, 0.1)
    grown = config.window(2.0)
    assert grown.linear == pytest.approx(2.0) and grown.angular == pytest.approx(3.0)
    longest = config.window(10.0)
    assert longest.linear == 4.0 and longest.angular == pytest.approx(math.pi)
    # Once more: twice as wide, within the caps; a window at both caps cannot grow.
    assert config.widened(grown) == SearchWindow(4.0, math.pi, 0.1)
    assert config.widened(SearchWindow(1.5, 0.5, 0.1)) == SearchWindow(3.0, 1.0, 0.1)
    assert config.widened(longest) is None


def test_a_rejected_step_is_anywhere_in_the_window_or_the_trusted_prediction():
    config = PipelineConfig()
    window = SearchWindow(2.5, 2.0, 0.1)
    np.testing.assert_array_equal(rejected_covariance(window), np.diag([6.25, 6.25, 4.0]))
    failed = MatchResult.failure(se2.pose(0.3, 0.0, 0.1))
    verdict = judge_match(Registration(failed, trigger='no_prior', trusted=False,
                                       window=window), se2.pose(), config)
    assert verdict.status == 'rejected'
    np.testing.assert_array_equal(verdict.covariance, np.diag([6.25, 6.25, 4.0]))
    # With a trusted prediction whose error was measured, the step is the prediction.
    prediction = Prediction(se2.pose(0.1, 0.0, 0.0), np.diag([1e-4, 4e-4, 1e-5]), 'prior')
    verdict = judge_match(Registration(MatchResult.failure(prediction.pose),
                                       prediction=prediction), prediction.pose, config)
    assert verdict.status == 'rejected'
    np.testing.assert_array_equal(verdict.pose, prediction.pose)
    np.testing.assert_array_equal(verdict.covariance, prediction.covariance)


def test_a_poorly_fitting_searched_match_keeps_its_pose_and_covers_the_window():
    config = PipelineConfig()
    window = SearchWindow(3.0, math.pi, 0.1)
    information = np.diag([1e6, 1e6, 1e6])
    match = MatchResult(pose=se2.pose(1.0, 0.2, 0.3), converged=True, iterations=5,
                        inlier_ratio=0.6, residual=0.01, information=information,
                        covariance=np.linalg.inv(information),
                        extra={'surface_fit': 0.40, 'surface_overlap': 0.5})
    verdict = judge_match(Registration(match, trigger='no_prior', trusted=False,
                                       window=window), se2.pose(), config, 3.0)
    assert verdict.status == 'degenerate' and match.extra['poor_fit']
    np.testing.assert_array_equal(verdict.pose, match.pose)
    np.testing.assert_allclose(verdict.covariance,
                               np.diag([9.0 + 1e-6, 9.0 + 1e-6, math.pi ** 2 + 1e-6]),
                               rtol=1e-9)
    # Fitting as well as global_search_poor_fit asks (0.45), it is an ordinary match.
    match.extra['surface_fit'] = 0.45
    verdict = judge_match(Registration(match, trigger='no_prior', trusted=False,
                                       window=window), se2.pose(), config, 3.0)
    assert verdict.status == 'matched'


DROPPED = {'office': (1, 2), 'cluttered': (1, 2)}
"""Worlds and seeds of the dropped-scan runs (60 s: 11-14 steps of up to 2.5 m)."""


@pytest.mark.parametrize('world', sorted(DROPPED))
@pytest.mark.parametrize('matcher', ['plicp', 'nicp', 'imls'])
def test_scans_dropped_until_2_5_m_and_60_deg_pass_between_them_never_fail(world, matcher):
    for seed in DROPPED[world]:
        data = drop_to_steps(simulate(world, duration=60.0, seed=seed), 2.5,
                             math.radians(60.0))
        truth = data.reference.poses
        steps = [se2.relative(a, b) for a, b in zip(truth[:-1], truth[1:])]
        assert max(math.hypot(s[0], s[1]) for s in steps) > 2.3  # steps that large
        row = benchmark_run(data, matcher, 'none')
        assert row.steps == len(steps) and row.failed == 0, (world, seed, row)


CORRIDOR_SEEDS = (1, 2)


def corridor_rows(world: str, matcher: str) -> list:
    """Return benchmark rows of 90 s runs in ``world``, scans dropped to 1 m / 30 deg."""
    return [benchmark_run(drop_to_steps(simulate(world, duration=90.0, seed=seed), 1.0,
                                        math.radians(30.0)), matcher, 'none')
            for seed in CORRIDOR_SEEDS]


def test_in_the_corridors_with_large_steps_nicp_fails_no_more_steps_than_imls():
    """The ring of corridors with doors and niches: the doors tell the motion."""
    failed = {m: sum(row.failed for row in corridor_rows('corridor', m))
              for m in ('nicp', 'imls')}
    assert failed['nicp'] <= failed['imls'], failed


@pytest.mark.parametrize('matcher', ['nicp', 'imls'])
def test_in_a_featureless_corridor_every_failed_step_is_announced(matcher):
    """Check that along smooth parallel walls every failed step says so.

    Nothing tells the motion along the axis, and no step was well constrained to
    predict it: which pose along it is chosen is chance (32-40 of 42 steps fail for
    either matcher).
    """
    for row in corridor_rows('featureless_corridor', matcher):
        assert row.steps == 42 and row.failed >= 20 and row.silent == 0, row


def test_what_the_evidence_did_is_counted_on_diagnostics_and_in_the_replay_summary():
    from laser_odom.ros.diagnostics import DiagnosticsReporter, Snapshot, skip_reasons
    from laser_odom.tools.replay_report import ReplayRecord, summary_lines
    assert set(EVIDENCE_EVENTS) <= set(EVENTS)
    counts = Counter(scans_in=10, processed=10, matched=6, degenerate=4,
                     weakly_constrained=2, poor_fit=1, prediction_used=1, search_widened=3)
    assert skip_reasons(counts) == {}  # events, not skipped scans
    reporter = DiagnosticsReporter('laser_odom: odometry', 'base_link', 0.0)
    snapshot = Snapshot(1.0, 10, counts, np.array([0.01]), 'nicp', 'none', '/scan',
                        latencies=np.array([0.01]))
    values = {kv.key: kv.value for kv in reporter.status(snapshot, NodeConfig()).values}
    assert values['weakly_constrained'] == '2' and values['poor_fit'] == '1'
    assert values['prediction_used'] == '1' and values['search_widened'] == '3'
    record = ReplayRecord(statuses=['matched'] * 6 + ['degenerate'] * 4, scans_read=10,
                          counters=dict(counts))
    lines = summary_lines(record, '/scan', 'nicp')
    assert 'matched 6, degenerate 4' in lines[0]
    assert ('counters: poor_fit 1, prediction_used 1, search_widened 3, '
            'weakly_constrained 2') in lines
