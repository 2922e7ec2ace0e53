"""The sim node over real ROS 2 topics: nodes and controllers run in subprocesses, each test module
in its own ROS domain; every process is stopped in a fixture finaliser, also when a test fails.

Four node runs: a lockstep PD loop (recording, SIGINT), a real-time node poked by the tests
(bad commands, timeout, services, late joiners, /clock, wrenches), a real-time pacing run at
1 kHz, and a lockstep recording killed with SIGKILL. Signals go at moments the tests control (a
lockstep node waiting for its next command), and no test assumes how fast the machine is.
"""
import json
import math
import os
import signal
import sys
import time
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from ros_helpers import (Domain, RosClient, diag_values, headless_lockstep, lockstep_pd_run, lockstep_step,  # noqa: E402
                         start_sim)

from robodyn_ros import dynamics as dyn  # noqa: E402
from robodyn_ros.recording import decode, read_raw_messages, summarize  # noqa: E402
from robodyn_ros.scene import load_scene  # noqa: E402

pytestmark = pytest.mark.processes   # ROS node subprocesses, signals, a real-time pacing run

SCENE = load_scene('stanford_arm')
JOINTS = list(SCENE.system.joint_names)
SETPOINT = [0.6, 0.8, 0.9, 0.5, 0.6, 0.4]
PD_PERIODS = 150            # 1.5 s of simulation at 100 Hz


@pytest.fixture(scope='module')
def lockstep_run(tmp_path_factory):
    """A lockstep node recording while a PD controller (another process) closes the loop; SIGINT."""
    yield from lockstep_pd_run(tmp_path_factory.mktemp('lockstep'), {'scene': 'stanford_arm'}, SETPOINT, PD_PERIODS)


def test_pd_controller_in_another_process_reaches_setpoint_in_lockstep(lockstep_run):
    r = lockstep_run
    assert r['pd_rc'] == 0, r['pd_log'] + r['node_log']
    assert r['pd']['sent'] == PD_PERIODS
    assert r['pd']['stamp'] == [1, 500000000]   # the state after the last command: 150 periods of 10 ms
    np.testing.assert_allclose(r['pd']['q'], SETPOINT, atol=2e-3)
    assert r['node_rc'] == 0, r['node_log']
    assert 'recording' in r['node_log'] and 'real-time factor' in r['node_log']  # the exit summary


def test_lockstep_recording_equals_headless_run_fed_the_same_commands(lockstep_run, tmp_path):
    """Same commands at the same period boundaries -> byte-identical state messages."""
    from robodyn_ros.recording.run_sink import McapRunSink
    from robodyn_ros.simulation import Simulator
    rec = lockstep_run['record']
    cmds = [[('effort', decode(ty, raw)['data'])]
            for _, ty, t, raw in read_raw_messages(rec, topics=['/effort_commands'])]
    assert len(cmds) == PD_PERIODS
    from robodyn_ros.scene import load_scene
    from robodyn_ros.systems.base import backend_scope
    settings = json.loads(summarize(rec)['metadata']['robodyn']['settings'])
    with backend_scope(settings['backend']):  # the node's kernels (recorded in its settings)
        scene = load_scene('stanford_arm')
    sim = Simulator(scene.system, scene.y0, integrator='rk4', dt=1e-3, command_timeout=settings['command_timeout'])
    out = tmp_path / 'headless.mcap'
    headless_lockstep(sim, McapRunSink(out, scene, {'mode': 'headless'}), cmds, 100.0)
    for topic in ['/joint_states', '/tf'] + [f'/constraint_wrenches/{j}' for j in JOINTS]:
        a = [(t, raw) for _, _, t, raw in read_raw_messages(rec, topics=[topic])]
        b = [(t, raw) for _, _, t, raw in read_raw_messages(out, topics=[topic])]
        assert len(a) == PD_PERIODS + 1
        assert a == b, topic
    # /tf_static once, latched; recorded even where tf2_msgs is missing (the node then says so)
    a = [raw for *_, raw in read_raw_messages(rec, topics=['/tf_static'])]
    assert len(a) == 1 and a == [raw for *_, raw in read_raw_messages(out, topics=['/tf_static'])]
    import importlib.util
    no_tf2 = importlib.util.find_spec('tf2_msgs') is None
    assert ('tf2_msgs is not installed: /tf and /tf_static are not published' in lockstep_run['node_log']) == no_tf2
    a = [raw for *_, raw in read_raw_messages(rec, topics=['/effort_commands'])]
    b = [raw for *_, raw in read_raw_messages(out, topics=['/effort_commands'])]
    assert a == b


