"""``laser_odom_replay --live``: drive a running ``laser_odom_node`` with a bag's scans.

Lock-step (the default): the scans are published one at a time on the node's scan
topic; after each, the replay waits (``--timeout``) for the node's ``nav_msgs/Odometry``
carrying that scan's stamp before sending the next, so the node - which keeps only the
newest scan - never drops one for backlog, and the trajectory is the offline one. With
``--prior odom|imu`` the bag's wheel odometry / IMU samples up to each scan (and the
first one after it) are published on the node's prior topics first.

``--rate R``: the scans and the prior samples are published in stamp order at ``R``
times their recorded rate (:mod:`laser_odom.tools.playback`, like ``ros2 bag play
--rate``), without waiting; the node skips the scans that arrive while it is busy, as
it would on the robot. At the end the replay waits (``--timeout``) for the odometry of
the last scan; the trajectory is the odometry that arrived (a skipped scan has none).

``--clock``: ``/clock`` carries each scan's stamp before the scan, for a node on sim
time (:mod:`laser_odom.tools.replay_clock`).

The time from publishing a scan to receiving its odometry is the round-trip latency
reported. The node's own figures are read from its ``/diagnostics`` by key (the
difference between a report before the first scan and one after the last): scans
received and processed, failed and degenerate matches (``nav_msgs/Odometry`` carries
no match status), scans not processed because the node was busy, scans dropped before
reaching it, and its receipt-to-publish latency (:mod:`laser_odom.tools.replay_figures`).
"""

from __future__ import annotations

import argparse
from functools import partial
import itertools
import sys
import time
from typing import Any, Callable, Iterator

from diagnostic_msgs.msg import DiagnosticArray
from nav_msgs.msg import Odometry
import numpy as np
import rclpy
from rclpy.executors import SingleThreadedExecutor
from rclpy.qos import QoSProfile, ReliabilityPolicy
from rclpy.signals import SignalHandlerOptions
from sensor_msgs.msg import Imu, LaserScan as LaserScanMsg
from std_srvs.srv import Trigger

from laser_odom.core.motion.priors import PriorFeed
from laser_odom.core.scan.laser_scan import LaserScan
from laser_odom.io.bag_reader import BagTruncatedError
from laser_odom.ros.conversions import (
    covariance_3x3, imu_msg, odometry_pose_from_msg, scan_to_msg, stamp_to_ns,
    wheel_odometry_msg)
from laser_odom.ros.graph import (
    DISCOVERY_TIMEOUT, domain_text, find_nodes, join, NODE_NAME, NodeNotFound, OdometryNode,
    OPTIONS_HINT, wait_for_node)
from laser_odom.ros.priors import PRIOR_TOPICS
from laser_odom.tools.playback import play, RecordedClock
from laser_odom.tools.replay_clock import ReplayClock, TICK
from laser_odom.tools.replay_figures import count, read_report
from laser_odom.tools.replay_report import ReplayError, ReplayRecord
from laser_odom.tools.replay_target import answer_timeout, live_target

DIAGNOSTICS_WAIT = 2.5
"""Seconds to wait for a diagnostics report (the node sends one per second)."""

RELIABLE = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE)


