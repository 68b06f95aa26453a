"""``laser_odom_tune``: the search space, a trial's score, shared and resumed studies, bad input.

Everything runs on one 10 s simulated bag (100 scans) with a handful of trials, so the
whole file stays well under a minute on two loaded cores.
"""

import math
import os
from pathlib import Path
import re
import subprocess
import sys
import types

import numpy as np
import pytest

from laser_odom.core.configuration.node import check_values, parameter_specs, settings_from_params
from laser_odom.core.simulation import simulate
from laser_odom.core.simulation.odometry import OdometryNoise
from laser_odom.core.tuning import objective as objective_module
from laser_odom.core.tuning.objective import FAILED_TRIAL_SCORE, laser_failure, run_trial
from laser_odom.core.tuning.space import matcher_space, read_space_file, SpaceError, suggest
from laser_odom.io.bag_writer import write_bag
from laser_odom.io.params_file import read_params_files
from laser_odom.io.tum import write_tum
import laser_odom.tools
from laser_odom.tools import tune as tune_module
from laser_odom.tools.tune import load_bag, main

optuna = pytest.importorskip('optuna')

ROOT = Path(__file__).resolve().parents[1]
SPECS = {spec.name: spec for spec in parameter_specs()}


@pytest.fixture(scope='module')
def sim(tmp_path_factory):
    """Return a folder with a 10 s simulated bag (scans, /odom, /ground_truth) and ref.tum."""
    folder = tmp_path_factory.mktemp('tune')
    data = simulate('office', duration=10.0, seed=1)
    write_bag(folder / 'bag', data.scans,
              odometry={'/ground_truth': data.reference, '/odom': data.odometry})
    write_tum(folder / 'ref.tum', data.reference)
    return folder


def _table(text: str) -> dict[str, list[str]]:
    """Return the rows of the last printed table by matcher."""
    lines = text.splitlines()
    start = max(i for i, line in enumerate(lines) if line.startswith('matcher'))
    rows = {}
    for line in lines[start + 1:]:
        if line.startswith('best:') or line.split()[0].endswith(':'):  # failures, best
            break
        rows[line.split()[0]] = line.split()[1:]
    return rows


def _study(storage: str, name: str):
    return optuna.load_study(study_name=name, storage=storage)


def test_space_narrows_the_declared_ranges_around_the_start():
    space = {d.name: d for d in matcher_space('plicp', {'min_inlier_ratio': 0.2},
                                              ('none', 'constant_velocity', 'odom'))}
    # [v/4, 4v] clipped to the declared range, log scale; the start is a params-file value.
    ratio = space['min_inlier_ratio']
    assert (ratio.low, ratio.high, ratio.log, ratio.start) == (0.05, 0.8, True, 0.2)
    distance = space['plicp.max_correspondence_distance']
    assert math.isclose(distance.low, 0.0375) and math.isclose(distance.high, 0.6)
    iterations = space['plicp.max_iterations']
    assert (iterations.kind, iterations.low, iterations.high) == ('int', 13, 200)
    assert space['min_inlier_ratio'].high <= SPECS['min_inlier_ratio'].info.high
    assert space['keyframe_distance'].low == 0.0 and not space['keyframe_distance'].log
    assert space['prior'].choices == ('none', 'constant_velocity', 'odom')
    assert space['global_search'].choices == ('off', 'recover', 'always')
    assert 'plicp.covariance_scale' not in space and 'nicp.damping' not in space
    # What each scan is matched against is searched (issue 39: ATE 0.14 -> 0.01 m).
    assert space['reference'].choices == ('scan', 'local_map')


def test_no_trial_crosses_an_ordered_pair():
    """A minimum is never proposed above its maximum.

    Issue 39: nicp.normal_min_neighbours 7 above nicp.normal_neighbours 6 was recommended.
    """
    space = matcher_space('nicp', {}, ('none', 'constant_velocity'))
    dims = {d.name: d for d in space}
    # A fixed maximum cuts the range; of two searched ones the lower follows the higher.
    assert dims['global_search_linear'].high == SPECS['global_search_max_linear'].default
    assert dims['nicp.normal_min_neighbours'].at_most == (
        'nicp.normal_neighbours', 'nicp.information_neighbours')
    assert dims['nicp.flat_curvature'].at_most == ('nicp.max_curvature',)
    study = optuna.create_study(sampler=optuna.samplers.RandomSampler(seed=5))
    crossed = 0
    for _ in range(300):
        values = suggest(space, study.ask())
        check_values({**values, 'matcher': 'nicp'})  # raises on a crossed pair
        crossed += values['nicp.normal_min_neighbours'] == values['nicp.normal_neighbours']
    assert crossed < 300  # not pinned to the maximum: the range below it is searched


