"""Mimic joints (URDF ``<mimic>``): the coupled dynamics of the compiled kernels against Pinocchio
(a model reduced by hand with the coupling read from the XML, and Pinocchio's own mimic model)
and against closed forms (a double pendulum whose second joint follows the first); joint_states,
efforts and wrenches of the following joints; what the importer does with odd mimics."""
from __future__ import annotations

import math
import warnings
import xml.etree.ElementTree as ET

import numpy as np
import pinocchio as pin
import pytest

from robodyn_ros import kernels
from robodyn_ros.scene import SceneError, load_scene, parse_scene
from robodyn_ros.simulation import Simulator, run_headless
from robodyn_ros.urdf import UrdfError, example_robot_data_dir, read_urdf
from test_pinocchio import rel

ERD = example_robot_data_dir()
MIMIC_ROBOTS = ['panda_description/urdf/panda.urdf', 'pr2_description/urdf/pr2.urdf',
                'tiago_pro_description/robots/tiago_pro.urdf', 'talos_data/robots/talos_full_v2.urdf',
                'baxter_description/urdf/baxter.urdf']
#: relative agreement with Pinocchio (measured worst: see the test's printout)
#: worst relative differences allowed: against Pinocchio's model reduced by hand (measured 7.9e-14), and
#: against Pinocchio's own mimic model (measured 2.3e-15); docs/urdf.md prints both beside these bounds
TOL = 1e-11
TOL_MIMIC_MODEL = 1e-12


def _scene(path, backend='numba'):
    from robodyn_ros.systems.base import backend_scope
    with warnings.catch_warnings(), backend_scope(backend):
        warnings.simplefilter('ignore')
        return load_scene(path)


def xml_coupling(path):
    """``{joint: (independent joint, multiplier, offset)}`` read from the URDF with ElementTree
    alone (an oracle independent of the importer): chains of mimics composed."""
    root = ET.parse(path).getroot()
    direct = {}
    for j in root.iter('joint'):
        m = j.find('mimic')
        if m is not None and j.get('type') != 'fixed':
            direct[j.get('name')] = (m.get('joint'), float(m.get('multiplier', 1)), float(m.get('offset', 0)))
    out = {}
    for j, (s, k, o) in direct.items():
        while s in direct:
            s2, k2, o2 = direct[s]
            s, k, o = s2, k * k2, k * o2 + o
        out[j] = (s, k, o)
    return out


class Bridge:
    """Our 1-DOF fixed-base model against Pinocchio's (mimic=False) model of the same file: q/v
    maps by joint name (a continuous joint is (cos, sin) there), and the coupling matrix G."""

    def __init__(self, m, path):
        self.m = m
        self.pm = pin.buildModelFromUrdf(path)
        self.pm.gravity.linear = np.asarray(m.gravity, dtype=float)
        self.pd = self.pm.createData()
        self.names = m.state_joint_names
        self.jm = [self.pm.joints[self.pm.getJointId(n)] for n in self.names]
        cpl = xml_coupling(path)
        self.cpl = {n: c for n, c in cpl.items() if n in self.names and c[0] in self.names}
        assert self.cpl, f'{path}: no mimic coupling read from the XML: the comparison would test none'
        ind = [n for n in self.names if n not in self.cpl]
        self.G = np.zeros((m.nv, len(ind)))
        for k, n in enumerate(self.names):
            src, mul = self.cpl.get(n, (n, 1.0, 0.0))[:2]
            self.G[k, ind.index(src)] = mul
        self.ind = ind

    def state(self, rng):
        """A coupled random state (q, v) in our order."""
        x = {n: rng.uniform(-1.5, 1.5) for n in self.ind}
        xd = {n: rng.normal() for n in self.ind}
        q = np.array([self.cpl[n][1] * x[self.cpl[n][0]] + self.cpl[n][2] if n in self.cpl else x[n]
                      for n in self.names])
        v = np.array([self.cpl[n][1] * xd[self.cpl[n][0]] if n in self.cpl else xd[n] for n in self.names])
        return q, v

    def pin_qv(self, q, v):
        qp, vp = pin.neutral(self.pm), np.zeros(self.pm.nv)
        for k, jm in enumerate(self.jm):
            if jm.nq == 2:
                qp[jm.idx_q:jm.idx_q + 2] = math.cos(q[k]), math.sin(q[k])
            else:
                qp[jm.idx_q] = q[k]
            vp[jm.idx_v] = v[k]
        return qp, vp

    def back(self, x):
        return np.array([x[jm.idx_v] for jm in self.jm])

    def coupled_fd(self, q, v, tau):
        """v̇ = G (Gᵀ M G)⁻¹ Gᵀ (τ − h) from pin.crba and pin.rnea of the unreduced model."""
        qp, vp = self.pin_qv(q, v)
        Mp = pin.crba(self.pm, self.pd, qp)
        Mp = np.triu(Mp) + np.triu(Mp, 1).T
        idx = [jm.idx_v for jm in self.jm]
        M = Mp[np.ix_(idx, idx)]
        h = self.back(pin.rnea(self.pm, self.pd, qp, vp, np.zeros(self.pm.nv)))
        G = self.G
        return G @ np.linalg.solve(G.T @ M @ G, G.T @ (tau - h)), M, h


