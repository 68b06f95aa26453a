"""The package's layers import downwards only, and no module imports itself back.

Issue 31: the tree shows the architecture. :data:`LAYERS` ranks the packages bottom up;
a module imports from its own package (a direct child of ``laser_odom.core``, or
``io``, ``ros``, ``tools``) and from lower layers only - never from a package beside it
in its layer, nor from above - and no module reaches itself again through its imports
(a cycle). Read from the source (deferred imports inside functions and imports under
``TYPE_CHECKING`` count too). docs/development.md shows the same layers (*Layers*).

The core is ROS-free (numpy/scipy: importable and testable without rclpy), and the
matchers and the search sit below the configuration and the pipeline: a matcher that
imports them makes an import cycle through the configuration, which imports the matcher
registry.
"""

import ast
from pathlib import Path
import re

import pytest

ROOT = Path(__file__).resolve().parent.parent
PACKAGE = ROOT / 'laser_odom'

LAYERS = (
    ('core.se2', 'core.events', 'core.parameters'),
    ('core.scan', 'core.uncertainty'),
    ('core.trajectory', 'core.search', 'core.matchers'),
    ('core.configuration', 'core.datasets', 'core.simulation'),
    ('core.motion', 'core.preprocess'),
    ('core.registration',),
    ('core.pipeline',),
    ('core.evaluation',),
    ('core.tuning',),
    ('io',),
    ('ros',),
    ('tools',),
)
"""The packages (and plain modules) of ``laser_odom``, bottom up, one tuple per layer."""

ROOTS = ('laser_odom', 'laser_odom.core')
"""Package roots below every layer: their ``__init__`` imports nothing of the package."""

ABOVE_THE_MATCHERS = ('configuration', 'motion', 'preprocess', 'registration', 'pipeline',
                      'evaluation', 'tuning')
"""Packages of ``laser_odom.core`` that assemble the matchers into the odometry."""

MATCHERS = ('icp', 'plicp', 'nicp', 'imls')


def imported_modules(path: Path) -> set[str]:
    """Return every module a source file imports, at any depth of its code."""
    names = set()
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            names.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom) and node.module:
            names.add(node.module)
    return names


def sources(*parts: str) -> list[Path]:
    """Return the Python files under ``laser_odom/<parts>``."""
    return sorted(PACKAGE.joinpath(*parts).rglob('*.py'))


def module_names(package: Path) -> dict[str, Path]:
    """Return dotted module name -> file, for every module of a package folder."""
    names = {}
    for path in sorted(package.rglob('*.py')):
        parts = path.relative_to(package.parent).with_suffix('').parts
        names['.'.join(parts[:-1] if parts[-1] == '__init__' else parts)] = path
    return names


def import_graph(package: Path) -> dict[str, set[str]]:
    """Return module -> the package's modules it imports (``from p import m`` counts p and m).

    A module's own parent packages are left out: Python imports them before it.
    """
    modules = module_names(package)

    def known(name: str) -> str | None:
        while name and name not in modules:
            name = name.rpartition('.')[0]
        return name or None

    graph = {}
    for name, path in modules.items():
        here = name if path.name == '__init__.py' else name.rpartition('.')[0]
        targets = set()
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            if isinstance(node, ast.Import):
                targets |= {known(alias.name) for alias in node.names}
            elif isinstance(node, ast.ImportFrom):
                base = node.module or ''
                if node.level:
                    base = '.'.join(filter(None, [here.rsplit('.', node.level - 1)[0], base]))
                targets.add(known(base))
                targets |= {f'{base}.{alias.name}' for alias in node.names
                            if f'{base}.{alias.name}' in modules}
        ancestors = {name.rsplit('.', i)[0] for i in range(1, name.count('.') + 1)}
        graph[name] = {t for t in targets if t and t != name and t not in ancestors}
    return graph


