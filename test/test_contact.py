"""Ground contact (kernels/contact.py) against closed forms: a box at rest, a box on a tilted plane
(sliding and creeping), a sphere bouncing (the Hunt–Crossley law's restitution), and bad input.

The law (module docstring of :mod:`robodyn_ros.kernels.contact`): ``f_n = max(0, k δ (1 + d δ̇))``,
``F_t = −μ f_n tanh(|u_t|/v_s) u_t/|u_t|``. The box is a URDF with one ``<collision><box>``: its 8
corners are its contact points, 4 of them touch.
"""
from __future__ import annotations

import math

import numpy as np
import pytest
import yaml
from scipy.optimize import brentq

from robodyn_ros import kernels
from robodyn_ros.kernels.contact import PACTIVE, PDEPTH, PF
from robodyn_ros.scene import parse_scene
from robodyn_ros.simulation import Simulator
from robodyn_ros.validation import SceneError

assert kernels.AVAILABLE, kernels.UNAVAILABLE_REASON

G = 9.81
MASS = 2.0
SIZE = (0.4, 0.3, 0.2)


def box_urdf(mass=MASS, size=SIZE):
    """A box body (uniform inertia) whose collision shape is the box itself."""
    a, b, c = size
    ixx, iyy, izz = mass * (b * b + c * c) / 12, mass * (a * a + c * c) / 12, mass * (a * a + b * b) / 12
    return (f'<robot name="box"><link name="box"><inertial><mass value="{mass}"/>'
            f'<inertia ixx="{ixx}" iyy="{iyy}" izz="{izz}" ixy="0" ixz="0" iyz="0"/></inertial>'
            f'<collision><geometry><box size="{a} {b} {c}"/></geometry></collision></link></robot>')


def sphere_urdf(mass=1.0, radius=0.05):
    i = 0.4 * mass * radius * radius
    return (f'<robot name="ball"><link name="ball"><inertial><mass value="{mass}"/>'
            f'<inertia ixx="{i}" iyy="{i}" izz="{i}" ixy="0" ixz="0" iyz="0"/></inertial>'
            f'<collision><geometry><sphere radius="{radius}"/></geometry></collision></link></robot>')


def scene(urdf, ground, q, v=None, gravity=(0.0, 0.0, -G)):
    data = {'name': 't', 'gravity': list(gravity),
            'parts': [{'kind': 'urdf', 'name': 'body', 'urdf': urdf, 'floating': True}, {'kind': 'ground', **ground}],
            'initial_state': {'q': list(map(float, q)), **({'v': list(map(float, v))} if v is not None else {})}}
    return parse_scene(yaml.safe_dump(data, sort_keys=False), file='t.yaml')


def run(sc, dt, T, every, integrator='rk4'):
    """``(times, states)`` every ``every`` s up to T."""
    sim = Simulator(sc.system, sc.y0, integrator=integrator, dt=dt)
    n = int(round(T / every))
    ts, ys = [0.0], [sim.y.copy()]
    for k in range(1, n + 1):
        sim.advance(k * every)
        ts.append(sim.t)
        ys.append(sim.y.copy())
    return np.array(ts), np.array(ys), sim


def quat_y(theta):
    return [0.0, math.sin(theta / 2), 0.0, math.cos(theta / 2)]


# --------------------------------------------------------------------------------------------
# a box at rest
# --------------------------------------------------------------------------------------------
def test_box_at_rest_carries_its_weight_at_the_closed_form_penetration_without_drift():
    """Σ f_n = m g, each of the 4 lower corners sinks m g / (4 k), and nothing moves over 10 s."""
    k = 1.0e4
    sc = scene(box_urdf(), {'stiffness': k, 'dissipation': 5.0, 'friction': 0.8}, [0, 0, 0.1 + 0.01, 0, 0, 0, 1])
    sysm = sc.system
    assert sysm.contact.n_points == 8
    ts, ys, sim = run(sc, 1e-3, 10.0, 0.5)
    P = sysm.contact.point_outputs(sysm._km, sim.y[:sysm.nq], sim.y[sysm.nq:])
    on = P[:, PACTIVE] > 0
    assert on.sum() == 4
    F = P[on, PF:PF + 3].sum(axis=0)
    assert abs(F[2] - MASS * G) < 1e-12 * MASS * G, F
    assert np.abs(F[:2]).max() < 1e-9
    np.testing.assert_allclose(P[on, PDEPTH], MASS * G / (4 * k), rtol=1e-12)
    i5 = int(np.flatnonzero(ts >= 5.0)[0])
    drift = np.abs(ys[i5:, :7] - ys[-1, :7]).max()
    assert drift < 1e-10, drift
    # the published wrench of the link: the same resultant, world axes, frame_id = the world frame
    out = sim.outputs()
    frame, w = out.contacts['box']
    assert frame == sysm.model.root == 'odom'
    assert abs(w[5] - MASS * G) < 1e-9 * MASS * G
    assert np.abs(w[:3]).max() < 1e-9     # about the centre of pressure: no moment
    assert out.extra['contact_active'] == 4
    assert abs(out.extra['contact_max_penetration'] - MASS * G / (4 * k)) < 1e-9 * MASS * G / (4 * k)
    # the energy balance closes with the contact work, which is negative (dissipation + stored spring);
    # its residue is RK4's error at the 1 cm touch-down (the force's slope jumps there): 5e-6 of E0
    e = sim.energy_report()
    assert abs(e['drift']) < 2e-5 * abs(e['energy0']), e
    assert e['contact_work'] < 0.0
    spring = 4 * 0.5 * k * (MASS * G / (4 * k)) ** 2
    assert e['contact_work'] < -spring