def test_space_file_overrides_and_its_mistakes_are_one_line(tmp_path):
    path = tmp_path / 'space.yaml'
    path.write_text('nicp:\n  max_iterations: [20, 30]\nglobal_search: [off, recover]\n'
                    'plicp.trim_sigma: [2, 4]\nmax_residual_ratio: [2.0, 4.0]\n')
    overrides = read_space_file(path, ['nicp'])
    assert 'plicp.trim_sigma' not in overrides
    space = {d.name: d for d in matcher_space('nicp', {}, ('none', 'constant_velocity'),
                                              overrides)}
    assert (space['nicp.max_iterations'].low, space['nicp.max_iterations'].high) == (20, 30)
    assert space['global_search'].choices == ('off', 'recover')  # an unquoted off is 'off'
    assert space['max_residual_ratio'].kind == 'float'  # added to the search
    for text, message in (('nicp.h_typo: [1, 2]\n', 'not a tunable parameter'),
                          ('prior: [odom]\n', 'not every bag has the topic'),
                          ('min_inlier_ratio: [0.5, 2.0]\n', 'leaves the declared range'),
                          ('global_search: [sometimes]\n', 'is not one of'),
                          ('global_search: []\n', 'empty choice list; give at least one')):
        path.write_text(text)
        with pytest.raises(SpaceError, match=message) as error:
            matcher_space('nicp', {}, ('none', 'constant_velocity'),
                          read_space_file(path, ['nicp']))
        assert '\n' not in str(error.value)


def test_a_failing_trial_scores_the_penalty_and_a_good_one_its_rpe(sim, monkeypatch):
    bag = load_bag(str(sim / 'bag'), None, None, '/odom')
    assert bag.reference is not None and bag.odometry is not None  # /ground_truth, /odom
    good = run_trial({'matcher': 'nicp'}, [bag], 'rpe')
    assert good.error is None and 0.0 < good.score < 0.01
    refused = run_trial({'matcher': 'nicp', 'prior': 'imu'}, [bag], 'rpe')
    assert refused.score == FAILED_TRIAL_SCORE and 'IMU' in refused.error

    def explode(*args, **kwargs):
        raise FloatingPointError('diverged')
    monkeypatch.setattr(objective_module, 'run_pipeline', explode)
    crashed = run_trial({'matcher': 'nicp'}, [bag], 'rpe')
    assert crashed.score == FAILED_TRIAL_SCORE and 'diverged' in crashed.error


def test_tuning_improves_or_equals_the_defaults_and_the_file_starts_the_node(
        sim, tmp_path, capsys):
    out = tmp_path / 'tuned.yaml'
    assert main([str(sim / 'bag'), '--matchers', 'nicp,plicp', '--trials', '5', '--seed', '3',
                 '--reference', str(sim / 'ref.tum'), '--output', str(out), '--quiet']) == 0
    printed = capsys.readouterr()
    rows = _table(printed.out)
    assert printed.err == ''
    for matcher in ('nicp', 'plicp'):
        default, best, trials = float(rows[matcher][0]), float(rows[matcher][1]), rows[matcher][2]
        assert best <= default < 0.01 and trials == '5'
    checked = read_params_files([out])  # what the node does with --params-file
    assert checked.warnings == []
    check_values(checked.values)
    settings_from_params(checked.values)
    text = out.read_text()
    assert text.splitlines()[2:4] == ['/**:', '  ros__parameters:']
    assert all('# ' in line and 'score' in line for line in text.splitlines()[4:]
               if ': ' in line)
    defaults = {name: spec.default for name, spec in SPECS.items()}
    assert all(value != defaults[name] or name == 'matcher'
               for name, value in checked.values.items())
    # The file reproduces the best score when run again.
    winner = checked.values['matcher']
    bag = load_bag(str(sim / 'bag'), str(sim / 'ref.tum'), None, '/odom')
    rerun = run_trial(checked.values, [bag], 'rpe')
    assert math.isclose(rerun.score, float(rows[winner][1]), rel_tol=1e-4)


