"""``laser_odom_bench``: rows per prior, a parameter file for every row, the search table."""

import json

from laser_odom.tools.bench import main


def test_params_file_applies_to_every_row_and_the_search_table_is_printed(tmp_path, capsys):
    off = tmp_path / 'off.yaml'
    off.write_text("/**:\n  ros__parameters:\n    global_search: 'off'\n")
    rows = {}
    for label, extra in (('recover', []), ('off', ['--params-file', str(off)])):
        out = tmp_path / f'{label}.json'
        assert main(['--matchers', 'nicp', '--datasets', 'sim-spin-drop20', '--priors',
                     'none', '--no-progress', '--json', str(out)] + extra) == 0
        rows[label] = json.loads(out.read_text())
    printed = capsys.readouterr().out
    assert 'global search alone' in printed and 'sim-spin-drop20' in printed
    recover, = rows['recover']['rows']
    assert recover['prior'] == 'none' and recover['failed'] == 0 and recover['ate'] < 0.05
    search, = rows['recover']['search']
    assert search['searches'] >= 40 and search['median_ms'] > 0.0
    # Without the search, spinning at 3 rad/s with no prior loses the track.
    off_row, = rows['off']['rows']
    assert off_row['rejected'] >= 10 and off_row['failed'] >= 10 and off_row['ate'] > 1.0


def test_zero_is_still_a_prior_name_and_bad_input_is_one_line(tmp_path, capsys):
    bad = tmp_path / 'bad.yaml'
    bad.write_text("/**:\n  ros__parameters:\n    global_search: 'sometimes'\n")
    assert main(['--matchers', 'nicp', '--datasets', 'sim-office-360', '--priors', 'zero',
                 '--params-file', str(bad), '--no-progress']) == 2
    error = capsys.readouterr().err.strip()
    assert error.count('\n') == 0 and 'global_search' in error and 'sometimes' in error
    assert main(['--priors', 'sometimes', '--no-progress']) == 2
    assert 'unknown prior' in capsys.readouterr().err
