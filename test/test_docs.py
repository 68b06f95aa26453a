"""The README guides, the docs pages stay in step with the code, and every figure is generated.

Issue 39 (after 30.12): the README is a guide under 200 lines - what it does, the two
set-up commands, how to run it on a robot (with robot_localization), which options
when, then the user journeys and where to read more - in words a newcomer knows: no
benchmark figures and none of the internals' names. Every command it shows exists
(tools, their options, make targets, launch arguments, parameters), and the defaults
it names are the node's. Long reference material lives in ``docs/``, where ``make
docs`` keeps the parameter table and the figure blocks generated; every generated block
is checked here wherever it sits. Issue 30.7: the real logs' origin, terms, layout and
a command per log are documented.
"""

import contextlib
import io
from pathlib import Path
import re
import shlex
import subprocess
import sys

import pytest

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / 'README.md'
DOCS = ROOT / 'docs'
BEGIN, END = '<!-- parameters:begin -->', '<!-- parameters:end -->'

JOURNEYS = ('Set up: two commands', 'On your robot', 'Which options when', 'Replaying a bag',
            'Tuning on your bags', 'Benchmark', 'Real robot logs', 'Where to read more',
            'License')
"""The README's sections, in the order a newcomer needs them (others may sit between)."""

JARGON = ('map_fallback', 'map_disputed', 'map_restarted', 'map_surprised', 'NEES', 'ATE',
          'RPE', 'CSM', 'virtual scan', 'ray-cast', 'silent', 'information-weighted',
          'hash of', 'de-skew', 'degenerate', 'global search', 'OdometryPipeline',
          'laser_odom/core', 'registration/', 'se2.py')
"""Names of the internals and the benchmark the README used and a newcomer does not know:
they live in docs/ (node.md, benchmark.md, development.md), the README says it in words."""


def _sections(text: str) -> list[str]:
    return [line[3:].strip() for line in text.splitlines() if line.startswith('## ')]


def _shell_commands(text: str) -> list[list[str]]:
    """Return every command of the ``sh`` blocks, split into words (comments dropped)."""
    commands = []
    for block in re.findall(r'```sh\n(.*?)```', text, re.S):
        for line in block.replace('\\\n', ' ').splitlines():
            line = line.split(' #', 1)[0].strip()
            for part in re.split(r'\s*(?:&&|;|\|\||\||&)\s*', line):
                words = shlex.split(part) if part.strip() else []
                if words:
                    commands.append(words)
    return commands


def _entry_points() -> dict[str, str]:
    """Return console script -> module of setup.py."""
    setup = (ROOT / 'setup.py').read_text()
    return dict(re.findall(r"'(laser_odom_\w+) = ([\w.]+):main'", setup))


def _help(tool: str, module: str) -> str:
    """Return a tool's --help text (the node's usage for the node)."""
    import importlib
    if tool in ('laser_odom_node', 'laser_odom_lifecycle_node'):  # the same ROS arguments
        from laser_odom.ros.usage import usage
        return usage() + ' --ros-args --params-file -r -p'
    out = io.StringIO()
    with contextlib.redirect_stdout(out), pytest.raises(SystemExit):
        importlib.import_module(module).main(['--help'])
    return out.getvalue()


def _check_tool(words: list[str], tools: dict[str, str], helps: dict[str, str]) -> list[str]:
    """Return what is wrong with one tool invocation: the tool, its options, its files."""
    tool, args = words[0], words[1:]
    if tool not in tools:
        return [f'{tool}: no such tool in setup.py']
    if tool not in helps:
        helps[tool] = _help(tool, tools[tool])
    problems = [f'{tool} {arg}: no such option' for arg in args
                if arg.startswith('--') and arg != '--' and arg not in helps[tool]]
    for arg, value in zip(args, args[1:]):
        if arg == '--params-file' and value.startswith('config/'):
            if not (ROOT / value).is_file():
                problems.append(f'{tool} --params-file {value}: no such file')
    if tool == 'laser_odom_ctl':
        commands = [a for a in args if not a.startswith('-') and a in helps[tool]]
        if not commands:
            problems.append(f'{" ".join(words)}: no command of laser_odom_ctl')
    return problems


