"""Score Censi's C PL-ICP (CSM, github.com/AndreaCensi/csm) on the real logs, as a peer.

The script behind ``CSM_BAR`` in test/test_real_data.py: mean translational /
rotational RPE, ATE after SE(2) alignment and failed steps of CSM's ``sm_icp`` run scan
to scan with a constant-velocity first guess, on fr079, mit-csail and intel.

Each log is loaded with the project's own loader, its scans are written to a text file,
``csm_driver`` (csm_driver.c, linked against CSM's library) matches every scan against
the previous one and writes one pose per scan, and the trajectory is scored by the
benchmark's own code (``laser_odom.core.evaluation.benchmark._row``: the metrics of
``laser_odom.core.evaluation.metrics.evaluate``, the same ``failed`` - a step whose RPE is above
0.5 m or 10 deg - and the same timing statistics, here of ``sm_icp`` alone).
``invalid`` counts the steps where ``sm_icp`` reported ``valid == 0`` (the driver then
keeps the prediction), the counterpart of the pipeline's ``rejected`` count.

The first guess is the previous step, scaled by ``--dt``: ``scan`` (the default) not at
all - the previous step repeated, which is how ``CSM_BAR`` was made; ``pipeline`` to
the time gap as the pipeline's constant-velocity prior does
(``laser_odom.core.motion.model.MotionModel``: an effective interval for the logger-stamped
Intel log, no guess over a gap longer than ``max_scan_gap``); ``stamps`` to the raw
stamp differences. ``--preset csm`` (the default, as ``CSM_BAR`` was made) gives CSM
its own default parameters (sm_options.c), ``--preset ros`` those laser_scan_matcher
(scan_tools, ROS) gives it; ``--param name=value`` overrides one
(``csm_driver --params`` lists them).

Needs: a C compiler, make, cmake, a CSM checkout (``--csm-src``) and GSL - the system's
(Ubuntu: ``apt install libgsl-dev``, found with pkg-config), an installed one
(``--gsl-prefix``) or a CMake-buildable source tree such as github.com/ampl/gsl
(``--gsl-src``, built into the build directory). Builds go to ``--build-dir``
(default .ci/peers/build, git-ignored), one job at a time.

    .venv/bin/python .ci/peers/csm_peer.py --csm-src CSM [--gsl-prefix P | --gsl-src S]
        [--data-dir ../shared/data] [--dataset fr079 ...] [--dt scan] [--preset csm]
        [--json out.json]
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path
import shutil
import subprocess
import sys
import tempfile

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))

from laser_odom.core.configuration.pipeline import MotionConfig  # noqa: E402
from laser_odom.core.datasets import discover_datasets, load_dataset  # noqa: E402
from laser_odom.core.evaluation.benchmark import _row, BenchRow, NOT_APPLICABLE  # noqa: E402
from laser_odom.core.motion.model import MotionModel  # noqa: E402
from laser_odom.core.trajectory import Dataset, Trajectory  # noqa: E402

PEERS = Path(__file__).resolve().parent
DEFAULT_BUILD = PEERS / 'build'
DEFAULT_DATA = ROOT.parent / 'shared' / 'data'
DATASETS = ('fr079', 'mit-csail', 'intel')
"""The logs of ``CSM_BAR`` in test/test_real_data.py."""

GUESSES = ('scan', 'pipeline', 'stamps')
"""The ``--dt`` choices: how the previous step becomes the first guess (:func:`cv_ratios`)."""

MATCHER = 'csm-plicp'
"""The matcher name of CSM's rows."""


def fail(message: str) -> None:
    """Say what went wrong in one line and exit with 2, as the project's tools do."""
    print(f'csm_peer: error: {message}', file=sys.stderr)
    sys.exit(2)


def have_system_gsl() -> bool:
    """Tell whether pkg-config knows a GSL (Ubuntu: libgsl-dev)."""
    if shutil.which('pkg-config') is None:
        return False
    return subprocess.run(['pkg-config', '--exists', 'gsl']).returncode == 0


