"""Every dependency of package.xml is a key rosdep resolves on Jazzy, and none is missing.

Issue 39: ``rosdep install --from-paths src`` on a robot's Jazzy workspace stops at the
first key it cannot resolve, so a single unknown key (``rosbags`` and
``python3-optuna-pip`` were; neither has a rule) leaves the whole install undone. The
keys below were each resolved with rosdep 0.27.0 for ``ubuntu:noble`` and
``--rosdistro jazzy``, its sources pointed at files of a checkout of ros/rosdistro
(commit 8468e88ccd523427f9131e39d2af0938f1c298b2, 2026-08-22): the system keys in
``rosdep/base.yaml`` and ``rosdep/python.yaml``, the ROS packages in
``jazzy/distribution.yaml``. A key added to package.xml must be checked the same way
and recorded here with where it was found.

The other direction is read from the source: every module the package and its launch
file import from outside the standard library is provided by a declared key, or is
one of the few that rosdep cannot install, each of which the README tells how to get.
"""

import ast
from pathlib import Path
import sys
import xml.etree.ElementTree as ElementTree

ROOT = Path(__file__).resolve().parents[1]
DISTRIBUTION = 'jazzy/distribution.yaml'
PYTHON_YAML = 'rosdep/python.yaml'

VERIFIED_KEYS = {
    # ROS 2 packages: released in jazzy/distribution.yaml (repository, version)
    'rclpy': (DISTRIBUTION, 'rclpy 7.1.11: ros-jazzy-rclpy'),
    'builtin_interfaces': (DISTRIBUTION, 'rcl_interfaces 2.0.4: ros-jazzy-builtin-interfaces'),
    'rcl_interfaces': (DISTRIBUTION, 'rcl_interfaces 2.0.4: ros-jazzy-rcl-interfaces'),
    'lifecycle_msgs': (DISTRIBUTION, 'rcl_interfaces 2.0.4: ros-jazzy-lifecycle-msgs'),
    'rosgraph_msgs': (DISTRIBUTION, 'rcl_interfaces 2.0.4: ros-jazzy-rosgraph-msgs'),
    'sensor_msgs': (DISTRIBUTION, 'common_interfaces 5.3.8: ros-jazzy-sensor-msgs'),
    'nav_msgs': (DISTRIBUTION, 'common_interfaces 5.3.8: ros-jazzy-nav-msgs'),
    'geometry_msgs': (DISTRIBUTION, 'common_interfaces 5.3.8: ros-jazzy-geometry-msgs'),
    'std_msgs': (DISTRIBUTION, 'common_interfaces 5.3.8: ros-jazzy-std-msgs'),
    'std_srvs': (DISTRIBUTION, 'common_interfaces 5.3.8: ros-jazzy-std-srvs'),
    'diagnostic_msgs': (DISTRIBUTION, 'common_interfaces 5.3.8: ros-jazzy-diagnostic-msgs'),
    'tf2_ros_py': (DISTRIBUTION, 'geometry2 0.36.22: ros-jazzy-tf2-ros-py'),
    'launch': (DISTRIBUTION, 'launch 3.4.11: ros-jazzy-launch'),
    'launch_ros': (DISTRIBUTION, 'launch_ros 0.26.12: ros-jazzy-launch-ros'),
    'ament_index_python': (DISTRIBUTION, 'ament_index 1.8.4: ros-jazzy-ament-index-python'),
    'ament_flake8': (DISTRIBUTION, 'ament_lint 0.17.5: ros-jazzy-ament-flake8'),
    'ament_pep257': (DISTRIBUTION, 'ament_lint 0.17.5: ros-jazzy-ament-pep257'),
    # system keys: rosdep/python.yaml, with an ubuntu rule for every release
    'python3-numpy': (PYTHON_YAML, 'apt python3-numpy'),
    'python3-scipy': (PYTHON_YAML, 'apt python3-scipy'),
    'python3-numba': (PYTHON_YAML, 'apt python3-numba'),
    'python3-yaml': (PYTHON_YAML, 'apt python3-yaml'),
    'python3-matplotlib': (PYTHON_YAML, 'apt python3-matplotlib'),
    'python3-pytest': (PYTHON_YAML, 'apt python3-pytest'),
    'python3-rosbags-pip': (PYTHON_YAML, 'pip rosbags'),
}
"""Key -> (the ros/rosdistro file that defines it, what rosdep resolves it to on noble)."""

