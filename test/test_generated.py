"""A model's generated dynamics (kernels.codegen) against the generic kernels it is traced from: the same
bits, so a run may change from one to the other and its recording does not change by a byte.

The generic kernels themselves are checked against Pinocchio, closed forms and the numpy reference
elsewhere (test_kernels, test_pinocchio); here the claim is equality of arithmetic: every value the
generated code returns is the generic one, or both are zeros (codegen's docstring: a folded zero can
only change the sign of a zero), and recordings of the same settings on backends numba (generic only),
generated (the model's own code from the first step) and auto (the generic kernels, then the model's own
code from a period boundary on) are the same files.
"""
from __future__ import annotations

import math
import os
import shutil
import warnings
import zlib

import numpy as np
import pytest

from robodyn_ros import kernels
from robodyn_ros.kernels import codegen, jit, tree, treefn
from robodyn_ros.model import FREE, SPHERICAL
from robodyn_ros.recording.run_sink import HEADLESS_BATCH, NODE_CHUNK_SPAN, McapRunSink
from robodyn_ros.runs import plan_run, resolve_settings
from robodyn_ros.scene import list_scenes, load_scene
from robodyn_ros.simulation import Simulator, run_headless
from robodyn_ros.systems.arm import ArmSystem
from robodyn_ros.systems.base import backend_scope, recorded_backend
from robodyn_ros.urdf import example_robot_data_dir

#: example-robot-data robots on a fixed base (their generated code is used; mimic or floating ones are not)
ROBOTS = ('ur_description/urdf/ur5_robot.urdf', 'xarm_description/urdf/xarm7.urdf', 'z1_description/urdf/z1.urdf',
          'so_arm_description/urdf/so101.urdf', 'double_pendulum_description/urdf/double_pendulum.urdf')


def _load(source, backend='numba'):
    with backend_scope(backend), warnings.catch_warnings():
        warnings.simplefilter('ignore')
        return load_scene(source)


def _robot(path):
    return str(example_robot_data_dir() / path)


def _specialised(scene) -> bool:
    """True when the scene's system is an arm whose loop would take its generated code."""
    s = scene.system
    return type(s) is ArmSystem and s.contact is None and not s._coupled and codegen.trace(s.model) is not None


def _on_ground(scene) -> bool:
    """True when the scene's system is a tree on a ground whose contact path would take its generated code."""
    s = scene.system
    return type(s) is ArmSystem and s.contact is not None and codegen.trace(s.model, ground=True) is not None


#: the bundled scenes whose arm takes generated code (found, then checked to be the expected ones)
ARM_SCENES = [n for n, _ in list_scenes() if _specialised(_load(n))]
#: the bundled scenes of a tree on a ground whose contact path takes generated code
GROUND_SCENES = [n for n, _ in list_scenes() if _on_ground(_load(n))]


def test_the_specialised_scenes_are_the_arms_and_the_legged_robots():
    """The lists the recordings below run over are the expected ones: the fixed-base arms off a ground, the
    floating-base robots on one; not the spherical human (its kernels branch on the state) nor the free flyers
    (other systems)."""
    assert {'stanford_arm', 'betancur_pendulum', 'huston_p19_2_3', 'huston_p19_4_1',
            'xarm7_trajectory'} <= set(ARM_SCENES)   # (xarm7_trajectory: a joint servo's feed-forward)
    assert not {'huston_human17', 'a1_stand', 'unfried_free_flyer'} & set(ARM_SCENES)
    assert set(GROUND_SCENES) == {'a1_stand', 'solo12_drop'}   # (not huston_human17_fall: spherical joints)
    for p in ROBOTS:
        assert _specialised(_load(_robot(p))), p


def _same_up_to_zero_signs(x, y) -> bool:
    """Equal values, and bits that differ only where both are zeros."""
    x, y = np.asarray(x, dtype=float), np.asarray(y, dtype=float)
    if not np.array_equal(x, y):
        return False
    differ = x.view(np.int64) != y.view(np.int64)
    return bool(np.all(x[differ] == 0.0))