def build(csm_src: Path, build_dir: Path, gsl_prefix: Path | None,
          gsl_src: Path | None) -> Path:
    """Build CSM's library and the driver (and GSL from source if asked); return the driver."""
    make = ['make', '-C', str(PEERS), f'BUILD={build_dir}', f'CSM_SRC={csm_src}', 'JOBS=1']
    if gsl_prefix is None and gsl_src is not None:
        gsl_prefix = build_dir / 'gsl'
        if not (gsl_prefix / 'lib' / 'libgsl.a').is_file():
            subprocess.run(make + [f'GSL_SRC={gsl_src}', 'gsl'], check=True)
    if gsl_prefix is None and not have_system_gsl():
        fail('no GSL: install libgsl-dev (pkg-config gsl), or pass --gsl-prefix (an '
             'installed GSL) or --gsl-src (a CMake GSL source tree, e.g. ampl/gsl)')
    if gsl_prefix is not None:
        make.append(f'GSL_PREFIX={gsl_prefix}')
    subprocess.run(make + ['driver'], check=True)
    return build_dir / 'csm_driver'


def cv_ratios(stamps_ns: np.ndarray, mode: str, config: MotionConfig) -> np.ndarray:
    """Return, per scan, the factor from the previous step to the first guess (0: none).

    ``scan``: the previous step as it is (factor 1 from the third scan on; the stamps
    are not read). ``pipeline`` replays :class:`MotionModel`: the guess is
    ``velocity * effective_dt`` and the velocity the last step over its effective
    interval, so the factor is the ratio of the two intervals, with no guess over a gap
    above ``max_scan_gap`` nor from a step over one. ``stamps`` divides the raw stamp
    differences, with the same gap rule.
    """
    ratios = np.zeros(len(stamps_ns))
    if mode == 'scan':
        ratios[2:] = 1.0
        return ratios
    dts = np.diff(stamps_ns.astype(np.int64)) * 1e-9
    if mode == 'stamps':
        for k in range(2, len(stamps_ns)):
            now, before = dts[k - 1], dts[k - 2]
            if 0.0 < now <= config.max_scan_gap and 0.005 <= before <= config.max_scan_gap:
                ratios[k] = now / before
        return ratios
    model = MotionModel(config)
    velocity_dt = 0.0
    for k in range(1, len(stamps_ns)):
        dt = float(dts[k - 1])
        if velocity_dt > 0.0 and not model.gap_exceeded(dt):
            ratios[k] = model.effective_dt(dt) / velocity_dt
        model.update(np.array([1.0, 0.0, 0.0]), dt)  # a unit step: velocity = 1 / dt_eff
        velocity_dt = 1.0 / model.velocity[0] if model.velocity[0] > 0.0 else 0.0
    return ratios


def write_scans(dataset: Dataset, ratios: np.ndarray, path: Path) -> None:
    """Write the driver's input: a header line, then one line per scan."""
    with open(path, 'w') as out:
        out.write(f'csm_peer_scans 1 {len(dataset.scans)}\n')
        for scan, ratio in zip(dataset.scans, ratios):
            ranges = ' '.join(f'{r:.9g}' for r in np.asarray(scan.ranges, dtype=float))
            out.write(f'{scan.stamp_ns} {ratio:.17g} {len(scan.ranges)} '
                      f'{scan.angle_min:.17g} {scan.angle_increment:.17g} '
                      f'{scan.range_min:.17g} {scan.range_max:.17g} {ranges}\n')


def run_driver(driver: Path, scans: Path, params: list[str]) -> np.ndarray:
    """Run the driver; return its rows (stamp, x, y, theta, valid, iterations, nvalid, s)."""
    done = subprocess.run([str(driver), str(scans), *params], stdout=subprocess.PIPE,
                          stderr=subprocess.PIPE, text=True)
    if done.returncode != 0:
        fail(f'csm_driver failed ({done.returncode}): {done.stderr[-2000:]}')
    rows = [line.split() for line in done.stdout.splitlines() if not line.startswith('#')]
    return np.array(rows, dtype=float)


