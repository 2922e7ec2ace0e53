"""URDF import: robots no one here wrote (example-robot-data) against Pinocchio on the same file,
the malformed-URDF table, effort limits, Coulomb friction, visuals and the export round trip."""
from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest
import yourdfpy

from robodyn_ros import dynamics as dyn
from robodyn_ros import kernels
from robodyn_ros.model import build_model, to_urdf
from robodyn_ros.scene import SceneError, load_scene, parse_scene
from robodyn_ros.simulation import Simulator, run_headless
from robodyn_ros.urdf import COULOMB_VELOCITY, UrdfError, example_robot_data_dir, read_urdf
from test_pinocchio import compare, random_q, rel

#: the example-robot-data robots against Pinocchio on the same files (README: measured <= 8.2e-16)
ROBOT_TOL = 1e-13

ERD = example_robot_data_dir()
assert ERD is not None, 'example-robot-data (test extras) is not installed'

#: robot -> (file under example-robot-data/robots, floating, locked joints, expected nq, nv)
ROBOTS = {
    'ur5': ('ur_description/urdf/ur5_robot.urdf', False, {}, 6, 6),
    'panda': ('panda_description/urdf/panda.urdf', False, {'panda_finger_joint1': 0.0, 'panda_finger_joint2': 0.0},
              7, 7),
    'solo12': ('solo_description/robots/solo12.urdf', True, {}, 19, 18),
    # sensor frames with made-up inertias, welded to the base: lumped into it (as Pinocchio does)
    'anymal_c': ('anymal_c_simple_description/urdf/anymal.urdf', True, {}, 19, 18),
}


def robot_scene_text(robot: str, extra: str = '') -> str:
    """A scene file of one example-robot-data robot (absolute file path)."""
    f, floating, locked, _, _ = ROBOTS[robot]
    lines = [f'name: {robot}', 'parts:', '  - kind: urdf', f'    name: {robot}', f'    file: {ERD / f}']
    if floating:
        lines.append('    floating: true')
    if locked:
        lines.append('    locked: {' + ', '.join(f'{k}: {v}' for k, v in locked.items()) + '}')
    return '\n'.join(lines) + '\n' + extra


def pinocchio_model(robot: str):
    """Pinocchio's model of the same file: free-flyer root when floating, locked joints reduced away."""
    f, floating, locked, _, _ = ROBOTS[robot]
    path = str(ERD / f)
    pm = pin.buildModelFromUrdf(path, pin.JointModelFreeFlyer()) if floating else pin.buildModelFromUrdf(path)
    if locked:
        ids = [pm.getJointId(j) for j in locked]
        q_ref = pin.neutral(pm)
        for j, val in locked.items():
            q_ref[pm.joints[pm.getJointId(j)].idx_q] = val
        pm = pin.buildReducedModel(pm, ids, q_ref)
    # the URDF root link of a fixed base is our fixed frame: its own <inertial> is welded to the
    # world and enters no dynamics (Pinocchio keeps it in its universe inertia: take it out)
    root = read_urdf(path, floating=floating, locked=locked).root
    lk = {lk.name: lk for lk in yourdfpy.URDF.load(path, build_scene_graph=False, load_meshes=False).robot.links}[root]
    if not floating and lk.inertial is not None:
        T = lk.inertial.origin
        I_root = pin.Inertia(lk.inertial.mass, T[:3, 3], T[:3, :3] @ lk.inertial.inertia @ T[:3, :3].T)
        pm.inertias[0] = pm.inertias[0] - I_root
    return pm


def _kernel_errors(m, pm, rng, n):
    """Largest relative errors of the compiled kernels (M, RNEA, ABA) against Pinocchio."""
    from test_pinocchio import PinBridge
    b = PinBridge(m, pm)
    km = kernels.CompiledModel(m)
    worst = 0.0
    for _ in range(n):
        q = random_q(m, rng)
        v, a, tau = rng.normal(size=m.nv), rng.normal(size=m.nv), 3 * rng.normal(size=m.nv)
        qp, vp = b.q(q), b.v(v)
        Mp = pin.crba(pm, b.pd, qp)
        Mp = np.triu(Mp) + np.triu(Mp, 1).T
        worst = max(worst, rel(km.crba(q), Mp[np.ix_(b.vmap, b.vmap)]),
                    rel(km.rnea(q, v, a), b.back(pin.rnea(pm, b.pd, qp, vp, b.v(a)))),
                    rel(km.aba(q, v, tau), b.back(pin.aba(pm, b.pd, qp, vp, b.v(tau)))))
    return worst