class _Client:
    """The replay's ROS side: publishers, the odometry and diagnostics subscriptions."""

    def __init__(self, args: argparse.Namespace, prior: str) -> None:
        """Create the node in its own context and find the odometry node to drive.

        The node and its topics come from the graph (:mod:`laser_odom.ros.graph`),
        narrowed by ``--namespace``, ``--node-name`` and the topic options; the wait
        lasts as long as a node that fits is still starting.
        """
        self.context = rclpy.Context()
        rclpy.init(context=self.context, signal_handler_options=SignalHandlerOptions.NO)
        self.node = rclpy.create_node('laser_odom_replay', context=self.context)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        self.target = live_target(args)
        # --timeout bounds the whole wait for the node (to appear, start, subscribe).
        self.deadline = None if args.timeout is None else time.monotonic() + args.timeout
        self.timeout = args.timeout
        found = self._find(args)
        target = self.target
        self.node_name = found.name if found else (
            target.node_fqn() or args.node_name or NODE_NAME)
        namespace = target.namespace if target.namespace is not None else ''
        scan_topic = target.scan_topic or (found.scan_topic if found else None) or join(
            namespace, 'scan')
        odom_topic = target.odom_topic or (found.odom_topic if found else None) or join(
            namespace, 'odom')
        self.scan_pub = self.node.create_publisher(LaserScanMsg, scan_topic, RELIABLE)
        self.prior, self.found, self.prior_pub = prior, found, None
        self._open_prior(found, join(namespace, PRIOR_TOPICS.get(prior, '')))
        self.odometry: dict[int, tuple[Odometry, float]] = {}
        self.odom_sub = self.node.create_subscription(
            Odometry, odom_topic, self._on_odometry, RELIABLE)
        self.diagnostics: dict[str, str] | None = None
        self.diagnostics_count = 0
        self.node.create_subscription(DiagnosticArray, '/diagnostics', self._on_diagnostics,
                                      RELIABLE)
        self.clock = ReplayClock(self.node) if getattr(args, 'clock', False) else None
        reset = self.node_name if self.node_name.startswith('/') else f'/{self.node_name}'
        self.reset_client = self.node.create_client(Trigger, f'{reset}/reset')

    def _find(self, args: argparse.Namespace) -> OdometryNode | None:
        """Return the ``laser_odom`` node on the graph that fits the options.

        Given both topics, or a namespace, the replay can drive whatever node uses
        them (``NS/scan``, ``NS/odom``): if no ``laser_odom`` node fits, it goes on
        without one and waits for the topics to be matched.
        """
        target = self.target
        fallback = bool(target.scan_topic and target.odom_topic) or target.namespace is not None
        discovery = DISCOVERY_TIMEOUT if self.deadline is None else args.timeout
        bounded = {} if self.deadline is None else {'startup_timeout': args.timeout}
        try:
            return wait_for_node(
                self.node, target, lambda seconds: self.spin_until(lambda: False, seconds),
                discovery_timeout=discovery / 3 if fallback else discovery, **bounded,
                say=None if args.quiet else (
                    lambda message: print(f'--live: {message}', file=sys.stderr, flush=True)),
                more_options='; with remapped topics, --scan-topic-out and --odom-topic-in')
        except NodeNotFound as error:
            if fallback and str(error).startswith('no laser_odom node'):
                return None
            raise ReplayError(f'--live: {error}') from None

    def _open_prior(self, found: OdometryNode | None, guessed: str) -> None:
        """Publish the ``--prior`` samples where ``found`` reads them, else on ``guessed``."""
        self.prior_listened = found is not None and self.prior in found.prior_topics
        if self.prior not in PRIOR_TOPICS:
            return
        topic = found.prior_topics.get(self.prior) if self.prior_listened else guessed
        if self.prior_pub is not None:
            if self.prior_pub.topic_name == topic:
                return
            self.node.destroy_publisher(self.prior_pub)
        self.prior_pub = self.node.create_publisher(
            Odometry if self.prior == 'odom' else Imu, topic, RELIABLE)

    def _adopt(self) -> None:
        """Take the node as the graph now shows it (seen late, or its prior topic seen late)."""
        fitting = [n for n in find_nodes(self.node) if self.target.fits(n) and n.ready]
        if len(fitting) == 1:
            self.found, self.node_name = fitting[0], fitting[0].name
            self._open_prior(self.found, getattr(self.prior_pub, 'topic_name', ''))

    def close(self) -> None:
        """Destroy the node and shut the context down."""
        self.executor.shutdown()
        self.node.destroy_node()
        rclpy.try_shutdown(context=self.context)

    def _on_odometry(self, msg: Odometry) -> None:
        """Keep each odometry message by its stamp, with its arrival time."""
        self.odometry[stamp_to_ns(msg.header.stamp)] = (msg, time.perf_counter())

    def _is_odometry_node(self, status_name: str) -> bool:
        """Tell whether a status (named ``[ns/]node: ...``) comes from the odometry node.

        A bare node name (no node found on the graph) matches that node in any namespace.
        """
        source = status_name.split(':', 1)[0].strip('/')
        name = self.node_name.strip('/')
        return source == name or (
            '/' not in name and source.rsplit('/', 1)[-1] == name)

    def _on_diagnostics(self, msg: DiagnosticArray) -> None:
        """Keep the newest status of the odometry node."""
        for status in msg.status:
            if self._is_odometry_node(status.name):
                self.diagnostics = {kv.key: kv.value for kv in status.values}
                self.diagnostics_count += 1

    def spin_until(self, done: Any, timeout: float) -> bool:
        """Spin until ``done()`` is true or ``timeout`` seconds pass; return ``done()``."""
        deadline = time.monotonic() + timeout
        while not done():
            remaining = deadline - time.monotonic()
            if remaining <= 0.0:
                return bool(done())
            self.executor.spin_once(timeout_sec=min(remaining, 0.05))
        return True

    def wait_for_node(self) -> None:
        """Wait until the node's scan subscription and odometry publisher are matched.

        When the node listens to the prior's topic, its subscription is waited for too:
        the first prior messages would otherwise be lost while it is being matched. The
        graph fills in meanwhile: a node not seen when looked for, or its (remapped)
        prior topic, is taken as it appears (:meth:`_adopt`).
        """
        def matched() -> bool:
            if self.found is None or (self.prior in PRIOR_TOPICS and not self.prior_listened):
                self._adopt()
            return (self.scan_pub.get_subscription_count() > 0
                    and self.odom_sub.get_publisher_count() > 0
                    and (not self.prior_listened or self.prior_pub.get_subscription_count() > 0))

        timeout = DISCOVERY_TIMEOUT if self.deadline is None else max(
            self.deadline - time.monotonic(), 0.0)
        if not self.spin_until(matched, timeout):
            within = DISCOVERY_TIMEOUT if self.deadline is None else self.timeout
            raise ReplayError(
                f'--live: nothing subscribes to {self.scan_pub.topic_name} and publishes '
                f'{self.odom_sub.topic_name} on {domain_text()} within '
                f'{within:g} s; start laser_odom_node, or {OPTIONS_HINT}')
        self.spin_until(lambda: False, 0.3)  # let the node's side of the match settle
        self.spin_until(matched, 1.0)  # a look more: a prior topic seen late is matched too

    def reset_node(self) -> bool:
        """Call the node's ``~/reset`` so the replay starts from the origin."""
        if not self.reset_client.wait_for_service(timeout_sec=2.0):
            return False
        future = self.reset_client.call_async(Trigger.Request())
        self.spin_until(future.done, 5.0)
        return future.done() and future.result() is not None and future.result().success

    def publish_clock(self, stamp_ns: int) -> None:
        """Set the node's sim time to ``stamp_ns`` (with ``--clock``; else nothing)."""
        if self.clock is not None:
            self.clock.publish(stamp_ns)

    def diagnostics_after(self, count: int) -> dict[str, str] | None:
        """Return the first diagnostics report newer than report number ``count``.

        With ``--clock`` the clock runs on meanwhile: the report is paced by it.
        """
        def arrived() -> bool:
            return self.diagnostics_count > count

        if self.clock is None:
            self.spin_until(arrived, DIAGNOSTICS_WAIT)
        else:
            tick, deadline = self.clock.running(), time.monotonic() + DIAGNOSTICS_WAIT
            while not arrived() and time.monotonic() < deadline:
                tick()
                self.spin_until(arrived, TICK)
        return self.diagnostics if arrived() else None

    def publish_priors(self, feed: PriorFeed, indices: range) -> None:
        """Publish the given prior samples on the node's prior topic."""
        if self.prior_pub is None:
            return
        for i in indices:
            if feed.odometry_samples is not None:
                odometry = feed.odometry_samples
                msg = wheel_odometry_msg(int(odometry.stamps_ns[i]), odometry.poses[i])
            else:
                imu = feed.imu_samples
                msg = imu_msg(int(imu.stamps_ns[i]), float(imu.yaw[i]), float(imu.yaw_rate[i]))
            self.prior_pub.publish(msg)


