"""A run starts without what it does not use, and without compiling what was compiled before.

Properties of our code, not timings (``robodyn bench startup`` measures those):

* ``robodyn run`` imports the adaptive integrators' scipy, the sweeps' Dask and Parquet, the plots'
  matplotlib, the recorder's mcap and rclpy only when it uses them; ``robodyn --help`` imports
  neither numpy nor numba;
* every kernel is cached on disk, stamped with the fingerprint of every kernel module's source
  (an edit of one invalidates all: they inline each other);
* the kernels' argument types do not depend on the robot: a robot never run before loads every
  kernel from a cache that other robots filled, in a new process (``test_cold_start.py``, on the
  cache a cold run's child filled);
* copies of the same sources at other paths (venvs, clones, ``colcon build``) share one compilation;
* ``robodyn warm`` (``make run``) meets every kernel signature the runs of the bundled scenes and of
  URDF robots use.
"""
from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from robodyn_ros import kernels

assert kernels.AVAILABLE, kernels.UNAVAILABLE_REASON   # numba is a hard dependency: fail, never skip

ROOT = Path(__file__).resolve().parents[1]
#: what a run without recording, plots, sweeps or adaptive integrators must not import
HEAVY = ('scipy.integrate', 'scipy.optimize', 'scipy.sparse', 'dask', 'distributed', 'pyarrow', 'matplotlib',
         'mcap', 'mcap_ros2', 'rosbags', 'rclpy', 'yourdfpy', 'pandas')


def _modules_after(argv, env=None) -> set:
    """Top-level and dotted names in sys.modules after ``robodyn ARGV`` in a new process."""
    code = ('import io, contextlib, json, sys\nfrom robodyn_ros.cli import main\n'
            'with contextlib.redirect_stdout(io.StringIO()):\n    rc = main(json.loads(sys.argv[1]))\n'
            'print(json.dumps([rc, sorted(sys.modules)]))\n')
    r = subprocess.run([sys.executable, '-c', code, json.dumps(argv)], capture_output=True, text=True, env=env,
                       cwd=ROOT)
    assert r.returncode == 0, r.stderr[-3000:]
    rc, mods = json.loads(r.stdout.strip().splitlines()[-1])
    assert rc == 0
    return set(mods)


def _heavy(mods) -> list:
    return sorted(h for h in HEAVY if h in mods)


@pytest.mark.parametrize('scene', ['stanford_arm', 'betancur_platform', 'unfried_free_flyer'])
def test_run_imports_only_what_it_uses(scene, tmp_path):
    mods = _modules_after(['run', scene, '--duration', '0.02'])
    assert 'robodyn_ros.kernels.tree' in mods      # it did run on the compiled kernels
    assert _heavy(mods) == []
    mods = _modules_after(['run', scene, '--duration', '0.02', '--record', str(tmp_path / 'r.mcap')])
    assert _heavy(mods) == ['mcap']                # the recorder, and nothing else heavy
    # the check sees an import when it happens: an adaptive integrator brings scipy.integrate
    assert 'scipy.integrate' in _modules_after(['run', scene, '--duration', '0.02', '--integrator', 'rk45'])


def test_help_imports_neither_numpy_nor_numba():
    code = 'import sys\nfrom robodyn_ros.cli import main\ntry:\n    main(["--help"])\nexcept SystemExit:\n    pass\n' \
           'print("numpy" in sys.modules, "numba" in sys.modules)'
    r = subprocess.run([sys.executable, '-c', code], capture_output=True, text=True, check=True)
    assert r.stdout.strip().splitlines()[-1] == 'False False'
    assert 'usage: robodyn' in r.stdout


def test_help_lists_every_subcommand_with_the_line_its_parser_registers():
    import argparse

    from robodyn_ros.cli import SUBCOMMANDS, build_parser
    full = build_parser()             # every subcommand built with its options
    short = build_parser(['--help'])  # only names and help lines
    def choices(p):
        sub = next(a for a in p._actions if isinstance(a, argparse._SubParsersAction))
        return {c.dest: c.help for c in sub._choices_actions}
    assert choices(full) == choices(short)
    assert set(choices(full)) == set(SUBCOMMANDS)
    args = build_parser(['run', 'x', '--duration', '1']).parse_args(['run', 'x', '--duration', '1'])
    assert args.command == 'run' and args.duration == 1.0


def test_every_kernel_is_cached_and_stamped_with_the_fingerprint():
    import importlib
    import pkgutil

    from numba.core.caching import NullCache

    from robodyn_ros.kernels import cache
    for m in pkgutil.iter_modules(kernels.__path__):
        importlib.import_module(f'robodyn_ros.kernels.{m.name}')
    disp = cache.dispatchers()
    assert len(disp) > 100
    uncached = [n for n, d in disp.items() if isinstance(d._cache, NullCache)]
    assert not uncached, f'kernels without cache=True: {uncached}'
    for name, d in disp.items():
        loc = d._cache._impl.locator
        assert getattr(loc, 'ROBODYN', False), name
        generated = name.startswith('robodyn_gen_')   # a generated module other tests loaded: its own text too
        stamp = cache._generated_stamp(loc._py_file) if generated else cache.FINGERPRINT
        assert loc.get_source_stamp() == stamp, name
        if not generated:   # (a generated module's cache is beside it, in the generated-code directory)
            assert os.path.abspath(loc.get_cache_path()).startswith(os.path.abspath(cache.cache_root())), name


