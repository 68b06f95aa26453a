"""Switch off each rejection rule and gate of the matchers, one at a time, and run its tests.

Every rule must be guarded by a self-contained test: with the rule switched off (its
condition replaced by "always passes") at least one test of its module's test file must
fail. Each case copies the package, its tests and configs to a temporary folder, edits
the one line there, and runs pytest with a kernel cache of its own (a cached kernel of
the unedited code would hide the change). A rule that is not guarded is a gap: close it
with a test. The propagation's two Jacobians are audited the same way.

    python .ci/rule_audit.py [WORD ...]   # every rule, or those whose name has a WORD
"""

from __future__ import annotations

from pathlib import Path
import shutil
import subprocess
import sys
import tempfile
import time
from typing import NamedTuple

ROOT = Path(__file__).resolve().parents[1]
M = 'laser_odom/core/matchers/'


class Rule(NamedTuple):
    """A rule: its name, file and test file, its code, and that code switched off."""

    name: str
    path: str
    tests: str
    code: str
    disabled: str


RULES = [
    Rule('nicp normal rule', M + 'nicp/model.py', 'test/test_nicp.py',
         'table[m, 0] = current_usable[m] and ref_usable[j]', 'table[m, 0] = True'),
    Rule('nicp distance rule', M + 'nicp/model.py', 'test/test_nicp.py',
         'table[m, 1] = distance[m] <= max_distance', 'table[m, 1] = True'),
    Rule('nicp normal angle rule', M + 'nicp/model.py', 'test/test_nicp.py',
         'table[m, 2] = cosine >= min_normal_cosine', 'table[m, 2] = True'),
    Rule('nicp curvature ratio rule', M + 'nicp/model.py', 'test/test_nicp.py',
         'table[m, 3] = abs(log_curvature[m] - ref_log_curvature[j]) <= max_curvature_ratio',
         'table[m, 3] = True'),
    Rule('plicp segment gap and length', M + 'plicp/segments.py', 'test/test_plicp.py',
         'ok[j] = (beam_index[j + 1] - beam_index[j] <= max_beam_gap\n'
         '                 and 0.0 < length[j] <= max_segment_length)',
         'ok[j] = 0.0 < length[j]'),
    Rule('plicp trimming', M + 'plicp/segments.py', 'test/test_plicp.py',
         'mask = trimmed_mask(residuals, keep_fraction)',
         'mask = np.ones(residuals.shape[0], dtype=np.bool_)'),
    Rule('plicp restart on residual', M + 'plicp/matcher.py', 'test/test_plicp.py',
         'or run.rms > cfg.restart_residual', 'or False'),
    Rule('plicp restart on non-convergence', M + 'plicp/matcher.py', 'test/test_plicp.py',
         'run is None or not run.converged', 'run is None'),
    Rule('icp trimming', M + 'icp/solver.py', 'test/test_icp.py',
         'kept = found[trimmed_mask(gated, keep)]', 'kept = found'),
    Rule('icp distance gate', M + 'icp/solver.py', 'test/test_icp.py',
         'move_points(estimate, points), max_distance,', 'move_points(estimate, points), np.inf,'),
    Rule('imls min neighbours', M + 'imls/surface.py', 'test/test_imls.py',
         'if count[q] < min_neighbours:', 'if count[q] < 1:'),
    Rule('imls inlier gate', M + 'imls/solver.py', 'test/test_imls.py',
         'inlier[np.flatnonzero(ok)] = inlier_mask(',
         'inlier[np.flatnonzero(ok)] = 1.0 + 0 * inlier_mask('),
    Rule('acceptance not_converged', 'laser_odom/core/registration/rejection.py',
         'test/test_acceptance.py',
         "    if not match.converged:\n        return 'not_converged'",
         "    if False:\n        return 'not_converged'"),
    Rule('acceptance low_inlier_ratio', 'laser_odom/core/registration/rejection.py',
         'test/test_acceptance.py',
         'if inlier_ratio < config.min_inlier_ratio:', 'if False:'),
    Rule('acceptance large_correction', 'laser_odom/core/registration/rejection.py',
         'test/test_acceptance.py',
         'if linear > config.max_correction_linear or angular > config.max_correction_angular:',
         'if False:'),
    Rule('propagation without ja', 'laser_odom/core/uncertainty/pose_uncertainty.py',
         'test/test_pose_covariance.py',
         'transition[0:3, 0:3] = ja', 'transition[0:3, 0:3] = np.eye(3)'),
    Rule('propagation without jb', 'laser_odom/core/uncertainty/pose_uncertainty.py',
         'test/test_pose_covariance.py',
         'noise[0:3, 0:3] = jb @ (shared + white + innovation) @ jb.T',
         'noise[0:3, 0:3] = shared + white + innovation'),
]


def audit(rule: Rule) -> bool:
    """Return whether switching ``rule`` off fails a test (and print one line)."""
    with tempfile.TemporaryDirectory(prefix='laser_odom-rule-') as temp:
        work = Path(temp)
        for folder in ('laser_odom', 'test', 'config'):
            shutil.copytree(ROOT / folder, work / folder,
                            ignore=shutil.ignore_patterns('__pycache__'))
        for name in ('setup.cfg', 'setup.py', 'package.xml', 'README.md'):
            shutil.copy(ROOT / name, work)
        source = (work / rule.path).read_text()
        if source.count(rule.code) != 1:
            print(f'{rule.name:35s} NOT FOUND: the code changed, update {__file__}')
            return False
        (work / rule.path).write_text(source.replace(rule.code, rule.disabled))
        env = {'NUMBA_CACHE_DIR': str(work / '.kernels'), 'PYTHONPATH': str(work),
               'PATH': '/usr/bin:/bin', 'HOME': temp}
        started = time.monotonic()
        result = subprocess.run([sys.executable, '-m', 'pytest', '-x', '-q', '-p',
                                 'no:cacheprovider', rule.tests], cwd=work, env=env,
                                capture_output=True, text=True)
        failed = [line.split()[1] for line in result.stdout.splitlines()
                  if line.startswith('FAILED')]
        verdict = f'guarded by {failed[0]}' if failed else 'NOT GUARDED'
        print(f'{rule.name:35s} {verdict} ({time.monotonic() - started:.0f} s)', flush=True)
        return bool(failed)


def main(words: list[str]) -> int:
    """Audit the rules chosen (all by default); exit 1 if one is not guarded."""
    chosen = [rule for rule in RULES if not words or any(w in rule.name for w in words)]
    results = [audit(rule) for rule in chosen]  # every rule, not only up to a gap
    return 0 if all(results) else 1


if __name__ == '__main__':
    sys.exit(main(sys.argv[1:]))