def test_lockstep_effort_is_the_command_held_over_the_period_ending_at_its_stamp(lockstep_run):
    """README's rule on the lockstep recording; at t0 no command has arrived yet: effort zero."""
    from test_joint_state_effort import (assert_effort_is_the_command_held_over_the_period_ending_at_its_stamp,
                                         efforts_and_commands)
    js, cmd = efforts_and_commands(lockstep_run['record'])
    assert len(js) == PD_PERIODS + 1 and len(cmd) == PD_PERIODS
    e0 = assert_effort_is_the_command_held_over_the_period_ending_at_its_stamp(js, cmd)
    np.testing.assert_array_equal(e0, np.zeros(6))
    assert cmd[0][0] == 0 and np.abs(cmd[0][1]).max() > 1.0   # the first command is set at t0, after the t0 state


def test_sigint_recording_is_read_in_full_by_check_mcap_ros2_and_rosbags(lockstep_run):
    from rosbags.highlevel import AnyReader

    from robodyn_ros.cli.check import check_file
    from robodyn_ros.recording import read_messages
    rec = lockstep_run['record']
    report = check_file(rec)
    assert report['ok'], report['problems']
    assert report['finished']
    n = report['message_count']
    assert report['topics']['/joint_states']['count'] == PD_PERIODS + 1
    assert report['topics']['/effort_commands']['count'] == PD_PERIODS
    assert report['topics']['/robot_description']['count'] == 1
    assert sum(1 for _ in read_messages(rec)) == n           # mcap-ros2-support decoder
    with AnyReader([Path(rec)]) as reader:                    # rosbags, types from the file's schemas
        decoded = [reader.deserialize(raw, c.msgtype) for c, _, raw in reader.messages()]
    assert len(decoded) == n
    md = report['metadata']['robodyn']
    assert md['scene_name'] == 'stanford_arm' and json.loads(md['settings'])['mode'] == 'lockstep'


def test_resim_of_lockstep_recording_reports_zero_deviation(lockstep_run, capsys):
    from robodyn_ros.cli import main as robodyn
    out = lockstep_run['tmp'] / 'resim.mcap'
    assert robodyn(['resim', str(lockstep_run['record']), '--record', str(out)]) == 0
    text = capsys.readouterr().out
    assert 'largest deviation 0 ' in text
    rows = {line.split()[0]: line.split()[1:] for line in text.splitlines() if line.startswith('/')}
    assert rows['/joint_states'] == [str(PD_PERIODS + 1), str(PD_PERIODS + 1), '0']
    assert all(r[2] == '0' for r in rows.values()) and len(rows) == 1 + len(JOINTS) + 1 + 2  # tool_joint, TF
    assert rows['/tf'] == [str(PD_PERIODS + 1), str(PD_PERIODS + 1), '0'] and rows['/tf_static'][1] == '1'


# ------------------------------------------------------------------------------------------
# a real-time node the tests talk to
# ------------------------------------------------------------------------------------------
TIMEOUT = 0.3


@pytest.fixture(scope='module')
def live(tmp_path_factory):
    """A realtime node (rk4, dt 5 ms, 100 Hz, command_timeout 0.3 s) and a test-side ROS client."""
    tmp = tmp_path_factory.mktemp('live')
    dom = Domain()
    node = start_sim(dom, {'scene': 'stanford_arm', 'mode': 'realtime', 'dt': 0.005,
                           'command_timeout': TIMEOUT, 'record': str(tmp / 'live.mcap')}, tmp / 'node.log')
    client = RosClient(dom)
    try:
        from sensor_msgs.msg import JointState
        states = []
        client.node.create_subscription(JointState, 'joint_states', states.append, 100)
        assert client.spin_until(lambda: len(states) > 5, 120, node), node.output()
        yield {'node': node, 'client': client, 'states': states, 'tmp': tmp}
    finally:
        client.close()
        node.cleanup()
        dom.release()


