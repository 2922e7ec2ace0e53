"""Work-precision measurements and advice (issue 6): the method is tested, never the timings.

* measured convergence orders match theory (euler 1, semi_implicit_euler 1, rk4 4);
* errors against a closed form fall as the tolerance tightens;
* a symplectic fixed step keeps a pendulum's energy error bounded over 1e4 s while explicit
  Euler's grows (a 1-link pendulum built with robodyn_ros.model);
* ``robodyn advise`` picks the cheapest run meeting the tolerance from a measurement table, and
  its cache is keyed so that an edited scene is measured again;
* ``robodyn bench precision`` writes its CSV, markdown and PNG (a tiny ladder).
"""
from __future__ import annotations

import csv
import dataclasses
import math
import warnings

import numpy as np
import pytest

from robodyn_ros import advise as adv
from robodyn_ros import measurements as meas
from robodyn_ros.bench import precision as P
from robodyn_ros.scene import load_scene, parse_scene
from robodyn_ros.simulation import Simulator


def _quiet(fn, *a, **kw):
    with warnings.catch_warnings():
        warnings.simplefilter('ignore')
        return fn(*a, **kw)


@pytest.fixture(scope='module')
def pendulum():
    return load_scene('betancur_pendulum')


@pytest.fixture(scope='module')
def pendulum_reference(pendulum):
    ref = Simulator(pendulum.system, pendulum.y0, integrator='dop853', rtol=1e-13, atol=1e-13)
    ref.advance(0.2)
    return ref.y


@pytest.mark.parametrize('integrator, order, steps', [
    ('euler', 1, (2e-3, 1e-3, 5e-4, 2.5e-4)),
    ('semi_implicit_euler', 1, (2e-3, 1e-3, 5e-4, 2.5e-4)),
    ('rk4', 4, (1e-2, 5e-3, 2.5e-3, 1.25e-3)),
])
def test_measured_convergence_order_matches_theory(pendulum, pendulum_reference, integrator, order, steps):
    """betancur_pendulum over 0.2 s (one advance, so the step grid is exact): the error of the final
    state falls as h^p; the slope of the two finest steps and the least-squares slope over the
    ladder both lie within a margin of p."""
    errs = []
    for h in steps:
        sim = _quiet(Simulator, pendulum.system, pendulum.y0, integrator=integrator, dt=h)
        sim.advance(0.2)
        errs.append(P.state_error(sim.y, pendulum_reference))
    logs = np.log(errs)
    finest = (logs[-2] - logs[-1]) / math.log(steps[-2] / steps[-1])
    fit = np.polyfit(np.log(steps), logs, 1)[0]
    assert abs(finest - order) < 0.25, (errs, finest)
    assert abs(fit - order) < 0.35, (errs, fit)


def _fast_platform():
    """betancur_platform with a 10x torque constant (τ = 0.79 s instead of 79 s, so the response is
    far from linear over 1 s) published at 1 Hz (one advance per second: no solver restarts)."""
    text = load_scene('betancur_platform').text
    text = text.replace('torque_constant: 0.061', 'torque_constant: 0.61')
    text = text.replace('publish_rate: 100', 'publish_rate: 1')
    return parse_scene(text, file='fast_platform.yaml')


def test_closed_form_of_the_platform_is_the_model_solution():
    sc = _fast_platform()
    exact = P.closed_form(sc)
    assert exact is not None and 'tau = 0.787 s' in exact.description
    r = P.simulate(sc, 'dop853', rtol=1e-12, atol=1e-12, horizon=1.0, sample=False)
    assert r.status == 'ok' and P.state_error(r.y, exact(1.0)) < 1e-12
    assert P.closed_form(load_scene('betancur_pendulum')) is None  # no closed form: DOP853 reference


@pytest.mark.parametrize('integrator', ['rk45', 'dop853', 'radau', 'bdf', 'lsoda'])
def test_errors_against_closed_form_fall_as_tolerance_tightens(integrator):
    sc = _fast_platform()
    exact = P.closed_form(sc)(1.0)
    errs = []
    for tol in (1e-3, 1e-6, 1e-9):
        r = P.simulate(sc, integrator, rtol=tol, atol=tol, horizon=1.0, sample=False)
        assert r.status == 'ok', r.note
        errs.append(P.state_error(r.y, exact))
    assert errs[0] > errs[1] > errs[2], errs
    assert errs[2] < 1e-8 and errs[0] / errs[2] > 100, errs