@pytest.mark.parametrize('robot', list(ROBOTS))
def test_example_robot_data_against_pinocchio_and_1s_run(robot):
    """M, RNEA, ABA (and poses, joint wrenches, energies) of the imported robot equal Pinocchio's on
    the same URDF file to 1e-9 at seeded random states, for the reference and the compiled kernels;
    then 1 s of simulation stays finite and conserves energy minus the damping work."""
    sc = parse_scene(robot_scene_text(robot))
    m = sc.system.model
    _, floating, _, nq, nv = ROBOTS[robot]
    assert (m.nq, m.nv) == (nq, nv)
    pm = pinocchio_model(robot)
    pm.gravity.linear = np.asarray(m.gravity, dtype=float)
    rng = np.random.default_rng(1300 + len(robot))
    errs = compare(m, rng, 4, robot, pm=pm)
    worst = {k: max(e)[0] for k, e in errs.items() if k in ('M', 'rnea', 'aba')}
    assert all(len(errs[k]) >= 4 for k in worst)
    print(f'{robot}: nq={m.nq} nv={m.nv} worst relative error vs Pinocchio', {k: f'{x:.2g}' for k, x in worst.items()})
    for k, e in errs.items():
        w = max(e, key=lambda x: x[0])
        assert w[0] < ROBOT_TOL, f'{robot} {k}: {w[0]:.3g} at {w[1]}'
    if kernels.AVAILABLE:
        assert _kernel_errors(m, pm, rng, 3) < ROBOT_TOL
    sim = Simulator(sc.system, sc.y0, integrator='rk4', dt=1e-3)
    assert run_headless(sim, 1.0, 100.0) == 100
    assert np.all(np.isfinite(sim.y)) and sim.t == pytest.approx(1.0)
    assert abs(sim.energy_report()['relative_drift']) < 1e-5
    if floating:  # free fall: the base's height drops by g t²/2 (no contact), momentum otherwise
        np.testing.assert_allclose(dyn.center_of_mass(m, sim.y[:m.nq])[0][2] -
                                   dyn.center_of_mass(m, sc.y0[:m.nq])[0][2], -0.5 * 9.81, rtol=1e-6)


# ------------------------------------------------------------------------------------------------
# the malformed-URDF table: every row is refused with the link/joint named and the reason
# ------------------------------------------------------------------------------------------------
_INERTIAL = '<inertial><mass value="1"/><inertia ixx="0.1" iyy="0.1" izz="0.1" ixy="0" ixz="0" iyz="0"/></inertial>'


def _robot(*body, name='bad'):
    return f'<robot name="{name}">' + ''.join(body) + '</robot>'


def _link(name, inertial=_INERTIAL):
    return f'<link name="{name}">{inertial}</link>'


def _joint(name, parent, child, kind='revolute', extra='<axis xyz="0 0 1"/>'):
    return f'<joint name="{name}" type="{kind}"><parent link="{parent}"/><child link="{child}"/>{extra}</joint>'


