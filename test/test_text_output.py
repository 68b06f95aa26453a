"""Text outputs are written whole: atomically into a regular file, in place into a pipe.

Replacing a device or a pipe with a regular file - the atomic rename - would break it
for everybody (``--output /dev/null`` run as root replaced ``/dev/null``).
"""

import os
from pathlib import Path
import stat
import threading

import numpy as np

from laser_odom.core.trajectory import Trajectory
from laser_odom.io.text_output import is_special_file, write_text_atomically
from laser_odom.io.tum import read_tum, write_tum


def read_fifo_in_background(fifo: Path) -> tuple[threading.Thread, list[str]]:
    """Start a reader of ``fifo`` (a writer blocks until one opens it)."""
    received: list[str] = []

    def read() -> None:
        with fifo.open() as handle:
            received.append(handle.read())
    reader = threading.Thread(target=read, daemon=True)
    reader.start()
    return reader, received


def test_a_regular_file_is_replaced_whole_and_leaves_no_partial(tmp_path):
    path = tmp_path / 'out.txt'
    path.write_text('old\n')
    write_text_atomically(path, 'new\n')
    assert path.read_text() == 'new\n'
    assert sorted(p.name for p in tmp_path.iterdir()) == ['out.txt']


def test_a_pipe_is_written_in_place_and_stays_a_pipe(tmp_path):
    fifo = tmp_path / 'pipe'
    os.mkfifo(fifo)
    assert is_special_file(fifo) and not is_special_file(tmp_path / 'none')
    reader, received = read_fifo_in_background(fifo)
    trajectory = Trajectory(np.array([10**9, 2 * 10**9]), np.array([[0.0, 0, 0], [1, 2, 0.5]]))
    write_tum(fifo, trajectory)
    reader.join(timeout=10)
    assert stat.S_ISFIFO(os.stat(fifo).st_mode)
    copy = tmp_path / 'copy.tum'
    copy.write_text(received[0])
    assert np.allclose(read_tum(copy).poses, trajectory.poses)
    assert sorted(p.name for p in tmp_path.iterdir()) == ['copy.tum', 'pipe']
