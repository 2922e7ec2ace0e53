"""Scene files: the bundled scenes load and mean what their sources say; malformed ones are refused.

Expected values come from the sources (the Stanford DH table of Corke's toolbox, Betancur's
a_i = 0.2 m / m_i = 0.1 kg / g = 9.8, Huston's P19.2.3 geometry), from closed forms, or from
Pinocchio, never from robodyn_ros itself.
"""
from __future__ import annotations

import copy
from pathlib import Path

import numpy as np
import pinocchio as pin
import pytest
import yaml
from scipy.integrate import solve_ivp

from robodyn_ros import dynamics as dyn
from robodyn_ros.model import PRISMATIC, REVOLUTE, to_urdf
from robodyn_ros.scene import SceneError, find_scene, list_scenes, load_scene

BUNDLED = ('betancur_pendulum', 'huston_p19_2_3', 'stanford_arm')
INCH = 0.0254


# ------------------------------------------------------------------------------------------
# independent homogeneous transforms (4x4), written here from the textbook definitions
# ------------------------------------------------------------------------------------------
def Rz(t):
    c, s = np.cos(t), np.sin(t)
    return np.array([[c, -s, 0, 0], [s, c, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1.0]])


def Rx(t):
    c, s = np.cos(t), np.sin(t)
    return np.array([[1, 0, 0, 0], [0, c, -s, 0], [0, s, c, 0], [0, 0, 0, 1.0]])


def Tx(a):
    T = np.eye(4)
    T[0, 3] = a
    return T


def Tz(d):
    T = np.eye(4)
    T[2, 3] = d
    return T


def pose(model, q, link):
    """(4, 4) world pose of a link of the model (robodyn_ros side)."""
    R, p = dyn.body_poses(model, q)
    T = np.eye(4)
    i = model.body(link)
    T[:3, :3], T[:3, 3] = R[i], p[i]
    return T


# ------------------------------------------------------------------------------------------
# every bundled scene
# ------------------------------------------------------------------------------------------
def test_list_scenes_lists_the_three_bundled_scenes():
    listed = dict(list_scenes())
    assert set(BUNDLED) <= set(listed)
    assert all(listed[n].strip() for n in BUNDLED), 'every bundled scene has a description'


@pytest.mark.parametrize('name', BUNDLED)
def test_bundled_scene_loads_and_its_urdf_agrees_with_pinocchio(name):
    scene = load_scene(name)
    assert scene.name == name
    assert scene.text == Path(scene.path).read_text(encoding='utf-8')
    assert scene.parts == ['arm']
    model = scene.system.model
    assert scene.y0.shape == (scene.system.ny,) and np.all(np.isfinite(scene.y0))
    pm = pin.buildModelFromXML(to_urdf(model))
    assert pm.nq == model.nq and pm.nv == model.nv
    # the same tree: Pinocchio's gravity torques at the scene's initial configuration
    pm.gravity.linear = model.gravity
    q0 = scene.y0[:model.nq]
    g_pin = pin.computeGeneralizedGravity(pm, pm.createData(), q0)
    g_ours = dyn.rnea(model, q0, np.zeros(model.nv), np.zeros(model.nv))
    assert np.allclose(g_ours, g_pin, atol=1e-9 * max(1.0, np.abs(g_pin).max()))
    assert np.abs(g_pin).max() > 1e-3  # gravity acts on every scene's initial posture


def test_scene_by_path_and_unknown_name(tmp_path):
    p = find_scene('stanford_arm')
    copy_path = tmp_path / 'my_arm.yaml'
    copy_path.write_text(p.read_text(encoding='utf-8'), encoding='utf-8')
    assert load_scene(copy_path).system.model.nq == 6
    assert load_scene(str(copy_path)).path == str(copy_path)
    with pytest.raises(SceneError, match='no_such_scene'):
        load_scene('no_such_scene')