MALFORMED = [
    ('not well-formed XML', '<robot name="x"><link name="a">', 'not well-formed XML'),
    ('wrong root element', '<model name="x"/>', 'root element must be <robot>'),
    ('loop: a link with two parents',
     _robot(_link('a'), _link('b'), _link('c'), _joint('j1', 'a', 'b'), _joint('j2', 'a', 'c'), _joint('j3', 'c', 'b')),
     "link 'b': has two parents (joints 'j1' and 'j3')"),
    ('loop: every link has a parent', _robot(_link('a'), _link('b'), _joint('j1', 'a', 'b'), _joint('j2', 'b', 'a')),
     'the joints form a loop'),
    ('two root links', _robot(_link('a'), _link('b'), _link('c'), _joint('j1', 'a', 'b')), "2 root links ['a', 'c']"),
    ('duplicate link names', _robot(_link('a'), _link('a')), "link 'a': duplicate link name"),
    ('duplicate joint names', _robot(_link('a'), _link('b'), _link('c'), _joint('j1', 'a', 'b'), _joint('j1', 'b', 'c')),
     "joint 'j1': duplicate joint name"),
    ('joint without a parent', _robot(_link('a'), _link('b'), '<joint name="j1" type="fixed"><child link="b"/></joint>'),
     "joint 'j1': missing <parent link=\"...\"/>"),
    ('non-finite joint origin', _robot(_link('a'), _link('b'), _joint('j1', 'a', 'b', extra='<origin xyz="0 0 nan"/>')),
     "joint 'j1': <origin xyz=\"0 0 nan\">: expected finite numbers"),
    ('joint to an unknown link', _robot(_link('a'), _joint('j1', 'a', 'ghost')), "joint 'j1': child link 'ghost'"),
    ('unknown joint type', _robot(_link('a'), _link('b'), _joint('j1', 'a', 'b', 'hinge')),
     "joint 'j1': unknown joint type 'hinge'"),
    ('planar joint', _robot(_link('a'), _link('b'), _joint('j1', 'a', 'b', 'planar')),
     "joint 'j1': planar joints are not supported"),
    ('floating joint below the root', _robot(_link('a'), _link('b'), _link('c'), _joint('j1', 'a', 'b'),
                                              _joint('j2', 'b', 'c', 'floating', '')),
     "joint 'j2': a floating joint is only supported from the root link"),
    ('mimic cycle', _robot(_link('a'), _link('b'), _link('c'), _joint('j1', 'a', 'b', extra='<mimic joint="j2"/>'),
                           _joint('j2', 'a', 'c', extra='<axis xyz="0 0 1"/><mimic joint="j1"/>')),
     "joint 'j1': the mimic joints form a cycle j1 -> j2 -> j1"),
    ('zero-mass moving leaf', _robot(_link('a'), _link('b', '<inertial><mass value="0"/><inertia ixx="0" iyy="0" '
                                                            'izz="0" ixy="0" ixz="0" iyz="0"/></inertial>'),
                                     _joint('j1', 'a', 'b')),
     "link 'b' (joint 'j1'): zero-mass moving link at a leaf"),
    ('missing inertial on a moving leaf', _robot(_link('a'), _link('b', ''), _joint('j1', 'a', 'b')),
     "link 'b' (joint 'j1'): missing <inertial> on a moving link, and no <collision> or <visual> geometry to infer "
     "one from at a leaf"),
    ('massless moving link above a massless fixed leaf',
     _robot(_link('a'), _link('b', ''), _link('c', ''), _joint('j1', 'a', 'b'), _joint('j2', 'b', 'c', 'fixed', '')),
     "link 'b' (joint 'j1'): missing <inertial> on a moving link, and no <collision> or <visual> geometry to infer "
     "one from whose subtree has no mass"),
    ('inertia not positive semi-definite',
     _robot(_link('a'), _link('b', '<inertial><mass value="1"/><inertia ixx="0.1" iyy="0.1" izz="0.1" ixy="0.2" '
                                   'ixz="0" iyz="0"/></inertial>'), _joint('j1', 'a', 'b')),
     "link 'b' (joint 'j1'): inertia is not positive semi-definite"),
    ('negative mass', _robot(_link('a'), _link('b', '<inertial><mass value="-1"/><inertia ixx="0.1" iyy="0.1" '
                                                    'izz="0.1" ixy="0" ixz="0" iyz="0"/></inertial>'),
                             _joint('j1', 'a', 'b')),
     "link 'b' (joint 'j1'): mass must be >= 0, got -1.0"),
    ('negative damping', _robot(_link('a'), _link('b'), _joint('j1', 'a', 'b', extra='<dynamics damping="-1"/>')),
     "joint 'j1': <dynamics damping> must be >= 0"),
    ('negative effort limit', _robot(_link('a'), _link('b'), _joint(
        'j1', 'a', 'b', extra='<limit effort="-1" lower="-1" upper="1" velocity="1"/>')),
     "joint 'j1': <limit effort> must be >= 0 (0: no limit given), got -1.0"),
    ('lower limit above upper', _robot(_link('a'), _link('b'), _joint(
        'j1', 'a', 'b', extra='<limit effort="1" lower="1" upper="-1" velocity="1"/>')),
     "joint 'j1': <limit lower=\"1.0\"> is above upper=\"-1.0\""),
    ('zero joint axis', _robot(_link('a'), _link('b'), _joint('j1', 'a', 'b', extra='<axis xyz="0 0 0"/>')),
     "link 'b' (joint 'j1'): axis must be a non-zero 3-vector"),
]


