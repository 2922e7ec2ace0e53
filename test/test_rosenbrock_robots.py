"""Stiff example-robot-data robots with the defaults of ``robodyn run FILE``: a 1 s fall at 1 ms, integrator
auto (rosenbrock2 for these), against an independent oracle written here: Pinocchio parses the URDF
itself, ``pin.aba`` with the URDF's damping and the documented Coulomb law ``−f tanh(q̇/v_s)``, integrated
by scipy's Radau at rtol 1e-10 with Pinocchio's analytic ABA derivatives as its Jacobian.

Plus the inductive-motor platform (L/R = 5.9 µs) and huston_human17 at 1 ms against Radau at rtol 1e-11
on the same equations, and the bundled scenes: what auto picks for each, and why, against the table of
docs/integrators.md, with the recording of every scene where it picks the scene's own method.
"""
from __future__ import annotations

import json
import math
import re
import warnings
from pathlib import Path

import numpy as np
import pytest
from scipy.integrate import solve_ivp

import pinocchio as pin   # a test dependency: a missing oracle fails, it does not skip
from robodyn_ros.integrator_choice import DEFAULT_DT
from robodyn_ros.scene import list_scenes, load_scene
from robodyn_ros.simulation import Simulator
from robodyn_ros.systems.base import backend_scope
from robodyn_ros.urdf import example_robot_data_dir

ROOT = Path(__file__).resolve().parents[1]

ERD = example_robot_data_dir()
V_S = 0.05   # the Coulomb regularisation speed docs/urdf.md documents (rad/s or m/s)


def urdf_path(stem):
    paths = sorted(ERD.glob(f'**/{stem}.urdf'))
    assert paths, stem
    return paths[0]


def oracle(text, names, q0, horizon=1.0, rate=100.0):
    """Joint positions every 1/rate s (rows) in the order of names: Pinocchio + Radau (module docstring)."""
    pm = pin.buildModelFromXML(text)
    pd = pm.createData()
    nv = pm.nv
    jv = np.array([pm.joints[pm.getJointId(n)].idx_v for n in names])
    joints = [pm.joints[j] for j in range(1, pm.njoints)]
    D, F = np.array(pm.damping), np.array(pm.friction)

    def qp(th):
        q = pin.neutral(pm)
        for j in joints:
            if j.nq == 2:
                q[j.idx_q], q[j.idx_q + 1] = math.cos(th[j.idx_v]), math.sin(th[j.idx_v])
            elif j.nq == 1:
                q[j.idx_q] = th[j.idx_v]
        return q

    def tau(v):
        return -D * v - F * np.tanh(v / V_S)

    def f(t, x):
        return np.concatenate([x[nv:], pin.aba(pm, pd, qp(x[:nv]), x[nv:], tau(x[nv:]))])

    def jac(t, x):
        v = x[nv:]
        pin.computeABADerivatives(pm, pd, qp(x[:nv]), v, tau(v))
        Minv = np.triu(pd.Minv) + np.triu(pd.Minv, 1).T
        J = np.zeros((2 * nv, 2 * nv))
        J[:nv, nv:] = np.eye(nv)
        J[nv:, :nv] = pd.ddq_dq
        J[nv:, nv:] = pd.ddq_dv + Minv * (-D - F * (1.0 - np.tanh(v / V_S) ** 2) / V_S)[None, :]
        return J
    x0 = np.zeros(2 * nv)
    x0[jv] = q0
    ts = np.arange(1, int(round(horizon * rate)) + 1) / rate
    sol = solve_ivp(f, (0.0, ts[-1]), x0, method='Radau', rtol=1e-10, atol=1e-12, jac=jac, t_eval=ts)
    assert sol.success, sol.message
    return sol.y[jv].T