def _check_command(words: list[str], tools: dict[str, str], helps: dict[str, str],
                   targets: set[str], parameters: set[str]) -> list[str]:
    """Return what is wrong with one documented command (nothing for foreign ones)."""
    launch = (ROOT / 'launch' / 'laser_odom.launch.py').read_text()
    if words[0].startswith('laser_odom_'):
        return _check_tool(words, tools, helps)
    if words[0] == 'make':
        return [f'make {w}: no such target' for w in words[1:] if '=' not in w
                and w not in targets]
    if words[:3] == ['ros2', 'run', 'laser_odom']:
        return _check_tool(words[3:], tools, helps)
    if words[:3] == ['ros2', 'launch', 'laser_odom']:
        problems = [] if (ROOT / 'launch' / words[3]).is_file() else [f'no {words[3]}']
        return problems + [f'launch argument {w}' for w in words[4:] if ':=' in w
                           and f"'{w.split(':=')[0]}'" not in launch]
    if words[:3] == ['ros2', 'param', 'set']:
        return [] if words[4] in parameters else [f'ros2 param set: no parameter {words[4]}']
    if words[:3] == ['ros2', 'service', 'call']:
        return [] if words[3] == '/laser_odom/reset' else [f'no service {words[3]}']
    return []


def _section(text: str, title: str) -> str:
    return text.split(f'\n## {title}\n', 1)[1].split('\n## ', 1)[0]


def test_readme_is_a_guide_under_200_lines_in_the_order_a_newcomer_needs():
    text = README.read_text()
    assert len(text.splitlines()) < 200
    sections = _sections(text)
    assert [s for s in sections if s in JOURNEYS] == list(JOURNEYS), sections
    first = text.split('\n## ', 1)[0]
    assert 'laser odometry' in first.lower() and len(first.splitlines()) < 15
    setup = _section(text, 'Set up: two commands')
    assert _shell_commands(setup) == [['make', 'demo'], ['make', 'test']]
    robot = _section(text, 'On your robot')
    lines = [' '.join(words) for words in _shell_commands(robot)]
    for command in ('rosdep install --from-paths src', 'colcon build',
                    'ros2 run laser_odom laser_odom_warmup', 'ros2 launch laser_odom'):
        assert any(command in line for line in lines), command
    assert '(docs/robot_localization.md)' in robot
    # issue 39: where a user looks for them - the managed node, sim time, every launch argument
    for words in ('`laser_odom_lifecycle_node`', '`managed:=true`', '`use_sim_time:=true`',
                  '--live --clock', '(docs/node.md#managed-node-lifecycle)',
                  '(docs/node.md#sim-time)', '(docs/node.md#launch-file-and-rviz)'):
        assert words in robot, words
    launch = (ROOT / 'launch' / 'laser_odom.launch.py').read_text()
    arguments = re.findall(r"DeclareLaunchArgument\(\s*'(\w+)'", launch)
    assert len(arguments) >= 12 and [a for a in arguments if f'`{a}`' not in robot] == []
    for journey in ('On your robot', 'Replaying a bag', 'Tuning on your bags', 'Benchmark'):
        body = text.split(f'## {journey}', 1)[1].split('\n## ', 1)[0]
        assert 'pip set-up' in body and 'colcon set-up' in body, journey
        commands = _shell_commands(body)
        assert any(w[0].startswith('laser_odom_') for w in commands), journey
        assert any(w[:2] == ['ros2', 'run'] or w[:2] == ['ros2', 'launch']
                   for w in commands), journey


