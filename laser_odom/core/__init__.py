"""ROS-free core of laser_odom: scans, SE(2) algebra, matchers and the odometry pipeline.

Nothing under this package imports rclpy or rosbags, so it can be used and tested on
any machine with numpy and scipy.
"""
