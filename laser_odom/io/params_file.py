"""Read the node's ROS 2 parameter YAML file into flat parameter values.

The file has the layout ``ros2 run ... --params-file`` takes:
``<node name or /**>: {ros__parameters: {...}}``. Nested dicts become dotted names
(``icp: {max_iterations: 30}`` -> ``icp.max_iterations``), as ROS 2 does, so the replay
harness and the node read the same file into the same values.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, Mapping

import yaml

NODE_NAMES = ('laser_odom', 'laser_odom_node')
"""Names under which the odometry node's section may appear (besides ``/**``)."""


class ParamsFileError(ValueError):
    """The parameter file is missing, not YAML, or not laid out as a ROS 2 params file."""


def flatten(values: Mapping[str, Any], prefix: str = '') -> dict[str, Any]:
    """Return nested dicts as one dict with dotted keys."""
    flat: dict[str, Any] = {}
    for key, value in values.items():
        name = f'{prefix}{key}'
        if isinstance(value, Mapping):
            flat.update(flatten(value, name + '.'))
        else:
            flat[name] = value
    return flat


def _matches_node(key: str, node_names: tuple[str, ...]) -> bool:
    """Tell whether a section key addresses the node (``/**``, ``name``, ``/ns/name``)."""
    if key in ('/**', '**'):
        return True
    last = key.rstrip('/').rsplit('/', 1)[-1]
    return last in node_names


def load_node_params(path: str | Path,
                     node_names: tuple[str, ...] = NODE_NAMES) -> dict[str, Any]:
    """Return the flat parameter values for the node from a ROS 2 params file.

    Wildcard sections (``/**``) apply first and the node's own section overrides them;
    a file with a single section is taken whatever its key.
    """
    path = Path(path)
    try:
        document = yaml.safe_load(path.read_text())
    except FileNotFoundError:
        raise ParamsFileError(f'params file not found: {path}') from None
    except (OSError, UnicodeDecodeError) as err:
        raise ParamsFileError(f'cannot read params file {path}: {err}') from None
    except yaml.YAMLError as err:
        where = getattr(err, 'problem_mark', None)
        line = f' (line {where.line + 1})' if where is not None else ''
        raise ParamsFileError(f'params file {path} is not valid YAML{line}') from None
    if document is None:
        return {}
    if not isinstance(document, dict):
        raise ParamsFileError(f'params file {path}: expected "<node>: ros__parameters: ..."')
    keys = list(document) if len(document) == 1 else [
        k for k in document if _matches_node(str(k), node_names)]
    if not keys:
        raise ParamsFileError(f'params file {path} has no section for {node_names[0]} or /**')
    keys.sort(key=lambda k: 0 if str(k) in ('/**', '**') else 1)
    values: dict[str, Any] = {}
    for key in keys:
        section = document[key]
        if not isinstance(section, dict) or not isinstance(
                section.get('ros__parameters', {}), dict):
            raise ParamsFileError(f'params file {path}: section {key!r} needs a '
                                  '"ros__parameters" mapping')
        values.update(flatten(section.get('ros__parameters') or {}))
    return values