# --------------------------------------------------------------------------------------------
# a box on a tilted plane
# --------------------------------------------------------------------------------------------
def _on_slope(theta, mu, v_s, T, dt=1e-4):
    """The box resting on a plane tilted by theta about y (normal (sin θ, 0, cos θ)): its displacement
    down the slope, ``(times, s(t))``."""
    n = np.array([math.sin(theta), 0.0, math.cos(theta)])
    k = 1e5
    c = (SIZE[2] / 2 - MASS * G * math.cos(theta) / (4 * k)) * n   # centre at the equilibrium penetration
    sc = scene(box_urdf(), {'normal': n.tolist(), 'stiffness': k, 'dissipation': 5.0, 'friction': mu,
                            'slip_speed': v_s}, [*c, *quat_y(theta)])
    ts, ys, _ = run(sc, dt, T, 0.01)
    down = np.array([math.cos(theta), 0.0, -math.sin(theta)])
    return ts, (ys[:, :3] - c) @ down


def test_box_slides_down_a_steep_slope_at_the_coulomb_deceleration():
    """tan θ > μ: ``s̈ = g (sin θ − μ cos θ)`` (the regularisation is saturated above ~5 v_s)."""
    theta, mu = math.radians(30.0), 0.3
    ts, s = _on_slope(theta, mu, 1e-3, 1.5)
    sel = ts >= 0.5
    a = 2.0 * np.polyfit(ts[sel], s[sel], 2)[0]
    expected = G * (math.sin(theta) - mu * math.cos(theta))
    assert abs(a - expected) < 1e-11 * expected, (a, expected)   # measured 7.9e-14 (docs/contact.md)


def test_box_on_a_gentle_slope_creeps_at_the_regularisations_speed():
    """tan θ < μ: held by friction up to the stated creep ``v = v_s artanh(tan θ / μ)``."""
    theta, mu, v_s = math.radians(10.0), 0.5, 1e-3
    ts, s = _on_slope(theta, mu, v_s, 2.0)
    sel = ts >= 1.0
    v = np.polyfit(ts[sel], s[sel], 1)[0]
    expected = v_s * math.atanh(math.tan(theta) / mu)
    assert abs(expected - 3.7e-4) < 5e-6                          # docs/contact.md: 0.37 mm/s
    print(f'creep {v!r} m/s against {expected!r}: {abs(v / expected - 1):.2g} relative')
    assert abs(v - expected) < 1e-9 * expected, (v, expected)     # docs/contact.md: 9.8e-12


# --------------------------------------------------------------------------------------------
# a sphere bouncing: the law's restitution
# --------------------------------------------------------------------------------------------
def restitution_speed(v_in, d):
    """Rebound speed of the law without gravity: the root w in (−1/d, 0) of
    ``w − ln(1 + d w)/d = v_in − ln(1 + d v_in)/d`` (``m v dv/dδ = −k δ (1 + d v)`` integrated over the
    contact, δ from 0 back to 0), returned as a positive speed."""
    C = v_in - math.log1p(d * v_in) / d
    w = brentq(lambda x: x - math.log1p(d * x) / d - C, -1.0 / d + 1e-15, -1e-12, xtol=1e-15, rtol=1e-15)
    return -w


