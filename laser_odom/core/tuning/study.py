"""The Optuna side of ``laser_odom_tune``: storage, one study per matcher, workers, summary.

Every matcher has its own study, ``<study name>-<matcher>``, minimised with a seeded
TPE sampler and a median pruner (a trial whose score after the first bag - or the
first half of a single bag - is worse than the median of earlier trials at that point
is stopped). A new study starts with the starting values enqueued as trial 0, marked
``default``: the best is then never worse than the defaults, and the summary can
print both. A study in a shared storage (``sqlite:///study.db``, PostgreSQL) is
resumed by name, and several processes - on one machine (``--jobs``) or many - add
trials to it at once. Optuna is imported only here and only when a study runs.
"""

from __future__ import annotations

from dataclasses import dataclass, field
import math
import multiprocessing
import os
import socket
import sys
import time
from typing import Any, Callable, Sequence

from laser_odom.core.trajectory import RecordedBag
from laser_odom.core.tuning.objective import FAILED_TRIAL_SCORE, run_trial
from laser_odom.core.tuning.space import Dimension, start_values, suggest

MEDIAN_PRUNER_STARTUP = 5
"""Trials that run to the end before the median pruner stops any (a median needs them)."""

OPEN_ATTEMPTS = 3
"""Tries to open a storage before its error counts (see :func:`open_storage`)."""

SQLITE_TIMEOUT = 60.0
"""Seconds a process waits for another's write lock on a shared sqlite storage."""


class StorageError(ValueError):
    """The storage URL cannot be opened; ``str(error)`` is one line."""


class StudyMismatchError(ValueError):
    """A resumed study was scored on other bags or by another objective (one line)."""


@dataclass
class TuneJob:
    """Everything a worker process needs: picklable, the bags as a loader to call."""

    load_bags: Callable[[], list[RecordedBag]]
    spaces: dict[str, list[Dimension]]
    """Per matcher, its search space."""
    base: dict[str, Any]
    """Values of every trial that the space does not set (a ``--params-file``)."""
    objective: str
    odom_weight: float
    study_name: str
    storage_url: str | None
    seed: int | None
    progress: bool
    definition: dict[str, Any] = field(default_factory=dict)
    """What a score means - objective, bags, starting values (JSON types): a study
    resumed with another definition would rank incomparable scores."""


@dataclass
class StudySummary:
    """One matcher's study after this run: default and best score, counts, wall time."""

    matcher: str
    default: float
    best: float
    best_values: dict[str, Any]
    trials: int
    total: int
    pruned: int
    failed: int
    wall: float
    best_counts: list[dict[str, int]] = field(default_factory=list)
    """The best trial's counts per bag (processed, matched, rejected...)."""
    failure: str | None = None
    """Why this run's first failed trial failed (``trial N: reason``), None if none did."""


def study_name(job: TuneJob, matcher: str) -> str:
    """Return the name of a matcher's study in the storage."""
    return f'{job.study_name}-{matcher}'


def _hide_password(url: str) -> str:
    """Return ``url`` without a password (``user:secret@`` -> ``user:***@``)."""
    head, sep, tail = url.partition('://')
    if sep and '@' in tail.split('/', 1)[0] and ':' in tail.split('@', 1)[0]:
        user = tail.split('@', 1)[0].split(':', 1)[0]
        return f'{head}://{user}:***@{tail.split("@", 1)[1]}'
    return url


