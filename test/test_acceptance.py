"""Acceptance of a match: the correction gates, the searched window, rejection texts, verdicts."""

import math

import numpy as np
import pytest

from laser_odom.core import se2
from laser_odom.core.configuration.pipeline import PipelineConfig


def good_match(pose=(0.0, 0.0, 0.0), **fields):
    """Return a converged, well-paired, well-constrained match at ``pose``."""
    from laser_odom.core.matchers import MatchResult
    values = {'pose': np.array(pose, dtype=float), 'converged': True, 'iterations': 5,
              'inlier_ratio': 0.9, 'residual': 0.01, 'information': np.diag([1e4, 2e4, 3e4]),
              'covariance': np.diag([1e-4, 5e-5, 1e-5])}
    values.update(fields)
    return MatchResult(**values)


def test_acceptance_gates_the_correction_inclusively_in_the_predictions_frame():
    """max_correction_* are inclusive and measured from the guess, in its frame.

    Non-finite poses or covariances are rejected before the correction is judged.
    """
    from laser_odom.core.registration.rejection import correction_from, rejection_reason
    from laser_odom.core.configuration.pipeline import AcceptanceConfig
    config = AcceptanceConfig(max_correction_linear=0.5, max_correction_angular=0.25)
    zero = se2.pose()
    for pose, reason in (((0.5, 0.0, 0.0), None), ((0.0, -0.5, 0.25), None),
                         ((0.0, 0.0, -0.25), None), ((0.5000001, 0.0, 0.0), 'large_correction'),
                         ((0.0, 0.0, 0.2500001), 'large_correction'),
                         ((0.0, 0.0, -0.2500001), 'large_correction')):
        assert rejection_reason(good_match(pose), zero, config) == reason, pose
    guess = se2.pose(2.0, 1.0, math.pi / 2)
    pose = se2.compose(guess, se2.pose(0.3, 0.39, 0.2))
    linear, angular = correction_from(guess, pose)
    assert linear == pytest.approx(math.hypot(0.3, 0.39), abs=1e-12)
    assert angular == pytest.approx(0.2, abs=1e-12)
    assert rejection_reason(good_match(pose), guess, config) is None
    far = se2.compose(guess, se2.pose(0.3, 0.41, 0.0))
    assert rejection_reason(good_match(far), guess, config) == 'large_correction'
    nan_pose = good_match((math.nan, 0.0, 0.0))
    assert rejection_reason(nan_pose, zero, config) == 'non_finite'
    inf_covariance = good_match(covariance=np.diag([1e-4, math.inf, 1e-5]))
    assert rejection_reason(inf_covariance, zero, config) == 'non_finite'
    bad = good_match((math.nan, 0.0, 0.0), converged=False, inlier_ratio=0.0)
    assert rejection_reason(bad, zero, config) == 'not_converged'
    assert rejection_reason(good_match((9.0, 0.0, 0.0), inlier_ratio=0.1), zero,
                            config) == 'low_inlier_ratio'


def test_a_searched_match_is_gated_by_the_window_and_its_surface_overlap():
    """The search window plus one cell is inclusive in x, y and the wrapped angle.

    The inlier ratio judged is the surface overlap the search measured, if there is one.
    """
    from laser_odom.core.registration.rejection import (
        searched_inlier_ratio, searched_rejection_reason)
    from laser_odom.core.configuration.pipeline import AcceptanceConfig
    from laser_odom.core.search import SearchWindow
    config = AcceptanceConfig(min_inlier_ratio=0.3)
    window = SearchWindow(linear=1.0, angular=0.5, resolution=0.25)
    guess = se2.pose(1.0, -2.0, 3.0)
    for offset, reason in (((1.25, 0.0, 0.0), None), ((0.0, -1.25, 0.0), None),
                           ((0.0, 0.0, 0.75), None), ((-1.25, 1.25, -0.75), None),
                           ((1.2500001, 0.0, 0.0), 'outside_window'),
                           ((0.0, -1.2500001, 0.0), 'outside_window'),
                           ((0.0, 0.0, -0.7500001), 'outside_window')):
        match = good_match(guess + np.array(offset))
        assert searched_rejection_reason(match, guess, config, window) == reason, offset
    wrapped = good_match(guess + np.array([0.0, 0.0, 0.7 - 2.0 * math.pi]))
    assert searched_rejection_reason(wrapped, guess, config, window) is None
    sparse = good_match(guess, inlier_ratio=0.1, extra={'surface_overlap': 0.3})
    assert searched_inlier_ratio(sparse) == 0.3
    assert searched_rejection_reason(sparse, guess, config, window) is None
    apart = good_match(guess, inlier_ratio=0.9, extra={'surface_overlap': 0.29})
    assert searched_rejection_reason(apart, guess, config, window) == 'low_overlap'
    plain = good_match(guess, inlier_ratio=0.29)
    assert searched_inlier_ratio(plain) == 0.29
    assert searched_rejection_reason(plain, guess, config, window) == 'low_overlap'
    failed = good_match(guess, converged=False)
    assert searched_rejection_reason(failed, guess, config, window) == 'not_converged'


