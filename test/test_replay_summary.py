"""``laser_odom_replay`` tells what happened: empty bags, bad references, Ctrl-C, outputs, priors.

Issue 30, points 4, 5, 6, 11 and 14: an empty bag is an error, a malformed reference
stops the replay before it starts, an interrupted run says so first, every written file
is named, and the summary says how often the motion prior predicted a match.
"""

import os
from pathlib import Path
import re
import signal

import pytest

from laser_odom.core.evaluation.metrics import distance_travelled
from laser_odom.io.bag_writer import write_bag
from laser_odom.io.tum import read_tum
from laser_odom.tools import replay, simulate


@pytest.fixture(scope='module')
def bag(tmp_path_factory) -> Path:
    """Simulate 10 s of the office world (100 scans, /odom, /ground_truth)."""
    path = tmp_path_factory.mktemp('summary') / 'office10'
    assert simulate.main([str(path), '--duration', '10', '--seed', '6']) == 0
    return path


@pytest.fixture(scope='module')
def slow_bag(tmp_path_factory) -> Path:
    """Simulate 40 s at 0.5 Hz: 20 scans 2 s apart, with 50 Hz wheel odometry."""
    path = tmp_path_factory.mktemp('slow') / 'slow'
    assert simulate.main([str(path), '--rate', '0.5', '--duration', '40', '--seed', '3']) == 0
    return path


def test_a_bag_whose_scan_topic_has_no_messages_is_an_error(tmp_path, capsys):
    """Point 4: ``scans 0`` and exit 0 looked like a success; bench and tune say exit 2."""
    empty = tmp_path / 'empty'
    write_bag(empty, [], scan_record_times=[])  # the /scan connection, no messages
    tum = tmp_path / 'empty.tum'
    assert replay.main([str(empty), '--tum', str(tum)]) == 2
    captured = capsys.readouterr()
    assert captured.err.strip() == (
        f'laser_odom_replay: error: {empty}: 0 scans on /scan; a replay needs a bag with scans')
    assert captured.out == '' and not tum.exists()


def test_a_malformed_reference_stops_the_replay_before_it_starts(bag, tmp_path, capsys):
    """Point 5: the reference used to be read after every scan was replayed."""
    not_tum = tmp_path / 'not_tum.csv'
    not_tum.write_text('stamp,x,y\n1,2,3\n')
    tum = tmp_path / 'est.tum'
    assert replay.main([str(bag), '--reference', str(not_tum), '--tum', str(tum)]) == 2
    captured = capsys.readouterr()
    lines = captured.err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(
        f'laser_odom_replay: error: cannot read reference {not_tum}: ')
    assert 'fields' in lines[0]
    assert captured.out == '' and not tum.exists()  # nothing was replayed


def test_ctrl_c_says_the_run_was_interrupted_and_keeps_what_was_done(bag, tmp_path, capsys,
                                                                     monkeypatch):
    """Point 6: exit 130 with the outputs, and the summary says first that it was cut short.

    Ctrl-C (a real SIGINT to this process, while the 31st scan is read) stops the run
    after that scan - between two scans, never inside a compiled kernel.
    """
    read_scans = replay.BagReader.scans

    def scans(self, topic=None):
        for index, scan in enumerate(read_scans(self, topic)):
            if index == 30:
                os.kill(os.getpid(), signal.SIGINT)
            yield scan

    monkeypatch.setattr(replay.BagReader, 'scans', scans)
    tum = tmp_path / 'part.tum'
    reference = read_tum(str(bag) + '.tum')
    assert replay.main([str(bag), '--matcher', 'imls', '--tum', str(tum),
                        '--reference', str(bag) + '.tum']) == 130
    out = capsys.readouterr().out.splitlines()
    assert out[0] == ('INTERRUPTED (Ctrl-C) after 31 scans of the 100 in the bag: the figures '
                      'and outputs cover only the scans before it')
    assert out[1].startswith('scans 31 from /scan (imls): processed 31, matched 30')
    assert len(read_tum(tum)) == 31 and out[-1] == f'wrote {tum} (31 poses, TUM)'
    # Issue 39: the ATE's distance is the reference's over the 31 scans, not the bag's.
    ate = next(line for line in out if ' ATE ' in line)
    travelled = float(re.search(r'of (\S+) m travelled', ate).group(1))
    assert travelled == round(distance_travelled(type(reference)(
        reference.stamps_ns[:31], reference.poses[:31])), 2)
    assert travelled < 0.5 * distance_travelled(reference)


def test_every_file_written_is_named(bag, tmp_path, capsys):
    """Point 11: ``wrote`` lines for --tum and --output-bag, as for --plot."""
    tum, out_bag = tmp_path / 'est.tum', tmp_path / 'odom_bag'
    assert replay.main([str(bag), '--tum', str(tum), '--output-bag', str(out_bag),
                        '--storage', 'mcap']) == 0
    lines = capsys.readouterr().out.splitlines()
    assert lines[-2:] == [f'wrote {tum} (100 poses, TUM)',
                          f'wrote {out_bag} (100 /odom and /pose messages, mcap)']
    assert len(read_tum(tum)) == 100 and any(out_bag.glob('*.mcap'))
    assert replay.main([str(bag), '--tum', str(tmp_path / 'q.tum'), '--quiet']) == 0
    assert 'wrote' not in capsys.readouterr().out  # --quiet: the summary only


def test_wheel_odometry_predicts_over_long_gaps_and_the_summary_says_how_often(
        slow_bag, capsys):
    """Point 14: on scans 2 s apart a 1 s max_scan_gap dropped even the odom prior.

    Now the wheel odometry predicts every match (no global search needed), the constant
    velocity none, and the summary says both, with what to change.
    """
    truth = str(slow_bag) + '.tum'
    assert replay.main([str(slow_bag), '--prior', 'odom', '--reference', truth,
                        '--quiet']) == 0
    odom = capsys.readouterr().out
    assert ('motion prior odom: predicted 19 of 19 matches; dropped on 0 (longer than '
            'max_scan_gap 1 s between scans), missing on 0') in odom
    assert 'search_gap' not in odom and 'note:' not in odom
    assert replay.main([str(slow_bag), '--reference', truth, '--quiet']) == 0
    constant = capsys.readouterr().out
    assert ('motion prior constant_velocity: predicted 0 of 19 matches; dropped on 19 '
            '(longer than max_scan_gap 1 s between scans)') in constant
    assert ('note: the scans are a median 2.00 s apart, so the prior was dropped on most '
            'steps: raise max_scan_gap above 2.00 s to predict over such gaps, or use the '
            'wheel odometry (--prior odom)') in constant
    for out in (odom, constant):  # 0.9 m steps: tracked either way, against ground truth
        assert float(re.search(r'ATE ([0-9.]+) m', out).group(1)) < 0.01
        assert 'failed steps 0' in out
