"""ROS 2 shell of laser_odom: the ``laser_odom`` node, its parameters and message conversions.

Everything here is thin: the odometry itself is
:class:`laser_odom.core.pipeline.odometry.OdometryPipeline`, the same object the replay
harness drives offline.

May import: ``laser_odom.core``, ``laser_odom.io``.
"""