#: robot -> largest joint-position error allowed over the 1 s fall (rad or m); measured at 1 ms:
#: xarm7 5.4e-6, z1 3.5e-5 (a 2.7 rad swing of its light forearm), tiago 5.9e-6, allegro_right_hand
#: 1.2e-11 (its friction holds it): each bound ~5-8x the figure; a first-order method misses them
#: (MuJoCo's implicit integrators on xarm7: 6e-4)
FALLS = {'xarm7': 3e-5, 'z1': 2e-4, 'tiago': 3e-5, 'allegro_right_hand': 1e-10}


@pytest.mark.parametrize('robot', sorted(FALLS))
def test_stiff_robot_falls_with_the_defaults_against_pinocchio(robot):
    path = urdf_path(robot)
    with backend_scope('numba'):   # (the generated backend runs the same loop; its first compile is slow)
        scene = load_scene(str(path))
    system = scene.system
    with warnings.catch_warnings():
        warnings.simplefilter('error')          # no step warning either
        sim = Simulator(system, scene.y0)       # the defaults: integrator auto, dt = 1 ms
    assert sim.settings['integrator'] == 'rosenbrock2' and sim.settings['dt'] == 1e-3, sim.choice.reason
    with pytest.raises(ValueError, match='Use rosenbrock2') as refused:   # what rk4 says at that step
        Simulator(system, scene.y0, integrator='rk4', dt=1e-3)
    if robot == 'xarm7':   # docs/integrators.md prints this refusal, its elided middle as '...'
        block = re.search(r'```text\n(rk4 with dt=.*?)```', (ROOT / 'docs' / 'integrators.md').read_text(), re.S)
        parts = [' '.join(p.split()) for p in block.group(1).split('...')]
        message = ' '.join(str(refused.value).split())
        assert len(parts) == 2 and message.startswith(parts[0]) and message.endswith(parts[1]), (parts, message)
    q = np.array([sim.advance((k + 1) / 100.0)[:system.nq].copy() for k in range(100)])
    ref = oracle(path.read_text(), list(system.joint_names), scene.y0[:system.nq])
    err = np.abs(q - ref).max()
    assert err < FALLS[robot], err
    assert np.abs(ref).max() > 10 * FALLS[robot]   # the robot moves more than the bound


def _platform():
    from robodyn_ros.bench.extremes import _scene_variant
    return _scene_variant('betancur_platform', ('inductance: 0.0', 'inductance: 1.0e-5'))


@pytest.mark.parametrize('label, bound, reference', [('platform', 1e-7, ('radau', None, 1e-11)),
                                                     ('huston_human17', 1.5e-2, ('rk4', 1e-5, None))])
def test_stiff_bundled_systems_at_one_millisecond(label, bound, reference):
    """The platform with L/R = 5.9 µs motors (rk4 refused at 1 ms; measured 1.3e-8) against Radau at
    rtol 1e-11, and huston_human17 with its joint stops (measured 3.4e-3 relative; rk4 at 1 ms, which auto
    picks there, 2.9e-4) against rk4 at 10 µs (which agrees with 20 µs to 5e-6), 1 s at 1 ms; both order 2."""
    from robodyn_ros.bench.precision import simulate
    from robodyn_ros.measures import state_error
    with backend_scope('numba'):
        scene = _platform() if label == 'platform' else load_scene(label)
    name, dt, rtol = reference
    ref = simulate(scene, name, dt=dt, rtol=rtol, atol=None if rtol is None else rtol * 1e-2, horizon=1.0,
                   sample=False)
    run = simulate(scene, 'rosenbrock2', dt=1e-3, horizon=1.0, sample=False)
    half = simulate(scene, 'rosenbrock2', dt=5e-4, horizon=1.0, sample=False)
    assert ref.status == run.status == half.status == 'ok', (ref.note, run.note, half.note)
    e1, e2 = state_error(run.y, ref.y), state_error(half.y, ref.y)
    assert e1 < bound, e1
    assert 2.5 < e1 / e2 < 6.0, (e1, e2)          # second order: halving h divides the error by ~4
    if label == 'platform':
        assert simulate(scene, 'rk4', dt=1e-3, horizon=1.0, sample=False).status == 'refused'
        assert Simulator(scene.system, scene.y0, dt=1e-3).settings['integrator'] == 'rosenbrock2'
    else:   # rk4 at 1 ms, which auto picks for the human: measured 2.9e-4 (docs/integrators.md)
        rk4 = simulate(scene, 'rk4', dt=1e-3, horizon=1.0, sample=False)
        assert rk4.status == 'ok', rk4.note
        e4 = state_error(rk4.y, ref.y)
        assert e4 < 3e-3 and e4 < e1, (e4, e1)


