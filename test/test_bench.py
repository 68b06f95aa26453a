"""``laser_odom_bench``: rows per prior, a parameter file for every row, the search table.

Progress only on a terminal; ``--quiet`` silences warnings but not errors.
"""

import io
import json
import logging
import math
import os
from pathlib import Path
import subprocess
import sys
import time
import warnings

import numpy as np
import pytest

from laser_odom.core.simulation import simulate
from laser_odom.tools import bench
from laser_odom.tools.bench import main
from laser_odom.tools.simulate import main as simulate_main


def test_params_file_applies_to_every_row_and_the_search_table_is_printed(tmp_path, capsys):
    off = tmp_path / 'off.yaml'
    off.write_text("/**:\n  ros__parameters:\n    global_search: 'off'\n")
    rows = {}
    for label, extra in (('recover', []), ('off', ['--params-file', str(off)])):
        out = tmp_path / f'{label}.json'
        assert main(['--matchers', 'nicp', '--datasets', 'sim-spin-drop20', '--priors',
                     'none', '--no-progress', '--json', str(out)] + extra) == 0
        rows[label] = json.loads(out.read_text())
    printed = capsys.readouterr().out
    assert 'global search alone' in printed and 'sim-spin-drop20' in printed
    recover, = rows['recover']['rows']
    assert recover['prior'] == 'none' and recover['failed'] == 0 and recover['ate'] < 0.05
    search, = rows['recover']['search']
    assert search['searches'] >= 40 and search['median_ms'] > 0.0
    # Without the search, spinning at 3 rad/s with no prior loses the track.
    off_row, = rows['off']['rows']
    assert off_row['rejected'] >= 10 and off_row['failed'] >= 10 and off_row['ate'] > 1.0


def test_zero_is_still_a_prior_name_and_bad_input_is_one_line(tmp_path, capsys):
    bad = tmp_path / 'bad.yaml'
    bad.write_text("/**:\n  ros__parameters:\n    global_search: 'sometimes'\n")
    assert main(['--matchers', 'nicp', '--datasets', 'sim-office-360', '--priors', 'zero',
                 '--params-file', str(bad), '--no-progress']) == 2
    error = capsys.readouterr().err.strip()
    assert error.count('\n') == 0 and 'global_search' in error and 'sometimes' in error
    assert main(['--priors', 'sometimes', '--no-progress']) == 2
    assert 'unknown prior' in capsys.readouterr().err


# A driver of laser_odom_bench on one tiny simulated dataset whose loading emits one
# warning of every kind that reaches stderr, and one logged error.
NOISY_BENCH = """
import logging, sys, warnings
import numpy as np
from laser_odom.core.events import EventLog
from laser_odom.core.simulation import simulate
from laser_odom.tools import bench


def load():
    logging.getLogger('laser_odom.core.datasets').warning('a logged warning')
    warnings.warn('a Python warning')
    np.log(np.zeros(1))
    EventLog().warn('test', 'a pipeline event warning')
    logging.getLogger('laser_odom').error('a logged error')
    dataset = simulate('office', duration=2.0, seed=3)
    dataset.name = 'tiny'
    return dataset


bench.dataset_loaders = lambda data_dir: {'tiny': load}
sys.exit(bench.main(sys.argv[1:]))
"""
TINY = ['--datasets', 'tiny', '--matchers', 'icp', '--priors', 'constant_velocity',
        '--no-search-table']
ROOT = Path(__file__).resolve().parents[1]


def _bench(tmp_path: Path, *args: str) -> subprocess.CompletedProcess:
    """Run the noisy bench driver with stdout and stderr piped, as in a CI log.

    Its params file has a misspelt name, which the benchmark warns about.
    """
    params = tmp_path / 'params.yaml'
    params.write_text('/**:\n  ros__parameters:\n    max_scan_gapp: 2.0\n')
    return subprocess.run([sys.executable, '-c', NOISY_BENCH, *TINY, '--params-file',
                           str(params), *args], cwd=ROOT, capture_output=True, text=True,
                          timeout=300)


def test_piped_stderr_gets_no_progress_bar_but_the_warnings(tmp_path):
    result = _bench(tmp_path)
    assert result.returncode == 0, result.stderr
    assert '\r' not in result.stderr and '[#' not in result.stderr
    for text in ('max_scan_gapp', 'a logged warning', 'a Python warning', 'RuntimeWarning',
                 'a pipeline event warning', 'a logged error'):
        assert text in result.stderr, (text, result.stderr)
    assert 'tiny' in result.stdout


