"""Bag and file input/output; rosbags is imported here, never in core.

May import: ``laser_odom.core``.
"""  # noqa: A005