def auto_table() -> dict:
    r"""docs/integrators.md's table of what auto picks for each bundled scene: scene -> (picks, why, recording),
    the cells as printed (``\|`` unescaped)."""
    text = (ROOT / 'docs' / 'integrators.md').read_text()
    rows = {}
    for line in text[text.index('**What auto picks for each bundled scene.**'):].splitlines():
        m = re.match(r'^\| `([a-z0-9_]+)` \|', line)
        if m:
            cells = [c.strip().replace('\\|', '|') for c in re.split(r'(?<!\\)\|', line)[1:-1]]
            assert len(cells) == 5, line
            rows[m.group(1)] = tuple(cells[2:])
    return rows


AUTO_TABLE = auto_table()


def test_the_auto_table_lists_every_bundled_scene_and_the_readme_counts_it():
    assert set(AUTO_TABLE) == {n for n, _ in list_scenes()}
    readme = ' '.join((ROOT / 'README.md').read_text().split())
    m = re.search(r'it picks rk4 for (\d+) of the bundled scenes and rosenbrock2 for the (\d+) robots', readme)
    picks = [row[0] for row in AUTO_TABLE.values()]
    assert m and (int(m.group(1)), int(m.group(2))) == (picks.count('rk4'), picks.count('rosenbrock2')), m


@pytest.mark.parametrize('name', sorted(AUTO_TABLE))
def test_auto_picks_for_each_bundled_scene_what_the_docs_say(name):
    """Each row of docs/integrators.md's table: auto at the scene's step picks the method the row names,
    at that step; its reason holds each phrase the row quotes and the row's h·|λ| (to its two
    significant digits); where the scene names another method, or the same under error control, the row says
    so."""
    picks, why, recording = AUTO_TABLE[name]
    with backend_scope('numba'):
        with warnings.catch_warnings():
            warnings.simplefilter('ignore')
            scene = load_scene(name)
    dt = scene.settings.get('dt', DEFAULT_DT)
    with warnings.catch_warnings():
        warnings.simplefilter('error')   # no step warning either
        sim = Simulator(scene.system, scene.y0, integrator='auto', dt=dt)
    reason = sim.choice.reason
    assert sim.settings['integrator'] == picks and sim.settings['dt'] == dt, reason
    phrases = re.findall(r'`([^`]+)`', why)
    assert phrases, why
    for phrase in phrases:
        assert phrase in reason, (phrase, reason)
    stated = re.findall(r'h·\|λ\| = ([0-9.]+)', why)
    if stated:
        measured = float(re.search(r'h·\|λ\| = ([0-9.e+-]+)', reason).group(1))
        assert abs(measured - float(stated[0])) <= 0.05 * float(stated[0]), (measured, reason)
    same = scene.settings['integrator'] == picks and scene.settings.get('rtol') is None   # auto's steps are fixed
    assert same == recording.startswith('the same'), recording


def _recording(path):
    """The messages of a recording (topic, log time, CDR bytes) and its metadata's settings."""
    from mcap.reader import make_reader

    from robodyn_ros.recording import read_raw_messages
    messages = [(topic, t, raw) for topic, _, t, raw in read_raw_messages(path)]
    with open(path, 'rb') as f:
        (meta,) = [m for m in make_reader(f).iter_metadata() if m.name == 'robodyn']
    return messages, json.loads(meta.metadata['settings'])