@pytest.mark.parametrize('d', [0.3, 2.0])
def test_sphere_rebounds_at_the_closed_form_restitution_without_gravity(d):
    """Thrown at the ground at 1 m/s in zero gravity, the sphere leaves at the law's rebound speed,
    whatever k: to the integration error (RK4 at 10 µs, contact lasting ~10 ms)."""
    r, v_in = 0.05, 1.0
    sc = scene(sphere_urdf(radius=r), {'stiffness': 1e4, 'dissipation': d, 'friction': 0.0},
               [0, 0, r + 0.005, 0, 0, 0, 1], v=[0, 0, 0, 0, 0, -v_in], gravity=(0, 0, 0))
    ts, ys, sim = run(sc, 1e-5, 0.06, 0.002)
    v_out = sim.y[sc.system.nq + 5]
    assert ys[:, 2].min() < r          # it touched
    assert sim.y[2] > r + 0.005        # and left
    expected = restitution_speed(v_in, d)
    print(f'd = {d}: rebound {v_out!r} m/s, closed form {expected!r}: {abs(v_out - expected):.2g}')
    assert abs(v_out - expected) < 1e-7, (v_out, expected)         # docs/contact.md: 1.7e-8 m/s
    assert abs(expected - {0.3: 0.83, 2.0: 0.41}[d]) < 0.005       # docs/contact.md's restitutions at 1 m/s


def test_dropped_sphere_rebounds_to_the_restitution_height():
    """Dropped from h0 = 0.5 m, the sphere's lowest point rises to ``e² h0`` (e = the law's restitution at
    the impact speed ``v_in = √(2 g h0)``) up to gravity's part in the contact, which the closed form leaves
    out: its impulse over the contact time ``t_c ≈ π √(m/k)`` (1 ms) changes the rebound height by about
    ``g t_c / v_in`` (0.3 %; measured against the 1-D law integrated with gravity by scipy: −0.32 %);
    asserted within ``1.5 g t_c / v_in``."""
    r, h0, d, k, m = 0.05, 0.5, 0.4, 1e7, 1.0
    sc = scene(sphere_urdf(mass=m, radius=r), {'stiffness': k, 'dissipation': d, 'friction': 0.0},
               [0, 0, r + h0, 0, 0, 0, 1])
    ts, ys, _ = run(sc, 5e-6, 0.55, 0.0005)
    z = ys[:, 2] - r
    i0 = int(np.argmin(z))
    h1 = z[i0:].max()
    assert ts[-1] - ts[i0 + int(np.argmax(z[i0:]))] > 0.01   # the apex is inside the run
    v_in = math.sqrt(2 * G * h0)
    e = restitution_speed(v_in, d) / v_in
    assert 0.3 < e < 0.9
    bound = 1.5 * G * math.pi * math.sqrt(m / k) / v_in
    print(f'rebound height {h1 / (e * e * h0) - 1.0:+.2%} of e² h0; bound {bound:.2%}')
    assert abs(bound - 0.0047) < 5e-5                               # docs/contact.md: 0.47 %
    assert abs(h1 / (e * e * h0) - 1.0) < bound, (h1, e * e * h0, bound)


def test_the_normal_force_is_continuous_at_touch_down_and_never_pulls():
    """At δ → 0 the force → 0 whatever the approach speed (the damping goes with δ); leaving faster than
    1/d it is clamped at 0, not pulling; between, ``k δ (1 + d δ̇)``."""
    r, k, d = 0.05, 1e4, 2.0
    sc = scene(sphere_urdf(radius=r), {'stiffness': k, 'dissipation': d, 'friction': 0.5}, [0, 0, r, 0, 0, 0, 1])
    sysm = sc.system

    def force(depth, vz):
        q = np.array([0, 0, r - depth, 0, 0, 0, 1.0])
        v = np.array([0, 0, 0, 0, 0, vz])
        P = sysm.contact.point_outputs(sysm._km, q, v)
        return P[0, PF:PF + 3], P[0, PACTIVE]
    for vz in (-5.0, -0.5, 0.0, 0.2):
        f, on = force(1e-12, vz)
        assert on and abs(f[2]) < 2 * k * 1e-12 * (1 + d * 5.0)
    f, on = force(1e-3, 1.0)              # leaving at 1 m/s > 1/d: 1 + d δ̇ = −1
    assert on and f[2] == 0.0 and np.all(f == 0.0)
    f, _ = force(1e-3, 0.2)               # leaving slower: 1 + d δ̇ = 0.6
    assert abs(f[2] - k * 1e-3 * (1 - d * 0.2)) < 1e-12
    f, _ = force(1e-3, -0.3)              # arriving: 1 + d δ̇ = 1.6
    assert abs(f[2] - k * 1e-3 * (1 + d * 0.3)) < 1e-12
    f, on = force(-1e-3, -0.3)            # above the plane: nothing
    assert not on and np.all(f == 0.0)


