"""``laser_odom_warmup`` compiles the kernels once; the node warms its matcher at start."""

import subprocess
import sys

from laser_odom.core import warmup
from laser_odom.tools.warmup import main


def test_warm_up_runs_each_matcher_once_per_process(monkeypatch):
    monkeypatch.setattr(warmup, '_WARM', set())
    first = warmup.warm_up(['icp'])
    assert first.matchers == ('icp',) and first.seconds > 0.0
    assert warmup._WARM == {'icp'}
    again = warmup.warm_up(['icp'])
    assert again.seconds < first.seconds and again.cache_dir == first.cache_dir


def test_the_tool_says_what_it_compiled_and_refuses_unknown_matchers(capsys):
    assert main(['plicp']) == 0
    out = capsys.readouterr().out
    assert out.startswith('laser_odom_warmup: kernels of plicp ready in ') and 'cache: ' in out
    result = subprocess.run([sys.executable, '-m', 'laser_odom.tools.warmup', 'sift'],
                            capture_output=True, text=True, timeout=120)
    assert result.returncode == 2 and result.stdout == ''
    assert result.stderr.strip().splitlines()[-1] == (
        "laser_odom_warmup: error: unknown matcher 'sift'; valid: icp, imls, nicp, plicp")
