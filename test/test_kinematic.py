"""Prescribed joint motion (part kind ``kinematic_arm``): the expression evaluator's exact
derivatives, its whitelist, scene errors, and the inverse-dynamics efforts against Pinocchio —
on a synthetic arm with non-zero accelerations, and on the recording of Betancur's DH animation
(seed 001) decoded with the independent mcap / mcap_ros2 readers and checked against
``pin.rnea`` on a Pinocchio model rebuilt from the recorded ``robot_description``.
"""
from __future__ import annotations

import subprocess
import sys

import numpy as np
import pinocchio as pin
import pytest
import yaml

from robodyn_ros.expressions import ExpressionError, parse_time_function
from robodyn_ros.scene import SceneError, load_scene, parse_scene
from robodyn_ros.simulation import Simulator
from robodyn_ros.systems.base import backend_scope

PI = np.pi

# text, f, f', f'' -- the derivatives written by hand
CASES = [
    ('pi*t', lambda t: PI * t, lambda t: PI + 0 * t, lambda t: 0 * t),
    ('pi/3 + t', lambda t: PI / 3 + t, lambda t: 1 + 0 * t, lambda t: 0 * t),
    ('t', lambda t: t, lambda t: 1 + 0 * t, lambda t: 0 * t),
    ('pi/4 + t', lambda t: PI / 4 + t, lambda t: 1 + 0 * t, lambda t: 0 * t),
    ('pi*t/8', lambda t: PI * t / 8, lambda t: PI / 8 + 0 * t, lambda t: 0 * t),
    ('sin(2*t)**2', lambda t: np.sin(2 * t) ** 2, lambda t: 2 * np.sin(4 * t), lambda t: 8 * np.cos(4 * t)),
    ('t**3 - 2*t', lambda t: t ** 3 - 2 * t, lambda t: 3 * t ** 2 - 2, lambda t: 6 * t),
    ('exp(-t/2)*cos(3*t)', lambda t: np.exp(-t / 2) * np.cos(3 * t),
     lambda t: np.exp(-t / 2) * (-0.5 * np.cos(3 * t) - 3 * np.sin(3 * t)),
     lambda t: np.exp(-t / 2) * (-8.75 * np.cos(3 * t) + 3 * np.sin(3 * t))),
    ('1/(1 + t*t)', lambda t: 1 / (1 + t * t), lambda t: -2 * t / (1 + t * t) ** 2,
     lambda t: (6 * t * t - 2) / (1 + t * t) ** 3),
    ('sqrt(1 + t)', lambda t: np.sqrt(1 + t), lambda t: 0.5 / np.sqrt(1 + t), lambda t: -0.25 * (1 + t) ** -1.5),
    ('log(2 + t)', lambda t: np.log(2 + t), lambda t: 1 / (2 + t), lambda t: -1 / (2 + t) ** 2),
    ('tan(t/4)', lambda t: np.tan(t / 4), lambda t: 0.25 / np.cos(t / 4) ** 2,
     lambda t: 0.125 * np.tan(t / 4) / np.cos(t / 4) ** 2),
    ('2**t', lambda t: 2 ** t, lambda t: np.log(2) * 2 ** t, lambda t: np.log(2) ** 2 * 2 ** t),
    ('t**t', lambda t: t ** t, lambda t: t ** t * (np.log(t) + 1), lambda t: t ** t * ((np.log(t) + 1) ** 2 + 1 / t)),
    ('arctan(t)', np.arctan, lambda t: 1 / (1 + t * t), lambda t: -2 * t / (1 + t * t) ** 2),
    ('arcsin(t/4) + arccos(t/4)', lambda t: PI / 2 + 0 * t, lambda t: 0 * t, lambda t: 0 * t),
    ('cosh(t) - sinh(t)', lambda t: np.exp(-t), lambda t: -np.exp(-t), lambda t: np.exp(-t)),
    ('tanh(t)', np.tanh, lambda t: 1 - np.tanh(t) ** 2, lambda t: -2 * np.tanh(t) * (1 - np.tanh(t) ** 2)),
    ('-t + +t*2 - e', lambda t: t - np.e, lambda t: 1 + 0 * t, lambda t: 0 * t),
    ('0.5', lambda t: 0.5 + 0 * t, lambda t: 0 * t, lambda t: 0 * t),
]