# --------------------------------------------------------------------------------------------
# bad input
# --------------------------------------------------------------------------------------------
def _bad(ground, contacts=None):
    data = {'name': 'bad', 'parts': [{'kind': 'urdf', 'name': 'body', 'urdf': box_urdf(), 'floating': True},
                                     {'kind': 'ground', **ground}]}
    if contacts is not None:
        data['parts'][1]['contacts'] = contacts
    with pytest.raises(SceneError) as e:
        parse_scene(yaml.safe_dump(data, sort_keys=False), file='bad.yaml')
    return str(e.value)


def test_bad_ground_input_is_refused_with_file_key_reason():
    assert _bad({'friction': -0.1}) == 'bad.yaml: parts[1].friction: must be >= 0.0, got -0.1'
    msg = _bad({'stiffness': 0.0})
    assert msg.startswith('bad.yaml: parts[1].stiffness: must be > 0'), msg
    msg = _bad({}, contacts=[{'link': 'box', 'point': [0, 0, 0]}, {'link': 'wheel', 'point': [0, 0, 0]}])
    assert msg.startswith("bad.yaml: parts[1].contacts[1].link: no link 'wheel' in this scene's tree"), msg
    msg = _bad({'stiffness': 1e4, 'time_constant': 0.02, 'damping_ratio': 1.0})
    assert msg.startswith('bad.yaml: parts[1].time_constant: give the compliance as'), msg
    msg = _bad({'normal': [0, 0, 0]})
    assert msg.startswith('bad.yaml: parts[1].normal: the normal must be a non-zero 3-vector'), msg
    msg = _bad({'slip_speed': 0.0})
    assert msg.startswith('bad.yaml: parts[1].slip_speed: must be > 0'), msg
    msg = _bad({'links': ['nope']})
    assert msg.startswith("bad.yaml: parts[1].links[0]: no link 'nope'"), msg


# --------------------------------------------------------------------------------------------
# the contact forces on a real tree, against Pinocchio's point Jacobians
# --------------------------------------------------------------------------------------------
def test_contact_forces_enter_the_dynamics_as_point_forces_on_a_real_robot():
    """A1 (example-robot-data, its <collision> primitives: feet spheres on welded links, boxes, rims)
    sunk into the ground at random configurations and velocities: our forward dynamics with contact
    equals Pinocchio's ABA under ``τ + Σ J_iᵀ F_i``, J_i the Jacobian of contact point i (from
    Pinocchio's frame Jacobian of its link, shifted to the point), F_i the law's force; the points'
    depths and slip speeds equal those of Pinocchio's kinematics."""
    import pinocchio as pin
    from test_pinocchio import PinBridge

    from robodyn_ros.kernels.contact import PSLIP, PX
    from robodyn_ros.urdf import example_robot_data_dir
    path = example_robot_data_dir() / 'a1_description/urdf/a1.urdf'
    data = {'name': 'a1', 'parts': [{'kind': 'urdf', 'name': 'a1', 'file': str(path), 'floating': True},
                                    {'kind': 'ground', 'stiffness': 3e4, 'dissipation': 2.0, 'friction': 0.7,
                                     'slip_speed': 0.05, 'height': 0.02, 'normal': [0.1, -0.05, 1.0]}]}
    sc = parse_scene(yaml.safe_dump(data), file='a1.yaml')
    sysm = sc.system
    m, con = sysm.model, sysm.contact
    br = PinBridge(m, pin.buildModelFromUrdf(str(path), pin.JointModelFreeFlyer()))
    n = con.con[0][0:3]
    rng = np.random.default_rng(7)
    checked = 0
    for trial in range(6):
        q = sc.y0[:sysm.nq].copy()
        q[7:] = [rng.uniform(-0.3, 0.3), rng.uniform(0.4, 1.2), rng.uniform(-2.2, -1.2)] * 4
        quat = np.array([*rng.normal(scale=0.1, size=3), 1.0])
        q[3:7] = quat / np.linalg.norm(quat)
        q[2] = 0.0
        z = con.point_outputs(sysm._km, q, np.zeros(sysm.nv))[:, PDEPTH]   # depths at base height 0
        q[2] = np.sort(z)[-4] - 0.003         # four points at least 3 mm deep
        v = rng.normal(scale=0.5, size=sysm.nv)
        y = np.concatenate([q, v])
        tau = rng.normal(scale=3.0, size=sysm.nv)
        tau[:6] = 0.0
        ours = sysm.rhs(0.0, y, {'effort': tau[6:]})[sysm.nq:]
        P = con.point_outputs(sysm._km, q, v)
        on = np.flatnonzero(P[:, PACTIVE] > 0)
        assert len(on) >= 4, 'the trial configuration must touch'
        qp, vp = br.q(q), br.v(v)
        pin.forwardKinematics(br.pm, br.pd, qp, vp)
        pin.computeJointJacobians(br.pm, br.pd, qp)
        pin.updateFramePlacements(br.pm, br.pd)
        tau_c = np.zeros(br.pm.nv)
        for c in on:
            link = con.points[c].link
            fid = br.pm.getFrameId(link)
            J = pin.getFrameJacobian(br.pm, br.pd, fid, pin.LOCAL_WORLD_ALIGNED)
            x = P[c, PX:PX + 3]
            r = x - br.pd.oMf[fid].translation
            Jx = J[:3] - np.cross(r, J[3:].T).T      # v_x = v_f + ω × r = J_lin v − r× J_ang v
            u = Jx @ vp
            assert abs((0.02 - n @ x) - P[c, PDEPTH]) < 1e-12
            ut = u - (u @ n) * n
            assert abs(np.linalg.norm(ut) - P[c, PSLIP]) < 1e-10
            F = P[c, PF:PF + 3]
            assert F @ n >= 0.0                  # never pulls
            Ft = F - (F @ n) * n
            if np.linalg.norm(ut) > 1e-6 and F @ n > 0:   # friction opposes the slip
                assert np.linalg.norm(np.cross(Ft, ut)) < 1e-9 * max(1.0, np.linalg.norm(Ft)) and Ft @ ut < 0
            tau_c += Jx.T @ F
            checked += 1
        theirs = br.back(pin.aba(br.pm, br.pd, qp, vp, br.v(np.concatenate([np.zeros(6), tau[6:]])) + tau_c))
        assert rel(ours, theirs) < 1e-10, (trial, rel(ours, theirs))
    assert checked >= 24


