"""Finding a running ``laser_odom`` node on the ROS graph, by itself or as the user names it.

``laser_odom_replay --live`` and ``laser_odom_ctl`` talk to a node that another process
started, perhaps in a namespace (``-r __ns:=/robot1``), renamed (``-r __node:=front``)
or with remapped topics. Rather than assume ``/laser_odom`` on ``/scan``, they look at
the graph: a ``laser_odom`` node is one that publishes ``<node>/matched_scan``
(``sensor_msgs/PointCloud2``) and ``nav_msgs/Odometry`` - both made as it starts, before
it compiles or loads its kernels - and it is *ready* once it also subscribes to
``sensor_msgs/LaserScan`` and offers ``<node>/reset`` (made after the warm-up). Its
actual topic names come from the graph, so remapped topics are found too.

:class:`Target` is what the user asked for (``--namespace``, ``--node-name`` and the
topic options); :func:`find_nodes` and :func:`wait_for_node` pick the one node that
fits, or raise :class:`NodeNotFound` with a one-line message naming the options to use.
"""

from __future__ import annotations

from dataclasses import dataclass, field
import os
import time
from typing import Callable, TYPE_CHECKING

if TYPE_CHECKING:  # the names and Target are ROS-free: the offline replay uses them
    from rclpy.node import Node

LASER_SCAN = 'sensor_msgs/msg/LaserScan'
ODOMETRY = 'nav_msgs/msg/Odometry'
IMU = 'sensor_msgs/msg/Imu'
POINT_CLOUD = 'sensor_msgs/msg/PointCloud2'
TRIGGER = 'std_srvs/srv/Trigger'

NODE_NAME = 'laser_odom'
"""The node's default name."""

DISCOVERY_TIMEOUT = 30.0
"""Seconds to wait for a ``laser_odom`` node to appear on the graph (one started just
before may take that long to import and join it on a busy machine)."""

PATIENCE = 3.0
"""Seconds after which a wait for a node that has not appeared says what it waits for."""

STARTUP_TIMEOUT = 300.0
"""Seconds to wait for a node that is on the graph but still starting (warming up)."""

OPTIONS_HINT = ('name it with --namespace NS (node NS/laser_odom on NS/scan and NS/odom) '
                'or --node-name NAME')
"""How to name the node when it cannot be found by itself."""


class NodeNotFound(RuntimeError):
    """No (or more than one) ``laser_odom`` node fits; ``str(error)`` is one line."""


@dataclass(frozen=True)
class OdometryNode:
    """A ``laser_odom`` node on the graph: its name and the topics it actually uses."""

    name: str
    """Fully qualified name, e.g. ``/robot1/laser_odom``."""
    odom_topic: str
    scan_topic: str | None = None
    """None while the node is starting (it subscribes once its kernels are ready)."""
    prior_topics: dict[str, str] = field(default_factory=dict)
    """``odom`` / ``imu``: the wheel odometry and IMU topics it subscribes to, if any."""
    has_reset: bool = False

    @property
    def ready(self) -> bool:
        """Tell whether the node takes scans and answers ``~/reset``."""
        return self.scan_topic is not None and self.has_reset

    @property
    def namespace(self) -> str:
        """Return the namespace the node runs in: ``/`` at the root."""
        return self.name.rsplit('/', 1)[0] or '/'


def join(namespace: str, name: str) -> str:
    """Return ``name`` under ``namespace`` (an absolute name stays as it is)."""
    if name.startswith('/'):
        return name
    return '/'.join(['', *namespace.strip('/').split('/'), name]).replace('//', '/')


def absolute(namespace: str) -> str:
    """Return a namespace as an absolute name: ``robot1`` is ``/robot1``, ``/`` stays."""
    return '/' + namespace.strip('/')


@dataclass(frozen=True)
class Target:
    """Which node the user means: any given part narrows the search, the rest is found.

    ``node_name`` with a slash (``robot1/laser_odom``) is a full name; a bare one
    (``front_odom``) is that node in ``namespace``, or in any namespace without one.
    ``namespace`` alone means the ``laser_odom`` node there (whatever it is called).
    """

    namespace: str | None = None
    node_name: str | None = None
    scan_topic: str | None = None
    odom_topic: str | None = None

    def node_fqn(self) -> str | None:
        """Return the fully qualified node name the options give, or None (find it)."""
        if self.node_name is not None:
            bare = self.node_name.strip('/')
            if '/' in bare or self.node_name.startswith('/'):
                return '/' + bare
            return join(self.namespace, bare) if self.namespace is not None else None
        if self.namespace is not None:
            return join(self.namespace, NODE_NAME)
        return None

    def fits(self, node: OdometryNode) -> bool:
        """Tell whether a node on the graph is the one the options name."""
        if self.node_name is not None:
            full = self.node_fqn()
            if full is not None and node.name != full:
                return False
            if full is None and node.name.rsplit('/', 1)[-1] != self.node_name.strip('/'):
                return False
        elif self.namespace is not None and node.namespace != absolute(self.namespace):
            return False
        if self.scan_topic is not None and node.scan_topic not in (None, self.scan_topic):
            return False
        return self.odom_topic is None or node.odom_topic == self.odom_topic

    def describe(self) -> str:
        """Return what was asked for, for messages."""
        parts = [f'{label} {value}' for label, value in (
            ('--namespace', self.namespace), ('--node-name', self.node_name),
            ('scan topic', self.scan_topic), ('odometry topic', self.odom_topic)) if value]
        return ', '.join(parts) or 'any name and namespace'


