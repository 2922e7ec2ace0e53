"""Compiled constrained and floating-base systems ≡ their numpy reference (1e-12), fused loops included.

The kernels of each system (:mod:`robodyn_ros.kernels.diffdrive`, ``freeflyer``, ``augmented``,
``prescribed``) re-implement the right-hand sides, projections and solves of the differential
drive (alone and as a mobile manipulator), the free-flying base in minimal and augmented
coordinates (orbit and air-bearing table, each stabilisation) and the prescribed end-point path (both formulations, circle and line, near-singular). Each is compared with the
numpy methods of the same class (``backend='numpy'``) at random states, then the fused loop that
the Simulator takes (``fused_advance``) against the Simulator's reference path over 0.1 s with
30 Hz periods (so every period ends with a partial step). No timings are asserted.
"""
from __future__ import annotations

import copy
import warnings

import numpy as np
import pytest

from robodyn_ros import kernels
from robodyn_ros.scene import load_scene
from robodyn_ros.simulation import Simulator, run_headless



def test_numba_kernels_are_available():
    """numba is a hard dependency: without it these tests fail (they never skip)."""
    import numba  # noqa: F401
    assert kernels.AVAILABLE, f'compiled kernels unavailable: {kernels.UNAVAILABLE_REASON}'

RTOL = 1e-12


def close(x, ref, rtol=RTOL):
    """Norm-wise relative agreement ``max|x − ref| <= rtol max|ref|`` (exact when ref is 0)."""
    x, ref = np.asarray(x, dtype=float), np.asarray(ref, dtype=float)
    assert x.shape == ref.shape, (x.shape, ref.shape)
    err = np.abs(x - ref).max() if ref.size else 0.0
    return bool(np.all(np.isfinite(x))) and err <= rtol * (np.abs(ref).max() if ref.size else 0.0)


def _pair(name, **changes):
    """(compiled system, numpy system, scene) of a bundled scene, with constructor changes."""
    sc = load_scene(name)
    s = sc.system
    assert hasattr(s, 'rebuilt'), type(s)

    def make(b):
        return s.rebuilt(b, **changes)
    fast, ref = make('numba'), make('numpy')
    assert fast._cs is not None and ref._cs is None
    return fast, ref, sc


def _cases():
    from robodyn_ros.systems.augmented import AugmentedFreeFlyerSystem
    from robodyn_ros.systems.freeflyer import FreeFlyerSystem
    from robodyn_ros.systems.prescribed import LinePath
    out = [('betancur_platform', {}), ('mobile_manipulator', {})]
    for scene in ('unfried_free_flyer', 'unfried_air_bearing'):
        for cls in (FreeFlyerSystem, AugmentedFreeFlyerSystem):
            for stab in ('baumgarte', 'projection', 'none'):
                out.append((scene, {'cls': cls, 'stabilisation': stab}))
    out += [('huston_prescribed_planar3', {'formulation': 'complement'}),
            ('huston_prescribed_planar3', {'formulation': 'kkt'}),
            ('huston_prescribed_planar3', {'formulation': 'kkt', 'actuated': ['joint2'],
                                           'path': LinePath([1.2, 0.3], [0.25, 0.9], 0.08, 0.01)})]
    return out


CASES = _cases()


def _id(case):
    name, ch = case
    return '-'.join([name] + [getattr(v, '__name__', str(v)) if k != 'path' else 'line' for k, v in ch.items()])


def _state(fast, sc, rng):
    """A random state of the system near the scene's initial state (consistent for the constrained ones)."""
    from robodyn_ros.systems.diffdrive import DiffDriveSystem
    from robodyn_ros.systems.prescribed import PrescribedPathSystem
    if isinstance(fast, DiffDriveSystem):
        y = sc.y0 + 0.2 * rng.normal(size=fast.ny)
        return y
    if isinstance(fast, PrescribedPathSystem):
        return sc.y0 + 0.3 * rng.normal(size=fast.ny)
    q0, v0 = sc.system.minimal(sc.y0) if hasattr(sc.system, 'minimal') else (sc.y0[:sc.system.nq], None)
    return fast.initial_state(q0, 0.3 * rng.normal(size=len(q0) - 1))


