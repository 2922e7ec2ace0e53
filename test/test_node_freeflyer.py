"""The sim node on the free-flying scene, commanded from another process, checked from its recording.

The node (``python -m robodyn_ros.nodes.sim``, scene ``unfried_free_flyer``, lockstep, DOP853)
runs as a subprocess in a private ROS domain; this test process is the commander: a thruster
burst on ``base_wrench_command`` (in base_link), then cosine arm torques on ``effort_commands``,
one lockstep period per message. Afterwards the node's MCAP recording is read with the
independent ``mcap_ros2`` decoder and the momentum is rebuilt *from the recorded messages
alone*: Pinocchio loads the recorded ``robot_description`` with its own free-flyer joint and
takes q, v from ``odom`` (pose in odom, twist in base_link) and ``joint_states``.
"""
import os
import signal
import sys

import numpy as np
import pinocchio as pin
import pytest

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from ros_helpers import (Domain, RosClient, assert_lockstep_recording_reproduced, lockstep_step,  # noqa: E402
                         start_sim)

pytestmark = pytest.mark.processes   # a lockstep node subprocess driven from here, SIGINT

RATE = 50.0                 # the scene's publish rate (Hz): one lockstep period = 20 ms
PUSH = np.array([3.0, 1.0, 0.0, 0.0, 0.0, 0.4])   # [fx, fy, fz, tx, ty, tz] in base_link
PUSH_PERIODS = 20           # thrusters on for 0.4 s (the first command of each phase is a wrench)
ARM_PERIODS = 130           # then arm torques only
TAU_A = np.array([0.06, 0.06, 0.04, 0.003, 0.0003])
TAU_W = 2 * np.pi * np.array([0.2, 0.25, 0.3, 0.35, 0.4])
DAMPING = 0.02              # the scene's joint damping (N m s/rad)


def _effort(t):
    return TAU_A * np.cos(TAU_W * t)


@pytest.fixture(scope='module')
def run(tmp_path_factory):
    """Drive a lockstep node from this process; stop it with SIGINT; return the recording path."""
    from geometry_msgs.msg import WrenchStamped
    from sensor_msgs.msg import JointState
    from std_msgs.msg import Float64MultiArray
    tmp = tmp_path_factory.mktemp('freeflyer')
    rec = tmp / 'freeflyer.mcap'
    dom = Domain()
    node = start_sim(dom, {'scene': 'unfried_free_flyer', 'mode': 'lockstep', 'integrator': 'dop853',
                           'rtol': 1e-10, 'atol': 1e-12, 'record': str(rec)}, tmp / 'node.log')
    client = RosClient(dom)
    try:
        states = []
        client.node.create_subscription(JointState, 'joint_states', states.append, 100)
        eff = client.node.create_publisher(Float64MultiArray, 'effort_commands', 10)
        wr = client.node.create_publisher(WrenchStamped, 'base_wrench_command', 10)
        ok = client.spin_until(lambda: states and eff.get_subscription_count() and wr.get_subscription_count(),
                               60, node)
        assert ok, node.output()
        sent = []

        def step(pub, msg):
            """Publish one command and wait for the state of the period it ran."""
            sent.append(lockstep_step(client, pub, msg, states, node) * 1e-9)

        def wrench(w):
            m = WrenchStamped()
            m.header.frame_id = 'base_link'
            m.wrench.force.x, m.wrench.force.y, m.wrench.force.z = (float(x) for x in w[:3])
            m.wrench.torque.x, m.wrench.torque.y, m.wrench.torque.z = (float(x) for x in w[3:])
            return m

        t = 0.0
        step(wr, wrench(PUSH))                       # period 1: thrusters on, arm torques zero
        for _ in range(PUSH_PERIODS - 1):
            t = sent[-1]
            step(eff, Float64MultiArray(data=_effort(t).tolist()))
        step(wr, wrench(np.zeros(6)))                # thrusters off
        for _ in range(ARM_PERIODS):
            t = sent[-1]
            step(eff, Float64MultiArray(data=_effort(t).tolist()))
        rc = node.stop(signal.SIGINT)
        yield {'record': rec, 'rc': rc, 'log': node.output(), 'periods': len(sent)}
    finally:
        client.close()
        node.cleanup()
        dom.release()


