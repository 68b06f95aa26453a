"""Declared, validated and live-changeable parameters of the ``laser_odom`` node.

At start-up the values given to the node (``--params-file`` / ``-p``, as rcl resolved
them for this node's name and namespace) are judged by
:func:`laser_odom.core.configuration.node.check_values` - the rules the replay and the tools
apply to the same file: unknown names are warned about, an integer is taken where a
floating-point number is declared, a wrong type or range stops start-up with a
one-line :class:`StartupError`. Every parameter of
:func:`laser_odom.core.configuration.node.parameter_specs` is then declared with its value.

While running, a change through the parameter service (``ros2 param set``) is judged
by :meth:`LiveParameters.refusal` before rclpy sees it: an unknown name is refused
with its name, an integer for a floating-point parameter is converted, a wrong type,
range, read-only parameter or cross-parameter rule is refused with the reason, and
``publish_tf: true`` is refused when tf2_ros is missing. Accepted changes are
applied from the next scan on, without losing the pose.
"""

from __future__ import annotations

from typing import Any, Callable, Sequence

from rcl_interfaces.msg import SetParametersResult
from rclpy.node import Node
from rclpy.parameter import Parameter

from laser_odom.core.configuration.node import (
    check_change, check_values, NodeSettings, parameter_specs, ROS_PARAMETERS,
    settings_from_params, unknown_parameter_warning)
from laser_odom.core.configuration.pipeline import MountingConfig, PipelineConfig
from laser_odom.core.parameters import check_value, ParameterError, yaml_word
from laser_odom.core.scan.laser_scan import LaserMounting
from laser_odom.io.params_file import ParamsFile, section_warnings
from laser_odom.ros.parameters import descriptor


class StartupError(RuntimeError):
    """The node cannot start with the given parameters (a one-line reason)."""


def _source(params_files: Sequence[ParamsFile], node_fqn: str) -> str:
    """Return ``' in FILE'`` for the first params file that is bad on its own, else ''.

    The replay names the file in the same words, so both say where to look.
    """
    for parsed in params_files:
        try:
            check_values(parsed.values_for(node_fqn) or {})
        except ParameterError:
            return f' in {parsed.path}'
    return ''


class LiveParameters:
    """The node's parameter values, their validation and change notification."""

    def __init__(self, node: Node, on_change: Callable[[dict[str, Any]], None],
                 params_files: Sequence[ParamsFile] = (), tf_available: bool = True) -> None:
        """Judge the given values, declare every parameter and validate the whole set.

        ``params_files`` are the files the node was started with (already parsed by
        :func:`laser_odom.io.params_file.parse_params_file`), used only to warn when
        none of a file's sections addresses this node.
        """
        self._node = node
        self._on_change = on_change
        self._tf_available = tf_available
        self.specs = {spec.name: spec for spec in parameter_specs()}
        self.tf_mounting: LaserMounting | None = None
        overrides = getattr(node, '_parameter_overrides', {}) or {}
        fqn = node.get_fully_qualified_name()
        try:
            given = check_values({name: p.value for name, p in overrides.items()})
        except ParameterError as error:
            raise StartupError(f'bad parameter{_source(params_files, fqn)}: {error}') from None
        log = node.get_logger()
        if not tf_available:  # reads back as what happens (the start-up line says why)
            given.values['publish_tf'] = False
        for warning in section_warnings(params_files, fqn):
            log.warning(warning)
        for warning in given.warnings:
            log.warning(warning)
        self.values: dict[str, Any] = {}
        for spec in self.specs.values():
            value = given.values.get(spec.name, spec.default)
            node.declare_parameter(spec.name, value, descriptor(spec), ignore_override=True)
            self.values[spec.name] = value
        try:
            self.settings: NodeSettings = settings_from_params(self.values)
        except ParameterError as error:
            raise StartupError(f'bad parameter: {error}') from None

    def start(self) -> None:
        """Start accepting live changes (after the node is fully built)."""
        self._node.add_on_set_parameters_callback(self._validate)
        self._node.add_post_set_parameters_callback(self._apply)

    def pipeline_config(self) -> PipelineConfig:
        """Return a fresh pipeline configuration of the current values.

        When the laser mounting comes from TF, it replaces the ``laser_*`` parameters.
        """
        config = settings_from_params(self.values).pipeline
        if self.tf_mounting is not None:
            m = self.tf_mounting
            config.mounting = MountingConfig(m.x, m.y, m.yaw, m.upside_down)
        return config

    def converted(self, parameters: Sequence[Parameter]) -> list[Parameter]:
        """Return ``parameters`` as the node means them, as in a params file.

        ``ros2 param set /laser_odom max_scan_gap 5`` sends an integer: taken as 5.0.
        ``ros2 param set /laser_odom global_search off`` sends ``false`` (YAML): taken
        as ``'off'`` (:func:`laser_odom.core.parameters.yaml_word`).
        """
        result = []
        for p in parameters:
            spec = self.specs.get(p.name)
            if spec is None:
                pass
            elif isinstance(spec.default, float) and p.type_ == Parameter.Type.INTEGER:
                p = Parameter(p.name, Parameter.Type.DOUBLE, float(p.value))
            elif isinstance(spec.default, str) and p.type_ == Parameter.Type.BOOL:
                word = yaml_word(p.value, spec.info)
                if isinstance(word, str):
                    p = Parameter(p.name, Parameter.Type.STRING, word)
            result.append(p)
        return result

    def refusal(self, parameters: Sequence[Parameter]) -> str | None:
        """Return why a change through the parameter service is refused (None: it is not).

        Runs before rclpy's own checks, so that every refusal names the parameter and
        says what is wrong in the words the start-up checks use.
        """
        for p in parameters:
            spec = self.specs.get(p.name)
            if spec is None:
                if p.name in ROS_PARAMETERS:
                    continue
                return unknown_parameter_warning(p.name, list(self.specs)).replace(
                    '; ignored', '')
            if spec.info.read_only:
                return f'{p.name} is read-only: it is fixed at start-up'
            try:
                check_value(p.name, p.value, spec.default, spec.info)
            except ParameterError as error:
                return str(error)
            if p.name == 'publish_tf' and p.value and not self._tf_available:
                return ('publish_tf cannot be enabled: tf2_ros is not installed, so this '
                        'node cannot broadcast TF')
        return None

    def _validate(self, parameters: list[Parameter]) -> SetParametersResult:
        """Accept or refuse a set of changes, with a reason (on-set callback)."""
        reason = self.refusal(parameters)
        if reason is None:
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