@pytest.mark.parametrize('text,f,d1,d2', CASES, ids=[c[0] for c in CASES])
def test_jets_equal_closed_form_derivatives(text, f, d1, d2):
    """q, q', q'' from the evaluator equal the hand-written derivatives (arrays and scalars)."""
    t = np.random.default_rng(7).uniform(0.1, 3.0, size=50)
    fn = parse_time_function(text)
    for got, want in zip(fn.jet(t), (f(t), d1(t), d2(t))):
        assert got.shape == t.shape
        assert np.abs(got - want).max() <= 1e-13 * max(1.0, np.abs(want).max()), text   # worst case 8.7e-16
    assert fn.jet(float(t[3])) == pytest.approx((f(t[3]), d1(t[3]), d2(t[3])), rel=1e-12, abs=1e-12)
    assert isinstance(fn.jet(0.5)[0], float)


@pytest.mark.parametrize('text', [
    "__import__('os').system('true')", 't.real', 'x + 1', 'sin(t, 2)', 'sin(x=t)', 't if t else 1', '[t]',
    'lambda: 1', 't < 1', 'abs(t)', 'np.sin(t)', "'a'", 'True', 't % 2', 't // 2', '(t, t)', '', '   ',
    'sin(t', 't; 1', '1j * t', 'getattr(t, "real")'])
def test_whitelist_refuses_everything_else(text):
    with pytest.raises(ExpressionError):
        parse_time_function(text)


_ARM = """
name: k
gravity: [0.0, -3.0, -9.81]
parts:
  - kind: kinematic_arm
    name: arm
    links:
      - {name: l1, joint: j1, parent: base_link, type: revolute, axis: [0.0, 0.0, 1.0], damping: 0.3,
         mass: 1.5, com: [0.2, 0.05, 0.0], inertia: [0.01, 0.02, 0.025, 0.001, 0.0, 0.002]}
      - {name: l2, joint: j2, parent: l1, type: prismatic, origin: {xyz: [0.4, 0.0, 0.1], rpy: [0.3, -0.2, 0.5]},
         axis: [1.0, 0.0, 0.0], mass: 0.8, com: [0.1, 0.0, 0.03], inertia: [0.004, 0.006, 0.007, 0.0, 0.0005, 0.0]}
      - {name: l3, joint: j3, parent: l2, type: revolute, origin: {xyz: [0.2, 0.1, 0.0], rpy: [1.1, 0.0, 0.0]},
         axis: [0.0, 0.6, 0.8], mass: 0.6, com: [0.15, 0.0, 0.0], inertia: [0.002, 0.004, 0.004, 0.0, 0.0, 0.0]}
    motion:
%s
"""
_MOTION = {'j1': 'sin(2*t) + 0.3*t', 'j2': '0.1 + 0.05*cos(3*t)', 'j3': 'exp(-t)*sin(5*t)'}


def _motion_closed_form(t):
    """q, q', q'' of _MOTION written by hand."""
    q = np.array([np.sin(2 * t) + 0.3 * t, 0.1 + 0.05 * np.cos(3 * t), np.exp(-t) * np.sin(5 * t)])
    qd = np.array([2 * np.cos(2 * t) + 0.3, -0.15 * np.sin(3 * t),
                   np.exp(-t) * (5 * np.cos(5 * t) - np.sin(5 * t))])
    qdd = np.array([-4 * np.sin(2 * t), -0.45 * np.cos(3 * t),
                    np.exp(-t) * (-24 * np.sin(5 * t) - 10 * np.cos(5 * t))])
    return q, qd, qdd


def _arm_text(motion=_MOTION, extra=''):
    return _ARM % '\n'.join(f'      {k}: {v}' for k, v in motion.items()) + extra


