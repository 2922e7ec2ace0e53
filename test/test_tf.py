"""TF (``/tf``, ``/tf_static``): the tree equals the URDF, the transforms equal the dynamics'
forward kinematics, the bundled tf2_msgs/TFMessage definition, and the recordings that carry it."""
import json
import os
import xml.etree.ElementTree as ET

import numpy as np
import pytest

from robodyn_ros import dynamics as dyn
from robodyn_ros import messages as M
from robodyn_ros.recording import msgdefs
from robodyn_ros.scene import list_scenes, load_scene
from robodyn_ros.model import FREE
from robodyn_ros.spatial import quat_to_R
from robodyn_ros.tf import ODOM_FRAME, TF_TYPE, TfTree

SCENES = [name for name, _ in list_scenes()]
#: tf2_msgs/msg/TFMessage on Jazzy (``ros2 topic info -v /tf`` on a Jazzy machine prints it)
JAZZY_TF_HASH = 'RIHS01_e369d0f05a23ae52508854b66f6aa0437f3449d652e8cbf22d5abe85d020f087'


def _state(system, rng):
    """A random state: configuration only (zero velocity), minimal coordinates mapped to y."""
    model = system.model
    q = rng.uniform(-1.5, 1.5, model.nq)
    for i in range(model.nb):
        if model.jtype[i] == FREE:   # position, unit quaternion
            k = model.q_idx[i]
            quat = rng.normal(size=4)
            q[k + 3:k + 7] = quat / np.linalg.norm(quat)
    if hasattr(system, 'from_minimal'):
        return system.from_minimal(q, np.zeros(model.nv)), q
    y = np.zeros(system.ny)
    y[:model.nq] = q
    return y, q


def _outputs(system, y):
    return system.outputs(0.0, y, system.zero_inputs(), wrenches=False)


def _all_transforms(tree, out):
    """Every (parent, child, p, quat) of one publication, /tf_static first."""
    static = [(t['header']['frame_id'], t['child_frame_id'],
               [t['transform']['translation'][k] for k in 'xyz'],
               [t['transform']['rotation'][k] for k in 'xyzw'])
              for t in tree.static_message(0)['transforms']]
    dynamic = [(t['header']['frame_id'], t['child_frame_id'],
                [t['transform']['translation'][k] for k in 'xyz'],
                [t['transform']['rotation'][k] for k in 'xyzw'])
               for t in tree.message(0, out)['transforms']]
    return static + dynamic


def _world_poses(transforms, root):
    """Pose (R, p) in ``root`` of every frame, composing the chain of transforms from the root."""
    by_child = {c: (p, np.asarray(t, float), quat_to_R(np.asarray(q, float))) for p, c, t, q in transforms}
    poses = {root: (np.eye(3), np.zeros(3))}

    def pose(frame):
        if frame not in poses:
            parent, t, R = by_child[frame]
            Rp, pp = pose(parent)
            poses[frame] = (Rp @ R, pp + Rp @ t)
        return poses[frame]
    for child in by_child:
        pose(child)
    return poses


@pytest.mark.parametrize('name', SCENES)
def test_tf_tree_is_the_urdf_tree_with_one_root(name):
    """Every non-root URDF link is the child of exactly one transform whose parent is the URDF
    joint's parent; ``odom -> <URDF root>`` for systems that publish odom; no other frame."""
    scene = load_scene(name)
    system = scene.system
    urdf = ET.fromstring(system.urdf())
    links = {link.get('name') for link in urdf.findall('link')}
    parent_of = {j.find('child').get('link'): j.find('parent').get('link') for j in urdf.findall('joint')}
    urdf_root = (links - set(parent_of)).pop()
    assert len(links - set(parent_of)) == 1
    out = _outputs(system, scene.y0)
    transforms = _all_transforms(TfTree(system), out)
    children = [c for _, c, _, _ in transforms]
    assert len(children) == len(set(children)), children   # each frame has one parent
    expected = dict(parent_of)
    if out.odom is not None:
        expected[urdf_root] = ODOM_FRAME
    assert {c: p for p, c, _, _ in transforms} == expected
    frames = set(children) | {p for p, _, _, _ in transforms}
    roots = frames - set(children)
    assert roots == {ODOM_FRAME if out.odom is not None else urdf_root}
    assert frames - {ODOM_FRAME} == links


def test_tree_refuses_a_urdf_it_does_not_match():
    system = load_scene('stanford_arm').system

    class Renamed:
        model = system.model

        def urdf(self):
            return system.urdf().replace('"link6"', '"wrist"')
    with pytest.raises(ValueError, match='robot_description'):
        TfTree(Renamed())


