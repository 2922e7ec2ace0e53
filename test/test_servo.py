"""The joint servo of position- and velocity-commanded joints (kernels/servo.py, systems/servo.py):
against the closed-form step response of ``J θ̈ = kp (θ* − θ) − kd θ̇`` (rk4 within its error; rosenbrock2
at its order), a stiff servo (kp = 1e6 on a light link) held at 1 ms under rosenbrock2 with its energy
never rising, a velocity servo's first-order response, saturation at the effort limit, the default
gains' stability at the scene's step, integrator auto seeing the servo, the fused loop against the
reference path, and bad command_interfaces refused."""
from __future__ import annotations

import math

import numpy as np
import pytest

from robodyn_ros.model import LinkSpec, build_model
from robodyn_ros.scene import parse_scene
from robodyn_ros.simulation import Simulator
from robodyn_ros.systems.arm import ArmSystem
from robodyn_ros.systems.servo import JointServo
from robodyn_ros.validation import SceneError

#: one rod about a vertical axis (gravity does no work): mass, length, its inertia about its centre (diagonal)
M1, L1, IC = 1.2, 0.5, 0.004
#: its inertia about the axis: parallel axes, the centre of mass at L1/2
J1 = M1 * (L1 / 2) ** 2 + IC


def _rod(gravity=(0.0, 0.0, -9.81), axis=(0.0, 0.0, 1.0), mass=M1, length=L1, effort=None, ic=IC):
    spec = LinkSpec(name='rod', joint='hinge', parent='base_link', joint_type='revolute', axis=axis, mass=mass,
                    com=(0.5 * length, 0.0, 0.0), inertia=np.diag([ic, ic, ic]), effort_limit=effort)
    return build_model([spec], gravity=np.array(gravity), name='rod', root='base_link')


def _step_response(J, kp, kd, th_star, t):
    """θ(t) of ``J θ̈ + kd θ̇ + kp θ = kp θ*`` from rest at 0 (underdamped), the closed form."""
    wn = math.sqrt(kp / J)
    z = kd / (2.0 * math.sqrt(kp * J))
    wd = wn * math.sqrt(1.0 - z * z)
    return th_star * (1.0 - np.exp(-z * wn * t) * (np.cos(wd * t) + z / math.sqrt(1.0 - z * z) * np.sin(wd * t)))


def _run(system, y0, integrator, dt, n, rate=100.0, command=None, port='position'):
    sim = Simulator(system, y0, integrator=integrator, dt=dt)
    if command is not None:
        sim.set_command(port, command)
    ys = []
    for k in range(n):
        sim.advance((k + 1) / rate)
        ys.append(sim.y.copy())
    return sim, np.array(ys)


def _servo_rod(kp, kd, ff=False, **kw):
    m = _rod(**kw)
    s = ArmSystem(m)
    s.use_servo(JointServo(m, ['hinge'], [], [kp], [kd], feedforward=ff))
    return s


def test_position_step_follows_the_closed_form():
    """A rod about a vertical axis (J = m (l/2)² + I_c) steps to θ* = 0.8 rad: rk4 at 1 ms within
    1e-8 rad of the closed form over 1 s; rosenbrock2 converges to it at order 2 (1 ms against 0.5 ms)."""
    J = J1
    kp, kd = 40.0, 1.0
    t = np.arange(1, 101) / 100.0
    want = _step_response(J, kp, kd, 0.8, t)
    assert np.ptp(want) > 0.5   # it moves: an underdamped step with overshoot
    _, ys = _run(_servo_rod(kp, kd), np.zeros(2), 'rk4', 1e-3, 100, command=[0.8])
    assert np.abs(ys[:, 0] - want).max() < 1e-8
    errs = []
    for dt in (1e-3, 5e-4):
        _, ys = _run(_servo_rod(kp, kd), np.zeros(2), 'rosenbrock2', dt, 100, command=[0.8])
        errs.append(np.abs(ys[:, 0] - want).max())
    assert 3.0 < errs[0] / errs[1] < 5.0, errs     # order 2
    assert errs[0] < 1e-4


