"""Read laser scans, wheel odometry and IMU data from ROS 1 and ROS 2 bags.

One entry point, :func:`open_bag`, accepts a ROS 2 bag directory (sqlite3 or mcap
storage), a single ``.db3`` or ``.mcap`` file, or a ROS 1 ``.bag`` file. Sound bags
are read with rosbags' ``AnyReader``; bags it refuses - a ROS 1 bag with a missing or
non-standard index, a recording cut short - are read record by record (see
:mod:`laser_odom.io.ros1_records` and :mod:`laser_odom.io.ros2_salvage`), so every
message that is intact is delivered, and then :class:`BagTruncatedError` says at
which message reading stopped. Messages come out as the core's types
(:class:`~laser_odom.core.scan.laser_scan.LaserScan`,
:class:`~laser_odom.core.trajectory.Trajectory`).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, Collection, Iterator

import numpy as np

from laser_odom.core import se2
from laser_odom.core.scan.laser_scan import LaserScan
from laser_odom.core.trajectory import ImuSamples, Trajectory
from laser_odom.io.bag_sources import (
    Message, Ros1RecordSource, Ros2SalvageSource, RosbagsSource, SourceReadError)
from laser_odom.io.ros1_records import MAGIC as ROS1_MAGIC
from laser_odom.io.ros2_salvage import MCAP_MAGIC
from laser_odom.io.sqlite_pages import SQLITE_MAGIC

LASER_SCAN = 'sensor_msgs/msg/LaserScan'
ODOMETRY = 'nav_msgs/msg/Odometry'
IMU = 'sensor_msgs/msg/Imu'


class BagError(Exception):
    """A bag cannot be read as asked; ``str(error)`` is a one-line explanation."""


class BagNotFoundError(BagError):
    """The bag path does not exist."""


class BagFormatError(BagError):
    """The path exists but holds no readable ROS 1 or ROS 2 bag."""


class TopicError(BagError):
    """The wanted topic is missing, of the wrong type, or ambiguous."""


class BagTruncatedError(BagError):
    """Reading stopped at damaged data after ``message_index`` messages were delivered.

    ``message_index`` counts the messages of the requested topics, from 0; it is the
    index of the first one that could not be read.
    """

    def __init__(self, path: Path, message_index: int, reason: str) -> None:
        """Store where reading stopped and why."""
        super().__init__(f'{path}: bag is truncated or corrupt; reading stopped at message '
                         f'{message_index} ({reason})')
        self.path = path
        self.message_index = message_index
        self.reason = reason


def stamp_to_ns(stamp: Any) -> int:
    """Return a ``builtin_interfaces/Time`` (ROS 1 or 2) in integer nanoseconds."""
    return int(stamp.sec) * 1_000_000_000 + int(stamp.nanosec)


def scan_from_msg(msg: Any) -> LaserScan:
    """Convert a ``sensor_msgs/LaserScan`` (rosbags or rclpy object) to the core type."""
    intensities = np.asarray(msg.intensities, dtype=float)
    return LaserScan(
        stamp_ns=stamp_to_ns(msg.header.stamp), angle_min=float(msg.angle_min),
        angle_max=float(msg.angle_max), angle_increment=float(msg.angle_increment),
        range_min=float(msg.range_min), range_max=float(msg.range_max),
        ranges=np.asarray(msg.ranges, dtype=float),
        intensities=intensities if intensities.size else None,
        frame_id=str(msg.header.frame_id), time_increment=float(msg.time_increment),
        scan_time=float(msg.scan_time))


def pose_from_odometry(msg: Any) -> se2.Pose:
    """Return the planar pose ``[x, y, yaw]`` of a ``nav_msgs/Odometry``."""
    p, q = msg.pose.pose.position, msg.pose.pose.orientation
    return se2.pose(p.x, p.y, se2.quaternion_to_yaw(q.x, q.y, q.z, q.w))


def _sniff(path: Path) -> bytes:
    """Return the first bytes of a file."""
    with path.open('rb') as f:
        return f.read(16)


def _storage_files(directory: Path) -> list[Path]:
    """Return a ROS 2 bag directory's storage files, in recording order."""
    return sorted(p for p in directory.iterdir() if p.suffix in ('.db3', '.mcap'))