def _states(model, rng, n):
    """Seeded states: the zero state (where folded zeros meet), then random ones, some at rest."""
    out = [(np.zeros(model.nq), np.zeros(model.nv), np.zeros(model.nv))]
    for k in range(n):
        out.append((rng.normal(size=model.nq), rng.normal(size=model.nv) * (k % 3), rng.normal(size=model.nv) * 20))
    return out


MODELS = ['stanford_arm', 'betancur_pendulum', 'huston_p19_2_3', 'huston_p19_4_1'] + list(ROBOTS)


@pytest.mark.parametrize('name', MODELS)
def test_traced_code_is_the_generic_arithmetic(name):
    """Run as Python, the generated fd, bm and rnea return the values of the generic Python source they are
    traced from (the kernels' own code, run by the interpreter with the same double arithmetic), bit for
    bit but for the sign of zeros; the DH residue cos(π/2) = 6.1e-17 is multiplied as the generic kernels do."""
    model = _load(name if name in ARM_SCENES else _robot(name)).system.model
    src = codegen.trace(model)
    assert set(src) == {'fd', 'bm', 'rnea'}
    fd_src = src['fd']
    ns = {'math': math}
    exec('\n'.join(src.values()), ns)
    mi, mf = kernels.pack_model(model, merge=True)
    gfd, gbm = codegen.python_kernel(treefn.generic_fd), codegen.python_kernel(treefn.generic_bm)
    gid = codegen.python_kernel(treefn.generic_id)
    nv = model.nv
    states = _states(model, np.random.default_rng(zlib.crc32(name.encode())), 12)
    assert len(states) == 13
    for q, v, tau in states:
        W = np.empty((mi.shape[0] + 1, tree.NW))
        a, b = np.empty(nv), np.empty(nv)
        gfd(mi, mf, q, v, tau, a, W)
        ns['fd'](None, None, q, v, tau, b, None)
        assert _same_up_to_zero_signs(a, b)
        out = [np.empty(nv), np.empty((nv, nv)), np.empty((nv, nv))]
        ref = [np.empty(nv), np.empty((nv, nv)), np.empty((nv, nv))]
        gbm(mi, mf, q, v, np.zeros(nv), *ref, W)
        ns['bm'](None, None, q, v, np.zeros(nv), *out, None)
        for x, y in zip(ref, out):
            assert _same_up_to_zero_signs(x, y)
        gid(mi, mf, q, v, tau, a, W)             # tau as the acceleration: RNEA(q, v, qdd)
        ns['rnea'](None, None, q, v, tau, b, None)
        assert _same_up_to_zero_signs(a, b)
    if name == 'stanford_arm':   # the residue kept, not snapped; at most one cos per revolute joint (the first
        # joint's turns only gravity, along its axis: its cos meets zeros)
        assert 'e-17' in fd_src and fd_src.count('math.cos(') == 4


def _same_or_both_nan(x, y) -> bool:
    """:func:`_same_up_to_zero_signs`, NaN (an entry neither wrote) equal to NaN."""
    x, y = np.asarray(x, dtype=float), np.asarray(y, dtype=float)
    nx, ny = np.isnan(x), np.isnan(y)
    return bool(np.array_equal(nx, ny)) and _same_up_to_zero_signs(x[~nx], y[~ny])


