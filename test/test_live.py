"""``robodyn run --live``: what a viewer gets is the recording, byte for byte; steering; slow clients;
a port in use; Ctrl-C.

Every test starts ``robodyn run`` in a process (port 0: a free one, read back from its ``live`` line)
and talks to it with the client of ``foxglove_client.py`` (written from the protocol's specification
on the ``websockets`` package; nothing of robodyn_ros.live). Runs that must see every message
start paused (``--start-paused``): the client subscribes to every channel while the run waits at
t = 0 (a new subscriber gets the last message of each channel: the initial state), then resumes it
with the ``pause`` service. Signals are sent at moments the test has seen happen.
"""
from __future__ import annotations

import os
import re
import signal
import socket
import subprocess
import sys
import threading
import time

import pytest

from foxglove_client import SDK, V1, Client, response_fields, set_bool_request, trigger_request
from robodyn_ros.recording import cdr
from robodyn_ros.recording.reader import read_raw_messages, summarize

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
pytestmark = pytest.mark.processes


class Run:
    """``robodyn run ARGS --live --port 0`` in a process; ``url`` once it serves; ``lines`` its stdout."""

    def __init__(self, *args, timeout=120.0):
        env = dict(os.environ, PYTHONUNBUFFERED='1')
        self.p = subprocess.Popen([sys.executable, '-m', 'robodyn_ros.cli', 'run', *args], cwd=REPO, env=env,
                                  stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, start_new_session=True)
        self.lines, self.err = [], []
        threading.Thread(target=lambda: self.lines.extend(self.p.stdout), daemon=True).start()
        threading.Thread(target=lambda: self.err.extend(self.p.stderr), daemon=True).start()
        self.url = None
        end = time.monotonic() + timeout
        while self.url is None and time.monotonic() < end and self.p.poll() is None:
            m = next((re.search(r'(ws://\S+)', x) for x in list(self.lines) if x.startswith('live ')), None)
            self.url = m.group(1) if m else None
            time.sleep(0.05)
        assert self.url, self.output()

    def wait(self, timeout=120.0) -> int:
        rc = self.p.wait(timeout=timeout)
        time.sleep(0.1)   # the reader threads take the last lines
        return rc

    def output(self) -> str:
        return ''.join(self.lines) + ''.join(self.err)

    def kill(self):
        if self.p.poll() is None:
            self.p.kill()
            self.p.wait(timeout=30)


@pytest.fixture
def runs():
    started = []
    yield lambda *a, **k: started.append(Run(*a, **k)) or started[-1]
    for r in started:
        r.kill()


def _subscribe_paused_run(client, last_topic):
    """Subscribe to every channel of a run paused at t = 0 (after ``last_topic``, the last written there,
    is advertised) and take each channel's initial message."""
    assert client.pump_until(lambda: any(c['topic'] == last_topic for c in client.channels.values()), 60)
    topics = client.subscribe()
    # the command topics are advertised from the start; a scene without scripted commands has none yet
    written = set(topics) - {'/effort_commands', '/wheel_voltage_commands', '/base_wrench_command'}
    assert client.pump_until(lambda: {m[0] for m in client.messages} >= written, 60), topics
    return topics


def _recorded(path):
    return [(topic, t, data) for topic, _, t, data in read_raw_messages(path)]


