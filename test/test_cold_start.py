"""A cold kernel cache: the kernels run as Python (kernels.jit, mode 'interpret'/'python') with the compiled
code's bits, while a child process compiles them for the next call.

The claim is equality of arithmetic: every bundled scene (and the URDF variants robodyn warm runs: friction
and effort limits, a mimic joint, stiff damping under rosenbrock2) is recorded by a process that runs every
kernel as Python (mode 'python', an empty cache) and by one that runs the compiled kernels: the same file.
The compiled kernels themselves are checked against independent references elsewhere.
"""
from __future__ import annotations

import os
import subprocess
import sys
import types
from pathlib import Path

import numpy as np
import pytest

from robodyn_ros import kernels
from robodyn_ros.kernels import jit
from robodyn_ros.scene import list_scenes

ROOT = Path(__file__).resolve().parents[1]
PY = sys.executable

#: simulated seconds per scene: enough for several diagnostics periods and a block of periods (the
#: recorder's layouts, the block path), short where the interpreter is slow (54 DOF at 50 µs steps)
DURATION = {'huston_human17': 0.05, 'huston_human17_fall': 0.01, 'solo12_drop': 0.02, 'a1_stand': 0.1,
            'mobile_manipulator': 0.1, 'unfried_free_flyer': 0.1}


def _env(mode, cache):
    """The environment of a child: cold-start mode, and an own kernel cache (None: the package's)."""
    env = dict(os.environ, ROBODYN_COLD_START=mode)
    if cache is not None:
        env.update(NUMBA_CACHE_DIR=str(cache), ROBODYN_GENERATED_DIR=str(Path(cache) / 'generated'))
    env['PYTHONPATH'] = str(ROOT) + (os.pathsep + env['PYTHONPATH'] if env.get('PYTHONPATH') else '')
    return env


def _urdf_variants(tmp_path):
    """robodyn warm's URDF robots (stanford_arm's arm as URDF: friction and effort limits, a mimic joint,
    stiff damping), written here."""
    from robodyn_ros.cli.warm import _scene_runs
    return [(label, load) for label, load in _scene_runs(str(tmp_path)) if label.startswith('stanford_arm as URDF')]


SCENES = [n for n, _ in list_scenes()]


def test_every_bundled_scene_is_covered():
    assert len(SCENES) >= 17 and {'a1_stand', 'huston_human17_fall', 'unfried_free_flyer'} <= set(SCENES)


_RUNS = r'''
import contextlib, io, json, sys, traceback
from robodyn_ros.cli import main
for argv in json.loads(sys.argv[1]):
    err = io.StringIO()
    try:
        with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(err):
            status = main(argv)
    except BaseException:
        status, err = 99, io.StringIO(traceback.format_exc())
    print(json.dumps([status, err.getvalue()[-2000:]]), flush=True)
'''

VARIANTS = ['friction', 'mimic', 'damped']


@pytest.fixture(scope='module')
def recorded(tmp_path_factory):
    """``{what: (status and stderr of each run, file of the interpreted run, file of the compiled one)}`` of
    ``robodyn run WHAT --record`` for every bundled scene and the URDF variants robodyn warm runs: every
    run of a mode in one process (one start instead of one per scene), mode 'python' on an empty cache."""
    import json
    d = tmp_path_factory.mktemp('cold')
    loads = dict(_urdf_variants(d))
    runs = [(scene, scene, DURATION.get(scene, 0.2)) for scene in SCENES]
    for variant in VARIANTS:
        loads[f'stanford_arm as URDF, {variant}']()   # writes the URDF file
        runs.append((variant, str(d / f'robot_{variant}.urdf'), 0.2))
    out = {}
    for mode, cache in (('python', d / 'empty'), ('compile', None)):
        argv = [['run', target, '--duration', str(dur), '--record', str(d / f'{mode}-{k}.mcap'), '--overwrite']
                for k, (_, target, dur) in enumerate(runs)]
        # the generic kernels (backend numba) in both: under auto, an arm that integrated 0.5 s (slow, when
        # interpreted) has a child compile its generated code, which a long process then takes up (the same
        # bits, test_generated.py; but not the interpreted run this compares)
        env = dict(_env(mode, cache), ROBODYN_BACKEND='numba')
        r = subprocess.run([PY, '-c', _RUNS, json.dumps(argv)], env=env, capture_output=True, text=True,
                           timeout=3600)
        assert r.returncode == 0, r.stderr[-3000:]
        for k, ((what, _, _), line) in enumerate(zip(runs, r.stdout.strip().splitlines()[-len(runs):])):
            out.setdefault(what, []).append((*json.loads(line), d / f'{mode}-{k}.mcap'))
    assert not (d / 'empty').exists() or not list((d / 'empty').rglob('*.nbc'))   # nothing compiled
    return out