# ------------------------------------------------------------------------------------------
# stanford_arm
# ------------------------------------------------------------------------------------------
#: the published standard-DH table (Corke, models.DH.Stanford): (type, theta, d, a, alpha)
STANFORD_DH = [('R', 0.0, 0.412, 0.0, -np.pi / 2), ('R', 0.0, 0.154, 0.0, np.pi / 2),
               ('P', -np.pi / 2, 0.0, 0.0203, 0.0), ('R', 0.0, 0.0, 0.0, -np.pi / 2),
               ('R', 0.0, 0.0, 0.0, np.pi / 2), ('R', 0.0, 0.263, 0.0, 0.0)]


def stanford_fk(q):
    """Tool pose as the product of standard DH matrices Rz(θ) Tz(d) Tx(a) Rx(α)."""
    T = np.eye(4)
    for (kind, theta, d, a, alpha), qi in zip(STANFORD_DH, q):
        if kind == 'R':
            theta = theta + qi
        else:
            d = d + qi
        T = T @ Rz(theta) @ Tz(d) @ Tx(a) @ Rx(alpha)
    return T


def test_stanford_arm_is_6dof_with_a_prismatic_third_joint():
    model = load_scene('stanford_arm').system.model
    assert model.nv == 6
    kinds = [int(model.jtype[model.joint_names.index(j)]) for j in model.dof_joint_names]
    assert kinds == [REVOLUTE, REVOLUTE, PRISMATIC, REVOLUTE, REVOLUTE, REVOLUTE]


def test_stanford_tool_pose_matches_the_dh_product():
    scene = load_scene('stanford_arm')
    model = scene.system.model
    rng = np.random.default_rng(7)
    configs = [scene.y0[:6], np.array([0.0, 0.0, 0.5, 0.0, 0.0, 0.0])]
    configs += [np.concatenate([rng.uniform(-2.5, 2.5, 2), rng.uniform(0.31, 1.27, 1), rng.uniform(-2.5, 2.5, 3)])
                for _ in range(3)]
    assert len(configs) == 5
    errors = [np.abs(pose(model, q, 'tool') - stanford_fk(q)).max() for q in configs]
    assert max(errors) < 1e-12


def test_stanford_scripted_commands_keep_the_arm_bounded_and_moving():
    """10 s of the scene's script at 100 Hz zero-order hold, RK45 rtol 1e-8 on ArmSystem.rhs."""
    scene = load_scene('stanford_arm')
    system = scene.system
    assert scene.script is not None
    rate, duration = 100.0, 10.0
    y, t = scene.y0.copy(), 0.0
    q_hist = [y[:6].copy()]
    finite = True
    for k in range(int(round(duration * rate))):
        u = scene.script(t, y)
        assert set(u) == {'effort'}
        finite &= bool(np.all(np.isfinite(u['effort'])))
        t1 = (k + 1) / rate
        sol = solve_ivp(lambda tt, yy: system.rhs(tt, yy, u), (t, t1), y, method='RK45', rtol=1e-8, atol=1e-10)
        assert sol.success, sol.message
        finite &= bool(np.all(np.isfinite(sol.y)))
        q_hist.extend(sol.y[:6, 1:].T)  # every accepted step, not only the samples
        y, t = sol.y[:, -1], t1
    q_hist = np.array(q_hist)
    assert finite
    assert len(q_hist) > duration * rate
    d3 = q_hist[:, 2]
    # published travel: 12 in minimum stroke plus the 38 in rack (Dobrotin & Scheinman 1973)
    assert d3.min() > 12 * INCH and d3.max() < 50 * INCH, (d3.min(), d3.max())
    # visibly moving: every joint sweeps at least 0.1 rad (0.1 m for the boom)
    assert np.all(np.ptp(q_hist, axis=0) > 0.1), np.ptp(q_hist, axis=0)
    # bounded: the revolute joints stay within +-170 degrees, speeds stay moderate
    assert np.abs(q_hist[:, [0, 1, 3, 5]]).max() < np.deg2rad(170)
    assert np.abs(y[6:]).max() < 20.0


