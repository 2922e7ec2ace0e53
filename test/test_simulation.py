"""The Simulator pipeline: command holding and rejection, timeouts, energy accounting, failure."""
import numpy as np
import pytest

from robodyn_ros import dynamics as dyn
from robodyn_ros.model import random_tree
from robodyn_ros.simulation import CommandError, SimulationError, Simulator, run_headless
from robodyn_ros.systems import ArmSystem


def _arm(nb=4, seed=3, damping=0.0):
    m = random_tree(nb, np.random.default_rng(seed), chain=True)
    if damping:
        from dataclasses import replace
        m = replace(m, damping=np.full(m.nv, damping))
    return ArmSystem(m)


class _Sink:
    """Counts what the simulator hands a sink."""

    wants_wrenches = True

    def __init__(self):
        self.outputs, self.commands, self.started = [], [], 0

    def on_start(self, sim):
        self.started += 1

    def on_command(self, t, port, values):
        self.commands.append((t, port, np.array(values)))

    def on_output(self, t, out, sim):
        self.outputs.append((t, out))

    def close(self):
        pass


def test_energy_balance_closes_with_damping_and_inputs():
    """E(t) - E0 equals the integrated input-minus-dissipation power (work quadrature in the state)."""
    sys_ = _arm(damping=0.3)
    sim = Simulator(sys_, sys_.initial_state(np.full(sys_.nq, 0.3)), integrator='dop853', rtol=1e-11, atol=1e-12)
    for k in range(50):
        sim.set_command('effort', np.sin(0.1 * k + np.arange(sys_.nv)))
        sim.advance((k + 1) * 0.02)
    e = sim.energy_report()
    assert abs(e['work']) > 0.1  # the inputs and damping really did work
    assert abs(e['drift']) < 1e-8 * max(1.0, abs(e['energy0']))


def test_energy_balance_detects_wrong_power():
    """The same check fails when the power bookkeeping is wrong (the test can fail)."""
    sys_ = _arm(damping=0.3)
    sys_.input_power = lambda t, y, u: 0.0  # pretend nothing does work
    sim = Simulator(sys_, sys_.initial_state(np.full(sys_.nq, 0.3)), integrator='dop853', rtol=1e-11, atol=1e-12)
    sim.set_command('effort', np.ones(sys_.nv))
    sim.advance(1.0)
    assert abs(sim.energy_report()['drift']) > 1e-3


@pytest.mark.parametrize('bad, word', [([1.0, 2.0], 'expected 4 values'), ([1.0, np.nan, 0.0, 0.0], 'non-finite'),
                                       ([np.inf, 0.0, 0.0, 0.0], 'non-finite'), ('abc', 'expected 4')])
def test_bad_commands_are_rejected_and_change_nothing(bad, word):
    sys_ = _arm()
    sim = Simulator(sys_, sys_.initial_state(), integrator='rk4', dt=1e-3)
    sim.set_command('effort', [1.0, 2.0, 3.0, 4.0])
    with pytest.raises(CommandError, match=word) as ei:
        sim.set_command('effort', bad)
    assert 'j0' in str(ei.value) or 'expected' in str(ei.value)
    assert np.array_equal(sim.held_inputs()['effort'], [1.0, 2.0, 3.0, 4.0])
    assert sim.rejected_commands == 1


def test_command_timeout_zeroes_efforts():
    sys_ = _arm()
    sim = Simulator(sys_, sys_.initial_state(), integrator='rk4', dt=1e-3, command_timeout=0.05)
    sim.set_command('effort', [1.0, 1.0, 1.0, 1.0])
    sim.advance(0.04)
    assert np.array_equal(sim.outputs(wrenches=False).effort, [1, 1, 1, 1])
    sim.advance(0.06)
    assert np.array_equal(sim.outputs(wrenches=False).effort, [0, 0, 0, 0])
    assert sim.diagnostics_values()['effort_timed_out'] is True
    sim.set_command('effort', [2.0, 0.0, 0.0, 0.0])
    assert np.array_equal(sim.held_inputs()['effort'], [2, 0, 0, 0])


def test_nonfinite_state_stops_and_keeps_last_good_state():
    sys_ = _arm()
    real_rhs = sys_.rhs
    sys_.rhs = lambda t, y, u: real_rhs(t, y, u) * (np.nan if t > 0.055 else 1.0)
    sim = Simulator(sys_, sys_.initial_state(np.full(sys_.nq, 0.2)), integrator='rk4', dt=1e-3)
    sim.advance(0.05)
    good_t, good_y = sim.t, sim.y.copy()
    with pytest.raises(SimulationError, match='non-finite'):
        sim.advance(0.06)
    assert sim.t == good_t and np.array_equal(sim.y, good_y)
    with pytest.raises(SimulationError):
        sim.advance(0.07)
    sim.reset()
    assert sim.failed is None and sim.t == 0.0


def test_every_integrator_runs_the_arm_and_agrees():
    """All integrators reach the same state after 0.2 s within their accuracy class."""
    sys_ = _arm()
    y0 = sys_.initial_state(np.full(sys_.nq, 0.4))
    ref = Simulator(sys_, y0, integrator='dop853', rtol=1e-12, atol=1e-12)
    ref.advance(0.2)
    tol = {'euler': 5e-2, 'semi_implicit_euler': 5e-2, 'rk4': 1e-8, 'rk45': 1e-5, 'dop853': 1e-8, 'radau': 1e-5}
    errs = {}
    for name, t in tol.items():
        sim = Simulator(sys_, y0, integrator=name, dt=1e-4, rtol=1e-8, atol=1e-10)
        sim.advance(0.2)
        errs[name] = np.abs(sim.y - ref.y).max()
    assert len(errs) == len(tol)
    bad = {k: v for k, v in errs.items() if v > tol[k]}
    assert not bad, bad


def test_run_headless_periods_commands_and_sinks():
    sys_ = _arm()
    sim = Simulator(sys_, sys_.initial_state(), integrator='rk4', dt=1e-3)
    sink = _Sink()
    n = run_headless(sim, 0.5, 100.0, lambda t, y: {'effort': np.full(4, t)}, [sink])
    assert n == 50 and sink.started == 1
    assert len(sink.outputs) == 51 and len(sink.commands) == 50
    assert sink.outputs[-1][0] == pytest.approx(0.5, abs=1e-12)
    # wrenches were computed because the sink wants them; each joint's axis projection = its effort
    out = sink.outputs[-1][1]
    assert len(out.wrenches) == 4
    q, v = sys_.split(sim.y)
    _, S = dyn.joint_transforms(sys_.model, q)
    proj = np.array([S[:, k] @ out.wrenches[sys_.model.joint_names[k]][1] for k in range(4)])
    assert np.allclose(proj, out.effort, atol=1e-9)
