"""Voltage-driven differential-drive platform and mobile manipulator (seed 001, issue 4).

The closed forms are derived here from the seed's parameters (eq. 57), independently of the code:

* chassis + payload + wheels, COM on the axle midpoint, thin-disc wheels (diametral inertia
  I_w/2), DC motors with L = 0, no friction: i = (V − K N φ̇)/R, wheel torque τ = N K i.
* Straight line (equal voltages V): φ̇_l = φ̇_r = v/r_w, so the kinetic energy is
  ½ m_eff v² with m_eff = m_c + m_a + 2 m_w + 2 (I_w + N² J_m)/r_w², and the motor power
  2 τ φ̇ = 2 N K v (V − K N v/r_w)/(R r_w) gives m_eff v̇ = (2 N K/(R r_w)) (V − K N v/r_w):
  v(t) = v_ss (1 − e^{−t/τ}), v_ss = r_w V/(K N), τ = m_eff R r_w² / (2 K² N²).
* Spin in place (−V left, +V right): v = 0, φ̇_r = −φ̇_l = r_c ω/r_w, kinetic energy ½ J_eff ω² with
  J_eff = I_c + I_a + 2 (m_w r_c² + I_w/2) + 2 (I_w + N² J_m) r_c²/r_w², power
  2 N K (r_c/r_w) ω (V − K N r_c ω/r_w)/R: ω_ss = r_w V/(K N r_c), τ_ω = J_eff R r_w²/(2 K² N² r_c²).
* Constant unequal voltages, steady state without friction: no net force or yaw moment along the
  rolling directions, so no motor torque, i = 0 and φ̇_s = V_s/(K N): v = r_w (φ̇_l + φ̇_r)/2,
  ω = r_w (φ̇_r − φ̇_l)/(2 r_c), a circle of radius ρ = v/ω = r_c (V_l + V_r)/(V_r − V_l) whose
  centripetal force m_tot v ω comes entirely from the lateral ground forces.
"""
from __future__ import annotations

import math
import textwrap
import warnings
from dataclasses import replace

import numpy as np
import pytest

from scipy.linalg import expm

from robodyn_ros import dynamics as dyn
from robodyn_ros.model import LinkSpec
from robodyn_ros.scene import SceneError, load_scene, parse_scene
from robodyn_ros.simulation import Simulator
from robodyn_ros.systems.diffdrive import Body, DiffDriveSystem, PlatformParams
from robodyn_ros.systems.motor import DCMotor

# seed 001, eq. (57) and (40)
R_C, R_W, M_C, M_W, I_C, I_W, I_A, K_T, R_A, M_A = 0.35, 0.28, 3.3, 0.3, 0.18965, 0.0037, 0.975, 0.061, 1.7, 0.4
M_TOT = M_C + M_A + 2 * M_W


def platform(motor=None, payload=True, **kw):
    """The seed's platform (COM on the axle midpoint) with the given motor on both wheels."""
    motor = motor or DCMotor(torque_constant=K_T, resistance=R_A)
    return DiffDriveSystem(PlatformParams(chassis=Body(M_C, I_C, (0.0, 0.0, R_W)),
                                          payload=Body(M_A, I_A, (0.0, 0.0, R_W)) if payload else None,
                                          motors=(motor, motor), **kw))


def run(system, volts, t_end, n, y0=None, integrator='dop853', wrenches=False, effort=None, **kw):
    """Simulate with constant commands; outputs at n equally spaced instants after t=0."""
    kw = kw or ({'rtol': 1e-10, 'atol': 1e-12} if integrator in ('dop853', 'rk45', 'radau') else {})
    sim = Simulator(system, system.initial_state() if y0 is None else y0, integrator=integrator, **kw)
    sim.set_command('wheel_voltage', volts)
    if effort is not None:
        sim.set_command('effort', effort)
    ts = np.linspace(0.0, t_end, n + 1)[1:]
    outs = []
    for t in ts:
        sim.advance(t)
        outs.append(sim.outputs(wrenches=wrenches))
    return sim, ts, outs


def odom(outs, key, k):
    return np.array([o.odom[key][k] for o in outs])


def yaw(outs):
    return np.unwrap(np.array([2.0 * math.atan2(o.odom['orientation'][2], o.odom['orientation'][3]) for o in outs]))


