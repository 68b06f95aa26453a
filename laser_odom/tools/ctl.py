"""``laser_odom_ctl``: talk to a running ``laser_odom`` node without the ``ros2`` CLI.

The pip set-up has rclpy but no ``ros2`` command (``ros2cli`` is not on the package
registries), so the node's parameters, its ``~/reset`` and ``~/set_pose`` and its
``/diagnostics`` get a small client of their own::

    laser_odom_ctl params                 # ros2 param dump /laser_odom
    laser_odom_ctl get matcher            # ros2 param get /laser_odom matcher
    laser_odom_ctl set matcher plicp      # ros2 param set /laser_odom matcher plicp
    laser_odom_ctl reset                  # ros2 service call /laser_odom/reset ...
    laser_odom_ctl reset 2.0 -1.0 0.5     # ros2 topic pub --once /laser_odom/set_pose ...
    laser_odom_ctl status                 # ros2 topic echo /diagnostics (the node's status)
    laser_odom_ctl lifecycle [configure]  # ros2 lifecycle get|set /laser_odom (managed node)

The node is found on the graph as ``laser_odom_replay --live`` finds it
(:mod:`laser_odom.ros.graph`): the one ``laser_odom`` node, in any namespace, or the
one ``--namespace`` / ``--node-name`` (or ``--ros-args -r __ns:=/robot1``) names. A
value is read as ``ros2 param set`` reads it (YAML: ``5`` an integer, which the node
takes for a floating-point parameter, ``off`` a word where it is a choice). Exit codes:
0 done, 1 the node did not answer, 2 a user mistake (no such node or parameter, a
value the node refuses) - each said in one line.
"""

from __future__ import annotations

import argparse
import difflib
import math
import sys
import time
from typing import Any, Sequence

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from geometry_msgs.msg import PoseWithCovarianceStamped
from lifecycle_msgs.srv import GetState
from rcl_interfaces.msg import Parameter as ParameterMsg
import rclpy
from rclpy.duration import Duration
from rclpy.executors import SingleThreadedExecutor
from rclpy.parameter import get_parameter_value, parameter_value_to_python
from rclpy.parameter_client import AsyncParameterClient
from rclpy.signals import SignalHandlerOptions
from std_srvs.srv import Trigger

from laser_odom.core import se2
from laser_odom.io.text_output import reader_may_leave
from laser_odom.ros.conversions import planar_pose_msg
from laser_odom.ros.default_params import yaml_value
from laser_odom.ros.graph import NodeNotFound, Target, wait_for_node
from laser_odom.tools.ctl_lifecycle import (
    LifecycleClient, TRANSITIONS, UnconfiguredWatch, wait_for_managed)

PROG = 'laser_odom_ctl'

ANSWER_TIMEOUT = 10.0
"""Seconds to wait for the node to answer a service call."""

STATUS_WAIT = 3.0
"""Seconds to wait for the node's next diagnostics report (it sends one a second)."""

CLOCK_TOPIC = '/clock'
GET_STATE = 'lifecycle_msgs/srv/GetState'

LEVELS = {DiagnosticStatus.OK: 'OK', DiagnosticStatus.WARN: 'WARN',
          DiagnosticStatus.ERROR: 'ERROR', DiagnosticStatus.STALE: 'STALE'}


class CtlError(Exception):
    """A user mistake (exit code 2); ``str(error)`` is one line."""


class NoAnswer(Exception):
    """The node did not answer in time (exit code 1)."""