@pytest.mark.parametrize('name', ['a1_stand', 'solo12_drop'])
def test_traced_contact_path_is_the_generic_arithmetic(name):
    """On a ground (free root: its quaternion, its 6x6 Cholesky solve), the generated kin, fdx, bmx and rnea, run
    as Python, against the generic Python they are traced from: kin's work array entry by entry (what the
    contacts' code reads), fdx and bmx after it under seeded body forces, bit for bit but for the sign of zeros.
    Also at a state whose base inertia is not positive definite (a pivot's root is NaN, as in the generic code)."""
    model = _load(name).system.model
    src = codegen.trace(model, ground=True)
    assert set(src) == {'rnea', 'kin', 'fdx', 'bmx'}
    assert '> 0.0 else math.nan' in src['fdx']   # the Cholesky pivot's root keeps its branch
    ns = {'math': math}
    exec('\n'.join(src.values()), ns)
    mi, mf = kernels.pack_model(model, merge=True)
    g = {k: codegen.python_kernel(f) for k, f in zip(treefn.NAMES, treefn.GENERIC)}
    nb, nv = mi.shape[0], model.nv
    rng = np.random.default_rng(zlib.crc32(name.encode()))
    states = _states(model, rng, 8)
    for q, v, tau in states:
        fext = rng.normal(size=(nb, 6)) * 10.0
        fext[rng.random(nb) < 0.5] = 0.0
        Wa, Wb = np.full((nb + 1, tree.NW), np.nan), np.full((nb + 1, tree.NW), np.nan)
        g['kin'](mi, mf, q, v, Wa)
        ns['kin'](None, None, q, v, Wb)
        assert _same_or_both_nan(Wa, Wb)
        a, b = np.empty(nv), np.empty(nv)
        g['fdx'](mi, mf, q, v, tau, fext, a, Wa.copy())
        ns['fdx'](None, None, q, v, tau, fext, b, Wb.copy())
        assert _same_up_to_zero_signs(a, b)
        ref = [np.empty(nv), np.empty((nv, nv)), np.empty((nv, nv))]
        out = [np.empty(nv), np.empty((nv, nv)), np.empty((nv, nv))]
        g['bmx'](mi, mf, q, v, np.zeros(nv), fext, *ref, Wa.copy())
        ns['bmx'](None, None, q, v, np.zeros(nv), fext, *out, Wb.copy())
        for x, y in zip(ref, out):
            assert _same_up_to_zero_signs(x, y)
        g['rnea'](mi, mf, q, v, tau, a, Wa)      # tau as the acceleration: RNEA(q, v, qdd)
        ns['rnea'](None, None, q, v, tau, b, None)
        assert _same_up_to_zero_signs(a, b)


def test_a_traced_cholesky_solve_keeps_the_pivot_branch():
    """The one comparison on the state the tracer writes into the code (tree.pivot_sqrt: a pivot's root, NaN when
    it is not positive): the 6x6 solve of a free root's ABA traced on symbols and run, against the generic Python,
    on seeded positive definite matrices and on indefinite, singular and negative ones (NaN results, as there)."""
    tr = codegen.Tracer()
    Ws = np.full((2, tree.NW), codegen.UNSET, dtype=object)
    for k in range(36):
        Ws[0, tree.IA_ + k] = tr.symbol(f'W[0, {tree.IA_ + k}]')
    for k in range(6):
        Ws[0, tree.UV_ + k] = tr.symbol(f'W[0, {tree.UV_ + k}]')
    codegen._traced(tree.chol6_solve, tr)(Ws, 0, tree.IA_, 0, tree.UV_, 1, tree.S4_)
    src = '\n'.join(codegen._render(tr, 'solve', 'W, x', [(f'x[{k}]', Ws[1, tree.S4_ + k]) for k in range(6)], 'x'))
    assert src.count('> 0.0 else math.nan') == 6
    ns = {'math': math}
    exec(src, ns)
    generic = codegen.python_kernel(tree.chol6_solve)
    rng = np.random.default_rng(61)
    nans = 0
    for k in range(40):
        B = rng.normal(size=(6, 6))
        A = B @ B.T + (0.1 if k % 4 else -3.0) * np.eye(6)     # every fourth: indefinite (most of them)
        if k == 1:
            A[:, 0] = A[0, :] = 0.0                              # a zero pivot
        W = np.zeros((2, tree.NW))
        W[0, tree.IA_:tree.IA_ + 36] = A.ravel()
        W[0, tree.UV_:tree.UV_ + 6] = rng.normal(size=6)
        x = np.empty(6)
        ns['solve'](W, x)
        generic(W, 0, tree.IA_, 0, tree.UV_, 1, tree.S4_)
        ref = W[1, tree.S4_:tree.S4_ + 6]
        assert _same_or_both_nan(ref, x)
        nans += bool(np.isnan(x).any())
        if not np.isnan(x).any():
            assert np.allclose(A @ x, W[0, tree.UV_:tree.UV_ + 6], rtol=1e-8, atol=1e-8)
    assert 5 <= nans <= 15