# ---------------------------------------------------------------------------------------------
# model
# ---------------------------------------------------------------------------------------------
def test_mass_matrix_from_first_principles_matches_crba():
    """(D3) against the hand sums of this test and against CRBA/RNEA on the tree, off-centre COMs."""
    rng = np.random.default_rng(4)
    mot = DCMotor(torque_constant=K_T, resistance=R_A, gear_ratio=3.0, rotor_inertia=2e-5)
    c_c, c_a = np.array([0.05, -0.02, 0.3]), np.array([-0.1, 0.04, 0.5])
    s = DiffDriveSystem(PlatformParams(chassis=Body(M_C, I_C, tuple(c_c)), payload=Body(M_A, I_A, tuple(c_a)),
                                       motors=(mot, mot)))
    m = M_TOT
    S = M_C * c_c[:2] + M_A * c_a[:2]
    J = I_C + M_C * c_c[:2] @ c_c[:2] + I_A + M_A * c_a[:2] @ c_a[:2] + 2 * (I_W / 2 + M_W * R_C ** 2)
    Is = I_W + 9.0 * 2e-5
    for _ in range(5):
        q, v = rng.normal(size=5), rng.normal(size=5)
        th = q[2]
        R = np.array([[np.cos(th), -np.sin(th)], [np.sin(th), np.cos(th)]])
        M_ref = np.zeros((5, 5))
        M_ref[:2, :2] = m * np.eye(2)
        M_ref[:2, 2] = M_ref[2, :2] = R @ np.array([-S[1], S[0]])
        M_ref[2, 2] = J
        M_ref[3, 3] = M_ref[4, 4] = Is
        h_ref = np.zeros(5)
        h_ref[:2] = -v[2] ** 2 * R @ S
        M, h = s.mass_and_bias(q, v)
        assert np.allclose(M, M_ref, atol=1e-14)
        assert np.allclose(h, h_ref, atol=1e-13)
        M_tree = dyn.crba(s.model, q) + np.diag([0, 0, 0, 9 * 2e-5, 9 * 2e-5])
        assert np.allclose(M, M_tree, atol=1e-13)
        assert np.allclose(h, dyn.bias_forces(s.model, q, v), atol=1e-12)  # gravity is vertical: no work


def test_state_layout_models_only_what_is_needed():
    """No current states with L = 0, one per inductive motor; the fixed arm has no platform states."""
    assert platform().ny == 10
    s = platform(DCMotor(torque_constant=K_T, resistance=R_A, inductance=1e-3))
    assert s.ny == 12 and s.n_current == 2
    mixed = DiffDriveSystem(PlatformParams(motors=(DCMotor(inductance=1e-3), DCMotor())))
    assert mixed.ny == 11
    assert load_scene('betancur_platform').system.ny == 10
    mm = load_scene('mobile_manipulator').system
    assert mm.ny == 18 and set(mm.inputs) == {'wheel_voltage', 'effort'}
    pend = load_scene('betancur_pendulum').system
    assert type(pend).__name__ == 'ArmSystem' and pend.ny == 8


# ---------------------------------------------------------------------------------------------
# closed forms
# ---------------------------------------------------------------------------------------------
@pytest.mark.parametrize('gear, rotor, V, t_end', [(1.0, 0.0, 6.0, 20.0), (10.0, 2e-5, 6.0, 4.0)])
def test_straight_line_first_order_speed(gear, rotor, V, t_end):
    """Equal voltages from rest: v(t) = v_ss (1 − e^{−t/τ}); x(t) its integral; y = θ = 0."""
    m_eff = M_TOT + 2 * (I_W + gear ** 2 * rotor) / R_W ** 2
    tau = m_eff * R_A * R_W ** 2 / (2 * K_T ** 2 * gear ** 2)
    v_ss = R_W * V / (K_T * gear)
    s = platform(DCMotor(torque_constant=K_T, resistance=R_A, gear_ratio=gear, rotor_inertia=rotor))
    assert s.fastest_time_constant(s.initial_state()) == pytest.approx(tau, rel=1e-9)
    sim, ts, outs = run(s, [V, V], t_end, 40)
    v = odom(outs, 'linear', 0)
    x = odom(outs, 'position', 0)
    # bounds ~100x the measured round-off (README accuracy table): v 1.2e-15, x 4.8e-16, i 1.3e-15, E 6e-15
    assert np.abs(v - v_ss * (1 - np.exp(-ts / tau))).max() < 1e-13 * v_ss
    assert np.abs(x - v_ss * (ts - tau * (1 - np.exp(-ts / tau)))).max() < 5e-14 * v_ss * t_end
    assert np.abs(odom(outs, 'position', 1)).max() < 1e-13 * x[-1] and np.abs(yaw(outs)).max() < 1e-13
    i = np.array([o.extra['left_motor_current'] for o in outs])
    assert np.abs(i - V / R_A * np.exp(-ts / tau)).max() < 1e-13 * V / R_A
    # joint_states: both wheels at v/r_w, effort = N K i
    assert outs[-1].joint_names == ['left_wheel_joint', 'right_wheel_joint']
    assert np.allclose(outs[-1].velocity, v[-1] / R_W, rtol=1e-12)
    assert np.allclose(outs[-1].effort, gear * K_T * i[-1], rtol=1e-12)
    assert abs(sim.energy_report()['drift']) < 5e-13 * sim.energy_report()['energy']
    if gear == 10.0:
        assert v[-1] > 0.99 * v_ss  # several time constants: the exponential itself is tested


