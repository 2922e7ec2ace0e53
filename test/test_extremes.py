"""Numerical extremes (GUIDE §3, issue 6): each has a defined behaviour and nothing non-finite is published.

The scenarios live in :mod:`robodyn_ros.bench.extremes` (``extreme_*``), which also writes the README
table (``python -m robodyn_ros.bench.extremes --out docs/extremes.md``); here each one is run and its
figures are checked. The step-stability check itself (:mod:`robodyn_ros.stability`) is tested first on linear systems whose
modes are known, against what the integrators actually do.
"""
from __future__ import annotations

import math

import numpy as np
import pytest

from robodyn_ros import stability as st
from robodyn_ros.bench import extremes as ex
from robodyn_ros import kernels
from robodyn_ros.integrator_choice import plan_integrator
from robodyn_ros.integrators import make_integrator
from robodyn_ros.simulation import SimulationError, Simulator, run_headless
from robodyn_ros.systems.base import System, SystemOutputs


class LinearSystem(System):
    """``ẏ = A y`` as a System: ``y = [q (n), v (n)]`` (for the symplectic split) or first order."""

    def __init__(self, A, nq=None):
        self.A = np.asarray(A, dtype=float)
        self.ny = self.A.shape[0]
        self.nq = nq if nq is not None else self.ny // 2
        self.nv = self.ny - self.nq
        self.inputs = {}

    def rhs(self, t, y, u):
        return self.A @ y

    def config_rate(self, q, w):
        return (self.A @ np.concatenate([q, w]))[:self.nq]

    def total_energy(self, y):
        return 0.5 * float(y @ y)

    def input_power(self, t, y, u):
        return float(y @ (self.A @ y))

    def outputs(self, t, y, u, wrenches=True):
        return SystemOutputs(joint_names=[], position=y[:self.nq].copy(), velocity=y[self.nq:].copy(),
                             effort=np.zeros(0))


def _oscillator(omega, zeta=0.0):
    """q̇ = v, v̇ = −ω² q − 2ζω v."""
    return LinearSystem([[0.0, 1.0], [-omega ** 2, -2.0 * zeta * omega]], nq=1)


def _decay(rate):
    """Two first-order decays ẏ = −rate y (no mechanical split: nq = 1 of 2)."""
    return LinearSystem(np.diag([-rate, -rate]), nq=1)


def _grows(system, integrator, dt, steps=400, weights=None):
    """True when the fixed-step integrator amplifies a unit initial state tenfold over ``steps`` steps,
    in the norm ``|weights * y|`` (an oscillator's energy norm: weights (ω, 1))."""
    kw = {'nq': system.nq, 'qdot': system.config_rate} if integrator == 'semi_implicit_euler' else {}
    integ = make_integrator(integrator, dt=dt, **kw)
    w = np.ones(system.ny) if weights is None else np.asarray(weights, dtype=float)
    y0 = np.ones(system.ny) / w
    y, _ = integ.advance(lambda t, y: system.rhs(t, y, {}), 0.0, y0, steps * dt)
    return np.linalg.norm(w * y) > 10.0 * np.linalg.norm(w * y0)


@pytest.mark.parametrize('integrator, limit', [('euler', 2.0), ('rk4', 2.785), ('semi_implicit_euler', 2.0)])
def test_stability_limit_on_a_decay_matches_the_integrator(integrator, limit):
    """A decay at 1000 1/s: steps below the real-axis limit pass and are stable, steps beyond are refused
    and really blow up."""
    s = _decay(1000.0)
    y0 = np.ones(2)
    below, beyond = 0.97 * limit / 1000.0, 1.05 * limit / 1000.0
    a = st.analyse_step(s, integrator, below, y0)
    assert a.verdict == 'ok' and not _grows(s, integrator, below)
    b = st.analyse_step(s, integrator, beyond, y0)
    assert b.verdict == 'refuse' and _grows(s, integrator, beyond)
    assert b.dt_limit == pytest.approx(limit / 1000.0, rel=1e-3)
    with pytest.raises(ValueError, match=rf'{integrator} with dt=.* is unstable.*\|λ\| = 1e\+03 1/s'):
        plan_integrator(s, y0, integrator, beyond)   # the run's plan refuses it


