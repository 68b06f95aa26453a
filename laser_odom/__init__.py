"""laser_odom: 2D laser odometry for ROS 2 (ICP, PL-ICP, NICP, IMLS-ICP).

``laser_odom.core`` is ROS-free (numpy/scipy only); ``laser_odom.ros`` holds the rclpy
node, ``laser_odom.io`` reads and writes bags and logs, and ``laser_odom.tools`` holds
the command-line programs.
"""

__version__ = '0.1.0'
