"""Real logs with large motion between scans, and a wheel-odometry prior with glitches.

With ``prior: none`` and otherwise default parameters (``global_search: recover``) the
odometry must hold on scans 0.5-1 m and 10-90 deg apart: the Intel keyframe log
(steps of median 0.67 m / 22 deg, 3-4 s apart) and fr079 taking every 5th or 10th
scan. With its own raw wheel odometry as the prior, MIT CSAIL (whose odometry jumps
and stalls) must score as well as with the constant-velocity prior. Skipped when
../shared/data is absent.
"""

import pytest

from laser_odom.core.benchmark import benchmark_run
from laser_odom.core.matchers import matcher_names

LARGE_MOTION_BAR = {
    'intel-kf': (45, 1.0),
    'fr079/5': (19, None),
    'fr079/10': (24, None),
}
"""Failed steps allowed (5 %, 2 % and 5 % of the steps) and mean rotational RPE [deg]."""


@pytest.mark.parametrize('dataset', sorted(LARGE_MOTION_BAR))
@pytest.mark.parametrize('matcher', ['plicp', 'nicp', 'imls'])
def test_large_motion_without_a_prior(real_log, matcher, dataset):
    row = benchmark_run(real_log(dataset), matcher, 'none')
    failed, rotation = LARGE_MOTION_BAR[dataset]
    figures = (f'{matcher} on {dataset}, prior none: {row.failed} of {row.steps} steps '
               f'failed, RPE {row.rpe_trans_mean:.4f} m / {row.rpe_rot_mean:.3f} deg, '
               f'ATE {row.ate:.3f} m')
    assert row.steps >= 470, figures
    assert row.failed <= failed, figures
    if rotation is not None:
        assert row.rpe_rot_mean <= rotation, figures


@pytest.mark.parametrize('matcher', matcher_names())
def test_wheel_odometry_prior_scores_as_well_as_constant_velocity(real_log, matcher):
    odom = benchmark_run(real_log('mit-csail'), matcher, 'odom')
    velocity = benchmark_run(real_log('mit-csail'), matcher, 'constant_velocity')
    figures = (f'{matcher} on mit-csail: odom prior RPE {odom.rpe_trans_mean:.4f} m / '
               f'{odom.rpe_rot_mean:.3f} deg, ATE {odom.ate:.3f} m; constant velocity '
               f'{velocity.rpe_trans_mean:.4f} m / {velocity.rpe_rot_mean:.3f} deg, '
               f'ATE {velocity.ate:.3f} m')
    assert odom.rpe_trans_mean <= 1.1 * velocity.rpe_trans_mean, figures
    assert odom.rpe_rot_mean <= 1.1 * velocity.rpe_rot_mean, figures
    assert odom.ate <= 1.1 * velocity.ate, figures
