"""Declarative parameters: one place says each setting's default, meaning and range.

Configuration dataclasses mark their fields with :func:`param`. The ROS node turns
those fields into declared ROS parameters (with description and range), the replay
harness reads the node's YAML into the same dataclasses, and validation happens here
once, so a value is judged the same way live and offline.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field, fields
from typing import Any, Mapping, Sequence, TypeVar

ConfigT = TypeVar('ConfigT')


class ParameterError(ValueError):
    """A parameter value is out of range, of the wrong type, or unknown."""


@dataclass(frozen=True)
class ParamInfo:
    """What a parameter means and which values it accepts."""

    description: str
    low: float | None = None
    high: float | None = None
    choices: Sequence[str] | None = None
    read_only: bool = False
    at_most: tuple[str, ...] = ()
    """Parameters of the same group (field names) this one must not exceed: a minimum
    above its maximum (``normal_min_neighbours`` above ``normal_neighbours``) would
    leave nothing to use - every point without a normal, every match rejected."""


def param(default: Any, description: str, low: float | None = None,
          high: float | None = None, choices: Sequence[str] | None = None,
          read_only: bool = False, at_most: str | Sequence[str] = ()) -> Any:
    """Declare a configuration field with its default, description and valid range.

    ``at_most`` names the fields of the same configuration whose values this one must
    not exceed; :func:`laser_odom.core.configuration.node.check_order` checks every such
    pair wherever values are read.
    """
    info = ParamInfo(description, low, high, tuple(choices) if choices else None, read_only,
                     (at_most,) if isinstance(at_most, str) else tuple(at_most))
    return field(default=default, metadata={'param': info})


def retune(config_type: type, name: str, default: Any) -> Any:
    """Redeclare an inherited parameter with a new (tuned) default.

    The meaning and range stay those of ``config_type``'s field, written once there, so
    a matcher's configuration states only what it tunes differently.
    """
    for f in fields(config_type):
        if f.name == name:
            return field(default=default, metadata=f.metadata)
    raise ParameterError(f'{config_type.__name__} has no parameter {name!r}')


def param_info(config_type: type, name: str) -> ParamInfo:
    """Return the :class:`ParamInfo` of one field of a configuration dataclass."""
    for f in fields(config_type):
        if f.name == name:
            return f.metadata['param']
    raise ParameterError(f'unknown parameter {name!r}')


def param_fields(config_type: type) -> list[dataclasses.Field]:
    """Return the declared parameter fields of a configuration dataclass."""
    return [f for f in fields(config_type) if 'param' in f.metadata]


YAML_BOOLEAN_WORDS = {False: ('off', 'no', 'false'), True: ('on', 'yes', 'true')}
"""Words YAML 1.1 (rcl, PyYAML, ``ros2 param set``) reads as booleans when unquoted."""


def yaml_word(value: Any, info: ParamInfo) -> Any:
    """Return the choice a user meant when YAML turned an unquoted word into a boolean.

    ``global_search: off`` reaches the node as ``false``; when exactly one of the
    choices is a word YAML reads as that boolean, that choice is meant.
    """
    if isinstance(value, bool) and info.choices:
        meant = [c for c in info.choices if c.lower() in YAML_BOOLEAN_WORDS[value]]
        if len(meant) == 1:
            return meant[0]
    return value


def check_value(name: str, value: Any, default: Any, info: ParamInfo) -> Any:
    """Validate and coerce one value; raise :class:`ParameterError` with a reason."""
    if isinstance(default, bool):
        if not isinstance(value, bool):
            raise ParameterError(f'{name} must be true or false, got {value!r}')
        return value
    if isinstance(default, (int, float)):
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise ParameterError(f'{name} must be a number, got {value!r}')
        if isinstance(default, int) and not float(value).is_integer():
            raise ParameterError(f'{name} must be an integer, got {value!r}')
        if value != value:
            raise ParameterError(f'{name} must not be NaN')
        if info.low is not None and value < info.low:
            raise ParameterError(f'{name}={value} is below the minimum {info.low}')
        if info.high is not None and value > info.high:
            raise ParameterError(f'{name}={value} is above the maximum {info.high}')
        return type(default)(value)
    if isinstance(default, str):
        value = yaml_word(value, info)
        if isinstance(value, bool):
            raise ParameterError(f'{name} must be a string, got {str(value).lower()} (YAML '
                                 'reads unquoted on/off/yes/no as booleans: quote the word)')
        if not isinstance(value, str):
            raise ParameterError(f'{name} must be a string, got {value!r}')
        if info.choices is not None and value not in info.choices:
            raise ParameterError(
                f'{name}={value!r} is not one of: {", ".join(info.choices)}')
        return value
    return value


def replace_checked(config: ConfigT, values: Mapping[str, Any], prefix: str = '') -> ConfigT:
    """Return a copy of ``config`` with ``values`` applied after validation.

    Raises :class:`ParameterError` naming the first bad or unknown parameter.
    """
    known = {f.name: f for f in param_fields(type(config))}
    changes = {}
    for name, value in values.items():
        if name not in known:
            raise ParameterError(f'unknown parameter {prefix}{name}')
        f = known[name]
        changes[name] = check_value(prefix + name, value, f.default, f.metadata['param'])
    return dataclasses.replace(config, **changes)


def flatten(values: Mapping[str, Any], prefix: str = '') -> dict[str, Any]:
    """Return nested names as dotted ones, as ROS 2 does (``nicp: {h: 1}`` is ``nicp.h``)."""
    flat: dict[str, Any] = {}
    for key, value in values.items():
        if isinstance(value, Mapping):
            flat.update(flatten(value, f'{prefix}{key}.'))
        else:
            flat[f'{prefix}{key}'] = value
    return flat


def as_dict(config: Any) -> dict[str, Any]:
    """Return the declared parameters of a configuration as a plain dict."""
    return {f.name: getattr(config, f.name) for f in param_fields(type(config))}
