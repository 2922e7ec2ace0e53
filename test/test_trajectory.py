"""Trajectories as joint_trajectory_controller takes them (setpoints.py): the desired samples against the
polynomials themselves (coefficients solved here from each segment's boundary conditions), replacement at
a future start time, partial goals, a start in the past, the hold after the last point, the refusals
(each counted, the program unchanged), an identical re-send leaving the program's samples bit for bit,
and tracking to 1e-6 rad with the model feed-forward on xarm7 (the bundled xarm7_trajectory scene)."""
from __future__ import annotations

import numpy as np
import pytest

from robodyn_ros.model import LinkSpec, build_model
from robodyn_ros.setpoints import SetpointProgram, parse_trajectory, trajectory_message
from robodyn_ros.simulation import CommandError, Simulator
from robodyn_ros.systems.arm import ArmSystem
from robodyn_ros.systems.servo import JointServo

J2 = ['j1', 'j2']


def _poly(T, pa, va, aa, pb, vb, ab, degree):
    """Coefficients (lowest first) of the polynomial of ``degree`` (1, 3, 5) meeting the boundary values
    at 0 and T: positions (and velocities, and accelerations), solved as a linear system."""
    rows, rhs = [], []
    n = degree + 1

    def cond(t, d, value):
        rows.append([0.0 if i < d else np.prod(range(i - d + 1, i + 1)) * t ** (i - d) for i in range(n)])
        rhs.append(value)
    cond(0.0, 0, pa)
    cond(T, 0, pb)
    if degree >= 3:
        cond(0.0, 1, va)
        cond(T, 1, vb)
    if degree == 5:
        cond(0.0, 2, aa)
        cond(T, 2, ab)
    return np.linalg.solve(np.array(rows), np.array(rhs))


def _eval(c, tau):
    """(q, q̇, q̈) of coefficients c (lowest first) at tau."""
    p = np.polynomial.Polynomial(c)
    return p(tau), p.deriv(1)(tau), p.deriv(2)(tau)


def _program(q0=(0.1, -0.2)):
    return SetpointProgram.hold(J2, np.array(q0), 0.0)


def _check(prog, times, want):
    got = prog.sample_many(np.array(times))
    assert got.shape == (len(times), 2, 3)
    for i, t in enumerate(times):
        for j in range(2):
            w = want(t, j)
            assert np.allclose(got[i, j], w, rtol=1e-11, atol=1e-11), (t, j, got[i, j], w)


@pytest.mark.parametrize('degree', [1, 3, 5])
def test_samples_are_the_segment_polynomials(degree):
    """From the hold at t = 0.2 to the first point, then point to point, then held: linear (positions only),
    cubic (velocities) or quintic (accelerations), each segment the polynomial meeting its end points."""
    pts = [{'time_from_start': 0.5, 'positions': [0.4, 0.3]}, {'time_from_start': 1.2, 'positions': [-0.1, 0.6]},
           {'time_from_start': 2.0, 'positions': [0.2, 0.0]}]
    vels = [[0.3, -0.1], [0.2, 0.5], [0.0, 0.0]]
    accs = [[0.1, 0.0], [-0.3, 0.2], [0.0, 0.0]]
    for p, v, a in zip(pts, vels, accs):
        if degree >= 3:
            p['velocities'] = v
        if degree == 5:
            p['accelerations'] = a
    now = 0.2
    prog = _program().with_trajectory(parse_trajectory(trajectory_message(J2, pts), J2), now)
    q0 = [0.1, -0.2]
    knots = [(now, q0, [0, 0], [0, 0])] + [(now + p['time_from_start'], p['positions'], v, a)
                                             for p, v, a in zip(pts, vels, accs)]

    def want(t, j):
        if t < now:
            return (q0[j], 0.0, 0.0)
        for (ta, pa, va, aa), (tb, pb, vb, ab) in zip(knots[:-1], knots[1:]):
            if ta <= t < tb:
                c = _poly(tb - ta, pa[j], va[j], aa[j], pb[j], vb[j], ab[j], degree)
                return _eval(c, t - ta)
        return (knots[-1][1][j], 0.0, 0.0)
    times = np.linspace(0.0, 2.6, 131)
    _check(prog, times, want)
    assert np.ptp(prog.sample_many(times)[:, 0, 0]) > 0.4     # it moves


