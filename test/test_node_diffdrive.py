"""The sim node driving betancur_platform through ``wheel_voltage_commands`` from another process.

The node runs in lockstep (one 10 ms period per command) in a private ROS domain and records; this
test process is the controller: 6 V / 6 V for 0.5 s, then 4 V / 8 V for 0.5 s. The recorded
odometry is checked against the closed forms derived here from the seed's parameters (eq. 57):
the platform is symmetric, so the forward speed responds to the mean voltage and the yaw rate to
the voltage difference, each a first-order lag (no friction, L = 0):

    v̇ = (v_ss(V̄) − v)/τ,   v_ss = r_w V̄ / K,        τ  = m_eff R r_w² / (2 K²)
    ω̇ = (ω_ss(ΔV) − ω)/τ_ω, ω_ss = r_w ΔV / (2 K r_c), τ_ω = J_eff R r_w² / (2 K² r_c²)

with V̄ = (V_l + V_r)/2, ΔV = V_r − V_l, m_eff = m_c + m_a + 2 m_w + 2 I_w/r_w²,
J_eff = I_c + I_a + 2 (m_w r_c² + I_w/2) + 2 I_w r_c²/r_w² (thin-disc wheels).
"""
import math
import os
import signal
import sys

import numpy as np
import pytest

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from ros_helpers import Domain, RosClient, assert_lockstep_recording_reproduced, start_sim  # noqa: E402

from robodyn_ros.recording import decode, read_raw_messages  # noqa: E402

pytestmark = pytest.mark.processes   # a lockstep node subprocess driven from here, SIGINT

R_C, R_W, M_C, M_W, I_C, I_W, I_A, K_T, R_A, M_A = 0.35, 0.28, 3.3, 0.3, 0.18965, 0.0037, 0.975, 0.061, 1.7, 0.4
M_EFF = M_C + M_A + 2 * M_W + 2 * I_W / R_W ** 2
J_EFF = I_C + I_A + 2 * (M_W * R_C ** 2 + I_W / 2) + 2 * I_W * R_C ** 2 / R_W ** 2
TAU_V = M_EFF * R_A * R_W ** 2 / (2 * K_T ** 2)
TAU_W = J_EFF * R_A * R_W ** 2 / (2 * K_T ** 2 * R_C ** 2)
SCHEDULE = [([6.0, 6.0], 50), ([4.0, 8.0], 50)]   # (volts, periods of 10 ms)
#: the last command is then followed by a refused one (NaN): lockstep still runs its period,
#: holding the last valid command, so the closed form holds 4 V / 8 V for one more period
HELD = [(SCHEDULE[0][0], SCHEDULE[0][1]), (SCHEDULE[1][0], SCHEDULE[1][1] + 1)]


def closed_form(t):
    """Forward speed and yaw rate at times t (s) under SCHEDULE from rest."""
    v = np.zeros_like(t)
    w = np.zeros_like(t)
    t0, v0, w0 = 0.0, 0.0, 0.0
    for (vl, vr), n in HELD:
        t1 = t0 + n * 0.01
        v_ss, w_ss = R_W * (vl + vr) / 2 / K_T, R_W * (vr - vl) / (2 * K_T * R_C)
        sel = (t > t0 - 1e-9) & (t <= t1 + 1e-9)
        v[sel] = v_ss + (v0 - v_ss) * np.exp(-(t[sel] - t0) / TAU_V)
        w[sel] = w_ss + (w0 - w_ss) * np.exp(-(t[sel] - t0) / TAU_W)
        v0 = v_ss + (v0 - v_ss) * math.exp(-(t1 - t0) / TAU_V)
        w0 = w_ss + (w0 - w_ss) * math.exp(-(t1 - t0) / TAU_W)
        t0 = t1
    return v, w


