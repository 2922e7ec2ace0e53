"""The pd_hold_controller node standing A1 with a lockstep sim node (real rclpy, subprocesses): the
recording equals the headless ``robodyn run a1_stand`` byte for byte (the same law, the scene's
pd_hold profile, evaluated by the same kernel on the state joint_states carries).

What is compared, over the drop, the landing and the first second of standing (DURATION; the
scene runs 5 s): every topic of both recordings (the same set), message for message, stamps and
bytes, joint_states at t = 0 included (A1 starts at the posture at rest, so the headless run's first
command is zero too: the node's "no command yet" is the same message), except that the node may
record one more effort command (the answer to its last state), and /diagnostics is left out (its
real-time factor is the wall clock's, and its period is each interface's own setting)."""
import json
import os
import signal
import sys
import time

import pytest

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from ros_helpers import Domain, Proc, start_sim  # noqa: E402

from robodyn_ros.recording import decode, read_raw_messages, summarize  # noqa: E402

DURATION = 1.0   # s: the drop (0.14 s), the landing and standing; 200 periods at 200 Hz


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
    topics = set(summarize(out)['topics'])
    assert set(summarize(rec)['topics']) == topics
    # every topic but /diagnostics (its real-time factor is the wall clock's) message for message
    compared = sorted(topics - {'/diagnostics'})
    assert len(compared) == 40 and {'/joint_states', '/odom', '/effort_commands', '/tf', '/tf_static', '/clock',
                                    '/markers', '/robot_description', '/contact_wrenches/FR_foot'} <= set(compared), \
        compared
    for topic in compared:
        a = [(t, raw) for _, _, t, raw in read_raw_messages(rec, topics=[topic])]
        b = [(t, raw) for _, _, t, raw in read_raw_messages(out, topics=[topic])]
        if topic == '/effort_commands':   # the node also records the answer to its last state, if it came in time
            assert len(b) == n and len(a) in (n, n + 1), (len(a), len(b))
            a = a[:n]
        assert len(a) == len(b) and len(b) >= 1, (topic, len(a), len(b))
        assert a == b, topic
    # the feet have landed within the run: the recorded contact wrench carries weight
    fz = [decode('geometry_msgs/msg/WrenchStamped', raw)['wrench']['force']['z']
          for _, _, _, raw in read_raw_messages(rec, topics=['/contact_wrenches/FR_foot'])]
    assert fz[0] == 0.0 and max(fz) > 10.0