# ------------------------------------------------------------------------------------------
# betancur_pendulum (seed 001: a_i = 0.2 m, m_i = 0.1 kg, g = 9.8)
# ------------------------------------------------------------------------------------------
A_I, M_I, G = 0.2, 0.1, 9.8


def test_betancur_pendulum_is_planar_with_the_papers_masses():
    scene = load_scene('betancur_pendulum')
    model = scene.system.model
    assert model.nv == 4 and scene.system.inputs['effort'].size == 0
    assert np.isclose(model.total_mass(), 4 * M_I)
    assert np.allclose(model.gravity, [0.0, 0.0, -G])
    rng = np.random.default_rng(3)
    configs = [np.zeros(4), scene.y0[:4]] + [rng.uniform(-np.pi, np.pi, 4) for _ in range(4)]
    assert len(configs) == 6
    for q in configs:
        R, p = dyn.body_poses(model, q)
        axes = np.array([R[i] @ model.axis[i] for i in range(4)])
        # all joint axes parallel to each other and horizontal: a vertical plane of motion
        assert np.allclose(np.cross(axes, axes[0]), 0.0, atol=1e-12)
        assert abs(axes[0] @ model.gravity) < 1e-12
        # every body origin (and the tool) stays in the plane through the pivot normal to the axes
        assert np.allclose((p - p[0]) @ axes[0], 0.0, atol=1e-12)


def test_betancur_pendulum_potential_energy_hanging_down_is_the_closed_form():
    scene = load_scene('betancur_pendulum')
    model = scene.system.model
    h = scene.data['parts'][0]['origin']['xyz'][2]  # pivot height above the world origin
    # four uniform bars hanging straight down: com of bar k at depth (k - 1/2) a below the pivot
    V = sum(M_I * G * (h - (k - 0.5) * A_I) for k in range(1, 5))
    q = np.zeros(4)
    assert np.isclose(dyn.potential_energy(model, q), V, rtol=1e-12, atol=1e-12)
    # and it is the equilibrium: no gravity torque on any joint
    assert np.allclose(dyn.rnea(model, q, np.zeros(4), np.zeros(4)), 0.0, atol=1e-12)
    # the released posture is not an equilibrium and lies higher
    q0 = scene.y0[:4]
    assert np.all(np.abs(q0) > 0.1)
    assert dyn.potential_energy(model, q0) > V + 0.1


# ------------------------------------------------------------------------------------------
# huston_p19_2_3: E = prod_k Tx(L_{k-1}) Rx(alpha_k) Rz(gamma_k) * Tx(L)
# ------------------------------------------------------------------------------------------
def test_huston_extremity_matches_the_problem_geometry():
    scene = load_scene('huston_p19_2_3')
    model = scene.system.model
    L, alpha = 0.5, np.deg2rad(45.0)
    gammas = np.deg2rad([15.0, 30.0, 45.0, 60.0])
    assert np.allclose(scene.y0[:4], gammas)

    def E(g):
        T = np.eye(4)
        for k in range(4):
            T = T @ Tx(0.0 if k == 0 else L) @ Rx(alpha) @ Rz(g[k])
        return T @ Tx(L)

    rng = np.random.default_rng(11)
    configs = [gammas, np.zeros(4)] + [rng.uniform(-np.pi, np.pi, 4) for _ in range(3)]
    errors = [np.abs(pose(model, g, 'E') - E(g)).max() for g in configs]
    assert len(errors) == 5 and max(errors) < 1e-12
    assert np.isclose(model.total_mass(), 4.0)


# ------------------------------------------------------------------------------------------
# command profiles evaluate to their definitions
# ------------------------------------------------------------------------------------------
def _write(tmp_path, data, name):
    p = tmp_path / name
    p.write_text(yaml.safe_dump(data, sort_keys=False), encoding='utf-8')
    return p


def _data(name):
    return yaml.safe_load(find_scene(name).read_text(encoding='utf-8'))


