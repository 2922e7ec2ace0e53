"""rosenbrock2 under error control (``rtol``; dt its largest step): the compiled loop of the trees
(``kernels.arm.arm_controlled_steps``) and the generic one (``integrators.Rosenbrock2``) against closed forms
and fine references of other methods; the settings it is given and refuses; its step budget.

The contact scenes that use it (solo12_drop, huston_human17_fall) are tested in test_contact_implicit.py.
"""
from __future__ import annotations

import math
import warnings

import numpy as np
import pytest

from robodyn_ros.integrators import make_integrator
from robodyn_ros.scene import load_scene
from robodyn_ros.simulation import SimulationError, Simulator

from test_contact_implicit import _slide
from test_diffdrive import K_T, M_TOT, R_A, R_W, I_W, platform


def _sim(system, y0, **kw):
    with warnings.catch_warnings():
        warnings.simplefilter('ignore')
        return Simulator(system, y0, **kw)


def test_the_error_follows_the_tolerance_on_a_sliding_box():
    """The box sliding down a stiff slope on its 4 corners (contacts in J, saturated friction; steps of at most
    2 ms) against rk4 at 10 µs: for rtol = atol from 1e-5 to 1e-8 the error stays below 0.1 rtol (measured 6.5e-3,
    2.6e-2, 3.2e-2 and 3.2e-2 of it), and the steps grow as rtol^(-1/2) between 1e-6 and 1e-8 (slope -0.50):
    the controller's signature for an embedded pair of orders 2 and 1. In fixed 2 ms steps the error is 1.7e-6."""
    ref, _ = _slide(1e-5, 'rk4')
    rtols = (1e-5, 1e-6, 1e-7, 1e-8)
    errs, steps = [], []
    for r in rtols:
        y, sim = _slide(2e-3, 'rosenbrock2', rtol=r)
        errs.append(np.abs(y - ref).max())
        steps.append(sim.integrator.stats.steps)
        assert sim.settings['rtol'] == r and sim.integrator.settings() == {
            'integrator': 'rosenbrock2', 'dt': 2e-3, 'rtol': r, 'atol': r}
    assert all(e < 0.1 * r for e, r in zip(errs, rtols)), errs
    slope = np.polyfit(np.log(rtols[1:]), np.log(steps[1:]), 1)[0]
    assert -0.6 < slope < -0.4, (steps, slope)
    y, _ = _slide(2e-3, 'rosenbrock2')
    assert np.abs(y - ref).max() > 100 * errs[-1]     # the fixed step is far coarser: the control did the work


def test_the_generic_path_follows_the_tolerance_on_the_platforms_closed_form():
    """The differential-drive platform (no compiled controlled loop: ``integrators.Rosenbrock2`` on its right-hand
    side) driven by equal voltages from rest: x(t) = v_ss (t − τ(1 − e^(−t/τ))) (test_diffdrive's closed form). With
    steps of at most 0.5 s over 2 s (τ = 0.84 s) the error stays below rtol·v_ss·t for rtol 1e-4 .. 1e-8 and falls
    by more than 100 over that range; each step is taken or refused by its own estimate (rejected steps counted)."""
    m_eff = M_TOT + 2 * I_W / R_W ** 2
    tau = m_eff * R_A * R_W ** 2 / (2 * K_T ** 2)
    V = 6.0
    v_ss = R_W * V / K_T
    t = 2.0
    x_exact = v_ss * (t - tau * (1 - math.exp(-t / tau)))
    errs = []
    for r in (1e-4, 1e-6, 1e-8):
        s = platform()
        sim = _sim(s, s.initial_state(), integrator='rosenbrock2', dt=0.5, rtol=r)
        sim.set_command('wheel_voltage', [V, V])
        sim.advance(t)
        e = abs(sim.outputs().odom['position'][0] - x_exact)
        assert e < r * v_ss * t, (r, e)
        assert sim.integrator.stats.steps > 4 and sim.integrator.stats.rejected_steps is not None
        errs.append(e)
    assert errs[-1] < 1e-2 * errs[0], errs
    assert not getattr(platform(), 'fused_tolerance', False)   # so the generic path is the one tested here


