"""The sim node on huston_human17 (54 DOF, spherical joints, free pelvis), lockstep, checked from its recording.

The node runs as a subprocess in a private ROS domain; this process sends the shoulder torques
(one ``effort_commands`` message per lockstep period: the scene's abduction push, then zero).
The MCAP is then read by the independent readers (``mcap_ros2`` and ``rosbags``), and from the
recorded messages alone — ``robot_description`` loaded by Pinocchio with its own free-flyer root,
``odom`` for the pelvis, ``joint_states`` for the 48 Bryan angles (the URDF's three revolute joints
per spherical joint) and the child-frame angular velocities (converted to Bryan-angle rates here) —
the linear and angular momentum are rebuilt and must stay constant (joint torques are internal).
"""
import os
import signal
import sys
from pathlib import Path

import numpy as np
import pinocchio as pin
import pytest

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from ros_helpers import Domain, RosClient, lockstep_step, start_sim  # noqa: E402
from test_node_freeflyer import _read  # noqa: E402  (mcap + mcap_ros2 decoder: topic -> [(t, msg)])
from pin_helpers import centroidal_momenta  # noqa: E402

pytestmark = pytest.mark.processes   # a lockstep node subprocess driven from here, SIGINT

PERIODS = 80                # 0.8 s at the scene's 100 Hz
PUSH = [3.0, 0.0, 0.0, -3.0, 0.0, 0.0]   # both arms abducted (the scene's first command)
PUSH_PERIODS = 50


@pytest.fixture(scope='module')
def run(tmp_path_factory):
    from sensor_msgs.msg import JointState
    from std_msgs.msg import Float64MultiArray
    tmp = tmp_path_factory.mktemp('human17')
    rec = tmp / 'human17.mcap'
    dom = Domain()
    node = start_sim(dom, {'scene': 'huston_human17', 'mode': 'lockstep', 'record': str(rec)}, tmp / 'node.log')
    client = RosClient(dom)
    try:
        states = []
        client.node.create_subscription(JointState, 'joint_states', states.append, 100)
        eff = client.node.create_publisher(Float64MultiArray, 'effort_commands', 10)
        ok = client.spin_until(lambda: states and eff.get_subscription_count(), 90, node)
        assert ok, node.output()
        for k in range(PERIODS):
            lockstep_step(client, eff, Float64MultiArray(data=PUSH if k < PUSH_PERIODS else [0.0] * 6), states, node)
        rc = node.stop(signal.SIGINT)
        yield {'record': rec, 'rc': rc, 'log': node.output(), 'live': states}
    finally:
        client.close()
        node.cleanup()
        dom.release()


def test_recording_complete_and_read_by_rosbags(run):
    from rosbags.highlevel import AnyReader
    assert run['rc'] == 0, run['log']
    msgs = _read(run['record'])
    assert len(msgs['/joint_states']) == PERIODS + 1 and len(msgs['/odom']) == PERIODS + 1
    assert len(msgs['/effort_commands']) == PERIODS
    js = msgs['/joint_states'][-1][1]
    assert len(js.name) == 48 and 'left_shoulder_x' in js.name and 'right_knee_z' in js.name
    odom = msgs['/odom'][0][1]
    assert odom.header.frame_id == 'odom' and odom.child_frame_id == 'lower_torso'
    children = {t.child_frame_id for _, m in msgs['/tf'] for t in m.transforms}
    assert {'lower_torso', 'head', 'left_hand', 'right_foot', 'left_shoulder_x_link'} <= children
    n = sum(len(v) for v in msgs.values())
    with AnyReader([Path(run['record'])]) as reader:
        decoded = [reader.deserialize(raw, c.msgtype) for c, _, raw in reader.messages()]
    assert len(decoded) == n


def test_momentum_constant_from_recorded_messages_alone(run):
    msgs = _read(run['record'])
    urdf = msgs['/robot_description'][0][1].data
    pm = pin.buildModelFromXML(urdf, pin.JointModelFreeFlyer())
    assert pm.nq == 7 + 48
    ps, Ls, positions = centroidal_momenta(pm, msgs)
    moved = [pos['left_shoulder_x'] for pos in positions]
    dp = np.linalg.norm(ps - ps[0], axis=1).max() / np.linalg.norm(ps[0])
    dL = np.linalg.norm(Ls - Ls[0], axis=1).max() / np.linalg.norm(Ls[0])
    print(f'from messages: |dp|/|p| {dp:.1e}, |dL|/|L| {dL:.1e}')
    assert np.linalg.norm(ps[0]) > 10 and np.linalg.norm(Ls[0]) > 10
    assert dp < 1e-6 and dL < 7e-8     # RK4 at 1 ms with the stops: measured 1.2e-8, 6.8e-10
    assert max(moved) > 1.0            # the left arm was swung up