def test_quiet_silences_every_warning_but_not_errors(tmp_path):
    result = _bench(tmp_path, '--quiet')
    assert result.returncode == 0, result.stderr
    assert result.stderr.strip() == 'a logged error', result.stderr
    assert 'tiny' in result.stdout


def test_progress_bar_only_on_a_terminal(monkeypatch, capsys):
    class Terminal(io.StringIO):
        def isatty(self) -> bool:
            return True

    dataset = simulate('office', duration=2.0, seed=3)
    dataset.name = 'tiny'
    monkeypatch.setattr(bench, 'dataset_loaders', lambda data_dir: {'tiny': lambda: dataset})
    for extra, drawn in (([], True), (['--no-progress'], False), (['--quiet'], False)):
        terminal = Terminal()
        monkeypatch.setattr(sys, 'stderr', terminal)
        assert bench.main(TINY + extra) == 0
        assert ('\r' in terminal.getvalue()) == drawn, (extra, terminal.getvalue())
        if drawn:
            assert terminal.getvalue().endswith(f'{len(dataset.scans)}/{len(dataset.scans)}\n')
    capsys.readouterr()


def test_quiet_keeps_the_error_line(capsys):
    assert bench.main(['--quiet', '--priors', 'sometimes']) == 2
    error = capsys.readouterr().err
    assert error.count('\n') == 1 and error.startswith('laser_odom_bench: error: unknown prior')


def test_warnings_silenced_restores_logging_and_warnings():
    logger = logging.getLogger('laser_odom.test_bench')
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter('always')
        with bench.warnings_silenced(True):
            assert not logger.isEnabledFor(logging.WARNING)
            assert logger.isEnabledFor(logging.ERROR)
            warnings.warn('hidden')
            np.log(np.zeros(1))
        assert caught == []
        assert logger.isEnabledFor(logging.WARNING)
        warnings.warn('shown')
        assert [str(w.message) for w in caught] == ['shown']


def test_live_table_says_busy_and_dropped_in_the_diagnostics_wording():
    from laser_odom.tools.bench_live import format_live, LiveRow
    row = LiveRow('nicp', 2400, 1800, 600, 9.1, 20.2, 11.0, 25.0, busy=590, dropped=10,
                  cpu_percent=17.25, process_median_ms=1.25, ready_s=1.5, first_ms=40.0)
    header, values = format_live([row], 1081, 40.0, 60.0).splitlines()[1:3]
    assert header.split()[:8] == ['matcher', 'reference', 'sent', 'processed', 'no', 'answer',
                                  'busy', 'dropped']
    assert header.split()[-8:] == ['proc', 'ms', 'CPU', '%', 'ready', 's', 'first', 'ms']
    assert values.split()[:7] == ['nicp', 'scan', '2400', '1800', '600', '590', '10']
    assert values.split()[-4:] == ['1.25', '17.2', '1.50', '40.0']
    legend = format_live([row], 1081, 40.0, 60.0)
    assert 'busy: scans not processed because the node was busy' in legend
    assert 'dropped: scans dropped before reaching the node' in legend


@pytest.mark.skipif(not Path('/proc/self/stat').exists(), reason='needs Linux /proc')
def test_live_bench_reads_the_cpu_time_a_process_used():
    from laser_odom.tools.bench_live import process_cpu_seconds
    before = process_cpu_seconds(os.getpid())
    end = time.process_time() + 0.3
    while time.process_time() < end:
        pass
    used = process_cpu_seconds(os.getpid()) - before
    assert 0.2 <= used <= 5.0, used
    assert math.isnan(process_cpu_seconds(2 ** 22 + 12345))  # above Linux's pid_max


def test_grid_is_left_out_by_default_and_selected_by_name():
    loaders = {name: (lambda: None) for name in ('sim-office-360', *bench.GRIDS['deskew'])}
    grid = list(bench.GRIDS['deskew'])
    assert len(grid) == 17 and {'sim-lds01-turning', 'sim-tim571-aggressive'} <= set(grid)

    def names(*argv: str) -> list[str]:
        return bench.dataset_names(bench.parse_args(list(argv)), loaders)

    assert names() == ['sim-office-360']
    assert names('--grid', 'deskew') == grid
    assert names('--datasets', 'sim-office-360', '--grid', 'deskew') == ['sim-office-360'] + grid
    assert names('--datasets', 'sim-ld06-spin') == ['sim-ld06-spin']