def test_rosenbrock2_under_error_control_is_on_the_ladder_and_follows_its_tolerance():
    """The ladder offers rosenbrock2 under error control (one publication period its largest step, atol = rtol) as
    a method of its own; on the platform's closed form (τ = 0.79 s, one 1 s period) its error falls as rtol
    tightens (measured 9.2e-5, 1.1e-7, 1.1e-10 for rtol 1e-3, 1e-6, 1e-9, in 24, 717 and 22 615 steps), and
    advise would give the command line that runs it."""
    sc = _fast_platform()
    exact = P.closed_form(sc)(1.0)
    assert [s for s in P.ladder(sc, 'quick', ['rosenbrock2']) if s[2] is not None] == \
        [('rosenbrock2', 1.0, r, r) for r in P.ADAPTIVE_LADDERS['quick']]
    assert P.method_of(('rosenbrock2', 1.0, 1e-6, 1e-6)) != P.method_of(('rosenbrock2', 1e-3, None, None))
    errs = []
    for tol in (1e-3, 1e-6, 1e-9):
        r = P.simulate(sc, 'rosenbrock2', dt=1.0, rtol=tol, atol=tol, horizon=1.0, sample=False)
        assert r.status == 'ok', r.note
        assert (r.kind, r.setting, r.label) == ('controlled', f'rtol={tol:g} dt<=1', 'rosenbrock2+rtol')
        assert r.steps > 1 and r.rejected_steps is not None
        errs.append(P.state_error(r.y, exact))
    assert errs[0] > errs[1] > errs[2] and errs[0] / errs[2] > 1e3, errs
    assert errs[2] < 1e-7, errs
    assert adv.run_command('x', r) == 'robodyn run x --integrator rosenbrock2 --dt 1 --rtol 1e-09 --atol 1e-09'


def test_symplectic_step_keeps_energy_bounded_over_1e4_s_while_euler_grows():
    """A 1-link pendulum (1 kg point mass on 1 m, small-angle ω = 0.05 rad/s, 80 periods in 1e4 s) at
    dt = 0.1 s: semi-implicit Euler's energy error stays bounded (no larger in the second half of the run
    than in the first); explicit Euler's grows (and the simulator warned that it would)."""
    from robodyn_ros.bench.extremes import slow_pendulum
    from robodyn_ros.stability import StepWarning
    s = slow_pendulum(0.05)
    y0 = s.initial_state(np.array([0.3]))
    scale = s.total_energy(y0) + 0.05 ** 2  # the swing energy (J) above the bottom
    result = {}
    for name in ('semi_implicit_euler', 'euler'):
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter('always')
            sim = Simulator(s, y0, integrator=name, dt=0.1)
        errs = []
        for k in range(100):
            sim.advance((k + 1) * 100.0)
            e = sim.energy_report()
            assert abs(e['work']) < 1e-12  # no damping, no input: the drift is the energy error itself
            errs.append(abs(e['drift']) / scale)
        result[name] = (max(errs[:50]), max(errs[50:]), [w.category for w in caught])
    first, second, warned = result['semi_implicit_euler']
    assert second < 0.01 and second <= 1.05 * first and not warned
    first, second, warned = result['euler']
    assert second > 1.0 and second > 2.0 * first
    assert StepWarning in warned


def test_formulations_of_a_scene_are_enumerated_and_comparable():
    ff = load_scene('unfried_free_flyer')
    variants = P.formulations(ff)
    assert [f for f, _ in variants] == ['minimal', 'augmented']
    assert P.scene_formulation(ff) == 'augmented'
    a, b = (P.comparable(sc.system, sc.y0) for _, sc in variants)
    assert a.shape == b.shape and np.allclose(a, b, atol=1e-12)
    assert [f for f, _ in P.formulations(load_scene('huston_prescribed_planar3'))] == ['complement', 'kkt']
    assert [f for f, _ in P.formulations(load_scene('stanford_arm'))] == ['']


def test_refused_and_failed_runs_are_recorded_not_raised():
    pend = load_scene('betancur_pendulum')
    r = P.simulate(pend, 'euler', dt=0.02, horizon=0.1)  # longer than the period: still refused first
    assert r.status == 'refused' and 'unstable' in r.note and r.y is None
    arm = load_scene('stanford_arm')
    scene = parse_scene(arm.text.replace('amplitude: [3.0, 4.0, 4.0, 0.15, 0.2, 0.001]',
                                         'amplitude: [1.0e+6, 1.0e+6, 1.0e+6, 1.0e+6, 1.0e+6, 1.0e+6]'),
                        file='huge.yaml')
    r = P.simulate(scene, 'rk4', dt=1e-3, horizon=0.1)
    assert r.status == 'failed' and 'non-finite' in r.note and math.isnan(r.error)