def _record_answer(record: ReplayRecord, msg: Odometry, seconds: float) -> None:
    """Record the node's odometry of one scan, ``seconds`` after the scan was sent."""
    stamp, pose = odometry_pose_from_msg(msg)
    record.add(stamp, pose, covariance_3x3(msg.pose.covariance), 'received', seconds)
    if record.messages is not None:
        record.messages.add_received(stamp, msg)


def _progress(record: ReplayRecord, args: argparse.Namespace) -> None:
    """Print a progress line every 500 scans (unless --quiet); stop here on Ctrl-C."""
    if not args.quiet and record.scans_read % 500 == 0:
        print(f'{record.scans_read} scans replayed so far (live)', file=sys.stderr, flush=True)
    if record.stop is not None:
        record.stop.check()


def _run_lock_step(client: _Client, scans: Iterator[LaserScan], feed: PriorFeed,
                   record: ReplayRecord, args: argparse.Namespace) -> None:
    """Publish each scan and wait for its odometry before the next."""
    for scan in scans:
        record.scans_read += 1
        client.publish_clock(scan.stamp_ns)
        client.publish_priors(feed, feed.advance(scan.stamp_ns))
        sent = time.perf_counter()
        client.scan_pub.publish(scan_to_msg(scan))
        if client.spin_until(lambda: scan.stamp_ns in client.odometry, answer_timeout(args)):
            msg, arrived = client.odometry.pop(scan.stamp_ns)
            _record_answer(record, msg, arrived - sent)
        else:
            record.counters['no_answer'] = record.counters.get('no_answer', 0) + 1
        _progress(record, args)


