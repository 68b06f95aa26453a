"""``laser_odom_lifecycle_node``: the ``laser_odom`` node as a managed (lifecycle) node.

The same node as ``laser_odom_node`` (:class:`laser_odom.ros.node.LaserOdomNode`: one
pipeline, one message builder), driven through the standard ``lifecycle_msgs``
services (``~/change_state``, ``~/get_state``, ...) as ``ros2 lifecycle set`` or a
lifecycle manager (nav2's, launch_ros's ``LifecycleNode``) drive it:

- *unconfigured* (as it starts): the parameters are declared and can be read and set
  (``ros2 param set``, ``laser_odom_ctl`` once configured); nothing else exists.
- ``configure``: the pipeline, topics, services and diagnostics timer are built from
  the parameters as they are now (the kernels are warmed up here), and the start-up
  line is logged. *inactive*: scans are received but not matched, nothing is
  published - no odometry, pose, TF or ``/diagnostics``.
- ``activate``: odometry flows (the first scan after it is a new reference if the gap
  since the last one exceeds ``max_scan_gap``); ``deactivate`` stops it again.
- ``cleanup``: everything ``configure`` built is destroyed (back to *unconfigured*,
  parameters kept); ``shutdown``: the same, to *finalized*, where the process stays
  until it is stopped (as a managed node's does in ROS 2) for introspection.

A scan that arrives while the node is inactive is dropped at the subscription, before
the pipeline, so the pose and the counters stay as they were.
"""

from __future__ import annotations

import sys
from typing import Any, Sequence

from lifecycle_msgs.srv import ChangeState
from rclpy.impl.implementation_singleton import rclpy_implementation as _rclpy
from rclpy.lifecycle import LifecycleNodeMixin, LifecycleState, TransitionCallbackReturn
from sensor_msgs.msg import LaserScan as LaserScanMsg

from laser_odom.io.params_file import ParamsFile
from laser_odom.ros import node as plain
from laser_odom.ros.diagnostics import ScanGapCounter
from laser_odom.ros.run import interrupted, run_node
from laser_odom.ros.usage import usage

PROG = 'laser_odom_lifecycle_node'

ENTITY_KINDS = (('publishers', 'destroy_publisher'), ('subscriptions', 'destroy_subscription'),
                ('services', 'destroy_service'), ('clients', 'destroy_client'),
                ('timers', 'destroy_timer'), ('guards', 'destroy_guard_condition'))
"""What a configure builds, by the Node property that lists it and its destroyer."""

CLOCK_TOPIC = '/clock'
"""rclpy's own sim-time subscription: it belongs to the node, not to a configure."""

SUCCESS = TransitionCallbackReturn.SUCCESS
FAILURE = TransitionCallbackReturn.FAILURE


