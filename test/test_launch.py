"""The launch file and the RViz configuration, checked against the node they start.

``launch``, ``launch_ros`` (and a package index holding laser_odom) are not available
from the package registries, so ``launch/laser_odom.launch.py`` is loaded against a
minimal stand-in of the API it uses: classes with the real constructors' keyword
arguments that record what they were given. The recorded node action is then turned
into the ``--ros-args`` that ``launch_ros`` would pass, and the real node is started
in-process with them: the launch arguments must reach its name, namespace, parameters
and topics. ``rviz/laser_odom.rviz`` must show what that node publishes.
"""

import importlib.util
import json
from pathlib import Path
import re
import runpy
import shutil
import sys
import types

from node_harness import wait_for
import pytest
from rclpy.time_source import USE_SIM_TIME_NAME
import setuptools
import yaml

from laser_odom.core.configuration.node import NodeConfig, parameter_specs
from laser_odom.ros.lifecycle import LaserOdomLifecycleNode
from laser_odom.ros.node import LaserOdomNode

ROOT = Path(__file__).resolve().parents[1]
LAUNCH_FILE = ROOT / 'launch' / 'laser_odom.launch.py'
RVIZ_FILE = ROOT / 'rviz' / 'laser_odom.rviz'
PACKAGE = 'laser_odom'
ARGUMENTS = {'scan_topic': 'scan', 'odom_topic': 'odom', 'pose_topic': 'pose',
             'wheel_odom_topic': 'wheel_odom', 'publish_tf': '', 'publish_debug': '',
             'reference': '',
             'namespace': '', 'use_sim_time': 'false', 'managed': 'false', 'rviz': 'false'}
"""Launch arguments and their defaults (params_file defaults to the installed file)."""

REMAPPED = {'scan': 'scan_topic', 'odom': 'odom_topic', 'pose': 'pose_topic',
            'wheel_odom': 'wheel_odom_topic'}
"""The node's topic names and the launch arguments remapping them (issue 39)."""


# --- stand-in of the launch / launch_ros / ament_index_python API -------------------

class LaunchDescription:
    """Stands in for launch.LaunchDescription."""

    def __init__(self, initial_entities=None, *, deprecated_reason=None):
        self.entities = list(initial_entities or [])


class DeclareLaunchArgument:
    """Stands in for launch.actions.DeclareLaunchArgument."""

    def __init__(self, name, *, default_value=None, description=None, choices=None,
                 **kwargs):
        self.name, self.default_value = name, default_value
        self.description, self.choices = description, choices


class LaunchConfiguration:
    """Stands in for launch.substitutions.LaunchConfiguration."""

    def __init__(self, variable_name, *, default=None):
        self.variable_name, self.default = variable_name, default

    def perform(self, context):
        return context.launch_configurations[self.variable_name]


class OpaqueFunction:
    """Stands in for launch.actions.OpaqueFunction: ``function(context, *args, **kwargs)``."""

    def __init__(self, *, function, args=None, kwargs=None, **other):
        self.function, self.args, self.kwargs = function, list(args or []), dict(kwargs or {})

    def execute(self, config: dict) -> list:
        """Return the actions the function gives in a context holding ``config``."""
        context = types.SimpleNamespace(launch_configurations=dict(config))
        return list(self.function(context, *self.args, **self.kwargs) or [])


class IfCondition:
    """Stands in for launch.conditions.IfCondition."""

    def __init__(self, predicate_expression):
        self.predicate_expression = predicate_expression


class ParameterValue:
    """Stands in for launch_ros.parameter_descriptions.ParameterValue."""

    def __init__(self, value, *, value_type=None):
        self.value, self.value_type = value, value_type


class Node:
    """Stands in for launch_ros.actions.Node (keywords of Node and ExecuteProcess)."""

    def __init__(self, *, executable, package=None, name=None, namespace=None,
                 exec_name=None, parameters=None, remappings=None, ros_arguments=None,
                 arguments=None, condition=None, output='log', **kwargs):
        self.executable, self.package, self.name = executable, package, name
        self.namespace, self.parameters = namespace, list(parameters or [])
        self.remappings, self.arguments = list(remappings or []), list(arguments or [])
        self.ros_arguments, self.condition, self.output = ros_arguments, condition, output


def stand_in_module(name: str, **attributes) -> types.ModuleType:
    module = types.ModuleType(name)
    module.__dict__.update(attributes)
    return module