@pytest.mark.parametrize('what, text, message', MALFORMED, ids=[r[0] for r in MALFORMED])
def test_malformed_urdf_is_refused_with_name_and_reason(what, text, message):
    with pytest.raises(UrdfError) as e:
        read_urdf(text)
    assert message in str(e.value), str(e.value)


def test_malformed_urdf_in_a_scene_names_the_file_and_key():
    text = _robot(_link('a'), _link('b', ''), _joint('j1', 'a', 'b'))
    scene = 'name: x\nparts:\n  - kind: urdf\n    name: r\n    urdf: |\n      ' + text + '\n'
    with pytest.raises(SceneError, match=r"^s\.yaml: parts\[0\]\.urdf: link 'b' \(joint 'j1'\): missing <inertial>"):
        parse_scene(scene, file='s.yaml')
    with pytest.raises(SceneError, match=r"parts\[0\]\.file: no such URDF file"):
        parse_scene('name: x\nparts:\n  - {kind: urdf, name: r, file: nowhere.urdf}\n', file='s.yaml')
    with pytest.raises(SceneError, match=r"parts\[0\]: give exactly one of 'file'"):
        parse_scene('name: x\nparts:\n  - {kind: urdf, name: r}\n', file='s.yaml')
    with pytest.raises(SceneError, match=r"parts\[0\]\.actuated\[1\]: 'nope' is not a 1-DOF joint"):
        parse_scene(robot_scene_text('solo12').replace('    floating: true', '    floating: true\n    actuated: [FL_HAA, nope]'),
                    file='s.yaml')
    with pytest.raises(SceneError, match=r"parts\[0\]\.locked: expected a mapping joint: position, got int 5"):
        parse_scene(robot_scene_text('ur5').replace('    file:', '    locked: 5\n    file:'), file='s.yaml')
    with pytest.raises(SceneError, match=r"parts\[0\]\.locked\.nope: .*no such joint"):
        parse_scene(robot_scene_text('ur5').replace('    file:', '    locked: {nope: 0.0}\n    file:'), file='s.yaml')


def test_mimic_joint_can_be_locked_and_continuous_joints_have_no_limits():
    text = _robot(_link('a'), _link('b'), _link('c'), _link('d'),
                  _joint('j1', 'a', 'b', 'continuous', '<axis xyz="0 1 0"/><limit effort="2" velocity="3"/>'),
                  _joint('j2', 'a', 'c', extra='<axis xyz="0 0 1"/><mimic joint="j1"/>'),
                  _joint('j3', 'b', 'd', 'prismatic', '<origin xyz="0 0 1" rpy="0.1 0.2 0.3"/><axis xyz="1 0 0"/>'
                         '<limit effort="5" lower="-0.5" upper="0.5" velocity="1"/>'
                         '<dynamics damping="0.5" friction="0.25"/>'))
    r = read_urdf(text, locked={'j2': 0.3})
    s = {x.joint: x for x in r.specs}
    assert s['j2'].joint_type == 'fixed' and s['j1'].joint_type == 'revolute' and s['j1'].limits is None
    assert s['j1'].effort_limit == 2.0 and r.velocity_limits == {'j1': 3.0, 'j3': 1.0}
    assert (s['j3'].limits, s['j3'].effort_limit, s['j3'].damping, s['j3'].friction) == ((-0.5, 0.5), 5.0, 0.5, 0.25)
    with pytest.raises(UrdfError, match="locked joint 'j3': position 0.9 is outside its limits"):
        read_urdf(text, locked={'j2': 0.0, 'j3': 0.9})


def test_inertial_origin_rpy_is_rotated_into_the_link_frame():
    """A box's inertia given about a rotated inertial frame equals Pinocchio's reading of the file."""
    text = _robot(_link('a'), _link('b', '<inertial><origin xyz="0.1 -0.2 0.3" rpy="0.4 -0.5 0.6"/><mass value="2"/>'
                                         '<inertia ixx="0.05" iyy="0.08" izz="0.1" ixy="0.01" ixz="0" iyz="0.002"/>'
                                         '</inertial>'),
                  _joint('j1', 'a', 'b', 'continuous', extra='<axis xyz="0.3 0.4 0.5"/>'))
    m = build_model(read_urdf(text).specs, root='a')
    pm = pin.buildModelFromXML(text)
    Ip = pm.inertias[1]
    assert rel(m.I[0][:3, :3], Ip.matrix()[3:, 3:]) < 1e-12  # rotational block about the body origin
    np.testing.assert_allclose(dyn.inertia_parts(m.I[0])[1], Ip.lever, atol=1e-15)


