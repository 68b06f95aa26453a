"""Start laser_odom_node (or the managed node) with a parameter file, remappings, RViz.

    ros2 launch laser_odom laser_odom.launch.py scan_topic:=/base_scan rviz:=true
    # beside robot_localization's EKF (docs/robot_localization.md):
    ros2 launch laser_odom laser_odom.launch.py odom_topic:=laser_odom/odom publish_tf:=false

    # a managed node, for a lifecycle manager (docs/node.md, "Managed node"):
    ros2 launch laser_odom laser_odom.launch.py managed:=true use_sim_time:=true

Arguments: ``scan_topic``, ``odom_topic``, ``pose_topic``, ``wheel_odom_topic``,
``params_file``, ``publish_tf``, ``publish_debug``, ``reference``, ``namespace``,
``use_sim_time``, ``managed`` and ``rviz`` (``ros2 launch laser_odom laser_odom.launch.py
-s`` lists them with their defaults). ``publish_tf``, ``publish_debug`` and
``reference`` left empty keep what the parameter file says; given, they override it.
The node's other names (``imu``, ``~/reset``, ``~/set_pose``, ``~/matched_scan``,
``~/local_map``) resolve under ``namespace`` and the node name ``laser_odom``; the
shipped RViz file assumes the defaults (no namespace).
"""

import os

from ament_index_python.packages import get_package_share_directory
from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument, OpaqueFunction
from launch.conditions import IfCondition
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node
from launch_ros.parameter_descriptions import ParameterValue

PACKAGE = 'laser_odom'

OVERRIDES = {'publish_tf': ('true', 'false'), 'publish_debug': ('true', 'false'),
             'reference': ('scan', 'local_map')}
"""Node parameters that a launch argument sets when it is not empty, with their values."""


def odometry_node(context):
    """Return the node action; the parameters of :data:`OVERRIDES` only when given.

    An empty argument must leave the parameter file's value alone, and a parameter
    list cannot leave a name out by substitution, so the list is built here, once
    the arguments are known (``choices`` has already refused any other value).
    """
    parameters = {'use_sim_time': ParameterValue(LaunchConfiguration('use_sim_time'),
                                                 value_type=bool)}
    for name in OVERRIDES:
        value = LaunchConfiguration(name).perform(context)
        if value:
            parameters[name] = value == 'true' if name.startswith('publish_') else value
    managed = LaunchConfiguration('managed').perform(context) == 'true'
    return [Node(
        package=PACKAGE,
        executable='laser_odom_lifecycle_node' if managed else 'laser_odom_node',
        name='laser_odom',
        namespace=LaunchConfiguration('namespace'),
        parameters=[LaunchConfiguration('params_file'), parameters],
        remappings=[('scan', LaunchConfiguration('scan_topic')),
                    ('odom', LaunchConfiguration('odom_topic')),
                    ('pose', LaunchConfiguration('pose_topic')),
                    ('wheel_odom', LaunchConfiguration('wheel_odom_topic'))],
        output='screen',
    )]


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
            description='nav_msgs/Odometry output, remapped from the node\'s "odom"; '
                        'beside wheel odometry on "odom", e.g. laser_odom/odom.'),
        DeclareLaunchArgument(
            'pose_topic', default_value='pose',
            description='geometry_msgs/PoseStamped output, remapped from the '
                        'node\'s "pose".'),
        DeclareLaunchArgument(
            'wheel_odom_topic', default_value='wheel_odom',
            description='nav_msgs/Odometry input of prior: odom, remapped onto the '
                        'node\'s "wheel_odom" (e.g. the drive controller\'s odom).'),
        DeclareLaunchArgument(
            'params_file', default_value=os.path.join(share, 'config', 'default.yaml'),
            description='Node parameter file (ros__parameters under "/**:" or the node '
                        'name); config/ ships default, icp, plicp, nicp and imls.'),
        DeclareLaunchArgument(
            'publish_tf', default_value='', choices=['', *OVERRIDES['publish_tf']],
            description='Broadcast odom -> base_link on /tf (false where an EKF '
                        'publishes it); empty: as the parameter file says.'),
        DeclareLaunchArgument(
            'publish_debug', default_value='', choices=['', *OVERRIDES['publish_debug']],
            description='Publish the matched scan and (reference local_map) the local map '
                        'for RViz; empty: as the parameter file says.'),
        DeclareLaunchArgument(
            'reference', default_value='', choices=['', *OVERRIDES['reference']],
            description='Match each scan against the previous scan or the local map; '
                        'empty: as the parameter file says.'),
        DeclareLaunchArgument(
            'namespace', default_value='',
            description='Namespace of the node and of its relative topics (e.g. robot1).'),
        DeclareLaunchArgument(
            'use_sim_time', default_value='false',
            description='Use the /clock topic (bag playback, simulators) for the node '
                        'and RViz.'),
        DeclareLaunchArgument(
            'managed', default_value='false', choices=['true', 'false'],
            description='Start laser_odom_lifecycle_node instead: the same node as a '
                        'managed node, unconfigured until a lifecycle manager (or ros2 '
                        'lifecycle set) configures and activates it.'),
        DeclareLaunchArgument(
            'rviz', default_value='false',
            description='Also start rviz2 with the shipped rviz/laser_odom.rviz (its '
                        'topics are /scan, /odom, /pose: without namespace or remaps).'),
    ]
    rviz = Node(
        package='rviz2',
        executable='rviz2',
        name='rviz2',
        arguments=['-d', os.path.join(share, 'rviz', 'laser_odom.rviz')],
        parameters=[{'use_sim_time': use_sim_time}],
        condition=IfCondition(LaunchConfiguration('rviz')),
        output='screen',
    )
    return LaunchDescription(arguments + [OpaqueFunction(function=odometry_node), rviz])