def test_compiled_generated_code_is_the_compiled_generic_code():
    """Compiled (cfuncs behind the loop's addresses), the generated fd gives the generic one's bits (but for
    zero signs) on stanford_arm; both are the reference ABA to round-off."""
    from robodyn_ros import dynamics as dyn
    model = _load('stanford_arm').system.model
    km = kernels.CompiledModel(model, specialize=True)
    assert km.gen is not None
    generic = treefn.generic_pointers()[0].address
    states = _states(model, np.random.default_rng(7), 20)
    for q, v, tau in states:
        a, b = np.empty(model.nv), np.empty(model.nv)
        treefn.call_fd(generic, km.mi_r, km.mf_r, q, v, tau, a)
        treefn.call_fd(km.gen[0].address, km.mi_r, km.mf_r, q, v, tau, b)
        assert _same_up_to_zero_signs(a, b)
        assert np.allclose(b, dyn.aba(model, q, v, tau), rtol=1e-10, atol=1e-10)


def _record(tmp_path, source, backend, tag, duration, batch=HEADLESS_BATCH, chunk_span=None):
    """One recorded headless run (the recorder of ``robodyn run``, or with batch 0 the node's); returns the
    file's bytes and the system."""
    scene = _load(source, backend)
    plan, st = plan_run(resolve_settings(scene, duration=duration), scene.system, scene.y0)
    sim = Simulator(scene.system, scene.y0, plan=plan)
    path = tmp_path / f'{tag}-{backend}.mcap'
    sink = McapRunSink(str(path), scene, {**st, 'backend': recorded_backend(backend)}, batch=batch, chunk_span=chunk_span,
                       diagnostics_period=0.1)
    try:
        run_headless(sim, duration, st['rate'], scene.script, [sink])
    finally:
        sink.close()
    return path.read_bytes(), scene.system


@pytest.mark.parametrize('source', ARM_SCENES + [f'erd:{p}' for p in ROBOTS])
def test_recordings_are_the_same_bytes_on_generic_and_generated_kernels(tmp_path, source):
    """Every bundled fixed-base arm scene and five example-robot-data robots (rk4 and, xarm7, rosenbrock2:
    the bias/mass pass too), 1 s recorded through the block path: the same file on numba and generated."""
    src = _robot(source[4:]) if source.startswith('erd:') else source
    tag = os.path.basename(src).replace('.urdf', '')
    a, sa = _record(tmp_path, src, 'numba', tag, 1.0)
    b, sb = _record(tmp_path, src, 'generated', tag, 1.0)
    assert sa._km.gen is None and sb._km.gen is not None   # each ran what it says
    assert len(a) > 10000 and a == b


@pytest.mark.parametrize('source,duration', [('a1_stand', 1.0), ('solo12_drop', 0.3)])
def test_ground_recordings_are_the_same_bytes_on_generic_and_generated_kernels(tmp_path, source, duration):
    """The legged robots on their ground (rosenbrock2: the contact path's kin, fdx and bmx between the contacts'
    code; solo12_drop under error control), recorded through the block path: the same file on numba and generated,
    the contact wrenches and markers included."""
    a, sa = _record(tmp_path, source, 'numba', source, duration)
    b, sb = _record(tmp_path, source, 'generated', source, duration)
    assert sa._km.gen is None and sb._km.gen is not None and sb._km.con is not None
    assert sb._km.dynamics(np.ones(3))[0][3:] == tuple(f.address for f in sb._km.gen[3:])   # its own kin, fdx, bmx
    assert len(a) > 10000 and a == b


