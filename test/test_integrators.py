"""Integrators against closed forms: accuracy, convergence order, conservation, bookkeeping."""
import math

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from robodyn_ros import integrators
from robodyn_ros.integrators import (
    DEFAULT_ATOL,
    DEFAULT_RTOL,
    INTEGRATORS,
    IntegrationError,
    IntegratorStats,
    make_integrator,
)

FIXED = [n for n, s in INTEGRATORS.items() if s.kind == 'fixed']
ADAPTIVE = [n for n, s in INTEGRATORS.items() if s.kind == 'adaptive']
ONE_STEP_ADAPTIVE = [n for n in ADAPTIVE if not INTEGRATORS[n].multistep]


def build(name, dt=1e-2, rtol=1e-8, atol=1e-10, nq=1, **kw):
    """Return an integrator of either kind with settings suited to the small test systems."""
    if INTEGRATORS[name].kind == 'fixed':
        if name == 'semi_implicit_euler':
            kw['nq'] = nq
        return make_integrator(name, dt=dt, **kw)
    return make_integrator(name, rtol=rtol, atol=atol, **kw)


def oscillator(omega):
    """Return f(t, y) of n harmonic oscillators x'' = -omega^2 x, y = [x (n), v (n)]."""
    omega2 = np.asarray(omega, dtype=float) ** 2
    n = omega2.size

    def f(t, y):
        return np.concatenate([y[n:], -omega2 * y[:n]])
    return f


def oscillator_exact(t, omega, x0, v0):
    """Closed-form state [x, v] of x'' = -omega^2 x at time t."""
    c, s = np.cos(omega * t), np.sin(omega * t)
    return np.concatenate([np.atleast_1d(x0 * c + v0 / omega * s),
                           np.atleast_1d(-x0 * omega * s + v0 * c)])


def oscillator_energy(y, omega):
    """Energy per unit mass of each oscillator, (v^2 + omega^2 x^2) / 2."""
    n = np.size(omega)
    return 0.5 * (y[n:] ** 2 + np.asarray(omega) ** 2 * y[:n] ** 2)


def global_error(name, h, T=2.0, omega=1.0):
    """Max-norm error at T of a fixed-step method on x'' = -omega^2 x, x(0) = 1, v(0) = 0."""
    integ = build(name, dt=h)
    y, cost = integ.advance(oscillator(omega), 0.0, [1.0, 0.0], T)
    assert cost.steps == round(T / h)
    return np.abs(y - oscillator_exact(T, omega, 1.0, 0.0)).max()


# ---------------------------------------------------------------- registry and arguments

def test_registry_holds_the_cli_names_with_their_properties():
    for name in ('euler', 'semi_implicit_euler', 'rk4', 'rk45', 'dop853', 'radau', 'bdf', 'lsoda'):
        assert name in INTEGRATORS
        assert INTEGRATORS[name].name == name
    assert {n: INTEGRATORS[n].order for n in FIXED} == {
        'euler': 1, 'semi_implicit_euler': 1, 'rk4': 4, 'rosenbrock2': 2}
    assert [n for n, s in INTEGRATORS.items() if s.symplectic] == ['semi_implicit_euler']
    assert {n for n, s in INTEGRATORS.items() if s.implicit} == {'radau', 'bdf', 'lsoda', 'rosenbrock2'}
    assert set(FIXED) == {'euler', 'semi_implicit_euler', 'rk4', 'rosenbrock2'}
    for name in INTEGRATORS:
        assert type(build(name)).__name__ != 'Integrator'


def test_unknown_name_lists_the_valid_names():
    with pytest.raises(ValueError) as info:
        make_integrator('rk5', dt=0.1)
    message = str(info.value)
    assert "'rk5'" in message
    for name in INTEGRATORS:
        assert name in message


@pytest.mark.parametrize('dt', [None, 0.0, -1e-3, math.nan, math.inf, 'fast'])
def test_fixed_step_requires_a_positive_finite_dt(dt):
    with pytest.raises(ValueError, match='dt'):
        make_integrator('rk4', dt=dt)


@pytest.mark.parametrize('rtol, atol', [(0.0, 1e-9), (-1e-6, 1e-9), (math.nan, 1e-9),
                                        (1e-20, 1e-9), (1e-6, 0.0), (1e-6, [1e-9, 0.0])])
