"""A looping bag (stamps jump back): the odometry resets once and keeps tracking."""

import numpy as np

from laser_odom.core.evaluation.metrics import evaluate
from laser_odom.core.simulation import simulate
from laser_odom.core.trajectory import Trajectory
from laser_odom.io.bag_writer import write_bag
from laser_odom.tools.replay import main


def read_tum_rows(path):
    rows = np.loadtxt(path)
    stamps = np.round(rows[:, 0] * 1e9).astype(np.int64)
    yaw = 2.0 * np.arctan2(rows[:, 6], rows[:, 7])
    return stamps, np.column_stack((rows[:, 1], rows[:, 2], yaw))


def test_looped_bag_resets_once_and_keeps_tracking(tmp_path, capsys):
    run = simulate('office', duration=12.0, seed=2)
    loop = 60
    scans = run.scans + run.scans[:loop]
    period = run.scans[1].stamp_ns - run.scans[0].stamp_ns
    record_times = [s.stamp_ns for s in run.scans] + [
        run.scans[-1].stamp_ns + (k + 1) * period for k in range(loop)]
    bag = tmp_path / 'looped'
    write_bag(bag, scans=scans, scan_record_times=record_times)
    assert main([str(bag), '--tum', str(tmp_path / 'out.tum')]) == 0
    output = capsys.readouterr()
    assert output.err.count('odometry reset') == 1
    assert 'time_jump_back 1' in output.out
    stamps, poses = read_tum_rows(tmp_path / 'out.tum')
    assert len(stamps) == len(scans)
    first = len(run.scans)
    assert np.allclose(poses[first], 0.0)  # restarted from the origin
    for part in (slice(0, first), slice(first, None)):
        estimate = Trajectory(stamps[part], poses[part])
        errors = evaluate(estimate, run.reference)
        assert errors.pairs == len(estimate)
        assert errors.ate_rms < 0.03
        assert errors.rpe_trans_mean < 0.005
