"""ROS-free core of laser_odom: the scan's path from a LaserScan to an integrated pose.

Nothing under this package imports rclpy or rosbags, so it can be used and tested on
any machine with numpy and scipy. Its packages are layers, bottom up: ``se2``,
``events``, ``parameters``; ``scan``, ``uncertainty``; ``trajectory``, ``search``,
``matchers``; ``configuration``, ``datasets``, ``simulation``; ``motion``,
``preprocess``; ``registration``; ``pipeline``; ``evaluation``; ``tuning``. A module
imports from its own package and from lower layers only (``test/test_layers.py``, the
README's architecture section).

May import: nothing of ``laser_odom`` outside this package, and neither rclpy nor rosbags.
"""