# ---------------------------------------------------------------------------------------------
# advise
# ---------------------------------------------------------------------------------------------
def _run(integ, error, wall, setting, status='ok', formulation=''):
    kind = 'fixed' if integ in P.FIXED else 'adaptive'
    return meas.Run(scene='s', formulation=formulation, integrator=integ, kind=kind,
                 dt=setting if kind == 'fixed' else None, rtol=setting if kind == 'adaptive' else None,
                 atol=setting if kind == 'adaptive' else None, horizon=1.0, status=status, error=error,
                 wall_per_sim_s=wall, rhs_evals=int(wall * 1e4), rhs_per_sim_s=wall * 1e4)


SYNTHETIC = [
    _run('euler', 3e-2, 0.01, 1e-3), _run('euler', 3e-3, 0.1, 1e-4),
    _run('rk4', 2e-4, 0.02, 1e-2), _run('rk4', 3e-7, 0.05, 2e-3), _run('rk4', 5e-9, 0.2, 5e-4),
    _run('dop853', 1e-6, 0.03, 1e-6), _run('dop853', 2e-10, 0.08, 1e-10),
    _run('radau', 1e-7, 0.01, 1e-8, status='failed'),       # cheapest at 1e-6 but it failed
    _run('lsoda', 9e-7, 0.025, 1e-7, formulation='kkt'),
    _run('rk45', math.nan, 0.001, 1e-3, status='refused'),
]


@pytest.mark.parametrize('tol, expected', [
    (1e-1, ('euler', 1e-3)), (1e-3, ('rk4', 1e-2)), (1e-6, ('lsoda', 1e-7)), (1e-9, ('dop853', 1e-10)),
    (1e-12, None)])
def test_advise_chooses_cheapest_run_meeting_tolerance(tol, expected):
    best, others = adv.choose(SYNTHETIC, tol)
    if expected is None:
        assert best is None and others == []
        return
    assert (best.integrator, best.dt if best.kind == 'fixed' else best.rtol) == expected
    assert all(r.error <= tol and r.status == 'ok' for r in [best] + others)
    assert all(meas.cost_key(best) <= meas.cost_key(r) for r in others)
    assert len({(r.integrator, r.formulation) for r in others}) == len(others)


def _synthetic_result(scene, mode='quick'):
    ref = P.Reference('closed form', np.zeros(1), 0.0, 'synthetic')
    return P.SceneResult(scene=scene.name, horizon=1.0, rate=100.0, mode=mode, reference=ref, runs=list(SYNTHETIC))


def test_advise_cache_is_keyed_by_scene_text_machine_and_version(tmp_path, monkeypatch):
    monkeypatch.setenv('XDG_CACHE_HOME', str(tmp_path / 'xdg'))
    assert meas.cache_dir() == tmp_path / 'xdg' / 'robodyn_ros' / 'precision'
    path = tmp_path / 'pend.yaml'
    text = load_scene('betancur_pendulum').text
    path.write_text(text)
    calls = []

    def measure(name):
        calls.append(name)
        return _synthetic_result(meas.load_scene_quietly(name))
    a = adv.advise(str(path), 1e-6, measure=measure)
    assert a.source == 'measured now' and calls == [str(path)]
    assert (a.best.integrator, a.best.rtol) == ('lsoda', 1e-7)
    cached = list(meas.cache_dir().glob('betancur_pendulum-*.json'))
    assert len(cached) == 1
    b = adv.advise(str(path), 1e-9, measure=measure)
    assert b.source == 'cache' and calls == [str(path)] and b.best.integrator == 'dop853'
    # a different machine or release gives another key
    k = meas.cache_key('betancur_pendulum', text)
    assert k != meas.cache_key('betancur_pendulum', text, machine='other-4')
    assert k != meas.cache_key('betancur_pendulum', text, version='999')
    # an edited scene is a cache miss: measured again, stored beside the old entry
    path.write_text(text.replace('mass: 0.1', 'mass: 0.2', 1))
    c = adv.advise(str(path), 1e-6, measure=measure)
    assert c.source == 'measured now' and len(calls) == 2
    assert len(list(meas.cache_dir().glob('betancur_pendulum-*.json'))) == 2
    # a quick measurement never replaces a full one
    scene = meas.load_scene_quietly(str(path))
    meas.store(scene, _synthetic_result(scene, mode='full'))
    meas.store(scene, _synthetic_result(scene, mode='quick'))
    assert meas.load(scene)['mode'] == 'full'
    text_out = adv.format_advice(c, str(path))
    assert 'lsoda rtol=1e-07' in text_out and 'robodyn run' in text_out and '--rtol 1e-07' in text_out