def _stamp_ns(msg):
    return msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec


def test_robot_description_reaches_late_joining_subscriber(live):
    from rclpy.qos import DurabilityPolicy, QoSProfile
    from std_msgs.msg import String
    got = []
    live['client'].node.create_subscription(
        String, 'robot_description', got.append, QoSProfile(depth=1, durability=DurabilityPolicy.TRANSIENT_LOCAL))
    assert live['client'].spin_until(lambda: got, 60)
    urdf = got[0].data
    assert urdf.startswith('<?xml') or '<robot' in urdf
    for j in JOINTS:
        assert f'name="{j}"' in urdf


def test_clock_is_monotonic_and_matches_joint_states(live):
    from rosgraph_msgs.msg import Clock
    clock = []
    live['client'].node.create_subscription(Clock, '/clock', clock.append, 100)
    assert live['client'].spin_until(lambda: len(clock) > 60, 60)
    t = [c.clock.sec * 1_000_000_000 + c.clock.nanosec for c in clock]
    assert len(t) > 60
    assert all(b > a for a, b in zip(t, t[1:]))
    assert all((b - a) % 10_000_000 == 0 for a, b in zip(t, t[1:]))   # whole 10 ms periods
    assert set(t[:30]) <= {_stamp_ns(s) for s in live['states']}


def test_constraint_wrench_projection_on_joint_axis_is_the_joint_effort(live):
    """S_iᵀ f_i = effort_i − damping_i v_i: the joint transmits the actuator and its damper."""
    from geometry_msgs.msg import WrenchStamped
    from std_msgs.msg import Float64MultiArray
    client, states = live['client'], live['states']
    model = SCENE.system.model
    wr = {j: {} for j in JOINTS}
    for j in JOINTS:
        client.node.create_subscription(WrenchStamped, f'constraint_wrenches/{j}',
                                        lambda m, j=j: wr[j].__setitem__(_stamp_ns(m), m), 100)
    pub = client.node.create_publisher(Float64MultiArray, 'effort_commands', 10)
    u = [5.0, -3.0, 20.0, 0.2, -0.1, 0.01]
    assert client.spin_until(lambda: pub.get_subscription_count() > 0, 60)

    def matched():
        pub.publish(Float64MultiArray(data=u))
        return [s for s in states if all(_stamp_ns(s) in wr[j] for j in JOINTS) and np.any(s.effort)]
    assert client.spin_until(lambda: len(matched()) >= 5, 60)
    for s in matched():
        q, v, effort = np.array(s.position), np.array(s.velocity), np.array(s.effort)
        _, S = dyn.joint_transforms(model, q)
        for k, j in enumerate(JOINTS):
            m = wr[j][_stamp_ns(s)]
            i = model.joint_names.index(j)
            assert m.header.frame_id == model.link_names[i]
            f = np.array([m.wrench.torque.x, m.wrench.torque.y, m.wrench.torque.z,
                          m.wrench.force.x, m.wrench.force.y, m.wrench.force.z])
            expected = effort[k] - model.damping[k] * v[k]
            assert S[:, k] @ f == pytest.approx(expected, rel=1e-9, abs=1e-9), j
        np.testing.assert_array_equal(effort, u)


