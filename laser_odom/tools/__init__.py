"""Command-line programs: replay, simulate, convert, bench, soak, warm-up, tune and ctl.

May import: ``laser_odom.core``, ``laser_odom.io``, ``laser_odom.ros``.
"""
