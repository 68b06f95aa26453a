"""``laser_odom_convert``: CARMEN / .mat files to ROS 2 bags, read back with rosbags."""

from collections import Counter
import math

import numpy as np
import pytest
from rosbags.rosbag2 import Reader
from rosbags.typesys import get_typestore, Stores

from laser_odom.io.tum import read_tum
from laser_odom.tools.convert import main

TYPESTORE = get_typestore(Stores.ROS2_JAZZY)


def flaser(ranges, pose, stamp):
    """Return one FLASER line whose pose and odometry fields are both ``pose``."""
    values = ' '.join(f'{r:.2f}' for r in ranges)
    pose_text = ' '.join(f'{v:.6f}' for v in (*pose, *pose))
    return f'FLASER {len(ranges)} {values} {pose_text} {stamp:.6f} host {stamp:.6f}\n'


def odom_line(pose, stamp):
    """Return one ODOM line."""
    return f'ODOM {pose[0]:.6f} {pose[1]:.6f} {pose[2]:.6f} 0 0 0 {stamp:.6f} pippo {stamp:.6f}\n'


CORRECTED = [(0.0, 0.0, 0.0), (0.11, 0.0, 0.012), (0.22, 0.02, 0.03)]
STAMPS = [0.5, 0.75, 1.0]


def corrected_log(tmp_path):
    """Write a GMapping-corrected log of three 181-beam scans and return its path."""
    text = odom_line((0.0, 0.0, 0.0), 0.25)
    for i, (pose, stamp) in enumerate(zip(CORRECTED, STAMPS)):
        text += odom_line((0.1 * i, 0.0, 0.01 * i), stamp)
        text += flaser(np.r_[np.full(180, 2.0 + i), 81.91], pose, stamp)
        text += odom_line(pose, 0.0) + 'NEFF 10\n'
    path = tmp_path / 'lab-corrected.log'
    path.write_text(text)
    return path


def read_bag(path):
    """Return ``{topic: count}`` and the deserialised messages by topic."""
    counts: Counter = Counter()
    messages: dict = {}
    with Reader(path) as reader:
        for connection, _, raw in reader.messages():
            counts[connection.topic] += 1
            msg = TYPESTORE.deserialize_cdr(raw, connection.msgtype)
            messages.setdefault(connection.topic, []).append(msg)
    return counts, messages


@pytest.mark.parametrize('storage', ['sqlite3', 'mcap'])
def test_corrected_log_to_bag(tmp_path, capsys, storage):
    out = tmp_path / 'bag'
    assert main([str(corrected_log(tmp_path)), str(out), '--storage', storage]) == 0
    counts, messages = read_bag(out)
    assert counts == {'/scan': 3, '/odom': 4, '/ground_truth': 3}
    scan = messages['/scan'][2]
    assert scan.header.stamp.sec == 1 and scan.header.stamp.nanosec == 0
    assert scan.header.frame_id == 'laser'
    assert len(scan.ranges) == 181 and scan.ranges[0] == pytest.approx(4.0)
    assert math.isinf(scan.ranges[180])
    assert scan.angle_min == pytest.approx(-math.pi / 2)
    assert scan.angle_max == pytest.approx(math.pi / 2)
    truth = messages['/ground_truth'][1]
    assert truth.header.frame_id == 'map'
    assert truth.pose.pose.position.x == pytest.approx(0.11)
    assert messages['/odom'][2].pose.pose.position.x == pytest.approx(0.1)
    reference = read_tum(tmp_path / 'bag.tum')
    assert reference.stamps_ns.tolist() == [500_000_000, 750_000_000, 1_000_000_000]
    assert reference.poses == pytest.approx(np.array(CORRECTED))
    assert 'wrote' in capsys.readouterr().out


def test_raw_log_without_reference(tmp_path):
    log = tmp_path / 'raw.clf'
    log.write_text(''.join(flaser([1.0, 2.0, 3.0], (0.1 * i, 0, 0), 10.0 + i)
                           for i in range(4)))
    tum = tmp_path / 'ref.tum'
    assert main([str(log), str(tmp_path / 'bag'), '--tum', str(tum)]) == 0
    counts, _ = read_bag(tmp_path / 'bag')
    assert counts == {'/scan': 4, '/odom': 4}
    assert not tum.exists()


def test_keyframes_become_ground_truth(tmp_path):
    log = tmp_path / 'raw.clf'
    log.write_text(''.join(flaser([1.0, 2.0], (0.1 * i, 0, 0), 10.0 + i) for i in range(4)))
    frames = tmp_path / 'frames.txt'
    frames.write_text('1 11.000000 5.0 6.0 0.5\n3 13.000000 7.0 8.0 0.6\n')
    out = tmp_path / 'bag'
    assert main([str(log), str(out), '--keyframes', str(frames)]) == 0
    counts, _ = read_bag(out)
    assert counts == {'/scan': 4, '/odom': 4, '/ground_truth': 2}
    assert read_tum(tmp_path / 'bag.tum').poses[:, 0].tolist() == pytest.approx([5.0, 7.0])


def test_malformed_line_warns_and_strict_fails(tmp_path, capsys):
    log = tmp_path / 'raw.clf'
    log.write_text(flaser([1.0, 2.0], (0, 0, 0), 1.0) + 'FLASER 2 1.0 x\n'
                   + flaser([1.0, 2.0], (0, 0, 0), 2.0))
    assert main([str(log), str(tmp_path / 'bag')]) == 0
    err = capsys.readouterr().err
    assert f'laser_odom_convert: warning: {log}:2: malformed FLASER line' in err
    assert main([str(log), str(tmp_path / 'bag2'), '--strict']) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith(f'laser_odom_convert: error: {log}:2: malformed FLASER line')
    assert '\n' not in err and not (tmp_path / 'bag2').exists()


@pytest.mark.parametrize('content, message', [
    (None, 'no such file'),
    ('PARAM a b 1 h 1\nODOM 0 0 0 0 0 0 1.0 h 1.0\n', 'no laser scans'),
])
def test_input_errors_exit_2(tmp_path, capsys, content, message):
    log = tmp_path / 'in.log'
    if content is not None:
        log.write_text(content)
    assert main([str(log), str(tmp_path / 'bag')]) == 2
    err = capsys.readouterr().err
    assert err.count('\n') == 1 and message in err
    assert err.startswith('laser_odom_convert: error: ')
    assert not (tmp_path / 'bag').exists()


def test_existing_output_exit_2(tmp_path, capsys):
    (tmp_path / 'bag').mkdir()
    assert main([str(corrected_log(tmp_path)), str(tmp_path / 'bag')]) == 2
    assert 'exists already' in capsys.readouterr().err
    with pytest.raises(SystemExit) as info:
        main([str(corrected_log(tmp_path)), str(tmp_path / 'x'), '--storage', 'zip'])
    assert info.value.code == 2