@pytest.mark.parametrize('scene,subprotocol', [('stanford_arm', V1), ('stanford_arm', SDK), ('a1_stand', SDK)])
def test_a_live_client_gets_the_recording_byte_for_byte(runs, tmp_path, scene, subprotocol):
    rec, plain = tmp_path / 'live.mcap', tmp_path / 'plain.mcap'
    run = runs(scene, '--duration', '0.2', '--record', str(rec), '--live', '--port', '0', '--start-paused',
               '--rate-factor', '2')
    c = Client(run.url, subprotocol)
    assert c.subprotocol == subprotocol and c.info['op'] == 'serverInfo'
    assert {'time', 'clientPublish', 'services', 'parameters', 'assets'} <= set(c.info['capabilities'])
    assert c.info['supportedEncodings'] == ['cdr']
    _subscribe_paused_run(c, '/diagnostics')
    k = len(c.messages)                      # the state at t = 0: each channel's message, as subscribed
    assert response_fields(c.call('/robodyn/pause', set_bool_request(False)))[0]
    assert c.until_closed(120), 'the server did not close at the end of the run'
    assert run.wait() == 0, run.output()
    got = c.messages
    want = _recorded(rec)
    assert len(want) > 200 and len(got) == len(want)
    assert sorted(got[:k]) == sorted(want[:k]) and {t for _, t, _ in got[:k]} == {0}
    assert got[k:] == want[k:]               # then the same topics, same order, same log times, same bytes
    # every channel advertises the recording's schema
    schemas = {ch['topic']: ch for ch in c.channels.values()}
    for topic, info in summarize(rec)['topics'].items():
        assert schemas[topic]['schemaName'] == info['type'] and schemas[topic]['encoding'] == 'cdr'
        assert schemas[topic]['schemaEncoding'] == 'ros2msg'
    # a Time frame carries each new simulation time before the first message stamped with it
    now = None
    for kind, *x in c.order:
        if kind == 'time':
            now = x[0]
        else:
            assert x[1] == now, (x, now)
    # and the recording is the one a run without a viewer makes
    p = subprocess.run([sys.executable, '-m', 'robodyn_ros.cli', 'run', scene, '--duration', '0.2', '--record',
                        str(plain)], cwd=REPO, capture_output=True, text=True, timeout=300)
    assert p.returncode == 0, p.stderr
    assert rec.read_bytes() == plain.read_bytes()
    c.close()


def test_a_client_commands_the_robot_through_the_ports_checks(runs, tmp_path):
    # paused at t = 0: a command, then a NaN one (refused, counted, the last valid one stays), then resume
    rec = tmp_path / 'cmd.mcap'
    run = runs('stanford_arm', '--duration', '0.05', '--record', str(rec), '--live', '--port', '0',
               '--start-paused', '--rate-factor', '1', '--diagnostics-period', '0.01')
    c = Client(run.url, V1)
    _subscribe_paused_run(c, '/diagnostics')
    ch = c.advertise('/effort_commands', 'std_msgs/msg/Float64MultiArray')
    effort = [1.5, -2.0, 3.0, 0.5, -0.25, 0.125]
    c.publish(ch, cdr.encode('std_msgs/msg/Float64MultiArray', {'data': effort}))
    c.publish(ch, cdr.encode('std_msgs/msg/Float64MultiArray', {'data': [float('nan')] * 6}))
    wrong = c.advertise('/effort_commands', 'std_msgs/msg/String')   # not the port's type
    c.publish(wrong, cdr.encode('std_msgs/msg/String', {'data': 'x'}))
    assert c.pump_until(lambda: len([s for s in c.statuses if s['level'] == 2]) >= 2, 30), c.statuses
    assert response_fields(c.call('/robodyn/pause', set_bool_request(False)))[0]
    assert c.until_closed(60)
    assert run.wait() == 0, run.output()
    cmds = [(t, cdr.decode('std_msgs/msg/Float64MultiArray', d)['data']) for _, _, t, d in
            read_raw_messages(rec, topics=['/effort_commands'])]
    # the scene's scripted command at t = 0, then the client's, which holds: the script no longer writes it
    assert [t for t, _ in cmds] == [0, 0] and list(cmds[1][1]) == effort
    js = [cdr.decode('sensor_msgs/msg/JointState', d)
          for _, _, _, d in read_raw_messages(rec, topics=['/joint_states'])]
    assert len(js) == 6
    for m in js[1:]:
        assert list(m['effort']) == effort   # the applied effort of every period after t = 0
    diag = [cdr.decode('diagnostic_msgs/msg/DiagnosticArray', d) for _, _, _, d in
            read_raw_messages(rec, topics=['/diagnostics'])]
    rejected = [dict((kv['key'], kv['value']) for kv in m['status'][0]['values'])['rejected_commands'] for m in diag]
    assert rejected[0] == '0' and rejected[-1] == '2'   # the NaN and the wrong type, counted
    assert 'live command refused' in run.output() and '2 client commands refused' in run.output()
    c.close()


