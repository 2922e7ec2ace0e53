"""Which integrator, which step, and why: decided once per run, in one room (robodyn_ros.integrator_choice).

Wherever a run starts (``robodyn run``, the node's configuration, a sweep task, a Simulator built
directly), :func:`~robodyn_ros.integrator_choice.plan_integrator` is asked once, and the state is
linearised once per state the analysis looks at; the Simulator handed a plan does not ask again. The
defaults a user reads in ``robodyn run --help`` and in the documents are the constants the code uses.
"""
from __future__ import annotations

import re
import subprocess
import sys
import warnings
from pathlib import Path

import numpy as np
import pytest

from robodyn_ros import integrator_choice as IC
from robodyn_ros import stability
from robodyn_ros.scene import load_scene
from robodyn_ros.simulation import Simulator

ROOT = Path(__file__).resolve().parents[1]


class Counts:
    """Counts the calls of plan_integrator (wherever it is looked up) and of the linearisation."""

    def __init__(self, monkeypatch):
        import robodyn_ros.simulation as simulation
        self.plans, self.linearisations = 0, 0
        plan, lin = IC.plan_integrator, stability.linearisation

        def counted_plan(*a, **kw):
            self.plans += 1
            return plan(*a, **kw)

        def counted_lin(*a, **kw):
            self.linearisations += 1
            return lin(*a, **kw)
        monkeypatch.setattr(IC, 'plan_integrator', counted_plan)
        monkeypatch.setattr(simulation, 'plan_integrator', counted_plan)
        monkeypatch.setattr(stability, 'linearisation', counted_lin)


@pytest.mark.parametrize('scene, integrator, states', [('stanford_arm', 'auto', 1), ('stanford_arm', 'rk4', 1),
                                                       ('a1_stand', 'auto', 2), ('stanford_arm', 'dop853', 0)])
def test_robodyn_run_decides_once(scene, integrator, states, monkeypatch, capsys):
    """auto on stanford_arm linearises its initial state once; on a1_stand also resting on the ground;
    a named rk4 is analysed once; an error-controlled method not at all. (Before, ``robodyn run`` asked
    auto, then the Simulator analysed the method auto had named again.)"""
    from robodyn_ros.cli import main
    n = Counts(monkeypatch)
    assert main(['run', scene, '--duration', '0.02', '--integrator', integrator]) == 0
    out = capsys.readouterr().out
    assert n.plans == 1 and n.linearisations == states, (n.plans, n.linearisations)
    assert ('auto chose' in out) == (integrator == 'auto'), out


def test_the_node_configuration_decides_once_and_the_simulator_takes_its_plan(monkeypatch):
    from robodyn_ros.nodes.config import PARAMETERS, resolve_config
    scene = load_scene('stanford_arm')
    raw = {k: d for k, (d, _) in PARAMETERS.items()}
    n = Counts(monkeypatch)
    cfg = resolve_config({**raw, 'integrator': 'auto'}, scene)
    sim = Simulator(scene.system, cfg.y0, plan=cfg.plan, command_timeout=cfg.command_timeout)
    assert n.plans == 1 and n.linearisations == 1
    assert sim.plan is cfg.plan and sim.choice is cfg.plan and cfg.auto == cfg.plan.reason
    assert cfg.settings('')['auto'] == sim.settings['auto'] == cfg.plan.reason
    assert (cfg.integrator, cfg.dt) == (sim.settings['integrator'], sim.settings['dt']) == ('rk4', 1e-3)


def test_a_sweep_task_decides_once_per_run(tmp_path, monkeypatch):
    """One task with a reference run of another method: one plan for the run, one for its reference."""
    from robodyn_ros import sweep as S
    spec = tmp_path / 'spec.yaml'
    spec.write_text('scene: stanford_arm\nduration: 0.05\ngrid: {integrator: [auto]}\n'
                    'figures: [final_error]\nreference: {integrator: rk4, dt: 1.0e-4}\n')
    (task,) = S.expand(S.load_spec(str(spec)))
    n = Counts(monkeypatch)
    row = S.execute_run(task)['row']
    assert row['status'] == 'ok' and row['integrator'] == 'rk4' and row['final_error'] > 0, row
    assert n.plans == 2 and n.linearisations == 2, (n.plans, n.linearisations)


def test_a_refused_step_keeps_its_settings_in_the_sweep_row(tmp_path):
    """A named step the plan refuses: the row is 'refused', with the message and the method and step
    that were refused (auto's refusals name none)."""
    from robodyn_ros import sweep as S
    spec = tmp_path / 'spec.yaml'
    spec.write_text('scene: betancur_pendulum\nduration: 0.1\ngrid: {integrator: [euler], dt: [0.5]}\n'
                    'figures: [energy_drift]\n')
    (task,) = S.expand(S.load_spec(str(spec)))
    row = S.execute_run(task)['row']
    assert row['status'] == 'refused' and 'dt=0.5' in row['message'], row
    assert (row['integrator'], row['dt'], row['duration']) == ('euler', 0.5, 0.1)