NOT_KEYS = {
    'rosbags': 'no rule in rosdep/*.yaml nor a Jazzy package: python3-rosbags-pip is the key',
    'python3-optuna-pip': 'no rule (nor python3-optuna): optuna is a pip install',
    'tf2_ros': 'the C++ package: the Python module tf2_ros is released as tf2_ros_py',
    'rviz2': 'a key, but only the launch file with rviz:=true needs it',
}
"""Keys that were declared once and are wrong, and why (none may come back)."""

PROVIDERS = {
    'rclpy': 'rclpy', 'builtin_interfaces': 'builtin_interfaces',
    'rcl_interfaces': 'rcl_interfaces', 'sensor_msgs': 'sensor_msgs',
    'lifecycle_msgs': 'lifecycle_msgs', 'rosgraph_msgs': 'rosgraph_msgs',
    'nav_msgs': 'nav_msgs', 'geometry_msgs': 'geometry_msgs', 'std_msgs': 'std_msgs',
    'std_srvs': 'std_srvs', 'diagnostic_msgs': 'diagnostic_msgs', 'tf2_ros': 'tf2_ros_py',
    'launch': 'launch', 'launch_ros': 'launch_ros', 'ament_index_python': 'ament_index_python',
    'numpy': 'python3-numpy', 'scipy': 'python3-scipy', 'numba': 'python3-numba',
    'yaml': 'python3-yaml', 'matplotlib': 'python3-matplotlib',
    'rosbags': 'python3-rosbags-pip',
    # dependencies of rosbags (its pip install brings them; no rosdep rule of their own)
    'lz4': 'python3-rosbags-pip', 'backports': 'python3-rosbags-pip',
    'compression': 'python3-rosbags-pip',  # the standard library's zstd from Python 3.14
}
"""Imported top-level module -> the declared key that provides it."""

PIP_ONLY = {'optuna': 'pip install optuna'}
"""Imported modules without a rosdep key: the README's colcon set-up installs them."""


def dependencies() -> dict[str, list[str]]:
    """Return package.xml's dependency keys by tag (exec_depend, test_depend, ...)."""
    root = ElementTree.parse(ROOT / 'package.xml').getroot()
    assert root.tag == 'package' and root.get('format') == '3'
    assert root.findtext('export/build_type') == 'ament_python'
    found: dict[str, list[str]] = {}
    for element in root:
        if element.tag.endswith('depend'):
            found.setdefault(element.tag, []).append(element.text.strip())
    return found


def imported_modules() -> set[str]:
    """Return the top-level modules the package and the launch file import (not stdlib)."""
    sources = [*(ROOT / 'laser_odom').rglob('*.py'), *(ROOT / 'launch').glob('*.py')]
    modules = set()
    for path in sources:
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            if isinstance(node, ast.Import):
                modules |= {alias.name.split('.')[0] for alias in node.names}
            elif isinstance(node, ast.ImportFrom) and node.level == 0:
                modules.add(node.module.split('.')[0])
    return modules - set(sys.stdlib_module_names) - {'laser_odom', '__future__'}


def test_every_dependency_key_was_verified_against_rosdistro():
    found = dependencies()
    keys = [key for tag_keys in found.values() for key in tag_keys]
    assert keys and len(keys) == len(set(keys)), keys
    unverified = [key for key in keys if key not in VERIFIED_KEYS]
    assert unverified == [], f'check these keys in ros/rosdistro first: {unverified}'
    assert not set(keys) & set(NOT_KEYS)
    assert set(found) <= {'exec_depend', 'test_depend'}, set(found)


def test_every_imported_module_comes_with_a_declared_key_or_the_readme():
    modules = imported_modules()
    assert {'rclpy', 'numpy', 'numba', 'rosbags', 'tf2_ros', 'optuna'} <= modules
    unknown = modules - set(PROVIDERS) - set(PIP_ONLY)
    assert unknown == set(), f'which rosdep key provides {sorted(unknown)}?'
    exec_keys = set(dependencies()['exec_depend'])
    missing = {m: PROVIDERS[m] for m in modules & set(PROVIDERS)
               if PROVIDERS[m] not in exec_keys}
    assert missing == {}, f'imported but not declared: {missing}'
    readme = (ROOT / 'README.md').read_text()
    for module, command in PIP_ONLY.items():
        assert command in readme, module


def test_rviz_is_the_launch_files_option_not_a_dependency():
    """A robot without a display installs the package without rviz2 (and its Qt)."""
    assert 'rviz2' not in [key for keys in dependencies().values() for key in keys]
    readme = (ROOT / 'README.md').read_text()
    assert 'rviz:=true' in readme and 'ros-jazzy-rviz2' in readme
