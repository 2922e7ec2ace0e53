"""The step budget of the error-controlled integrators: a stiff scene under an explicit pair stops
with the integrator, the steps and the stiff mode named, instead of running for hours.

The stiff scene: a 1 kg bar carrying a light disk (I = 1e-7 kg·m² about its pin) on a heavily
damped pin (c = 1 N·m·s/rad), so the disk's spin decays with the time constant I / c = 1e-7 s
(|λ| = c / I = 1e7 1/s, closed form), while the bar swings with a period of about a second. An
explicit method needs steps of that time constant for the whole run: rk45 would take ~1e8 steps
for 10 s.
"""
from __future__ import annotations

import math
import re
import subprocess
import sys

import numpy as np
import pytest

from robodyn_ros import integrator_choice as IC
from robodyn_ros.scene import SceneError, parse_scene
from robodyn_ros.simulation import SimulationError, Simulator, run_headless

I_DISK, C_PIN = 1e-7, 1.0

STIFF = f"""\
name: stiff_light_link
description: a pendulum carrying a light disk on a heavily damped pin
gravity: [0.0, 0.0, -9.81]
parts:
  - kind: arm
    name: arm
    mount: world
    links:
      - {{name: bar, joint: joint1, parent: base_link, type: revolute, origin: {{xyz: [0, 0, 0], rpy: [1.5707963267948966, 0, 0]}},
         axis: [0, 0, 1], mass: 1.0, com: [0.25, 0, 0], inertia: [0.001, 0.02, 0.02, 0, 0, 0]}}
      - {{name: disk, joint: joint2, parent: bar, type: revolute, origin: {{xyz: [0.5, 0, 0], rpy: [0, 0, 0]}},
         axis: [0, 0, 1], mass: 0.001, com: [0, 0, 0], inertia: [{I_DISK}, {I_DISK}, {I_DISK}, 0, 0, 0], damping: {C_PIN}}}
initial_state: {{q: [0.5, 0.0], v: [0.0, 3.0]}}
simulation: {{integrator: rk45, rtol: 1.0e-8, atol: 1.0e-10, duration: 10.0}}
"""


def _run(tmp_path, *args, text=STIFF):
    path = tmp_path / 'stiff.yaml'
    path.write_text(text)
    return subprocess.run([sys.executable, '-m', 'robodyn_ros.cli', 'run', str(path), *args], capture_output=True,
                          text=True, timeout=600)


@pytest.mark.parametrize('integrator, budget', [('rk45', None), ('dop853', 5e4)])
def test_stiff_scene_under_an_explicit_pair_stops_naming_the_integrator_the_steps_and_the_mode(
        tmp_path, integrator, budget):
    """``robodyn run`` (10 s asked) exits 1 within the budget's steps; the message names the
    integrator, the steps taken, the mode (|λ| = c / I within 1 %, the disk joint's velocity) and
    the implicit integrators; no traceback."""
    args = ['--integrator', integrator] + (['--step-budget', str(budget)] if budget else [])
    r = _run(tmp_path, *args)
    assert r.returncode == 1, r.stdout + r.stderr
    err = r.stderr
    assert 'Traceback' not in err and err.startswith('robodyn run: simulation stopped: '), err
    m = re.search(rf'{integrator} spent its step budget: (\d+) steps for ([0-9.e+-]+) s of simulated time '
                  rf'\(budget ([0-9.e+-]+) steps per simulated second\)', err)
    assert m, err
    steps, t, b = int(m.group(1)), float(m.group(2)), float(m.group(3))
    assert b == (budget or IC.STEP_BUDGET)
    period_end = math.ceil(t / 0.01) * 0.01             # a call's budget covers its whole 10 ms period
    assert steps <= b * (period_end + IC.STEP_BURST) + 1   # the budget holds
    assert t < 0.1                                      # of the 10 s asked: stopped early
    lam = float(re.search(r'\|λ\| = ([0-9.e+-]+) 1/s', err).group(1))
    assert lam == pytest.approx(C_PIN / I_DISK, rel=1e-2), err
    assert "the velocity of joint 'joint2'" in err and 'radau, bdf' in err
    assert 'FAILED       ' + integrator in r.stdout     # the summary says so too


def test_an_implicit_integrator_runs_the_stiff_scene_within_the_budget(tmp_path):
    """The same scene under radau runs its 0.5 s (a stiff solver is stable on the fast mode)."""
    r = _run(tmp_path, '--integrator', 'radau', '--duration', '0.5')
    assert r.returncode == 0, r.stdout + r.stderr
    steps = int(re.search(r'(\d+) steps,', r.stdout).group(1))
    assert 0 < steps < IC.STEP_BUDGET * 0.5 / 100, r.stdout   # far below the budget