def test_velocity_servo_reaches_its_setpoint_exponentially():
    """A velocity-commanded rod (no position term): ``J ω̇ = kd (ω* − ω)``, so ω(t) = ω* (1 − e^{−kd t / J})."""
    J = J1
    m = _rod()
    s = ArmSystem(m)
    s.use_servo(JointServo(m, [], ['hinge'], [0.0], [0.5], feedforward=False))
    assert set(s.inputs) == {'effort', 'velocity'}
    _, ys = _run(s, np.zeros(2), 'rk4', 1e-3, 50, command=[2.0], port='velocity')
    t = np.arange(1, 51) / 100.0
    assert np.abs(ys[:, 1] - 2.0 * (1.0 - np.exp(-0.5 * t / J))).max() < 1e-9


def _energy(system, y, kp, q_star):
    return system.total_energy(y) + 0.5 * kp * (q_star - y[0]) ** 2


def test_stiff_servo_holds_at_1ms_with_rosenbrock2_and_its_energy_never_rises():
    """kp = 1e6 N·m/rad on a 50 g, 0.1 m rod under gravity about a horizontal axis (J = 1.35e-4 kg·m²: ω = 8.6e4
    rad/s, h ω = 86 at 1 ms): rk4 is refused, integrator auto picks rosenbrock2, which holds the setpoint against gravity
    (error kp⁻¹ m g l/2 = 2.5e-8 rad) and whose energy (kinetic + gravity + the servo's spring) never rises."""
    kp, kd, q_star = 1e6, 2.0, 0.3
    kw = dict(axis=(0.0, 1.0, 0.0), mass=0.05, length=0.1, ic=1e-5)
    assert 80 < 1e-3 * math.sqrt(kp / (0.05 * 0.05 ** 2 + 1e-5)) < 92   # h ω of the docs' figure (86)
    with pytest.raises(ValueError, match='rk4 with dt=0.001 s is unstable'):
        Simulator(_servo_rod(kp, kd, **kw), np.zeros(2), integrator='rk4', dt=1e-3)
    s = _servo_rod(kp, kd, **kw)
    sim = Simulator(s, np.zeros(2), integrator='auto', dt=1e-3)
    assert sim.settings['integrator'] == 'rosenbrock2', sim.settings
    sim.set_command('position', [q_star])
    E = [_energy(s, sim.y, kp, q_star)]
    for k in range(200):
        sim.advance((k + 1) / 100.0)
        E.append(_energy(s, sim.y, kp, q_star))
    E = np.array(E)
    assert len(E) == 201
    assert np.all(np.diff(E) <= 1e-12 * abs(E[0])), np.diff(E).max()
    assert E[0] - E[-1] > 1e4 * 1e-12 * abs(E[0])   # it did dissipate the step
    # at rest kp (q* − q) + m g (l/2) cos q = 0 (gravity's torque about +y on a rod along x): q − q* = m g l cos q* / (2 kp)
    sag = 0.05 * 9.81 * 0.05 * math.cos(q_star) / kp
    assert abs(sim.y[0] - q_star - sag) < 1e-11, (sim.y[0] - q_star, sag)
    assert abs(sim.y[1]) < 1e-9


def test_saturation_clamps_the_torque_to_the_effort_limit():
    """A far step on a rod with a 0.5 N·m limit: the published effort is ±0.5 while saturated, and the motion
    is the constant-torque motion ``θ = τ t² / (2J)`` until it comes near (rk4: exact for a quadratic)."""
    J = J1
    m = _rod(effort=0.5)
    s = ArmSystem(m)
    s.use_servo(JointServo(m, ['hinge'], [], [1000.0], [10.0], feedforward=False))
    sim, ys = _run(s, np.zeros(2), 'rk4', 1e-3, 10, command=[3.0])
    t = np.arange(1, 11) / 100.0
    assert np.abs(ys[:, 0] - 0.5 * t ** 2 / (2 * J)).max() < 1e-12
    assert sim.outputs(wrenches=False).effort[0] == 0.5