@pytest.mark.processes
@pytest.mark.parametrize('scene', SCENES)
def test_interpreted_kernels_record_the_compiled_bytes(recorded, scene):
    """robodyn run SCENE --record, once with every kernel interpreted (an empty cache, nothing compiled) and
    once on the compiled kernels: the same file."""
    (sa, ea, pa), (sb, eb, pb) = recorded[scene]
    assert sa == 0 and sb == 0, ea + eb
    a, b = pa.read_bytes(), pb.read_bytes()
    assert len(a) > 1000 and a == b


@pytest.mark.processes
@pytest.mark.parametrize('variant', VARIANTS)
def test_interpreted_urdf_robots_record_the_compiled_bytes(recorded, variant):
    """The URDF paths robodyn warm covers (Coulomb friction and effort limits, the coupled dynamics of a
    mimic joint, rosenbrock2 on stiff damping), interpreted and compiled: the same file."""
    (sa, ea, pa), (sb, eb, pb) = recorded[variant]
    assert sa == 0 and sb == 0, ea + eb
    a, b = pa.read_bytes(), pb.read_bytes()
    assert len(a) > 1000 and a == b


#: a process whose arm loops are not compiled yet while the kernels they call are (the package's cache, warm): the loops
#: run as Python calling their callees' machine code (jit._Hybrid); no compiler child
_MIXED = r'''
from robodyn_ros.kernels import jit
LOOPS = {'run_arm_periods', 'arm_steps', 'arm_controlled_steps', 'arm_rosenbrock_step', 'arm_rhs'}
real = jit.load_cached
jit.load_cached = lambda d, sig, key=None, poll=True: None if d.py_func.__name__ in LOOPS else real(d, sig, key, poll)
class Child:
    generation = 0
    def request(self, what, first=False, spent=0.0): pass
    def spend(self, n, seconds): pass
    def poll(self): pass
    def recent_generation(self): return 0
    def wait(self): pass
jit.COMPILER = Child()
''' + _RUNS + r'''
print(json.dumps(sorted({d.py_func.__name__ for d, _ in jit._SIGS.values()} & LOOPS)))
print(json.dumps(len(jit._ENTRIES)))
'''
MIXED = ['a1_stand', 'stanford_arm', 'huston_human17', 'solo12_drop', 'xarm7_trajectory']


@pytest.mark.processes
def test_interpreted_loops_calling_compiled_kernels_record_the_compiled_bytes(recorded, tmp_path):
    """The arm loops interpreted while the kernels they call are compiled (a first run once the compiler child has
    done the loop's pieces): each call goes to machine code or to Python, and the files are the compiled run's, for a
    legged robot on the ground, an RK4 arm, the 17-body human with spherical stops, a falling quadruped and a servoed
    arm with sensors."""
    import json
    argv = [['run', scene, '--duration', str(DURATION.get(scene, 0.2)), '--record', str(tmp_path / f'{scene}.mcap')]
            for scene in MIXED]
    env = dict(_env('interpret', None), ROBODYN_BACKEND='numba')
    r = subprocess.run([PY, '-c', _MIXED, json.dumps(argv)], env=env, capture_output=True, text=True, timeout=1800)
    assert r.returncode == 0, r.stderr[-3000:]
    *runs, loops, entries = [json.loads(line) for line in r.stdout.strip().splitlines()[-len(MIXED) - 2:]]
    assert set(loops) >= {'run_arm_periods'}   # the loops were interpreted
    assert entries >= 10                       # and called machine code
    for scene, (status, err) in zip(MIXED, runs):
        assert status == 0, err
        assert (tmp_path / f'{scene}.mcap').read_bytes() == recorded[scene][1][2].read_bytes(), scene


_COLD_THEN_WAIT = r'''
import sys
import types
from robodyn_ros.kernels import jit
from robodyn_ros.cli import main
status = main(sys.argv[1:])
print('requested', len(jit.COMPILER.sent))
jit.COMPILER.wait()   # the child's compile done before the next process looks
sys.exit(status)
'''

_LOADS = r'''
import sys
import types
from robodyn_ros.kernels import jit, cache
from robodyn_ros.cli import main
status = main(sys.argv[1:])
print('requested', len(jit.COMPILER.sent), 'compiled', len(cache.compiled_here()))
sys.exit(status)
'''