class LaserOdomLifecycleNode(LifecycleNodeMixin, plain.LaserOdomNode):
    """The ``laser_odom`` node, built on configure and publishing only while active."""

    def __init__(self, params_files: Sequence[ParamsFile] = (), **kwargs) -> None:
        """Declare the parameters (judged as the plain node judges them) and wait.

        Raises :class:`laser_odom.ros.live.StartupError` for invalid given values, as
        the plain node does: a managed node's parameters come from the same files.
        """
        self._configured = False
        self._active = False
        self._own: dict[str, set] = {}
        plain.LaserOdomNode.__init__(self, params_files, **kwargs)
        LifecycleNodeMixin.__init__(self)
        self._refuse_unknown_transitions()

    def _refuse_unknown_transitions(self) -> None:
        """Answer a transition the state does not have with ``success: false``.

        rclpy raises from its ``~/change_state`` callback there (rclcpp answers
        false), which would stop the executor: an ``activate`` sent too early must
        not end the node.
        """
        service = self._service_change_state
        change_state = service.callback

        def guarded(request: ChangeState.Request,
                    response: ChangeState.Response) -> ChangeState.Response:
            try:
                return change_state(request, response)
            except _rclpy.RCLError as error:
                self.get_logger().warning(
                    f'transition {request.transition.label or request.transition.id} '
                    f'refused: {str(error).split(",")[0]}')
                response.success = False
                return response
        service.callback = guarded

    def _setup(self, params_files: Sequence[ParamsFile]) -> None:
        """Only declare the parameters: the rest is built on configure."""
        self._declare(params_files)
        self.params.start()

    def _entities(self) -> dict[str, set]:
        """Return the node's publishers, subscriptions, services... as they are now."""
        return {kind: set(getattr(self, kind)) for kind, _ in ENTITY_KINDS}

    def _destroy_built(self) -> None:
        """Destroy what configure created (all made since, but rclpy's /clock reader)."""
        for kind, destroyer in ENTITY_KINDS:
            for entity in set(getattr(self, kind)) - self._own.get(kind, set()):
                if kind == 'subscriptions' and entity.topic_name == CLOCK_TOPIC:
                    continue
                getattr(self, destroyer)(entity)
        self._waiting = None
        self.pipeline = None
        self._configured = False

    def on_configure(self, state: LifecycleState) -> TransitionCallbackReturn:
        """Build the pipeline and the node's interfaces from the current parameters."""
        self._own = self._entities()
        try:
            self._build()
        except Exception as error:  # noqa: B902 - said in one line; the node stays unconfigured
            self._destroy_built()
            if interrupted(error):  # Ctrl-C while a kernel compiled or ran
                raise KeyboardInterrupt() from error
            self.get_logger().error(f'configure failed: {error}')
            return FAILURE
        self._configured = True
        self._log_startup()
        return super().on_configure(state)

    def on_activate(self, state: LifecycleState) -> TransitionCallbackReturn:
        """Start matching and publishing."""
        self._gaps = ScanGapCounter()  # the scans dropped while inactive are no gap
        self._active = True
        self.get_logger().info('activated: matching scans and publishing odometry')
        return super().on_activate(state)

    def on_deactivate(self, state: LifecycleState) -> TransitionCallbackReturn:
        """Stop matching and publishing; the pose is kept."""
        self._active = False
        self._waiting = None
        self.get_logger().info('deactivated: scans are dropped, nothing is published')
        return super().on_deactivate(state)

    def on_cleanup(self, state: LifecycleState) -> TransitionCallbackReturn:
        """Destroy the pipeline and the node's interfaces (the parameters stay)."""
        self._destroy_built()
        self.get_logger().info('cleaned up: configure builds the node again')
        return super().on_cleanup(state)

    def on_shutdown(self, state: LifecycleState) -> TransitionCallbackReturn:
        """Stop and destroy what is built, from whatever state."""
        self._active = False
        if self._configured:
            self._destroy_built()
        self.get_logger().info('shut down (finalized)')
        return super().on_shutdown(state)

    def on_error(self, state: LifecycleState) -> TransitionCallbackReturn:
        """Recover to unconfigured after a failed transition."""
        self._active = False
        if self._configured:
            self._destroy_built()
        return super().on_error(state)

    def _on_settings(self, changed: dict) -> None:
        """Apply changes while configured; before that, keep them for configure."""
        if self._configured:
            super()._on_settings(changed)
            return
        self.get_logger().info('parameters set (applied on configure): ' + ', '.join(
            f'{k}={v!r}' for k, v in sorted(changed.items())))

    def _on_scan(self, msg: LaserScanMsg, info: dict[str, Any]) -> None:
        """Match the scan only while active."""
        if self._active:
            super()._on_scan(msg, info)

    def _publish_diagnostics(self) -> None:
        """Report health only while active (nothing is published while inactive)."""
        if self._active:
            super()._publish_diagnostics()


LIFECYCLE_USAGE = f"""\
{PROG}: laser_odom_node as a managed (lifecycle) node. It starts
unconfigured; drive it with the lifecycle_msgs services (ros2 lifecycle set /laser_odom
configure|activate|deactivate|cleanup|shutdown, or a lifecycle manager). The parameters
are applied on configure; nothing is published unless it is active.
"""


def lifecycle_usage() -> str:
    """Return the managed node's help: the usage line, what is its own, the node's rest.

    It starts with ``usage:`` as every tool's help does (``ros2 run ... --help``).
    """
    plain_usage = usage().replace(
        '\n' + ' ' * len('usage: laser_odom_node '), '\n' + ' ' * len(f'usage: {PROG} '), 1)
    synopsis, rest = plain_usage.replace('laser_odom_node', PROG).split('\n\n', 1)
    return f'{synopsis}\n\n{LIFECYCLE_USAGE}\n{rest}'


def main(args: list[str] | None = None) -> int:
    """Run the managed node until Ctrl-C; return the exit code (2 for bad parameters)."""
    return run_node(args, LaserOdomLifecycleNode, PROG, lifecycle_usage)


if __name__ == '__main__':
    sys.exit(main())
