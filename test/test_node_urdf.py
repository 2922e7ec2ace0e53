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

pytestmark = pytest.mark.processes   # node subprocesses: lockstep runs, refusals

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
    # its own meshes, carried in the recording (data: URIs; the ROS topic keeps the package:// references)
    assert len(desc) == 1 and 'shoulder_pan_joint' in desc[0] and '<mesh filename="data:model/' in desc[0]
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
    robot_description, simulates it, and does not publish a description of its own. Lockstep:
    the node waits for this process (its initial state is resent until the first command), so
    nothing depends on how fast discovery is; it ends by itself after its two periods."""
    from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
    from sensor_msgs.msg import JointState
    from std_msgs.msg import Float64MultiArray, String

    from ros_helpers import Domain, RosClient, start_sim
    dom = Domain()
    client = RosClient(dom)
    node = None
    try:
        latched = QoSProfile(depth=1, durability=DurabilityPolicy.TRANSIENT_LOCAL,
                             reliability=ReliabilityPolicy.RELIABLE)
        pub = client.node.create_publisher(String, 'robot_description', latched)
        pub.publish(String(data=open(UR5).read()))
        states = []
        client.node.create_subscription(JointState, 'joint_states', states.append, 100)
        cmd = client.node.create_publisher(Float64MultiArray, 'effort_commands', 10)
        node = start_sim(dom, {'scene': '', 'mode': 'lockstep', 'duration': 0.02, 'robot_description_timeout': 120.0},
                         tmp_path / 'node.log')
        assert client.spin_until(lambda: states and cmd.get_subscription_count(), 120, node), node.output()
        assert list(states[-1].name)[:2] == ['shoulder_pan_joint', 'shoulder_lift_joint']
        assert client.node.count_publishers('robot_description') == 1  # the test's: the node adds none
        for k in (1, 2):
            cmd.publish(Float64MultiArray(data=[0.0] * 6))
            assert client.spin_until(lambda: states[-1].header.stamp.nanosec == k * 10_000_000, 60, node), \
                node.output()
        assert node.wait(timeout=60) == 0, node.output()
    finally:
        client.close()
        if node is not None:
            node.cleanup()
        dom.release()


def _one_line_refusal(log: str, reason: str):
    """The node's whole output is one line ``sim: ...`` naming ``reason``: no traceback, no log noise."""
    lines = [ln for ln in log.splitlines() if ln.strip()]
    assert 'Traceback' not in log and len(lines) == 1, log
    assert lines[0].startswith('sim: ') and reason in lines[0], log


_MINI = ('<robot name="mini"><link name="a"/><link name="b"><inertial><mass value="1"/>'
         '<inertia ixx="0.1" iyy="0.1" izz="0.1" ixy="0" ixz="0" iyz="0"/></inertial></link>'
         '<joint name="j" type="revolute"><parent link="a"/><child link="b"/><axis xyz="0 0 1"/></joint></robot>')
#: (file name, its text or None for no file, what the one-line error says)
BAD_FILES = [
    ('missing.urdf', None, 'no such URDF file'),
    ('broken.urdf', _MINI[:-len('</robot>')], 'not well-formed XML'),
    ('empty.urdf', '', 'not well-formed XML'),
    ('loop.urdf', _MINI.replace('</robot>', '<joint name="k" type="revolute"><parent link="b"/><child link="a"/>'
                                            '<axis xyz="0 0 1"/></joint></robot>'), 'form a loop'),
    ('robot.xml', _MINI, "must be the path of a .urdf file"),
]


@pytest.mark.parametrize('name, text, reason', BAD_FILES, ids=[b[0] for b in BAD_FILES])
def test_node_refuses_a_bad_robot_description_file_in_one_line(tmp_path, name, text, reason):
    """A missing or malformed robot_description_file: one line naming the file and the reason, exit 2."""
    from ros_helpers import run_sim_to_end
    path = tmp_path / name
    if text is not None:
        path.write_text(text)
    rc, log = run_sim_to_end({'robot_description_file': str(path)}, tmp_path / 'node.log')
    assert rc == 2, log
    _one_line_refusal(log, reason)
    if name.endswith('.urdf'):
        assert str(path) in log


