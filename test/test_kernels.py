"""Compiled kernels (numba) ≡ numpy reference, to 1e-12 relative, and the fused integrator path.

The reference is :mod:`robodyn_ros.dynamics`; the compiled kernels are
:mod:`robodyn_ros.kernels`. Compared on seeded random trees (chains and branched trees,
revolute and prismatic joints, FIXED joints mid-tree, FREE root joints) and on every bundled
scene: RNEA (with and without external forces, with joint wrenches), CRBA, ABA, joint wrenches,
kinetic and potential energy, q̇ and quaternion normalisation. Then the fused fixed-step loop
(``ArmSystem.fused_advance``, used by the Simulator) against the Simulator's reference path over
0.1 s. No timings are asserted here (see ``robodyn bench speed``).
"""
from __future__ import annotations

import dataclasses
import os
import subprocess
import sys
import warnings
import zlib

import numpy as np
import pytest

from robodyn_ros import dynamics as dyn
from robodyn_ros import kernels
from robodyn_ros.model import FIXED, FREE, build_model, random_tree



def test_numba_kernels_are_available():
    """numba is a hard dependency: without it these tests fail (they never skip)."""
    import numba  # noqa: F401
    assert kernels.AVAILABLE, f'compiled kernels unavailable: {kernels.UNAVAILABLE_REASON}'

RTOL = 1e-12
N_TREES = 24


def close(x, ref, rtol=RTOL):
    """Norm-wise relative agreement: ``max|x - ref| <= rtol * max|ref|`` (exact when ref is 0)."""
    x = np.asarray(x, dtype=float)
    ref = np.asarray(ref, dtype=float)
    assert x.shape == ref.shape, (x.shape, ref.shape)
    err = np.abs(x - ref).max() if ref.size else 0.0
    scale = np.abs(ref).max() if ref.size else 0.0
    return bool(np.all(np.isfinite(x))) and err <= rtol * scale


def _variant(model, name, fixed=(), free_root=False):
    """Rebuild a random tree with some joints welded (FIXED) and/or a FREE joint at the first root."""
    specs = []
    for k, s in enumerate(model.specs):
        if s.name in fixed:
            s = dataclasses.replace(s, joint_type='fixed')
        if free_root and k == 0:
            s = dataclasses.replace(s, joint_type='free')
        specs.append(s)
    return build_model(specs, gravity=model.gravity, name=name)


def make_trees():
    """``N_TREES`` seeded models: chains/trees of 1..12 bodies, prismatic shares 0..1, tilted
    gravity, FIXED joints mid-tree, FREE roots (floating base), and combinations."""
    out = []
    fractions = (0.0, 0.3, 0.6, 1.0)
    for k in range(16):
        rng = np.random.default_rng(7000 + k)
        nb = 1 + (5 * k) % 12
        chain = k % 3 == 0
        g = (0.0, 0.0, -9.81) if k % 4 else tuple(9.81 * rng.normal(size=3) / np.sqrt(3.0))
        out.append((f'seed{7000 + k}-nb{nb}-{"chain" if chain else "tree"}',
                    random_tree(nb, rng, prismatic_fraction=fractions[k % 4], chain=chain, gravity=g)))
    for k in range(4):  # FIXED joints mid-tree (a leaf weld in the branched ones)
        rng = np.random.default_rng(7100 + k)
        m = random_tree(6 + 2 * k, rng, prismatic_fraction=0.3, chain=k % 2 == 0)
        welded = {'l2', 'l3'} if k == 0 else {'l3', m.link_names[-1]}
        out.append((f'fixed{k}', _variant(m, f'fixed{k}', fixed=welded)))
    for k in range(4):  # FREE root joint (floating base), with and without a weld
        rng = np.random.default_rng(7200 + k)
        m = random_tree(3 + 2 * k, rng, prismatic_fraction=0.3, chain=k % 2 == 1)
        out.append((f'free{k}', _variant(m, f'free{k}', fixed={'l2'} if k >= 2 else (), free_root=True)))
    assert len(out) == N_TREES
    return out


TREES = make_trees()


def random_state(model, rng):
    """Random ``(q, v, a, f_ext)`` with unit quaternions for FREE joints."""
    q = rng.uniform(-np.pi, np.pi, size=model.nq)
    for i in range(model.nb):
        if model.jtype[i] == FREE:
            s = model.q_idx[i]
            q[s:s + 3] = rng.normal(size=3)
            quat = rng.normal(size=4)
            q[s + 3:s + 7] = quat / np.linalg.norm(quat)
    return q, rng.normal(size=model.nv), rng.normal(size=model.nv), rng.normal(size=(model.nb, 6))