def test_command_profiles(tmp_path):
    data = _data('huston_p19_2_3')
    data['commands'] = {'effort': {'profile': 'piecewise_constant', 'times': [0.5, 1.0],
                                   'values': [[1.0, 2.0, 3.0, 4.0], [5.0, 6.0, 7.0, 8.0]]}}
    s = load_scene(_write(tmp_path, data, 'pw.yaml'))
    y = s.y0
    assert np.array_equal(s.script(0.2, y)['effort'], np.zeros(4))
    assert np.array_equal(s.script(0.7, y)['effort'], [1.0, 2.0, 3.0, 4.0])
    assert np.array_equal(s.script(3.0, y)['effort'], [5.0, 6.0, 7.0, 8.0])
    A, f, ph, off = [1.0, 2.0, 0.5, 0.1], [0.5, 1.0, 2.0, 0.0], [0.0, 0.3, 1.0, 0.0], [0.0, 1.0, -1.0, 2.0]
    data['commands'] = {'effort': {'profile': 'sine', 'amplitude': A, 'frequency_hz': f, 'phase': ph, 'offset': off}}
    s = load_scene(_write(tmp_path, data, 'sine.yaml'))
    t = 0.37
    expect = [off[i] + A[i] * np.sin(2 * np.pi * f[i] * t + ph[i]) for i in range(4)]
    assert np.allclose(s.script(t, s.y0)['effort'], expect, rtol=1e-14)
    data['commands'] = {'effort': {'profile': 'constant', 'value': [1.5, -2.0, 0.0, 3.0]}}
    s = load_scene(_write(tmp_path, data, 'const.yaml'))
    assert np.array_equal(s.script(4.0, s.y0)['effort'], [1.5, -2.0, 0.0, 3.0])
    del data['commands']
    assert load_scene(_write(tmp_path, data, 'none.yaml')).script is None


def test_gravity_compensation_holds_the_arm_when_the_sine_is_zero(tmp_path):
    data = _data('stanford_arm')
    eff = data['commands']['effort']
    eff['amplitude'] = [0.0] * 6
    for k in ('stiffness', 'center'):
        eff.pop(k)
    s = load_scene(_write(tmp_path, data, 'hold.yaml'))
    y = s.y0
    qdd = dyn.aba(s.system.model, y[:6], y[6:], s.script(0.0, y)['effort'])
    assert np.allclose(qdd, 0.0, atol=1e-9)


# ------------------------------------------------------------------------------------------
# malformed scenes: each broken in one place, each refused with file, key path and reason
# ------------------------------------------------------------------------------------------
def _set(path, value):
    def mutate(d):
        *head, last = path
        for k in head:
            d = d[k]
        d[last] = value
    return mutate


def _delete(path):
    def mutate(d):
        *head, last = path
        for k in head:
            d = d[k]
        del d[last]
    return mutate


