"""Code style as ament_flake8 and ament_pep257 check it (configuration in setup.cfg)."""

from pathlib import Path
import subprocess
import sys

import pytest

ROOT = Path(__file__).resolve().parents[1]


def run_tool(module: str, *args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, '-m', module, *args], cwd=ROOT,
                          capture_output=True, text=True)


@pytest.mark.linter
def test_flake8():
    pytest.importorskip('flake8')
    result = run_tool('flake8', 'laser_odom', 'test', 'setup.py')
    assert result.returncode == 0, result.stdout + result.stderr


@pytest.mark.linter
def test_pep257():
    pytest.importorskip('pydocstyle')
    result = run_tool('pydocstyle', 'laser_odom', 'setup.py')
    assert result.returncode == 0, result.stdout + result.stderr