def test_tree_family_covers_every_joint_kind():
    kinds = set()
    for _, m in TREES:
        kinds |= set(int(j) for j in m.jtype)
    assert kinds == {0, 1, 2, 3}
    mid_fixed = [m for _, m in TREES if any(m.jtype[i] == FIXED and i in set(m.parent.tolist())
                                            for i in range(m.nb))]
    assert len(mid_fixed) >= 3
    assert sum(1 for _, m in TREES if m.jtype[0] == FREE) == 4
    assert sum(1 for _, m in TREES if np.any(m.parent[1:] != np.arange(m.nb - 1))) >= 5  # branched


def _compare_all(model, q, v, a, fe):
    """Every compiled kernel against its reference at one state; returns the failing names."""
    km = kernels.CompiledModel(model)
    bad = []
    checks = {
        'rnea': (km.rnea(q, v, a), dyn.rnea(model, q, v, a)),
        'rnea_fext': (km.rnea(q, v, a, fe), dyn.rnea(model, q, v, a, fe)),
        'rnea_wrenches': (km.rnea_wrenches(q, v, a, fe)[1], dyn.rnea_wrenches(model, q, v, a, fe)[1]),
        'crba': (km.crba(q), dyn.crba(model, q)),
        'aba': (km.aba(q, v, a), dyn.aba(model, q, v, a)),
        'aba_fext': (km.aba(q, v, a, fe), dyn.aba(model, q, v, a, fe)),
        'joint_wrenches_qdd': (km.joint_wrenches(q, v, a)[0], dyn.joint_wrenches(model, q, v, a)[0]),
        'joint_wrenches_f': (km.joint_wrenches(q, v, a)[1], dyn.joint_wrenches(model, q, v, a)[1]),
        'joint_wrenches_fext': (km.joint_wrenches(q, v, a, fe)[1], dyn.joint_wrenches(model, q, v, a, fe)[1]),
        'kinetic': (km.kinetic_energy(q, v), dyn.kinetic_energy(model, q, v)),
        'potential': (km.potential_energy(q), dyn.potential_energy(model, q)),
        'energies': (km.energies(q, v), (dyn.kinetic_energy(model, q, v), dyn.potential_energy(model, q))),
        'qdot': (km.qdot(q, v), dyn.qdot(model, q, v)),
        'normalize': (km.normalize(2.0 * q), dyn.normalize_configuration(model, 2.0 * q) if model.nq != model.nv
                      else 2.0 * q),
    }
    for name, (x, ref) in checks.items():
        if not close(x, ref):
            bad.append(name)
    return bad


@pytest.mark.parametrize('label,model', TREES, ids=[t[0] for t in TREES])
def test_compiled_equals_reference_on_random_trees(label, model):
    rng = np.random.default_rng(zlib.crc32(label.encode()))
    for _ in range(2):
        assert _compare_all(model, *random_state(model, rng)) == []


def _scene_names():
    from robodyn_ros.scene import list_scenes
    return [n for n, _ in list_scenes()]


def _load(name, backend=None):
    from robodyn_ros.scene import load_scene
    old = os.environ.get('ROBODYN_BACKEND')
    if backend:
        os.environ['ROBODYN_BACKEND'] = backend
    try:
        with warnings.catch_warnings():
            warnings.simplefilter('ignore')
            return load_scene(name)
    finally:
        if old is None:
            os.environ.pop('ROBODYN_BACKEND', None)
        else:
            os.environ['ROBODYN_BACKEND'] = old


SCENES = _scene_names()


#: scenes with spherical joints: the numpy reference has none, so test_spherical.py checks the kernels on
#: them against Pinocchio instead
SPHERICAL = ('huston_human17', 'huston_human17_fall')


def test_the_scenes_left_to_pinocchio_are_those_with_spherical_joints():
    for name in SPHERICAL:
        assert _load(name).system.model.has_spherical, name


