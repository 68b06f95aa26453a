"""``laser_odom_ctl lifecycle [TRANSITION]``: drive a managed ``laser_odom`` node.

``ros2 lifecycle get|set`` for the pip set-up, which has no ``ros2`` CLI: the
``lifecycle_msgs`` services of ``laser_odom_lifecycle_node``. An unconfigured managed
node has none of the topics by which :mod:`laser_odom.ros.graph` knows a ``laser_odom``
node, so it is found by its ``~/change_state`` service and its name: ``laser_odom``
(in any namespace), or the one ``--namespace`` / ``--node-name`` give.
"""

from __future__ import annotations

import time
from typing import Any, Callable

from lifecycle_msgs.msg import Transition
from lifecycle_msgs.srv import ChangeState, GetAvailableTransitions, GetState
from rclpy.node import Node

from laser_odom.ros.graph import (
    absolute, DISCOVERY_TIMEOUT, domain_text, find_nodes, join, NODE_NAME, NodeNotFound,
    OPTIONS_HINT, STARTUP_TIMEOUT, Target)

CHANGE_STATE = 'lifecycle_msgs/srv/ChangeState'

UNCONFIGURED_PATIENCE = 1.0
"""Seconds a managed node is seen without the topics of a configured one before it is
said to be unconfigured (discovery brings a node's services and topics one by one)."""

TRANSITIONS = ('configure', 'activate', 'deactivate', 'cleanup', 'shutdown')
"""The transitions a user asks for, by label (as ``ros2 lifecycle set`` takes them)."""


def managed_nodes(node: Node) -> list[str]:
    """Return the fully qualified names of the managed nodes on the graph."""
    found = []
    for name, namespace in node.get_node_names_and_namespaces():
        fqn = join(namespace, name)
        try:
            services = node.get_service_names_and_types_by_node(name, namespace)
        except Exception:  # noqa: B902 - the node left the graph while we looked
            continue
        if any(service == f'{fqn}/change_state' and CHANGE_STATE in types
               for service, types in services):
            found.append(fqn)
    return sorted(found)


def fits(fqn: str, target: Target) -> bool:
    """Tell whether a managed node is the one the options name (default: ``laser_odom``)."""
    full = target.node_fqn()
    if full is not None:
        return fqn == full
    namespace, name = fqn.rsplit('/', 1)
    if name != (target.node_name or NODE_NAME).strip('/'):
        return False
    return target.namespace is None or (namespace or '/') == absolute(target.namespace)


def wait_for_managed(node: Node, target: Target, spin: Callable[[float], None],
                     timeout: float = DISCOVERY_TIMEOUT) -> str:
    """Wait until exactly one managed node fits ``target``; return its name."""
    end = time.monotonic() + timeout
    while True:
        fitting = [fqn for fqn in managed_nodes(node) if fits(fqn, target)]
        if len(fitting) > 1:
            raise NodeNotFound(f'{len(fitting)} managed laser_odom nodes found '
                               f'({", ".join(fitting)}); {OPTIONS_HINT}')
        if fitting:
            return fitting[0]
        if time.monotonic() > end:
            raise NodeNotFound(
                f'no managed laser_odom node found ({target.describe()}) on {domain_text()} '
                f'within {timeout:.0f} s; start one (laser_odom_lifecycle_node --ros-args '
                f'...), or, if it runs under another name, {OPTIONS_HINT}')
        spin(0.1)


class UnconfiguredWatch:
    """A wait for a ``laser_odom`` node that stops at a managed one not configured yet.

    ``status``, ``get``, ``set`` and ``reset`` look for a node by its topics, which a
    managed node builds on configure: unconfigured, it is on the graph but would be
    waited for in vain (then called absent). :meth:`spin` serves the wait and raises
    :class:`NodeNotFound` saying what to do instead.
    """

    def __init__(self, node: Node, target: Target, spin: Callable[[float], None]) -> None:
        """Watch the graph of ``node`` for a managed node that fits ``target``."""
        self._node, self._target, self._spin = node, target, spin
        self._since: float | None = None

    def spin(self, seconds: float) -> None:
        """Spin; raise NodeNotFound once only an unconfigured managed node fits."""
        self._spin(seconds)
        if any(self._target.fits(n) for n in find_nodes(self._node)):
            self._since = None
            return
        managed = [fqn for fqn in managed_nodes(self._node) if fits(fqn, self._target)]
        if len(managed) != 1:
            self._since = None
            return
        self._since = self._since or time.monotonic()
        if time.monotonic() - self._since >= UNCONFIGURED_PATIENCE:
            raise NodeNotFound(
                f'{managed[0]} is a managed node that is not configured: it has no topics '
                'or services of its own until then; configure and activate it '
                '(laser_odom_ctl lifecycle configure, then laser_odom_ctl lifecycle activate; '
                f'or ros2 lifecycle set {managed[0]} configure)')


class LifecycleClient:
    """The ``lifecycle_msgs`` services of one managed node."""

    def __init__(self, node: Node, name: str, result: Callable[..., Any],
                 timeout: float) -> None:
        """Create the clients and wait for their services (False from :attr:`ready`).

        ``result(future, what[, timeout])`` waits for an answer.
        """
        self.name = name
        self._result = result
        self._state = node.create_client(GetState, f'{name}/get_state')
        self._change = node.create_client(ChangeState, f'{name}/change_state')
        self._transitions = node.create_client(
            GetAvailableTransitions, f'{name}/get_available_transitions')
        self.ready = all(client.wait_for_service(timeout_sec=timeout) for client in (
            self._state, self._change, self._transitions))

    def state(self) -> str:
        """Return the node's state label (``unconfigured``, ``inactive``, ...)."""
        future = self._state.call_async(GetState.Request())
        return self._result(future, '~/get_state').current_state.label

    def available(self) -> list[str]:
        """Return the labels of the transitions the node's state has."""
        future = self._transitions.call_async(GetAvailableTransitions.Request())
        return [t.transition.label
                for t in self._result(future, '~/get_available_transitions')
                .available_transitions]

    def change(self, label: str) -> tuple[bool, str, list[str]]:
        """Ask for a transition; return (succeeded, the state after, what was possible).

        Configure loads the matcher's kernels: its answer may take as long as a start.
        """
        possible = self.available()
        request = ChangeState.Request(transition=Transition(label=label))
        answer = self._result(self._change.call_async(request), f'~/change_state {label}',
                              STARTUP_TIMEOUT)
        return answer.success, self.state(), possible
