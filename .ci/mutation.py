"""Mutation testing of one core module with cosmic-ray (``make mutation MODULE=se2``).

Each mutant (an operator, comparison, constant or boolean changed in the module's
source) is run against the module's self-contained tests; a mutant the tests do not
notice is a gap to close with a test, or an equivalent change to list with the reason.
The run happens in a temporary clone of the committed tree (the working tree is never
mutated). In a module with compiled kernels numba is switched off, since a kernel of
another module keeps the code it inlined from a cached one and would hide the mutant;
the pure-Python modules keep numba on, with a kernel cache of their own that only
their unmutated callees fill. The mutants are the operators a typo could produce:
arithmetic (+ - * /), comparisons, boolean constants and connectives, unary minus,
numbers and loops. Left out: bit, power, modulo and floor-division replacements (a
float raises at once) and decorator removal (numba's ``njit`` is equivalent to the
plain function).

    python .ci/mutation.py se2 [--session FILE]

prints every surviving mutant and the score; ``--session`` keeps the cosmic-ray
session (a sqlite file) to resume or inspect with ``cr-report``. Only committed code is
tested (the clone): commit a new test before running again. Survivors judged
equivalent are listed, with the reason, in ``.ci/mutation-survivors.md``.
"""

from __future__ import annotations

import argparse
import os
from pathlib import Path
import sqlite3
import subprocess
import sys
import tempfile

ROOT = Path(__file__).resolve().parents[1]
CORE = 'laser_odom/core'
M = f'{CORE}/matchers'
IMLS_TESTS = ['test/test_imls.py', '--deselect',
              'test/test_imls.py::test_symmetric_match_averages_out_a_sparse_noisy_reference']
"""test_imls.py but its symmetric-match test: that test guards the fusion of the two
directions in imls.py, not the surface or the solver, and takes 45 of a pass's 55 s
with numba off (without it a module's run takes under an hour, not six)."""
MODULES = {
    'se2': (f'{CORE}/se2.py', ['test/test_se2.py']),
    'acceptance': (f'{CORE}/registration/acceptance.py',
                   ['test/test_acceptance.py', 'test/test_pipeline.py',
                    'test/test_degeneracy.py', 'test/test_global_search.py',
                    'test/test_large_motion.py']),
    'rejection': (f'{CORE}/registration/rejection.py',
                  ['test/test_acceptance.py', 'test/test_pipeline.py',
                   'test/test_degeneracy.py', 'test/test_global_search.py',
                   'test/test_large_motion.py']),
    'validation': (f'{CORE}/preprocess/validation.py', ['test/test_scan.py',
                                                        'test/test_pipeline.py']),
    'motion': (f'{CORE}/motion/model.py',
               ['test/test_motion.py', 'test/test_pipeline.py', 'test/test_priors.py']),
    'pipeline': (f'{CORE}/pipeline/odometry.py',
                 ['test/test_pipeline.py', 'test/test_deskew_pipeline.py']),
    'pose_uncertainty': (f'{CORE}/uncertainty/pose_uncertainty.py', [
        f'test/test_pose_covariance.py::test_{name}' for name in (
            'white_errors_compound_as_smith_self_and_cheeseman',
            'shared_scan_noise_telescopes', 'a_persistent_bias_adds_up_linearly',
            'one_step_keeps_the_matchers_covariance_whatever_the_shares',
            'what_is_not_the_scans_own_noise_falls_off_with_the_baseline',
            'a_state_whose_scan_is_not_known_starts_its_noise_and_bias_from_their_prior')]),
    'robust': (f'{M}/robust.py', ['test/test_robust.py']),
    'icp_solver': (f'{M}/icp/solver.py', ['test/test_icp.py']),
    'plicp_solver': (f'{M}/plicp/solver.py', ['test/test_plicp.py']),
    'plicp_segments': (f'{M}/plicp/segments.py', ['test/test_plicp.py']),
    'nicp_model': (f'{M}/nicp/model.py', ['test/test_nicp.py']),
    'nicp_solver': (f'{M}/nicp/solver.py', ['test/test_nicp.py']),
    'imls_surface': (f'{M}/imls/surface.py', IMLS_TESTS),
    'imls_solver': (f'{M}/imls/solver.py', IMLS_TESTS),
}
"""Module name -> (source file, the self-contained tests that guard it)."""

PURE_PYTHON = {'acceptance', 'rejection', 'validation', 'motion', 'pipeline'}
"""Modules without compiled kernels: their tests run with numba on. (pose_uncertainty has a
kernel of its own, which numba would compile again for every mutant, 15 s each; its model
tests call nothing else compiled.)"""

