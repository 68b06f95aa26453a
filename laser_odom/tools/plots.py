"""Headless plots of the tools (matplotlib, Agg backend, PNG files).

``laser_odom_replay --plot`` draws the map that the scans make at the estimated poses
with the trajectory (and the reference, SE(2)-aligned as for the ATE) over it, and the
error over time (:func:`plot_replay`); ``laser_odom_tune --plot`` draws the score of
every trial and the best trajectory per matcher (:func:`plot_study`).

matplotlib serves these plots only: it is imported inside the functions, so the
package imports and the node runs without it, and a tool that lacks it says so in one
line (:class:`PlotError`).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, Sequence

import numpy as np

from laser_odom.core import se2
from laser_odom.core.evaluation.metrics import associate, evaluate, TrajectoryErrors
from laser_odom.core.trajectory import Trajectory

MISSING_MATPLOTLIB = '--plot needs matplotlib: pip install matplotlib'
"""The one-line error of a tool asked to plot without matplotlib."""

MAP_POINTS = 200_000
"""Most map points drawn: the scans' points are subsampled evenly down to this."""

FIGURE_SIZE = (15.0, 6.5)
"""Figure size [in]; at :data:`DPI` a 1500 x 650 px PNG."""

DPI = 100

TrajectoryArrays = tuple[np.ndarray, np.ndarray]
"""``(stamps_ns (N,), poses (N, 3))`` of a trajectory."""


class PlotError(Exception):
    """A plot cannot be drawn (matplotlib missing, no such directory); one line."""


def _pyplot_free_figure() -> Any:
    """Return a new matplotlib ``Figure`` on the Agg backend; PlotError without matplotlib."""
    try:
        import matplotlib
    except ImportError:
        raise PlotError(MISSING_MATPLOTLIB) from None
    matplotlib.use('Agg')
    from matplotlib.figure import Figure
    return Figure(figsize=FIGURE_SIZE, dpi=DPI, layout='constrained')


def check_plot_output(path: str | Path) -> None:
    """Fail before a long run: matplotlib missing, or the PNG's directory missing."""
    try:
        import matplotlib  # noqa: F401 - only whether it imports
    except ImportError:
        raise PlotError(MISSING_MATPLOTLIB) from None
    parent = Path(path).parent
    if not parent.is_dir():
        raise PlotError(f'directory {parent} does not exist (for {path})')


def _save(fig: Any, path: str | Path) -> None:
    """Write the figure as a PNG; PlotError (one line) when it cannot be written."""
    try:
        fig.savefig(Path(path), dpi=DPI, format='png')
    except OSError as err:
        raise PlotError(f'cannot write {path}: {err.strerror or err}') from None


class ScanPointsRecorder:
    """The base-frame points of every estimate, thinned evenly to stay under a budget.

    One array per estimate (empty when it had none), so the list lines up with the
    poses; when the points kept exceed ``budget`` every array is halved and later
    scans are taken at the doubled stride, so a long bag costs bounded memory.
    """

    def __init__(self, budget: int = 2 * MAP_POINTS) -> None:
        """Start empty, keeping every point until ``budget`` points are held."""
        self.points: list[np.ndarray] = []
        self.budget = budget
        self.stride = 1
        self.count = 0

    def add(self, points: np.ndarray | None) -> None:
        """Keep the points of the next estimate (None: it has none)."""
        kept = (np.zeros((0, 2), dtype=np.float32) if points is None else
                np.asarray(points, dtype=float).reshape(-1, 2)[::self.stride]
                .astype(np.float32))
        self.points.append(kept)
        self.count += len(kept)
        if self.count > self.budget:
            self.points = [p[::2].copy() for p in self.points]
            self.stride *= 2
            self.count = sum(len(p) for p in self.points)