def test_advise_cli_answers_from_the_cache(tmp_path, monkeypatch, capsys):
    from robodyn_ros.cli import main
    monkeypatch.setenv('XDG_CACHE_HOME', str(tmp_path))
    scene = meas.load_scene_quietly('betancur_pendulum')
    meas.store(scene, _synthetic_result(scene, mode='full'))
    assert main(['advise', 'betancur_pendulum', '--tolerance', '1e-3']) == 0
    out = capsys.readouterr().out
    assert 'cheapest: rk4 dt=0.01' in out and 'robodyn run betancur_pendulum --integrator rk4 --dt 0.01' in out
    assert main(['advise', 'betancur_pendulum', '--tolerance', '1e-12']) == 1
    assert 'no measured setting reaches it' in capsys.readouterr().out
    assert main(['advise', 'betancur_pendulum', '--tolerance', '-1']) == 2


def test_bench_precision_writes_csv_markdown_and_png(tmp_path, monkeypatch):
    """A tiny ladder (rk4 and dop853, 0.05 s) of the free flyer in both formulations, end to end."""
    from robodyn_ros.bench import run_argv
    monkeypatch.setenv('XDG_CACHE_HOME', str(tmp_path / 'xdg'))
    monkeypatch.setitem(P.FIXED_LADDERS, 'quick', {'rk4': (0.02, 0.01)})
    monkeypatch.setitem(P.ADAPTIVE_LADDERS, 'quick', (1e-6,))
    out = tmp_path / 'out'
    assert run_argv(['precision', 'unfried_free_flyer', '--quick', '--horizon', '0.06', '--integrators', 'rk4',
                     'dop853', '--out', str(out), '--quiet']) == 0
    rows = list(csv.DictReader(open(out / 'unfried_free_flyer.csv')))
    assert {(r['formulation'], r['integrator']) for r in rows} == {
        (f, i) for f in ('minimal', 'augmented') for i in ('rk4', 'dop853')}
    assert len(rows) == 6 and all(r['status'] == 'ok' for r in rows)
    for r in rows:
        assert float(r['error']) < 1e-3 and float(r['rhs_evals']) > 0
        assert float(r['momentum_drift']) < 1e-6  # orbit, no thrust: momentum is conserved
        if r['formulation'] == 'augmented':
            assert float(r['constraint_residual']) < 1e-6
    md = (out / 'unfried_free_flyer.md').read_text()
    assert '## unfried_free_flyer' in md and '**0.001**' in md and 'selects the **augmented** formulation' in md
    assert (out / 'unfried_free_flyer.png').read_bytes()[:8] == b'\x89PNG\r\n\x1a\n'
    assert 'unfried_free_flyer' in (out / 'summary.md').read_text()
    assert meas.load(meas.load_scene_quietly('unfried_free_flyer')) is not None  # cached for robodyn advise