def test_bad_commands_rejected_node_alive_states_finite_then_timeout_zeroes_efforts(live):
    from diagnostic_msgs.msg import DiagnosticArray
    from std_msgs.msg import Float64MultiArray
    client, states, node = live['client'], live['states'], live['node']
    diags = []
    client.node.create_subscription(DiagnosticArray, 'diagnostics', diags.append, 10)
    pub = client.node.create_publisher(Float64MultiArray, 'effort_commands', 10)
    assert client.spin_until(lambda: pub.get_subscription_count() > 0, 60)
    good = [1.0, 2.0, 3.0, 0.1, 0.2, 0.01]
    pub.publish(Float64MultiArray(data=good))
    assert client.spin_until(lambda: list(states[-1].effort) == good, 60)
    n0 = len(states)
    for bad in ([1.0, 2.0], [math.nan] * 6, [0.0, 0.0, math.inf, 0.0, 0.0, 0.0], [1.0] * 7):
        pub.publish(Float64MultiArray(data=bad))
        client.spin_for(0.02)
    # the last valid command stays until the timeout, then zero
    assert client.spin_until(lambda: len(states) > n0 + 3 and not np.any(states[-1].effort), 60), node.output()
    first_good = next(s for s in states if list(s.effort) == good)   # one period after the command
    zero = [s for s in states[n0:] if not np.any(s.effort)]
    # inputs go to zero in the first period that starts more than TIMEOUT after the command
    assert _stamp_ns(zero[0]) - _stamp_ns(first_good) == round(TIMEOUT * 1e9)
    assert all(list(s.effort) in (good, [0.0] * 6) for s in states[n0:])
    # the first diagnostics published after the timeout
    late = lambda: [d for d in diags if _stamp_ns(d) >= _stamp_ns(zero[0])]  # noqa: E731
    assert client.spin_until(late, 60)
    v = diag_values(late()[0])
    assert int(v['rejected_commands']) == 4
    assert v['effort_timed_out'] == 'true'
    assert node.alive()
    assert states, 'no joint_states received'
    for s in states:
        assert np.all(np.isfinite(s.position)) and np.all(np.isfinite(s.velocity)) and np.all(np.isfinite(s.effort))
    log = node.output()
    assert 'command rejected' in log and 'expected 6 values (joint1, joint2' in log
    assert 'non-finite value' in log
    assert 'effort_commands for 0.3 s' in log


def test_pause_stops_time_and_reset_returns_to_initial_state(live):
    """~/pause: the node's idle diagnostics (one per wall second while paused) report the same
    simulation time twice and no state after it ever arrives; resumed, time goes on; ~/reset
    starts again from 0 (the initial state itself is checked in the recording, see below)."""
    from diagnostic_msgs.msg import DiagnosticArray
    from std_srvs.srv import SetBool, Trigger
    client, states = live['client'], live['states']
    diags = []
    client.node.create_subscription(DiagnosticArray, 'diagnostics', diags.append, 10)
    r = client.call(SetBool, '/robodyn_sim/pause', SetBool.Request(data=True), timeout=60)
    assert r.success and r.message.startswith('paused')
    n_diag = len(diags)
    paused = lambda: [diag_values(d) for d in diags[n_diag:] if diag_values(d)['paused'] == 'true']  # noqa: E731
    assert client.spin_until(lambda: len(paused()) >= 2, 60)
    times = {p['sim_time'] for p in paused()}
    assert len(times) == 1, times                       # a wall second apart: time stood still
    t_paused = round(float(times.pop()) * 1e9)
    assert max(_stamp_ns(s) for s in states) <= t_paused
    r = client.call(SetBool, '/robodyn_sim/pause', SetBool.Request(data=False), timeout=60)
    assert r.success and r.message.startswith('running')
    assert client.spin_until(lambda: _stamp_ns(states[-1]) > t_paused + 100_000_000, 30)
    t_before = _stamp_ns(states[-1])
    n = len(states)
    r = client.call(Trigger, '/robodyn_sim/reset', Trigger.Request(), timeout=60)
    assert r.success and 'reset to the initial state at t=0 s' in r.message
    # every state before the reset was later than t_paused: one earlier than that is the new episode
    assert client.spin_until(lambda: any(_stamp_ns(s) < t_paused for s in states[n:]), 30)
    assert t_before > t_paused


def test_sigterm_finishes_the_recording_of_each_episode(live):
    """After ~/reset the recording continues in live-1.mcap; SIGTERM finishes both files."""
    from robodyn_ros.cli.check import check_file
    node = live['node']
    assert node.stop(signal.SIGTERM) == 0, node.output()
    assert 'recording ' in node.output() and 'live-1.mcap' in node.output()
    for name, least in (('live.mcap', 100), ('live-1.mcap', 1)):
        report = check_file(live['tmp'] / name)
        assert report['ok'], (name, report['problems'])
        assert report['topics']['/joint_states']['count'] >= least
        assert report['topics']['/robot_description']['count'] == 1
    first = [(t, decode(ty, raw)) for _, ty, t, raw in read_raw_messages(live['tmp'] / 'live-1.mcap',
                                                                        topics=['/joint_states'])]
    assert first[0][0] == 0                              # the reset episode starts at the initial state
    np.testing.assert_array_equal(first[0][1]['position'], SCENE.y0[:6])
    np.testing.assert_array_equal(first[0][1]['velocity'], np.zeros(6))