def test_the_fingerprint_changes_with_any_kernel_module(tmp_path):
    from robodyn_ros.kernels import cache
    for p in Path(cache.HERE).glob('*.py'):
        shutil.copy(p, tmp_path / p.name)
    assert cache._fingerprint(str(tmp_path)) == cache.FINGERPRINT
    for name in ('tree.py', 'linalg.py'):   # a callee's module, edited alone
        text = (tmp_path / name).read_text()
        (tmp_path / name).write_text(text + '\n# edited\n')
        assert cache._fingerprint(str(tmp_path)) != cache.FINGERPRINT
        (tmp_path / name).write_text(text)
    assert cache._fingerprint(str(tmp_path)) == cache.FINGERPRINT


_ONE_KERNEL = ('import json, sys\nfrom robodyn_ros.kernels import cache, tree\n'
               'assert tree.__file__.startswith(sys.argv[1]), tree.__file__\n'
               'tree.joint_nv(1)\n'
               'print(json.dumps([cache.compiled_here(), cache.loaded_here(), cache.kernel_cache_dir()]))\n')


def test_copies_of_the_same_sources_share_one_compilation_in_the_user_cache(tmp_path):
    """Installs of the same sources at other paths (a second venv or clone, ``colcon build``'s copy) with
    one user cache: the first compiles a kernel, the next loads it; a copy with an edited kernel module
    compiles its own into a directory of its own, and the first's stays."""
    import shutil

    import robodyn_ros
    src = Path(robodyn_ros.__file__).parent
    for name in ('a', 'b', 'c'):
        shutil.copytree(src, tmp_path / name / 'robodyn_ros', ignore=shutil.ignore_patterns('__pycache__'))
    edited = tmp_path / 'c' / 'robodyn_ros' / 'kernels' / 'linalg.py'
    edited.write_text(edited.read_text() + '\n# an edit\n')
    got = {}
    for name in ('a', 'b', 'c', 'a'):
        env = {k: v for k, v in os.environ.items() if k not in ('NUMBA_CACHE_DIR', 'ROBODYN_BACKEND')}
        env.update(XDG_CACHE_HOME=str(tmp_path / 'home'), PYTHONPATH=str(tmp_path / name),
                   ROBODYN_COLD_START='compile', ROBODYN_INTERPRET_BUDGET='0')
        r = subprocess.run([sys.executable, '-c', _ONE_KERNEL, str(tmp_path / name)], capture_output=True,
                           text=True, env=env, cwd=str(tmp_path))
        assert r.returncode == 0, r.stderr[-3000:]
        got.setdefault(name, []).append(json.loads(r.stdout.strip().splitlines()[-1]))
    (a, a_again), (b,), (c,) = got['a'], got['b'], got['c']
    home = str(tmp_path / 'home' / 'robodyn_ros' / 'numba')
    assert a[0] and a[2].startswith(home)                      # the first copy compiled, into the user cache
    assert b[0] == [] and b[1] == ['robodyn_ros.kernels.tree.joint_nv'] and b[2] == a[2]   # the second loaded it
    assert c[0] and c[2] != a[2] and c[2].startswith(home)     # other sources: their own directory
    assert a_again[0] == [] and a_again[1] == b[1]             # and the first's is still there


def test_a_new_kernel_cache_directory_removes_the_least_recently_used_beyond_keep(tmp_path):
    from robodyn_ros.kernels import cache
    for i in range(cache.KEEP + 2):
        d = tmp_path / f'kernels-{i:016x}'
        d.mkdir()
        os.utime(d, (1000 + i, 1000 + i))   # 0 the least recently used
    (tmp_path / 'other').mkdir()
    os.utime(tmp_path / 'other', (1, 1))
    made = tmp_path / 'kernels-new'
    assert cache._writable(str(made))     # made now: the most recent; the two oldest go
    assert sorted(p.name for p in tmp_path.iterdir()) == \
        sorted(['other', 'kernels-new'] + [f'kernels-{i:016x}' for i in range(3, cache.KEEP + 2)])


def test_a_kernel_called_with_constants_and_with_variables_is_compiled_once():
    """Kernels call kernels with constant offsets and flags (``xmot(W, 12, 12, ...)``, ``aba_ws(..., True)``)
    as well as with variables: one signature of plain types serves them all (numba alone compiled one per
    constant: Literal[int](3), Literal[bool](True), then int64 and bool again), and the results are the
    plain Python function's."""
    from robodyn_ros.kernels.jit import njit

    def scale(x, k, flag):
        return x * k if flag else x - k

    def both(x, n, f):
        return callee(x, 3, True) + callee(x, n, f) + callee(x, 5, False)

    callee = njit(cache=False)(scale)
    caller = njit(cache=False)(both)
    assert caller(2.0, 4, False) == scale(2.0, 3, True) + scale(2.0, 4, False) + scale(2.0, 5, False)
    assert [str(s) for s in callee.signatures] == ['(float64, int64, bool)']