def test_each_rejection_is_described_with_its_numbers():
    """The log line of each reason carries the figures behind it."""
    from laser_odom.core.registration.rejection import describe_rejection
    config = PipelineConfig()
    config.acceptance.min_inlier_ratio = 0.3
    config.acceptance.max_correction_linear = 0.5
    config.acceptance.max_correction_angular = math.radians(20.0)
    config.search.global_search_linear = 1.5
    config.search.global_search_angular = math.radians(45.0)
    guess = se2.pose(1.0, 1.0, math.pi / 2)
    match = good_match(se2.compose(guess, se2.pose(0.6, -0.8, math.radians(30.0))),
                       iterations=17, inlier_ratio=0.25, extra={'surface_overlap': 0.125})
    assert describe_rejection('not_converged', match, guess, config) == (
        'not converged after 17 iterations')
    assert describe_rejection('low_inlier_ratio', match, guess, config) == (
        '25% of the points paired, min_inlier_ratio 30%')
    assert describe_rejection('low_overlap', match, guess, config) == (
        '12% of the points on the reference surface, min_inlier_ratio 30%')
    assert describe_rejection('large_correction', match, guess, config) == (
        '1.00 m / 30.0 deg from the prediction, gate 0.50 m / 20.0 deg')
    assert describe_rejection('outside_window', match, guess, config) == (
        '1.00 m / 30.0 deg from the prediction, outside the search window +-1.50 m / '
        '+-45.0 deg')
    assert describe_rejection('non_finite', match, guess, config) == 'non finite'
    # A reason without figures of its own (a local failure against a usual level of 0).
    assert describe_rejection('high_residual', match, guess, config) == 'high residual'
    assert describe_rejection('few_inliers', match, guess, config) == 'few inliers'
    assert describe_rejection('unknown', match, guess, config) == 'unknown'


def test_judge_match_rejects_to_the_prediction_or_holds():
    """A rejected match is replaced by the guess (or no motion); its covariance is the window."""
    from laser_odom.core.registration.acceptance import judge_match
    from laser_odom.core.registration.registrar import Registration
    config = PipelineConfig()
    guess = se2.pose(0.1, 0.02, 0.01)
    # ''.join: the name as a parameter file gives it (equal, not the same object).
    for motion, expected in (('predict', guess), (''.join(list('predict')), guess),
                             ('hold', se2.pose())):
        config.acceptance.rejected_motion = motion
        match = good_match(guess, converged=False)
        verdict = judge_match(Registration(match), guess, config)
        assert verdict.status == 'rejected' and match.extra['rejection'] == 'not_converged'
        np.testing.assert_array_equal(verdict.pose, expected)
        # The motion is anywhere in the window: the default half-widths, 1.5 m and
        # 90 deg, are its standard deviations.
        np.testing.assert_allclose(verdict.covariance,
                                   np.diag([2.25, 2.25, (math.pi / 2) ** 2]), rtol=1e-12)
    # A searched match is judged by the window: 2 m off the guess is outside 1.5 m + 0.1.
    config.acceptance.max_correction_linear = 5.0
    far = good_match(guess + np.array([1.65, 0.0, 0.0]))
    assert judge_match(Registration(far), guess, config).status == 'matched'
    searched = judge_match(Registration(far, trigger='reset', trusted=False), guess, config)
    assert searched.status == 'rejected' and far.extra['rejection'] == 'outside_window'
    near = good_match(guess + np.array([1.55, 0.0, 0.0]))
    assert judge_match(Registration(near, trigger='reset'), guess, config).status == 'matched'


