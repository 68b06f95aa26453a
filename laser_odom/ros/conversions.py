"""Conversions between ROS messages and the ROS-free core types.

Stamps travel as integer nanoseconds in the core so that an output carries exactly
the stamp of its scan. Planar poses and 3x3 ``[x, y, yaw]`` covariances are embedded
in the 6x6 ``[x, y, z, roll, pitch, yaw]`` covariances of ``nav_msgs/Odometry``
(REP-105 frames: pose in ``odom_frame``, twist in ``base_frame``), with
:data:`UNOBSERVED_VARIANCE` on the three dimensions a planar odometry does not
observe, the convention 2D consumers such as robot_localization's ``two_d_mode``
expect. Nothing non-finite is ever put in an outgoing message.

:func:`published_messages` is the one builder of what the node sends for a scan; the
replay's ``--output-bag`` serialises the same messages, so a bag written offline
holds byte for byte what the node would have published.
"""

from __future__ import annotations

from array import array
from dataclasses import dataclass
import math

from builtin_interfaces.msg import Time
from geometry_msgs.msg import (
    Pose as PoseMsg, PoseStamped, PoseWithCovarianceStamped, Quaternion, TransformStamped)
from nav_msgs.msg import Odometry
import numpy as np
from sensor_msgs.msg import Imu, LaserScan as LaserScanMsg, PointCloud2, PointField

from laser_odom.core import se2
from laser_odom.core.pipeline.estimate import OdometryEstimate
from laser_odom.core.scan.laser_scan import LaserMounting, LaserScan

UNOBSERVED_VARIANCE = 1.0e6
"""Variance [m^2 or rad^2] published for z, roll and pitch: a planar odometry does not
observe them, so they are marked as unknown rather than as perfectly known."""

PLANAR_INDEX = np.array([0, 1, 5])
"""Rows/columns of x, y and yaw in a row-major 6x6 ROS covariance."""

NANOSECONDS = 1_000_000_000


def stamp_to_ns(stamp: Time) -> int:
    """Return a ``builtin_interfaces/Time`` as integer nanoseconds (exact)."""
    return int(stamp.sec) * NANOSECONDS + int(stamp.nanosec)


def ns_to_stamp(stamp_ns: int) -> Time:
    """Return integer nanoseconds as a ``builtin_interfaces/Time`` (exact)."""
    sec, nanosec = divmod(int(stamp_ns), NANOSECONDS)
    return Time(sec=sec, nanosec=nanosec)


def _float32_array(values: np.ndarray) -> array:
    """Pack values into the ``array('f')`` that rclpy stores float32[] fields as."""
    packed = array('f')
    packed.frombytes(np.ascontiguousarray(values, dtype=np.float32).tobytes())
    return packed


def scan_from_msg(msg: LaserScanMsg) -> LaserScan:
    """Convert a ``sensor_msgs/LaserScan`` to the core :class:`LaserScan`."""
    ranges = np.asarray(msg.ranges, dtype=np.float32).astype(float)
    intensities = (np.asarray(msg.intensities, dtype=np.float32).astype(float)
                   if len(msg.intensities) else None)
    return LaserScan(
        stamp_ns=stamp_to_ns(msg.header.stamp), angle_min=float(msg.angle_min),
        angle_max=float(msg.angle_max), angle_increment=float(msg.angle_increment),
        range_min=float(msg.range_min), range_max=float(msg.range_max), ranges=ranges,
        intensities=intensities, frame_id=msg.header.frame_id,
        time_increment=float(msg.time_increment), scan_time=float(msg.scan_time))


def scan_to_msg(scan: LaserScan) -> LaserScanMsg:
    """Convert a core :class:`LaserScan` to a ``sensor_msgs/LaserScan``."""
    msg = LaserScanMsg()
    msg.header.stamp = ns_to_stamp(scan.stamp_ns)
    msg.header.frame_id = scan.frame_id
    msg.angle_min = float(scan.angle_min)
    msg.angle_max = float(scan.angle_max)
    msg.angle_increment = float(scan.angle_increment)
    msg.time_increment = float(scan.time_increment)
    msg.scan_time = float(scan.scan_time)
    msg.range_min = float(scan.range_min)
    msg.range_max = float(scan.range_max)
    msg.ranges = _float32_array(scan.ranges)
    if scan.intensities is not None:
        msg.intensities = _float32_array(scan.intensities)
    return msg


def covariance_6x6(covariance: np.ndarray) -> np.ndarray:
    """Embed a 3x3 ``[x, y, yaw]`` covariance in a row-major 6x6 ROS covariance.

    A non-finite input (which the pipeline should never produce) becomes
    :data:`UNOBSERVED_VARIANCE` on the diagonal rather than NaN on the wire. The
    result is a flat float64 array, which a message field takes without checking
    each element in Python.
    """
    planar = np.asarray(covariance, dtype=float).reshape(3, 3)
    if not np.all(np.isfinite(planar)):
        planar = np.eye(3) * UNOBSERVED_VARIANCE
    full = np.diag([0.0, 0.0, UNOBSERVED_VARIANCE, UNOBSERVED_VARIANCE,
                    UNOBSERVED_VARIANCE, 0.0])
    full[np.ix_(PLANAR_INDEX, PLANAR_INDEX)] = 0.5 * (planar + planar.T)
    return full.reshape(-1)