@pytest.mark.processes
def test_a_cold_run_has_a_child_compile_what_the_next_run_loads_and_new_robots_load_it_too(tmp_path):
    """On an empty cache robodyn run interprets and asks a child for the machine code; once the child is done,
    the same run in a new process neither interprets nor compiles anything and records the same bytes, and a
    new process running two robots the cache never saw (other sizes, joint types, fixed links) compiles
    nothing either: a model is packed into arrays of fixed types, so its kernels are every robot's."""
    import json

    from robodyn_ros.scene import load_scene
    from robodyn_ros.urdf import example_robot_data_dir
    erd = example_robot_data_dir()
    assert erd is not None, 'example-robot-data (a test dependency) is not installed'
    first = tmp_path / 'stanford_arm.urdf'
    first.write_text(load_scene('stanford_arm').system.urdf())
    args = ['run', str(first), '--duration', '0.2', '--record']
    env = _env('interpret', tmp_path / 'cache')
    env.pop('ROBODYN_COLD_START')   # robodyn run sets 'interpret' itself
    env['ROBODYN_COMPILE_LOG'] = str(tmp_path / 'compile.log')
    a = subprocess.run([PY, '-c', _COLD_THEN_WAIT, *args, str(tmp_path / 'a.mcap')], env=env, capture_output=True,
                       text=True, timeout=1800)
    assert a.returncode == 0, a.stderr[-2000:]
    requested = int(a.stdout.split('requested')[1].split()[0])
    assert requested >= 5
    log = (tmp_path / 'compile.log').read_text().splitlines()   # ROBODYN_COMPILE_LOG: a line per request
    assert len(log) == requested and all(' done (' in line for line in log), log
    env.pop('ROBODYN_COMPILE_LOG')
    b = subprocess.run([PY, '-c', _LOADS, *args, str(tmp_path / 'b.mcap')], env=env, capture_output=True,
                       text=True, timeout=600)
    assert b.returncode == 0, b.stderr[-2000:]
    assert 'requested 0 compiled 0' in b.stdout, b.stdout
    assert (tmp_path / 'a.mcap').read_bytes() == (tmp_path / 'b.mcap').read_bytes()
    others = [['run', str(next(erd.rglob(f))), '--duration', '0.05'] for f in ('go2.urdf', 'ur5_robot.urdf')]
    env.update(ROBODYN_COLD_START='compile',     # a miss would compile here (interpreted, it would hide)
               ROBODYN_INTERPRET_BUDGET='0')     # (and runs this short would not load numba: test_deferred_numba)
    c = subprocess.run([PY, '-c', _COMPILED, json.dumps(others)], env=env, capture_output=True, text=True,
                       timeout=600)
    assert c.returncode == 0, c.stderr[-3000:]
    compiled, loaded = json.loads(c.stdout.strip().splitlines()[-1])
    assert compiled == [] and len(loaded) >= 3, (compiled, loaded)


_COMPILED = ('import io, contextlib, json, sys\nfrom robodyn_ros.cli import main\n'
             'for argv in json.loads(sys.argv[1]):\n'
             '    with contextlib.redirect_stdout(io.StringIO()):\n'
             '        assert main(argv) == 0, argv\n'
             'from robodyn_ros.kernels.cache import compiled_here, loaded_here\n'
             'print(json.dumps([compiled_here(), loaded_here()]))\n')


def test_where_python_raises_the_call_is_compiled_and_gives_the_compiled_result(monkeypatch):
    """math.cos(inf) raises in Python and is nan in compiled code: an interpreted call on such a state puts
    its arrays back, runs compiled and returns the compiled result (nan where the compiled kernel has nan)."""
    from robodyn_ros.kernels import tree
    from robodyn_ros.scene import load_scene
    model = load_scene('betancur_pendulum').system.model
    mi, mf = kernels.pack_model(model, merge=True)
    q = np.full(model.nq, np.inf)
    v = np.zeros(model.nv)
    ref = np.empty(model.nv)
    tree.aba_into(mi, mf, q, v, v, ref)          # compiled (the cache is warm)
    d = tree.aba_into
    sig = tuple(d.typeof_pyval(a) for a in (mi, mf, q, v, v, ref))
    with pytest.raises(ValueError):   # what the interpreter alone does
        jit.interpreted(d)(mi, mf, q, v, v, np.empty(model.nv))
    out = np.zeros(model.nv)
    jit.run_interpreted(d, sig, (mi, mf, q, v, v, out))
    assert np.array_equal(np.isnan(out), np.isnan(ref)) and np.isnan(out).any()


def test_interpreted_calls_reach_every_kernel_they_call_through_its_python_source_or_its_machine_code():
    """python_kernel rebinds a kernel's callees: the interpreted RNEA calls no dispatcher (a compiled callee would
    compile on a cold cache, in the foreground) but each callee's _Hybrid, whose Python is the callee's source."""
    from numba.core.dispatcher import Dispatcher
    from robodyn_ros.kernels import tree
    f = jit.python_kernel(tree.rnea_into)
    ns = f.__globals__
    assert not any(isinstance(ns[name], Dispatcher) for name in f.__code__.co_names if name in ns)
    assert isinstance(ns['rnea_ws'], jit._Hybrid) and ns['rnea_ws'].py.__code__ is tree.rnea_ws.py_func.__code__


