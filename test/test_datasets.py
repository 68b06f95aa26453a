"""Dataset importers: CARMEN logs, .mat scan files, keyframe joins, and the real logs."""

import gzip
import logging
import math

import numpy as np
import pytest
import scipy.io

from laser_odom.core.datasets import (
    DatasetError, discover_datasets, load_carmen, load_dataset, load_mat)
from laser_odom.core.datasets.common import (
    longest_increasing, MIN_STAMP_STEP_NS, no_return_threshold, repair_scan_stamps)
from laser_odom.core.scan.laser_scan import beam_angles, scan_to_points

DEG = math.pi / 180.0


def flaser(ranges, pose=(0.0, 0.0, 0.0), odom=None, stamp=1.0, logger=None):
    """Return one FLASER line (``odom`` defaults to ``pose``)."""
    odom = pose if odom is None else odom
    values = ' '.join(f'{r:.2f}' for r in ranges)
    pose_text = ' '.join(f'{v:.6f}' for v in (*pose, *odom))
    logger = stamp if logger is None else logger
    return f'FLASER {len(ranges)} {values} {pose_text} {stamp:.6f} host {logger:.6f}\n'


def odom_line(pose, stamp):
    """Return one ODOM line."""
    return f'ODOM {pose[0]:.6f} {pose[1]:.6f} {pose[2]:.6f} 0 0 0 {stamp:.6f} pippo {stamp:.6f}\n'


def write(tmp_path, name, text):
    """Write ``text`` to ``tmp_path / name`` and return the path."""
    path = tmp_path / name
    path.write_text(text)
    return path


@pytest.mark.parametrize('count, increment_deg, last_deg', [
    (180, 1.0, 89.0), (181, 1.0, 90.0), (360, 0.5, 89.5), (361, 0.5, 90.0)])