def _read(path):
    """topic -> [(log_time ns, decoded message)] with the mcap / mcap_ros2 readers."""
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory
    out = {}
    with open(path, 'rb') as f:
        for _, channel, message, msg in make_reader(f, decoder_factories=[DecoderFactory()]).iter_decoded_messages():
            out.setdefault(channel.topic, []).append((message.log_time, msg))
    return out


def _momentum_from_messages(msgs):
    """(t (n,), p (n, 3), L about the CoM (n, 3), CoM (n, 3)) from robot_description, odom, joint_states."""
    urdf = msgs['/robot_description'][0][1].data
    pm = pin.buildModelFromXML(urdf, pin.JointModelFreeFlyer())
    pd = pm.createData()
    odom = dict(msgs['/odom'])
    out = []
    for t_ns, js in msgs['/joint_states']:
        o = odom[t_ns]
        q = np.zeros(pm.nq)
        v = np.zeros(pm.nv)
        P, Q = o.pose.pose.position, o.pose.pose.orientation
        q[:7] = [P.x, P.y, P.z, Q.x, Q.y, Q.z, Q.w]
        lin, ang = o.twist.twist.linear, o.twist.twist.angular
        v[:6] = [lin.x, lin.y, lin.z, ang.x, ang.y, ang.z]   # Pinocchio: (linear, angular), local frame
        for name, pos, vel in zip(js.name, js.position, js.velocity):
            jm = pm.joints[pm.getJointId(name)]
            q[jm.idx_q], v[jm.idx_v] = pos, vel
        hg = pin.computeCentroidalMomentum(pm, pd, q, v)
        c = pin.centerOfMass(pm, pd, q)
        out.append((t_ns * 1e-9, np.array(hg.linear), np.array(hg.angular), np.array(c), q))
    t, p, L, c, qs = (np.array(x) for x in zip(*out))
    return t, p, L, c, qs, pm


def test_node_run_and_recording_complete(run):
    assert run['rc'] == 0, run['log']
    msgs = _read(run['record'])
    n = run['periods'] + 1                   # the initial state plus one per command
    assert run['periods'] == PUSH_PERIODS + 1 + ARM_PERIODS
    for topic in ['/joint_states', '/odom'] + [f'/constraint_wrenches/joint{k}' for k in range(1, 6)]:
        assert len(msgs[topic]) == n, topic
    assert len(msgs['/effort_commands']) == PUSH_PERIODS - 1 + ARM_PERIODS
    assert len(msgs['/base_wrench_command']) == 2
    assert msgs['/odom'][0][1].header.frame_id == 'odom' and msgs['/odom'][0][1].child_frame_id == 'base_link'