class _Child:
    """A compiler child that compiles nothing and notes what it is asked, in order."""

    generation = 0

    def __init__(self):
        self.asked = []
        self.spent = []
        self.whats = []

    def request(self, what, first=False, spent=0.0):
        self.asked.append((what[2], first))
        self.whats.append(what)
        self.spend(len(self.whats) - 1, spent)
        return len(self.whats) - 1

    def spend(self, n, seconds):
        what = self.whats[n]
        self.spent.append((what[2], str(getattr(what[3][0], 'dtype', what[3][0])), seconds))

    def poll(self):
        pass

    def recent_generation(self):
        return self.generation


def _pendulum_args():
    from robodyn_ros.scene import load_scene
    model = load_scene('betancur_pendulum').system.model
    mi, mf = kernels.pack_model(model, merge=True)
    rng = np.random.default_rng(5)
    return mi, mf, rng.normal(size=model.nq), rng.normal(size=model.nv), rng.normal(size=model.nv)


def _spied(f, name):
    """The interpreted kernel f with its callee ``name``'s Python source counting its calls (the count: a list)."""
    hybrid = f.__globals__[name]
    calls = []
    py = hybrid.py
    hybrid.py = lambda *a: calls.append(1) or py(*a)
    return calls


def test_an_interpreted_kernel_calls_the_machine_code_of_its_callees_where_there_is_some(monkeypatch):
    """Mode 'interpret': the interpreted ABA calls aba_ws's machine code (in the package's cache: warm) instead of its
    Python, and gets the compiled kernel's bits; mode 'python' runs the Python source."""
    from robodyn_ros.kernels import tree
    mi, mf, q, v, tau = _pendulum_args()
    ref = np.empty(v.size)
    tree.aba_into(mi, mf, q, v, tau, ref)   # compiled
    monkeypatch.setattr(jit, 'COMPILER', _Child())
    for mode, python_calls in (('interpret', 0), ('python', 1)):
        monkeypatch.setattr(jit, 'MODE', mode)
        f = jit.python_kernel(tree.aba_into)
        calls = _spied(f, 'aba_ws')
        out = np.empty(v.size)
        f(mi, mf, q, v, tau, out)
        assert len(calls) == python_calls, mode
        assert np.array_equal(out, ref)
    assert jit.COMPILER.asked == []   # nothing missing, nothing asked


def test_machine_code_is_not_given_python_only_dynamics_tokens(monkeypatch):
    """A callee whose dynamics address is a Python-only token (a negative int, treefn.GENERIC_TOKENS) runs as Python:
    machine code would call it; with the generic cfunc's address it runs as machine code. Both give aba_into's bits."""
    from robodyn_ros.kernels import tree, treefn
    mi, mf, q, v, tau = _pendulum_args()
    ref = np.empty(v.size)
    tree.aba_into(mi, mf, q, v, tau, ref)
    treefn.call_fd(treefn.generic_addresses()[0], mi, mf, q, v, tau, np.empty(v.size))   # its machine code in memory
    monkeypatch.setattr(jit, 'COMPILER', _Child())
    monkeypatch.setattr(jit, 'MODE', 'interpret')
    calls = []
    h = jit._Hybrid(treefn.call_fd, lambda *a: calls.append(1) or jit.python_kernel(treefn.call_fd)(*a))
    assert h.addresses == (0,)
    for fd, python_calls in ((treefn.GENERIC_TOKENS[0], 1), (treefn.generic_addresses()[0], 1)):   # (calls so far)
        out = np.empty(v.size)
        h(fd, mi, mf, q, v, tau, out)
        assert len(calls) == python_calls and np.array_equal(out, ref)


def test_a_callee_once_found_goes_through_numbas_dispatcher_and_other_types_still_run_as_python(monkeypatch):
    """Once a _Hybrid has found its kernel's machine code, numba's dispatcher types each call (in C); arguments of
    types with no machine code in memory or the cache do not compile or interpret through it (_Miss) but run the
    Python source and ask the child, marked first, as before the kernel was found."""
    from robodyn_ros.kernels import records
    records._put(np.zeros(8, dtype=np.uint8), 0, 1, 1)   # machine code for uint8 buffers in memory
    monkeypatch.setattr(jit, 'COMPILER', _Child())
    monkeypatch.setattr(jit, 'MODE', 'interpret')
    monkeypatch.setattr(jit, 'SMALL_CALL', 0.0)   # (else a call this short stays Python)
    monkeypatch.setattr(jit, 'load_cached', lambda d, sig, key=None, poll=True:
                        d.overloads[sig].entry_point if sig in d.overloads else None)
    monkeypatch.setattr(jit, '_ENTRIES', {})
    python = []
    h = jit._Hybrid(records._put, lambda *a: python.append(a[0].dtype) or records._put.py_func(*a))
    for k in range(3):
        b = np.zeros(4, dtype=np.uint8)
        h(b, 1, 0x0A0B, 2)
        assert b.tolist() == [0, 0x0B, 0x0A, 0] and python == [] and h.found
    for k in range(2):
        b = np.zeros(4, dtype=np.int64)   # no machine code for int64 buffers
        h(b, 1, 0x0A0B, 2)
        assert b.tolist() == [0, 0x0B, 0x0A, 0] and python == [np.dtype(np.int64)] * (k + 1)
    assert not jit._IN_HYBRID.on
    assert jit.COMPILER.asked == [('_put', True)] * 2
    assert np.dtype(np.int64) not in {s[0].dtype for s in records._put.overloads}   # nothing compiled here


