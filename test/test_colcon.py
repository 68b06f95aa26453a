"""``colcon build`` of the package installs tools that run, as on a robot's workspace.

Issue 39: the README's colcon set-up is the way onto a real robot's ROS 2 stack. colcon
(``colcon-common-extensions``, from requirements-dev.txt) builds this checkout into a
temporary build and install base; the package must be identified from package.xml as
an ``ament_python`` ROS package, install its share files where the launch file and
``ros2 launch`` look for them, and register itself in the ament index. Then, with
only the install's ``local_setup.sh`` sourced (the checkout off the Python path),
every console script is found as ``ros2 run`` finds it - the package prefix from the
ament index, then ``lib/laser_odom/`` - and answers ``--help``.
"""

import importlib.util
import os
from pathlib import Path
import re
import shlex
import subprocess
import sys

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = 'laser_odom'
SHARE_FILES = ('package.xml', 'launch/laser_odom.launch.py', 'config/default.yaml',
               'config/nicp.yaml', 'rviz/laser_odom.rviz')


def console_scripts() -> list[str]:
    """Return the console script names of setup.py."""
    return re.findall(r"'(laser_odom_\w+) = [\w.]+:main'", (ROOT / 'setup.py').read_text())


@pytest.fixture(scope='module')
def workspace(tmp_path_factory):
    """Build the checkout with colcon; return the temporary workspace and colcon's output."""
    if importlib.util.find_spec('colcon_core') is None:
        pytest.skip('colcon is not installed in this Python '
                    '(pip install -r requirements-dev.txt installs it)')
    base = tmp_path_factory.mktemp('colcon')
    env = dict(os.environ, COLCON_HOME=str(base / 'colcon_home'))  # no user defaults
    colcon = [sys.executable, '-c', 'import sys; from colcon_core.command import main; '
              'sys.exit(main())', '--log-base', str(base / 'log')]
    listed = subprocess.run(colcon + ['list', '--paths', str(ROOT)], env=env,
                            capture_output=True, text=True, timeout=120)
    build = subprocess.run(
        colcon + ['build', '--paths', str(ROOT), '--build-base', str(base / 'build'),
                  '--install-base', str(base / 'install')],
        env=env, capture_output=True, text=True, timeout=300)
    assert build.returncode == 0, build.stdout + build.stderr
    return base, listed.stdout


def run_installed(install: Path, *commands: str) -> list[subprocess.CompletedProcess]:
    """Run each command in sh with the install sourced and nothing of the checkout around.

    The commands run side by side (each a Python start-up, twice with the wheels'
    library-path re-exec); their results come back in order.
    """
    env = {name: value for name, value in os.environ.items()
           if name not in ('PYTHONPATH', 'AMENT_PREFIX_PATH', 'COLCON_PREFIX_PATH')}
    setup = shlex.quote(str(install / 'local_setup.sh'))
    processes = [subprocess.Popen(['sh', '-c', f'. {setup} && {command}'], env=env,
                                  cwd=install.parent, stdout=subprocess.PIPE,
                                  stderr=subprocess.PIPE, text=True) for command in commands]
    results = []
    for command, process in zip(commands, processes):
        stdout, stderr = process.communicate(timeout=120)
        results.append(subprocess.CompletedProcess(command, process.returncode, stdout, stderr))
    return results


def test_colcon_identifies_an_ament_python_package(workspace):
    _, listed = workspace
    assert listed.split() == [PACKAGE, str(ROOT), '(ros.ament_python)']


def test_the_install_holds_the_share_files_and_the_ament_index_entry(workspace):
    base, _ = workspace
    prefix = base / 'install' / PACKAGE
    for relative in SHARE_FILES:
        installed = prefix / 'share' / PACKAGE / relative
        assert installed.read_bytes() == (ROOT / relative).read_bytes(), relative
    assert (prefix / 'share' / 'ament_index' / 'resource_index' / 'packages'
            / PACKAGE).is_file()
    assert sorted(p.name for p in (prefix / 'lib' / PACKAGE).iterdir()) == sorted(
        console_scripts())


def test_every_installed_tool_answers_help_as_ros2_run_finds_it(workspace):
    base, _ = workspace
    install = base / 'install'
    tools = console_scripts()
    assert 'laser_odom_node' in tools and len(tools) >= 9
    locate = (f'import laser_odom; print(laser_odom.__file__); '
              f'from ament_index_python.packages import get_package_prefix; '
              f'print(get_package_prefix({PACKAGE!r}))')
    [where] = run_installed(install, f'{shlex.quote(sys.executable)} -c {shlex.quote(locate)}')
    assert where.returncode == 0, where.stderr
    module, prefix = where.stdout.split()
    assert Path(module).is_relative_to(install / PACKAGE)  # the installed copy, not ROOT
    assert Path(prefix) == install / PACKAGE
    helps = run_installed(install, *(f'{shlex.quote(prefix)}/lib/{PACKAGE}/{tool} --help'
                                     for tool in tools))
    for tool, found in zip(tools, helps):
        assert found.returncode == 0, (tool, found.stderr[-2000:])
        assert found.stdout.startswith(f'usage: {tool}'), (tool, found.stdout[:200])
        assert found.stderr == '', (tool, found.stderr[-2000:])
