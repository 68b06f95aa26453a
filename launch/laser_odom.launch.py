"""Start laser_odom_node with a parameter file, topic remappings and, optionally, RViz.

    ros2 launch laser_odom laser_odom.launch.py scan_topic:=/base_scan rviz:=true

Arguments: ``scan_topic``, ``odom_topic``, ``params_file``, ``namespace``,
``use_sim_time`` and ``rviz`` (``ros2 launch laser_odom laser_odom.launch.py -s``
lists them with their defaults). The node's other names (``pose``, ``~/reset``,
``~/set_pose``, ``~/matched_scan``) resolve under ``namespace`` and the node name
``laser_odom``; the shipped RViz file assumes the defaults (no namespace).
"""

import os

from ament_index_python.packages import get_package_share_directory
from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument
from launch.conditions import IfCondition
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node
from launch_ros.parameter_descriptions import ParameterValue

PACKAGE = 'laser_odom'


def generate_launch_description():
    """Declare the arguments and return the node (and RViz when ``rviz:=true``)."""
    share = get_package_share_directory(PACKAGE)
    use_sim_time = ParameterValue(LaunchConfiguration('use_sim_time'), value_type=bool)
    arguments = [
        DeclareLaunchArgument(
            'scan_topic', default_value='scan',
            description='sensor_msgs/LaserScan input, remapped onto the node\'s "scan" '
                        '(relative names resolve under the namespace).'),
        DeclareLaunchArgument(
            'odom_topic', default_value='odom',
            description='nav_msgs/Odometry output, remapped from the node\'s "odom".'),
        DeclareLaunchArgument(
            'params_file', default_value=os.path.join(share, 'config', 'default.yaml'),
            description='Node parameter file (ros__parameters under "/**:" or the node '
                        'name); config/ ships default, icp, plicp, nicp and imls.'),
        DeclareLaunchArgument(
            'namespace', default_value='',
            description='Namespace of the node and of its relative topics (e.g. robot1).'),
        DeclareLaunchArgument(
            'use_sim_time', default_value='false',
            description='Use the /clock topic (bag playback, simulators) for the node '
                        'and RViz.'),
        DeclareLaunchArgument(
            'rviz', default_value='false',
            description='Also start rviz2 with the shipped rviz/laser_odom.rviz (its '
                        'topics are /scan, /odom, /pose: without namespace or remaps).'),
    ]
    odometry = Node(
        package=PACKAGE,
        executable='laser_odom_node',
        name='laser_odom',
        namespace=LaunchConfiguration('namespace'),
        parameters=[LaunchConfiguration('params_file'), {'use_sim_time': use_sim_time}],
        remappings=[('scan', LaunchConfiguration('scan_topic')),
                    ('odom', LaunchConfiguration('odom_topic'))],
        output='screen',
    )
    rviz = Node(
        package='rviz2',
        executable='rviz2',
        name='rviz2',
        arguments=['-d', os.path.join(share, 'rviz', 'laser_odom.rviz')],
        parameters=[{'use_sim_time': use_sim_time}],
        condition=IfCondition(LaunchConfiguration('rviz')),
        output='screen',
    )
    return LaunchDescription(arguments + [odometry, rviz])