def test_the_compiled_and_generic_loops_meet_the_same_reference_on_the_stanford_arm():
    """The Stanford arm (compiled kernels: ``arm_controlled_steps``; and with the system's fused path declined: the
    generic loop) over 1 s under its scene's script, rtol 1e-8, steps of at most 10 ms, against dop853 at rtol
    1e-12: both within 1e-6 of it; the two differ in how they measure (tangent coordinates against the state's
    own), not in what they converge to."""
    sc = load_scene('stanford_arm')

    ref = _sim(sc.system, sc.y0, integrator='dop853', rtol=1e-12, atol=1e-12)
    ref.advance(1.0)
    compiled = _sim(sc.system, sc.y0, integrator='rosenbrock2', dt=1e-2, rtol=1e-8)
    compiled.advance(1.0)
    generic_sys = load_scene('stanford_arm').system
    generic_sys.fused_advance = lambda *a, **k: None     # this instance only: the Simulator's Python path
    generic = _sim(generic_sys, sc.y0, integrator='rosenbrock2', dt=1e-2, rtol=1e-8)
    generic.advance(1.0)
    for sim in (compiled, generic):
        assert np.abs(sim.y - ref.y).max() < 1e-6, np.abs(sim.y - ref.y).max()
        assert sim.integrator.stats.steps > 100       # the tolerance, not the 10 ms cap, set the steps
    assert not np.array_equal(compiled.y, generic.y)


def _scene_names():
    from robodyn_ros.scene import list_scenes
    return [n for n, _ in list_scenes()]


@pytest.mark.parametrize('name', _scene_names())
def test_every_bundled_scene_runs_under_error_control_as_radau_does(name):
    """Every bundled scene (each kind of system: trees on the compiled loop, the platform, the free flyer, the
    prescribed path on the generic one) over 0.1 s with its scripted commands, rosenbrock2 at rtol 1e-7 with
    steps of at most 10 ms (which the step analysis would refuse in fixed steps for the human's fall: not
    analysed, as the error-controlled methods are not) against radau at rtol 1e-11: within 1e-5 (the state
    error of ``bench.precision``; measured 0 to 1.3e-6)."""
    from robodyn_ros.bench.precision import comparable, state_error
    sc = load_scene(name)

    def run(**kw):
        sim = _sim(sc.system, sc.y0, step_budget=math.inf, **kw)
        rate = sc.settings.get('publish_rate', 100.0)
        for k in range(1, int(round(0.1 * rate)) + 1):
            if sc.script is not None:
                for port, values in sc.script(sim.t, sim.y).items():
                    sim.set_command(port, values)
            sim.advance(k / rate)
        return sim
    a = run(integrator='rosenbrock2', dt=1e-2, rtol=1e-7)
    b = run(integrator='radau', rtol=1e-11, atol=1e-11)
    assert a.settings['rtol'] == 1e-7 and a.integrator.stats.steps >= 10
    assert state_error(comparable(sc.system, a.y), comparable(sc.system, b.y)) < 1e-5


def test_the_step_budget_stops_a_tolerance_the_model_cannot_afford():
    """solo12_drop at rtol 1e-9 with a budget of 2000 steps per simulated second: the run stops in the compiled loop
    (in its first period: the body is still falling) with the budget's message saying no mode is stiff there, so
    the tolerance costs the steps, and keeps the state and time of its last good period."""
    sc = load_scene('solo12_drop')
    sim = _sim(sc.system, sc.y0, integrator='rosenbrock2', dt=1e-3, rtol=1e-9, step_budget=2000)
    good = sim.y.copy(), sim.t
    with pytest.raises(SimulationError, match='spent its step budget') as e:
        for k in range(1, 101):
            sim.advance(0.01 * k)
            good = sim.y.copy(), sim.t
    assert 'no mode is stiff there: its error control needs these steps for rtol=1e-09' in str(e.value)
    assert np.array_equal(sim.y, good[0]) and sim.t == good[1]
    with pytest.raises(SimulationError, match='spent its step budget'):
        sim.advance(1.0)       # refused until reset


