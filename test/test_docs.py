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


def test_documented_figures_come_from_the_committed_benchmark_result():
    from laser_odom.tools.figures import (
        load_figures, MATCHERS, rendered_config, rendered_readme)
    payload = load_figures()
    assert payload['date'] and {'numpy', 'scipy', 'python'} <= set(payload['versions'])
    readme = (ROOT / 'README.md').read_text()
    assert rendered_readme(readme, payload) == readme, (
        'README figures differ from test/figures/benchmark.json: run `make docs`')
    for matcher in MATCHERS:
        path = ROOT / 'config' / f'{matcher}.yaml'
        text = path.read_text()
        assert rendered_config(text, payload, matcher) == text, (
            f'{path.name} figures differ from test/figures/benchmark.json: run `make docs`')


def test_a_figure_out_of_step_with_the_result_is_caught():
    from laser_odom.tools.figures import load_figures, readme_table, rendered_readme
    payload = load_figures()
    row = next(r for r in payload['rows'] if r['dataset'] == 'fr079' and r['matcher'] == 'nicp')
    readme = (ROOT / 'README.md').read_text()
    row['ate'] += 0.01  # the code moved on, the text did not
    assert rendered_readme(readme, payload) != readme
    assert f'{row["ate"]:.2f}' in readme_table(payload)


def test_figure_regression_allows_five_percent():
    from laser_odom.tools.figures import regression
    documented = {'rpe_trans_mean': 0.02, 'rpe_rot_mean': 0.4, 'ate': 2.0, 'failed': 0}
    assert regression(dict(documented, ate=2.09), documented) == []
    assert regression(dict(documented, ate=2.11), documented) == ['ate 2.1100 > 2.0000 + 5%']
    assert regression(dict(documented, rpe_rot_mean=0.43), documented)[0].startswith('rpe_rot')
    assert regression(dict(documented, failed=1), documented) == ['failed 1 > 0']
    assert regression(dict(documented, failed=20), dict(documented, failed=19)) == []
    assert regression(dict(documented, failed=21, ate=float('nan')),
                      dict(documented, failed=19)) == ['ate nan > 2.0000 + 5%', 'failed 21 > 20']


def test_figures_tool_says_what_is_missing(tmp_path, capsys):
    from laser_odom.tools.figures import main
    (tmp_path / 'bad.json').write_text('{"rows": []}')
    assert main(['--json', str(tmp_path / 'bad.json')]) == 2
    assert capsys.readouterr().err.strip() == (
        'figures: error: the benchmark result has no icp row on fr079 (constant_velocity '
        'prior): run make figures')
