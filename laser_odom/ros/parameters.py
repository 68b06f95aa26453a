"""The node's parameters as ROS declares them: description, range and read-only flag.

What the parameters are and how values are judged is ROS-free
(:mod:`laser_odom.core.configuration.node`); this module only turns a
:class:`~laser_odom.core.configuration.node.ParameterSpec` into an rcl ``ParameterDescriptor``.
"""

from __future__ import annotations

import sys

from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor

from laser_odom.core.configuration.node import ParameterSpec


def descriptor(spec: ParameterSpec) -> ParameterDescriptor:
    """Return the ROS parameter descriptor: description, range and read-only flag."""
    info = spec.info
    text = info.description
    if info.choices:
        text += f' One of: {", ".join(info.choices)}.'
    result = ParameterDescriptor(description=text, read_only=info.read_only)
    if isinstance(spec.default, bool):
        return result
    low = info.low if info.low is not None else -sys.float_info.max
    high = info.high if info.high is not None else sys.float_info.max
    if isinstance(spec.default, int):
        imin, imax = -2 ** 63, 2 ** 63 - 1
        result.integer_range = [IntegerRange(
            from_value=max(int(low), imin), to_value=min(int(high), imax), step=1)]
    elif isinstance(spec.default, float):
        result.floating_point_range = [FloatingPointRange(
            from_value=float(low), to_value=float(high), step=0.0)]
    return result