def test_opposite_voltages_first_order_yaw_rate():
    """−V left, +V right: the platform spins in place (positive yaw), ω(t) first order."""
    V, gear = 5.0, 8.0
    J_eff = I_C + I_A + 2 * (M_W * R_C ** 2 + I_W / 2) + 2 * I_W * R_C ** 2 / R_W ** 2
    tau = J_eff * R_A * R_W ** 2 / (2 * K_T ** 2 * gear ** 2 * R_C ** 2)
    w_ss = R_W * V / (K_T * gear * R_C)
    s = platform(DCMotor(torque_constant=K_T, resistance=R_A, gear_ratio=gear))
    _, ts, outs = run(s, [-V, V], 4 * tau, 40)
    w = odom(outs, 'angular', 2)
    assert np.abs(w - w_ss * (1 - np.exp(-ts / tau))).max() < 1e-13 * w_ss             # measured 7.6e-16
    assert np.abs(yaw(outs) - w_ss * (ts - tau * (1 - np.exp(-ts / tau)))).max() < 3e-14 * w_ss * ts[-1]  # 3e-16
    assert np.abs(np.array([o.odom['position'][:2] for o in outs])).max() < 1e-10
    assert w[-1] > 0.98 * w_ss


def _circle_checks(s, outs, Vl, Vr, gear):
    phi_l, phi_r = Vl / (K_T * gear), Vr / (K_T * gear)
    v = R_W * (phi_l + phi_r) / 2
    w = R_W * (phi_r - phi_l) / (2 * R_C)
    rho = R_C * (Vl + Vr) / (Vr - Vl)
    assert v / w == pytest.approx(rho, rel=1e-12)
    pos = np.array([o.odom['position'][:2] for o in outs])
    th = yaw(outs)
    centre = pos + rho * np.stack([-np.sin(th), np.cos(th)], axis=1)
    # the path is a circle of radius rho about a fixed centre, at speed v and yaw rate w (bounds
    # ~100x the measured: centre, radius 2.5e-12 rho; v 5e-13; w 2.7e-12; lateral 3.2e-12 relative)
    assert np.abs(centre - centre[0]).max() < 3e-10 * rho
    assert np.abs(np.linalg.norm(pos - centre[0], axis=1) - rho).max() < 3e-10 * rho
    assert np.abs(odom(outs, 'linear', 0) - v).max() < 3e-10 * v
    assert np.abs(odom(outs, 'angular', 2) - w).max() < 3e-10 * w
    # ground forces: total lateral = centripetal m v w (towards the centre = +y of base_link),
    # longitudinal ~ 0, the lateral force split equally (statically indeterminate: min-norm)
    for o in outs:
        Fl, Fr = o.wrenches['left_wheel_contact'][1], o.wrenches['right_wheel_contact'][1]
        assert o.wrenches['left_wheel_contact'][0] == 'left_wheel_contact'
        assert Fl[4] + Fr[4] == pytest.approx(M_TOT * v * w, rel=3e-10)
        assert abs(Fl[3]) + abs(Fr[3]) < 3e-10 * M_TOT * v * w
        assert Fl[4] == pytest.approx(Fr[4], rel=1e-9)
        assert np.all(Fl[:3] == 0.0) and Fl[5] == 0.0
        assert o.extra['constraint_rank'] == 3


def test_unequal_voltages_steady_circle_from_rest():
    """Geared motors (fast transients) from rest: settles on the circle the wheel speeds imply."""
    Vl, Vr, gear = 4.0, 6.0, 20.0
    s = platform(DCMotor(torque_constant=K_T, resistance=R_A, gear_ratio=gear))
    sim = Simulator(s, s.initial_state(), integrator='dop853', rtol=1e-11, atol=1e-12)
    sim.set_command('wheel_voltage', [Vl, Vr])
    sim.advance(12.0)  # 26 yaw time constants (0.46 s) and 60 speed ones (0.20 s)
    outs = []
    for t in np.linspace(12.0, 16.0, 21)[1:]:
        sim.advance(t)
        outs.append(sim.outputs(wrenches=True))
    _circle_checks(s, outs, Vl, Vr, gear)


def test_seed_platform_started_on_its_steady_circle_stays_there():
    """The seed's ungeared platform started at the steady state of 4 V / 6 V (ρ = 1.75 m)."""
    Vl, Vr = 4.0, 6.0
    s = platform()
    phi = np.array([Vl, Vr]) / K_T
    v, w = R_W * phi.mean(), R_W * (phi[1] - phi[0]) / (2 * R_C)
    y0 = s.initial_state(np.zeros(5), np.array([v, 0.0, w, phi[0], phi[1]]))
    _, _, outs = run(s, [Vl, Vr], 1.0, 20, y0=y0, wrenches=True)  # two turns (period 0.48 s)
    _circle_checks(s, outs, Vl, Vr, 1.0)