# ------------------------------------------------------------------------------------------------
# effort limits, friction
# ------------------------------------------------------------------------------------------------
_LIMITED_ARM = """name: limited
gravity: [0, 0, -9.81]
parts:
  - kind: arm
    name: arm
    links:
      - {name: l1, joint: j1, parent: base_link, type: revolute, axis: [0, 1, 0], mass: 1.0, com: [0.5, 0, 0],
         inertia: [0.01, 0.01, 0.01, 0, 0, 0], effort_limit: 2.0}
      - {name: l2, joint: j2, parent: l1, type: revolute, origin: {xyz: [1, 0, 0]}, axis: [0, 1, 0], mass: 1.0,
         com: [0.5, 0, 0], inertia: [0.01, 0.01, 0.01, 0, 0, 0]}
commands:
  effort: {profile: constant, value: [5.0, -1.0]}
"""


def test_effort_limit_clamps_counts_and_is_what_the_recording_shows(tmp_path):
    from robodyn_ros.recording import read_messages
    from robodyn_ros.recording.run_sink import McapRunSink
    sc = parse_scene(_LIMITED_ARM)
    port = sc.system.inputs['effort']
    assert port.limit == (2.0, np.inf)
    sim = Simulator(sc.system, sc.y0, integrator='rk4', dt=1e-3)
    sim.set_command('effort', [-7.0, 100.0])  # j2 has no limit
    assert sim.ports['effort'].clamped == 1
    np.testing.assert_array_equal(sim.held_inputs()['effort'], [-2.0, 100.0])
    np.testing.assert_array_equal(sim.outputs(wrenches=False).effort, [-2.0, 100.0])
    sim.set_command('effort', [1.5, 0.0])  # within the limit: untouched, not counted
    assert sim.ports['effort'].clamped == 1 and sim.diagnostics_values()['effort_clamped'] == 1
    # the clamped effort is what drives the arm: equal to a run commanded at the limit
    sim.set_command('effort', [9.0, 0.0])
    sim.advance(0.05)
    ref = Simulator(sc.system, sc.y0, integrator='rk4', dt=1e-3)
    ref.set_command('effort', [2.0, 0.0])
    ref.advance(0.05)
    np.testing.assert_array_equal(sim.y, ref.y)
    assert sim.diagnostics_values()['effort_clamped'] == 2
    # recording: the command as received on effort_commands, the applied effort in joint_states
    sim = Simulator(sc.system, sc.y0, integrator='rk4', dt=1e-3)
    path = tmp_path / 'limited.mcap'
    sink = McapRunSink(path, sc, {'integrator': 'rk4'}, diagnostics_period=0.05)
    run_headless(sim, 0.1, 100.0, sc.script, [sink])
    sink.close()
    js = [msg for _, _, _, msg in read_messages(path, topics=['/joint_states'])]
    assert len(js) == 11
    assert all(list(m.effort) == [2.0, -1.0] for m in js[1:])
    cmds = [list(msg.data) for _, _, _, msg in read_messages(path, topics=['/effort_commands'])]
    assert len(cmds) == 10 and all(c == [5.0, -1.0] for c in cmds)
    diags = [msg for _, _, _, msg in read_messages(path, topics=['/diagnostics'])]
    vals = {kv.key: kv.value for kv in diags[-1].status[0].values}
    assert vals['effort_clamped'] == '10'


def test_effort_limit_from_urdf_reaches_the_port_and_the_export():
    sc = parse_scene(robot_scene_text('panda'))
    lim = sc.system.inputs['effort'].limit
    np.testing.assert_array_equal(lim, [87.0] * 4 + [12.0] * 3)
    assert '<limit lower="-2.8973" upper="2.8973" effort="87.0"' in sc.system.urdf()
    assert sc.system.model.specs[0].limits == (-2.8973, 2.8973)