@pytest.mark.parametrize('backend', ['numba', 'generated'])
def test_fused_loop_equals_the_reference_path(backend):
    """The compiled loop (servo inside every stage; the generated backend's own right-hand side too) and the
    Python reference path (``rhs`` at each stage's time, rosenbrock2 with the time term) agree on a two-link arm
    tracking a trajectory under gravity, knots on the step grid included."""
    from robodyn_ros.setpoints import trajectory_message
    specs = [LinkSpec(name='l1', joint='j1', parent='base_link', joint_type='revolute', axis=(0, 1, 0), mass=1.0,
                      com=(0.5, 0, 0), inertia=np.diag([0.01] * 3)),
             LinkSpec(name='l2', joint='j2', parent='l1', joint_type='revolute', axis=(0, 1, 0), origin_xyz=(1, 0, 0),
                      mass=0.5, com=(0.3, 0, 0), inertia=np.diag([0.01] * 3), damping=0.2)]
    m = build_model(specs, gravity=np.array([0, 0, -9.81]), name='two', root='base_link')
    msg = trajectory_message(['j1', 'j2'], [{'time_from_start': 0.2, 'positions': [0.3, -0.2], 'velocities': [0.5, 0.1]},
                                            {'time_from_start': 0.4, 'positions': [0.5, 0.2], 'velocities': [0, 0]}])
    for integ, (kp, kd) in (('rk4', (1e3, 20.0)), ('rosenbrock2', (1e6, 1e3))):
        out = []
        for reference in (False, True):
            s = ArmSystem(m, backend=backend)
            s.use_servo(JointServo(m, ['j1', 'j2'], [], [kp] * 2, [kd] * 2, feedforward=True))
            if reference:
                s.fused_advance = lambda *a, **k: None   # the Simulator's Python path
            assert (s._km.gen is not None) == (backend == 'generated')
            sim = Simulator(s, np.zeros(4), integrator=integ, dt=1e-3)
            sim.set_command('trajectory', msg)
            for k in range(50):
                sim.advance((k + 1) / 100.0)
            out.append(sim.y.copy())
        assert np.abs(out[0] - out[1]).max() < 1e-12, (integ, out)