@pytest.mark.parametrize('rel_path', MIMIC_ROBOTS, ids=[p.split('/')[-1] for p in MIMIC_ROBOTS])
def test_coupled_forward_dynamics_equals_pinocchio_reduced_by_hand(rel_path):
    """At seeded random coupled states and random efforts on every joint (mimic ones too: their
    damping or an external torque enters through Gᵀ), our v̇ equals Pinocchio's unreduced model
    reduced by hand with the XML's coupling; the coupling's force λ = M v̇ + h − τ does no work
    (Gᵀ λ = 0) and is what the kernels report."""
    path = str(ERD / rel_path)
    sc = _scene(path)
    m = sc.system.model
    assert m.has_mimic and sc.system._coupled
    b = Bridge(m, path)
    assert len(b.cpl) == len(m.mimic_joint_names) and set(b.cpl) == set(m.mimic_joint_names)
    km = kernels.CompiledModel(m)
    rng = np.random.default_rng(2020)
    worst = {'qdd': 0.0, 'lambda': 0.0, 'work': 0.0}
    for _ in range(4):
        q, v = b.state(rng)
        tau = 5.0 * rng.normal(size=m.nv)
        qdd = km.aba(q, v, tau)
        ref, M, h = b.coupled_fd(q, v, tau)
        worst['qdd'] = max(worst['qdd'], rel(qdd, ref))
        _, f, lam = km.coupled_wrenches(q, v, tau)
        lam_ref = M @ ref + h - tau
        worst['lambda'] = max(worst['lambda'], rel(lam, lam_ref))
        worst['work'] = max(worst['work'], float(np.max(np.abs(b.G.T @ lam))) / max(1.0, float(np.max(np.abs(lam)))))
    print(rel_path, m.nv, 'dof,', len(b.cpl), 'mimic; worst relative differences', worst)
    assert worst['qdd'] < TOL and worst['lambda'] < TOL and worst['work'] < TOL


@pytest.mark.parametrize('rel_path', MIMIC_ROBOTS[:3], ids=[p.split('/')[-1] for p in MIMIC_ROBOTS[:3]])
def test_coupled_dynamics_equals_pinocchios_own_mimic_model(rel_path):
    """Pinocchio's mimic model (``mimic=True``: the following joints have no coordinates) gives
    ``M_r`` by CRBA and ``Gᵀ h`` by RNEA; its v̇_r equals our independent joints' v̇."""
    path = str(ERD / rel_path)
    m = _scene(path).system.model
    b = Bridge(m, path)
    pr = pin.buildModelFromUrdf(path, mimic=True)
    pr.gravity.linear = np.asarray(m.gravity, dtype=float)
    prd = pr.createData()
    assert pr.nv == len(b.ind)
    km = kernels.CompiledModel(m)
    rng = np.random.default_rng(7)
    worst = 0.0
    for _ in range(4):
        q, v = b.state(rng)
        tau = 5.0 * rng.normal(size=m.nv)
        qr, vr, tr = pin.neutral(pr), np.zeros(pr.nv), np.zeros(pr.nv)
        for k, n in enumerate(b.names):
            if n in b.cpl:
                continue
            jm = pr.joints[pr.getJointId(n)]
            if jm.nq == 2:
                qr[jm.idx_q:jm.idx_q + 2] = math.cos(q[k]), math.sin(q[k])
            else:
                qr[jm.idx_q] = q[k]
            vr[jm.idx_v] = v[k]
        gt = b.G.T @ tau
        for a, n in enumerate(b.ind):
            tr[pr.joints[pr.getJointId(n)].idx_v] = gt[a]
        Mr = pin.crba(pr, prd, qr)
        Mr = np.triu(Mr) + np.triu(Mr, 1).T
        ar = np.linalg.solve(Mr, tr - pin.rnea(pr, prd, qr, vr, np.zeros(pr.nv)))
        qdd = km.aba(q, v, tau)
        ours = np.array([qdd[b.names.index(n)] for n in b.ind])
        theirs = np.array([ar[pr.joints[pr.getJointId(n)].idx_v] for n in b.ind])
        worst = max(worst, rel(ours, theirs))
    print(rel_path, 'worst relative difference to Pinocchio mimic=True:', worst)
    assert worst < TOL_MIMIC_MODEL