def test_coulomb_friction_decelerates_at_f_over_I():
    """A horizontal wheel (axis along gravity) spinning at 2 rad/s under Coulomb friction f:
    while |q̇| >> COULOMB_VELOCITY, q̇(t) = q̇0 − f t / I (closed form), and the energy lost is
    the friction work the Simulator integrates."""
    f, I, v0 = 0.3, 0.5, 2.0
    text = _robot(_link('base'), _link('wheel', f'<inertial><mass value="1"/><inertia ixx="0.25" iyy="0.25" izz="{I}" '
                                                'ixy="0" ixz="0" iyz="0"/></inertial>'),
                  _joint('spin', 'base', 'wheel', 'continuous', f'<axis xyz="0 0 1"/><dynamics friction="{f}"/>'))
    scene = ('name: w\nparts:\n  - kind: urdf\n    name: w\n    urdf: |\n      ' + text +
             '\ninitial_state: {v: [' + str(v0) + ']}\nsimulation: {integrator: rk4, dt: 0.001}\n')
    sc = parse_scene(scene)
    sim = Simulator(sc.system, sc.y0, integrator='rk4', dt=1e-3)
    sim.advance(2.0)
    vdot = -f / I
    assert sim.y[1] == pytest.approx(v0 + vdot * 2.0, rel=1e-6)
    assert sim.y[0] == pytest.approx(v0 * 2.0 + 0.5 * vdot * 4.0, rel=1e-6)
    assert abs(sim.energy_report()['drift']) < 1e-9
    assert COULOMB_VELOCITY == 0.05


def test_velocity_limit_is_reported_and_counted_at_publication():
    """``<limit velocity>`` is not enforced; the published joint-velocity samples above it are
    counted (diagnostics ``velocity_limit_exceeded``). A damped spin with no gravity moment:
    q̇(t) = q̇0 e^(-d t / I) (closed form) crosses the 1 rad/s limit at t = ln 2 s from
    q̇0 = 2 rad/s, so of the 11 publications at 10 Hz over 1 s, those at t = 0 ... 0.6 s exceed it
    (7); the second joint (limit 5 rad/s) never does, a continuous third joint without a limit
    never counts, and velocity="0" means no limit."""
    inertial = ('<inertial><mass value="1"/><inertia ixx="0.25" iyy="0.25" izz="0.2" ixy="0" ixz="0" iyz="0"/>'
                '</inertial>')
    text = _robot(_link('base'), _link('a', inertial), _link('b', inertial), _link('c', inertial),
                  _link('d', inertial),
                  _joint('j1', 'base', 'a', 'revolute', '<axis xyz="0 0 1"/><dynamics damping="0.2"/>'
                                                        '<limit effort="1" lower="-9" upper="9" velocity="1.0"/>'),
                  _joint('j2', 'a', 'b', 'revolute', '<axis xyz="0 0 1"/><origin xyz="0 0 0.1"/>'
                                                     '<limit effort="1" lower="-9" upper="9" velocity="5.0"/>'),
                  _joint('j3', 'b', 'c', 'continuous', '<axis xyz="0 0 1"/><origin xyz="0 0 0.1"/>'),
                  _joint('j4', 'c', 'd', 'revolute', '<axis xyz="0 0 1"/><origin xyz="0 0 0.1"/>'
                                                     '<limit effort="1" lower="-9" upper="9" velocity="0"/>'))
    r = read_urdf(text)
    assert [s.velocity_limit for s in r.specs] == [1.0, 5.0, None, None]
    assert 'velocity="1.0"' in to_urdf(build_model(r.specs, root='base'))
    # links b, c, d start at rest in space and feel no moment about z: they stay at rest, so link a
    # alone carries the damper (I = 0.2): q̇1 = 2 e^(-t), q̇2 = -q̇1 (|q̇2| <= 2 < 5), q̇3 = q̇4 = 0
    scene = ('name: v\ngravity: [0, 0, -9.81]\nparts:\n  - kind: urdf\n    name: v\n    urdf: |\n      ' + text +
             '\ninitial_state: {v: [2.0, -2.0, 0.0, 0.0]}\n')
    sc = parse_scene(scene)
    sim = Simulator(sc.system, sc.y0, integrator='rk4', dt=1e-4)
    t_cross = 0.2 / 0.2 * np.log(2.0)   # I / d ln(q̇0 / limit)
    assert 0.6 < t_cross < 0.7

    class Counts:
        wants_wrenches = False
        seen = []

        def on_start(self, sim):
            pass

        def on_command(self, *a):
            pass

        def on_output(self, t, out, sim):
            sim.outputs(wrenches=False)   # a second look at the same state is not counted again
            self.seen.append(sim.diagnostics_values()['velocity_limit_exceeded'])

        def close(self):
            pass
    sink = Counts()
    run_headless(sim, 1.0, 10.0, sinks=[sink])
    assert sink.seen[0] == 1 and sink.seen[-1] == 7, sink.seen
    assert sim.diag.velocity_limit_exceeded == 7
    from robodyn_ros.runs import summary
    assert 'limits       7 published joint velocities above the velocity limits' in \
        summary(sc, sim, {'integrator': 'rk4', 'dt': 1e-4}, 1.0, None, [])
    assert sim.y[4] == pytest.approx(2.0 * np.exp(-1.0), rel=1e-9) and sim.y[5] == pytest.approx(-sim.y[4], rel=1e-9)
    # a scene without velocity limits publishes no such value (its recordings stay as they were)
    plain = load_scene('stanford_arm')
    assert 'velocity_limit_exceeded' not in Simulator(plain.system, plain.y0).diagnostics_values()