def test_judge_match_keeps_the_prediction_along_a_degenerate_direction():
    """Weak along x: x keeps the anchor with DEGENERATE_VARIANCE, y and yaw the match's.

    The anchor is the guess when the prediction is trusted, else the match itself.
    """
    from laser_odom.core.registration.acceptance import DEGENERATE_VARIANCE, judge_match
    from laser_odom.core.registration.registrar import Registration
    config = PipelineConfig()
    config.acceptance.degeneracy_min_information = 400.0
    config.acceptance.max_correction_angular = 1.0
    length = 2.0
    information = np.diag([100.0, 1e4, 2e4 * length ** 2])  # metric: 100, 1e4, 2e4 1/m^2
    guess = se2.pose(1.0, 2.0, 3.1)
    pose = se2.pose(1.3, 2.2, -3.1)  # 0.083 rad from the guess, across the wrap
    match = good_match(pose, information=information)
    verdict = judge_match(Registration(match), guess, config, length)
    assert verdict.status == 'degenerate' and match.degenerate
    np.testing.assert_allclose(verdict.pose, [1.0, 2.2, -3.1], atol=1e-12)
    expected = np.diag([DEGENERATE_VARIANCE, 1e-4, 1.0 / 2e4 / length ** 2])
    np.testing.assert_allclose(verdict.covariance, expected, rtol=1e-9, atol=1e-15)
    assert verdict.covariance[0, 0] == 1.0  # as uncertain as the prior: 1 m^2
    untrusted = good_match(pose, information=information)
    verdict = judge_match(Registration(untrusted, trigger='reset', trusted=False), guess,
                          config, length)
    assert verdict.status == 'degenerate'
    np.testing.assert_allclose(verdict.pose, pose, atol=1e-12)
    strong = good_match(pose, information=np.diag([400.0, 1e4, 1e4 * length ** 2]))
    verdict = judge_match(Registration(strong), guess, config, length)
    assert verdict.status == 'matched' and not strong.degenerate
    np.testing.assert_array_equal(verdict.pose, pose)
    np.testing.assert_array_equal(verdict.covariance, strong.covariance)
    assert verdict.pose is not strong.pose and verdict.covariance is not strong.covariance


def test_a_searched_match_keeps_its_turn_where_the_prediction_stands_in():
    """A trusted prediction's match failed; the search found a turn 112 deg from it.

    Along the weak direction (translation coupled with the turn, in metric units) the
    prediction stands in for the translation only: the searched turn stays. Before,
    the predicted turn was the anchor, and the correction's projection on the strong
    directions put the step 2 m and 59 deg from the match (fr079 every 10th scan 0.1 s
    apart, nicp, scan 394: 5.4 m off).
    """
    from laser_odom.core.registration.acceptance import judge_match
    from laser_odom.core.registration.registrar import Registration
    from laser_odom.core.search import SearchWindow
    config = PipelineConfig()
    config.acceptance.degeneracy_min_information = 400.0
    length = 2.0
    half = math.sqrt(0.5)
    directions = np.array([[half, 0.0, -half], [0.0, 1.0, 0.0], [half, 0.0, half]])
    metric = directions @ np.diag([100.0, 1e4, 2e4]) @ directions.T  # weak: x + L theta
    scale = np.array([1.0, 1.0, 1.0 / length])
    information = metric / scale[:, None] / scale[None, :]
    guess, pose = se2.pose(0.8, -0.6, -1.2), se2.pose(1.0, 0.2, 0.75)
    searched = Registration(good_match(pose, information=information), trigger='doubtful',
                            window=SearchWindow(3.0, math.pi, 0.1))
    verdict = judge_match(searched, guess, config, length)
    assert verdict.status == 'degenerate'
    np.testing.assert_allclose(verdict.pose, [0.9, 0.2, 0.7], atol=1e-9)
    # Matched from the prediction (not searched), the prediction is the anchor.
    config.acceptance.max_correction_angular = math.pi
    config.acceptance.max_correction_linear = 3.0
    local = judge_match(Registration(good_match(pose, information=information)), guess,
                        config, length)
    assert local.status == 'degenerate'
    assert abs(se2.wrap_angle(local.pose[2] - pose[2])) > 0.5


def test_an_ambiguous_match_covers_its_alternatives():
    """Each alternative's offset (angle wrapped) is added as d d^T: reported degenerate."""
    from laser_odom.core.registration.acceptance import covering_covariance, judge_match
    from laser_odom.core.registration.registrar import Registration
    config = PipelineConfig()
    pose = se2.pose(1.0, 2.0, 3.0)
    covariance = np.diag([1e-4, 2e-4, 3e-5])
    alternatives = [se2.pose(1.5, 2.0, 3.0), se2.pose(1.0, 1.8, 3.2 - 2.0 * math.pi)]
    d1, d2 = np.array([0.5, 0.0, 0.0]), np.array([0.0, -0.2, 0.2])
    expected = covariance + np.outer(d1, d1) + np.outer(d2, d2)
    covering = covering_covariance(pose, covariance, alternatives)
    np.testing.assert_allclose(covering, expected, atol=1e-12)
    for alternative in alternatives:  # each within one standard deviation
        d = alternative - pose
        d[2] = se2.wrap_angle(d[2])
        assert d @ np.linalg.solve(covering, d) < 1.0
    match = good_match(pose, covariance=covariance)
    registration = Registration(match, trigger='reset', trusted=False,
                                alternatives=[(a, 0.95) for a in alternatives])
    verdict = judge_match(registration, pose, config)
    assert verdict.status == 'degenerate' and match.extra['ambiguous']
    np.testing.assert_allclose(verdict.covariance, expected, atol=1e-12)
    np.testing.assert_array_equal(verdict.pose, pose)


