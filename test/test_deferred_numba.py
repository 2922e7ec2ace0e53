"""A short ``robodyn run`` never loads numba, and records the bytes the compiled kernels record.

``robodyn run`` imports the kernels deferred (:data:`robodyn_ros.kernels.jit.DEFERRED`): each kernel runs its
Python source (the compiled code's operations, in the same order) until the run's interpreted time passes
``jit.INTERPRET_BUDGET``, or the run is expected to (``jit.expect``); then numba is loaded and every kernel
becomes numba's. The oracle is the compiled run: ``ROBODYN_INTERPRET_BUDGET=0`` loads numba before the first
step. Whether numba was loaded is read from the process's own ``sys.modules``.
"""
from __future__ import annotations

import filecmp
import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def _robodyn(argv, budget=None, patch_expect=False) -> dict:
    """``robodyn ARGV`` in a new process: ``{'rc', 'numba' (loaded at the end), 'spent' (s interpreted),
    'out' (stdout), 'left' (Deferred objects left in robodyn_ros's module namespaces)}``. patch_expect: the
    run's estimate says "short" whatever it is, so only the budget can load numba (mid-run)."""
    code = f'''
import contextlib, io, json, sys
from robodyn_ros.cli import run as run_cli
out = io.StringIO()
if {patch_expect!r}:
    import os
    os.environ['_ROBODYN_DEFER_NUMBA'] = '1'
    from robodyn_ros.kernels import jit
    del os.environ['_ROBODYN_DEFER_NUMBA']
    assert jit.DEFERRED and not jit.LOADED
    jit.expect = lambda seconds, before=None: None
from robodyn_ros.cli import main
with contextlib.redirect_stdout(out):
    rc = main(json.loads(sys.argv[1]))
from robodyn_ros.kernels import jit
left = [f'{{n}}.{{k}}' for n, m in list(sys.modules.items()) if n.startswith('robodyn_ros') and m is not None
        for k, v in vars(m).items() if isinstance(v, jit.Deferred)
        or isinstance(v, tuple) and any(isinstance(x, jit.Deferred) for x in v)
        or isinstance(v, dict) and any(isinstance(x, jit.Deferred) or isinstance(x, tuple)
                                       and any(isinstance(y, jit.Deferred) for y in x) for x in v.values())]
print(json.dumps({{'rc': rc, 'numba': 'numba' in sys.modules, 'spent': jit.SPENT[0], 'out': out.getvalue(),
                  'left': left}}))
'''
    env = dict(os.environ)
    env.pop('ROBODYN_INTERPRET_BUDGET', None)
    if budget is not None:
        env['ROBODYN_INTERPRET_BUDGET'] = str(budget)
    r = subprocess.run([sys.executable, '-c', code, json.dumps(argv)], capture_output=True, text=True, env=env,
                       cwd=ROOT)
    assert r.returncode == 0, r.stderr[-3000:]
    got = json.loads(r.stdout.strip().splitlines()[-1])
    assert got['rc'] == 0, got['out']
    return got


@pytest.mark.parametrize('scene', ['stanford_arm', 'xarm7_trajectory', 'betancur_platform', 'huston_p19_4_1'])
def test_a_short_run_does_not_load_numba_and_records_the_compiled_bytes(tmp_path, scene):
    # the budget out of reach, so that a slow or loaded machine cannot load numba mid-run (no timing in the test)
    short = _robodyn(['run', scene, '--duration', '0.02', '--record', str(tmp_path / 'deferred.mcap')], budget=1e9)
    assert not short['numba'], 'numba was loaded by a 0.02 s run'
    assert short['spent'] > 0   # its kernels ran, as Python
    assert 'numba not loaded' in short['out']
    compiled = _robodyn(['run', scene, '--duration', '0.02', '--record', str(tmp_path / 'compiled.mcap')], budget=0)
    assert compiled['numba'] and compiled['spent'] == 0   # the oracle: compiled kernels from the first step
    assert 'numba not loaded' not in compiled['out']
    assert filecmp.cmp(tmp_path / 'deferred.mcap', tmp_path / 'compiled.mcap', shallow=False)


def test_numba_loads_mid_run_at_the_budget_and_the_bytes_do_not_change(tmp_path):
    # (the run interprets about 0.023 s of kernels here, 4.6x the budget: its recorder's loops run as numpy)
    argv = ['run', 'stanford_arm', '--duration', '0.5', '--record']
    mid = _robodyn(argv + [str(tmp_path / 'mid.mcap')], budget=0.005, patch_expect=True)
    assert mid['numba'] and mid['spent'] >= 0.005         # interpreted past the budget, then loaded
    assert mid['left'] == []                               # every kernel in every namespace is numba's now
    compiled = _robodyn(argv + [str(tmp_path / 'compiled.mcap')], budget=0)
    assert compiled['numba'] and compiled['spent'] == 0
    assert filecmp.cmp(tmp_path / 'mid.mcap', tmp_path / 'compiled.mcap', shallow=False)


@pytest.mark.parametrize('argv', [['stanford_arm', '--duration', '20'],        # many steps
                                  ['huston_human17', '--duration', '0.01']])     # its plan: 251 evaluations of 125 states
def test_a_run_expected_to_be_long_loads_numba_before_its_first_step(argv):
    got = _robodyn(['run', *argv])
    assert got['numba'] and got['spent'] == 0 and got['left'] == []