def test_power_balance_with_friction_inductance_and_saturation():
    """ΔE = ∫ Σ (v i − R i²) − friction losses, both from the simulator's quadrature and from the
    published voltages, currents and losses (Simpson's rule over each constant-voltage segment)."""
    rng = np.random.default_rng(7)
    left = DCMotor(torque_constant=K_T, resistance=R_A, inductance=0.05, gear_ratio=10.0, rotor_inertia=1e-5,
                   viscous_friction=2e-4, coulomb_friction=5e-3, coulomb_velocity=0.5, supply_voltage=8.0)
    right = replace(left, inductance=0.0, viscous_friction=1e-4)
    s = DiffDriveSystem(PlatformParams(chassis=Body(M_C, I_C, (0.03, 0.01, 0.2)), motors=(left, right)))
    sim = Simulator(s, s.initial_state(), integrator='dop853', rtol=1e-11, atol=1e-12)
    n, dt, m = 6, 0.2, 80  # segments of dt with m (even) samples; L/R = 29 ms
    E0 = s.total_energy(sim.y)
    W, sat = 0.0, False

    def net_power(o):
        x = o.extra
        return x['electrical_power'] - x['copper_loss'] - x['left_motor_friction_loss'] - x['right_motor_friction_loss']
    for k in range(n):
        sim.set_command('wheel_voltage', rng.uniform(-10.0, 10.0, size=2))
        o = sim.outputs(wrenches=False)
        sat |= o.extra['voltage_saturated']
        p = [net_power(o)]
        for j in range(1, m + 1):
            sim.advance(k * dt + j * dt / m)
            p.append(net_power(sim.outputs(wrenches=False)))
        W += dt / m / 3 * (p[0] + p[-1] + 4 * sum(p[1:-1:2]) + 2 * sum(p[2:-1:2]))
    E1 = s.total_energy(sim.y)
    rep = sim.energy_report()
    assert sat  # some commands beyond the 8 V supply were clipped
    assert abs(E1 - E0) > 0.1
    assert abs(rep['drift']) < 8e-13 * abs(rep['work'])   # measured 7.7e-15
    assert E1 - E0 == pytest.approx(W, rel=1e-4)  # Simpson error only
    assert s.energies(sim.y)['magnetic'] > 0.0


# ---------------------------------------------------------------------------------------------
# outputs, wrenches, constraints
# ---------------------------------------------------------------------------------------------
def test_conventions_outputs_and_wrench_consistency():
    """Equal positive voltages drive +x of base_link; a faster right wheel yaws left; the joint
    wrenches carry the motor torques; the plane reaction has no horizontal part; Newton holds."""
    s = platform(DCMotor(torque_constant=K_T, resistance=R_A, gear_ratio=4.0))
    _, _, outs = run(s, [6.0, 6.0], 0.5, 2, wrenches=True)
    assert outs[-1].odom['linear'][0] > 0.0 and abs(outs[-1].odom['angular'][2]) < 1e-12
    _, _, outs = run(s, [5.0, 7.0], 0.5, 2, wrenches=True)
    o = outs[-1]
    assert o.odom['angular'][2] > 0.0
    assert set(o.wrenches) >= {'left_wheel_contact', 'right_wheel_contact', 'left_wheel_joint',
                               'right_wheel_joint', 'base_plane'}
    for k, side in enumerate(('left', 'right')):
        frame, f = o.wrenches[f'{side}_wheel_joint']
        assert frame == f'{side}_wheel'
        assert f[1] == pytest.approx(o.effort[k], rel=1e-9)  # axis (+y) component = motor torque
        assert o.effort[k] == pytest.approx(4.0 * K_T * o.extra[f'{side}_motor_current'], rel=1e-12)
    frame, f = o.wrenches['base_plane']
    assert frame == 'base_link'
    assert np.abs(f[[2, 3, 4]]).max() < 1e-9  # no yaw torque, no horizontal force from the plane
    assert f[5] == pytest.approx(M_TOT * 9.81, rel=1e-9)  # it carries the weight
    # Newton for the whole platform: Σ contact forces = m_tot × acceleration of the centre of mass
    y = np.concatenate([np.zeros(5), [0.3, 0.1, 0.4, 0.0, 0.0]])
    y[8], y[9] = (0.3 - R_C * 0.4) / R_W, (0.3 + R_C * 0.4) / R_W
    y[5], y[6] = 0.3, 0.0
    y = s.initial_state(y[:5], y[5:])
    u = {'wheel_voltage': np.array([3.0, -2.0])}
    a, lam, info = s.solve(y, u)
    F = np.array([lam[0] + lam[2], lam[1] + lam[3]])
    assert np.allclose(F, M_TOT * a[:2], atol=1e-12) and info.rank == 3
    # Euler about the centre (COM): Σ moments of the contact forces = J θ̈ + wheel spin reactions
    J = I_C + I_A + 2 * (I_W / 2 + M_W * R_C ** 2)
    assert R_C * (lam[2] - lam[0]) == pytest.approx(J * a[2], rel=1e-10)