def test_callees_ask_for_machine_code_after_their_call_and_before_their_callers(monkeypatch):
    """With nothing compiled (every lookup misses), an interpreted ABA asks the child for aba_ws after running it,
    marked first (an interpreted kernel's callee), and then for aba_into, unmarked (a call from Python); a quiet
    probe asks for nothing; a call from Python faster than SMALL_CALL asks only at its 100th."""
    from robodyn_ros.kernels import tree
    mi, mf, q, v, tau = _pendulum_args()
    monkeypatch.setattr(jit, 'COMPILER', _Child())
    monkeypatch.setattr(jit, 'MODE', 'interpret')
    monkeypatch.setattr(jit, 'load_cached', lambda d, sig, key=None, poll=True: None)
    monkeypatch.setattr(jit, '_ENTRIES', {})
    monkeypatch.setattr(jit, '_SMALL', {})
    monkeypatch.setattr(jit, 'SMALL_CALL', 0.0)   # every call counts as slow here
    monkeypatch.setattr(tree.aba_into, '_robodyn_python', None, raising=False)   # a fresh interpreted kernel
    sig = tuple(tree.aba_into.typeof_pyval(a) for a in (mi, mf, q, v, tau, np.empty(v.size)))
    with jit.quiet():
        jit._interpret_then_request(tree.aba_into, sig, (mi, mf, q, v, tau, np.empty(v.size)))
    assert jit.COMPILER.asked == []
    monkeypatch.setattr(tree.aba_into, '_robodyn_python', None, raising=False)
    jit._interpret_then_request(tree.aba_into, sig, (mi, mf, q, v, tau, np.empty(v.size)))
    asked = jit.COMPILER.asked
    assert ('aba_ws', True) in asked and asked[-1] == ('aba_into', False)
    assert asked.index(('aba_ws', True)) < len(asked) - 1
    monkeypatch.setattr(jit, 'SMALL_CALL', 1e9)   # now every call is short
    jit.COMPILER.asked.clear()
    for k in range(100):
        jit.request_after(tree.aba_into, sig, 0.0)
        assert len(jit.COMPILER.asked) == (1 if k == 99 else 0)


def test_the_child_takes_requests_marked_first_before_the_others_and_every_request_once():
    """The compiler child's queue: the requests marked ``!`` first, each kind in the order it came; and its reader
    yields every line of its input once, then ends."""
    import io
    q = jit._Requests()
    for line in (b'a\n', b'!b\n', b'c\n', b'!d\n'):
        q.add(line)
    assert [q.take() for _ in range(5)] == [b'!b\n', b'!d\n', b'a\n', b'c\n', None]
    lines = [b'%d\n' % k if k % 3 else b'!%d\n' % k for k in range(50)]
    assert sorted(jit._requests(io.BytesIO(b''.join(lines)))) == sorted(lines)


def test_the_child_takes_first_the_request_that_saves_most_interpreted_time_per_compile_cost():
    """Among requests marked first, the child takes the one with the largest interpreted time so far (the parent's
    ``?`` lines) over its compile cost; requests with no time, in the order they came; those not marked first after
    them, in the order they came, whatever their time. The times sent by _Compiler's polls are the sums of what
    spend was given, keyed by the lines the child was sent."""
    import base64
    import pickle
    q = jit._Requests(cost={b'a': 1.0, b'b': 10.0, b'c': 1.0, b'd': 2.0, b'e': 1.0}.__getitem__)
    for line in (b'!a\n', b'!b\n', b'e\n', b'!c\n', b'!d\n'):   # numbered 0 to 4 as they come
        q.add(line)
    q.add(b'?' + base64.b64encode(pickle.dumps({1: 5.0, 3: 0.8, 4: 1.0, 2: 9.0})) + b'\n')
    # gains: a 0 (none), b 0.5, c 0.8, d 0.5 (b came first), e not marked first; by time alone b, d, c
    assert [q.take() for _ in range(6)] == [b'!c\n', b'!b\n', b'!d\n', b'!a\n', b'e\n', None]
    q = jit._Requests()   # no cost: the time alone
    for line in (b'!a\n', b'!b\n'):
        q.add(line)
    q.add(b'?' + base64.b64encode(pickle.dumps({0: 1.0, 1: 2.0})) + b'\n')
    assert q.take() == b'!b\n'

    class Stdin:
        def __init__(self):
            self.lines = []

        def write(self, b):
            self.lines.append(b)

        def flush(self):
            pass
    c = jit._Compiler()
    c.proc = type('P', (), {'stdin': Stdin(), 'stdout': None})()
    for name in ('x', 'y'):
        c.request(('kernel', 'm', name, ()), first=True, spent=0.25)
    c.spend(0, 1.0)
    c.spend(None, 7.0)   # (a request not sent)
    c._tell()
    c._tell()   # (at most every TELL_EVERY s, and only when the time grew)
    sent = c.proc.stdin.lines
    assert len(sent) == 3 and sent[0].startswith(b'!') and sent[2].startswith(b'?'), sent
    q = jit._Requests()
    for line in sent:
        q.add(line)
    assert q.spent == {0: 1.25, 1: 0.25}
    assert q.take() == sent[0]