@pytest.mark.parametrize('backend', ['numpy', 'numba'])
def test_efforts_equal_pinocchio_rnea_with_accelerations(backend):
    """A branched-axis arm with a prismatic joint, damping and oblique gravity: the published
    effort is RNEA(q, q', q'') + D q' by Pinocchio with the hand-derived q, q', q'', and the
    joint wrenches are Pinocchio's joint forces."""
    with backend_scope(backend):
        sc = parse_scene(_arm_text(), 'k.yaml')
    sysm = sc.system
    assert sysm.backend == backend and sysm.inputs == {} and sc.y0.tolist() == [0.0]
    m = sysm.model
    pm = pin.buildModelFromXML(sysm.urdf())
    pm.gravity.linear = np.array([0.0, -3.0, -9.81])
    pd = pm.createData()
    iv = [pm.joints[pm.getJointId(j)].idx_v for j in ('j1', 'j2', 'j3')]
    damping = np.array([0.3, 0.0, 0.0])
    n, worst, worst_w = 0, 0.0, 0.0
    for t in np.random.default_rng(8).uniform(0.0, 4.0, size=12):
        q, qd, qdd = _motion_closed_form(t)
        qp, vp, ap = np.empty(3), np.empty(3), np.empty(3)
        qp[iv], vp[iv], ap[iv] = q, qd, qdd
        tau_ref = pin.rnea(pm, pd, qp, vp, ap)[iv] + damping * qd
        out = sysm.outputs(t, np.array([t]), {})
        assert np.abs(out.position - q).max() < 1e-14 and np.abs(out.velocity - qd).max() < 1e-14
        worst = max(worst, np.abs(out.effort - tau_ref).max() / np.abs(tau_ref).max())
        for jn in ('j1', 'j2', 'j3'):
            fj = pd.f[pm.getJointId(jn)]
            ref = np.concatenate([fj.angular, fj.linear])
            worst_w = max(worst_w, np.abs(out.wrenches[jn][1] - ref).max() / max(1.0, np.abs(ref).max()))
            assert out.wrenches[jn][0] == m.link_names[m.joint_names.index(jn)]
        n += 1
    assert n == 12
    print(f'prescribed motion ({backend}) vs pin.rnea: efforts {worst:.1e}, wrenches {worst_w:.1e} relative')
    assert worst <= 6e-14 and worst_w <= 6e-14    # ~100x the figures of docs/accuracy.md (round-off)


def test_energy_balance_is_the_work_of_the_efforts():
    """The Simulator integrates q'·RNEA as the work in; E(t) − E0 − W stays at quadrature error,
    and the clock state equals t."""
    sc = parse_scene(_arm_text(), 'k.yaml')
    sim = Simulator(sc.system, sc.y0, integrator='rk4', dt=1e-3)
    works, drifts = [], []
    for k in range(1, 301):
        sim.advance(k * 0.01)
        e = sim.energy_report()
        works.append(abs(e['work']))
        drifts.append(abs(e['drift']))
    assert abs(sim.y[0] - 3.0) < 1e-12
    assert max(works) > 1.0  # the efforts move energy in and out (the net over 3 s is small)
    print(f'prescribed motion: energy balance {max(drifts) / max(works):.1e} of the work')
    assert max(drifts) < 8e-11 * max(works), (max(drifts), max(works))   # RK4 quadrature: measured 8e-13


@pytest.mark.parametrize('edit,where', [
    (lambda t: t.replace('      j3: exp(-t)*sin(5*t)\n', ''), 'parts[0].motion.j3: missing'),
    (lambda t: t.replace('exp(-t)*sin(5*t)', 'os.system(1)'), 'parts[0].motion.j3'),
    (lambda t: t.replace('exp(-t)*sin(5*t)', 'log(t)'), 'parts[0].motion.j3: '),
    (lambda t: t + '      j9: t\n', 'parts[0].motion.j9: unknown key'),
    (lambda t: t + 'initial_state: {q: [0.0, 0.0, 0.0]}\n', 'initial_state: the joints follow'),
    (lambda t: t + 'commands: {effort: {profile: zero}}\n', "commands.effort: unknown input port"),
    (lambda t: t.replace('    name: arm\n', '    name: arm\n    actuated: [j1]\n'), 'parts[0].actuated: unknown key'),
])
def test_scene_errors_name_the_key(edit, where):
    with pytest.raises(SceneError) as e:
        parse_scene(edit(_arm_text()), 'k.yaml')
    assert str(e.value).startswith('k.yaml: ') and where in str(e.value), str(e.value)


