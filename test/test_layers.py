"""The package's layers import downwards only (read from the source, deferred imports too).

The core is ROS-free (numpy/scipy: importable and testable without rclpy), and the
matchers sit below the pipeline: a matcher that imports the acceptance test or the
configuration makes an import cycle through ``core/config``, which imports the
matcher registry.
"""

import ast
from pathlib import Path

import pytest

PACKAGE = Path(__file__).resolve().parent.parent / 'laser_odom'

PIPELINE_LAYER = ('acceptance', 'announce', 'benchmark', 'config', 'map_reference',
                  'map_registration', 'pipeline', 'priors', 'registration', 'runner',
                  'settings', 'tuning')
"""Modules of ``laser_odom.core`` that assemble the matchers into the odometry."""


def imported_modules(path: Path) -> set[str]:
    """Return every module a source file imports, at any depth of its code."""
    names = set()
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            names.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom) and node.module:
            names.add(node.module)
    return names


def sources(*parts: str) -> list[Path]:
    """Return the Python files under ``laser_odom/<parts>``."""
    return sorted(PACKAGE.joinpath(*parts).rglob('*.py'))


def test_the_helper_sees_imports_inside_functions(tmp_path):
    source = tmp_path / 'm.py'
    source.write_text('import a\n\ndef f():\n    from b.c import d\n    import e.f\n')
    assert imported_modules(source) == {'a', 'b.c', 'e.f'}


@pytest.mark.parametrize('path', sources('core'), ids=lambda p: str(p.relative_to(PACKAGE)))
def test_core_is_ros_free(path):
    banned = [name for name in imported_modules(path)
              if name.split('.')[0] in ('rclpy', 'rosbags') or name.startswith(
                  ('laser_odom.ros', 'laser_odom.io', 'laser_odom.tools'))]
    assert not banned, f'{path} imports {banned}'


@pytest.mark.parametrize('path', sources('core', 'matchers') + sources('core', 'search'),
                         ids=lambda p: str(p.relative_to(PACKAGE)))
def test_matchers_and_search_do_not_import_the_pipeline_layer(path):
    banned = [name for name in imported_modules(path)
              if name.startswith('laser_odom.core.')
              and name.split('.')[2] in PIPELINE_LAYER]
    assert not banned, f'{path} imports {banned}'