def covariance_3x3(covariance: list[float] | np.ndarray) -> np.ndarray:
    """Extract the ``[x, y, yaw]`` block of a row-major 6x6 ROS covariance."""
    full = np.asarray(covariance, dtype=float).reshape(6, 6)
    return full[np.ix_(PLANAR_INDEX, PLANAR_INDEX)].copy()


def yaw_quaternion(yaw: float) -> Quaternion:
    """Return the quaternion message of a rotation by ``yaw`` about z."""
    x, y, z, w = se2.yaw_to_quaternion(yaw)
    return Quaternion(x=x, y=y, z=z, w=w)


def planar_pose_msg(pose: se2.Pose) -> PoseMsg:
    """Return a planar pose as a ``geometry_msgs/Pose`` (z = 0)."""
    msg = PoseMsg()
    msg.position.x, msg.position.y = float(pose[0]), float(pose[1])
    msg.orientation = yaw_quaternion(float(pose[2]))
    return msg


def pose_from_msg(msg: PoseMsg) -> se2.Pose:
    """Return the planar part ``[x, y, yaw]`` of a ``geometry_msgs/Pose``."""
    q = msg.orientation
    return se2.pose(msg.position.x, msg.position.y, se2.quaternion_to_yaw(q.x, q.y, q.z, q.w))


def odometry_to_msg(estimate: OdometryEstimate, stamp: Time, odom_frame: str,
                    base_frame: str) -> Odometry | None:
    """Return the estimate as ``nav_msgs/Odometry``, or None if its pose is not finite.

    ``stamp`` is the scan's header stamp, copied verbatim. A non-finite twist is
    published as zero with :data:`UNOBSERVED_VARIANCE`.
    """
    if not se2.is_finite_pose(estimate.pose):
        return None
    msg = Odometry()
    msg.header.stamp = stamp
    msg.header.frame_id = odom_frame
    msg.child_frame_id = base_frame
    msg.pose.pose = planar_pose_msg(estimate.pose)
    msg.pose.covariance = covariance_6x6(estimate.pose_covariance)
    twist, twist_covariance = estimate.twist, estimate.twist_covariance
    if not np.all(np.isfinite(twist)):
        twist, twist_covariance = np.zeros(3), np.eye(3) * UNOBSERVED_VARIANCE
    msg.twist.twist.linear.x, msg.twist.twist.linear.y = float(twist[0]), float(twist[1])
    msg.twist.twist.angular.z = float(twist[2])
    msg.twist.covariance = covariance_6x6(twist_covariance)
    return msg


def pose_stamped_from_odometry(msg: Odometry) -> PoseStamped:
    """Return the ``PoseStamped`` the node publishes beside an ``Odometry`` message."""
    pose = PoseStamped()
    pose.header = msg.header
    pose.pose = msg.pose.pose
    return pose


def transform_to_msg(estimate: OdometryEstimate, stamp: Time, odom_frame: str,
                     base_frame: str) -> TransformStamped | None:
    """Return the ``odom_frame -> base_frame`` transform of an estimate (None if not finite)."""
    if not se2.is_finite_pose(estimate.pose):
        return None
    msg = TransformStamped()
    msg.header.stamp = stamp
    msg.header.frame_id = odom_frame
    msg.child_frame_id = base_frame
    msg.transform.translation.x = float(estimate.pose[0])
    msg.transform.translation.y = float(estimate.pose[1])
    msg.transform.rotation = yaw_quaternion(float(estimate.pose[2]))
    return msg


@dataclass
class PublishedMessages:
    """What the node publishes for one processed scan."""

    odometry: Odometry
    pose: PoseStamped
    transform: TransformStamped


def published_messages(estimate: OdometryEstimate, stamp: Time, odom_frame: str,
                       base_frame: str) -> PublishedMessages | None:
    """Return the odometry, pose and TF of an estimate (None if its pose is not finite)."""
    odometry = odometry_to_msg(estimate, stamp, odom_frame, base_frame)
    if odometry is None:
        return None
    return PublishedMessages(odometry, pose_stamped_from_odometry(odometry),
                             transform_to_msg(estimate, stamp, odom_frame, base_frame))


CLOUD_FIELDS = [PointField(name=axis, offset=4 * k, datatype=PointField.FLOAT32, count=1)
                for k, axis in enumerate('xyz')]
"""``x y z`` float32 fields of the debug point cloud."""


def point_cloud_msg(points: np.ndarray, fields: list[PointField], stamp: Time,
                    frame_id: str) -> PointCloud2:
    """Return float32 ``points`` (N, len(fields)) as a dense ``sensor_msgs/PointCloud2``.

    The one builder of the node's clouds (the matched scan, the local map): each row
    is a point, each column the float32 field of ``fields`` at that offset.
    """
    points = np.ascontiguousarray(points, dtype=np.float32)
    msg = PointCloud2()
    msg.header.stamp = stamp
    msg.header.frame_id = frame_id
    msg.height, msg.width = 1, len(points)
    msg.fields = fields
    msg.is_bigendian = False
    msg.point_step = 4 * len(fields)
    msg.row_step = msg.point_step * len(points)
    msg.data = points.tobytes()
    msg.is_dense = True
    return msg