def test_non_finite_motion_stops_the_run_with_the_joint_named():
    """sqrt(1 - t) is fine at t = 0 but not beyond 1 s: the run stops there, no NaN published."""
    sc = parse_scene(_arm_text({**_MOTION, 'j2': 'sqrt(1 - t)'}), 'k.yaml')
    sim = Simulator(sc.system, sc.y0, integrator='rk4', dt=1e-3)
    sim.advance(0.9)
    from robodyn_ros.simulation import SimulationError
    with pytest.raises(SimulationError, match=r"\['j2'\].*sqrt\(1 - t\)"):
        sim.advance(1.1)
    assert sim.t == pytest.approx(0.9) and np.all(np.isfinite(sim.outputs().effort))


# ---------------------------------------------------------------------------------------------
# Betancur's DH animation: the recording against Pinocchio
# ---------------------------------------------------------------------------------------------
BETANCUR = {  # joint: (q(t), q'(t)); all q'' = 0 (the animation's functions are linear in t)
    'joint0': (lambda t: PI * t, PI), 'joint1': (lambda t: PI / 3 + t, 1.0), 'joint2': (lambda t: t, 1.0),
    'joint2_alpha': (lambda t: PI / 4 + t, 1.0), 'joint3': (lambda t: PI * t / 8, PI / 8)}


@pytest.fixture(scope='module')
def betancur_recording(tmp_path_factory):
    out = tmp_path_factory.mktemp('betancur') / 'anim.mcap'
    p = subprocess.run([sys.executable, '-m', 'robodyn_ros.cli', 'run', 'betancur_dh_animation', '--duration', '3',
                        '--record', str(out)], capture_output=True, text=True, timeout=300)
    assert p.returncode == 0, p.stdout + p.stderr
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory
    msgs, meta = {}, {}
    with open(out, 'rb') as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        for m in reader.iter_metadata():
            meta[m.name] = dict(m.metadata)
        for _, channel, message, msg in reader.iter_decoded_messages():
            msgs.setdefault(channel.topic, []).append((message.log_time, msg))
    return msgs, meta


def test_betancur_recording_efforts_equal_pinocchio_rnea(betancur_recording):
    """Every recorded joint_states message: positions and velocities are the seed's functions of
    its stamp, and the efforts are Pinocchio's RNEA of (q, q', 0) on the recorded URDF (gravity
    from the recorded scene) to 1e-13 relative; the recorded joint wrenches are Pinocchio's."""
    msgs, meta = betancur_recording
    assert len(msgs['/joint_states']) == 301 and len(msgs['/robot_description']) == 1
    assert len(msgs['/tf']) == 301 and len(msgs['/tf_static']) == 1
    for j in BETANCUR:
        assert len(msgs[f'/constraint_wrenches/{j}']) == 301
    pm = pin.buildModelFromXML(msgs['/robot_description'][0][1].data)
    pm.gravity.linear = np.array(yaml.safe_load(meta['robodyn']['scene'])['gravity'], dtype=float)
    assert np.allclose(pm.gravity.linear, [0.0, 0.0, -9.8])
    pd = pm.createData()
    wrenches = {j: dict(msgs[f'/constraint_wrenches/{j}']) for j in BETANCUR}
    worst = worst_w = 0.0
    for log_time, js in msgs['/joint_states']:
        t = js.header.stamp.sec + js.header.stamp.nanosec * 1e-9
        assert abs(t - log_time * 1e-9) < 1e-12
        assert list(js.name) == list(BETANCUR)
        q, v = np.zeros(pm.nq), np.zeros(pm.nv)
        for k, j in enumerate(js.name):
            jm = pm.joints[pm.getJointId(j)]
            f, fd = BETANCUR[j]
            assert abs(js.position[k] - f(t)) < 1e-12 * max(1.0, abs(f(t))) and abs(js.velocity[k] - fd) < 1e-14
            q[jm.idx_q], v[jm.idx_v] = js.position[k], js.velocity[k]
        tau = pin.rnea(pm, pd, q, v, np.zeros(pm.nv))
        ref = np.array([tau[pm.joints[pm.getJointId(j)].idx_v] for j in js.name])
        worst = max(worst, np.abs(np.array(js.effort) - ref).max() / np.abs(ref).max())
        for j in BETANCUR:
            w = wrenches[j][log_time].wrench
            got = np.array([w.torque.x, w.torque.y, w.torque.z, w.force.x, w.force.y, w.force.z])
            fj = pd.f[pm.getJointId(j)]
            want = np.concatenate([fj.angular, fj.linear])
            worst_w = max(worst_w, np.abs(got - want).max() / max(1.0, np.abs(want).max()))
    print(f'betancur_dh_animation: efforts vs pin.rnea {worst:.2e} relative, wrenches {worst_w:.2e}')
    assert worst <= 1e-13 and worst_w <= 1e-13    # measured 1e-15, 2e-15