def test_a_resumed_study_continues_its_trial_count(sim, tmp_path, capsys):
    storage = f'sqlite:///{tmp_path / "study.db"}'
    args = [str(sim / 'bag'), '--matchers', 'plicp', '--trials', '2', '--seed', '1',
            '--storage', storage, '--study-name', 'resume', '--output',
            str(tmp_path / 't.yaml')]
    assert main(args) == 0 and main(args) == 0
    printed = capsys.readouterr()
    assert 'trial' not in printed.err  # progress lines only on a terminal
    rows = _table(printed.out)
    assert rows['plicp'][2] == '2' and rows['plicp'][5] == '4'  # this run 2, study 4
    trials = _study(storage, 'resume-plicp').trials
    assert [t.number for t in trials] == [0, 1, 2, 3]
    assert [t.number for t in trials if t.user_attrs.get('default')] == [0]
    # Its scores mean mean RPE on this bag: another objective may not join them.
    assert main(args + ['--objective', 'ate']) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith('laser_odom_tune: error: study resume-plicp was scored by rpe on '
                          'bag (100 scans), this run would score by ate on bag (100 scans)')
    assert '\n' not in err and len(_study(storage, 'resume-plicp').trials) == 4


def test_two_processes_share_one_sqlite_study(sim, tmp_path):
    storage = f'sqlite:///{tmp_path / "shared.db"}'
    commands = [[sys.executable, '-m', 'laser_odom.tools.tune', str(sim / 'bag'),
                 '--matchers', 'plicp', '--trials', '3', '--seed', str(seed), '--storage',
                 storage, '--study-name', 'S', '--output', str(tmp_path / f'{seed}.yaml'),
                 '--quiet'] for seed in (1, 2)]
    processes = [subprocess.Popen(c, cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                                  text=True) for c in commands]
    for process in processes:
        _, err = process.communicate(timeout=120)
        assert process.returncode == 0, err
    trials = _study(storage, 'S-plicp').trials
    assert len(trials) == 6
    workers = {t.user_attrs['worker'] for t in trials}
    assert {str(p.pid) for p in processes} == {w.rsplit(':', 1)[1] for w in workers}


def test_jobs_run_the_queued_start_in_this_process_so_no_two_workers_take_it(sim, tmp_path):
    """Run trial 0 here: SQLite cannot give one queued trial to just one of two processes."""
    storage = f'sqlite:///{tmp_path / "jobs.db"}'
    assert main([str(sim / 'bag'), '--matchers', 'plicp', '--trials', '3', '--jobs', '2',
                 '--seed', '1', '--storage', storage, '--study-name', 'J', '--output',
                 str(tmp_path / 't.yaml'), '--quiet']) == 0
    trials = _study(storage, 'J-plicp').trials
    assert [t.state.name for t in trials] == ['COMPLETE'] * 3
    defaults = [t for t in trials if t.user_attrs.get('default')]
    assert len(defaults) == 1 and defaults[0].number == 0
    assert defaults[0].user_attrs['worker'].rsplit(':', 1)[1] == str(os.getpid())
    others = {t.user_attrs['worker'] for t in trials[1:]}
    assert len(others) == 2 and str(os.getpid()) not in {w.rsplit(':', 1)[1] for w in others}


def test_jobs_run_parallel_processes_on_a_temporary_storage(sim, tmp_path, capsys,
                                                            monkeypatch):
    made = []
    real_mkdtemp = tune_module.tempfile.mkdtemp

    def mkdtemp(*args, **kwargs) -> str:
        if kwargs.get('prefix') != 'laser_odom_tune.':  # not the storage's
            return real_mkdtemp(*args, **kwargs)
        made.append(tmp_path / 'laser_odom_tune.study')
        made[-1].mkdir()
        return str(made[-1])
    monkeypatch.setattr(tune_module.tempfile, 'mkdtemp', mkdtemp)
    assert main([str(sim / 'bag'), '--matchers', 'nicp', '--trials', '2', '--jobs', '2',
                 '--seed', '1', '--output', str(tmp_path / 't.yaml'), '--quiet']) == 0
    rows = _table(capsys.readouterr().out)
    assert rows['nicp'][2] == '2' and float(rows['nicp'][1]) <= float(rows['nicp'][0])
    assert len(made) == 1 and not made[0].exists()  # the temporary storage is gone


def test_progress_lines_only_on_a_terminal(sim, tmp_path, capsys, monkeypatch):
    monkeypatch.setattr(sys.stderr, 'isatty', lambda: True)
    assert main([str(sim / 'bag'), '--matchers', 'plicp', '--trials', '2', '--output',
                 str(tmp_path / 't.yaml')]) == 0
    err = capsys.readouterr().err
    assert 'plicp trial 1/2' in err and 'plicp trial 2/2' in err and 'best so far' in err


