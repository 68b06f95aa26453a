"""End-to-end tests of ``laser_odom_replay`` on simulated and real bags."""

import os
from pathlib import Path
import shutil
import subprocess
import sys

import numpy as np
import pytest

from laser_odom.core.evaluation.metrics import distance_travelled, evaluate
from laser_odom.io.bag_reader import BagReader
from laser_odom.io.tum import read_tum
from laser_odom.tools import replay, simulate

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope='module')
def sim_bag(tmp_path_factory) -> Path:
    """Simulate 60 s of the office world (600 scans) into a ROS 2 sqlite3 bag."""
    bag = tmp_path_factory.mktemp('sim') / 'office60'
    assert simulate.main([str(bag), '--duration', '60', '--seed', '3']) == 0
    return bag


def _run_cli(*args: str) -> subprocess.CompletedProcess:
    """Run laser_odom_replay in a subprocess, as a user would."""
    env = dict(os.environ, PYTHONPATH=str(ROOT) + os.pathsep + os.environ.get('PYTHONPATH', ''))
    return subprocess.run([sys.executable, '-m', 'laser_odom.tools.replay', *args], cwd=ROOT,
                          env=env, capture_output=True, text=True, timeout=120)


def _assert_one_line_error(result: subprocess.CompletedProcess, text: str) -> None:
    """Exit code 2, and stderr is one line naming the problem, without a traceback."""
    assert result.returncode == 2, result.stderr
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1, result.stderr
    assert 'Traceback' not in result.stderr
    assert lines[0].startswith('laser_odom_replay: error:') and text in lines[0]


def test_icp_replay_is_accurate_and_writes_outputs(sim_bag, tmp_path, capsys):
    tum, out_bag = tmp_path / 'icp.tum', tmp_path / 'odom_bag'
    reference = Path(str(sim_bag) + '.tum')
    code = replay.main([str(sim_bag), '--matcher', 'icp', '--tum', str(tum),
                        '--output-bag', str(out_bag), '--reference', str(reference),
                        '--quiet'])
    stdout = capsys.readouterr().out
    assert code == 0
    assert 'scans 600 from /scan (icp): processed 600' in stdout
    assert 'ATE' in stdout and 'RPE over 599 steps' in stdout
    estimate, truth = read_tum(tum), read_tum(reference)
    assert len(estimate) == 600
    np.testing.assert_array_equal(estimate.stamps_ns, truth.stamps_ns)
    errors = evaluate(estimate, truth)
    travelled = distance_travelled(truth)
    assert travelled > 20.0
    assert errors.ate_rms < 0.02 * travelled
    assert errors.failed_steps == 0
    with BagReader(out_bag) as bag:
        assert bag.topics == {'/odom': 'nav_msgs/msg/Odometry',
                              '/pose': 'geometry_msgs/msg/PoseStamped'}
        odom = bag.odometry('/odom')
        covariances = [np.array(msg.pose.covariance).reshape(6, 6)
                       for _, _, msg in bag.messages(['/odom'])]
        poses = [msg for _, _, msg in bag.messages(['/pose'])]
    np.testing.assert_allclose(odom.poses, estimate.poses, atol=1e-6)
    assert len(poses) == 600
    # The integrated covariance of scan-to-scan odometry grows along the path.
    assert covariances[-1][0, 0] > covariances[10][0, 0] > 0.0


def test_params_file_and_odom_prior(sim_bag, tmp_path, capsys):
    params = tmp_path / 'params.yaml'
    params.write_text('/**:\n  ros__parameters:\n    matcher: icp\n    keyframe_distance: 0.3\n'
                      '    plicp:\n      max_iterations: 40\n')
    tum = tmp_path / 'kf.tum'
    code = replay.main([str(sim_bag), '--params-file', str(params), '--matcher', 'plicp',
                        '--prior', 'odom', '--tum', str(tum), '--quiet'])
    stdout = capsys.readouterr().out
    assert code == 0
    assert '(plicp)' in stdout  # --matcher overrides the file
    assert 'prior_missing' not in stdout  # the /odom prior covered every scan
    errors = evaluate(read_tum(tum), read_tum(Path(str(sim_bag) + '.tum')))
    assert errors.ate_rms < 0.02 * 20.0