def rel(x, y):
    return float(np.max(np.abs(np.asarray(x) - np.asarray(y))) / max(float(np.max(np.abs(y))), 1.0))


# --------------------------------------------------------------------------------------------
# the contact Jacobian of the linearly implicit step
# --------------------------------------------------------------------------------------------
@pytest.mark.parametrize('mu, d', [(0.0, 3.0), (0.7, 0.0)])
def test_contact_jacobian_is_the_derivative_of_the_contact_forces(mu, d):
    """``D_c = −∂τ_c/∂v`` and ``K_c = −∂τ_c/∂q`` (kernels.contact (C4), (C5)) against central finite
    differences of ``τ_c = M (v̇ − v̇_free)`` on A1 in contact: exact where the law makes them so (the
    friction at fixed f_n: d = 0; the normal spring and damping without friction: μ = 0), K_c at a shallow
    penetration (the geometric stiffness ``∂Jᵀ/∂q F`` it leaves out goes with F)."""
    from robodyn_ros.kernels.contact import contact_jacobian
    from robodyn_ros.urdf import example_robot_data_dir
    path = example_robot_data_dir() / 'a1_description/urdf/a1.urdf'
    data = {'name': 'a1', 'parts': [{'kind': 'urdf', 'name': 'a1', 'file': str(path), 'floating': True},
                                    {'kind': 'ground', 'stiffness': 3e4, 'dissipation': d, 'friction': mu,
                                     'slip_speed': 0.05, 'links': ['FR_foot', 'FL_foot', 'RR_foot', 'RL_foot']}]}
    sc = parse_scene(yaml.safe_dump(data), file='a1.yaml')
    s, km = sc.system, sc.system._km
    rng = np.random.default_rng(3)
    q = sc.y0[:s.nq].copy()
    q[7:] = [0.1, 0.8, -1.5, -0.1, 0.9, -1.6, 0.05, 0.7, -1.4, -0.05, 0.85, -1.5]
    q[2] = 0.0
    depth = s.contact.point_outputs(km, q, np.zeros(s.nv))[:, PDEPTH]
    v = rng.normal(scale=0.2, size=s.nv)

    def tau_c(q, v):
        y = np.concatenate([q, v])
        zero = {'effort': np.zeros(len(s.actuated))}
        acc = s.rhs(0.0, y, zero)[s.nq:]
        free = km.aba(q, v, np.zeros(s.nv))
        return km.crba(q) @ (acc - free)

    def moved(q, dv):   # q displaced by the velocity-coordinate increment dv (first order, then projected)
        return km.normalize(q + km.qdot(q, dv))
    for shallow in (False, True):
        q[2] = depth.max() - (1e-7 if shallow else 4e-3)   # the deepest foot that deep
        Dm, Km = contact_jacobian(s.contact.con, km.mi_r, km.mf_r, q, v)
        on = int((s.contact.point_outputs(km, q, v)[:, PACTIVE] > 0).sum())
        assert on >= 1
        eps = 1e-7
        Dfd = np.column_stack([-(tau_c(q, v + eps * e) - tau_c(q, v - eps * e)) / (2 * eps) for e in np.eye(s.nv)])
        assert np.abs(Dm - Dm.T).max() < 1e-9 * np.abs(Dm).max()
        assert np.abs(Dm - Dfd).max() < 1e-5 * max(np.abs(Dm).max(), 1.0), np.abs(Dm - Dfd).max()
        if shallow and mu == 0.0:   # with friction, F_t depends on q through f_n (left out of K_c)
            Kfd = np.column_stack([-(tau_c(moved(q, eps * e), v) - tau_c(moved(q, -eps * e), v)) / (2 * eps)
                                   for e in np.eye(s.nv)])
            assert np.abs(Km - Km.T).max() < 1e-9 * np.abs(Km).max()
            assert np.abs(Km - Kfd).max() < 1e-4 * np.abs(Km).max(), np.abs(Km - Kfd).max() / np.abs(Km).max()
        assert np.linalg.eigvalsh(Km).min() > -1e-9 * np.abs(Km).max()
        assert np.linalg.eigvalsh(Dm).min() > -1e-9 * max(np.abs(Dm).max(), 1.0)