@pytest.mark.parametrize('name', [n for n in SCENES if n not in SPHERICAL])
def test_compiled_equals_reference_on_scenes(name):
    scene = _load(name)
    model = getattr(scene.system, 'model', None)
    assert model is not None, f'{name}: no kinematic tree to compare'
    assert not model.has_spherical, f'{name} has spherical joints: list it in SPHERICAL'
    rng = np.random.default_rng(11)
    q0 = np.asarray(scene.y0[:model.nq], dtype=float).copy()
    if q0.shape == (model.nq,):  # the scene's own initial configuration, moving
        _, v, a, fe = random_state(model, rng)
        assert _compare_all(model, q0, v, a, fe) == []
    assert _compare_all(model, *random_state(model, rng)) == []


def test_bundled_scenes_are_all_there():
    for name in ('stanford_arm', 'betancur_pendulum', 'huston_p19_2_3'):
        assert name in SCENES


# ------------------------------------------------------------------------------------------
# the fused integrator path of ArmSystem/Simulator
# ------------------------------------------------------------------------------------------
def _run(system, y0, integrator, duration, rate, script, dt=1e-3):
    from robodyn_ros.simulation import Simulator, run_headless
    with warnings.catch_warnings():
        warnings.simplefilter('ignore')
        sim = Simulator(system, y0, integrator=integrator, dt=dt)
    run_headless(sim, duration, rate, script)
    return sim


#: scenes whose joints take position commands: their tree runs under a joint servo (and their URDF's friction is
#: stiff for the explicit methods at 1 ms), so test_servo.py holds the fused loop with the servo to the reference
#: path instead (rk4 and rosenbrock2, both backends)
SERVO = ('xarm7_trajectory',)


def test_the_scenes_left_to_test_servo_are_those_with_a_servo():
    for name in SERVO:
        assert _load(name).system.servo is not None, name


def _arm_cases():
    """(label, model, actuated, y0, script) for every ArmSystem scene (those with a servo: see SERVO) and a
    floating-base random tree."""
    from robodyn_ros.systems.arm import ArmSystem
    cases = []
    for name in SCENES:
        scene = _load(name)
        if type(scene.system) is ArmSystem and name not in SERVO:
            cases.append((name, scene.system.model, scene.system.actuated, scene.y0, scene.script))
    _, m = TREES[-1]  # FREE root + weld
    rng = np.random.default_rng(5)
    q, v, _, _ = random_state(m, rng)
    u = rng.normal(size=len(m.dof_joint_names))
    cases.append(('free-root-tree', m, None, np.concatenate([q, 0.3 * v]), lambda t, y: {'effort': u * np.cos(t)}))
    return cases


ARM_CASES = _arm_cases()


@pytest.mark.parametrize('backend', ['numba', 'generated'])
@pytest.mark.parametrize('integrator', ['rk4', 'semi_implicit_euler', 'euler'])
@pytest.mark.parametrize('label,model,actuated,y0,script', ARM_CASES, ids=[c[0] for c in ARM_CASES])
def test_fused_loop_equals_simulator_reference_path(label, model, actuated, y0, script, integrator, backend):
    from robodyn_ros.model import limit_table
    from robodyn_ros.systems.arm import ArmSystem
    kernels_only = model.has_spherical or limit_table(model).shape[0] > 0
    if kernels_only:   # no numpy reference: the Simulator's own loop on the compiled rhs is the reference
        ref_sys = ArmSystem(model, actuated=actuated, backend='numba')
        ref_sys.fused_advance = lambda *a, **k: None
    else:
        ref_sys = ArmSystem(model, actuated=actuated, backend='numpy')
    fast_sys = ArmSystem(model, actuated=actuated, backend=backend)
    assert (fast_sys._km.gen is not None) == (backend == 'generated'
                                              and not model.has_spherical)   # SPHERICAL: generic kernels
    calls = []
    fused = fast_sys.fused_advance

    def counting(*a, **k):
        res = fused(*a, **k)
        calls.append(res is not None)
        return res
    fast_sys.fused_advance = counting
    # 30 Hz publications with 1 ms steps: 33 full steps and a partial one per period; 0.1 ms (333 and a partial
    # one) where the step check refuses the explicit method at 1 ms through a joint stop's bounce (the human's
    # elbows under euler: stability.STOP_RESOLUTION)
    from robodyn_ros.stability import STOP_RESOLUTION
    dt = 1e-3 if 1e-3 <= STOP_RESOLUTION[integrator] * fast_sys.stop_time_constant(np.asarray(y0, float)) else 1e-4
    assert dt <= STOP_RESOLUTION[integrator] * fast_sys.stop_time_constant(np.asarray(y0, float))
    ref = _run(ref_sys, y0, integrator, 0.1, 30.0, script, dt)
    fast = _run(fast_sys, y0, integrator, 0.1, 30.0, script, dt)
    assert calls and all(calls)  # the Simulator took the fused path every period
    assert fast.t == ref.t
    assert close(fast.y, ref.y), np.abs(fast.y - ref.y).max()
    assert close([fast.diag.work], [ref.diag.work]) or abs(fast.diag.work - ref.diag.work) < 1e-14
    assert (fast.diag.steps, fast.diag.rhs_evals) == (ref.diag.steps, ref.diag.rhs_evals)
    assert fast.integrator.stats.steps == ref.integrator.stats.steps
    assert np.all(np.isfinite(fast.y)) and not np.allclose(fast.y, y0)  # it moved