def test_default_gains_are_stable_at_the_scenes_step_and_auto_sees_them():
    """xarm7 on position commands with the default gains: kp = I_j ω², kd = 2 I_j ω with I_j = 1/(M⁻¹)_jj at the
    initial state, ω = 2π·10 Hz or lower so that the servo's fastest mode has h |λ| <= 1 at 1 ms; with kp 1e6
    given instead, rk4 is refused and auto picks rosenbrock2 naming the passive stiffness."""
    from robodyn_ros.systems.servo import DEFAULT_FREQUENCY_HZ
    text = ('name: x\nparts:\n  - kind: urdf\n    name: xarm7\n'
            '    file: package://example-robot-data/robots/xarm_description/urdf/xarm7.urdf\n'
            '    command_interfaces: position\n{servo}simulation: {{dt: 1.0e-3}}\n')
    sc = parse_scene(text.format(servo=''), file='x.yaml')
    sv = sc.system.servo
    M = sc.system._km.crba(np.ascontiguousarray(sc.y0[:7]))
    inertia = 1.0 / np.diag(np.linalg.inv(M))
    w = np.sqrt(sv.kp / inertia)
    assert np.allclose(w, w[0]) and np.allclose(sv.kd, 2.0 * inertia * w[0])
    assert w[0] <= 2 * math.pi * DEFAULT_FREQUENCY_HZ * (1 + 1e-12)
    nv = 7
    A = np.zeros((14, 14))
    A[:7, 7:] = np.eye(7)
    A[7:, :7] = -np.linalg.solve(M, np.diag(sv.kp))
    A[7:, 7:] = -np.linalg.solve(M, np.diag(sv.kd))
    assert 1e-3 * np.abs(np.linalg.eigvals(A)).max() <= 1.0 + 1e-9
    assert nv == sc.system.nv

    def fastest(inertia, w):   # h |λ| of gains kp = inertia ω², kd = 2 inertia ω
        A[7:, :7] = -np.linalg.solve(M, np.diag(inertia * w * w))
        A[7:, 7:] = -np.linalg.solve(M, np.diag(2.0 * inertia * w))
        return 1e-3 * np.abs(np.linalg.eigvals(A)).max()
    w10 = 2 * math.pi * DEFAULT_FREQUENCY_HZ
    # the docs' figures: gains from the diagonal M_jj would be unstable for rk4 at 1 ms (3.3); from I_j, 0.21
    assert 3.0 < fastest(np.diag(M), w10) < 3.6 and 0.19 < fastest(inertia, w10) < 0.23
    stiff = parse_scene(text.format(servo='    servo: {kp: 1.0e6, kd: 1.0e3}\n'), file='x.yaml')
    with pytest.raises(ValueError, match='unstable'):
        Simulator(stiff.system, stiff.y0, integrator='rk4', dt=1e-3)
    sim = Simulator(stiff.system, stiff.y0, integrator='auto', dt=1e-3)
    assert sim.settings['integrator'] == 'rosenbrock2' and 'passive' in sim.settings['auto']


@pytest.mark.parametrize('ci, where', [
    ('{position: [nope]}', "command_interfaces.position[0]: joint 'nope' is not an actuated joint"),
    ('{position: [joint1], velocity: [joint1]}', "command_interfaces.velocity[0]: joint 'joint1' is already"),
    ('torque', "command_interfaces: unknown command interface 'torque'"),
])
def test_bad_command_interfaces_are_refused_naming_the_key(ci, where):
    text = ('name: x\nparts:\n  - kind: urdf\n    name: xarm7\n'
            '    file: package://example-robot-data/robots/xarm_description/urdf/xarm7.urdf\n'
            f'    command_interfaces: {ci}\n')
    with pytest.raises(SceneError, match=None) as e:
        parse_scene(text, file='x.yaml')
    assert where in str(e.value), str(e.value)


def test_stiff_servo_on_a_moving_setpoint_keeps_up_under_rosenbrock2():
    """kp = 1e6 tracking a cubic trajectory at 1 ms (rosenbrock2): within 1e-6 rad of the desired at every
    period. The step's time term carries it: without ``F_t`` a stiff spring on a moving setpoint overshoots
    each step by (1/(2γ) − 1) Δq* (here 0.71 · 0.5 rad/s · 1 ms = 3.5e-4 rad)."""
    from robodyn_ros.setpoints import trajectory_message
    s = _servo_rod(1e6, 1e3, ff=True, axis=(0.0, 1.0, 0.0), mass=0.05, length=0.1, ic=1e-5)
    sim = Simulator(s, np.zeros(2), integrator='rosenbrock2', dt=1e-3)
    sim.set_command('trajectory', trajectory_message(['hinge'], [
        {'time_from_start': 0.0, 'positions': [0.0], 'velocities': [0.0]},
        {'time_from_start': 0.5, 'positions': [0.25], 'velocities': [0.5]},
        {'time_from_start': 1.0, 'positions': [0.5], 'velocities': [0.0]}]))
    worst = 0.0
    for k in range(120):
        sim.advance((k + 1) / 100.0)
        err = dict((t, m) for t, _, m in sim.outputs(wrenches=False).messages)['joint_trajectory_error']
        worst = max(worst, abs(err['position'][0]))
    assert worst < 1e-6, worst
    assert abs(sim.y[0] - 0.5) < 1e-6
