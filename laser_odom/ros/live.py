"""Declared, validated and live-changeable parameters of the ``laser_odom`` node.

At start-up every parameter of :func:`laser_odom.ros.parameters.parameter_specs` is
declared (values from ``--params-file`` / ``-p`` override the defaults) and the whole
set is validated; a bad value stops start-up with a one-line :class:`StartupError`.
While running, ``ros2 param set`` (or any parameter-service client) is first checked
against the declaration (rclpy enforces type, range and read-only) and then against
the configuration rules (:func:`check_change`); a refusal carries the reason. Accepted
changes are applied from the next scan on, without losing the pose.
"""

from __future__ import annotations

from typing import Any, Callable

from rcl_interfaces.msg import SetParametersResult
from rclpy.exceptions import InvalidParameterTypeException, ParameterException
from rclpy.node import Node
from rclpy.parameter import Parameter

from laser_odom.core.config import MountingConfig, PipelineConfig
from laser_odom.core.params import ParameterError
from laser_odom.core.scan import LaserMounting
from laser_odom.ros.parameters import (
    check_change, descriptor, NodeSettings, parameter_specs, settings_from_params)


TYPE_NAMES = {bool: 'true or false', int: 'an integer', float: 'a floating-point number',
              str: 'a string'}
"""How a parameter's expected type is named in a start-up error."""


class StartupError(RuntimeError):
    """The node cannot start with the given parameters (a one-line reason)."""


class LiveParameters:
    """The node's parameter values, their validation and change notification."""

    def __init__(self, node: Node, on_change: Callable[[dict[str, Any]], None]) -> None:
        """Declare every parameter and validate the start-up values."""
        self._node = node
        self._on_change = on_change
        self.specs = {spec.name: spec for spec in parameter_specs()}
        self.values: dict[str, Any] = {}
        self.tf_mounting: LaserMounting | None = None
        for spec in self.specs.values():
            try:
                declared = node.declare_parameter(spec.name, spec.default, descriptor(spec))
            except InvalidParameterTypeException:
                raise StartupError(
                    f'parameter {spec.name} must be {TYPE_NAMES[type(spec.default)]}'
                    + (' (write 1.0, not 1)' if isinstance(spec.default, float) else '')
                ) from None
            except ParameterException as error:
                reason = str(error.args[0]).removesuffix(f': {spec.name}')
                raise StartupError(f'parameter {spec.name}: {reason}') from None
            self.values[spec.name] = declared.value
        try:
            self.settings: NodeSettings = settings_from_params(self.values)
        except ParameterError as error:
            raise StartupError(str(error)) from None
        self._warn_unknown_overrides()

    def start(self) -> None:
        """Start accepting live changes (after the node is fully built)."""
        self._node.add_on_set_parameters_callback(self._validate)
        self._node.add_post_set_parameters_callback(self._apply)

    def _warn_unknown_overrides(self) -> None:
        """Warn about parameters given to the node that it does not have (likely typos)."""
        overrides = getattr(self._node, '_parameter_overrides', {}) or {}
        for name in sorted(overrides):
            if not self._node.has_parameter(name):
                self._node.get_logger().warning(
                    f'parameter {name!r} is not a parameter of this node; ignored')

    def pipeline_config(self) -> PipelineConfig:
        """Return a fresh pipeline configuration of the current values.

        When the laser mounting comes from TF, it replaces the ``laser_*`` parameters.
        """
        config = settings_from_params(self.values).pipeline
        if self.tf_mounting is not None:
            m = self.tf_mounting
            config.mounting = MountingConfig(m.x, m.y, m.yaw, m.upside_down)
        return config

    def _validate(self, parameters: list[Parameter]) -> SetParametersResult:
        """Accept or refuse a set of changes, with a reason (on-set callback)."""
        changes = {p.name: p.value for p in parameters if p.name in self.specs}
        reason = check_change(self.values, changes, self.specs)
        return SetParametersResult(successful=reason is None, reason=reason or '')

    def _apply(self, parameters: list[Parameter]) -> None:
        """Store accepted changes and hand them to the node (post-set callback)."""
        changes = {p.name: p.value for p in parameters if p.name in self.specs}
        if not changes:
            return
        self.values.update(changes)
        self.settings = settings_from_params(self.values)
        self._on_change(changes)