def test_readme_speaks_plainly_and_leaves_the_figures_to_docs():
    """No benchmark figures, no internal names: those are in docs/benchmark.md and node.md."""
    from laser_odom.tools.figures import blocks_in
    text = README.read_text()
    named = [word for word in JARGON
             if re.search(rf'(?<![\w-]){re.escape(word)}(?![\w-])', text)]
    assert named == []
    assert blocks_in(text) == [] and 'figures:' not in text
    assert not re.search(r'^\|.*\d\.\d.*\|$', text, re.M), 'a table of figures'
    assert '(docs/benchmark.md)' in _section(text, 'Benchmark')


def test_the_options_the_readme_advises_on_are_the_nodes_with_their_defaults():
    """The section "Which options when" names each choice and the node's real default."""
    from laser_odom.core.configuration.node import parameter_specs
    specs = {spec.name: spec for spec in parameter_specs()}
    options = _section(README.read_text(), 'Which options when')
    for name, choices in (('matcher', ('icp', 'plicp', 'nicp', 'imls')),
                          ('reference', ('scan', 'local_map')),
                          ('prior', ('none', 'constant_velocity', 'odom', 'imu'))):
        paragraph = options.split(f'**`{name}`**', 1)[1].split('\n\n', 1)[0]
        assert f'The default, `{specs[name].default}`' in paragraph or (
            f'Keep the default, `{specs[name].default}`' in paragraph), name
        assert all(f'`{choice}`' in paragraph for choice in choices), name
    keyframes = options.split('**Keyframes**', 1)[1].split('\n\n', 1)[0]
    assert 'off by default' in keyframes
    for name in ('keyframe_distance', 'keyframe_angle'):
        assert f'`{name}`' in keyframes and specs[name].default == 0.0, name
    for matcher in ('icp', 'plicp', 'nicp', 'imls'):
        assert (ROOT / 'config' / f'{matcher}.yaml').is_file()


def test_every_command_the_readme_and_the_docs_show_exists():
    """Tools, their options and commands, make targets, launch arguments, parameters."""
    from laser_odom.core.configuration.node import parameter_specs
    tools = _entry_points()
    targets = set(re.findall(r'^([\w-]+):', (ROOT / 'Makefile').read_text(), re.M))
    parameters = {spec.name for spec in parameter_specs()}
    helps: dict[str, str] = {}
    problems = []
    for page in [README, *sorted(DOCS.glob('*.md'))]:
        for words in _shell_commands(page.read_text()):
            problems += [f'{page.name}: {p}' for p in _check_command(
                words, tools, helps, targets, parameters)]
    assert problems == []
    assert {'laser_odom_node', 'laser_odom_replay', 'laser_odom_ctl', 'laser_odom_tune',
            'laser_odom_bench', 'laser_odom_convert', 'laser_odom_simulate'} <= set(helps)


def test_the_checker_catches_what_does_not_exist():
    tools, helps = _entry_points(), {}
    for command, problem in (
            ('laser_odom_replay BAG --no-such-flag', '--no-such-flag: no such option'),
            ('laser_odom_sift BAG', 'no such tool'),
            ('make deploy', 'make deploy: no such target'),
            ('ros2 param set /laser_odom max_scan_gapp 5', 'no parameter max_scan_gapp'),
            ('laser_odom_node --ros-args --params-file config/sift.yaml', 'no such file')):
        found = _check_command(shlex.split(command), tools, helps, {'demo', 'test'},
                               {'max_scan_gap'})
        assert len(found) == 1 and problem in found[0], (command, found)


def test_every_link_between_the_pages_resolves():
    pages = [README, *sorted(DOCS.glob('*.md'))]
    for page in pages:
        for target, anchor in re.findall(r'\]\(((?:\.\./|docs/)?[\w./-]*\.md)(?:#([\w-]+))?\)',
                                         page.read_text()):
            path = (page.parent / target).resolve()
            assert path.is_file(), f'{page.name} links to missing {target}'
            if anchor:
                headings = {re.sub(r'[^\w\- ]', '', h.strip().lower()).replace(' ', '-')
                            for h in re.findall(r'^#+ (.*)$', path.read_text(), re.M)}
                assert anchor in headings, f'{page.name} links to missing {target}#{anchor}'
    linked = set(re.findall(r'\(docs/([\w-]+\.md)', README.read_text()))
    assert linked == {p.name for p in DOCS.glob('*.md')}  # every page reachable from it