def find_cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """Return the import cycles: every strongly connected set of two or more modules."""
    index, low, stack, on_stack, cycles = {}, {}, [], set(), []

    def visit(node: str) -> None:  # Tarjan's algorithm
        index[node] = low[node] = len(index)
        stack.append(node)
        on_stack.add(node)
        for target in sorted(graph.get(node, ())):
            if target not in index:
                visit(target)
                low[node] = min(low[node], low[target])
            elif target in on_stack:
                low[node] = min(low[node], index[target])
        if low[node] == index[node]:
            component = []
            while True:
                member = stack.pop()
                on_stack.discard(member)
                component.append(member)
                if member == node:
                    break
            if len(component) > 1:
                cycles.append(sorted(component))

    for node in sorted(graph):
        if node not in index:
            visit(node)
    return sorted(cycles)


def unit_of(module: str) -> str | None:
    """Return the entry of :data:`LAYERS` a module belongs to (None: it has none)."""
    name = module.removeprefix('laser_odom.')
    for layer in LAYERS:
        for unit in layer:
            if name == unit or name.startswith(unit + '.'):
                return unit
    return None


def rank(unit: str) -> int:
    return next(i for i, layer in enumerate(LAYERS) if unit in layer)


def wrong_way(graph: dict[str, set[str]]) -> list[str]:
    """Return every import of a package beside the importer in its layer or above it."""
    found = []
    for module, targets in sorted(graph.items()):
        unit = unit_of(module)
        for target in sorted(targets):
            other = unit_of(target)
            if module in ROOTS or (target not in ROOTS and other != unit and (
                    None in (unit, other) or rank(other) >= rank(unit))):
                found.append(f'{module} -> {target}')
    return found


def write_package(root: Path, files: dict[str, str]) -> Path:
    for name, text in files.items():
        (root / name).parent.mkdir(parents=True, exist_ok=True)
        (root / name).write_text(text)
    return root / next(iter(files)).split('/')[0]


def test_the_helper_sees_imports_inside_functions(tmp_path):
    source = tmp_path / 'm.py'
    source.write_text('import a\n\ndef f():\n    from b.c import d\n    import e.f\n')
    assert imported_modules(source) == {'a', 'b.c', 'e.f'}


def test_the_cycle_finder_sees_deferred_typing_and_submodule_imports(tmp_path):
    """Issue 31's two cycles in small: replay <-> replay_live, acceptance <-> registration."""
    package = write_package(tmp_path, {
        'pkg/__init__.py': '',
        'pkg/replay.py': 'def main():\n    from pkg.replay_live import run_live\n',
        'pkg/replay_live.py': 'from pkg.replay import PriorFeed\n',
        'pkg/acceptance.py': ('from typing import TYPE_CHECKING\n'
                              'if TYPE_CHECKING:\n    from pkg import registration\n'),
        'pkg/registration.py': 'from .acceptance import rejection_reason\n',
        'pkg/fine.py': 'import pkg.replay\nfrom pkg import acceptance\n',
    })
    graph = import_graph(package)
    assert graph['pkg.fine'] == {'pkg.replay', 'pkg.acceptance'}
    assert find_cycles(graph) == [['pkg.acceptance', 'pkg.registration'],
                                  ['pkg.replay', 'pkg.replay_live']]


def test_no_module_imports_itself_back():
    assert find_cycles(import_graph(PACKAGE)) == []


def test_every_module_has_a_layer():
    assert [m for m in module_names(PACKAGE) if m not in ROOTS and unit_of(m) is None] == []


def test_imports_point_down_the_layers():
    assert wrong_way(import_graph(PACKAGE)) == []


def test_the_layer_check_catches_an_upward_and_a_sideways_import():
    core = 'laser_odom.core'
    graph = {f'{core}.scan.nearest': {f'{core}.se2'},
             f'{core}.matchers.base': {f'{core}.pipeline.odometry', f'{core}.search.grid',
                                       f'{core}.matchers.robust', core},
             core: {f'{core}.se2'}}
    assert wrong_way(graph) == [f'{core} -> {core}.se2',
                                f'{core}.matchers.base -> {core}.pipeline.odometry',
                                f'{core}.matchers.base -> {core}.search.grid']


def test_core_has_at_most_eight_modules_beside_its_packages():
    plain = sorted(p.name for p in (PACKAGE / 'core').glob('*.py'))
    assert len(plain) <= 8, plain