@pytest.fixture
def launch_api(monkeypatch, tmp_path):
    """Install the stand-in modules in sys.modules (monkeypatch restores them after).

    The package's data files are installed under ``tmp_path/install`` as setup.py
    says, and the stand-in package index points there.
    """
    prefix = tmp_path / 'install'
    for target, source in installed_files(monkeypatch).items():
        (prefix / target).parent.mkdir(parents=True, exist_ok=True)
        shutil.copy(ROOT / source, prefix / target)
    share_root = prefix / 'share'
    asked = []

    def get_package_share_directory(package_name):
        asked.append(package_name)
        return str(share_root / package_name)

    modules = [
        stand_in_module('launch', LaunchDescription=LaunchDescription),
        stand_in_module('launch.actions', DeclareLaunchArgument=DeclareLaunchArgument,
                        OpaqueFunction=OpaqueFunction),
        stand_in_module('launch.conditions', IfCondition=IfCondition),
        stand_in_module('launch.substitutions', LaunchConfiguration=LaunchConfiguration),
        stand_in_module('launch_ros'),
        stand_in_module('launch_ros.actions', Node=Node),
        stand_in_module('launch_ros.parameter_descriptions', ParameterValue=ParameterValue),
        stand_in_module('ament_index_python'),
        stand_in_module('ament_index_python.packages',
                        get_package_share_directory=get_package_share_directory),
    ]
    for module in modules:
        monkeypatch.setitem(sys.modules, module.__name__, module)
        parent, _, child = module.__name__.rpartition('.')
        if parent:
            setattr(sys.modules[parent], child, module)
    return types.SimpleNamespace(share=share_root / PACKAGE, asked=asked)


def load_launch_description():
    """Import the launch file from its path and call generate_launch_description()."""
    spec = importlib.util.spec_from_file_location('laser_odom_launch', LAUNCH_FILE)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module.generate_launch_description()


# --- what launch_ros would do with the recorded actions -----------------------------

def arguments_of(description) -> dict:
    return {e.name: e for e in description.entities if isinstance(e, DeclareLaunchArgument)}


def launch_configuration(description, **overrides) -> dict:
    """Return the launch configuration: the declared defaults, then ``name:=value``.

    A value outside an argument's ``choices`` is refused, as ``ros2 launch`` does.
    """
    declared = arguments_of(description)
    unknown = set(overrides) - set(declared)
    assert not unknown, f'not declared by the launch file: {unknown}'
    for name, value in overrides.items():
        choices = declared[name].choices
        if choices is not None and value not in choices:
            raise ValueError(f'{name}:={value!r} is not one of {choices}')
    return {name: overrides.get(name, argument.default_value)
            for name, argument in declared.items()}


def substitute(value, config: dict) -> str:
    """Perform the substitutions of ``value`` (a string, a LaunchConfiguration or a list)."""
    if isinstance(value, str):
        return value
    if isinstance(value, LaunchConfiguration):
        return config[value.variable_name]
    if isinstance(value, (list, tuple)):
        return ''.join(substitute(part, config) for part in value)
    raise TypeError(f'unexpected substitution {value!r}')


def parameter_value(value, config: dict):
    """Evaluate a parameter value as launch_ros does (YAML, then the declared type)."""
    if isinstance(value, ParameterValue):
        loaded = yaml.safe_load(substitute(value.value, config))
        if value.value_type is not None:
            assert isinstance(loaded, value.value_type), (loaded, value.value_type)
        return loaded
    if isinstance(value, (bool, int, float)):
        return value
    return yaml.safe_load(substitute(value, config))


def node_parameters(node: Node, config: dict) -> tuple[list[str], dict]:
    """Return the parameter files and the inline parameters the node action passes."""
    files, inline = [], {}
    for entry in node.parameters:
        if isinstance(entry, dict):
            inline.update({name: parameter_value(v, config) for name, v in entry.items()})
        else:
            files.append(substitute(entry, config))
    return files, inline


def ros_arguments(node: Node, config: dict) -> list[str]:
    """Return the ``--ros-args`` launch_ros gives the process of a node action."""
    args = ['--ros-args', '-r', f'__node:={node.name}']
    namespace = substitute(node.namespace or '', config)
    if namespace:
        args += ['-r', f'__ns:={namespace if namespace.startswith("/") else "/" + namespace}']
    files, inline = node_parameters(node, config)
    for path in files:
        args += ['--params-file', path]
    for name, value in inline.items():
        args += ['-p', f'{name}:={json.dumps(value)}']
    for source, target in node.remappings:
        args += ['-r', f'{substitute(source, config)}:={substitute(target, config)}']
    return args