def test_reference_free_and_plot_are_wired_to_their_modules(sim, tmp_path, capsys,
                                                            monkeypatch):
    calls = {}

    def score(stamps_ns, poses, points, odometry=None, odom_weight=0.0):
        calls['score'] = (len(stamps_ns), poses.shape, len(points), odometry, odom_weight)
        return float(np.abs(np.diff(poses[:, 2])).sum())  # any deterministic score

    def plot_study(path, studies, best, reference):
        calls['plot'] = (studies, best, reference)
        Path(path).write_bytes(b'png')
    monkeypatch.setitem(sys.modules, 'laser_odom.core.evaluation.map_quality',
                        types.SimpleNamespace(reference_free_score=score))
    monkeypatch.setattr(laser_odom.tools, 'plots', types.SimpleNamespace(
        plot_study=plot_study, PlotError=RuntimeError), raising=False)
    monkeypatch.setitem(sys.modules, 'laser_odom.tools.plots', laser_odom.tools.plots)
    png = tmp_path / 'study.png'
    assert main([str(sim / 'bag'), '--matchers', 'nicp', '--trials', '2', '--reference-free',
                 '--odom-agreement', '0.5', '--plot', str(png), '--output',
                 str(tmp_path / 't.yaml'), '--quiet']) == 0
    assert 'reference-free' in capsys.readouterr().out
    count, shape, points, odometry, weight = calls['score']
    assert shape == (count, 3) and points == count and weight == 0.5
    assert len(odometry) > count  # the bag's /odom, at its own rate
    studies, best, reference = calls['plot']
    assert [n for n, _ in studies['nicp']] == [0, 1]
    stamps, poses = best['nicp']
    assert poses.shape == (len(stamps), 3) and len(stamps) >= 90
    assert reference[1].shape == (100, 3) and png.read_bytes() == b'png'


def test_plot_writes_a_png_with_content(sim, tmp_path):
    pytest.importorskip('laser_odom.tools.plots')
    image = pytest.importorskip('matplotlib.image')
    png = tmp_path / 'study.png'
    assert main([str(sim / 'bag'), '--matchers', 'plicp', '--trials', '2', '--plot',
                 str(png), '--output', str(tmp_path / 't.yaml'), '--quiet']) == 0
    pixels = image.imread(png)
    assert pixels.shape[0] >= 200 and pixels.shape[1] >= 200
    assert float(np.std(pixels[..., :3])) > 0.01  # not blank


def _bad_inputs(sim: Path, tmp_path: Path) -> dict[str, tuple[list[str], str]]:
    """Return bad command lines and a fragment of their error line."""
    far = tmp_path / 'far.tum'
    reference = load_bag(str(sim / 'bag'), None, None, '/odom').reference
    write_tum(far, type(reference)(reference.stamps_ns + 10 ** 12, reference.poses))
    half = tmp_path / 'half.tum'
    write_tum(half, type(reference)(reference.stamps_ns[:40], reference.poses[:40]))
    empty = tmp_path / 'space.yaml'
    empty.write_text('nicp.max_iterations: [50, 10]\n')
    no_scans = tmp_path / 'no_scans'
    write_bag(no_scans, odometry={'/odom': reference})
    crossed = tmp_path / 'crossed.yaml'
    crossed.write_text('/**:\n  ros__parameters:\n    nicp:\n      normal_neighbours: 6\n'
                       '      normal_min_neighbours: 7\n')
    other = tmp_path / 'other.yaml'
    other.write_text('front_odom:\n  ros__parameters:\n    matcher: icp\n')
    unreachable = tmp_path / 'unreachable.yaml'
    unreachable.write_text('nicp.normal_min_neighbours: [10, 20]\n'
                           'nicp.normal_neighbours: [3, 8]\n')
    bag = str(sim / 'bag')
    return {
        'no scans': ([str(no_scans)], 'no LaserScan topic'),
        'no overlap': ([bag, '--reference', str(far)], 'does not overlap'),
        'little overlap': ([bag, '--reference', str(half)],
                           'it covers only 39 % of the run in time (40 of 100 poses'),
        'odom topic': ([bag, '--odom-topic', 'odm'], 'no topic /odm in the bag'),
        'empty range': ([bag, '--space', str(empty)], 'empty range'),
        'postgres': ([bag, '--storage', 'postgresql://nobody@127.0.0.1:1/x'],
                     'cannot open storage'),
        'sqlite dir': ([bag, '--storage', f'sqlite:///{tmp_path}/missing/x.db'],
                       'cannot open storage'),
        'matcher': ([bag, '--matchers', 'nicp,sift'], "unknown matcher 'sift'"),
        'crossed pair': ([bag, '--params-file', str(crossed)],
                         'nicp.normal_min_neighbours=7 must not exceed nicp.normal_neighbours=6'),
        'no section': ([bag, '--params-file', str(other)],
                       f'params file {other} has no section for /laser_odom (it has front_odom):'
                       ' none of its parameters apply, so nothing would be run with it'),
        'no ordered value': ([bag, '--matchers', 'nicp', '--space', str(unreachable)],
                             'nicp.normal_min_neighbours <= nicp.normal_neighbours'),
    }