def test_bench_precision_without_matplotlib_writes_the_tables_and_says_how_to_get_the_plot(tmp_path, monkeypatch,
                                                                                           capsys):
    """matplotlib missing (simulated: ``sys.modules['matplotlib'] = None`` makes every import of it
    raise ModuleNotFoundError): CSV, markdown and summary are written, the markdown does not link a
    PNG that is not there, and one line says how to get the diagram; exit 0, no traceback."""
    import sys

    from robodyn_ros.bench import run_argv
    monkeypatch.setenv('XDG_CACHE_HOME', str(tmp_path / 'xdg'))
    monkeypatch.setitem(P.FIXED_LADDERS, 'quick', {'rk4': (0.01,)})
    monkeypatch.setitem(P.ADAPTIVE_LADDERS, 'quick', ())
    for mod in [m for m in sys.modules if m == 'matplotlib' or m.startswith('matplotlib.')]:
        monkeypatch.delitem(sys.modules, mod)
    monkeypatch.setitem(sys.modules, 'matplotlib', None)
    with pytest.raises(ModuleNotFoundError):
        import matplotlib  # noqa: F401  (the simulation of its absence works)
    out = tmp_path / 'out'
    assert run_argv(['precision', 'betancur_pendulum', '--quick', '--horizon', '0.04', '--integrators', 'rk4',
                     '--out', str(out), '--quiet']) == 0
    assert sorted(p.name for p in out.iterdir()) == ['betancur_pendulum.csv', 'betancur_pendulum.md', 'summary.md']
    rows = list(csv.DictReader(open(out / 'betancur_pendulum.csv')))
    assert [(r['integrator'], r['status']) for r in rows] == [('rk4', 'ok')]
    md = (out / 'betancur_pendulum.md').read_text()
    assert '## betancur_pendulum' in md and '.png' not in md
    err = capsys.readouterr().err
    assert 'matplotlib is not installed' in err and 'pip install matplotlib' in err
    assert 'Traceback' not in err


def test_the_reference_and_its_floor_against_an_independent_reference():
    """stanford_arm holds its commands per 10 ms period, so every period is a fresh start and one
    DOP853 or RK45 step per period meets any rtol: an unbounded DOP853 reference would take the very
    steps of the dop853 run it measures and call its error 0. The reference's steps are bounded
    (at least 4 per period: it cannot coincide with a measured run) and its floor is its difference
    to the same with 8 per period. Against an independent reference, rk4 at 1e-5 s converged by
    halving (to round-off): the reference agrees within its floor, each measured error agrees with
    the independent one (rk45 1.9e-13 over 0.1 s, dop853 2.2e-15: figures, not 0), a value at or
    below the floor is printed as "≤ floor", and both runs say that rtol had no effect (about one step
    per period)."""
    sc = _quiet(load_scene, 'stanford_arm')
    H, rate = 0.1, float(sc.settings['publish_rate'])
    fine = [P.simulate(sc, 'rk4', dt=h, horizon=H, sample=False) for h in (1e-5, 5e-6)]
    rk_diff = P.state_error(fine[0].y, fine[1].y)
    assert rk_diff < 1e-13, rk_diff                      # converged: round-off
    y_ind = fine[1].y
    ref = P.reference(sc, H)
    periods = int(round(H * rate))
    assert ref.steps >= P.REFERENCE_STEPS_PER_PERIOD * periods
    slack = ref.error_estimate + 2 * rk_diff + 1e-15
    assert P.state_error(ref.y, y_ind) <= slack, (P.state_error(ref.y, y_ind), ref.error_estimate, rk_diff)
    runs = {name: P.simulate(sc, name, rtol=1e-4, atol=1e-4, horizon=H, sample=False) for name in ('dop853', 'rk45')}
    for name, r in runs.items():
        assert r.status == 'ok' and periods <= r.steps <= periods + 2 < ref.steps, (name, r.steps)
        assert r.one_step_per_period(rate)
        r.error = P.state_error(r.y, ref.y)
        r.error_floor = r.error <= ref.error_estimate
        assert abs(r.error - P.state_error(r.y, y_ind)) <= slack, (name, r.error, P.state_error(r.y, y_ind))
    rk45, dop = runs['rk45'], runs['dop853']
    assert 10 * ref.error_estimate < rk45.error < 1e-11, rk45.error      # measured 1.9e-13 over 0.1 s
    assert 0.0 < dop.error < 1e-13 and P.state_error(dop.y, y_ind) < 1e-13, dop.error   # measured 2.2e-15
    meta = {'rate': rate, 'reference': {'error_estimate': ref.error_estimate, 'kind': ref.kind, 'check': ref.check}}
    assert 'one step per period' in adv._describe(dop, meta) and 'e-' in adv._describe(rk45, meta)
    below = dataclasses.replace(dop, error=0.0, error_floor=True)     # a value at or below the floor
    text = adv._describe(below, meta)
    assert f'≤ {ref.error_estimate:.1g} (the reference\'s floor)' in text and 'error 0' not in text, text
    res = P.SceneResult(scene=sc.name, horizon=H, rate=rate, mode='quick', reference=ref, runs=[rk45, below])
    md = P.markdown(res)
    assert '~1 step/period' in md and '(the reference\'s floor)' in md and '0.0e+00' not in md