def open_storage(url: str | None) -> Any:
    """Return the Optuna storage of ``url`` (None: in memory); raise :class:`StorageError`.

    Processes that start a new study at once race to create its tables; the loser's
    error goes away on a second try, so an error counts after :data:`OPEN_ATTEMPTS`.
    """
    import optuna
    optuna.logging.set_verbosity(optuna.logging.WARNING)  # the tool says what happened
    if url is None:
        return optuna.storages.InMemoryStorage()
    kwargs = {'connect_args': {'timeout': SQLITE_TIMEOUT}} if url.startswith('sqlite') else {}
    error: Exception = RuntimeError('not opened')
    for attempt in range(OPEN_ATTEMPTS):
        try:
            return optuna.storages.RDBStorage(url, engine_kwargs=kwargs)
        except Exception as err:  # noqa: B902 - drivers, DNS, refusals, bad URLs alike
            error = err
            if isinstance(err, ImportError):  # e.g. PostgreSQL without psycopg
                break
            time.sleep(0.25 * (attempt + 1))
    reason = (str(error).strip().splitlines() or [type(error).__name__])[0]
    if isinstance(error, ImportError):
        dialect = url.partition(':')[0]
        hint = ('; pip install "psycopg[binary]" (or psycopg2-binary with a '
                'postgresql+psycopg2:// URL)' if dialect == 'postgresql' else '')
        reason = f'no database driver for {dialect} installed{hint}'
    raise StorageError(f'cannot open storage {_hide_password(url)}: {reason[:200]}')


def _sampler_and_pruner(seed: int | None) -> tuple[Any, Any]:
    """Return the TPE sampler (seeded) and the median pruner of every study."""
    import optuna
    return (optuna.samplers.TPESampler(seed=seed),
            optuna.pruners.MedianPruner(n_startup_trials=MEDIAN_PRUNER_STARTUP))


def prepare_studies(job: TuneJob, storage: Any) -> dict[str, int]:
    """Create (or load) each matcher's study; return how many trials each had before.

    A study without trials gets the starting values as trial 0, marked ``default``.
    """
    import optuna
    existing = {}
    for matcher, dimensions in job.spaces.items():
        name = study_name(job, matcher)
        study = optuna.create_study(storage=storage, study_name=name, direction='minimize',
                                    load_if_exists=True)
        existing[matcher] = len(study.trials)
        recorded = study.user_attrs.get('definition')
        if recorded is None:
            study.set_user_attr('definition', job.definition)
        elif recorded != job.definition:
            raise StudyMismatchError(
                f'study {name} was scored {describe_definition(recorded)}, this run would '
                f'score {describe_definition(job.definition)}: resume it with the same bags, '
                'objective and --params-file, or give another --study-name')
        if not study.trials:  # skip_if_exists: two processes that start a study at once
            study.enqueue_trial(start_values(dimensions), user_attrs={'default': True},
                                skip_if_exists=True)
    return existing


def describe_definition(definition: dict[str, Any]) -> str:
    """Return a study definition in a few words for a one-line message."""
    words = [f'by {definition.get("objective")}']
    if definition.get('odom_weight'):
        words.append(f'+ {definition["odom_weight"]:g} x odometry disagreement')
    words.append(f'on {", ".join(definition.get("bags", []))}')
    if definition.get('start'):
        words.append(f'from {len(definition["start"])} --params-file values')
    return ' '.join(words)


def _objective(job: TuneJob, matcher: str, bags: list[RecordedBag]) -> Callable[[Any], float]:
    """Return the Optuna objective of one matcher's study."""
    import optuna

    def objective(trial: Any) -> float:
        is_default = bool(trial.user_attrs.get('default'))
        values = {**job.base, **suggest(job.spaces[matcher], trial, default=is_default),
                  'matcher': matcher}

        def report(step: int, score: float) -> None:
            trial.report(score, step)
            if trial.should_prune():
                raise optuna.TrialPruned()

        trial.set_user_attr('worker', f'{socket.gethostname()}:{os.getpid()}')  # who ran it
        result = run_trial(values, bags, job.objective, job.odom_weight, report)
        trial.set_user_attr('bag_scores', result.bag_scores)
        trial.set_user_attr('counts', result.counts)
        if result.error is not None:
            trial.set_user_attr('error', result.error[:500])
        return result.score
    return objective


def _progress(matcher: str, before: int, total: int) -> Callable[[Any, Any], None]:
    """Return a callback printing ``trial k/N`` and the best so far on stderr."""
    def callback(study: Any, trial: Any) -> None:
        done = trial.state.name == 'COMPLETE'
        value = f'{trial.value:.5g}' if done else trial.state.name.lower()
        if trial.user_attrs.get('error'):
            value = f'failed ({trial.user_attrs["error"]})'
        try:
            best = f'{study.best_value:.5g}'
        except ValueError:
            best = '-'
        print(f'laser_odom_tune: {matcher} trial {trial.number - before + 1}/{total}: '
              f'{value}, best so far {best}', file=sys.stderr, flush=True)
    return callback