# ------------------------------------------------------------------------------------------------
# closed forms: a double pendulum (point masses m at l below each joint, joints about y) whose
# second joint follows the first
# ------------------------------------------------------------------------------------------------
M_, L_, G_ = 0.7, 0.4, 9.81


def _pendulum(multiplier, offset=0.0, damping2=0.0):
    pm = (f'<inertial><origin xyz="0 0 -{L_}"/><mass value="{M_}"/>'
          '<inertia ixx="0" iyy="0" izz="0" ixy="0" ixz="0" iyz="0"/></inertial>')
    return (f'<robot name="coupled"><link name="base"/><link name="l1">{pm}</link><link name="l2">{pm}</link>'
            '<joint name="j1" type="continuous"><parent link="base"/><child link="l1"/><axis xyz="0 1 0"/></joint>'
            '<joint name="j2" type="continuous"><parent link="l1"/><child link="l2"/>'
            f'<origin xyz="0 0 -{L_}"/><axis xyz="0 1 0"/><dynamics damping="{damping2}"/>'
            f'<mimic joint="j1" multiplier="{multiplier}" offset="{offset}"/></joint></robot>')


class Recorder:
    """A run_headless sink keeping (t, joint names, position, velocity, effort) of every output."""

    def __init__(self):
        self.seen = []

    def on_start(self, sim):
        pass

    def on_command(self, t, port, values):
        pass

    def on_output(self, t, out, sim):
        self.seen.append((t, list(out.joint_names), out.position.copy(), out.velocity.copy(), out.effort.copy()))

    def close(self):
        pass


def _system(text):
    sc = parse_scene('name: p\nparts:\n  - kind: urdf\n    name: p\n    urdf: |\n      ' + text + '\n')
    return sc


def closed_form(multiplier, offset, th, thd, tau1, tau2):
    """θ̈ of the coupled pendulum from Lagrange's equation derived by hand (θ = q1, q2 = k θ + o;
    link 2's absolute angle φ = (1 + k) θ + o; generalised force τ1 + k τ2):

    T = ½ m l² θ̇² (1 + 1 + (1 + k)² + 2 (1 + k) cos(kθ + o)),
    V = −m g l (2 cos θ + cos φ)."""
    k, o = multiplier, offset
    a = 1.0 + k
    Mr = M_ * L_ ** 2 * (2.0 + a * a + 2.0 * a * math.cos(k * th + o))
    # d/dt ∂T/∂θ̇ − ∂T/∂θ = Mr θ̈ + (dMr/dθ) θ̇² − ½ (dMr/dθ) θ̇² = Mr θ̈ + ½ dMr/dθ θ̇²
    dMr = -2.0 * M_ * L_ ** 2 * a * k * math.sin(k * th + o)
    dV = M_ * G_ * L_ * (2.0 * math.sin(th) + a * math.sin(a * th + o))
    return (tau1 + k * tau2 - 0.5 * dMr * thd ** 2 - dV) / Mr


