"""The one params-file reader: rcl's layout and node-name rules, the node's value rules."""

from pathlib import Path

import pytest

from laser_odom.core.configuration.node import check_values
from laser_odom.core.parameters import ParameterError
from laser_odom.io.params_file import (
    node_name_matches, ParamsFileError, parse_params_file, read_params_files)

CONFIG_DIR = Path(__file__).resolve().parents[1] / 'config'


@pytest.mark.parametrize('pattern, fqn, applies', [
    ('/**', '/laser_odom', True),
    ('/**', '/robot1/front/laser_odom', True),
    ('**', '/laser_odom', True),
    ('laser_odom', '/laser_odom', True),
    ('laser_odom', '/robot1/laser_odom', False),
    ('/robot1/laser_odom', '/robot1/laser_odom', True),
    ('robot1/laser_odom', '/robot1/laser_odom', True),
    ('/*', '/laser_odom', True),
    ('/*', '/robot1/laser_odom', False),
    ('/robot1/*', '/robot1/laser_odom', True),
    ('/robot1/*', '/robot2/laser_odom', False),
    ('/**/laser_odom', '/a/b/laser_odom', True),
    ('/**/laser_odom', '/laser_odom', True),
    ('/**/laser_odom', '/robot1/front_odom', False),
    ('laser_odom_node', '/laser_odom', False),
])
def test_section_names_match_as_rclpy_resolves_them(pattern, fqn, applies):
    assert node_name_matches(pattern, fqn) is applies


def _write(tmp_path: Path, text: str) -> Path:
    path = tmp_path / 'params.yaml'
    path.write_text(text)
    return path


def test_sections_apply_in_file_order_and_nest(tmp_path):
    path = _write(tmp_path, (
        '/**:\n  ros__parameters:\n    matcher: icp\n    max_scan_gap: 2.0\n'
        'robot1:\n  laser_odom:\n    ros__parameters:\n      matcher: plicp\n'
        'other:\n  ros__parameters:\n    matcher: imls\n'))
    assert read_params_files([path], '/robot1/laser_odom').values == {
        'matcher': 'plicp', 'max_scan_gap': 2.0}
    assert read_params_files([path], '/laser_odom').values['matcher'] == 'icp'
    # Later files override earlier ones.
    second = tmp_path / 'second.yaml'
    second.write_text('/**:\n  ros__parameters:\n    matcher: nicp\n')
    assert read_params_files([path, second], '/laser_odom').values['matcher'] == 'nicp'


def test_values_are_typed_as_rcl_types_them(tmp_path):
    path = _write(tmp_path, (
        '/**:\n  ros__parameters:\n    max_scan_gap: 5\n    nicp:\n'
        '      max_iterations: 40\n    global_search: off\n'
        '    max_residual_ratio: 1e2\n'))
    values = read_params_files([path]).values
    assert values['max_scan_gap'] == 5.0 and isinstance(values['max_scan_gap'], float)
    assert values['nicp.max_iterations'] == 40
    assert values['global_search'] == 'off'  # YAML reads unquoted off as false
    assert values['max_residual_ratio'] == 100.0  # rcl reads 1e2 as a number


@pytest.mark.parametrize('text, words', [
    ('laser_odom:\n  max_scan_gap: 5.0\n', ['laser_odom', 'ros__parameters']),
    ('/**:\n  ros__parameters:\n', ['/**', 'no parameters']),
    ('/**:\n  ros__parameters: 5\n', ['not a mapping']),
    ('/**:\n  ros__parameters:\n    a: 1\n  other: 3\n', ["'other' beside"]),
    ('/**:\n  ros__parameters:\n    a: [1, 2.5]\n', ["'a'", 'one type']),
    ('/**:\n  ros__parameters:\n    a:\n', ["'a'", 'no value']),
    ('/**:\n  ros__parameters:\n    a: [1\n', ['not valid YAML', 'line 4']),
    ('- a\n- b\n', ['expected', 'list']),
    ('just text\n', ['expected', 'str']),
])
def test_files_rcl_refuses_are_one_line_errors(tmp_path, text, words):
    with pytest.raises(ParamsFileError) as error:
        parse_params_file(_write(tmp_path, text))
    message = str(error.value)
    assert '\n' not in message and all(w in message for w in words), message


def test_unknown_names_are_warned_with_a_likely_intent_and_ignored(tmp_path):
    path = _write(tmp_path, (
        '/**:\n  ros__parameters:\n    max_scan_gapp: 5.0\n    use_sim_time: true\n'
        '    nicpp:\n      max_iterations: 3\n    nicp:\n      max_iteratons: 3\n'))
    checked = read_params_files([path])
    assert checked.values == {}
    assert len(checked.warnings) == 3
    for name, meant in (('max_scan_gapp', 'max_scan_gap'),
                        ('nicpp.max_iterations', 'nicp.max_iterations'),
                        ('nicp.max_iteratons', 'nicp.max_iterations')):
        assert any(f"'{name}' is not a parameter" in w and f"'{meant}'" in w
                   for w in checked.warnings), checked.warnings


def test_files_that_address_no_node_or_nothing_are_warned(tmp_path):
    path = _write(tmp_path, 'front_odom:\n  ros__parameters:\n    matcher: icp\n')
    checked = read_params_files([path], '/laser_odom')
    assert checked.values == {}
    warning, = checked.warnings
    assert 'no section for /laser_odom' in warning and 'front_odom' in warning
    assert 'none of its parameters apply, the node runs on its defaults for them' in warning
    empty = tmp_path / 'empty.yaml'
    empty.write_text('')
    assert 'empty' in read_params_files([empty]).warnings[0]
    # The replay, the benchmark and the tuner: an error, not a run on the defaults.
    for unaddressed in (path, empty):
        with pytest.raises(ParamsFileError) as error:
            read_params_files([unaddressed], '/laser_odom', require_section=True)
        assert str(error.value).startswith(f'params file {unaddressed} ')
        assert 'so nothing would be run with it' in str(error.value)


@pytest.mark.parametrize('values, words', [
    ({'max_scan_gap': 'soon'}, ['max_scan_gap', 'must be a number']),
    ({'min_inlier_ratio': 7.0}, ['min_inlier_ratio', 'above the maximum']),
    ({'nicp.max_iterations': 2.5}, ['nicp.max_iterations', 'integer']),
    ({'global_search': True}, ['global_search', 'must be a string', 'quote the word']),
    ({'matcher': 'gicp'}, ['matcher', 'not one of']),
    ({'diagnostics_warn_failure_rate': 0.9}, ['must not exceed']),
])
def test_wrong_types_and_ranges_are_refused_by_name(values, words):
    with pytest.raises(ParameterError) as error:
        check_values(values)
    assert all(w in str(error.value) for w in words), str(error.value)


@pytest.mark.parametrize('path', sorted(CONFIG_DIR.glob('*.yaml')), ids=lambda p: p.name)
def test_every_shipped_file_addresses_any_node_name_and_is_clean(path):
    assert parse_params_file(path).names() == ['/**']
    for fqn in ('/laser_odom', '/robot1/laser_odom', '/front_odom'):
        checked = read_params_files([path], fqn)
        assert checked.warnings == [] and checked.values