def run_worker(job: TuneJob, storage: Any, shares: dict[str, int], existing: dict[str, int],
               totals: dict[str, int], worker: int = 0) -> None:
    """Run this process's share of trials of every matcher's study, one after another."""
    import optuna
    optuna.logging.set_verbosity(optuna.logging.WARNING)  # also in --jobs processes
    bags = job.load_bags()
    for index, matcher in enumerate(job.spaces):
        seed = None if job.seed is None else (
            job.seed + 1009 * worker + 101 * index + existing[matcher])
        sampler, pruner = _sampler_and_pruner(seed)
        study = optuna.load_study(study_name=study_name(job, matcher), storage=storage,
                                  sampler=sampler, pruner=pruner)
        callbacks = ([_progress(matcher, existing[matcher], totals[matcher])]
                     if job.progress else [])
        _optimize(study, _objective(job, matcher, bags), shares[matcher], callbacks)


def _optimize(study: Any, objective: Callable[[Any], float], trials: int,
              callbacks: list[Callable[[Any, Any], None]]) -> None:
    """Run ``trials`` trials of ``study`` here, one at a time.

    Two tune processes started on one new SQLite study may both take its queued
    starting trial; the one that reports second is refused ("Cannot tell a COMPLETE
    trial": SQLite has no ``SELECT ... FOR UPDATE``, optuna issue 4621). That trial
    was the other process's: this one runs another in its place instead of stopping
    with a traceback.
    """
    done = taken = 0
    while done < trials and taken <= trials:
        try:
            study.optimize(objective, n_trials=1, catch=(Exception,), callbacks=callbacks)
        except ValueError as error:
            if 'Cannot tell a' not in str(error):
                raise
            taken += 1
            continue
        done += 1


def _worker_main(job: TuneJob, shares: dict[str, int], existing: dict[str, int],
                 totals: dict[str, int], worker: int) -> None:
    """Entry point of a ``--jobs`` process: open the shared storage and run its share."""
    run_worker(job, open_storage(job.storage_url), shares, existing, totals, worker)


def _waiting_trials(job: TuneJob, storage: Any, matcher: str) -> int:
    """Return how many queued trials a matcher's study holds."""
    import optuna
    from optuna.trial import TrialState
    study = optuna.load_study(study_name=study_name(job, matcher), storage=storage)
    return len(study.get_trials(deepcopy=False, states=(TrialState.WAITING,)))


def run_studies(job: TuneJob, storage: Any, trials: int, jobs: int) -> dict[str, int]:
    """Run ``trials`` more trials per matcher in ``jobs`` processes; return prior counts.

    With one job the trials run in this process (``storage`` may be in memory); with
    more, ``job.storage_url`` must name a storage every process can open. The queued
    starting values (trial 0 of a new study) run in this process before the others
    start: SQLite has no ``SELECT ... FOR UPDATE``, so two processes can both take one
    queued trial and the second fails to report it ("Cannot tell a COMPLETE trial",
    optuna issue 4621).
    """
    existing = prepare_studies(job, storage)
    totals = {matcher: trials for matcher in job.spaces}
    if jobs == 1:
        run_worker(job, storage, totals, existing, totals)
        return existing
    queued = {m: min(_waiting_trials(job, storage, m), trials) for m in job.spaces}
    if any(queued.values()):
        run_worker(job, storage, queued, existing, totals)
    remaining = {m: trials - queued[m] for m in job.spaces}
    context = multiprocessing.get_context('spawn')  # no inherited database connections
    processes = []
    for worker in range(jobs):
        shares = {m: remaining[m] // jobs + (worker < remaining[m] % jobs)
                  for m in job.spaces}
        process = context.Process(target=_worker_main, name=f'laser_odom_tune-{worker}',
                                  args=(job, shares, existing, totals, worker))
        process.start()
        processes.append(process)
    try:
        for process in processes:
            process.join()
    finally:
        for process in processes:
            if process.is_alive():
                process.terminate()
                process.join()
    failed = [p.name for p in processes if p.exitcode != 0]
    if failed:
        raise RuntimeError(f'worker process {", ".join(failed)} failed')
    return existing


