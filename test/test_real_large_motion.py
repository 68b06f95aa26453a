"""Real logs with large motion between scans, and a wheel-odometry prior with glitches.

With ``prior: none`` and otherwise default parameters (``global_search: recover``) the
odometry must hold on scans 0.5-2 m and 10-170 deg apart: the Intel keyframe log
(steps of median 0.67 m / 22 deg, 3-4 s apart) and fr079 taking every 5th, 10th or
20th scan. No log fails more steps than before the search window adapted (the
counts of c7b0fbe), and at most one failed step per log is silent: the published step
covariance covers every other (NEES within the 99.9 % bound, the reference's noise
accounted, :mod:`laser_odom.core.evaluation.consistency`). With its own raw wheel odometry as the
prior, MIT CSAIL (whose odometry jumps and stalls) must score as well as with the
constant-velocity prior. Matched against the local map, intel-kf, fr079/5 and fr079/10
fail no more steps than scan to scan (issue 28). Skipped when ../shared/data is absent.
"""

import pytest

from laser_odom.core.evaluation.benchmark import benchmark_run, REAL_REFERENCE_NOISE
from laser_odom.core.matchers import matcher_names
from laser_odom.tools.figures import figure, load_figures

FAILED_BEFORE = {
    'intel-kf': {'plicp': 17, 'nicp': 11, 'imls': 11},
    'fr079/5': {'plicp': 0, 'nicp': 1, 'imls': 1},
    'fr079/10': {'plicp': 6, 'nicp': 8, 'imls': 7},
    'fr079/20': {'plicp': 150, 'nicp': 150, 'imls': 149},
}
"""Failed steps with ``prior: none`` before the window adapted (c7b0fbe): none may fail
more now."""

SCAN_MODE_FAILED = {
    'intel-kf': {'plicp': 12, 'nicp': 3, 'imls': 8},
    'fr079/5': {'plicp': 0, 'nicp': 0, 'imls': 1},
    'fr079/10': {'plicp': 5, 'nicp': 8, 'imls': 7},
}
"""Failed steps of scan to scan with ``prior: none`` (measured 2026-12-04, the test
above holds it): matched against the local map no log may fail more (issue 28)."""

ROTATION_BAR = {'intel-kf': 1.0}
"""Mean rotational RPE [deg] allowed."""

SILENT_ALLOWED = 1
"""Failed steps per log whose covariance did not cover them."""


@pytest.mark.parametrize('dataset', sorted(FAILED_BEFORE))
@pytest.mark.parametrize('matcher', ['plicp', 'nicp', 'imls'])
def test_large_motion_without_a_prior(real_log, matcher, dataset):
    row = benchmark_run(real_log(dataset), matcher, 'none',
                        reference_noise=REAL_REFERENCE_NOISE)
    figures = (f'{matcher} on {dataset}, prior none: {row.failed} of {row.steps} steps '
               f'failed ({row.silent} silent), RPE {row.rpe_trans_mean:.4f} m / '
               f'{row.rpe_rot_mean:.3f} deg, ATE {row.ate:.3f} m')
    assert row.steps >= 230, figures
    assert row.failed <= FAILED_BEFORE[dataset][matcher], figures
    assert row.failed <= SCAN_MODE_FAILED.get(dataset, {}).get(matcher, row.failed), figures
    assert row.silent <= SILENT_ALLOWED, figures
    if dataset in ROTATION_BAR:
        assert row.rpe_rot_mean <= ROTATION_BAR[dataset], figures


@pytest.mark.parametrize('dataset', sorted(SCAN_MODE_FAILED))
@pytest.mark.parametrize('matcher', ['plicp', 'nicp', 'imls'])
def test_large_motion_against_the_local_map(real_log, matcher, dataset):
    """The step is found against the previous scan and refined on the map: no more fail."""
    row = benchmark_run(real_log(dataset), matcher, 'none',
                        reference_noise=REAL_REFERENCE_NOISE, reference='local_map')
    figures = (f'{matcher} on {dataset}, prior none, local map: {row.failed} of '
               f'{row.steps} steps failed ({row.silent} silent; scan to scan '
               f'{SCAN_MODE_FAILED[dataset][matcher]}), ATE {row.ate:.3f} m')
    assert row.reference == 'local_map' and row.steps >= 470, figures
    assert row.failed <= SCAN_MODE_FAILED[dataset][matcher], figures
    assert row.silent <= SILENT_ALLOWED, figures


@pytest.mark.parametrize('matcher', matcher_names())
def test_wheel_odometry_prior_scores_as_well_as_constant_velocity(real_log, matcher):
    """Compare with the documented constant-velocity row (one run here, not two).

    test_real_data holds today's constant-velocity run to that row within 5 %.
    """
    odom = benchmark_run(real_log('mit-csail'), matcher, 'odom')
    velocity = figure(load_figures(), 'mit-csail', matcher)
    assert velocity['prior'] == 'constant_velocity'
    figures = (f'{matcher} on mit-csail: odom prior RPE {odom.rpe_trans_mean:.4f} m / '
               f'{odom.rpe_rot_mean:.3f} deg, ATE {odom.ate:.3f} m; constant velocity '
               f'(documented) {velocity["rpe_trans_mean"]:.4f} m / '
               f'{velocity["rpe_rot_mean"]:.3f} deg, ATE {velocity["ate"]:.3f} m')
    assert odom.rpe_trans_mean <= 1.1 * velocity['rpe_trans_mean'], figures
    assert odom.rpe_rot_mean <= 1.1 * velocity['rpe_rot_mean'], figures
    assert odom.ate <= 1.1 * velocity['ate'], figures
