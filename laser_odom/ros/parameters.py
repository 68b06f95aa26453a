"""The node's parameters: declared from the configuration dataclasses, validated once.

Every field marked with :func:`laser_odom.core.params.param` becomes a ROS parameter
with its description, numeric range and read-only flag; matcher settings are
namespaced ``<matcher>.<field>`` for every registered matcher, so a YAML file can
tune all of them and ``matcher`` switches between them. The same
:func:`laser_odom.core.config.pipeline_config_from_params` that the replay harness
uses turns the values into a :class:`PipelineConfig`, so a value is judged the same
way live, at start-up and offline.
"""

from __future__ import annotations

from dataclasses import dataclass
import sys
from typing import Any, Mapping

from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor

from laser_odom.core.config import (
    pipeline_config_from_params, PIPELINE_GROUPS, PipelineConfig)
from laser_odom.core.matchers import default_config, matcher_names
from laser_odom.core.params import (
    check_value, param, param_fields, ParameterError, ParamInfo, replace_checked)
from laser_odom.core.priors import prior_config_from_params, PriorConfig


@dataclass
class NodeConfig:
    """Settings of the ROS shell only: frames, TF and diagnostics thresholds."""

    odom_frame: str = param(
        'odom', 'Frame of the published pose (parent of base_frame).', read_only=True)
    base_frame: str = param(
        'base_link', 'Robot base frame: the odometry is of this frame.', read_only=True)
    publish_tf: bool = param(
        True, 'Broadcast odom_frame -> base_frame on /tf (needs tf2_ros).')
    use_tf_extrinsic: bool = param(
        False, 'Take the laser mounting from TF (base_frame <- scan frame_id) instead of '
        'laser_x/laser_y/laser_yaw/laser_upside_down (needs tf2_ros).', read_only=True)
    diagnostics_warn_failure_rate: float = param(
        0.2, 'Diagnostics WARN when this fraction of the matches in the last period failed.',
        0.0, 1.0)
    diagnostics_error_failure_rate: float = param(
        0.5, 'Diagnostics ERROR when this fraction of the matches in the last period failed.',
        0.0, 1.0)
    diagnostics_warn_processing_time: float = param(
        0.1, 'Diagnostics WARN when the median processing time per scan exceeds this [s].',
        0.0, 60.0)
    diagnostics_error_processing_time: float = param(
        0.5, 'Diagnostics ERROR when the median processing time per scan exceeds this [s].',
        0.0, 60.0)


MATCHER_INFO_TEXT = 'Scan matcher. May be switched while running; the pose is kept.'


@dataclass(frozen=True)
class ParameterSpec:
    """One declared parameter: name, default and what it accepts."""

    name: str
    default: Any
    info: ParamInfo


def parameter_specs() -> list[ParameterSpec]:
    """Return every parameter of the node, in declaration order."""
    names = matcher_names()
    specs = [ParameterSpec('matcher', PipelineConfig().matcher,
                           ParamInfo(MATCHER_INFO_TEXT,
                                     choices=tuple(names)))]
    pipeline = PipelineConfig()
    groups = [type(getattr(pipeline, g)) for g in PIPELINE_GROUPS] + [PriorConfig, NodeConfig]
    for group in groups:
        specs += [ParameterSpec(f.name, f.default, f.metadata['param'])
                  for f in param_fields(group)]
    for name in names:
        specs += [ParameterSpec(f'{name}.{f.name}', f.default, f.metadata['param'])
                  for f in param_fields(type(default_config(name)))]
    return specs


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


@dataclass
class NodeSettings:
    """Everything the node runs with, built from a complete set of parameter values."""

    pipeline: PipelineConfig
    priors: PriorConfig
    node: NodeConfig


def node_config_from_params(values: Mapping[str, Any]) -> NodeConfig:
    """Build a :class:`NodeConfig` from flat parameters, ignoring unrelated names."""
    names = {f.name for f in param_fields(NodeConfig)}
    return replace_checked(NodeConfig(), {k: v for k, v in values.items() if k in names})


def settings_from_params(values: Mapping[str, Any]) -> NodeSettings:
    """Validate a complete set of values; raise :class:`ParameterError` with a reason."""
    node = node_config_from_params(values)
    if node.diagnostics_warn_failure_rate > node.diagnostics_error_failure_rate:
        raise ParameterError('diagnostics_warn_failure_rate must not exceed '
                             'diagnostics_error_failure_rate')
    if node.diagnostics_warn_processing_time > node.diagnostics_error_processing_time:
        raise ParameterError('diagnostics_warn_processing_time must not exceed '
                             'diagnostics_error_processing_time')
    return NodeSettings(pipeline_config_from_params(values),
                        prior_config_from_params(values), node)


def check_change(values: Mapping[str, Any], changes: Mapping[str, Any],
                 specs: Mapping[str, ParameterSpec]) -> str | None:
    """Return why ``changes`` cannot be applied on top of ``values``, or None if they can.

    Each changed value is checked against its own declaration (type, range, choices);
    then the whole merged set is validated, so that cross-parameter rules hold too.
    """
    try:
        for name, value in changes.items():
            spec = specs.get(name)
            if spec is None:
                continue
            check_value(name, value, spec.default, spec.info)
        settings_from_params({**values, **changes})
    except ParameterError as error:
        return str(error)
    return None