# ------------------------------------------------------------------------------------------
# real-time pacing and crash safety
# ------------------------------------------------------------------------------------------
def test_realtime_mode_never_runs_ahead_of_the_wall_clock(tmp_path):
    """2 s at 1 kHz (semi-implicit Euler, dt = 1 ms, joint_states at 1 kHz) in real time: the node's
    own real-time factor (diagnostics ``real_time_factor_overall``) is at most 1, within one period:
    paced, however idle the machine. How close to 1 it stays depends on how busy the machine is:
    printed, not asserted."""
    from diagnostic_msgs.msg import DiagnosticArray
    dom = Domain()
    node = start_sim(dom, {'scene': 'stanford_arm', 'mode': 'realtime', 'integrator': 'semi_implicit_euler',
                           'dt': 0.001, 'publish_rate': 1000.0, 'rate_factor': 1.0}, tmp_path / 'node.log')
    client = RosClient(dom)
    try:
        diags = []
        client.node.create_subscription(DiagnosticArray, 'diagnostics', diags.append, 10)
        assert client.spin_until(lambda: diags, 120, node), node.output()
        first = diag_values(diags[-1])
        assert client.spin_until(lambda: float(diag_values(diags[-1])['sim_time'])
                                 >= float(first['sim_time']) + 2.0 - 1e-9, 240, node), node.output()
        v = diag_values(diags[-1])
    finally:
        client.close()
        node.cleanup()
        dom.release()
    rtf, compute = float(v['real_time_factor_overall']), float(v['real_time_factor_compute'])
    print(f'\nrealtime 1 kHz: real-time factor {rtf:.4f} overall, last interval {v["real_time_factor"]}, '
          f'compute-only {compute:.2f}, load average {os.getloadavg()}')
    assert float(v['sim_time']) >= 2.0
    assert rtf <= 1.0 + 0.001 / float(v['sim_time']) + 1e-9, v   # at most one period ahead


def test_sigkill_leaves_every_complete_chunk_readable(tmp_path):
    """A recording killed with SIGKILL: complete chunks read back, only the open one is lost.

    Lockstep, driven from here: when the signal goes, the node has published (and recorded) the
    state of every command this process sent, and waits for the next one.
    """
    from sensor_msgs.msg import JointState
    from std_msgs.msg import Float64MultiArray

    from robodyn_ros.recording import read_messages
    from robodyn_ros.recording.run_sink import NODE_CHUNK_SPAN
    periods = 123
    dom = Domain()
    rec = tmp_path / 'killed.mcap'
    node = start_sim(dom, {'scene': 'stanford_arm', 'mode': 'lockstep', 'record': str(rec)}, tmp_path / 'node.log')
    client = RosClient(dom)
    try:
        states = []
        client.node.create_subscription(JointState, 'joint_states', states.append, 100)
        eff = client.node.create_publisher(Float64MultiArray, 'effort_commands', 10)
        assert client.spin_until(lambda: states and eff.get_subscription_count(), 120, node), node.output()
        for k in range(periods):
            seen_ns = lockstep_step(client, eff, Float64MultiArray(data=[0.0, 1.0, 0.0, 0.0, 0.0, 0.0]), states, node)
        assert seen_ns == periods * 10_000_000
        node.stop(signal.SIGKILL)
    finally:
        client.close()
        node.cleanup()
        dom.release()
    s = summarize(rec)
    assert not s['finished'] and s['chunk_count'] >= 2
    assert s['error'] is None or s['error'].startswith('truncated'), s['error']
    js = [t for _, _, t, _ in read_raw_messages(rec, topics=['/joint_states'])]
    assert js == [k * 10_000_000 for k in range(len(js))]   # every period up to the cut, no gap
    decoded = sum(1 for _ in read_messages(rec))
    assert decoded == s['message_count']
    lost_s = (seen_ns - js[-1]) / 1e9
    size = os.path.getsize(rec)
    print(f'\nSIGKILL: {s["message_count"]} messages in {s["chunk_count"]} complete chunks recovered '
          f'({size} bytes on disk, recording up to t = {js[-1] / 1e9:.2f} s); the node had reached '
          f't = {seen_ns / 1e9:.2f} s: {lost_s:.2f} s of simulation ({lost_s * 100:.0f} periods, the open '
          f'chunk) lost')
    assert 0 <= lost_s < NODE_CHUNK_SPAN