def test_no_wrench_solve_without_wrenches(monkeypatch):
    """outputs(wrenches=False) publishes odometry and currents without the contact-force solve."""
    s = platform()
    y = s.initial_state()
    monkeypatch.setattr(s, 'solve', lambda *a, **k: pytest.fail('contact-force solve without wrenches'))
    o = s.outputs(0.0, y, {'wheel_voltage': np.array([6.0, 6.0])}, wrenches=False)
    assert o.wrenches == {} and o.extra['left_motor_current'] == pytest.approx(6.0 / R_A)


def test_constraint_drift_is_stabilised():
    """The velocity projection keeps ‖K v‖ at round-off while RK4 alone lets it grow; a Baumgarte
    gain α makes an initial violation decay as e^{−α t} (closed form), none leaves it constant."""
    gear = DCMotor(torque_constant=K_T, resistance=R_A, gear_ratio=10.0)

    def residual(sys_, T):
        sim = Simulator(sys_, sys_.initial_state(), integrator='rk4', dt=0.02)
        sim.set_command('wheel_voltage', [4.0, 7.0])
        sim.advance(T)
        return sim.outputs(wrenches=False).extra['constraint_residual']
    raw = platform(gear)
    raw.project = lambda y: y
    early, late = residual(raw, 2.5), residual(raw, 5.0)
    assert late > 1e-8 and late > 10 * early  # drift grows without projection
    assert residual(platform(gear), 5.0) < 1e-13

    y0 = np.zeros(10)
    y0[5] = 0.1  # forward speed with the wheels at rest: both longitudinal rows violated by 0.1 m/s
    for alpha in (0.0, 20.0):
        s = platform(gear, baumgarte_alpha=alpha)
        s.project = lambda y: y
        sim = Simulator(s, y0, integrator='dop853', rtol=1e-11, atol=1e-13)
        for t in (0.1, 0.25):
            sim.advance(t)
            e = sim.outputs(wrenches=False).extra['constraint_residual']
            assert e == pytest.approx(0.1 * math.exp(-alpha * t), rel=1e-6)


def test_initial_state_must_roll_without_slip():
    s = platform()
    with pytest.raises(ValueError, match='rolling without slip'):
        s.initial_state(np.zeros(5), np.array([1.0, 0.0, 0.0, 0.0, 0.0]))
    with pytest.raises(ValueError, match='lateral'):
        s.initial_state(np.zeros(5), np.array([0.0, 1.0, 0.0, 0.0, 0.0]))


def test_never_non_finite():
    """Random states and voltages far beyond the supply: finite derivatives and outputs; a NaN
    state gives a NaN derivative (for the integrator's guard) instead of an exception."""
    rng = np.random.default_rng(11)
    s = platform(DCMotor(torque_constant=K_T, resistance=R_A, inductance=1e-4, supply_voltage=12.0,
                         coulomb_friction=1e-3, coulomb_velocity=1e-3))
    n = 0
    for _ in range(20):
        q = rng.normal(size=5) * 10
        vf, w = rng.normal(size=2) * 50
        v = np.array([vf * np.cos(q[2]), vf * np.sin(q[2]), w, (vf - R_C * w) / R_W, (vf + R_C * w) / R_W])
        y = s.initial_state(q, v, rng.normal(size=2) * 100)
        u = {'wheel_voltage': rng.normal(size=2) * 1e6}
        assert np.all(np.isfinite(s.rhs(0.0, y, u)))
        o = s.outputs(0.0, y, u)
        assert o.extra['voltage_saturated'] and abs(o.extra['left_motor_voltage']) == 12.0
        vals = [o.position, o.velocity, o.effort] + [w for _, w in o.wrenches.values()] + list(o.odom.values())
        assert all(np.all(np.isfinite(x)) for x in vals)
        n += 1
    assert n == 20
    assert np.all(np.isnan(s.rhs(0.0, np.full(s.ny, np.nan), {'wheel_voltage': np.zeros(2)})))


def test_motor_parameters_are_validated():
    for kw, word in (({'resistance': 0.0}, 'resistance'), ({'inductance': -1e-3}, 'inductance'),
                     ({'gear_ratio': -2.0}, 'gear_ratio'), ({'coulomb_velocity': 0.0}, 'coulomb_velocity'),
                     ({'torque_constant': float('nan')}, 'torque_constant')):
        with pytest.raises(ValueError, match=word):
            DCMotor(**kw)
    m = DCMotor(viscous_friction=1e-3, coulomb_friction=2e-3, gear_ratio=3.0)
    w = np.linspace(-5, 5, 11)
    assert np.all(m.friction_loss(w) >= 0.0) and np.all(m.friction_slope(w) > 0.0)
    with pytest.raises(ValueError, match='exceeds m_w r_w'):
        PlatformParams(wheel_spin_inertia=1.0)