def matched_cloud_msg(estimate: OdometryEstimate, stamp: Time,
                      odom_frame: str) -> PointCloud2 | None:
    """Return the matched scan in ``odom_frame`` as ``sensor_msgs/PointCloud2`` (for RViz).

    The scan's base-frame points are moved by the estimated pose, so in RViz they
    should lie on the walls the previous scans outlined; where they do not, the match
    is wrong. None when the estimate has no points or a non-finite pose.
    """
    if estimate.scan_points is None or not se2.is_finite_pose(estimate.pose):
        return None
    world = se2.transform_points(estimate.pose, np.asarray(estimate.scan_points, float))
    xyz = np.zeros((len(world), 3), dtype=np.float32)
    xyz[:, :2] = world
    return point_cloud_msg(xyz, CLOUD_FIELDS, stamp, odom_frame)


def initial_pose_from_msg(msg: PoseWithCovarianceStamped) -> tuple[se2.Pose, np.ndarray]:
    """Return the planar pose and 3x3 covariance of a ``PoseWithCovarianceStamped``."""
    covariance = covariance_3x3(msg.pose.covariance)
    if not np.all(np.isfinite(covariance)):
        raise ValueError('covariance is not finite')
    pose = pose_from_msg(msg.pose.pose)
    if not se2.is_finite_pose(pose):
        raise ValueError('pose is not finite')
    return pose, 0.5 * (covariance + covariance.T)


def odometry_pose_from_msg(msg: Odometry) -> tuple[int, se2.Pose]:
    """Return ``(stamp_ns, [x, y, yaw])`` of a wheel odometry message."""
    return stamp_to_ns(msg.header.stamp), pose_from_msg(msg.pose.pose)


def imu_yaw_from_msg(msg: Imu) -> tuple[int, float | None, float]:
    """Return ``(stamp_ns, yaw or None, yaw rate)`` of an IMU message.

    Per ``sensor_msgs/Imu``, ``orientation_covariance[0] == -1`` means the IMU gives
    no orientation; an all-zero quaternion is treated the same way.
    """
    q = msg.orientation
    has_orientation = (msg.orientation_covariance[0] != -1.0
                       and (q.x * q.x + q.y * q.y + q.z * q.z + q.w * q.w) > 1e-6)
    yaw = se2.quaternion_to_yaw(q.x, q.y, q.z, q.w) if has_orientation else None
    return stamp_to_ns(msg.header.stamp), yaw, float(msg.angular_velocity.z)


def wheel_odometry_msg(stamp_ns: int, pose: se2.Pose) -> Odometry:
    """Return a wheel odometry sample as the node reads it (:func:`odometry_pose_from_msg`)."""
    msg = Odometry()
    msg.header.stamp = ns_to_stamp(stamp_ns)
    msg.pose.pose = planar_pose_msg(pose)
    return msg


def imu_msg(stamp_ns: int, yaw: float, yaw_rate: float) -> Imu:
    """Return an IMU sample as the node reads it (:func:`imu_yaw_from_msg`).

    A non-finite ``yaw`` (an IMU without orientation) is sent as
    ``orientation_covariance[0] = -1``, as ``sensor_msgs/Imu`` says.
    """
    msg = Imu()
    msg.header.stamp = ns_to_stamp(stamp_ns)
    if math.isfinite(yaw):
        msg.orientation = yaw_quaternion(yaw)
    else:
        msg.orientation_covariance[0] = -1.0
    msg.angular_velocity.z = float(yaw_rate)
    return msg


def mounting_from_transform(translation: tuple[float, float, float],
                            rotation: tuple[float, float, float, float]
                            ) -> tuple[LaserMounting, float]:
    """Return the planar :class:`LaserMounting` of a base <- laser transform, and its tilt.

    A laser whose z axis points down (roll of pi) is ``upside_down``: it mirrors the
    scan, then the yaw of its x axis in the base frame applies, as in
    ``scan_to_points``. The tilt [rad] between the laser's z axis and the base's
    vertical is returned so that a caller can warn about a non-planar mounting.
    """
    x, y, z, w = rotation
    norm = math.sqrt(x * x + y * y + z * z + w * w) or 1.0
    x, y, z, w = x / norm, y / norm, z / norm, w / norm
    r00 = 1.0 - 2.0 * (y * y + z * z)
    r10 = 2.0 * (x * y + w * z)
    r22 = 1.0 - 2.0 * (x * x + y * y)
    upside_down = r22 < 0.0
    tilt = math.acos(min(1.0, abs(r22)))
    mounting = LaserMounting(float(translation[0]), float(translation[1]),
                             math.atan2(r10, r00), upside_down)
    return mounting, tilt