def build_parser() -> argparse.ArgumentParser:
    """Return the command-line parser."""
    p = argparse.ArgumentParser(
        prog=PROG, description='Read and set the parameters of a running laser_odom node, '
        'restart its odometry and show its status, without the ros2 CLI.',
        epilog='ros2 equivalents: ros2 param dump|get|set /laser_odom ..., ros2 service '
        'call /laser_odom/reset std_srvs/srv/Trigger, ros2 topic echo /diagnostics.')
    p.add_argument('--namespace', metavar='NS',
                   help='the node runs in namespace NS (-r __ns:=NS); default: the one '
                   'laser_odom node on the graph, in any namespace')
    p.add_argument('--node-name', metavar='NAME',
                   help='the node is called NAME (-r __node:=NAME), or give NS/NAME')
    p.add_argument('--timeout', type=float, default=None, metavar='S',
                   help='seconds to wait for the node to appear (default 15)')
    commands = p.add_subparsers(dest='command', metavar='COMMAND', required=True)
    commands.add_parser('params', help='list every parameter and its value')
    get = commands.add_parser('get', help="print one parameter's value")
    get.add_argument('name')
    put = commands.add_parser('set', help='set a parameter (takes effect at the next scan)')
    put.add_argument('name')
    put.add_argument('value', help='read as YAML, as ros2 param set reads it')
    reset = commands.add_parser(
        'reset', help='restart the odometry at the origin (~/reset), or at x y yaw '
        '(~/set_pose, in odom_frame)')
    reset.add_argument('pose', nargs='*', type=float, metavar='x y yaw',
                       help='metres, metres, radians')
    commands.add_parser('status', help="print the node's diagnostics (once a second on "
                        '/diagnostics): matcher, reference (scan or local_map), prior, '
                        'counters, timing')
    lifecycle = commands.add_parser(
        'lifecycle', help="a managed node's (laser_odom_lifecycle_node) state, or a "
        'transition to it, as ros2 lifecycle get|set')
    lifecycle.add_argument('transition', nargs='?', choices=TRANSITIONS)
    return p


def split_ros_args(argv: Sequence[str]) -> tuple[list[str], list[str]]:
    """Split ``argv`` into the tool's own arguments and ``--ros-args ... [--]``."""
    argv = list(argv)
    if '--ros-args' not in argv:
        return argv, []
    start = argv.index('--ros-args')
    end = argv.index('--', start) if '--' in argv[start:] else len(argv)
    return argv[:start] + argv[end + 1:], argv[start:end]