@pytest.mark.parametrize('source', ['stanford_arm', 'erd:xarm_description/urdf/xarm7.urdf'])
def test_per_period_recordings_are_the_same_bytes(tmp_path, source):
    """The node's way (period by period, each message as it comes): the same file on numba and generated."""
    src = _robot(source[4:]) if source.startswith('erd:') else source
    a, _ = _record(tmp_path, src, 'numba', 'pp', 0.5, batch=0, chunk_span=NODE_CHUNK_SPAN)
    b, sb = _record(tmp_path, src, 'generated', 'pp', 0.5, batch=0, chunk_span=NODE_CHUNK_SPAN)
    assert sb._km.gen is not None and len(a) > 5000 and a == b


def test_auto_takes_up_the_generated_code_at_a_period_boundary(tmp_path, monkeypatch):
    """Backend auto: the run starts on the generic kernels, a child process compiles the model's code
    (asked for at once here), and the run takes it up at its third loop call: the recording is the numba
    run's file, and the code did change mid-run."""
    gen_dir = tmp_path / 'generated'
    monkeypatch.setattr(codegen, 'GENERATED_DIR', str(gen_dir))   # an empty cache: the child really compiles
    monkeypatch.setattr(kernels, 'GENERATE_AFTER', 0.0)
    calls, used = [], []
    poll = kernels.CompiledModel.poll_generated

    def polling(self):
        calls.append(self.gen is not None)
        if len(calls) == 3 and self._requested is not None:
            jit.COMPILER.wait()   # the child's compile done before this call looks
        poll(self)
        used.append(self.gen is not None)
    monkeypatch.setattr(kernels.CompiledModel, 'poll_generated', polling)
    a, _ = _record(tmp_path, 'betancur_pendulum', 'numba', 'auto', 2.0)
    calls.clear()
    used.clear()
    b, sb = _record(tmp_path, 'betancur_pendulum', 'auto', 'auto', 2.0)
    assert used[:2] == [False, False] and used[2] and all(used[2:])   # generic, then generated from call 3 on
    assert sb._km.gen is not None and sb._km._requested is not None
    assert a == b
    shutil.rmtree(gen_dir, ignore_errors=True)


def test_auto_takes_up_code_an_earlier_run_compiled_at_its_first_call(tmp_path, monkeypatch):
    """Backend auto, the model's code compiled by an earlier run (here the generated one): the run takes it
    up at its first loop call, without integrating GENERATE_AFTER seconds first, and records the numba file."""
    gen_dir = tmp_path / 'generated'
    monkeypatch.setattr(codegen, 'GENERATED_DIR', str(gen_dir))
    monkeypatch.setattr(kernels, 'GENERATE_AFTER', 1e9)   # never asked for: only the first look can find it
    used = []
    poll = kernels.CompiledModel.poll_generated

    def polling(self):
        poll(self)
        used.append(self.gen is not None)
    a, _ = _record(tmp_path, 'betancur_pendulum', 'numba', 'first', 1.0)
    _record(tmp_path, 'betancur_pendulum', 'generated', 'first', 1.0)   # compiles the model's code
    monkeypatch.setattr(kernels.CompiledModel, 'poll_generated', polling)
    b, sb = _record(tmp_path, 'betancur_pendulum', 'auto', 'first', 1.0)
    assert len(used) >= 3 and all(used)   # generated from the first call on
    assert sb._km.gen is not None and a == b
    used.clear()
    shutil.rmtree(gen_dir)                # nothing compiled on disk: generic throughout (nothing asked for)
    c, sc = _record(tmp_path, 'betancur_pendulum', 'auto', 'second', 1.0)
    assert len(used) >= 3 and not any(used) and sc._km.gen is None and c == a


def test_a_negative_zero_in_the_state_keeps_the_generic_kernels():
    """x + (−0) changes −0 only: a state entry −0.0 is the one place a folded zero could change a bit, so
    the loop gets the generic addresses for such a state, the generated ones otherwise."""
    model = _load('stanford_arm').system.model
    km = kernels.CompiledModel(model, specialize=True)
    generic = tuple(f.address for f in treefn.generic_pointers())
    z = np.concatenate([np.linspace(0.1, 0.6, model.nq), np.zeros(model.nv), [0.0]])
    assert km.dynamics(z) == (tuple(f.address for f in km.gen), False) and len(km.gen) == 6
    z[model.nq + 2] = -0.0
    assert km.dynamics(z) == (generic, False)