@pytest.mark.parametrize('name', sorted(n for n, row in AUTO_TABLE.items() if row[2].startswith('the same')))
def test_auto_records_the_same_bytes_as_the_method_it_picks(name, tmp_path, capsys):
    """Where the table says so, ``robodyn run SCENE --integrator auto`` records what ``--integrator <the
    scene's method>`` records, message for message and byte for byte (0.2 s; every default topic); the
    metadata's settings differ by auto's reason alone."""
    from robodyn_ros.cli import main
    runs = {}
    for integrator in ('auto', AUTO_TABLE[name][0]):
        path = tmp_path / f'{integrator}.mcap'
        assert main(['run', name, '--duration', '0.2', '--integrator', integrator, '--record', str(path)]) == 0
        runs[integrator] = _recording(path)
    capsys.readouterr()
    (auto_msgs, auto_st), (named_msgs, named_st) = runs['auto'], runs[AUTO_TABLE[name][0]]
    assert len(named_msgs) > 20 and auto_msgs == named_msgs
    assert auto_st.pop('auto').startswith(f'auto chose {AUTO_TABLE[name][0]}') and auto_st == named_st


def test_xarm7_with_damping_only_against_pinocchio_as_the_mujoco_comparison_has_it():
    """The speed table's xarm7 row (``robodyn bench stiff``): friction and limits removed, a 1 s fall at
    1 ms by rosenbrock2 (auto's choice) against Pinocchio's ABA + damping by Radau at rtol 1e-10.
    Measured 2.7e-7 rad; asserted < 3e-6 (MuJoCo's implicit integrators at 1 ms: 6e-4)."""
    from robodyn_ros.bench import stiff
    files = stiff.erd_urdfs(['xarm7'])
    assert files, 'example-robot-data (test extras) has xarm7'
    with open(files[0]) as f:
        text = stiff.damping_only(f.read())
    scene = stiff._load_urdf(files[0], text=text)
    s = scene.system
    ref = stiff.pinocchio_fall(text, list(s.joint_names), scene.y0[:s.nq], scene.y0[s.nq:])
    q, sim, _ = stiff.robodyn_fall(scene, repeat=1)
    assert sim.settings['integrator'] == 'rosenbrock2'
    err = float(np.max(np.abs(q - ref)))
    assert err < 3e-6, err


def test_xarm7_the_small_root_is_the_accurate_one():
    """docs/integrators.md: γ = 1 − 1/√2 (the compiled loop's, when no stop or contact is in J) against the
    paper's 1 + 1/√2 on the same J, xarm7 (damping only) falling 1 s at 1 ms, the generic W-method step
    (:class:`robodyn_ros.integrators.Rosenbrock2`, an LU of I − γhJ on the state) against Pinocchio.
    Measured 2.7e-7 rad (the compiled loop's, to round-off) and 8.2e-6 rad."""
    from robodyn_ros.bench import stiff
    from robodyn_ros.integrators import make_integrator
    files = stiff.erd_urdfs(['xarm7'])
    assert files, 'example-robot-data (test extras) has xarm7'
    with open(files[0]) as f:
        text = stiff.damping_only(f.read())
    scene = stiff._load_urdf(files[0], text=text)
    s, h = scene.system, 1e-3
    u = s.zero_inputs()
    ref = stiff.pinocchio_fall(text, list(s.joint_names), scene.y0[:s.nq], scene.y0[s.nq:])
    err = {}
    for gamma in (1.0 - 1.0 / math.sqrt(2.0), 1.0 + 1.0 / math.sqrt(2.0)):
        integ = make_integrator('rosenbrock2', dt=h, jac=lambda t, y: s.passive_jacobian(t, y, u, h), gamma=gamma)
        y, q = scene.y0.copy(), []
        for k in range(100):
            y, _ = integ.advance(lambda t, y: s.rhs(t, y, u), k / 100, y, (k + 1) / 100, project=s.project)
            q.append(y[:s.nq].copy())
        err[gamma] = float(np.max(np.abs(np.array(q) - ref)))
    small, large = err.values()
    assert small < 3e-6 < large < 1e-4, err
