"""Deterministic 2D simulation for tests, demos and benchmarks (numpy only, no ROS).

Worlds are line segments (:mod:`.world`), scans are cast against them in one
broadcast (:mod:`.raycast`), the robot drives a smooth loop (:mod:`.trajectory`) as a
motion profile says (:mod:`.motions`: gentle, spinning in place, aggressive) and
wheel odometry drifts with a seeded error model (:mod:`.odometry`). The range finder
(:mod:`.laser`) is instantaneous or a rotating lidar whose beams are taken across the
sweep while the robot moves; :mod:`.sensors` has presets of common lidars.
:func:`simulate` ties them together into a :class:`laser_odom.core.trajectory.Dataset`;
:func:`render_scan` renders one scan at a known pose (or one pose per beam), and
:func:`render_swept_scan` one scan taken while following a motion; :func:`drop_to_steps`
loses scans until the steps are as large as asked (large motion between scans).

May import: ``se2``, ``scan``, ``trajectory``.
"""

from laser_odom.core.simulation.laser import (
    beam_base_poses, laser_world_pose, laser_world_poses, LaserModel, render_scan,
    render_swept_scan, STAMP_AT, true_ranges)
from laser_odom.core.simulation.motions import (
    ConstantTwist, DEFAULT_MOTION, Motion, motion_profile, MOTIONS, UnknownMotionError)
from laser_odom.core.simulation.odometry import OdometryNoise, wheel_odometry
from laser_odom.core.simulation.sensors import (
    DEFAULT_SENSOR, sensor_model, sensor_names, SensorPreset, SENSORS, UnknownSensorError)
from laser_odom.core.simulation.simulator import (
    drop_to_steps, EPOCH_NS, ODOMETRY_RATE, simulate)
from laser_odom.core.simulation.trajectory import SmoothPath, SpeedProfile
from laser_odom.core.simulation.world import (
    DEFAULT_WORLD, get_world, UnknownWorldError, World, world_names)

__all__ = [
    'ConstantTwist', 'DEFAULT_MOTION', 'DEFAULT_SENSOR', 'DEFAULT_WORLD', 'EPOCH_NS',
    'LaserModel', 'MOTIONS', 'Motion', 'ODOMETRY_RATE', 'OdometryNoise', 'SENSORS',
    'STAMP_AT', 'SensorPreset', 'UnknownMotionError', 'UnknownSensorError', 'motion_profile',
    'SmoothPath', 'SpeedProfile', 'UnknownWorldError', 'World', 'beam_base_poses',
    'drop_to_steps',
    'get_world', 'laser_world_pose', 'laser_world_poses', 'render_scan', 'render_swept_scan',
    'sensor_model', 'sensor_names', 'simulate', 'true_ranges', 'wheel_odometry',
    'world_names',
]