def test_adaptive_requires_positive_tolerances(rtol, atol):
    with pytest.raises(ValueError, match='tol'):
        make_integrator('rk45', rtol=rtol, atol=atol)


def test_arguments_of_the_other_kind_are_refused_with_a_hint():
    with pytest.raises(ValueError, match='fixed-step.*give dt'):
        make_integrator('rk4', dt=1e-3, rtol=1e-6)
    with pytest.raises(ValueError, match='error-controlled.*not dt'):
        make_integrator('rk45', dt=1e-3)
    with pytest.raises(ValueError, match='unexpected option.*jac.*accepted options: max_step'):
        make_integrator('rk45', jac=lambda t, y: None)
    with pytest.raises(ValueError, match='nq'):
        make_integrator('semi_implicit_euler', dt=1e-3)
    with pytest.raises(ValueError, match='nq'):
        make_integrator('semi_implicit_euler', dt=1e-3, nq=True)
    with pytest.raises(ValueError, match='max_step'):
        make_integrator('dop853', max_step=0.0)


def test_adaptive_defaults_and_names_are_case_insensitive():
    integ = make_integrator('RK45')
    assert integ.name == 'rk45'
    assert (integ.rtol, integ.atol) == (DEFAULT_RTOL, DEFAULT_ATOL)
    assert integ.settings() == {'integrator': 'rk45', 'rtol': DEFAULT_RTOL,
                                'atol': DEFAULT_ATOL, 'max_step': math.inf}


def test_semi_implicit_euler_checks_the_state_split():
    integ = make_integrator('semi_implicit_euler', dt=0.1, nq=2)
    with pytest.raises(ValueError, match='nv == nq'):
        integ.advance(oscillator([1.0]), 0.0, np.zeros(3), 1.0)


def test_backward_time_is_refused():
    with pytest.raises(ValueError, match='forward'):
        build('rk4').advance(oscillator(1.0), 1.0, [1.0, 0.0], 0.5)


# ---------------------------------------------------------------- closed forms

# Bounds ~ C h^p with C ~ T w_max^(p+1) |y| (2.3^2 * 1.5 * 2 ~ 16 for the first-order ones).
@pytest.mark.parametrize('name, h, bound', [('euler', 1e-4, 2e-3),
                                            ('semi_implicit_euler', 1e-4, 2e-3),
                                            ('rk4', 1e-2, 1e-7)])
def test_fixed_step_oscillator_against_exact_solution(name, h, bound):
    omega = np.array([0.7, 1.0, 2.3])
    x0, v0 = np.array([1.0, -0.5, 0.2]), np.array([0.0, 1.0, -2.0])
    integ = build(name, dt=h, nq=3)
    T = 1.5
    y, cost = integ.advance(oscillator(omega), 0.0, np.concatenate([x0, v0]), T)
    assert np.abs(y - oscillator_exact(T, omega, x0, v0)).max() < bound
    assert cost.steps == round(T / h) == {1e-4: 15000, 1e-2: 150}[h]  # whole steps, none rejected or added


@pytest.mark.parametrize('name', [n for n in INTEGRATORS if n != 'semi_implicit_euler'])
def test_exponential_decay_against_exact_solution(name):
    lam = np.array([0.5, 1.0, 2.0, 4.0])
    y0 = np.array([1.0, -2.0, 3.0, 0.5])
    T = 2.0

    def f(t, y):
        return -lam * y

    dt, bound = {'euler': (1e-4, 1e-3), 'rk4': (1e-2, 1e-8), 'rosenbrock2': (1e-3, 1e-5)}.get(name, (None, 1e-6))
    integ = build(name, dt=dt, rtol=1e-9, atol=1e-12)
    y, _ = integ.advance(f, 0.0, y0, T)
    exact = y0 * np.exp(-lam * T)
    assert np.abs(y - exact).max() < bound


# ---------------------------------------------------------------- convergence order