def test_an_interpreted_callee_counts_its_own_time_beyond_its_interpreted_callees(monkeypatch):
    """A _Hybrid running Python times its call and gives the child the time beyond its timed callees' (a clock that
    advances only where the test says): an outer call of 1 + inner 2 + 0.5 s spends 1.5 s, the inner 2 s; the first
    call of each asks with its time, the later ones (no lookup) add theirs to that request."""
    import numba
    jit.load_numba()

    def inner_k(b):
        return b

    def outer_k(b):
        return b
    inner_k, outer_k = numba.njit(cache=False)(inner_k), numba.njit(cache=False)(outer_k)   # never compiled
    clock = [0.0]
    monkeypatch.setattr(jit, 'time', type('T', (), {'perf_counter': staticmethod(lambda: clock[0]),
                                                     'monotonic': staticmethod(lambda: clock[0])}))
    monkeypatch.setattr(jit, 'COMPILER', _Child())
    monkeypatch.setattr(jit, 'MODE', 'interpret')
    monkeypatch.setattr(jit, 'load_cached', lambda d, sig, key=None, poll=True: None)
    monkeypatch.setattr(jit, '_ENTRIES', {})

    def inner_py(*a):
        clock[0] += 2.0

    def outer_py(*a):
        clock[0] += 1.0
        inner(np.zeros(4, dtype=np.int64))
        clock[0] += 0.5
    inner = jit._Hybrid(inner_k, inner_py)
    outer = jit._Hybrid(outer_k, outer_py)
    for _ in range(3):
        outer(np.zeros(4, dtype=np.uint8))
    assert jit.COMPILER.asked == [('inner_k', True), ('outer_k', True)]   # each once
    assert jit.COMPILER.spent == [('inner_k', 'int64', 2.0), ('outer_k', 'uint8', 1.5)] * 3
    assert jit._INNER.times == []
    fast = jit._Hybrid(inner_k, lambda *a: None)   # shorter than SMALL_CALL: neither asks nor spends
    fast(np.zeros(4, dtype=np.uint8))
    assert len(jit.COMPILER.spent) == 6 and fast.small == jit.SMALL_CALLS


def test_a_request_costs_its_code_and_that_of_the_callees_it_compiles_with_it():
    """The child's compile cost of a kernel: the fixed cost, its bytecode, and that of each kernel it reaches with no
    machine code in the process (numba compiles those with it); once the callee has machine code, only its own;
    once it has its own for the signature asked, the fixed cost; 'call' requests the fixed cost."""
    import base64
    import pickle

    import numba
    jit.load_numba()
    leaf = numba.njit(cache=False)(lambda x: x + 1.0)
    ns = {'leaf': leaf}
    exec('def caller(x):\n    return leaf(x) * 2.0\n', ns)
    caller = numba.njit(cache=False)(ns['caller'])
    mod = types.ModuleType('_cost_probe')
    mod.caller, mod.leaf = caller, leaf
    sys.modules['_cost_probe'] = mod
    try:
        sig = (numba.float64,)
        size = {f: len(f.py_func.__code__.co_code) for f in (leaf, caller)}
        assert jit._code_size(('kernel', '_cost_probe', 'caller', sig)) == \
            jit.COMPILE_OVERHEAD + size[caller] + size[leaf]
        line = base64.b64encode(pickle.dumps(('kernel', '_cost_probe', 'caller', sig)))   # the child's form
        assert jit._line_cost(line) == jit.COMPILE_OVERHEAD + size[caller] + size[leaf]
        assert jit._line_cost(b'not base64 at all!') == jit.COMPILE_OVERHEAD
        leaf(1.0)
        assert jit._code_size(('kernel', '_cost_probe', 'caller', sig)) == jit.COMPILE_OVERHEAD + size[caller]
        assert jit._code_size(('kernel', '_cost_probe', 'leaf', sig)) == jit.COMPILE_OVERHEAD
        assert caller(1.0) == 4.0
        assert jit._code_size(('kernel', '_cost_probe', 'caller', sig)) == jit.COMPILE_OVERHEAD
        assert jit._code_size(('call', '_cost_probe', 'caller')) == jit.COMPILE_OVERHEAD
        assert jit._code_size(('kernel', '_no_such_module', 'f', sig)) == jit.COMPILE_OVERHEAD
    finally:
        del sys.modules['_cost_probe']


