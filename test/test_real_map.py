"""Real robot logs matched against the local map: a map you can trust (issue 37).

Each of ``plicp``, ``nicp`` and ``imls`` runs over fr079, mit-csail and intel at full
rate with the constant-velocity prior and ``reference: local_map``. The run is one of
the documented copies (copy 1: as a bag delivers the log, float32, with 1 mm of range
noise from seed 1), so it is held to the documented worst copy (no figure more than
5 % worse, test/figures/benchmark.json) and to issue 37's bars: 50 m drift and ATE
at most :data:`DRIFT_TARGET` and :data:`ATE_TARGET`, no more failed steps than scan
mode's worst copy, a whole-log NEES within :data:`NEES_RANGE`. Where it falls short,
:data:`SHORT_OF_TARGET` says which bar and why; the check is strict both ways, so a fix
shows.

The fast-robot logs' map-mode bars (no worse than scan mode on the same scans) are
held by :mod:`test_fast_robot`, which runs scan mode there once for both issues.
Skipped when ../shared/data is absent.
"""

import pytest

from laser_odom.core.datasets import as_received, with_range_noise
from laser_odom.core.evaluation.benchmark import benchmark_run, REAL_REFERENCE_NOISE
from laser_odom.tools.figures import figure, load_figures, regression

DRIFT_TARGET = {'fr079': 0.30, 'mit-csail': 0.55, 'intel': 0.50}
"""Issue 37: 50 m drift [%] of map mode (hector_mapping at its best on these logs:
0.28, 0.52, 0.49)."""

ATE_TARGET = {'fr079': 0.20, 'mit-csail': 0.60, 'intel': 0.20}
"""Issue 37: ATE [m] of map mode."""

NEES_RANGE = (1.0, 8.0)
"""Issue 37: the whole-log integrated NEES (3 when honest; below 1 a fusing filter
trusts the odometry less than it should)."""

MEMORY = ('the map restarts after 5 scans in a row fit it poorly (fr079, copy 1: 29 restarts; '
          'the residual of nicp against the view is 2.3x its usual at the 90th percentile), '
          'so its memory is short; hector_mapping never forgets')
"""Why map mode still drifts more than hector_mapping at its best on fr079 and MIT CSAIL.

Measured 2026-12-05: with ``map_max_age`` unbounded the figures are the same (the age
limit never binds); with no restart after refused scans nicp's 50 m drift is 0.27 % on
fr079 and 0.76 % on MIT CSAIL but Intel's goes 0.55 -> 1.25 % and plicp's MIT CSAIL
map never takes a scan again (all steps from the previous scan); restarting after 15
instead of 5 gave nicp 0.33 / 0.57 / 0.79 % (fr079 / MIT CSAIL / Intel) and Intel plicp
1.82 %; letting scans join at 3x the usual residual instead of 2x made plicp fail
silently on all three logs.

Measured 2026-12-05 too (5 copies, 50 m drift median [worst] %, fr079 / MIT CSAIL /
Intel): letting the fifth poorly fitting scan join instead of restarting the map gave
nicp 0.36 [0.44] / 0.68 [0.69] / 1.13 [1.45] and plicp 7 silent failed steps on Intel;
the same with ``map_max_age`` 200: nicp 0.30 [0.32] / 0.59 [0.74] / 0.62 [0.77], imls
0.27 [0.28] on fr079, but plicp silent failures on all three logs; with 60: no failed
step on any log for any of the three matchers (plicp 0.36 [0.38] / 0.68 [0.76] / 0.54
[0.98]), but plicp against the map in the simulated hall and campus failed 22 steps (11
silent) where it fails 8 (5): a scan that joined after a 1.2 m slide along the hall's
pillars put them in the map twice. Joining only when every scan of the row was matched
cleanly on the map (else restarting) fixed that slide but, with ``map_max_age`` 1000,
60 or 200, was no better on the real logs than restarting (plicp on Intel 5 silent
failed steps with 1000); counting a clean fallback to the previous scan as matched on
the map (only a degenerate step restarts it), with 60: no failed step on the real logs
and the worst copy within 1.2x the median on 7 of 9 log-matcher pairs (today 4), but
medians no better (fr079 plicp 0.36 %, imls 0.40 %) and, against the map in the
simulated hall and campus, plicp 17 failed steps (11 silent), imls 5 (2). Restarting
only when the matcher-free surface fit of the scan on the map's view is below 0.8
(0.95) of that on the previous scan: Intel plicp 1.19 [2.30] % (nicp 0.85 [0.95] %).

Measured 2026-12-06: a clean map match whose step fits the previous scan 0.25 (0.35,
0.4) below the usual fit there (fr079 plicp copy 4: 0.45 against 0.88, 6.6 deg off)
found again against the previous scan and refined on the map: fr079 plicp copies 4 / 1
drift 0.41 / 0.43 % (0.37 / 0.42, 0.39 / 0.30) against 0.53 / 0.30 %: not taken."""

