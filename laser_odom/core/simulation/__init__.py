"""Deterministic 2D simulation for tests, demos and benchmarks (numpy only, no ROS).

Worlds are line segments (:mod:`.world`), scans are cast against them in one
broadcast (:mod:`.raycast`), the robot drives a smooth loop (:mod:`.trajectory`) as a
motion profile says (:mod:`.motions`: gentle, spinning in place, aggressive) and
wheel odometry drifts with a seeded error model (:mod:`.odometry`).
:func:`simulate` ties them together into a :class:`laser_odom.core.trajectory.Dataset`;
:func:`render_scan` renders one scan at a known pose.
"""

from laser_odom.core.simulation.laser import (
    laser_world_pose, LaserModel, render_scan, true_ranges)
from laser_odom.core.simulation.motions import (
    DEFAULT_MOTION, motion_profile, MOTIONS, UnknownMotionError)
from laser_odom.core.simulation.odometry import OdometryNoise, wheel_odometry
from laser_odom.core.simulation.simulator import EPOCH_NS, ODOMETRY_RATE, simulate
from laser_odom.core.simulation.trajectory import SmoothPath, SpeedProfile
from laser_odom.core.simulation.world import (
    DEFAULT_WORLD, get_world, UnknownWorldError, World, world_names)

__all__ = [
    'DEFAULT_MOTION', 'DEFAULT_WORLD', 'EPOCH_NS', 'LaserModel', 'MOTIONS', 'ODOMETRY_RATE',
    'OdometryNoise', 'UnknownMotionError', 'motion_profile',
    'SmoothPath', 'SpeedProfile', 'UnknownWorldError', 'World', 'get_world',
    'laser_world_pose', 'render_scan', 'simulate', 'true_ranges', 'wheel_odometry',
    'world_names',
]