def test_tf_chain_equals_body_poses_of_the_stanford_arm():
    """Composing /tf_static and /tf from base_link to each link (tool included) gives
    dynamics.body_poses at random states (revolute and the prismatic joint 3)."""
    system = load_scene('stanford_arm').system
    tree = TfTree(system)
    rng = np.random.default_rng(7)
    for _ in range(4):
        y, q = _state(system, rng)
        poses = _world_poses(_all_transforms(tree, _outputs(system, y)), system.model.root)
        R, p = dyn.body_poses(system.model, q)
        for i, link in enumerate(system.model.link_names):
            np.testing.assert_allclose(poses[link][0], R[i], atol=1e-12, err_msg=link)
            np.testing.assert_allclose(poses[link][1], p[i], atol=1e-12, err_msg=link)
    assert 'tool' in poses and abs(q[2]) > 0   # the fixed tool frame and a moved prismatic joint


@pytest.mark.parametrize('name', ['betancur_platform', 'mobile_manipulator', 'unfried_free_flyer',
                                  'unfried_air_bearing'])
def test_tf_from_odom_equals_odometry_and_the_dynamics_tree(name):
    """``odom -> base_link`` is the published odometry pose, and composing the whole TF tree from
    odom gives body_poses of the dynamics model (rooted at odom: planar joints or a free joint)."""
    system = load_scene(name).system
    tree = TfTree(system)
    rng = np.random.default_rng(11)
    for _ in range(3):
        y, q = _state(system, rng)
        out = _outputs(system, y)
        transforms = _all_transforms(tree, out)
        (parent, child, t, quat), = [tr for tr in transforms if tr[0] == ODOM_FRAME]
        assert (parent, child) == ('odom', 'base_link')
        assert t == [float(x) for x in out.odom['position']]
        assert quat == [float(x) for x in out.odom['orientation']]
        poses = _world_poses(transforms, ODOM_FRAME)
        R, p = dyn.body_poses(system.model, q)
        shared = [n for n in system.model.link_names if n in poses]
        assert 'base_link' in shared and len(shared) >= 3
        for link in shared:
            i = system.model.link_names.index(link)
            np.testing.assert_allclose(poses[link][0], R[i], atol=1e-12, err_msg=link)
            np.testing.assert_allclose(poses[link][1], p[i], atol=1e-12, err_msg=link)


def test_bundled_tfmessage_definition_and_type_hash():
    """The bundled .msg is Jazzy's text; its RIHS01 hash is Jazzy's; the bundled type description
    hashes to it with rosidl's own function, and its geometry_msgs parts equal the installed ones."""
    from rosidl_generator_type_description import calculate_type_hash
    path = os.path.join(msgdefs.BUNDLED_DIR, 'tf2_msgs', 'msg', 'TFMessage.msg')
    with open(path, 'rb') as f:
        assert f.read() == b'geometry_msgs/TransformStamped[] transforms\n'
    with open(path[:-4] + '.json', encoding='utf-8') as f:
        desc = json.load(f)
    hashes = {h['type_name']: h['hash_string'] for h in desc['type_hashes']}
    assert hashes[TF_TYPE] == calculate_type_hash(desc['type_description_msg']) == JAZZY_TF_HASH
    with open(msgdefs.find_msg_file('geometry_msgs/TransformStamped')[:-4] + '.json', encoding='utf-8') as f:
        ts = json.load(f)
    assert desc['type_description_msg']['referenced_type_descriptions'] == sorted(
        [ts['type_description_msg']['type_description']] + ts['type_description_msg']['referenced_type_descriptions'],
        key=lambda d: d['type_name'])
    assert {h['type_name']: h['hash_string'] for h in ts['type_hashes']}.items() <= hashes.items()
    assert msgdefs.type_hash(TF_TYPE) == JAZZY_TF_HASH   # the bundled definition or an installed Jazzy one


def test_installed_tf2_msgs_take_precedence_over_the_bundled_definition(tmp_path, monkeypatch):
    share = tmp_path / 'share' / 'tf2_msgs' / 'msg'
    share.mkdir(parents=True)
    (share / 'TFMessage.msg').write_text('geometry_msgs/TransformStamped[] transforms\n')
    assert msgdefs.find_msg_file(TF_TYPE) != str(share / 'TFMessage.msg')
    monkeypatch.setenv('AMENT_PREFIX_PATH', str(tmp_path))
    assert msgdefs.find_msg_file(TF_TYPE) == str(share / 'TFMessage.msg')
    monkeypatch.delenv('AMENT_PREFIX_PATH')
    monkeypatch.setattr(msgdefs.sys, 'prefix', str(tmp_path / 'elsewhere'))   # nothing installed
    assert msgdefs.find_msg_file(TF_TYPE) == os.path.join(msgdefs.BUNDLED_DIR, 'tf2_msgs', 'msg', 'TFMessage.msg')