def test_simulation_error_stops_the_node_cleanly_and_reset_recovers(tmp_path):
    """In-process node started paused: ~/pause starts it; the state turns non-finite at t > 0.2 s.
    Nothing non-finite is published, an ERROR diagnostic says why, time stops, ~/reset still
    answers and the run resumes."""
    import rclpy
    from diagnostic_msgs.msg import DiagnosticArray
    from rclpy.context import Context
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.parameter import Parameter
    from sensor_msgs.msg import JointState
    from std_srvs.srv import SetBool, Trigger

    from robodyn_ros.nodes.sim import make_node_class
    dom = Domain()
    ctx = Context()
    rclpy.init(context=ctx, domain_id=dom.id)
    node = listener = None
    try:
        rec = tmp_path / 'failed.mcap'
        node = make_node_class()(context=ctx, parameter_overrides=[
            Parameter('mode', value='max'), Parameter('record', value=str(rec)),
            Parameter('start_paused', value=True)])
        listener = rclpy.create_node('listener', context=ctx)
        ex = SingleThreadedExecutor(context=ctx)
        ex.add_node(node)
        ex.add_node(listener)
        states, diags = [], []
        listener.create_subscription(JointState, 'joint_states', states.append, 1000)
        listener.create_subscription(DiagnosticArray, 'diagnostics', diags.append, 100)
        reset = listener.create_client(Trigger, '/robodyn_sim/reset')
        pause = listener.create_client(SetBool, '/robodyn_sim/pause')

        def spin(pred, timeout=20.0, advance=True):
            end = time.monotonic() + timeout
            while time.monotonic() < end and not pred():
                ex.spin_once(timeout_sec=0.01)
                if advance:
                    node.work()
            return pred()
        assert spin(lambda: node.pub['joint_states'].get_subscription_count()
                    and node.pub['diagnostics'].get_subscription_count() and reset.service_is_ready()
                    and pause.service_is_ready(), advance=False)
        spin(lambda: False, timeout=0.2)
        assert node.sim.t == 0.0 and node.paused
        integrate = node.sim._integrate

        def blow_up(u, t1):
            y, w, st = integrate(u, t1)
            return (y * np.nan if t1 > 0.2 else y), w, st
        node.sim._integrate = blow_up
        fut = pause.call_async(SetBool.Request(data=False))
        assert spin(fut.done) and fut.result().success and not node.paused
        assert spin(lambda: node.sim.failed)
        t_fail = node.sim.t
        assert t_fail == pytest.approx(0.2)
        assert spin(lambda: any(d.status[0].level == b'\x02' for d in diags))
        error = next(d for d in diags if d.status[0].level == b'\x02')
        assert 'non-finite' in error.status[0].message
        spin(lambda: False, timeout=0.3)                    # time stands still, the loop keeps going
        assert node.sim.t == t_fail
        assert all(np.all(np.isfinite(s.position)) and np.all(np.isfinite(s.velocity)) for s in states)
        assert max(_stamp_ns(s) for s in states) == round(t_fail * 1e9)
        node.sim._integrate = integrate
        fut = reset.call_async(Trigger.Request())
        assert spin(fut.done) and fut.result().success
        assert spin(lambda: node.sim.t > 0.1)
    finally:
        if node is not None:
            node.close()
            node.destroy_node()
        if listener is not None:
            listener.destroy_node()
        rclpy.try_shutdown(context=ctx)
        dom.release()
    from robodyn_ros.cli.check import check_file
    report = check_file(rec)                                  # the failed episode's file is clean
    assert report['ok'], report['problems']
    assert report['end_time_ns'] == round(t_fail * 1e9)
