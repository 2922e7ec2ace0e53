"""The kernels that count no references (``kernels.tree._LEAF``: numba's ``_nrt=False``) leak nothing.

A kernel compiled without numba's reference counting neither counts up its array arguments nor down
again; that is right as long as no reference it is handed needs counting: it must not allocate (numba
refuses to compile it then), and an array one returns must reach only callers that count nothing
either. A counting callee returning an array to such a kernel would leak that array's reference: its
memory would never be freed.

Checked two ways: by the source (every kernel states whether it counts, so that no kernel inherits a
caller's setting; a leaf whose compiled return type holds an array is called only from leaves), and by numba's own allocation
statistics around real runs of the scenes whose paths go through the leaves (a tree on a ground, a
joint servo, spherical joint stops, mimic coupling, error control), each run twice, recorded and not:
the second run must leave as many live allocations as it found (a leaked reference keeps its array).
Broken once: with ``stiffness_rate`` counting again while its leaf caller does not, a1_stand's runs
leave 2 and 3 arrays alive.
"""
from __future__ import annotations

import ast
import json
import os
import subprocess
import sys
from pathlib import Path

KERNELS = Path(__file__).resolve().parents[1] / 'robodyn_ros' / 'kernels'


def _kernels():
    """``{name: (module, FunctionDef, leaf)}`` of every ``@njit`` kernel, and the decorator sources."""
    out, decorators = {}, []
    for path in sorted(KERNELS.glob('*.py')):
        tree = ast.parse(path.read_text())
        for f in tree.body:
            if not isinstance(f, ast.FunctionDef):
                continue
            for d in f.decorator_list:
                src = ast.unparse(d)
                if src.startswith('njit'):
                    decorators.append((path.name, f.name, src))
                    out[f.name] = (path.name, f, '_LEAF' in src or '_nrt=False' in src)
    return out, decorators


def test_every_kernel_says_whether_it_counts():
    """A kernel that does not say takes its caller's setting: called from a leaf it would be compiled
    without counting, and refused if it allocates."""
    kernels, decorators = _kernels()
    assert len(decorators) > 100
    unstated = [(m, n, d) for m, n, d in decorators
                if not any(k in d for k in ('_JIT', '_LEAF', '_nrt=True', '_nrt=False'))]
    assert unstated == []
    for m in {m for m, _, _ in decorators}:   # the option dicts themselves say it
        for line in (KERNELS / m).read_text().splitlines():
            if line.startswith('_JIT = dict('):
                assert '_nrt=True' in line, (m, line)
    leaves = {n for n, (_, _, leaf) in kernels.items() if leaf}
    assert {'arm_rosenbrock_step', 'aba_ws', 'cholesky'} <= leaves


_RUNS = r'''
import gc, json, os, sys, tempfile, warnings
warnings.simplefilter('ignore')
from numba.core.runtime import _nrt_python, rtsys
from robodyn_ros.cli.warm import _scene_runs
from robodyn_ros.recording.run_sink import HEADLESS_BATCH, McapRunSink
from robodyn_ros.runs import plan_run, resolve_settings
from robodyn_ros.simulation import Simulator, run_headless
scratch = tempfile.mkdtemp()
loads = dict(_scene_runs(scratch))
_nrt_python.memsys_enable_stats()

def run(load, record):
    scene = load()
    plan, st = plan_run(resolve_settings(scene, duration=0.1), scene.system, scene.y0)
    sim = Simulator(scene.system, scene.y0, plan=plan)
    path = os.path.join(scratch, 'x.mcap')
    sinks = [McapRunSink(path, scene, st, batch=HEADLESS_BATCH)] if record else []
    n = run_headless(sim, 0.1, st['rate'], scene.script, sinks)
    for s in sinks:
        s.close()
        os.remove(path)
    del scene, sim, sinks
    gc.collect()
    return n

out = {}
for label in json.loads(sys.argv[1]):
    for record in (False, True):
        run(loads[label], record)           # compiles or loads, fills caches
        s0 = rtsys.get_allocation_stats()
        n = run(loads[label], record)
        s1 = rtsys.get_allocation_stats()
        out[f'{label}, recorded={record}'] = dict(
            periods=n, allocations=s1.alloc - s0.alloc,
            live=(s1.alloc - s1.free) - (s0.alloc - s0.free),
            live_meminfos=(s1.mi_alloc - s1.mi_free) - (s0.mi_alloc - s0.mi_free))
import numba, robodyn_ros.kernels as K
from numba.core.registry import CPUDispatcher
returning = set()
for mod in list(sys.modules.values()):
    if getattr(mod, '__name__', '').startswith('robodyn_ros.kernels.'):
        for name, d in vars(mod).items():
            if isinstance(d, CPUDispatcher) and d.targetoptions.get('_nrt') is False:
                for key in d._cache._cache_file._load_index():   # a callee's signatures, from its cache
                    d.compile(key[0])
                for cres in d.overloads.values():
                    rt = cres.signature.return_type
                    if isinstance(rt, numba.types.Array) or any(isinstance(t, numba.types.Array)
                                                                for t in getattr(rt, 'types', ())):
                        returning.add(d.py_func.__name__)
print(json.dumps({'runs': out, 'returning': sorted(returning)}))
'''

LABELS = ['a1_stand', 'xarm7_trajectory', 'huston_human17', 'solo12_drop', 'stanford_arm',
          'stanford_arm as URDF, damped, mimic', 'stanford_arm as URDF, friction']


def test_runs_through_the_leaves_leave_no_array_alive():
    env = dict(os.environ, PYTHONHASHSEED='0')
    proc = subprocess.run([sys.executable, '-c', _RUNS, json.dumps(LABELS)], capture_output=True, text=True,
                          env=env, timeout=900)
    assert proc.returncode == 0, proc.stderr[-3000:]
    got = json.loads(proc.stdout.strip().splitlines()[-1])
    out = got['runs']
    assert len(out) == 2 * len(LABELS)
    for key, row in out.items():
        assert row['periods'] >= 5, (key, row)
        assert row['allocations'] > 0, (key, row)   # the statistics see the run's arrays
        assert row['live'] == 0 and row['live_meminfos'] == 0, (key, row)
    # a leaf returning an array (numba's type of its compiled return) is called only from leaves
    assert 'stiffness_rate' in got['returning']   # the one today (a1_stand's path): the check sees it
    kernels, _ = _kernels()
    leaves = {n for n, (_, _, leaf) in kernels.items() if leaf}
    callers = {r: {n for n, (_, f, _) in kernels.items()
                   for node in ast.walk(f)
                   if isinstance(node, ast.Call) and isinstance(node.func, ast.Name) and node.func.id == r}
               for r in got['returning']}
    assert all(callers.values()), callers
    assert {r: sorted(c - leaves) for r, c in callers.items() if c - leaves} == {}