class Ctl:
    """A short-lived rclpy node that talks to one ``laser_odom`` node."""

    def __init__(self, args: argparse.Namespace, ros_args: list[str]) -> None:
        """Start rclpy (with the ``--ros-args``) and find the node."""
        self.context = rclpy.Context()
        rclpy.init(args=['laser_odom_ctl', *ros_args], context=self.context,
                   signal_handler_options=SignalHandlerOptions.NO)
        self.node = rclpy.create_node('laser_odom_ctl', context=self.context)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        own = self.node.get_namespace()
        namespace = args.namespace if args.namespace is not None else (
            own if own != '/' else None)
        timeout = {} if args.timeout is None else {'discovery_timeout': args.timeout}
        if args.command == 'lifecycle':  # found by its services: unconfigured, it has no topics
            try:
                self.name = wait_for_managed(self.node, Target(namespace, args.node_name),
                                             self.spin, *timeout.values())
            except NodeNotFound as error:
                raise CtlError(str(error)) from None
            return
        target = Target(namespace, args.node_name)
        try:
            self.target = wait_for_node(self.node, target,
                                        UnconfiguredWatch(self.node, target, self.spin).spin,
                                        **timeout,
                                        say=lambda text: print(f'{PROG}: {text}',
                                                               file=sys.stderr))
        except NodeNotFound as error:
            raise CtlError(str(error)) from None
        self.name = self.target.name

    def close(self) -> None:
        """Destroy the node and shut rclpy down."""
        self.executor.shutdown()
        self.node.destroy_node()
        rclpy.try_shutdown(context=self.context)

    def spin(self, seconds: float) -> None:
        """Process callbacks for ``seconds``."""
        self.spin_until(lambda: False, seconds)

    def spin_until(self, done: Any, timeout: float) -> bool:
        """Process callbacks until ``done()`` or ``timeout`` seconds; return ``done()``."""
        end = time.monotonic() + timeout
        while not done():
            if time.monotonic() >= end:
                return bool(done())
            self.executor.spin_once(timeout_sec=0.05)
        return True

    def _result(self, future: Any, what: str, timeout: float = ANSWER_TIMEOUT) -> Any:
        """Wait for a service future; NoAnswer when it does not complete."""
        if not self.spin_until(future.done, timeout) or future.result() is None:
            raise NoAnswer(f'{self.name} did not answer {what} within {timeout:.0f} s')
        return future.result()

    def lifecycle(self, transition: str | None) -> str:
        """Return a managed node's state, or make a transition and return the line to say.

        CtlError (exit 2) when the state has no such transition or the node's
        callback refused it (then its own log says why).
        """
        client = LifecycleClient(self.node, self.name, self._result, ANSWER_TIMEOUT)
        if not client.ready:
            raise NoAnswer(f'{self.name} offers no lifecycle services')
        if transition is None:
            return f'{self.name}: {client.state()}'
        done, state, possible = client.change(transition)
        if done:
            return f'{self.name}: {transition} -> {state}'
        if transition not in possible:
            raise CtlError(f'{self.name} cannot {transition} from state {state} (it can: '
                           f'{", ".join(sorted(set(possible))) or "nothing"})')
        raise CtlError(f'{self.name}: {transition} failed, state {state} (its log says why)')

    def _parameters(self) -> AsyncParameterClient:
        """Return a parameter client of the node, its services ready."""
        client = AsyncParameterClient(self.node, self.name)
        if not client.wait_for_services(timeout_sec=ANSWER_TIMEOUT):
            raise NoAnswer(f'{self.name} offers no parameter services')
        return client

    def values(self, names: list[str] | None = None) -> dict[str, Any]:
        """Return the node's parameters (all, or ``names``) and their values."""
        client = self._parameters()
        if names is None:
            names = sorted(self._result(client.list_parameters(), 'list_parameters')
                           .result.names)
        answer = self._result(client.get_parameters(names), 'get_parameters')
        return {name: parameter_value_to_python(value)
                for name, value in zip(names, answer.values)}

    def set_value(self, name: str, text: str) -> Any:
        """Set a parameter from its text; CtlError with the node's reason if it refuses."""
        known = self.values()
        if name not in known:
            raise CtlError(no_parameter(self.name, name, list(known)))
        message = ParameterMsg(name=name, value=get_parameter_value(text))
        answer = self._result(self._parameters().set_parameters([message]), 'set_parameters')
        outcome = answer.results[0]
        if not outcome.successful:
            raise CtlError(f'{self.name} refused {name} = {text}: {outcome.reason}')
        return self.values([name])[name]

    def reset(self) -> str:
        """Call ``~/reset``; return the node's message."""
        client = self.node.create_client(Trigger, f'{self.name}/reset')
        if not client.wait_for_service(timeout_sec=ANSWER_TIMEOUT):
            raise NoAnswer(f'{self.name}/reset is not offered')
        return self._result(client.call_async(Trigger.Request()), '~/reset').message

    def set_pose(self, pose: se2.Pose) -> None:
        """Publish the pose on ``~/set_pose`` and wait until the node has it."""
        publisher = self.node.create_publisher(
            PoseWithCovarianceStamped, f'{self.name}/set_pose', 10)
        if not self.spin_until(lambda: publisher.get_subscription_count() > 0,
                               ANSWER_TIMEOUT):
            raise NoAnswer(f'{self.name} does not subscribe to {self.name}/set_pose')
        msg = PoseWithCovarianceStamped()
        msg.header.stamp = self.node.get_clock().now().to_msg()
        msg.pose.pose = planar_pose_msg(pose)
        publisher.publish(msg)
        if not publisher.wait_for_all_acked(Duration(seconds=ANSWER_TIMEOUT)):
            raise NoAnswer(f'{self.name} did not acknowledge the pose')

    def status(self) -> DiagnosticStatus:
        """Return the node's next diagnostics status."""
        found: list[DiagnosticStatus] = []
        source = self.name.lstrip('/')

        def keep(msg: DiagnosticArray) -> None:
            found.extend(s for s in msg.status if s.name.split(':', 1)[0] == source)

        self.node.create_subscription(DiagnosticArray, '/diagnostics', keep, 10)
        if not self.spin_until(lambda: bool(found), STATUS_WAIT):
            reason = self.silence()
            raise NoAnswer(f'no diagnostics from {self.name} within {STATUS_WAIT:.0f} s'
                           + (f': {reason}' if reason else ''))
        return found[-1]

    def lifecycle_state(self) -> str | None:
        """Return a managed node's state (``inactive``...), None for a plain node."""
        service = f'{self.name}/get_state'
        if not any(name == service and GET_STATE in types
                   for name, types in self.node.get_service_names_and_types()):
            return None
        client = self.node.create_client(GetState, service)
        if not client.wait_for_service(timeout_sec=ANSWER_TIMEOUT):
            return None
        return self._result(client.call_async(GetState.Request()),
                            '~/get_state').current_state.label

    def silence(self) -> str:
        """Return why the node sends no diagnostics, when it can be told ('' if not).

        A managed node publishes nothing unless it is active. A node on sim time
        reports once a second of its ROS time, which stands still until ``/clock``
        moves: with nothing publishing ``/clock`` the report never comes.
        """
        state = self.lifecycle_state()
        if state is not None and state != 'active':
            return (f'it is a managed node in state {state}, which publishes nothing; '
                    f'activate it ({PROG} lifecycle activate, or ros2 lifecycle set '
                    f'{self.name} activate)')
        if not self.values(['use_sim_time'])['use_sim_time']:
            return ''
        clocks = self.node.count_publishers(CLOCK_TOPIC)
        if clocks == 0:
            return ('it runs on sim time (use_sim_time is true) and nothing publishes '
                    '/clock, so its ROS time stands still and its once-a-second report '
                    'never comes; publish /clock (ros2 bag play --clock, laser_odom_replay '
                    f'--live --clock) or run it with use_sim_time false ({PROG} set '
                    'use_sim_time false)')
        return (f'it runs on sim time (use_sim_time is true): it reports once a second of '
                f'/clock time, and /clock ({clocks} publisher{"s" if clocks > 1 else ""}) '
                'has not moved on by a second - paused?')