def _topics(pairs: list[tuple[str, list[str]]], msgtype: str) -> list[str]:
    """Return the topics of ``pairs`` (name, types) that carry ``msgtype``."""
    return sorted(name for name, types in pairs if msgtype in types)


def find_nodes(node: 'Node') -> list[OdometryNode]:
    """Return the ``laser_odom`` nodes on the graph, as ``node`` sees it now."""
    found = []
    for name, namespace in node.get_node_names_and_namespaces():
        fqn = join(namespace, name)
        try:
            publishers = node.get_publisher_names_and_types_by_node(name, namespace)
            if f'{fqn}/matched_scan' not in _topics(publishers, POINT_CLOUD):
                continue
            odom = _topics(publishers, ODOMETRY)
            subscriptions = node.get_subscriber_names_and_types_by_node(name, namespace)
            services = node.get_service_names_and_types_by_node(name, namespace)
        except Exception:  # noqa: B902 - the node left the graph while we looked
            continue
        if not odom:
            continue
        scans = _topics(subscriptions, LASER_SCAN)
        priors = {kind: topics[0] for kind, topics in (
            ('odom', _topics(subscriptions, ODOMETRY)), ('imu', _topics(subscriptions, IMU)))
            if topics}
        found.append(OdometryNode(fqn, odom[0], scans[0] if scans else None, priors,
                                  f'{fqn}/reset' in _topics(services, TRIGGER)))
    return sorted(found, key=lambda n: n.name)


def domain_text() -> str:
    """Return which ROS domain this process is on, for messages."""
    domain = os.environ.get('ROS_DOMAIN_ID')
    return f'ROS_DOMAIN_ID {domain}' if domain else 'ROS_DOMAIN_ID 0 (unset)'


def wait_for_node(node: 'Node', target: Target, spin: Callable[[float], None],
                  discovery_timeout: float = DISCOVERY_TIMEOUT,
                  startup_timeout: float = STARTUP_TIMEOUT,
                  say: Callable[[str], None] | None = None,
                  more_options: str = '') -> OdometryNode:
    """Wait until exactly one ready ``laser_odom`` node fits ``target``; return it.

    ``spin(seconds)`` lets ``node`` take in the graph. A node that fits but is still
    starting (compiling or loading its kernels) is waited for up to ``startup_timeout``;
    ``say`` hears once that it is; ``more_options`` adds the caller's own options to
    the message when none is found. Raises :class:`NodeNotFound` when none fits within
    ``discovery_timeout``, when several do, or when the one that does never gets ready.
    """
    start = time.monotonic()
    told = announced = False
    settle_until: float | None = None
    while True:
        fitting = [n for n in find_nodes(node) if target.fits(n)]
        ready = [n for n in fitting if n.ready]
        elapsed = time.monotonic() - start
        if len(fitting) > 1:
            names = ', '.join(n.name for n in fitting)
            raise NodeNotFound(f'{len(fitting)} laser_odom nodes found ({names}); '
                               f'{OPTIONS_HINT}')
        if ready:
            # Discovery is gradual: give a second node a moment to show up.
            settle_until = settle_until or time.monotonic() + 0.3
            if time.monotonic() >= settle_until:
                return ready[0]
        elif fitting:
            if say is not None and not told:
                say(f'waiting for {fitting[0].name} to finish starting (it compiles or '
                    'loads its kernels before it subscribes to scans)')
                told = True
            if elapsed > startup_timeout:
                raise NodeNotFound(f'{fitting[0].name} did not finish starting within '
                                   f'{startup_timeout:.0f} s')
        elif say is not None and not announced and elapsed > PATIENCE:
            say(f'waiting for a laser_odom node ({target.describe()}) on {domain_text()}')
            announced = True
        if not fitting and elapsed > discovery_timeout:
            raise NodeNotFound(
                f'no laser_odom node found ({target.describe()}) on {domain_text()} within '
                f'{discovery_timeout:.0f} s; start one (laser_odom_node --ros-args ..., or '
                f'ros2 run laser_odom laser_odom_node), or, if it runs under another name, '
                f'{OPTIONS_HINT}{more_options}')
        spin(0.1)