def test_deskew_rows_on_a_fast_turn_with_a_slow_lidar(tmp_path, capsys):
    out = tmp_path / 'rows.json'
    assert main(['--datasets', 'sim-rplidar_a1-turning', '--matchers', 'nicp', '--priors',
                 'constant_velocity', '--deskew', 'off,auto', '--no-progress',
                 '--no-search-table', '--json', str(out)]) == 0
    header = capsys.readouterr().out.splitlines()[1].split()
    assert header[:4] == ['dataset', 'matcher', 'prior', 'deskew']
    off, auto = json.loads(out.read_text())['rows']
    assert (off['deskew'], auto['deskew']) == ('off', 'auto')
    assert off['steps'] == auto['steps'] >= 100 and off['failed'] == auto['failed'] == 0
    # Turning at 1.5 rad/s under a 5.5 Hz sweep bends every scan by about 16 degrees.
    assert auto['rpe_rot_mean'] < 0.3 * off['rpe_rot_mean']
    assert auto['ate'] < 0.5 * off['ate']
    assert main(['--datasets', 'sim-office-360', '--deskew', 'sometimes',
                 '--no-progress']) == 2
    assert 'unknown deskew value: sometimes' in capsys.readouterr().err


@pytest.fixture(scope='module')
def user_bag(tmp_path_factory) -> Path:
    """Simulate 10 s of the office (100 scans, /odom, /ground_truth) and its TUM file."""
    bag = tmp_path_factory.mktemp('bench_bag') / 'my_robot'
    assert simulate_main([str(bag), '--duration', '10']) == 0
    return bag


def test_bag_with_its_reference_is_a_dataset_with_wheel_odometry(user_bag, tmp_path, capsys):
    out = tmp_path / 'rows.json'
    assert main(['--bag', str(user_bag), '--reference', str(user_bag) + '.tum', '--matchers',
                 'icp', '--priors', 'constant_velocity,odom', '--no-progress',
                 '--no-search-table', '--json', str(out)]) == 0
    table = capsys.readouterr().out
    rows = {(row['matcher'], row['prior']): row for row in json.loads(out.read_text())['rows']}
    assert set(rows) == {('wheel_odometry', 'odom'), ('icp', 'constant_velocity'),
                         ('icp', 'odom')}
    assert {row['dataset'] for row in rows.values()} == {'my_robot'}
    for key in (('icp', 'constant_velocity'), ('icp', 'odom')):
        row = rows[key]
        assert row['steps'] == 99 and row['failed'] == 0 and row['ate'] < 0.05
        assert row['median_ms'] > 0.0
    assert rows[('wheel_odometry', 'odom')]['ate'] > rows[('icp', 'odom')]['ate']
    assert 'my_robot' in table and 'wheel_odometry' in table and 'n/a' in table


def test_bag_without_reference_is_timed_only(user_bag, tmp_path, capsys):
    from laser_odom.io.bag_reader import BagReader
    from laser_odom.io.bag_writer import write_bag
    with BagReader(user_bag) as bag:  # the same scans and /odom, no /ground_truth
        scans, odometry = list(bag.scans())[:30], bag.odometry('/odom')
    plain = tmp_path / 'plain'
    write_bag(plain, scans, odometry={'/odom': odometry})
    out = tmp_path / 'rows.json'
    assert main(['--bag', str(plain), '--scan-topic', 'scan', '--matchers', 'nicp',
                 '--priors', 'odom', '--no-progress', '--no-search-table', '--json',
                 str(out)]) == 0
    table = capsys.readouterr().out
    row, = json.loads(out.read_text())['rows']
    assert (row['dataset'], row['matcher'], row['failed'], row['steps']) == (
        'plain', 'nicp', None, 0)
    assert np.isnan(row['ate']) and row['median_ms'] > 0.0
    assert 'n/a: no reference for plain' in table