def node_actions(description, config: dict | None = None) -> list[Node]:
    """Return the node actions, those of opaque functions made with ``config``."""
    config = launch_configuration(description) if config is None else config
    actions = []
    for entity in description.entities:
        if isinstance(entity, OpaqueFunction):
            actions += entity.execute(config)
        else:
            actions.append(entity)
    return [e for e in actions if isinstance(e, Node)]


def odometry_node(description, config: dict | None = None) -> Node:
    nodes = [n for n in node_actions(description, config) if n.package == PACKAGE]
    assert len(nodes) == 1, nodes
    return nodes[0]


def setup_arguments(monkeypatch) -> dict:
    """Run setup.py with setuptools.setup replaced; return the keywords it was given."""
    captured = {}
    monkeypatch.setattr(setuptools, 'setup', lambda **kwargs: captured.update(kwargs))
    monkeypatch.chdir(ROOT)
    runpy.run_path(str(ROOT / 'setup.py'), run_name='__main__')
    return captured


def installed_files(monkeypatch) -> dict[str, str]:
    """Map each installed file, relative to the prefix, to its source in the repository."""
    result = {}
    for target, sources in setup_arguments(monkeypatch)['data_files']:
        for source in sources:
            result[f'{target}/{Path(source).name}'] = source
    return result


def console_scripts(monkeypatch) -> dict[str, str]:
    entries = setup_arguments(monkeypatch)['entry_points']['console_scripts']
    return dict(tuple(part.strip() for part in entry.split('=', 1)) for entry in entries)


def flat_parameters(section: dict, prefix: str = '') -> set[str]:
    """Return the dotted names of a ros__parameters mapping (nested = ``a.b``)."""
    names = set()
    for key, value in section.items():
        if isinstance(value, dict):
            names |= flat_parameters(value, f'{prefix}{key}.')
        else:
            names.add(f'{prefix}{key}')
    return names


def declared_node_name() -> str:
    """Return the name LaserOdomNode gives itself (``super().__init__(<name>)``)."""
    source = (ROOT / 'laser_odom' / 'ros' / 'node.py').read_text()
    match = re.search(r"super\(\).__init__\(\s*'([^']+)'", source)
    assert match, 'LaserOdomNode no longer names itself in super().__init__'
    return match.group(1)


# --- the launch file -------------------------------------------------------------------

def test_arguments_are_declared_with_descriptions_and_defaults(launch_api):
    description = load_launch_description()
    declared = arguments_of(description)
    assert set(declared) == set(ARGUMENTS) | {'params_file'}
    for name, argument in declared.items():
        assert isinstance(argument.description, str) and len(argument.description) > 15, name
    defaults = {name: argument.default_value for name, argument in declared.items()}
    assert {name: defaults[name] for name in ARGUMENTS} == ARGUMENTS
    assert launch_api.asked and set(launch_api.asked) == {PACKAGE}
    assert Path(defaults['params_file']) == launch_api.share / 'config' / 'default.yaml'


def test_default_params_file_is_installed_and_read_by_the_node(launch_api, monkeypatch):
    """The default params_file is config/default.yaml as installed, keyed for any node."""
    default = arguments_of(load_launch_description())['params_file'].default_value
    relative = Path(default).relative_to(launch_api.share.parent.parent)
    assert relative == Path('share', PACKAGE, 'config', 'default.yaml')
    installed = installed_files(monkeypatch)
    assert installed[relative.as_posix()] == 'config/default.yaml'
    content = yaml.safe_load((ROOT / 'config' / 'default.yaml').read_text())
    assert set(content) == {'/**'}, 'the default file must apply under any name/namespace'
    names = flat_parameters(content['/**']['ros__parameters'])
    declared = {spec.name for spec in parameter_specs()}
    assert names and names <= declared, names - declared


def test_node_action_starts_laser_odom_node(launch_api, monkeypatch):
    description = load_launch_description()
    node = odometry_node(description)
    assert (node.package, node.executable, node.name) == (
        PACKAGE, 'laser_odom_node', declared_node_name())
    assert console_scripts(monkeypatch)[node.executable] == 'laser_odom.ros.node:main'
    assert node.output == 'screen' and node.condition is None
    assert isinstance(node.namespace, LaunchConfiguration)
    assert node.namespace.variable_name == 'namespace'
    assert {source: target.variable_name for source, target in node.remappings} == REMAPPED
    assert len(node.remappings) == len(REMAPPED)