ODD = '(BitAnd|BitOr|BitXor|LShift|RShift|Mod|FloorDiv|Pow)'
EXCLUDED = [rf'core/ReplaceBinaryOperator_\w+_{ODD}', rf'core/ReplaceBinaryOperator_{ODD}_\w+',
            r'core/ReplaceUnaryOperator_\w+_(Invert|Not|UAdd)', r'core/RemoveDecorator']


def config_text(module: str, work: Path, python: str, timeout: float) -> str:
    """Return the cosmic-ray configuration for ``module`` in the clone ``work``."""
    path, tests = MODULES[module]
    numba = (f'NUMBA_CACHE_DIR={work}/.kernels' if module in PURE_PYTHON
             else 'NUMBA_DISABLE_JIT=1')
    command = (f'env {numba} PYTHONPATH={work} {python} -m pytest -x -q '
               f'-p no:cacheprovider {" ".join(tests)}')
    excluded = ', '.join(f"'{pattern}'" for pattern in EXCLUDED)  # TOML literal strings
    return (f'[cosmic-ray]\nmodule-path = "{path}"\ntimeout = {timeout}\n'
            f'excluded-modules = []\ntest-command = "{command}"\n\n'
            f'[cosmic-ray.distributor]\nname = "local"\n\n'
            f'[cosmic-ray.filters.operators-filter]\nexclude-operators = [{excluded}]\n')


def main(argv: list[str] | None = None) -> int:
    """Run cosmic-ray over one module and print its score and surviving mutants."""
    parser = argparse.ArgumentParser(
        description='Mutation testing of one core module with cosmic-ray, in a temporary '
        'clone of the committed tree.')
    parser.add_argument('module', choices=sorted(MODULES))
    parser.add_argument('--session', type=Path, default=None,
                        help='keep the cosmic-ray session here (sqlite; resumed if it exists)')
    parser.add_argument('--timeout', type=float, default=300.0,
                        help='seconds one mutant may take before it counts as killed')
    args = parser.parse_args(argv)
    bin_dir = Path(sys.executable).parent
    with tempfile.TemporaryDirectory(prefix='laser_odom-mutation-') as temp:
        work = Path(temp) / 'tree'
        subprocess.run(['git', 'clone', '-q', str(ROOT), str(work)], check=True)
        config = work / 'mutation.toml'
        config.write_text(config_text(args.module, work, sys.executable, args.timeout))
        path, tests = MODULES[args.module]
        print(f'mutating {path} (commit {head(work)}) against {" ".join(tests)}; this takes '
              'minutes and prints nothing until the end', flush=True)
        session = (args.session or Path(temp) / 'session.sqlite').resolve()
        env = dict(os.environ)
        if not session.exists():
            subprocess.run([bin_dir / 'cosmic-ray', 'init', str(config), str(session)],
                           cwd=work, check=True, env=env)
            subprocess.run([bin_dir / 'cr-filter-operators', str(session), str(config)],
                           cwd=work, check=True, env=env)
        subprocess.run([bin_dir / 'cosmic-ray', 'exec', str(config), str(session)],
                       cwd=work, check=True, env=env)
        report = subprocess.run([bin_dir / 'cr-report', '--show-diff', '--surviving-only',
                                 str(session)],
                                cwd=work, check=True, env=env, capture_output=True, text=True)
        print(report.stdout)
        print(score_line(session))
    print('survivors judged equivalent, with the reason: .ci/mutation-survivors.md')
    return 0


def head(work: Path) -> str:
    """Return the short commit id of the clone."""
    return subprocess.run(['git', 'rev-parse', '--short', 'HEAD'], cwd=work, check=True,
                          capture_output=True, text=True).stdout.strip()


def score_line(session: Path) -> str:
    """Return 'N mutants run: K killed, S survived (score)' from a cosmic-ray session."""
    with sqlite3.connect(session) as db:
        counts = dict(db.execute('SELECT test_outcome, COUNT(*) FROM work_results WHERE '
                                 'worker_outcome != ? GROUP BY test_outcome', ('SKIPPED',)))
    killed, survived = counts.get('KILLED', 0), counts.get('SURVIVED', 0)
    run = sum(counts.values())
    score = f'{100.0 * killed / run:.1f} %' if run else 'n/a'
    return (f'{run} mutants run: {killed} killed, {survived} survived, '
            f'{run - killed - survived} incompetent (score {score})')


if __name__ == '__main__':
    sys.exit(main())
