"""Position-commanded joints through the sim node (real rclpy; the node in a subprocess, the controller in
this process): a lockstep run driven by ``joint_trajectory`` (the same stamped trajectory sent every period,
as a controller republishes it) records the states, desired and error messages of the headless run with
the trajectory as a scripted profile byte for byte; a bad trajectory sent in between is refused with its
reason in the log and counted, and nothing of the run is lost; ``command_joint_names`` is latched with the
joints of each command topic in their order."""
import json
import os
import sys
import time

import pytest

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from ros_helpers import Domain, start_sim  # noqa: E402

from robodyn_ros.nodes.probe import Probe  # noqa: E402
from robodyn_ros.recording import decode, read_raw_messages, summarize  # noqa: E402

pytestmark = pytest.mark.processes

PERIODS = 60            # 0.6 s at 100 Hz
BAD_AT = 20             # the period whose message is a bad trajectory (refused: the period still runs)
POINTS = [{'time_from_start': 0.0, 'positions': [0.0, 0.0], 'velocities': [0.0, 0.0]},
          {'time_from_start': 0.3, 'positions': [0.4, -0.3], 'velocities': [0.5, 0.0], 'accelerations': [0.0, 0.0]},
          {'time_from_start': 0.7, 'positions': [0.6, -0.1], 'velocities': [0.0, 0.0], 'accelerations': [0.0, 0.0]}]
STAMP = 0.01            # absolute: the same message re-sent is the same trajectory (its last point, due at 0.71 s,
                        # is after the run: the controller would refuse a trajectory that ends in the past)


def _scene_text(scripted: bool) -> str:
    head = ('name: two_link_trajectory\nparts:\n  - kind: arm\n    name: arm\n    links:\n'
            '      - {name: l1, joint: j1, parent: base_link, type: revolute, axis: [0, 1, 0], mass: 1.0,\n'
            '         com: [0.5, 0, 0], inertia: [[0.01, 0, 0], [0, 0.01, 0], [0, 0, 0.01]], damping: 0.1}\n'
            '      - {name: l2, joint: j2, parent: l1, type: revolute, axis: [0, 1, 0], origin: {xyz: [1, 0, 0]},\n'
            '         mass: 0.5, com: [0.3, 0, 0], inertia: [[0.01, 0, 0], [0, 0.01, 0], [0, 0, 0.01]]}\n'
            '    command_interfaces: position\n    servo: {kp: 400.0, kd: 40.0}\n'
            'simulation: {integrator: rk4, dt: 1.0e-3}\n')
    if not scripted:
        return head
    pts = ',\n'.join('      ' + json.dumps(p) for p in POINTS)
    return head + f'commands:\n  trajectory:\n    profile: trajectory\n    stamp: {STAMP}\n    points: [\n{pts}]\n'


def _message(bad=False):
    from builtin_interfaces.msg import Duration, Time
    from trajectory_msgs.msg import JointTrajectory, JointTrajectoryPoint
    msg = JointTrajectory()
    msg.header.stamp = Time(sec=0, nanosec=int(round(STAMP * 1e9)))
    msg.joint_names = ['j1', 'j1'] if bad else ['j1', 'j2']
    for p in POINTS:
        pt = JointTrajectoryPoint()
        pt.positions = [float(x) for x in p['positions']]
        pt.velocities = [float(x) for x in p.get('velocities', [])]
        pt.accelerations = [float(x) for x in p.get('accelerations', [])]
        sec = int(p['time_from_start'])
        pt.time_from_start = Duration(sec=sec, nanosec=int(round((p['time_from_start'] - sec) * 1e9)))
        msg.points.append(pt)
    return msg