def score(dataset: Dataset, driver: Path, mode: str, params: list[str],
          work: Path) -> tuple[BenchRow, int]:
    """Run CSM over a dataset and score it like the benchmark; also return invalid steps."""
    stamps = np.array([scan.stamp_ns for scan in dataset.scans], dtype=np.int64)
    scans = work / f'{dataset.name}.scans'
    write_scans(dataset, cv_ratios(stamps, mode, MotionConfig()), scans)
    rows = run_driver(driver, scans, params)
    if len(rows) != len(stamps):
        fail(f'{dataset.name}: {len(rows)} poses for {len(stamps)} scans')
    estimate = Trajectory(stamps, rows[:, 1:4])
    matched = rows[1:]
    invalid = int(np.count_nonzero(matched[:, 4] == 0))
    row = _row(dataset, MATCHER, 'constant_velocity', NOT_APPLICABLE, estimate,
               matched[:, 7], invalid)
    return row, invalid


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('--csm-src', type=Path, required=True,
                        help='a checkout of github.com/AndreaCensi/csm')
    parser.add_argument('--gsl-prefix', type=Path,
                        help='an installed GSL (default: pkg-config gsl)')
    parser.add_argument('--gsl-src', type=Path,
                        help='a CMake GSL source tree (ampl/gsl), built if no GSL is found')
    parser.add_argument('--build-dir', type=Path, default=DEFAULT_BUILD,
                        help=f'where CSM, GSL and the driver are built (default {DEFAULT_BUILD})')
    parser.add_argument('--data-dir', type=Path, default=DEFAULT_DATA,
                        help=f'the real logs (default {DEFAULT_DATA})')
    parser.add_argument('--dataset', action='append', choices=DATASETS,
                        help='a log to score (repeatable; default: all three)')
    parser.add_argument('--dt', choices=GUESSES, default='scan',
                        help='how the previous step is scaled into the guess (default scan: '
                        'not at all, as CSM_BAR was made)')
    parser.add_argument('--preset', choices=('csm', 'ros'), default='csm',
                        help="CSM's parameters: its own defaults (csm, as CSM_BAR was made) "
                        "or laser_scan_matcher's (ros)")
    parser.add_argument('--param', action='append', default=[], metavar='NAME=VALUE',
                        help='override a CSM parameter (csm_driver --params lists them)')
    parser.add_argument('--json', type=Path, help='also write the rows to this file')
    args = parser.parse_args(argv)
    for option, folder in (('--csm-src', args.csm_src), ('--gsl-prefix', args.gsl_prefix),
                           ('--gsl-src', args.gsl_src), ('--data-dir', args.data_dir)):
        if folder is not None and not folder.is_dir():
            parser.error(f'{option} {folder}: no such directory')
    try:
        driver = build(args.csm_src.resolve(), args.build_dir.resolve(),
                       args.gsl_prefix.resolve() if args.gsl_prefix else None,
                       args.gsl_src.resolve() if args.gsl_src else None)
    except subprocess.CalledProcessError as error:
        print(f'csm_peer: error: the build failed ({" ".join(error.cmd[-1:])} target, exit '
              f'{error.returncode}); its output is above', file=sys.stderr)
        return 2
    found = discover_datasets(args.data_dir)
    names = args.dataset or list(DATASETS)
    missing = [name for name in names if name not in found]
    if missing:
        fail(f'not under {args.data_dir}: {", ".join(missing)}')

    results = []
    print(f'CSM sm_icp (--preset {args.preset}), constant-velocity guess (--dt {args.dt})'
          + (f', {" ".join(args.param)}' if args.param else ''))
    print(f'{"dataset":<10} {"trans RPE m":>11} {"rot RPE deg":>11} {"ATE m":>7} '
          f'{"failed":>6} {"invalid":>7} {"steps":>6} {"median ms":>9}')
    with tempfile.TemporaryDirectory(prefix='csm_peer_') as tmp:
        for name in names:
            dataset = load_dataset(found[name], name=name)
            row, invalid = score(dataset, driver, args.dt,
                                 [f'preset={args.preset}', *args.param], Path(tmp))
            print(f'{name:<10} {row.rpe_trans_mean:>11.4f} {row.rpe_rot_mean:>11.3f} '
                  f'{row.ate:>7.3f} {row.failed:>6} {invalid:>7} {row.steps:>6} '
                  f'{row.median_ms:>9.3f}', flush=True)
            results.append(dict(row.as_dict(), invalid=invalid, preset=args.preset,
                                dt=args.dt, params=args.param))
    if args.json:
        args.json.write_text(json.dumps(results, indent=1) + '\n')
    return 0


if __name__ == '__main__':
    sys.exit(main())