def test_fixed_joint_wrench_carries_the_ground_force_of_its_link():
    """A box on four feet welded to it (sphere collisions on the feet links), at rest: each foot's
    fixed joint transmits the ground's force less the foot's weight, ``f = −(M/4 − m_f) g`` along z (the
    ground's force acts on the foot, the link its point belongs to, not on the body it is welded to)."""
    mf, M0 = 0.05, 2.0
    feet = ''.join(
        f'<link name="foot{k}"><inertial><mass value="{mf}"/><inertia ixx="1e-5" iyy="1e-5" izz="1e-5" ixy="0" '
        f'ixz="0" iyz="0"/></inertial><collision><geometry><sphere radius="0.02"/></geometry></collision></link>'
        f'<joint name="weld{k}" type="fixed"><parent link="box"/><child link="foot{k}"/>'
        f'<origin xyz="{sx * 0.15} {sy * 0.1} -0.1"/></joint>'
        for k, (sx, sy) in enumerate([(1, 1), (1, -1), (-1, 1), (-1, -1)]))
    urdf = (f'<robot name="table"><link name="box"><inertial><mass value="{M0}"/><inertia ixx="0.02" iyy="0.03" '
            f'izz="0.04" ixy="0" ixz="0" iyz="0"/></inertial></link>{feet}</robot>')
    k = 1e4
    sc = scene(urdf, {'stiffness': k, 'dissipation': 5.0, 'friction': 0.8}, [0, 0, 0.12 + 0.002, 0, 0, 0, 1])
    ts, ys, sim = run(sc, 1e-3, 5.0, 0.5)
    out = sim.outputs()
    M = M0 + 4 * mf
    for j in range(4):
        frame, w = out.wrenches[f'weld{j}']
        assert frame == f'foot{j}'
        assert abs(w[5] + (M / 4 - mf) * G) < 1e-9 * M * G, (j, w)
        assert np.abs(w[3:5]).max() < 1e-9 * M * G
        assert abs(out.contacts[f'foot{j}'][1][5] - M * G / 4) < 1e-9 * M * G