def test_fused_path_declines_where_it_would_be_wrong():
    from robodyn_ros.systems.arm import ArmSystem
    model = TREES[3][1]
    z0 = np.zeros(2 * model.nv + 1)
    u = {'effort': np.zeros(model.nv)}
    assert ArmSystem(model, backend='numpy').fused_advance('rk4', 1e-3, 0.0, z0, 0.01, u) is None
    fast = ArmSystem(model, backend='numba')
    assert fast.fused_advance('rk45', 1e-3, 0.0, z0, 0.01, u) is None
    assert fast.fused_advance('rk4', 1e-3, 0.0, z0, 0.01, u) is not None

    class Changed(ArmSystem):
        def rhs(self, t, y, u):
            return super().rhs(t, y, u) * 0.0
    assert Changed(model, backend='numba').fused_advance('rk4', 1e-3, 0.0, z0, 0.01, u) is None
    patched = ArmSystem(model, backend='numba')
    real_rhs = patched.rhs
    patched.rhs = lambda t, y, u: real_rhs(t, y, u) * 2.0
    assert patched.fused_advance('rk4', 1e-3, 0.0, z0, 0.01, u) is None


def test_fused_path_reports_non_finite_state_like_the_reference():
    from robodyn_ros.integrators import IntegrationError
    from robodyn_ros.systems.arm import ArmSystem
    model = TREES[3][1]
    z0 = np.zeros(2 * model.nv + 1)
    u = {'effort': np.full(model.nv, 1e308)}
    with pytest.raises(IntegrationError, match='non-finite'):
        ArmSystem(model, backend='numba').fused_advance('rk4', 1e-3, 0.0, z0, 0.01, u)


def test_arm_outputs_and_energy_equal_on_both_backends():
    from robodyn_ros.systems.arm import ArmSystem
    scene = _load('stanford_arm')
    m = scene.system.model
    u = {'effort': np.linspace(-1.0, 1.0, len(scene.system.actuated))}
    y = scene.y0 + 0.1
    a = ArmSystem(m, actuated=scene.system.actuated, backend='numpy')
    b = ArmSystem(m, actuated=scene.system.actuated, backend='numba')
    oa, ob = a.outputs(0.0, y, u), b.outputs(0.0, y, u)
    assert close(ob.energy['kinetic'], oa.energy['kinetic']) and close(ob.energy['potential'], oa.energy['potential'])
    assert set(oa.wrenches) == set(ob.wrenches) and oa.wrenches, 'no wrenches to compare'
    for k in oa.wrenches:
        assert oa.wrenches[k][0] == ob.wrenches[k][0] and close(ob.wrenches[k][1], oa.wrenches[k][1])
    assert close(b.rhs(0.0, y, u), a.rhs(0.0, y, u))
    assert close(b.total_energy(y), a.total_energy(y))
    q, v = y[:m.nq], y[m.nq:]
    assert close(b.inverse_dynamics(q, v, v), a.inverse_dynamics(q, v, v))


def test_backend_selection():
    from robodyn_ros.systems.arm import ArmSystem, default_backend
    model = TREES[0][1]
    assert ArmSystem(model).backend == default_backend() == 'numba'
    assert ArmSystem(model, backend='NumPy').backend == 'numpy'
    with pytest.raises(ValueError, match='unknown backend'):
        ArmSystem(model, backend='fortran')


