"""The sim node on a robot no one here wrote: UR5 from example-robot-data through
``robot_description_file``, closed in lockstep by the PD controller process; and the CLI on a URDF."""
from __future__ import annotations

import os
import subprocess
import sys

import numpy as np
import pytest

sys.path.insert(0, os.path.dirname(__file__))
from ros_helpers import lockstep_pd_run  # noqa: E402

from robodyn_ros.recording import read_messages, summarize  # noqa: E402
from robodyn_ros.urdf import example_robot_data_dir  # noqa: E402

UR5 = str(example_robot_data_dir() / 'ur_description/urdf/ur5_robot.urdf')
SETPOINT = [0.3, -0.5, 0.4, -0.3, 0.2, 0.1]
PERIODS = 150


@pytest.fixture(scope='module')
def ur5_lockstep(tmp_path_factory):
    yield from lockstep_pd_run(tmp_path_factory.mktemp('ur5'), {'robot_description_file': UR5}, SETPOINT, PERIODS,
                               timeout=120, scene=UR5)


def test_ur5_node_in_lockstep_reaches_setpoint_and_records_its_urdf(ur5_lockstep):
    r = ur5_lockstep
    assert r['pd_rc'] == 0, r['pd_log'] + r['node_log']
    assert r['pd']['sent'] == PERIODS and r['pd']['stamp'] == [1, 500000000]
    np.testing.assert_allclose(r['pd']['q'], SETPOINT, atol=2e-3)
    assert r['node_rc'] == 0, r['node_log']
    s = summarize(r['record'])
    assert s['topics']['/joint_states']['count'] == PERIODS + 1
    desc = [m.data for *_, m in read_messages(r['record'], topics=['/robot_description'])]
    assert len(desc) == 1 and 'shoulder_pan_joint' in desc[0] and 'package://' in desc[0]  # its own meshes
    js = [m for *_, m in read_messages(r['record'], topics=['/joint_states'])]
    assert list(js[-1].name) == ['shoulder_pan_joint', 'shoulder_lift_joint', 'elbow_joint', 'wrist_1_joint',
                                 'wrist_2_joint', 'wrist_3_joint']
    lim = np.array([150.0, 150.0, 150.0, 28.0, 28.0, 28.0])  # the URDF's <limit effort>
    assert all(np.all(np.abs(m.effort) <= lim) for m in js)


def test_cli_runs_a_urdf_file_and_lists_how(tmp_path):
    out = tmp_path / 'ur5.mcap'
    cmd = [sys.executable, '-m', 'robodyn_ros.cli']
    p = subprocess.run(cmd + ['run', UR5, '--duration', '0.2', '--record', str(out)], capture_output=True, text=True,
                       timeout=240)
    assert p.returncode == 0, p.stderr
    assert summarize(out)['topics']['/joint_states']['count'] == 21
    p = subprocess.run(cmd + ['scenes'], capture_output=True, text=True, timeout=60)
    assert 'robot_description_file:=robot.urdf' in p.stdout and 'robodyn run robot.urdf' in p.stdout


def test_cli_summary_counts_clamped_efforts(tmp_path):
    from test_urdf import _LIMITED_ARM
    (tmp_path / 'limited.yaml').write_text(_LIMITED_ARM)
    p = subprocess.run([sys.executable, '-m', 'robodyn_ros.cli', 'run', str(tmp_path / 'limited.yaml'), '--duration',
                        '0.5'], capture_output=True, text=True, timeout=240)
    assert p.returncode == 0, p.stderr
    assert 'limits       50 effort command components clamped to the effort limits' in p.stdout  # 50 periods, j1


def test_node_with_empty_scene_simulates_the_urdf_on_robot_description(tmp_path):
    """scene:='' and no file: the node takes the URDF a robot_state_publisher would latch on
    robot_description, simulates it, and does not publish a description of its own."""
    from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
    from sensor_msgs.msg import JointState
    from std_msgs.msg import String

    from ros_helpers import Domain, RosClient, start_sim
    dom = Domain()
    client = RosClient(dom)
    node = None
    try:
        latched = QoSProfile(depth=1, durability=DurabilityPolicy.TRANSIENT_LOCAL,
                             reliability=ReliabilityPolicy.RELIABLE)
        pub = client.node.create_publisher(String, 'robot_description', latched)
        pub.publish(String(data=open(UR5).read()))
        node = start_sim(dom, {'scene': '', 'mode': 'max', 'duration': 0.5}, tmp_path / 'node.log')
        states = []
        client.node.create_subscription(JointState, 'joint_states', states.append, 100)
        assert client.spin_until(lambda: states, 60, node), node.output()
        assert list(states[-1].name)[:2] == ['shoulder_pan_joint', 'shoulder_lift_joint']
        assert client.node.count_publishers('robot_description') == 1  # the test's: the node adds none
        assert node.wait(timeout=60) == 0, node.output()
    finally:
        client.close()
        if node is not None:
            node.cleanup()
        dom.release()


def test_node_with_empty_scene_and_no_description_says_so(tmp_path):
    from ros_helpers import Domain, start_sim
    dom = Domain()
    node = start_sim(dom, {'scene': '', 'robot_description_timeout': 1.0}, tmp_path / 'node.log')
    try:
        assert node.wait(timeout=60) != 0
        assert 'no URDF arrived on robot_description within 1 s' in node.output(), node.output()
    finally:
        node.cleanup()
        dom.release()