def test_reset_starts_again_at_t0_in_the_next_episode_file(runs, tmp_path):
    rec = tmp_path / 'ep.mcap'
    run = runs('betancur_pendulum', '--duration', '1.0', '--record', str(rec), '--live', '--port', '0',
               '--start-paused', '--rate-factor', '1')
    c = Client(run.url, SDK)
    _subscribe_paused_run(c, '/diagnostics')
    js = lambda: [t for topic, t, _ in c.messages if topic == '/joint_states']  # noqa: E731
    assert response_fields(c.call('/robodyn/pause', set_bool_request(False)))[0]
    assert c.pump_until(lambda: max(js()) >= 40_000_000, 60)
    assert response_fields(c.call('/robodyn/pause', set_bool_request(True)))[0]
    ok, message = response_fields(c.call('/robodyn/reset', trigger_request()))
    assert ok and 'ep-1.mcap' in message, message
    n = len(js())
    assert c.pump_until(lambda: len(js()) > n and js()[-1] == 0, 30)   # the initial state again
    assert 0 in c.times[c.times.index(max(c.times)):]                    # a Time frame back to 0 (a seek)
    assert response_fields(c.call('/robodyn/pause', set_bool_request(False)))[0]
    assert c.until_closed(60)
    assert run.wait() == 0, run.output()
    first = [t for topic, t, _ in _recorded(rec) if topic == '/joint_states']
    second = [t for topic, t, _ in _recorded(tmp_path / 'ep-1.mcap') if topic == '/joint_states']
    assert 40_000_000 <= first[-1] < 1_000_000_000 and second[0] == 0 and second[-1] == 1_000_000_000
    assert summarize(rec)['finished'] and summarize(tmp_path / 'ep-1.mcap')['finished']
    c.close()


def test_rate_factor_is_a_parameter(runs, tmp_path):
    run = runs('betancur_pendulum', '--duration', '0.05', '--live', '--port', '0', '--start-paused')
    c = Client(run.url, V1)
    c.send_json(op='getParameters', parameterNames=[], id='all')
    assert c.pump_until(lambda: any(p.get('id') == 'all' for p in c.parameter_values), 30)
    assert [p for p in c.parameter_values if p.get('id') == 'all'][0]['parameters'] == \
        [{'name': 'rate_factor', 'value': 1.0, 'type': 'float64'}]
    c.send_json(op='subscribeParameterUpdates', parameterNames=['rate_factor'])
    c.send_json(op='setParameters', parameters=[{'name': 'rate_factor', 'value': -1.0}], id='bad')
    c.send_json(op='setParameters', parameters=[{'name': 'rate_factor', 'value': 0.0}], id='max')
    assert c.pump_until(lambda: {p.get('id') for p in c.parameter_values} >= {'bad', 'max'}, 30)
    answer = {p.get('id'): p['parameters'][0]['value'] for p in c.parameter_values if p.get('id')}
    assert answer['bad'] == 1.0 and answer['max'] == 0.0     # refused (kept), then as fast as possible
    assert any(s['level'] == 2 and 'rate_factor' in s['message'] for s in c.statuses)
    assert any(p.get('id') is None and p['parameters'][0]['value'] == 0.0 for p in c.parameter_values)  # the update
    assert response_fields(c.call('/robodyn/pause', set_bool_request(False)))[0]
    assert c.until_closed(60) and run.wait() == 0
    c.close()


def test_a_client_that_stops_reading_changes_nothing_and_the_run_ends(runs, tmp_path):
    # as fast as possible, a client subscribed to everything that never reads again: the A1's 27 MB
    # robot_description alone fills the socket; its queue drops the oldest messages, the run goes on
    rec, plain = tmp_path / 'slow.mcap', tmp_path / 'plain.mcap'
    run = runs('a1_stand', '--duration', '2.0', '--record', str(rec), '--live', '--port', '0', '--start-paused',
               '--rate-factor', '0')
    c = Client(run.url, V1)
    assert c.pump_until(lambda: any(ch['topic'] == '/diagnostics' for ch in c.channels.values()), 60)
    c.subscribe()
    assert response_fields(c.call('/robodyn/pause', set_bool_request(False)))[0]
    # from here on the client reads nothing
    assert run.wait(timeout=300) == 0, run.output()
    assert 'messages dropped for slow clients' in run.output(), run.output()
    p = subprocess.run([sys.executable, '-m', 'robodyn_ros.cli', 'run', 'a1_stand', '--duration', '2.0', '--record',
                        str(plain)], cwd=REPO, capture_output=True, text=True, timeout=300)
    assert p.returncode == 0, p.stderr
    assert rec.read_bytes() == plain.read_bytes()
    c.close()


