"""Real robot logs matched against the local map: less drift than scan to scan.

Each of ``plicp``, ``nicp`` and ``imls`` runs over fr079, mit-csail and intel at full
rate with the constant-velocity prior and ``reference: local_map``, and is compared
with its own documented scan-to-scan figures (test/figures/benchmark.json, which
``test_real_data.py`` holds the scan mode to; the median of the documented copies):
drift over 50 m segments at most 0.6x, ATE below the best peer measured (fr079 2.08 m,
CSM's PL-ICP; mit-csail 0.88 m, small_gicp) and on intel at most 0.6x scan mode's, and
no failed step added. The map mode is also held to its own documented figures: no
more than 5 % worse than the worst copy. The run here is one of the documented copies
(copy 1: as a bag delivers the log, float32, with 1 mm of range noise from seed 1), so
the code unchanged meets that bar. Skipped when ../shared/data is absent.
"""

import pytest

from laser_odom.core.datasets import as_received, with_range_noise
from laser_odom.core.evaluation.benchmark import benchmark_run, REAL_REFERENCE_NOISE
from laser_odom.tools.figures import figure, load_figures, regression

BEST_PEER_ATE = {'fr079': 2.08, 'mit-csail': 0.88}
"""ATE [m] of the best peer measured on these logs (issue 28); on intel the bar is 0.6x
the matcher's own scan-mode ATE."""

DRIFT_RATIO = 0.6
ATE_RATIO = 0.6

SHORT_OF_TARGET = {
    ('nicp', 'mit-csail'): 'drift 0.68 % (0.81x); the three matchers disagree with each '
                           'other by 0.47-0.63 % over 50 m, and with the reference by '
                           "0.66-0.81 %: the keyframe reference's own error is about "
                           '0.55-0.65 % there, a floor the ratio cannot go below',
    ('imls', 'mit-csail'): 'drift 0.65 % (0.62x), the same reference floor',
}
"""Where the map mode falls short of issue 28's targets, and why (a fix shows: the test
then fails until the entry goes)."""

DOCUMENTED_COPY = 1
"""The seed of the documented copy a test runs (``laser_odom_bench --perturb``: 1..N)."""

CASES = [(matcher, dataset) for matcher in ('plicp', 'nicp', 'imls')
         for dataset in ('fr079', 'mit-csail', 'intel')]


@pytest.mark.parametrize('matcher, dataset', CASES)
def test_the_local_map_drifts_less_than_scan_to_scan(real_log, matcher, dataset):
    """One run per case (a map run takes 10-40 s) is held to both bars below."""
    log = as_received(with_range_noise(real_log(dataset), DOCUMENTED_COPY))
    row = benchmark_run(log, matcher, 'constant_velocity', reference='local_map',
                        reference_noise=REAL_REFERENCE_NOISE)
    documented = figure(load_figures(), dataset, matcher, reference='local_map')
    assert regression(row.as_dict(), documented) == [], (matcher, dataset)
    scan = figure(load_figures(), dataset, matcher)
    figures = (f'{matcher} on {dataset}: local map drift {row.drift_trans:.2f} % / '
               f'{row.drift_rot:.3f} deg/m, ATE {row.ate:.3f} m, failed {row.failed}; scan '
               f'{scan["drift_trans"]:.2f} % / {scan["drift_rot"]:.3f} deg/m, ATE '
               f'{scan["ate"]:.3f} m, failed {scan["failed"]}')
    assert row.reference == 'local_map' and row.drift_length == 50.0, figures
    short = {'drift': row.drift_trans > DRIFT_RATIO * scan['drift_trans'],
             'ATE': row.ate >= BEST_PEER_ATE.get(dataset, ATE_RATIO * scan['ate']),
             'failed steps': row.failed > scan['failed']}
    if (matcher, dataset) in SHORT_OF_TARGET:  # strict: a fix shows
        assert any(short.values()), f'now meets the targets, update SHORT_OF_TARGET: {figures}'
    else:
        assert not any(short.values()), f'short of target ({short}): {figures}'
