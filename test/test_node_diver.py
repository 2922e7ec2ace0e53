"""The diver_controller node closing the loop with a lockstep sim node (real rclpy, subprocesses):
the recording equals the headless ``robodyn run`` of the same scene byte for byte."""
import json
import os
import signal
import sys

import pytest

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from ros_helpers import Domain, Proc, start_sim  # noqa: E402

from robodyn_ros.recording import decode, read_raw_messages, summarize  # noqa: E402

pytestmark = pytest.mark.processes   # a lockstep node and a controller node in subprocesses


@pytest.fixture(scope='module')
def diver_lockstep(tmp_path_factory):
    tmp = tmp_path_factory.mktemp('diver')
    dom = Domain()
    rec = tmp / 'node.mcap'
    node = start_sim(dom, {'scene': 'diver_tuck', 'mode': 'lockstep', 'record': str(rec)}, tmp / 'node.log')
    ctl = Proc([sys.executable, '-m', 'robodyn_ros.nodes.diver_controller', '--ros-args', '-p', 'scene:=diver_tuck',
                '-p', f'result:={tmp / "ctl.json"}', '-p', 'timeout:=150.0'], dom.env(), tmp / 'ctl.log')
    try:
        ctl_rc = ctl.wait(timeout=170)
        node_rc = node.wait(timeout=60) if node.alive() else node.poll()
        yield {'record': rec, 'tmp': tmp, 'ctl_rc': ctl_rc, 'node_rc': node_rc, 'ctl_log': ctl.output(),
               'node_log': node.output(),
               'result': json.loads((tmp / 'ctl.json').read_text()) if (tmp / 'ctl.json').exists() else None}
    finally:
        if node.alive():
            node.stop(signal.SIGINT)
        ctl.cleanup()
        node.cleanup()
        dom.release()


def test_controller_node_runs_the_dive_to_the_entry(diver_lockstep):
    r = diver_lockstep
    assert r['ctl_rc'] == 0, r['ctl_log'] + r['node_log']
    assert r['node_rc'] == 0, r['node_log']            # the sim stopped by itself at the entry
    # 183 commands (t = 0 ... 1.82 s); the controller saw the entry state (t = 1.83 s), or the sim
    # leaving right after publishing it
    assert r['result']['sent'] == 183 and r['result']['done']
    assert r['result']['last_ns'] in (1_820_000_000, 1_830_000_000)
    assert r['result']['turns'] == pytest.approx(2.5, abs=1e-2)
    assert 'rotation' in r['node_log'] and '2.5000 turns' in r['node_log']


def test_lockstep_recording_equals_headless_run_byte_for_byte(diver_lockstep):
    from robodyn_ros.cli import main as robodyn
    rec = diver_lockstep['record']
    settings = json.loads(summarize(rec)['metadata']['robodyn']['settings'])
    out = diver_lockstep['tmp'] / 'headless.mcap'
    assert robodyn(['run', 'diver_tuck', '--record', str(out), '--backend', settings['backend']]) == 0
    for topic in ('/joint_states', '/odom', '/effort_commands', '/tf'):
        a = [(t, raw) for _, _, t, raw in read_raw_messages(rec, topics=[topic])]
        b = [(t, raw) for _, _, t, raw in read_raw_messages(out, topics=[topic])]
        assert len(a) == (183 if topic == '/effort_commands' else 184), topic
        if topic != '/joint_states':
            assert a == b, topic
            continue
        # joint_states effort = the command held over the period ending at the stamp; at t = 0 the
        # command applied from t = 0 on as far as it is known when published: the headless run's
        # profile knows it (its first command), the lockstep node has received nothing yet (zero).
        assert a[1:] == b[1:], topic
        m_node, m_head = decode('sensor_msgs/msg/JointState', a[0][1]), decode('sensor_msgs/msg/JointState', b[0][1])
        assert a[0][0] == b[0][0] == 0
        for field in ('name', 'position', 'velocity'):
            assert list(m_node[field]) == list(m_head[field]), field
        first = [decode(ty, raw)['data'] for _, ty, _, raw in read_raw_messages(out, topics=['/effort_commands'])][0]
        assert list(m_node['effort']) == [0.0] * len(first)
        assert list(m_head['effort']) == list(first) and any(e != 0.0 for e in first)
