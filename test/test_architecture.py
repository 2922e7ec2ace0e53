"""The layering of the package (README "Architecture"), checked on the import statements.

Every module under ``robodyn_ros/`` is parsed with :mod:`ast` (no import is executed), each
``import``/``from ... import`` — at module level or inside a function — is resolved to an absolute
module name, and the rules are checked on those names.
"""
from __future__ import annotations

import ast
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