def _timeline(scans: Iterator[LaserScan], feed: PriorFeed, client: _Client,
              record: ReplayRecord, send: Callable[[int, LaserScanMsg], None],
              clock: RecordedClock) -> Iterator[tuple[float, Callable[[], None]]]:
    """Yield ``(offset, publish)`` for the scans and prior samples, in stamp order.

    Before each scan come the prior samples stamped up to it, each at its own time;
    of those older than the first scan only the newest is sent (the node needs no more).
    """
    stamps = feed.stamps()
    first: int | None = None
    for scan in scans:
        end = int(np.searchsorted(stamps, scan.stamp_ns, side='right'))
        if first is None:
            first = max(end - 1, 0)
        for i in range(first, end):
            yield clock.offset(int(stamps[i])), partial(
                client.publish_priors, feed, range(i, i + 1))
        first = max(first, end)
        record.scans_read += 1
        msg = scan_to_msg(scan)  # built before its time comes
        yield clock.offset(scan.stamp_ns), partial(send, scan.stamp_ns, msg)


def _run_at_rate(client: _Client, scans: Iterator[LaserScan], feed: PriorFeed,
                 record: ReplayRecord, args: argparse.Namespace) -> None:
    """Publish the scans at ``--rate`` times their recorded rate, without waiting.

    The odometry that arrived is recorded even when the bag turns out damaged or
    the replay is interrupted.
    """
    sent: dict[int, float] = {}

    def send(stamp_ns: int, msg: LaserScanMsg) -> None:
        client.publish_clock(stamp_ns)
        sent[stamp_ns] = time.perf_counter()
        client.scan_pub.publish(msg)
        _progress(record, args)

    record.rate = args.rate
    interrupted = False
    try:
        record.late = play(_timeline(scans, feed, client, record, send,
                                     RecordedClock(args.rate)),
                           wait=lambda seconds: client.spin_until(lambda: False, seconds))
    except KeyboardInterrupt:
        interrupted = True
        raise
    finally:
        if sent and not interrupted:
            _settle(client, list(sent), answer_timeout(args))
        for stamp_ns, at in sent.items():
            answer = client.odometry.pop(stamp_ns, None)
            if answer is not None:
                _record_answer(record, answer[0], answer[1] - at)
        record.counters['no_answer'] = len(sent) - len(record.stamps_ns)
        answered = set(record.stamps_ns)
        taken = [i for i, stamp in enumerate(sent) if stamp in answered]
        record.after_last = len(sent) - 1 - taken[-1] if taken else len(sent)


def _settle(client: _Client, sent: list[int], timeout: float) -> None:
    """Wait for the answer to the last scan sent, as long as the node keeps answering.

    A node that fell behind is still working through the run when the playback ends;
    while its answers keep coming (each within ``timeout``) it is waited for, so that
    every scan is either answered or counted by the node as skipped or dropped.
    """
    last = sent[-1]
    while last not in client.odometry:
        count = len(client.odometry)
        if not client.spin_until(lambda: len(client.odometry) > count
                                 or last in client.odometry, timeout):
            return


def run_live(scans: Iterator[LaserScan], feed: PriorFeed, record: ReplayRecord,
             args: argparse.Namespace) -> None:
    """Publish every scan to the node and record the odometry it answers with."""
    client = _Client(args, feed.prior)
    try:
        client.wait_for_node()
        record.node_name, record.sent_topic = client.node_name, client.scan_pub.topic_name
        if client.clock is not None:  # the clock starts a little before the first scan
            scans = iter(scans)
            first = next(scans, None)
            if first is not None:
                scans = itertools.chain([first], scans)
                client.clock.start_before(first.stamp_ns)
        before = client.diagnostics_after(client.diagnostics_count)
        # A fresh node starts at the origin: a reset would only say so in its log.
        if before is None or count(before, 'scans in') > 0:
            if not client.reset_node() and not args.quiet:
                print(f'--live: could not call {client.node_name}/reset; the node keeps its '
                      'pose')
        try:
            if getattr(args, 'rate', None) is None:
                _run_lock_step(client, scans, feed, record, args)
            else:
                _run_at_rate(client, scans, feed, record, args)
        except BagTruncatedError:
            read_report(client, before, record)  # what was replayed still counts
            raise
        read_report(client, before, record)
    finally:
        client.close()