def test_parameters_reach_the_node_with_their_types(launch_api):
    description = load_launch_description()
    node = odometry_node(description)
    default = launch_configuration(description)
    files, inline = node_parameters(node, default)
    assert files == [default['params_file']]
    assert inline == {'use_sim_time': False}
    config = launch_configuration(description, use_sim_time='true', params_file='/tmp/x.yaml')
    files, inline = node_parameters(odometry_node(description, config), config)
    assert files == ['/tmp/x.yaml'] and inline == {'use_sim_time': True}
    accepted = {spec.name for spec in parameter_specs()} | {USE_SIM_TIME_NAME}
    assert set(inline) <= accepted
    assert ros_arguments(node, launch_configuration(
        description, scan_topic='/base_scan', namespace='robot1')) == [
        '--ros-args', '-r', '__node:=laser_odom', '-r', '__ns:=/robot1',
        '--params-file', default['params_file'], '-p', 'use_sim_time:=false',
        '-r', 'scan:=/base_scan', '-r', 'odom:=odom', '-r', 'pose:=pose',
        '-r', 'wheel_odom:=wheel_odom']


def test_publish_tf_and_reference_override_the_params_file_only_when_given(launch_api):
    """Empty (the default), the parameter file decides; given, they win over it."""
    description = load_launch_description()
    config = launch_configuration(description, publish_tf='false', reference='local_map',
                                  publish_debug='true')
    files, inline = node_parameters(odometry_node(description, config), config)
    assert inline == {'use_sim_time': False, 'publish_tf': False, 'reference': 'local_map',
                      'publish_debug': True}
    assert files == [config['params_file']]  # the overrides come after the file: they win
    config = launch_configuration(description, publish_tf='true', reference='scan')
    _, inline = node_parameters(odometry_node(description, config), config)
    assert inline == {'use_sim_time': False, 'publish_tf': True, 'reference': 'scan'}
    with pytest.raises(ValueError, match='publish_tf'):
        launch_configuration(description, publish_tf='maybe')
    with pytest.raises(ValueError, match='reference'):
        launch_configuration(description, reference='map')
    specs = {spec.name: spec for spec in parameter_specs()}
    declared = arguments_of(description)
    assert set(declared['reference'].choices) == {'', *specs['reference'].info.choices}
    for name in ('publish_tf', 'publish_debug'):
        assert set(declared[name].choices) == {'', 'true', 'false'}
        assert isinstance(specs[name].default, bool)


def test_rviz_is_optional_and_uses_the_shipped_config(launch_api, monkeypatch):
    description = load_launch_description()
    rviz = [n for n in node_actions(description) if n.package == 'rviz2']
    assert len(rviz) == 1
    rviz = rviz[0]
    assert rviz.executable == 'rviz2'
    assert isinstance(rviz.condition, IfCondition)
    assert rviz.condition.predicate_expression.variable_name == 'rviz'
    assert rviz.arguments[0] == '-d'
    config = Path(substitute(rviz.arguments[1], launch_configuration(description)))
    relative = config.relative_to(launch_api.share.parent.parent).as_posix()
    assert installed_files(monkeypatch)[relative] == 'rviz/laser_odom.rviz'
    _, inline = node_parameters(rviz, launch_configuration(description, use_sim_time='true'))
    assert inline == {'use_sim_time': True}


def test_setup_installs_the_launch_and_rviz_files(monkeypatch):
    installed = installed_files(monkeypatch)
    assert installed[f'share/{PACKAGE}/launch/laser_odom.launch.py'] == (
        'launch/laser_odom.launch.py')
    assert installed[f'share/{PACKAGE}/rviz/laser_odom.rviz'] == 'rviz/laser_odom.rviz'
    package_xml = (ROOT / 'package.xml').read_text()
    for dependency in ('launch', 'launch_ros', 'ament_index_python'):
        assert f'<exec_depend>{dependency}</exec_depend>' in package_xml, dependency
    # rviz2 is the rviz:=true option's, not a dependency (test_package_xml): launch_ros
    # looks a node's package up only when the node starts, and the condition keeps it off
    assert '<exec_depend>rviz2</exec_depend>' not in package_xml


def test_the_package_imports_without_launch():
    """Nothing the laser_odom package imports may need launch or launch_ros."""
    for path in (ROOT / 'laser_odom').rglob('*.py'):
        text = path.read_text()
        assert not re.search(r'^\s*(from|import)\s+launch(_ros)?\b', text, re.M), path


