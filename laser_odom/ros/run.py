"""A node's process: help, parameter files, rclpy, spin, exit code.

``laser_odom_node`` and ``laser_odom_lifecycle_node`` start, fail and stop the same way:
``--help`` prints the usage and starts nothing; a malformed ``--params-file`` or
``--ros-args`` is a one-line error (exit code 2) before the node exists, as are bad
parameter values (:class:`laser_odom.ros.live.StartupError`); Ctrl-C ends the spin
quietly (exit code 0).
"""

from __future__ import annotations

import sys
import time
from typing import Callable, Sequence, TYPE_CHECKING

import rclpy
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor

from laser_odom.io.params_file import ParamsFile, ParamsFileError, parse_params_file
from laser_odom.io.text_output import reader_may_leave
from laser_odom.ros.live import StartupError
from laser_odom.ros.usage import params_file_arguments, wants_help

if TYPE_CHECKING:
    from rclpy.context import Context
    from rclpy.node import Node

SIGNAL_THREAD_WAIT = 2.0
"""Seconds teardown waits for rclpy's signal thread to shut the context down."""


def interrupted(error: BaseException | None) -> bool:
    """Tell whether an error stands for Ctrl-C.

    A ``KeyboardInterrupt`` raised while a numba kernel ran comes back as a
    ``SystemError`` whose cause is the interrupt ("returned a result with an exception
    set"). Where a node catches and logs a scan's errors to keep running, such an error
    is a request to stop, not a bad scan.
    """
    seen: set[int] = set()
    while error is not None and id(error) not in seen:
        if isinstance(error, KeyboardInterrupt):
            return True
        seen.add(id(error))
        error = error.__cause__ or error.__context__
    return False


def let_the_signal_thread_finish(context: 'Context',
                                 timeout: float = SIGNAL_THREAD_WAIT) -> None:
    """Wait until the context is shut down, as rclpy's signal thread does after Ctrl-C.

    rclpy answers SIGINT in two threads: the Python handler raises
    ``KeyboardInterrupt`` here, and a deferred C++ thread triggers the executors'
    SIGINT guard conditions, then shuts every context down
    (``rclpy/src/rclpy/signal_handler.cpp``), with no lock against this thread. When
    that thread runs late on a busy machine, destroying the node and the executor
    (whose guard condition it is walking) is a use after free: about one Ctrl-C in a
    hundred ended in a segfault (exit code -11), more often when the executor was
    shut down first. The context stops being ok only after that thread has
    triggered the guard conditions, so teardown waits for it - at most ``timeout``,
    as a ``KeyboardInterrupt`` that no signal raised never shuts it down.
    """
    end = time.monotonic() + timeout
    while context.ok() and time.monotonic() < end:
        time.sleep(0.01)


def run_node(args: list[str] | None, node_type: Callable[[Sequence[ParamsFile]], 'Node'],
             prog: str, help_text: Callable[[], str]) -> int:
    """Run ``node_type(params_files)`` until Ctrl-C; return the exit code (2: bad input).

    ``args`` is the command line (``sys.argv`` when None), ``prog`` names the program
    in its errors and ``help_text()`` is what ``--help`` prints.
    """
    argv = sys.argv if args is None else args
    if wants_help(argv):
        with reader_may_leave(status=0):  # `--help | head`: the reader left; say no more
            print(help_text(), flush=True)
        return 0
    try:
        # The files' layout is judged by the same reader the replay and tools use,
        # before rcl parses them, so a malformed file gets the same one-line error.
        params_files = [parse_params_file(path) for path in params_file_arguments(argv)]
    except ParamsFileError as error:
        print(f'{prog}: error: {error}', file=sys.stderr)
        return 2
    try:
        rclpy.init(args=args)
    except Exception as error:  # malformed --ros-args or an unreadable params file
        message = str(error).strip().splitlines()
        print(f'{prog}: error: {message[0] if message else error!r}', file=sys.stderr)
        return 2
    node = None
    code = 0
    try:
        # Built before the node so that a Ctrl-C at any later moment finds it complete.
        executor = SingleThreadedExecutor()
        node = node_type(params_files)
        executor.add_node(node)
        executor.spin()
    except StartupError as error:
        print(f'{prog}: error: {error}', file=sys.stderr)
        code = 2
    except (KeyboardInterrupt, ExternalShutdownException):
        let_the_signal_thread_finish(rclpy.get_default_context())
    finally:
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown()
    return code