def test_oscillator_limits_per_method():
    """An undamped oscillator at 100 rad/s: symplectic Euler is stable up to hω = 2, RK4 up to 2√2, and
    explicit Euler has no stable step (warned for small steps, refused once the growth is 1 % per step)."""
    s = _oscillator(100.0)
    y0 = np.array([1.0, 0.0])
    assert st.analyse_step(s, 'semi_implicit_euler', 0.019, y0).verdict == 'ok'
    assert not _grows(s, 'semi_implicit_euler', 0.019, 2000, weights=(100.0, 1.0))
    assert st.analyse_step(s, 'semi_implicit_euler', 0.021, y0).verdict == 'refuse'
    assert _grows(s, 'semi_implicit_euler', 0.021, weights=(100.0, 1.0))
    assert st.analyse_step(s, 'rk4', 0.028, y0).verdict == 'ok'
    assert st.analyse_step(s, 'rk4', 0.029, y0).verdict == 'refuse' and _grows(s, 'rk4', 0.029, weights=(100.0, 1.0))
    assert not _grows(s, 'rk4', 0.028, 2000, weights=(100.0, 1.0))
    w = st.analyse_step(s, 'euler', 1e-4, y0)
    assert w.verdict == 'warn' and w.doubling_time == pytest.approx(1e-4 * math.log(2) / (0.5 * 1e-4), rel=0.01)
    assert st.analyse_step(s, 'euler', 2e-3, y0).verdict == 'refuse'
    assert 'doubles it every' in plan_integrator(s, y0, 'euler', 1e-4).warnings[0]   # the plan carries the warning
    with pytest.warns(st.StepWarning, match='doubles it every'):                    # and the Simulator gives it
        Simulator(s, y0, integrator='euler', dt=1e-4)


def test_saddle_counts_as_the_oscillation_it_becomes():
    """A pendulum released off its equilibrium linearises to a saddle ±λ; explicit Euler is still warned."""
    s = LinearSystem([[0.0, 1.0], [25.0, 0.0]], nq=1)  # eigenvalues ±5
    a = st.analyse_step(s, 'euler', 1e-3, np.array([1.0, 0.0]))
    assert a.verdict == 'warn' and abs(a.worst) == pytest.approx(5.0)


def test_adaptive_integrators_are_not_checked_and_report_rejections():
    s = _decay(1e5)
    plan = plan_integrator(s, np.ones(2), 'dop853', None)
    assert plan.analysis is None and plan.warnings == ()
    sim = Simulator(s, np.ones(2), integrator='rk45', rtol=1e-6, atol=1e-9)
    sim.advance(1e-3)
    assert isinstance(sim.diagnostics_values()['rejected_steps'], int)
    sim = Simulator(s, np.ones(2), integrator='radau', rtol=1e-6, atol=1e-9)
    sim.advance(1e-3)
    assert sim.diagnostics_values()['rejected_steps'] == 'unknown'


# ---------------------------------------------------------------------------------------------
# the extremes of the issue
# ---------------------------------------------------------------------------------------------
def test_step_far_too_large_is_refused_naming_the_mode():
    r = ex.extreme_large_step()
    msg = r.data['euler_refused']
    assert 'euler with dt=0.02 s is unstable' in msg and '|λ| = 8.25 1/s' in msg
    assert any('doubles it every' in w for w in r.data['euler_warning'])
    assert r.data['rk4_ok']
    msg = r.data['rk4_free_flyer_refused']
    assert 'rk4 with dt=0.1 s is unstable' in msg and 'at most 0.058 s' in msg and 'radau' in msg
    assert r.finite