def test_betancur_scene_energy_balance_and_scene_facts():
    """Over 4 s the work of the efforts equals the change of mechanical energy (1e-9 relative);
    the scene's motion is the seed's (alpha_2 as the extra joint, q'' = 0)."""
    sc = load_scene('betancur_dh_animation')
    assert sc.system.joint_names == list(BETANCUR)
    for j, (f, fd) in BETANCUR.items():
        q, qd, qdd = sc.system.motion[j].jet(1.7)
        assert (q, qd, qdd) == pytest.approx((f(1.7), fd, 0.0), abs=1e-15)
    sim = Simulator(sc.system, sc.y0, integrator=sc.settings['integrator'], dt=sc.settings['dt'])
    for k in range(1, 401):
        sim.advance(k * 0.01)
    e = sim.energy_report()
    assert abs(e['work']) > 1000.0
    print(f"betancur_dh_animation: energy balance {e['relative_drift']:.1e} relative over 4 s")
    assert abs(e['relative_drift']) < 1e-9, e


# ---------------------------------------------------------------------------------------------
# the sim node
# ---------------------------------------------------------------------------------------------
def test_node_refuses_lockstep_for_a_scene_without_commands():
    from robodyn_ros.nodes.sim import PARAMETERS, ConfigError, resolve_config
    params = {k: default for k, (default, _) in PARAMETERS.items()}
    scene = load_scene('betancur_dh_animation')
    with pytest.raises(ConfigError, match='takes no commands; use mode realtime or max'):
        resolve_config({**params, 'mode': 'lockstep'}, scene)
    assert resolve_config({**params, 'mode': 'max'}, scene).mode == 'max'


@pytest.mark.processes
def test_node_runs_the_animation_and_records_the_efforts(tmp_path):
    """``sim`` (mode max, 1 s) publishes and records the same efforts as the system computes."""
    import os
    sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
    from ros_helpers import Domain, start_sim
    rec = tmp_path / 'node.mcap'
    dom = Domain()
    node = start_sim(dom, {'scene': 'betancur_dh_animation', 'mode': 'max', 'duration': 1.0, 'record': str(rec)},
                     tmp_path / 'node.log')
    try:
        rc = node.wait(180)
        assert rc == 0, node.output()
    finally:
        node.cleanup()
        dom.release()
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory
    states = []
    with open(rec, 'rb') as f:
        for _, channel, _, msg in make_reader(f, decoder_factories=[DecoderFactory()]).iter_decoded_messages(
                topics=['/joint_states']):
            states.append(msg)
    assert len(states) == 101
    system = load_scene('betancur_dh_animation').system
    for js in states:
        t = js.header.stamp.sec + js.header.stamp.nanosec * 1e-9
        tau = system.outputs(t, np.array([t]), {}).effort
        assert np.abs(np.array(js.effort) - tau).max() <= 1e-9 * np.abs(tau).max()
