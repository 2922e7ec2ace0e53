"""The pd_hold_controller node standing A1 with a lockstep sim node (real rclpy, subprocesses): the
recording equals the headless ``robodyn run a1_stand`` byte for byte (the same law, the scene's
pd_hold profile, evaluated by the same kernel on the state joint_states carries)."""
import json
import os
import signal
import sys
import time

import pytest

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from ros_helpers import Domain, Proc, start_sim  # noqa: E402

from robodyn_ros.recording import decode, read_raw_messages, summarize  # noqa: E402

DURATION = 0.3   # s: the drop (0.14 s) and the first landing; 60 periods at 200 Hz


@pytest.fixture(scope='module')
def a1_lockstep(tmp_path_factory):
    tmp = tmp_path_factory.mktemp('a1')
    dom = Domain()
    rec = tmp / 'node.mcap'
    node = start_sim(dom, {'scene': 'a1_stand', 'mode': 'lockstep', 'record': str(rec), 'scripted_commands': False,
                           'duration': DURATION}, tmp / 'node.log')
    ctl = Proc([sys.executable, '-m', 'robodyn_ros.nodes.pd_hold_controller', '--ros-args', '-p', 'scene:=a1_stand',
                '-p', f'result:={tmp / "ctl.json"}', '-p', 'timeout:=150.0'], dom.env(), tmp / 'ctl.log')
    try:
        ctl_rc = ctl.wait(timeout=170)
        node_rc = node.wait(timeout=30) if node.alive() else node.poll()
        time.sleep(0.1)
        yield {'record': rec, 'tmp': tmp, 'ctl_rc': ctl_rc, 'node_rc': node_rc, 'ctl_log': ctl.output(),
               'node_log': node.output(),
               'result': json.loads((tmp / 'ctl.json').read_text()) if (tmp / 'ctl.json').exists() else None}
    finally:
        if node.alive():
            node.stop(signal.SIGINT)
        ctl.cleanup()
        node.cleanup()
        dom.release()


def test_pd_hold_node_recording_equals_headless_run(a1_lockstep):
    from robodyn_ros.cli import main as robodyn
    r = a1_lockstep
    assert r['ctl_rc'] == 0, r['ctl_log'] + r['node_log']
    assert r['node_rc'] == 0, r['node_log']
    n = int(round(DURATION * 200))
    assert r['result']['sent'] in (n, n + 1), r['result']   # the last state's answer may come after the end
    rec = r['record']
    settings = json.loads(summarize(rec)['metadata']['robodyn']['settings'])
    out = r['tmp'] / 'headless.mcap'
    assert robodyn(['run', 'a1_stand', '--duration', str(DURATION), '--record', str(out),
                    '--backend', settings['backend']]) == 0
    topics = ('/joint_states', '/odom', '/effort_commands', '/contact_wrenches/FR_foot', '/tf')
    for topic in topics:
        a = [(t, raw) for _, _, t, raw in read_raw_messages(rec, topics=[topic])]
        b = [(t, raw) for _, _, t, raw in read_raw_messages(out, topics=[topic])]
        if topic == '/effort_commands':   # the node also records the answer to its last state, if it came in time
            assert len(b) == n and len(a) in (n, n + 1), (len(a), len(b))
            a = a[:n]
        assert len(a) == len(b) == (n if topic == '/effort_commands' else n + 1), (topic, len(a))
        if topic != '/joint_states':
            assert a == b, topic
            continue
        assert a[1:] == b[1:], topic   # at t = 0 the node has received no command yet (effort 0)
        m_node, m_head = (decode('sensor_msgs/msg/JointState', x[0][1]) for x in (a, b))
        for field in ('name', 'position', 'velocity'):
            assert list(m_node[field]) == list(m_head[field]), field
    # the feet have landed within the run: the recorded contact wrench carries weight
    fz = [decode('geometry_msgs/msg/WrenchStamped', raw)['wrench']['force']['z']
          for _, _, _, raw in read_raw_messages(rec, topics=['/contact_wrenches/FR_foot'])]
    assert fz[0] == 0.0 and max(fz) > 10.0