def test_bad_input_is_one_line_and_exit_2(sim, tmp_path, capsys, monkeypatch):
    for name, (args, fragment) in _bad_inputs(sim, tmp_path).items():
        code = main(args + ['--trials', '1', '--output', str(tmp_path / 't.yaml')])
        err = capsys.readouterr().err.strip()
        assert code == 2 and fragment in err and '\n' not in err, (name, err)
    monkeypatch.setitem(sys.modules, 'optuna', None)  # as if not installed
    assert main([str(sim / 'bag')]) == 2
    assert capsys.readouterr().err.strip() == (
        'laser_odom_tune: error: laser_odom_tune needs optuna: pip install optuna')


def test_a_keyframe_reference_spanning_the_bag_is_accepted(sim, tmp_path, capsys):
    """A reference on every third scan (MIT CSAIL's pairs with 35 %) covers the bag in time."""
    reference = load_bag(str(sim / 'bag'), None, None, '/odom').reference
    keyframes = tmp_path / 'keyframes.tum'
    write_tum(keyframes, type(reference)(reference.stamps_ns[::3], reference.poses[::3]))
    assert main([str(sim / 'bag'), '--reference', str(keyframes), '--matchers', 'plicp',
                 '--trials', '1', '--output', str(tmp_path / 't.yaml'), '--quiet']) == 0
    rows = _table(capsys.readouterr().out)
    assert 0.0 < float(rows['plicp'][0]) < 0.01  # scored against the keyframes (RPE)


@pytest.fixture(scope='module')
def good_odom(tmp_path_factory):
    """Return a 10 s simulated bag whose wheel odometry beats the laser's RPE.

    Odometry at a fifth of the simulator's default noise: over 10 s its RPE (0.0007)
    is below nicp's (0.0016), so a trial that rejects every match - and so follows the
    odometry (prior: odom, rejected_motion: predict) - scores better than the laser.
    """
    folder = tmp_path_factory.mktemp('tune_odom')
    data = simulate('office', duration=10.0, seed=1,
                    odometry_noise=OdometryNoise().scaled(0.2))
    write_bag(folder / 'bag', data.scans,
              odometry={'/ground_truth': data.reference, '/odom': data.odometry})
    return folder


def test_a_trial_whose_matches_are_rejected_fails_with_its_counts(good_odom):
    bag = load_bag(str(good_odom / 'bag'), None, None, '/odom')
    laser = run_trial({'matcher': 'nicp', 'prior': 'odom'}, [bag], 'rpe')
    assert laser.error is None and laser.counts[0]['matched'] == 99
    # One iteration never converges: 93 of 99 matches rejected, the odometry takes over.
    prior_only = run_trial({'matcher': 'nicp', 'prior': 'odom', 'nicp.max_iterations': 1},
                           [bag], 'rpe')
    assert prior_only.score == FAILED_TRIAL_SCORE
    assert prior_only.counts[0]['rejected_not_converged'] > 90
    assert prior_only.error.startswith('laser matches rejected on ')
    assert 'its trajectory is the motion prior, not the laser' in prior_only.error