def test_the_budget_comes_from_the_scene_the_option_or_the_default(tmp_path):
    """``simulation.step_budget`` sets it, ``--step-budget`` overrides it, ``inf`` removes it: 3 ms
    of the stiff scene under rk45 (~1e4 steps) stop under a budget of 1e4/s and run without one."""
    short = STIFF.replace('duration: 10.0', 'duration: 0.003, publish_rate: 1000.0')
    scene = parse_scene(short)
    sim = Simulator(scene.system, scene.y0, integrator='rk45', rtol=1e-8, atol=1e-10)
    run_headless(sim, 0.003, 1000.0, None, [])                      # the default budget: no stop
    taken = sim.diag.steps
    assert taken > 1e4 * (0.003 + IC.STEP_BURST)                   # ... above a budget of 1e4 per second
    r = _run(tmp_path, text=short.replace('duration: 0.003', 'duration: 0.003, step_budget: 1.0e+4'))
    assert r.returncode == 1 and 'budget 1e+04 steps per simulated second' in r.stderr, r.stderr
    r = _run(tmp_path, '--step-budget', 'inf', text=short.replace('duration: 0.003', 'duration: 0.003, step_budget: 1.0e+4'))
    assert r.returncode == 0, r.stderr
    assert f'{taken} steps' in r.stdout                             # the same run as the default's
    for bad in ('-1', '0', 'true', "'many'"):
        with pytest.raises(SceneError, match=r'simulation\.step_budget: expected a number of steps per simulated '
                                             r'second > 0'):
            parse_scene(short.replace('duration: 0.003', f'duration: 0.003, step_budget: {bad}'))
    r = _run(tmp_path, '--step-budget', '-5', text=short)
    assert r.returncode == 2 and 'step_budget must be a number of steps per simulated second > 0' in r.stderr


STOP = """\
name: stiff_stop
gravity: [0.0, 0.0, -0.5]
parts:
  - kind: arm
    name: arm
    mount: world
    links:
      - {name: bar, joint: joint1, parent: base_link, type: revolute, origin: {xyz: [0, 0, 0], rpy: [1.5707963267948966, 0, 0]},
         axis: [0, 0, 1], mass: 1.0, com: [0.25, 0, 0], inertia: [0.001, 0.02, 0.02, 0, 0, 0],
         limits: {lower: -1.0, upper: 1.0, stiffness: 1.0e+9, damping: 1.0e+5}}
initial_state: {q: [0.0], v: [0.0]}
"""


def test_a_run_that_turns_stiff_late_stops_soon_after_whatever_it_saved_before(monkeypatch):
    """A bar falls (slowly: g = 0.5) onto a stiff, heavily damped joint-limit stop, bounces and comes
    to rest on it at t ≈ 1.54 s; resting there is stiff (|λ| ≈ 6e5 1/s). Under rk45 with a budget of
    2e4 steps/s the first 1.5 s take a few steps per period, yet the run stops within 0.06 s of
    coming to rest: the bucket holds STEP_BURST seconds' worth, not what the smooth part left over
    (that would be 3e4 steps, 0.15 s more). Every stretch of periods keeps budget·(W + STEP_BURST)."""
    scene = parse_scene(STOP)
    budget = 2e4
    calls = []
    sim = Simulator(scene.system, scene.y0, integrator='rk45', rtol=1e-8, atol=1e-10, step_budget=budget)
    advance = sim.integrator.advance

    def counting(f, t0, y0, t1, project=None, max_steps=None):
        calls.append([t0, t1, max_steps, max_steps])   # a call that raises spent its cap
        y, st = advance(f, t0, y0, t1, project=project, max_steps=max_steps)
        calls[-1][3] = st.steps
        return y, st
    monkeypatch.setattr(sim.integrator, 'advance', counting)
    with pytest.raises(SimulationError, match=r"rk45 spent its step budget.*\|λ\| = [0-9.e+]+ 1/s .*joint 'joint1'"):
        run_headless(sim, 5.0, 1000.0, None, [])
    assert 1.5 < sim.t < 1.6, sim.t
    assert sum(c[3] for c in calls if c[1] <= 1.0) < 0.1 * budget       # the smooth part: little spent
    t0, t1, n = (np.array([c[k] for c in calls], dtype=float) for k in (0, 1, 3))
    spent = np.concatenate([[0.0], np.cumsum(n)])
    for i in range(len(calls)):   # steps of calls i..j against the budget of [t0_i, t1_j]
        assert np.all(spent[i + 1:] - spent[i] <= budget * (t1[i:] - t0[i] + IC.STEP_BURST) + 1), i


def test_node_parameter_step_budget():
    """The node takes ``step_budget`` (0: the scene's or the default; .inf: none; records it)."""
    from robodyn_ros.nodes.config import PARAMETERS, ConfigError, resolve_config
    scene = parse_scene(STIFF)
    raw = {k: v for k, (v, _) in PARAMETERS.items()}
    assert resolve_config(raw, scene).step_budget is None
    cfg = resolve_config(dict(raw, step_budget=5e4), scene)
    assert cfg.step_budget == 5e4 and cfg.settings('')['step_budget'] == 5e4
    assert resolve_config(dict(raw, step_budget=math.inf), scene).step_budget == math.inf
    assert 'step_budget' not in resolve_config(raw, scene).settings('')   # recordings keep their settings
    with pytest.raises(ConfigError, match="parameter 'step_budget'"):
        resolve_config(dict(raw, step_budget=-1.0), scene)