def test_friction_is_refused_where_it_is_not_modelled():
    text = _robot(_link('a', ''), _link('b'), _joint('j1', 'a', 'b', extra='<axis xyz="0 0 1"/>'
                                                                          '<dynamics friction="1"/>'))
    scene = 'name: x\ngravity: [0, 0, 0]\nparts:\n  - kind: urdf\n    name: r\n    floating: true\n    urdf: |\n      ' + text
    with pytest.raises(SceneError, match=r"joint 'j1': Coulomb <dynamics friction> is supported for a URDF mounted "
                                         r"on the world only"):
        parse_scene(scene + '\n')


# ------------------------------------------------------------------------------------------------
# export: round trip and visuals
# ------------------------------------------------------------------------------------------------
@pytest.mark.parametrize('scene', ['stanford_arm', 'betancur_pendulum', 'huston_p19_2_3', 'unfried_free_flyer',
                                   'mobile_manipulator'])
def test_export_reimport_round_trip_has_identical_dynamics(scene):
    """to_urdf of a bundled scene's model, read back by the importer: M, RNEA and ABA equal to 1e-12."""
    m = load_scene(scene).system.model
    floating = m.nb > 0 and m.jtype[0] == 3
    r = read_urdf(to_urdf(m))
    assert r.floating == floating and r.root == (m.link_names[0] if floating else m.root)
    m2 = build_model(r.specs, gravity=m.gravity, name=m.name, root='odom' if floating else r.root)
    assert m2.link_names == m.link_names and m2.joint_names == m.joint_names
    rng = np.random.default_rng(77)
    for _ in range(5):
        q = random_q(m, rng)
        v, a, tau = rng.normal(size=m.nv), rng.normal(size=m.nv), rng.normal(size=m.nv)
        assert rel(dyn.crba(m2, q), dyn.crba(m, q)) < 1e-12
        assert rel(dyn.rnea(m2, q, v, a), dyn.rnea(m, q, v, a)) < 1e-12
        assert rel(dyn.aba(m2, q, v, tau), dyn.aba(m, q, v, tau)) < 1e-12


def _visual_links(urdf_text):
    u = yourdfpy.URDF.load(__import__('io').BytesIO(urdf_text.encode()), build_scene_graph=False, load_meshes=False)
    return u, {lk.name: lk for lk in u.robot.links}


@pytest.mark.parametrize('scene', ['stanford_arm', 'mobile_manipulator', 'unfried_free_flyer', 'betancur_platform'])
def test_bundled_scene_urdf_has_a_visual_per_massive_link_and_parses(scene):
    sc = load_scene(scene)
    text = sc.system.urdf()
    u, links = _visual_links(text)
    assert u.validate()
    massive = [lk for lk in links.values() if lk.inertial is not None and lk.inertial.mass > 0]
    assert massive and all(lk.visuals for lk in massive), [lk.name for lk in massive if not lk.visuals]
    for lk in massive:
        g = lk.visuals[0].geometry
        assert (g.box, g.cylinder, g.sphere).count(None) == 2
    pm = pin.buildModelFromXML(text)  # a free base's URDF leaves the floating joint out (odom carries it)
    assert pm.njoints >= 2 and pm.nframes >= len(links)