def test_bad_params_file_is_a_one_line_error(sim_bag, tmp_path, capsys):
    params = tmp_path / 'bad.yaml'
    params.write_text('laser_odom:\n  ros__parameters:\n    min_inlier_ratio: 7.0\n')
    assert replay.main([str(sim_bag), '--params-file', str(params)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and 'min_inlier_ratio' in err[0]


def test_missing_bag_is_a_one_line_error(tmp_path):
    _assert_one_line_error(_run_cli(str(tmp_path / 'nope')), 'bag not found')


def test_bag_without_laser_scan_is_a_one_line_error(tmp_path):
    from laser_odom.core.trajectory import Trajectory
    from laser_odom.io.bag_writer import write_bag
    write_bag(tmp_path / 'odom_only', odometry={'/odom': Trajectory([1, 2], np.zeros((2, 3)))})
    _assert_one_line_error(_run_cli(str(tmp_path / 'odom_only')), 'no LaserScan topic')


def test_truncated_bag_writes_what_was_processed(sim_bag, tmp_path):
    cut = tmp_path / 'cut'
    shutil.copytree(sim_bag, cut)
    db3 = next(cut.glob('*.db3'))
    data = db3.read_bytes()
    db3.write_bytes(data[:len(data) // 4])
    tum = tmp_path / 'cut.tum'
    result = _run_cli(str(cut), '--tum', str(tum), '--quiet')
    _assert_one_line_error(result, 'truncated or corrupt')
    estimate = read_tum(tum)  # complete lines only, or read_tum would raise
    assert 20 < len(estimate) < 600
    assert f'reading stopped at message {len(estimate)} ' in result.stderr
    assert tum.read_text().endswith('\n')
    truth = read_tum(Path(str(sim_bag) + '.tum'))
    np.testing.assert_array_equal(estimate.stamps_ns, truth.stamps_ns[:len(estimate)])
    errors = evaluate(estimate, truth)
    assert errors.ate_rms < 0.02 * max(distance_travelled(estimate), 1.0)


def test_ccny_demo_bag_replays_all_scans(shared_data_dir, tmp_path, capsys):
    path = shared_data_dir / 'ccny-demo' / 'demo.bag'
    if not path.is_file():
        pytest.skip(f'{path} not available')
    tum = tmp_path / 'demo.tum'
    assert replay.main([str(path), '--tum', str(tum), '--quiet']) == 0
    assert 'scans 360 from /scan' in capsys.readouterr().out
    estimate = read_tum(tum)
    assert len(estimate) == 360
    # The robot moves a few metres in 36 s; wild jumps would mean broken scans.
    steps = np.hypot(*np.diff(estimate.poses[:, :2], axis=0).T)
    assert 1.0 < distance_travelled(estimate) < 20.0 and steps.max() < 0.3


def test_prior_feed_interpolates_odometry_and_imu_between_scans():
    from laser_odom.core import se2
    from laser_odom.core.configuration.node import PriorConfig
    from laser_odom.core.trajectory import Trajectory
    from laser_odom.core.trajectory import ImuSamples
    # Wheel odometry at 50 Hz of a robot turning on a circle; scans at 10 Hz in between.
    t = np.arange(0, 101) * 20_000_000
    phi = 0.5 * t * 1e-9
    odom = Trajectory(t, np.column_stack((np.sin(phi), 1 - np.cos(phi), phi)))
    feed = replay.PriorFeed('odom', PriorConfig(), odometry=odom)
    start, end = 105_000_000, 205_000_000
    assert feed.prior_for(None, start) == (None, None)
    step, yaw = feed.prior_for(start, end)
    truth = se2.relative(odom.interpolate(start), odom.interpolate(end))
    np.testing.assert_allclose(step, truth, atol=1e-12)
    assert yaw is None
    # Samples up to the scan and the first one after it have been buffered, no more.
    assert len(feed.odometry) == int(np.searchsorted(t, end, side='right')) + 1
    # IMU without orientation: the yaw change integrates the rate (0.5 rad/s).
    imu = ImuSamples(t, np.full(len(t), np.nan), np.full(len(t), 0.5))
    feed = replay.PriorFeed('imu', PriorConfig(), imu=imu)
    feed.prior_for(None, start)
    step, yaw = feed.prior_for(start, end)
    assert step is None and yaw == pytest.approx(0.05, abs=1e-12)


def test_a_reader_that_leaves_early_gets_no_traceback(sim_bag, tmp_path):
    """``laser_odom_replay BAG | head -1``: the pipe closes; the replay stops quietly.

    The outputs written to files are complete: the summary on stdout comes last.
    """
    env = dict(os.environ, PYTHONPATH=str(ROOT) + os.pathsep + os.environ.get('PYTHONPATH', ''))
    tum = tmp_path / 'replay.tum'
    process = subprocess.Popen(
        [sys.executable, '-m', 'laser_odom.tools.replay', str(sim_bag), '--matcher', 'plicp',
         '--tum', str(tum)], cwd=ROOT, env=env, stdout=subprocess.PIPE,
        stderr=subprocess.PIPE, text=True)
    process.stdout.close()  # the reader is gone before the first line
    _, stderr = process.communicate(timeout=120)
    assert process.returncode == 1, stderr
    assert 'Traceback' not in stderr and 'BrokenPipeError' not in stderr, stderr
    assert len(read_tum(tum)) == 600
