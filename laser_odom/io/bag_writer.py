"""Write scans and trajectories to a ROS 2 bag (sqlite3 or mcap) with rosbags.

Scans become ``sensor_msgs/msg/LaserScan``, odometry topics ``nav_msgs/msg/Odometry``
(pose, optional pose covariance, and a twist from finite differences) and pose topics
``geometry_msgs/msg/PoseStamped``. Messages are written in stamp order and each
message's bag time is its header stamp, so a replay by bag time and a replay by
header stamp agree. The bag is built in a hidden temporary directory beside the
target and renamed into place at the end: a failure never leaves a half-written bag,
and an existing path is never overwritten.
"""

from __future__ import annotations

import heapq
from pathlib import Path
import shutil
import tempfile
from typing import Any, Iterator, Mapping, Sequence

import numpy as np
from rosbags.rosbag2 import StoragePlugin, Writer, WriterError
from rosbags.typesys import get_typestore, Stores

from laser_odom.core import se2
from laser_odom.core.scan.laser_scan import LaserScan
from laser_odom.core.trajectory import Trajectory
from laser_odom.io.errors import BagWriteError, OutputExistsError

STORAGES = {'sqlite3': StoragePlugin.SQLITE3, 'mcap': StoragePlugin.MCAP}
"""Storage plugins by their ``ros2 bag`` name."""

BAG_VERSION = 9
"""rosbag2 metadata version written by ROS 2 Jazzy."""

LASER_SCAN = 'sensor_msgs/msg/LaserScan'
ODOMETRY = 'nav_msgs/msg/Odometry'
POSE_STAMPED = 'geometry_msgs/msg/PoseStamped'
COVARIANCE_INDEX = np.array([0, 1, 5])
"""Rows/columns of x, y and yaw in a ROS 6x6 ``[x y z roll pitch yaw]`` covariance."""

_TYPESTORE = get_typestore(Stores.ROS2_JAZZY)
_T = _TYPESTORE.types


def _time(stamp_ns: int) -> Any:
    """Return a ``builtin_interfaces/msg/Time``."""
    sec, nanosec = divmod(int(stamp_ns), 1_000_000_000)
    return _T['builtin_interfaces/msg/Time'](sec=sec, nanosec=nanosec)


def _header(stamp_ns: int, frame_id: str) -> Any:
    """Return a ``std_msgs/msg/Header``."""
    return _T['std_msgs/msg/Header'](stamp=_time(stamp_ns), frame_id=frame_id)


def _pose_msg(p: np.ndarray) -> Any:
    """Return a ``geometry_msgs/msg/Pose`` of a planar pose."""
    qx, qy, qz, qw = se2.yaw_to_quaternion(float(p[2]))
    return _T['geometry_msgs/msg/Pose'](
        position=_T['geometry_msgs/msg/Point'](x=float(p[0]), y=float(p[1]), z=0.0),
        orientation=_T['geometry_msgs/msg/Quaternion'](x=qx, y=qy, z=qz, w=qw))


def _vector(x: float, y: float, z: float) -> Any:
    """Return a ``geometry_msgs/msg/Vector3``."""
    return _T['geometry_msgs/msg/Vector3'](x=float(x), y=float(y), z=float(z))


def scan_message(scan: LaserScan) -> Any:
    """Return the rosbags ``sensor_msgs/msg/LaserScan`` of a core scan."""
    intensities = (np.zeros(0, dtype=np.float32) if scan.intensities is None
                   else np.asarray(scan.intensities, dtype=np.float32))
    return _T[LASER_SCAN](
        header=_header(scan.stamp_ns, scan.frame_id), angle_min=float(scan.angle_min),
        angle_max=float(scan.angle_max), angle_increment=float(scan.angle_increment),
        time_increment=float(scan.time_increment), scan_time=float(scan.scan_time),
        range_min=float(scan.range_min), range_max=float(scan.range_max),
        ranges=np.asarray(scan.ranges, dtype=np.float32), intensities=intensities)


def body_twists(trajectory: Trajectory) -> np.ndarray:
    """Return ``[vx, vy, wz]`` in the base frame at every pose (backward differences).

    The twist at pose k is ``relative(T_k-1, T_k) / dt`` (REP-105: the twist of an
    odometry message is expressed in its child frame); the first pose takes the
    second's. A single pose has zero twist.
    """
    n = len(trajectory)
    out = np.zeros((n, 3))
    if n < 2:
        return out
    p = trajectory.poses
    dt = np.diff(trajectory.stamps_ns) * 1e-9
    d = np.diff(p, axis=0)
    c, s = np.cos(p[:-1, 2]), np.sin(p[:-1, 2])
    step = np.column_stack((c * d[:, 0] + s * d[:, 1], -s * d[:, 0] + c * d[:, 1],
                            se2.wrap_angle(d[:, 2])))
    with np.errstate(divide='ignore', invalid='ignore'):
        out[1:] = np.where(dt[:, None] > 0.0, step / dt[:, None], 0.0)
    out[0] = out[1]
    return out