SHORT_OF_TARGET: dict[tuple[str, str], dict[str, str]] = {
    ('plicp', 'fr079'): {'NEES': '0.58 on the documented copy, 0.6 [2.4] over 5 copies: too '
                                 "pessimistic since the refinement on the map's surfaces "
                                 '(map_surface_refine; 2.0 before) made its steps more '
                                 'accurate; a smaller heading walk takes Intel above 8 first '
                                 '(plicp.matcher.PLICP_MAP_HEADING_WALK)'},
    ('plicp', 'mit-csail'): {'drift': '0.44 [0.59] %, median [worst] of 5 copies, the '
                                      'documented copy 0.550 % (0.61 [0.67] %, copy 1 0.543 %, '
                                      "before the refinement on the map's surfaces)"},
    ('nicp', 'fr079'): {'drift': f'0.36 [0.53] %, the documented copy 0.36 %; {MEMORY}',
                        'ATE': '0.39 [0.54] m, the documented copy 0.41 m (0.44 [0.59] m before '
                               "the refinement on the map's surfaces)"},
    ('nicp', 'mit-csail'): {'drift': '0.53 [0.61] %, median [worst] of 5 copies, the documented '
                                     'copy 0.59 % (0.79 [0.99] % before the refinement on the '
                                     f"map's surfaces); {MEMORY}"},
    ('plicp', 'intel'): {'drift': '0.77 [1.43] %, the documented copy 0.93 %: along the '
                                  'corridors of scans 1833-1840 and 3401-3420 the map match '
                                  'slides back where other basins fit alike (issue 37 '
                                  'stability; 10 copies 0.65 [2.66] % -> 0.60 [1.43] % with '
                                  "the refinement on the map's surfaces)",
                         'ATE': '0.28 [0.72] m, the documented copy 0.51 m',
                         'NEES': '5.3 [36], the documented copy 18.1'},
    ('imls', 'fr079'): {
        'drift': '0.27 [0.33] %, median [worst] of 5 copies, the documented copy 0.302 % '
                 '(0.289 % before unproven predictions could surprise; 10 copies 0.29 '
                 '[0.38] -> 0.28 [0.45] %)',
        'NEES': '0.72 on the documented copy, 0.6-2.2 over 5 copies: too pessimistic; 1.00 '
                "before the published covariance covered the matcher's other basins (fr079 "
                'copy 1: 36 map matches checked, 23 stopped elsewhere from a start 3 sigma '
                'off)'},
    ('imls', 'intel'): {'drift': '0.39 [0.66] %, median [worst] of 5 copies, the documented '
                                 'copy 0.66 % (issue 37 stability)',
                        'ATE': '0.15 [0.38] m, the documented copy 0.38 m',
                        'NEES': '7.0 [14.6], the documented copy 10.7'},
}
"""Bars a case misses on the documented copy, and why (the test fails when one is met,
or another missed): issue 37 is open on these."""