def test_time_constant_and_damping_ratio_give_the_resting_mode_they_name():
    """``time_constant: τ``, ``damping_ratio: ζ`` (MuJoCo's solref): a box resting on its 4 points moves
    about its rest penetration ``g τ² ζ²`` as ``ẍ + (2/τ) ẋ + x/(τ ζ)² = 0``: decay rate 1/τ and
    damped frequency ``√(1/(τζ)² − 1/τ²)``, fitted to a small bounce (amplitude 0.1 % of the rest
    penetration: the law's nonlinearity is of that order)."""
    from scipy.optimize import curve_fit
    tau, zeta = 0.02, 0.3
    corners = [{'link': 'box', 'point': [sx * 0.2, sy * 0.15, -0.1]} for sx in (-1, 1) for sy in (-1, 1)]
    d0 = G * tau * tau * zeta * zeta
    w = 1.0 / (tau * zeta)
    v0 = 1e-3 * d0 * w
    sc = scene(box_urdf(), {'time_constant': tau, 'damping_ratio': zeta, 'friction': 0.5, 'contacts': corners},
               [0, 0, 0.1 - d0, 0, 0, 0, 1], v=[0, 0, 0, 0, 0, -v0])
    ts, ys, _ = run(sc, 1e-5, 0.12, 2e-4)
    x = (0.1 - d0) - ys[:, 2]                    # sinking below the rest height
    (A, s, wd, ph), _ = curve_fit(lambda t, A, s, wd, ph: A * np.exp(-s * t) * np.sin(wd * t + ph), ts, x,
                                  p0=[v0 / w, 1 / tau, w, 0.0])
    print(f"decay {s * tau - 1:.2e}, frequency {wd / math.sqrt(w * w - 1 / tau ** 2) - 1:.2e}")
    assert abs(s * tau - 1.0) < 1e-3, s
    assert abs(wd / math.sqrt(w * w - 1 / tau ** 2) - 1.0) < 1e-3, wd


def test_fixed_base_arm_resting_its_tip_on_the_ground():
    """A fixed-base link (uniform bar, length L, hinged at height L·sin θ0 above a ground it leans on
    with a sphere at its tip) comes to rest on its tip: the ground's vertical force there holds the
    bar's weight moment about the hinge, ``F_z L cos θ = m g (L/2) cos θ``, i.e. F_z = m g / 2 (up to
    the friction's horizontal share, which has no moment arm along z)."""
    m, L, r = 1.5, 0.6, 0.02
    i = m * L * L / 12
    urdf = (f'<robot name="bar"><link name="post"/><link name="bar"><inertial><origin xyz="{L / 2} 0 0"/>'
            f'<mass value="{m}"/><inertia ixx="1e-4" iyy="{i}" izz="{i}" ixy="0" ixz="0" iyz="0"/></inertial>'
            f'<collision><origin xyz="{L} 0 0"/><geometry><sphere radius="{r}"/></geometry></collision></link>'
            f'<joint name="hinge" type="continuous"><parent link="post"/><child link="bar"/>'
            f'<origin xyz="0 0 0.3"/><axis xyz="0 1 0"/><dynamics damping="0.5"/></joint></robot>')
    data = {'name': 'bar', 'parts': [{'kind': 'urdf', 'name': 'bar', 'urdf': urdf},
                                     {'kind': 'ground', 'stiffness': 1e5, 'dissipation': 2.0, 'friction': 0.5}],
            'initial_state': {'q': [0.3]}}
    sc = parse_scene(yaml.safe_dump(data, sort_keys=False), file='bar.yaml')
    ts, ys, sim = run(sc, 2e-4, 3.0, 0.1)
    s = sc.system
    P = s.contact.point_outputs(s._km, sim.y[:1], sim.y[1:])
    assert P[0, PACTIVE] > 0 and abs(sim.y[1]) < 1e-9        # resting on its tip
    assert abs(P[0, PF + 2] / (m * G / 2) - 1.0) < 1e-6, P[0, PF + 2]
    # the tip's contact point is where the bar's geometry puts it: z = 0 (minus the penetration)
    theta = sim.y[0]
    assert abs((0.3 - L * math.sin(theta) - r) + P[0, PDEPTH]) < 1e-12   # a turn about +y lowers +x


def test_refusals_of_what_contact_does_not_cover():
    """A tree with mimic joints, and the numpy backend: refused at load with the reason."""
    mimic = ('<robot name="g"><link name="b"/><link name="f1"><inertial><mass value="0.1"/><inertia ixx="1e-4" '
             'iyy="1e-4" izz="1e-4" ixy="0" ixz="0" iyz="0"/></inertial><collision><geometry><sphere radius="0.01"/>'
             '</geometry></collision></link><link name="f2"><inertial><mass value="0.1"/><inertia ixx="1e-4" '
             'iyy="1e-4" izz="1e-4" ixy="0" ixz="0" iyz="0"/></inertial></link>'
             '<joint name="j1" type="prismatic"><parent link="b"/><child link="f1"/><axis xyz="1 0 0"/>'
             '<limit lower="0" upper="0.1" effort="10" velocity="1"/></joint>'
             '<joint name="j2" type="prismatic"><parent link="b"/><child link="f2"/><axis xyz="1 0 0"/>'
             '<limit lower="0" upper="0.1" effort="10" velocity="1"/><mimic joint="j1"/></joint></robot>')
    data = {'name': 'g', 'parts': [{'kind': 'urdf', 'name': 'g', 'urdf': mimic}, {'kind': 'ground'}]}
    with pytest.raises(SceneError, match=r'^g\.yaml: parts\[1\]: .*mimic joints is not supported'):
        parse_scene(yaml.safe_dump(data), file='g.yaml')
    from robodyn_ros.systems.base import backend_scope
    with backend_scope('numpy'), pytest.raises(SceneError, match=r"parts\[1\]: .*compiled kernels only"):
        scene(box_urdf(), {}, [0, 0, 0.2, 0, 0, 0, 1])