@pytest.mark.parametrize('multiplier, offset', [(1.0, 0.0), (-1.0, 0.3), (0.0, 0.5), (2.0, -0.2)])
def test_coupled_pendulum_against_its_closed_form(multiplier, offset):
    """k = 1: the second link turns twice as fast; k = −1: it translates (a simple pendulum of mass
    2m); k = 0: the two links are one rigid body bent by o (a compound pendulum); k = 2."""
    sc = _system(_pendulum(multiplier, offset))
    sys_ = sc.system
    assert sys_.joint_names == ['j1', 'j2'] and sys_.actuated == ['j1']
    rng = np.random.default_rng(11)
    for _ in range(5):
        th, thd, u = rng.uniform(-2, 2), rng.normal(), rng.normal()
        y = sys_.initial_state(q0=[th, 0.0], v0=[thd, 0.0])
        assert y[1] == multiplier * th + offset and y[3] == multiplier * thd
        dy = sys_.rhs(0.0, y, {'effort': np.array([u])})
        expect = closed_form(multiplier, offset, th, thd, u, 0.0)
        assert dy[2] == pytest.approx(expect, rel=1e-12, abs=1e-12)
        assert dy[3] == pytest.approx(multiplier * expect, rel=1e-12, abs=1e-12)


def test_translating_link_swings_as_a_simple_pendulum_of_twice_the_mass():
    """k = −1: θ̈ = −(g/l) sin θ exactly (2 m l² θ̈ = −2 m g l sin θ). Two seconds from 0.5 rad by
    RK4 at 1 ms against scipy's DOP853 on that equation at rtol 1e-12; energy conserved; the
    following joint stays at −θ + o to the last bit; joint_states lists it."""
    from scipy.integrate import solve_ivp
    sc = _system(_pendulum(-1.0, 0.3))
    sim = Simulator(sc.system, sc.system.initial_state(q0=[0.5, 0.0]), integrator='rk4', dt=1e-3)
    rec = Recorder()
    run_headless(sim, 2.0, 50.0, None, [rec])
    seen = rec.seen
    assert len(seen) == 101
    ref = solve_ivp(lambda t, x: [x[1], -G_ / L_ * math.sin(x[0])], (0, 2.0), [0.5, 0.0], method='DOP853',
                    rtol=1e-12, atol=1e-12, dense_output=True)
    err = max(abs(p[0] - ref.sol(t)[0]) for t, _, p, _, _ in seen)
    print(f'simple-pendulum error over 2 s at RK4 1 ms: {err:.2e} rad')
    assert err < 1e-9
    assert abs(sim.energy_report()['relative_drift']) < 1e-10
    assert all(names == ['j1', 'j2'] and p[1] == -p[0] + 0.3 and v[1] == -v[0] for _, names, p, v, _ in seen)


def test_mimic_effort_is_the_coupling_force_and_wrenches_project_to_joint_efforts():
    """joint_states: the source's effort is its command; the follower's is the coupling force λ₂,
    here from the closed form (the torque about j2 that moves link 2's point mass as the coupled
    motion requires). The constraint wrench of each joint, projected on its axis, is that
    joint's total effort (command + λ)."""
    sc = _system(_pendulum(1.0, 0.0))
    sys_ = sc.system
    th, thd, u = 0.4, -0.8, 0.25
    y = sys_.initial_state(q0=[th, 0.0], v0=[thd, 0.0])
    out = sys_.outputs(0.0, y, {'effort': np.array([u])})
    a = closed_form(1.0, 0.0, th, thd, u, 0.0)
    # link 2: a point mass m at l below j2; j2 at l below j1. Torque about j2 = m l × (accel of the mass)
    # in the plane, plus gravity: from the mass's world position p2 = p1 + l (−sin φ, −cos φ), φ = 2θ
    ph, phd, phdd = 2 * th, 2 * thd, 2 * a
    acc1 = L_ * np.array([-math.cos(th) * a + math.sin(th) * thd ** 2, math.sin(th) * a + math.cos(th) * thd ** 2])
    acc2 = acc1 + L_ * np.array([-math.cos(ph) * phdd + math.sin(ph) * phd ** 2,
                                 math.sin(ph) * phdd + math.cos(ph) * phd ** 2])
    r = L_ * np.array([-math.sin(ph), -math.cos(ph)])   # from j2 to the mass, (x, z)
    F = M_ * (acc2 - np.array([0.0, -G_]))                # force on the mass from the link (x, z)
    lam2 = r[1] * F[0] - r[0] * F[1]                      # j2's torque on link 2 about +y: (r × F)_y = z F_x − x F_z
    assert list(out.effort) == pytest.approx([u, lam2], rel=1e-12)
    # the coupling does no work (λ1 + k λ2 = 0, k = 1): j1 transmits its command plus λ1 = −λ2
    for j, total in (('j1', u - lam2), ('j2', lam2)):
        frame, w = out.wrenches[j]
        assert w[1] == pytest.approx(total, rel=1e-12)   # the axis is y, the wrench in the child frame


