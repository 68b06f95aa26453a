"""The node's settings: every parameter it has, and the one set of rules that judges them.

Every field marked with :func:`laser_odom.core.parameters.param` is a parameter of the
node with its description, numeric range and read-only flag; matcher settings are
namespaced ``<matcher>.<field>`` for every registered matcher, so a YAML file can
tune all of them and ``matcher`` switches between them. This module is ROS-free: the
node declares these parameters (:mod:`laser_odom.ros.parameters`), and the node, the
replay, the benchmark and the tools all pass the values they were given through
:func:`check_values` and :func:`settings_from_params`, so a value is judged the same
way live, at start-up and offline.
"""

from __future__ import annotations

from dataclasses import dataclass, field
import difflib
from typing import Any, Mapping

from laser_odom.core.configuration.pipeline import (
    pipeline_config_from_params, PIPELINE_GROUPS, PipelineConfig)
from laser_odom.core.matchers import default_config, matcher_names
from laser_odom.core.parameters import (
    check_value, param, param_fields, ParameterError, ParamInfo, replace_checked)


@dataclass
class PriorConfig:
    """How long prior messages are kept and how far they may be extrapolated."""

    prior_buffer_duration: float = param(
        5.0, 'History of wheel odometry / IMU messages kept for the prior [s].', 0.1, 600.0)
    prior_max_extrapolation: float = param(
        0.1, 'The prior is stale when a scan is newer than the newest prior message by '
        'more than this [s]; up to it the last rate is extrapolated.', 0.0, 10.0)


def prior_config_from_params(values: Mapping[str, Any]) -> PriorConfig:
    """Build a :class:`PriorConfig` from flat parameters, ignoring unrelated names."""
    names = {f.name for f in param_fields(PriorConfig)}
    return replace_checked(PriorConfig(), {k: v for k, v in values.items() if k in names})


@dataclass
class NodeConfig:
    """Settings of the ROS shell only: frames, TF and diagnostics thresholds."""

    odom_frame: str = param(
        'odom', 'Frame of the published pose (parent of base_frame).', read_only=True)
    base_frame: str = param(
        'base_link', 'Robot base frame: the odometry is of this frame.', read_only=True)
    publish_tf: bool = param(
        True, 'Broadcast odom_frame -> base_frame on /tf (needs tf2_ros).')
    publish_debug: bool = param(
        False, 'Publish each matched scan in odom_frame on ~/matched_scan '
        '(sensor_msgs/PointCloud2), to check matches in RViz; with reference: local_map '
        'also the local map on ~/local_map, at most once a second.')
    use_tf_extrinsic: bool = param(
        False, 'Take the laser mounting from TF (base_frame <- scan frame_id) instead of '
        'laser_x/laser_y/laser_yaw/laser_upside_down (needs tf2_ros).', read_only=True)
    diagnostics_warn_failure_rate: float = param(
        0.2, 'Diagnostics WARN when this fraction of the matches in the last period failed.',
        0.0, 1.0, at_most='diagnostics_error_failure_rate')
    diagnostics_error_failure_rate: float = param(
        0.5, 'Diagnostics ERROR when this fraction of the matches in the last period failed.',
        0.0, 1.0)
    diagnostics_warn_processing_time: float = param(
        0.1, 'Diagnostics WARN when the median processing time per scan exceeds this [s].',
        0.0, 60.0, at_most='diagnostics_error_processing_time')
    diagnostics_error_processing_time: float = param(
        0.5, 'Diagnostics ERROR when the median processing time per scan exceeds this [s].',
        0.0, 60.0)


MATCHER_INFO_TEXT = 'Scan matcher. May be switched while running; the pose is kept.'


ROS_PARAMETERS = ('use_sim_time', 'start_type_description_service')
"""Parameters every rclpy node declares itself: known, never ours to judge."""


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


def ordered_pairs(specs: list[ParameterSpec] | None = None) -> list[tuple[str, str]]:
    """Return every ``(low, high)`` pair of parameters whose values must not cross.

    The pairs are declared beside the parameters (``param(..., at_most=...)``): a
    minimum and its maximum, a warning and its error threshold, a matcher's
    ``normal_min_neighbours`` and ``normal_neighbours`` - a matcher's pairs under
    its prefix (``nicp.normal_min_neighbours``, ``nicp.normal_neighbours``).
    """
    pairs = []
    for spec in parameter_specs() if specs is None else specs:
        prefix = spec.name.rpartition('.')[0]
        pairs += [(spec.name, f'{prefix}.{high}' if prefix else high)
                  for high in spec.info.at_most]
    return pairs


def order_error(low: str, low_value: Any, high: str, high_value: Any) -> str:
    """Return the one-line reason a pair is refused, naming both parameters."""
    return f'{low}={low_value:g} must not exceed {high}={high_value:g}'


def check_order(values: Mapping[str, Any]) -> None:
    """Raise :class:`ParameterError` when a pair of :func:`ordered_pairs` is crossed.

    ``values`` may be partial: a parameter it does not set has its default. The node
    (at start-up and on every ``ros2 param set``), the replay, the benchmark and the
    tuner all reach this through :func:`settings_from_params`, so a crossed pair is
    refused in the same words everywhere.
    """
    specs = parameter_specs()
    defaults = {spec.name: spec.default for spec in specs}
    for low, high in ordered_pairs(specs):
        low_value, high_value = values.get(low, defaults[low]), values.get(high, defaults[high])
        if low_value > high_value:
            raise ParameterError(order_error(low, low_value, high, high_value))


def settings_from_params(values: Mapping[str, Any]) -> NodeSettings:
    """Validate a complete set of values; raise :class:`ParameterError` with a reason.

    Each value is judged on its own (type, range), then every ordered pair
    (:func:`check_order`).
    """
    node = node_config_from_params(values)
    settings = NodeSettings(pipeline_config_from_params(values),
                            prior_config_from_params(values), node)
    check_order(values)
    return settings


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


@dataclass
class CheckedValues:
    """Parameter values as the node takes them, and what was said about them.

    ``values`` holds the node's own parameters only, with their declared types
    (an integer given for a floating-point parameter is taken as that number);
    ``warnings`` names every given parameter the node does not have.
    """

    values: dict[str, Any] = field(default_factory=dict)
    warnings: list[str] = field(default_factory=list)


def unknown_parameter_warning(name: str, known: list[str] | None = None) -> str:
    """Return the warning for a parameter the node does not have, with a likely intent."""
    known = known if known is not None else [s.name for s in parameter_specs()]
    close = difflib.get_close_matches(name, known, n=1, cutoff=0.8)
    hint = f' (did you mean {close[0]!r}?)' if close else ''
    return f'parameter {name!r} is not a parameter of this node; ignored{hint}'


def check_values(values: Mapping[str, Any]) -> CheckedValues:
    """Judge parameter values the way the node does at start-up.

    Unknown names (a misspelt parameter, matcher section or matcher parameter) are
    warned about and ignored; a known name with a value of the wrong type or out of
    range raises :class:`ParameterError` naming it; an integer where a floating-point
    number is declared is taken. The node, the replay, the benchmark and every tool
    that reads a params file call this, so they accept, warn and refuse alike.
    """
    specs = {spec.name: spec for spec in parameter_specs()}
    checked = CheckedValues()
    for name, value in values.items():
        spec = specs.get(name)
        if spec is None:
            if name not in ROS_PARAMETERS:
                checked.warnings.append(unknown_parameter_warning(name, list(specs)))
            continue
        checked.values[name] = check_value(name, value, spec.default, spec.info)
    settings_from_params(checked.values)
    return checked