def test_ground_defaults_are_set_once_and_documented_as_they_are():
    """A ``ground`` part with no law keys gets :class:`Ground`'s field defaults (the one place they are
    set), and docs/contact.md's "Defaults:" sentence states those values."""
    import re
    from pathlib import Path

    from robodyn_ros.systems.contact import Ground
    sc = scene(box_urdf(), {}, [0, 0, 0.2, 0, 0, 0, 1])
    law = sc.system.contact.ground
    assert law == Ground(normal=law.normal, height=0.0)
    text = (Path(__file__).resolve().parents[1] / 'docs' / 'contact.md').read_text()
    line = re.search(r'^Defaults: (.*)$', text, re.MULTILINE).group(1)
    said = dict(re.findall(r'(stiffness|dissipation|friction|slip speed) ([0-9.e]+)', line))
    assert {k.replace(' ', '_'): float(v) for k, v in said.items()} == {
        'stiffness': law.stiffness, 'dissipation': law.dissipation, 'friction': law.friction,
        'slip_speed': law.slip_speed}, line


def test_the_figures_docs_contact_gives_of_the_bundled_scenes():
    """docs/contact.md's counts and the pd_hold rate: a1_stand's ground has 44 points on 9 links (every
    <collision> shape of A1: 212), the human's 20; a cylinder's rim points lie at most r (1 − cos 22.5°)
    = 0.076 r above its true lowest line; A1's knee under pd_hold (kp 40, kd 1, the knee's effective
    inertia 1/(M⁻¹)_kk with the base and the other joints free: no rotor inertia in the URDF), sampled and
    held, is stable at a1_stand's 200 Hz and not at 100 Hz."""
    import warnings

    from robodyn_ros.scene import load_scene
    from robodyn_ros.systems.contact import RIM_POINTS
    with warnings.catch_warnings():
        warnings.simplefilter('ignore')
        a1 = load_scene('a1_stand')
        every = parse_scene(a1.text.replace('    links: [trunk, FR_calf, FL_calf, RR_calf, RL_calf, FR_foot, FL_foot, '
                                            'RR_foot, RL_foot]\n', ''), file='a1_every_shape.yaml')
        human = load_scene('huston_human17_fall')
    assert (a1.system.contact.n_points, len(a1.system.contact.links)) == (44, 9)
    assert every.system.contact.n_points == 212
    assert human.system.contact.n_points == 20
    assert abs((1 - math.cos(math.pi / RIM_POINTS)) - 0.076) < 5e-4
    s = a1.system
    Minv = np.linalg.inv(s._km.crba(a1.y0[:s.nq]))
    k = 6 + list(s.actuated).index('FR_calf_joint')
    inertia = 1.0 / Minv[k, k]
    c = a1.data['commands']['effort']
    kp, kd = float(c['kp']), float(c['kd'])

    def radius(T):   # a double integrator under the PD sampled every T and held (exact discretisation)
        A = np.array([[1.0, T], [0.0, 1.0]]) - np.outer([T * T / 2, T], [kp, kd]) / inertia
        return max(abs(np.linalg.eigvals(A)))
    rate = float(a1.settings['publish_rate'])
    assert rate == 200.0 and radius(1 / rate) < 0.9 and radius(1 / 100.0) > 1.0, (inertia, radius(1 / rate))
    T = np.linspace(1e-3, 2e-2, 2000)
    largest = T[np.flatnonzero([radius(t) < 1 for t in T])[-1]]
    print(f'knee effective inertia {inertia:.2g} kg m²; largest stable period {largest * 1e3:.1f} ms')
    assert 5e-3 < largest < 1e-2    # docs/contact.md: 8.8 ms