def test_bags_of_the_same_name_are_told_apart_by_their_folders(user_bag, tmp_path, capsys):
    """Issue 30.9: ``--bag A/bag --bag B/bag`` makes rows ``A/bag`` and ``B/bag``."""
    import shutil

    from laser_odom.io.bag_dataset import bag_names
    for folder in ('A', 'B'):
        shutil.copytree(user_bag, tmp_path / folder / 'bag')
    out = tmp_path / 'rows.json'
    assert main(['--bag', str(tmp_path / 'A' / 'bag'), '--bag', str(tmp_path / 'B' / 'bag'),
                 '--matchers', 'plicp', '--priors', 'constant_velocity', '--no-progress',
                 '--no-search-table', '--json', str(out)]) == 0
    assert [row['dataset'] for row in json.loads(out.read_text())['rows']] == ['A/bag', 'B/bag']
    capsys.readouterr()
    # A bag's own name when it is unique; deeper folders when those clash too; a
    # simulated dataset's name or the same bag twice get a number.
    assert bag_names([str(user_bag), str(tmp_path / 'A' / 'bag')]) == ['my_robot', 'bag']
    assert bag_names(['x/run/bag', 'y/run/bag', 'z/bag']) == ['x/run/bag', 'y/run/bag', 'z/bag']
    assert bag_names(['a/bag', 'a/bag']) == ['bag', 'bag-2']
    assert bag_names(['sim-office-360'], taken=['sim-office-360']) == ['sim-office-360-2']


def test_bad_bag_is_one_line_and_exit_2(user_bag, tmp_path, capsys):
    from laser_odom.io.bag_writer import write_bag
    from laser_odom.io.tum import read_tum, write_tum
    no_scans = tmp_path / 'no_scans'
    write_bag(no_scans, [], odometry={'/odom': read_tum(str(user_bag) + '.tum')})
    later = read_tum(str(user_bag) + '.tum')
    later.stamps_ns = later.stamps_ns + 3_600 * 10**9  # an hour after the bag
    other_clock = tmp_path / 'later.tum'
    write_tum(other_clock, later)
    cases = [
        (['--bag', str(tmp_path / 'missing')], 'bag not found'),
        (['--bag', str(no_scans)], 'no LaserScan topic'),
        (['--bag', str(user_bag), '--scan-topic', '/front'], 'no topic /front in the bag'),
        (['--bag', str(user_bag), '--reference', str(other_clock)], 'does not overlap'),
        (['--bag', str(user_bag), '--reference', str(tmp_path / 'none.tum')],
         'reference file not found'),
        (['--bag', str(user_bag), '--reference', '-', '--reference', 'x.tum'],
         'the i-th --reference belongs to the i-th --bag'),
    ]
    for argv, text in cases:
        assert main(argv + ['--matchers', 'icp', '--no-progress']) == 2, argv
        captured = capsys.readouterr()
        assert captured.err.count('\n') == 1 and text in captured.err, captured.err
        assert captured.err.startswith('laser_odom_bench: error: ') and captured.out == ''


def test_nees_columns_are_finite_and_old_results_still_load(monkeypatch, tmp_path, capsys):
    from laser_odom.core.evaluation.benchmark import BenchRow
    from laser_odom.tools.figures import FIGURES_JSON
    dataset = simulate('office', duration=15.0, seed=3)  # 150 scans: a 100-step window
    dataset.name = 'tiny'
    monkeypatch.setattr(bench, 'dataset_loaders', lambda data_dir: {'tiny': lambda: dataset})
    out = tmp_path / 'rows.json'
    nees = ('nees_1', 'nees_10', 'nees_100', 'nees_integrated')
    rows = {}
    for label, extra in (('default', []), ('none', ['--reference-noise-m', '0',
                                                    '--reference-noise-deg', '0'])):
        assert bench.main(['--datasets', 'tiny', '--matchers', 'nicp', '--priors',
                           'constant_velocity', '--no-search-table', '--no-progress', '--nees',
                           '--json', str(out)] + extra) == 0
        rows[label], = json.loads(out.read_text())['rows']
        table = capsys.readouterr().out
        assert 'NEES 1' in table and 'NEES int' in table
        assert all(math.isfinite(rows[label][key]) and rows[label][key] > 0 for key in nees)
    # 'tiny' is not one of the datasets simulated here: its reference counts as a real
    # log's (4 cm, 1 deg), which lowers every NEES; the truth needs none.
    assert (rows['default']['reference_noise_m'], rows['default']['reference_noise_deg']) == (
        0.04, 1.0)
    assert all(rows['default'][key] < rows['none'][key] for key in nees)
    assert bench.reference_noise(bench.parse_args([]), 'sim-office-360').translation == 0.0
    assert BenchRow.from_dict(rows['none']).as_dict() == rows['none']
    # A result written before the NEES existed (as the committed figures were) loads.
    committed = [{key: value for key, value in row.items()
                  if not key.startswith(('nees_', 'reference_noise_'))}
                 for row in json.loads(FIGURES_JSON.read_text())['rows']]
    loaded = [BenchRow.from_dict(row) for row in committed]
    assert all(math.isnan(row.nees_1) and row.ate == old['ate']
               for row, old in zip(loaded, committed))