def summarize(job: TuneJob, storage: Any, existing: dict[str, int]) -> list[StudySummary]:
    """Return each matcher's summary: default and best score, this run's counts and time."""
    import optuna
    from optuna.trial import TrialState
    summaries = []
    for matcher in job.spaces:
        study = optuna.load_study(study_name=study_name(job, matcher), storage=storage)
        trials = study.get_trials(deepcopy=False)
        done = [t for t in trials if t.state == TrialState.COMPLETE]
        default = next((t.value for t in done if t.user_attrs.get('default')), math.nan)
        usable = [t for t in done if t.value < FAILED_TRIAL_SCORE]
        best = min(usable, key=lambda t: t.value, default=None)  # never a failed trial
        new = [t for t in trials if t.number >= existing[matcher]]
        failure = next((f'trial {t.number}: {t.user_attrs["error"]}' for t in new
                        if t.user_attrs.get('error')), None)
        starts = [t.datetime_start for t in new if t.datetime_start is not None]
        ends = [t.datetime_complete for t in new if t.datetime_complete is not None]
        wall = (max(ends) - min(starts)).total_seconds() if starts and ends else 0.0
        best_values = {}
        if best is not None:
            best_values = {**job.base, **suggest_fixed(job.spaces[matcher], best),
                           'matcher': matcher}
        summaries.append(StudySummary(
            matcher, default, math.nan if best is None else best.value, best_values,
            len(new), len(trials), sum(t.state == TrialState.PRUNED for t in new),
            sum(t.state == TrialState.FAIL or (t.state == TrialState.COMPLETE and (
                t.value >= FAILED_TRIAL_SCORE)) for t in new), wall,
            [] if best is None else list(best.user_attrs.get('counts', [])), failure))
    return summaries


def suggest_fixed(dimensions: Sequence[Dimension], trial: Any) -> dict[str, Any]:
    """Return the values a finished trial ran with (its params, else the start values)."""
    return {d.name: trial.params.get(d.name, d.start) for d in dimensions}


def table_lines(summaries: Sequence[StudySummary], objective: str,
                start: str = 'default') -> list[str]:
    """Return the table of default vs best score per matcher, trials and wall time.

    ``start`` names trial 0's column: ``default``, or ``start`` for a ``--params-file``.
    """
    lines = [f'score: {objective.replace("_", "-")} (lower is better)',
             f'{"matcher":8} {start:>10} {"best":>10} {"trials":>7} {"pruned":>6} '
             f'{"failed":>6} {"total":>6} {"wall [s]":>9}']
    for s in summaries:
        lines.append(f'{s.matcher:8} {s.default:10.5g} {s.best:10.5g} {s.trials:7d} '
                     f'{s.pruned:6d} {s.failed:6d} {s.total:6d} {s.wall:9.1f}')
    return lines


def plot_data(job: TuneJob, storage: Any, bags: list[RecordedBag],
              summaries: Sequence[StudySummary]) -> tuple[dict, dict]:
    """Return what ``plot_study`` draws: the scores of the trials, the best runs.

    Per matcher, ``(number, score)`` of every finished trial, and the best values run
    again on ``bags`` as ``(stamps_ns, poses)``: a trial keeps its score, not its
    trajectory (it may have run on another machine).
    """
    import optuna
    from optuna.trial import TrialState
    studies, best = {}, {}
    for s in summaries:
        study = optuna.load_study(study_name=study_name(job, s.matcher), storage=storage)
        studies[s.matcher] = [(t.number, t.value) for t in study.get_trials(
            deepcopy=False, states=(TrialState.COMPLETE,))]
        if s.best_values:
            run = run_trial(s.best_values, bags, job.objective, job.odom_weight,
                            keep_trajectories=True)
            if run.trajectories:
                best[s.matcher] = (run.trajectories[0].stamps_ns, run.trajectories[0].poses)
    return studies, best