def no_parameter(node: str, name: str, known: list[str]) -> str:
    """Return the error for a parameter the node does not have, with the likely intent.

    The closest declared name (difflib, as the node's own warning for a params file)
    is the intent of a typo (``max_scan_gapp``); else a matcher parameter given
    without its matcher (``max_iterations``: ``nicp.max_iterations``).
    """
    close = difflib.get_close_matches(name, known, n=1, cutoff=0.8) or [
        n for n in known if n.endswith('.' + name) or name in n]
    hint = f' (did you mean {close[0]!r}?)' if close else ''
    return f'{node} has no parameter {name!r}{hint}; {PROG} params lists them'


def status_lines(status: DiagnosticStatus) -> list[str]:
    """Return a diagnostics status as ``name: LEVEL message`` and ``  key: value`` lines."""
    level = LEVELS.get(status.level, str(status.level))
    return [f'{status.name}: {level} {status.message}'] + [
        f'  {kv.key}: {kv.value}' for kv in status.values]


def run(args: argparse.Namespace, ros_args: list[str]) -> int:
    """Carry out one command; return the exit code."""
    if args.command == 'reset' and len(args.pose) not in (0, 3):
        raise CtlError('reset takes no pose or all of x y yaw')
    if args.command == 'reset' and not all(math.isfinite(v) for v in args.pose):
        raise CtlError(f'reset: the pose must be finite, got {" ".join(map(str, args.pose))}')
    try:
        ctl = Ctl(args, ros_args)
    except (CtlError, NoAnswer):
        raise
    except Exception as error:  # noqa: B902 - malformed --ros-args (rclpy's RCLError)
        lines = str(error).strip().splitlines()
        raise CtlError(lines[0] if lines else repr(error)) from None
    try:
        if args.command == 'params':
            for name, value in ctl.values().items():
                print(f'{name}: {yaml_value(value)}')
        elif args.command == 'get':
            values = ctl.values()
            if args.name not in values:
                raise CtlError(no_parameter(ctl.name, args.name, list(values)))
            value = values[args.name]
            print(value if isinstance(value, str) else yaml_value(value))
        elif args.command == 'set':
            value = ctl.set_value(args.name, args.value)
            print(f'{ctl.name}: {args.name} = {yaml_value(value)}')
        elif args.command == 'reset' and args.pose:
            ctl.set_pose(se2.pose(*args.pose))
            print(f'{ctl.name}: odometry restarted from x={args.pose[0]:g} '
                  f'y={args.pose[1]:g} yaw={args.pose[2]:g}')
        elif args.command == 'reset':
            print(f'{ctl.name}: {ctl.reset()}')
        elif args.command == 'lifecycle':
            print(ctl.lifecycle(args.transition))
        else:
            print('\n'.join(status_lines(ctl.status())))
    finally:
        ctl.close()
    return 0


def main(argv: Sequence[str] | None = None) -> int:
    """Run ``laser_odom_ctl``; return the exit code."""
    own, ros_args = split_ros_args(sys.argv[1:] if argv is None else argv)
    args = build_parser().parse_args(own)
    try:
        with reader_may_leave():
            return run(args, ros_args)
    except CtlError as error:
        print(f'{PROG}: error: {error}', file=sys.stderr)
        return 2
    except NoAnswer as error:
        print(f'{PROG}: error: {error}', file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        return 130


if __name__ == '__main__':
    sys.exit(main())