def test_every_package_says_what_it_holds_and_what_it_may_import():
    for path in sorted(PACKAGE.rglob('__init__.py')):
        doc = ast.get_docstring(ast.parse(path.read_text())) or ''
        assert doc and 'May import' in doc, path.relative_to(ROOT)


def test_the_development_page_shows_the_layers():
    """docs/development.md's diagram of ``core/``: a row per layer, top down, as in LAYERS."""
    page = (ROOT / 'docs' / 'development.md').read_text()
    section = page.split('\n### Layers\n', 1)[1].split('\n## ', 1)[0]
    block = next(b for b in re.findall(r'```\n(.*?)```', section, re.S) if 'se2.py' in b)
    rows = [sorted('core.' + re.sub(r'(/|\.py)$', '', word) for word in line.split()
                   if re.fullmatch(r'\w+(/|\.py)', word)) for line in block.splitlines()]
    core = [sorted(unit for unit in layer if unit.startswith('core.')) for layer in LAYERS]
    assert rows[::-1] == [layer for layer in core if layer]
    for package in sorted(p.name for p in (PACKAGE / 'core').iterdir()
                          if (p / '__init__.py').is_file()):
        assert f'{package}/' in section, package


def test_the_module_paths_the_docs_name_exist():
    """Every ``laser_odom/...py`` path and ``laser_odom.x.y`` name in the docs exists."""
    modules = module_names(PACKAGE)
    pages = [ROOT / 'README.md', *sorted((ROOT / 'docs').glob('*.md')),
             *sorted((ROOT / 'config').glob('*.yaml')), *sorted((ROOT / '.ci').glob('*.py')),
             *sorted((ROOT / '.ci').glob('*.md')), *sources()]
    missing = []
    for page in pages:
        text = page.read_text()
        for path in re.findall(r'(?<![\w/])laser_odom/[\w/]+\.py', text):
            if not (ROOT / path).is_file():
                missing.append(f'{page.name}: {path}')
        for name in re.findall(r'(?<![\w./-])laser_odom(?:\.\w+)+', text):
            if name.endswith(('.py', '.rviz')):  # laser_odom.launch.py, not a module
                continue
            module = name
            while module not in modules:
                module = module.rpartition('.')[0]
            rest = name[len(module) + 1:].split('.')[0] if name != module else ''
            tree = ast.parse(modules[module].read_text())
            defined = {getattr(n, 'name', None) for n in tree.body} | {
                getattr(t, 'id', None) for n in tree.body if isinstance(n, ast.Assign)
                for t in n.targets} | {a.asname or a.name for n in tree.body if isinstance(
                    n, (ast.Import, ast.ImportFrom)) for a in n.names}
            if rest and rest not in defined:
                missing.append(f'{page.name}: {name}')
    assert missing == []


@pytest.mark.parametrize('path', sources('core'), ids=lambda p: str(p.relative_to(PACKAGE)))
def test_core_is_ros_free(path):
    banned = [name for name in imported_modules(path)
              if name.split('.')[0] in ('rclpy', 'rosbags') or name.startswith(
                  ('laser_odom.ros', 'laser_odom.io', 'laser_odom.tools'))]
    assert not banned, f'{path} imports {banned}'


@pytest.mark.parametrize('path', sources('core', 'matchers') + sources('core', 'search'),
                         ids=lambda p: str(p.relative_to(PACKAGE)))
def test_matchers_and_search_do_not_import_the_pipeline_layer(path):
    banned = [name for name in imported_modules(path)
              if name.startswith('laser_odom.core.')
              and name.split('.')[2] in ABOVE_THE_MATCHERS]
    assert not banned, f'{path} imports {banned}'


@pytest.mark.parametrize('matcher', MATCHERS)
def test_a_matcher_imports_no_other_matcher(matcher):
    others = tuple(f'laser_odom.core.matchers.{m}' for m in MATCHERS if m != matcher)
    for path in sources('core', 'matchers', matcher):
        banned = [name for name in imported_modules(path) if name.startswith(others)]
        assert not banned, f'{path} imports {banned}'