def test_inertia_visuals_reproduce_the_inertia():
    """The drawn solids have the link's mass distribution: a slender bar -> a thin cylinder of its
    length, a uniform box -> that box, a sphere -> that sphere."""
    import xml.etree.ElementTree as ET

    from robodyn_ros.model import inertia_visual
    m, L = 2.0, 0.8
    bar = ET.fromstring(inertia_visual(m, (0.4, 0, 0), np.diag([0.0, m * L * L / 12, m * L * L / 12])))
    cyl = bar.find('geometry/cylinder')
    assert float(cyl.get('length')) == pytest.approx(L) and float(cyl.get('radius')) == 0.01
    from robodyn_ros.spatial import rpy_to_R
    R = rpy_to_R([float(x) for x in bar.find('origin').get('rpy').split()])
    assert abs(abs(R[:, 2] @ [1, 0, 0]) - 1) < 1e-12  # cylinder axis along the bar
    dims = np.array([0.1, 0.2, 0.3])
    Ib = m / 12 * np.diag([dims[1] ** 2 + dims[2] ** 2, dims[0] ** 2 + dims[2] ** 2, dims[0] ** 2 + dims[1] ** 2])
    box = ET.fromstring(inertia_visual(m, (0, 0, 0), Ib))
    np.testing.assert_allclose(sorted(float(x) for x in box.find('geometry/box').get('size').split()), dims)
    sph = ET.fromstring(inertia_visual(m, (0, 0, 0), np.eye(3) * 0.4 * m * 0.3 ** 2))
    assert float(sph.find('geometry/sphere').get('radius')) == pytest.approx(0.3)
    assert inertia_visual(0.0, (0, 0, 0), np.zeros((3, 3))) == ''


def test_imported_urdf_keeps_its_own_visuals():
    sc = parse_scene(robot_scene_text('panda'))
    text = sc.system.urdf()
    assert 'package://example-robot-data/robots/panda_description/meshes/visual/link1.dae' in text
    assert 'robodyn_body' not in text  # no drawn shapes where the URDF has its own
    u, links = _visual_links(text)
    assert links['panda_link1'].visuals[0].geometry.mesh is not None
    pm = pin.buildModelFromXML(text)
    assert pm.nv == 7


@pytest.mark.parametrize('scene', ['unfried_free_flyer', 'mobile_manipulator'])
def test_urdf_part_mounts_where_an_arm_does(scene, tmp_path):
    """The arm of a bundled scene exported to a URDF file and mounted back (free base, platform) as
    a ``kind: urdf`` part: the scene's right-hand side is unchanged (1e-12)."""
    import yaml
    data = yaml.safe_load(open(load_scene(scene).path).read())
    k = next(i for i, p in enumerate(data['parts']) if p['kind'] == 'arm')
    arm = data['parts'][k]
    alone = {'name': 'arm_alone', 'parts': [{**arm, 'mount': 'world'}]}
    (tmp_path / 'arm.urdf').write_text(to_urdf(parse_scene(yaml.safe_dump(alone)).system.model))
    data['parts'][k] = {'kind': 'urdf', 'name': arm['name'], 'mount': arm['mount'], 'file': 'arm.urdf'}
    (tmp_path / 'scene.yaml').write_text(yaml.safe_dump(data))
    a, b = load_scene(scene), load_scene(tmp_path / 'scene.yaml')
    assert type(a.system) is type(b.system) and a.system.joint_names == b.system.joint_names
    rng = np.random.default_rng(5)
    u = {p: rng.normal(size=port.size) for p, port in a.system.inputs.items()}
    ya, yb = a.system.rhs(0.0, a.y0, u), b.system.rhs(0.0, b.y0, u)
    np.testing.assert_array_equal(a.y0, b.y0)
    assert rel(yb, ya) < 1e-12


def test_effort_limit_in_a_dh_arm():
    text = load_scene('mobile_manipulator').text.replace('damping: 0.01', 'effort_limit: 0.05, damping: 0.01', 1)
    assert text != load_scene('mobile_manipulator').text
    sc = parse_scene(text)
    assert sc.system.inputs['effort'].limit[0] == 0.05 and np.isinf(sc.system.inputs['effort'].limit[1:]).all()
    with pytest.raises(SceneError, match=r'effort_limit: must be > 0'):
        parse_scene(text.replace('effort_limit: 0.05', 'effort_limit: 0.0'))