@pytest.mark.parametrize('kw, message', [
    ({'atol': 1e-6}, 'atol needs rtol'),
    ({'rtol': 1e-20}, 'below 100 machine epsilon'),
    ({'rtol': float('nan')}, 'rtol must be finite and > 0'),
    ({'rtol': 1e-6, 'atol': [1e-6, 1e-6]}, 'atol must be one number'),
])
def test_bad_tolerances_are_refused_with_the_reason(kw, message):
    with pytest.raises(ValueError, match=message):
        make_integrator('rosenbrock2', dt=1e-3, **kw)


def test_the_other_fixed_step_methods_refuse_a_tolerance_and_name_the_ones_that_take_it():
    with pytest.raises(ValueError, match='rk4 is a fixed-step integrator: give dt, not rtol/atol') as e:
        make_integrator('rk4', dt=1e-3, rtol=1e-6)
    assert 'rosenbrock2' in str(e.value)


def test_a_run_refuses_a_tolerance_its_fixed_step_method_would_ignore_and_drops_the_scenes(capsys):
    """``robodyn run`` and the node refuse rtol/atol given for rk4 (or euler) instead of running without them,
    naming the methods that take them; a scene's tolerances (solo12_drop: rosenbrock2 at rtol 1e-5) are not
    carried to another fixed-step method the run asks for (its recorded settings then hold none), and a sweep's
    grid drops them on its rk4 rows."""
    from robodyn_ros.cli import main
    from robodyn_ros.nodes.config import PARAMETERS, ConfigError, resolve_config
    from robodyn_ros.runs import resolve_settings
    from robodyn_ros.sweep import requested_settings
    for flag in ('--rtol', '--atol'):
        assert main(['run', 'stanford_arm', '--duration', '0.01', '--integrator', 'rk4', flag, '1e-6']) == 2
        err = capsys.readouterr().err
        assert f'rk4 is a fixed-step integrator: give dt, not {flag[2:]}' in err and 'rosenbrock2' in err, err
    scene = load_scene('solo12_drop')
    assert resolve_settings(scene)['rtol'] == 1e-5                                   # the scene's own method
    assert resolve_settings(scene, 'rosenbrock2')['rtol'] == 1e-5
    assert (resolve_settings(scene, 'rk4')['rtol'], resolve_settings(scene, 'rk4')['atol']) == (None, None)
    assert requested_settings(scene, {'integrator': 'rk4', 'rtol': 1e-6}, 0.1)['rtol'] is None
    assert requested_settings(scene, {'integrator': 'dop853', 'rtol': 1e-6}, 0.1)['rtol'] == 1e-6
    raw = {k: v for k, (v, _) in PARAMETERS.items()}
    with pytest.raises(ConfigError, match='rk4 is a fixed-step integrator: give dt, not rtol'):
        resolve_config(dict(raw, integrator='rk4', rtol=1e-6), load_scene('stanford_arm'))


def test_a_sweep_row_of_rosenbrock2_under_error_control_keeps_its_step_and_its_tolerances():
    """A sweep's integrator columns: dt for a fixed step, rtol/atol for an error-controlled method, both for
    rosenbrock2 under error control (its largest step and its tolerances: what reruns it)."""
    from robodyn_ros.sweep import _settings_columns
    st = {'dt': 1e-2, 'rtol': 1e-6, 'atol': 1e-7, 'duration': 1.0}
    cols = {name: _settings_columns({**st, 'integrator': name}) for name in ('rosenbrock2', 'rk4', 'dop853')}
    assert (cols['rosenbrock2']['dt'], cols['rosenbrock2']['rtol'], cols['rosenbrock2']['atol']) == (1e-2, 1e-6, 1e-7)
    assert (cols['rk4']['dt'], cols['rk4']['rtol'], cols['rk4']['atol']) == (1e-2, None, None)
    assert (cols['dop853']['dt'], cols['dop853']['rtol']) == (None, 1e-6)
    fixed = _settings_columns({**st, 'rtol': None, 'atol': None, 'integrator': 'rosenbrock2'})
    assert (fixed['dt'], fixed['rtol']) == (1e-2, None)