def test_recording_has_tf_every_publication_and_tf_static_once(tmp_path):
    """McapRunSink: /tf at every publication (stamp = log time), /tf_static once and transient
    local; both decode with mcap-ros2-support and rosbags from the file's own schemas; record_tf=False
    and ``robodyn run --no-tf`` leave them out."""
    from rosbags.highlevel import AnyReader

    from robodyn_ros.cli import main as robodyn
    from robodyn_ros.recording import read_messages, summarize
    from robodyn_ros.recording.run_sink import McapRunSink
    from robodyn_ros.simulation import Simulator, run_headless
    scene = load_scene('mobile_manipulator')
    path = tmp_path / 'mm.mcap'
    sim = Simulator(scene.system, scene.y0, integrator='rk4', dt=1e-3)
    sink = McapRunSink(path, scene, {'mode': 'headless'}, record_wrenches=False)
    run_headless(sim, 0.1, 100.0, scene.script, [sink])
    sink.close()
    s = summarize(path)
    topics = s['topics']
    assert topics['/tf']['count'] == topics['/joint_states']['count'] == 11
    assert topics['/tf_static']['count'] == 1
    assert topics['/tf']['type'] == topics['/tf_static']['type'] == TF_TYPE
    assert 'durability: transient_local' in topics['/tf_static']['offered_qos_profiles']
    assert 'durability: volatile' in topics['/tf']['offered_qos_profiles']
    odom = {t: m for _, _, t, m in read_messages(path, topics=['/odom'])}
    n = 0
    for topic, _, t_ns, msg in read_messages(path, topics=['/tf', '/tf_static']):   # mcap-ros2-support
        for tr in msg.transforms:
            assert tr.header.stamp.sec * 10**9 + tr.header.stamp.nanosec == t_ns
        if topic == '/tf':
            base = msg.transforms[0]
            assert (base.header.frame_id, base.child_frame_id) == ('odom', 'base_link')
            assert base.transform.translation.x == odom[t_ns].pose.pose.position.x
            assert base.transform.rotation.z == odom[t_ns].pose.pose.orientation.z
            n += 1
        else:
            assert [tr.child_frame_id for tr in msg.transforms] == [
                'chassis', 'left_wheel_contact', 'right_wheel_contact', 'tool']
    assert n == 11
    with AnyReader([path]) as reader:
        conns = [c for c in reader.connections if c.topic in ('/tf', '/tf_static')]
        decoded = [reader.deserialize(raw, c.msgtype) for c, _, raw in reader.messages(connections=conns)]
    assert len(decoded) == 12 and all(len(m.transforms) >= 4 for m in decoded)
    assert decoded[-1].transforms[0].transform.translation.x == base.transform.translation.x
    assert robodyn(['run', 'mobile_manipulator', '--duration', '0.02', '--record', str(tmp_path / 'no.mcap'),
                    '--no-tf']) == 0
    assert not {'/tf', '/tf_static'} & set(summarize(tmp_path / 'no.mcap')['topics'])


def test_tf_message_fills_an_rclpy_style_message():
    """The node publishes ``M.fill(TFMessage(), dict)``: the sequence of TransformStamped fills."""
    from geometry_msgs.msg import TransformStamped
    scene = load_scene('unfried_free_flyer')
    msg = TfTree(scene.system).message(1_500_000_000, _outputs(scene.system, scene.y0))

    class TFMessage:   # what tf2_msgs.msg.TFMessage looks like to M.fill
        def __init__(self):
            self.transforms = []

        @staticmethod
        def get_fields_and_field_types():
            return {'transforms': 'sequence<geometry_msgs/TransformStamped>'}
    filled = M.fill(TFMessage(), msg)
    assert all(isinstance(t, TransformStamped) for t in filled.transforms)
    assert [(t.header.frame_id, t.child_frame_id) for t in filled.transforms] == [
        (t['header']['frame_id'], t['child_frame_id']) for t in msg['transforms']]
    assert filled.transforms[2].header.stamp.sec == 1 and filled.transforms[2].header.stamp.nanosec == 500_000_000
    assert filled.transforms[3].transform.rotation.w == msg['transforms'][3]['transform']['rotation']['w']


def test_node_parameter_publish_tf():
    from robodyn_ros.nodes.sim import PARAMETERS, ConfigError, resolve_config
    scene = load_scene('stanford_arm')
    raw = {k: default for k, (default, _) in PARAMETERS.items()}
    assert raw['publish_tf'] is True and resolve_config(raw, scene).publish_tf is True
    assert resolve_config({**raw, 'publish_tf': False}, scene).publish_tf is False
    with pytest.raises(ConfigError, match='publish_tf'):
        resolve_config({**raw, 'publish_tf': 'yes'}, scene)
    from pathlib import Path
    yaml_text = (Path(__file__).resolve().parents[1] / 'config' / 'sim.yaml').read_text()
    assert 'publish_tf: true' in yaml_text
