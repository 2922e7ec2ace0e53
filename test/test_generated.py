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


#: the bundled scenes whose arm takes generated code (found, then checked to be the expected ones)
ARM_SCENES = [n for n, _ in list_scenes() if _specialised(_load(n))]


def test_the_specialised_scenes_are_the_fixed_base_arms():
    """The list the recordings below run over is not empty, and the free, spherical and ground scenes are
    not in it (their trees branch on the state, or their loop takes the contact path)."""
    assert {'stanford_arm', 'betancur_pendulum', 'huston_p19_2_3', 'huston_p19_4_1',
            'xarm7_trajectory'} <= set(ARM_SCENES)   # (xarm7_trajectory: a joint servo's feed-forward)
    assert not {'huston_human17', 'a1_stand', 'unfried_free_flyer'} & set(ARM_SCENES)
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
    fd_src, bm_src, id_src = codegen.trace(model)
    ns = {'math': math}
    exec(fd_src + '\n' + bm_src + '\n' + id_src, ns)
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
    assert km.dynamics(z) == (tuple(f.address for f in km.gen), False) and len(km.gen) == 3
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
    """Free and spherical joints (their kernels compare state values), mimic joints and ground contacts:
    no generated code, the generic kernels run."""
    for name in ('huston_human17', 'unfried_air_bearing', 'a1_stand'):
        model = _load(name).system.model
        assert np.any(model.jtype == FREE) or np.any(model.jtype == SPHERICAL)
        assert codegen.trace(model) is None, name
    a1 = _load('a1_stand', 'generated').system
    assert a1.contact is not None and a1._km.gen is None