def test_replacement_at_a_future_start_time():
    """Trajectory A from t = 0; at t = 0.3, B stamped 0.6 naming j1 only: A runs on until 0.6; from there j1
    goes from A's desired state at 0.6 to B's point (cubic), j2 holds A's desired position at 0.6."""
    A = trajectory_message(J2, [{'time_from_start': 1.0, 'positions': [0.5, 0.5], 'velocities': [0.0, 0.0]}])
    B = trajectory_message(['j1'], [{'time_from_start': 0.4, 'positions': [-0.3], 'velocities': [0.0]}], stamp=0.6)
    pa = _program().with_trajectory(parse_trajectory(A, J2), 0.0)
    pb = pa.with_trajectory(parse_trajectory(B, J2), 0.3)
    q0 = [0.1, -0.2]

    def a_state(t, j):
        return _eval(_poly(1.0, q0[j], 0.0, 0.0, 0.5, 0.0, 0.0, 3), t)

    def want(t, j):
        if t < 0.6:
            return a_state(t, j)
        s = a_state(0.6, j)
        if j == 1:
            return (s[0], 0.0, 0.0)
        if t < 1.0:   # B's first point at 0.6 + 0.4: cubic from A's state (position, velocity) at 0.6
            return _eval(_poly(0.4, s[0], s[1], 0.0, -0.3, 0.0, 0.0, 3), t - 0.6)
        return (-0.3, 0.0, 0.0)
    _check(pb, np.linspace(0.3, 1.3, 101), want)


def test_a_start_in_the_past_samples_the_messages_own_segments():
    """Stamped at 0.1, applied at 0.5 (past its first point at 0.3): from 0.5 the segment between its points,
    as the controller samples it; the part before 0.5 is not re-played."""
    msg = trajectory_message(J2, [{'time_from_start': 0.2, 'positions': [0.3, 0.1]},
                                  {'time_from_start': 1.0, 'positions': [0.7, -0.5]}], stamp=0.1)
    prog = _program().with_trajectory(parse_trajectory(msg, J2), 0.5)
    p0, p1 = [0.3, 0.1], [0.7, -0.5]

    def want(t, j):
        if t < 1.1:
            return _eval(_poly(0.8, p0[j], 0, 0, p1[j], 0, 0, 1), t - 0.3)
        return (p1[j], 0.0, 0.0)
    _check(prog, np.linspace(0.5, 1.5, 51), want)


def test_an_identical_resend_keeps_every_sample_bit_for_bit():
    """A stamped trajectory sent again at later periods (what a lockstep controller does) changes no sample
    from then on: the same polynomials in the same time origins."""
    msg = trajectory_message(J2, [{'time_from_start': 0.0, 'positions': [0.1, -0.2], 'velocities': [0, 0]},
                                  {'time_from_start': 0.5, 'positions': [0.4, 0.2], 'velocities': [0.1, 0]},
                                  {'time_from_start': 1.0, 'positions': [0.0, 0.0], 'velocities': [0, 0]}],
                             stamp=0.01)
    tr = parse_trajectory(msg, J2)
    prog = _program().with_trajectory(tr, 0.0)
    times = np.linspace(0.0, 1.5, 301)
    for now in (0.01, 0.02, 0.37, 0.5, 0.9):
        again = prog.with_trajectory(tr, now)
        late = times[times >= now]
        assert np.array_equal(again.sample_many(late), prog.sample_many(late)), now
        prog = again


def _arm():
    specs = [LinkSpec(name='l1', joint='j1', parent='base_link', joint_type='revolute', axis=(0, 1, 0), mass=1.0,
                      com=(0.5, 0, 0), inertia=np.diag([0.01] * 3)),
             LinkSpec(name='l2', joint='j2', parent='l1', joint_type='revolute', axis=(0, 1, 0), origin_xyz=(1, 0, 0),
                      mass=0.5, com=(0.3, 0, 0), inertia=np.diag([0.01] * 3))]
    m = build_model(specs, gravity=np.array([0, 0, -9.81]), name='two', root='base_link')
    s = ArmSystem(m)
    s.use_servo(JointServo(m, J2, [], [400.0] * 2, [40.0] * 2, feedforward=True))
    return s


GOOD = {'time_from_start': 0.5, 'positions': [0.2, 0.1]}


