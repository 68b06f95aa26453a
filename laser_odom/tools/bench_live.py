"""``laser_odom_bench --live``: whether the node keeps up with a fast laser, per matcher.

For each matcher, a fresh ``laser_odom_node`` process is started on a private ROS
domain and simulated scans (default 1081 beams over 270 deg, like a Hokuyo UTM-30LX)
are published to it at the sensor rate (default 40 Hz for 60 s), without waiting for
answers. The table says how many scans the node processed, how many got no answer,
and of those, from the node's diagnostics, how many were not processed because the
node was busy (it never queues: a scan arriving while it matches replaces the waiting
one) and how many were dropped before reaching the node (lost on the way); then the
receipt-to-publish latency the node measured, the end-to-end latency seen by the
publisher (scan sent -> odometry received, DDS included), and what the node costs:
its CPU time over the stream as a share of one core (from /proc, all its threads:
DDS, diagnostics and the matcher), the seconds from starting its process to being
ready (subscribed and publishing, after loading or compiling its kernels), and the
end-to-end latency of the first scan it gets.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import partial
import math
import os
from pathlib import Path
import random
import signal
import subprocess
import sys
import tempfile
import threading
import time
from typing import Sequence

from diagnostic_msgs.msg import DiagnosticArray
from nav_msgs.msg import Odometry
import numpy as np
import rclpy
from rclpy.context import Context
from rclpy.executors import SingleThreadedExecutor
from rclpy.qos import QoSProfile, ReliabilityPolicy
from rclpy.signals import SignalHandlerOptions
from sensor_msgs.msg import LaserScan as LaserScanMsg

from laser_odom.core.simulation import LaserModel, simulate
from laser_odom.ros.conversions import scan_to_msg, stamp_to_ns
from laser_odom.ros.diagnostics import BUSY_KEY, DROPPED_KEY
from laser_odom.tools.playback import play

STARTUP_TIMEOUT = 30.0
"""Seconds to wait for a node to come up (discovery included)."""

DISCOVERY_SETTLE = 1.0
"""Seconds between seeing the node's subscription and the first scan: the publisher
sees the match before the node's side has finished it, and a best-effort scan sent in
between is lost on the way (not by the node)."""


@dataclass
class LiveRow:
    """What one matcher did with a stream of scans.

    ``skipped`` is the number of scans without an answer (sent - processed); ``busy``
    and ``dropped`` are the node's own counts of the scans it did not process because
    it was busy and of those that never reached it.
    """

    matcher: str
    sent: int
    processed: int
    skipped: int
    node_median_ms: float
    node_p95_ms: float
    e2e_median_ms: float
    e2e_p95_ms: float
    busy: int = 0
    dropped: int = 0
    cpu_percent: float = math.nan
    process_median_ms: float = math.nan
    ready_s: float = math.nan
    first_ms: float = math.nan
    reference: str = 'scan'
    """The node's ``reference`` setting (``scan`` or ``local_map``)."""


def process_cpu_seconds(pid: int) -> float:
    """Return the user + system CPU seconds a process has used (Linux /proc), else nan."""
    try:
        fields = Path(f'/proc/{pid}/stat').read_text().rsplit(')', 1)[1].split()
    except (OSError, IndexError):
        return math.nan
    # After the command name: state is field 3, utime and stime are fields 14 and 15.
    return (int(fields[11]) + int(fields[12])) / os.sysconf('SC_CLK_TCK')


class LiveSession:
    """One node process and a publisher/subscriber peer on a private domain."""

    def __init__(self, matcher: str, domain_id: int, reference: str = 'scan',
                 params_file: Path | None = None) -> None:
        """Start the node with ``matcher`` matching against ``reference``, and the peer.

        ``params_file`` (``--params-file``) is the node's too; ``matcher`` and
        ``reference`` override it, as ``-p`` overrides a params file in ROS 2.
        """
        env = dict(os.environ, ROS_DOMAIN_ID=str(domain_id))
        root = str(Path(__file__).resolve().parents[2])
        env['PYTHONPATH'] = os.pathsep.join(p for p in (root, env.get('PYTHONPATH', '')) if p)
        self.log = tempfile.TemporaryFile('w+')
        self.started = time.monotonic()
        self.process = subprocess.Popen(
            [sys.executable, '-m', 'laser_odom.ros.node', '--ros-args',
             *(['--params-file', str(params_file)] if params_file is not None else []),
             '-p', f'matcher:={matcher}', '-p', f'reference:={reference}', '-p',
             'publish_tf:=false'],
            env=env, stdout=self.log, stderr=subprocess.STDOUT)
        self.context = Context()
        rclpy.init(context=self.context, domain_id=domain_id,
                   signal_handler_options=SignalHandlerOptions.NO)
        self.node = rclpy.create_node('laser_odom_bench_live', context=self.context)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        self.publisher = self.node.create_publisher(LaserScanMsg, 'scan', 10)
        self.received: dict[int, float] = {}
        self.diagnostics: dict[str, str] = {}
        reliable = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE)
        self.node.create_subscription(Odometry, 'odom', self._on_odom, reliable)
        self.node.create_subscription(DiagnosticArray, '/diagnostics', self._on_diag, 10)

    def _on_odom(self, msg: Odometry) -> None:
        self.received[stamp_to_ns(msg.header.stamp)] = time.monotonic()

    def _on_diag(self, msg: DiagnosticArray) -> None:
        for status in msg.status:
            if status.name.endswith(': odometry'):
                self.diagnostics = {kv.key: kv.value for kv in status.values}

    def spin_until(self, predicate, timeout: float) -> bool:
        """Process callbacks until ``predicate`` holds or ``timeout`` passes."""
        end = time.monotonic() + timeout
        while time.monotonic() < end and not predicate():
            self.executor.spin_once(timeout_sec=0.01)
        return predicate()

    def close(self) -> None:
        """Stop the node (Ctrl-C) and the peer."""
        if self.process.poll() is None:
            self.process.send_signal(signal.SIGINT)
            try:
                self.process.wait(20)
            except subprocess.TimeoutExpired:
                self.process.kill()
        self.executor.shutdown()
        self.node.destroy_node()
        rclpy.try_shutdown(context=self.context)