def test_carmen_beam_angles(tmp_path, count, increment_deg, last_deg):
    path = write(tmp_path, 'a.clf', flaser(np.full(count, 2.0)))
    scan = load_dataset(path).scans[0]
    assert scan.angle_min == pytest.approx(-90 * DEG)
    assert scan.angle_increment == pytest.approx(increment_deg * DEG)
    assert scan.angle_max == pytest.approx(last_deg * DEG)
    assert beam_angles(scan)[-1] == pytest.approx(last_deg * DEG)
    # beam 0 points to the right (-y), the middle one (when there is one) straight ahead
    points = scan_to_points(scan).points
    assert points[0] == pytest.approx([0.0, -2.0], abs=1e-12)
    if count % 2:
        assert points[count // 2] == pytest.approx([2.0, 0.0], abs=1e-12)


def test_no_return_readings_become_inf(tmp_path):
    ranges = np.array([1.0, 81.91, 80.99, 81.83, 81.0, 50.0, 3.5, 2.0])
    path = write(tmp_path, 'a.clf', flaser(ranges))
    scan = load_dataset(path).scans[0]
    assert scan.range_min == 0.0
    assert scan.range_max == pytest.approx(80.999)
    expected = [1.0, math.inf, 80.99, math.inf, math.inf, 50.0, 3.5, 2.0]
    assert scan.ranges.tolist() == pytest.approx(expected)
    assert len(scan_to_points(scan)) == 5
    assert scan.frame_id == 'laser'


def test_max_range_fill_value_is_no_return(tmp_path):
    # a driver that writes its 50 m maximum for "no echo": the repeated largest reading
    lines = [flaser([1.0, 50.0, 2.0, 50.0], stamp=1.0), flaser([50.0, 3.0, 49.9, 4.0], stamp=2.0)]
    dataset = load_dataset(write(tmp_path, 'a.log', ''.join(lines)))
    assert dataset.scans[0].ranges.tolist() == [1.0, math.inf, 2.0, math.inf]
    assert dataset.scans[1].ranges.tolist() == [math.inf, 3.0, 49.9, 4.0]
    assert dataset.scans[0].range_max == pytest.approx(49.999)
    # a single farthest reading is a real wall, not a fill value
    assert no_return_threshold(np.array([1.0, 50.0, 2.0, 49.0])) == math.inf
    assert no_return_threshold(np.array([1.0, 7.0, 7.0, 2.0])) == math.inf


def test_raw_log_scans_stamps_and_odometry(tmp_path):
    text = ('# comment\nPARAM robot_length 0.47 1.0 merci 1.0\n'
            + flaser([1.0, 2.0, 3.0], pose=(9, 9, 9), odom=(1.0, 2.0, 0.5),
                     stamp=1134864629.895182, logger=0.086)
            + odom_line((1.5, 2.0, 0.6), 1134864630.0)
            + flaser([1.5, 2.5, 3.5], odom=(2.0, 2.0, 3.5), stamp=1134864630.105179,
                     logger=0.273))
    dataset = load_dataset(write(tmp_path, 'run.clf', text))
    assert dataset.name == 'run'
    assert [s.stamp_ns for s in dataset.scans] == [1134864629895182000, 1134864630105179000]
    assert dataset.scans[1].ranges.tolist() == [1.5, 2.5, 3.5]
    odometry = dataset.odometry
    assert odometry.stamps_ns.tolist() == [1134864629895182000, 1134864630000000000,
                                           1134864630105179000]
    # odom_* fields are the odometry (not x y theta); theta is wrapped to (-pi, pi]
    assert odometry.poses[0] == pytest.approx([1.0, 2.0, 0.5])
    assert odometry.poses[1] == pytest.approx([1.5, 2.0, 0.6])
    assert odometry.poses[2] == pytest.approx([2.0, 2.0, 3.5 - 2 * math.pi])
    assert len(dataset.reference) == 0


def corrected_log(stray_echo_stamp=False):
    """Return a GMapping-corrected log of three scans and its expected content."""
    raw = [(0.0, 0.0, 0.0), (0.1, 0.0, 0.01), (0.2, 0.01, 0.02)]
    corrected = [(0.0, 0.0, 0.0), (0.11, 0.0, 0.012), (0.22, 0.02, 0.03)]
    stamps = [0.5, 0.75, 1.0]
    text = odom_line((0.0, 0.0, 0.0), 0.25)
    for i, (r, c, t) in enumerate(zip(raw, corrected, stamps)):
        text += odom_line(r, t)
        text += flaser([1.0 + i, 2.0, 81.91], pose=c, odom=c, stamp=t)
        text += odom_line(c, 5.36 if stray_echo_stamp and i == 1 else 0)
        text += 'NEFF 10\n'
    text += odom_line((0.25, 0.01, 0.02), 1.2)
    return text, raw, corrected, stamps


@pytest.mark.parametrize('stray_echo_stamp', [False, True])
def test_corrected_log_reference_and_raw_odometry(tmp_path, stray_echo_stamp):
    text, raw, corrected, stamps = corrected_log(stray_echo_stamp)
    dataset = load_dataset(write(tmp_path, 'x-corrected.log', text))
    stamp_ns = [int(t * 1e9) for t in stamps]
    assert [s.stamp_ns for s in dataset.scans] == stamp_ns
    assert dataset.scans[2].ranges.tolist() == [3.0, 2.0, math.inf]
    assert dataset.reference.stamps_ns.tolist() == stamp_ns
    assert dataset.reference.poses == pytest.approx(np.array(corrected))
    # raw odometry: the ODOM lines before each FLASER and the other stamped ODOM lines,
    # never the corrected echo after a FLASER (even with a stray stamp)
    assert dataset.odometry.stamps_ns.tolist() == [250_000_000, *stamp_ns, 1_200_000_000]
    assert dataset.odometry.poses[1:4] == pytest.approx(np.array(raw))


def test_gzip_log_equals_plain(tmp_path):
    text, _, corrected, _ = corrected_log()
    path = tmp_path / 'y-corrected.log.gz'
    with gzip.open(path, 'wt') as handle:
        handle.write(text)
    dataset = load_dataset(path)
    assert dataset.name == 'y-corrected'
    assert len(dataset.scans) == 3
    assert dataset.reference.poses == pytest.approx(np.array(corrected))


def test_malformed_line_is_skipped_with_file_and_line(tmp_path, caplog):
    text = (flaser([1.0, 2.0, 3.0], stamp=1.0)
            + 'FLASER 3 1.0 2.0 oops 0 0 0 0 0 0 2.0 host 2.0\n'
            + 'FLASER 4 1.0 2.0 3.0 0 0 0 0 0 0 3.0 host 3.0\n'
            + flaser([1.0, 2.0, 3.0], stamp=4.0))
    path = write(tmp_path, 'bad.clf', text)
    with caplog.at_level(logging.WARNING, logger='laser_odom.core.datasets'):
        dataset = load_dataset(path)
    assert [s.stamp_ns for s in dataset.scans] == [1_000_000_000, 4_000_000_000]
    assert f'{path}:2: malformed FLASER line' in caplog.text
    assert f'{path}:3: malformed FLASER line' in caplog.text
    with pytest.raises(DatasetError, match=rf'^{path}:2: malformed FLASER line'):
        load_dataset(path, strict=True)


def test_log_without_laser_lines_is_an_error(tmp_path):
    path = write(tmp_path, 'odom.log', odom_line((0, 0, 0), 1.0) + 'PARAM a b 1 h 1\n')
    with pytest.raises(DatasetError) as info:
        load_dataset(path)
    assert str(info.value) == f'{path}: no laser scans (no valid FLASER line)'
    path = write(tmp_path, 'robot.log', 'ROBOTLASER1 0 -1.57 3.14 0.01 81.9 0.01 0 2 1 1\n')
    with pytest.raises(DatasetError, match='1 ROBOTLASER1 lines are not supported'):
        load_dataset(path)


@pytest.mark.parametrize('name, message', [
    ('missing.clf', 'no such file'), ('data.bag', 'unknown dataset format')])
def test_bad_paths_are_errors(tmp_path, name, message):
    if name.endswith('.bag'):
        write(tmp_path, name, 'x')
    with pytest.raises(DatasetError, match=message):
        load_dataset(tmp_path / name)


def test_backward_scan_stamps_are_repaired_in_file_order(tmp_path, caplog):
    # one late stamp (1.9) and one repeated stamp (2.0): rows keep their order
    stamps = [1.0, 1.2, 1.9, 1.6, 1.8, 2.0, 2.0]
    text = ''.join(flaser([1.0 + i, 2.0], odom=(0.1 * i, 0, 0), stamp=t)
                   for i, t in enumerate(stamps))
    with caplog.at_level(logging.WARNING, logger='laser_odom.core.datasets'):
        dataset = load_carmen(write(tmp_path, 'jitter.clf', text))
    got = [s.stamp_ns for s in dataset.scans]
    expected = [1.0e9, 1.2e9, 1.4e9, 1.6e9, 1.8e9, 2.0e9, 2.0e9 + MIN_STAMP_STEP_NS]
    assert got == [int(e) for e in expected]
    assert [s.ranges[0] for s in dataset.scans] == [1.0 + i for i in range(7)]
    assert 're-stamped 2 of 7 scans' in caplog.text
    # odometry drops the samples with out-of-order or repeated stamps instead
    assert dataset.odometry.stamps_ns.tolist() == [1.0e9, 1.2e9, 1.6e9, 1.8e9, 2.0e9]
    assert dataset.odometry.poses[:, 0] == pytest.approx([0.0, 0.1, 0.3, 0.4, 0.5])
    assert 'dropped 2 of 7 odometry samples' in caplog.text


def test_longest_increasing_and_repair():
    t = np.array([5, 1, 2, 9, 3, 4, 4, 10])
    assert t[longest_increasing(t, strict=True)].tolist() == [1, 2, 3, 4, 10]
    assert t[longest_increasing(t, strict=False)].tolist() == [1, 2, 3, 4, 4, 10]
    fixed, changed = repair_scan_stamps(np.array([0, 10_000, 10_000, 10_000, 50_000]))
    assert fixed.tolist() == [0, 10_000, 11_000, 12_000, 50_000] and changed == 2
    same, changed = repair_scan_stamps(np.array([1, 2, 3]))
    assert same.tolist() == [1, 2, 3] and changed == 0


KEYFRAMES_HEADER = '# columns: raw_scan_index(0-based) ipc_timestamp x y theta\n'


def test_keyframes_beside_raw_log(tmp_path, caplog):
    stamps = [100.0 + 0.2 * i for i in range(6)]
    text = ''.join(flaser([1.0, 2.0, 3.0], stamp=t) for t in stamps)
    text = text.replace('FLASER 3 1.00 2.00 3.00 0.000000 0.000000 0.000000 0.000000 '
                        '0.000000 0.000000 100.600000', 'FLASER 3 broken', 1)
    path = write(tmp_path, 'log.clf', text)
    write(tmp_path, 'reference_keyframes.txt', KEYFRAMES_HEADER
          + '1 100.200000 1.0 2.0 0.1\n4 100.800000 1.5 2.5 0.2\n'
          + '5 100.700000 9 9 9\n7 101.4 9 9 9\n3 100.600000 9 9 9\n')
    with caplog.at_level(logging.WARNING, logger='laser_odom.core.datasets'):
        dataset = load_dataset(path)
    assert len(dataset.scans) == 5
    # indices count the broken FLASER line (index 3), so index 4 is the scan at 100.8 s
    assert dataset.reference.stamps_ns.tolist() == [100_200_000_000, 100_800_000_000]
    assert dataset.reference.poses == pytest.approx(np.array([[1, 2, 0.1], [1.5, 2.5, 0.2]]))
    assert 'reference_keyframes.txt:4: stamp 100.700000 does not match scan 5' in caplog.text
    assert "reference_keyframes.txt:5: scan index 7 outside the log's 6 scans" in caplog.text
    assert 'reference_keyframes.txt:6: scan 3 was skipped as malformed' in caplog.text


def test_keyframes_for_mat_rows_are_not_joined_to_a_log(tmp_path):
    path = write(tmp_path, 'log.clf', flaser([1.0, 2.0], stamp=1.0))
    write(tmp_path, 'reference_keyframes.txt',
          '# columns: mat_row_index(0-based) timestamp x y theta\n0 1.0 0 0 0\n')
    assert len(load_dataset(path).reference) == 0


def write_mat(path, stamps, beams=180, **extra):
    """Write a scan_intel.mat-style file with ``len(stamps)`` rows."""
    rows = len(stamps)
    data = np.tile(np.linspace(1.0, 5.0, beams), (rows, 1))
    data[:, 0] = 81.83
    odom = np.column_stack((0.1 * np.arange(rows), np.zeros(rows), np.full(rows, 0.01)))
    variables = {'beam_data': data, 'odom': odom,
                 'timestamp': np.asarray(stamps, dtype=float).reshape(-1, 1),
                 'beam_start': np.array([[-math.pi / 2]]), 'beam_end': np.array([[math.pi / 2]]),
                 'beam_n': np.array([[beams]], dtype=np.uint8)}
    variables.update(extra)
    scipy.io.savemat(path, variables)
    return path


def test_mat_file(tmp_path):
    path = write_mat(tmp_path / 'scan_intel.mat', [0.000246, 0.2, 0.5, 0.4, 0.6])
    (tmp_path / 'reference_keyframes.txt').write_text(
        '# columns: mat_row_index(0-based) timestamp x y theta\n'
        '1 0.200000 0.5 0.0 -0.3\n4 0.600001 0.7 0.1 -0.4\n')
    dataset = load_dataset(path)
    assert dataset.name == 'intel'
    assert len(dataset.scans) == 5 and len(dataset.scans[0].ranges) == 180
    scan = dataset.scans[0]
    assert scan.angle_increment == pytest.approx(DEG)
    assert (scan.angle_min, scan.angle_max) == pytest.approx((-90 * DEG, 89 * DEG))
    assert scan.ranges[0] == math.inf and scan.ranges[1] == pytest.approx(1.0 + 4.0 / 179)
    # the late 0.5 s stamp is re-estimated between its neighbours, rows keep their order
    stamps = [s.stamp_ns for s in dataset.scans]
    assert stamps == [246_000, 200_000_000, 300_000_000, 400_000_000, 600_000_000]
    assert dataset.odometry.stamps_ns.tolist() == stamps
    assert dataset.odometry.poses[:, 0] == pytest.approx(0.1 * np.arange(5))
    assert dataset.reference.stamps_ns.tolist() == [200_000_000, 600_000_000]
    assert dataset.reference.poses[1] == pytest.approx([0.7, 0.1, -0.4])


def test_mat_errors(tmp_path):
    path = tmp_path / 'empty.mat'
    scipy.io.savemat(path, {'odom': np.zeros((2, 3))})
    with pytest.raises(DatasetError, match='no laser scans .missing variable beam_data'):
        load_mat(path)
    with pytest.raises(DatasetError, match='timestamp has 2 values for 3 scans'):
        load_mat(write_mat(tmp_path / 'a.mat', [1.0, 2.0, 3.0], timestamp=np.ones(2)))
    with pytest.raises(DatasetError, match='not a readable MATLAB'):
        load_mat(write(tmp_path, 'text.mat', 'not a mat file\n' * 20))


def test_discover_datasets(tmp_path):
    (tmp_path / 'mit-csail').mkdir()
    write(tmp_path / 'mit-csail', 'mit-csail.clf', flaser([1.0, 2.0]))
    (tmp_path / 'intel').mkdir()
    assert discover_datasets(tmp_path) == {'mit-csail': tmp_path / 'mit-csail/mit-csail.clf'}


def real_dataset(data_dir, name):
    """Load one real dataset, skipping the test when its file is not in ``data_dir``."""
    found = discover_datasets(data_dir)
    if name not in found:
        pytest.skip(f'real dataset {name} not found under {data_dir}')
    return load_dataset(found[name])


def increasing(stamps):
    """Tell whether stamps are strictly increasing."""
    return bool(np.all(np.diff(stamps) > 0))


def test_real_mit_csail(shared_data_dir):
    dataset = real_dataset(shared_data_dir, 'mit-csail')
    assert dataset.name == 'mit-csail'
    assert len(dataset.scans) == 1988
    assert {len(s.ranges) for s in dataset.scans} == {361}
    stamps = np.array([s.stamp_ns for s in dataset.scans])
    assert increasing(stamps) and len(dataset.odometry) == 1988
    assert len(dataset.reference) == 686
    # keyframe 0 is scan 61 at the map origin
    assert dataset.reference.stamps_ns[0] == stamps[61] == 1134864642914187000
    assert dataset.reference.poses[0] == pytest.approx([0.0, 0.0, 0.0])
    assert np.isin(dataset.reference.stamps_ns, stamps).all()


def test_real_intel_mat(shared_data_dir):
    dataset = real_dataset(shared_data_dir, 'intel')
    assert len(dataset.scans) == 5505
    assert {len(s.ranges) for s in dataset.scans} == {180}
    stamps = np.array([s.stamp_ns for s in dataset.scans])
    assert increasing(stamps) and increasing(dataset.odometry.stamps_ns)
    assert len(dataset.reference) == 345
    assert np.isin(dataset.reference.stamps_ns, stamps).all()
    assert dataset.reference.stamps_ns[0] == stamps[169]


def test_real_fr079(shared_data_dir):
    dataset = real_dataset(shared_data_dir, 'fr079')
    assert len(dataset.scans) == 4791
    assert {len(s.ranges) for s in dataset.scans} == {360}
    stamps = np.array([s.stamp_ns for s in dataset.scans])
    assert increasing(stamps)
    assert dataset.reference.stamps_ns.tolist() == stamps.tolist()
    assert len(dataset.odometry) == 4934 and increasing(dataset.odometry.stamps_ns)