def test_warm_meets_every_kernel_signature_the_runs_use(tmp_path, monkeypatch):
    """After ``robodyn warm``'s runs, the runs of ``robodyn run`` (every bundled scene, with and
    without recording) and of example-robot-data robots (friction, mimic joints) add no kernel
    signature: what warm compiles into the cache is all they load. In one process, whatever the
    cache holds (the signatures, not the disk, are compared)."""
    import contextlib
    import io
    import warnings

    from robodyn_ros.cli import main
    from robodyn_ros.cli.warm import _scene_runs, warm_scene
    from robodyn_ros.kernels.cache import dispatchers
    from robodyn_ros.systems.base import tools_backend
    from robodyn_ros.urdf import example_robot_data_dir
    backend = tools_backend()
    monkeypatch.setenv('ROBODYN_COLD_START', 'compile')   # a miss compiles here (interpreted, it would hide)
    with warnings.catch_warnings():
        warnings.simplefilter('ignore')
        for _, load in _scene_runs(str(tmp_path)):
            warm_scene(load, backend, str(tmp_path))
    warmed = {n: set(d.overloads) for n, d in dispatchers().items()}
    runs = []
    from robodyn_ros.scene import list_scenes
    for name, _ in list_scenes():
        runs += [['run', name, '--duration', '0.3'],
                 ['run', name, '--duration', '0.3', '--record', str(tmp_path / 'r.mcap'), '--overwrite']]
    d = example_robot_data_dir()
    assert d is not None, 'example-robot-data (a test dependency) is not installed'
    # a quadruped, an arm with friction (z1), a humanoid, an arm with a mimic finger
    runs += [['run', str(next(d.rglob(f))), '--duration', '0.05'] for f in ('go2.urdf', 'z1.urdf', 'human.urdf', 'panda.urdf')]
    out = io.StringIO()
    failed = []
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(out):
        for argv in runs:
            if main(argv) != 0:
                failed.append(argv)
    assert not failed, (failed, out.getvalue()[-3000:])
    after = {n: set(d.overloads) for n, d in dispatchers().items()}
    new = {n: sorted(map(str, s - warmed.get(n, set()))) for n, s in after.items() if s - warmed.get(n, set())}
    assert new == {}, new


@pytest.mark.processes
def test_warm_in_worker_processes_leaves_nothing_for_the_loading_pass():
    """``robodyn warm --jobs 2 SCENE SCENE``: two spawned workers run the scenes into the one cache, then
    the loading pass in the parent runs them again and compiles nothing they left out (whether the
    cache was empty or full before); an unknown scene is refused in one line, exit 2."""
    env = {k: v for k, v in os.environ.items() if k != 'ROBODYN_BACKEND'}
    r = subprocess.run([sys.executable, '-m', 'robodyn_ros.cli', 'warm', '--jobs', '2', 'betancur_dh_animation',
                        'huston_p19_2_3'], capture_output=True, text=True, env=env, cwd=ROOT, timeout=1800)
    assert r.returncode == 0, r.stderr[-3000:]
    lines = r.stdout.strip().splitlines()
    assert sorted(ln.split()[0] for ln in lines if ln.endswith('(worker)')) == ['betancur_dh_animation',
                                                                                 'huston_p19_2_3'], lines
    assert '(2 processes: ' in lines[-1] and ', 0 after them;' in lines[-1], lines[-1]
    r = subprocess.run([sys.executable, '-m', 'robodyn_ros.cli', 'warm', 'no_such_scene'], capture_output=True,
                       text=True, env=env, cwd=ROOT, timeout=600)
    assert r.returncode == 2 and r.stderr.count('\n') == 1 and "unknown scene 'no_such_scene'" in r.stderr, r.stderr


@pytest.mark.processes
def test_the_startup_bench_sees_a_compiler_child_until_it_ends():
    """``bench.startup.compiler_children`` (what the bench waits on before a first run) finds a process whose
    command line is the compiler child's, and no longer once it has ended."""
    from robodyn_ros.bench.startup import compiler_children
    p = subprocess.Popen([sys.executable, '-c', 'import sys; print("up", flush=True); sys.stdin.read()', '-m',
                          'robodyn_ros.kernels.jit'], stdin=subprocess.PIPE, stdout=subprocess.PIPE)
    try:
        assert p.stdout.readline() == b'up\n'   # running (right after its exec, /proc may show no command line yet)
        assert p.pid in compiler_children()
    finally:
        p.stdin.close()
        p.wait(timeout=60)
    assert p.pid not in compiler_children()
    assert os.getpid() not in compiler_children()