@pytest.mark.parametrize('msg, reason', [
    (trajectory_message(['j1', 'j9'], [{'time_from_start': 0.5, 'positions': [0.2, 0.1]}]), "joint 'j9' is not"),
    (trajectory_message(['j1', 'j1'], [{'time_from_start': 0.5, 'positions': [0.2, 0.1]}]), 'duplicate joint names'),
    (trajectory_message([], [GOOD]), 'empty joint_names'),
    (trajectory_message(J2, [GOOD, {'time_from_start': 0.5, 'positions': [0.3, 0.1]}]), 'not strictly increasing'),
    (trajectory_message(J2, [{'time_from_start': 0.5, 'positions': [0.2]}]), 'positions has 1 values for 2'),
    (trajectory_message(J2, [{'time_from_start': 0.5, 'positions': [0.2, 0.1], 'velocities': [0.0]}]),
     'velocities has 1 values'),
    (trajectory_message(J2, [{'time_from_start': 0.5, 'positions': [0.2, float('nan')]}]), 'non-finite'),
    (trajectory_message(J2, [{'time_from_start': 0.5, 'positions': [0.2, 0.1], 'accelerations': [0, 0]}]),
     'accelerations but no velocities'),
    (trajectory_message(J2, [{'time_from_start': 0.1, 'positions': [0.2, 0.1]}], stamp=0.2), 'ends in the past'),
])
def test_bad_trajectories_are_refused_counted_and_change_nothing(msg, reason):
    sim = Simulator(_arm(), np.zeros(4), integrator='rk4', dt=1e-3)
    sim.set_command('trajectory', trajectory_message(J2, [GOOD]))
    sim.advance(0.5)
    before = sim.ports['position'].applied
    with pytest.raises(CommandError, match=reason):
        sim.set_command('trajectory', msg)
    assert sim.ports['trajectory'].rejected == 1 and sim.rejected_commands == 1
    assert sim.ports['position'].applied is before
    sim.advance(1.0)
    assert np.allclose(sim.y[:2], [0.2, 0.1], atol=1e-3)   # the good one held on


def test_xarm7_tracks_a_quintic_trajectory_to_1e6_rad_with_the_feedforward():
    """The bundled xarm7_trajectory scene over its first 4 s (quintic segments through its waypoints,
    rosenbrock2 at 1 ms): every published joint within 1e-6 rad of the desired; without the feed-forward
    (the same gains) the error is orders of magnitude larger."""
    from robodyn_ros.scene import load_scene
    from robodyn_ros.simulation import run_headless

    class Errors:
        def __init__(self):
            self.worst, self.n = 0.0, 0

        def on_start(self, sim):
            pass

        def on_command(self, t, port, values):
            pass

        def on_output(self, t, out, sim):
            err = dict((topic, msg) for topic, _, msg in out.messages)['joint_trajectory_error']
            self.worst = max(self.worst, float(np.abs(err['position']).max()))
            self.n += 1

        def close(self):
            pass
    res = []
    for ff in (True, False):
        sc = load_scene('xarm7_trajectory')
        sc.system.servo.opt[0] = 1.0 if ff else 0.0
        sim = Simulator(sc.system, sc.y0, integrator='auto', dt=1e-3)
        sink = Errors()
        run_headless(sim, 4.0, 100.0, sc.script, [sink])
        assert sink.n == 401
        res.append(sink.worst)
    assert res[0] < 1e-6, res
    assert res[1] > 1e3 * res[0], res


@pytest.mark.parametrize('segments', ['cubic', 'quintic'])
def test_cubic_and_quintic_trajectories_are_tracked_to_1e6_rad_knots_included(tmp_path, segments):
    """xArm7 without its Coulomb friction (damping only) through the bundled scene's waypoints, 10 s at 1 ms: the
    cubic segments' acceleration jumps at every knot (on the step grid, read on each step's side of it) and the
    quintic's does not; with the feed-forward both stay within 1e-6 rad of the desired at every period."""
    import re

    from robodyn_ros.meshes import resolve_uri
    from robodyn_ros.scene import find_scene, parse_scene
    from robodyn_ros.simulation import run_headless
    url = 'package://example-robot-data/robots/xarm_description/urdf/xarm7.urdf'
    urdf = tmp_path / 'xarm7_damped.urdf'
    urdf.write_text(re.sub(r'\s+friction="[^"]*"', '', open(resolve_uri(url)).read()))
    text = find_scene('xarm7_trajectory').read_text().replace(url, str(urdf))
    if segments == 'cubic':
        text = re.sub(r', accelerations: \[[^\]]*\]', '', text)
    sc = parse_scene(text, file=str(tmp_path / 'scene.yaml'))
    pts = sc.script.profiles['trajectory'](0.0, sc.y0)['points']
    assert len(pts) == 5 and all(len(p['accelerations']) == (7 if segments == 'quintic' else 0) for p in pts)
    sc = parse_scene(text, file=str(tmp_path / 'scene.yaml'))   # (the profile above has sent its message)
    worst = []

    class Worst:
        def on_start(self, sim):
            pass

        def on_command(self, *a):
            pass

        def on_output(self, t, out, sim):
            err = dict((topic, m) for topic, _, m in out.messages)['joint_trajectory_error']
            worst.append(float(np.abs(err['position']).max()))

        def close(self):
            pass
    sim = Simulator(sc.system, sc.y0, integrator='auto', dt=1e-3)
    run_headless(sim, 10.0, 100.0, sc.script, [Worst()])
    assert len(worst) == 1001
    assert max(worst) < 1e-6, max(worst)
