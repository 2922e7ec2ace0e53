"""The sim node's live server (parameter ``foxglove_port``): a viewer steers it as a ROS client does.

Two lockstep runs of stanford_arm record while the same commands arrive, one over rclpy, one
published by a WebSocket client (``foxglove_client.py``, written from the protocol's specification):
the recordings are byte-identical (but for ``diagnostics``, whose real-time factors are wall-clock
figures), and the client received the second recording byte for byte. Then the services (reset,
pause), a NaN command, a port in use. Each node runs in its own ROS domain (ros_helpers).
"""
from __future__ import annotations

import math
import signal
import socket

import numpy as np
import pytest

from foxglove_client import SDK, V1, Client, response_fields, set_bool_request, trigger_request
from robodyn_ros.recording import cdr
from robodyn_ros.recording.reader import read_raw_messages, summarize
from ros_helpers import Domain, Probe, start_sim

pytestmark = pytest.mark.processes
N = 12
COMMANDS = [[2.0 * math.sin(0.3 * k + j) for j in range(6)] for k in range(N)]
FLOAT_ARRAY = 'std_msgs/msg/Float64MultiArray'


def _free_port() -> int:
    with socket.create_server(('127.0.0.1', 0)) as s:
        return s.getsockname()[1]


def _wait_url(node, port, timeout=120.0):
    """Connect once the node serves (it binds before loading the scene, serves once it has started)."""
    import time
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        assert node.alive(), node.output()
        if f'live on ws://127.0.0.1:{port}' in node.output():
            return f'ws://127.0.0.1:{port}'
        time.sleep(0.05)
    raise AssertionError(node.output())


def _js_times(client):
    return [t for topic, t, _ in client.messages if topic == '/joint_states']


@pytest.fixture(scope='module')
def two_runs(tmp_path_factory):
    """``{ros, live, client, logs}``: the recordings of N commands over rclpy and over the WebSocket."""
    tmp = tmp_path_factory.mktemp('livenode')
    params = {'scene': 'stanford_arm', 'mode': 'lockstep', 'diagnostics_period': 0.05}
    out = {}
    # over rclpy
    dom = Domain()
    try:
        node = start_sim(dom, {**params, 'record': str(tmp / 'ros.mcap')}, tmp / 'ros.log')
        probe = Probe(dom, 'live_test')
        try:
            from sensor_msgs.msg import JointState
            from std_msgs.msg import Float64MultiArray
            got = []
            probe.node.create_subscription(JointState, 'joint_states', lambda m: got.append(
                m.header.stamp.sec * 10**9 + m.header.stamp.nanosec), 100)
            pub = probe.node.create_publisher(Float64MultiArray, 'effort_commands', 10)
            assert probe.spin_until(lambda: got and pub.get_subscription_count(), 120), node.output()
            for k, cmd in enumerate(COMMANDS):
                pub.publish(Float64MultiArray(data=cmd))
                assert probe.spin_until(lambda k=k: got[-1] == (k + 1) * 10_000_000, 60), node.output()
        finally:
            probe.close()
        assert node.stop(signal.SIGINT) == 0, node.output()
        node.cleanup()
    finally:
        dom.release()
    # over the WebSocket
    dom = Domain()
    port = _free_port()
    try:
        node = start_sim(dom, {**params, 'record': str(tmp / 'live.mcap'), 'foxglove_port': port}, tmp / 'live.log')
        c = Client(_wait_url(node, port), V1)
        assert c.pump_until(lambda: any(ch['topic'] == '/diagnostics' for ch in c.channels.values()), 60)
        topics = set(c.subscribe()) - {'/effort_commands'}   # advertised at the start, no command yet
        assert c.pump_until(lambda: {m[0] for m in c.messages} >= topics, 60)
        ch = c.advertise('/effort_commands', FLOAT_ARRAY)
        for k, cmd in enumerate(COMMANDS):
            c.publish(ch, cdr.encode(FLOAT_ARRAY, {'data': cmd}))
            assert c.pump_until(lambda k=k: _js_times(c)[-1] == (k + 1) * 10_000_000, 60), node.output()
        assert node.stop(signal.SIGINT) == 0, node.output()
        assert c.until_closed(30), 'the node did not close the connection'
        out['log'] = node.output()
        node.cleanup()
    finally:
        dom.release()
    out.update(ros=tmp / 'ros.mcap', live=tmp / 'live.mcap', client=c)
    return out