@pytest.mark.parametrize('name, order, ladder', [
    ('euler', 1, [2.0 / 2 ** k for k in range(6, 12)]),
    ('semi_implicit_euler', 1, [2.0 / 2 ** k for k in range(6, 12)]),
    ('rk4', 4, [2.0 / 2 ** k for k in range(3, 8)]),
    ('rosenbrock2', 2, [2.0 / 2 ** k for k in range(5, 11)]),   # J = 0: Heun's method
])
def test_measured_convergence_order(name, order, ladder):
    errors = [global_error(name, h) for h in ladder]
    slope = np.polyfit(np.log(ladder), np.log(errors), 1)[0]
    assert abs(slope - order) < 0.1, (slope, errors)
    assert INTEGRATORS[name].order == order


@pytest.mark.parametrize('h', [0.25, 0.125, 0.0625])
def test_rk4_halving_h_divides_global_error_by_16(h):
    ratio = global_error('rk4', h) / global_error('rk4', h / 2)
    assert 16 * 0.8 <= ratio <= 16 * 1.2, ratio


# ---------------------------------------------------------------- error control

@pytest.mark.parametrize('name', ADAPTIVE)
def test_error_control_meets_tolerance_and_tightens(name):
    f = oscillator(1.0)
    T = 10.0
    # Global error is a multiple of the local tolerance: ~1x for the one-step pairs over ten
    # radians; the variable-order multistep methods run at low order and pay up to ~50x.
    factor = 100.0 if INTEGRATORS[name].multistep else 10.0
    errors = []
    for rtol in (1e-4, 1e-6, 1e-8):
        y, cost = build(name, rtol=rtol, atol=rtol * 1e-2).advance(f, 0.0, [1.0, 0.0], T)
        error = np.abs(y - oscillator_exact(T, 1.0, 1.0, 0.0)).max()
        assert error < factor * rtol, (rtol, error)
        assert cost.steps > 0 and cost.rhs_evals > cost.steps
        errors.append(error)
    assert errors[0] > 10 * errors[1] > 100 * errors[2], errors


@pytest.mark.parametrize('name', ONE_STEP_ADAPTIVE)
def test_error_control_over_many_short_calls(name):
    """The simulator calls advance once per period: accuracy holds and the step size carries."""
    f = oscillator(1.0)
    integ = build(name, rtol=1e-6, atol=1e-9)
    y, t, calls = np.array([1.0, 0.0]), 0.0, 500
    for _ in range(calls):
        y, _ = integ.advance(f, t, y, t + 0.01)
        t += 0.01
    assert np.abs(y - oscillator_exact(t, 1.0, 1.0, 0.0)).max() < 1e-6
    # The natural step (~0.1 s) exceeds the period, so after the first call every call takes
    # one step: no initial-step search and no rejection thanks to the remembered step size.
    assert integ.stats.advance_calls == calls
    assert integ.stats.steps <= calls + 2
    if name == 'rk45':
        assert integ.stats.rhs_evals <= 7 * calls + 10  # f(t0) + 6 stages per call
        assert integ.stats.rejected_steps == 0


@pytest.mark.parametrize('name, method, stages', [('rk45', 'RK45', 6), ('dop853', 'DOP853', 12)])
def test_rejected_steps_are_counted_exactly_for_runge_kutta_pairs(name, method, stages):
    mu = 5.0

    def van_der_pol(t, y):
        return np.array([y[1], mu * (1.0 - y[0] ** 2) * y[1] - y[0]])

    _, cost = build(name, rtol=1e-6, atol=1e-9).advance(van_der_pol, 0.0, [2.0, 0.0], 20.0)
    ref = solve_ivp(van_der_pol, (0.0, 20.0), [2.0, 0.0], method=method, rtol=1e-6, atol=1e-9)
    accepted = len(ref.t) - 1
    # solve_ivp: 1 evaluation at t0, 1 to choose the first step, n_stages per attempted step.
    rejected = (ref.nfev - 2) // stages - accepted
    assert cost.steps == accepted
    assert cost.rhs_evals == ref.nfev
    assert cost.rejected_steps == rejected > 0


