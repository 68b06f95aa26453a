"""Build script for the laser_odom ament_python package (colcon and pip alike)."""

from glob import glob

from setuptools import find_packages, setup

PACKAGE_NAME = 'laser_odom'

setup(
    name=PACKAGE_NAME,
    version='0.1.0',
    packages=find_packages(exclude=['test']),
    data_files=[
        ('share/ament_index/resource_index/packages', ['resource/' + PACKAGE_NAME]),
        ('share/' + PACKAGE_NAME, ['package.xml']),
        ('share/' + PACKAGE_NAME + '/config', glob('config/*.yaml')),
        # robot_localization examples: not laser_odom parameter files, so kept apart
        ('share/' + PACKAGE_NAME + '/config/robot_localization',
         glob('config/robot_localization/*.yaml')),
        ('share/' + PACKAGE_NAME + '/launch', glob('launch/*.launch.py')),
        ('share/' + PACKAGE_NAME + '/rviz', glob('rviz/*.rviz')),
    ],
    install_requires=['setuptools', 'numpy', 'scipy', 'numba', 'rosbags'],
    python_requires='>=3.10',
    zip_safe=True,
    maintainer='laser_odom maintainers',
    maintainer_email='maintainers@laser-odom.dev',
    description='2D laser odometry (ICP, PL-ICP, NICP, IMLS-ICP) for ROS 2, scan to scan '
                'or against a local map',
    license='Apache-2.0',
    tests_require=['pytest'],
    extras_require={'tools': ['optuna', 'matplotlib']},
    entry_points={
        'console_scripts': [
            'laser_odom_node = laser_odom.ros.node:main',
            'laser_odom_lifecycle_node = laser_odom.ros.lifecycle:main',
            'laser_odom_replay = laser_odom.tools.replay:main',
            'laser_odom_simulate = laser_odom.tools.simulate:main',
            'laser_odom_convert = laser_odom.tools.convert:main',
            'laser_odom_bench = laser_odom.tools.bench:main',
            'laser_odom_soak = laser_odom.tools.soak:main',
            'laser_odom_warmup = laser_odom.tools.warmup:main',
            'laser_odom_tune = laser_odom.tools.tune:main',
            'laser_odom_ctl = laser_odom.tools.ctl:main',
        ],
    },
)