def test_a_match_made_again_keeps_the_doubts_of_the_first():
    """De-skewed and matched again, an ambiguous step stays degenerate.

    The second match is clean and tight, but its covariance covers the first verdict's
    (the alternative, and the shift between the two poses); a clean first match leaves
    the second's verdict as judged.
    """
    from laser_odom.core.registration.acceptance import (
        covering_both, covering_covariance, judge_again, judge_match)
    from laser_odom.core.registration.registrar import Registration
    config = PipelineConfig()
    first_pose, alternative = se2.pose(0.2, 0.0, 0.1), se2.pose(0.7, 0.0, 0.1)
    first = judge_match(Registration(good_match(first_pose), trigger='reset', trusted=False,
                                     alternatives=[(alternative, 0.97)]), first_pose, config)
    assert first.status == 'degenerate'
    again = Registration(good_match((0.23, 0.0, 0.1)))
    assert judge_match(again, first_pose, config).status == 'matched'
    verdict = judge_again(first, Registration(good_match((0.23, 0.0, 0.1))), config)
    assert verdict.status == 'degenerate'
    np.testing.assert_array_equal(verdict.pose, [0.23, 0.0, 0.1])
    offset = alternative - verdict.pose
    assert offset @ np.linalg.solve(verdict.covariance, offset) < 1.0  # still covered
    shift = verdict.pose - first_pose
    expected = covering_covariance(verdict.pose, first.covariance, [first_pose])
    for direction in (np.array([1.0, 0.0, 0.0]), shift / np.linalg.norm(shift)):
        assert direction @ verdict.covariance @ direction >= \
            direction @ expected @ direction - 1e-12
    clean = judge_match(Registration(good_match(first_pose)), first_pose, config)
    verdict = judge_again(clean, Registration(good_match((0.21, 0.0, 0.1))), config)
    assert verdict.status == 'matched'
    np.testing.assert_array_equal(verdict.covariance, good_match().covariance)
    wide, narrow = np.diag([4.0, 1.0, 1.0]), np.diag([1.0, 9.0, 0.5])
    np.testing.assert_allclose(covering_both(wide, narrow), np.diag([4.0, 9.0, 1.0]),
                               atol=1e-12)


def test_acceptance_rejects_unconverged_and_poorly_paired_matches():
    from laser_odom.core.registration.rejection import rejection_reason
    from laser_odom.core.configuration.pipeline import AcceptanceConfig
    from laser_odom.core.matchers import MatchResult
    guess = se2.pose(0.1, 0.0, 0.0)
    good = MatchResult(pose=guess.copy(), converged=True, iterations=5, inlier_ratio=0.9,
                       residual=0.01, information=np.eye(3), covariance=np.eye(3) * 1e-4)
    config = AcceptanceConfig()
    assert rejection_reason(good, guess, config) is None
    unconverged = MatchResult(**{**good.__dict__, 'converged': False})
    assert rejection_reason(unconverged, guess, config) == 'not_converged'
    sparse = MatchResult(**{**good.__dict__, 'inlier_ratio': config.min_inlier_ratio - 0.01})
    assert rejection_reason(sparse, guess, config) == 'low_inlier_ratio'
    assert rejection_reason(MatchResult(**{**good.__dict__, 'inlier_ratio':
                                           config.min_inlier_ratio}), guess, config) is None


def test_a_direction_without_information_keeps_a_finite_variance():
    """With degeneracy_min_information 0, a zero eigenvalue's variance is 1e300, not 1 / 0.

    A zero eigenvalue is then not weak; a slightly negative one is (DEGENERATE_VARIANCE).
    """
    from laser_odom.core.registration.acceptance import judge_match
    from laser_odom.core.registration.registrar import Registration
    config = PipelineConfig()
    config.acceptance.degeneracy_min_information = 0.0
    match = good_match(se2.pose(0.01, 0.0, 0.0), information=np.diag([-1e-9, 0.0, 1e4]))
    verdict = judge_match(Registration(match), se2.pose(), config, 1.0)
    assert verdict.status == 'degenerate'
    assert np.all(np.isfinite(verdict.covariance))
    np.testing.assert_allclose(np.diag(verdict.covariance), [1.0, 1e300, 1e-4], rtol=1e-12)