BAD_DESCRIPTIONS = [
    ('broken XML', _MINI[:-len('</robot>')], 'not well-formed XML'),
    ('not XML', 'hello', 'not well-formed XML'),
    ('no links', '<robot name="r"></robot>', "no <link>"),
    ('planar joint', _MINI.replace('type="revolute"', 'type="planar"'), 'planar joints are not supported'),
]


@pytest.mark.parametrize('text, reason', [b[1:] for b in BAD_DESCRIPTIONS], ids=[b[0] for b in BAD_DESCRIPTIONS])
def test_node_refuses_a_malformed_robot_description_in_one_line(tmp_path, text, reason):
    """scene:='' and a malformed URDF latched on robot_description: one line, exit 2."""
    from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
    from std_msgs.msg import String

    from ros_helpers import Domain, RosClient, start_sim
    dom = Domain()
    client = RosClient(dom)
    node = None
    try:
        latched = QoSProfile(depth=1, durability=DurabilityPolicy.TRANSIENT_LOCAL,
                             reliability=ReliabilityPolicy.RELIABLE)
        client.node.create_publisher(String, 'robot_description', latched).publish(String(data=text))
        node = start_sim(dom, {'scene': '', 'robot_description_timeout': 120.0}, tmp_path / 'node.log')
        assert client.spin_until(lambda: node.poll() is not None, 150), node.output()   # answers discovery meanwhile
        rc = node.wait(timeout=10)
    finally:
        client.close()
        if node is not None:
            node.cleanup()
        dom.release()
    log = node.output()
    assert rc == 2, log
    _one_line_refusal(log, 'the URDF on robot_description cannot be simulated')
    assert reason in log, log


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


FLOAT_PERIODS = 30


def test_floating_urdf_through_the_node_in_lockstep(tmp_path):
    """solo12 (example-robot-data) with its floating base written into the URDF (a massless world link
    and a floating joint), as ``robot_description_file``, driven in lockstep by this process (12 joint
    torques per period): joint_states and odom come back each period, the base falls freely, and the
    recording equals the headless run of the same scene fed the same commands byte for byte (and
    ``robodyn resim`` reproduces it)."""
    import signal

    from nav_msgs.msg import Odometry
    from sensor_msgs.msg import JointState
    from std_msgs.msg import Float64MultiArray

    from ros_helpers import Domain, RosClient, assert_lockstep_recording_reproduced, lockstep_step, start_sim
    solo = example_robot_data_dir() / 'solo_description/robots/solo12.urdf'
    path = tmp_path / 'solo12_floating.urdf'
    path.write_text(solo.read_text().replace(
        '</robot>', '<link name="world"/><joint name="root_joint" type="floating"><parent link="world"/>'
                    '<child link="base_link"/></joint></robot>'))
    rec = tmp_path / 'solo.mcap'
    dom = Domain()
    node = start_sim(dom, {'robot_description_file': str(path), 'mode': 'lockstep', 'record': str(rec)},
                     tmp_path / 'node.log')
    client = RosClient(dom)
    try:
        states, odom = [], []
        client.node.create_subscription(JointState, 'joint_states', states.append, 100)
        client.node.create_subscription(Odometry, 'odom', odom.append, 100)
        eff = client.node.create_publisher(Float64MultiArray, 'effort_commands', 10)
        assert client.spin_until(lambda: states and odom and eff.get_subscription_count(), 120, node), node.output()
        for k in range(FLOAT_PERIODS):
            lockstep_step(client, eff, Float64MultiArray(data=(0.2 * np.sin(0.3 * k + np.arange(12))).tolist()),
                          states, node, also=[odom])
        rc = node.stop(signal.SIGINT)
    finally:
        client.close()
        node.cleanup()
        dom.release()
    assert rc == 0, node.output()
    assert len(states[-1].name) == 12 and states[-1].header.stamp.nanosec == FLOAT_PERIODS * 10_000_000
    assert odom[-1].child_frame_id == 'base_link' and odom[-1].header.stamp == states[-1].header.stamp
    t = FLOAT_PERIODS * 0.01   # no contact: the base's height follows free fall (internal torques only)
    z0, z1 = odom[0].pose.pose.position.z, odom[-1].pose.pose.position.z
    assert abs(z0) < 1e-12 and 0.2 * 9.81 * t * t < z0 - z1 < 2.0 * 9.81 * t * t, (z0, z1)
    assert_lockstep_recording_reproduced(rec, tmp_path, FLOAT_PERIODS, scene_path=str(path))
