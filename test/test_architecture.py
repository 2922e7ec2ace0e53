"""The layering of the package (README "Architecture"), checked on the import statements.

Every module under ``robodyn_ros/`` is parsed with :mod:`ast` (no import is executed), each
``import``/``from ... import`` — at module level or inside a function — is resolved to an absolute
module name, and the rules are checked on those names: the floors listed in README (no import
from a higher floor, no circle between rooms), the top floor's benchmarks, and rclpy only in the
ROS adapters.
"""
from __future__ import annotations

import ast
import re
from pathlib import Path

import pytest

PACKAGE = Path(__file__).resolve().parents[1] / 'robodyn_ros'

#: modules that stand on the top floor: they may import the benchmarks
MAY_IMPORT_BENCH = ('robodyn_ros.bench', 'robodyn_ros.cli', 'robodyn_ros.advise')
#: modules that may import rclpy (and ROS message packages)
MAY_IMPORT_ROS = ('robodyn_ros.nodes', 'robodyn_ros.recording', 'robodyn_ros.cli', 'robodyn_ros.bench')


def module_name(path: Path) -> str:
    """``robodyn_ros.a.b`` for ``robodyn_ros/a/b.py`` (``robodyn_ros.a`` for ``a/__init__.py``)."""
    parts = list(path.relative_to(PACKAGE.parent).with_suffix('').parts)
    if parts[-1] == '__init__':
        parts.pop()
    return '.'.join(parts)