def test_real_launch_api_if_available(monkeypatch, tmp_path):
    """With a real ROS install, the file loads against the real API too."""
    launch = pytest.importorskip('launch')
    pytest.importorskip('launch_ros')
    packages = pytest.importorskip('ament_index_python.packages')
    monkeypatch.setattr(packages, 'get_package_share_directory',
                        lambda name: str(tmp_path / 'share' / name))
    description = load_launch_description()
    assert isinstance(description, launch.LaunchDescription)
    declared = {e.name: e.description for e in description.entities
                if isinstance(e, launch.actions.DeclareLaunchArgument)}
    assert set(declared) == set(ARGUMENTS) | {'params_file'}
    assert all(declared.values())


# --- the node started with the launch file's arguments --------------------------------

def graph_topics(node, kind: str) -> set[str]:
    query = getattr(node, f'get_{kind}_names_and_types_by_node')
    return {name for name, _ in query(node.get_name(), node.get_namespace())}


def start_node(context, args: list[str]) -> LaserOdomNode:
    return LaserOdomNode(context=context, cli_args=args, use_global_arguments=False)


def test_node_runs_with_the_launch_arguments(launch_api, context, tmp_path):
    params = tmp_path / 'plicp.yaml'
    params.write_text("/**:\n  ros__parameters:\n    matcher: 'plicp'\n    prior: 'odom'\n"
                      "    publish_tf: true\n    reference: 'scan'\n")
    description = load_launch_description()
    config = launch_configuration(
        description, scan_topic='/base_scan', odom_topic='laser_odom/odom',
        pose_topic='laser_odom/pose', wheel_odom_topic='/diff_drive/odom',
        namespace='robot1', use_sim_time='true', params_file=str(params),
        publish_tf='false', reference='local_map')
    node = start_node(context, ros_arguments(odometry_node(description, config), config))
    try:
        assert node.get_fully_qualified_name() == '/robot1/laser_odom'
        assert node.get_parameter('use_sim_time').value is True
        assert node.get_parameter('matcher').value == 'plicp'
        assert node.get_parameter('prior').value == 'odom'
        assert node.get_parameter('publish_tf').value is False  # over the file's true
        assert node.get_parameter('reference').value == 'local_map'  # over 'scan'
        assert node.pipeline.map_cells() is not None  # the node matches against a map
        assert wait_for(lambda: {'/base_scan', '/diff_drive/odom'}
                        <= graph_topics(node, 'subscriber'), 10.0), graph_topics(
            node, 'subscriber')
        assert wait_for(lambda: {'/robot1/laser_odom/odom', '/robot1/laser_odom/pose'}
                        <= graph_topics(node, 'publisher'), 10.0), graph_topics(
            node, 'publisher')
        assert not {'/robot1/odom', '/robot1/pose'} & graph_topics(node, 'publisher')
    finally:
        node.destroy_node()


def test_managed_starts_the_lifecycle_node_with_the_same_arguments(
        launch_api, context, monkeypatch, tmp_path):
    """``managed:=true``: laser_odom_lifecycle_node, named, remapped and set up alike.

    It starts unconfigured, with the launch file's parameters declared (applied on
    configure); a lifecycle manager drives it by its name, ``laser_odom``.
    """
    description = load_launch_description()
    with pytest.raises(ValueError, match='managed'):
        launch_configuration(description, managed='yes')
    plain = launch_configuration(description, reference='local_map', namespace='robot1')
    config = dict(plain, managed='true')
    node = odometry_node(description, config)
    assert (node.package, node.executable, node.name) == (
        PACKAGE, 'laser_odom_lifecycle_node', declared_node_name())
    assert console_scripts(monkeypatch)[node.executable] == 'laser_odom.ros.lifecycle:main'
    assert ros_arguments(node, config) == ros_arguments(
        odometry_node(description, plain), plain)
    assert odometry_node(description, plain).executable == 'laser_odom_node'
    managed = LaserOdomLifecycleNode(context=context, cli_args=ros_arguments(node, config),
                                     use_global_arguments=False)
    try:
        assert managed.get_fully_qualified_name() == '/robot1/laser_odom'
        assert managed.get_parameter('reference').value == 'local_map'
        assert managed._state_machine.current_state[1] == 'unconfigured'
        assert getattr(managed, 'pipeline', None) is None  # built on configure
    finally:
        managed.destroy_node()