def test_the_negative_zero_check_is_the_sign_bit_of_a_zero():
    """kernels.has_negative_zero (the loops' per-call check) against ``(z == 0) & signbit(z)`` on seeded arrays
    holding −0.0, +0.0, ±inf and NaNs of both signs, strided views and the empty state."""
    rng = np.random.default_rng(11)
    pool = np.array([-0.0, 0.0, np.inf, -np.inf, np.nan, -np.nan, 5e-324, -5e-324, 1.0, -1.0])
    for _ in range(400):
        z = rng.normal(size=int(rng.integers(0, 40)))
        z[rng.random(z.shape[0]) < 0.2] = rng.choice(pool)
        for x in (z, z[::2]):
            assert kernels.has_negative_zero(x) == bool(np.any((x == 0.0) & np.signbit(x))), x
    assert kernels.has_negative_zero(np.array([1.0, -0.0])) and not kernels.has_negative_zero(np.array([0.0, -1.0]))
    assert not kernels.has_negative_zero(np.zeros(0))


def test_trees_that_branch_on_the_state_keep_the_generic_kernels():
    """Spherical joints (their kernels compare state values): no generated code, on a ground or not, the generic
    kernels run; a free root (its one comparison, a Cholesky pivot's sign, is written into the code) is traced."""
    for name in ('huston_human17', 'huston_human17_fall'):
        model = _load(name).system.model
        assert np.any(model.jtype == SPHERICAL)
        assert codegen.trace(model) is None and codegen.trace(model, ground=True) is None, name
        assert _load(name, 'generated').system._km.gen is None
    model = _load('a1_stand').system.model
    assert np.any(model.jtype == FREE) and codegen.trace(model) is not None


def test_auto_interpreting_waits_for_the_generic_cfuncs_instead_of_compiling_them(monkeypatch):
    """Backend auto in an interpreting run (a cold cache): a generated module is taken up with the generic cfuncs
    for the functions it leaves out (a tree off a ground: kin, fdx, bmx). While those are not compiled the run does
    not compile them itself (a live run would stop answering for the minute it takes): it stays on the generic
    kernels and takes the module up at a later period, once the child has them."""
    model = _load('betancur_pendulum').system.model
    codegen.specialize(model)                       # the module compiled, as an earlier run leaves it
    path = codegen.written_path(model)
    real = treefn.generic_pointers

    def missing(block=True):
        assert not block, 'the generic cfuncs compiled in the run'
        return None
    monkeypatch.setattr(treefn, 'generic_pointers', missing)
    monkeypatch.setattr(codegen, '_LOADED', {})
    monkeypatch.setattr(jit, 'MODE', 'interpret')
    assert codegen.load(path, block=False) is None
    km = kernels.CompiledModel(model, specialize='auto')
    km.poll_generated()
    assert km.gen is None and km._requested == path
    km.poll_generated()                              # the child has finished nothing since: not looked again
    assert km.gen is None
    monkeypatch.setattr(treefn, 'generic_pointers', real)
    monkeypatch.setattr(jit.COMPILER, 'generation', jit.COMPILER.generation + 1)   # the child finished a request
    monkeypatch.setattr(jit.COMPILER, 'poll', lambda: None)
    km.poll_generated()
    assert km.gen is not None and km.gen[0].address != real()[0].address


_LOAD_CHILD = r'''
import json, sys, warnings
from robodyn_ros.kernels import codegen, treefn
from robodyn_ros.scene import load_scene
from robodyn_ros.systems.base import backend_scope
with backend_scope('numba'), warnings.catch_warnings():
    warnings.simplefilter('ignore')
    scene = load_scene(sys.argv[1])
path = codegen.module_path(scene.system.model)
got = codegen.load(path)
mine = [i for i, _ in codegen._functions(codegen._import(path))]
print(json.dumps({'hits': [got[i].cache_hits for i in mine], 'waited': len(codegen.WAITED)}))
'''