@pytest.mark.parametrize('name,changes', CASES, ids=[_id(c) for c in CASES])
def test_compiled_system_equals_reference(name, changes):
    fast, ref, sc = _pair(name, **dict(changes))
    rng = np.random.default_rng(11)
    for _ in range(3):
        y = _state(fast, sc, rng)
        u = {k: rng.normal(size=p.size) for k, p in fast.inputs.items()}
        t = 0.037
        with warnings.catch_warnings():
            warnings.simplefilter('ignore')
            assert close(fast.rhs(t, y, u), ref.rhs(t, y.copy(), u))
            dz = fast._cs.evaluate(t, y, fast._u_vec(u))
            assert close(dz[:-1], ref.rhs(t, y.copy(), u))
            assert close([dz[-1]], [ref.input_power(t, y.copy(), u)], 1e-11)
            assert close(fast.project(y.copy()), ref.project(y.copy()))
            for w in (False, True):
                oa, ob = fast.outputs(t, y.copy(), u, wrenches=w), ref.outputs(t, y.copy(), u, wrenches=w)
                assert list(oa.joint_names) == list(ob.joint_names)
                for x, xr in ((oa.position, ob.position), (oa.velocity, ob.velocity), (oa.effort, ob.effort)):
                    assert close(x, xr, 1e-11), (x, xr)
                assert (oa.odom is None) == (ob.odom is None)
                if ob.odom is not None:
                    assert oa.odom.keys() == ob.odom.keys()
                    for k in ob.odom:
                        assert close(oa.odom[k], ob.odom[k], 1e-11), (k, oa.odom[k], ob.odom[k])
                assert set(oa.wrenches) == set(ob.wrenches) and (ob.wrenches or not w), 'no wrenches to compare'
                for k in ob.wrenches:
                    assert oa.wrenches[k][0] == ob.wrenches[k][0] and close(oa.wrenches[k][1], ob.wrenches[k][1], 1e-11)
                for k, v in ob.energy.items():
                    assert close([oa.energy[k]], [v], 1e-11), k
                assert oa.extra.keys() == ob.extra.keys()
                for k, v in ob.extra.items():
                    if isinstance(v, float) and k not in ('constraint_residual', 'constraint_velocity_residual',
                                                          'joint_torque_residual'):
                        assert close([oa.extra[k]], [v], 1e-10) or abs(oa.extra[k] - v) < 1e-12, (k, oa.extra[k], v)
                    elif not isinstance(v, float):
                        assert oa.extra[k] == v, k
            assert close([fast.total_energy(y)], [ref.total_energy(y)])
            if hasattr(ref, 'contact_wrenches'):   # the differential drive's wrenches from given multipliers
                a, lam, _ = ref.solve(y.copy(), u)
                wa, wb = fast.contact_wrenches(y.copy(), u, a, lam), ref.contact_wrenches(y.copy(), u, a, lam)
                assert list(wa) == list(wb) and len(wb) >= 5
                for k in wb:
                    assert wa[k][0] == wb[k][0] and close(wa[k][1], wb[k][1], 1e-11), k


def _run(system, y0, integrator, script):
    with warnings.catch_warnings():
        warnings.simplefilter('ignore')
        sim = Simulator(system, y0, integrator=integrator, dt=1e-3)
        run_headless(sim, 0.1, 30.0, script)
    return sim


@pytest.mark.parametrize('integrator', ['rk4', 'semi_implicit_euler', 'euler'])
@pytest.mark.parametrize('name,changes', CASES, ids=[_id(c) for c in CASES])
def test_fused_loop_equals_simulator_reference_path(name, changes, integrator):
    fast, ref, sc = _pair(name, **dict(changes))
    rng = np.random.default_rng(3)
    y0 = _state(fast, sc, rng) if name.startswith('unfried') else sc.y0
    inputs = {k: 0.5 * rng.normal(size=p.size) for k, p in fast.inputs.items()}

    def script(t, y):
        return {k: v * np.cos(3.0 * t) for k, v in inputs.items()}
    calls = []
    fused = fast.fused_advance

    def counting(*a, **k):
        res = fused(*a, **k)
        calls.append(res is not None)
        return res
    fast.fused_advance = counting
    a = _run(fast, y0, integrator, script if inputs else None)
    b = _run(ref, y0, integrator, script if inputs else None)
    declines = fast.formulation == 'augmented' and fast.stabilisation == 'projection' \
        if hasattr(fast, 'formulation') and fast.formulation in ('minimal', 'augmented') else False
    assert calls and all(c != declines for c in calls)
    assert a.t == b.t and (a.diag.steps, a.diag.rhs_evals) == (b.diag.steps, b.diag.rhs_evals)
    assert close(a.y, b.y, 1e-11), np.abs(a.y - b.y).max()
    assert close([a.diag.work], [b.diag.work], 1e-10) or abs(a.diag.work - b.diag.work) < 1e-12
    assert not np.allclose(a.y, y0)
    assert getattr(fast, 'singular_evaluations', None) == getattr(ref, 'singular_evaluations', None)