def map_points(poses: np.ndarray, points: Sequence[np.ndarray],
               limit: int = MAP_POINTS) -> np.ndarray:
    """Return the points (M, 2) of every pose's scan at that pose, at most ``limit``."""
    clouds = [se2.transform_points(pose, np.asarray(cloud, dtype=float).reshape(-1, 2))
              for pose, cloud in zip(poses, points) if cloud is not None and len(cloud)
              and se2.is_finite_pose(pose)]
    if not clouds:
        return np.zeros((0, 2))
    cloud = np.vstack(clouds)
    stride = -(-len(cloud) // limit)
    return cloud[::stride]


def _pose_errors(estimate: Trajectory, reference: Trajectory,
                 errors: TrajectoryErrors | None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Return the alignment, the paired estimate stamps and their position errors [m].

    The alignment is the ATE's (:func:`laser_odom.core.evaluation.metrics.evaluate`); each
    estimate is compared with the reference interpolated to its stamp.
    """
    alignment = errors.alignment if errors is not None else evaluate(
        estimate, reference).alignment
    ref_index, est_index = associate(estimate, reference)
    order = np.argsort(est_index, kind='stable')
    ref_index, est_index = ref_index[order], est_index[order]
    stamps = estimate.stamps_ns[est_index]
    truth = reference.poses[ref_index, :2].copy()
    for i in np.flatnonzero(reference.stamps_ns[ref_index] != stamps):
        interpolated = reference.interpolate(int(stamps[i]))
        if interpolated is not None:
            truth[i] = interpolated[:2]
    aligned = se2.transform_points(alignment, estimate.poses[est_index, :2])
    return alignment, stamps, np.hypot(*(aligned - truth).T)


def _seconds(stamps_ns: np.ndarray, start_ns: int) -> np.ndarray:
    """Return stamps as seconds since ``start_ns``."""
    return (np.asarray(stamps_ns, dtype=np.int64) - start_ns) * 1e-9


def _draw_map(ax: Any, estimate: Trajectory, points: Sequence[np.ndarray] | None) -> None:
    """Draw the map points and the estimated trajectory (equal aspect)."""
    cloud = map_points(estimate.poses, points) if points else np.zeros((0, 2))
    if len(cloud):
        ax.scatter(cloud[:, 0], cloud[:, 1], s=1.0, c='0.55', marker='.', linewidths=0,
                   rasterized=True)
        ax.plot([], [], '.', color='0.55', ms=6,  # a legend entry of a visible size
                label=f'scans at the estimated poses ({len(cloud)} points)')
    ax.plot(estimate.poses[:, 0], estimate.poses[:, 1], color='tab:blue', lw=1.3,
            label='estimate')
    if len(estimate):
        ax.plot(*estimate.poses[0, :2], 'o', color='tab:blue', ms=5, label='start')
    ax.set_xlabel('x [m] (odom frame)')
    ax.set_ylabel('y [m]')
    ax.set_aspect('equal', adjustable='datalim')
    ax.grid(True, lw=0.3)


def _draw_reference(ax: Any, reference: Trajectory, alignment: np.ndarray) -> None:
    """Draw the reference in the estimate's frame (the ATE alignment, inverted)."""
    shown = se2.transform_points(se2.inverse(alignment), reference.poses[:, :2])
    ax.plot(shown[:, 0], shown[:, 1], '--', color='tab:orange', lw=1.1,
            label='reference (SE(2)-aligned)')


def _draw_rotation_steps(ax: Any, estimate: Trajectory) -> None:
    """Draw the estimate's rotation per step [deg] over time (no reference)."""
    start = int(estimate.stamps_ns[0]) if len(estimate) else 0
    steps = np.degrees(np.abs(se2.wrap_angle(np.diff(estimate.poses[:, 2]))))
    ax.plot(_seconds(estimate.stamps_ns[1:], start), steps, color='tab:blue', lw=0.8)
    ax.set_ylabel('rotation per step [deg]')
    ax.set_title('rotation of the estimate between scans (no reference)')


def _draw_errors(ax: Any, estimate: Trajectory, stamps: np.ndarray,
                 position_error: np.ndarray) -> None:
    """Draw the position error after alignment [m] over time."""
    start = int(estimate.stamps_ns[0])
    ax.plot(_seconds(stamps, start), position_error, color='tab:red', lw=0.9)
    rms = float(np.sqrt(np.mean(np.square(position_error)))) if len(stamps) else 0.0
    ax.set_ylabel('translation error after SE(2) alignment [m]')
    ax.set_title(f'position error against the reference (ATE {rms:.3f} m RMS, '
                 f'{len(stamps)} poses)')


def plot_replay(path: str | Path, stamps_ns: np.ndarray, poses: np.ndarray,
                points: Sequence[np.ndarray] | None, reference: TrajectoryArrays | None = None,
                errors: TrajectoryErrors | None = None) -> None:
    """Write a PNG: the map and trajectories (left), the error over time (right).

    ``points`` holds each pose's scan points in the base frame (None or empty: the
    trajectory only, as after ``--live``); ``reference`` is ``(stamps_ns, poses)``,
    aligned to the estimate with the ATE's SE(2) alignment - that of ``errors`` (the
    result of :func:`laser_odom.core.evaluation.metrics.evaluate`) when given. Without a
    reference, or one that pairs with no estimate, the right panel shows the
    estimate's rotation per step.
    """
    fig = _pyplot_free_figure()
    left, right = fig.subplots(1, 2, gridspec_kw={'width_ratios': [1.15, 1.0]})
    estimate = Trajectory(stamps_ns, poses)
    _draw_map(left, estimate, points)
    compared = _compare(estimate, reference, errors)
    if compared is not None:
        truth, (alignment, stamps, position_error) = compared
        _draw_reference(left, truth, alignment)
        _draw_errors(right, estimate, stamps, position_error)
    else:
        _draw_rotation_steps(right, estimate)
    left.set_title(f'trajectory over the map ({len(estimate)} poses)'
                   + ('' if points else '; no scan points'))
    left.legend(loc='upper right', fontsize=8, framealpha=0.85)  # 'best' scans every point
    right.set_xlabel('time since the first scan [s]')
    right.grid(True, lw=0.3)
    _save(fig, path)


def _compare(estimate: Trajectory, reference: TrajectoryArrays | None,
             errors: TrajectoryErrors | None
             ) -> tuple[Trajectory, tuple[np.ndarray, np.ndarray, np.ndarray]] | None:
    """Return the reference and the estimate's errors against it; None when not comparable."""
    if reference is None or len(estimate) == 0:
        return None
    truth = Trajectory(*reference)
    if len(associate(estimate, truth)[0]) == 0:
        return None
    return truth, _pose_errors(estimate, truth, errors)


def _draw_scores(ax: Any, studies: dict[str, list[tuple[int, float]]],
                 colours: dict[str, Any]) -> None:
    """Draw every trial's score and the running best per matcher.

    Scores span decades (a failed trial scores a large penalty), so the axis is
    logarithmic when every score is positive; trial numbers are whole.
    """
    from matplotlib.ticker import MaxNLocator
    positive = True
    for matcher, trials in studies.items():
        finite = sorted((n, v) for n, v in trials if v is not None and np.isfinite(v))
        if not finite:
            continue
        numbers, scores = np.array(finite, dtype=float).T
        positive = positive and bool(np.all(scores > 0.0))
        ax.plot(numbers, scores, '.', color=colours[matcher], ms=5, alpha=0.6,
                label=f'{matcher} trials')
        ax.step(numbers, np.minimum.accumulate(scores), where='post', color=colours[matcher],
                lw=1.5, label=f'{matcher} best so far')
    if positive and any(studies.values()):
        ax.set_yscale('log')
    ax.xaxis.set_major_locator(MaxNLocator(integer=True))
    ax.set_xlabel('trial number')
    ax.set_ylabel('score (lower is better)')
    ax.set_title('score of the trials')
    ax.grid(True, lw=0.3)
    ax.legend(loc='best', fontsize=8)


def _draw_best(ax: Any, best: dict[str, TrajectoryArrays], reference: TrajectoryArrays | None,
               colours: dict[str, Any]) -> None:
    """Draw each matcher's best trajectory, SE(2)-aligned to the reference when given."""
    truth = Trajectory(*reference) if reference is not None else None
    if truth is not None:
        ax.plot(truth.poses[:, 0], truth.poses[:, 1], '--', color='black', lw=1.2,
                label='reference')
    for matcher, arrays in best.items():
        run = Trajectory(*arrays)
        xy = run.poses[:, :2]
        if truth is not None and len(associate(run, truth)[0]):
            xy = se2.transform_points(evaluate(run, truth).alignment, xy)
        ax.plot(xy[:, 0], xy[:, 1], color=colours[matcher], lw=1.2, label=f'{matcher} best')
    ax.set_xlabel('x [m]' + (' (reference frame)' if truth is not None else ''))
    ax.set_ylabel('y [m]')
    ax.set_title('best trajectory per matcher'
                 + (' (SE(2)-aligned to the reference)' if truth is not None else ''))
    ax.set_aspect('equal', adjustable='datalim')
    ax.grid(True, lw=0.3)
    ax.legend(loc='upper right', fontsize=8, framealpha=0.85)


def plot_study(path: str | Path, studies: dict[str, list[tuple[int, float]]],
               best: dict[str, TrajectoryArrays],
               reference: TrajectoryArrays | None = None) -> None:
    """Write a PNG: trial scores per matcher (left), best trajectories (right).

    ``studies`` maps a matcher to its finished trials ``(number, score)``; ``best``
    maps a matcher to its best run's ``(stamps_ns, poses)``; ``reference`` is
    ``(stamps_ns, poses)`` or None.
    """
    fig = _pyplot_free_figure()
    left, right = fig.subplots(1, 2)
    names = list(dict.fromkeys([*studies, *best]))
    colours = {name: f'C{i % 10}' for i, name in enumerate(names)}
    _draw_scores(left, studies, colours)
    _draw_best(right, best, reference, colours)
    _save(fig, path)