def test_a_viewer_command_moves_the_robot_as_the_same_ros_command(two_runs):
    ros = [m for m in read_raw_messages(two_runs['ros']) if m[0] != '/diagnostics']
    live = [m for m in read_raw_messages(two_runs['live']) if m[0] != '/diagnostics']
    assert len([m for m in ros if m[0] == '/joint_states']) == N + 1
    assert len([m for m in ros if m[0] == '/effort_commands']) == N
    assert live == ros     # every other topic, in order, byte for byte
    sent = [list(cdr.decode(FLOAT_ARRAY, d)['data']) for t, _, _, d in read_raw_messages(two_runs['live'])
            if t == '/effort_commands']
    assert sent == COMMANDS


def test_the_viewer_got_the_node_recording_byte_for_byte(two_runs):
    c = two_runs['client']
    want = [(topic, t, data) for topic, _, t, data in read_raw_messages(two_runs['live'])]
    assert len(want) > 10 * N and c.messages == want   # diagnostics included: the same bytes as recorded
    assert 'live on ws://127.0.0.1:' in two_runs['log'] and 'recording' in two_runs['log']


def test_nan_is_refused_and_counted_reset_and_pause_are_services(tmp_path):
    dom = Domain()
    port = _free_port()
    rec = tmp_path / 'svc.mcap'
    try:
        node = start_sim(dom, {'scene': 'stanford_arm', 'mode': 'lockstep', 'foxglove_port': port,
                               'record': str(rec), 'diagnostics_period': 0.01}, tmp_path / 'svc.log')
        c = Client(_wait_url(node, port), SDK)
        assert c.pump_until(lambda: len(c.services) == 2, 30)
        assert set(c.services) == {'/robodyn_sim/reset', '/robodyn_sim/pause'}
        assert c.services['/robodyn_sim/pause']['type'] == 'std_srvs/srv/SetBool'
        assert c.pump_until(lambda: any(ch['topic'] == '/diagnostics' for ch in c.channels.values()), 60)
        c.subscribe()
        ch = c.advertise('/effort_commands', FLOAT_ARRAY)
        good = [0.5, 1.0, -1.0, 0.25, 0.0, -0.5]
        c.publish(ch, cdr.encode(FLOAT_ARRAY, {'data': good}))
        assert c.pump_until(lambda: _js_times(c) and _js_times(c)[-1] == 10_000_000, 60)
        c.publish(ch, cdr.encode(FLOAT_ARRAY, {'data': [float('nan')] * 6}))   # lockstep: still one period
        assert c.pump_until(lambda: _js_times(c)[-1] == 20_000_000, 60)
        assert c.pump_until(lambda: any(s['level'] == 2 and 'rejected' in s['message'] for s in c.statuses), 30)
        assert response_fields(c.call('/robodyn_sim/pause', set_bool_request(True)))[0]
        ok, message = response_fields(c.call('/robodyn_sim/reset', trigger_request()))
        assert ok and 'svc-1.mcap' in message, message
        assert c.pump_until(lambda: _js_times(c)[-1] == 0, 60)                # the initial state again
        assert node.stop(signal.SIGINT) == 0, node.output()
        log = node.output()
        node.cleanup()
    finally:
        dom.release()
    assert 'command rejected (1 so far)' in log
    js = [cdr.decode('sensor_msgs/msg/JointState', d) for t, _, _, d in read_raw_messages(rec) if t == '/joint_states']
    assert len(js) == 3
    np.testing.assert_array_equal(js[2]['effort'], good)   # the last valid command stays in force
    cmds = [t for t, *_ in read_raw_messages(rec) if t == '/effort_commands']
    assert len(cmds) == 1                                    # the refused one is not recorded
    diag = [cdr.decode('diagnostic_msgs/msg/DiagnosticArray', d) for t, _, _, d in read_raw_messages(rec)
            if t == '/diagnostics']
    last = dict((kv['key'], kv['value']) for kv in diag[-1]['status'][0]['values'])
    assert last['rejected_commands'] == '1'
    assert summarize(tmp_path / 'svc-1.mcap')['finished']


def test_a_port_in_use_stops_the_node_in_one_line(tmp_path):
    from ros_helpers import run_sim_to_end
    busy = socket.create_server(('127.0.0.1', 0))
    try:
        rc, log = run_sim_to_end({'scene': 'stanford_arm', 'foxglove_port': busy.getsockname()[1],
                                  'record': str(tmp_path / 'never.mcap')}, tmp_path / 'busy.log')
    finally:
        busy.close()
    assert rc == 2
    lines = [x for x in log.splitlines() if x.startswith('sim:')]
    assert len(lines) == 1 and "parameter 'foxglove_port'" in lines[0] and 'in use' in lines[0], log
    assert 'Traceback' not in log and not (tmp_path / 'never.mcap').exists()