def test_a_port_in_use_is_refused_in_one_line_before_anything_runs(tmp_path):
    busy = socket.create_server(('127.0.0.1', 0))
    port = busy.getsockname()[1]
    try:
        rec = tmp_path / 'never.mcap'
        p = subprocess.run([sys.executable, '-m', 'robodyn_ros.cli', 'run', 'stanford_arm', '--live', '--port',
                            str(port), '--record', str(rec)], cwd=REPO, capture_output=True, text=True, timeout=300)
    finally:
        busy.close()
    assert p.returncode == 2
    lines = p.stderr.strip().splitlines()
    assert len(lines) == 1 and f'127.0.0.1:{port}' in lines[0] and 'in use' in lines[0], p.stderr
    assert 'Traceback' not in p.stderr and p.stdout == '' and not rec.exists()


def test_live_options_need_live(tmp_path):
    p = subprocess.run([sys.executable, '-m', 'robodyn_ros.cli', 'run', 'stanford_arm', '--rate-factor', '2'],
                       cwd=REPO, capture_output=True, text=True, timeout=300)
    assert p.returncode == 2 and p.stderr.strip() == 'robodyn run: --rate-factor only with --live'


@pytest.mark.parametrize('signame,said', [('SIGINT', 'Ctrl-C'), ('SIGTERM', 'SIGTERM')])
def test_ctrl_c_closes_the_server_and_keeps_the_recording(runs, tmp_path, signame, said):
    """Ctrl-C (or SIGTERM: a container stopped) ends a live run at the next period: exit 0 (a live run's
    ordinary end), the server closed, the recording finished with every period the client got."""
    rec = tmp_path / 'int.mcap'
    run = runs('stanford_arm', '--duration', '60', '--record', str(rec), '--live', '--port', '0', '--start-paused')
    c = Client(run.url, V1)
    _subscribe_paused_run(c, '/diagnostics')
    assert response_fields(c.call('/robodyn/pause', set_bool_request(False)))[0]
    js = lambda: [t for topic, t, _ in c.messages if topic == '/joint_states']  # noqa: E731
    assert c.pump_until(lambda: max(js()) >= 50_000_000, 60)
    os.killpg(run.p.pid, getattr(signal, signame))   # the run has streamed 0.05 s of simulation
    assert c.until_closed(60), 'the server did not close'
    assert run.wait() == 0, run.output()
    assert f'stopped by {said} at t=' in run.output() and 'Traceback' not in run.output()
    s = summarize(rec)
    assert s['finished'] and s['end_time_ns'] >= max(js())
    assert [m for m in c.messages if m[0] == '/joint_states'] == \
        [m for m in _recorded(rec) if m[0] == '/joint_states'][:len(js())]
    with pytest.raises(OSError):   # the port is closed
        socket.create_connection(tuple(re.match(r'ws://(.+):(\d+)', run.url).groups()), timeout=2)
    c.close()


def test_fetch_asset_answers_package_and_file_uris_and_refuses_others():
    # the server alone, in this process
    from robodyn_ros.assets import asset_file
    from robodyn_ros.live.server import LiveServer, bind
    server = LiveServer(bind('127.0.0.1', 0), 'test').start()
    try:
        c = Client(server.url, SDK)
        uri = 'package://example-robot-data/robots/a1_description/meshes/hip.dae'
        status, error, data = c.fetch_asset(uri)
        assert status == 0 and error == '' and data == asset_file(uri).read_bytes() and len(data) > 100_000
        path = asset_file(uri)
        assert c.fetch_asset(f'file://{path}')[2] == data and c.fetch_asset(str(path))[2] == data
        status, error, data = c.fetch_asset('package://no_such_package/mesh.stl')
        assert status == 1 and 'no_such_package' in error and data == b''
        status, error, _ = c.fetch_asset('https://example.com/x.stl')
        assert status == 1 and 'package://' in error
        c.close()
    finally:
        server.close()
