"""Read ROS 2 parameter files the way rcl does, for the node and every offline tool.

A params file (``--params-file``) maps node names to ``ros__parameters``::

    /**:                      # every node; also /*, /robot1/*, laser_odom, /ns/laser_odom
      ros__parameters:
        matcher: nicp
        nicp:
          max_iterations: 30  # nested names become nicp.max_iterations

The rules follow rcl's parser and rclpy's override resolution, so that a file means
the same to the live node and to the replay, the benchmark and the tools:

- a section key is a node name, absolute or not (a leading ``/`` is implied), in which
  ``/*`` stands for one name token and ``/**`` for any number; keys may also nest
  (``robot1: {laser_odom: {ros__parameters: ...}}`` is ``/robot1/laser_odom``);
- every section whose name matches the node's fully qualified name applies, in file
  order, later values overriding earlier ones (several files: in order given);
- a section without ``ros__parameters``, or with anything beside it, and a
  ``ros__parameters`` that is not a mapping are errors (rcl refuses such files);
- values are YAML scalars as rcl reads them (``1e6`` is a number, ``yes`` is true).

Which parameters exist, their types and ranges are judged afterwards by
:func:`laser_odom.core.configuration.node.check_values`, for files and for ``-p`` alike.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
import re
from typing import Any, Iterator, Mapping, Sequence

import yaml

from laser_odom.core.configuration.node import check_values, CheckedValues
from laser_odom.core.parameters import flatten, ParameterError

NODE_NAME = 'laser_odom'
"""The odometry node's default name."""

PARAMETERS_KEY = 'ros__parameters'


class ParamsFileError(ValueError):
    """The parameter file is missing, not YAML, or not laid out as a ROS 2 params file."""


class _RclLoader(yaml.SafeLoader):
    """YAML 1.1 as PyYAML reads it, plus the numbers rcl reads that PyYAML leaves as text.

    rcl parses an unquoted ``1e6`` or ``-2E-3`` as a floating-point number; YAML 1.1
    demands a dot in the mantissa. The resolver below adds the dot-less form.
    """


_RclLoader.add_implicit_resolver(
    'tag:yaml.org,2002:float', re.compile(r'^[-+]?[0-9]+[eE][-+]?[0-9]+$'),
    list('-+0123456789'))


@dataclass
class ParamsFile:
    """One parsed params file: its sections in file order."""

    path: Path
    sections: list[tuple[str, dict[str, Any]]] = field(default_factory=list)

    def names(self) -> list[str]:
        """Return the section names, as written (nesting joined with ``/``)."""
        return [name for name, _ in self.sections]

    def values_for(self, node_fqn: str) -> dict[str, Any] | None:
        """Return the flat values that apply to ``node_fqn`` (None: no section matches)."""
        values: dict[str, Any] | None = None
        for name, params in self.sections:
            if node_name_matches(name, node_fqn):
                values = {**(values or {}), **params}
        return values


def node_name_matches(pattern: str, node_fqn: str) -> bool:
    """Tell whether a section name applies to the node ``node_fqn`` (rclpy's rule).

    ``/*`` matches one name token and ``/**`` any number of them; a name without a
    leading slash is taken as absolute.
    """
    if not pattern.startswith('/'):
        pattern = '/' + pattern
    parts = re.split(r'(/\*)', pattern)
    regex = ''.join(r'(/\w+)' if part == '/*' else re.escape(part).replace(r'\*', '*')
                    for part in parts)
    try:
        return re.fullmatch(regex, node_fqn) is not None
    except re.error:
        return False


def rcl_values(values: Mapping[str, Any]) -> dict[str, Any]:
    """Return a section's parameters with dotted names, as rcl reads them.

    Raises :class:`ValueError` where rcl refuses the file: a name without a value, or
    a list mixing types.
    """
    flat = flatten(values)
    for name, value in flat.items():
        if value is None:
            raise ValueError(f'parameter {name!r} has no value')
        if isinstance(value, list) and len({type(v) for v in value}) > 1:
            raise ValueError(f'parameter {name!r}: a list must hold values of one type')
    return flat