def imported_modules(source: str, module: str, is_package: bool = False) -> list[tuple[int, str]]:
    """``[(line, absolute module name)]`` of every import in ``source`` (the text of ``module``).

    ``from . import x`` counts as importing ``<package>.x`` (x may be a submodule) and as
    importing the package itself.
    """
    package = module if is_package else module.rpartition('.')[0]
    out = []
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.Import):
            out += [(node.lineno, a.name) for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split('.')
                base = base[:len(base) - (node.level - 1)]
                if not base:
                    raise ValueError(f'{module}:{node.lineno}: relative import beyond the top package')
                target = '.'.join(base + ([node.module] if node.module else []))
            else:
                target = node.module
            out.append((node.lineno, target))
            out += [(node.lineno, f'{target}.{a.name}') for a in node.names if a.name != '*']
    return out


def _within(name: str, prefixes) -> bool:
    return any(name == p or name.startswith(p + '.') for p in prefixes)


def violations(module: str, source: str, is_package: bool = False) -> list[str]:
    """The layering rules this module's imports break, as ``module:line: reason`` strings."""
    bad = []
    for line, target in imported_modules(source, module, is_package):
        if _within(target, ('robodyn_ros.bench',)) and not _within(module, MAY_IMPORT_BENCH):
            bad.append(f'{module}:{line}: imports {target}; only bench/, cli/ and advise may import bench')
        if target.split('.')[0] == 'rclpy' and not _within(module, MAY_IMPORT_ROS):
            bad.append(f'{module}:{line}: imports {target}; rclpy only in nodes/, recording/, cli/, bench/')
    return bad


def all_modules():
    files = sorted(PACKAGE.rglob('*.py'))
    assert len(files) > 40, f'found only {len(files)} modules under {PACKAGE}'
    return files


def test_the_checker_sees_a_violation():
    """The rule can fail: a runtime module importing the bench, relatively, absolutely and lazily."""
    for src in ('from .bench.precision import simulate\n',
                'from . import bench\n',
                'def f():\n    from .bench import precision\n',
                'import robodyn_ros.bench.speed\n'):
        assert violations('robodyn_ros.simulation', src), src
    assert violations('robodyn_ros.systems.arm', 'from ..bench import timing\n')
    assert violations('robodyn_ros.systems', 'from ..bench import timing\n', is_package=True)  # systems/__init__
    assert violations('robodyn_ros.kernels', 'from .. import bench\n', is_package=True)
    assert not violations('robodyn_ros.kernels', 'from . import bench\n', is_package=True)  # kernels.bench
    assert not violations('robodyn_ros.cli.advise', 'from ..bench.precision import Progress\n')
    assert not violations('robodyn_ros.advise', 'from .bench.precision import Run\n')
    assert not violations('robodyn_ros.bench.extremes', 'from .precision import simulate\n')
    assert violations('robodyn_ros.dynamics', 'import rclpy\n')


@pytest.mark.parametrize('rule', ['bench', 'rclpy'])
def test_runtime_modules_do_not_import_the_top_floor(rule):
    """No module under robodyn_ros/ outside bench/, cli/ and advise imports bench (and rclpy stays
    in the ROS adapters)."""
    bad = []
    for path in all_modules():
        name = module_name(path)
        bad += [v for v in violations(name, path.read_text(), path.name == '__init__.py') if rule in v.split(';')[0]]
    assert bad == []


def test_the_runtime_checks_sit_low_in_the_house():
    """stability.py (step preflight, diagnosis) imports only model and dynamics from the package,
    so the Simulator's run-time checks never pull in scenes, systems or benchmarks."""
    path = PACKAGE / 'stability.py'
    own = {t for _, t in imported_modules(path.read_text(), 'robodyn_ros.stability') if t.startswith('robodyn_ros')}
    assert own and own <= {'robodyn_ros', 'robodyn_ros.model', 'robodyn_ros.model.FREE', 'robodyn_ros.dynamics'}, own


# ---------------------------------------------------------------------------------------------
# floors: README "Architecture" lists them, one line a floor; every import stays level or goes down
# ---------------------------------------------------------------------------------------------
README = PACKAGE.parent / 'README.md'
_FLOOR_LINE = re.compile(r'^(\d+)\. [^:`]+: (`[A-Za-z_]+`(?:, `[A-Za-z_]+`)*)\s*$')


def readme_floors(text: str) -> dict:
    """``{room: floor}`` from the numbered list of README's ``## Architecture`` section: each line
    ``N. title: `a`, `b`, ...`` puts the rooms a, b (top-level modules or packages of
    robodyn_ros) on floor N, 1 the ground."""
    m = re.search(r'^## Architecture\n(.*?)(?=^## |\Z)', text, re.M | re.S)
    assert m, 'README.md has no "## Architecture" section'
    floors = {}
    for line in m.group(1).splitlines():
        hit = _FLOOR_LINE.match(line)
        if hit:
            for room in re.findall(r'`([A-Za-z_]+)`', hit.group(2)):
                assert room not in floors, f'{room} is listed on two floors'
                floors[room] = int(hit.group(1))
    return floors


def room(module: str) -> str | None:
    """The room of ``robodyn_ros.a.b``: ``a`` (None for the package ``robodyn_ros`` itself)."""
    parts = module.split('.')
    return parts[1] if len(parts) > 1 else None


def floor_violations(module: str, source: str, floors: dict, is_package: bool = False) -> list[str]:
    """Imports of ``module`` that reach a higher floor than its own, as ``module:line: reason``."""
    own = floors[room(module)]
    bad = []
    for line, target in imported_modules(source, module, is_package):
        r = room(target) if target.split('.')[0] == 'robodyn_ros' else None
        if r is not None and r in floors and floors[r] > own:
            bad.append(f'{module}:{line}: imports {target} (floor {floors[r]}) from floor {own}')
    return bad


def room_imports() -> dict:
    """``{room: {rooms it imports}}`` over every module of the package (same-room imports left out)."""
    out = {}
    for path in all_modules():
        name = module_name(path)
        r = room(name)
        if r is None:
            continue
        targets = {room(t) for _, t in imported_modules(path.read_text(), name, path.name == '__init__.py')
                   if t.split('.')[0] == 'robodyn_ros'}
        out.setdefault(r, set()).update(t for t in targets if t not in (None, r))
    return out


def circles(graph: dict) -> list[list[str]]:
    """The strongly connected components of more than one room (Tarjan), each sorted."""
    index, low, stack, on, out = {}, {}, [], set(), []

    def visit(v):
        index[v] = low[v] = len(index)
        stack.append(v)
        on.add(v)
        for w in graph.get(v, ()):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                out.append(sorted(comp))
    for v in sorted(graph):
        if v not in index:
            visit(v)
    return out


def test_readme_lists_the_floors_of_every_room():
    """README's Architecture list names seven floors, and every module of the package stands in a
    room it names (a new module or package must be given its floor there)."""
    floors = readme_floors(README.read_text(encoding='utf-8'))
    assert sorted(set(floors.values())) == list(range(1, 8)), floors
    rooms = {room(module_name(p)) for p in all_modules()} - {None}
    assert rooms - set(floors) == set(), 'rooms missing from README "Architecture"'
    assert set(floors) - rooms == set(), 'README "Architecture" names rooms that do not exist'
    # the package itself holds nothing of its rooms: its __init__ imports os alone (a process-wide default,
    # set before numpy loads) and no module of the package
    root = ast.parse((PACKAGE / '__init__.py').read_text())
    imported = [a.name for n in ast.walk(root) if isinstance(n, (ast.Import, ast.ImportFrom))
                for a in n.names] + [n.module for n in ast.walk(root) if isinstance(n, ast.ImportFrom)]
    assert imported == ['os'], imported


def test_the_floor_checker_sees_a_violation():
    """The floor rule can fail: an import up from a lower floor, relative, absolute or lazy; level
    and downward imports pass."""
    floors = {'model': 1, 'kernels': 2, 'systems': 3, 'scene': 4, 'nodes': 6, 'cli': 7}
    for src in ('from ..scene import load_scene\n', 'from .. import scene\n', 'import robodyn_ros.scene.arm\n',
                'def f():\n    from ..systems.arm import ArmSystem\n'):
        assert floor_violations('robodyn_ros.kernels.tree', src, floors), src
    assert floor_violations('robodyn_ros.kernels', 'from ..cli import main\n', floors, is_package=True)
    assert floor_violations('robodyn_ros.systems.arm', 'def f():\n    from ..nodes import sim\n', floors)
    assert not floor_violations('robodyn_ros.kernels.tree', 'from ..model import FREE\nfrom . import linalg\n', floors)
    assert not floor_violations('robodyn_ros.nodes.sim', 'from ..scene import load_scene\n', floors)
    assert not floor_violations('robodyn_ros.scene.arm', 'from ..systems.arm import ArmSystem\n', floors)
    assert circles({'a': {'b'}, 'b': {'c'}, 'c': {'a'}, 'd': {'a'}}) == [['a', 'b', 'c']]
    assert circles({'a': {'b'}, 'b': set()}) == []


def test_no_import_climbs_a_floor():
    """No module imports a room on a higher floor than its own (README "Architecture")."""
    floors = readme_floors(README.read_text(encoding='utf-8'))
    bad = []
    for path in all_modules():
        name = module_name(path)
        if room(name) is not None:
            bad += floor_violations(name, path.read_text(), floors, path.name == '__init__.py')
    assert bad == []


def test_no_import_circle_between_rooms():
    """No two rooms import each other, directly or around a circle (level imports included)."""
    graph = room_imports()
    assert len(graph) > 20 and graph['scene'] and graph['cli']
    assert circles(graph) == []
