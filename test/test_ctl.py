"""``laser_odom_ctl``: the node's parameters, reset and status without the ``ros2`` CLI (30.3).

One real node runs in a namespace of its own; the tool finds it on the graph by itself,
by ``--namespace`` and by ``--ros-args -r __ns:=...``, as a user of the pip set-up would.
"""

import os

import pytest

pytest.importorskip('rclpy')

from laser_odom.tools.ctl import main  # noqa: E402 - after the rclpy check

from node_harness import NodeProcess, unique_domain_id  # noqa: E402,I100

DOMAIN = unique_domain_id()
NAMESPACE = f'/ctl_{os.getpid()}'
NODE = f'{NAMESPACE}/laser_odom'


@pytest.fixture(scope='module')
def node():
    """Start the node in its namespace and wait until it is ready for scans."""
    process = NodeProcess(DOMAIN, ['-r', f'__ns:={NAMESPACE}', '-p', 'publish_tf:=false'])
    try:
        process.wait_started()
        yield process
    finally:
        process.interrupt()


@pytest.fixture
def ctl(monkeypatch, capsys):
    """Return ``run(*argv) -> (exit code, stdout, stderr)`` of the tool on the node's domain."""
    monkeypatch.setenv('ROS_DOMAIN_ID', str(DOMAIN))

    def run(*argv: str) -> tuple[int, str, str]:
        code = main(list(argv))
        captured = capsys.readouterr()
        # On a busy machine the tool may say that it waits for the node: not an error.
        err = ''.join(line for line in captured.err.splitlines(keepends=True)
                      if not line.startswith('laser_odom_ctl: waiting for'))
        return code, captured.out, err
    return run


def test_parameters_are_listed_read_and_set_as_ros2_param_would(node, ctl):
    code, out, _ = ctl('params')
    listing = dict(line.split(': ', 1) for line in out.splitlines())
    assert code == 0 and listing['matcher'] == "'nicp'" and listing['max_scan_gap'] == '1.0'
    assert listing['nicp.max_iterations'] == '40' and len(listing) > 100
    assert ctl('get', 'matcher') == (0, 'nicp\n', '')
    # An integer for a floating-point parameter and an unquoted word, as ros2 param set.
    assert ctl('set', 'max_scan_gap', '5') == (0, f'{NODE}: max_scan_gap = 5.0\n', '')
    assert ctl('--namespace', NAMESPACE, 'set', 'global_search', 'off') == (
        0, f"{NODE}: global_search = 'off'\n", '')
    assert ctl('get', 'max_scan_gap')[1] == '5.0\n'
    assert ctl('--node-name', NODE, 'get', 'max_scan_gap')[1] == '5.0\n'  # NS/NAME
    assert ctl('--node-name', 'laser_odom', 'get', 'matcher')[1] == 'nicp\n'  # any NS
    assert node.wait_for_output("parameters set: global_search='off'", 10.0)


def test_a_refused_value_or_an_unknown_name_is_one_line_and_exit_2(node, ctl):
    code, out, err = ctl('set', 'min_inlier_ratio', '7')
    assert (code, out) == (2, '')
    assert err == (f'laser_odom_ctl: error: {NODE} refused min_inlier_ratio = 7: '
                   'min_inlier_ratio=7.0 is above the maximum 1.0\n')
    # A crossed pair (issue 39): refused with both names; the node runs on, unchanged.
    assert ctl('set', 'nicp.normal_min_neighbours', '13') == (2, '', (
        f'laser_odom_ctl: error: {NODE} refused nicp.normal_min_neighbours = 13: '
        'nicp.normal_min_neighbours=13 must not exceed nicp.normal_neighbours=12\n'))
    assert ctl('get', 'nicp.normal_min_neighbours') == (0, '3\n', '')
    for command in (('get', 'max_scan_gapp'), ('set', 'max_scan_gapp', '2')):
        code, out, err = ctl(*command)
        assert (code, out) == (2, '') and err == (
            f"laser_odom_ctl: error: {NODE} has no parameter 'max_scan_gapp' (did you mean "
            "'max_scan_gap'?); laser_odom_ctl params lists them\n"), command
    assert "(did you mean 'icp.max_iterations'?)" in ctl('get', 'max_iterations')[2]
    assert ctl('reset', '1', '2')[0] == 2  # a pose needs x, y and yaw


def test_reset_and_set_pose_reach_the_node(node, ctl):
    assert ctl('reset') == (0, f'{NODE}: odometry reset to the origin; the next scan is the '
                               'new reference\n', '')
    assert ctl('reset', '2', '-1', '0.5') == (
        0, f'{NODE}: odometry restarted from x=2 y=-1 yaw=0.5\n', '')
    assert node.wait_for_output('odometry restarted from x=2.000 y=-1.000 yaw=0.500', 10.0)


def test_status_prints_the_nodes_diagnostics(node, ctl):
    code, out, _ = ctl('--ros-args', '-r', f'__ns:={NAMESPACE}', '--', 'status')
    lines = out.splitlines()
    assert code == 0 and lines[0].startswith(f'{NODE[1:]}: odometry: ')
    values = dict(line.strip().split(': ', 1) for line in lines[1:])
    assert values['scans received'] == '0' and values['matcher'] in ('nicp', 'plicp')


def test_a_node_that_is_not_there_is_named_with_the_options(node, ctl):
    code, out, err = ctl('--timeout', '2', '--namespace', '/elsewhere', 'status')
    assert (code, out) == (2, '')
    assert err.startswith('laser_odom_ctl: error: no laser_odom node found (--namespace '
                          f'/elsewhere) on ROS_DOMAIN_ID {DOMAIN} within 2 s; ')
    assert '--namespace NS' in err and '--node-name NAME' in err and err.count('\n') == 1


def test_the_node_help_shows_the_tool_beside_the_ros2_commands():
    from laser_odom.ros.usage import usage
    text = usage()
    for ctl_command, ros2_command in (
            ('laser_odom_ctl set NAME VALUE', 'ros2 param set /laser_odom NAME VALUE'),
            ('laser_odom_ctl reset', 'ros2 service call /laser_odom/reset'),
            ('laser_odom_ctl status', 'ros2 topic echo /diagnostics')):
        line = next(line for line in text.splitlines() if ctl_command in line)
        assert ros2_command in line