def test_implicit_methods_report_jacobians_and_factorisations():
    lam = np.array([1.0, 1e4])  # stiff: explicit methods would need h < 2e-4

    def f(t, y):
        return -lam * (y - np.cos(t))

    integ = build('radau', rtol=1e-6, atol=1e-9)
    y, cost = integ.advance(f, 0.0, [0.0, 0.0], 1.0)
    assert cost.njev >= 1 and cost.nlu >= 1
    assert cost.rejected_steps is None  # not exposed by scipy: unknown, not zero
    assert cost.steps < 200
    # y_i -> cos t - (lam_i sin t + lam_i^2 cos t) / (lam_i^2 + 1) transient + particular
    particular = (lam ** 2 * np.cos(1.0) + lam * np.sin(1.0)) / (lam ** 2 + 1.0)
    homogeneous = -lam ** 2 / (lam ** 2 + 1.0) * np.exp(-lam)
    assert np.abs(y - (particular + homogeneous)).max() < 1e-5


# ---------------------------------------------------------------- long horizon

def test_symplectic_euler_energy_bounded_while_explicit_euler_grows():
    """1e4 periods of a bank of oscillators with h = 0.5 (about 1.3e5 steps)."""
    rng = np.random.default_rng(7)
    n = 16
    omega = np.linspace(0.5, 1.2, n)
    phase = rng.uniform(0.0, 2.0 * np.pi, n)
    y0 = np.concatenate([np.cos(phase), -omega * np.sin(phase)])
    f = oscillator(omega)
    E0 = oscillator_energy(y0, omega)
    h = 0.5
    chunk = 16 * h
    calls = math.ceil(2.0 * np.pi * 1e4 / chunk)

    symplectic = make_integrator('semi_implicit_euler', dt=h, nq=n)
    drift = np.empty((calls, n))
    y = y0
    for k in range(calls):
        y, _ = symplectic.advance(f, k * chunk, y, (k + 1) * chunk)
        drift[k] = oscillator_energy(y, omega) / E0 - 1.0
    assert symplectic.stats.steps == 16 * calls
    # Symplectic Euler conserves Q = v^2 + w^2 x^2 - h w^2 x v exactly, and |x v| <= E / w,
    # so |E / E0 - 1| <= h w / (1 - h w / 2) for ever (GNI IX: modified Hamiltonian).
    assert (np.abs(drift).max(axis=0) <= h * omega / (1.0 - h * omega / 2.0)).all()
    # no secular growth: the last tenth of the run wanders no further than the first tenth
    tenth = calls // 10
    first, last = np.abs(drift[:tenth]).max(axis=0), np.abs(drift[-tenth:]).max(axis=0)
    assert (last <= 1.001 * first).all()

    # Explicit Euler multiplies each oscillator's energy by exactly (1 + h^2 w^2) per step.
    explicit = make_integrator('euler', dt=h)
    y, _ = explicit.advance(f, 0.0, y0, 200 * h)
    growth = oscillator_energy(y, omega) / E0
    np.testing.assert_allclose(growth, (1.0 + (h * omega) ** 2) ** 200, rtol=1e-9)
    assert (growth > 1e5).all()  # (1 + 0.25^2)^200 = 1.8e5 for the slowest
    # ... and over the long horizon it overflows: an error, never a non-finite state.
    with np.errstate(over='ignore', invalid='ignore'), \
            pytest.raises(IntegrationError, match='euler.*non-finite'):
        explicit.advance(f, 0.0, y0, calls * chunk)


# ---------------------------------------------------------------- step bookkeeping

def test_thousand_steps_of_a_millisecond_reach_one_second_exactly():
    integ = make_integrator('rk4', dt=1e-3)
    y, cost = integ.advance(oscillator(1.0), 0.0, [1.0, 0.0], 1.0)
    assert (cost.steps, cost.rhs_evals, cost.rejected_steps) == (1000, 4000, 0)


@pytest.mark.parametrize('t_start', [0.0, 1e4])
@pytest.mark.parametrize('clock', ['accumulated', 'multiplied'])
def test_periods_of_ten_steps_whatever_the_round_off(t_start, clock):
    """Round-off in t1 - t0, also at large t, must not add (or drop) a step.

    With the naive floor((t1 - t0) / dt) rule about a fifth of the periods t = k * 0.01
    from 0 get a spurious step of ~1e-18 s.
    """
    integ = make_integrator('euler', dt=1e-3)
    y, t = np.array([1.0, 0.0]), t_start
    for k in range(1, 1001):
        t1 = t + 0.01 if clock == 'accumulated' else t_start + k * 0.01
        y, cost = integ.advance(oscillator(1.0), t, y, t1)
        assert cost.steps == 10, (k, t, t1)
        t = t1
    assert integ.stats.steps == 10000 and integ.stats.advance_calls == 1000