def test_compiled_systems_decline_and_fail_like_the_reference():
    from robodyn_ros.integrators import IntegrationError
    fast, ref, sc = _pair('betancur_platform')
    z0 = np.append(sc.y0, 0.0)
    u = {'wheel_voltage': np.array([1.0, 2.0])}
    assert ref.fused_advance('rk4', 1e-3, 0.0, z0, 0.01, u) is None
    assert fast.fused_advance('rk45', 1e-3, 0.0, z0, 0.01, u) is None
    assert fast.fused_advance('rk4', 1e-3, 0.0, z0, 0.01, u) is not None
    patched = copy.copy(fast)
    patched.electrical = lambda y, u: ref.electrical(y, u)  # a changed method: the compiled path steps aside
    assert patched.fused_advance('rk4', 1e-3, 0.0, z0, 0.01, u) is None
    ff, _, sc = _pair('unfried_free_flyer', stabilisation='baumgarte')
    z0 = np.append(sc.system.minimal(sc.y0)[0], np.zeros(ff.nv + 1)) if ff.formulation == 'minimal' else \
        np.append(ff.initial_state(*sc.system.minimal(sc.y0)), 0.0)
    with pytest.raises(IntegrationError, match='non-finite'):
        ff.fused_advance('rk4', 1e-3, 0.0, z0, 0.01, {'effort': np.full(len(ff.actuated), 1e308),
                                                       'base_wrench': np.full(6, 1e308)})


def test_compiled_path_checks_subclasses_and_instances_at_every_call():
    """keeps_methods: a subclass that overrides nothing keeps the compiled path, one that overrides a
    reproduced method (or an instance given one later, after the path was taken) declines."""
    from robodyn_ros.systems.diffdrive import DiffDriveSystem
    fast, ref, sc = _pair('betancur_platform')
    z0 = np.append(sc.y0, 0.0)
    u = {'wheel_voltage': np.array([1.0, 2.0])}

    class Same(DiffDriveSystem):
        pass

    class Changed(DiffDriveSystem):
        def electrical(self, y, u):
            return ref.electrical(y, u)

    for cls, kept in ((Same, True), (Changed, False)):
        s = copy.copy(fast)
        s.__class__ = cls
        assert (s.fused_advance('rk4', 1e-3, 0.0, z0, 0.01, u) is not None) is kept, cls
    s = copy.copy(fast)
    assert s.fused_advance('rk4', 1e-3, 0.0, z0, 0.01, u) is not None
    s.solve = ref.solve
    assert s.fused_advance('rk4', 1e-3, 0.0, z0, 0.01, u) is None
    del s.solve
    assert s.fused_advance('rk4', 1e-3, 0.0, z0, 0.01, u) is not None


def test_compiled_outputs_publish_an_overridden_contact_wrenches():
    """``outputs`` on the compiled path computes the wrenches inside ``dd_outputs``; a subclass or an
    instance that replaces ``contact_wrenches`` publishes its own, as the numpy method does, and a
    subclass keeps the compiled integration (fused_advance) all the same."""
    from robodyn_ros.systems.diffdrive import DiffDriveSystem
    fast, ref, sc = _pair('mobile_manipulator')
    u = {k: np.linspace(0.5, 2.0, p.size) for k, p in fast.inputs.items()}
    y = sc.y0.copy()
    plain = fast.outputs(0.0, y, u).wrenches

    def doubled(obj):
        return lambda y, u, a, lam: {k: (fr, 2.0 * w) for k, (fr, w) in
                                     DiffDriveSystem.contact_wrenches(obj, y, u, a, lam).items()}

    class Doubled(DiffDriveSystem):
        def contact_wrenches(self, y, u, a, lam):
            return doubled(self)(y, u, a, lam)

    s = copy.copy(fast)
    s.__class__ = Doubled
    t = copy.copy(fast)
    t.contact_wrenches = doubled(t)
    assert np.abs(plain['left_wheel_contact'][1]).max() > 1e-3 and len(plain) >= 5
    for obj in (s, t):
        got = obj.outputs(0.0, y, u).wrenches
        assert list(got) == list(plain)
        for k in plain:
            assert got[k][0] == plain[k][0] and close(got[k][1], 2.0 * plain[k][1], 1e-11), k
    assert s.fused_advance('rk4', 1e-3, 0.0, np.append(y, 0.0), 0.01, u) is not None
