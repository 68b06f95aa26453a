"""The README and the config files stay in step with the declared parameters."""

from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
BEGIN, END = '<!-- parameters:begin -->', '<!-- parameters:end -->'


def test_readme_parameter_table_is_current():
    pytest.importorskip('rclpy')
    from laser_odom.ros.default_params import markdown_table
    readme = (ROOT / 'README.md').read_text()
    table = readme.split(BEGIN, 1)[1].split(END, 1)[0].strip()
    assert table == markdown_table().strip(), (
        'README parameter table is stale: run `make docs`')


def test_readme_names_every_executable():
    readme = (ROOT / 'README.md').read_text()
    setup = (ROOT / 'setup.py').read_text()
    for name in ('laser_odom_node', 'laser_odom_replay', 'laser_odom_simulate',
                 'laser_odom_convert', 'laser_odom_bench'):
        assert name in setup
        assert name in readme