# ---------------------------------------------------------------------------------------------
# stiff electrics
# ---------------------------------------------------------------------------------------------
def test_stiff_electrics_refused_by_explicit_steps_and_accurate_with_radau():
    """L = 1e-4 H: L/R = 59 µs. Fixed explicit steps of 1 ms are refused naming the time
    constant; Radau follows the L = 0 closed form (the current lags by L/R only)."""
    L, V, gear = 1e-4, 6.0, 10.0
    s = platform(DCMotor(torque_constant=K_T, resistance=R_A, inductance=L, gear_ratio=gear))
    y0 = s.initial_state()
    assert s.fastest_time_constant(y0) == pytest.approx(L / R_A)
    for integ in ('euler', 'semi_implicit_euler', 'rk4'):
        with pytest.raises(ValueError, match=r'5\.88e-05 s'):
            Simulator(s, y0, integrator=integ, dt=1e-3)
    with warnings.catch_warnings():
        warnings.simplefilter('ignore')
        Simulator(s, y0, integrator='rk4', dt=2e-5)  # below 2.785 L/R: accepted
    # straight line with L > 0 is linear in (v, i): m_eff v̇ = 2 N K i / r_w, L i̇ = V − R i − K N v / r_w
    m_eff = M_TOT + 2 * I_W / R_W ** 2
    A = np.array([[0.0, 2 * gear * K_T / (R_W * m_eff)], [-K_T * gear / (R_W * L), -R_A / L]])
    b = np.array([0.0, V / L])
    sim, ts, outs = run(s, [V, V], 2.0, 20, integrator='radau', rtol=1e-8, atol=1e-10)
    ref = np.array([np.linalg.solve(A, (expm(A * t) - np.eye(2)) @ b) for t in ts])  # ∫ e^{A s} ds b
    v = odom(outs, 'linear', 0)
    i = np.array([o.extra['right_motor_current'] for o in outs])
    assert np.abs(v - ref[:, 0]).max() < 1e-7 * np.abs(ref[:, 0]).max()
    assert np.abs(i - ref[:, 1]).max() < 1e-6 * V / R_A
    assert ref[-1, 0] > 0.9 * R_W * V / (K_T * gear)  # well into the mechanical transient
    assert all(np.all(np.isfinite(o.position)) and np.all(np.isfinite(o.velocity)) for o in outs)


# ---------------------------------------------------------------------------------------------
# mobile manipulator
# ---------------------------------------------------------------------------------------------
def _arm_on_platform(motor, chassis=None, wheel_spin=I_W):
    """The betancur_pendulum arm (its specs, origin included) on the seed platform without payload."""
    arm = load_scene('betancur_pendulum').system
    p = PlatformParams(chassis=chassis or Body(M_C, I_C, (0.0, 0.0, R_W)), payload=None,
                       wheel_spin_inertia=wheel_spin, motors=(motor, motor))
    return arm, DiffDriveSystem(p, arm_specs=list(arm.model.specs), arm_root=arm.model.root,
                                gravity=arm.model.gravity)


def test_mobile_manipulator_free_wheels_momentum_balance():
    """Motors disconnected (K = 0: wheels free): swinging the arm yaws and moves the platform;
    d/dt of the total horizontal momentum = Σ contact forces, d/dt of the angular momentum about
    the odom z axis = Σ moments of the contact forces (central differences of the recording)."""
    mm = load_scene('mobile_manipulator')
    free = DCMotor(torque_constant=0.0, resistance=R_A)
    p = replace(mm.system.params, motors=(free, free))
    arm_specs = [sp for sp in mm.system.model.specs if sp.name.startswith('arm_') or sp.name == 'tool']
    s = DiffDriveSystem(p, arm_specs=arm_specs, gravity=mm.system.model.gravity)
    sim = Simulator(s, s.initial_state(), integrator='dop853', rtol=1e-11, atol=1e-12)

    def sample():
        o = sim.outputs(wrenches=True)
        q, v = s.split(sim.y)
        hm = dyn.spatial_momentum(s.model, q, v)  # [angular about the odom origin; linear], odom axes
        Rz = np.array([[np.cos(q[2]), -np.sin(q[2])], [np.sin(q[2]), np.cos(q[2])]])
        F, Mz = np.zeros(2), 0.0
        for side, sig in (('left', 1.0), ('right', -1.0)):
            f = Rz @ o.wrenches[f'{side}_wheel_contact'][1][3:5]
            r = q[:2] + Rz @ np.array([0.0, sig * R_C])
            F += f
            Mz += r[0] * f[1] - r[1] * f[0]
        return np.array([hm[3], hm[4], hm[2]]), np.array([F[0], F[1], Mz]), q[2]
    # the arm torque is held for 20 ms blocks (zero-order hold), sampled 10 times per block: within
    # a block the forces are smooth, so Simpson's rule integrates them to O(h⁴)
    h, blocks, m = 2e-3, 40, 10
    err, scale, heading = np.zeros(3), np.zeros(3), []
    for b in range(blocks):
        sim.set_command('effort', [0.5 * math.sin(2 * math.pi * 0.8 * sim.t), 0.0, 0.0, 0.0])
        P, F = [], []
        for j in range(m + 1):
            if j:
                sim.advance((b * m + j) * h)
            p_, f_, th = sample()
            P.append(p_)
            F.append(f_)
            heading.append(th)
        F = np.array(F)
        impulse = h / 3 * (F[0] + F[-1] + 4 * F[1:-1:2].sum(axis=0) + 2 * F[2:-1:2].sum(axis=0))
        err = np.maximum(err, np.abs(P[-1] - P[0] - impulse))
        scale = np.maximum(scale, np.abs(F).max(axis=0) * m * h)
    assert np.all(scale > 1e-4)  # the arm really pushes the platform around
    assert np.all(err < 1e-6 * scale), (err, scale)
    assert np.abs(heading).max() > 1e-3  # the heading changed
    assert abs(sim.energy_report()['drift']) < 1e-8  # free wheels, arm damping, efforts: balanced