def _embed(covariance: np.ndarray | None) -> np.ndarray:
    """Return the flat 6x6 covariance holding a 3x3 ``[x, y, yaw]`` block (zeros: unknown)."""
    full = np.zeros((6, 6))
    if covariance is not None:
        full[np.ix_(COVARIANCE_INDEX, COVARIANCE_INDEX)] = covariance
    return full.reshape(36)


def odometry_messages(trajectory: Trajectory, frame_id: str, child_frame_id: str,
                      covariances: np.ndarray | None = None) -> Iterator[tuple[int, Any]]:
    """Yield ``(stamp_ns, nav_msgs/msg/Odometry)`` for every pose of ``trajectory``."""
    twists = body_twists(trajectory)
    zero = np.zeros(36)
    for i, stamp in enumerate(trajectory.stamps_ns):
        cov = None if covariances is None else covariances[i]
        pose = _T['geometry_msgs/msg/PoseWithCovariance'](
            pose=_pose_msg(trajectory.poses[i]), covariance=_embed(cov))
        twist = _T['geometry_msgs/msg/TwistWithCovariance'](
            twist=_T['geometry_msgs/msg/Twist'](
                linear=_vector(twists[i, 0], twists[i, 1], 0.0),
                angular=_vector(0.0, 0.0, twists[i, 2])),
            covariance=zero)
        yield int(stamp), _T[ODOMETRY](header=_header(int(stamp), frame_id),
                                       child_frame_id=child_frame_id, pose=pose, twist=twist)


def pose_messages(trajectory: Trajectory, frame_id: str) -> Iterator[tuple[int, Any]]:
    """Yield ``(stamp_ns, geometry_msgs/msg/PoseStamped)`` for every pose."""
    for i, stamp in enumerate(trajectory.stamps_ns):
        yield int(stamp), _T[POSE_STAMPED](header=_header(int(stamp), frame_id),
                                           pose=_pose_msg(trajectory.poses[i]))


def _check_covariances(topic: str, trajectory: Trajectory, cov: np.ndarray) -> np.ndarray:
    """Return ``cov`` as (N, 3, 3) matching the trajectory, or raise ValueError."""
    cov = np.asarray(cov, dtype=float)
    if cov.shape != (len(trajectory), 3, 3):
        raise ValueError(f'covariances of {topic} must have shape ({len(trajectory)}, 3, 3), '
                         f'not {cov.shape}')
    return cov


def write_bag(path: str | Path, scans: Sequence[LaserScan] = (),
              odometry: Mapping[str, Trajectory] | None = None,
              poses: Mapping[str, Trajectory] | None = None, scan_topic: str = '/scan',
              storage: str = 'sqlite3', odom_frame: str = 'odom',
              base_frame: str = 'base_link',
              covariances: Mapping[str, np.ndarray] | None = None,
              frame_ids: Mapping[str, str] | None = None,
              scan_record_times: Sequence[int] | None = None) -> None:
    """Write a ROS 2 bag at ``path`` (a directory, as ``ros2 bag record`` makes).

    Scans are recorded at their header stamps, in stamp order, unless
    ``scan_record_times`` gives each scan's recording time [ns]: then they are written
    in the given order at those times, whatever their header stamps (a bag recorded
    while a simulator restarted, or a looped playback).

    ``odometry`` and ``poses`` map topic names to trajectories; their header frame is
    ``odom_frame`` unless ``frame_ids`` names another for the topic, and odometry's
    child frame is ``base_frame``. ``covariances`` maps odometry topics to (N, 3, 3)
    ``[x, y, yaw]`` pose covariances. Raises :class:`OutputExistsError` if ``path``
    exists, :class:`BagWriteError` if the bag cannot be written, ValueError for bad
    arguments.
    """
    odometry = dict(odometry or {})
    poses = dict(poses or {})
    covariances = dict(covariances or {})
    frame_ids = dict(frame_ids or {})
    if storage not in STORAGES:
        raise ValueError(f'unknown storage {storage!r}; valid: {", ".join(STORAGES)}')
    topics = ([scan_topic] if len(scans) else []) + list(odometry) + list(poses)
    if len(set(topics)) != len(topics):
        raise ValueError(f'a topic appears twice among {topics}')
    unknown = set(covariances) - set(odometry)
    if unknown:
        raise ValueError(f'covariances given for topics that are not odometry: {sorted(unknown)}')
    covariances = {t: _check_covariances(t, odometry[t], c) for t, c in covariances.items()}
    for topic, traj in [*odometry.items(), *poses.items()]:
        if np.any(np.diff(traj.stamps_ns) < 0):
            raise ValueError(f'stamps of {topic} are not in increasing order')
    streams: list[tuple[str, str, Iterator[tuple[int, Any]]]] = []
    if scan_record_times is not None:
        if len(scan_record_times) != len(scans) or np.any(np.diff(scan_record_times) < 0):
            raise ValueError('scan_record_times needs one increasing time per scan')
        streams.append((scan_topic, LASER_SCAN, (
            (int(t), scan_message(s)) for t, s in zip(scan_record_times, scans))))
    elif len(scans):
        order = sorted(scans, key=lambda s: s.stamp_ns)
        streams.append((scan_topic, LASER_SCAN,
                        ((s.stamp_ns, scan_message(s)) for s in order)))
    for topic, traj in odometry.items():
        streams.append((topic, ODOMETRY, odometry_messages(
            traj, frame_ids.get(topic, odom_frame), base_frame, covariances.get(topic))))
    for topic, traj in poses.items():
        streams.append((topic, POSE_STAMPED,
                        pose_messages(traj, frame_ids.get(topic, odom_frame))))

    _write_atomically(Path(path), storage, streams)