def test_partial_final_step_lands_on_t1():
    """dt = 0.3 on [0, 1]: steps at 0, 0.3, 0.6 of 0.3, then one of 0.1 at 0.9."""
    def ramp(t, y):
        return np.array([t, t * t])

    y, cost = make_integrator('euler', dt=0.3).advance(ramp, 0.0, [0.0, 0.0], 1.0)
    assert cost.steps == 4
    # stages read time GRID_ROUNDOFF_ULPS (16) ulps inside their step (integrators.step_start: a knot on
    # the grid acts over the step it starts), so the sum of h t is exact to 16 ulps of each t, ~1.3e-15
    assert integrators.GRID_ROUNDOFF_ULPS <= 16
    assert y[0] == pytest.approx(0.3 * (0.0 + 0.3 + 0.6) + 0.1 * 0.9, abs=4e-15)
    # RK4 reduces to Simpson's rule on quadratures: exact for t^2 whatever the step sizes.
    y, cost = make_integrator('rk4', dt=0.3).advance(ramp, 0.0, [0.0, 0.0], 1.0)
    assert cost.steps == 4
    assert y == pytest.approx([0.5, 1.0 / 3.0], abs=1e-15)


@pytest.mark.parametrize('name', list(INTEGRATORS))
def test_zero_length_interval_and_inputs_untouched(name):
    integ = build(name)
    y0 = np.array([1.0, 0.5])
    y, cost = integ.advance(oscillator(1.0), 2.0, y0, 2.0)
    assert cost.steps == 0 and cost.rhs_evals == 0
    assert y is not y0 and (y == y0).all()
    y, _ = integ.advance(oscillator(1.0), 2.0, y0, 2.5)
    assert y is not y0 and (y0 == [1.0, 0.5]).all()


def test_statistics_accumulate_and_reset():
    integ = make_integrator('rk45', rtol=1e-6, atol=1e-9)
    total = IntegratorStats(advance_calls=0)
    y = np.array([1.0, 0.0])
    for k in range(5):
        y, cost = integ.advance(oscillator(1.0), 0.1 * k, y, 0.1 * (k + 1))
        total.accumulate(cost)
    assert integ.stats == total and total.advance_calls == 5
    unknown = IntegratorStats(rejected_steps=None)
    total.accumulate(unknown)
    assert total.rejected_steps is None
    integ.reset()
    assert integ.stats == IntegratorStats()


# ---------------------------------------------------------------- manifolds

def circular_orbit(t, y):
    """Particle on the unit circle, q'' = -q with q(0) = (1, 0), v(0) = (0, 1); y = [q, v]."""
    return np.concatenate([y[2:], -y[:2]])


@pytest.mark.parametrize('name', list(INTEGRATORS))
def test_project_hook_is_applied(name):
    calls = []

    def renormalise(y):
        calls.append(1)
        y[:2] /= np.linalg.norm(y[:2])  # in place, like a quaternion renormalisation
        return y

    integ = build(name, dt=0.05, rtol=1e-4, atol=1e-7, nq=2)
    y, cost = integ.advance(circular_orbit, 0.0, [1.0, 0.0, 0.0, 1.0], 3.0, project=renormalise)
    assert np.linalg.norm(y[:2]) == pytest.approx(1.0, abs=4e-16)
    per_step = INTEGRATORS[name].projection == 'step'
    assert len(calls) == cost.projections == (cost.steps if per_step else 1)
    assert np.abs(y[:2] - [np.cos(3.0), np.sin(3.0)]).max() < 0.2


def renormalised_copy(y):
    """Projection returning a new array."""
    return np.concatenate([y[:2] / np.linalg.norm(y[:2]), y[2:]])


def renormalise_in_place(y):
    """Projection working in place and returning None."""
    y[:2] /= np.linalg.norm(y[:2])