def test_stiff_motor_electrics():
    r = ex.extreme_stiff_motor()
    assert r.data['tau'] == pytest.approx(1e-5 / 1.7)
    assert 'fastest time constant is 5.88e-06 s' in r.data['rk4_refused'] and 'L/R' in r.data['rk4_refused']
    currents = [r.data[k]['current'] for k in ('radau', 'bdf', 'lsoda', 'rk45')]
    assert all(r.data[k]['ok'] for k in ('radau', 'bdf', 'lsoda', 'rk45'))
    assert np.ptp(currents) < 1e-5 * abs(currents[0])  # they agree on the (quasi-static) current
    # the stiff solvers take far fewer steps than the explicit pair, which adapts with rejections
    assert r.data['radau']['steps'] * 10 < r.data['rk45']['steps'] and r.data['rk45']['rejected'] > 0
    assert r.finite


def test_free_base_spinning_at_100_rad_s():
    r = ex.extreme_spin()
    for form in ('minimal', 'augmented'):
        d = r.data[form]
        assert 'unstable' in d['rk4_0.05_refused']
        assert d['rk4']['omega_error'] < 1e-6 and d['dop853']['omega_error'] < 7e-10   # measured 2e-8, 7e-12
        assert d['rk4']['momentum_change'] < 1e-6 and d['dop853']['momentum_change'] < 1e-8
        assert d['rk4']['quat_norm'] == pytest.approx(1.0, abs=1e-12)
    assert 'spins at 100 rad/s' in r.data['minimal']['rk4_0.05_refused']
    assert r.finite


def test_stretched_arm_under_prescribed_end_point():
    r = ex.extreme_stretched_arm()
    for form in ('complement', 'kkt'):
        d = r.data[form]
        assert d['ok'] and d['warned'] and d['singular'] and d['rank'] == 1
        assert d['sigma_ratio'] < 0.1
        assert d['residual'] < 0.1  # E follows its path approximately, and the error is reported
    assert r.data['complement']['final_residual'] == pytest.approx(r.data['kkt']['final_residual'], rel=1e-6)
    assert r.finite


def test_mass_ratio_of_1e6():
    r = ex.extreme_mass_ratio()
    assert set(r.data) == {'heavy_then_light', 'light_then_heavy'}
    for d in r.data.values():
        assert d['rk4']['ok'] and d['rk4']['error'] < 1e-6 and d['radau']['error'] < 1e-6
        assert d['rk4']['energy_drift'] < 3e-10   # measured 3e-12
    assert r.finite


def test_zero_and_near_zero_inertia():
    r = ex.extreme_zero_inertia()
    assert 'joint2' in r.data['zero_refused'] and 'mass matrix is singular' in r.data['zero_refused']
    assert 'unstable' in r.data['small_rk4_refused'] and '1.57e+05' in r.data['small_rk4_refused']
    assert r.data['radau']['ok'] and r.data['dop853']['ok']
    assert r.data['radau']['steps'] * 10 < r.data['dop853']['steps']
    assert r.finite


@pytest.mark.long(reason='~90 s without the compiled kernels') if not kernels.AVAILABLE else (lambda f: f)
def test_long_horizon_1e4_s():
    r = ex.extreme_long_horizon()
    d = r.data
    assert all(v['t'] == 1e4 for v in d.values())
    assert d['semi_implicit_euler']['energy_error_second_half'] < 0.01
    sie = d['semi_implicit_euler']
    assert sie['energy_error_second_half'] <= 1.1 * sie['energy_error_first_half']
    assert d['euler']['energy_error_final'] > 1.0
    assert d['euler']['energy_error_second_half'] > 2 * d['euler']['energy_error_first_half']
    assert d['rk4']['energy_error_final'] < 2e-9 and d['dop853']['energy_error_final'] < 1e-6   # 2e-11, 2e-8
    assert r.finite