@pytest.mark.parametrize('arguments, expected', [
    (['--reference-noise-deg', 'inf'], '--reference-noise-deg must be a finite number >= 0'),
    (['--reference-noise-m', 'nan'], '--reference-noise-m must be a finite number >= 0'),
    (['--reference-noise-m', '-0.01'], '--reference-noise-m must be a finite number >= 0'),
    (['--datasets', 'fr079', '--data-dir', '/nonexistent'],
     'fr079: a real log, not found under /nonexistent (pass --data-dir DIR'),
])
def test_bad_reference_noise_or_a_missing_real_log_is_one_named_error(
        capsys, arguments, expected):
    assert main(['--datasets', 'sim-office-360', '--matchers', 'plicp', '--no-progress',
                 *arguments]) == 2
    error = capsys.readouterr().err.strip()
    assert error.count('\n') == 0 and expected in error, error


def test_a_reader_that_leaves_early_loses_no_json(tmp_path):
    """``laser_odom_bench ... --json F | head -1``: no traceback, exit 1, the JSON written."""
    env = dict(os.environ, PYTHONPATH=str(ROOT) + os.pathsep + os.environ.get('PYTHONPATH', ''))
    result = tmp_path / 'bench.json'
    process = subprocess.Popen(
        [sys.executable, '-m', 'laser_odom.tools.bench', '--datasets', 'sim-office-360',
         '--matchers', 'plicp', '--priors', 'constant_velocity', '--no-search-table',
         '--quiet', '--json', str(result)], cwd=ROOT, env=env, stdout=subprocess.PIPE,
        stderr=subprocess.PIPE, text=True)
    process.stdout.close()  # the reader is gone before the first line
    _, stderr = process.communicate(timeout=300)
    assert process.returncode == 1, stderr
    assert 'Traceback' not in stderr and 'BrokenPipeError' not in stderr, stderr
    rows = json.loads(result.read_text())['rows']
    assert [row['matcher'] for row in rows] == ['plicp'] and rows[0]['steps'] == 599


def test_live_bench_runs_the_nodes_with_the_params_file_and_its_reference(
        tmp_path, capsys, monkeypatch):
    """Issue 39: ``--live --params-file F`` with ``reference: local_map`` ran scan mode."""
    pytest.importorskip('rclpy')
    from laser_odom.tools import bench_live
    params = tmp_path / 'map.yaml'
    params.write_text('/**:\n  ros__parameters:\n    reference: local_map\n')
    runs = []

    def run_matcher(matcher, messages, rate, reference='scan', params_file=None):
        runs.append((matcher, reference, params_file))
        return bench_live.LiveRow(matcher, len(messages), len(messages), 0, 1.0, 2.0, 1.0,
                                  2.0, 0, 0, 10.0, 1.0, 1.0, 5.0, reference)
    monkeypatch.setattr(bench_live, 'run_matcher', run_matcher)
    assert main(['--live', '--matchers', 'nicp', '--duration', '0.5', '--beams', '90',
                 '--params-file', str(params)]) == 0
    assert runs == [('nicp', 'local_map', params)]
    assert capsys.readouterr().out.splitlines()[3].split()[:2] == ['nicp', 'local_map']

    class Started(Exception):
        pass

    def popen(command, **kwargs):
        raise Started(command)
    monkeypatch.setattr(bench_live.subprocess, 'Popen', popen)
    with pytest.raises(Started) as started:
        bench_live.LiveSession('nicp', 7, 'local_map', params)
    command = started.value.args[0]
    assert command[command.index('--params-file') + 1] == str(params)
    assert command.index('--params-file') < command.index('reference:=local_map') - 1


@pytest.mark.parametrize('live', [False, True], ids=['offline', 'live'])
def test_a_params_file_with_no_section_for_the_node_is_an_error(live, tmp_path, capsys):
    """Issue 39: it warned, then ran on the defaults with exit 0."""
    other = tmp_path / 'other.yaml'
    other.write_text('front_odom:\n  ros__parameters:\n    matcher: icp\n')
    argv = ['--params-file', str(other)] + (
        ['--live', '--matchers', 'nicp'] if live else ['--datasets', 'sim-office-360'])
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert err == (f'laser_odom_bench: error: params file {other} has no section for '
                   '/laser_odom (it has front_odom): none of its parameters apply, so '
                   'nothing would be run with it - use "/**:" to address the node under any '
                   'name and namespace\n')