DH = ('parts', 0, 'dh', 'links')
MALFORMED = [
    # id, base scene, mutation, key path expected in the message, reason word
    ('missing_key', 'stanford_arm', _delete(DH + (2, 'mass')), 'parts[0].dh.links[2].mass', 'missing'),
    ('wrong_type', 'stanford_arm', _set(DH + (1, 'a'), 'abc'), 'parts[0].dh.links[1].a', 'number'),
    ('negative_mass', 'stanford_arm', _set(DH + (3, 'mass'), -1.0), 'parts[0].dh.links[3].mass', 'negative'),
    ('non_pd_inertia', 'stanford_arm', _set(DH + (0, 'inertia'), [[1.0, 0.0, 0.0], [0.0, -1.0, 0.0], [0.0, 0.0, 1.0]]),
     'parts[0].dh.links[0].inertia', 'positive semi-definite'),
    ('non_physical_inertia', 'stanford_arm', _set(DH + (4, 'inertia'), [0.003, 0.0004, 0.0, 0.0, 0.0, 0.0]),
     'parts[0].dh.links[4].inertia', 'triangle'),
    ('unknown_joint_type', 'stanford_arm', _set(DH + (0, 'type'), 'helical'), 'parts[0].dh.links[0].type',
     'unknown joint type'),
    ('typo_in_link', 'stanford_arm', _set(DH + (0, 'masss'), 1.0), 'parts[0].dh.links[0].masss', 'unknown key'),
    ('parent_cycle', 'huston_p19_2_3', _set(('parts', 0, 'links', 0, 'parent'), 'link4'),
     'parts[0].links[0].parent', 'cycle'),
    ('unknown_parent', 'huston_p19_2_3', _set(('parts', 0, 'links', 2, 'parent'), 'link9'),
     'parts[0].links[2].parent', 'unknown parent'),
    ('unknown_part_kind', 'stanford_arm', _set(('parts', 0, 'kind'), 'hexapod'), 'parts[0].kind', 'unknown part kind'),
    ('wrong_length_q', 'stanford_arm', _set(('initial_state', 'q'), [0.0, 1.0, 0.8, 0.0, 0.5]), 'initial_state.q',
     'expected 6'),
    ('q_outside_limits', 'stanford_arm', _set(('initial_state', 'q'), [0.0, 1.0, 2.0, 0.0, 0.5, 0.0]),
     'initial_state.q[2]', 'outside the limits'),
    ('wrong_length_command', 'stanford_arm', _set(('commands', 'effort', 'amplitude'), [1.0, 2.0]),
     'commands.effort.amplitude', 'expected 6'),
    ('unknown_profile', 'stanford_arm', _set(('commands', 'effort', 'profile'), 'square_wave'),
     'commands.effort.profile', 'unknown command profile'),
    ('unknown_port', 'stanford_arm', _set(('commands', 'wheel_voltage'), {'profile': 'zero'}),
     'commands.wheel_voltage', 'unknown input port'),
    ('unknown_top_level_key', 'stanford_arm', _set(('simulaton',), {'dt': 0.001}), 'simulaton', 'unknown key'),
    ('unknown_actuated_joint', 'stanford_arm', _set(('parts', 0, 'actuated'), ['joint1', 'joint7']),
     'parts[0].actuated[1]', 'not a 1-DOF joint'),
    ('bad_setting', 'stanford_arm', _set(('simulation', 'dt'), -0.001), 'simulation.dt', 'must be > 0'),
]


@pytest.mark.parametrize('case, base, mutate, key_path, reason', MALFORMED, ids=[m[0] for m in MALFORMED])
def test_malformed_scene_is_refused_with_file_key_path_and_reason(tmp_path, case, base, mutate, key_path, reason):
    data = copy.deepcopy(_data(base))
    load_scene(_write(tmp_path, data, f'valid_{case}.yaml'))  # the unbroken copy loads
    mutate(data)
    p = _write(tmp_path, data, f'bad_{case}.yaml')
    with pytest.raises(SceneError) as info:
        load_scene(p)
    msg = str(info.value)
    assert isinstance(info.value, ValueError)
    assert msg.startswith(f'{p}: {key_path}: '), msg
    assert reason in msg, msg


@pytest.mark.parametrize('case, text_edit, reason', [
    ('syntax', lambda t: t + '\nbroken: [1, 2\n', 'YAML syntax error'),
    ('duplicate_key', lambda t: t + '\nname: again\n', 'duplicate key'),
    ('not_a_mapping', lambda t: '- just\n- a list\n', 'expected a mapping'),
])
def test_unparsable_scene_text_is_refused(tmp_path, case, text_edit, reason):
    text = find_scene('stanford_arm').read_text(encoding='utf-8')
    p = tmp_path / f'bad_{case}.yaml'
    p.write_text(text_edit(text), encoding='utf-8')
    with pytest.raises(SceneError) as info:
        load_scene(p)
    msg = str(info.value)
    assert msg.startswith(f'{p}: '), msg
    assert reason in msg, msg
    if case != 'not_a_mapping':
        assert ': line ' in msg, msg  # the key path of a syntax error is its line and column