@pytest.mark.parametrize('renormalise', [renormalised_copy, renormalise_in_place])
def test_projection_styles_are_honoured_and_keep_accuracy(renormalise):
    for name in ('rk4', 'semi_implicit_euler', 'rk45', 'radau'):
        integ = build(name, dt=1e-3, rtol=1e-9, atol=1e-12, nq=2)
        y, cost = integ.advance(circular_orbit, 0.0, [1.0, 0.0, 0.0, 1.0], 2.0,
                                project=renormalise)
        assert np.linalg.norm(y[:2]) == pytest.approx(1.0, abs=4e-16)
        bound = 1e-2 if name == 'semi_implicit_euler' else 1e-7
        assert np.abs(y[:2] - [np.cos(2.0), np.sin(2.0)]).max() < bound, name


def test_semi_implicit_euler_updates_v_first_then_q_through_qdot():
    h = 0.1
    y, _ = make_integrator('semi_implicit_euler', dt=h, nq=1).advance(
        oscillator(1.0), 0.0, [1.0, 0.0], h)
    assert y == pytest.approx([1.0 - h * h, -h], abs=1e-16)  # explicit Euler: [1, -h]

    # nq = 2, nv = 1: q = (x, s) with s accumulating v^2 through a user qdot map
    def f(t, y):
        return np.array([np.nan, np.nan, -y[0]])  # the q half of f is not used

    def qdot(q, v):
        return np.array([v[0], v[0] ** 2])

    integ = make_integrator('semi_implicit_euler', dt=h, nq=2, qdot=qdot)
    y, cost = integ.advance(f, 0.0, [1.0, 0.0, 2.0], 2 * h)
    v1 = 2.0 - h * 1.0
    q1 = [1.0 + h * v1, h * v1 ** 2]
    v2 = v1 - h * q1[0]
    assert y == pytest.approx([q1[0] + h * v2, q1[1] + h * v2 ** 2, v2], abs=1e-15)
    assert cost.steps == 2


# ---------------------------------------------------------------- failures

@pytest.mark.parametrize('name', list(INTEGRATORS))
def test_non_finite_right_hand_side_raises_integration_error(name):
    def poisoned(t, y):
        return np.array([y[1], -y[0] + (math.nan if t > 0.5 else 0.0)])

    integ = build(name, dt=0.01, rtol=1e-6, atol=1e-9)
    with pytest.raises(IntegrationError) as info:
        integ.advance(poisoned, 0.0, [1.0, 0.0], 1.0)
    err = info.value
    assert err.integrator == name and str(err).startswith(f'{name}: ')
    assert 0.4 < err.t <= 1.0 and 't=' in str(err)
    assert 'non-finite' in str(err)
    assert integ.stats.advance_calls == 1  # a failed call still counts its cost


def test_non_finite_initial_state_raises():
    with pytest.raises(IntegrationError, match=r'rk4.*t=0 s.*initial state.*\[1\]'):
        build('rk4').advance(oscillator(1.0), 0.0, [1.0, math.inf], 1.0)


@pytest.mark.parametrize('name', ['rk4', 'rk45', 'bdf'])
def test_model_errors_propagate_unchanged(name):
    def broken(t, y):
        raise ZeroDivisionError('model bug')

    with pytest.raises(ZeroDivisionError, match='model bug'):
        build(name).advance(broken, 0.0, [1.0, 0.0], 1.0)


def test_step_grids_are_step_grid_element_by_element():
    # the block path's vectorised grid: the same (n_full, h_last) as the per-period one, on exact
    # multiples, round-off-near multiples, partial steps and large times
    from robodyn_ros.integrators import make_integrator
    rng = np.random.default_rng(7)
    for dt in (1e-3, 2.5e-4, 0.01, 1.0 / 3.0):
        g = make_integrator('rk4', dt=dt)
        t0 = np.r_[rng.uniform(0, 1e4, 300), np.arange(200) / 100.0, 1e6 + np.arange(50) * 0.01]
        span = np.r_[rng.choice([0.01, 0.02, dt, 3 * dt], 300) * (1 + rng.choice([0, 1e-16, -1e-16, 1e-9], 300)),
                     np.full(200, 0.01), rng.uniform(1e-6, 0.1, 50)]
        t1 = t0 + span
        n_full, h_last = g.step_grids(t0, t1)
        want = [g.step_grid(float(a), float(b)) for a, b in zip(t0, t1)]
        assert len(want) == 550
        assert n_full.tolist() == [w[0] for w in want]
        assert np.array_equal(h_last, np.array([w[1] for w in want]))
        assert np.any(h_last > 0) and np.any(h_last == 0)