def test_parameter_table_is_current():
    pytest.importorskip('rclpy')
    from laser_odom.ros.default_params import markdown_table
    page = (DOCS / 'parameters.md').read_text()
    table = page.split(BEGIN, 1)[1].split(END, 1)[0].strip()
    assert table == markdown_table().strip(), (
        'docs/parameters.md parameter table is stale: run `make docs`')


def test_readme_names_every_executable():
    text = README.read_text() + (DOCS / 'tools.md').read_text()
    for name in _entry_points():
        assert name in text, name


def test_documented_figures_come_from_the_committed_benchmark_result():
    """Every figure block, wherever it moved, renders to itself from the JSON, once.

    Both results must be committed (``make figures``): the real logs' and the
    fast-robot logs' (the ``fast`` block). The copies the text says the medians are of
    are the copies of the result. The renderers themselves: test_figures.py.
    """
    from laser_odom.tools.figures import (
        BLOCKS, blocks_in, DOCUMENTS, FAST_JSON, load_figures, MATCHERS, rendered_config,
        rendered_text)
    payload = load_figures(fast=FAST_JSON)
    for result in (payload, payload['fast']):
        assert result['date'] and {'numpy', 'scipy', 'python'} <= set(result['versions'])
    placed = []
    for relative in DOCUMENTS:
        text = (ROOT / relative).read_text()
        placed += blocks_in(text)
        assert rendered_text(text, payload, relative) == text, (
            f'{relative} figures differ from test/figures/*.json: run `make docs`')
    assert sorted(placed) == sorted(BLOCKS)  # each block in exactly one document
    benchmark = (DOCS / 'benchmark.md').read_text()
    assert {'table', 'map', 'speed', 'fast'} <= set(blocks_in(benchmark))  # the evidence
    if 'spread' in payload:  # the copies said around the table and the map block
        said = re.findall(r'(\d+) copies', benchmark.split('### A fast robot', 1)[0])
        assert said and {int(n) for n in said} == {e['copies'] for e in payload['spread']}
    for matcher in MATCHERS:
        path = ROOT / 'config' / f'{matcher}.yaml'
        text = path.read_text()
        assert rendered_config(text, payload, matcher) == text, (
            f'{path.name} figures differ from test/figures/benchmark.json: run `make docs`')


def test_the_demo_and_the_install_print_a_line_per_step_not_their_recipes():
    """Issue 30.13: make echoed the demo's multi-line recipe and a setuptools notice."""
    makefile = (ROOT / 'Makefile').read_text()
    for target in ('$(STAMP)', 'demo'):
        recipe = makefile.split(f'\n{target}:', 1)[1].split('\n\n', 1)[0].splitlines()[1:]
        commands = [line for before, line in zip([''] + recipe, recipe)
                    if line.startswith('\t') and not before.endswith('\\')]
        assert commands and all(line.startswith(('\t$(Q)', '\t@echo ')) for line in commands)
    assert 'Q := $(if $(filter 1,$(V)),,@)' in makefile
    assert 'PIP := $(BIN)/python -m pip install $(if $(filter 1,$(V)),,-qq)' in makefile
    assert '$(Q)$(PIP) --no-deps --no-build-isolation -e .' in makefile


