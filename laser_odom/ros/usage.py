"""``laser_odom_node --help``: what the node reads, publishes and accepts.

ROS arguments (``--ros-args ... [--]``) belong to rcl; ``--help`` before them is the
node's own and prints the usage without starting anything. The parameter list is
generated from the same declarations the node uses.
"""

from __future__ import annotations

from pathlib import Path
import sys
import textwrap

from laser_odom.core.configuration.node import parameter_specs, ParameterSpec
from laser_odom.ros.priors import PRIOR_TOPICS

PACKAGE = 'laser_odom'

TOPICS = f"""\
Subscribes:
  scan                      sensor_msgs/LaserScan (sensor-data QoS, newest scan only)
  {PRIOR_TOPICS['odom']:<25} nav_msgs/Odometry (prior: odom)
  {PRIOR_TOPICS['imu']:<25} sensor_msgs/Imu (prior: imu)
  ~/set_pose                geometry_msgs/PoseWithCovarianceStamped: restart from a pose
Publishes:
  odom                      nav_msgs/Odometry of base_frame in odom_frame, scan stamps
  pose                      geometry_msgs/PoseStamped, the same pose
  /tf                       odom_frame -> base_frame (publish_tf, needs tf2_ros)
  ~/matched_scan            sensor_msgs/PointCloud2, the matched scan in odom_frame
                            (publish_debug)
  ~/local_map               sensor_msgs/PointCloud2, the local map's cells in odom_frame,
                            at most 1 Hz (publish_debug, reference: local_map)
  /diagnostics              diagnostic_msgs/DiagnosticArray, once a second
Services:
  ~/reset                   std_srvs/Trigger: restart at the origin

Talking to a running node (laser_odom_ctl needs no ros2 CLI; it finds the node in any
namespace, or give --namespace NS / --node-name NAME):
  laser_odom_ctl params               ros2 param dump /laser_odom
  laser_odom_ctl get NAME             ros2 param get /laser_odom NAME
  laser_odom_ctl set NAME VALUE       ros2 param set /laser_odom NAME VALUE
  laser_odom_ctl reset                ros2 service call /laser_odom/reset std_srvs/srv/Trigger
  laser_odom_ctl reset X Y YAW        ros2 topic pub --once /laser_odom/set_pose ...
  laser_odom_ctl status               ros2 topic echo /diagnostics
  laser_odom_ctl lifecycle [T]        ros2 lifecycle get|set /laser_odom [T] (the managed
                                      laser_odom_lifecycle_node; T: configure, activate...)"""


def wants_help(argv: list[str]) -> bool:
    """Tell whether ``-h``/``--help`` was given as the node's own argument."""
    own = argv[1:]
    if '--ros-args' in own:
        own = own[:own.index('--ros-args')]
    return '-h' in own or '--help' in own


def params_file_arguments(argv: list[str]) -> list[str]:
    """Return the ``--params-file`` paths among the ROS arguments, in order."""
    paths = []
    in_ros_args = False
    for k, arg in enumerate(argv):
        if arg == '--ros-args':
            in_ros_args = True
        elif arg == '--':
            in_ros_args = False
        elif in_ros_args and arg == '--params-file' and k + 1 < len(argv):
            paths.append(argv[k + 1])
    return paths


def config_directory() -> Path:
    """Return where the shipped parameter files are (installed share or source tree)."""
    try:
        from ament_index_python.packages import get_package_share_directory
        return Path(get_package_share_directory(PACKAGE)) / 'config'
    except Exception:  # not a colcon install (pip, source tree)
        pass
    source = Path(__file__).resolve().parents[2] / 'config'
    if source.is_dir():
        return source
    return Path(sys.prefix) / 'share' / PACKAGE / 'config'


def _parameter_line(spec: ParameterSpec) -> str:
    """Return one parameter's help: name, default, meaning, accepted values."""
    info = spec.info
    accepted = ''
    if info.choices:
        accepted = f' [{" | ".join(info.choices)}]'
    elif info.low is not None or info.high is not None:
        low = '-inf' if info.low is None else f'{info.low:g}'
        high = 'inf' if info.high is None else f'{info.high:g}'
        accepted = f' [{low}, {high}]'
    read_only = ' (read-only)' if info.read_only else ''
    head = f'  {spec.name} = {spec.default!r}'
    body = textwrap.fill(f'{info.description}{accepted}{read_only}', width=92,
                         initial_indent='      ', subsequent_indent='      ')
    return f'{head}\n{body}'


def usage() -> str:
    """Return the node's help text."""
    configs = config_directory()
    files = ', '.join(sorted(p.name for p in configs.glob('*.yaml'))) or 'none found'
    specs = [s for s in parameter_specs() if '.' not in s.name]
    matcher_groups = sorted({s.name.split('.')[0] for s in parameter_specs() if '.' in s.name})
    return '\n'.join([
        'usage: laser_odom_node [-h] [--ros-args [-r scan:=/my_scan] [-r __ns:=/robot1]',
        '                       [--params-file FILE] [-p NAME:=VALUE] ...]',
        '',
        '2D laser odometry (ICP, PL-ICP, NICP, IMLS-ICP) as a ROS 2 node (node name '
        f'{PACKAGE}):',
        'each scan is matched against the previous scan (reference: scan, the default) or',
        'against a local map of the recent scans (reference: local_map: less drift).',
        f'With colcon: ros2 run {PACKAGE} laser_odom_node --ros-args ...',
        '',
        TOPICS,
        '',
        f'Parameter files ({configs}): {files}.',
        'Sections keyed "/**:" apply under any node name and namespace. Unknown names are',
        'warned about; an integer is taken where a floating-point number is declared.',
        '',
        'Parameters (laser_odom_ctl params, or ros2 param describe /laser_odom NAME):',
        *[_parameter_line(s) for s in specs],
        '',
        'Matcher parameters, per matcher (' + ', '.join(matcher_groups) + '): '
        '<matcher>.<name>; every one is listed with its default in '
        f'{configs / "default.yaml"}.',
    ])
