"""``laser_odom_soak``: a console script with help for every option and one-line errors."""

from importlib import metadata
from pathlib import Path
import subprocess
import sys

import pytest

from laser_odom.tools import soak

ROOT = Path(__file__).resolve().parents[1]
OPTIONS = ('--scans', '--matcher', '--reference', '--world', '--beams', '--report-every',
           '--limit-mib')


def test_help_lists_every_option_with_its_text_and_exits_0():
    result = subprocess.run([sys.executable, '-m', 'laser_odom.tools.soak', '--help'],
                            cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert result.returncode == 0 and result.stderr == ''
    assert result.stdout.startswith('usage: laser_odom_soak')
    assert 'resident memory' in result.stdout
    for option in OPTIONS:
        assert option in result.stdout
    actions = [a for a in soak.build_parser()._actions if a.option_strings != ['-h', '--help']]
    assert sorted(a.option_strings[0] for a in actions) == sorted(OPTIONS)
    for action in actions:
        assert action.help and len(action.help) > 10, action.option_strings


def test_main_returns_0_for_help(capsys):
    assert soak.main(['--help']) == 0
    assert 'laser_odom_soak' in capsys.readouterr().out


def test_defaults_are_kept():
    args = soak.build_parser().parse_args([])
    assert (args.scans, args.world, args.beams, args.report_every, args.limit_mib) == (
        100_000, 'office', 360, 10_000, 20.0)


@pytest.mark.parametrize('argv, text', [
    (['--scans', '0'], 'argument --scans: 0 is too few'),
    (['--scans', '1000'], f'more than {soak.WARMUP_SCANS}'),
    (['--scans', 'many'], "'many' is not an integer"),
    (['--report-every', '0'], 'argument --report-every: 0 is outside'),
    (['--beams', '1'], 'argument --beams: 1 is outside'),
    (['--limit-mib', '0'], 'argument --limit-mib: 0 is outside'),
    (['--world', 'moon'], "invalid choice: 'moon'"),
    (['--matcher', 'slam'], "invalid choice: 'slam'"),
    (['--verbose'], 'unrecognized arguments: --verbose'),
])
def test_a_bad_argument_is_one_line_and_exit_code_2(argv, text, capsys):
    assert soak.main(argv) == 2
    captured = capsys.readouterr()
    assert captured.out == ''
    assert captured.err.count('\n') == 1, captured.err
    assert captured.err.startswith('laser_odom_soak: error: ') and text in captured.err


def test_a_short_soak_prints_the_table_and_passes(monkeypatch, capsys):
    monkeypatch.setattr(soak, 'WARMUP_SCANS', 20)
    assert soak.main(['--scans', '60', '--report-every', '20', '--beams', '90',
                      '--matcher', 'icp', '--limit-mib', '1000']) == 0
    out = capsys.readouterr().out
    assert out.startswith('# soak: 60 scans, matcher icp, reference scan, world office, 90 beams')
    assert [line.split()[0] for line in out.splitlines()[2:-1]] == ['20', '40', '60']
    assert '# resident memory growth after warm-up' in out


def test_console_script_is_installed():
    scripts = {ep.name: ep.value for ep in metadata.entry_points(group='console_scripts')}
    assert scripts.get('laser_odom_soak') == 'laser_odom.tools.soak:main', (
        'reinstall: python -m pip install --no-deps --no-build-isolation -e .')
    assert "'laser_odom_soak = laser_odom.tools.soak:main'" in (ROOT / 'setup.py').read_text()