def _chain_link(n):
    return (f'<link name="{n}"><inertial><origin xyz="0 0 -0.3"/><mass value="1"/><inertia ixx="0.01" iyy="0.01" '
            'izz="0.01" ixy="0" ixz="0" iyz="0"/></inertial></link>')


def _chain_joint(n, p, c, mimic=''):
    return (f'<joint name="{n}" type="revolute"><parent link="{p}"/><child link="{c}"/><axis xyz="0 1 0"/>'
            f'<limit effort="5" lower="-3" upper="3" velocity="2"/><dynamics damping="0.05"/>{mimic}</joint>')


#: four links on joints about y: j2 follows j1 (x2, +0.1), j3 follows j2 (x-0.5, +0.2), j4's mimic names no joint
CHAIN = ('<robot name="c"><link name="base"/>' + ''.join(_chain_link(n) for n in 'abcd') +
         _chain_joint('j1', 'base', 'a') + _chain_joint('j2', 'a', 'b', '<mimic joint="j1" multiplier="2" offset="0.1"/>') +
         _chain_joint('j3', 'b', 'c', '<mimic joint="j2" multiplier="-0.5" offset="0.2"/>') +
         _chain_joint('j4', 'c', 'd', '<mimic joint="ghost"/>') + '</robot>')


def test_mimic_chains_locks_and_odd_mimics():
    chain = CHAIN
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter('always')
        r = read_urdf(chain)
    assert r.notes == ["joint 'j4': <mimic joint=\"ghost\"> ignored: 'ghost' is not a joint of the robot; the joint "
                       "moves on its own"] and len(caught) == 1
    sc = _system(chain)
    s = sc.system
    assert s.actuated == ['j1', 'j4'] and s.joint_names == ['j1', 'j2', 'j3', 'j4']
    y = s.initial_state(q0=[0.4, 0, 0, 0.1])
    assert y[:4].tolist() == [0.4, 2 * 0.4 + 0.1, -0.5 * (2 * 0.4 + 0.1) + 0.2, 0.1]   # a mimic of a mimic
    with pytest.raises(SceneError, match=r"actuated\[0\]: .*'j2'|actuated joints \['j2'\] are not joints that take"):
        parse_scene('name: p\nparts:\n  - kind: urdf\n    name: p\n    actuated: [j2]\n    urdf: |\n      '
                    + chain + '\n')
    # locking the source locks its followers, with a note
    with warnings.catch_warnings(record=True):
        warnings.simplefilter('always')
        r = read_urdf(chain, locked={'j1': 0.5})
    types = {x.joint: x.joint_type for x in r.specs}
    assert types == {'j1': 'fixed', 'j2': 'fixed', 'j3': 'fixed', 'j4': 'revolute'}
    assert "joint 'j3': mimics locked joint 'j2', so it is locked too, at -0.35" in r.notes
    # a cycle is refused
    cyc = chain.replace('<mimic joint="j1" multiplier="2"', '<mimic joint="j3" multiplier="2"')
    with pytest.raises(UrdfError, match=r"joint 'j\d': the mimic joints form a cycle"):
        read_urdf(cyc)


def test_example_robot_data_mimic_robots_run_and_keep_the_coupling_exact():
    """panda (fingers) and pr2 (grippers, 10 mimic joints): 0.3 s from rest on the per-step RK4
    path with recorded joint_states: every following joint equals m q_i + o exactly at every
    publication; energy balance holds."""
    for rel_path in MIMIC_ROBOTS[:2]:
        path = str(ERD / rel_path)
        sc = _scene(path)
        s = sc.system
        table = kernels.CompiledModel(s.model).mimic
        sim = Simulator(s, sc.y0, integrator='rk4', dt=1e-3)
        rec = Recorder()
        run_headless(sim, 0.3, 100.0, None, [rec])
        states = [p for _, _, p, _, _ in rec.seen]
        assert len(states) == 31
        assert s.model.nq == s.model.nv == len(s.joint_names)   # joint_states in q order
        for p in states:
            for qj, vj, qi, vi, k, o in table:
                assert p[int(qj)] == k * p[int(qi)] + o
        assert abs(sim.energy_report()['relative_drift']) < 1e-8, rel_path