def _kinds_of_arguments(rng):
    """Arguments of many numba types: arrays of several dtypes and dimensions, C, F and strided, read-only and
    misaligned ones, Python and numpy scalars (ints near the int64 and uint64 limits), None, nested tuples."""
    base = [np.zeros(3), np.zeros((2, 3)), np.zeros((2, 3), order='F'), np.zeros((3, 4))[:, ::2], np.zeros(4)[::2],
            np.zeros(3, dtype=np.int64), np.zeros(3, dtype=np.int32), np.zeros(2, dtype=bool), np.zeros(5, np.uint8),
            np.zeros((2, 2, 2)), np.zeros(()), np.zeros((1, 1)), np.zeros((1, 3)), np.zeros((3, 1), order='F')]
    ro = np.zeros(3)
    ro.flags.writeable = False
    odd = np.frombuffer(bytes(25), dtype=np.uint8)[1:].view(np.float64)   # 8-byte floats at an odd address
    scalars = [0, -1, 2 ** 63 - 1, 2 ** 63, 2 ** 64 - 1, -2 ** 63, 1.5, True, False, None, np.float64(1),
               np.int64(1), np.int32(1), np.bool_(True), np.float32(1)]
    pool = base + [ro, odd] + scalars
    out = []
    for _ in range(300):
        n = int(rng.integers(1, 4))
        args = [pool[int(i)] for i in rng.integers(0, len(pool), n)]
        if rng.random() < 0.3:
            args.append(tuple(pool[int(i)] for i in rng.integers(0, len(pool), int(rng.integers(0, 3)))))
        out.append(tuple(args))
    return out + [(a,) for a in pool]


def test_the_cheap_key_of_argument_types_tells_apart_what_numbas_typeof_tells_apart():
    """jit._types_key stands in for numba's typeof of each argument on the interpreted path: arguments with
    equal keys have equal numba signatures (checked against typeof on 300+ seeded argument lists), and the
    key tells the layouts, dtypes, read-only and misaligned arrays and the int ranges apart."""
    from robodyn_ros.kernels import tree
    d = tree.aba_into
    seen = {}
    lists = _kinds_of_arguments(np.random.default_rng(7))
    for args in lists:
        key = jit._types_key(args)
        assert key is not None
        sig = tuple(d.typeof_pyval(a) for a in args)
        assert seen.setdefault(key, sig) == sig, (args, key, seen[key], sig)
    assert len(seen) > 100
    assert jit._types_key(([1],)) is None and jit._types_key(('a',)) is None   # typed by numba each call


def test_an_interpreted_kernel_types_its_arguments_once(monkeypatch):
    """On a cold cache (mode 'python' here) a kernel called again with the same kinds of arguments is not typed
    by numba again, and still gives the compiled kernel's result; other kinds of arguments are typed anew."""
    from robodyn_ros.kernels import tree
    from robodyn_ros.scene import load_scene
    model = load_scene('betancur_pendulum').system.model
    mi, mf = kernels.pack_model(model, merge=True)
    rng = np.random.default_rng(3)
    q, v, tau = (rng.normal(size=model.nq), rng.normal(size=model.nv), rng.normal(size=model.nv))
    ref = np.empty(model.nv)
    tree.aba_into(mi, mf, q, v, tau, ref)   # compiled
    typed = []
    real = type(tree.aba_into).typeof_pyval
    monkeypatch.setattr(type(tree.aba_into), 'typeof_pyval', lambda self, a: typed.append(a) or real(self, a))
    monkeypatch.setattr(jit, 'MODE', 'python')
    fresh = jit.njit(cache=False)(tree.aba_into.py_func)   # no machine code in memory: every call misses
    outs = []
    for _ in range(3):
        out = np.empty(model.nv)
        fresh(mi, mf, q, v, tau, out)
        outs.append(out)
    assert len(typed) == 6   # the six arguments, typed at the first call only
    assert all(np.array_equal(o, ref) for o in outs)
    fresh(mi, mf, q, v, tau, np.empty((model.nv, 2))[:, 0])   # a strided out: another signature
    assert len(typed) >= 12   # its six typed anew (numba's own dispatch types a strided array once more)