def _lock_waiters(lock_path) -> int:
    """How many flock requests wait on the file at lock_path (Linux's /proc/locks: blocked ones are marked ``->``)."""
    ino = f':{os.stat(lock_path).st_ino} '
    with open('/proc/locks') as f:
        return sum('->' in line and ino in line for line in f)


@pytest.mark.processes
def test_processes_that_start_the_same_robot_at_once_compile_its_code_once(tmp_path):
    """Two processes load the same model's generated code into an empty cache while a third holds its compile
    lock: both wait (the test sees both requests blocked in /proc/locks before it lets go), then one compiles
    and the other loads that machine code from numba's cache (its cfuncs' cache hits: all of them)."""
    import json
    import subprocess
    import sys
    import time
    gen_dir = tmp_path / 'generated'
    source = _robot('double_pendulum_description/urdf/double_pendulum.urdf')
    env = dict(os.environ, ROBODYN_GENERATED_DIR=str(gen_dir))
    old = codegen.GENERATED_DIR
    codegen.GENERATED_DIR = str(gen_dir)
    try:
        path = codegen.module_path(_load(source).system.model)   # the file the children compile
    finally:
        codegen.GENERATED_DIR = old
    assert path is not None and not os.path.exists(path + '.lock')
    import fcntl
    with open(path + '.lock', 'a+b') as held:
        fcntl.flock(held, fcntl.LOCK_EX)
        kids = [subprocess.Popen([sys.executable, '-c', _LOAD_CHILD, source], env=env, cwd=str(tmp_path),
                                 stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True) for _ in range(2)]
        deadline = time.monotonic() + 300
        while _lock_waiters(path + '.lock') < 2 and all(k.poll() is None for k in kids) and time.monotonic() < deadline:
            time.sleep(0.05)
        waiting = _lock_waiters(path + '.lock')
        fcntl.flock(held, fcntl.LOCK_UN)
    outs = [k.communicate(timeout=600) for k in kids]
    assert all(k.returncode == 0 for k in kids), [e[-2000:] for _, e in outs]
    assert waiting == 2, (waiting, outs)
    res = sorted((json.loads(o.strip().splitlines()[-1]) for o, _ in outs), key=lambda r: sum(r['hits']))
    assert [r['waited'] for r in res] == [1, 1]
    assert sum(res[0]['hits']) == 0 and len(res[0]['hits']) >= 2   # the first compiled every function ...
    # ... and the other loaded them
    assert all(h == 1 for h in res[1]['hits']) and len(res[1]['hits']) == len(res[0]['hits'])


def test_a_generated_module_is_compiled_to_bytecode_once_where_python_writes_no_bytecode(tmp_path, monkeypatch):
    """With ``PYTHONDONTWRITEBYTECODE`` (``sys.dont_write_bytecode``), Python compiles an imported module's source
    in every process; a generated module's bytecode is written into its ``__pycache__`` at its first import, and
    an import in a later process (here: the module dropped from ``sys.modules``) reads it: importlib compiles the
    module's source once over both imports (``SourceFileLoader.source_to_code``, counted), not twice."""
    import importlib.machinery
    import importlib.util
    import sys
    monkeypatch.setattr(sys, 'dont_write_bytecode', True)
    monkeypatch.setattr(codegen, 'GENERATED_DIR', str(tmp_path))
    path = codegen.module_path(_load(_robot('double_pendulum_description/urdf/double_pendulum.urdf')).system.model)
    name = os.path.splitext(os.path.basename(path))[0]
    monkeypatch.delitem(sys.modules, name, raising=False)
    compiled = []
    real = importlib.machinery.SourceFileLoader.source_to_code

    def counted(self, data, where, *args, **kw):
        compiled.append(where)
        return real(self, data, where, *args, **kw)
    monkeypatch.setattr(importlib.machinery.SourceFileLoader, 'source_to_code', counted)
    first = codegen._import(path)
    assert os.path.exists(importlib.util.cache_from_source(path))
    del sys.modules[name]
    second = codegen._import(path)
    assert second is not first and second.__file__ == path
    assert compiled == [path]