def test_mimic_joints_are_refused_where_the_coupling_is_not_modelled():
    """A floating URDF base or a platform mount with mimic joints: refused with the way out (lock
    them); locked, the same robot loads; the numpy backend refuses the coupled tree."""
    text = _pendulum(1.0)
    with pytest.raises(SceneError, match=r"parts\[0\]\.urdf: joint 'j2': <mimic> joints are supported for a URDF "
                                         r"mounted on the world only"):
        parse_scene('name: p\nparts:\n  - kind: urdf\n    name: p\n    floating: true\n    urdf: |\n      '
                    + text + '\n')
    sc = parse_scene('name: p\nparts:\n  - kind: urdf\n    name: p\n    floating: true\n    locked: {j2: 0.0}\n'
                     '    urdf: |\n      ' + text + '\n')
    assert sc.system.model.nv == 7
    from robodyn_ros.systems.base import backend_scope
    with backend_scope('numpy'), pytest.raises(SceneError, match='mimic joints .* compiled kernels only'):
        _system(text)


def test_robot_description_keeps_the_mimics_and_reads_back_the_same_coupling():
    sc = _scene(str(ERD / MIMIC_ROBOTS[1]))
    text = sc.system.urdf()
    assert text.count('<mimic ') == len(sc.system.model.mimic_joint_names) == 10
    back = read_urdf(text)
    assert {s.joint: s.mimic for s in back.specs if s.mimic} == \
        {s.joint: s.mimic for s in sc.system.model.specs if s.mimic}
    pr = pin.buildModelFromXML(text, mimic=True)   # urdfdom and Pinocchio read them as mimics
    assert pr.nv == sc.system.model.nv - 10


@pytest.mark.parametrize('robot', ['pr2', 'chain'])
@pytest.mark.parametrize('method', ['rk4', 'euler', 'semi_implicit_euler'])
def test_fused_loop_equals_the_per_step_path_on_a_mimic_robot(method, robot):
    """pr2 (10 mimic joints, multipliers ±1, damping) and the chain (multipliers 2 and −0.5,
    offsets): 0.2 s with a command on every independent joint, through the compiled fused loop
    and through the Simulator's per-step Python path (the system's rhs and projection): the same
    states, bit for bit (as for every arm: the same operations in the same order; B is a 0/1
    selection, so numpy's B u has the compiled loop's bits)."""
    sc = _scene(str(ERD / MIMIC_ROBOTS[1])) if robot == 'pr2' else _system(CHAIN)
    s = sc.system
    u = 0.3 * np.sin(np.arange(s.inputs['effort'].size))
    out = []
    per_step = _PerStep(s)
    for system in (s, per_step):
        sim = Simulator(system, sc.y0, integrator=method, dt=1e-3)
        sim.set_command('effort', u)
        calls = per_step.rhs_calls
        sim.advance(0.2)
        out.append(sim.y.copy())
    assert per_step.rhs_calls - calls >= 200   # the second run stepped in Python
    assert s.fused_advance(method, 1e-3, 0.0, np.concatenate([sc.y0, [0.0]]), 1e-3, {'effort': u}) is not None
    diff = float(np.max(np.abs(out[0] - out[1])))
    print(f'{method}: fused vs per-step largest difference {diff:.2e}')
    assert diff == 0.0   # the same arithmetic, compiled once: the fused loop is the per-step path, step by step


class _PerStep:
    """A system that forwards everything but the fused loop (the Simulator then steps in Python)."""

    def __init__(self, system):
        self._s = system
        self.rhs_calls = 0

    def rhs(self, t, y, u):
        self.rhs_calls += 1
        return self._s.rhs(t, y, u)

    def __getattr__(self, name):
        if name in ('fused_advance', 'fused_periods'):
            raise AttributeError(name)
        return getattr(self._s, name)