def canonical_cdr(data: bytes, msgtype: str) -> bytes:
    """Return a serialised message with its alignment padding zeroed.

    The middleware leaves whatever was in its buffer in the padding between fields, so
    the same message can travel as different bytes; decoded and encoded again, every
    field keeps its exact bytes and the padding becomes zeros.
    """
    return bytes(_TYPESTORE.serialize_cdr(_TYPESTORE.deserialize_cdr(data, msgtype), msgtype))


def _canonical(messages: Sequence[tuple[int, bytes]],
               msgtype: str) -> Iterator[tuple[int, bytes]]:
    """Yield ``(stamp, canonical bytes)`` of serialised messages of one type."""
    for stamp, data in messages:
        yield stamp, canonical_cdr(data, msgtype)


def write_message_bag(path: str | Path,
                      topics: Mapping[str, tuple[str, Sequence[tuple[int, bytes]]]],
                      storage: str = 'sqlite3') -> None:
    """Write already serialised (CDR) messages: ``{topic: (type, [(stamp_ns, data)])}``.

    Each topic's messages must be in stamp order; their bag time is their stamp. Used
    for messages that must be stored as a node publishes them: every field's bytes are
    kept, the padding is zeroed (:func:`canonical_cdr`) so that the same messages
    always make the same bag.
    """
    if storage not in STORAGES:
        raise ValueError(f'unknown storage {storage!r}; valid: {", ".join(STORAGES)}')
    streams = [(topic, msgtype, _canonical(messages, msgtype))
               for topic, (msgtype, messages) in topics.items()]
    _write_atomically(Path(path), storage, streams)


def _write_atomically(path: Path, storage: str,
                      streams: list[tuple[str, str, Iterator[tuple[int, Any]]]]) -> None:
    """Write the bag in a hidden staging directory and rename it into place."""
    if path.exists() or path.is_symlink():
        raise OutputExistsError(f'{path} exists already; not overwriting it')
    parent = path.parent
    if not parent.is_dir():
        raise BagWriteError(f'cannot write {path}: directory {parent} does not exist')
    try:
        staging = Path(tempfile.mkdtemp(prefix=f'.{path.name}.', suffix='.partial', dir=parent))
    except OSError as error:
        raise BagWriteError(f'cannot write {path}: {error.strerror or error}') from None
    try:
        _write(staging / path.name, STORAGES[storage], streams)
        if path.exists():
            raise OutputExistsError(f'{path} appeared while writing; not overwriting it')
        (staging / path.name).rename(path)
    except (WriterError, OSError) as error:
        if isinstance(error, OutputExistsError):
            raise
        raise BagWriteError(f'cannot write {path}: {error}') from None
    finally:
        shutil.rmtree(staging, ignore_errors=True)


def _write(target: Path, plugin: StoragePlugin,
           streams: list[tuple[str, str, Iterator[tuple[int, Any]]]]) -> None:
    """Write the merged, stamp-ordered streams into a new bag at ``target``."""
    with Writer(target, version=BAG_VERSION, storage_plugin=plugin) as writer:
        connections = [writer.add_connection(topic, msgtype, typestore=_TYPESTORE)
                       for topic, msgtype, _ in streams]
        tagged = [_tag(k, stream) for k, (_, _, stream) in enumerate(streams)]
        for stamp, k, msg in heapq.merge(*tagged, key=lambda item: (item[0], item[1])):
            data = msg if isinstance(msg, bytes) else _TYPESTORE.serialize_cdr(
                msg, streams[k][1])
            writer.write(connections[k], stamp, data)


def _tag(index: int, stream: Iterator[tuple[int, Any]]) -> Iterator[tuple[int, int, Any]]:
    """Yield ``(stamp, index, message)``: the stream index breaks ties between topics."""
    for stamp, msg in stream:
        yield stamp, index, msg