@pytest.fixture(scope='module')
def platform_run(tmp_path_factory):
    """A lockstep node on betancur_platform, recording, driven by this process; stopped by SIGINT."""
    from sensor_msgs.msg import JointState
    from std_msgs.msg import Float64MultiArray
    tmp = tmp_path_factory.mktemp('diffdrive')
    rec = tmp / 'platform.mcap'
    dom = Domain()
    node = start_sim(dom, {'scene': 'betancur_platform', 'mode': 'lockstep', 'record': str(rec),
                           'diagnostics_period': 0.1}, tmp / 'node.log')
    client = None
    try:
        client = RosClient(dom, 'diffdrive_driver')
        got = []
        client.node.create_subscription(JointState, 'joint_states', lambda m: got.append(
            (m.header.stamp.sec, m.header.stamp.nanosec, list(m.name))), 10)
        pub = client.node.create_publisher(Float64MultiArray, 'wheel_voltage_commands', 10)
        ok = client.spin_until(lambda: got and pub.get_subscription_count(), 60.0, proc=node)
        assert ok, 'no joint_states from the lockstep node:\n' + node.output()
        sent = 0
        for volts, n in SCHEDULE:
            for _ in range(n):
                last = got[-1][:2]
                pub.publish(Float64MultiArray(data=volts))
                sent += 1
                assert client.spin_until(lambda: got[-1][:2] != last, 30.0, proc=node), node.output()
        last = got[-1][:2]
        pub.publish(Float64MultiArray(data=[float('nan'), 1.0]))  # refused; the period runs on [4, 8]
        assert client.spin_until(lambda: got[-1][:2] != last, 30.0, proc=node), node.output()
        rc = node.stop(signal.SIGINT)
        yield {'record': rec, 'rc': rc, 'sent': sent, 'names': got[-1][2], 'log': node.output()}
    finally:
        if client is not None:
            client.close()
        node.cleanup()
        dom.release()


def _topic(rec, topic):
    return [(t, decode(ty, raw)) for _, ty, t, raw in read_raw_messages(rec, topics=[topic])]


def test_recorded_odometry_follows_the_closed_form(platform_run):
    r = platform_run
    assert r['rc'] == 0, r['log']
    assert r['names'] == ['left_wheel_joint', 'right_wheel_joint']
    odom = _topic(r['record'], '/odom')
    n = sum(k for _, k in HELD)
    assert len(odom) == n + 1  # the initial state and one state per command message
    t = np.array([ts for ts, _ in odom]) * 1e-9
    assert np.allclose(t, np.arange(n + 1) * 0.01, atol=1e-12)
    v = np.array([m['twist']['twist']['linear']['x'] for _, m in odom])
    w = np.array([m['twist']['twist']['angular']['z'] for _, m in odom])
    vy = np.array([m['twist']['twist']['linear']['y'] for _, m in odom])
    v_ref, w_ref = closed_form(t)
    assert np.abs(v - v_ref).max() < 1e-9 * np.abs(v_ref).max()
    assert np.abs(w - w_ref).max() < 1e-9 * np.abs(w_ref).max()
    assert w_ref[-1] > 0.01 and np.abs(vy).max() < 1e-12  # it turned left, without side slip
    # heading from the quaternion = ∫ ω dt of the closed form (trapezoid on the 10 ms grid)
    q = [m['pose']['pose']['orientation'] for _, m in odom]
    yaw = np.array([2 * math.atan2(o['z'], o['w']) for o in q])
    yaw_ref = np.concatenate([[0.0], np.cumsum(0.5 * (w_ref[1:] + w_ref[:-1]) * 0.01)])
    assert np.abs(yaw - yaw_ref).max() < 1e-3 * yaw_ref[-1]
    assert all(m['header']['frame_id'] == 'odom' and m['child_frame_id'] == 'base_link' for _, m in odom)


def test_recording_has_wheel_wrenches_currents_and_the_voltage_commands(platform_run):
    rec = platform_run['record']
    cmds = _topic(rec, '/wheel_voltage_commands')
    assert len(cmds) == platform_run['sent']  # the refused NaN command is not recorded
    assert list(cmds[0][1]['data']) == [6.0, 6.0] and list(cmds[-1][1]['data']) == [4.0, 8.0]
    for side in ('left', 'right'):
        w = _topic(rec, f'/constraint_wrenches/{side}_wheel_contact')
        assert len(w) == len(cmds) + 2 and w[-1][1]['header']['frame_id'] == f'{side}_wheel_contact'
    diags = _topic(rec, '/diagnostics')
    vals = [{kv['key']: kv['value'] for kv in m['status'][0]['values']} for _, m in diags]
    last = [d for d in vals if 'left_motor_current' in d][-1]
    assert float(last['right_motor_voltage']) == 8.0  # the last diagnostics: 4 V / 8 V
    assert float(last['right_motor_current']) > float(last['left_motor_current']) > 0.0
    assert float(last['electrical_power']) > 0.0 and float(last['constraint_residual']) < 1e-12


def test_lockstep_recording_equals_headless_run_and_resim_is_exact(platform_run, tmp_path):
    """The node in lockstep == the Simulator fed the same voltages per period, byte for byte
    (joint_states, odom, wrenches, TF, commands); robodyn resim reproduces the recording exactly."""
    r = platform_run
    assert r['rc'] == 0, r['log']
    # one period per command sent, and one more on the refused NaN command
    assert_lockstep_recording_reproduced(r['record'], str(tmp_path), r['sent'] + 1)