@pytest.fixture(scope='module')
def lockstep(tmp_path_factory):
    from sensor_msgs.msg import JointState
    from std_msgs.msg import String
    from trajectory_msgs.msg import JointTrajectory
    tmp = tmp_path_factory.mktemp('control')
    scene = tmp / 'two_link.yaml'
    scene.write_text(_scene_text(False))
    dom = Domain()
    rec = tmp / 'node.mcap'
    node = start_sim(dom, {'scene': str(scene), 'mode': 'lockstep', 'record': str(rec), 'duration': PERIODS / 100.0,
                           'diagnostics_period': 0.1}, tmp / 'node.log')
    probe = Probe(dom)
    try:
        got, names = [], []
        probe.node.create_subscription(JointState, 'joint_states', lambda m: got.append(
            (m.header.stamp.sec, m.header.stamp.nanosec)), 10)
        from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
        latched = QoSProfile(depth=1, durability=DurabilityPolicy.TRANSIENT_LOCAL, reliability=ReliabilityPolicy.RELIABLE)
        probe.node.create_subscription(String, 'command_joint_names', lambda m: names.append(m.data), latched)
        pub = probe.node.create_publisher(JointTrajectory, 'joint_trajectory', 10)
        assert probe.spin_until(lambda: got and pub.get_subscription_count() and names, 120, node.p), node.output()
        for k in range(PERIODS):
            last = got[-1]
            pub.publish(_message(bad=k == BAD_AT))
            assert probe.spin_until(lambda: got[-1] != last, 60, node.p), node.output()
        rc = node.wait(timeout=60)
        time.sleep(0.1)
        yield {'record': rec, 'tmp': tmp, 'rc': rc, 'log': node.output(), 'names': names}
    finally:
        probe.close()
        node.cleanup()
        dom.release()


def test_lockstep_trajectory_run_equals_the_headless_scripted_run_byte_for_byte(lockstep):
    from robodyn_ros.cli import main as robodyn
    r = lockstep
    assert r['rc'] == 0, r['log']
    settings = json.loads(summarize(r['record'])['metadata']['robodyn']['settings'])
    scripted = r['tmp'] / 'scripted.yaml'
    scripted.write_text(_scene_text(True))
    out = r['tmp'] / 'headless.mcap'
    assert robodyn(['run', str(scripted), '--duration', str(PERIODS / 100.0), '--record', str(out),
                    '--backend', settings['backend']]) == 0
    for topic in ('/joint_states', '/joint_trajectory_desired', '/joint_trajectory_error', '/tf'):
        a = [(t, raw) for _, _, t, raw in read_raw_messages(r['record'], topics=[topic])]
        b = [(t, raw) for _, _, t, raw in read_raw_messages(out, topics=[topic])]
        assert len(a) == len(b) == PERIODS + 1, (topic, len(a), len(b))
        # at t = 0 the node has no trajectory yet (the scripted run sets it before publishing t0)
        assert a[1:] == b[1:], topic
    js = decode('sensor_msgs/msg/JointState', [raw for *_, raw in read_raw_messages(out, topics=['/joint_states'])][-1])
    assert 0.45 < js['position'][0] < 0.6   # on its way from the second point to the third
    a = [raw for *_, raw in read_raw_messages(r['record'], topics=['/joint_trajectory'])]
    b = [raw for *_, raw in read_raw_messages(out, topics=['/joint_trajectory'])]
    assert len(a) == PERIODS - 1 and len(b) == 1 and a[0] == b[0]   # every accepted message, as received
    c = [raw for *_, raw in read_raw_messages(r['record'], topics=['/command_joint_names'])]
    assert c == [raw for *_, raw in read_raw_messages(out, topics=['/command_joint_names'])] and len(c) == 1


def test_a_bad_trajectory_is_refused_with_its_reason_and_counted(lockstep):
    r = lockstep
    assert 'command rejected (1 so far), last valid command stays: trajectory: duplicate joint names' in r['log'], \
        r['log']
    diags = [decode('diagnostic_msgs/msg/DiagnosticArray', raw)
             for *_, raw in read_raw_messages(r['record'], topics=['/diagnostics'])]
    last = {kv['key']: kv['value'] for kv in diags[-1]['status'][0]['values']}
    assert last['rejected_commands'] == '1'


def test_command_joint_names_are_latched_and_logged(lockstep):
    r = lockstep
    assert r['names'] == ['position_commands: [j1, j2]\njoint_trajectory: [j1, j2]'], r['names']
    assert 'position_commands: [j1, j2]' in r['log']
