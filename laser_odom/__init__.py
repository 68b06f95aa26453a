"""laser_odom: 2D laser odometry for ROS 2 (ICP, PL-ICP, NICP, IMLS-ICP).

``laser_odom.core`` is ROS-free (numpy/scipy only); ``laser_odom.io`` reads and writes
bags and logs, ``laser_odom.ros`` holds the rclpy node, and ``laser_odom.tools`` holds
the command-line programs. Each imports only from those before it in this list
(``test/test_layers.py``).

May import: nothing (this module only names the package and its version).
"""

__version__ = '0.1.0'