def test_arm_only_limit_reproduces_the_fixed_base_pendulum():
    """A platform a million times heavier (same arm, same mount) lets the arm swing exactly as the
    betancur_pendulum ArmSystem does."""
    pend = load_scene('betancur_pendulum')
    heavy = Body(1e6 * M_C, 1e6 * I_C, (0.0, 0.0, R_W))
    arm, s = _arm_on_platform(DCMotor(torque_constant=K_T, resistance=R_A), chassis=heavy, wheel_spin=I_W)
    y0 = s.initial_state(np.concatenate([np.zeros(5), pend.y0[:4]]))
    sim_a = Simulator(pend.system, pend.y0, integrator='dop853', rtol=1e-10, atol=1e-12)
    sim_b = Simulator(s, y0, integrator='dop853', rtol=1e-10, atol=1e-12)
    err, swing = 0.0, 0.0
    for t in np.linspace(0.0, 1.0, 11)[1:]:
        sim_a.advance(t)
        sim_b.advance(t)
        qa = pend.system.split(sim_a.y)[0]
        qb = s.split(sim_b.y)[0][5:]
        err = max(err, np.abs(qa - qb).max())
        swing = max(swing, np.abs(qa - pend.y0[:4]).max())
    assert swing > 0.5 and err < 1e-4
    wr = sim_b.outputs(wrenches=True).wrenches
    fa = sim_a.outputs(wrenches=True).wrenches
    assert np.allclose(wr['joint1'][1], fa['joint1'][1], atol=1e-3)


def test_platform_only_tree_path_reproduces_the_analytic_platform():
    """The payload as a rigid 'arm' (one fixed link) takes the CRBA/RNEA path of the mobile
    manipulator; it reproduces the first-principles platform, compiled kernels or numpy."""
    mot = DCMotor(torque_constant=K_T, resistance=R_A, gear_ratio=5.0)
    ref = platform(mot)
    payload_link = [LinkSpec('payload_link', 'payload_weld', None, 'fixed', mass=M_A, com=(0.0, 0.0, R_W),
                             inertia=Body(M_A, I_A).inertia())]
    tree = DiffDriveSystem(PlatformParams(chassis=Body(M_C, I_C, (0.0, 0.0, R_W)), payload=None,
                                          motors=(mot, mot)), arm_specs=payload_link)
    assert tree.has_arm and tree.ny == ref.ny
    assert tree._km is not None  # numba is a hard dependency: the tree path runs compiled
    systems = [tree]
    systems.append(DiffDriveSystem(tree.params, arm_specs=payload_link, backend='numpy'))
    _, _, o_ref = run(ref, [4.0, 7.0], 2.0, 10, wrenches=True)
    for sys_ in systems:
        _, _, o = run(sys_, [4.0, 7.0], 2.0, 10, wrenches=True)
        for a, b in zip(o_ref, o):
            assert np.allclose(a.odom['position'], b.odom['position'], atol=1e-9)
            assert np.allclose(a.velocity, b.velocity, atol=1e-9)
            assert np.allclose(a.wrenches['left_wheel_contact'][1], b.wrenches['left_wheel_contact'][1], atol=1e-7)


def test_mobile_manipulator_scene_runs_and_couples():
    """The bundled scene: arm swing during the first 2 s (0 V) yaws and rocks the platform."""
    sc = load_scene('mobile_manipulator')
    sim = Simulator(sc.system, sc.y0, integrator='rk4', dt=0.005)
    ths = []
    for k in range(1, 101):
        for port, val in sc.script(sim.t, sim.y).items():
            sim.set_command(port, val)
        sim.advance(k * 0.01)
        ths.append(sim.y[2])
    o = sim.outputs(wrenches=True)
    assert np.abs(ths).max() > 1e-3 and abs(sim.y[0]) > 1e-4
    assert o.joint_names[:2] == ['left_wheel_joint', 'right_wheel_joint'] and len(o.joint_names) == 6
    assert {'arm_joint1', 'left_wheel_contact', 'base_plane'} <= set(o.wrenches)
    assert o.extra['constraint_residual'] < 1e-12
    assert 'arm_link1' in sc.system.urdf() and '<link name="odom"' not in sc.system.urdf()


