"""Real robot logs: each matcher is at least as good as CSM's PL-ICP on the same scans.

CSM (Censi's C implementation of PL-ICP) with the constant-velocity prior scores mean
translational / rotational RPE, ATE after SE(2) alignment and failed steps of:
fr079 0.025 m / 0.50 deg / 2.1 m / 1, mit-csail 0.033 m / 0.36 deg / 1.6 m / 2,
intel 0.052 m / 0.40 deg / 3.2 m / 7. Skipped when ../shared/data is absent.

These ``CSM_BAR`` figures are made by ``.ci/peers/csm_peer.py`` (CSM's ``sm_icp`` scan
to scan with its own default parameters, the previous step repeated as the first
guess, scored by the benchmark's code; how to build and run it, and the figures of
other settings: ``.ci/peers/README.md``).

Every matcher is also held to its own documented figures (the committed benchmark
result, test/figures/benchmark.json, from which docs and configs are rendered): no
figure may be more than 5 % worse than the worst of the documented copies. The run
here is one of them - copy 1: the log as a bag delivers it (float32 LaserScan) with
1 mm of range noise from seed 1, as ``laser_odom_bench --perturb 5`` made it - so the
code unchanged meets the bar on every copy, and a run that drew the worse branch is
no regression; the median copy is what the docs quote. Those that meet CSM's figures
also publish an honest pose covariance over the whole log: its mean NEES (the
reference's noise accounted) is at most ``MAX_WHOLE_LOG_NEES``.
"""

import pytest

from laser_odom.core.datasets import as_received, with_range_noise
from laser_odom.core.evaluation.benchmark import benchmark_run, REAL_REFERENCE_NOISE
from laser_odom.tools.figures import figure, load_figures, MATCHERS, regression

CSM_BAR = {
    'fr079': (0.025, 0.50, 2.1, 1),
    'mit-csail': (0.033, 0.36, 1.6, 2),
    'intel': (0.052, 0.40, 3.2, 7),
}


ATE_ABOVE_CSM: dict[tuple[str, str], str] = {}
"""Where the documented copy's ATE is above CSM's (the rest of the bar holds); strict, so
a fix shows."""

PEERS_MET = ('plicp', 'nicp', 'imls')
"""The matchers that meet CSM's figures (``icp`` does not: fr079 ATE, intel failed steps)."""

DOCUMENTED_COPY = 1
"""The seed of the documented copy a test runs (``laser_odom_bench --perturb``: 1..N)."""

CASES = [(m, d) for m in MATCHERS for d in sorted(CSM_BAR)]

MAX_WHOLE_LOG_NEES = 10.0
"""Mean NEES of the published pose over a whole log (3 when honest; 20-78 before the
heading walk of a real scanner was modelled)."""


@pytest.mark.parametrize('matcher, dataset', CASES)
def test_matcher_meets_its_documented_figures_and_the_csm_bar(real_log, matcher, dataset):
    log = as_received(with_range_noise(real_log(dataset), DOCUMENTED_COPY))
    row = benchmark_run(log, matcher, 'constant_velocity', reference_noise=REAL_REFERENCE_NOISE)
    figures = (f'{matcher} on {dataset}: RPE {row.rpe_trans_mean:.4f} m / '
               f'{row.rpe_rot_mean:.3f} deg, ATE {row.ate:.3f} m, failed {row.failed}, '
               f'whole-log NEES {row.nees_integrated:.2f}')
    assert row.steps >= 340, figures
    assert regression(row.as_dict(), figure(load_figures(), dataset, matcher)) == [], figures
    if matcher not in PEERS_MET:
        return
    assert row.nees_integrated <= MAX_WHOLE_LOG_NEES, figures
    trans, rot, ate, failed = CSM_BAR[dataset]
    assert row.rpe_trans_mean <= trans, figures
    assert row.rpe_rot_mean <= rot, figures
    assert (row.ate > ate) == ((matcher, dataset) in ATE_ABOVE_CSM), figures
    assert row.failed <= failed, figures