def test_empty_overrides_keep_the_params_file(launch_api, context, tmp_path):
    """publish_tf and reference left empty: the node runs with the file's values."""
    params = tmp_path / 'map.yaml'
    params.write_text('/**:\n  ros__parameters:\n    publish_tf: false\n'
                      '    reference: local_map\n')
    description = load_launch_description()
    config = launch_configuration(description, params_file=str(params))
    node = start_node(context, ros_arguments(odometry_node(description, config), config))
    try:
        assert node.get_parameter('publish_tf').value is False
        assert node.get_parameter('reference').value == 'local_map'
        assert node.get_parameter('publish_debug').value is False  # the node's default
    finally:
        node.destroy_node()


# --- the RViz configuration --------------------------------------------------------------

DISPLAYS = {'Grid': 'Grid', 'TF': 'TF', 'LaserScan': 'LaserScan', 'Odometry': 'Odometry',
            'Pose': 'Pose', 'MatchedScan': 'PointCloud2', 'LocalMap': 'PointCloud2'}
"""The displays of the shipped RViz file by name, with their class."""


def rviz_displays() -> dict[str, dict]:
    """Return the displays by name (two PointCloud2 displays: matched scan, local map)."""
    config = yaml.safe_load(RVIZ_FILE.read_text())
    displays = config['Visualization Manager']['Displays']
    by_name = {}
    for display in displays:
        assert display['Name'] not in by_name, f'two displays named {display["Name"]}'
        by_name[display['Name']] = display
    return by_name


def test_rviz_file_is_an_rviz2_config():
    config = yaml.safe_load(RVIZ_FILE.read_text())
    assert {'Panels', 'Visualization Manager', 'Window Geometry'} <= set(config)
    manager = config['Visualization Manager']
    assert manager['Global Options']['Fixed Frame'] == NodeConfig().odom_frame
    assert manager['Views']['Current']['Class'] == 'rviz_default_plugins/TopDownOrtho'
    classes = [p['Class'] for p in config['Panels']]
    classes += [d['Class'] for d in manager['Displays']] + [t['Class'] for t in manager['Tools']]
    assert 'rviz_common/Displays' in classes
    assert all(re.fullmatch(r'rviz_(common|default_plugins)/\w[\w ]*', c) for c in classes)
    displays = rviz_displays()
    assert {name: d['Class'].split('/', 1)[1] for name, d in displays.items()} == DISPLAYS
    assert all(d['Enabled'] is True for d in displays.values())


def test_rviz_displays_match_the_node(launch_api, context):
    """Topics are those of the node started with the launch defaults; QoS compatible."""
    displays = rviz_displays()
    topic = {name: d['Topic']['Value'] for name, d in displays.items() if 'Topic' in d}
    assert displays['LaserScan']['Topic']['Reliability Policy'] == 'Best Effort'
    assert displays['MatchedScan']['Topic']['Reliability Policy'] == 'Best Effort'
    # The map is sent at most once a second and kept for late subscribers: RViz asks for
    # it as the node offers it (a volatile subscriber would miss the last one).
    local_map = displays['LocalMap']
    assert local_map['Topic']['Durability Policy'] == 'Transient Local'
    assert local_map['Topic']['Reliability Policy'] == 'Reliable'
    assert local_map['Color Transformer'] == 'Intensity'  # the cells' weights
    covariance = displays['Odometry']['Covariance']
    assert covariance['Value'] is True and covariance['Position']['Value'] is True

    description = load_launch_description()
    # The matched scan and the map, as node.md starts RViz.
    config = launch_configuration(description, reference='local_map', publish_debug='true')
    args = ros_arguments(odometry_node(description, config), config)
    published = {topic[name] for name in ('Odometry', 'Pose', 'MatchedScan', 'LocalMap')}
    node = start_node(context, args)
    try:
        assert wait_for(lambda: topic['LaserScan'] in graph_topics(node, 'subscriber'), 10.0)
        assert wait_for(lambda: published <= graph_topics(node, 'publisher'), 10.0), (
            published - graph_topics(node, 'publisher'))
        assert topic['MatchedScan'] == node.resolve_topic_name('~/matched_scan')
        assert topic['LocalMap'] == node.resolve_topic_name('~/local_map')
    finally:
        node.destroy_node()
    assert topic == {'LaserScan': '/scan', 'Odometry': '/odom', 'Pose': '/pose',
                     'MatchedScan': '/laser_odom/matched_scan',
                     'LocalMap': '/laser_odom/local_map'}