def test_cache_dir_is_writable_and_used():
    assert os.path.isdir(kernels.CACHE_DIR) or os.access(os.path.dirname(kernels.CACHE_DIR), os.W_OK)
    # a child process with an unwritable package dir is not simulated here; the fallback is
    # checked through NUMBA_CACHE_DIR, which kernels honours
    code = 'from robodyn_ros import kernels; print(kernels.CACHE_DIR)'
    env = dict(os.environ, NUMBA_CACHE_DIR='/tmp/robodyn-test-numba-cache')
    out = subprocess.run([sys.executable, '-c', code], env=env, capture_output=True, text=True, check=True)
    assert out.stdout.strip() == '/tmp/robodyn-test-numba-cache'


def test_kernel_cache_files_are_read_and_written_under_the_directory_lock(monkeypatch):
    """Every kernel's numba cache file takes the cache directory's lock (exclusive to save, shared to
    load), so that processes compiling at once (``robodyn warm --jobs``, a suite's children) never
    give two signatures one data file."""
    from robodyn_ros.kernels import cache, tree
    disp = cache.dispatchers()
    assert len(disp) > 50, len(disp)
    files = [d._cache._cache_file for d in disp.values()]
    assert all(type(f).__name__ == '_LockedCacheFile' for f in files), {type(f).__name__ for f in files}
    assert {f._cache_path for f in files} <= cache._OURS
    taken = []
    real = cache._dir_lock

    def spy(path, exclusive):
        taken.append((path, exclusive))
        return real(path, exclusive)

    monkeypatch.setattr(cache, '_dir_lock', spy)
    f = tree.joint_nv._cache._cache_file
    key = ('no such signature', 'no such machine')
    assert f.load(key) is None
    assert taken == [(f._cache_path, False)]


def test_bench_cli_smoke(tmp_path):
    """``robodyn bench speed`` runs and writes its table (figures are not checked)."""
    from robodyn_ros.cli import build_parser
    args = build_parser().parse_args(['bench'])
    assert args.command == 'bench' and getattr(args, '_bench_main', None) is None  # defaults to speed
    out = tmp_path / 'bench.md'
    skip = ['rtf', 'recording', 'scaling', 'memory', 'compile', 'node', 'stiff']   # (recording: test_bench_recording)
    args = build_parser().parse_args(['bench', 'speed', '--quick', '--scenes', 'betancur_pendulum', '--repeat', '2',
                                      '--skip', *skip, '--out', str(out)])
    assert args._main(args) == 0
    text = out.read_text()
    assert '| betancur_pendulum | 5/4 | FD |' in text and 'compiled / Pinocchio' in text


# ------------------------------------------------------------------------------------------
# scene-specialised code (method of Zs)
# ------------------------------------------------------------------------------------------
GEN_MODELS = [(n, None) for n in ('stanford_arm', 'betancur_pendulum', 'huston_p19_2_3')] + \
    [(label, m) for label, m in TREES if label in ('fixed1', 'seed7005-nb2-tree', 'seed7007-nb12-tree', 'free3')]


@pytest.mark.parametrize('label,model', GEN_MODELS, ids=[g[0] for g in GEN_MODELS])
def test_generated_forward_dynamics_equals_reference(label, model):
    """The generated forward dynamics (the loops' fd, :meth:`CompiledModel.forward`) against the numpy
    reference; its equality with the generic kernels, bit for bit, is test_generated's."""
    from robodyn_ros.kernels import codegen
    model = model if model is not None else _load(label).system.model
    km = kernels.CompiledModel(model, specialize=True)
    assert km.gen is not None and codegen.module_path(model).startswith(codegen.GENERATED_DIR)
    rng = np.random.default_rng(zlib.crc32(label.encode()))
    for _ in range(3):
        q, v, tau, fe = random_state(model, rng)
        assert close(km.forward(q, v, tau), dyn.aba(model, q, v, tau))
        assert close(km.aba(q, v, tau, fe), dyn.aba(model, q, v, tau, fe))  # f_ext: generic path


def test_generated_models_are_covered_and_spherical_joints_decline():
    from robodyn_ros.kernels import codegen
    labels = {g[0] for g in GEN_MODELS}
    assert len(labels) == len(GEN_MODELS) == 7  # the chosen random trees exist
    assert any(FIXED in m.jtype for _, m in GEN_MODELS if m is not None)
    assert any(FREE in m.jtype for _, m in GEN_MODELS if m is not None)   # a floating base (free3, with a weld)
    sph = random_tree(4, np.random.default_rng(5), spherical_fraction=0.7)
    assert sph.has_spherical and codegen.trace(sph) is None and codegen.trace(sph, ground=True) is None
    assert kernels.CompiledModel(sph, specialize=True).gen is None