def test_redundant_constraints():
    r = ex.extreme_redundant_constraints()
    assert r.data['ok'] and r.data['rank'] == 3
    left, right = r.data['lateral']
    assert left != 0.0 and left == pytest.approx(right, rel=1e-9)
    assert r.data['residual'] < 3e-15   # round-off: measured 3e-17 m/s
    assert r.finite


def test_orientation_through_pitch_90():
    r = ex.extreme_pitch_90()
    assert set(r.data) == {'minimal', 'augmented'}
    for form, d in r.data.items():
        assert d['rk4']['quat_error'] < 4e-10 and d['dop853']['quat_error'] < 6e-14, form   # 4e-12, 6e-16
        assert d['rk4']['odom_quat_norm'] == pytest.approx(1.0, abs=1e-12)
    assert r.finite


def test_huge_efforts_and_voltages():
    r = ex.extreme_huge_commands()
    e = r.data['rk4_effort']
    assert not e['ok'] and e['kept_finite'] and not e['moved']
    assert 'non-finite' in e['failure'] and 'largest command effort = 1e+06' in e['failure']
    assert r.data['dop853_effort']['ok']
    assert r.data['saturated'] == {'flag': True, 'applied': 12.0}
    assert r.data['unlimited']['error'] < 5e-11   # measured 5e-13
    assert r.finite


def test_zero_gravity_zero_damping_no_input_nothing_moves():
    r = ex.extreme_nothing_moves()
    assert set(r.data) == {'stanford_arm', 'unfried_free_flyer (minimal)', 'unfried_free_flyer (augmented)',
                           'betancur_platform'}
    for label, moved in r.data.items():
        if 'augmented' in label:
            assert moved < 7e-13, label  # Baumgarte acting on the round-off of C(x0): measured 7e-15
        else:
            assert moved == 0.0, label
    assert r.finite


def test_a_failed_run_records_no_non_finite_value(tmp_path):
    """1e6 N·m on the Stanford arm with RK4 through the MCAP recorder: the run stops with the cause and
    every number in the file is finite."""
    from robodyn_ros.recording.cdr import decode
    from robodyn_ros.recording.reader import read_raw_messages
    from robodyn_ros.recording.run_sink import McapRunSink
    from robodyn_ros.scene import load_scene
    scene = load_scene('stanford_arm')
    sim = Simulator(scene.system, scene.y0, integrator='rk4', dt=1e-3)
    path = tmp_path / 'huge.mcap'
    sink = McapRunSink(path, scene, {'integrator': 'rk4', 'dt': 1e-3}, diagnostics_period=0.01)
    with pytest.raises(SimulationError, match='largest command effort'):
        try:
            run_headless(sim, 0.1, 100.0, lambda t, y: {'effort': np.full(6, 1e6)}, [sink])
        finally:
            sink.close()
    numbers = []

    def walk(x):
        if isinstance(x, dict):
            for v in x.values():
                walk(v)
        elif isinstance(x, (list, tuple)):
            for v in x:
                walk(v)
        elif isinstance(x, float):
            numbers.append(x)
        elif isinstance(x, np.ndarray) and x.dtype.kind == 'f':
            numbers.extend(x.ravel().tolist())
    topics = set()
    for topic, type_name, _, data in read_raw_messages(str(path)):
        topics.add(topic)
        walk(decode(type_name, data))
    assert {'/joint_states', '/effort_commands'} <= topics
    assert numbers and all(math.isfinite(v) for v in numbers)


def test_extremes_table_has_a_row_per_extreme():
    rows = [ex.Extreme(fn.__name__, fn.__doc__.split('.')[0], 'b', 'w') for fn in ex.EXTREMES]
    rows[0].what = 'dt·|λ| = 5'
    text = ex.extremes_markdown(rows)
    assert len(ex.EXTREMES) == 11 and text.count('\n') == 11 + 1
    assert 'dt·\\|λ\\| = 5' in text  # a pipe inside a cell is escaped