def run_matcher(matcher: str, messages: list, rate: float, reference: str = 'scan',
                params_file: Path | None = None) -> LiveRow:
    """Stream ``messages`` at ``rate`` Hz to a fresh node running ``matcher``."""
    session = LiveSession(matcher, random.randint(101, 230), reference, params_file)
    try:
        if not session.spin_until(lambda: session.publisher.get_subscription_count() > 0
                                  and session.node.count_publishers('odom') > 0,
                                  STARTUP_TIMEOUT):
            session.log.seek(0)
            raise RuntimeError(f'{matcher}: node did not start: {session.log.read()[-500:]}')
        ready_s = time.monotonic() - session.started
        session.spin_until(lambda: False, DISCOVERY_SETTLE)
        sent: dict[int, float] = {}
        spinner = threading.Thread(target=session.spin_until,
                                   args=(lambda: False, len(messages) / rate + 3.0))
        spinner.start()

        def send(stamp: int, msg: LaserScanMsg) -> None:
            sent[stamp] = time.monotonic()
            session.publisher.publish(msg)

        cpu_start, wall_start = process_cpu_seconds(session.process.pid), time.monotonic()
        play((index / rate, partial(send, stamp, msg))
             for index, (stamp, msg) in enumerate(messages))
        spinner.join()
        cpu_percent = 100.0 * ((process_cpu_seconds(session.process.pid) - cpu_start)
                               / (time.monotonic() - wall_start))
        first = messages[0][0]
        latencies = np.array([session.received[s] - sent[s] for s in sent
                              if s in session.received])
        diag = session.diagnostics
        return LiveRow(
            matcher, len(sent), len(latencies), len(sent) - len(latencies),
            float(diag.get('latency median [ms]', 'nan').replace('n/a', 'nan')),
            float(diag.get('latency p95 [ms]', 'nan').replace('n/a', 'nan')),
            float(np.median(latencies) * 1e3) if len(latencies) else math.nan,
            float(np.percentile(latencies, 95) * 1e3) if len(latencies) else math.nan,
            int(diag.get(BUSY_KEY, '0')), int(diag.get(DROPPED_KEY, '0')), cpu_percent,
            float(diag.get('processing time median [ms]', 'nan')), ready_s,
            (session.received[first] - sent[first]) * 1e3 if first in session.received
            else math.nan, reference)
    finally:
        session.close()


def run_live(matchers: Sequence[str], beams: int, rate: float, duration: float,
             fov_deg: float = 270.0, references: Sequence[str] = ('scan',),
             params_file: Path | None = None) -> list[LiveRow]:
    """Run every matcher against every reference on one simulated stream; return the rows.

    Every node is started with ``params_file`` (``--params-file``), if given.
    """
    laser = LaserModel(beams=beams, fov=math.radians(fov_deg), rate=rate, max_range=30.0)
    dataset = simulate('office', duration=duration, laser=laser, seed=7)
    messages = [(scan.stamp_ns, scan_to_msg(scan)) for scan in dataset.scans]
    return [run_matcher(matcher, messages, rate, reference, params_file)
            for matcher in matchers for reference in references]


def format_live(rows: Sequence[LiveRow], beams: int, rate: float, duration: float) -> str:
    """Return the live benchmark table."""
    lines = [f'# live: {beams} beams at {rate:g} Hz for {duration:g} s, published to a '
             'fresh laser_odom_node per matcher',
             f'{"matcher":<8} {"reference":<9} {"sent":>6} {"processed":>9} {"no answer":>9} '
             f'{"busy":>6} {"dropped":>7} {"node med ms":>11} {"node p95 ms":>11} '
             f'{"e2e med ms":>10} {"e2e p95 ms":>10} {"proc ms":>7} {"CPU %":>6} {"ready s":>7} '
             f'{"first ms":>8}']
    for r in rows:
        lines.append(f'{r.matcher:<8} {r.reference:<9} {r.sent:>6} {r.processed:>9} '
                     f'{r.skipped:>9} '
                     f'{r.busy:>6} {r.dropped:>7} '
                     f'{r.node_median_ms:>11.2f} {r.node_p95_ms:>11.2f} '
                     f'{r.e2e_median_ms:>10.2f} {r.e2e_p95_ms:>10.2f} '
                     f'{r.process_median_ms:>7.2f} {r.cpu_percent:>6.1f} {r.ready_s:>7.2f} '
                     f'{r.first_ms:>8.1f}')
    lines.append('# sent: scans published; processed: scans whose odometry came back; no '
                 'answer: sent - processed, of which the node counted')
    lines.append(f'#   busy: {BUSY_KEY}; dropped: {DROPPED_KEY} (both from its '
                 '/diagnostics; the rest was lost after the node)')
    lines.append('# node: receipt -> publish inside the node (its /diagnostics); e2e: '
                 'publish of the scan -> receipt of its odometry by the publisher')
    lines.append("# proc ms: the pipeline's own median time per scan (the rest of 'node' is "
                 "the node's message conversion and publishing); CPU %: the node process over the")
    lines.append('#   stream, 100 = one core; ready s: process start -> subscribed and '
                 'publishing; first ms: e2e of the first scan')
    return '\n'.join(lines)