def test_a_tune_never_recommends_a_run_of_the_prior_alone(good_odom, tmp_path, capsys):
    """Issue 39: the best of 6 trials was the wheel odometry, every match rejected."""
    space = tmp_path / 'space.yaml'
    space.write_text('prior: [odom]\nnicp.max_iterations: [1, 1]\n')  # the laser switched off
    out = tmp_path / 'tuned.yaml'
    assert main([str(good_odom / 'bag'), '--matchers', 'nicp', '--trials', '6', '--seed', '3',
                 '--space', str(space), '--output', str(out), '--quiet']) == 0
    printed = capsys.readouterr().out
    default, best, trials, pruned, failed = _table(printed)['nicp'][:5]
    # Only the default trial (40 iterations) ran on the laser in full: it is the best.
    # With one iteration most trials fail (their matches rejected, or none constraining
    # every direction); one whose global search ran on every scan may still match.
    assert float(best) == float(default) and 0.0 < float(best) < 0.01
    assert int(failed) + int(pruned) >= 4 and int(failed) >= 1
    assert 'nicp.max_iterations' not in read_params_files([out]).values
    lines = printed.splitlines()
    failure = next(line for line in lines if line.startswith('nicp: '))
    assert 'trials failed, first trial ' in failure and 'rejected_not_converged' in failure
    assert 'best run on bag: processed 100, matched 99, degenerate 0, failed (rejected) 0' \
        in lines


def test_nothing_is_recommended_when_every_trial_fails(good_odom, tmp_path, capsys):
    space = tmp_path / 'space.yaml'
    space.write_text('prior: [odom]\nnicp.max_iterations: [1, 1]\n')
    start = tmp_path / 'start.yaml'
    start.write_text('/**:\n  ros__parameters:\n    prior: odom\n    nicp:\n'
                     '      max_iterations: 1\n')
    out = tmp_path / 'tuned.yaml'
    assert main([str(good_odom / 'bag'), '--matchers', 'nicp', '--trials', '2', '--seed', '3',
                 '--space', str(space), '--params-file', str(start), '--output', str(out),
                 '--quiet']) == 1
    err = capsys.readouterr().err
    assert err == (f'laser_odom_tune: error: no trial of nicp ran on the laser (see the '
                   f'failures above); nothing written to {out}\n')
    assert not out.exists()


def test_the_tuned_file_scores_against_the_start_file_it_began_from(good_odom, tmp_path, capsys):
    """Trial 0 ran the --params-file: the file's comments call its score the start's.

    The summary said ``(start 0.0014628)`` and the written file ``(defaults 0.0014628)``
    of the same number (the new-user trial of issue 39).
    """
    start = tmp_path / 'start.yaml'
    start.write_text('/**:\n  ros__parameters:\n    prior: odom\n    max_scan_gap: 2.0\n')
    out = tmp_path / 'tuned.yaml'
    assert main([str(good_odom / 'bag'), '--matchers', 'nicp', '--trials', '1',
                 '--params-file', str(start), '--output', str(out), '--quiet']) == 0
    printed = capsys.readouterr().out
    score = re.search(r'\(start ([0-9.e-]+)\); wrote', printed).group(1)
    text = out.read_text()
    assert f'(start {score})' in text and '(defaults ' not in text
    assert read_params_files([out]).values['max_scan_gap'] == 2.0


def test_a_run_of_degenerate_and_rejected_matches_is_not_the_lasers():
    """Degenerate matches take the prediction where the scan is blind: none fully the laser's."""
    counts = {'processed': 100, 'matched': 0, 'degenerate': 60, 'rejected': 39}
    why = laser_failure(counts, 'bag')
    assert why.startswith('laser matches constrained every direction on only 0 of 99 scans')
    assert laser_failure({**counts, 'matched': 20, 'degenerate': 40}, 'bag') is None
    assert laser_failure({**counts, 'matched': 40, 'degenerate': 0, 'rejected': 59},
                         'bag').startswith('laser matches rejected on 59 of 99 scans')


def test_a_trial_another_process_reported_first_is_replaced_not_a_traceback():
    """Optuna issue 4621: two processes on one new SQLite study may take one queued trial."""
    from laser_odom.core.tuning.study import _optimize

    class Study:
        def __init__(self, refusals):
            self.refusals, self.ran = refusals, 0

        def optimize(self, objective, n_trials, catch, callbacks):
            assert n_trials == 1
            if self.refusals:
                self.refusals -= 1
                raise ValueError('Cannot tell a COMPLETE trial.')
            self.ran += 1

    study = Study(refusals=1)
    _optimize(study, lambda trial: 0.0, 3, [])
    assert study.ran == 3
    broken = Study(refusals=0)
    broken.optimize = lambda *args, **kwargs: (_ for _ in ()).throw(ValueError('other'))
    with pytest.raises(ValueError, match='other'):
        _optimize(broken, lambda trial: 0.0, 3, [])