def test_a_kernel_asked_for_again_is_typed_once_and_looked_up_once_per_compiler_generation(monkeypatch):
    """The interpreted loop asks for its compiled kernel at every period (``jit.request_compiled``, about 1000
    times in xarm7_trajectory's first 10 s): the arguments are typed by numba at the first call only, and a
    signature the cache lacks is looked up again only once the compiler child has finished something."""
    from robodyn_ros.kernels import tree
    from robodyn_ros.scene import load_scene
    model = load_scene('betancur_pendulum').system.model
    mi, mf = kernels.pack_model(model, merge=True)
    args = (mi, mf, np.zeros(model.nq), np.zeros(model.nv), np.zeros(model.nv), np.empty(model.nv))
    fresh = jit.njit(cache=False)(tree.aba_into.py_func)   # nothing in memory, nothing in a cache
    typed, looked, asked = [], [], []
    real = type(fresh).typeof_pyval
    monkeypatch.setattr(type(fresh), 'typeof_pyval', lambda self, a: typed.append(a) or real(self, a))
    monkeypatch.setattr(type(fresh._cache), 'load_overload', lambda self, sig, ctx: looked.append(sig))
    monkeypatch.setattr(jit.COMPILER, 'request', lambda what, first=False, spent=0.0: asked.append(what))
    monkeypatch.setattr(jit, 'MODE', 'interpret')
    for _ in range(5):
        jit.request_compiled(fresh, args, 1.0)   # (after a call that took 1 s)
    assert len(typed) == len(args) and len(looked) == 1 and len(asked) == 5
    assert asked[0][:3] == ('kernel', tree.aba_into.py_func.__module__, 'aba_into')
    monkeypatch.setattr(jit.COMPILER, 'generation', jit.COMPILER.generation + 1)   # the child finished a request
    jit.request_compiled(fresh, args, 1.0)
    assert len(looked) == 2 and len(typed) == len(args)


_FIRST_REQUEST = r'''
import contextlib, io, json, os, sys
os.environ['_ROBODYN_DEFER_NUMBA'] = '1'   # the kernels imported as robodyn run imports them: numba not loaded
from robodyn_ros.kernels import jit
del os.environ['_ROBODYN_DEFER_NUMBA']
from robodyn_ros.cli import main
assert jit.DEFERRED and not jit.LOADED
seen = []
request = jit._Compiler._request


def first(self, what, first=False):   # was the child there before the run's first request?
    if not seen:
        seen.append(self.proc is not None)
    return request(self, what, first)


jit._Compiler._request = first
with contextlib.redirect_stdout(io.StringIO()):
    status = main(sys.argv[1:])
print(json.dumps([status, seen]))
'''


@pytest.mark.processes
def test_on_an_empty_cache_the_compiler_child_starts_before_the_first_request_and_not_on_a_cache_with_kernels(
        tmp_path):
    """A first run (``robodyn run``, which loads numba for a run this long) on an empty kernel cache starts the
    compiler child before its first interpreted call asks for anything; on a cache holding a compiled kernel
    (here one index file) the child starts at the first request, as before. Both runs request something."""
    import json

    from robodyn_ros.kernels import cache
    runs = {}
    for name in ('empty', 'with a kernel'):
        env = _env('interpret', tmp_path / name)
        env.pop('ROBODYN_COLD_START')   # robodyn run sets 'interpret' itself
        if name == 'with a kernel':
            d = Path(cache.kernel_cache_dir().replace(cache.cache_root(), str(tmp_path / name), 1))
            d.mkdir(parents=True)
            (d / 'tree.some_kernel-1.py311.nbi').write_bytes(b'')
        r = subprocess.run([PY, '-c', _FIRST_REQUEST, 'run', 'stanford_arm', '--duration', '0.3'], env=env,
                           capture_output=True, text=True, timeout=900)
        assert r.returncode == 0, r.stderr[-2000:]
        runs[name] = json.loads(r.stdout.strip().splitlines()[-1])
    assert runs == {'empty': [0, [True]], 'with a kernel': [0, [False]]}


def test_a_cache_holds_a_kernel_once_it_has_an_index_file(tmp_path):
    from robodyn_ros.kernels import cache
    assert cache.holds_no_kernel(str(tmp_path / 'missing'))
    (tmp_path / 'tree.qdot_into-1.py311.1.nbc').write_bytes(b'')   # machine code without its index: none
    assert cache.holds_no_kernel(str(tmp_path))
    (tmp_path / 'tree.qdot_into-1.py311.nbi').write_bytes(b'')
    assert not cache.holds_no_kernel(str(tmp_path))


@pytest.mark.processes
def test_a_child_given_nothing_to_compile_readies_its_compiler_and_leaves_the_cache_empty(tmp_path):
    """The child readies numba's compiler with a function of its own (jit._ready) before its first request; that
    function is cached nowhere: a child whose input ends at once exits 0 and writes no file."""
    env = _env('compile', tmp_path / 'cache')
    r = subprocess.run([PY, '-m', 'robodyn_ros.kernels.jit'], env=env, stdin=subprocess.DEVNULL,
                       capture_output=True, timeout=300)
    assert r.returncode == 0, r.stderr[-2000:]
    written = [p for p in (tmp_path / 'cache').rglob('*') if p.is_file()]
    assert written == []
