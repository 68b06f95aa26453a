"""Plots of the tools: ``laser_odom_replay --plot`` and the tuner's study plot (PNG files)."""

import math
from pathlib import Path
import sys

import numpy as np
import pytest

from laser_odom.core import se2
from laser_odom.tools import plots, replay, simulate

pytest.importorskip('matplotlib')


def _image(path: Path) -> np.ndarray:
    """Return the PNG's pixels (H, W, channels) as floats in [0, 1]."""
    from matplotlib.image import imread
    return np.asarray(imread(str(path)), dtype=float)


def _assert_drawn(path: Path) -> None:
    """Check the PNG: at least 800 x 400 px, not blank, more than one colour."""
    assert path.is_file() and path.stat().st_size > 10_000
    pixels = _image(path)
    height, width = pixels.shape[:2]
    assert width >= 800 and height >= 400, pixels.shape
    assert pixels[..., :3].std() > 0.05
    rgb = (pixels[..., :3] * 255).round().astype(np.uint32).reshape(-1, 3)
    assert len(np.unique(rgb[:, 0] << 16 | rgb[:, 1] << 8 | rgb[:, 2])) > 10


def _circle(count: int, radius: float = 3.0) -> tuple[np.ndarray, np.ndarray]:
    """Return stamps [ns] and poses of a drive once around a circle."""
    angle = np.linspace(0.0, 2.0 * math.pi, count)
    poses = np.column_stack((radius * np.sin(angle), radius * (1.0 - np.cos(angle)),
                             se2.wrap_angle(angle)))
    return np.arange(count, dtype=np.int64) * 100_000_000 + 10**18, poses


def _room_scan(pose: np.ndarray) -> np.ndarray:
    """Return the walls of a 10 x 10 m room seen from ``pose``, in its frame."""
    side = np.linspace(-5.0, 5.0, 80)
    walls = np.vstack([np.column_stack((side, np.full_like(side, y))) for y in (-2.0, 8.0)]
                      + [np.column_stack((np.full_like(side, x), side + 3.0))
                         for x in (-5.0, 5.0)])
    return se2.transform_points(se2.inverse(pose), walls)


def test_plot_replay_draws_map_trajectories_and_errors(tmp_path):
    stamps, truth = _circle(120)
    drift = truth.copy()
    drift[:, :2] += np.linspace(0.0, 0.4, len(truth))[:, None]
    points = [_room_scan(pose) for pose in drift]
    offset = se2.pose(2.0, -1.0, 0.5)  # the reference in another frame: aligned for the plot
    reference = np.array([se2.compose(offset, pose) for pose in truth])
    with_reference, without = tmp_path / 'ref.png', tmp_path / 'noref.png'
    plots.plot_replay(with_reference, stamps, drift, points, reference=(stamps, reference))
    plots.plot_replay(without, stamps, drift, points)
    for path in (with_reference, without):
        _assert_drawn(path)
    # Trajectory only (as after --live), and a reference of another clock, still draw.
    only = tmp_path / 'only.png'
    plots.plot_replay(only, stamps, drift, None, reference=(stamps + 10**12, reference))
    _assert_drawn(only)


def test_map_points_are_subsampled_and_the_recorder_stays_bounded():
    poses = np.zeros((50, 3))
    cloud = plots.map_points(poses, [np.ones((10_000, 2))] * 50, limit=100_000)
    assert 50_000 <= len(cloud) <= 100_000
    recorder = plots.ScanPointsRecorder(budget=5_000)
    for _ in range(40):
        recorder.add(np.random.default_rng(0).normal(size=(1_000, 2)))
    recorder.add(None)
    assert len(recorder.points) == 41 and len(recorder.points[-1]) == 0
    assert recorder.count <= 5_000 and recorder.stride > 1


def test_plot_study_draws_scores_and_best_runs(tmp_path):
    rng = np.random.default_rng(4)
    studies = {matcher: [(n, float(rng.uniform(0.01, 0.2))) for n in range(30)]
               for matcher in ('plicp', 'nicp', 'imls')}
    studies['imls'].append((30, math.inf))  # a failed trial is left out
    stamps, truth = _circle(80)
    best = {matcher: (stamps, truth + rng.normal(scale=0.05, size=truth.shape))
            for matcher in studies}
    path, free = tmp_path / 'study.png', tmp_path / 'free.png'
    plots.plot_study(path, studies, best, reference=(stamps, truth))
    plots.plot_study(free, studies, best)
    _assert_drawn(path)
    _assert_drawn(free)


@pytest.fixture(scope='module')
def short_bag(tmp_path_factory) -> Path:
    """Simulate 10 s of the office (100 scans) into a ROS 2 bag, with its TUM reference."""
    bag = tmp_path_factory.mktemp('plot') / 'office10'
    assert simulate.main([str(bag), '--duration', '10']) == 0
    return bag


def test_replay_plot_writes_a_png(short_bag, tmp_path, capsys):
    png = tmp_path / 'replay.png'
    assert replay.main([str(short_bag), '--plot', str(png), '--reference',
                        str(short_bag) + '.tum']) == 0
    assert f'wrote {png}' in capsys.readouterr().out
    _assert_drawn(png)


def test_missing_matplotlib_is_one_error_line(short_bag, tmp_path, monkeypatch, capsys):
    for name in [m for m in sys.modules if m == 'matplotlib' or m.startswith('matplotlib.')]:
        monkeypatch.delitem(sys.modules, name)
    monkeypatch.setitem(sys.modules, 'matplotlib', None)  # import matplotlib fails
    png = tmp_path / 'replay.png'
    assert replay.main([str(short_bag), '--plot', str(png), '--quiet']) == 2
    captured = capsys.readouterr()
    assert captured.err == ('laser_odom_replay: error: --plot needs matplotlib: '
                            'pip install matplotlib\n')
    assert captured.out == '' and not png.exists()  # said before the replay
    with pytest.raises(plots.PlotError, match='^--plot needs matplotlib'):
        plots.plot_study(png, {}, {})