DOCUMENTED_COPY = 1
"""The seed of the documented copy a test runs (``laser_odom_bench --perturb``: 1..N)."""

CASES = [(matcher, dataset) for matcher in ('plicp', 'nicp', 'imls')
         for dataset in ('fr079', 'mit-csail', 'intel')]


@pytest.mark.parametrize('matcher, dataset', CASES)
def test_the_local_map_meets_its_figures_and_the_targets(real_log, matcher, dataset):
    """One run per case (a map run takes 10-40 s) is held to both kinds of bar."""
    log = as_received(with_range_noise(real_log(dataset), DOCUMENTED_COPY))
    row = benchmark_run(log, matcher, 'constant_velocity', reference='local_map',
                        reference_noise=REAL_REFERENCE_NOISE)
    documented = figure(load_figures(), dataset, matcher, reference='local_map')
    assert regression(row.as_dict(), documented) == [], (matcher, dataset)
    scan = figure(load_figures(), dataset, matcher)
    figures = (f'{matcher} on {dataset}: local map drift {row.drift_trans:.2f} %, ATE '
               f'{row.ate:.3f} m, failed {row.failed} ({row.silent} silent), NEES '
               f'{row.nees_integrated:.2f}; scan mode worst copy failed '
               f'{scan["worst"]["failed"]:.0f}')
    assert row.reference == 'local_map' and row.drift_length == 50.0, figures
    low, high = NEES_RANGE
    short = {'drift': row.drift_trans > DRIFT_TARGET[dataset],
             'ATE': row.ate > ATE_TARGET[dataset],
             'failed steps': row.failed > scan['worst']['failed'],
             'NEES': not low <= row.nees_integrated <= high}
    missed = {bar for bar, is_short in short.items() if is_short}
    known = set(SHORT_OF_TARGET.get((matcher, dataset), {}))
    assert missed == known, f'missed {sorted(missed)}, documented {sorted(known)}: {figures}'


def test_a_map_whose_view_has_its_minimum_elsewhere_does_not_carry_the_robot_back(real_log):
    """MIT CSAIL, plicp, copy 5: the map no longer carries the robot backwards (issue 37).

    Scan 592's map view had its minimum 0.25 m behind a prediction the previous scan
    confirmed to 1 cm, and from scan 597 the constant velocity carried such steps on
    for 9 scans, 2.8 m backwards while the robot drove forwards: 3 silent failed
    steps, ATE 1.68 m (the other copies 0.49-0.62 m). The surprise is now checked
    against the previous scan (``map_surprised``).
    """
    log = as_received(with_range_noise(real_log('mit-csail'), 5))
    row = benchmark_run(log, 'plicp', 'constant_velocity', reference='local_map',
                        reference_noise=REAL_REFERENCE_NOISE)
    assert row.failed == 0 and row.ate < 0.9, (row.failed, row.silent, row.ate)


def test_a_map_step_the_previous_scan_refutes_is_not_taken(real_log):
    """fr079, imls, copy 5: the previous scan's step is taken where it refutes the map's.

    At scans 2552-2553 two map matches that fitted the map worse than usual were 1.6
    and 5.8 deg off; the previous scan, matched from the same prediction, was within
    0.9 deg and fitted the scan at 0.89-0.93 where the map's steps fitted it at
    0.39-0.43, and the map's own view fitted neither better. The map's steps were
    kept (``map_disputed``): 50 m drift 0.58 % against 0.28-0.34 % for the other
    copies. They are now refuted (``map_refuted``).
    """
    log = as_received(with_range_noise(real_log('fr079'), 5))
    row = benchmark_run(log, 'imls', 'constant_velocity', reference='local_map',
                        reference_noise=REAL_REFERENCE_NOISE)
    assert row.failed == 0 and row.drift_trans < 0.4, (row.drift_trans, row.ate)