# ---------------------------------------------------------------------------------------------
# scenes: refusals
# ---------------------------------------------------------------------------------------------
_BASE = textwrap.dedent("""\
    name: t
    parts:
      - kind: diff_drive
        name: platform
        chassis: {mass: 3.3, yaw_inertia: 0.18965}
        wheels: {radius: 0.28, half_track: 0.35, mass: 0.3, spin_inertia: 0.0037}
        motor: {torque_constant: 0.061, resistance: 1.7}
    """)
_ARM = textwrap.indent(textwrap.dedent("""\
      - kind: arm
        name: arm
        mount: platform
        links:
          - {name: l1, joint: j1, parent: base_link, type: revolute, origin: {xyz: [0, 0, 0.5]},
             mass: 0.1, com: [0.1, 0, 0], inertia: [1e-4, 1e-4, 1e-4, 0, 0, 0]}
    """), '  ')


def test_scene_builds_platform_and_mobile_manipulator():
    assert parse_scene(_BASE, file='t.yaml').system.ny == 10
    sc = parse_scene(_BASE + _ARM, file='t.yaml')
    assert sc.system.ny == 12 and sc.system.joint_names == ['left_wheel_joint', 'right_wheel_joint', 'j1']


@pytest.mark.parametrize('old, new, key, word', [
    ('motor: {torque_constant', 'motor: {kind: stepper, torque_constant', 'parts[0].motor.kind', 'unknown motor kind'),
    ('name: platform\n', 'name: platform\n    mount: table\n', 'parts[0].mount', "must be 'world'"),
    ('spin_inertia: 0.0037', 'spin_inertia: 0.5', 'parts[0].wheels.spin_inertia', 'exceeds'),
    ('spin_inertia: 0.0037', 'spin_inertia: 0.0037, diametral_inertia: 0.001', 'parts[0].wheels.diametral_inertia',
     'triangle'),
    ('resistance: 1.7}', 'resistance: 1.7, inductance: -0.001}', 'parts[0].motor.inductance', '>= 0'),
    ('resistance: 1.7}', 'resistance: 0.0}', 'parts[0].motor.resistance', '> 0'),
    ('half_track: 0.35', 'half_track: 0.0', 'parts[0].wheels.half_track', '> 0'),
    ('motor: {torque', 'motors: {left: {torque_constant: 0.061, resistance: 1.7}}\n    motor: {torque',
     'parts[0]', 'exactly one'),
    ('chassis: {mass: 3.3', 'chassis: {mass: 0.0', 'parts[0].chassis', 'mass and a yaw inertia'),
])
def test_scene_refuses_inconsistent_platforms(old, new, key, word):
    assert old in _BASE
    with pytest.raises(SceneError) as e:
        parse_scene(_BASE.replace(old, new), file='bad.yaml')
    msg = str(e.value)
    assert msg.startswith(f'bad.yaml: {key}') and word in msg, msg


@pytest.mark.parametrize('text, key, word', [
    (_BASE + _ARM.replace('mount: platform', 'mount: nowhere'), 'parts[1].mount', 'must be mounted on the platform'),
    (_BASE + _ARM.replace('mount: platform', 'mount: world'), 'parts[1].mount', 'independent systems'),
    (_BASE + _ARM.replace('name: l1', 'name: left_wheel'), 'parts[1]', 'clash'),
    (_BASE + _BASE.split('parts:\n')[1].replace('name: platform', 'name: p2'), 'parts[1].kind', 'one diff_drive'),
    (_BASE + 'initial_state: {q: [0, 0, 0, 0, 0], v: [1, 0, 0, 0, 0]}\n', 'initial_state', 'rolling without slip'),
    (_BASE + 'initial_state: {q: [0, 0, 0]}\n', 'initial_state.q', 'x, y, yaw'),
])
def test_scene_refuses_bad_mounts_and_states(text, key, word):
    with pytest.raises(SceneError) as e:
        parse_scene(text, file='bad.yaml')
    msg = str(e.value)
    assert msg.startswith(f'bad.yaml: {key}') and word in msg, msg


def test_bundled_platform_scenes():
    """betancur_platform drives straight at 6/6 V; the turn scene switches to unequal voltages."""
    a = load_scene('betancur_platform')
    assert a.script(5.0, a.y0)['wheel_voltage'].tolist() == [6.0, 6.0]
    b = load_scene('betancur_platform_turn')
    assert b.script(3.0, b.y0)['wheel_voltage'].tolist() == [3.0, 9.0]
    assert a.system.params.motors[0].supply_voltage == 12.0 and not a.system.motors[0].has_current_state