class BagReader:
    """A readable bag: its topics, and its messages as core types."""

    def __init__(self, path: str | Path) -> None:
        """Open a bag; raise :class:`BagNotFoundError` or :class:`BagFormatError`."""
        self.path = Path(path)
        if not self.path.exists():
            raise BagNotFoundError(f'bag not found: {self.path}')
        self.strict_error: str | None = None
        self._source = self._open_source()
        self.topics: dict[str, str] = dict(self._source.topics)
        self.counts: dict[str, int] = dict(self._source.counts)
        """Messages per topic from the bag's index; empty for a bag read record by record."""

    def _open_source(self) -> Any:
        """Open with rosbags, or fall back to the record-by-record readers."""
        path = self.path
        if path.is_dir():
            files = _storage_files(path)
            strict_ok = (path / 'metadata.yaml').exists() or len(files) == 1
            strict_path = path if (path / 'metadata.yaml').exists() else (files or [path])[0]
            kind = 'ros2'
            if not files:
                raise BagFormatError(f'{path}: no ROS 2 storage file (.db3, .mcap) inside')
        else:
            magic = _sniff(path)
            if magic.startswith(ROS1_MAGIC[:12]):
                kind, strict_ok = 'ros1', path.suffix == '.bag'
            elif magic.startswith(MCAP_MAGIC[:5]) or magic.startswith(SQLITE_MAGIC):
                kind, strict_ok = 'ros2', path.suffix in ('.db3', '.mcap')
            else:
                raise BagFormatError(f'{path}: not a ROS 1 or ROS 2 bag')
            strict_path, files = path, [path]
        if strict_ok:
            try:
                return RosbagsSource(strict_path)
            except Exception as err:  # noqa: B902 - rosbags raises many types; fall back
                self.strict_error = f'{type(err).__name__}: {err}'.strip()
        try:
            return Ros1RecordSource(path) if kind == 'ros1' else Ros2SalvageSource(files)
        except (ValueError, OSError) as err:
            raise BagFormatError(f'{path}: unreadable bag ({err})') from None

    def close(self) -> None:
        """Close the bag."""
        self._source.close()

    def __enter__(self) -> BagReader:
        """Return self for ``with`` blocks."""
        return self

    def __exit__(self, *exc: object) -> None:
        """Close the bag."""
        self.close()

    def topics_of_type(self, msgtype: str) -> list[str]:
        """Return the topics carrying ``msgtype`` (``pkg/msg/Type``), sorted."""
        return sorted(t for t, typ in self.topics.items() if typ == msgtype)

    def select_topic(self, msgtype: str, requested: str | None = None,
                     option: str = '--scan-topic') -> str:
        """Return ``requested`` if the bag has it with ``msgtype``, else the only such topic.

        Raises :class:`TopicError` (none, several, wrong type) - or
        :class:`BagTruncatedError` when nothing at all could be read from a damaged bag.
        """
        name = msgtype.rsplit('/', 1)[-1]
        candidates = self.topics_of_type(msgtype)
        if requested is not None:
            requested = requested if requested.startswith('/') else '/' + requested
            there = (f'; its {name} topics: {", ".join(candidates)}' if candidates
                     else f'; it has no {name} topic')
            if requested not in self.topics:
                raise TopicError(f'{self.path}: no topic {requested} in the bag{there}')
            if self.topics[requested] != msgtype:
                raise TopicError(f'{self.path}: topic {requested} is '
                                 f'{self.topics[requested]}, not {msgtype}{there}')
            return requested
        if not candidates:
            if not self.topics and self.strict_error is not None:
                raise BagTruncatedError(self.path, 0, self.strict_error)
            raise TopicError(f'{self.path}: no {name} topic in the bag')
        if len(candidates) > 1:
            raise TopicError(f'{self.path}: several {name} topics ({", ".join(candidates)}); '
                             f'choose one with {option}')
        return candidates[0]

    def message_count(self, topic: str) -> int | None:
        """Return how many messages ``topic`` holds by the bag's index (None: unknown)."""
        return self.counts.get(topic)

    def messages(self, topics: Collection[str]) -> Iterator[Message]:
        """Yield ``(topic, log_time_ns, message)`` of ``topics``.

        Raises :class:`BagTruncatedError` after the last readable message of a damaged bag.
        """
        count = 0
        try:
            for item in self._source.messages(set(topics)):
                yield item
                count += 1
        except SourceReadError as err:
            raise BagTruncatedError(self.path, count, str(err)) from None

    def scans(self, topic: str | None = None) -> Iterator[LaserScan]:
        """Yield the scans of ``topic`` (default: the bag's only LaserScan topic)."""
        topic = self.select_topic(LASER_SCAN, topic)
        for _, _, msg in self.messages([topic]):
            yield scan_from_msg(msg)

    def odometry(self, topic: str | None, strict: bool = True) -> Trajectory:
        """Return the poses of a ``nav_msgs/Odometry`` topic, sorted by header stamp.

        With ``strict=False`` a damaged bag gives the poses read before the damage.
        """
        topic = self.select_topic(ODOMETRY, topic, '--odom-topic')
        stamps, poses = [], []
        try:
            for _, _, msg in self.messages([topic]):
                stamps.append(stamp_to_ns(msg.header.stamp))
                poses.append(pose_from_odometry(msg))
        except BagTruncatedError:
            if strict:
                raise
        return _sorted_trajectory(stamps, poses)

    def imu(self, topic: str | None, strict: bool = True) -> ImuSamples:
        """Return the yaw and yaw rate of a ``sensor_msgs/Imu`` topic, sorted by stamp.

        ``yaw`` is NaN for samples without orientation (``orientation_covariance[0]`` is
        -1, REP-145). With ``strict=False`` a damaged bag gives the samples before the damage.
        """
        topic = self.select_topic(IMU, topic, '--imu-topic')
        stamps, yaw, rate = [], [], []
        try:
            for _, _, msg in self.messages([topic]):
                stamps.append(stamp_to_ns(msg.header.stamp))
                q = msg.orientation
                has_orientation = float(msg.orientation_covariance[0]) != -1.0
                yaw.append(se2.quaternion_to_yaw(q.x, q.y, q.z, q.w)
                           if has_orientation else np.nan)
                rate.append(float(msg.angular_velocity.z))
        except BagTruncatedError:
            if strict:
                raise
        order = np.argsort(np.asarray(stamps, dtype=np.int64), kind='stable')
        return ImuSamples(np.asarray(stamps, dtype=np.int64)[order],
                          np.asarray(yaw, dtype=float)[order],
                          np.asarray(rate, dtype=float)[order])


def _sorted_trajectory(stamps: list[int], poses: list[np.ndarray]) -> Trajectory:
    """Return a trajectory sorted by stamp, duplicate stamps dropped (first kept)."""
    stamps_arr = np.asarray(stamps, dtype=np.int64)
    unique, first = np.unique(stamps_arr, return_index=True)
    return Trajectory(unique, np.asarray(poses, dtype=float).reshape(-1, 3)[first])


def open_bag(path: str | Path) -> BagReader:
    """Open a ROS 1 or ROS 2 bag (see :class:`BagReader`)."""
    return BagReader(path)