def test_momentum_conserved_from_recorded_messages_alone(run):
    """After the thrusters stop, p and L about the CoM are constant (1e-9 relative) and the CoM
    moves uniformly; during the burst p changes by the thrust impulse ∫ R(t) f dt."""
    msgs = _read(run['record'])
    t, p, L, c, qs, pm = _momentum_from_messages(msgs)
    k0 = PUSH_PERIODS + 1                    # index of the state after the thrusters went off
    assert np.allclose(p[0], 0.0, atol=1e-12) and np.allclose(L[0], 0.0, atol=1e-12)
    pref, Lref = p[k0], L[k0]
    assert np.linalg.norm(pref) > 0.05 and np.linalg.norm(Lref) > 0.01
    dp = np.linalg.norm(p[k0:] - pref, axis=1).max() / np.linalg.norm(pref)
    dL = np.linalg.norm(L[k0:] - Lref, axis=1).max() / np.linalg.norm(Lref)
    mass = sum(I.mass for I in pm.inertias)
    dc = np.linalg.norm(c[k0:] - (c[k0] + np.outer(t[k0:] - t[k0], pref / mass)), axis=1).max()
    print(f'from messages: |dp|/|p| {dp:.1e}, |dL|/|L| {dL:.1e}, CoM off uniform motion {dc:.1e} m')
    assert dp < 1e-9 and dL < 1e-9 and dc < 1e-9
    # the arm really moved while the momentum stayed put
    js = [m for _, m in msgs['/joint_states']]
    assert np.ptp([m.position[1] for m in js[k0:]]) > 0.05
    # thrust impulse ∫ R(t) f dt over the burst (force held in base_link while the base tumbles),
    # Simpson's rule on the 20 recorded periods
    from scipy.integrate import simpson
    R = [pin.Quaternion(q[6], q[3], q[4], q[5]).toRotationMatrix() for q in qs[:k0]]
    F = np.array([Ri @ PUSH[:3] for Ri in R])
    impulse = simpson(F, x=t[:k0], axis=0)
    print('impulse error', np.abs(p[k0 - 1] - impulse).max())
    assert np.allclose(p[k0 - 1], impulse, rtol=0, atol=1e-6 * np.linalg.norm(impulse))
    assert np.allclose(p[k0], p[k0 - 1], rtol=0, atol=1e-12 * np.linalg.norm(impulse))  # thrusters off


def test_published_diagnostics_and_wrenches_agree_with_the_messages(run):
    """The momentum in diagnostics equals the one rebuilt by Pinocchio; the joint wrenches carry the
    applied torque (command minus joint damping) on their axis (z of the child link)."""
    msgs = _read(run['record'])
    t, p, L, c, _, _ = _momentum_from_messages(msgs)
    index = {round(x * 1e9): k for k, x in enumerate(t)}
    checked = 0
    for t_ns, d in msgs['/diagnostics']:
        vals = {kv.key: kv.value for kv in d.status[0].values}
        if 'momentum_linear_x' not in vals or t_ns not in index:
            continue
        k = index[t_ns]
        got = np.array([[float(vals[f'{n}_{a}']) for a in 'xyz'] for n in ('momentum_linear', 'momentum_angular_com',
                                                                             'com')])
        assert np.allclose(got, [p[k], L[k], c[k]], rtol=0, atol=1e-9), t_ns
        assert vals['formulation'] == 'augmented' and int(vals['constraint_rank']) == 15
        assert float(vals['constraint_residual']) < 1e-9
        checked += 1
    assert checked >= 2
    cmd = {t_ns: np.array(m.data) for t_ns, m in msgs['/effort_commands']}
    js = dict(msgs['/joint_states'])
    wrenches = [dict(msgs[f'/constraint_wrenches/joint{k + 1}']) for k in range(5)]
    held = np.zeros(5)
    n = 0
    for t_ns, state in sorted(js.items())[1:]:
        # the state at t_ns was produced by the command in force over the period before it
        prev = [x for x in cmd if x < t_ns]
        held = cmd[max(prev)] if prev else held
        for k in range(5):
            w = wrenches[k][t_ns]
            assert w.header.frame_id == f'link{k + 1}'
            assert w.wrench.torque.z == pytest.approx(state.effort[k] - DAMPING * state.velocity[k], abs=1e-9)
        assert np.allclose(state.effort, held if prev else 0.0, atol=0.0)
        n += 1
    assert n == run['periods']


def test_lockstep_recording_equals_headless_run_and_resim_is_exact(run, tmp_path):
    """The node in lockstep == the Simulator fed the same base wrenches and arm torques per period, byte for byte
    (joint_states, odom, wrenches, TF, commands); robodyn resim reproduces the recording exactly."""
    r = run
    assert r['rc'] == 0, r['log']
    assert_lockstep_recording_reproduced(r['record'], str(tmp_path), r['periods'])