def test_the_real_logs_are_documented_with_origin_terms_layout_and_a_command_each():
    """Issue 30.7: where fr079, MIT CSAIL and Intel come from and how to use them."""
    from laser_odom.core.datasets import KNOWN_DATASETS
    page = (DOCS / 'datasets.md').read_text()
    for section in ('The logs and their origin', 'Layout', 'One command per log'):
        assert f'## {section}' in page
    for words in ('ais.informatik.uni-freiburg.de/slamevaluation', 'radish.sourceforge.net',
                  'Kümmerle', 'BSD', 'license'):
        assert words in page, words
    converted = {w[1] for w in _shell_commands(page) if w[0] == 'laser_odom_convert'}
    for name, relative in KNOWN_DATASETS.items():
        assert f'`{relative}`' in page or relative in page, name
        assert f'../shared/data/{relative}' in converted, name
    assert '../shared/data/ccny-demo/demo.bag' in page
    assert '(docs/datasets.md)' in README.read_text()


def test_the_documented_conversion_of_a_keyframe_log_works(shared_data_dir, tmp_path):
    """The MIT CSAIL command of docs/datasets.md gives a bag with its keyframe reference."""
    from laser_odom.io.bag_reader import BagReader
    from laser_odom.io.tum import read_tum
    from laser_odom.tools.convert import main
    command = next(w for w in _shell_commands((DOCS / 'datasets.md').read_text())
                   if w[0] == 'laser_odom_convert' and 'mit-csail' in w[1])
    source = shared_data_dir / command[1][len('../shared/data/'):]
    out = tmp_path / Path(command[2]).name
    assert main([str(source), str(out)]) == 0
    with BagReader(out) as bag:
        assert bag.message_count('/scan') == 1988 and bag.message_count('/ground_truth') == 686
    assert len(read_tum(Path(str(out) + '.tum'))) == 686


def test_the_examples_make_the_folder_they_write_into():
    """The tools never create folders: a page's first example writing to out/ makes it."""
    for page in [README, *sorted(DOCS.glob('*.md'))]:
        commands = _shell_commands(page.read_text())
        first = next((i for i, words in enumerate(commands)
                      if any(w.startswith('out/') for w in words)), None)
        if first is not None:
            assert ['mkdir', '-p', 'out'] in commands[:first], page.name


def test_make_test_says_why_each_test_was_skipped(tmp_path):
    """Issue 39: ``make test`` skipped 57 tests without a word on why."""
    makefile = (ROOT / 'Makefile').read_text()
    recipe = makefile.split('\ntest: $(STAMP)\n', 1)[1].splitlines()[0]
    flags = recipe.split('-m pytest', 1)[1].split()[:-1]  # without the test folder
    flags = [f for i, f in enumerate(flags) if f not in ('-n', '--dist') and (
        i == 0 or flags[i - 1] not in ('-n', '--dist'))]  # one process is enough here
    (tmp_path / 'test_skipping.py').write_text(
        'import pytest\n\n\ndef test_real_logs():\n'
        "    pytest.skip('real robot logs not available (../shared/data does not exist)')\n")
    result = subprocess.run([sys.executable, '-m', 'pytest', '-p', 'no:cacheprovider', *flags,
                             'test_skipping.py'], cwd=tmp_path, capture_output=True, text=True)
    assert result.returncode == 0, result.stdout
    assert ('SKIPPED [1] test_skipping.py:5: real robot logs not available '
            '(../shared/data does not exist)') in result.stdout


def test_the_help_texts_and_the_package_mention_the_local_map():
    """Issue 39: they described the package as scan-to-scan only."""
    from laser_odom.ros.usage import usage
    from laser_odom.tools import bench, replay, tune
    texts = {'laser_odom_node': usage(),
             'laser_odom_replay': replay.build_parser().format_help(),
             'laser_odom_tune': tune.build_parser().format_help(),
             'package.xml': (ROOT / 'package.xml').read_text()}
    with contextlib.redirect_stdout(io.StringIO()) as bench_help, pytest.raises(SystemExit):
        bench.parse_args(['--help'])
    texts['laser_odom_bench'] = bench_help.getvalue()
    for name, text in texts.items():
        flat = ' '.join(text.split())
        assert 'local map of the recent scans' in flat, name
        assert 'local_map' in flat, name