def _sections(node: Any, path: Path, prefix: str) -> Iterator[tuple[str, dict[str, Any]]]:
    """Yield ``(node name, flat parameters)`` under one YAML mapping of node names."""
    for key, value in node.items():
        name = f'{prefix}/{key}' if prefix else str(key)
        if not isinstance(value, Mapping):
            where = (f'section {prefix!r} has {str(key)!r} where "{PARAMETERS_KEY}" belongs'
                     if prefix else f'section {name!r} has no "{PARAMETERS_KEY}" mapping')
            raise ParamsFileError(f'params file {path}: {where} (expected "<node name>: '
                                  f'{PARAMETERS_KEY}: <name>: <value>")')
        if PARAMETERS_KEY not in value:
            yield from _sections(value, path, name)
            continue
        params = value[PARAMETERS_KEY]
        if len(value) > 1 or not isinstance(params, Mapping):
            other = ', '.join(repr(str(k)) for k in value if k != PARAMETERS_KEY)
            problem = (f'has {other} beside "{PARAMETERS_KEY}"' if other else
                       f'has no parameters under "{PARAMETERS_KEY}"' if params is None else
                       f'"{PARAMETERS_KEY}" is not a mapping')
            raise ParamsFileError(f'params file {path}: section {name!r} {problem}')
        try:
            yield name, rcl_values(params)
        except ValueError as err:
            raise ParamsFileError(f'params file {path}: section {name!r}: {err}') from None


def parse_params_file(path: str | Path) -> ParamsFile:
    """Read and check the layout of one params file; raise :class:`ParamsFileError`."""
    path = Path(path)
    try:
        document = yaml.load(path.read_text(), Loader=_RclLoader)
    except FileNotFoundError:
        raise ParamsFileError(f'params file not found: {path}') from None
    except (OSError, UnicodeDecodeError) as err:
        raise ParamsFileError(f'cannot read params file {path}: {err}') from None
    except yaml.YAMLError as err:
        where = getattr(err, 'problem_mark', None)
        line = f' (line {where.line + 1})' if where is not None else ''
        raise ParamsFileError(f'params file {path} is not valid YAML{line}') from None
    parsed = ParamsFile(path)
    if document is None:
        return parsed
    if not isinstance(document, Mapping):
        raise ParamsFileError(f'params file {path}: expected "<node name>: '
                              f'{PARAMETERS_KEY}: ...", found a {type(document).__name__}')
    parsed.sections = list(_sections(document, path, ''))
    return parsed


def section_warnings(files: Sequence[ParamsFile], node_fqn: str,
                     consequence: str = 'the node runs on its defaults for them') -> list[str]:
    """Return a warning for every file none of whose sections applies to the node.

    The node starts anyway, as every ROS 2 node does with such a file; the warning
    says that it runs on its defaults, and how to address it.
    """
    warnings = []
    for parsed in files:
        if not parsed.sections:
            warnings.append(f'params file {parsed.path} is empty: none of its parameters '
                            f'apply, {consequence}')
        elif parsed.values_for(node_fqn) is None:
            warnings.append(
                f'params file {parsed.path} has no section for {node_fqn} (it has '
                f'{", ".join(parsed.names())}): none of its parameters apply, {consequence} '
                '- use "/**:" to address the node under any name and namespace')
    return warnings


def read_params_files(paths: Sequence[str | Path], node_fqn: str = '/' + NODE_NAME,
                      require_section: bool = False) -> CheckedValues:
    """Return the node's values from params files, judged as the node judges them.

    Raises :class:`ParamsFileError` for an unreadable or malformed file and for a value
    the node would refuse (wrong type, out of range); names the node does not have are
    reported in ``warnings``, and so are files with no section for ``node_fqn`` - or,
    with ``require_section`` (the replay, the benchmark, the tuner: a run on the
    defaults would be a run of settings the user did not ask for), they are an error.
    """
    files = [parse_params_file(path) for path in paths]
    if require_section:
        for message in section_warnings(files, node_fqn, 'so nothing would be run with it'):
            raise ParamsFileError(message)
    values: dict[str, Any] = {}
    for parsed in files:
        values.update(parsed.values_for(node_fqn) or {})
    try:
        checked = check_values(values)
    except ParameterError as err:
        where = ', '.join(str(p) for p in paths)
        raise ParamsFileError(f'bad parameter in {where}: {err}') from None
    checked.warnings[:0] = section_warnings(files, node_fqn)
    return checked