def test_the_plan_of_a_named_method_and_of_auto():
    scene = load_scene('stanford_arm')
    s, y0 = scene.system, scene.y0
    rk4 = IC.plan_integrator(s, y0, 'RK4', 2e-3)
    assert (rk4.integrator, rk4.dt, rk4.auto, rk4.reason, rk4.warnings) == ('rk4', 2e-3, False, '', ())
    assert rk4.analysis.verdict == 'ok' and rk4.step_budget == IC.STEP_BUDGET and rk4.fixed_step
    auto = IC.plan_integrator(s, y0)
    assert (auto.integrator, auto.dt, auto.auto) == ('rk4', IC.DEFAULT_DT, True)
    assert auto.settings() == {'integrator': 'rk4', 'dt': IC.DEFAULT_DT, 'rtol': None, 'atol': None,
                               'auto': auto.reason} and auto.reason.startswith('auto chose rk4 at dt=0.001 s')
    adaptive = IC.plan_integrator(s, y0, 'dop853', None, 1e-9, 1e-12, step_budget=float('inf'))
    assert adaptive.analysis is None and not adaptive.fixed_step and adaptive.step_budget == float('inf')
    with pytest.raises(ValueError, match="unknown integrator 'rk5'; valid names: euler, "):
        IC.plan_integrator(s, y0, 'rk5')
    with pytest.raises(ValueError, match='step_budget must be a number of steps per simulated second > 0'):
        IC.plan_integrator(s, y0, step_budget=0)
    with pytest.raises(ValueError, match=r'integrator auto needs a step dt > 0 \(s\), got 0'):
        IC.plan_integrator(s, y0, 'auto', 0.0)


def test_a_warning_of_the_plan_is_given_by_the_simulator_that_adopts_it():
    """Explicit Euler on an undamped pendulum: the plan carries the warning, each Simulator built from
    it gives it (a sweep catches it there and writes it in its row)."""
    scene = load_scene('betancur_pendulum')
    plan = IC.plan_integrator(scene.system, scene.y0, 'euler', 1e-3)
    assert len(plan.warnings) == 1 and 'doubles it every' in plan.warnings[0]
    with pytest.warns(stability.StepWarning, match='doubles it every'):
        Simulator(scene.system, scene.y0, plan=plan)
    with warnings.catch_warnings():
        warnings.simplefilter('error')
        Simulator(scene.system, scene.y0, plan=IC.plan_integrator(scene.system, scene.y0, 'rk4', 1e-3))


def test_the_step_budget_bucket():
    """STEP_BURST seconds' worth at the start; a call over W seconds may take the bucket plus W's worth."""
    b = IC.StepBudget(1e4)
    assert b.limit(0.01) == int(1e4 * IC.STEP_BURST + 100)
    b.spend(b.limit(0.01), 600)              # took 600 of 600: nothing left over
    assert b.limit(0.01) == 100
    b.spend(100, 10)
    assert b.limit(0.0) == 90
    b.reset()
    assert b.limit(0.0) == int(1e4 * IC.STEP_BURST)
    assert IC.StepBudget(float('inf')).limit(1.0) is None


def _help() -> str:
    r = subprocess.run([sys.executable, '-m', 'robodyn_ros.cli', 'run', '--help'], capture_output=True, text=True,
                       cwd=ROOT)
    assert r.returncode == 0, r.stderr
    return ' '.join(r.stdout.split())


def test_the_defaults_robodyn_run_help_prints_are_the_code_s():
    """The step budget's default in ``robodyn run --help`` (it once said 1e6 where the code had 2e5), and
    the step's, the rate's and the diagnostics period's, are the constants the run uses."""
    from robodyn_ros.runs import DEFAULT_RATE, DIAGNOSTICS_PERIOD
    text = _help()
    budget = re.search(r'--step-budget N .*?simulation\.step_budget, else ([0-9.e+]+); inf: none', text)
    assert budget and float(budget.group(1)) == IC.STEP_BUDGET, text
    dt = re.search(r"--dt DT fixed step \(s\) for fixed-step integrators \(default: the scene's, else ([0-9.e-]+)\)",
                   text)
    assert dt and float(dt.group(1)) == IC.DEFAULT_DT, text
    rate = re.search(r"--rate RATE .*?\(default: the scene's, else ([0-9.]+)\)", text)
    assert rate and float(rate.group(1)) == DEFAULT_RATE, text
    period = re.search(r'--diagnostics-period DIAGNOSTICS_PERIOD .*?\(default ([0-9.]+)\)', text)
    assert period and float(period.group(1)) == DIAGNOSTICS_PERIOD, text


#: where the documents and the node's configuration state the step budget's default: (file, pattern)
BUDGET_STATED = [('README.md', r'past (\S+) accepted steps per simulated second'),
                 ('docs/node.md', r"\| `step_budget` \| scene's \((\S+)\) \|"),
                 ('docs/node.md', r"`simulation:` value, else (\S+) \|"),
                 ('docs/scenes.md', r'default (\S+), `\.inf`'),
                 ('config/sim.yaml', r'naming the stiff mode; \.inf = none; 0 = scene, else (\S+)')]


def test_the_documents_state_the_step_budget_the_code_uses():
    found = []
    for file, pattern in BUDGET_STATED:
        text = ' '.join((ROOT / file).read_text().split())
        m = re.search(pattern, text)
        assert m, (file, pattern)
        found.append((file, float(m.group(1))))
    assert len(found) == len(BUDGET_STATED) and all(v == IC.STEP_BUDGET for _, v in found), found


def test_a_simulator_handed_a_plan_builds_its_integrator_from_it_alone():
    """The plan's method and step are what runs, whatever else the constructor is given."""
    scene = load_scene('stanford_arm')
    plan = IC.plan_integrator(scene.system, scene.y0, 'rk4', 5e-4)
    sim = Simulator(scene.system, scene.y0, integrator='euler', dt=0.1, plan=plan)
    assert sim.integrator.name == 'rk4' and sim.integrator.dt == 5e-4 and sim.choice is None
    sim.advance(0.01)
    assert sim.diag.steps == 20 and np.all(np.isfinite(sim.y))
